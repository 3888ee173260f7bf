"""SPX + MGG: the paper's real-coded GA (refs [13] [14], docs/method.md#spec-7) as a steppable optimiser.

* Simplex crossover (Tsutsui et al.): ``n + 1`` parents ``x_0..x_n`` drawn at random without
  replacement from the population, centroid ``G``, expanded vertices
  ``y_k = G + eps (x_k - G)`` with ``eps = sqrt(n + 2)``; with ``r_j = u_j^(1/(j+1))``
  (``u_j`` uniform in (0, 1)), ``C_0 = 0``, ``C_k = r_(k-1) (y_(k-1) - y_k + C_(k-1))``,
  child ``= y_n + C_n``. A child is uniform in the expanded simplex, whose mean is ``G``.
* Minimal generation gap (Satoh, Ono, Kobayashi): two of the ``n + 1`` parents, picked at
  random, are the ones to be replaced. The family is the children plus those two parents; the
  best of the family and one more chosen by rank-based roulette (linear ranking: the i-th best
  of the remaining ``m`` members has weight ``m - i``) replace the two. The population size is
  therefore constant and its best value never worsens.
* The expanded simplex may stick out of the unit cube: such children are *reflected* back
  coordinate-wise at the faces (a triangle wave, ``v mod 2`` folded at 1, valid for any
  distance), which keeps the search near a boundary optimum unbiased better than clipping.
* The first ``ask()`` returns the whole initial population (uniform in the unit cube, its first
  rows replaced by the optional ``initial`` guesses); each later ``ask()`` returns one family's
  children (``D.GA_CHILDREN`` by default). One ``tell`` = one generation.

SPX + MGG stops when its population has collapsed (spread below ``tolx`` in every unit-cube
coordinate) or when the best value has not improved by more than ``tolfun`` during the last
``stall_evaluations`` evaluations (both off unless set).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .space import (
    SearchSpace,
    checked_integer,
    checked_number,
    float_to_json,
    reflect_unit,
    rng_state_from_json,
    sanitize_fitness,
    saved_array,
    saved_field,
    saved_stop_reason,
    saved_value,
)
from .steppable import Optimizer

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


def spx_children(parents: np.ndarray, n_children: int, eps: float, rng: np.random.Generator) -> np.ndarray:
    """Tsutsui's simplex crossover: (n_children, dim) children of ``parents`` (m, dim).

    Children are uniform in the simplex of the ``m`` parents expanded by ``eps`` about their
    centroid; nothing is clipped or reflected here.
    """
    P = np.asarray(parents, dtype=np.float64)
    m = P.shape[0]
    G = P.mean(axis=0)
    Y = G + eps * (P - G)  # (m, dim) expanded vertices y_0..y_{m-1}
    u = rng.random((n_children, m - 1))
    r = u ** (1.0 / np.arange(1, m))  # r_j = u_j^(1/(j+1)), j = 0..m-2
    C = np.zeros((n_children, P.shape[1]))
    for k in range(1, m):
        C = r[:, k - 1 : k] * (Y[k - 1] - Y[k] + C)
    return Y[m - 1] + C


class SPXMGG(Optimizer):
    """Real-coded GA: simplex crossover (SPX) with the minimal generation gap (MGG) model."""

    name = "spx-mgg"

    def __init__(
        self,
        space: SearchSpace,
        seed=None,
        initial=None,
        population: int | None = None,
        children: int | None = None,
        eps: float | None = None,
        tolx: float = 0.0,
        tolfun: float = 0.0,
        stall_evaluations: int | None = None,
    ):
        super().__init__(space, seed, initial)
        n = space.n
        self.population = checked_integer(D.GA_POPULATION if population is None else population, "spx-mgg: population")
        self.children = checked_integer(D.GA_CHILDREN if children is None else children, "spx-mgg: children")
        self.eps = float(math.sqrt(n + 2) if eps is None else eps)
        self.tolx = checked_number(tolx, "spx-mgg: tolx")
        self.tolfun = checked_number(tolfun, "spx-mgg: tolfun")
        self.stall_evaluations = (
            None if stall_evaluations is None else checked_integer(stall_evaluations, "spx-mgg: stall_evaluations")
        )
        self._ref_best = math.inf  # best at the last improvement by more than tolfun
        self._last_improved = 0  # evaluations then
        self.stop_reason = None
        if self.population < n + 1:
            raise ClothFitError(f"spx-mgg: population must be at least n + 1 = {n + 1}, got {self.population}")
        if self.children < 1:
            raise ClothFitError(f"spx-mgg: children must be >= 1, got {self.children}")
        if not (math.isfinite(self.eps) and self.eps > 0):
            raise ClothFitError(f"spx-mgg: eps must be a positive number, got {self.eps}")
        if len(self._initial_u) > self.population:
            raise ClothFitError(
                f"spx-mgg: {len(self._initial_u)} initial guesses do not fit in a population of {self.population}"
            )
        self.pop_u = None  # (P, n) unit-cube population, None until initialised
        self.pop_f = None  # (P,) fitness (+inf = bad)
        self._pending = None  # (B, n) unit-cube candidates asked but not told
        self._replace = None  # (2,) population slots replaced by the pending family

    @property
    def population_x(self) -> np.ndarray | None:
        """Current population in real space (P, n), None before the first ask()."""
        return None if self.pop_u is None else self.space.decode(self.pop_u)

    def ask(self) -> np.ndarray:
        """Candidates (B, n) in real space; asking again before tell() returns the same batch."""
        if self._pending is None:
            n = self.space.n
            if self.pop_u is None:
                U = self.rng.random((self.population, n))
                U[: len(self._initial_u)] = self._initial_u
                self._pending, self._replace = U, None
            else:
                idx = self.rng.choice(self.population, size=n + 1, replace=False)
                self._replace = idx[self.rng.choice(n + 1, size=2, replace=False)]
                kids = spx_children(self.pop_u[idx], self.children, self.eps, self.rng)
                self._pending = reflect_unit(kids)
        return self.space.decode(self._pending)

    def tell(self, X: ArrayLike, f: ArrayLike) -> None:
        self._check_told(X, self._pending)
        U = self._pending
        f = sanitize_fitness(f, len(U))
        if self.pop_u is None:
            self.pop_u, self.pop_f = U.copy(), f.copy()
        else:
            slots = self._replace
            fam_u = np.vstack([U, self.pop_u[slots]])
            fam_f = np.concatenate([f, self.pop_f[slots]])
            order = np.argsort(fam_f, kind="stable")
            best, rest = order[0], order[1:]
            w = np.arange(len(rest), 0, -1, dtype=np.float64)  # linear ranking: m, m-1, ..., 1
            other = rest[self.rng.choice(len(rest), p=w / w.sum())]
            new_u, new_f = fam_u[[best, other]], fam_f[[best, other]]
            self.pop_u[slots] = new_u
            self.pop_f[slots] = new_f
        self._pending, self._replace = None, None
        self._record(U, f)
        if self.best_f < self._ref_best - self.tolfun:
            self._ref_best, self._last_improved = self.best_f, self.evaluations
        self.stop_reason = self._check_stop()

    def _check_stop(self):
        if self.pop_u is None:
            return None
        ok = np.isfinite(self.pop_f)
        if self.tolx > 0 and ok.sum() >= 2:
            spread = np.ptp(self.pop_u[ok], axis=0)
            if np.all(spread < self.tolx):
                return "tolx"
        if self.stall_evaluations is not None and self.evaluations - self._last_improved >= self.stall_evaluations:
            return "stagnation"
        return None

    @property
    def stopped(self) -> bool:
        return self.stop_reason is not None

    STATE_KEYS = (
        "population",
        "children",
        "eps",
        "tolx",
        "tolfun",
        "stall_evaluations",
        "ref_best",
        "last_improved",
        "stop_reason",
        "rng",
        "initial_u",
        "pop_u",
        "pop_f",
        "pending_u",
        "replace",
    )

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update(
            {
                "population": self.population,
                "children": self.children,
                "eps": self.eps,
                "tolx": self.tolx,
                "tolfun": self.tolfun,
                "stall_evaluations": self.stall_evaluations,
                "ref_best": float_to_json(self._ref_best),
                "last_improved": int(self._last_improved),
                "stop_reason": self.stop_reason,
                "rng": self.rng.bit_generator.state,
                "initial_u": self._initial_u.tolist(),
                "pop_u": None if self.pop_u is None else self.pop_u.tolist(),
                "pop_f": None if self.pop_f is None else [float_to_json(v) for v in self.pop_f],
                "pending_u": None if self._pending is None else self._pending.tolist(),
                "replace": None if self._replace is None else [int(i) for i in self._replace],
            }
        )
        return d

    @classmethod
    def from_state(cls, d: dict) -> SPXMGG:
        w = cls.name
        space = cls._check_state(d, w, cls.STATE_KEYS)
        n = space.n
        stall = saved_value(d, "stall_evaluations", w, int, 1, 10**12, allow_none=True)
        opt = cls(
            space,
            seed=d["seed"],
            population=saved_value(d, "population", w, int, n + 1, 10**6),
            children=saved_value(d, "children", w, int, 1, 10**6),
            eps=saved_value(d, "eps", w, float, 1e-12, 1e6),
            tolx=saved_value(d, "tolx", w, float, 0.0),
            tolfun=saved_value(d, "tolfun", w, float, 0.0),
            stall_evaluations=stall,
        )
        opt._load_base(d)
        rb = saved_value(d, "ref_best", w, float, allow_none=True)
        opt._ref_best = math.inf if rb is None else rb
        opt._last_improved = saved_value(d, "last_improved", w, int, 0, opt.evaluations)
        opt.stop_reason = saved_stop_reason(d, w, ("tolx", "stagnation"))
        opt.rng = rng_state_from_json(saved_field(d, "rng", w), w)
        opt._initial_u = saved_array(d, "initial_u", w, (None, n))
        if len(opt._initial_u) > opt.population:
            raise ClothFitError(f"checkpoint: {w} has more initial guesses than its population")
        opt.pop_u = saved_array(d, "pop_u", w, (opt.population, n), allow_none=True)
        pop_f = saved_array(d, "pop_f", w, (opt.population,), allow_none=True, inf_as_none=True)
        if (opt.pop_u is None) != (pop_f is None):
            raise ClothFitError(f"checkpoint: {w} 'pop_u' and 'pop_f' must be both set or both null")
        opt.pop_f = pop_f
        rows = opt.population if opt.pop_u is None else opt.children
        opt._pending = saved_array(d, "pending_u", w, (rows, n), allow_none=True)
        rep = saved_field(d, "replace", w)
        if opt._pending is not None and opt.pop_u is not None:
            if (
                not isinstance(rep, list)
                or len(rep) != 2
                or len(set(map(repr, rep))) != 2
                or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < opt.population for i in rep)
            ):
                raise ClothFitError(f"checkpoint: {w} 'replace' must be two distinct population slots")
            opt._replace = np.array(rep, dtype=np.int64)
        elif rep is not None:
            raise ClothFitError(f"checkpoint: {w} 'replace' must be null without a pending family")
        return opt
