"""Optional numba kernels for the two hot loops: the simulator and the silhouette comparison.

The numpy code in ``simulate.py`` and ``raster.py`` is the reference and runs everywhere (inside
Blender too, which does not ship numba). When numba is importable, these kernels compute the same
quantities with the same formulas (tests check the agreement) an order of magnitude faster, and
run the candidates of a population in parallel threads. Set ``CLOTHFIT_NO_NUMBA=1`` to disable.
"""
from __future__ import annotations

import math
import os

import numpy as np

from . import defaults as D

try:  # pragma: no cover - depends on the environment
    if os.environ.get("CLOTHFIT_NO_NUMBA"):
        raise ImportError("disabled by CLOTHFIT_NO_NUMBA")
    import numba
    from numba import njit, prange
    _HAVE = True
except ImportError:  # pragma: no cover
    numba = None
    _HAVE = False


def available() -> bool:
    return _HAVE


REASONS = ["", "invalid parameters", "non-finite state", "flew away", "spring overstretched", "too many steps"]

if _HAVE:
    _jit = dict(cache=True, nogil=True, fastmath=False)

    @njit(**_jit)
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

    @njit(**_jit)
    def _spring(x, i, j, c, out, q):
        d0 = x[j, 0] - x[i, 0]
        d1 = x[j, 1] - x[i, 1]
        d2 = x[j, 2] - x[i, 2]
        ln = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        w = c[0] * (1.0 - c[1] / max(ln, 1e-12))
        out[q, 0] = w * d0
        out[q, 1] = w * d1
        out[q, 2] = w * d2

    @njit(**_jit)
    def _grid_forces(x, F, fh, fv, fd, nx, ny, kap, L, g):
        """Per-unit-mass forces, in the same order as simulate_numpy: gravity, then the
        horizontal, vertical and diagonal spring families, each computed then scattered."""
        ch = np.array([kap, L])
        cd = np.array([kap, math.sqrt(2.0) * L])
        for i in range(ny):
            for j in range(nx - 1):
                _spring(x, i * nx + j, i * nx + j + 1, ch, fh, i * (nx - 1) + j)
        for i in range(ny - 1):
            for j in range(nx):
                _spring(x, i * nx + j, (i + 1) * nx + j, ch, fv, i * nx + j)
        for i in range(ny - 1):
            for j in range(nx - 1):
                _spring(x, i * nx + j, (i + 1) * nx + j + 1, cd, fd, i * (nx - 1) + j)
        for q in range(x.shape[0]):
            F[q, 0] = g[0]
            F[q, 1] = g[1]
            F[q, 2] = g[2]
        for i in range(ny):
            for j in range(nx - 1):
                q = i * (nx - 1) + j
                for a in range(3):
                    F[i * nx + j, a] += fh[q, a]
                for a in range(3):
                    F[i * nx + j + 1, a] -= fh[q, a]
        for i in range(ny - 1):
            for j in range(nx):
                q = i * nx + j
                for a in range(3):
                    F[i * nx + j, a] += fv[q, a]
                    F[(i + 1) * nx + j, a] -= fv[q, a]
        for i in range(ny - 1):
            for j in range(nx - 1):
                q = i * (nx - 1) + j
                for a in range(3):
                    F[i * nx + j, a] += fd[q, a]
                    F[(i + 1) * nx + j + 1, a] -= fd[q, a]

    @njit(**_jit)
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

    @njit(**_jit)
    def _scatter(F, Fb, n, off):
        for a in range(3):
            for q in range(n):
                F[a, q] += Fb[a, q]
            for q in range(n):
                F[a, q + off] -= Fb[a, q]

    @njit(**_jit)
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

    @njit(**_jit)
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

    @njit(**_jit)
    def simulate_one(par, nx, ny, rest, springs, rest_factor, hv, key_start, key_times, key_pos, release,
                     events, frame_of_event, n_frames, gravity, settle_rate, safety, centre, limit,
                     max_strain, max_steps, out):
        """Simulate one candidate; writes frames into ``out`` (F, V, 3). Returns (code, steps)."""
        m, k, L, dmp = par[0], par[1], par[2], par[3]
        if not (math.isfinite(m) and math.isfinite(k) and math.isfinite(L) and math.isfinite(dmp)) \
                or m <= 0 or k <= 0 or L <= 0 or dmp < 0:
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

    @njit(**_jit)
    def _project(X, K, R, t, dist, uv, ok):
        V = X.shape[0]
        has_dist = False
        for q in range(5):
            if dist[q] != 0.0:
                has_dist = True
        for i in range(V):
            xc = R[0, 0] * X[i, 0] + R[0, 1] * X[i, 1] + R[0, 2] * X[i, 2] + t[0]
            yc = R[1, 0] * X[i, 0] + R[1, 1] * X[i, 1] + R[1, 2] * X[i, 2] + t[1]
            zc = R[2, 0] * X[i, 0] + R[2, 1] * X[i, 1] + R[2, 2] * X[i, 2] + t[2]
            if not (zc > 1e-9) or not math.isfinite(zc):
                ok[i] = False
                uv[i, 0] = np.nan
                uv[i, 1] = np.nan
                continue
            ok[i] = True
            x = xc / zc
            y = yc / zc
            if has_dist:
                k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
                r2 = x * x + y * y
                radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
                xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
                yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
                x = xd
                y = yd
            uv[i, 0] = K[0, 0] * x + K[0, 1] * y + K[0, 2]
            uv[i, 1] = K[1, 1] * y + K[1, 2]

    @njit(**_jit)
    def _span_count(uv, ok, tris, Hh, Ww, pre, pofs, bb, srow, sc0, sc1, cnt, start, oc0, oc1, cntc, trow, tc0, tc1):
        """Model pixel count and overlap with the observation, from row spans only.

        Every triangle is cut into one span per pixel row (pixel-centre sampling, as raster.py);
        spans are sorted by (row, column) with two counting sorts, merged into their union row by
        row, and each union span's overlap with the observed silhouette is read from the
        observation's per-row prefix sums: the cost grows with the number of spans, not pixels.
        """
        n = 0
        rmin = Hh
        rmax = -1
        cmin = Ww
        cmax = -1
        for q in range(tris.shape[0]):
            a = tris[q, 0]
            b = tris[q, 1]
            c = tris[q, 2]
            if not (ok[a] and ok[b] and ok[c]):
                continue
            if (uv[b, 0] - uv[a, 0]) * (uv[c, 1] - uv[a, 1]) - (uv[c, 0] - uv[a, 0]) * (uv[b, 1] - uv[a, 1]) == 0.0:
                continue  # zero-area triangle
            # scanline set-up: vertices sorted by y; the long edge 0-2 and the short edges 0-1, 1-2
            xa, ya, xb, yb, xc, yc = uv[a, 0], uv[a, 1], uv[b, 0], uv[b, 1], uv[c, 0], uv[c, 1]
            if ya > yb:
                xa, ya, xb, yb = xb, yb, xa, ya
            if yb > yc:
                xb, yb, xc, yc = xc, yc, xb, yb
            if ya > yb:
                xa, ya, xb, yb = xb, yb, xa, ya
            if yc == ya:
                continue
            r0 = max(int(math.ceil(ya)), 0)
            r1 = min(int(math.floor(yc)), Hh - 1)
            sl = (xc - xa) / (yc - ya)
            s01 = (xb - xa) / (yb - ya) if yb > ya else 0.0
            s12 = (xc - xb) / (yc - yb) if yc > yb else 0.0
            for r in range(r0, r1 + 1):
                y = float(r)
                x1 = xa + (y - ya) * sl
                if y < yb:
                    x2 = xa + (y - ya) * s01
                else:
                    x2 = xb + (y - yb) * s12
                xl = min(x1, x2)
                xr = max(x1, x2)
                c0 = max(int(math.ceil(xl)), 0)
                c1 = min(int(math.floor(xr)), Ww - 1)
                if c1 < c0:
                    continue
                if n >= srow.shape[0]:
                    return -1, -1
                srow[n] = r
                sc0[n] = c0
                sc1[n] = c1
                n += 1
                if r < rmin:
                    rmin = r
                if r > rmax:
                    rmax = r
                if c0 < cmin:
                    cmin = c0
                if c0 > cmax:
                    cmax = c0
        if n == 0:
            return 0, 0
        # sort the spans by (row, start column): counting sort by column, then a stable one by row
        for x in range(cmin, cmax + 2):
            cntc[x] = 0
        for k in range(n):
            cntc[sc0[k] + 1] += 1
        for x in range(cmin + 1, cmax + 2):
            cntc[x] += cntc[x - 1]
        for k in range(n):
            pos = cntc[sc0[k]]
            cntc[sc0[k]] = pos + 1
            trow[pos] = srow[k]
            tc0[pos] = sc0[k]
            tc1[pos] = sc1[k]
        for r in range(rmin, rmax + 2):
            cnt[r] = 0
        for k in range(n):
            cnt[trow[k] + 1] += 1
        start[rmin] = 0
        for r in range(rmin, rmax + 1):
            start[r + 1] = start[r] + cnt[r + 1]
        for r in range(rmin, rmax + 1):
            cnt[r] = start[r]
        for k in range(n):
            r = trow[k]
            pos = cnt[r]
            oc0[pos] = tc0[k]
            oc1[pos] = tc1[k]
            cnt[r] = pos + 1
        # merge each row's sorted spans into their union; overlap with the observation from the
        # observation's per-row prefix sums (over its bounding box)
        br0, br1, bc0, bc1 = bb[0], bb[1], bb[2], bb[3]
        bw1 = bc1 - bc0 + 2
        nmod = 0
        inter = 0
        for r in range(rmin, rmax + 1):
            s0 = start[r]
            s1 = start[r + 1]
            if s1 == s0:
                continue
            inrow = r >= br0 and r <= br1
            base = pofs + (r - br0) * bw1
            ca = oc0[s0]
            cb = oc1[s0]
            for i in range(s0 + 1, s1 + 1):
                last = i == s1
                if not last and oc0[i] <= cb + 1:
                    if oc1[i] > cb:
                        cb = oc1[i]
                    continue
                nmod += cb - ca + 1
                if inrow:
                    x0 = max(ca, bc0)
                    x1 = min(cb, bc1)
                    if x1 >= x0:
                        inter += pre[base + x1 - bc0 + 1] - pre[base + x0 - bc0]
                if not last:
                    ca = oc0[i]
                    cb = oc1[i]
        return nmod, inter

    @njit(**_jit)
    def eval_frames(X, Ks, Rs, ts, dists, Hs, Ws, pre, pofs, bbs, areas, tris, work, out):
        """E_sil for every camera c and frame f of one simulated candidate: out[c, f]."""
        C = Ks.shape[0]
        Fn = X.shape[0]
        V = X.shape[1]
        uv = np.empty((V, 2))
        ok = np.empty(V, dtype=np.bool_)
        srow, sc0, sc1, cnt, start, oc0, oc1, cntc, trow, tc0, tc1 = work
        for c in range(C):
            for f in range(Fn):
                _project(X[f], Ks[c], Rs[c], ts[c], dists[c], uv, ok)
                nmod, inter = _span_count(uv, ok, tris, Hs[c], Ws[c], pre, pofs[c, f], bbs[c, f], srow, sc0, sc1,
                                          cnt, start, oc0, oc1, cntc, trow, tc0, tc1)
                if nmod < 0:
                    out[c, f] = np.inf
                else:
                    out[c, f] = (areas[c, f] + nmod - 2 * inter) / areas[c, f]

    @njit(parallel=True, cache=True, nogil=True)
    def simulate_population(P, nx, ny, rest, springs, rest_factor, hv, key_start, key_times, key_pos, release,
                            events, frame_of_event, n_frames, gravity, settle_rate, safety, centre, limit,
                            max_strain, max_steps, out, codes, steps):
        for p in prange(P.shape[0]):
            code, st = simulate_one(P[p], nx, ny, rest, springs, rest_factor, hv, key_start, key_times, key_pos,
                                    release, events, frame_of_event, n_frames, gravity, settle_rate, safety,
                                    centre, limit, max_strain, max_steps, out[p])
            codes[p] = code
            steps[p] = st

    @njit(parallel=True, cache=True, nogil=True)
    def objective_population(P, nx, ny, rest, springs, rest_factor, hv, key_start, key_times, key_pos, release,
                             events, frame_of_event, n_frames, gravity, settle_rate, safety, centre, limit,
                             max_strain, max_steps, Ks, Rs, ts, dists, Hs, Ws, pre, pofs, bbs, areas, tris,
                             max_h, max_w, span_cap, esil, codes):
        """Simulate and score every candidate: esil[p, c, f]; codes[p] != 0 = exploded."""
        V = rest.shape[0]
        for p in prange(P.shape[0]):
            X = np.zeros((n_frames, V, 3))
            code, st = simulate_one(P[p], nx, ny, rest, springs, rest_factor, hv, key_start, key_times, key_pos,
                                    release, events, frame_of_event, n_frames, gravity, settle_rate, safety,
                                    centre, limit, max_strain, max_steps, X)
            codes[p] = code
            if code != 0:
                continue
            work = (np.empty(span_cap, dtype=np.int32), np.empty(span_cap, dtype=np.int32),
                    np.empty(span_cap, dtype=np.int32), np.zeros(max_h + 2, dtype=np.int64),
                    np.zeros(max_h + 2, dtype=np.int64), np.empty(span_cap, dtype=np.int32),
                    np.empty(span_cap, dtype=np.int32), np.zeros(max_w + 2, dtype=np.int64),
                    np.empty(span_cap, dtype=np.int32), np.empty(span_cap, dtype=np.int32),
                    np.empty(span_cap, dtype=np.int32))
            eval_frames(X, Ks, Rs, ts, dists, Hs, Ws, pre, pofs, bbs, areas, tris, work, esil[p])


