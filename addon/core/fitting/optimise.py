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
:class:`CMAES` wraps ``cma.CMAEvolutionStrategy`` (imported lazily) in the unit cube: bounds
``[0, 1]``, ``sigma0 = 0.3``, ``x0`` = the centre or the mean of ``initial`` (the initial guesses
are also injected into the first generation), population ``D.CMA_POPSIZE``. Its normal samples
come from this object's own ``numpy`` Generator (cma's ``randn`` option), never from the global
``numpy.random`` state, so a seed reproduces a run. The run stops early when cma's own
termination criteria fire (``stopped``); no restarts.

Non-finite fitness
------------------
An exploded or failed model is a bad candidate, never a crash (SPEC 4): every non-finite value
(``nan``, ``+inf``, ``-inf``) is treated as ``+inf``, the worst. Such a candidate can never
become ``best_x``; in MGG it ranks last in its family; cma, which is rank based, receives a
finite stand-in worse than every finite value of that generation. ``best_x`` stays ``None`` and
``best_f`` ``inf`` until a finite value has been told.

Checkpoints
-----------
``state_dict()`` returns a JSON-serialisable dict (strict JSON: no NaN / Infinity; an infinite
fitness is stored as ``None``), and ``from_state(d)`` (or :func:`optimizer_from_state`) resumes
exactly: a run checkpointed after any ``tell`` (or even between ``ask`` and ``tell``) and
resumed produces the very same candidates as the uninterrupted run. For SPX + MGG the dict
holds the population, fitnesses, pending children, counters and the PCG64 state as plain
numbers. For CMA-ES the ``cma`` object (with its Generator) is pickled and stored as base64
text inside the dict: only load CMA-ES checkpoints you wrote yourself (unpickling runs code),
and resume with the same ``cma`` version.
"""
from __future__ import annotations

import base64
import math
import pickle

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError

STATE_VERSION = 1


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
        return cls(d["names"], {k: tuple(v) for k, v in d["bounds"].items()}, d.get("log_scaled"))

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
        self.history.append((self.evaluations, self.best_f))

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

    def _load_base(self, d: dict):
        self.evaluations = int(d["evaluations"])
        self.generation = int(d["generation"])
        self.history = [(int(e), _float_from_json(b)) for e, b in d["history"]]
        self.best_f = _float_from_json(d["best_f"])
        self._best_u = None if d["best_u"] is None else np.array(d["best_u"], dtype=np.float64)

    @staticmethod
    def _check_state(d, name):
        if not isinstance(d, dict) or d.get("algorithm") != name:
            got = d.get("algorithm") if isinstance(d, dict) else type(d).__name__
            raise ClothFitError(f"checkpoint: expected an '{name}' optimiser state, got {got!r}")
        if d.get("version") != STATE_VERSION:
            raise ClothFitError(f"checkpoint: unsupported optimiser state version {d.get('version')!r}")

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
                 children: int | None = None, eps: float | None = None):
        super().__init__(space, seed, initial)
        n = space.n
        self.population = int(D.GA_POPULATION if population is None else population)
        self.children = int(D.GA_CHILDREN if children is None else children)
        self.eps = float(math.sqrt(n + 2) if eps is None else eps)
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

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update({
            "population": self.population, "children": self.children, "eps": self.eps,
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
        cls._check_state(d, cls.name)
        space = SearchSpace.from_state(d["space"])
        opt = cls(space, seed=d["seed"], population=d["population"], children=d["children"], eps=d["eps"])
        opt._load_base(d)
        opt.rng = _rng_from_state(d["rng"])
        opt._initial_u = np.array(d["initial_u"], dtype=np.float64).reshape(-1, space.n)
        if d["pop_u"] is not None:
            opt.pop_u = np.array(d["pop_u"], dtype=np.float64).reshape(-1, space.n)
            opt.pop_f = np.array([_float_from_json(v) for v in d["pop_f"]], dtype=np.float64)
        if d["pending_u"] is not None:
            opt._pending = np.array(d["pending_u"], dtype=np.float64).reshape(-1, space.n)
        if d["replace"] is not None:
            opt._replace = np.array(d["replace"], dtype=np.int64)
        return opt


# --------------------------------------------------------------------------- CMA-ES

class _GaussianSource:
    """cma's ``randn(lam, N)`` option drawing from our own Generator (picklable)."""

    def __init__(self, rng):
        self.rng = rng

    def __call__(self, *shape):
        return self.rng.standard_normal(shape)


def _import_cma():
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # e.g. "could not import matplotlib"
        try:
            import cma
        except ImportError as exc:
            raise ClothFitError("cma-es needs the 'cma' package (pip install cma)") from exc
    return cma


