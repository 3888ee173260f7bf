"""A steppable fit of a capture: one optimiser generation per ``step()``.

Used by the CLI (a loop with a progress bar), by the Blender modal operator (one step per timer
tick) and by the experiment protocol. The job never loses the best result found so far: it is
kept in memory at every step, written to the checkpoint (if a path is given) after every
generation, and ``result()`` returns it whether the job finished, was cancelled or failed.

Identifiability (SPEC 2): the motion depends on k/m, d/m and l only. The job fixes ``m`` from the
cloth mass (``FitConfig.cloth_mass``, else the capture's ``cloth_mass``, else the default point
mass, flagged in the result) and searches k/m, d/m and l (relative to the grid spacing), in log
scale. The result reports m, k, l, d for that m and the identifiable quantities.
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..physics.paper import identifiable, identifiable_errors
from .objective import SilhouetteObjective
from .optimise import SearchSpace, make_optimizer

FREE_NAMES = ("k_over_m", "d_over_m", "l_rel")


@dataclass
class FitConfig:
    train_cameras: list | None = None     # camera indices (None = all)
    train_times: list | None = None       # frame times (None = all of the capture's)
    optimizer: str = D.DEFAULT_OPTIMIZER
    seed: int = 0
    max_evaluations: int = D.FIT_EVALUATIONS
    target_error: float | None = None     # stop when E_all per image falls below this
    resolution: list | None = None        # (H, W) to fit at: silhouettes resampled, cameras rescaled
    cloth_mass: float | None = None       # kg, total; m = cloth_mass / n_vertices
    bounds: dict = field(default_factory=lambda: {k: list(v) for k, v in D.SEARCH_BOUNDS.items()})
    backend: str = "auto"
    population: int | None = None
    children: int | None = None

    @classmethod
    def from_dict(cls, d):
        known = {f for f in cls.__dataclass_fields__}
        bad = set(d) - known
        if bad:
            raise ClothFitError(f"fit config: unknown keys {sorted(bad)}")
        return cls(**d)


def resample_silhouette(mask: np.ndarray, height: int, width: int) -> np.ndarray:
    """Silhouette at another resolution: area-average and threshold at one half."""
    import cv2
    if mask.shape == (height, width):
        return mask.astype(bool)
    img = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return img >= 0.5


def point_mass(capture, cfg_mass=None):
    """(m, source) for a capture: from the given total mass, the capture's, or the default."""
    n = capture.scenario.grid.n_vertices
    if cfg_mass is not None:
        if not (cfg_mass > 0 and math.isfinite(cfg_mass)):
            raise ClothFitError(f"cloth mass {cfg_mass} kg must be positive")
        return cfg_mass / n, "given cloth mass"
    if getattr(capture, "cloth_mass", None):
        return capture.cloth_mass / n, "capture's cloth_mass"
    return D.GT_PARAMS["m"], "default point mass (cloth mass unknown: k and d scale with it)"


