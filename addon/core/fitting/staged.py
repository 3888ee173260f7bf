"""The strong settings first ("cma-staged").

:class:`StagedCMA` runs CMA-ES (IPOP restarts) over a subset of the coordinates, ``first``, with
every other coordinate held at ``hold``, for ``first_fraction`` of ``budget`` evaluations (or until
that run stops by its own criteria); then CMA-ES over every coordinate from the best point found,
with step ``second_sigma``; for the last ``warm_tail`` of the budget a third run from the best point with
the first stage's own steps (docs/search.md, "A warm tail"; with ``warm_tail_stuck`` only where the second
stage has found nothing better than the first stage's best point by then, as FitJob sets it where the fit
searches the manipulation's unknowns: "Runs again and the tail"). On Blender's cloth the silhouettes see tension, shear, bending and air
damping far more than compression and the structural dampings (docs/search.md, *The landscape*):
a search over all eight at once spends its budget in the directions it cannot see, while the four
it can see are found within a fraction of the budget on their own (docs/search.md, *Strong settings
first*, has the A/B). Same ask/tell and exact-resume contract as the other optimisers.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .evolution_strategy import CMA_STOPS, CMAES
from .restart_grid import (
    GRID_KEYS,
    centres,
    grid_batch,
    grid_settings,
    grid_state,
    is_run_end,
    near_offsets,
    restart_levels,
    restore_grid,
    starts_left,
    window_best,
)
from .space import (
    SearchSpace,
    checked_flag,
    checked_integer,
    checked_number,
    checked_tie,
    float_from_json,
    float_to_json,
    rng_state_from_json,
    sanitize_fitness,
    saved_active,
    saved_array,
    saved_bool,
    saved_field,
    saved_step,
    saved_value,
)
from .steppable import Optimizer

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


class StagedCMA(Optimizer):
    """CMA-ES over ``first`` (the others held), then over everything from the best point.

    ``first``: names of the space searched in the first stage (default: all of them); ``hold``:
    name -> value (real units) of coordinates held during the first stage (default: the mean of
    ``initial``, else the middle of the unit cube). ``popsize``: the second stage's population
    (the first stage's is ``first_popsize``, by default Hansen's 4 + 3 ln k for its k coordinates);
    ``sigma0``, ``restarts``, ``tolx``, ``tolfun``, ``active``: both stages' CMA-ES, except the second stage's step,
    ``second_sigma``. ``budget`` only shapes the schedule; the caller decides when to stop.
    ``race``: first-stage runs raced (default 1: none), the others from random points of the strong
    settings' cube, each given ``race_evals`` (at most a (race + 1)-th of the first stage) before the
    one with the best point goes on alone. ``scan_points``: between the stages, each first-stage
    coordinate tried at that many values evenly across its range, the others at the best point
    (default 0: none). ``first_restart_step``: a first-stage run whose every coordinate's step (sigma
    times the root of its variance, unit cube) is below this has converged, and another run starts
    where the first began (``initial``, else the middle), same step and population, new random
    stream, while the evaluations are within ``first_explore`` of ``budget``; then the run with the
    best point (kept as it stood when it converged) goes on to the end of the first stage's share, and
    the second stage starts from the best point of them all (0: one run, as before; the default 0.01, with
    the warm tail: docs/search.md, "Runs again and the tail" and "Shorter runs again"; FitJob gives 0.005 where a
    quality ladder follows). ``first_restart_vary``: a first-stage coordinate that each run after the
    first starts at another of ``first_restart_levels`` (unit cube, in turn), the others where the first began
    (default None: every run where the first began; tried on bending, docs/search.md, "Runs again at other
    bendings"). ``first_restart_grid``: two first-stage coordinates tried on a grid across their ranges
    (``first_restart_grid_points``: n x n, or [rows, columns], a count of 1 holding that coordinate at the run's own
    value), the others at the first run's best point (and, with ``first_restart_grid_near``, again with each named
    coordinate moved by -step and by +step, one at a time), once that run has converged; each later run starts at the
    grid's best cell that no run has ended near (one cell, at least ``STAGED_FIRST_RESTART_GRID_APART``), with the
    step ``first_restart_grid_sigma``, until the cells run out (default None: no grid; docs/search.md, "Runs again
    from a grid"); with ``first_restart_grid_at_end``, the grid once at the first stage's end through its best point (then, with
    ``first_restart_grid_end_run``, a first-stage run from the best point of all for that share of the budget)
    instead, and the second stage from the best point of all (docs/search.md, "A line near the run's end").
    ``first_run_cap``: a first-stage run that has had this share of ``budget`` ends as if it had converged (default
    0: only when it converges; docs/search.md, "A cap on the first run"). Race and scan were both
    tried against the bending valley that first stages miss and not kept (docs/search.md). ``tie``: follower ->
    leader, coordinates held in the first stage at the leader's value (clipped to the follower's bounds) rather than
    at ``hold`` (e.g. compression following tension, as in
    Blender's defaults; tried as the fit's default and not kept, docs/search.md); in the second
    stage they are free like every other. ``second_warm``: the second stage's first covariance is the first
    stage's run's on its coordinates (at most ``second_sigma``) and ``second_sigma`` on the others, not
    ``second_sigma`` on all (tried, not kept). ``warm_tail``: the last share of ``budget`` goes to a third run
    from the best point with that covariance; with ``warm_tail_stuck`` only if the second stage has not beaten
    the first stage's best point by then (the defaults: 0.2, off; FitJob turns it on where the fit searches the
    manipulation's unknowns). ``warm_tail_stall``: the tail also starts as soon as the second stage has gained less
    than ``warm_tail_stall_gain`` of its best value over that share of ``budget`` (default 0: tried, not kept,
    docs/search.md, "A tail where the second stage stalls").
    """

    name = "cma-staged"

    def __init__(
        self,
        space: SearchSpace,
        seed=None,
        initial=None,
        popsize=None,
        sigma0: float = 0.3,
        tolx: float = 1e-11,
        tolfun: float = 1e-11,
        active: bool = False,
        restarts: int = 4,
        first=None,
        hold: dict | None = None,
        first_fraction: float = D.STAGED_FIRST_FRACTION,
        budget: int | None = None,
        second_sigma: float = D.STAGED_SECOND_SIGMA,
        tie: dict | None = None,
        first_popsize: int | None = None,
        race: int = D.STAGED_RACE,
        race_evals: int = D.STAGED_RACE_EVALS,
        scan_points: int = D.STAGED_SCAN_POINTS,
        first_restart_step: float = D.STAGED_FIRST_RESTART_STEP,
        first_explore: float = D.STAGED_FIRST_EXPLORE,
        first_restart_vary: str | None = D.STAGED_FIRST_RESTART_VARY,
        first_restart_levels=D.STAGED_FIRST_RESTART_LEVELS,
        second_warm: bool = D.STAGED_SECOND_WARM,
        warm_tail: float = D.STAGED_WARM_TAIL,
        warm_tail_stuck: bool = D.STAGED_WARM_TAIL_STUCK,
        warm_tail_stall: float = D.STAGED_WARM_TAIL_STALL,
        warm_tail_stall_gain: float = D.STAGED_WARM_TAIL_STALL_GAIN,
        first_restart_grid=D.STAGED_FIRST_RESTART_GRID,
        first_restart_grid_points: int | tuple | list = D.STAGED_FIRST_RESTART_GRID_POINTS,
        first_restart_grid_sigma: float = D.STAGED_FIRST_RESTART_GRID_SIGMA,
        first_run_cap: float = D.STAGED_FIRST_RUN_CAP,
        first_restart_grid_near: dict | None = D.STAGED_FIRST_RESTART_GRID_NEAR,
        first_restart_grid_at_end: bool = D.STAGED_FIRST_RESTART_GRID_AT_END,
        first_restart_grid_end_run: float = D.STAGED_FIRST_RESTART_GRID_END_RUN,
        first_restart_grid_frames: int = D.STAGED_FIRST_RESTART_GRID_FRAMES,
        first_restart_grid_window_share: float = 1.0,
    ):
        super().__init__(space, seed, initial)
        w = "cma-staged"
        names = list(space.names)
        first = names if first is None else [str(n) for n in first]
        if first_fraction == 0.0:
            first = names  # no first stage: one CMA-ES run over everything
        unknown = [n for n in first if n not in names]
        if unknown or not first:
            raise ClothFitError(f"{w}: 'first' must name coordinates of the search ({', '.join(names)}), got {first}")
        self.first = [n for n in names if n in set(first)]
        self.popsize = checked_integer(D.CMA_POPSIZE if popsize is None else popsize, f"{w}: popsize", 2)
        self.sigma0 = checked_number(sigma0, f"{w}: sigma0 (unit cube)", 0.0, 10.0, lo_open=True)
        self.second_sigma = checked_number(second_sigma, f"{w}: second_sigma (unit cube)", 0.0, 10.0, lo_open=True)
        self.tolx = checked_number(tolx, f"{w}: tolx")
        self.tolfun = checked_number(tolfun, f"{w}: tolfun")
        self.active = checked_flag(active, f"{w}: active")
        self.restarts = checked_integer(restarts, f"{w}: restarts", 0, 100)
        self.first_fraction = checked_number(first_fraction, f"{w}: first_fraction", 0.0, 1.0)
        self.budget = checked_integer(D.FIT_EVALUATIONS if budget is None else budget, f"{w}: budget")
        u = self._initial_u.mean(axis=0) if len(self._initial_u) else np.full(space.n, 0.5)
        x = space.decode(u)
        for n, v in (hold or {}).items():
            if n not in names:
                raise ClothFitError(f"{w}: 'hold' names {n!r}, not a coordinate of the search")
            x[names.index(n)] = float(v)
        # a held value outside the search range (a scene's zero damping) is held at its bound
        self.hold_u = np.clip(space.encode(space.clip(x)), 0.0, 1.0)
        self.tie = checked_tie(tie or {}, names, self.first, w)
        self.stage = 1
        self._stopped = False
        sub = self._subspace()
        init = [space.decode(self.hold_u)[self._idx]] if len(self._initial_u) else None
        k = sub.n if len(self.first) < space.n else None
        if first_popsize is not None:
            lam1 = checked_integer(first_popsize, f"{w}: first_popsize", 2)
        else:
            lam1 = self.popsize if k is None else 4 + int(3 * np.log(k))
        self.race = checked_integer(race, f"{w}: race", 1, 100)
        # each raced run gets at most a (race + 1)-th of the first stage: the winner as much again at least
        share = int(self.first_fraction * self.budget) // (self.race + 1)
        self.race_evals = max(1, min(checked_integer(race_evals, f"{w}: race_evals", 1), share))
        self.first_restart_step = checked_number(first_restart_step, f"{w}: first_restart_step (unit cube)", 0.0, 1.0)
        self.first_init = None if init is None else [float(v) for v in init[0]]  # where each first-stage run starts
        self.first_runs = 1
        self.first_explore = checked_number(first_explore, f"{w}: first_explore", 0.0, 1.0)
        self.first_run_cap = checked_number(first_run_cap, f"{w}: first_run_cap", 0.0, 1.0)
        self.first_best_run = None  # the converged run with the best point so far (its CMA-ES state)
        self.run_ends: list = []  # each first-stage run's end: [best value, its point in the strong settings' cube]
        self.first_restart_vary, self.first_restart_levels = restart_levels(
            first_restart_vary, first_restart_levels, self.first, w
        )
        # the grid's settings (the first_restart_grid* arguments), checked, and its state before it has run
        grid = {k: v for k, v in locals().items() if k.startswith("first_restart_grid")}
        vars(self).update(grid_settings(self, w, **grid))
        self.second_warm = checked_flag(second_warm, f"{w}: second_warm")
        self.warm_tail = checked_number(warm_tail, f"{w}: warm_tail", 0.0, 1.0)
        self.warm_tail_stuck = checked_flag(warm_tail_stuck, f"{w}: warm_tail_stuck")
        self.first_best_f = None  # the best value when the first stage ended (warm_tail_stuck compares with it)
        self.warm_tail_stall = checked_number(warm_tail_stall, f"{w}: warm_tail_stall", 0.0, 1.0)
        self.warm_tail_stall_gain = checked_number(warm_tail_stall_gain, f"{w}: warm_tail_stall_gain", 0.0, 1.0)
        self.stall_mark = None  # the second stage's [evaluations, best value] its gain is measured from
        self.children = [self._child(sub, lam1, self.sigma0, init)]
        # the race (off by default): more first-stage runs from random points of the strong settings'
        # cube, each given race_evals before the best one goes on alone (docs/search.md, "The race")
        self.racing = self._staging and self.race > 1
        if self.racing:
            for _ in range(self.race - 1):
                u0 = self.rng.uniform(D.STAGED_RACE_START[0], D.STAGED_RACE_START[1], sub.n)
                self.children.append(self._child(sub, lam1, self.sigma0, [sub.decode(u0)]))
        self.turn = 0
        self.scan_points = checked_integer(scan_points, f"{w}: scan_points", 0, 10000)
        self.scan_left: list = []  # the first stage's coordinates still to scan (between the stages)
        self.scanned = False
        self._scan_pending = None

    def _full_u(self, U_sub):
        """The first stage's points in the whole unit cube: held coordinates at ``hold_u``, tied ones at
        their leader's value."""
        U = np.repeat(self.hold_u[None], len(U_sub), 0)
        U[:, self._idx] = U_sub
        if self.tie:
            names = self.space.names
            X = self.space.decode(U)
            for f, lead in self.tie.items():
                X[:, names.index(f)] = X[:, names.index(lead)]
            U = np.clip(self.space.encode(self.space.clip(X)), 0.0, 1.0)
            U[:, self._idx] = U_sub  # the searched coordinates exactly as the child has them
        return U

    @property
    def _staging(self) -> bool:
        """In the first stage, over a proper subset (the others held)."""
        return self.stage == 1 and len(self.first) < self.space.n

    @property
    def _idx(self) -> list:
        return [self.space.names.index(n) for n in self.first]

    def _subspace(self) -> SearchSpace:
        return self.space.subspace(self.first)

    def _child(self, space, popsize, sigma, initial):
        return CMAES(
            space,
            seed=int(self.rng.integers(0, 2**63 - 1)),
            initial=initial,
            popsize=popsize,
            sigma0=sigma,
            restarts=self.restarts,
            tolx=self.tolx,
            tolfun=self.tolfun,
            active=self.active,
        )

    @property
    def stopped(self) -> bool:
        return self._stopped

    @property
    def _current(self) -> CMAES:
        return self.children[self.turn] if self.racing else self.children[-1]

    @property
    def stop_reason(self) -> str | None:
        return self._current.stop_reason

    @property
    def run_popsize(self) -> int:
        return self._current.run_popsize

    @property
    def scanning(self) -> bool:
        """Between the stages: scanning the first stage's coordinates one at a time."""
        return bool(self.scan_left)

    def phase_info(self) -> str:
        if self.scanning:
            return f"scan of {self.scan_left[0]} ({self.scan_points} points across its range)"
        race = f", race: run {self.turn + 1} of {len(self.children)}" if self.racing else ""
        run = f", run {self.first_runs}" if self.stage == 1 and self.first_runs > 1 else ""
        what = (
            ", ".join(self.first) if self.stage == 1 else "all" if self.stage == 2 else "all, the first stage's steps"
        )
        return f"stage {self.stage} ({what}{race}{run})"

    def _next_turn(self) -> None:
        """Racing: the run with the fewest evaluations asks next; once each has had ``race_evals`` (or
        stopped), the one with the best point goes on alone."""
        live = [i for i, c in enumerate(self.children) if not c.stopped and c.evaluations < self.race_evals]
        if live:
            self.turn = min(live, key=lambda i: (self.children[i].evaluations, i))
            return
        best = min(range(len(self.children)), key=lambda i: (self.children[i].best_f, i))
        self.children = [self.children[best]]
        self.racing = False
        self.turn = 0

    def _converged(self, c: CMAES) -> bool:
        """A first-stage run (not racing) whose every coordinate's step is below ``first_restart_step``."""
        step = self.first_restart_step
        return bool(step > 0 and np.all(c.sigma * np.sqrt(np.diag(c.C)) < step))

    def _capped(self, c: CMAES) -> bool:
        """A first-stage run (not racing) that has had ``first_run_cap`` of the budget, settled or not."""
        return bool(self.first_run_cap > 0 and c.evaluations >= self.first_run_cap * self.budget)

    def _run_ended(self, c: CMAES) -> None:
        """Keep a first-stage run's end (its best value and point) for ``looks``."""
        if c.best_x is not None and len(self.run_ends) < self.first_runs:
            self.run_ends.append([float(c.best_f), [float(v) for v in np.clip(c.space.encode(c.best_x), 0.0, 1.0)]])

    def looks(self) -> dict | None:
        """The first stage's starts (runs again: docs/search.md, "Runs again"): ``starts``, the runs made;
        ``ended``, the best value each found; ``agreeing``, how many ended in the best one's basin (every strong
        setting within ``LOOKS_AGREE_UNIT`` of its search range of the best one's); None without a first stage
        or before it has ended."""
        if len(self.first) >= self.space.n or self.stage == 1 or not self.run_ends:
            return None
        best = min(self.run_ends, key=lambda e: e[0])
        u = np.array(best[1])
        agree = sum(1 for e in self.run_ends if np.all(np.abs(np.array(e[1]) - u) <= D.LOOKS_AGREE_UNIT))
        return {
            "starts": int(self.first_runs),
            "ended": [float_to_json(e[0]) for e in self.run_ends],
            "agreeing": int(agree),
            "settings": list(self.first),
        }

    def _scan_batch(self) -> np.ndarray:
        """The best point so far with one first-stage coordinate at ``scan_points`` values evenly across
        its range (in the unit cube: log-scaled settings at even ratios)."""
        idx = self._idx
        U_sub = np.repeat(self._best_u[idx][None], self.scan_points, 0)
        U_sub[:, self.first.index(self.scan_left[0])] = centres(self.scan_points)
        return self._full_u(U_sub)  # held coordinates held, tied ones following, as in the first stage

    def _end_first_stage(self) -> None:
        """The scan, if any, then the second stage from the best point."""
        if self.scan_points and self._best_u is not None and not self.scanned:
            self.scanned = True
            self.scan_left = list(self.first)
            return
        if self.first_runs > len(self.run_ends) and self.children:  # the last run, cut by the stage's end
            self._run_ended(self.children[-1])
        self.stage = 2
        self.first_best_f = None if self._best_u is None else float(self.best_f)
        self.stall_mark = None if self._best_u is None else [int(self.evaluations), float(self.best_f)]
        first = self.children[-1] if self.children else None
        self.children.append(
            self._child(self.space, self.popsize, self.second_sigma, [self.space.decode(self._best_u)])
            if self._best_u is not None
            else self._child(self.space, self.popsize, self.sigma0, None)
        )
        if self.second_warm and first is not None and self._best_u is not None and len(self.first) < self.space.n:
            self.children[-1].shape_start(first.warm_covariance(self.second_sigma, self._idx, self.space.n))

    def _start_tail(self) -> None:
        """The third stage (``warm_tail``): a run over everything from the best point so far, the first
        stage's coordinates at the steps its run converged at, the others at ``second_sigma``."""
        self.stage = 3
        self.children.append(
            self._child(self.space, self.popsize, self.second_sigma, [self.space.decode(self._best_u)])
        )
        self.children[-1].shape_start(self.children[0].warm_covariance(self.second_sigma, self._idx, self.space.n))

    def ask(self) -> np.ndarray:
        if self._stopped:
            raise ClothFitError("cma-staged: ask() after it has stopped")
        if self.scanning:
            if self._scan_pending is None:
                self._scan_pending = self._scan_batch()
            return self.space.decode(self._scan_pending)
        if self.grid_pending is not None:
            return self.space.decode(self._full_u(self.grid_pending))
        c = self._current
        Xc = c.ask()
        if not self._staging:
            return Xc
        X = self.space.decode(self._full_u(c.pending_unit))
        X[:, self._idx] = Xc
        return X

    def tell(self, X: ArrayLike, f: ArrayLike) -> None:
        if self.scanning:
            U = self._scan_pending
            if U is None:
                raise ClothFitError("tell() called without a pending ask()")
            self._check_told(X, U)
            self._record(U, sanitize_fitness(f, len(U)))
            self._scan_pending = None
            self.scan_left.pop(0)
            if not self.scan_left:
                self._end_first_stage()
            return
        if self.grid_pending is not None:
            U = self._full_u(self.grid_pending)
            self._check_told(X, U)
            f = sanitize_fitness(f, len(U))
            if self.grid_windowed:  # values on the first frames only: not the search's; the best cells again
                self.evaluations += math.ceil(len(f) * self.grid_window_share)
                self.generation += 1
                self.grid_windowed = False
                self.grid_pending = window_best(self.grid_pending, f, D.STAGED_FIRST_RESTART_GRID_RESCORE)
                if self.grid_pending is None:
                    self._end_first_stage()
                return
            self._record(U, f)
            order = np.argsort(f, kind="stable")
            self.grid_starts = [[float(v) for v in self.grid_pending[i]] for i in order if np.isfinite(f[i])]
            self.grid_pending = None
            if self.grid_at_end:  # the second stage, from the best point of all (the grid's cells among them)
                self.grid_starts = []
                if self.grid_end_run > 0 and self._best_u is not None:
                    self._end_run()  # one more first-stage run from the best point of all, then the second stage
                else:
                    self._end_first_stage()
            else:
                self._next_run(self.children[-1])
            return
        c = self._current
        U = c.pending_unit
        if U is None:
            raise ClothFitError("tell() called without a pending ask()")
        staging = self._staging
        if staging:
            U = self._full_u(U)
        self._check_told(X, U)
        f = sanitize_fitness(f, len(U))
        A = np.asarray(X, dtype=np.float64)
        c.tell(A[:, self._idx] if staging else A, f)
        self._record(U, f)
        if self.racing:
            self._next_turn()
        if staging and not self.racing:
            c = self.children[-1]
            if c.stopped or self.evaluations >= max(self.first_fraction * self.budget, self.grid_end_until or 0):
                if self.grid_at_end and self.first_restart_grid is not None and not self.grid_done:
                    # the grid at the stage's end (first_restart_grid_at_end), through the stage's best point
                    self.grid_done, self.grid_windowed = True, self.grid_frames > 0
                    self.grid_pending = self._grid_batch(self._best_u[self._idx])
                else:
                    self._end_first_stage()
            elif self.evaluations < self.first_explore * self.budget and self.grid_end_until is None:
                if self._converged(c) or self._capped(c):
                    # another run from where the first began, with a new random stream: the first stage's
                    # runs settle early, each in one of a few basins (docs/search.md, "Runs again")
                    self._run_ended(c)
                    if self.first_best_run is None or c.best_f < float_from_json(self.first_best_run["best_f"]):
                        self.first_best_run = c.state_dict()
                    self.first_runs += 1
                    if self.first_restart_grid is not None and not (self.grid_done or self.grid_at_end):
                        # the grid first (first_restart_grid): the next run starts at its best cell
                        self.grid_done = True
                        self.grid_pending = self._grid_batch(self._subspace().encode(np.asarray(c.best_x)[None])[0])
                    else:
                        self._next_run(c)
            elif self.first_best_run is not None:
                # the runs are over: the one with the best point goes on, to the end of the first stage
                self._run_ended(c)
                if float_from_json(self.first_best_run["best_f"]) < c.best_f:
                    self.children[-1] = CMAES.from_state(self.first_best_run)
                self.first_best_run = None
        elif self._tail_due(c):
            self._start_tail()
        elif c.stopped:
            self._stopped = True

    @property
    def window(self) -> int | None:
        """The first training frames the batch asked for is to be scored on (``first_restart_grid_frames``), or
        None: on every frame."""
        return self.grid_frames if self.grid_windowed and self.grid_pending is not None else None

    def _grid_batch(self, u: np.ndarray) -> np.ndarray:
        """``first_restart_grid``: a point of the strong settings' cube (a converged run's best, or the stage's) on
        the grid (``grid_batch``)."""
        u = np.clip(u, 0.0, 1.0)
        a, b = (self.first.index(x) for x in self.first_restart_grid)
        return grid_batch(u, a, b, self.grid_points, near_offsets(self.grid_near, self.first))

    def _end_run(self) -> None:
        """``first_restart_grid_end_run``: after the grid at the stage's end, one more first-stage run (a start of
        ``looks``) from the best point of all, at the grid's step, for that share of the budget."""
        if self.first_runs > len(self.run_ends) and self.children:  # the last run, cut by the stage's end
            self._run_ended(self.children[-1])
        self.first_best_run = None
        self.first_runs += 1
        sub = self._subspace()
        start = sub.decode(self._best_u[self._idx][None])[0]
        self.children[-1] = self._child(sub, self.children[-1].popsize, self.grid_sigma, [start])
        self.grid_end_until = int(self.evaluations + self.grid_end_run * self.budget)

    def _next_run(self, c: CMAES) -> None:
        """Runs again: the next first-stage run, from the grid's best cell that no run has ended in yet
        (``first_restart_grid``), else where the first began (at another level of ``first_restart_vary``)."""
        sub = self._subspace()
        if self.grid_starts:
            left = starts_left(self.grid_starts, self.run_ends, self.first, self.first_restart_grid, self.grid_points)
            self.grid_starts = left[1:]
            if left:
                self.children[-1] = self._child(
                    sub, c.popsize, self.grid_sigma, [sub.decode(np.array(left[0])[None])[0]]
                )
                return
        init = None if self.first_init is None else [np.array(self.first_init)]
        if self.first_restart_vary is not None:  # this run at another level of that coordinate
            u = np.full(sub.n, 0.5) if init is None else sub.encode(init[0][None])[0]
            levels = self.first_restart_levels
            u[self.first.index(self.first_restart_vary)] = levels[(self.first_runs - 2) % len(levels)]
            init = [sub.decode(u[None])[0]]
        self.children[-1] = self._child(sub, c.popsize, self.sigma0, init)

    def _tail_due(self, c: CMAES) -> bool:
        """The second stage gives way to the warm tail: its run has stopped or the tail's share is reached
        (with ``warm_tail_stuck``, only if it has found nothing better than the first stage's best point; once
        past the tail's start it keeps checking, so a stage that stops unimproved later gives way then); with
        ``warm_tail_stall``, also as soon as it stalls (``_stalled``), stuck or not."""
        if self.stage != 2 or self.warm_tail <= 0 or len(self.first) >= self.space.n or self._best_u is None:
            return False
        if self._stalled():
            return True
        if not (c.stopped or self.evaluations >= (1.0 - self.warm_tail) * self.budget):
            return False
        # warm_tail_stuck: only where the second stage has not beaten the first stage's best point
        return not self.warm_tail_stuck or self.first_best_f is None or not self.best_f < self.first_best_f

    def _stalled(self) -> bool:
        """``warm_tail_stall``: the second stage has gained less than ``warm_tail_stall_gain`` of its best value
        over the last ``warm_tail_stall`` of the budget (measured in windows from the stage's start)."""
        if self.warm_tail_stall <= 0 or self.stall_mark is None:
            return False
        e0, f0 = self.stall_mark
        if self.evaluations - e0 < self.warm_tail_stall * self.budget:
            return False
        if not self.best_f < f0 - self.warm_tail_stall_gain * abs(f0):
            return True
        self.stall_mark = [int(self.evaluations), float(self.best_f)]
        return False

    STATE_KEYS = (
        "popsize",
        "sigma0",
        "second_sigma",
        "tolx",
        "tolfun",
        "active",
        "restarts",
        "first",
        "first_fraction",
        "budget",
        "hold_u",
        "tie",
        "race",
        "race_evals",
        "racing",
        "turn",
        "scan_points",
        "scan_left",
        "scanned",
        "scan_pending",
        "first_restart_step",
        "first_init",
        "first_runs",
        "first_explore",
        "first_run_cap",
        "first_best_run",
        "run_ends",
        "first_restart_vary",
        "first_restart_levels",
        *GRID_KEYS,
        "second_warm",
        "warm_tail",
        "warm_tail_stuck",
        "warm_tail_stall",
        "warm_tail_stall_gain",
        "stall_mark",
        "first_best_f",
        "stage",
        "stopped",
        "children",
        "rng",
        "initial_u",
    )

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update(
            {
                "popsize": self.popsize,
                "sigma0": self.sigma0,
                "second_sigma": self.second_sigma,
                "tolx": self.tolx,
                "tolfun": self.tolfun,
                "active": self.active,
                "restarts": self.restarts,
                "first": list(self.first),
                "first_fraction": self.first_fraction,
                "budget": self.budget,
                "hold_u": self.hold_u.tolist(),
                "tie": dict(self.tie),
                "race": self.race,
                "race_evals": self.race_evals,
                "racing": self.racing,
                "turn": self.turn,
                "scan_points": self.scan_points,
                "scan_left": list(self.scan_left),
                "scanned": self.scanned,
                "scan_pending": None if self._scan_pending is None else self._scan_pending.tolist(),
                "first_restart_step": self.first_restart_step,
                "first_init": self.first_init,
                "first_runs": self.first_runs,
                "first_explore": self.first_explore,
                "first_run_cap": self.first_run_cap,
                "first_best_run": self.first_best_run,
                "run_ends": [[float_to_json(f), list(u)] for f, u in self.run_ends],
                "first_restart_vary": self.first_restart_vary,
                "first_restart_levels": list(self.first_restart_levels),
                **grid_state(self),
                "second_warm": self.second_warm,
                "warm_tail": self.warm_tail,
                "warm_tail_stuck": self.warm_tail_stuck,
                "warm_tail_stall": self.warm_tail_stall,
                "warm_tail_stall_gain": self.warm_tail_stall_gain,
                "stall_mark": None
                if self.stall_mark is None
                else [self.stall_mark[0], float_to_json(self.stall_mark[1])],
                "first_best_f": None if self.first_best_f is None else float_to_json(self.first_best_f),
                "stage": self.stage,
                "stopped": self._stopped,
                "children": [c.state_dict() for c in self.children],
                "rng": self.rng.bit_generator.state,
                "initial_u": self._initial_u.tolist(),
            }
        )
        return d

    def _restore_runs_again(self, d: dict, w: str) -> None:
        """from_state's part for runs again in the first stage (its fields, checked; older checkpoints: one run)."""
        # runs again in the first stage came after the scan: one run (none again) in older checkpoints
        self.first_restart_step = (
            saved_value(d, "first_restart_step", w, float, 0.0, 1.0) if "first_restart_step" in d else 0.0
        )
        self.first_runs = saved_value(d, "first_runs", w, int, 1, 10**9) if "first_runs" in d else 1
        init = saved_array(d, "first_init", w, (len(self.first),), allow_none=True) if "first_init" in d else None
        self.first_init = None if init is None else init.tolist()
        self.first_explore = saved_value(d, "first_explore", w, float, 0.0, 1.0) if "first_explore" in d else 0.0
        # the run cap came after the line: none (a run ends only when it settles) in older checkpoints
        self.first_run_cap = saved_value(d, "first_run_cap", w, float, 0.0, 1.0) if "first_run_cap" in d else 0.0
        kept = d.get("first_best_run")
        if kept is not None:
            if not isinstance(kept, dict) or kept.get("algorithm") != "cma-es":
                raise ClothFitError(f"checkpoint: {w} 'first_best_run' must be null or a CMA-ES state")
            if CMAES.from_state(kept).space.state_dict() != self._subspace().state_dict():
                raise ClothFitError(f"checkpoint: {w} 'first_best_run' holds a run of another search space")
        self.first_best_run = kept
        # the runs' ends came after runs again: none kept in older checkpoints
        ends = d.get("run_ends", [])
        k = len(self.first)
        if not isinstance(ends, list) or len(ends) > self.first_runs or not all(is_run_end(e, k) for e in ends):
            raise ClothFitError(f"checkpoint: {w} 'run_ends' must list [value, {k} numbers in [0, 1]] per run")
        self.run_ends = [[float_from_json(e[0]), [float(v) for v in e[1]]] for e in ends]
        # runs again at other levels of a coordinate came after the stall rule: all where the first began before
        self.first_restart_vary, self.first_restart_levels = restart_levels(
            d.get("first_restart_vary"),
            d.get("first_restart_levels", D.STAGED_FIRST_RESTART_LEVELS),
            self.first,
            f"checkpoint: {w}",
        )
        # the grid before runs again came after the runs' ends: none in older checkpoints
        vars(self).update(restore_grid(d, self.first, w))

    @classmethod
    def from_state(cls, d: dict) -> StagedCMA:
        w = cls.name
        space = cls._check_state(d, w, cls.STATE_KEYS)
        n = space.n
        opt = cls.__new__(cls)
        Optimizer.__init__(opt, space, d["seed"], None)
        opt.popsize = saved_value(d, "popsize", w, int, 2, 10**6)
        opt.sigma0 = saved_step(d, "sigma0", w)
        opt.second_sigma = saved_step(d, "second_sigma", w)
        opt.tolx = saved_value(d, "tolx", w, float, 0.0)
        opt.tolfun = saved_value(d, "tolfun", w, float, 0.0)
        opt.active = saved_active(d, w)
        opt.restarts = saved_value(d, "restarts", w, int, 0, 100)
        first = saved_field(d, "first", w)
        if (
            not isinstance(first, list)
            or not first
            or any(not isinstance(x, str) or x not in space.names for x in first)
            or first != [x for x in space.names if x in set(first)]
        ):
            raise ClothFitError(f"checkpoint: {w} 'first' must list coordinates of the search in order")
        opt.first = list(first)
        opt.first_fraction = saved_value(d, "first_fraction", w, float, 0.0, 1.0)
        opt.budget = saved_value(d, "budget", w, int, 1, 10**12)
        opt._load_base(d)
        opt.hold_u = saved_array(d, "hold_u", w, (n,))
        if np.any(opt.hold_u < 0.0) or np.any(opt.hold_u > 1.0):
            raise ClothFitError(f"checkpoint: {w} 'hold_u' must lie in the unit cube")
        # 'tie' came after the first checkpoints of this search: none there
        opt.tie = checked_tie(d.get("tie", {}), list(space.names), opt.first, f"checkpoint: {w}")
        opt.stage = saved_value(d, "stage", w, int, 1, 3)
        opt._stopped = saved_bool(d, "stopped", w)
        # the race came after the first checkpoints of this search: none there
        opt.race = saved_value(d, "race", w, int, 1, 100) if "race" in d else 1
        opt.race_evals = saved_value(d, "race_evals", w, int, 1, 10**12) if "race_evals" in d else D.STAGED_RACE_EVALS
        opt.racing = saved_bool(d, "racing", w) if "racing" in d else False
        kids = saved_field(d, "children", w)
        n_kids = opt.race if opt.racing else opt.stage
        if (
            (opt.racing and opt.stage != 1)
            or not isinstance(kids, list)
            or len(kids) != n_kids
            or any(not isinstance(k, dict) for k in kids)
        ):
            raise ClothFitError(f"checkpoint: {w} 'children' must hold one CMA-ES state per stage (per run racing)")
        opt.turn = saved_value(d, "turn", w, int, 0, len(kids) - 1) if "turn" in d else 0
        # the scan between the stages came after the race: none in older checkpoints
        opt.scan_points = saved_value(d, "scan_points", w, int, 0, 10000) if "scan_points" in d else 0
        opt.scanned = saved_bool(d, "scanned", w) if "scanned" in d else False
        left = d.get("scan_left", [])
        if (
            not isinstance(left, list)
            or any(x not in opt.first for x in left)
            or (left and (opt.stage != 1 or not opt.scanned or opt.racing))
        ):
            raise ClothFitError(f"checkpoint: {w} 'scan_left' must list first-stage coordinates, while scanning")
        opt.scan_left = list(left)
        opt._scan_pending = (
            saved_array(d, "scan_pending", w, (opt.scan_points, n), allow_none=True) if "scan_pending" in d else None
        )
        if opt._scan_pending is not None and not opt.scan_left:
            raise ClothFitError(f"checkpoint: {w} 'scan_pending' without a scan under way")
        opt._restore_runs_again(d, w)
        # the warm second stage came after runs again: a plain one in older checkpoints
        opt.second_warm = saved_bool(d, "second_warm", w) if "second_warm" in d else False
        opt.warm_tail = saved_value(d, "warm_tail", w, float, 0.0, 1.0) if "warm_tail" in d else 0.0
        opt.warm_tail_stuck = saved_bool(d, "warm_tail_stuck", w) if "warm_tail_stuck" in d else False
        # the stalled second stage came after the stuck one: none in older checkpoints
        opt.warm_tail_stall = saved_value(d, "warm_tail_stall", w, float, 0.0, 1.0) if "warm_tail_stall" in d else 0.0
        opt.warm_tail_stall_gain = (
            saved_value(d, "warm_tail_stall_gain", w, float, 0.0, 1.0)
            if "warm_tail_stall_gain" in d
            else D.STAGED_WARM_TAIL_STALL_GAIN
        )
        mark = d.get("stall_mark")
        if mark is not None and (
            not isinstance(mark, list)
            or len(mark) != 2
            or isinstance(mark[0], bool)
            or not isinstance(mark[0], int)
            or not 0 <= mark[0] <= opt.evaluations
            or isinstance(mark[1], bool)
            or not isinstance(mark[1], (int, float, str))
        ):
            raise ClothFitError(f"checkpoint: {w} 'stall_mark' must be null or [evaluations, value]")
        opt.stall_mark = None if mark is None or opt.stage != 2 else [mark[0], float_from_json(mark[1])]
        fb = d.get("first_best_f")
        if fb is not None and (isinstance(fb, bool) or not isinstance(fb, (int, float))):
            raise ClothFitError(f"checkpoint: {w} 'first_best_f' must be a number or null")
        # null: no first stage ended yet, or (past it) a first stage without a finite value
        opt.first_best_f = float_from_json(fb) if opt.stage >= 2 and "first_best_f" in d else None
        opt.children = []
        for i, k in enumerate(kids):
            if k.get("algorithm") != "cma-es":
                raise ClothFitError(f"checkpoint: {w} 'children' hold a state of the wrong algorithm")
            c = CMAES.from_state(k)
            want = opt._subspace() if (opt.stage == 1 or i == 0) and len(opt.first) < n else space
            if c.space.state_dict() != want.state_dict():
                raise ClothFitError(f"checkpoint: {w} 'children' hold a run of another search space")
            if c.stop_reason is not None and c.stop_reason not in CMA_STOPS:
                raise ClothFitError(f"checkpoint: {w} 'children' hold an unknown stop criterion")
            opt.children.append(c)
        opt.rng = rng_state_from_json(saved_field(d, "rng", w), w)
        opt._initial_u = saved_array(d, "initial_u", w, (None, n))
        return opt
