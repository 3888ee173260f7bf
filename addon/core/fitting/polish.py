"""Coordinate polish ("coord-polish"): a batch coordinate pattern search with a step per coordinate."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ClothFitError
from .space import (
    SearchSpace,
    checked_number,
    float_from_json,
    float_to_json,
    reflect_unit,
    sanitize_fitness,
    saved_array,
    saved_bool,
    saved_stop_reason,
    saved_value,
)
from .steppable import Optimizer

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


class CoordinatePolish(Optimizer):
    """A batch coordinate pattern search from one point, with a step per coordinate.

    Each generation asks ``2 n`` probes ``x +- s_i e_i`` (reflected into the unit cube), plus the
    *pattern* probe (the last generation's improving coordinate moves all at once) when there is
    one. ``tell`` moves ``x`` to the best probe if it beats ``f(x)``; a coordinate whose probe
    beat ``f(x)`` doubles its step (up to ``max_step``), the others halve it. So a coordinate on a
    knife edge soon takes tiny steps while a flat, weakly identified one keeps large ones: what a
    single CMA-ES step size cannot do before its covariance has learnt the scales. Deterministic (no
    random numbers); stops (``tolx``) when every step is below ``tolx``.
    """

    name = "coord-polish"

    def __init__(
        self,
        space: SearchSpace,
        seed=None,
        initial=None,
        f0=None,
        step: float = 0.05,
        max_step: float = 0.3,
        tolx: float = 1e-11,
    ):
        super().__init__(space, seed, initial)
        self.step0 = checked_number(step, "coord-polish: step (unit cube)", 0.0, 10.0, lo_open=True)
        self.max_step = checked_number(max_step, "coord-polish: max_step (unit cube)", 0.0, 10.0, lo_open=True)
        self.tolx = checked_number(tolx, "coord-polish: tolx")
        n = space.n
        self.x = self._initial_u[0].copy() if len(self._initial_u) else np.full(n, 0.5)
        self.fx = math.inf if f0 is None else float(f0)
        if not (self.fx == math.inf or math.isfinite(self.fx)):
            raise ClothFitError(f"coord-polish: f0 must be a number, got {f0!r}")
        if math.isfinite(self.fx):
            self.best_f, self._best_u = self.fx, self.x.copy()
        self.steps = np.full(n, self.step0)
        self.pattern = None  # the next pattern probe (unit cube), or None
        self._pending = None
        self.stop_reason = None
        self._stopped = False

    @property
    def stopped(self) -> bool:
        return self._stopped

    def _probes(self):
        n = self.space.n
        P = np.repeat(self.x[None], 2 * n + (0 if math.isfinite(self.fx) else 1), axis=0)
        for i in range(n):
            P[2 * i, i] += self.steps[i]
            P[2 * i + 1, i] -= self.steps[i]
        if self.pattern is not None:
            P = np.vstack([P, self.pattern[None]])
        return reflect_unit(P)

    def ask(self) -> np.ndarray:
        if self._pending is None:
            self._pending = self._probes()
        return self.space.decode(self._pending)

    def tell(self, X: ArrayLike, f: ArrayLike) -> None:
        P = self._pending
        self._check_told(X, P)
        f = sanitize_fitness(f, len(P))
        n = self.space.n
        if not math.isfinite(self.fx):
            self.fx = float(f[2 * n])  # x itself was evaluated (no f0 given)
        better = np.array([min(f[2 * i], f[2 * i + 1]) < self.fx for i in range(n)])
        move = np.zeros(n)
        for i in np.nonzero(better)[0]:
            j = 2 * i if f[2 * i] <= f[2 * i + 1] else 2 * i + 1
            move[i] = P[j, i] - self.x[i]
        self.steps = np.where(better, np.minimum(2 * self.steps, self.max_step), 0.5 * self.steps)
        k = int(np.argmin(f))
        old = self.x.copy()
        if f[k] < self.fx:
            self.x, self.fx = P[k].copy(), float(f[k])
        self.pattern = reflect_unit(old + move) if better.sum() >= 2 else None
        self._pending = None
        self._record(P, f)
        if np.all(self.steps < self.tolx):
            self._stopped, self.stop_reason = True, "tolx"

    STATE_KEYS = (
        "step0",
        "max_step",
        "tolx",
        "x",
        "fx",
        "steps",
        "pattern",
        "pending",
        "stop_reason",
        "stopped",
        "initial_u",
    )

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update(
            {
                "step0": self.step0,
                "max_step": self.max_step,
                "tolx": self.tolx,
                "x": self.x.tolist(),
                "fx": float_to_json(self.fx),
                "steps": self.steps.tolist(),
                "pattern": None if self.pattern is None else self.pattern.tolist(),
                "pending": None if self._pending is None else self._pending.tolist(),
                "stop_reason": self.stop_reason,
                "stopped": self._stopped,
                "initial_u": self._initial_u.tolist(),
            }
        )
        return d

    @classmethod
    def from_state(cls, d: dict) -> CoordinatePolish:
        w = cls.name
        space = cls._check_state(d, w, cls.STATE_KEYS)
        n = space.n
        opt = cls(
            space,
            seed=d["seed"],
            step=saved_value(d, "step0", w, float),
            max_step=saved_value(d, "max_step", w, float),
            tolx=saved_value(d, "tolx", w, float, 0.0),
        )
        opt._load_base(d)
        opt._initial_u = saved_array(d, "initial_u", w, (None, n))
        opt.x = saved_array(d, "x", w, (n,))
        if opt.x.min() < 0 or opt.x.max() > 1:
            raise ClothFitError(f"checkpoint: {w} 'x' must lie in the unit cube")
        opt.fx = float_from_json(saved_value(d, "fx", w, float, allow_none=True))
        opt.steps = saved_array(d, "steps", w, (n,))
        if opt.steps.min() < 0 or opt.steps.max() > opt.max_step:
            raise ClothFitError(f"checkpoint: {w} 'steps' must lie in [0, max_step]")
        opt.pattern = saved_array(d, "pattern", w, (n,), allow_none=True)
        opt._pending = saved_array(d, "pending", w, (None, n), allow_none=True)
        if opt._pending is not None and (opt._pending.min() < 0 or opt._pending.max() > 1):
            raise ClothFitError(f"checkpoint: {w} 'pending' must lie in the unit cube")
        opt.stop_reason = saved_stop_reason(d, w, ("tolx",))
        opt._stopped = saved_bool(d, "stopped", w)
        return opt
