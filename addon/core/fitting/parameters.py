"""What a fit searches, for each model: the free coordinates, their bounds, and the map from a
free vector to the model's parameter rows and back to the numbers a user reads.

Identifiability (docs/method.md#spec-2, #spec-9): in both models the motion depends on ratios to the mass
(scaling the mass, every stiffness and every damping together leaves it unchanged), so the mass
is fixed from the cloth's weighed mass (``cloth_mass``, total; per vertex = cloth_mass / V) and
the rest is searched per unit mass, in log scale.

* ``PaperParameters``: k/m [1/s^2], d/m [1/s] and l relative to the grid spacing.
* ``BlenderParameters``: a chosen set of ``bpy.types.ClothSettings`` values (by default
  ``BLENDER_FREE``), each mass-scaled one as ``value / mass``; the other settings are fixed
  (Blender's defaults, a warm-start result's values, or the user's), ``time_scale`` is the one
  that makes the cloth move in real time at the target frame rate. Bounds are the defaults'
  ranges, clipped to Blender's own limits at the fixed mass.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from ..observation.frame_rate import frame_rate_from_times
from ..physics import blender as B
from ..physics.models import BlenderModel, PaperModel, get_model
from ..physics.paper import identifiable
from ..physics.scenario import Offsets, Uncertainty, fitted_scenario  # noqa: F401 (the fitted manipulation)
from .result import FitResult
from .space import SearchSpace

if TYPE_CHECKING:
    from ..observation.capture import Capture
    from ..physics.scenario import ClothGrid, Scenario
    from .job import FitConfig

PAPER_FREE = ("k_over_m", "d_over_m", "l_rel")

# Blender settings searched by default (docs/models.md, "What is searched"); the rest stay fixed.
BLENDER_FREE = {
    "ANGULAR": (
        "tension_stiffness",
        "compression_stiffness",
        "shear_stiffness",
        "bending_stiffness",
        "tension_damping",
        "shear_damping",
        "bending_damping",
        "air_damping",
    ),
    "LINEAR": (
        "tension_stiffness",
        "shear_stiffness",
        "bending_stiffness",
        "tension_damping",
        "shear_damping",
        "bending_damping",
        "air_damping",
    ),
}
# search ranges in Blender's units *for a vertex mass of 0.3 kg* (Blender's default); scaled with the
# fixed mass for the mass-scaled settings, then clipped to Blender's limits. Bending and air damping start
# where a cloth still resists folding and air at all: Blender's own presets use bending 0.05 (silk) to 25
# (rubber) and air damping 1; below 0.01 and 0.05 the searches found basins of a cloth with no bending or no
# air (a stiffer shear making up for it) that fit the silhouettes worse than the truth (docs/intervals.md)
BLENDER_BOUNDS_AT_DEFAULT_MASS = {
    "tension_stiffness": (0.5, 2000.0),
    "compression_stiffness": (0.5, 2000.0),
    "shear_stiffness": (0.05, 2000.0),
    "bending_stiffness": (1e-2, 500.0),
    "tension_damping": (1e-3, 50.0),
    "compression_damping": (1e-3, 50.0),
    "shear_damping": (1e-3, 50.0),
    "bending_damping": (1e-4, 50.0),
    "air_damping": (5e-2, 10.0),
    "pin_stiffness": (1e-2, 50.0),
}
FITTABLE = tuple(BLENDER_BOUNDS_AT_DEFAULT_MASS)


def point_mass(
    capture: Capture, cfg_mass: float | None, default: float | None, n_vertices: int | None = None
) -> tuple[float | None, str | None]:
    """(mass per vertex, source) from the given total mass, the capture's, or ``default``; the
    total is spread over ``n_vertices`` (default: the capture's grid)."""
    n = capture.scenario.grid.n_vertices if n_vertices is None else int(n_vertices)
    if cfg_mass is not None:
        if not (isinstance(cfg_mass, (int, float)) and math.isfinite(cfg_mass) and cfg_mass > 0):
            raise ClothFitError(f"cloth mass {cfg_mass!r} kg must be a positive number")
        return cfg_mass / n, "given cloth mass"
    if getattr(capture, "cloth_mass", None):
        return capture.cloth_mass / n, "capture's cloth_mass"
    return default, None


def free_set(cfg: FitConfig, bending_model: str) -> tuple:
    """The Blender settings a fit searches (``cfg.free`` or the default set), checked."""
    free = tuple(cfg.free) if cfg.free else BLENDER_FREE[bending_model]
    bad = [n for n in free if n not in FITTABLE]
    if bad:
        raise ClothFitError(f"fit: cannot search {', '.join(bad)} (searchable: {', '.join(FITTABLE)})")
    if len(set(free)) != len(free) or not free:
        raise ClothFitError(f"fit: free settings {list(free)} must be distinct and not empty")
    clash = set(free) & set(cfg.fixed or {})
    if clash:
        raise ClothFitError(f"fit: {sorted(clash)} cannot be both free and fixed")
    return free


class PaperParameters:
    """The paper's sheet: free (k/m, d/m, l / spacing), m fixed."""

    def __init__(self, capture, cfg):
        self.model = PaperModel()
        m, src = point_mass(capture, cfg.cloth_mass, D.GT_PARAMS["m"])
        self.m = m
        self.m_source = src or "default point mass (cloth mass unknown: k and d scale with it)"
        self.spacing = capture.scenario.grid.spacing
        bounds = {k: tuple(v) for k, v in (cfg.bounds or D.SEARCH_BOUNDS).items()}
        missing = set(PAPER_FREE) - set(bounds)
        if missing:
            raise ClothFitError(f"fit config: bounds missing for {sorted(missing)}")
        self.space = SearchSpace(list(PAPER_FREE), bounds, {k: D.LOG_SCALED.get(k, True) for k in PAPER_FREE})
        self.initial = None
        self.note = "m is not observable from silhouettes (only k/m, d/m and l are): m is fixed and k, d scale with it"

    def rows(self, X: ArrayLike) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        m = self.m
        return np.stack([np.full(len(X), m), X[:, 0] * m, X[:, 2] * self.spacing, X[:, 1] * m], 1)

    def params(self, x: ArrayLike) -> dict[str, float]:
        r = self.rows(x)[0]
        return {"m": float(r[0]), "k": float(r[1]), "l": float(r[2]), "d": float(r[3])}

    def reported(self, name: str, coord: float) -> tuple[str, float]:
        """A search coordinate's value in the result's units: (k, d or l, value)."""
        per = {"k_over_m": ("k", self.m), "d_over_m": ("d", self.m), "l_rel": ("l", self.spacing)}
        out, scale = per[name]
        return out, float(coord) * scale

    def describe(self, x: ArrayLike) -> dict:
        p = self.params(x)
        return {"model": self.model.to_dict(), "params": p, "identifiable": identifiable(p)}


class BlenderParameters:
    """Blender's cloth: free ClothSettings (per unit mass, log scale), the rest fixed."""

    def __init__(self, capture, cfg, spec=None):
        spec = get_model(spec or "blender")  # the asked-for model (frame rate, quality, bending)
        init = load_init(cfg.init) if cfg.init else None
        base = dict(B.DEFAULTS, quality=spec.quality, bending_model=spec.bending_model)
        if init is not None and init.get("blender_cloth"):
            base.update({k: v for k, v in init["blender_cloth"].items() if k in ("quality", "bending_model")})
        fps, self.fps_source = scene_frame_rate(capture, cfg, init)
        quality = cfg.quality if cfg.quality not in (None, "auto") else base["quality"]
        bending = cfg.bending_model if cfg.bending_model is not None else base["bending_model"]
        self.model = BlenderModel(fps, quality, bending)
        m, src = point_mass(capture, cfg.cloth_mass, None)
        init_settings = None
        if init is not None:
            init_settings = settings_from_result(init, self.model, capture.scenario.grid)
        if m is None:
            m = init_settings["mass"] if init_settings else B.DEFAULTS["mass"]
            src = (
                "warm-start result's mass"
                if init_settings
                else "Blender's default vertex mass (cloth mass unknown: every stiffness and damping scales with it)"
            )
        self.m, self.m_source = float(m), src
        # Blender's defaults are for its default vertex mass: moved to this mass, they move alike
        fixed = _rescale(dict(base, mass=B.DEFAULTS["mass"]), self.m, self.model.bending_model)
        fixed.update(
            quality=self.model.quality, bending_model=self.model.bending_model, time_scale=B.physical_time_scale(fps)
        )
        if init_settings:
            fixed.update(_rescale(init_settings, self.m, self.model.bending_model))
        fixed.update(cfg.fixed or {})
        fixed["mass"] = self.m
        self.fixed = B.check_settings(fixed, "fit: fixed Blender settings")
        self.free = free = free_set(cfg, self.model.bending_model)
        self.scaled = set(B.mass_scaled(self.model.bending_model))
        bounds = {}
        for n in free:
            # user bounds are in Blender's units at this mass; the defaults at Blender's default mass
            user = (cfg.bounds or {}).get(n)
            lo, hi = user if user is not None else BLENDER_BOUNDS_AT_DEFAULT_MASS[n]
            ref = self.m if user is not None else B.DEFAULTS["mass"]
            hard = B.RANGES[n][1]
            if n in self.scaled:  # coordinates per unit mass
                lo, hi, hard = lo / ref, hi / ref, hard / self.m
            hi = min(hi, hard)
            if not (0 < lo < hi):
                raise ClothFitError(
                    f"fit: the search range of {n} is empty at vertex mass {self.m:g} kg "
                    f"(bounds must be positive and within Blender's limit {B.RANGES[n][1]:g})"
                )
            bounds[n] = (lo, hi)
        self.space = SearchSpace(list(free), bounds, {n: True for n in free})
        self.initial = None
        if init_settings:
            x0 = np.array([self._coord(n, self.fixed[n]) for n in free])
            self.initial = [self.space.clip(x0[None])[0]]
        self.note = (
            "silhouettes cannot tell mass from stiffness and damping (the motion depends on their ratios): "
            "the vertex mass is fixed and every stiffness and damping scales with it"
        )

    def _coord(self, name, value):
        return value / self.m if name in self.scaled else value

    def coordinate(self, name: str, value: float) -> float:
        """A setting's value in Blender's units -> its search coordinate (per unit mass where it scales)."""
        return self._coord(name, value)

    def reported(self, name: str, coord: float) -> tuple[str, float]:
        """A search coordinate's value in the result's units (``blender_cloth``: Blender's, at the mass)."""
        return name, float(coord) * self.m if name in self.scaled else float(coord)

    def rows(self, X: ArrayLike) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        base = B.settings_row(self.fixed)
        R = np.repeat(base[None], len(X), 0)
        for k, n in enumerate(self.free):
            col = B.FLOAT_SETTINGS.index(n)
            v = X[:, k] * self.m if n in self.scaled else X[:, k]
            R[:, col] = np.minimum(v, B.RANGES[n][1])  # a bound at Blender's limit, per unit mass and back: 1 ulp over
        return R

    def settings(self, x: ArrayLike) -> dict:
        return self.model.settings(self.rows(x)[0])

    def describe(self, x: ArrayLike) -> dict:
        s = self.settings(x)
        per_mass = {n: s[n] / s["mass"] for n in sorted(self.scaled)}
        return {
            "model": self.model.to_dict(),
            "blender_cloth": s,
            "blender_scene": {"fps": self.model.fps, "fps_source": self.fps_source},
            "free": list(self.free),
            "per_unit_mass": per_mass,
        }


SCENE_BOUND_FACTOR = 20.0  # a scene fit searches value / 20 .. value * 20 around the scene's (or warm start's) value


class SceneParameters(BlenderParameters):
    """Blender's cloth on a user's scene (``--backend blender``): the Cloth modifier's own values are
    the fixed settings and the centre of the search (a warm start's values replace the free ones);
    ``quality``, ``bending_model`` and ``time_scale`` stay the scene's. The vertex mass is
    ``cloth_mass`` over the scene mesh's vertices, else the modifier's; every mass-scaled value is
    moved to that mass without changing the motion. Default bounds: a factor ``SCENE_BOUND_FACTOR``
    either side of the centre (per unit mass, log scale), clipped to Blender's limits."""

    def __init__(self, capture, cfg, evaluator):
        self.model = evaluator
        self.fps_source = "the scene's (--blend)"
        scene = B.check_settings(dict(evaluator.initial), f"Cloth settings of '{getattr(evaluator, 'object', '?')}'")
        bending = scene["bending_model"]
        m, src = point_mass(capture, cfg.cloth_mass, scene["mass"], evaluator.mesh.n_vertices)
        src = src or "the scene's vertex mass (cloth mass unknown: every stiffness and damping scales with it)"
        self.m, self.m_source = float(m), src
        fixed = _rescale(scene, self.m, bending)
        self.init_note = None
        if cfg.init:
            res = load_init(cfg.init)
            core = BlenderModel(evaluator.fps, scene["quality"], bending)
            ini = settings_from_result(res, core, capture.scenario.grid)
            ini = _rescale(ini, self.m, bending)
            fixed.update({n: ini[n] for n in free_set(cfg, bending) if n in ini})
            if (
                abs(ini["time_scale"] - scene["time_scale"]) > 1e-6 * scene["time_scale"]
                or ini["quality"] != scene["quality"]
                or ini["bending_model"] != bending
            ):
                self.init_note = (
                    f"warm start {cfg.init} was fitted at time_scale {ini['time_scale']:.6g}, quality "
                    f"{ini['quality']}, {ini['bending_model']}; the scene's are kept "
                    f"({scene['time_scale']:.6g}, {scene['quality']}, {bending})"
                )
        fixed.update(cfg.fixed or {})
        fixed["mass"] = self.m
        self.fixed = B.check_settings(fixed, "fit: fixed Blender settings")
        self.free = free = free_set(cfg, bending)
        self.scaled = set(B.mass_scaled(bending))
        bounds = {}
        for n in free:
            user = (cfg.bounds or {}).get(n)
            hard = B.RANGES[n][1] / self.m if n in self.scaled else B.RANGES[n][1]
            if user is not None:
                lo, hi = (float(v) for v in user)
                if n in self.scaled:
                    lo, hi = lo / self.m, hi / self.m
            else:
                c = self._coord(n, self.fixed[n])
                if c > 0:
                    lo, hi = c / SCENE_BOUND_FACTOR, c * SCENE_BOUND_FACTOR
                else:  # a zero setting: Blender's presets' range at this mass
                    lo, hi = BLENDER_BOUNDS_AT_DEFAULT_MASS[n]
                    if n in self.scaled:
                        lo, hi = lo / B.DEFAULTS["mass"], hi / B.DEFAULTS["mass"]
            hi = min(hi, hard)
            if not (0 < lo < hi):
                raise ClothFitError(
                    f"fit: the search range of {n} is empty at vertex mass {self.m:g} kg "
                    f"(bounds must be positive and within Blender's limit {B.RANGES[n][1]:g})"
                )
            bounds[n] = (lo, hi)
        self.space = SearchSpace(list(free), bounds, {n: True for n in free})
        self.initial = None
        if cfg.init:
            x0 = np.array([self._coord(n, self.fixed[n]) for n in free])
            self.initial = [self.space.clip(x0[None])[0]]
        self.note = (
            "Blender's own solver on the scene's cloth object; silhouettes cannot tell mass from stiffness "
            "and damping: the vertex mass is fixed and every stiffness and damping scales with it"
        )
        if self.init_note:
            self.note += "; " + self.init_note


def scene_frame_rate(capture: Capture, cfg: FitConfig, init: dict | None = None) -> tuple[float, str]:
    """(fps, where it came from) of the scene a Blender-cloth fit's settings are for: ``"given"`` (``cfg.fps``,
    or a frame rate in ``cfg.model``: ``--fps``, the add-on's scene), ``"warm start"`` (the ``init`` result's
    ``blender_scene``), ``"capture"`` (the capture's own ``model``: a synthetic capture declares the rate its
    cloth was simulated at), ``"frame times"`` (the rate whose period divides every gap between the capture's
    frame times: ``observation.frame_rate``), else ``"default (why the frame times could not tell)"``."""
    if cfg.fps is not None:
        return float(cfg.fps), "given"
    m = cfg.model
    given = m.get("fps") if isinstance(m, dict) else None if isinstance(m, str) else getattr(m, "fps", None)
    if given is not None:
        return float(given), "given"
    warm = ((init or {}).get("blender_scene") or {}).get("fps") if (init or {}).get("blender_cloth") else None
    if warm is not None:
        return float(warm), "warm start"
    fps, why = capture_frame_rate(capture)
    if fps is None:
        return float(D.BLENDER_FPS), f"default ({why})"
    return fps, why


def capture_frame_rate(capture: Capture) -> tuple[float | None, str]:
    """(fps, where it came from) of a capture alone: ``"capture"`` (its own ``model``: a synthetic capture
    declares the rate its cloth was simulated at), ``"frame times"`` (the rate whose period divides every gap
    between its frame times: ``observation.frame_rate``), else (None, why the frame times could not tell)."""
    cap = getattr(capture, "model", None)
    if isinstance(cap, dict) and cap.get("fps") is not None:
        return float(cap["fps"]), "capture"
    fps, why = frame_rate_from_times(capture.frame_times)
    return (fps, "frame times") if fps is not None else (None, why)


def declared_model(capture: Capture, cfg: FitConfig) -> dict:
    """The model asked for: ``cfg.model``, over the capture's own ``model`` where both are Blender's
    (``--model blender`` on a capture that declares its frame rate and quality keeps them), else the
    capture's; {} for none."""
    spec = cfg.model if cfg.model is not None else getattr(capture, "model", None)
    if isinstance(spec, str):
        spec = {"name": spec}
    spec = dict(spec or {})
    cap = getattr(capture, "model", None)
    cap = {"name": cap} if isinstance(cap, str) else dict(cap or {})
    if cfg.model is not None and spec.get("name") == "blender" and cap.get("name") == "blender":
        spec = dict(cap, **spec)
    return spec


def make_parameters(capture: Capture, cfg: FitConfig) -> PaperParameters | BlenderParameters:
    """The search of ``cfg.model``, else the capture's own ``model``, else the paper's sheet."""
    spec = declared_model(capture, cfg) or None
    model = get_model(spec)
    return PaperParameters(capture, cfg) if model.name == "paper" else BlenderParameters(capture, cfg, model)


def load_init(path: str | os.PathLike) -> FitResult:
    """A result JSON to warm-start from (checked: ``FitResult.from_json``)."""
    return FitResult.from_json(path, "warm-start result")


def _rescale(settings: dict, mass: float, bending_model: str) -> dict:
    """Settings moved to another vertex mass without changing the motion."""
    f = mass / settings["mass"]
    out = dict(settings)
    for n in B.mass_scaled(bending_model):
        out[n] = settings[n] * f
    return out


def settings_from_result(res: dict, model: BlenderModel, grid: ClothGrid) -> dict:
    """Blender settings from a fit result: its ``blender_cloth``, or, for a paper-model result, an
    approximation (the paper's springs as structural = compression = shear stiffness, its viscous
    damping as air damping, in Blender's time unit at the model's frame rate)."""
    if res.get("blender_cloth"):
        return B.check_settings(
            {k: v for k, v in res["blender_cloth"].items() if k in B.DEFAULTS}, "warm-start blender_cloth"
        )
    p = res.get("params") or {}
    try:
        m, k, d = float(p["m"]), float(p["k"]), float(p["d"])
    except (KeyError, TypeError, ValueError):
        raise ClothFitError("warm-start result: its 'params' lack m, k, d") from None
    unit = 1.0 / (model.fps * B.physical_time_scale(model.fps))  # seconds per solver time unit
    avg = grid.spacing
    stiff = k * unit * unit * avg  # Blender: k_spring = stiffness / avg
    air = d * unit / B.AIR_SCALE
    conv = {
        "mass": m,
        "tension_stiffness": stiff,
        "compression_stiffness": stiff,
        "shear_stiffness": stiff,
        "air_damping": air,
        "tension_damping": 0.0,
        "compression_damping": 0.0,
        "shear_damping": 0.0,
    }
    # moved to Blender's default mass so the numbers fall in Blender's ranges; the paper's sheet has no
    # bending: Blender's default bending at that mass
    f = B.DEFAULTS["mass"] / m
    scaled = set(B.mass_scaled(model.bending_model))
    s = dict(
        B.DEFAULTS,
        quality=model.quality,
        bending_model=model.bending_model,
        time_scale=B.physical_time_scale(model.fps),
    )
    s.update({n: (v * f if n in scaled else v) for n, v in conv.items()})
    for n in scaled:
        s[n] = min(s[n], B.RANGES[n][1])
    return B.check_settings(s, "warm start from a paper-model result")


class ManipulationParameters:
    """The manipulation's unknowns a fit estimates with the cloth's settings (``Uncertainty``): the
    time offset ``time_offset_s`` in ``[-b, b]`` and one 3-D offset per uncertain handle, each
    coordinate in ``[-b_k, b_k]`` (linear coordinates: an offset of zero is the declared
    manipulation), and with a declared ``time_scale`` S the stretch of the capture's clock as
    ``log_time_scale`` in ``[-ln S, ln S]`` (zero: the declared frame interval). ``offsets(X)`` turns the
    coordinates of a population into ``scenario.Offsets``."""

    def __init__(self, uncertainty: Uncertainty, scenario):
        self.uncertainty = uncertainty
        self.n_handles = len(scenario.handles)
        names, bounds = [], {}
        if uncertainty.time_offset > 0:
            names.append("time_offset_s")
            bounds["time_offset_s"] = (-uncertainty.time_offset, uncertainty.time_offset)
        if uncertainty.time_scale > 1.0:
            names.append("log_time_scale")
            bounds["log_time_scale"] = (-math.log(uncertainty.time_scale), math.log(uncertainty.time_scale))
        self.handle_coords = []  # (name, handle index, axis)
        for k, b in enumerate(uncertainty.handles):
            if b > 0:
                for a, ax in enumerate("xyz"):
                    nm = f"handle{k}_{ax}"
                    names.append(nm)
                    bounds[nm] = (-b, b)
                    self.handle_coords.append((nm, k, a))
        self.names = names
        self.bounds = bounds

    @property
    def n(self) -> int:
        return len(self.names)

    def offsets(self, M: ArrayLike) -> Offsets:
        """``M`` (P, n) coordinates in ``names`` order -> per-candidate offsets."""
        M = np.atleast_2d(np.asarray(M, dtype=np.float64)).reshape(-1, self.n)
        P = M.shape[0]
        t = M[:, self.names.index("time_offset_s")] if "time_offset_s" in self.names else np.zeros(P)
        h = np.zeros((P, self.n_handles, 3))
        for nm, k, a in self.handle_coords:
            h[:, k, a] = M[:, self.names.index(nm)]
        if "log_time_scale" not in self.names:
            return Offsets(t, h)
        return Offsets(t, h, np.exp(M[:, self.names.index("log_time_scale")]))

    def at_bound(self, m: ArrayLike, share: float = D.MANIP_AT_BOUND_SHARE) -> list[str]:
        """The unknowns whose fitted value ``m`` (coordinates in ``names`` order) lies at the edge of its
        declared bound (``|value| >= share * bound``): the capture may be further off than it declares."""
        m = np.asarray(m, dtype=np.float64).reshape(-1)
        return [n for n, v in zip(self.names, m) if abs(v) >= share * self.bounds[n][1]]

    def describe(self, m: ArrayLike, scenario: Scenario, spread: Sequence[float] | None = None) -> dict:
        """The fitted manipulation for a result: ``time_offset_s`` and ``handles`` (the capture's
        scenario format, moved), each with its uncertainty (``spread``: per coordinate, e.g. the
        search distribution's standard deviation; None = not estimated)."""
        off = self.offsets(np.asarray(m)[None])
        sd = dict(zip(self.names, spread)) if spread is not None else {}
        moved = scenario.moved(0.0, off.handles[0])
        handles = []
        for k, h in enumerate(moved.handles):
            d = h.to_dict()
            d["offset_m"] = off.handles[0, k].tolist()
            if self.uncertainty.handles[k] > 0:
                d["offset_bound_m"] = self.uncertainty.handles[k]
                d["offset_uncertainty_m"] = [sd.get(f"handle{k}_{ax}") for ax in "xyz"]
            handles.append(d)
        d = {
            "time_offset_s": float(off.time[0]),
            "time_offset_uncertainty_s": sd.get("time_offset_s"),
            "uncertain": self.uncertainty.to_dict(),
            "handles": handles,
        }
        if "log_time_scale" in self.names:  # the stretch and its relative uncertainty (of its logarithm)
            d["time_scale"] = float(off.scale[0])
            d["time_scale_uncertainty"] = sd.get("log_time_scale")
        return d


def release_instants(
    model: Any, scenario: Scenario, time_offset_s: float | None, uncertainty_s: float | None, time_scale: float = 1.0
) -> list:
    """Where a fit puts each released handle's release on the capture's clock: the instant the model's
    cloth starts to fall (``model.release_instant``: Blender's cloth lets go at the last held frame, so
    up to a frame before the declared time, stretched by a fitted ``time_scale``) plus the fitted
    ``time_offset_s``, on the capture's clock (true time = time_scale x capture time - offset). Empty when nothing is released, the offset was not estimated (None) or the model
    does not say when its cloth lets go (a user's own scene: its pins are its own)."""
    at = getattr(model, "release_instant", None)
    if time_offset_s is None or at is None:
        return []
    out = []
    for k, h in enumerate(scenario.handles):
        if h.release_time is None:
            continue
        m = float(at(h.release_time * time_scale))
        out.append(
            {
                "handle": k,
                "vertex": int(h.vertex),
                "declared_s": float(h.release_time),
                "model_s": m,
                "capture_s": (m + float(time_offset_s)) / time_scale,
                "uncertainty_s": uncertainty_s,
            }
        )
    return out


def joint_space(par_space: SearchSpace, manip: ManipulationParameters | None) -> SearchSpace:
    """The cloth's search space followed by the manipulation's unknowns (linear, zero = as declared)."""
    if manip is None:
        return par_space
    names = list(par_space.names) + list(manip.names)
    bounds = {n: (float(lo), float(hi)) for n, lo, hi in zip(par_space.names, par_space.lo, par_space.hi)}
    bounds.update(manip.bounds)
    logs = {n: bool(v) for n, v in zip(par_space.names, par_space.log)}
    return SearchSpace(names, bounds, logs)