def scenario_arrays(scenario, safety=D.DT_SAFETY):
    """Flatten a Scenario into the plain arrays the kernels take."""
    from .simulate import event_times, explosion_limits
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
    return dict(nx=int(grid.nx), ny=int(grid.ny), rest=np.ascontiguousarray(grid.rest, dtype=np.float64),
                springs=np.ascontiguousarray(grid.springs, dtype=np.int64),
                rest_factor=np.ascontiguousarray(grid.rest_factor, dtype=np.float64),
                hv=hv, key_start=key_start, key_times=np.ascontiguousarray(key_times, dtype=np.float64),
                key_pos=np.ascontiguousarray(key_pos, dtype=np.float64), release=release,
                events=ev, frame_of_event=frame_of_event, n_frames=int(scenario.frame_times.size),
                gravity=np.asarray(scenario.gravity, dtype=np.float64), settle_rate=float(D.SETTLE_DAMPING_RATE),
                safety=float(safety), centre=np.asarray(centre, dtype=np.float64), limit=float(limit),
                max_strain=float(D.MAX_STRAIN), max_steps=int(D.MAX_TOTAL_STEPS))


_ORDER = ["nx", "ny", "rest", "springs", "rest_factor", "hv", "key_start", "key_times", "key_pos", "release", "events",
          "frame_of_event", "n_frames", "gravity", "settle_rate", "safety", "centre", "limit", "max_strain",
          "max_steps"]


def simulate(scenario, P, safety=D.DT_SAFETY):
    from .simulate import SimResult
    P = np.ascontiguousarray(P, dtype=np.float64).reshape(-1, 4)
    a = scenario_arrays(scenario, safety)
    V = a["rest"].shape[0]
    out = np.zeros((P.shape[0], a["n_frames"], V, 3))
    codes = np.zeros(P.shape[0], dtype=np.int64)
    steps = np.zeros(P.shape[0], dtype=np.int64)
    simulate_population(P, *[a[k] for k in _ORDER], out, codes, steps)
    exploded = codes != 0
    out[exploded] = np.nan
    reason = [REASONS[c] for c in codes]
    return SimResult(out, exploded, steps, reason)
