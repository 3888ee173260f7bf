"""The plain numba twins of ``simd.py``'s lane-vector intrinsics (``CLOTHFIT_NO_SIMD=1``).

Same names, arguments and arithmetic as the hand-written LLVM IR of ``simd.py`` (one float32
rounding per operation, in the same order), written as ordinary numba loops over the lanes: the
Blender kernel runs on these when ``CLOTHFIT_NO_SIMD=1`` is set, gives the same trajectory (to the
float32 rounding; ``tests/test_simd_switch.py``) and is slower (``docs/kernels.md``).
"""

from __future__ import annotations

import numpy as np

from .jit import JIT, njit
from .simd import W  # noqa: F401  (blender_kernels reads simd.W from whichever module it runs on)


@njit(**JIT)
def _row3(m0, m1, m2, m3, m4, m5, x0, x1, x2, a):
    """Row a of a symmetric block (m00, m01, m02, m11, m12, m22) times x: ((ma0 x0 + ma1 x1) + ma2 x2)."""
    if a == 0:
        return (m0 * x0 + m1 * x1) + m2 * x2
    if a == 1:
        return (m1 * x0 + m3 * x1) + m4 * x2
    return (m2 * x0 + m4 * x1) + m5 * x2


@njit(**JIT)
def matvec(Md, Mo, sp_i, sp_j, x, to, temp):
    """Blender's mul_bfmatrix_lfvector on lane arrays (see ``simd.matvec``)."""
    rows, L = x.shape
    for k in range(rows):
        for l in range(L):
            to[k, l] = 0.0
            temp[k, l] = 0.0
    for v in range(rows // 3):
        v3, v6 = 3 * v, 6 * v
        for l in range(L):
            for a in range(3):
                temp[v3 + a, l] = temp[v3 + a, l] + _row3(
                    Md[v6, l],
                    Md[v6 + 1, l],
                    Md[v6 + 2, l],
                    Md[v6 + 3, l],
                    Md[v6 + 4, l],
                    Md[v6 + 5, l],
                    x[v3, l],
                    x[v3 + 1, l],
                    x[v3 + 2, l],
                    a,
                )
    for s in range(sp_i.shape[0]):
        r3, c3, s6 = 3 * sp_i[s], 3 * sp_j[s], 6 * s
        for l in range(L):
            m0, m1, m2, m3, m4, m5 = (
                Mo[s6, l],
                Mo[s6 + 1, l],
                Mo[s6 + 2, l],
                Mo[s6 + 3, l],
                Mo[s6 + 4, l],
                Mo[s6 + 5, l],
            )
            xr0, xr1, xr2 = x[r3, l], x[r3 + 1, l], x[r3 + 2, l]
            xc0, xc1, xc2 = x[c3, l], x[c3 + 1, l], x[c3 + 2, l]
            for a in range(3):
                to[c3 + a, l] = to[c3 + a, l] + _row3(m0, m1, m2, m3, m4, m5, xr0, xr1, xr2, a)
            for a in range(3):
                temp[r3 + a, l] = temp[r3 + a, l] + _row3(m0, m1, m2, m3, m4, m5, xc0, xc1, xc2, a)
    for k in range(rows):
        for l in range(L):
            to[k, l] = to[k, l] + temp[k, l]


@njit(**JIT)
def dot(a, b, out):
    """out[0] = sum over vertices of (a_v0 b_v0 + a_v1 b_v1) + a_v2 b_v2, per lane (``simd.dot``)."""
    rows, L = a.shape
    for l in range(L):
        acc = np.float32(0.0)
        for v in range(rows // 3):
            v3 = 3 * v
            p = a[v3, l] * b[v3, l]
            p = p + a[v3 + 1, l] * b[v3 + 1, l]
            p = p + a[v3 + 2, l] * b[v3 + 2, l]
            acc = acc + p
        out[0, l] = acc


@njit(**JIT)
def scale_rows(x, free):
    """x[3v + a] = x[3v + a] * free[v] (``simd.scale_rows``)."""
    rows, L = x.shape
    for v in range(rows // 3):
        f = free[v]
        for a in range(3):
            for l in range(L):
                x[3 * v + a, l] = x[3 * v + a, l] * f


@njit(**JIT)
def cg_step(dV, r, c, q, alpha, mask):
    """Where mask != 0: dV = dV + c * alpha; r = r + q * (-alpha) (``simd.cg_step``)."""
    rows, L = dV.shape
    for l in range(L):
        if mask[0, l] != 0.0:
            a = alpha[0, l]
            na = -a
            for k in range(rows):
                dV[k, l] = dV[k, l] + c[k, l] * a
                r[k, l] = r[k, l] + q[k, l] * na


@njit(**JIT)
def cg_direction(c, r, ratio, mask, free):
    """Where mask != 0: c = (r + c * ratio) * free[v] (``simd.cg_direction``)."""
    rows, L = c.shape
    for l in range(L):
        if mask[0, l] != 0.0:
            rt = ratio[0, l]
            for v in range(rows // 3):
                f = free[v]
                for a in range(3):
                    k = 3 * v + a
                    c[k, l] = (r[k, l] + c[k, l] * rt) * f
