"""A steppable fit of a capture: one optimiser generation per ``step()``.

Used by the CLI (a loop with a progress bar), by the Blender modal operator (one step per timer
tick) and by the experiment protocol. The job never loses the best result found so far: it is
kept in memory at every step, written to the checkpoint (if a path is given) after every
generation (or every ``checkpoint_interval`` seconds, and always at the end), and ``result()``
returns it whether the job finished, was cancelled or failed.

A job stops (``stop_reason``) when the optimiser has converged by its own criteria
("converged"), the evaluation budget is spent ("budget"), the target error is reached
("target"), it is cancelled ("cancelled") or it failed ("error": e.g. every candidate exploded).

The checkpoint (what the job is a fit of, its optimiser and stages; resumed only by the same fit)
is ``checkpoint.py``'s; the result (``FitResult``) is ``result.py``'s; the configuration (``FitConfig``) is
``config.py``'s.

A fit is of one take (a capture) or of several takes of one cloth (``takes.py``): one set of settings shared
by every take, each take its own cameras, frames, frame rate and manipulation's unknowns.

The model is the paper's sheet (default) or Blender's cloth (``FitConfig.model``); what is searched
for each lives in ``parameters.py``. Identifiability (SPEC 2): the motion depends on ratios to the
mass only, so the job fixes the mass from the cloth mass (``FitConfig.cloth_mass``, else the
capture's ``cloth_mass``, else a default, flagged in the result) and searches the rest per unit
mass, in log scale. The result reports the model's parameters for that mass (paper: m, k, l, d and
the identifiable k/m, d/m, l; Blender: ``blender_cloth``, ClothSettings values a Cloth modifier
takes, with the scene frame rate they belong to).
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from ..observation.floor import resample_ignore, resample_silhouette  # noqa: F401 (also the fit's resampling)
from ..physics.blender_settings import rate_factor
from ..physics.models import BlenderModel
from ..safeio import exclusive_lock  # noqa: F401 (re-exported for the CLI)
from . import checkpoint
from .again import extra_budget, searches_result, start_again
from .alone import alone_budget, alone_step
from .checkpoint import STOP_REASONS, capture_hash, identity_diff, read_checkpoint, silhouettes_hash  # noqa: F401 (re-exported)  # noqa: F401 (re-exported for the CLI and tests)
from .config import (  # noqa: F401 (re-exported)
    CMA_OPTIMIZERS,
    SEARCH_OPTIONS,
    FitConfig,
    check_resolution,
    resolve_optimizer,
)
from .intervals import interval_budget, interval_step, intervals_plan
from .objective import SilhouetteObjective, load_observed  # noqa: F401 (re-exported)
from .offset_profile import profile_step
from .optimise import make_optimizer
from .parameters import (
    BlenderParameters,
    PaperParameters,
    SceneParameters,
    declared_model,
    joint_space,
    make_parameters,
    scene_frame_rate,
)
from .quality import Ladder
from .result import FitResult, job_result
from .result import finite_or_none as _finite
from .run_state import RunState
from .steppable import ask_within
from .takes import (
    Take,
    TakesManipulation,
    TakesObjective,
    candidate_errors,
    check_same_cloth,
    combined_hash,
    manipulation_result,
    selection,
    take_names,
    takes_entries,
    window_objective,
    window_share,
)

if TYPE_CHECKING:
    from ..observation.capture import Capture


class FitJob:
    """A fit in stages, one generation per ``step()``: the main search; then, where the quality is
    the fit's to choose, the quality ladder's rungs (``quality.Ladder``: short warm-started CMA-ES runs
    at neighbouring qualities); then, where the manipulation has unknowns, their profile (the
    objective either side of the best offsets: their uncertainty, or that the fit cannot separate
    them). At the end, ``diagnose.report`` puts the training and held-out errors beside the images'
    noise floor."""

    def __init__(
        self,
        capture,
        config: FitConfig | None = None,
        checkpoint: str | None = None,
        checkpoint_interval: float = 0.0,
        evaluator=None,
    ):
        """``evaluator``: where candidates are simulated when not by the core's models: a model-like
        object (``simulate(scenario, rows) -> SimResult``, ``scenario(times)``, ``describe()``), e.g.
        ``addon.farm.scene.BlendSceneEvaluator`` (Blender's solver on a .blend in worker processes)."""
        self.capture = capture
        self.config = cfg = (config or FitConfig()).checked()
        self.checkpoint = checkpoint
        if cfg.evaluator not in ("core", "blender"):
            raise ClothFitError(f"fit config: evaluator {cfg.evaluator!r} must be 'core' or 'blender'")
        if cfg.evaluator != "core" and evaluator is None:
            raise ClothFitError(
                f"a fit with the {cfg.evaluator} backend needs its workers "
                f"(python -m clothfit fit ... --backend blender --blend SCENE.blend)"
            )
        self.evaluator = evaluator
        self.checkpoint_interval = float(checkpoint_interval)
        self._last_save = -math.inf
        captures = list(capture) if isinstance(capture, (list, tuple)) else [capture]
        if not captures:
            raise ClothFitError("a fit needs at least one take (a capture folder)")
        if len(captures) > 1 and evaluator is not None:
            raise ClothFitError(
                "several takes are fitted with the core models; --backend blender fits one take (its .blend)"
            )
        names = take_names(captures) if len(captures) > 1 else [""]
        if len(captures) > 1:
            check_same_cloth(captures, names)
        self.takes = [
            Take(
                c,
                cfg,
                names[k],
                selection(cfg.train_cameras, k, len(captures), "train_cameras"),
                selection(cfg.train_times, k, len(captures), "train_times"),
                evaluator,
            )
            for k, c in enumerate(captures)
        ]
        t0 = self.takes[0]
        self.capture = t0.capture
        self.train_cameras, self.train_frames, self.train_times = t0.train_cameras, t0.train_frames, t0.train_times
        self.scenario = t0.scenario
        self.capture_hash = combined_hash([t.capture_hash for t in self.takes]) if names[0] else t0.capture_hash
        self.silhouettes_hash = (
            combined_hash([t.silhouettes_hash for t in self.takes]) if names[0] else t0.silhouettes_hash
        )
        self.par = (
            SceneParameters(self.capture, cfg, evaluator)
            if evaluator is not None
            else make_parameters(self.capture, cfg)
        )
        self.take_scales = self._take_rates(cfg)
        self._objectives = {}
        self.windows: dict = {}  # the running objective on the first frames (takes.window_objective)
        self.objective = self._build_objective(None)
        self.m, self.m_source = self.par.m, self.par.m_source
        if len(self.takes) == 1:
            self.manip, self.manip_note = t0.manip, t0.manip_note
        else:
            tm = TakesManipulation(self.takes)
            self.manip, self.manip_note = (tm if tm.n else None), None
        self.npar = self.par.space.n
        self.space = joint_space(self.par.space, self.manip)
        strong = self._strong_free()
        stageable = 0 < len(strong) < len(getattr(self.par, "free", ()))
        self.optimizer_name = resolve_optimizer(cfg.optimizer, stageable)
        self.ladder = self._ladder(capture, cfg, evaluator)
        self.start_quality = None if self.ladder is None else self.ladder.start
        reserved = self.profile_reserve = 0
        if self.ladder is not None:
            reserved = (D.QUALITY_RUNGS_RESERVED if not self.ladder.probe_only else 1) * self._rung_budget()
        if self.manip is not None:  # the profile: either side of each offset, its centre, its polish rounds
            k = self.manip.n
            self.profile_reserve = 2 * k + D.PROFILE_JITTER + D.PROFILE_POLISH_ROUNDS * (2 * k + 1)
        self.state = RunState()  # where the fit is: everything a checkpoint saves of its progress (run_state.py)
        self.intervals_note = intervals_plan(self)
        if self.intervals_note is None:  # kept like the profile's: no rung eats into it
            self.profile_reserve += interval_budget(self.space.n)
        self.alone_opt = None  # several takes: the running optimiser of each take searched alone (alone.py)
        self.floor_cache: dict = {}  # the training floor at the last point checked (diagnose.py; not checkpointed)
        self.profile_reserve += alone_budget(self)
        reserved += self.profile_reserve
        self.search_end = cfg.max_evaluations - reserved
        self.opt = self.main_optimizer()
        self.state.stage_quality = self.start_quality
        self.state.stage_end = self.search_end
        self.start_x = self._start_point()  # the user's own settings, scored first (state.start_f)
        self.started = time.time()

    # ------------------------------------------------------------- set-up
    def _take_rates(self, cfg) -> list[float]:
        """Each take's frame rate (``Take.fps``) and the factor its rows' time scale takes (the first take's rate
        over its own: the same cloth in physical time); 1 for the paper's sheet."""
        model = self.par.model
        out = []
        for k, t in enumerate(self.takes):
            if getattr(model, "name", "") != "blender" or self.evaluator is not None:
                t.fps, t.fps_source = getattr(model, "fps", None), getattr(self.par, "fps_source", None)
            elif k == 0:
                t.fps, t.fps_source = model.fps, self.par.fps_source
            else:
                t.fps, t.fps_source = scene_frame_rate(t.capture, cfg)
            out.append(1.0 if not t.fps or k == 0 else rate_factor(model.fps, t.fps))
        return out

    def _ladder(self, capture, cfg, evaluator):
        """The quality ladder where the fit chooses the quality (blender model; None otherwise)."""
        if isinstance(self.par, PaperParameters):
            return None
        if evaluator is not None:
            return Ladder(
                evaluator.quality,
                probe_only=cfg.quality != "auto",
                max_rungs=1 if cfg.quality != "auto" else D.QUALITY_RUNGS_RESERVED,
            )
        if cfg.quality != "auto" and (cfg.quality is not None or cfg.init or "quality" in declared_model(capture, cfg)):
            return None
        return Ladder(self.par.model.quality)

    def _start_point(self):
        """Where the user's own settings are (a scene's Cloth modifier, a warm start), or None: it is
        evaluated first and kept, so the fit never answers worse than what it was given."""
        x = None
        if self.par.initial is not None:
            x = np.asarray(self.par.initial[0], dtype=np.float64)
        elif self.evaluator is not None:
            scene = np.array([self.par.coordinate(n, self.par.fixed[n]) for n in self.par.free])
            x = self.par.space.clip(scene[None])[0]
        if x is None:
            return None
        return np.concatenate([x, np.zeros(self.space.n - self.npar)])

    def _score_aside(self, X) -> float:
        """Score candidates outside the optimiser (the start point; a last batch cut to the budget):
        counted, the best kept if it is the best so far. Returns their lowest error (inf if none)."""
        f = self.evaluate(X) if len(X) else np.zeros(0)
        self.state.done_evals += len(f)
        self.state.exploded += int(np.sum(~np.isfinite(f)))
        g = np.where(np.isfinite(f), f, np.inf)
        i = int(np.argmin(g)) if len(g) else -1
        have = self.state.best_by_quality.get(self.state.stage_quality)
        if i >= 0 and math.isfinite(g[i]) and (have is None or g[i] < have[0]):
            self.state.best_by_quality[self.state.stage_quality] = [
                float(g[i]),
                np.asarray(X[i], dtype=np.float64).tolist(),
            ]
        return float(g[i]) if i >= 0 else math.inf

    def _rung_budget(self) -> int:
        frac = (
            D.SCENE_QUALITY_PROBE if (self.ladder is not None and self.ladder.probe_only) else D.QUALITY_RUNG_FRACTION
        )
        return max(1, int(round(frac * self.config.max_evaluations)))

    def _optimizer_kw(self, warm_x=None):
        cfg = self.config
        is_cma = self.optimizer_name in CMA_OPTIMIZERS
        tolfun = (
            D.FIT_TOLFUN_PER_IMAGE if cfg.tolfun_per_image is None else cfg.tolfun_per_image
        ) * self.objective.n_images
        kw = {"tolx": D.FIT_TOLX if cfg.tolx is None else cfg.tolx, "tolfun": tolfun}
        initial = None
        if warm_x is not None:
            initial = [np.asarray(warm_x, dtype=np.float64)]
        elif self.par.initial is not None:  # warm start: from the given result, a closer search
            initial = [
                np.concatenate([np.asarray(x, dtype=np.float64), np.zeros(self.space.n - self.npar)])
                for x in self.par.initial
            ]
        if initial is not None:
            kw["initial"] = initial
            if is_cma:
                kw["sigma0"] = D.WARM_START_SIGMA
        paper = isinstance(self.par, PaperParameters)
        n = self.space.n
        if self.optimizer_name == "cma-staged" and warm_x is None:
            kw.update(self._staged_kw())
        if self.optimizer_name == "cma-portfolio" and warm_x is None:  # docs/search.md: runs share the budget
            kw["budget"] = max(1, self.search_budget())
            kw["popsize"] = cfg.population if cfg.population is not None else 4 + int(3 * math.log(n))
        elif is_cma:
            kw["restarts"] = (
                0
                if warm_x is not None
                else cfg.restarts
                if cfg.restarts is not None
                else D.FIT_RESTARTS
                if paper
                else D.BLENDER_FIT_RESTARTS
            )
            # Hansen's default population 4 + 3 ln n (7 for the paper's 3 free quantities)
            kw["popsize"] = cfg.population if cfg.population is not None else 4 + int(3 * math.log(n))
        else:  # the paper's GA: population 7n, 5n children per family
            kw["population"] = cfg.population if cfg.population is not None else D.FIT_GA_POPULATION if paper else 7 * n
            kw["children"] = cfg.children if cfg.children is not None else D.FIT_GA_CHILDREN if paper else 5 * n
            kw["stall_evaluations"] = D.FIT_GA_STALL
        for name, value in cfg.search_options().items():  # the config's own settings of this optimiser
            key, optimizers = SEARCH_OPTIONS[name]
            if key is None or self.optimizer_name not in optimizers:
                continue  # read above (a rung's sigma0 stays the warm start's) or in _staged_kw (the grid's names, shape)
            kw[key] = value
        if cfg.sigma0 is not None and warm_x is None:
            kw["sigma0"] = cfg.sigma0
        return kw

    def _staged_kw(self) -> dict:
        """cma-staged: the settings the silhouettes see most (``STAGED_STRONG``) and the manipulation's
        strong unknown (``STAGED_FIRST_UNKNOWNS``: its time offset) first, every other setting (and the
        handles' offsets, at the declared positions) held where the fit starts (Blender's defaults at this
        mass, or the warm start's); the main search's budget."""
        par = self.par
        kw = {"budget": max(1, self.search_budget())}
        if self.config.population is not None:  # the user's population, in both stages
            kw["first_popsize"] = self.config.population
        strong = self._strong_free()
        if self.space.n > self.npar:
            # the manipulation's unknowns: the second stage searches the handles' offsets too and still improves
            # when the tail would start; there the tail only where it is stuck (docs/search.md, "Runs again and
            # the tail")
            kw["warm_tail_stuck"] = D.STAGED_WARM_TAIL_STUCK_UNKNOWNS
        if self.ladder is not None:  # the rungs share the budget: shorter runs again cost time there (D's note)
            kw["first_restart_step"] = D.STAGED_FIRST_RESTART_STEP_LADDER
        grid = self.config.staged_restart_grid
        rows, cols = self.config.staged_restart_grid_rows, self.config.staged_restart_grid_columns
        near = self.config.staged_restart_grid_near
        if (D.FIT_RESTART_GRID_ON if grid is None else grid) and all(n in strong for n in D.FIT_RESTART_GRID):
            kw["first_restart_grid"] = list(D.FIT_RESTART_GRID)  # runs again from the grid's best cells
            if rows is not None or cols is not None:
                n = D.STAGED_FIRST_RESTART_GRID_POINTS
                kw["first_restart_grid_points"] = [n if rows is None else rows, n if cols is None else cols]
            if near is not None:  # the grid also around the run's end in the settings named there that are free
                kw["first_restart_grid_near"] = {n: near for n in D.FIT_RESTART_NEAR if n in strong}
            if self.config.staged_restart_grid_frames:  # what an evaluation on the first frames costs
                kw["first_restart_grid_window_share"] = window_share(self.takes, self.config.staged_restart_grid_frames)
        elif rows is not None or cols is not None or near is not None:
            raise ClothFitError(
                "--search staged_restart_grid_rows/columns/near: this fit runs no grid (staged_restart_grid is off, "
                f"or {' and '.join(D.FIT_RESTART_GRID)} are not both free)"
            )
        if strong:
            kw["first"] = strong + [n for n in list(self.space.names)[self.npar :] if n in D.STAGED_FIRST_UNKNOWNS]
            if par.initial is None:
                kw["hold"] = {n: par.coordinate(n, par.fixed[n]) for n in par.free if n not in strong}
        return kw

    def _strong_free(self) -> list:
        """The free settings of Blender's cloth among ``D.STAGED_STRONG`` (none on the paper's sheet)."""
        if not isinstance(self.par, BlenderParameters):
            return []
        return [n for n in D.STAGED_STRONG if n in self.par.free]

    def search_budget(self) -> int:
        """The main search's share of the budget (the rest is kept for the ladder and the profile)."""
        return getattr(self, "search_end", self.config.max_evaluations)

    def main_optimizer(self) -> Any:
        """The main search's optimiser, as configured (a fresh one: the checkpoint's identity names it); a
        search again (``again.py``) from the seed ``SEARCH_AGAIN_SEED`` on for each."""
        seed = self.config.seed + D.SEARCH_AGAIN_SEED * (self.state.again or {}).get("searches", 0)
        return make_optimizer(self.optimizer_name, self.space, seed, **self._optimizer_kw())

    @property
    def budget(self) -> int:
        """The fit's evaluations in all: ``max_evaluations``, and the first search's share for each search
        again."""
        return self.config.max_evaluations + extra_budget(self)

    def rung_optimizer_name(self) -> str:
        """A rung's optimiser: CMA-ES from the warm start (a local search whatever the main optimiser was),
        in two stages like the main search's where that is "cma-staged" (``QUALITY_RUNG_FIRST_FRACTION``)."""
        staged = self.optimizer_name == "cma-staged" and D.QUALITY_RUNG_FIRST_FRACTION > 0
        return "cma-staged" if staged and self._strong_free() else "cma-es"

    def _rung_optimizer(self, x0):
        kw = self._optimizer_kw(warm_x=x0)
        if self.rung_optimizer_name() == "cma-staged":
            # the strong settings (and the time offset) re-settle first at the new quality, the others held
            # at the warm start; then every coordinate (docs/real_captures.md, "The quality the fit chooses")
            names = list(self.space.names)
            first = self._strong_free() + [n for n in names[self.npar :] if n in D.STAGED_FIRST_UNKNOWNS]
            return make_optimizer(
                "cma-staged",
                self.space,
                self.config.seed,
                initial=kw["initial"],
                sigma0=D.WARM_START_SIGMA,
                second_sigma=D.STAGED_SECOND_SIGMA,
                restarts=0,
                tolx=kw["tolx"],
                tolfun=kw["tolfun"],
                first=first,
                first_fraction=D.QUALITY_RUNG_FIRST_FRACTION,
                warm_tail=0.0,  # the main search's warm tail and runs again were A/B'd on main searches, not on rungs
                first_restart_step=0.0,
                budget=self._rung_budget(),
                popsize=4 + int(3 * math.log(self.space.n)),
            )
        if self.optimizer_name == "cma-portfolio":
            kw.pop("budget", None)
        if self.optimizer_name != "cma-es":
            kw = {
                "tolx": kw["tolx"],
                "tolfun": kw["tolfun"],
                "initial": kw["initial"],
                "sigma0": D.WARM_START_SIGMA,
                "restarts": 0,
                "popsize": 4 + int(3 * math.log(self.space.n)),
            }
        return make_optimizer("cma-es", self.space, self.config.seed, **kw)

    def model_at(self, quality: int | None) -> Any:
        """The parameter set-up's model at ``quality`` (the main one when None)."""
        if quality is None or self.evaluator is not None:
            return self.par.model
        base = self.par.model
        return BlenderModel(base.fps, int(quality), base.bending_model)

    def activate(self, quality: int | None) -> None:
        """Simulate at ``quality`` from now on: the objective, the settings the result reports."""
        if quality is None:
            return
        if self.evaluator is not None:
            self.evaluator.quality = int(quality)
            self.par.fixed["quality"] = int(quality)
            return
        if quality == self.start_quality and not self._objectives:
            self._objectives[quality] = self.objective
        self.objective = self.objective_at(quality)
        self.par.model = self.objective.model
        self.par.fixed["quality"] = int(quality)

    def objective_at(self, quality: int | None) -> SilhouetteObjective | TakesObjective:
        """The training objective simulated at ``quality`` (kept once built; not made the running one): a
        ``SilhouetteObjective``, or over several takes a ``takes.TakesObjective``."""
        if quality not in self._objectives:
            self._objectives[quality] = self._build_objective(quality)
        return self._objectives[quality]

    def _build_objective(self, quality):
        if len(self.takes) == 1:
            return self.take_objective(0, quality)
        return TakesObjective([self.take_objective(k, quality) for k in range(len(self.takes))], self.take_scales)

    def take_objective(self, k: int, quality: int | None) -> SilhouetteObjective:
        """Take ``k``'s own training objective at ``quality``, simulated at its own frame rate (kept once built)."""
        key = ("take", k, quality)
        if key not in self._objectives:
            model = self.model_at(quality)
            t = self.takes[k]
            if k and isinstance(model, BlenderModel) and self.evaluator is None:
                model = BlenderModel(t.fps, model.quality, model.bending_model)
            self._objectives[key] = t.objective(model, self.config.backend)
        return self._objectives[key]

    # ------------------------------------------------------------- identity
    def identity(self) -> dict:
        """What this job is a fit of: a checkpoint is only resumed by a job with the same identity."""
        return checkpoint.identity(self)

    # ------------------------------------------------------------- mapping
    def to_params(self, X: ArrayLike) -> np.ndarray:
        """Free vectors -> the model's parameter rows (paper: (P, 4) rows of m, k, l, d)."""
        return self.par.rows(np.atleast_2d(X)[:, : self.npar])

    def evaluate(self, X: ArrayLike, objective: SilhouetteObjective | None = None) -> np.ndarray:
        """Training error (sum of E_sil over the training images) of candidates ``X`` (search space)."""
        return candidate_errors(self, X, objective)

    # ---------------------------------------------------------------- state
    @property
    def evaluations(self) -> int:
        return int(self.state.done_evals + (self.opt.evaluations if self.state.stage in ("search", "rung") else 0))

    @property
    def generation(self) -> int:
        return int(
            sum(r["generations"] for r in self.state.records)
            + self.state.cut_batches
            + (self.opt.generation if self.state.stage in ("search", "rung") else 0)
        )

    @property
    def progress(self) -> float:
        return 1.0 if self.state.finished else min(1.0, self.evaluations / max(1, self.budget))

    def chosen_quality(self) -> int | None:
        if self.ladder is None:
            return None
        return self.ladder.chosen() if self.ladder.tried else self.start_quality

    def best_point(self) -> tuple[float, np.ndarray | None]:
        """(best_f, best_x) at the chosen quality: the stages' records, or the running search's."""
        q = self.chosen_quality()
        if q in self.state.best_by_quality:
            f, x = self.state.best_by_quality[q]
            return float(f), np.asarray(x, dtype=np.float64)
        if self.state.stage == "search" and self.opt.best_x is not None:
            return float(self.opt.best_f), np.asarray(self.opt.best_x, dtype=np.float64)
        return float("inf"), None

    @property
    def best_error(self) -> float:
        """Best E_all found so far (sum over the training images) at the chosen quality."""
        return self.best_point()[0]

    @property
    def best_x(self) -> np.ndarray | None:
        return self.best_point()[1]

    @property
    def best_params(self) -> dict[str, float] | None:
        """The best parameters so far: paper m, k, l, d; Blender the ClothSettings values."""
        x = self.best_x
        if x is None:
            return None
        if isinstance(self.par, PaperParameters):
            return self.par.params(x[: self.npar])
        with self.at_quality(self.chosen_quality()):
            return self.par.settings(x[: self.npar])

    @contextlib.contextmanager
    def at_quality(self, quality: int | None) -> Iterator[None]:
        was = self.state.stage_quality
        if quality is not None and quality != was:
            self.activate(quality)
        try:
            yield
        finally:
            if quality is not None and quality != was and was is not None:
                self.activate(was)

    def _track(self):
        """The running stage's best into ``state.best_by_quality``."""
        if self.opt.best_x is not None:
            self.state.track(self.state.stage_quality, float(self.opt.best_f), np.asarray(self.opt.best_x))

    def update_stop(self) -> None:
        """After a generation: finish the job, or end the running stage and start the next."""
        if self.state.finished:
            return
        n_img = self.objective.n_images
        if self.state.stage == "search" and self.opt.best_x is None and self.evaluations >= D.FIT_EXPLODED_LIMIT:
            self.state.error = (
                f"every one of the {self.evaluations} candidates tried made the simulation explode or "
                f"fail: check the capture's scenario (settle_time, gravity, cloth size) and the bounds"
            )
            self.state.stop_reason = "error"
        elif self.config.target_error is not None and self.best_error / n_img <= self.config.target_error:
            self.state.stop_reason = "target"
        elif self.state.stage in ("search", "rung") and (self.opt.stopped or self.evaluations >= self.state.stage_end):
            self._next_stage()
        elif self.state.stage == "done" or (
            self.evaluations >= self.budget and self.state.stage not in ("profile", "alone", "intervals")
        ):
            self._next_stage()
        self.state.finished = self.state.stop_reason is not None

    def _end_running(self):
        s = self.state
        if s.stage in ("search", "rung"):
            self._track()
            record = {
                "stage": s.stage,
                "quality": s.stage_quality,
                "evaluations": int(self.opt.evaluations),
                "generations": int(self.opt.generation),
                "best_f": _finite(self.opt.best_f) if self.opt.best_x is not None else None,
                "stop": "converged" if self.opt.stopped else "budget",
            }
            looks = self.opt.looks() if s.stage == "search" else None
            if looks is not None:  # the search's independent starts and how many reached the best one's basin
                record["looks"] = looks
            s.end_stage(record, self.opt_history(), self.opt.evaluations)
            if self.ladder is not None and s.stage_quality in s.best_by_quality:
                self.ladder.record(s.stage_quality, s.best_by_quality[s.stage_quality][0])

    def _next_stage(self):
        """End the running stage; search again, or start a rung, the profile, the intervals, each take alone,
        or finish."""
        self._end_running()
        if self.state.stage == "search" and start_again(self):  # above the floor its jitter allows (again.py)
            self.opt = self.main_optimizer()
            self.state.stage_end = self.state.done_evals + self.search_end
            return
        left = self.budget - self.state.done_evals - self.profile_reserve  # the profile's kept
        if self.state.stage in ("search", "rung") and self.ladder is not None and self.state.best_by_quality:
            q = self.ladder.next()
            rung = self._rung_budget()
            if q is not None and left >= max(1, rung // 2):  # the search's last generation may eat into a rung
                f, x = self.state.best_by_quality[self.chosen_quality()]
                self.state.stage, self.state.stage_quality = "rung", q
                self.activate(q)
                self.opt = self._rung_optimizer(x)
                self.state.stage_end = self.state.done_evals + min(rung, left)
                return
        if self.state.stage in ("search", "rung") and self.manip is not None and self.state.best_by_quality:
            self.state.stage = "profile"
            self.activate(self.chosen_quality())
            self.state.stage_quality = self.chosen_quality()
            return
        if (
            self.state.stage in ("search", "rung", "profile")
            and self.intervals_note is None
            and self.state.best_by_quality
        ):
            self.state.stage = "intervals"
            self.activate(self.chosen_quality())
            self.state.stage_quality = self.chosen_quality()
            return
        # several takes: each take alone from the final best point (the intervals may have moved it)
        if (
            self.state.stage in ("search", "rung", "profile", "intervals")
            and alone_budget(self)
            and self.state.best_by_quality
        ):
            self.state.stage = "alone"
            self.activate(self.chosen_quality())
            self.state.stage_quality = self.chosen_quality()
            return
        self.state.stage = "done"
        if self.chosen_quality() is not None:
            self.activate(self.chosen_quality())
            self.state.stage_quality = self.chosen_quality()
        self.state.stop_reason = self.state.search_stop or "budget"

    def end_profile(self) -> None:
        """The profile is over: the intervals stage next, or the end."""
        self._next_stage()

    def _profile_step(self):
        """The "profile" stage's step: a polish round of the offsets or their profile (``offset_profile.profile_step``)."""
        profile_step(self)

    def opt_history(self) -> list[list]:
        """The running optimiser's [evaluations, best error] steps (None for an error that is not finite)."""
        return [[int(a), float(b) if math.isfinite(b) else None] for a, b in self.opt.history]

    def step(self) -> bool:
        """Run one generation. Returns False once the job is finished (converged, budget, target,
        cancelled or failed)."""
        if self.state.finished:
            return False
        t0 = time.time()
        if self.state.stage == "profile":
            self._profile_step()
        elif self.state.stage == "intervals":
            if interval_step(self):
                self._next_stage()
        elif self.state.stage == "alone":
            if alone_step(self):
                self._next_stage()
        elif self.state.stage == "search" and self.start_x is not None and self.state.start_f is None:
            self.state.start_f = self._score_aside(self.start_x[None])
        elif self.state.stage in (
            "search",
            "rung",
        ):  # never past the stage's budget (unless it left none for a first best)
            left = self.state.stage_end - self.evaluations
            left = math.inf if left <= 0 and self.best_x is None else left
            self.opt, X, whole = ask_within(self.opt, left)
            if whole:  # on every training frame, or on the first ones where the optimiser asks (its window)
                f = self.evaluate(X, window_objective(self, self.opt.window))
                self.state.exploded += int(np.sum(~np.isfinite(f)))
                self.opt.tell(X, f)
                self._track()
            else:  # the budget's last batch, cut to what is left: scored aside, and the stage ends
                self._score_aside(X)
                self.state.stage_end, self.state.cut_batches = self.evaluations, self.state.cut_batches + 1
        self.state.elapsed += time.time() - t0
        self.update_stop()
        if self.state.finished:
            self.finalise()
        if self.checkpoint and (self.state.finished or time.monotonic() - self._last_save >= self.checkpoint_interval):
            self.save_checkpoint(self.checkpoint)
        return not self.state.finished

    def run(self, callback: Callable[[FitJob], Any] | None = None) -> FitResult:
        try:
            while self.step():
                if callback is not None and callback(self):
                    self.cancel()
                    break
        except ClothFitError as e:
            self.fail(str(e))
            raise
        except Exception as e:
            self.fail(f"{type(e).__name__}: {e}")
            raise
        return self.result()

    def finalise(self) -> None:
        """Once, at the end: the errors beside the noise floor (``diagnose.report``)."""
        if self.state.final is not None or self.state.error or self.best_x is None:
            return
        from .diagnose import report, report_takes

        try:
            if len(self.takes) == 1:
                self.state.final = report(self)
            else:
                self.state.final, self.state.take_finals = report_takes(self)
        except ClothFitError as e:  # never a reason to lose the result
            self.state.final = {"error": str(e)}

    def cancel(self) -> None:
        """Stop; the best result so far is kept (and written to the checkpoint)."""
        self.state.cancelled = True
        if not self.state.finished:
            self.state.stop_reason = "cancelled"
        self.state.finished = True
        if self.state.stage in ("search", "rung"):
            self._track()
        if self.checkpoint:
            self.save_checkpoint(self.checkpoint)

    def fail(self, message: str) -> None:
        """Stop because of an error; the best so far is kept (and written to the checkpoint)."""
        self.state.error = str(message)
        self.state.stop_reason = "error"
        self.state.finished = True
        if self.checkpoint:
            with contextlib.suppress(ClothFitError):
                self.save_checkpoint(self.checkpoint)

    # --------------------------------------------------------------- output
    def manipulation(self) -> dict:
        """The result's fitted manipulation (``takes.manipulation_result``); over several takes, each take's
        is in its own entry of the result's ``takes``."""
        return manipulation_result(self) if len(self.takes) == 1 else {}

    def take_entries(self) -> list[dict]:
        """Several takes: the result's entry for each (``takes.takes_entries``)."""
        return takes_entries(self)

    def result(self) -> FitResult:
        """The result so far (``result.FitResult``; ``to_json()`` is what the result file holds)."""
        return job_result(self, isinstance(self.par, PaperParameters), searches_result(self))

    def save_result(self, path: str | os.PathLike) -> None:
        self.result().save(path)

    def checkpoint_dict(self) -> dict:
        return checkpoint.checkpoint_dict(self)

    def save_checkpoint(self, path: str | os.PathLike) -> None:
        checkpoint.write_checkpoint(path, self.checkpoint_dict())
        self._last_save = time.monotonic()

    @classmethod
    def resume(
        cls,
        path: str | os.PathLike,
        capture: Capture | None = None,
        config: FitConfig | None = None,
        checkpoint_interval: float = 0.0,
        evaluator: Any = None,
    ) -> FitJob:
        """Continue a job from its checkpoint (``checkpoint.resume``: a checkpoint of another fit is refused
        naming the differing fields; only the budget and the target may differ). ``evaluator``: the workers
        of a Blender-scene fit."""
        return checkpoint.resume(cls, FitConfig, path, capture, config, checkpoint_interval, evaluator)
