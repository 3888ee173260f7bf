"""A steppable fit of a capture: one optimiser generation per ``step()``.

Used by the CLI (a loop with a progress bar), by the Blender modal operator (one step per timer
tick) and by the experiment protocol. The job never loses the best result found so far: it is
kept in memory at every step, written to the checkpoint (if a path is given) after every
generation, and ``result()`` returns it whether the job finished, was cancelled or failed.

The model is the paper's sheet (default) or Blender's cloth (``FitConfig.model``); what is searched
for each lives in ``parameters.py``. Identifiability (SPEC 2): the motion depends on ratios to the
mass only, so the job fixes the mass from the cloth mass (``FitConfig.cloth_mass``, else the
capture's ``cloth_mass``, else a default, flagged in the result) and searches the rest per unit
mass, in log scale. The result reports the model's parameters for that mass (paper: m, k, l, d and
the identifiable k/m, d/m, l; Blender: ``blender_cloth``, ClothSettings values a Cloth modifier
takes, with the scene frame rate they belong to).
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from ..physics.paper import identifiable, identifiable_errors
from .objective import SilhouetteObjective
from .optimise import make_optimizer
from .parameters import PaperParameters, SceneParameters, make_parameters


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
    bounds: dict | None = None            # per free name (low, high); None = the model's defaults
    backend: str = "auto"
    population: int | None = None
    children: int | None = None
    model: object = None                  # "paper", "blender" or a model dict; None = the capture's, else paper
    fps: float | None = None              # blender: the scene frame rate the settings are for (24)
    quality: int | None = None            # blender: solver steps per frame (5, or the warm start's)
    bending_model: str | None = None      # blender: ANGULAR (default) or LINEAR
    free: list | None = None              # blender: settings to search (default parameters.BLENDER_FREE)
    fixed: dict | None = None             # blender: settings held at given values
    init: str | None = None               # a result JSON to start from (warm start)
    evaluator: str = "core"               # where candidates are simulated: "core" or "blender" (a .blend's own
                                          # solver in worker processes: addon.farm, handed to FitJob)
    blend: str | None = None              # blender: the scene file, its cloth object, the frame of t = 0
    blend_object: str | None = None
    frame_zero: float | None = None
    workers: int | None = None            # blender: worker processes (default: the cores)
    address: str | None = None            # blender: a running Ray cluster ("auto", "ray://host:port")
    executor: str = "auto"                # blender: "ray", "process" (no Ray) or "auto"

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


def resample_ignore(mask, height: int, width: int):
    """An ignore mask at another resolution: a pixel is unknown when any part of it was (None stays None)."""
    import cv2
    if mask is None or mask.shape == (height, width):
        return mask
    img = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return img > 0


def load_observed(capture, cams, fidx, resolution=None):
    """Cameras, observed silhouettes and ignore masks ``[cam][frame]`` of a capture, at ``resolution``."""
    cameras = [capture.cameras[c] for c in cams]
    observed, ignore = capture.load_observations(cams, fidx)
    if resolution is not None:
        h, w = int(resolution[0]), int(resolution[1])
        if h <= 0 or w <= 0:
            raise ClothFitError(f"fit resolution {resolution} must be positive")
        cameras = [c.resized(h, w) for c in cameras]
        observed = [[resample_silhouette(o, h, w) for o in oc] for oc in observed]
        ignore = [[resample_ignore(g, h, w) for g in gc] for gc in ignore]
    return cameras, observed, ignore


class FitJob:
    def __init__(self, capture, config: FitConfig | None = None, checkpoint: str | None = None, evaluator=None):
        """``evaluator``: where candidates are simulated when not by the core's models: a model-like
        object (``simulate(scenario, rows) -> SimResult``, ``scenario(times)``, ``describe()``), e.g.
        ``addon.farm.scene.BlendSceneEvaluator`` (Blender's solver on a .blend in worker processes)."""
        self.capture = capture
        self.config = cfg = config or FitConfig()
        self.checkpoint = checkpoint
        if cfg.evaluator not in ("core", "blender"):
            raise ClothFitError(f"fit config: evaluator {cfg.evaluator!r} must be 'core' or 'blender'")
        if cfg.evaluator != "core" and evaluator is None:
            raise ClothFitError(f"a fit with the {cfg.evaluator} backend needs its workers "
                                f"(python -m addon fit ... --backend blender --blend SCENE.blend)")
        self.evaluator = evaluator
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
        cameras, observed, ignore = load_observed(capture, cams, fidx, cfg.resolution)
        names = [[capture.silhouette_path(c, f) for f in fidx] for c in cams]
        if evaluator is not None:
            self.scenario = evaluator.scenario(self.train_times)
            self.par = SceneParameters(capture, cfg, evaluator)
        else:
            self.scenario = capture.scenario.with_frames(self.train_times)
            self.par = make_parameters(capture, cfg)
        self.objective = SilhouetteObjective(self.scenario, cameras, observed, backend=cfg.backend, names=names,
                                             model=self.par.model, ignore=ignore)
        self.m, self.m_source = self.par.m, self.par.m_source
        self.space = self.par.space
        kw = {}
        is_cma = cfg.optimizer.lower() in ("cma", "cma-es")
        if self.par.initial is not None:          # warm start: from the given result, a closer search
            kw["initial"] = self.par.initial
            if is_cma:
                kw["sigma0"] = D.WARM_START_SIGMA
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
        """Free vectors -> the model's parameter rows (paper: (P, 4) rows of m, k, l, d)."""
        return self.par.rows(X)

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
        """The best parameters so far: paper m, k, l, d; Blender the ClothSettings values."""
        if self.opt.best_x is None:
            return None
        if isinstance(self.par, PaperParameters):
            return self.par.params(self.opt.best_x)
        return self.par.settings(self.opt.best_x)

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
            "model": self.par.model.to_dict(),
            "params": bp if isinstance(self.par, PaperParameters) else None,
            "identifiable": identifiable(bp) if bp and isinstance(self.par, PaperParameters) else None,
            "mass_source": self.m_source,
            "note": self.par.note,
            "finished": self.finished, "cancelled": self.cancelled, "error": self.error,
            "elapsed_s": self.elapsed, "backend": self.objective.backend,
            "history": [[int(a), float(b) if math.isfinite(b) else None] for a, b in self.opt.history],
        }
        if bp and not isinstance(self.par, PaperParameters):
            res.update(self.par.describe(self.opt.best_x))
        if self.evaluator is not None:
            res["raster_backend"] = res["backend"]
            res.update(self.evaluator.describe())
            res["seconds"] = self.elapsed
        gt = (self.capture.meta or {}).get("true_params")
        if gt and bp and isinstance(self.par, PaperParameters):
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
    def resume(cls, path, capture=None, evaluator=None):
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
        job = cls(cap, FitConfig.from_dict(ck["config"]), checkpoint=path, evaluator=evaluator)
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
