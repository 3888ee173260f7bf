"""The population kernels of the fit: for the paper's sheet, simulate a candidate and score its
silhouettes in the same thread, so a population never holds all its simulated frames at once;
for models simulated elsewhere (Blender's cloth runs its candidates as SIMD lanes), score given
positions, one candidate per thread.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..observation.silhouette_kernels import eval_frames
from ..physics.jit import JIT, PARALLEL, njit, prange
from ..physics.paper_kernels import simulate_candidate


class Views(NamedTuple):
    """The training images as the scoring kernels read them (``objective.SilhouetteObjective``): each
    camera's K, R, t, distortion (5), height and width; per image the observed silhouette's row prefix sums
    inside its bounding box (``pre``, offsets ``pofs``, boxes ``bbs``) and the ignore mask's (``ipre``,
    ``ipofs``, ``ibbs``); the silhouettes' areas (C, F); the mesh's triangles; the largest image and the
    row spans a thread's scratch holds."""

    Ks: np.ndarray
    Rs: np.ndarray
    ts: np.ndarray
    dists: np.ndarray
    Hs: np.ndarray
    Ws: np.ndarray
    pre: np.ndarray
    pofs: np.ndarray
    bbs: np.ndarray
    ipre: np.ndarray
    ipofs: np.ndarray
    ibbs: np.ndarray
    areas: np.ndarray
    tris: np.ndarray
    max_h: int
    max_w: int
    span_cap: int


@njit(**JIT)
def work_buffers(span_cap, max_h, max_w):
    """One thread's scratch arrays for ``eval_frames`` (row spans and prefix sums)."""
    return (
        np.empty(span_cap, dtype=np.int32),
        np.empty(span_cap, dtype=np.int32),
        np.empty(span_cap, dtype=np.int32),
        np.zeros(max_h + 2, dtype=np.int64),
        np.zeros(max_h + 2, dtype=np.int64),
        np.empty(span_cap, dtype=np.int32),
        np.empty(span_cap, dtype=np.int32),
        np.zeros(max_w + 2, dtype=np.int64),
        np.empty(span_cap, dtype=np.int32),
        np.empty(span_cap, dtype=np.int32),
        np.empty(span_cap, dtype=np.int32),
    )


@njit(**PARALLEL)
def objective_population(P, sheet, moves, views, esil, codes):
    """Simulate and score every candidate (its own key positions and events, as
    ``paper_kernels.population_arrays`` gives them): esil[p, c, f]; codes[p] != 0 = exploded."""
    Ks, Rs, ts, dists, Hs, Ws, pre, pofs, bbs, ipre, ipofs, ibbs, areas, tris, max_h, max_w, span_cap = views
    V = sheet.rest.shape[0]
    for p in prange(P.shape[0]):
        X = np.zeros((sheet.n_frames, V, 3))
        code, st = simulate_candidate(P[p], sheet, moves, p, X)
        codes[p] = code
        if code != 0:
            continue
        work = work_buffers(span_cap, max_h, max_w)
        eval_frames(X, Ks, Rs, ts, dists, Hs, Ws, pre, pofs, bbs, ipre, ipofs, ibbs, areas, tris, work, esil[p])


@njit(**PARALLEL)
def score_population(X, ok, views, esil):
    """esil[p, c, f] for the positions X (P, F, V, 3) of every candidate with ok[p]."""
    Ks, Rs, ts, dists, Hs, Ws, pre, pofs, bbs, ipre, ipofs, ibbs, areas, tris, max_h, max_w, span_cap = views
    for p in prange(X.shape[0]):
        if not ok[p]:
            continue
        work = work_buffers(span_cap, max_h, max_w)
        eval_frames(X[p], Ks, Rs, ts, dists, Hs, Ws, pre, pofs, bbs, ipre, ipofs, ibbs, areas, tris, work, esil[p])
