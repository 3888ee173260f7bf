"""Several takes of one cloth in one fit (docs/takes.md).

A *take* is one capture of the cloth under one handling: its own cameras (a rig may differ between takes),
frame times and frame rate, handles and release, and the manipulation's unknowns it declares. A fit of several
takes searches one set of cloth settings shared by all of them and each take's own unknowns beside them; a fit
of one take is the same machinery with one take.

* ``Take``: one capture in a fit: its training cameras and frames, their silhouettes, its scenario, its frame
  rate and its manipulation's unknowns (``take_manipulation``);
* ``TakesObjective``: the training error of a population summed over the takes, each take simulated at its own
  frame rate (Blender's cloth: the same settings with each take's own real-time Speed Multiplier, so that the
  cloth moves alike in physical time whatever the rate);
* ``TakesManipulation``: the takes' unknowns one after another, named ``<take>:<unknown>``;
* ``TakeView``: one take of a fit of several, seen as a fit of that take alone (the shared settings and that
  take's own unknowns), so that the floor report (``diagnose.report``), the fitted manipulation
  (``manipulation_result``) and the verdict speak for each take;
* ``manipulation_result``: a fit's (or a take's) fitted manipulation for the result.
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from ..physics import blender as B
from ..physics.scenario import Uncertainty
from .checkpoint import capture_hash, silhouettes_hash
from .objective import SilhouetteObjective, load_observed
from .parameters import ManipulationParameters, release_instants
from .verdict import verdict

TAKE_SEP = ":"  # between a take's name and its unknown's: "one_corner:time_offset_s"


def selection(value: Any, k: int, n_takes: int, what: str) -> list | None:
    """Take ``k``'s share of a config's ``train_cameras`` or ``train_times``: a list per take (a list of lists,
    one per take), or one list (or None) for every take."""
    if value is None or not any(v is None or isinstance(v, (list, tuple)) for v in value):
        return None if value is None else list(value)
    if len(value) != n_takes or not all(v is None or isinstance(v, (list, tuple)) for v in value):
        raise ClothFitError(f"fit config: {what} must be one list, or one list per take ({n_takes}), got {value!r}")
    return None if value[k] is None else list(value[k])


def take_names(captures: Sequence[Any]) -> list[str]:
    """Each take's name: its capture folder's, made unique by its place where two are alike."""
    base = [os.path.basename(os.path.normpath(c.root)) or f"take{i + 1}" for i, c in enumerate(captures)]
    return [b if base.count(b) == 1 else f"{b}#{i + 1}" for i, b in enumerate(base)]


def check_same_cloth(captures: Sequence[Any], names: Sequence[str]) -> None:
    """Takes of one cloth: the same grid (vertices, size) and the same cloth mass where they give one; else a
    one-line error naming the takes that differ."""
    first = captures[0]
    g0 = first.scenario.grid
    for c, n in zip(captures[1:], names[1:]):
        g = c.scenario.grid
        if (g.nx, g.ny) != (g0.nx, g0.ny) or not np.allclose([g.side, g.side_y], [g0.side, g0.side_y], rtol=1e-9):
            raise ClothFitError(
                f"takes {names[0]} and {n} are not of one cloth: a {g0.nx} x {g0.ny} grid of "
                f"{g0.side:g} x {g0.side_y:g} m against a {g.nx} x {g.ny} grid of {g.side:g} x {g.side_y:g} m"
            )
        m0, m = first.cloth_mass, c.cloth_mass
        if m0 is not None and m is not None and abs(m - m0) > 1e-9 * max(m, m0):
            raise ClothFitError(f"takes {names[0]} and {n} are not of one cloth: cloth_mass {m0:g} kg against {m:g} kg")


class Take:
    """One capture in a fit: the training cameras and frames (``cameras``: indices, None = all; ``times``:
    frame times, None = all), their silhouettes at the fit's resolution, the scenario at those frames, and
    the manipulation's unknowns (``take_manipulation``). ``fps`` (the frame rate its settings' time scale is
    for) is set by the fit once it knows the model."""

    def __init__(self, capture, cfg, name: str, cameras=None, times=None, evaluator=None):
        self.capture, self.name = capture, name
        ncam = len(capture.cameras)
        where = f"take {name}: " if name else ""
        cams = list(range(ncam)) if cameras is None else [int(c) for c in cameras]
        for c in cams:
            if not 0 <= c < ncam:
                raise ClothFitError(f"{where}training camera index {c} outside 0..{ncam - 1}")
        if not cams:
            raise ClothFitError(f"{where}no training camera selected")
        if len(set(cams)) != len(cams):
            raise ClothFitError(f"{where}training cameras {cams} name a camera twice")
        times = list(capture.frame_times) if times is None else list(times)
        if not times:
            raise ClothFitError(f"{where}no training frame selected")
        try:
            fidx = [capture.frame_index(t) for t in times]
        except ClothFitError as e:  # which take has no frame there
            raise ClothFitError(f"{where}{e}") from None
        if len(set(fidx)) != len(fidx):
            raise ClothFitError(f"{where}training times {times} name a frame twice")
        self.train_cameras = cams
        self.train_frames = fidx
        self.train_times = [float(capture.frame_times[i]) for i in fidx]
        cameras_, observed, ignore = load_observed(capture, cams, fidx, cfg.resolution)
        self.capture_hash = capture_hash(capture)
        self.silhouettes_hash = silhouettes_hash(observed, ignore)
        names = [[capture.silhouette_path(c, f) for f in fidx] for c in cams]
        self.images = (cameras_, observed, ignore, names)
        if evaluator is not None:
            self.scenario = evaluator.scenario(self.train_times, capture.scenario.crop)
        else:
            self.scenario = capture.scenario.with_frames(self.train_times)
        self.evaluator = evaluator
        self.manip, self.manip_note = take_manipulation(capture, cfg, self.scenario, self.train_times, evaluator)
        self.fps = None
        self.fps_source = None

    def objective(self, model: Any, backend: str) -> SilhouetteObjective:
        """The take's training objective simulated by ``model``."""
        cameras, observed, ignore, names = self.images
        return SilhouetteObjective(
            self.scenario, cameras, observed, backend=backend, names=names, model=model, ignore=ignore
        )

    def window(self, k: int, model: Any, backend: str) -> SilhouetteObjective:
        """The take's training objective on its first ``k`` training frames only (every one if it has no more):
        the simulation stops at the last of them."""
        cameras, observed, ignore, names = self.images
        times = self.train_times[:k]
        if self.evaluator is not None:
            scenario = self.evaluator.scenario(times, self.capture.scenario.crop)
        else:
            scenario = self.scenario.with_frames(times)
        return SilhouetteObjective(
            scenario,
            cameras,
            [o[:k] for o in observed],
            backend=backend,
            names=[n[:k] for n in names],
            model=model,
            ignore=None if ignore is None else [None if g is None else g[:k] for g in ignore],
        )

    def window_share(self, k: int) -> float:
        """What an evaluation on the first ``k`` training frames costs beside one on every frame
        (``first_frames_share``)."""
        return first_frames_share(self.train_times, self.capture.scenario.settle_time, k)


