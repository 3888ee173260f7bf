"""numba kernels of the paper's sheet: the simulator of ``paper.simulate_numpy``, one candidate per
thread. Same formulas, same order of operations (tests compare them with the numpy reference).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from .. import defaults as D
from .jit import JIT, PARALLEL, njit, prange
from .paper import SimResult, event_times, explosion_limits
from .scenario import Offsets, Scenario

REASONS = ["", "invalid parameters", "non-finite state", "flew away", "spring overstretched", "too many steps"]

_jit = dict(cache=True, nogil=True, fastmath=False)


@njit(**JIT)
def _handle_at(h, t, key_start, key_times, key_pos, out_p, out_v):
    k0 = key_start[h]
    k1 = key_start[h + 1]
    n = k1 - k0
    for a in range(3):
        out_v[a] = 0.0
    if n == 1 or t <= key_times[k0]:
        for a in range(3):
            out_p[a] = key_pos[k0, a]
        if n > 1 and t == key_times[k0]:
            s = (key_pos[k0 + 1] - key_pos[k0]) / (key_times[k0 + 1] - key_times[k0])
            for a in range(3):
                out_v[a] = s[a]
        return
    if t >= key_times[k1 - 1]:
        for a in range(3):
            out_p[a] = key_pos[k1 - 1, a]
        return
    j = k0
    while key_times[j + 1] <= t:
        j += 1
    w = (t - key_times[j]) / (key_times[j + 1] - key_times[j])
    for a in range(3):
        out_p[a] = key_pos[j, a] + w * (key_pos[j + 1, a] - key_pos[j, a])
        out_v[a] = (key_pos[j + 1, a] - key_pos[j, a]) / (key_times[j + 1] - key_times[j])


@njit(**JIT)
def _family(X, Fb, n, off, rl, kap, mask):
    """Forces of one spring family: pairs (q, q + off) for q < n, masked (0 = no spring)."""
    for q in range(n):
        d0 = X[0, q + off] - X[0, q]
        d1 = X[1, q + off] - X[1, q]
        d2 = X[2, q + off] - X[2, q]
        ln = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        w = kap * (1.0 - rl / max(ln, 1e-12)) * mask[q]
        Fb[0, q] = w * d0
        Fb[1, q] = w * d1
        Fb[2, q] = w * d2


@njit(**JIT)
def _scatter(F, Fb, n, off):
    for a in range(3):
        for q in range(n):
            F[a, q] += Fb[a, q]
        for q in range(n):
            F[a, q + off] -= Fb[a, q]


@njit(**JIT)
def _soa_forces(X, F, Fb, mh, mv, md, nx, V, kap, L, g):
    """Per-unit-mass forces on a structure-of-arrays state X (3, V), in the order of
    simulate_numpy: gravity, then horizontal, vertical and diagonal springs. Each family is
    one contiguous loop over vertex pairs (q, q + offset) with a 0/1 mask for pairs that
    would wrap around a row end, so the loops vectorise."""
    for a in range(3):
        for q in range(V):
            F[a, q] = g[a]
    _family(X, Fb, V - 1, 1, L, kap, mh)
    _scatter(F, Fb, V - 1, 1)
    _family(X, Fb, V - nx, nx, L, kap, mv)
    _scatter(F, Fb, V - nx, nx)
    _family(X, Fb, V - nx - 1, nx + 1, math.sqrt(2.0) * L, kap, md)
    _scatter(F, Fb, V - nx - 1, nx + 1)


@njit(**JIT)
def _max_strain(x, springs, rest_factor, L):
    r = 0.0
    for s in range(springs.shape[0]):
        i = springs[s, 0]
        j = springs[s, 1]
        d0 = x[j, 0] - x[i, 0]
        d1 = x[j, 1] - x[i, 1]
        d2 = x[j, 2] - x[i, 2]
        q = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) / (rest_factor[s] * L)
        if q > r:
            r = q
    return r


@njit(**JIT)
def simulate_one(
    par,
    nx,
    ny,
    rest,
    springs,
    rest_factor,
    hv,
    key_start,
    key_times,
    key_pos,
    release,
    events,
    frame_of_event,
    n_frames,
    gravity,
    settle_rate,
    safety,
    centre,
    limit,
    max_strain,
    max_steps,
    out,
):
    """Simulate one candidate; writes frames into ``out`` (F, V, 3). Returns (code, steps)."""
    m, k, L, dmp = par[0], par[1], par[2], par[3]
    if (
        not (math.isfinite(m) and math.isfinite(k) and math.isfinite(L) and math.isfinite(dmp))
        or m <= 0
        or k <= 0
        or L <= 0
        or dmp < 0
    ):
        return 1, 0
    kap = k / m
    beta = dmp / m
    V = rest.shape[0]
    X = np.ascontiguousarray(rest.T)
    Vv = np.zeros((3, V))
    F = np.zeros((3, V))
    Fb = np.zeros((3, V))
    mh = np.ones(V)
    md = np.ones(V)
    for q in range(V):
        if q % nx == nx - 1:
            mh[q] = 0.0
            md[q] = 0.0
    mv = np.ones(V)
    p = np.zeros(3)
    pv = np.zeros(3)
    H = hv.shape[0]
    for h in range(H):
        _handle_at(h, events[0], key_start, key_times, key_pos, p, pv)
        for a in range(3):
            X[a, hv[h]] = p[a]
    dt_max = safety * math.sqrt(m / k)
    steps = 0
    for e in range(events.shape[0] - 1):
        a0 = events[e]
        b0 = events[e + 1]
        seg = b0 - a0
        n_full = int(math.floor(seg / dt_max))
        rem = seg - n_full * dt_max
        if rem <= 1e-12 * seg:
            rem = 0.0
        nsub = n_full + (1 if rem > 0.0 else 0)
        if steps + nsub > max_steps:
            return 5, steps
        settling = b0 <= 0.0
        rate = max(beta, settle_rate) if settling else beta
        for s in range(nsub):
            if s < n_full:
                dt = dt_max
                tc = a0 + (s + 1) * dt_max
            else:
                dt = rem
                tc = b0
            damp = 1.0 / (1.0 + dt * rate)
            _soa_forces(X, F, Fb, mh, mv, md, nx, V, kap, L, gravity)
            for a in range(3):
                for i in range(V):
                    Vv[a, i] = (Vv[a, i] + dt * F[a, i]) * damp
                    X[a, i] = X[a, i] + dt * Vv[a, i]
            for h in range(H):
                if settling or tc <= release[h]:
                    _handle_at(h, tc, key_start, key_times, key_pos, p, pv)
                    for a in range(3):
                        X[a, hv[h]] = p[a]
                        Vv[a, hv[h]] = pv[a]
        steps += nsub
        # explosion checks once per interval
        far = 0.0
        for a in range(3):
            for i in range(V):
                if not (math.isfinite(X[a, i]) and math.isfinite(Vv[a, i])):
                    return 2, steps
                dd = abs(X[a, i] - centre[a])
                if dd > far:
                    far = dd
        if far > limit:
            return 3, steps
        xt = X.T
        if _max_strain(xt, springs, rest_factor, L) > 1.0 + max_strain:
            return 4, steps
        f = frame_of_event[e + 1]
        if f >= 0:
            out[f] = xt
    return 0, steps


@njit(**JIT)
def simulate_candidate(row, sheet, moves, p, out):
    """Candidate ``p`` of a population (``row``: its m, k, l, d; its own handle keys ``moves.key_pos[p]`` and
    events ``moves.events[p, :moves.n_events[p]]``) simulated into ``out`` (n_frames, V, 3): (code, steps)."""
    (
        nx,
        ny,
        rest,
        springs,
        rest_factor,
        hv,
        key_start,
        key_times,
        release,
        n_frames,
        gravity,
        settle_rate,
        safety,
        centre,
        limit,
        max_strain,
        max_steps,
    ) = sheet
    key_pos, events, n_events, frame_of_event = moves
    ne = n_events[p]
    return simulate_one(
        row,
        nx,
        ny,
        rest,
        springs,
        rest_factor,
        hv,
        key_start,
        key_times,
        key_pos[p],
        release,
        events[p, :ne],
        frame_of_event[p, :ne],
        n_frames,
        gravity,
        settle_rate,
        safety,
        centre,
        limit,
        max_strain,
        max_steps,
        out,
    )


@njit(**PARALLEL)
def simulate_population(P, sheet, moves, out, codes, steps):
    """Every candidate p with its own handle keys ``key_pos[p]`` and events ``events[p, :n_events[p]]``
    (a fit of an uncertain manipulation; otherwise all the same)."""
    for p in prange(P.shape[0]):
        code, st = simulate_candidate(P[p], sheet, moves, p, out[p])
        codes[p] = code
        steps[p] = st


def scenario_arrays(scenario: Scenario, safety: float = D.DT_SAFETY) -> dict[str, Any]:
    """Flatten a Scenario into the plain arrays the kernels take."""
    grid = scenario.grid
    hs = scenario.handles
    hv = np.array([h.vertex for h in hs], dtype=np.int64)
    key_start = np.zeros(len(hs) + 1, dtype=np.int64)
    for i, h in enumerate(hs):
        key_start[i + 1] = key_start[i] + h.times.size
    key_times = np.concatenate([h.times for h in hs]) if hs else np.zeros(1)
    key_pos = np.concatenate([h.positions for h in hs]) if hs else np.zeros((1, 3))
    release = np.array([np.inf if h.release_time is None else h.release_time for h in hs], dtype=np.float64)
    ev = event_times(scenario)
    frame_of_event = np.full(ev.size, -1, dtype=np.int64)
    lookup = {round(float(t), 12): i for i, t in enumerate(scenario.frame_times)}
    for e, t in enumerate(ev):
        frame_of_event[e] = lookup.get(round(float(t), 12), -1)
    centre, limit = explosion_limits(scenario)
    return dict(
        nx=int(grid.nx),
        ny=int(grid.ny),
        rest=np.ascontiguousarray(grid.rest, dtype=np.float64),
        springs=np.ascontiguousarray(grid.springs, dtype=np.int64),
        rest_factor=np.ascontiguousarray(grid.rest_factor, dtype=np.float64),
        hv=hv,
        key_start=key_start,
        key_times=np.ascontiguousarray(key_times, dtype=np.float64),
        key_pos=np.ascontiguousarray(key_pos, dtype=np.float64),
        release=release,
        events=ev,
        frame_of_event=frame_of_event,
        n_frames=int(scenario.frame_times.size),
        gravity=np.asarray(scenario.gravity, dtype=np.float64),
        settle_rate=float(D.SETTLE_DAMPING_RATE),
        safety=float(safety),
        centre=np.asarray(centre, dtype=np.float64),
        limit=float(limit),
        max_strain=float(D.MAX_STRAIN),
        max_steps=int(D.MAX_TOTAL_STEPS),
    )


class Sheet(NamedTuple):
    """What the kernel reads of a scenario, the same for every candidate (``scenario_arrays``): the grid
    (``nx`` x ``ny``, rest positions, springs and their rest-length factors), the handles' vertices, key
    times (``key_start``: each handle's first key) and release times, the frames, gravity, the settle's
    damping rate, the time step's safety factor and the explosion test (centre, distance limit, largest
    strain, most steps)."""

    nx: int
    ny: int
    rest: np.ndarray
    springs: np.ndarray
    rest_factor: np.ndarray
    hv: np.ndarray
    key_start: np.ndarray
    key_times: np.ndarray
    release: np.ndarray
    n_frames: int
    gravity: np.ndarray
    settle_rate: float
    safety: float
    centre: np.ndarray
    limit: float
    max_strain: float
    max_steps: int


class Moves(NamedTuple):
    """Each candidate's own manipulation (``population_arrays``): handle key positions (P, K, 3), event
    times (P, E) of which the first ``n_events[p]`` count, and the frame each event is (or -1)."""

    key_pos: np.ndarray
    events: np.ndarray
    n_events: np.ndarray
    frame_of_event: np.ndarray


def population_arrays(
    scenario: Scenario, n: int, safety: float = D.DT_SAFETY, offsets: Offsets | None = None
) -> dict[str, Any]:
    """``scenario_arrays`` for ``n`` candidates: ``key_pos`` (n, K, 3), ``events`` and
    ``frame_of_event`` (n, E) and ``n_events`` (n,) per candidate: the same for all, or each
    candidate's own manipulation (``scenario.Offsets``: its frames read earlier by its time offset,
    its handles moved)."""
    a = scenario_arrays(scenario, safety)
    if offsets is None:
        a["key_pos"] = np.ascontiguousarray(np.broadcast_to(a["key_pos"], (n,) + a["key_pos"].shape))
        a["events"] = np.ascontiguousarray(np.broadcast_to(a["events"], (n,) + a["events"].shape))
        a["frame_of_event"] = np.ascontiguousarray(
            np.broadcast_to(a["frame_of_event"], (n,) + a["frame_of_event"].shape)
        )
        a["n_events"] = np.full(n, a["events"].shape[1], dtype=np.int64)
        return a
    per = [scenario_arrays(scenario.moved(offsets.time[p], offsets.handles[p]), safety) for p in range(n)]
    E = max(q["events"].size for q in per)
    ev = np.zeros((n, E))
    foe = np.full((n, E), -1, dtype=np.int64)
    for p, q in enumerate(per):
        ev[p, : q["events"].size] = q["events"]
        foe[p, : q["events"].size] = q["frame_of_event"]
    a.update(
        key_pos=np.ascontiguousarray([q["key_pos"] for q in per]),
        events=ev,
        frame_of_event=foe,
        n_events=np.array([q["events"].size for q in per], dtype=np.int64),
    )
    return a


def kernel_inputs(a: dict[str, Any]) -> tuple[Sheet, Moves]:
    """``population_arrays``' dict as the kernels take it: the scenario's ``Sheet``, the candidates' ``Moves``."""
    return Sheet(*(a[k] for k in Sheet._fields)), Moves(*(a[k] for k in Moves._fields))


def simulate(
    scenario: Scenario, P: ArrayLike, safety: float = D.DT_SAFETY, offsets: Offsets | None = None
) -> SimResult:
    P = np.ascontiguousarray(P, dtype=np.float64).reshape(-1, 4)
    a = population_arrays(scenario, P.shape[0], safety, offsets)
    V = a["rest"].shape[0]
    out = np.zeros((P.shape[0], a["n_frames"], V, 3))
    codes = np.zeros(P.shape[0], dtype=np.int64)
    steps = np.zeros(P.shape[0], dtype=np.int64)
    simulate_population(P, *kernel_inputs(a), out, codes, steps)
    exploded = codes != 0
    out[exploded] = np.nan
    reason = [REASONS[c] for c in codes]
    return SimResult(out, exploded, steps, reason)
