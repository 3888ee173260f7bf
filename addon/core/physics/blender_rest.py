"""numba kernels of the cloth's rest state (``blender_kernels.setup``): rest lengths, the mean
structural rest length and the hinges' rest angles, in float32 as Blender's cloth.cc computes them
(the polygon normals and signed hinge angle of ``spring_angle``)."""

from __future__ import annotations

import math

import numpy as np

from .blender_constants import F32, NORM_EPS, ONE, ZERO
from .jit import JIT, njit


@njit(**JIT)
def _normalize(x, y, z):
    d = x * x + y * y + z * z
    if d > NORM_EPS:
        d = math.sqrt(d)
        f = ONE / d
        return x * f, y * f, z * f
    return ZERO, ZERO, ZERO


@njit(**JIT)
def _normal_tri(a0, a1, a2, b0, b1, b2, c0, c1, c2):
    """normal_tri_v3(n, a, b, c): normalize((a - b) x (b - c))."""
    n10 = a0 - b0
    n20 = b0 - c0
    n11 = a1 - b1
    n21 = b1 - c1
    n12 = a2 - b2
    n22 = b2 - c2
    return _normalize(n11 * n22 - n12 * n21, n12 * n20 - n10 * n22, n10 * n21 - n11 * n20)


@njit(**JIT)
def _poly_avg(P, inds, n, l):
    """poly_avg over the first n corners, lane l of P (V, 3, L)."""
    fact = ONE / F32(n)
    r0 = ZERO
    r1 = ZERO
    r2 = ZERO
    for x in range(n):
        v = inds[x]
        r0 += P[3 * v, l] * fact
        r1 += P[3 * v + 1, l] * fact
        r2 += P[3 * v + 2, l] * fact
    return r0, r1, r2


@njit(**JIT)
def _hinge_angle(P, i, j, pa, la, pb, lb, l):
    """spring_angle: polygon normals on both sides, edge direction, signed angle (lane l)."""
    m0, m1, m2 = _poly_avg(P, pa, la, l)
    a0, a1, a2 = _normal_tri(
        P[3 * j, l], P[3 * j + 1, l], P[3 * j + 2, l], P[3 * i, l], P[3 * i + 1, l], P[3 * i + 2, l], m0, m1, m2
    )
    m0, m1, m2 = _poly_avg(P, pb, lb, l)
    b0, b1, b2 = _normal_tri(
        P[3 * i, l], P[3 * i + 1, l], P[3 * i + 2, l], P[3 * j, l], P[3 * j + 1, l], P[3 * j + 2, l], m0, m1, m2
    )
    e0, e1, e2 = _normalize(
        P[3 * i, l] - P[3 * j, l], P[3 * i + 1, l] - P[3 * j + 1, l], P[3 * i + 2, l] - P[3 * j + 2, l]
    )
    cos = a0 * b0 + a1 * b1 + a2 * b2
    t0 = a1 * b2 - a2 * b1
    t1 = a2 * b0 - a0 * b2
    t2 = a0 * b1 - a1 * b0
    sin = t0 * e0 + t1 * e1 + t2 * e2
    return math.atan2(sin, cos), a0, a1, a2, b0, b1, b2


@njit(**JIT)
def setup(rest, sp_i, sp_j, struct_creation, h_spring, h_pa, h_la, h_pb, h_lb):
    """Rest state in float32 as cloth.cc computes it: rest lengths, mean structural rest length (summed
    in creation order), rest angles. ``rest`` is (V, 3) float32."""
    S = sp_i.shape[0]
    V = rest.shape[0]
    P = np.empty((3 * V, 1), dtype=np.float32)
    for v in range(V):
        for a in range(3):
            P[3 * v + a, 0] = rest[v, a]
    restlen = np.empty(S, dtype=np.float32)
    for s in range(S):
        i = sp_i[s]
        j = sp_j[s]
        d0 = rest[j, 0] - rest[i, 0]
        d1 = rest[j, 1] - rest[i, 1]
        d2 = rest[j, 2] - rest[i, 2]
        restlen[s] = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    avg = ZERO
    for k in range(struct_creation.shape[0]):
        avg += restlen[struct_creation[k]]
    if struct_creation.shape[0] > 0:
        avg = avg / F32(struct_creation.shape[0])
    B = h_spring.shape[0]
    restang = np.empty(B, dtype=np.float32)
    for b in range(B):
        s = h_spring[b]
        ang, _, _, _, _, _, _ = _hinge_angle(P, sp_i[s], sp_j[s], h_pa[b], h_la[b], h_pb[b], h_lb[b], 0)
        restang[b] = ang
    return restlen, avg, restang
