"""The cloth models of the core and the one entry point that simulates them.

A *model* turns a scenario (``scenario.py``) and a population of parameter rows into the cloth's
positions at the scenario's frame times (``SimResult``), with the fastest backend available: the
numba kernels (``*_kernels``) or the numpy reference code they are tested against.

* ``paper`` (``PaperModel``): the paper's mass-spring sheet; a row is ``(m, k, l, d)``.
* ``blender`` (``BlenderModel``): Blender's own cloth solver (``blender.py``); a row is one value
  per name of ``blender.FLOAT_SETTINGS``; the model fixes the frame rate it targets, the
  solver quality and the bending model.

``get_model`` builds one from a name or its ``to_dict()``; ``simulate`` keeps the paper model's
historical call.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from . import blender as B
from . import blender_kernels, jit, paper_kernels
from .paper import PARAM_NAMES, Params, SimResult, as_params, simulate_numpy
from .scenario import Offsets, Scenario

MODEL_NAMES = ("paper", "blender")


def _backend(backend: str) -> str:
    if backend == "auto":
        return "numba" if jit.available() else "numpy"
    if backend not in ("numba", "numpy"):
        raise ClothFitError(f"unknown simulation backend {backend!r} (numpy, numba, auto)")
    if backend == "numba" and not jit.available():
        raise ClothFitError("the numba backend was asked for but numba is not importable")
    return backend


@runtime_checkable
class ClothModel(Protocol):
    """What a fit asks of a cloth model: ``PaperModel``, ``BlenderModel``, or a model-like evaluator (Blender's
    own solver on a user's scene, ``farm.scene.BlendSceneEvaluator``). ``name``: "paper" or "blender";
    ``row_names``: the values of a parameter row, in order; ``to_dict``: what a result and a checkpoint record
    of it (``get_model`` builds the model back from it); ``simulate``: a population of rows on a scenario,
    each candidate with its own manipulation (``offsets``) or the scenario's."""

    name: str
    row_names: tuple[str, ...]

    def to_dict(self) -> dict: ...

    def simulate(
        self, scenario: Scenario, rows: ArrayLike, backend: str = "auto", offsets: Offsets | None = None
    ) -> SimResult: ...


class PaperModel:
    """The paper's sheet (docs/method.md#spec-2): rows ``(m, k, l, d)``."""

    name = "paper"
    row_names = PARAM_NAMES

    def __init__(self, safety: float = D.DT_SAFETY):
        self.safety = float(safety)

    def to_dict(self) -> dict:
        return {"name": self.name}

    def release_instant(self, release_time: float) -> float:
        """When this model's cloth starts to fall for a handle declared released at ``release_time``:
        the sheet's steps meet the release time exactly (``paper.py``), so at that time."""
        return float(release_time)

    def simulate(
        self,
        scenario: Scenario,
        rows: Params | dict[str, float] | ArrayLike | Iterable[Params | dict[str, float]],
        backend: str = "auto",
        offsets: Offsets | None = None,
    ) -> SimResult:
        """``offsets``: each candidate's own manipulation (``Scenario.moved``), None = the scenario's."""
        if scenario.colliders is not None:
            raise ClothFitError("the paper model has no colliders: fit a scene with a table with --model blender")
        P = as_params(rows)
        if _backend(backend) == "numba":
            if offsets is not None and offsets.stretches:  # key times differ per candidate: one by one
                return _each(P, offsets, lambda p, sc: paper_kernels.simulate(sc, p, self.safety), scenario)
            return paper_kernels.simulate(scenario, P, self.safety, offsets)
        if offsets is None:
            return simulate_numpy(scenario, P, self.safety)
        return _each(P, offsets, lambda p, sc: simulate_numpy(sc, p, self.safety), scenario)


class BlenderModel:
    """Blender's Cloth modifier (``blender.py``) on the scenario's grid, for a scene at ``fps``
    frames per second with ``quality`` steps per frame and the given bending model. Rows hold the
    ``FLOAT_SETTINGS`` (``time_scale`` included: ``blender.physical_time_scale(fps)`` makes the
    cloth move in real time)."""

    name = "blender"
    row_names = B.FLOAT_SETTINGS

    def __init__(self, fps: float = D.BLENDER_FPS, quality: int = 5, bending_model: str = "ANGULAR"):
        if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
            raise ClothFitError(f"frame rate {fps!r} must be a positive number")
        s = B.check_settings({"quality": quality, "bending_model": bending_model}, "blender model")
        self.fps = float(fps)
        self.quality = s["quality"]
        self.bending_model = s["bending_model"]
        self._cache = {}
        self._spans = {}

    def to_dict(self) -> dict:
        return {"name": self.name, "fps": self.fps, "quality": self.quality, "bending_model": self.bending_model}

    def settings(self, row: ArrayLike) -> dict:
        return B.row_settings(row, self.quality, self.bending_model)

    def release_instant(self, release_time: float) -> float:
        """When this model's cloth starts to fall for a handle declared released at ``release_time``:
        Blender pins per frame (``blender.FramePlan``: pinned during the step into every frame at or
        before the release time, frames at multiples of 1/fps from t = 0), so the fall starts at the
        last held frame, up to one frame before the declared instant. A fit's ``time_offset_s`` moves
        that frame against the capture's clock: it is how the fit places the release between frames."""
        t = float(release_time)
        j = max(math.floor(t * self.fps), -1)
        while (j + 1) / self.fps <= t:  # the frames' own test (t_frame <= release_time), against rounding
            j += 1
        while j >= 0 and j / self.fps > t:
            j -= 1
        return j / self.fps

    def plan(self, scenario: Scenario) -> tuple[B.Network, B.FramePlan]:
        """(network, frame plan) of a scenario, built once per scenario object."""
        key = id(scenario)
        hit = self._cache.get(key)
        if hit is None or hit[0] is not scenario:
            plan = B.FramePlan.from_scenario(scenario, self.fps)
            first = scenario.grid.rest.copy()
            first[plan.handle_vertices] = plan.targets[0]
            net = B.Network.from_grid(scenario.grid, self.bending_model, first_frame=first)
            hit = (scenario, net, plan, {})
            if len(self._cache) >= 8:  # a few scenarios (a fit's and its time-spanning ones)
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = hit
        return hit[1], hit[2]

    def spanning(self, scenario: Scenario, span: float) -> Scenario:
        """The scenario with its frames extended by ``span`` seconds either way (within the settle):
        what candidates that read the frames up to ``span`` s earlier or later need simulated. Its last
        frame is the first whole frame at or after ``span`` past the scenario's last: the solver steps
        whole frames, so every span ending within one frame simulates the same, and one extended
        scenario (and one network and kernel set-up) serves them all."""
        t = np.asarray(scenario.frame_times, dtype=np.float64)
        k = math.ceil((t[-1] + float(span)) * self.fps - 1e-6)  # FramePlan's own tolerance for a whole frame
        key = (id(scenario), k)
        hit = self._spans.get(key)
        if hit is None or hit[0] is not scenario:
            end = max(k / self.fps, float(t[-1]))
            ext = np.concatenate([[max(t[0] - float(span), -scenario.settle_time)], t, [end]])
            hit = (scenario, scenario.with_frames(np.unique(ext)))
            if len(self._spans) >= 4:  # a fit's spans end within a frame or two of its last frame
                self._spans.pop(next(iter(self._spans)))
            self._spans[key] = hit
        return hit[1]

    def check_rows(self, rows: ArrayLike) -> np.ndarray:
        rows = np.asarray(rows, dtype=np.float64)
        if rows.ndim == 1:
            rows = rows[None]
        if rows.ndim != 2 or rows.shape[1] != len(B.FLOAT_SETTINGS):
            raise ClothFitError(
                f"blender model: rows must have {len(B.FLOAT_SETTINGS)} values "
                f"({', '.join(B.FLOAT_SETTINGS)}), got shape {rows.shape}"
            )
        for r in rows:
            B.check_settings(self.settings(r), "blender model")
        return rows

    def simulate(
        self, scenario: Scenario, rows: ArrayLike, backend: str = "auto", offsets: Offsets | None = None
    ) -> SimResult:
        """``offsets``: each candidate's own manipulation (its frames read ``offsets.time`` s earlier,
        its handles moved, its rest shape that of its own first frame); None = the scenario's."""
        rows = self.check_rows(rows)
        if offsets is not None:
            return self._simulate_offsets(scenario, rows, backend, offsets)
        net, plan = self.plan(scenario)
        n = rows.shape[0]
        V = net.n_vertices
        F = plan.lo.size
        if _backend(backend) == "numpy":
            out = np.full((n, F, V, 3), np.nan)
            exploded = np.zeros(n, bool)
            reason = [""] * n
            steps = np.zeros(n, dtype=np.int64)
            for p in range(n):
                tr = B.simulate_reference(
                    net, plan, self.settings(rows[p]), scenario.gravity, colliders=scenario.colliders
                )
                out[p], exploded[p], reason[p] = tr.positions, tr.exploded, tr.reason
                steps[p] = tr.steps_per_frame * plan.n_frames
            return SimResult(out, exploded, steps, reason)
        out = np.full((n, F, V, 3), np.nan)
        codes = np.zeros(n, dtype=np.int64)
        steps = np.zeros(n, dtype=np.int64)
        ts_col = B.FLOAT_SETTINGS.index("time_scale")
        for ts in np.unique(rows[:, ts_col]):  # the kernel runs one time step per call
            sel = np.nonzero(rows[:, ts_col] == ts)[0]
            prep = self.prepared(scenario, float(ts))
            frames, c, _ = prep.run(rows[sel])
            out[sel] = prep.sample(frames)
            codes[sel] = c
            steps[sel] = prep.tg.size * plan.n_frames
        exploded = codes != 0
        out[exploded] = np.nan
        reason = ["" if c == 0 else f"exploded ({blender_kernels.REASONS[c]})" for c in codes]
        return SimResult(out, exploded, steps, reason)

    def prepared(self, scenario: Scenario, time_scale: float, all_frames: bool = False) -> blender_kernels.Prepared:
        """The kernel's float32 arrays for a scenario and time step, built once."""
        net, plan = self.plan(scenario)
        store = self._cache[id(scenario)][3]
        prep = store.get((time_scale, all_frames))
        if prep is None:
            prep = store[(time_scale, all_frames)] = blender_kernels.Prepared(
                net, plan, self.quality, time_scale, scenario.gravity, all_frames, scenario.colliders
            )
        return prep

    def _simulate_offsets(self, scenario, rows, backend, offsets: Offsets) -> SimResult:
        n = rows.shape[0]
        if len(offsets) != n:
            raise ClothFitError(f"blender model: {len(offsets)} offsets for {n} candidates")
        if _backend(backend) == "numpy" or offsets.stretches:  # stretched keys: each candidate on its own
            return _each(rows, offsets, lambda r, sc: self.simulate(sc, r, backend), scenario)
        ext = self.spanning(scenario, offsets.span)
        net, plan = self.plan(ext)
        F, V = scenario.frame_times.size, net.n_vertices
        out = np.full((n, F, V, 3), np.nan)
        codes = np.zeros(n, dtype=np.int64)
        steps = np.zeros(n, dtype=np.int64)
        ts_col = B.FLOAT_SETTINGS.index("time_scale")
        moved = offsets.moves_handles
        for ts in np.unique(rows[:, ts_col]):
            sel = np.nonzero(rows[:, ts_col] == ts)[0]
            prep = self.prepared(ext, float(ts), all_frames=True)
            frames, c, _ = prep.run(rows[sel], offsets.handles[sel] if moved else None)
            t = scenario.frame_times[None, :] - offsets.time[sel, None]
            read = np.maximum(plan.frame_of(t), 0.0)
            out[sel] = prep.sample(frames, read)
            codes[sel] = c
            steps[sel] = prep.tg.size * plan.n_frames
        exploded = codes != 0
        out[exploded] = np.nan
        reason = ["" if c == 0 else f"exploded ({blender_kernels.REASONS[c]})" for c in codes]
        return SimResult(out, exploded, steps, reason)


def _each(rows, offsets: Offsets, simulate_one, scenario: Scenario) -> SimResult:
    """The reference path of a population with offsets: each candidate on its own moved scenario."""
    parts = [
        simulate_one(rows[p : p + 1], scenario.moved(offsets.time[p], offsets.handles[p], offsets.scale[p]))
        for p in range(len(offsets))
    ]
    return SimResult(
        np.concatenate([r.positions for r in parts]),
        np.concatenate([r.exploded for r in parts]),
        np.concatenate([np.atleast_1d(r.substeps) for r in parts]),
        [x for r in parts for x in r.reason],
    )


def get_model(spec: str | dict[str, Any] | ClothModel | None = None) -> ClothModel:
    """A model from a name ("paper", "blender") or a ``to_dict()``; None = the paper model; a model (or a
    model-like evaluator, e.g. Blender's workers on a scene) is returned as it is."""
    if spec is None:
        return PaperModel()
    if isinstance(spec, ClothModel) and callable(spec.simulate):
        return spec
    if isinstance(spec, str):
        spec = {"name": spec}
    if not isinstance(spec, dict) or "name" not in spec:
        raise ClothFitError(f"model: expected a name ({', '.join(MODEL_NAMES)}) or an object with 'name', got {spec!r}")
    name = str(spec["name"]).strip().lower()
    if name == "paper":
        return PaperModel()
    if name == "blender":
        extra = set(spec) - {"name", "fps", "quality", "bending_model"}
        if extra:
            raise ClothFitError(f"model: unknown key(s) {sorted(extra)} for the blender model")
        return BlenderModel(
            spec.get("fps", D.BLENDER_FPS),
            spec.get("quality", B.DEFAULTS["quality"]),
            spec.get("bending_model", B.DEFAULTS["bending_model"]),
        )
    raise ClothFitError(f"unknown model {spec['name']!r}: choose one of {', '.join(MODEL_NAMES)}")


def model_and_row(
    res: dict[str, Any], default_model: str | dict[str, Any] | ClothModel | None = None
) -> tuple[ClothModel, np.ndarray]:
    """(model, one parameter row) to replay ``res``: a fit result (its ``model``, ``blender_cloth``,
    ``blender_scene`` or ``params``), a paper parameter object (m, k, l, d) or an object of
    ClothSettings values (for ``default_model``'s frame rate, else Blender's default 24 fps)."""
    if not isinstance(res, dict):
        raise ClothFitError("parameters: expected a JSON object (a fit result, m/k/l/d or ClothSettings values)")
    bc = res.get("blender_cloth")
    if bc is None and set(res) & (set(B.FLOAT_SETTINGS) | {"quality", "bending_model"}) and "k" not in res:
        bc = res  # bare ClothSettings values
    spec = res.get("model") or ("blender" if bc is not None else None)
    if spec is None:
        spec = default_model if default_model is not None else "paper"
        if get_model(spec).name == "blender":
            raise ClothFitError(
                "parameters: the blender model needs 'blender_cloth' (ClothSettings values), not m, k, l, d"
            )
    model = get_model(spec)
    if isinstance(model, BlenderModel):
        if not isinstance(bc, dict):
            raise ClothFitError("parameters: a blender-model result needs 'blender_cloth'")
        base = get_model(default_model) if default_model is not None else model
        fps = float(
            (res.get("blender_scene") or {}).get(
                "fps", model.fps if res.get("model") else getattr(base, "fps", model.fps)
            )
        )
        given = dict(bc)
        given.setdefault("time_scale", B.physical_time_scale(fps))
        s = B.check_settings(given, "blender_cloth")
        model = BlenderModel(fps, s["quality"], s["bending_model"])
        return model, B.settings_row(s)
    p = Params.from_dict(res.get("params") or res, "parameters")
    return model, np.array([p.m, p.k, p.l, p.d])


def simulate(
    scenario: Scenario,
    params: Params | dict[str, float] | ArrayLike | Iterable[Params | dict[str, float]],
    backend: str = "auto",
    safety: float = D.DT_SAFETY,
    model: str | dict[str, Any] | ClothModel | None = None,
) -> SimResult:
    """Simulate a population of ``model`` (default: the paper's sheet, rows (m, k, l, d)).
    ``safety`` scales the paper model's time step (``dt <= safety * sqrt(m/k)``); synthetic ground
    truth may use a finer step than the fitter (``defaults.TRUTH_DT_SAFETY``)."""
    m = get_model(model)
    if isinstance(m, PaperModel) and safety != m.safety:
        m = PaperModel(safety)
    return m.simulate(scenario, params, backend)
