"""Silhouette error (paper eq. 6, 7), shape error, and the boundary-noise model (docs/method.md#spec-4, #spec-5)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ..errors import ClothFitError


def e_sil(observed: np.ndarray, model: np.ndarray, name: str = "silhouette") -> float:
    """Eq. 6: ``|S_real XOR S_mod| / |S_real|`` (a fraction; the paper's tables show x 100)."""
    observed = np.asarray(observed, dtype=bool)
    model = np.asarray(model, dtype=bool)
    if observed.shape != model.shape:
        raise ClothFitError(
            f"{name}: observed silhouette is {observed.shape[0]}x{observed.shape[1]} but the "
            f"model's is {model.shape[0]}x{model.shape[1]}"
        )
    area = int(observed.sum())
    if area == 0:
        raise ClothFitError(f"{name}: the observed silhouette is empty, E_sil is undefined")
    return float(np.count_nonzero(observed ^ model)) / area


def e_all(observed: Iterable[Iterable[np.ndarray]], model: Iterable[Iterable[np.ndarray]]) -> float:
    """Eq. 7: sum of ``E_sil`` over all (shape, camera) pairs; inputs are nested [cam][frame]."""
    return float(sum(e_sil(o, m) for oc, mc in zip(observed, model) for o, m in zip(oc, mc)))


def shape_error_mm(model_positions: np.ndarray, true_positions: np.ndarray) -> np.ndarray:
    """Mean vertex distance [mm] per shape; inputs ``(F, V, 3)`` in metres. NaN model -> inf."""
    a = np.asarray(model_positions, dtype=np.float64)
    b = np.asarray(true_positions, dtype=np.float64)
    if a.shape != b.shape:
        raise ClothFitError(f"shape error: model shapes {a.shape} and true shapes {b.shape} differ")
    d = np.linalg.norm(a - b, axis=-1).mean(-1) * 1000.0
    return np.where(np.isfinite(d), d, np.inf)


def boundary_pixels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inner boundary (object pixels with a 4-neighbour outside) and outer boundary (background
    pixels with an object 4-neighbour), as boolean images."""
    m = np.asarray(mask, dtype=bool)
    p = np.pad(m, 1, mode="constant")
    nb_bg = ~p[:-2, 1:-1] | ~p[2:, 1:-1] | ~p[1:-1, :-2] | ~p[1:-1, 2:]
    nb_fg = p[:-2, 1:-1] | p[2:, 1:-1] | p[1:-1, :-2] | p[1:-1, 2:]
    return m & nb_bg, ~m & nb_fg


def add_boundary_noise(mask: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Flip ``round(fraction * n_boundary)`` pixels drawn uniformly from the silhouette's boundary
    band (inner boundary pixels become missing, outer boundary pixels become extra), where
    ``n_boundary`` is the number of inner-boundary pixels (the silhouette's boundary pixel count)."""
    if fraction < 0 or fraction > 1:
        raise ClothFitError(f"noise fraction {fraction} must be within 0..1")
    m = np.asarray(mask, dtype=bool).copy()
    inner, outer = boundary_pixels(m)
    n_flip = int(round(fraction * int(inner.sum())))
    if n_flip == 0:
        return m
    cand = np.flatnonzero((inner | outer).ravel())
    pick = rng.choice(cand, size=min(n_flip, cand.size), replace=False)
    flat = m.ravel()
    flat[pick] = ~flat[pick]
    return flat.reshape(m.shape)


def points_to_cloth_m(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Each point's distance [m] to the nearest point of a triangle mesh (``vertices`` (V, 3), ``triangles``
    (T, 3) indices): the one-sided distance of real points (a depth camera's, cropped) to a fitted cloth, which
    need not cover the part of the cloth the points miss. Exact point-triangle distance (Ericson's closest
    point on a triangle); NaN vertices give inf."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    X = np.asarray(vertices, dtype=np.float64)
    T = np.asarray(triangles, dtype=np.int64)
    if not np.all(np.isfinite(X)):
        return np.full(len(P), np.inf)
    a, b, c = X[T[:, 0]], X[T[:, 1]], X[T[:, 2]]
    out = np.empty(len(P))
    for s in range(0, len(P), chunk):
        p = P[s : s + chunk, None, :]
        out[s : s + chunk] = np.sqrt(_closest_sq(p, a[None], b[None], c[None]).min(axis=1))
    return out


def points_scatter_m(points: np.ndarray, k: int = 16, chunk: int = 512) -> np.ndarray:
    """Each point's distance [m] to the plane through its ``k`` nearest neighbours (itself among them): the
    points' own scatter about a smooth surface (a depth camera's noise), which a perfect cloth would still
    score in ``points_to_cloth_m``. A surface curved on the scale of the neighbourhood adds to it: at 3000
    points on a 0.28 m square (``k`` = 16 spans about 1 cm), a bend round a 10 cm cylinder adds 0.15 mm."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(P)
    if n < 4:
        return np.zeros(n)
    k = min(int(k), n)
    out = np.empty(n)
    sq = (P * P).sum(1)
    for s in range(0, n, chunk):
        p = P[s : s + chunk]
        d2 = sq[s : s + chunk, None] - 2.0 * p @ P.T + sq[None, :]
        nb = P[np.argpartition(d2, k - 1, axis=1)[:, :k]]  # (m, k, 3)
        c = nb.mean(1)
        A = nb - c[:, None]
        normal = np.linalg.eigh(np.einsum("mki,mkj->mij", A, A))[1][:, :, 0]  # the smallest spread's direction
        out[s : s + chunk] = np.abs(((p - c) * normal).sum(1))
    return out


def _closest_sq(p, a, b, c):
    """Squared distance from points ``p`` to triangles ``a, b, c`` (broadcast), by the triangle's Voronoi regions."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in, w_in = vb / denom, vc / denom
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    q = a + v_in[..., None] * ab + w_in[..., None] * ac  # inside the face
    regions = [
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t_ab[..., None] * ab),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t_ac[..., None] * ac),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + t_bc[..., None] * (c - b)),
    ]
    for mask, point in reversed(regions):  # the first region that holds wins (Ericson's order)
        q = np.where(mask[..., None], np.broadcast_to(point, q.shape), q)
    return ((p - q) ** 2).sum(-1)
