"""Filled-triangle silhouettes of the cloth mesh, sampled at pixel centres.

A pixel ``(row i, col j)`` is in the silhouette when its centre, the point ``(x=j, y=i)`` in the
OpenCV pixel convention of ``camera.py``, lies inside (or on the edge of) at least one projected
triangle. That is what Blender does with anti-aliasing off (one sample at each pixel centre), and it
is *not* what ``cv2.fillPoly`` does (it also fills pixels an edge merely touches, which makes every
silhouette about half a pixel fatter all round).

Zero-area (degenerate) triangles cover nothing.

Implementation: each triangle is cut into horizontal spans, one per pixel row whose centre line it
crosses; spans are accumulated in a difference buffer and a cumulative sum over each row gives the
coverage count. Everything is vectorised over the triangles; triangles with a vertex behind the
camera (NaN) are skipped.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..physics.crop import clip_mesh

if TYPE_CHECKING:
    from ..physics.crop import CropPlane
    from .camera import Camera


def paired_quads(tris: np.ndarray) -> np.ndarray:
    """A triangle list as quads ``(a, b, c, d)``, the triangles ``a b c`` and ``a c d``: each two consecutive
    triangles that share an edge (a quad as Blender tessellates it, corners 0-1-2 and 0-2-3) become one quad
    across it, any other triangle stays alone as ``(a, b, c, -1)``. The fit's scoring kernels cut a quad that
    projects convex into one span per pixel row; the pixels are the triangles' either way."""
    tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
    out, i = [], 0
    while i < len(tris):
        t = [int(v) for v in tris[i]]
        if i + 1 < len(tris):
            u = [int(v) for v in tris[i + 1]]
            shared = [v for v in t if v in u]
            if len(shared) == 2 and len(set(t)) == 3 and len(set(u)) == 3:
                # the shared edge a-b, t's corner c off it and u's corner d: the quad a c b d, whose
                # triangles a c b (t) and a b d (u) meet along its diagonal a-b
                k = next(j for j in range(3) if t[j] not in shared)
                a, b, c = t[(k + 1) % 3], t[(k + 2) % 3], t[k]
                d = next(v for v in u if v not in shared)
                out.append((a, c, b, d))
                i += 2
                continue
        out.append((t[0], t[1], t[2], -1))
        i += 1
    return np.array(out, dtype=np.int64).reshape(-1, 4)