def first_frames_share(times: Sequence[float], settle: float, k: int) -> float:
    """What an evaluation on the first ``k`` of the frames at ``times`` costs beside one on all of them: the larger of
    their share of the frames (the silhouettes) and of the simulated time from the settle's start (the simulation)."""
    k = min(k, len(times))
    return max(k / len(times), (times[k - 1] + settle) / (times[-1] + settle))


def window_objective(job: Any, k: int | None) -> SilhouetteObjective | TakesObjective | None:
    """``job``'s running objective (``FitJob``) on each take's first ``k`` training frames, or None for ``k`` None:
    every frame (the optimiser's ``window``). Kept once built, until the running objective changes."""
    if k is None:
        return None
    obj = job.objective
    kept = job.windows.get(k)
    if kept is None or kept[0] is not obj:
        parts = obj.objectives if isinstance(obj, TakesObjective) else [obj]
        w = [t.window(k, o.model, o.backend) for t, o in zip(job.takes, parts)]
        kept = (obj, w[0] if len(w) == 1 else TakesObjective(w, obj.scales))
        job.windows[k] = kept
    return kept[1]


def window_share(takes: Sequence[Take], k: int) -> float:
    """What an evaluation on every take's first ``k`` training frames costs beside one on every frame (the dearest
    take's ``Take.window_share``)."""
    return max(t.window_share(k) for t in takes)


