"""A fit's configuration (``FitConfig``): what to fit, with which optimiser and its options
(``SEARCH_OPTIONS``), each value checked; and ``check_resolution``, the check of a fit resolution.
Re-exported by ``job.py``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .optimise import FIT_OPTIMIZERS, canonical_name

CMA_OPTIMIZERS = ("cma-es", "cma-portfolio", "cma-staged")  # the CMA-ES searches (step, active, restarts)
# FitConfig's optimiser options: field -> (the optimiser's keyword, the optimisers it applies to). None (the
# default) leaves the optimiser as it has always been built; only options that are set enter the fit's identity.
# A keyword of None: FitJob reads the option itself (a rung's first step, the tolerances per image, the grid's names
# and shape), not passed through as it stands.
SEARCH_OPTIONS = {
    "sigma0": (None, CMA_OPTIMIZERS),
    "cma_active": ("active", CMA_OPTIMIZERS),
    "tolx": (None, FIT_OPTIMIZERS),
    "tolfun_per_image": (None, FIT_OPTIMIZERS),
    "ga_eps": ("eps", ("spx-mgg",)),
    "ga_stall": ("stall_evaluations", ("spx-mgg",)),
    "portfolio_runs": ("runs", ("cma-portfolio",)),
    "portfolio_explore": ("explore", ("cma-portfolio",)),
    "portfolio_polish": ("polish", ("cma-portfolio",)),
    "portfolio_polish_sigma": ("polish_sigma", ("cma-portfolio",)),
    "portfolio_max_polishes": ("max_polishes", ("cma-portfolio",)),
    "portfolio_refine_until": ("refine_until", ("cma-portfolio",)),
    "staged_first_fraction": ("first_fraction", ("cma-staged",)),
    "staged_restart_step": ("first_restart_step", ("cma-staged",)),
    "staged_explore": ("first_explore", ("cma-staged",)),
    "staged_run_cap": ("first_run_cap", ("cma-staged",)),
    "staged_second_warm": ("second_warm", ("cma-staged",)),
    "staged_warm_tail": ("warm_tail", ("cma-staged",)),
    "staged_warm_tail_stuck": ("warm_tail_stuck", ("cma-staged",)),
    "staged_restart_grid": (None, ("cma-staged",)),
    "staged_restart_grid_rows": (None, ("cma-staged",)),
    "staged_restart_grid_columns": (None, ("cma-staged",)),
    "staged_restart_grid_sigma": ("first_restart_grid_sigma", ("cma-staged",)),
    "staged_restart_grid_near": (None, ("cma-staged",)),
    "staged_restart_grid_at_end": ("first_restart_grid_at_end", ("cma-staged",)),
    "staged_restart_grid_end_run": ("first_restart_grid_end_run", ("cma-staged",)),
    "staged_restart_grid_frames": ("first_restart_grid_frames", ("cma-staged",)),
}

# the search options that are true or false
FLAG_OPTIONS = (
    "cma_active",
    "staged_second_warm",
    "staged_warm_tail_stuck",
    "staged_restart_grid",
    "staged_restart_grid_at_end",
)


def resolve_optimizer(name: str, stageable: bool) -> str:
    """The fit's search: ``name`` itself (canonical), or for "auto" ``D.BLENDER_OPTIMIZER`` where it has
    something to stage (``stageable``: Blender's cloth with free settings both in and outside
    ``D.STAGED_STRONG``) and ``D.DEFAULT_OPTIMIZER`` elsewhere (the paper's sheet, or only strong
    settings free, where the staged search would be one CMA-ES run with another random stream)."""
    if str(name).strip().lower() == "auto":
        return D.BLENDER_OPTIMIZER if stageable else D.DEFAULT_OPTIMIZER
    return canonical_name(name)


@dataclass
class FitConfig:
    train_cameras: list | None = None  # camera indices (None = all); several takes: one list (or None) per take
    train_times: list | None = None  # frame times (None = all of the capture's); several takes: one list per take
    optimizer: str = D.FIT_OPTIMIZER  # "auto": resolve_optimizer
    seed: int = 0
    max_evaluations: int = D.FIT_EVALUATIONS
    target_error: float | None = None  # stop when E_all per image falls below this
    resolution: list | None = None  # (H, W) to fit at: silhouettes resampled, cameras rescaled
    cloth_mass: float | None = None  # kg, total; m = cloth_mass / n_vertices
    bounds: dict | None = None  # per free name (low, high); None = the model's defaults
    backend: str = "auto"
    population: int | None = None
    children: int | None = None
    model: object = None  # "paper", "blender" or a model dict; None = the capture's, else paper
    fps: float | None = None  # blender: the scene frame rate the settings are for (None: parameters.scene_frame_rate)
    quality: int | None = None  # blender: solver steps per frame (5, or the warm start's)
    bending_model: str | None = None  # blender: ANGULAR (default) or LINEAR
    free: list | None = None  # blender: settings to search (default parameters.BLENDER_FREE)
    fixed: dict | None = None  # blender: settings held at given values
    init: str | None = None  # a result JSON to start from (warm start)
    evaluator: str = "core"  # where candidates are simulated: "core" or "blender" (a .blend's own
    # solver in worker processes: addon.farm, handed to FitJob)
    blend: str | None = None  # blender: the scene file, its cloth object, the frame of t = 0
    blend_object: str | None = None
    frame_zero: float | None = None
    workers: int | None = None  # blender: worker processes (default: the cores)
    address: str | None = None  # blender: a running Ray cluster ("auto", "ray://host:port")
    executor: str = "auto"  # blender: "ray", "process" (no Ray) or "auto"
    restarts: int | None = None  # cma-es: IPOP restarts after convergence (population doubled each);
    # None = the model's default (paper 0, blender BLENDER_FIT_RESTARTS)
    intervals: bool = True  # end with each setting's and offset's interval (fitting/intervals.py)
    searches: int | None = None  # searches at most: a search that ends above the floor its jitter allows searches
    # again from another seed (None: D.FIT_SEARCHES; 1: never; each search again adds its budget to the fit's)
    uncertain: object = None  # the manipulation's unknowns to estimate: None = the capture's
    # 'uncertain' block; "none" = nothing; "time_offset=S,handles=M" or an
    # object {time_offset, handles} (physics/scenario.Uncertainty)
    # the optimiser's own settings (SEARCH_OPTIONS; None = the default it has always had)
    sigma0: float | None = None  # cma-es, cma-portfolio: first step (unit cube; 0.3, from --init WARM_START_SIGMA)
    cma_active: bool | None = None  # cma-es, cma-portfolio: active CMA (default: cma-es off, cma-portfolio on)
    tolx: float | None = None  # unit-cube step (GA: population spread) = converged (D.FIT_TOLX)
    tolfun_per_image: float | None = (
        None  # spread of recent bests per training image = converged (D.FIT_TOLFUN_PER_IMAGE)
    )
    ga_eps: float | None = None  # spx-mgg: simplex expansion (sqrt(n + 2))
    ga_stall: int | None = None  # spx-mgg: evaluations without improvement = stagnated (D.FIT_GA_STALL)
    portfolio_runs: int | None = None  # cma-portfolio: CMA-ES runs at the start (4)
    portfolio_explore: float | None = None  # cma-portfolio: budget share of successive halving (0.5)
    portfolio_polish: str | None = None  # cma-portfolio: "cma" (active CMA-ES) or "coord" (coordinate polish)
    portfolio_polish_sigma: float | None = None  # cma-portfolio: a polish's first step (0.05)
    portfolio_max_polishes: int | None = None  # cma-portfolio: polishes before it stops (20)
    portfolio_refine_until: float | None = None  # cma-portfolio: budget share after which refining gives way (1.0)
    staged_first_fraction: float | None = None  # cma-staged: budget share of the first stage (D.STAGED_FIRST_FRACTION)
    staged_restart_step: float | None = (
        None  # cma-staged: a first-stage run converged below this step runs again (0: off)
    )
    staged_explore: float | None = None  # cma-staged, runs again: budget share in which runs start again (0.36)
    staged_run_cap: float | None = None  # cma-staged, runs again: budget share after which a first-stage run ends
    staged_second_warm: bool | None = None  # cma-staged: the second stage keeps the first's steps
    staged_warm_tail: float | None = None  # cma-staged: budget share of a third, warm run (D.STAGED_WARM_TAIL)
    staged_warm_tail_stuck: bool | None = None  # cma-staged: that run only if the second stage found nothing better
    staged_restart_grid: bool | None = None  # cma-staged: runs again from a grid over D.FIT_RESTART_GRID (D's default)
    staged_restart_grid_rows: int | None = None  # cma-staged: that grid's points along its first setting (bending)
    staged_restart_grid_columns: int | None = None  # ... along its second (air damping; 1: the run's own value)
    staged_restart_grid_sigma: float | None = None  # cma-staged: the step of a run started at a grid cell
    staged_restart_grid_at_end: bool | None = None  # cma-staged: that grid at the first stage's end, not the run's
    staged_restart_grid_near: float | None = None  # cma-staged: the grid also at D.FIT_RESTART_NEAR moved by -S and +S
    staged_restart_grid_end_run: float | None = None  # cma-staged: after the grid at the end, a run of this share
    staged_restart_grid_frames: int | None = None  # cma-staged: the grid at the end on the first K frames (0: all)

    @classmethod
    def from_dict(cls, d: Any) -> FitConfig:
        if not isinstance(d, dict):
            raise ClothFitError(f"fit config: expected an object, got {type(d).__name__}")
        known = {f for f in cls.__dataclass_fields__}
        bad = set(d) - known
        if bad:
            raise ClothFitError(f"fit config: unknown keys {sorted(bad)}")
        return cls(**d).checked()

    def checked(self) -> FitConfig:
        """The config with every value checked (one-line ClothFitError naming the first bad one)."""

        def intval(name, lo, hi=10**12, none_ok=True):
            v = getattr(self, name)
            if v is None and none_ok:
                return
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise ClothFitError(f"fit config: {name} must be an integer in {lo}..{hi}, got {v!r}")
            setattr(self, name, int(v))

        def numval(name, lo, hi=math.inf, none_ok=True):
            v = getattr(self, name)
            if v is None and none_ok:
                return
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float, np.number))
                or not math.isfinite(v)
                or not lo <= v <= hi
            ):
                raise ClothFitError(f"fit config: {name} must be a finite number in [{lo}, {hi}], got {v!r}")

        def per_take(v):  # a list per take (several takes), or one list for every take
            nested = isinstance(v, (list, tuple)) and any(x is None or isinstance(x, (list, tuple)) for x in v)
            return list(v) if nested else [v]

        def intlist(name):
            for v in per_take(getattr(self, name)):
                if v is not None and (
                    not isinstance(v, (list, tuple))
                    or not all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in v)
                ):
                    raise ClothFitError(f"fit config: {name} must be a list of integers (or one per take), got {v!r}")

        intval("seed", 0, 2**63 - 1, none_ok=False)
        intval("max_evaluations", 1, none_ok=False)
        intval("population", 2, 10**6)
        intval("children", 1, 10**6)
        intval("restarts", 0, 20)
        if self.quality != "auto":
            intval("quality", 1, 80)
        numval("target_error", 0.0)
        numval("cloth_mass", 1e-12)
        numval("fps", 1e-3, 1e4)
        intlist("train_cameras")
        for tt in per_take(self.train_times):
            if tt is not None and (
                not isinstance(tt, (list, tuple))
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in tt)
            ):
                raise ClothFitError(
                    f"fit config: train_times must be a list of finite numbers (or one per take), got {tt!r}"
                )
        if not isinstance(self.optimizer, str):
            raise ClothFitError(f"fit config: optimizer must be a name, got {self.optimizer!r}")
        opt = resolve_optimizer(self.optimizer, stageable=True)  # "auto" is a CMA-ES search either way
        if opt not in FIT_OPTIMIZERS:
            raise ClothFitError(
                f"fit config: optimizer {self.optimizer!r} is a polish, not a fit's search: choose one "
                f"of {', '.join(FIT_OPTIMIZERS)}"
            )
        if self.resolution is not None:
            check_resolution(self.resolution, "fit config: resolution")
        if self.backend not in ("auto", "numba", "numpy"):
            raise ClothFitError(f"fit config: unknown backend {self.backend!r} (numba, numpy, auto)")
        for name in ("bounds", "fixed"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, dict):
                raise ClothFitError(f"fit config: {name} must be an object, got {v!r}")
        if self.free is not None and (
            not isinstance(self.free, (list, tuple)) or not all(isinstance(x, str) for x in self.free)
        ):
            raise ClothFitError(f"fit config: free must be a list of setting names, got {self.free!r}")
        for name in ("bending_model", "init"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, str):
                raise ClothFitError(f"fit config: {name} must be a string, got {v!r}")
        if self.uncertain is not None and not isinstance(self.uncertain, (str, dict)):
            raise ClothFitError(
                f"fit config: uncertain must be 'none', 'time_offset=S,handles=M' or an object, got {self.uncertain!r}"
            )
        if self.model is not None and not isinstance(self.model, (str, dict)):
            raise ClothFitError(f"fit config: model must be a name or a model object, got {self.model!r}")
        for name, lo, hi in (
            ("sigma0", 1e-9, 10.0),
            ("tolx", 0.0, 1.0),
            ("tolfun_per_image", 0.0, math.inf),
            ("ga_eps", 1e-9, 1e6),
            ("portfolio_explore", 0.0, 1.0),
            ("portfolio_polish_sigma", 1e-9, 10.0),
            ("portfolio_refine_until", 0.0, 1.0),
            ("staged_first_fraction", 0.0, 1.0),
            ("staged_restart_step", 0.0, 1.0),
            ("staged_explore", 0.0, 1.0),
            ("staged_run_cap", 0.0, 1.0),
            ("staged_warm_tail", 0.0, 1.0),
            ("staged_restart_grid_sigma", 1e-9, 1.0),
            ("staged_restart_grid_near", 1e-9, 0.25),
            ("staged_restart_grid_end_run", 0.0, 1.0),
        ):
            numval(name, lo, hi)
        intval("ga_stall", 1)
        intval("searches", 1, 10)
        intval("portfolio_runs", 1, 64)
        intval("portfolio_max_polishes", 1, 10**6)
        intval("staged_restart_grid_rows", 2, 64)
        intval("staged_restart_grid_columns", 1, 64)
        intval("staged_restart_grid_frames", 0, 10**6)
        for name in FLAG_OPTIONS:
            if getattr(self, name) is not None and not isinstance(getattr(self, name), bool):
                raise ClothFitError(f"fit config: {name} must be true or false, got {getattr(self, name)!r}")
        if self.portfolio_polish not in (None, "cma", "coord"):
            raise ClothFitError(f"fit config: portfolio_polish must be 'cma' or 'coord', got {self.portfolio_polish!r}")
        for name, (_, optimizers) in SEARCH_OPTIONS.items():
            if getattr(self, name) is not None and opt not in optimizers:
                shown = "auto (a CMA-ES search)" if str(self.optimizer).strip().lower() == "auto" else opt
                raise ClothFitError(f"fit config: {name} is a setting of {' and '.join(optimizers)}, not of {shown}")
        return self

    def search_options(self) -> dict:
        """The optimiser options this config sets (SEARCH_OPTIONS not None): a fit's identity holds them,
        so a checkpoint is resumed only with the same ones (and one from before they existed, without)."""
        return {name: getattr(self, name) for name in SEARCH_OPTIONS if getattr(self, name) is not None}


def check_resolution(res: Any, what: str = "resolution") -> tuple[int, int]:
    """(H, W) as two positive integers within the size limits."""
    try:
        h, w = res
        ok = all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in (h, w))
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ClothFitError(f"{what} {res!r} must be two integers (height, width)")
    h, w = int(h), int(w)
    if not (0 < h <= D.MAX_IMAGE_SIDE and 0 < w <= D.MAX_IMAGE_SIDE and h * w <= D.MAX_FIT_PIXELS):
        raise ClothFitError(
            f"{what} {h}x{w} must be positive, at most {D.MAX_IMAGE_SIDE} per side and {D.MAX_FIT_PIXELS} pixels in all"
        )
    return [h, w]