class FitJob:
    def __init__(self, capture, config: FitConfig | None = None, checkpoint: str | None = None):
        self.capture = capture
        self.config = cfg = config or FitConfig()
        self.checkpoint = checkpoint
        ncam = len(capture.cameras)
        cams = list(range(ncam)) if cfg.train_cameras is None else [int(c) for c in cfg.train_cameras]
        for c in cams:
            if not 0 <= c < ncam:
                raise ClothFitError(f"training camera index {c} outside 0..{ncam - 1}")
        if not cams:
            raise ClothFitError("no training camera selected")
        times = list(capture.frame_times) if cfg.train_times is None else list(cfg.train_times)
        if not times:
            raise ClothFitError("no training frame selected")
        fidx = [capture.frame_index(t) for t in times]
        self.train_cameras = cams
        self.train_frames = fidx
        self.train_times = [float(capture.frame_times[i]) for i in fidx]
        cameras = [capture.cameras[c] for c in cams]
        observed = [[capture.load_silhouette(c, f) for f in fidx] for c in cams]
        if cfg.resolution is not None:
            h, w = int(cfg.resolution[0]), int(cfg.resolution[1])
            if h <= 0 or w <= 0:
                raise ClothFitError(f"fit resolution {cfg.resolution} must be positive")
            cameras = [c.resized(h, w) for c in cameras]
            observed = [[resample_silhouette(o, h, w) for o in oc] for oc in observed]
        self.scenario = capture.scenario.with_frames(self.train_times)
        names = [[capture.silhouette_path(c, f) for f in fidx] for c in cams]
        self.objective = SilhouetteObjective(self.scenario, cameras, observed, backend=cfg.backend, names=names)
        self.m, self.m_source = point_mass(capture, cfg.cloth_mass)
        self.spacing = capture.scenario.grid.spacing
        bounds = {k: tuple(v) for k, v in cfg.bounds.items()}
        self.space = SearchSpace(list(FREE_NAMES), bounds, {k: D.LOG_SCALED.get(k, True) for k in FREE_NAMES})
        kw = {}
        is_cma = cfg.optimizer.lower() in ("cma", "cma-es")
        if cfg.population:
            kw["popsize" if is_cma else "population"] = cfg.population
        elif not is_cma:
            kw["population"] = D.FIT_GA_POPULATION
        if not is_cma:
            kw["children"] = cfg.children or D.FIT_GA_CHILDREN
        self.opt = make_optimizer(cfg.optimizer, self.space, cfg.seed, **kw)
        self.started = time.time()
        self.elapsed = 0.0
        self.finished = False
        self.cancelled = False
        self.error = None
        self.exploded = 0

    # ------------------------------------------------------------- mapping
    def to_params(self, X):
        """Free vectors (k/m, d/m, l_rel) -> (P, 4) rows of m, k, l, d."""
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        m = self.m
        return np.stack([np.full(len(X), m), X[:, 0] * m, X[:, 2] * self.spacing, X[:, 1] * m], 1)

    # ---------------------------------------------------------------- state
    @property
    def evaluations(self):
        return int(self.opt.evaluations)

    @property
    def generation(self):
        return int(self.opt.generation)

    @property
    def progress(self):
        return 1.0 if self.finished else min(1.0, self.evaluations / max(1, self.config.max_evaluations))

    @property
    def best_error(self):
        """Best E_all found so far (sum over the training images)."""
        return float(self.opt.best_f) if self.opt.best_x is not None else float("inf")

    @property
    def best_params(self):
        if self.opt.best_x is None:
            return None
        r = self.to_params(self.opt.best_x)[0]
        return {"m": float(r[0]), "k": float(r[1]), "l": float(r[2]), "d": float(r[3])}

    def step(self) -> bool:
        """Run one generation. Returns False once the job is finished (budget, target or cancel)."""
        if self.finished:
            return False
        t0 = time.time()
        X = self.opt.ask()
        f = self.objective(self.to_params(X))
        self.exploded += int(np.sum(~np.isfinite(f)))
        self.opt.tell(X, f)
        self.elapsed += time.time() - t0
        n_img = self.objective.n_images
        if self.evaluations >= self.config.max_evaluations:
            self.finished = True
        if self.config.target_error is not None and self.best_error / n_img <= self.config.target_error:
            self.finished = True
        if self.checkpoint:
            self.save_checkpoint(self.checkpoint)
        return not self.finished

    def run(self, callback=None):
        while self.step():
            if callback is not None and callback(self):
                self.cancel()
                break
        return self.result()

    def cancel(self):
        """Stop; the best result so far is kept (and written to the checkpoint)."""
        self.cancelled = True
        self.finished = True
        if self.checkpoint:
            self.save_checkpoint(self.checkpoint)

    # --------------------------------------------------------------- output
    def result(self) -> dict:
        bp = self.best_params
        n_img = self.objective.n_images
        res = {
            "format": "silhouette-cloth-fit/result", "version": 1,
            "capture": os.path.abspath(self.capture.root),
            "optimizer": self.config.optimizer, "seed": self.config.seed,
            "train_cameras": [self.capture.cameras[c].name for c in self.train_cameras],
            "train_camera_indices": self.train_cameras,
            "train_times": self.train_times,
            "resolution": self.config.resolution,
            "evaluations": self.evaluations, "generations": self.generation,
            "exploded_candidates": self.exploded,
            "best_E_all": _finite(self.best_error), "best_E_sil_mean_pct": _finite(100.0 * self.best_error / n_img),
            "n_train_images": n_img,
            "params": bp,
            "identifiable": identifiable(bp) if bp else None,
            "mass_source": self.m_source,
            "note": "m is not observable from silhouettes (only k/m, d/m and l are): m is fixed and k, d scale with it",
            "finished": self.finished, "cancelled": self.cancelled, "error": self.error,
            "elapsed_s": self.elapsed, "backend": self.objective.backend,
            "history": [[int(a), float(b) if math.isfinite(b) else None] for a, b in self.opt.history],
        }
        gt = (self.capture.meta or {}).get("true_params")
        if gt and bp:
            res["true_params"] = gt
            res["true_identifiable"] = identifiable(gt)
            res["identifiable_error_pct"] = identifiable_errors(bp, gt)
        return res

    def save_result(self, path):
        _atomic_json(path, self.result())

    def save_checkpoint(self, path):
        _atomic_json(path, {"config": asdict(self.config), "capture": os.path.abspath(self.capture.root),
                            "optimizer_state": self.opt.state_dict(), "elapsed": self.elapsed,
                            "exploded": self.exploded, "finished": self.finished, "cancelled": self.cancelled,
                            "result": self.result()})

    @classmethod
    def resume(cls, path, capture=None):
        """Continue a job from its checkpoint (same capture, same config)."""
        from ..observation.capture import load_capture
        from .optimise import CMAES, SPXMGG  # noqa: F401
        try:
            with open(path) as f:
                ck = json.load(f)
        except FileNotFoundError:
            raise ClothFitError(f"checkpoint not found: {path}") from None
        except json.JSONDecodeError as e:
            raise ClothFitError(f"checkpoint {path} is corrupt: {e}") from None
        cap = capture or load_capture(ck["capture"])
        job = cls(cap, FitConfig.from_dict(ck["config"]), checkpoint=path)
        job.opt = type(job.opt).from_state(ck["optimizer_state"])
        job.elapsed = ck.get("elapsed", 0.0)
        job.exploded = ck.get("exploded", 0)
        job.finished = False
        job.cancelled = False
        if job.evaluations >= job.config.max_evaluations:
            job.finished = True
        return job


def _finite(x):
    return float(x) if math.isfinite(x) else None


def _atomic_json(path, obj):
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, default=_default)
    os.replace(tmp, path)


def _default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")
