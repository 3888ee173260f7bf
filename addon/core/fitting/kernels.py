"""The population kernels of the fit: for the paper's sheet, simulate a candidate and score its
silhouettes in the same thread, so a population never holds all its simulated frames at once;
for models simulated elsewhere (Blender's cloth runs its candidates as SIMD lanes), score given
positions, one candidate per thread.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..observation.silhouette_kernels import eval_frames, row_words
from ..physics.jit import PARALLEL, njit, prange
from ..physics.paper_kernels import simulate_candidate


class Views(NamedTuple):
    """The training images as the scoring kernels read them (``objective.SilhouetteObjective``): each
    camera's K, R, t, distortion (5), height and width; per image the observed silhouette packed in rows
    of 64-bit words over its bounding box (``bits``, offsets ``bofs``, boxes ``bbs``:
    ``silhouette_kernels.pack_rows``) and the ignore mask's (``ibits``, ``ibofs``, ``ibbs``); the
    silhouettes' areas (C, F); the mesh's triangles in pairs, quads ``a b c d`` of the triangles ``a b c``
    and ``a c d`` (``d`` < 0: one triangle); the largest image."""

    Ks: np.ndarray
    Rs: np.ndarray
    ts: np.ndarray
    dists: np.ndarray
    Hs: np.ndarray
    Ws: np.ndarray
    bits: np.ndarray
    bofs: np.ndarray
    bbs: np.ndarray
    ibits: np.ndarray
    ibofs: np.ndarray
    ibbs: np.ndarray
    areas: np.ndarray
    quads: np.ndarray
    max_h: int
    max_w: int


@njit(**PARALLEL)
def objective_population(P, sheet, moves, views, esil, codes):
    """Simulate and score every candidate (its own key positions and events, as
    ``paper_kernels.population_arrays`` gives them): esil[p, c, f]; codes[p] != 0 = exploded."""
    Ks, Rs, ts, dists, Hs, Ws, bits, bofs, bbs, ibits, ibofs, ibbs, areas, quads, max_h, max_w = views
    V = sheet.rest.shape[0]
    for p in prange(P.shape[0]):
        X = np.zeros((sheet.n_frames, V, 3))
        code, st = simulate_candidate(P[p], sheet, moves, p, X)
        codes[p] = code
        if code != 0:
            continue
        rows = row_words(max_h, max_w)
        eval_frames(X, Ks, Rs, ts, dists, Hs, Ws, bits, bofs, bbs, ibits, ibofs, ibbs, areas, quads, rows, esil[p])


@njit(**PARALLEL)
def score_population(X, ok, views, esil):
    """esil[p, c, f] for the positions X (P, F, V, 3) of every candidate with ok[p]."""
    Ks, Rs, ts, dists, Hs, Ws, bits, bofs, bbs, ibits, ibofs, ibbs, areas, quads, max_h, max_w = views
    for p in prange(X.shape[0]):
        if not ok[p]:
            continue
        rows = row_words(max_h, max_w)
        eval_frames(X[p], Ks, Rs, ts, dists, Hs, Ws, bits, bofs, bbs, ibits, ibofs, ibbs, areas, quads, rows, esil[p])
