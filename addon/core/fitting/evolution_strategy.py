"""CMA-ES as a steppable optimiser, with active CMA and IPOP restarts.

:class:`CMAES` is this module's own steppable CMA-ES (Hansen's tutorial algorithm, "The CMA
Evolution Strategy: A Tutorial", with rank-one and rank-mu updates and cumulative step-size
adaptation) in the unit cube: the search runs on unbounded coordinates, and a candidate is
*reflected* into ``[0, 1]`` (the triangle wave of :func:`.space.reflect_unit`) before it is decoded; ``sigma0 = 0.3``,
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
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .. import defaults as D
from ..errors import ClothFitError
from .space import (
    SearchSpace,
    checked_flag,
    checked_integer,
    checked_number,
    float_to_json,
    reflect_unit,
    rng_state_from_json,
    sanitize_fitness,
    saved_active,
    saved_array,
    saved_bool,
    saved_field,
    saved_stop_reason,
    saved_value,
)
from .steppable import Optimizer

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

CMA_STOPS = ("tolx", "tolfun", "tolstagnation", "conditioncov", "noeffectcoord", "noeffectaxis", "tolupsigma")


class CMAES(Optimizer):
    """CMA-ES (Hansen's tutorial algorithm) in the unit cube, with optional IPOP restarts."""

    name = "cma-es"

    def __init__(
        self,
        space: SearchSpace,
        seed=None,
        initial=None,
        popsize: int | None = None,
        sigma0: float = 0.3,
        restarts: int = 0,
        tolx: float = 1e-11,
        tolfun: float = 1e-11,
        active: bool = False,
    ):
        super().__init__(space, seed, initial)
        self.active = checked_flag(
            active, "cma-es: active"
        )  # active CMA: the worse half lowers the variance along its steps
        self.popsize = checked_integer(D.CMA_POPSIZE if popsize is None else popsize, "cma-es: popsize", 2)
        self.sigma0 = checked_number(sigma0, "cma-es: sigma0 (unit cube)", 0.0, 10.0, lo_open=True)
        self.restarts = checked_integer(restarts, "cma-es: restarts", 0, 20)
        self.tolx = checked_number(tolx, "cma-es: tolx")
        self.tolfun = checked_number(tolfun, "cma-es: tolfun")
        self.restarts_done = 0
        self.stop_reason = None  # the criterion that ended the last run (None: running)
        self.run_stops = []  # the criterion that ended each finished run
        self._stopped = False
        n = space.n
        x0 = self._initial_u.mean(axis=0) if len(self._initial_u) else np.full(n, 0.5)
        self._start_run(x0, self.popsize)
        self._inject = self._initial_u.copy()
        self._pending = None  # (lam, n) unbounded coordinates asked but not told
        self._pending_injected = 0

    # -- strategy parameters (derived from n and lambda, never stored)
    def _setup(self, lam):
        n = self.space.n
        self.lam = int(lam)
        self.mu = self.lam // 2
        w = math.log(self.mu + 0.5) - np.log(np.arange(1, self.mu + 1))
        self.weights = w / w.sum()
        self.mueff = 1.0 / float(np.sum(self.weights**2))
        self.cc = (4 + self.mueff / n) / (n + 4 + 2 * self.mueff / n)
        self.cs = (self.mueff + 2) / (n + self.mueff + 5)
        self.c1 = 2 / ((n + 1.3) ** 2 + self.mueff)
        self.cmu = min(1 - self.c1, 2 * (self.mueff - 2 + 1 / self.mueff) / ((n + 2) ** 2 + self.mueff))
        if self.active:
            # Hansen's tutorial (2016), eq. 53: weights for all lambda, negative for the worse half,
            # scaled so the covariance stays positive definite
            wa = math.log((self.lam + 1) / 2) - np.log(np.arange(1, self.lam + 1))
            pos, neg = wa[wa >= 0], wa[wa < 0]
            mueff_neg = float(neg.sum() ** 2 / np.sum(neg**2)) if neg.size else 0.0
            amu = 1 + self.c1 / self.cmu
            amueff = 1 + 2 * mueff_neg / (self.mueff + 2)
            aposdef = (1 - self.c1 - self.cmu) / (n * self.cmu)
            self.weights_all = np.where(
                wa >= 0, wa / pos.sum(), min(amu, amueff, aposdef) * wa / max(np.abs(neg).sum(), 1e-300)
            )
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
        self.run_bests = []  # generation bests of this run, the last 2 * stag_window
        self.last_fvals = []  # this generation's finite values (for tolfun)

    def warm_covariance(self, sigma: float, idx: list, n: int) -> np.ndarray:
        """A first covariance (in units of ``sigma``) for a run over ``n`` coordinates that goes on from this one,
        whose coordinates are ``idx`` of them: this run's covariance (sigma^2 C), scaled down where a step exceeds
        ``sigma`` (a run that has just restarted), and the identity on the others. ``StagedCMA``'s second stage and
        tail start with it: the strong settings are then varied by the steps at which their run converged, the held
        ones by ``sigma``, where one step for all would throw the strong ones off the narrow valley they were found
        in."""
        S = self.sigma**2 * self.C
        top = float(np.sqrt(np.diag(S)).max())
        if top > sigma:
            S = S * (sigma / top) ** 2
        C = np.eye(n)
        C[np.ix_(idx, idx)] = S / sigma**2
        return C

    def shape_start(self, C: ArrayLike) -> None:
        """This run's first covariance (n x n, symmetric positive definite, in units of ``sigma0``) instead
        of the identity: a run that starts where another left off keeps the steps that run learned. Only
        before the run's first generation; a restart (IPOP) starts from the identity again."""
        n = self.space.n
        C = np.asarray(C, dtype=np.float64)
        if C.shape != (n, n) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T):
            raise ClothFitError(f"cma-es: a start covariance must be a finite symmetric {n} x {n} matrix")
        if np.linalg.eigvalsh(C).min() <= 0:
            raise ClothFitError("cma-es: a start covariance must be positive definite")
        if self.run_generation or self._pending is not None:
            raise ClothFitError("cma-es: a start covariance only before the run's first generation")
        self.C = (C + C.T) / 2

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

    @property
    def pending_unit(self) -> np.ndarray | None:
        """The batch asked but not told, in the unit cube (reflected as ``ask`` decodes it); None when none is."""
        return None if self._pending is None else reflect_unit(self._pending)

    def ask(self) -> np.ndarray:
        """Candidates (lambda, n) in real space; asking again before tell() returns the same batch."""
        if self._pending is None:
            B, Dv = self._eig()
            Z = self.rng.standard_normal((self.lam, self.space.n))
            # the symmetric square root of C (B D B^T), not B D: both sample N(0, C), but the eigenvectors of
            # a C with near-equal eigenvalues turn on its last bits (which differ between CPUs: NumPy's
            # AVX-512 exp and log), while B D B^T is a smooth function of C, so a seed gives the same fit on
            # every machine (docs/search.md, "The same fit on every machine")
            G = self.mean + self.sigma * (Z @ ((B * Dv) @ B.T).T)
            k = min(len(self._inject), self.lam)
            if k:
                G[:k] = self._inject[:k]
                self._inject = self._inject[k:]
            self._pending, self._pending_injected = G, k
        return self.space.decode(reflect_unit(self._pending))

    def tell(self, X: ArrayLike, f: ArrayLike) -> None:
        G = self._pending
        U = None if G is None else reflect_unit(G)
        self._check_told(X, U)
        f = sanitize_fitness(f, len(U))
        n = self.space.n
        order = np.argsort(f, kind="stable")  # +inf (bad) last
        B, Dv = self._eig()
        invsqrt = (B / Dv) @ B.T
        Y = (G - self.mean) / self.sigma
        k = self._pending_injected
        if k:  # injected solutions: clip their steps in Mahalanobis norm
            cap = math.sqrt(n) + 2 * n / (n + 2)
            norms = np.linalg.norm(Y[:k] @ invsqrt.T, axis=1)
            Y[:k] *= np.minimum(1.0, cap / np.maximum(norms, 1e-300))[:, None]
        sel = Y[order[: self.mu]]
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
            if neg.any():  # negative weights act on steps normalised in the Mahalanobis norm
                m2 = np.sum((Yo[neg] @ invsqrt.T) ** 2, axis=1)
                wo[neg] *= n / np.maximum(m2, 1e-300)
            rank_mu = (Yo.T * wo) @ Yo
            self.C = (
                (1 - c1a - self.cmu * float(self.weights_all.sum())) * self.C
                + self.c1 * np.outer(self.pc, self.pc)
                + self.cmu * rank_mu
            )
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
        del self.run_bests[: -2 * self.stag_window]
        reason = self._run_stop()
        if reason is not None:
            self.run_stops.append(reason)
            self.stop_reason = reason
            if self.restarts_done < self.restarts:  # IPOP: twice the population, a new random mean
                self.restarts_done += 1
                self._start_run(self.rng.random(n), 2 * self.lam)
            else:
                self._stopped = True

    def _run_stop(self):
        n = self.space.n
        sd = self.sigma * np.sqrt(np.diag(self.C))
        if np.all(sd < self.tolx) and np.all(self.sigma * np.abs(self.pc) < self.tolx):
            return "tolx"
        hist = self.run_bests[-self.tolfun_window :]
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

    STATE_KEYS = (
        "popsize",
        "sigma0",
        "restarts",
        "tolx",
        "tolfun",
        "active",
        "restarts_done",
        "stop_reason",
        "run_stops",
        "stopped",
        "lam",
        "mean",
        "sigma",
        "C",
        "pc",
        "ps",
        "run_generation",
        "run_bests",
        "last_fvals",
        "rng",
        "initial_u",
        "inject",
        "pending",
        "pending_injected",
    )

    def state_dict(self) -> dict:
        d = self._base_state()
        d.update(
            {
                "popsize": self.popsize,
                "sigma0": self.sigma0,
                "restarts": self.restarts,
                "tolx": self.tolx,
                "tolfun": self.tolfun,
                "active": self.active,
                "restarts_done": self.restarts_done,
                "stop_reason": self.stop_reason,
                "run_stops": list(self.run_stops),
                "stopped": self._stopped,
                "lam": self.lam,
                "mean": self.mean.tolist(),
                "sigma": self.sigma,
                "C": self.C.tolist(),
                "pc": self.pc.tolist(),
                "ps": self.ps.tolist(),
                "run_generation": self.run_generation,
                "run_bests": [float_to_json(v) for v in self.run_bests],
                "last_fvals": list(self.last_fvals),
                "rng": self.rng.bit_generator.state,
                "initial_u": self._initial_u.tolist(),
                "inject": self._inject.tolist(),
                "pending": None if self._pending is None else self._pending.tolist(),
                "pending_injected": self._pending_injected,
            }
        )
        return d

    @classmethod
    def from_state(cls, d: dict) -> CMAES:
        w = cls.name
        space = cls._check_state(d, w, cls.STATE_KEYS)
        n = space.n
        opt = cls(
            space,
            seed=d["seed"],
            popsize=saved_value(d, "popsize", w, int, 2, 10**6),
            sigma0=saved_value(d, "sigma0", w, float, 1e-300, 10.0),
            restarts=saved_value(d, "restarts", w, int, 0, 20),
            tolx=saved_value(d, "tolx", w, float, 0.0),
            tolfun=saved_value(d, "tolfun", w, float, 0.0),
            active=saved_active(d, w),
        )
        opt._load_base(d)
        opt.restarts_done = saved_value(d, "restarts_done", w, int, 0, opt.restarts)
        lam = saved_value(d, "lam", w, int, 2, 10**7)
        if lam != opt.popsize * 2**opt.restarts_done:
            raise ClothFitError(f"checkpoint: {w} 'lam' {lam} is not popsize x 2^restarts_done")
        opt._setup(lam)
        opt.stop_reason = saved_stop_reason(d, w, CMA_STOPS)
        rs = saved_field(d, "run_stops", w)
        if not isinstance(rs, list) or len(rs) > opt.restarts + 1 or any(r not in CMA_STOPS for r in rs):
            raise ClothFitError(f"checkpoint: {w} 'run_stops' must be a list of stop criteria")
        opt.run_stops = list(rs)
        opt._stopped = saved_bool(d, "stopped", w)
        opt.mean = saved_array(d, "mean", w, (n,))
        if np.abs(opt.mean).max() > 1e6:
            raise ClothFitError(f"checkpoint: {w} 'mean' is absurdly far from the unit cube")
        opt.sigma = saved_value(d, "sigma", w, float, 1e-300, 1e6)
        if opt.sigma <= 0:
            raise ClothFitError(f"checkpoint: {w} 'sigma' must be positive")
        C = saved_array(d, "C", w, (n, n))
        if not np.array_equal(C, C.T):
            raise ClothFitError(f"checkpoint: {w} 'C' is not symmetric")
        ev = np.linalg.eigvalsh(C)
        if not ev.min() > 0 or ev.max() > 1e12:
            raise ClothFitError(f"checkpoint: {w} 'C' is not a positive-definite covariance matrix")
        opt.C = C
        opt.pc = saved_array(d, "pc", w, (n,))
        opt.ps = saved_array(d, "ps", w, (n,))
        opt.run_generation = saved_value(d, "run_generation", w, int, 0, opt.generation)
        rb = saved_array(d, "run_bests", w, (None,), inf_as_none=True)
        if len(rb) > 2 * opt.stag_window:
            raise ClothFitError(f"checkpoint: {w} 'run_bests' is longer than its window")
        opt.run_bests = rb.tolist()
        opt.last_fvals = saved_array(d, "last_fvals", w, (None,)).tolist()
        if len(opt.last_fvals) > lam:
            raise ClothFitError(f"checkpoint: {w} 'last_fvals' has more values than a generation")
        opt.rng = rng_state_from_json(saved_field(d, "rng", w), w)
        opt._initial_u = saved_array(d, "initial_u", w, (None, n))
        opt._inject = saved_array(d, "inject", w, (None, n))
        opt._pending = saved_array(d, "pending", w, (lam, n), allow_none=True)
        if opt._pending is not None and np.abs(opt._pending).max() > 1e7:
            raise ClothFitError(f"checkpoint: {w} 'pending' is absurdly far from the unit cube")
        opt._pending_injected = saved_value(d, "pending_injected", w, int, 0, lam if opt._pending is not None else 0)
        return opt
