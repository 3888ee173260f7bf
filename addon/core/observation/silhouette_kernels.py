"""numba kernels of the silhouette comparison (``raster.py`` is their numpy reference): project a
mesh, cut its quads (or triangles) into pixel-row spans, set the spans' pixels in rows of 64-bit
words, and count the model's pixels and their overlap with the observed silhouette, packed the same
way, by population counts; model pixels inside the image's ignore mask (pixels of unknown truth, e.g.
behind an occluder), packed likewise, are counted in the same pass and leave the XOR.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..physics.jit import JIT, njit

ALL = np.uint64(0xFFFFFFFFFFFFFFFF)
M1 = np.uint64(0x5555555555555555)
M2 = np.uint64(0x3333333333333333)
M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
H01 = np.uint64(0x0101010101010101)


def pack_rows(images: Sequence[np.ndarray | None], C: int, F: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each image (``images[c * F + f]``, None = nothing) as rows of little-endian 64-bit words over its
    bounding box (the words holding its first to its last column; bit k of word w is column 64 w + k):
    ``(bits, offsets (C, F), boxes (C, F, 4) r0 r1 c0 c1)``; an empty image gets the rows 0..-1."""
    offs = np.zeros((C, F), dtype=np.int64)
    boxes = np.zeros((C, F, 4), dtype=np.int64)
    boxes[:, :, 1] = -1
    boxes[:, :, 3] = -1
    parts, o = [np.zeros(1, dtype=np.uint64)], 1
    for c in range(C):
        for f in range(F):
            im = images[c * F + f]
            if im is None or not im.any():
                continue
            rows = np.flatnonzero(im.any(1))
            cols = np.flatnonzero(im.any(0))
            r0, r1, c0, c1 = rows[0], rows[-1], cols[0], cols[-1]
            w0, w1 = c0 // 64, c1 // 64
            box = np.zeros((r1 - r0 + 1, 64 * (w1 - w0 + 1)), dtype=bool)
            part = im[r0 : r1 + 1, 64 * w0 : 64 * (w1 + 1)]
            box[:, : part.shape[1]] = part
            words = np.packbits(box, axis=1, bitorder="little").view("<u8").astype(np.uint64)
            offs[c, f] = o
            boxes[c, f] = (r0, r1, c0, c1)
            parts.append(words.ravel())
            o += words.size
    return np.concatenate(parts), offs, boxes


@njit(**JIT)
def _ones(x):
    """The number of set bits of the 64-bit word ``x``, as a signed integer (the counts it adds to stay integers:
    numba, as numpy, makes a float of a signed and an unsigned integer added)."""
    x = x - ((x >> np.uint64(1)) & M1)
    x = (x & M2) + ((x >> np.uint64(2)) & M2)
    x = (x + (x >> np.uint64(4))) & M4
    return np.int64((x * H01) >> np.uint64(56))


@njit(**JIT)
def _fill(rows, r, c0, c1, ext):
    """Set the pixels c0..c1 of row r in ``rows`` (one row of 64-bit words per pixel row); ``ext`` keeps
    the rows and words touched (r min, r max, w min, w max)."""
    w0 = c0 >> 6
    w1 = c1 >> 6
    lo = ALL << np.uint64(c0 & 63)
    hi = ALL >> np.uint64(63 - (c1 & 63))
    if w0 == w1:
        rows[r, w0] |= lo & hi
    else:
        rows[r, w0] |= lo
        for w in range(w0 + 1, w1):
            rows[r, w] = ALL
        rows[r, w1] |= hi
    if r < ext[0]:
        ext[0] = r
    if r > ext[1]:
        ext[1] = r
    if w0 < ext[2]:
        ext[2] = w0
    if w1 > ext[3]:
        ext[3] = w1


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
def _tri_spans(xa, ya, xb, yb, xc, yc, Hh, Ww, rows, ext):
    """Set one triangle's pixels (pixel-centre sampling, as raster.py)."""
    if (xb - xa) * (yc - ya) - (xc - xa) * (yb - ya) == 0.0:
        return  # zero-area triangle
    # scanline set-up: vertices sorted by y; the long edge 0-2 and the short edges 0-1, 1-2
    if ya > yb:
        xa, ya, xb, yb = xb, yb, xa, ya
    if yb > yc:
        xb, yb, xc, yc = xc, yc, xb, yb
    if ya > yb:
        xa, ya, xb, yb = xb, yb, xa, ya
    if yc == ya:
        return
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
        if c1 >= c0:
            _fill(rows, r, c0, c1, ext)