class CMAES(Optimizer):
    """``cma.CMAEvolutionStrategy`` in the unit cube, behind the common ask/tell interface."""

    name = "cma-es"

    def __init__(self, space: SearchSpace, seed=None, initial=None, popsize: int | None = None,
                 sigma0: float = 0.3, cma_options: dict | None = None):
        super().__init__(space, seed, initial)
        cma = _import_cma()
        self.popsize = int(D.CMA_POPSIZE if popsize is None else popsize)
        self.sigma0 = float(sigma0)
        if self.popsize < 2:
            raise ClothFitError(f"cma-es: popsize must be >= 2, got {self.popsize}")
        if not (math.isfinite(self.sigma0) and self.sigma0 > 0):
            raise ClothFitError(f"cma-es: sigma0 must be a positive number, got {sigma0}")
        n = space.n
        x0 = self._initial_u.mean(axis=0) if len(self._initial_u) else np.full(n, 0.5)
        self._randn = _GaussianSource(self.rng)
        opts = {"bounds": [0.0, 1.0], "popsize": self.popsize, "seed": np.nan,
                "randn": self._randn, "verbose": -9, "verb_disp": 0, "verb_log": 0,
                "maxfevals": np.inf, "maxiter": np.inf, "tolflatfitness": 10 ** 9}
        opts.update(cma_options or {})
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self.es = cma.CMAEvolutionStrategy(list(x0), self.sigma0, opts)
        if len(self._initial_u):
            bh = getattr(self.es, "boundary_handler", None)
            geno = [bh.inverse(u) if hasattr(bh, "inverse") else u for u in self._initial_u]
            self.es.inject([np.asarray(g, dtype=np.float64) for g in geno], force=True)
        self._pending = None

    @property
    def stopped(self) -> bool:
        return bool(self.es.stop())

    def ask(self) -> np.ndarray:
        """Candidates (popsize, n) in real space; asking again before tell() returns the same batch."""
        if self._pending is None:
            import warnings
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self._pending = self.es.ask()
        return self.space.decode(np.array(self._pending))

    def tell(self, X, f) -> None:
        U = None if self._pending is None else np.array(self._pending)
        self._check_told(X, U)
        f = sanitize_fitness(f, len(U))
        finite = np.isfinite(f)
        if finite.all():
            g = f
        else:   # cma is rank based: a finite stand-in worse than every finite value
            worst = float(f[finite].max()) if finite.any() else 0.0
            g = np.where(finite, f, worst + 1.0 + abs(worst))
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self.es.tell(self._pending, [float(v) for v in g])
        self._pending = None
        self._record(U, f)

    def state_dict(self) -> dict:
        """JSON dict; the cma object (with the Generator) is pickled to base64 text."""
        d = self._base_state()
        blob = pickle.dumps({"es": self.es, "randn": self._randn, "pending": self._pending},
                            protocol=pickle.HIGHEST_PROTOCOL)
        d.update({"popsize": self.popsize, "sigma0": self.sigma0,
                  "rng": self.rng.bit_generator.state,      # informational: the pickle is authoritative
                  "pickle_b64": base64.b64encode(blob).decode("ascii")})
        return d

    @classmethod
    def from_state(cls, d: dict) -> "CMAES":
        cls._check_state(d, cls.name)
        _import_cma()
        space = SearchSpace.from_state(d["space"])
        opt = cls.__new__(cls)
        Optimizer.__init__(opt, space, seed=d["seed"])
        opt.popsize, opt.sigma0 = int(d["popsize"]), float(d["sigma0"])
        opt._load_base(d)
        try:
            payload = pickle.loads(base64.b64decode(d["pickle_b64"]))
        except Exception as exc:  # corrupt text, other cma version...
            raise ClothFitError(f"checkpoint: cannot restore the cma-es state ({exc})") from exc
        opt.es, opt._randn, opt._pending = payload["es"], payload["randn"], payload["pending"]
        opt.rng = opt._randn.rng
        return opt


# --------------------------------------------------------------------------- factory

OPTIMIZERS = {"spx-mgg": SPXMGG, "cma-es": CMAES}
ALIASES = {"spx-mgg": "spx-mgg", "spx_mgg": "spx-mgg", "ga": "spx-mgg", "spxmgg": "spx-mgg",
           "cma-es": "cma-es", "cma": "cma-es", "cma_es": "cma-es", "cmaes": "cma-es"}


def canonical_name(name: str) -> str:
    key = str(name).strip().lower()
    if key not in ALIASES:
        raise ClothFitError(f"unknown optimiser '{name}': choose one of "
                            f"{', '.join(sorted(ALIASES))} (i.e. {' or '.join(OPTIMIZERS)})")
    return ALIASES[key]


def make_optimizer(name: str, space: SearchSpace, seed=None, **kw) -> Optimizer:
    """Build an optimiser by name: "spx-mgg" ("ga", "spx_mgg") or "cma-es" ("cma")."""
    return OPTIMIZERS[canonical_name(name)](space, seed=seed, **kw)


def optimizer_from_state(d: dict) -> Optimizer:
    """Resume any optimiser from its ``state_dict()``."""
    if not isinstance(d, dict) or "algorithm" not in d:
        raise ClothFitError("checkpoint: not an optimiser state (no 'algorithm' key)")
    return OPTIMIZERS[canonical_name(d["algorithm"])].from_state(d)