def take_manipulation(
    capture: Any, cfg: Any, scenario: Any, train_times: Sequence[float], evaluator: Any
) -> tuple[ManipulationParameters | None, str | None]:
    """(ManipulationParameters or None, note): what of a take's manipulation the fit estimates (the config's
    ``uncertain`` for every take, else the capture's own)."""
    sc = capture.scenario
    nh = len(sc.handles)
    if cfg.uncertain is None:
        unc = capture.uncertain
    elif isinstance(cfg.uncertain, str):
        unc = Uncertainty.from_text(cfg.uncertain, nh, "fit: uncertain")
    else:
        unc = Uncertainty.parse(cfg.uncertain, nh, "fit: uncertain")
    if unc is None or not unc.active:
        return None, None
    notes = []
    if evaluator is not None and any(b > 0 for b in unc.handles):
        raise ClothFitError(
            "fit: uncertain handles cannot be estimated with --backend blender (the scene's pins "
            "are its own objects): give --uncertain time_offset=S,handles=0, or fit the capture "
            "with the core model"
        )
    if evaluator is not None and unc.time_scale > 1.0:
        raise ClothFitError(
            "fit: an uncertain time_scale cannot be estimated with --backend blender (the scene keeps its own "
            "frame rate): fit the capture with the core model"
        )
    n_frames = len(train_times)
    rel = [h.release_time for h in sc.handles if h.release_time is not None]
    after = sum(t >= min(rel) for t in train_times) if rel else n_frames
    t_bound, h_bounds = unc.time_offset, unc.handles
    if t_bound > 0 and after < D.MIN_FRAMES_FOR_TIME_OFFSET:
        notes.append(
            f"time_offset not estimated: {after} training frame(s) after the release cannot separate "
            f"it from the cloth's settings (need {D.MIN_FRAMES_FOR_TIME_OFFSET})"
        )
        t_bound = 0.0
    if any(b > 0 for b in h_bounds) and n_frames < 2:
        notes.append("handle offsets not estimated: one training frame cannot separate them from the cloth's settings")
        h_bounds = (0.0,) * nh
    unc = Uncertainty(t_bound, tuple(h_bounds), unc.time_scale)
    note = "; ".join(notes) or None
    if not unc.active:
        return None, note
    return ManipulationParameters(unc, scenario), note


def time_scaled(rows: np.ndarray, scale: float) -> np.ndarray:
    """Blender-cloth rows with their Speed Multiplier times ``scale`` (a take at another frame rate: the
    same cloth in physical time); the rows themselves when ``scale`` is 1."""
    if scale == 1.0:
        return rows
    out = np.array(rows, dtype=np.float64, copy=True)
    out[:, B.FLOAT_SETTINGS.index("time_scale")] *= scale
    return out


def combined_hash(hashes: Sequence[str]) -> str:
    """One hash of several takes' hashes, in order."""
    return hashlib.sha256("\n".join(hashes).encode()).hexdigest()


class TakesObjective:
    """The training error of a population over several takes: the sum of each take's (``objectives``), the
    rows given to take ``k`` with their time scale times ``scales[k]`` (``time_scaled``). A candidate that
    explodes in any take scores ``inf``."""

    def __init__(self, objectives: Sequence[SilhouetteObjective], scales: Sequence[float]):
        self.objectives = list(objectives)
        self.scales = [float(s) for s in scales]
        self.model = self.objectives[0].model
        self.backend = self.objectives[0].backend

    @property
    def n_images(self) -> int:
        return int(sum(o.n_images for o in self.objectives))

    def per_take(self, P: ArrayLike, offsets: Sequence[Any] | None = None) -> np.ndarray:
        """(P, takes): each candidate's training error on each take."""
        P = np.atleast_2d(np.asarray(P, dtype=np.float64))
        out = np.zeros((P.shape[0], len(self.objectives)))
        for k, (obj, s) in enumerate(zip(self.objectives, self.scales)):
            off = None if offsets is None else offsets[k]
            rows = time_scaled(P, s) if not obj.paper else P
            out[:, k] = obj(rows) if off is None else obj(rows, offsets=off)
        return out

    def __call__(self, P: ArrayLike, offsets: Sequence[Any] | None = None) -> np.ndarray:
        e = self.per_take(P, offsets).sum(axis=1)
        e[~np.isfinite(e)] = np.inf
        return e


