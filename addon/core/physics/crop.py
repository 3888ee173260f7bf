"""A crop plane: the part of the scene a sensor's data leaves out, left out of the model's silhouettes too.

Point clouds of a cloth on a table are often cropped near the table (a depth camera cannot tell a
cloth lying flat from the table under it, so every point within a few centimetres of it is dropped).
Silhouettes splatted from such points show only the cloth above the crop; a model whose silhouettes
showed all of the cloth would be compared with something the data never saw. A capture declares the
plane (``{"point": [x, y, z], "normal": [nx, ny, nz]}`` [m] in its scenario, ``"crop"``) and every
silhouette of the model then shows only what lies on the normal's side of the plane (the plane
itself included): each triangle is clipped at the plane (``clip_mesh``) before it is rasterised.

The clipped mesh keeps a fixed shape whatever the cloth does, so the numba kernels score it as any
other mesh: each triangle becomes four points and two triangles, the polygon left of it above the
plane (a triangle, a quad or nothing); slots it does not need repeat a point and have zero area,
which every rasteriser here skips.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ClothFitError

MAX_CROP_COORD_M = 1000.0  # a crop point farther out is a typo, not a table


@dataclass(frozen=True)
class CropPlane:
    """The half-space kept: points ``X`` with ``(X - point) . normal >= 0`` (``normal`` of unit length)."""

    point: tuple
    normal: tuple

    @property
    def p(self) -> np.ndarray:
        return np.asarray(self.point, dtype=np.float64)

    @property
    def n(self) -> np.ndarray:
        return np.asarray(self.normal, dtype=np.float64)

    def height(self, X: ArrayLike) -> np.ndarray:
        """Signed distance [m] of points ``X`` (..., 3) above the plane (negative: cropped away)."""
        return (np.asarray(X, dtype=np.float64) - self.p) @ self.n

    def to_dict(self) -> dict[str, list[float]]:
        return {"point": [float(x) for x in self.point], "normal": [float(x) for x in self.normal]}

    @classmethod
    def parse(cls, value: Any, source: str = "crop") -> CropPlane | None:
        """From ``{"point": [x, y, z], "normal": [nx, ny, nz]}`` (None: no crop); the normal is made unit."""
        if value is None:
            return None
        if isinstance(value, CropPlane):
            return value
        if not isinstance(value, dict) or set(value) != {"point", "normal"}:
            raise ClothFitError(
                f"{source}: expected {{'point': [x, y, z], 'normal': [nx, ny, nz]}}, got {value!r:.120}"
            )
        p = _three(value["point"], f"{source} point")
        n = _three(value["normal"], f"{source} normal")
        norm = math.sqrt(sum(x * x for x in n))
        if not norm > 1e-12:
            raise ClothFitError(f"{source} normal: {list(n)} is not a direction (zero length)")
        return cls(tuple(p), tuple(x / norm for x in n))


def _three(v: Any, what: str) -> list[float]:
    if not isinstance(v, (list, tuple)) or len(v) != 3 or any(isinstance(x, bool) for x in v):
        raise ClothFitError(f"{what}: expected 3 numbers, got {v!r:.80}")
    try:
        out = [float(x) for x in v]
    except (TypeError, ValueError):
        raise ClothFitError(f"{what}: expected 3 numbers, got {v!r:.80}") from None
    if not all(math.isfinite(x) and abs(x) <= MAX_CROP_COORD_M for x in out):
        raise ClothFitError(f"{what}: {out} must be finite numbers within +-{MAX_CROP_COORD_M:g} m")
    return out


def clipped_quads(n_triangles: int) -> np.ndarray:
    """The quads (T, 4) of a clipped mesh of ``n_triangles`` triangles (``clip_mesh``'s points): what is
    kept of each triangle, as the two triangles ``clipped_triangles`` gives, corners 0-1-2 and 0-2-3."""
    return 4 * np.arange(n_triangles, dtype=np.int64)[:, None] + np.arange(4, dtype=np.int64)


def clipped_triangles(n_triangles: int) -> np.ndarray:
    """The triangles (2T, 3) of a clipped mesh of ``n_triangles`` triangles (``clip_mesh``'s points)."""
    q = clipped_quads(n_triangles)
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]).astype(np.int64)


def clip_mesh(X: ArrayLike, tris: ArrayLike, crop: CropPlane) -> tuple[np.ndarray, np.ndarray]:
    """The mesh ``X`` (..., V, 3), ``tris`` (T, 3) cut at ``crop``: ``(points (..., 4T, 3), triangles (2T, 3))``
    covering exactly the part of every triangle on the kept side of the plane."""
    X = np.asarray(X, dtype=np.float64)
    tris = np.asarray(tris, dtype=np.int64)
    V = X[..., tris, :]  # (..., T, 3 corners, 3)
    d = crop.height(V)  # (..., T, 3)
    above = d >= 0.0
    count = above.sum(-1)
    # the pivot: the one corner kept (count 1) or the one cut away (count 2); the others follow it in turn
    pivot = np.where(count == 1, np.argmax(above, -1), np.argmin(above, -1))
    order = (pivot[..., None] + np.arange(3)) % 3
    W = np.take_along_axis(V, order[..., None], -2)
    e = np.take_along_axis(d, order, -1)

    def cut(a: int, b: int) -> np.ndarray:  # where edge a-b of the turned corners meets the plane
        den = e[..., a] - e[..., b]
        s = np.divide(e[..., a], den, out=np.zeros_like(den), where=den != 0)
        return W[..., a, :] + np.clip(s, 0.0, 1.0)[..., None] * (W[..., b, :] - W[..., a, :])

    c01, c02, c20 = cut(0, 1), cut(0, 2), cut(2, 0)
    w0, w1, w2 = W[..., 0, :], W[..., 1, :], W[..., 2, :]
    a0, a1, a2 = V[..., 0, :], V[..., 1, :], V[..., 2, :]
    k = count[..., None]
    pts = [
        np.where(k == 3, a0, np.where(k == 2, w1, np.where(k == 1, w0, a0))),
        np.where(k == 3, a1, np.where(k == 2, w2, np.where(k == 1, c01, a0))),
        np.where(k == 3, a2, np.where(k == 2, c20, np.where(k == 1, c02, a0))),
        np.where(k == 3, a2, np.where(k == 2, c01, np.where(k == 1, c02, a0))),
    ]
    out = np.stack(pts, -2)  # (..., T, 4, 3)
    return out.reshape(*out.shape[:-3], 4 * tris.shape[0], 3), clipped_triangles(tris.shape[0])