def triangle_spans(
    pts: np.ndarray, tris: np.ndarray, height: int, width: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row spans of all triangles: arrays ``row, x_start, x_end`` (inclusive, clipped to the image)."""
    P = pts[tris]  # (T, 3, 2)
    ok = np.all(np.isfinite(P), axis=(1, 2))
    with np.errstate(invalid="ignore"):
        area2 = (P[:, 1, 0] - P[:, 0, 0]) * (P[:, 2, 1] - P[:, 0, 1]) - (P[:, 2, 0] - P[:, 0, 0]) * (
            P[:, 1, 1] - P[:, 0, 1]
        )
    ok &= area2 != 0  # zero-area triangles cover nothing (as in Blender)
    P = P[ok]
    if P.shape[0] == 0:
        e = np.zeros(0, dtype=np.int64)
        return e, e, e
    ys = P[:, :, 1]
    r0 = np.maximum(np.ceil(ys.min(1)), 0)
    r1 = np.minimum(np.floor(ys.max(1)), height - 1)
    n = np.maximum(r1 - r0 + 1, 0).astype(np.int64)
    keep = n > 0
    P, r0, n = P[keep], r0[keep].astype(np.int64), n[keep]
    if P.shape[0] == 0:
        e = np.zeros(0, dtype=np.int64)
        return e, e, e
    tri = np.repeat(np.arange(P.shape[0]), n)
    start = np.cumsum(n) - n
    row = r0[tri] + (np.arange(tri.size) - start[tri])
    y = row.astype(np.float64)
    xl = np.full(tri.size, np.inf)
    xr = np.full(tri.size, -np.inf)
    Q = P[tri]  # (S, 3, 2)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        xa, ya = Q[:, a, 0], Q[:, a, 1]
        xb, yb = Q[:, b, 0], Q[:, b, 1]
        lo = np.minimum(ya, yb)
        hi = np.maximum(ya, yb)
        hit = (y >= lo) & (y <= hi) & (ya != yb)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = xa + (y - ya) * (xb - xa) / (yb - ya)
        xl = np.where(hit, np.minimum(xl, x), xl)
        xr = np.where(hit, np.maximum(xr, x), xr)
    c0 = np.maximum(np.ceil(xl), 0)
    c1 = np.minimum(np.floor(xr), width - 1)
    good = c1 >= c0
    return row[good], c0[good].astype(np.int64), c1[good].astype(np.int64)


def rasterize(pts: np.ndarray, tris: np.ndarray, height: int, width: int) -> np.ndarray:
    """Binary silhouette ``(height, width)`` of the triangles ``tris`` with 2D vertices ``pts``."""
    row, c0, c1 = triangle_spans(np.asarray(pts, dtype=np.float64), np.asarray(tris), height, width)
    W1 = width + 1
    idx = np.concatenate([row * W1 + c0, row * W1 + c1 + 1])
    w = np.concatenate([np.ones(row.size), -np.ones(row.size)])
    diff = np.bincount(idx, weights=w, minlength=height * W1).reshape(height, W1)
    return np.cumsum(diff[:, :width], axis=1) > 0.5


def silhouette(
    camera: Camera,
    vertices: np.ndarray,
    tris: np.ndarray,
    height: int | None = None,
    width: int | None = None,
    crop: CropPlane | None = None,
) -> np.ndarray:
    """Silhouette of a mesh (world vertices ``(V, 3)``) seen by ``camera``; with a ``crop`` plane
    (``physics/crop.py``) only the part of the mesh on its kept side."""
    if crop is not None:
        vertices, tris = clip_mesh(vertices, tris, crop)
    h = camera.height if height is None else height
    w = camera.width if width is None else width
    cam = camera if (h, w) == (camera.height, camera.width) else camera.resized(h, w)
    return rasterize(cam.project(vertices), tris, h, w)


def reference_fill(pts: np.ndarray, tris: np.ndarray, height: int, width: int) -> np.ndarray:
    """Slow brute-force reference: test every pixel centre against every triangle (for tests)."""
    yy, xx = np.mgrid[0:height, 0:width]
    q = np.stack([xx.ravel(), yy.ravel()], -1).astype(np.float64)
    out = np.zeros(q.shape[0], dtype=bool)
    for t in tris:
        a, b, c = (np.asarray(pts[i], dtype=np.float64) for i in t)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(c))):
            continue
        if (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]) == 0:
            continue  # zero-area triangle: covers nothing

        def cross(p, q1, q2):
            return (q2[0] - q1[0]) * (p[:, 1] - q1[1]) - (q2[1] - q1[1]) * (p[:, 0] - q1[0])

        d1, d2, d3 = cross(q, a, b), cross(q, b, c), cross(q, c, a)
        neg = (d1 < 0) | (d2 < 0) | (d3 < 0)
        pos = (d1 > 0) | (d2 > 0) | (d3 > 0)
        out |= ~(neg & pos)
    return out.reshape(height, width)


def rasterize_window(pts: np.ndarray, tris: np.ndarray, height: int, width: int) -> tuple[int, int, np.ndarray]:
    """Like ``rasterize`` but only over the silhouette's bounding box: returns ``(r0, c0, mask)``
    with ``mask`` covering rows ``r0..`` and columns ``c0..`` (an empty mask for nothing visible)."""
    row, c0, c1 = triangle_spans(np.asarray(pts, dtype=np.float64), np.asarray(tris), height, width)
    if row.size == 0:
        return 0, 0, np.zeros((0, 0), dtype=bool)
    R0, R1 = int(row.min()), int(row.max())
    C0, C1 = int(c0.min()), int(c1.max())
    h, w = R1 - R0 + 1, C1 - C0 + 1
    W1 = w + 1
    idx = np.concatenate([(row - R0) * W1 + (c0 - C0), (row - R0) * W1 + (c1 - C0) + 1])
    wt = np.concatenate([np.ones(row.size), -np.ones(row.size)])
    diff = np.bincount(idx, weights=wt, minlength=h * W1).reshape(h, W1)
    return R0, C0, np.cumsum(diff[:, :w], axis=1) > 0.5