@njit(**JIT)
def _quad_spans(uv, a, b, c, d, Hh, Ww, rows, ext):
    """Set one quad's pixels: one span per row where it projects convex (the union of its two
    triangles' spans), else its triangles ``a b c`` and ``a c d``'s."""
    xa, ya, xb, yb = uv[a, 0], uv[a, 1], uv[b, 0], uv[b, 1]
    xc, yc, xd, yd = uv[c, 0], uv[c, 1], uv[d, 0], uv[d, 1]
    t0 = (xb - xa) * (yc - yb) - (yb - ya) * (xc - xb)
    t1 = (xc - xb) * (yd - yc) - (yc - yb) * (xd - xc)
    t2 = (xd - xc) * (ya - yd) - (yd - yc) * (xa - xd)
    t3 = (xa - xd) * (yb - ya) - (ya - yd) * (xb - xa)
    if not ((t0 > 0 and t1 > 0 and t2 > 0 and t3 > 0) or (t0 < 0 and t1 < 0 and t2 < 0 and t3 < 0)):
        _tri_spans(xa, ya, xb, yb, xc, yc, Hh, Ww, rows, ext)
        _tri_spans(xa, ya, xc, yc, xd, yd, Hh, Ww, rows, ext)
        return
    ylo = min(min(ya, yb), min(yc, yd))
    yhi = max(max(ya, yb), max(yc, yd))
    r0 = max(int(math.ceil(ylo)), 0)
    r1 = min(int(math.floor(yhi)), Hh - 1)
    for r in range(r0, r1 + 1):
        y = float(r)
        xl = math.inf
        xr = -math.inf
        for e in range(4):
            if e == 0:
                x0, y0, x1, y1 = xa, ya, xb, yb
            elif e == 1:
                x0, y0, x1, y1 = xb, yb, xc, yc
            elif e == 2:
                x0, y0, x1, y1 = xc, yc, xd, yd
            else:
                x0, y0, x1, y1 = xd, yd, xa, ya
            if y0 == y1 or y < min(y0, y1) or y > max(y0, y1):
                continue
            x = x0 + (y - y0) * ((x1 - x0) / (y1 - y0))
            if x < xl:
                xl = x
            if x > xr:
                xr = x
        c0 = max(int(math.ceil(xl)), 0)
        c1 = min(int(math.floor(xr)), Ww - 1)
        if c1 >= c0:
            _fill(rows, r, c0, c1, ext)


@njit(**JIT)
def _pixel_count(uv, ok, quads, Hh, Ww, bits, bofs, bb, ibits, ibofs, ibb, rows, ext):
    """Model pixel count, overlap with the observation and overlap with the ignore mask (an image
    without ignore mask has an empty box ``ibb``: rows 0..-1).

    Every quad ``(a, b, c, d)``, the triangles ``a b c`` and ``a c d`` (``d`` < 0: the triangle
    alone), is cut into one span per pixel row (pixel-centre sampling, as raster.py), or its two
    triangles where it does not project convex; the spans' pixels are set in ``rows`` (zero on entry,
    left zero) and counted word by word against the observation's words (``pack_rows``): the cost
    grows with the spans and the words the model covers, not with the image.
    """
    ext[0] = Hh
    ext[1] = -1
    ext[2] = Ww
    ext[3] = -1
    for q in range(quads.shape[0]):
        a = quads[q, 0]
        b = quads[q, 1]
        c = quads[q, 2]
        d = quads[q, 3]
        if not (ok[a] and ok[b] and ok[c]):
            continue
        if d >= 0 and ok[d]:
            _quad_spans(uv, a, b, c, d, Hh, Ww, rows, ext)
        else:
            _tri_spans(uv[a, 0], uv[a, 1], uv[b, 0], uv[b, 1], uv[c, 0], uv[c, 1], Hh, Ww, rows, ext)
    br0, br1 = bb[0], bb[1]
    bw0, bw1 = bb[2] >> 6, bb[3] >> 6
    bn = bw1 - bw0 + 1
    ir0, ir1 = ibb[0], ibb[1]
    iw0, iw1 = ibb[2] >> 6, ibb[3] >> 6
    inn = iw1 - iw0 + 1
    nmod = 0
    inter = 0
    hid = 0
    for r in range(ext[0], ext[1] + 1):
        inrow = r >= br0 and r <= br1
        base = bofs + (r - br0) * bn - bw0
        ignrow = r >= ir0 and r <= ir1
        ibase = ibofs + (r - ir0) * inn - iw0
        for w in range(ext[2], ext[3] + 1):
            m = rows[r, w]
            if m == 0:
                continue
            rows[r, w] = 0
            nmod += _ones(m)
            if inrow and w >= bw0 and w <= bw1:
                inter += _ones(m & bits[base + w])
            if ignrow and w >= iw0 and w <= iw1:
                hid += _ones(m & ibits[ibase + w])
    return nmod, inter, hid


@njit(**JIT)
def eval_frames(X, Ks, Rs, ts, dists, Hs, Ws, bits, bofs, bbs, ibits, ibofs, ibbs, areas, quads, rows, out):
    """E_sil for every camera c and frame f of one simulated candidate: out[c, f]. ``areas`` are the
    observed silhouettes' areas outside their ignore masks (eq. 6's normaliser); ``rows`` a zeroed
    scratch of 64-bit words (``row_words``), left zeroed."""
    C = Ks.shape[0]
    Fn = X.shape[0]
    V = X.shape[1]
    uv = np.empty((V, 2))
    ok = np.empty(V, dtype=np.bool_)
    ext = np.empty(4, dtype=np.int64)
    for c in range(C):
        for f in range(Fn):
            _project(X[f], Ks[c], Rs[c], ts[c], dists[c], uv, ok)
            nmod, inter, hid = _pixel_count(
                uv, ok, quads, Hs[c], Ws[c], bits, bofs[c, f], bbs[c, f], ibits, ibofs[c, f], ibbs[c, f], rows, ext
            )
            out[c, f] = (areas[c, f] + nmod - hid - 2 * inter) / areas[c, f]


@njit(**JIT)
def row_words(max_h, max_w):
    """One thread's scratch for ``eval_frames``: a row of 64-bit words per pixel row, zeroed."""
    return np.zeros((max_h, (max_w + 63) // 64), dtype=np.uint64)