class TakesManipulation:
    """The manipulation's unknowns of several takes one after another (a take without any adds none), named
    ``<take>:<unknown>``; ``offsets(M)`` gives each take's ``scenario.Offsets`` (None for a take without
    unknowns), which ``TakesObjective`` hands to that take."""

    def __init__(self, takes: Sequence[Take]):
        self.parts = []  # (first coordinate, the take's ManipulationParameters or None)
        names, bounds = [], {}
        for t in takes:
            self.parts.append((len(names), t.manip))
            for n in t.manip.names if t.manip is not None else ():
                names.append(f"{t.name}{TAKE_SEP}{n}")
                bounds[names[-1]] = t.manip.bounds[n]
        self.names, self.bounds = names, bounds

    @property
    def n(self) -> int:
        return len(self.names)

    def part(self, M: ArrayLike, k: int) -> np.ndarray:
        """Take ``k``'s own coordinates of ``M`` (P, n)."""
        M = np.atleast_2d(np.asarray(M, dtype=np.float64)).reshape(-1, self.n)
        start, manip = self.parts[k]
        return M[:, start : start + (manip.n if manip is not None else 0)]

    def offsets(self, M: ArrayLike) -> list:
        return [None if m is None else m.offsets(self.part(M, k)) for k, (_, m) in enumerate(self.parts)]

    def at_bound(self, m: ArrayLike, share: float = D.MANIP_AT_BOUND_SHARE) -> list[str]:
        m = np.asarray(m, dtype=np.float64).reshape(-1)
        return [n for n, v in zip(self.names, m) if abs(v) >= share * self.bounds[n][1]]


class TakeParameters:
    """A fit's parameter set-up seen from one take: the same settings, the rows' time scale for the take's
    frame rate (``time_scaled``); everything else is the fit's."""

    def __init__(self, par: Any, scale: float):
        self._par, self.scale = par, float(scale)

    def __getattr__(self, name):
        return getattr(self._par, name)

    def rows(self, X: ArrayLike) -> np.ndarray:
        R = self._par.rows(X)
        return R if getattr(self._par.model, "name", "") != "blender" else time_scaled(R, self.scale)


class TakeView:
    """Take ``k`` of a fit of several takes (``job``: a ``FitJob``), seen as a fit of that take alone: the
    shared settings with the take's own unknowns (``best_x``), its training error, its objectives at any
    quality, its part of the profile. What ``diagnose.report`` and ``manipulation_result`` read of a fit."""

    def __init__(self, job: Any, k: int):
        t = job.takes[k]
        self.job, self.k, self.take = job, k, t
        self.capture, self.config, self.evaluator = t.capture, job.config, job.evaluator
        self.train_cameras, self.train_frames, self.train_times = t.train_cameras, t.train_frames, t.train_times
        self.scenario, self.manip, self.manip_note = t.scenario, t.manip, t.manip_note
        self.npar, self.ladder = job.npar, job.ladder
        self.par = TakeParameters(job.par, job.take_scales[k])
        x = job.best_x
        self.best_x = None
        if x is not None:
            own = job.manip.part(x[None, job.npar :], k)[0] if job.manip is not None else np.zeros(0)
            self.best_x = np.concatenate([np.asarray(x[: job.npar], dtype=np.float64), own])
        self.objective = self.objective_at(job.chosen_quality())
        self._best_error = None
        prefix = f"{t.name}{TAKE_SEP}"
        prof = job.state.profile
        own = None if prof is None or t.manip is None else {n: prof[prefix + n] for n in t.manip.names}
        self.state = replace(job.state, profile=own)  # the fit's progress, with this take's part of the profile

    @property
    def best_error(self) -> float:
        """The take's own training error at the fit's best point (one evaluation, the first time it is asked)."""
        if self._best_error is None:
            self._best_error = float("inf") if self.best_x is None else float(self.evaluate(self.best_x[None])[0])
        return self._best_error

    def chosen_quality(self) -> int | None:
        return self.job.chosen_quality()

    def objective_at(self, quality: int | None) -> SilhouetteObjective:
        return self.job.take_objective(self.k, quality)

    def evaluate(self, X: ArrayLike, objective: SilhouetteObjective | None = None) -> np.ndarray:
        return candidate_errors(self, X, objective)


def candidate_errors(fit: Any, X: ArrayLike, objective: Any = None) -> np.ndarray:
    """The training error of candidates ``X`` (``fit``'s search space: settings, then the manipulation's
    unknowns) by ``objective`` (default ``fit.objective``): ``fit`` is a ``FitJob`` or a ``TakeView``."""
    obj = objective or fit.objective
    X = np.atleast_2d(np.asarray(X, dtype=np.float64))
    rows = fit.par.rows(X[:, : fit.npar])
    if fit.manip is None:
        return obj(rows)
    return obj(rows, offsets=fit.manip.offsets(X[:, fit.npar :]))


