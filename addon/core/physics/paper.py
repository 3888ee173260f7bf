"""The paper's mass-spring sheet (docs/method.md#spec-2): parameters, identifiability and the numpy reference
simulator (vectorised over candidates; ``paper_kernels`` is its numba twin).

Parameters (per point mass / per spring): point mass ``m`` [kg], spring coefficient ``k`` [N/m],
natural length ``l`` [m] of the grid-aligned springs (diagonals rest at ``sqrt(2) l``), viscous
damping ``d`` [N s/m] (force ``-d v_i``). The equations of motion divided by ``m`` only contain
``k/m``, ``d/m`` and ``l``: those are what silhouettes can identify (see ``identifiable``).


Integrator (part of the model, docs/method.md#spec-2):

* semi-implicit (symplectic) Euler with the viscous damping treated implicitly::

      v <- (v + dt * (g + sum_j (k/m) (|p_j - p_i| - l_ij) e_ij)) / (1 + dt * d/m)
      p <- p + dt * v

  held handles are then set to their prescribed position and velocity;
* per candidate, the step is ``dt = DT_SAFETY * sqrt(m/k)`` (the stability bound of a node with
  6 springs is 2/sqrt(12) = 0.58 sqrt(m/k)); every interval between consecutive event times (start
  of settling, 0, release times, handle keys, frame times) is covered by whole steps of ``dt`` and
  one shorter remainder step that lands exactly on the event. Unlike "split the interval into
  ceil(len/dt) equal steps", this makes the simulated motion a *continuous* function of k/m: the
  number of steps never jumps (an earlier equal-split version of this simulator, not kept, moved the
  cloth by about 0.1 mm for a 1e-4 relative change of k; now it is 1e-5 m: lab/sensitivity.py);
* before t = 0 the cloth settles for ``settle_time`` with every handle held and damping rate
  ``max(d/m, SETTLE_DAMPING_RATE)``: the rest shape does not depend on d, this only gets there fast;
* a candidate whose state goes non-finite, stretches a spring beyond ``1 + MAX_STRAIN`` times its
  rest length, or flies further than ``EXPLODE_FACTOR`` cloth sizes away is flagged ``exploded``
  and frozen: never an exception.

Only k/m, d/m and l enter the equations (``model.identifiable``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from ..errors import ClothFitError
from .scenario import ClothGrid, Scenario

PARAM_NAMES = ("m", "k", "l", "d")


@dataclass
class Params:
    m: float
    k: float
    l: float
    d: float

    def as_dict(self) -> dict[str, float]:
        return {n: float(getattr(self, n)) for n in PARAM_NAMES}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "parameters") -> Params:
        try:
            p = cls(*(float(d[n]) for n in PARAM_NAMES))
        except KeyError as e:
            raise ClothFitError(f"{source}: missing parameter {e.args[0]!r} (need m, k, l, d)") from None
        except (TypeError, ValueError) as e:
            raise ClothFitError(f"{source}: parameters must be numbers ({e})") from None
        p.check(source)
        return p

    def check(self, source: str = "parameters") -> None:
        for n in PARAM_NAMES:
            v = getattr(self, n)
            if not math.isfinite(v):
                raise ClothFitError(f"{source}: {n} = {v} is not finite")
        if self.m <= 0 or self.k <= 0 or self.l <= 0:
            raise ClothFitError(f"{source}: m, k and l must be positive (m={self.m}, k={self.k}, l={self.l})")
        if self.d < 0:
            raise ClothFitError(f"{source}: damping d = {self.d} must be >= 0")

    def identifiable(self) -> dict[str, float]:
        return identifiable(self.as_dict())


def identifiable(p: dict) -> dict:
    """The combinations the motion depends on: k/m [1/s^2], d/m [1/s], l [m]."""
    return {"k_over_m": p["k"] / p["m"], "d_over_m": p["d"] / p["m"], "l": p["l"]}


def identifiable_errors(est: dict, true: dict) -> dict:
    """Relative recovery error [%] of each identifiable quantity."""
    a, b = identifiable(est), identifiable(true)
    return {k: 100.0 * abs(a[k] - b[k]) / abs(b[k]) for k in a}


@dataclass
class SimResult:
    positions: np.ndarray  # (P, F, V, 3), NaN for exploded candidates
    exploded: np.ndarray  # (P,) bool
    substeps: np.ndarray  # (P,) total number of integration steps per candidate
    reason: list  # per candidate: "" or why it was flagged


def as_params(params: Any) -> np.ndarray:
    """(P, 4) array of m, k, l, d from a Params, dict, list of those or an array."""
    if hasattr(params, "as_dict"):
        params = [params]
    elif isinstance(params, dict):
        params = [params]
    arr = []
    for p in params:
        if hasattr(p, "as_dict"):
            p = p.as_dict()
        if isinstance(p, dict):
            p = [p["m"], p["k"], p["l"], p["d"]]
        arr.append(np.asarray(p, dtype=np.float64).reshape(4))
    arr = np.array(arr, dtype=np.float64).reshape(-1, 4)
    return arr


def event_times(scenario: Scenario) -> np.ndarray:
    ev = {-scenario.settle_time, 0.0}
    ev.update(float(t) for t in scenario.frame_times)
    for h in scenario.handles:
        ev.update(float(t) for t in h.times if -scenario.settle_time < t <= scenario.frame_times[-1])
        if h.release_time is not None and -scenario.settle_time < h.release_time <= scenario.frame_times[-1]:
            ev.add(float(h.release_time))
    ev = np.array(sorted(ev))
    return ev[ev >= -scenario.settle_time - 1e-15]


def step_plan(
    params: np.ndarray, seg_len: float, safety: float = D.DT_SAFETY
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per candidate: step ``dt``, number of whole steps, remainder step (0 = none) for an interval."""
    m, k = params[:, 0], params[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = safety * np.sqrt(m / k)
    dt = np.where(np.isfinite(dt) & (dt > 0), dt, seg_len)
    n_full = np.floor(seg_len / dt).astype(np.int64)
    rem = seg_len - n_full * dt
    rem = np.where(rem > 1e-12 * seg_len, rem, 0.0)
    return dt, n_full, rem


MAX_TOTAL_STEPS = D.MAX_TOTAL_STEPS


def check_params(params: np.ndarray) -> np.ndarray:
    bad = (
        ~np.all(np.isfinite(params), axis=1)
        | (params[:, 0] <= 0)
        | (params[:, 1] <= 0)
        | (params[:, 2] <= 0)
        | (params[:, 3] < 0)
    )
    return bad


def _handle_tables(scenario):
    hv = np.array([h.vertex for h in scenario.handles], dtype=np.int64)
    return hv


def handle_state(scenario: Scenario, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (..., H, 3), velocities and held mask (..., H) of the handles at times ``t``."""
    t = np.asarray(t, dtype=np.float64)
    pos = np.stack([h.position(t) for h in scenario.handles], -2) if scenario.handles else np.zeros(t.shape + (0, 3))
    vel = np.stack([h.velocity(t) for h in scenario.handles], -2) if scenario.handles else np.zeros(t.shape + (0, 3))
    held = (
        np.stack([h.held(t) | (t < 0) for h in scenario.handles], -1)
        if scenario.handles
        else np.zeros(t.shape + (0,), bool)
    )
    return pos, vel, held


def initial_state(scenario: Scenario, n: int) -> tuple[np.ndarray, np.ndarray]:
    x = np.broadcast_to(scenario.grid.rest, (n,) + scenario.grid.rest.shape).copy()
    t0 = -scenario.settle_time
    if scenario.handles:
        pos, _, _ = handle_state(scenario, np.array(t0))
        hv = _handle_tables(scenario)
        x[:, hv] = pos
    return x, np.zeros_like(x)


def explosion_limits(scenario: Scenario) -> tuple[np.ndarray, float]:
    g = scenario.grid
    size = max(g.side, g.side_y)
    if scenario.handles:
        centre = np.mean([h.positions.mean(0) for h in scenario.handles], axis=0)
        span = max(np.ptp(np.concatenate([h.positions for h in scenario.handles]), axis=0).max(), 0.0)
    else:
        centre = g.rest.mean(0)
        span = 0.0
    return centre, D.EXPLODE_FACTOR * (size + span)


def simulate_numpy(scenario: Scenario, P: np.ndarray, safety: float = D.DT_SAFETY) -> SimResult:
    grid = scenario.grid
    nP = P.shape[0]
    ny, nx = grid.ny, grid.nx
    bad_param = check_params(P)
    Pw = P.copy()
    Pw[bad_param] = [1.0, 1.0, 1.0, 0.0]
    kap = (Pw[:, 1] / Pw[:, 0])[:, None, None, None]
    beta = Pw[:, 3] / Pw[:, 0]
    L = Pw[:, 2][:, None, None]
    sq2 = math.sqrt(2.0)
    g = scenario.gravity
    hv = _handle_tables(scenario)
    hi, hj = hv // nx, hv % nx
    centre, limit = explosion_limits(scenario)

    x, v = initial_state(scenario, nP)
    x = x.reshape(nP, ny, nx, 3)
    v = v.reshape(nP, ny, nx, 3)
    exploded = bad_param.copy()
    reason = ["invalid parameters" if b else "" for b in bad_param]
    out = np.full((nP, scenario.frame_times.size, ny * nx, 3), np.nan)
    steps_total = np.zeros(nP, dtype=np.int64)
    ev = event_times(scenario)
    frame_idx = {round(float(t), 12): i for i, t in enumerate(scenario.frame_times)}
    F = np.empty_like(x)

    for a, b in zip(ev[:-1], ev[1:]):
        seg = b - a
        dtf, n_full, rem = step_plan(Pw, seg, safety)
        nsub = n_full + (rem > 0)
        stiff = ~exploded & (steps_total + nsub > MAX_TOTAL_STEPS)
        for p in np.nonzero(stiff)[0]:
            reason[p] = f"too many steps (k/m = {kap[p, 0, 0, 0]:.3g} is too stiff)"
        exploded |= stiff
        nsub = np.where(exploded, 0, nsub)
        settling = b <= 0.0
        rate = np.maximum(beta, D.SETTLE_DAMPING_RATE) if settling else beta
        for s in range(int(nsub.max(initial=0))):
            active = (s < nsub) & ~exploded
            if not active.any():
                break
            dt = np.where(s < n_full, dtf, rem)
            dta = np.where(active, dt, 0.0)
            damp = 1.0 / (1.0 + dta * rate)
            F[:] = g
            d = x[:, :, 1:] - x[:, :, :-1]
            ln = np.sqrt(np.einsum("...i,...i->...", d, d))[..., None]
            f = kap * (1.0 - L[..., None] / np.maximum(ln, 1e-12)) * d
            F[:, :, :-1] += f
            F[:, :, 1:] -= f
            d = x[:, 1:, :] - x[:, :-1, :]
            ln = np.sqrt(np.einsum("...i,...i->...", d, d))[..., None]
            f = kap * (1.0 - L[..., None] / np.maximum(ln, 1e-12)) * d
            F[:, :-1, :] += f
            F[:, 1:, :] -= f
            d = x[:, 1:, 1:] - x[:, :-1, :-1]
            ln = np.sqrt(np.einsum("...i,...i->...", d, d))[..., None]
            f = kap * (1.0 - sq2 * L[..., None] / np.maximum(ln, 1e-12)) * d
            F[:, :-1, :-1] += f
            F[:, 1:, 1:] -= f
            dtb = dta[:, None, None, None]
            v = (v + dtb * F) * damp[:, None, None, None]
            x = x + dtb * v
            if hv.size:
                tc = np.where(s < n_full, a + (s + 1) * dtf, b)
                pos, vel, held = handle_state(scenario, tc)  # (P, H, 3), (P, H)
                if settling:
                    held = np.ones_like(held)
                m = held & active[:, None]
                if m.any():
                    pi, hk = np.nonzero(m)
                    x[pi, hi[hk], hj[hk]] = pos[pi, hk]
                    v[pi, hi[hk], hj[hk]] = vel[pi, hk]
        steps_total += np.where(exploded, 0, nsub)
        # explosion checks once per interval
        flat = x.reshape(nP, -1, 3)
        fin = np.all(np.isfinite(flat), axis=(1, 2)) & np.all(np.isfinite(v.reshape(nP, -1)), axis=1)
        far = np.zeros(nP, bool)
        far[fin] = np.abs(flat[fin] - centre).max(axis=(1, 2)) > limit
        strain = np.zeros(nP, bool)
        if fin.any():
            strain[fin] = _max_strain(x[fin], Pw[fin, 2]) > 1.0 + D.MAX_STRAIN
        newbad = ~exploded & (~fin | far | strain)
        for p in np.nonzero(newbad)[0]:
            reason[p] = (
                f"exploded before t = {b:.3f} s ("
                + ("non-finite state" if not fin[p] else "flew away" if far[p] else "spring overstretched")
                + ")"
            )
        exploded |= newbad
        x[exploded] = 0.0
        v[exploded] = 0.0
        fi = frame_idx.get(round(float(b), 12))
        if fi is not None:
            ok = ~exploded
            if ok.any():
                out[ok, fi] = x[ok].reshape(int(ok.sum()), ny * nx, 3)
    out[exploded] = np.nan
    return SimResult(out, exploded, steps_total, reason)


def _max_strain(x, L):
    """Largest length / rest-length ratio over the springs, per candidate."""
    r = []
    for d, fac in (
        (x[:, :, 1:] - x[:, :, :-1], 1.0),
        (x[:, 1:, :] - x[:, :-1, :], 1.0),
        (x[:, 1:, 1:] - x[:, :-1, :-1], math.sqrt(2.0)),
    ):
        ln = np.sqrt((d * d).sum(-1)).reshape(len(x), -1).max(1)
        r.append(ln / (fac * L))
    return np.max(r, axis=0)


def spring_energy(x: np.ndarray, grid: ClothGrid, k: float, l: float) -> float:
    """Elastic energy of one configuration ``x`` (V, 3): sum 1/2 k (|e| - l_ij)^2."""
    s = grid.springs
    ln = np.linalg.norm(x[s[:, 1]] - x[s[:, 0]], axis=1)
    return float(0.5 * k * np.sum((ln - l * grid.rest_factor) ** 2))


def spring_forces(x: np.ndarray, grid: ClothGrid, k: float, l: float) -> np.ndarray:
    """Spring forces on each vertex of one configuration (V, 3), from the spring list."""
    s = grid.springs
    d = x[s[:, 1]] - x[s[:, 0]]
    ln = np.linalg.norm(d, axis=1)
    f = (k * (ln - l * grid.rest_factor) / np.maximum(ln, 1e-12))[:, None] * d
    F = np.zeros_like(x)
    np.add.at(F, s[:, 0], f)
    np.add.at(F, s[:, 1], -f)
    return F
