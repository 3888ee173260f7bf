"""Black-box minimisers of the silhouette error: SPX + MGG (the paper's GA) and CMA-ES.

Both optimisers share one *steppable* ask/tell interface, so that the CLI can loop, and a
Blender modal operator can do one generation per timer event and checkpoint in between::

    opt = make_optimizer("spx-mgg", space, seed=1)
    while opt.evaluations < budget:
        X = opt.ask()            # (B, n) candidates, REAL parameter values (decoded)
        f = objective(X)         # (B,) values to MINIMISE; inf / nan allowed
        opt.tell(X, f)
    opt.best_x, opt.best_f       # or simply opt.run(objective, budget)

Encoding
--------
:class:`SearchSpace` maps each parameter to ``[0, 1]``: linearly between its bounds, or
linearly in ``log(x)`` for a log-scaled (scale) parameter, whose bounds must then be > 0.
The optimisers work only in this unit cube, ``ask`` returns decoded real values, and
``decode`` clips to the bounds, so a candidate can never leave them.

SPX + MGG (real-coded GA, paper refs [13] [14], SPEC 7)
--------------------------------------------------------
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

CMA-ES
------
:class:`CMAES` is this module's own steppable CMA-ES (Hansen's tutorial algorithm, "The CMA
Evolution Strategy: A Tutorial", with rank-one and rank-mu updates and cumulative step-size
adaptation) in the unit cube: the search runs on unbounded coordinates, and a candidate is
*reflected* into ``[0, 1]`` (the triangle wave above) before it is decoded; ``sigma0 = 0.3``,
the mean starts at the centre or the mean of ``initial`` (the guesses are also the first
candidates of the first generation, their steps clipped in Mahalanobis norm as Hansen advises
for injected solutions), population ``D.CMA_POPSIZE``. All random numbers come from this
object's own PCG64 Generator, never from the global ``numpy.random`` state, so a seed
reproduces a run.

A run ends by its own criteria (``stop_reason``):

* ``tolx``: ``sigma * sqrt(C_ii)`` and ``sigma * |pc_i|`` below ``tolx`` in every coordinate
  (unit-cube units);
* ``tolfun``: the best values of the last ``10 + ceil(30 n / lambda)`` generations and all
  values of this one lie within ``tolfun``;
* ``tolstagnation``: the median of the generation bests over the last
  ``W = 120 + 30 n / lambda`` generations is no better than over the ``W`` before;
* ``conditioncov`` (condition number of C above 1e14), ``noeffectcoord`` / ``noeffectaxis``
  (a step no longer changes the mean), ``tolupsigma`` (sigma above 1e4: no signal at all).

With ``restarts = R > 0`` (IPOP-CMA-ES, Auger & Hansen 2005) a run that stops is followed by a
new one from a uniformly random mean with twice the population, up to ``R`` times; the best
over all runs is kept. ``stopped`` is True once the last run has ended.

Portfolio and coordinate polish
-------------------------------
:class:`CMAPortfolio` ("cma-portfolio") spends a known ``budget`` on several :class:`CMAES` runs:
successive halving among ``runs`` runs, the best continued, then polishes from the best point
(active CMA-ES or :class:`CoordinatePolish`). :class:`CoordinatePolish` ("coord-polish") is a
batch coordinate pattern search with a step per coordinate. Both keep the same ask/tell and
exact-resume contract (docs/search.md has what they were measured to do: neither beat plain
IPOP CMA-ES on the exact-model captures).

SPX + MGG stops when its population has collapsed (spread below ``tolx`` in every unit-cube
coordinate) or when the best value has not improved by more than ``tolfun`` during the last
``stall_evaluations`` evaluations (both off unless set).

Non-finite fitness
------------------
An exploded or failed model is a bad candidate, never a crash (SPEC 4): every non-finite value
(``nan``, ``+inf``, ``-inf``) is treated as ``+inf``, the worst. Such a candidate can never
become ``best_x``; in MGG it ranks last in its family; CMA-ES, which is rank based, ranks it
after every finite value. ``best_x`` stays ``None`` and ``best_f`` ``inf`` until a finite value
has been told.

History
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

import math

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError

STATE_VERSION = 2


# --------------------------------------------------------------------------- helpers

def _new_rng(seed):
    return np.random.Generator(np.random.PCG64(seed))


def _rng_from_state(state):
    rng = np.random.Generator(np.random.PCG64())
    rng.bit_generator.state = state
    return rng


def _float_to_json(v):
    v = float(v)
    return v if math.isfinite(v) else None


def _float_from_json(v):
    return math.inf if v is None else float(v)


def sanitize_fitness(f, count: int) -> np.ndarray:
    """``f`` as a float (count,) array with every non-finite value replaced by ``+inf``."""
    try:
        arr = np.asarray(f, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ClothFitError(f"fitness values must be numbers, got {f!r}") from exc
    if arr.shape[0] != count:
        raise ClothFitError(f"fitness: expected {count} values (one per candidate), got {arr.shape[0]}")
    return np.where(np.isfinite(arr), arr, np.inf)


def reflect_unit(U: np.ndarray) -> np.ndarray:
    """Reflect values into [0, 1] at the faces of the unit cube (triangle wave, any distance)."""
    V = np.mod(np.asarray(U, dtype=np.float64), 2.0)
    return np.where(V > 1.0, 2.0 - V, V)


# --------------------------------------------------------------------------- state validation

def _field(d, key, where):
    if key not in d:
        raise ClothFitError(f"checkpoint: {where} state lacks '{key}'")
    return d[key]


def _check_keys(d, allowed, where):
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise ClothFitError(f"checkpoint: {where} state has unknown fields {unknown} (not written by this version)")


def _num(d, key, where, kind=float, lo=None, hi=None, allow_none=False):
    v = _field(d, key, where)
    if v is None and allow_none:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (kind is int and not isinstance(v, int)):
        raise ClothFitError(f"checkpoint: {where} '{key}' must be {'an integer' if kind is int else 'a number'}, "
                            f"got {type(v).__name__}")
    if kind is float and not math.isfinite(v):
        raise ClothFitError(f"checkpoint: {where} '{key}' must be finite, got {v!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ClothFitError(f"checkpoint: {where} '{key}' = {v!r} outside [{lo}, {hi}]")
    return kind(v)


def _array(d, key, where, shape, allow_none=False, inf_as_none=False):
    """A nested list of numbers of the given shape (None in shape = any length), all finite
    (or ``None`` = +inf where ``inf_as_none``)."""
    v = _field(d, key, where)
    if v is None and allow_none:
        return None
    if not isinstance(v, list):
        raise ClothFitError(f"checkpoint: {where} '{key}' must be a list of numbers, got {type(v).__name__}")
    try:
        if inf_as_none:
            flat = np.array([math.inf if x is None else x for x in v], dtype=object)
            if any(isinstance(x, (bool, list, dict, str)) for x in flat):
                raise TypeError
            A = flat.astype(np.float64)
        else:
            A = np.array(v, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ClothFitError(f"checkpoint: {where} '{key}' must be a (nested) list of numbers") from None
    if A.size == 0 and len(shape) == 2 and shape[0] is None and shape[1] is not None:
        A = A.reshape(0, shape[1])
    if A.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, A.shape)):
        want = "x".join("*" if s is None else str(s) for s in shape)
        raise ClothFitError(f"checkpoint: {where} '{key}' has shape {A.shape}, expected {want}")
    if A.size > 10_000_000:
        raise ClothFitError(f"checkpoint: {where} '{key}' is too large ({A.size} numbers)")
    bad = np.isnan(A) | (np.isinf(A) if not inf_as_none else np.isneginf(A))
    if bad.any():
        raise ClothFitError(f"checkpoint: {where} '{key}' holds non-finite values")
    return A


def _rng_state_from_json(v, where):
    """A PCG64 bit-generator state made of plain integers, validated."""
    if (not isinstance(v, dict) or set(v) != {"bit_generator", "state", "has_uint32", "uinteger"}
            or v["bit_generator"] != "PCG64" or not isinstance(v["state"], dict)
            or set(v["state"]) != {"state", "inc"}):
        raise ClothFitError(f"checkpoint: {where} 'rng' is not a PCG64 generator state")
    ints = [v["state"]["state"], v["state"]["inc"], v["has_uint32"], v["uinteger"]]
    if not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < 2 ** 128 for i in ints):
        raise ClothFitError(f"checkpoint: {where} 'rng' must hold non-negative integers below 2**128")
    try:
        return _rng_from_state(v)
    except (TypeError, ValueError) as exc:
        raise ClothFitError(f"checkpoint: {where} 'rng' is invalid ({exc})") from None


# --------------------------------------------------------------------------- search space

class SearchSpace:
    """Bounded real parameters <-> the unit cube ``[0, 1]^n`` (log scale where asked).

    ``names``: the free parameters in order; ``bounds``: name -> (lo, hi) (extra keys ignored);
    ``log_scaled``: name -> bool (missing = linear).
    """

    def __init__(self, names, bounds: dict, log_scaled: dict | None = None):
        names = [str(n) for n in names]
        if not names:
            raise ClothFitError("search space: no parameter names given")
        if len(set(names)) != len(names):
            raise ClothFitError(f"search space: duplicate parameter names in {names}")
        log_scaled = dict(log_scaled or {})
        lo, hi, logs = [], [], []
        for name in names:
            if name not in bounds:
                raise ClothFitError(f"search space: no bounds given for parameter '{name}'")
            try:
                a, b = bounds[name]
                a, b = float(a), float(b)
            except (TypeError, ValueError) as exc:
                raise ClothFitError(f"search space: bounds of parameter '{name}' must be a pair of "
                                    f"numbers (lo, hi), got {bounds[name]!r}") from exc
            if not (math.isfinite(a) and math.isfinite(b)):
                raise ClothFitError(f"search space: bounds of parameter '{name}' must be finite, "
                                    f"got ({a}, {b})")
            if not a < b:
                raise ClothFitError(f"search space: parameter '{name}' needs lo < hi, got ({a}, {b})")
            is_log = bool(log_scaled.get(name, False))
            if is_log and a <= 0.0:
                raise ClothFitError(f"search space: parameter '{name}' is log-scaled, so its bounds "
                                    f"must be > 0, got ({a}, {b})")
            lo.append(a)
            hi.append(b)
            logs.append(is_log)
        self.names = names
        self.lo = np.array(lo)
        self.hi = np.array(hi)
        self.log = np.array(logs, dtype=bool)
        self._tlo = np.where(self.log, np.log(np.where(self.log, self.lo, 1.0)), self.lo)
        self._thi = np.where(self.log, np.log(np.where(self.log, self.hi, 1.0)), self.hi)

    @property
    def n(self) -> int:
        return len(self.names)

    @property
    def bounds(self) -> dict:
        return {n: (float(a), float(b)) for n, a, b in zip(self.names, self.lo, self.hi)}

    @property
    def log_scaled(self) -> dict:
        return {n: bool(g) for n, g in zip(self.names, self.log)}

    def _rows(self, X, what):
        try:
            A = np.asarray(X, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ClothFitError(f"{what}: expected numbers, got {X!r}") from exc
        if A.ndim not in (1, 2) or A.shape[-1] != self.n:
            raise ClothFitError(f"{what}: expected shape ({self.n},) or (B, {self.n}) for "
                                f"parameters {self.names}, got {A.shape}")
        return A

    def encode(self, X) -> np.ndarray:
        """Real values (n,) or (B, n) -> unit-cube coordinates, same shape (not clipped)."""
        A = self._rows(X, "encode")
        A2 = A.reshape(-1, self.n)
        bad = ~np.isfinite(A2) | (self.log & (A2 <= 0.0))
        if bad.any():
            j = int(np.nonzero(bad.any(axis=0))[0][0])
            raise ClothFitError(f"encode: parameter '{self.names[j]}' has a non-finite"
                                f"{' or non-positive (log-scaled)' if self.log[j] else ''} value "
                                f"{A2[bad[:, j], j][0]!r}")
        T = np.where(self.log, np.log(np.where(self.log, A2, 1.0)), A2)
        U = (T - self._tlo) / (self._thi - self._tlo)
        return U.reshape(A.shape)

    def decode(self, U) -> np.ndarray:
        """Unit-cube coordinates (n,) or (B, n) -> real values, clipped to the bounds."""
        A = self._rows(U, "decode")
        A = np.clip(A, 0.0, 1.0)
        T = self._tlo + A * (self._thi - self._tlo)
        X = np.where(self.log, np.exp(T), T)
        return np.clip(X, self.lo, self.hi)

    def clip(self, X) -> np.ndarray:
        """Real values clipped to the bounds."""
        return np.clip(self._rows(X, "clip"), self.lo, self.hi)

    def to_dict(self, x) -> dict:
        """One real vector -> {name: value}."""
        x = self._rows(x, "to_dict").reshape(self.n)
        return {n: float(v) for n, v in zip(self.names, x)}

    def from_dict(self, values: dict) -> np.ndarray:
        """{name: value} -> one real vector (n,)."""
        missing = [n for n in self.names if n not in values]
        if missing:
            raise ClothFitError(f"parameter values: missing {missing}")
        return np.array([float(values[n]) for n in self.names])

    def state_dict(self) -> dict:
        return {"names": list(self.names),
                "bounds": {n: [float(a), float(b)] for n, a, b in zip(self.names, self.lo, self.hi)},
                "log_scaled": self.log_scaled}

    @classmethod
    def from_state(cls, d: dict) -> "SearchSpace":
        if not isinstance(d, dict):
            raise ClothFitError("checkpoint: search space must be an object")
        _check_keys(d, ("names", "bounds", "log_scaled"), "search space")
        names, bounds, logs = d.get("names"), d.get("bounds"), d.get("log_scaled") or {}
        if (not isinstance(names, list) or not all(isinstance(n, str) for n in names) or len(names) > 1000
                or not isinstance(bounds, dict) or not isinstance(logs, dict)
                or not all(isinstance(v, list) and len(v) == 2 for v in bounds.values())
                or not all(isinstance(v, bool) for v in logs.values())):
            raise ClothFitError("checkpoint: search space needs 'names' (strings), 'bounds' (name: [lo, hi]) "
                                "and 'log_scaled' (name: true/false)")
        return cls(names, {k: tuple(v) for k, v in bounds.items()}, logs)

    def __repr__(self):
        parts = [f"{n}=[{a:g}, {b:g}]{' log' if g else ''}"
                 for n, a, b, g in zip(self.names, self.lo, self.hi, self.log)]
        return f"SearchSpace({', '.join(parts)})"


# --------------------------------------------------------------------------- common interface

class Optimizer:
    """Common steppable ask/tell machinery: counters, best-so-far, history, run loop, state."""

    name = "optimizer"

    def __init__(self, space: SearchSpace, seed=None, initial=None):
        if not isinstance(space, SearchSpace):
            raise ClothFitError(f"optimizer: expected a SearchSpace, got {type(space).__name__}")
        self.space = space
        self.seed = None if seed is None else int(seed)
        self.rng = _new_rng(self.seed)
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
                raise ClothFitError(f"initial guess #{i}: expected {self.space.n} values for "
                                    f"{self.space.names}, got {x!r}") from exc
        if not rows:
            return np.zeros((0, self.space.n))
        return np.clip(np.array(rows), 0.0, 1.0)   # guesses outside the bounds are clipped

    # -- best so far
    @property
    def best_x(self):
        """Best real-space vector (n,) told so far, None before any finite value."""
        return None if self._best_u is None else self.space.decode(self._best_u)

    @property
    def best_params(self):
        """``best_x`` as {name: value}, None before any finite value."""
        return None if self._best_u is None else self.space.to_dict(self.best_x)

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
            h[-1] = (self.evaluations, self.best_f)       # a run of equal bests: move its end
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
            raise ClothFitError(f"tell(): X (shape {A.shape}) is not the batch returned by the "
                                f"last ask() (shape {expected.shape})")

    # -- to implement
    def ask(self) -> np.ndarray:
        raise NotImplementedError

    def tell(self, X, f) -> None:
        raise NotImplementedError

    # -- driving
    def step(self, fn) -> float:
        """One generation: ``X = ask(); f = fn(X); tell(X, f)``; returns ``best_f``."""
        X = self.ask()
        f = fn(X)
        self.tell(X, f)
        return self.best_f

    def run(self, fn, max_evaluations: int, target=None, callback=None):
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
        return {"algorithm": self.name, "version": STATE_VERSION,
                "space": self.space.state_dict(), "seed": self.seed,
                "evaluations": int(self.evaluations), "generation": int(self.generation),
                "history": [[int(e), _float_to_json(b)] for e, b in self.history],
                "best_f": _float_to_json(self.best_f),
                "best_u": None if self._best_u is None else self._best_u.tolist(),
                "best_x": None if self._best_u is None else self.best_x.tolist()}

    BASE_KEYS = ("algorithm", "version", "space", "seed", "evaluations", "generation", "history", "best_f",
                 "best_u", "best_x")

    def _load_base(self, d: dict):
        w = self.name
        self.evaluations = _num(d, "evaluations", w, int, 0, 10 ** 12)
        self.generation = _num(d, "generation", w, int, 0, 10 ** 12)
        hist = _field(d, "history", w)
        if not isinstance(hist, list) or len(hist) > 10 ** 6:
            raise ClothFitError(f"checkpoint: {w} 'history' must be a list of [evaluations, best] pairs")
        out = []
        for item in hist:
            if (not isinstance(item, list) or len(item) != 2 or isinstance(item[0], bool)
                    or not isinstance(item[0], int) or not (item[1] is None or (
                        isinstance(item[1], (int, float)) and not isinstance(item[1], bool) and math.isfinite(item[1])))):
                raise ClothFitError(f"checkpoint: {w} 'history' must be a list of [evaluations, best] pairs")
            out.append((int(item[0]), _float_from_json(item[1])))
        self.history = out
        bf = _num(d, "best_f", w, float, allow_none=True)
        self.best_f = math.inf if bf is None else bf
        bu = _array(d, "best_u", w, (self.space.n,), allow_none=True)
        if (bu is None) != (bf is None):
            raise ClothFitError(f"checkpoint: {w} 'best_f' and 'best_u' must be both set or both null")
        self._best_u = bu

    @staticmethod
    def _check_state(d, name, keys=()):
        if not isinstance(d, dict) or d.get("algorithm") != name:
            got = d.get("algorithm") if isinstance(d, dict) else type(d).__name__
            raise ClothFitError(f"checkpoint: expected an '{name}' optimiser state, got {got!r}")
        if d.get("version") != STATE_VERSION:
            raise ClothFitError(f"checkpoint: unsupported {name} state version {d.get('version')!r} "
                                f"(this version reads {STATE_VERSION})")
        _check_keys(d, Optimizer.BASE_KEYS + tuple(keys), name)
        seed = _field(d, "seed", name)
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
            raise ClothFitError(f"checkpoint: {name} 'seed' must be a non-negative integer or null")
        return SearchSpace.from_state(_field(d, "space", name))

    def state_dict(self) -> dict:
        raise NotImplementedError

    @classmethod
    def from_state(cls, d: dict) -> "Optimizer":
        return optimizer_from_state(d)


# --------------------------------------------------------------------------- SPX + MGG

def spx_children(parents: np.ndarray, n_children: int, eps: float, rng) -> np.ndarray:
    """Tsutsui's simplex crossover: (n_children, dim) children of ``parents`` (m, dim).

    Children are uniform in the simplex of the ``m`` parents expanded by ``eps`` about their
    centroid; nothing is clipped or reflected here.
    """
    P = np.asarray(parents, dtype=np.float64)
    m = P.shape[0]
    G = P.mean(axis=0)
    Y = G + eps * (P - G)                              # (m, dim) expanded vertices y_0..y_{m-1}
    u = rng.random((n_children, m - 1))
    r = u ** (1.0 / np.arange(1, m))                   # r_j = u_j^(1/(j+1)), j = 0..m-2
    C = np.zeros((n_children, P.shape[1]))
    for k in range(1, m):
        C = r[:, k - 1:k] * (Y[k - 1] - Y[k] + C)
    return Y[m - 1] + C


class SPXMGG(Optimizer):
    """Real-coded GA: simplex crossover (SPX) with the minimal generation gap (MGG) model."""

    name = "spx-mgg"

    def __init__(self, space: SearchSpace, seed=None, initial=None, population: int | None = None,
                 children: int | None = None, eps: float | None = None, tolx: float = 0.0,
                 tolfun: float = 0.0, stall_evaluations: int | None = None):
        super().__init__(space, seed, initial)
        n = space.n
        self.population = _pos_int(D.GA_POPULATION if population is None else population, "spx-mgg: population")
        self.children = _pos_int(D.GA_CHILDREN if children is None else children, "spx-mgg: children", 0)
        self.eps = float(math.sqrt(n + 2) if eps is None else eps)
        self.tolx = _nonneg(tolx, "spx-mgg: tolx")
        self.tolfun = _nonneg(tolfun, "spx-mgg: tolfun")
        self.stall_evaluations = (None if stall_evaluations is None else
                                  _pos_int(stall_evaluations, "spx-mgg: stall_evaluations"))
        self._ref_best = math.inf     # best at the last improvement by more than tolfun
        self._last_improved = 0       # evaluations then
        self.stop_reason = None
        if self.population < n + 1:
            raise ClothFitError(f"spx-mgg: population must be at least n + 1 = {n + 1}, got {self.population}")
        if self.children < 1:
            raise ClothFitError(f"spx-mgg: children must be >= 1, got {self.children}")
        if not (math.isfinite(self.eps) and self.eps > 0):
            raise ClothFitError(f"spx-mgg: eps must be a positive number, got {self.eps}")
        if len(self._initial_u) > self.population:
            raise ClothFitError(f"spx-mgg: {len(self._initial_u)} initial guesses do not fit in a "
                                f"population of {self.population}")
        self.pop_u = None           # (P, n) unit-cube population, None until initialised
        self.pop_f = None           # (P,) fitness (+inf = bad)
        self._pending = None        # (B, n) unit-cube candidates asked but not told
        self._replace = None        # (2,) population slots replaced by the pending family

    @property
    def population_x(self):
        """Current population in real space (P, n), None before the first ask()."""
        return None if self.pop_u is None else self.space.decode(self.pop_u)

    def ask(self) -> np.ndarray:
        """Candidates (B, n) in real space; asking again before tell() returns the same batch."""
        if self._pending is None:
            n = self.space.n
            if self.pop_u is None:
                U = self.rng.random((self.population, n))
                U[:len(self._initial_u)] = self._initial_u
                self._pending, self._replace = U, None
            else:
                idx = self.rng.choice(self.population, size=n + 1, replace=False)
                self._replace = idx[self.rng.choice(n + 1, size=2, replace=False)]
                kids = spx_children(self.pop_u[idx], self.children, self.eps, self.rng)
                self._pending = reflect_unit(kids)
        return self.space.decode(self._pending)

    def tell(self, X, f) -> None:
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
            w = np.arange(len(rest), 0, -1, dtype=np.float64)     # linear ranking: m, m-1, ..., 1
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

    STATE_KEYS = ("population", "children", "eps", "tolx", "tolfun", "stall_evaluations", "ref_best",
                  "last_improved", "stop_reason", "rng", "initial_u", "pop_u", "pop_f", "pending_u", "replace")

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update({
            "population": self.population, "children": self.children, "eps": self.eps,
            "tolx": self.tolx, "tolfun": self.tolfun, "stall_evaluations": self.stall_evaluations,
            "ref_best": _float_to_json(self._ref_best), "last_improved": int(self._last_improved),
            "stop_reason": self.stop_reason,
            "rng": self.rng.bit_generator.state,
            "initial_u": self._initial_u.tolist(),
            "pop_u": None if self.pop_u is None else self.pop_u.tolist(),
            "pop_f": None if self.pop_f is None else [_float_to_json(v) for v in self.pop_f],
            "pending_u": None if self._pending is None else self._pending.tolist(),
            "replace": None if self._replace is None else [int(i) for i in self._replace],
        })
        return d

    @classmethod
    def from_state(cls, d: dict) -> "SPXMGG":
        w = cls.name
        space = cls._check_state(d, w, cls.STATE_KEYS)
        n = space.n
        stall = _num(d, "stall_evaluations", w, int, 1, 10 ** 12, allow_none=True)
        opt = cls(space, seed=d["seed"], population=_num(d, "population", w, int, n + 1, 10 ** 6),
                  children=_num(d, "children", w, int, 1, 10 ** 6), eps=_num(d, "eps", w, float, 1e-12, 1e6),
                  tolx=_num(d, "tolx", w, float, 0.0), tolfun=_num(d, "tolfun", w, float, 0.0),
                  stall_evaluations=stall)
        opt._load_base(d)
        rb = _num(d, "ref_best", w, float, allow_none=True)
        opt._ref_best = math.inf if rb is None else rb
        opt._last_improved = _num(d, "last_improved", w, int, 0, opt.evaluations)
        opt.stop_reason = _stop_reason(d, w, ("tolx", "stagnation"))
        opt.rng = _rng_state_from_json(_field(d, "rng", w), w)
        opt._initial_u = _array(d, "initial_u", w, (None, n))
        if len(opt._initial_u) > opt.population:
            raise ClothFitError(f"checkpoint: {w} has more initial guesses than its population")
        opt.pop_u = _array(d, "pop_u", w, (opt.population, n), allow_none=True)
        pop_f = _array(d, "pop_f", w, (opt.population,), allow_none=True, inf_as_none=True)
        if (opt.pop_u is None) != (pop_f is None):
            raise ClothFitError(f"checkpoint: {w} 'pop_u' and 'pop_f' must be both set or both null")
        opt.pop_f = pop_f
        rows = opt.population if opt.pop_u is None else opt.children
        opt._pending = _array(d, "pending_u", w, (rows, n), allow_none=True)
        rep = _field(d, "replace", w)
        if opt._pending is not None and opt.pop_u is not None:
            if (not isinstance(rep, list) or len(rep) != 2 or len(set(map(repr, rep))) != 2
                    or not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < opt.population
                               for i in rep)):
                raise ClothFitError(f"checkpoint: {w} 'replace' must be two distinct population slots")
            opt._replace = np.array(rep, dtype=np.int64)
        elif rep is not None:
            raise ClothFitError(f"checkpoint: {w} 'replace' must be null without a pending family")
        return opt


def _pos_int(v, what, minimum=1):
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or int(v) < max(1, minimum):
        raise ClothFitError(f"{what} must be an integer >= 1, got {v!r}")
    return int(v)


def _nonneg(v, what):
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ClothFitError(f"{what} must be a number >= 0, got {v!r}") from None
    if not (math.isfinite(x) and x >= 0):
        raise ClothFitError(f"{what} must be a finite number >= 0, got {v!r}")
    return x


def _stop_reason(d, where, allowed):
    v = _field(d, "stop_reason", where)
    if v is not None and v not in allowed:
        raise ClothFitError(f"checkpoint: {where} 'stop_reason' {v!r} is not one of {list(allowed)}")
    return v


# --------------------------------------------------------------------------- CMA-ES

CMA_STOPS = ("tolx", "tolfun", "tolstagnation", "conditioncov", "noeffectcoord", "noeffectaxis", "tolupsigma")


class CMAES(Optimizer):
    """CMA-ES (Hansen's tutorial algorithm) in the unit cube, with optional IPOP restarts."""

    name = "cma-es"

    def __init__(self, space: SearchSpace, seed=None, initial=None, popsize: int | None = None,
                 sigma0: float = 0.3, restarts: int = 0, tolx: float = 1e-11, tolfun: float = 1e-11,
                 active: bool = False):
        super().__init__(space, seed, initial)
        if not isinstance(active, (bool, np.bool_)):
            raise ClothFitError(f"cma-es: active must be true or false, got {active!r}")
        self.active = bool(active)     # active CMA: the worse half lowers the variance along its steps
        self.popsize = _pos_int(D.CMA_POPSIZE if popsize is None else popsize, "cma-es: popsize")
        if self.popsize < 2:
            raise ClothFitError(f"cma-es: popsize must be >= 2, got {self.popsize}")
        try:
            self.sigma0 = float(sigma0)
        except (TypeError, ValueError):
            raise ClothFitError(f"cma-es: sigma0 must be a positive number, got {sigma0!r}") from None
        if not (math.isfinite(self.sigma0) and 0 < self.sigma0 <= 10):
            raise ClothFitError(f"cma-es: sigma0 must be a positive number (unit cube), got {sigma0}")
        if isinstance(restarts, bool) or not isinstance(restarts, (int, np.integer)) or not 0 <= restarts <= 20:
            raise ClothFitError(f"cma-es: restarts must be an integer in 0..20, got {restarts!r}")
        self.restarts = int(restarts)
        self.tolx = _nonneg(tolx, "cma-es: tolx")
        self.tolfun = _nonneg(tolfun, "cma-es: tolfun")
        self.restarts_done = 0
        self.stop_reason = None        # the criterion that ended the last run (None: running)
        self.run_stops = []            # the criterion that ended each finished run
        self._stopped = False
        n = space.n
        x0 = self._initial_u.mean(axis=0) if len(self._initial_u) else np.full(n, 0.5)
        self._start_run(x0, self.popsize)
        self._inject = self._initial_u.copy()
        self._pending = None           # (lam, n) unbounded coordinates asked but not told
        self._pending_injected = 0

    # -- strategy parameters (derived from n and lambda, never stored)
    def _setup(self, lam):
        n = self.space.n
        self.lam = int(lam)
        self.mu = self.lam // 2
        w = math.log(self.mu + 0.5) - np.log(np.arange(1, self.mu + 1))
        self.weights = w / w.sum()
        self.mueff = 1.0 / float(np.sum(self.weights ** 2))
        self.cc = (4 + self.mueff / n) / (n + 4 + 2 * self.mueff / n)
        self.cs = (self.mueff + 2) / (n + self.mueff + 5)
        self.c1 = 2 / ((n + 1.3) ** 2 + self.mueff)
        self.cmu = min(1 - self.c1, 2 * (self.mueff - 2 + 1 / self.mueff) / ((n + 2) ** 2 + self.mueff))
        if self.active:
            # Hansen's tutorial (2016), eq. 53: weights for all lambda, negative for the worse half,
            # scaled so the covariance stays positive definite
            wa = math.log((self.lam + 1) / 2) - np.log(np.arange(1, self.lam + 1))
            pos, neg = wa[wa >= 0], wa[wa < 0]
            mueff_neg = float(neg.sum() ** 2 / np.sum(neg ** 2)) if neg.size else 0.0
            amu = 1 + self.c1 / self.cmu
            amueff = 1 + 2 * mueff_neg / (self.mueff + 2)
            aposdef = (1 - self.c1 - self.cmu) / (n * self.cmu)
            self.weights_all = np.where(wa >= 0, wa / pos.sum(),
                                        min(amu, amueff, aposdef) * wa / max(np.abs(neg).sum(), 1e-300))
        else:
            self.weights_all = np.concatenate([self.weights, np.zeros(self.lam - self.mu)])
        self.damps = 1 + 2 * max(0.0, math.sqrt((self.mueff - 1) / (n + 1)) - 1) + self.cs
        self.chin = math.sqrt(n) * (1 - 1 / (4 * n) + 1 / (21 * n * n))
        self.tolfun_window = 10 + int(math.ceil(30 * n / self.lam))
        self.stag_window = int(120 + 30 * n / self.lam)

    def _start_run(self, mean, lam):
        n = self.space.n
        self._setup(lam)
        self.mean = np.array(mean, dtype=np.float64)
        self.sigma = self.sigma0
        self.C = np.eye(n)
        self.pc = np.zeros(n)
        self.ps = np.zeros(n)
        self.run_generation = 0
        self.run_bests = []            # generation bests of this run, the last 2 * stag_window
        self.last_fvals = []           # this generation's finite values (for tolfun)

    def _eig(self):
        d2, B = np.linalg.eigh(self.C)
        d2 = np.maximum(d2, 1e-300)
        return B, np.sqrt(d2)

    @property
    def stopped(self) -> bool:
        return self._stopped

    @property
    def run_popsize(self) -> int:
        return self.lam

    def ask(self) -> np.ndarray:
        """Candidates (lambda, n) in real space; asking again before tell() returns the same batch."""
        if self._pending is None:
            B, Dv = self._eig()
            Z = self.rng.standard_normal((self.lam, self.space.n))
            G = self.mean + self.sigma * (Z @ (B * Dv).T)
            k = min(len(self._inject), self.lam)
            if k:
                G[:k] = self._inject[:k]
                self._inject = self._inject[k:]
            self._pending, self._pending_injected = G, k
        return self.space.decode(reflect_unit(self._pending))

    def tell(self, X, f) -> None:
        G = self._pending
        U = None if G is None else reflect_unit(G)
        self._check_told(X, U)
        f = sanitize_fitness(f, len(U))
        n = self.space.n
        order = np.argsort(f, kind="stable")           # +inf (bad) last
        B, Dv = self._eig()
        invsqrt = (B / Dv) @ B.T
        Y = (G - self.mean) / self.sigma
        k = self._pending_injected
        if k:   # injected solutions: clip their steps in Mahalanobis norm
            cap = math.sqrt(n) + 2 * n / (n + 2)
            norms = np.linalg.norm(Y[:k] @ invsqrt.T, axis=1)
            Y[:k] *= np.minimum(1.0, cap / np.maximum(norms, 1e-300))[:, None]
        sel = Y[order[:self.mu]]
        yw = self.weights @ sel
        self.mean = self.mean + self.sigma * yw
        self.ps = (1 - self.cs) * self.ps + math.sqrt(self.cs * (2 - self.cs) * self.mueff) * (invsqrt @ yw)
        g = self.run_generation + 1
        nps = float(np.linalg.norm(self.ps))
        hsig = nps / math.sqrt(1 - (1 - self.cs) ** (2 * g)) / self.chin < 1.4 + 2 / (n + 1)
        self.pc = (1 - self.cc) * self.pc + (math.sqrt(self.cc * (2 - self.cc) * self.mueff) * yw if hsig else 0.0)
        c1a = self.c1 * (1 - (0.0 if hsig else 1.0) * self.cc * (2 - self.cc))
        if self.active:
            Yo = Y[order]
            wo = self.weights_all.copy()
            neg = wo < 0
            if neg.any():       # negative weights act on steps normalised in the Mahalanobis norm
                m2 = np.sum((Yo[neg] @ invsqrt.T) ** 2, axis=1)
                wo[neg] *= n / np.maximum(m2, 1e-300)
            rank_mu = (Yo.T * wo) @ Yo
            self.C = ((1 - c1a - self.cmu * float(self.weights_all.sum())) * self.C
                      + self.c1 * np.outer(self.pc, self.pc) + self.cmu * rank_mu)
        else:
            rank_mu = (sel.T * self.weights) @ sel
            self.C = (1 - c1a - self.cmu) * self.C + self.c1 * np.outer(self.pc, self.pc) + self.cmu * rank_mu
        self.C = (self.C + self.C.T) / 2
        self.sigma *= math.exp(min(1.0, (self.cs / self.damps) * (nps / self.chin - 1)))
        self.run_generation = g
        self._pending, self._pending_injected = None, 0
        self._record(U, f)
        fin = f[np.isfinite(f)]
        self.last_fvals = fin.tolist()
        self.run_bests.append(float(fin.min()) if fin.size else math.inf)
        del self.run_bests[:-2 * self.stag_window]
        reason = self._run_stop()
        if reason is not None:
            self.run_stops.append(reason)
            self.stop_reason = reason
            if self.restarts_done < self.restarts:          # IPOP: twice the population, a new random mean
                self.restarts_done += 1
                self._start_run(self.rng.random(n), 2 * self.lam)
            else:
                self._stopped = True

    def _run_stop(self):
        n = self.space.n
        sd = self.sigma * np.sqrt(np.diag(self.C))
        if np.all(sd < self.tolx) and np.all(self.sigma * np.abs(self.pc) < self.tolx):
            return "tolx"
        hist = self.run_bests[-self.tolfun_window:]
        if len(hist) >= self.tolfun_window and all(math.isfinite(v) for v in hist) and self.last_fvals:
            vals = hist + self.last_fvals
            if max(vals) - min(vals) < self.tolfun:
                return "tolfun"
        W = self.stag_window
        if len(self.run_bests) >= 2 * W:
            old, new = np.median(self.run_bests[:W]), np.median(self.run_bests[W:])
            if not new < old:
                return "tolstagnation"
        B, Dv = self._eig()
        if (Dv.max() / Dv.min()) ** 2 > 1e14:
            return "conditioncov"
        if np.any(self.mean == self.mean + 0.2 * sd):
            return "noeffectcoord"
        i = self.run_generation % n
        if np.all(self.mean == self.mean + 0.1 * self.sigma * Dv[i] * B[:, i]):
            return "noeffectaxis"
        if self.sigma * Dv.max() > 1e4:
            return "tolupsigma"
        return None

    STATE_KEYS = ("popsize", "sigma0", "restarts", "tolx", "tolfun", "active", "restarts_done", "stop_reason", "run_stops",
                  "stopped", "lam", "mean", "sigma", "C", "pc", "ps", "run_generation", "run_bests", "last_fvals",
                  "rng", "initial_u", "inject", "pending", "pending_injected")

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update({"popsize": self.popsize, "sigma0": self.sigma0, "restarts": self.restarts,
                  "tolx": self.tolx, "tolfun": self.tolfun, "active": self.active,
                  "restarts_done": self.restarts_done,
                  "stop_reason": self.stop_reason, "run_stops": list(self.run_stops), "stopped": self._stopped,
                  "lam": self.lam, "mean": self.mean.tolist(), "sigma": self.sigma, "C": self.C.tolist(),
                  "pc": self.pc.tolist(), "ps": self.ps.tolist(), "run_generation": self.run_generation,
                  "run_bests": [_float_to_json(v) for v in self.run_bests], "last_fvals": list(self.last_fvals),
                  "rng": self.rng.bit_generator.state, "initial_u": self._initial_u.tolist(),
                  "inject": self._inject.tolist(),
                  "pending": None if self._pending is None else self._pending.tolist(),
                  "pending_injected": self._pending_injected})
        return d

    @classmethod
    def from_state(cls, d: dict) -> "CMAES":
        w = cls.name
        space = cls._check_state(d, w, cls.STATE_KEYS)
        n = space.n
        opt = cls(space, seed=d["seed"], popsize=_num(d, "popsize", w, int, 2, 10 ** 6),
                  sigma0=_num(d, "sigma0", w, float, 1e-300, 10.0), restarts=_num(d, "restarts", w, int, 0, 20),
                  tolx=_num(d, "tolx", w, float, 0.0), tolfun=_num(d, "tolfun", w, float, 0.0),
                  active=_active(d, w))
        opt._load_base(d)
        opt.restarts_done = _num(d, "restarts_done", w, int, 0, opt.restarts)
        lam = _num(d, "lam", w, int, 2, 10 ** 7)
        if lam != opt.popsize * 2 ** opt.restarts_done:
            raise ClothFitError(f"checkpoint: {w} 'lam' {lam} is not popsize x 2^restarts_done")
        opt._setup(lam)
        opt.stop_reason = _stop_reason(d, w, CMA_STOPS)
        rs = _field(d, "run_stops", w)
        if not isinstance(rs, list) or len(rs) > opt.restarts + 1 or any(r not in CMA_STOPS for r in rs):
            raise ClothFitError(f"checkpoint: {w} 'run_stops' must be a list of stop criteria")
        opt.run_stops = list(rs)
        st = _field(d, "stopped", w)
        if not isinstance(st, bool):
            raise ClothFitError(f"checkpoint: {w} 'stopped' must be true or false")
        opt._stopped = st
        opt.mean = _array(d, "mean", w, (n,))
        if np.abs(opt.mean).max() > 1e6:
            raise ClothFitError(f"checkpoint: {w} 'mean' is absurdly far from the unit cube")
        opt.sigma = _num(d, "sigma", w, float, 1e-300, 1e6)
        if opt.sigma <= 0:
            raise ClothFitError(f"checkpoint: {w} 'sigma' must be positive")
        C = _array(d, "C", w, (n, n))
        if not np.array_equal(C, C.T):
            raise ClothFitError(f"checkpoint: {w} 'C' is not symmetric")
        ev = np.linalg.eigvalsh(C)
        if not ev.min() > 0 or ev.max() > 1e12:
            raise ClothFitError(f"checkpoint: {w} 'C' is not a positive-definite covariance matrix")
        opt.C = C
        opt.pc = _array(d, "pc", w, (n,))
        opt.ps = _array(d, "ps", w, (n,))
        opt.run_generation = _num(d, "run_generation", w, int, 0, opt.generation)
        rb = _array(d, "run_bests", w, (None,), inf_as_none=True)
        if len(rb) > 2 * opt.stag_window:
            raise ClothFitError(f"checkpoint: {w} 'run_bests' is longer than its window")
        opt.run_bests = rb.tolist()
        opt.last_fvals = _array(d, "last_fvals", w, (None,)).tolist()
        if len(opt.last_fvals) > lam:
            raise ClothFitError(f"checkpoint: {w} 'last_fvals' has more values than a generation")
        opt.rng = _rng_state_from_json(_field(d, "rng", w), w)
        opt._initial_u = _array(d, "initial_u", w, (None, n))
        opt._inject = _array(d, "inject", w, (None, n))
        opt._pending = _array(d, "pending", w, (lam, n), allow_none=True)
        if opt._pending is not None and np.abs(opt._pending).max() > 1e7:
            raise ClothFitError(f"checkpoint: {w} 'pending' is absurdly far from the unit cube")
        opt._pending_injected = _num(d, "pending_injected", w, int, 0, lam if opt._pending is not None else 0)
        return opt


# --------------------------------------------------------------------------- coordinate polish

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

    def __init__(self, space: SearchSpace, seed=None, initial=None, f0=None, step: float = 0.05,
                 max_step: float = 0.3, tolx: float = 1e-11):
        super().__init__(space, seed, initial)
        self.step0 = _unit_step(step, "coord-polish: step")
        self.max_step = _unit_step(max_step, "coord-polish: max_step")
        self.tolx = _nonneg(tolx, "coord-polish: tolx")
        n = space.n
        self.x = self._initial_u[0].copy() if len(self._initial_u) else np.full(n, 0.5)
        self.fx = math.inf if f0 is None else float(f0)
        if not (self.fx == math.inf or math.isfinite(self.fx)):
            raise ClothFitError(f"coord-polish: f0 must be a number, got {f0!r}")
        if math.isfinite(self.fx):
            self.best_f, self._best_u = self.fx, self.x.copy()
        self.steps = np.full(n, self.step0)
        self.pattern = None            # the next pattern probe (unit cube), or None
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

    def tell(self, X, f) -> None:
        P = self._pending
        self._check_told(X, P)
        f = sanitize_fitness(f, len(P))
        n = self.space.n
        if not math.isfinite(self.fx):
            self.fx = float(f[2 * n])                 # x itself was evaluated (no f0 given)
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

    STATE_KEYS = ("step0", "max_step", "tolx", "x", "fx", "steps", "pattern", "pending", "stop_reason", "stopped",
                  "initial_u")

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update({"step0": self.step0, "max_step": self.max_step, "tolx": self.tolx, "x": self.x.tolist(),
                  "fx": _float_to_json(self.fx), "steps": self.steps.tolist(),
                  "pattern": None if self.pattern is None else self.pattern.tolist(),
                  "pending": None if self._pending is None else self._pending.tolist(),
                  "stop_reason": self.stop_reason, "stopped": self._stopped, "initial_u": self._initial_u.tolist()})
        return d

    @classmethod
    def from_state(cls, d: dict) -> "CoordinatePolish":
        w = cls.name
        space = cls._check_state(d, w, cls.STATE_KEYS)
        n = space.n
        opt = cls(space, seed=d["seed"], step=_num(d, "step0", w, float), max_step=_num(d, "max_step", w, float),
                  tolx=_num(d, "tolx", w, float, 0.0))
        opt._load_base(d)
        opt._initial_u = _array(d, "initial_u", w, (None, n))
        opt.x = _array(d, "x", w, (n,))
        if opt.x.min() < 0 or opt.x.max() > 1:
            raise ClothFitError(f"checkpoint: {w} 'x' must lie in the unit cube")
        opt.fx = _float_from_json(_num(d, "fx", w, float, allow_none=True))
        opt.steps = _array(d, "steps", w, (n,))
        if opt.steps.min() < 0 or opt.steps.max() > opt.max_step:
            raise ClothFitError(f"checkpoint: {w} 'steps' must lie in [0, max_step]")
        opt.pattern = _array(d, "pattern", w, (n,), allow_none=True)
        opt._pending = _array(d, "pending", w, (None, n), allow_none=True)
        if opt._pending is not None and (opt._pending.min() < 0 or opt._pending.max() > 1):
            raise ClothFitError(f"checkpoint: {w} 'pending' must lie in the unit cube")
        opt.stop_reason = _stop_reason(d, w, ("tolx",))
        st = _field(d, "stopped", w)
        if not isinstance(st, bool):
            raise ClothFitError(f"checkpoint: {w} 'stopped' must be true or false")
        opt._stopped = st
        return opt


# --------------------------------------------------------------------------- CMA-ES portfolio

PORTFOLIO_PHASES = ("explore", "refine", "polish")
PORTFOLIO_STOPS = CMA_STOPS + ("polishes",)
PORTFOLIO_POLISH = ("cma", "coord")


class CMAPortfolio(Optimizer):
    """A portfolio of CMA-ES runs for a budget: successive halving, the winner continued, polishes.

    * ``explore`` (``explore`` x ``budget`` evaluations): ``runs`` CMA-ES runs (population
      ``popsize``, step ``sigma0``), the first from the centre (or the mean of ``initial``), the
      others from uniformly random means, take generations in turn (the run with the fewest
      evaluations next). The exploration is cut into ``ceil(log2 runs) + 1`` rounds of equal
      evaluations; after each round but the last, the better half of the runs (by their best
      value) go on and the others are dropped (successive halving). A run that stops by its
      own criteria simply stops taking evaluations.
    * ``refine``: the best run left goes on until it stops by its own criteria.
    * ``polish``: new CMA-ES runs (active, step ``polish_sigma``, population ``popsize``) from the
      best point found so far, one after the other, each until it stops; after
      ``max_polishes`` of them the portfolio stops (``stop_reason`` "polishes").

    Every run is this module's :class:`CMAES` (``restarts=0``), seeded from the portfolio's own
    generator, so a seed reproduces a run; ``state_dict`` holds the runs' own states and the
    schedule, and resumes exactly. ``budget`` only shapes the schedule: the caller still
    decides when to stop asking (``run(fn, budget)``).
    """

    name = "cma-portfolio"

    def __init__(self, space: SearchSpace, seed=None, initial=None, popsize=None, sigma0: float = 0.3,
                 tolx: float = 1e-11, tolfun: float = 1e-11, active: bool = True, runs: int = 4,
                 explore: float = 0.5, budget: int | None = None, polish_sigma: float = 0.05,
                 max_polishes: int = 20, polish: str = "cma", refine_until: float = 1.0):
        super().__init__(space, seed, initial)
        if polish not in PORTFOLIO_POLISH:
            raise ClothFitError(f"cma-portfolio: polish must be one of {list(PORTFOLIO_POLISH)}, got {polish!r}")
        self.polish = polish
        self.refine_until = _fraction(refine_until, "cma-portfolio: refine_until")
        self.popsize = _pos_int(D.CMA_POPSIZE if popsize is None else popsize, "cma-portfolio: popsize")
        if self.popsize < 2:
            raise ClothFitError(f"cma-portfolio: popsize must be >= 2, got {self.popsize}")
        self.sigma0 = _unit_step(sigma0, "cma-portfolio: sigma0")
        self.polish_sigma = _unit_step(polish_sigma, "cma-portfolio: polish_sigma")
        self.tolx = _nonneg(tolx, "cma-portfolio: tolx")
        self.tolfun = _nonneg(tolfun, "cma-portfolio: tolfun")
        if not isinstance(active, (bool, np.bool_)):
            raise ClothFitError(f"cma-portfolio: active must be true or false, got {active!r}")
        self.active = bool(active)
        self.runs = _pos_int(runs, "cma-portfolio: runs")
        if self.runs > 64:
            raise ClothFitError(f"cma-portfolio: runs must be at most 64, got {runs}")
        try:
            self.explore = float(explore)
        except (TypeError, ValueError):
            raise ClothFitError(f"cma-portfolio: explore must be a fraction in [0, 1], got {explore!r}") from None
        if not (math.isfinite(self.explore) and 0.0 <= self.explore <= 1.0):
            raise ClothFitError(f"cma-portfolio: explore must be a fraction in [0, 1], got {explore!r}")
        self.budget = _pos_int(D.FIT_EVALUATIONS if budget is None else budget, "cma-portfolio: budget")
        self.max_polishes = _pos_int(max_polishes, "cma-portfolio: max_polishes")
        self.n_rounds = int(math.ceil(math.log2(self.runs))) + 1
        self.phase = "explore"
        self.round = 0
        self.round_spent = 0
        self.polishes = 0
        self.stop_reason = None
        self.run_stops = []
        self._stopped = False
        self._current = None           # the run whose batch is pending (between ask and tell)
        n = space.n
        x0 = self._initial_u.mean(axis=0) if len(self._initial_u) else np.full(n, 0.5)
        starts = [x0] + [self.rng.random(n) for _ in range(self.runs - 1)]
        self.children = []
        for i, u in enumerate(starts):
            init = self.space.decode(self._initial_u) if (i == 0 and len(self._initial_u)) else None
            c = self._child(self.sigma0, self.active, init)
            if i > 0:
                c._start_run(u, c.popsize)
            self.children.append(c)
        self.alive = list(range(self.runs))
        self._advance()

    def _child(self, sigma, active, initial=None):
        s = int(self.rng.integers(0, 2 ** 63 - 1))
        return CMAES(self.space, seed=s, initial=initial, popsize=self.popsize, sigma0=sigma, restarts=0,
                     tolx=self.tolx, tolfun=self.tolfun, active=active)

    @property
    def round_budget(self) -> float:
        return self.explore * self.budget / self.n_rounds

    @property
    def stopped(self) -> bool:
        return self._stopped

    @property
    def run_popsize(self) -> int:
        return self.popsize

    def phase_info(self) -> str:
        return f"{self.phase} round {self.round} alive {self.alive} polishes {self.polishes}"

    def _next(self):
        """The run to ask next (None once stopped)."""
        if self.phase == "explore":
            live = [i for i in self.alive if not self.children[i].stopped]
            return min(live, key=lambda i: (self.children[i].evaluations, i))
        return len(self.children) - 1 if self.phase == "polish" else self.alive[0]

    def _advance(self):
        """Move the schedule on after a tell (or at the start): rounds, halving, phases."""
        while not self._stopped:
            if self.phase == "explore":
                live = [i for i in self.alive if not self.children[i].stopped]
                if live and self.round_spent < self.round_budget:
                    return
                if self.round < self.n_rounds - 1 and len(self.alive) > 1:
                    keep = sorted(self.alive, key=lambda i: (self.children[i].best_f, i))
                    keep = keep[:int(math.ceil(len(keep) / 2))]
                    for i in self.alive:
                        if i not in keep:
                            self.children[i] = None          # dropped: its state is no longer kept
                    self.alive = sorted(keep, key=lambda i: (self.children[i].best_f, i))
                    self.round += 1
                    self.round_spent = 0
                    continue
                self.alive = sorted(self.alive, key=lambda i: (self.children[i].best_f, i))[:1]
                self.phase = "refine"
                continue
            last = self.children[self._next()]
            cut = self.phase == "refine" and self.evaluations >= self.refine_until * self.budget
            if not last.stopped and not cut:
                return
            if self.phase == "polish" and self.polishes >= self.max_polishes:
                self._stopped = True
                self.stop_reason = "polishes"
                return
            self.phase = "polish"
            self.polishes += 1
            u = self._best_u if self._best_u is not None else np.full(self.space.n, 0.5)
            if self.polish == "coord":
                c = CoordinatePolish(self.space, initial=[self.space.decode(u)], step=self.polish_sigma,
                                     f0=self.best_f if self._best_u is not None else None, tolx=self.tolx)
                c.x = u.copy()                    # exactly the best point (decode/encode may round)
                if self._best_u is not None:
                    c._best_u = u.copy()
            else:
                c = self._child(self.polish_sigma, True)
                c._start_run(u, c.popsize)
            self.children.append(c)

    def ask(self) -> np.ndarray:
        if self._stopped:
            raise ClothFitError("cma-portfolio: ask() after the portfolio has stopped")
        if self._current is None:
            self._current = self._next()
        return self.children[self._current].ask()

    def tell(self, X, f) -> None:
        if self._current is None:
            raise ClothFitError("tell() called without a pending ask()")
        c = self.children[self._current]
        U = None if c._pending is None else reflect_unit(c._pending)
        self._check_told(X, U)
        f = sanitize_fitness(f, len(U))
        c.tell(X, f)
        self._record(U, f)
        if c.stopped:
            self.run_stops.append(c.stop_reason)
            del self.run_stops[:-100]
            self.stop_reason = c.stop_reason
        if self.phase == "explore":
            self.round_spent += len(f)
        self._current = None
        self._advance()

    STATE_KEYS = ("popsize", "sigma0", "polish_sigma", "tolx", "tolfun", "active", "runs", "explore", "budget",
                  "max_polishes", "polish", "refine_until", "phase", "round", "round_spent", "polishes", "stop_reason", "run_stops",
                  "stopped", "current", "alive", "children", "rng", "initial_u")

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update({"popsize": self.popsize, "sigma0": self.sigma0, "polish_sigma": self.polish_sigma,
                  "tolx": self.tolx, "tolfun": self.tolfun, "active": self.active, "runs": self.runs,
                  "explore": self.explore, "budget": self.budget, "max_polishes": self.max_polishes,
                  "polish": self.polish, "refine_until": self.refine_until,
                  "phase": self.phase, "round": self.round, "round_spent": self.round_spent,
                  "polishes": self.polishes, "stop_reason": self.stop_reason, "run_stops": list(self.run_stops),
                  "stopped": self._stopped, "current": self._current, "alive": list(self.alive),
                  "children": [None if c is None else c.state_dict() for c in self.children],
                  "rng": self.rng.bit_generator.state, "initial_u": self._initial_u.tolist()})
        return d

    @classmethod
    def from_state(cls, d: dict) -> "CMAPortfolio":
        w = cls.name
        space = cls._check_state(d, w, cls.STATE_KEYS)
        n = space.n
        opt = cls.__new__(cls)
        Optimizer.__init__(opt, space, d["seed"], None)
        opt.popsize = _num(d, "popsize", w, int, 2, 10 ** 6)
        opt.sigma0 = _unit_step(_num(d, "sigma0", w, float), f"checkpoint: {w} 'sigma0'")
        opt.polish_sigma = _unit_step(_num(d, "polish_sigma", w, float), f"checkpoint: {w} 'polish_sigma'")
        opt.tolx = _num(d, "tolx", w, float, 0.0)
        opt.tolfun = _num(d, "tolfun", w, float, 0.0)
        opt.active = _active(d, w)
        opt.runs = _num(d, "runs", w, int, 1, 64)
        opt.explore = _num(d, "explore", w, float, 0.0, 1.0)
        opt.budget = _num(d, "budget", w, int, 1, 10 ** 12)
        opt.max_polishes = _num(d, "max_polishes", w, int, 1, 10 ** 6)
        opt.polish = _field(d, "polish", w)
        if opt.polish not in PORTFOLIO_POLISH:
            raise ClothFitError(f"checkpoint: {w} 'polish' must be one of {list(PORTFOLIO_POLISH)}")
        opt.refine_until = _num(d, "refine_until", w, float, 0.0, 1.0)
        opt.n_rounds = int(math.ceil(math.log2(opt.runs))) + 1
        opt._load_base(d)
        opt.phase = _field(d, "phase", w)
        if opt.phase not in PORTFOLIO_PHASES:
            raise ClothFitError(f"checkpoint: {w} 'phase' must be one of {list(PORTFOLIO_PHASES)}")
        opt.round = _num(d, "round", w, int, 0, opt.n_rounds - 1)
        opt.round_spent = _num(d, "round_spent", w, int, 0, 10 ** 12)
        opt.polishes = _num(d, "polishes", w, int, 0, opt.max_polishes)
        opt.stop_reason = _stop_reason(d, w, PORTFOLIO_STOPS)
        rs = _field(d, "run_stops", w)
        if not isinstance(rs, list) or len(rs) > 100 or any(r not in CMA_STOPS for r in rs):
            raise ClothFitError(f"checkpoint: {w} 'run_stops' must be a list of stop criteria")
        opt.run_stops = list(rs)
        st = _field(d, "stopped", w)
        if not isinstance(st, bool):
            raise ClothFitError(f"checkpoint: {w} 'stopped' must be true or false")
        opt._stopped = st
        kids = _field(d, "children", w)
        if not isinstance(kids, list) or not opt.runs <= len(kids) <= opt.runs + opt.max_polishes:
            raise ClothFitError(f"checkpoint: {w} 'children' must be a list of CMA-ES states")
        opt.children = []
        for k in kids:
            if k is None:
                opt.children.append(None)
                continue
            polish_child = len(opt.children) >= opt.runs and opt.polish == "coord"
            if not isinstance(k, dict) or k.get("algorithm") != ("coord-polish" if polish_child else "cma-es"):
                raise ClothFitError(f"checkpoint: {w} 'children' hold a state of the wrong algorithm")
            c = (CoordinatePolish if polish_child else CMAES).from_state(k)
            if c.space.state_dict() != space.state_dict() or (
                    not polish_child and (c.popsize != opt.popsize or c.restarts != 0)):
                raise ClothFitError(f"checkpoint: {w} 'children' hold a run of another space or population")
            opt.children.append(c)
        al = _field(d, "alive", w)
        if (not isinstance(al, list) or not al or len(set(al)) != len(al)
                or any(isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < len(opt.children)
                       or opt.children[i] is None for i in al)):
            raise ClothFitError(f"checkpoint: {w} 'alive' must list kept runs")
        opt.alive = list(al)
        cur = _field(d, "current", w)
        if cur is not None and (isinstance(cur, bool) or not isinstance(cur, int) or not 0 <= cur < len(opt.children)
                                or opt.children[cur] is None or opt.children[cur]._pending is None):
            raise ClothFitError(f"checkpoint: {w} 'current' must be a run with a pending batch, or null")
        opt._current = cur
        opt.rng = _rng_state_from_json(_field(d, "rng", w), w)
        opt._initial_u = _array(d, "initial_u", w, (None, n))
        return opt


def _fraction(v, what):
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ClothFitError(f"{what} must be a fraction in [0, 1], got {v!r}") from None
    if not (math.isfinite(x) and 0.0 <= x <= 1.0):
        raise ClothFitError(f"{what} must be a fraction in [0, 1], got {v!r}")
    return x


def _unit_step(v, what):
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ClothFitError(f"{what} must be a positive number (unit cube), got {v!r}") from None
    if not (math.isfinite(x) and 0 < x <= 10):
        raise ClothFitError(f"{what} must be a positive number (unit cube), got {v!r}")
    return x


# --------------------------------------------------------------------------- factory

OPTIMIZERS = {"spx-mgg": SPXMGG, "cma-es": CMAES, "cma-portfolio": CMAPortfolio, "coord-polish": CoordinatePolish}
ALIASES = {"spx-mgg": "spx-mgg", "spx_mgg": "spx-mgg", "ga": "spx-mgg", "spxmgg": "spx-mgg",
           "cma-es": "cma-es", "cma": "cma-es", "cma_es": "cma-es", "cmaes": "cma-es",
           "cma-portfolio": "cma-portfolio", "cma_portfolio": "cma-portfolio", "portfolio": "cma-portfolio",
           "coord-polish": "coord-polish", "coord_polish": "coord-polish"}


def canonical_name(name: str) -> str:
    key = str(name).strip().lower()
    if key not in ALIASES:
        raise ClothFitError(f"unknown optimiser '{name}': choose one of "
                            f"{', '.join(sorted(ALIASES))} (i.e. {' or '.join(OPTIMIZERS)})")
    return ALIASES[key]


def _active(d, where):
    v = d.get("active", False)          # older checkpoints: plain CMA-ES
    if not isinstance(v, bool):
        raise ClothFitError(f"checkpoint: {where} 'active' must be true or false")
    return v


def make_optimizer(name: str, space: SearchSpace, seed=None, **kw) -> Optimizer:
    """Build an optimiser by name: "spx-mgg" ("ga", "spx_mgg") or "cma-es" ("cma")."""
    return OPTIMIZERS[canonical_name(name)](space, seed=seed, **kw)


def optimizer_from_state(d: dict) -> Optimizer:
    """Resume any optimiser from its ``state_dict()``."""
    if not isinstance(d, dict) or "algorithm" not in d:
        raise ClothFitError("checkpoint: not an optimiser state (no 'algorithm' key)")
    return OPTIMIZERS[canonical_name(d["algorithm"])].from_state(d)
