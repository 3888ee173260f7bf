"""The steppable ask/tell interface every optimiser shares: counters, best so far, history,
the run loop and the common part of a checkpoint.

-------
``history`` is the best-so-far curve as ``(evaluations, best_f)`` steps: a point where the best
changes, and one at the end of every run of equal bests (so its size grows with the number of
improvements, not of generations). Its last point is always the current one.

Checkpoints
-----------
``state_dict()`` returns a JSON-serialisable dict of plain numbers (strict JSON: no NaN /
Infinity; an infinite fitness is stored as ``None``), and ``from_state(d)`` (or
:func:`optimizer_from_state`) resumes exactly: a run checkpointed after any ``tell`` (or even
between ``ask`` and ``tell``) and resumed produces the very same candidates as the
uninterrupted run. SPX + MGG: population, fitnesses, pending children, counters. CMA-ES: mean,
step size, covariance matrix (its eigendecomposition is recomputed, deterministically), the
evolution paths, counters, the restart state. Both: the PCG64 state as integers. Nothing is
unpickled or executed: ``from_state`` checks every field (known keys only, types, shapes,
finiteness, ranges, a symmetric positive-definite covariance) and raises a one-line
:class:`ClothFitError` naming the field at fault.
"""

from __future__ import annotations

import copy
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ClothFitError
from .space import (
    SearchSpace,
    check_keys,
    float_from_json,
    float_to_json,
    new_rng,
    saved_array,
    saved_field,
    saved_value,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from numpy.typing import ArrayLike

STATE_VERSION = 2


class Optimizer:
    """Common steppable ask/tell machinery: counters, best-so-far, history, run loop, state."""

    name = "optimizer"
    window: int | None = None  # the batch asked for is scored on the first this many training frames (None: all)

    def __init__(self, space: SearchSpace, seed=None, initial=None):
        if not isinstance(space, SearchSpace):
            raise ClothFitError(f"optimizer: expected a SearchSpace, got {type(space).__name__}")
        self.space = space
        self.seed = None if seed is None else int(seed)
        self.rng = new_rng(self.seed)
        self.evaluations = 0
        self.generation = 0
        self.history: list = []
        self.best_f = math.inf
        self._best_u = None
        self._initial_u = self._encode_initial(initial)

    # -- initial guesses
    def _encode_initial(self, initial):
        if initial is None:
            return np.zeros((0, self.space.n))
        rows = []
        for i, x in enumerate(initial):
            if isinstance(x, dict):
                x = self.space.from_dict(x)
            try:
                rows.append(self.space.encode(np.asarray(x, dtype=np.float64).reshape(self.space.n)))
            except (ValueError, TypeError) as exc:
                raise ClothFitError(
                    f"initial guess #{i}: expected {self.space.n} values for {self.space.names}, got {x!r}"
                ) from exc
        if not rows:
            return np.zeros((0, self.space.n))
        return np.clip(np.array(rows), 0.0, 1.0)  # guesses outside the bounds are clipped

    # -- best so far
    @property
    def best_x(self) -> np.ndarray | None:
        """Best real-space vector (n,) told so far, None before any finite value."""
        return None if self._best_u is None else self.space.decode(self._best_u)

    @property
    def best_params(self) -> dict[str, float] | None:
        """``best_x`` as {name: value}, None before any finite value."""
        return None if self._best_u is None else self.space.to_dict(self.best_x)

    def looks(self) -> dict | None:
        """How many independent starts the search made and how many ended in the basin of the best one
        (``StagedCMA``'s runs again), or None where it does not make several."""
        return None

    @property
    def stopped(self) -> bool:
        """True when the algorithm itself has nothing more to do (never for SPX + MGG)."""
        return False

    def _record(self, U, f):
        """Update counters, best-so-far and history after a tell of unit-cube rows U."""
        self.evaluations += len(f)
        self.generation += 1
        if len(f):
            i = int(np.argmin(f))
            if math.isfinite(f[i]) and f[i] < self.best_f:
                self.best_f = float(f[i])
                self._best_u = np.array(U[i], dtype=np.float64)
        h = self.history
        if len(h) >= 2 and h[-1][1] == self.best_f and h[-2][1] == self.best_f:
            h[-1] = (self.evaluations, self.best_f)  # a run of equal bests: move its end
        else:
            h.append((self.evaluations, self.best_f))

    def _check_told(self, X, pending_u):
        if pending_u is None:
            raise ClothFitError("tell() called without a pending ask()")
        try:
            A = np.asarray(X, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ClothFitError("tell(): X must be the array returned by ask()") from exc
        expected = self.space.decode(pending_u)
        if A.shape != expected.shape or not np.allclose(A, expected, rtol=1e-9, atol=0.0, equal_nan=True):
            raise ClothFitError(
                f"tell(): X (shape {A.shape}) is not the batch returned by the last ask() (shape {expected.shape})"
            )

    # -- to implement
    def ask(self) -> np.ndarray:
        raise NotImplementedError

    def tell(self, X: ArrayLike, f: ArrayLike) -> None:
        raise NotImplementedError

    # -- driving
    def step(self, fn: Callable[[np.ndarray], ArrayLike]) -> float:
        """One generation: ``X = ask(); f = fn(X); tell(X, f)``; returns ``best_f``."""
        X = self.ask()
        f = fn(X)
        self.tell(X, f)
        return self.best_f

    def run(
        self,
        fn: Callable[[np.ndarray], ArrayLike],
        max_evaluations: int,
        target: float | None = None,
        callback: Callable[[Optimizer], Any] | None = None,
    ) -> tuple[np.ndarray | None, float]:
        """Step until ``evaluations >= max_evaluations`` (a total, so a resumed run continues
        to the same budget; the last generation may overshoot it), ``best_f <= target``, the
        algorithm stops itself, or ``callback(self)`` returns True. Returns (best_x, best_f)."""
        max_evaluations = int(max_evaluations)
        while self.evaluations < max_evaluations and not self.stopped:
            if target is not None and self.best_f <= target:
                break
            self.step(fn)
            if callback is not None and callback(self):
                break
        return self.best_x, self.best_f

    # -- checkpoints
    def _base_state(self) -> dict:
        return {
            "algorithm": self.name,
            "version": STATE_VERSION,
            "space": self.space.state_dict(),
            "seed": self.seed,
            "evaluations": int(self.evaluations),
            "generation": int(self.generation),
            "history": [[int(e), float_to_json(b)] for e, b in self.history],
            "best_f": float_to_json(self.best_f),
            "best_u": None if self._best_u is None else self._best_u.tolist(),
            "best_x": None if self._best_u is None else self.best_x.tolist(),
        }

    BASE_KEYS = (
        "algorithm",
        "version",
        "space",
        "seed",
        "evaluations",
        "generation",
        "history",
        "best_f",
        "best_u",
        "best_x",
    )

    def _load_base(self, d: dict):
        w = self.name
        self.evaluations = saved_value(d, "evaluations", w, int, 0, 10**12)
        self.generation = saved_value(d, "generation", w, int, 0, 10**12)
        hist = saved_field(d, "history", w)
        if not isinstance(hist, list) or len(hist) > 10**6:
            raise ClothFitError(f"checkpoint: {w} 'history' must be a list of [evaluations, best] pairs")
        out = []
        for item in hist:
            if (
                not isinstance(item, list)
                or len(item) != 2
                or isinstance(item[0], bool)
                or not isinstance(item[0], int)
                or not (
                    item[1] is None
                    or (isinstance(item[1], (int, float)) and not isinstance(item[1], bool) and math.isfinite(item[1]))
                )
            ):
                raise ClothFitError(f"checkpoint: {w} 'history' must be a list of [evaluations, best] pairs")
            out.append((int(item[0]), float_from_json(item[1])))
        self.history = out
        bf = saved_value(d, "best_f", w, float, allow_none=True)
        self.best_f = math.inf if bf is None else bf
        bu = saved_array(d, "best_u", w, (self.space.n,), allow_none=True)
        if (bu is None) != (bf is None):
            raise ClothFitError(f"checkpoint: {w} 'best_f' and 'best_u' must be both set or both null")
        self._best_u = bu

    @staticmethod
    def _check_state(d, name, keys=()):
        if not isinstance(d, dict) or d.get("algorithm") != name:
            got = d.get("algorithm") if isinstance(d, dict) else type(d).__name__
            raise ClothFitError(f"checkpoint: expected an '{name}' optimiser state, got {got!r}")
        if d.get("version") != STATE_VERSION:
            raise ClothFitError(
                f"checkpoint: unsupported {name} state version {d.get('version')!r} "
                f"(this version reads {STATE_VERSION})"
            )
        check_keys(d, Optimizer.BASE_KEYS + tuple(keys), name)
        seed = saved_field(d, "seed", name)
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
            raise ClothFitError(f"checkpoint: {name} 'seed' must be a non-negative integer or null")
        return SearchSpace.from_state(saved_field(d, "space", name))

    def state_dict(self) -> dict:
        raise NotImplementedError

    @classmethod
    def from_state(cls, d: dict) -> Optimizer:
        from .optimise import (
            optimizer_from_state,  # the registry of every optimiser (imports this module)
        )

        return optimizer_from_state(d)


def ask_within(opt: Optimizer, left: int) -> tuple[Optimizer, np.ndarray, bool]:
    """The next batch of ``opt`` within ``left`` evaluations: ``(opt, X, True)`` when the whole batch
    fits (tell ``opt`` its values as usual); else ``(opt as before the ask, X cut to its first
    ``left`` rows, False)``: candidates to score for the best so far only, never told, so that an
    optimiser continued later (a resume with a larger budget) asks the very same batch again."""
    before = copy.deepcopy(opt)
    X = opt.ask()
    if len(X) <= left:
        return opt, X, True
    return before, X[: max(0, int(left))], False