def manipulation_result(fit: Any) -> dict:
    """The result's fitted manipulation of ``fit`` (a ``FitJob`` of one take, or a ``TakeView``):
    ``time_offset_s``, ``handles`` with uncertainties (from the profile), what could not be separated, or
    nothing when the manipulation had no unknowns."""
    x = fit.best_x
    if fit.manip is None or x is None:
        return {"manipulation_note": fit.manip_note} if fit.manip_note else {}
    manip, npar = fit.manip, fit.npar
    m = np.array(x[npar:], dtype=np.float64)
    spread = None
    notes = [fit.manip_note] if fit.manip_note else []
    prof = fit.state.profile or {}

    def falls_outward(n):  # the profile's error still falls beyond the bound, on the value's side
        p = prof.get(n)
        if p is None:
            return False  # no profile: only the value itself, at the bound, tells
        out = p["E_plus"] if m[manip.names.index(n)] > 0 else p["E_minus"]
        return None not in (out, p["E_centre"], p["rise"]) and out < p["E_centre"] - p["rise"]

    # at the edge of its declared bound: a separated offset there, or one within a profile step of it whose
    # error still falls outward (a slope the profile cannot call a valley: the capture is further off than
    # it declares, and the search stopped against the bound)
    at = manip.at_bound(m)
    near = manip.at_bound(m, D.MANIP_AT_BOUND_SHARE - D.PROFILE_STEP)
    # exactly at its bound: only the polish puts an offset there (a step cut at the bound that lowered the error)
    pressed = manip.at_bound(m, 1.0)
    edge = [
        n for n in near if (n in at and (prof.get(n) or {}).get("separated", True)) or n in pressed or falls_outward(n)
    ]
    flat = []
    if fit.state.profile is not None:
        spread = [fit.state.profile[n]["uncertainty"] for n in manip.names]
        flat = [n for n in manip.names if not fit.state.profile[n]["separated"] and n not in edge]
        if flat:
            # the settings were fitted with these values: a replay with the capture's own (as this fit did
            # before) scored other settings than the fit's, on the released corner often much worse
            notes.append(
                f"cannot be separated from the cloth's settings (the error is flat within the bound): "
                f"{', '.join(flat)}; the fitted value is kept for the replay (the settings were fitted with "
                f"it) but is not a measurement"
            )
    d = manip.describe(m, fit.capture.scenario, spread)
    d["at_bound"] = edge
    d["not_separated"] = flat
    if edge:

        def shown(n):
            v, b = m[manip.names.index(n)], manip.bounds[n][1]
            if n == "log_time_scale":
                return f"time_scale {math.exp(v):.3f} (bound {math.exp(-b):.3f}..{math.exp(b):.3f})"
            unit = "ms" if n == "time_offset_s" else "mm"
            return f"{n} {1e3 * v:+.2f} {unit} (bound {1e3 * b:.2f} {unit})"

        notes.append(
            f"at the edge of the capture's declared bound: {', '.join(shown(n) for n in edge)}; the "
            f"manipulation may be further off than the capture declares: fit again with a wider --uncertain"
        )
    rel = release_instants(
        fit.objective.model,
        fit.capture.scenario,
        d.get("time_offset_s"),
        d.get("time_offset_uncertainty_s"),
        d.get("time_scale", 1.0),
    )
    if rel:
        d["release_instants"] = rel
    if fit.state.profile is None:
        notes.append("uncertainties not estimated (the fit stopped before its profile)")
    d["manipulation_profile"] = fit.state.profile
    if notes:
        d["manipulation_note"] = "; ".join(notes)
    return d


def takes_entries(job: Any) -> list[dict]:
    """A fit of several takes: one entry per take (its capture, training cameras and frames, frame rate, its
    fitted manipulation, and once the fit is done its errors beside its floor and its verdict)."""
    out = []
    for k, t in enumerate(job.takes):
        e = {
            "take": t.name,
            "capture": os.path.abspath(t.capture.root),
            "capture_hash": t.capture_hash,
            "train_cameras": [t.capture.cameras[c].name for c in t.train_cameras],
            "train_camera_indices": t.train_cameras,
            "train_times": t.train_times,
            "fps": t.fps,
            "fps_source": t.fps_source,
            "n_train_images": len(t.train_cameras) * len(t.train_frames),
        }
        if job.best_x is not None:
            e.update(manipulation_result(TakeView(job, k)))
        if job.state.take_finals is not None:
            e["floor"] = fl = job.state.take_finals[k]
            e["train_E_sil_pct"] = fl.get("train_E_sil_pct")
            e["heldout_E_sil_pct"] = fl.get("heldout_E_sil_pct")
            e["alone_E_sil_pct"] = fl.get("alone_E_sil_pct")
            e["verdict_kind"], e["verdict"] = verdict({"floor": fl, "evaluations": job.evaluations})
        out.append(e)
    return out
