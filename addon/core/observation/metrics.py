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
