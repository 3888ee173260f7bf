"""numba kernels of the silhouette comparison (``raster.py`` is their numpy reference): project a
mesh, cut its triangles into pixel-row spans, and count model pixels and their overlap with an
observed silhouette from the observation's per-row prefix sums; model pixels inside the image's
ignore mask (pixels of unknown truth, e.g. behind an occluder) are counted from the ignore mask's
prefix sums in the same way and leave the XOR.
"""

from __future__ import annotations

import math

import numpy as np

from ..physics.jit import JIT, njit


@njit(**JIT)
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


@njit(**JIT)
def _span_count(
    uv, ok, tris, Hh, Ww, pre, pofs, bb, ipre, ipofs, ibb, srow, sc0, sc1, cnt, start, oc0, oc1, cntc, trow, tc0, tc1
):
    """Model pixel count, overlap with the observation and overlap with the ignore mask, from row
    spans only (an image without ignore mask has an empty box ``ibb``: rows 0..-1).

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
                return -1, -1, -1
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
        return 0, 0, 0
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
    ir0, ir1, ic0, ic1 = ibb[0], ibb[1], ibb[2], ibb[3]
    iw1 = ic1 - ic0 + 2
    nmod = 0
    inter = 0
    hid = 0
    for r in range(rmin, rmax + 1):
        s0 = start[r]
        s1 = start[r + 1]
        if s1 == s0:
            continue
        inrow = r >= br0 and r <= br1
        base = pofs + (r - br0) * bw1
        ignrow = r >= ir0 and r <= ir1
        ibase = ipofs + (r - ir0) * iw1
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
            if ignrow:
                x0 = max(ca, ic0)
                x1 = min(cb, ic1)
                if x1 >= x0:
                    hid += ipre[ibase + x1 - ic0 + 1] - ipre[ibase + x0 - ic0]
            if not last:
                ca = oc0[i]
                cb = oc1[i]
    return nmod, inter, hid


@njit(**JIT)
def eval_frames(X, Ks, Rs, ts, dists, Hs, Ws, pre, pofs, bbs, ipre, ipofs, ibbs, areas, tris, work, out):
    """E_sil for every camera c and frame f of one simulated candidate: out[c, f]. ``areas`` are the
    observed silhouettes' areas outside their ignore masks (eq. 6's normaliser)."""
    C = Ks.shape[0]
    Fn = X.shape[0]
    V = X.shape[1]
    uv = np.empty((V, 2))
    ok = np.empty(V, dtype=np.bool_)
    srow, sc0, sc1, cnt, start, oc0, oc1, cntc, trow, tc0, tc1 = work
    for c in range(C):
        for f in range(Fn):
            _project(X[f], Ks[c], Rs[c], ts[c], dists[c], uv, ok)
            nmod, inter, hid = _span_count(
                uv,
                ok,
                tris,
                Hs[c],
                Ws[c],
                pre,
                pofs[c, f],
                bbs[c, f],
                ipre,
                ipofs[c, f],
                ibbs[c, f],
                srow,
                sc0,
                sc1,
                cnt,
                start,
                oc0,
                oc1,
                cntc,
                trow,
                tc0,
                tc1,
            )
            if nmod < 0:
                out[c, f] = np.inf
            else:
                out[c, f] = (areas[c, f] + nmod - hid - 2 * inter) / areas[c, f]
