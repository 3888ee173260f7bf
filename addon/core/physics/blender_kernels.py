"""numba kernels of Blender's cloth (``blender.py`` is the model and its float64 numpy reference).

The kernel follows Blender's solver operation by operation *in float32*, in Blender's order: the
spring list order of cloth.cc (newest spring first), force and Jacobian accumulation in
``cloth_calc_force``'s order, the block order of the sparse matrix and the two-section sparse
product of ``mul_bfmatrix_lfvector``, sequential float dot products and the filtered conjugate
gradient of ``cg_filtered``. The CG stops at a 1 % residual, so its iteration count, and with it
the motion, depends on rounding: doing the same operations on the same floats keeps the kernel on
Blender's trajectory (measured: ``python -m addon blender-agreement``), where a float64 solver
drifts by up to millimetres on soft cloth.

Candidates run as SIMD lanes: every array has the lane (candidate) axis last, and every operation
is a loop over the lanes, so one batch of L candidates costs about as much as one candidate;
each lane keeps its own CG (a lane that has converged stops changing). ``simulate_population``
runs the batches in parallel threads.
"""
from __future__ import annotations

import math

import numpy as np

from .jit import JIT, PARALLEL, njit, prange

F32 = np.float32
ZERO = F32(0.0)
ONE = F32(1.0)
HALF = F32(0.5)
TENTH = F32(0.1)
TWENTY = F32(20.0)
FLT_EPS = F32(1.1920928955078125e-07)      # FLT_EPSILON, also Blender's ALMOST_ZERO
NORM_EPS = F32(1.0e-35)                     # normalize_v3's threshold
CG_EPS = F32(0.01)
SNAP = F32(0.999)                           # SOFTGOALSNAP
C4 = (F32(-11.541), F32(34.193), F32(-39.083), F32(23.116), F32(-9.713))   # Choi & Ko's fb
D3 = (F32(-46.164), F32(102.579), F32(-78.166), F32(23.116))               # and its derivative
CG_MAX = 100

# lane parameters (columns of the float32 parameter table)
P_MASS, P_DRAG, P_KT, P_KC, P_KS, P_DT, P_DC, P_DS, P_BEND, P_BDAMP, P_KGOAL, P_KB, P_CB = range(13)
N_LANE_PARAMS = 13
# codes
OK, NONFINITE, FLEW, STRETCHED = 0, 1, 2, 3
REASONS = ["", "non-finite state", "flew away", "spring overstretched"]
KIND_STRUCT, KIND_SHEAR, KIND_BEND = 0, 1, 2


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
        r0 += P[v, 0, l] * fact
        r1 += P[v, 1, l] * fact
        r2 += P[v, 2, l] * fact
    return r0, r1, r2


@njit(**JIT)
def _hinge_angle(P, i, j, pa, la, pb, lb, l):
    """spring_angle: polygon normals on both sides, edge direction, signed angle (lane l)."""
    m0, m1, m2 = _poly_avg(P, pa, la, l)
    a0, a1, a2 = _normal_tri(P[j, 0, l], P[j, 1, l], P[j, 2, l], P[i, 0, l], P[i, 1, l], P[i, 2, l], m0, m1, m2)
    m0, m1, m2 = _poly_avg(P, pb, lb, l)
    b0, b1, b2 = _normal_tri(P[i, 0, l], P[i, 1, l], P[i, 2, l], P[j, 0, l], P[j, 1, l], P[j, 2, l], m0, m1, m2)
    e0, e1, e2 = _normalize(P[i, 0, l] - P[j, 0, l], P[i, 1, l] - P[j, 1, l], P[i, 2, l] - P[j, 2, l])
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
    P = np.empty((V, 3, 1), dtype=np.float32)
    for v in range(V):
        for a in range(3):
            P[v, a, 0] = rest[v, a]
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


@njit(**JIT)
def _fb(x):
    xx = x * x
    xxx = xx * x
    xxxx = xxx * x
    return C4[0] * xxxx + C4[1] * xxx + C4[2] * xx + C4[3] * x + C4[4]


@njit(**JIT)
def _fbderiv(x):
    xx = x * x
    xxx = xx * x
    return D3[0] * xxx + D3[1] * xx + D3[2] * x + D3[3]


@njit(**JIT)
def _matvec(Md, Mo, sp_i, sp_j, x, to, temp, L):
    """mul_bfmatrix_lfvector for symmetric 3x3 blocks stored as (m00, m01, m02, m11, m12, m22):
    section 1 adds the transposed off-diagonal blocks into ``to``, section 2 every block into
    ``temp`` (diagonal blocks first), then ``to += temp``."""
    V = x.shape[0]
    S = sp_i.shape[0]
    for v in range(V):
        for a in range(3):
            for l in range(L):
                to[v, a, l] = ZERO
                temp[v, a, l] = ZERO
    for s in range(S):
        r = sp_i[s]
        c = sp_j[s]
        for l in range(L):
            m00 = Mo[s, 0, l]
            m01 = Mo[s, 1, l]
            m02 = Mo[s, 2, l]
            m11 = Mo[s, 3, l]
            m12 = Mo[s, 4, l]
            m22 = Mo[s, 5, l]
            x0 = x[r, 0, l]
            x1 = x[r, 1, l]
            x2 = x[r, 2, l]
            to[c, 0, l] += m00 * x0 + m01 * x1 + m02 * x2
            to[c, 1, l] += m01 * x0 + m11 * x1 + m12 * x2
            to[c, 2, l] += m02 * x0 + m12 * x1 + m22 * x2
    for v in range(V):
        for l in range(L):
            m00 = Md[v, 0, l]
            m01 = Md[v, 1, l]
            m02 = Md[v, 2, l]
            m11 = Md[v, 3, l]
            m12 = Md[v, 4, l]
            m22 = Md[v, 5, l]
            x0 = x[v, 0, l]
            x1 = x[v, 1, l]
            x2 = x[v, 2, l]
            temp[v, 0, l] += m00 * x0 + m01 * x1 + m02 * x2
            temp[v, 1, l] += m01 * x0 + m11 * x1 + m12 * x2
            temp[v, 2, l] += m02 * x0 + m12 * x1 + m22 * x2
    for s in range(S):
        r = sp_i[s]
        c = sp_j[s]
        for l in range(L):
            m00 = Mo[s, 0, l]
            m01 = Mo[s, 1, l]
            m02 = Mo[s, 2, l]
            m11 = Mo[s, 3, l]
            m12 = Mo[s, 4, l]
            m22 = Mo[s, 5, l]
            x0 = x[c, 0, l]
            x1 = x[c, 1, l]
            x2 = x[c, 2, l]
            temp[r, 0, l] += m00 * x0 + m01 * x1 + m02 * x2
            temp[r, 1, l] += m01 * x0 + m11 * x1 + m12 * x2
            temp[r, 2, l] += m02 * x0 + m12 * x1 + m22 * x2
    for v in range(V):
        for a in range(3):
            for l in range(L):
                to[v, a, l] = to[v, a, l] + temp[v, a, l]


@njit(**JIT)
def _add_block(Mb, k, l, o00, o01, o02, o11, o12, o22):
    Mb[k, 0, l] += o00
    Mb[k, 1, l] += o01
    Mb[k, 2, l] += o02
    Mb[k, 3, l] += o11
    Mb[k, 4, l] += o12
    Mb[k, 5, l] += o22


@njit(**JIT)
def _assemble(X, Vel, F, Xd, Vd, Xo, Vo, act, sp_i, sp_j, sp_kind, sp_hinge, restlen, h_pa, h_la, h_pb, h_lb,
              restang, angular, par, g, goal, pinned, xold, xconst, hv, tg, avg_eps, L):
    """cloth_calc_force for every lane: forces F and the blocks of dF/dx (Xd diagonal, Xo per spring)
    and dF/dv (Vd, Vo); ``act[s, l]`` = spring s has a block in lane l."""
    V = X.shape[0]
    S = sp_i.shape[0]
    for v in range(V):
        for a in range(3):
            for l in range(L):
                F[v, a, l] = ZERO
        for q in range(6):
            for l in range(L):
                Xd[v, q, l] = ZERO
                Vd[v, q, l] = ZERO
    # gravity (and goal springs, vertex by vertex)
    for v in range(V):
        for l in range(L):
            m = par[l, P_MASS]
            F[v, 0, l] += g[0] * m
            F[v, 1, l] += g[1] * m
            F[v, 2, l] += g[2] * m
    for h in range(hv.shape[0]):
        v = hv[h]
        gw = goal[h]
        if pinned[h] or not (gw > FLT_EPS):
            continue
        # interp_v3_v3v3(goal_x, xold, xconst, t); goal_v = xconst - xold
        sfac = ONE - tg
        for l in range(L):
            gx0 = sfac * xold[h, 0] + tg * xconst[h, 0]
            gx1 = sfac * xold[h, 1] + tg * xconst[h, 1]
            gx2 = sfac * xold[h, 2] + tg * xconst[h, 2]
            k = gw * par[l, P_KGOAL] / avg_eps
            e0 = gx0 - X[v, 0, l]
            e1 = gx1 - X[v, 1, l]
            e2 = gx2 - X[v, 2, l]
            dd = e0 * e0 + e1 * e1 + e2 * e2
            if dd > NORM_EPS:
                ln = math.sqrt(dd)
                f = ONE / ln
                d0 = e0 * f
                d1 = e1 * f
                d2 = e2 * f
            else:
                ln = ZERO
                d0 = ZERO
                d1 = ZERO
                d2 = ZERO
            if ln > FLT_EPS:
                s = k * ln
                F[v, 0, l] += d0 * s
                F[v, 1, l] += d1 * s
                F[v, 2, l] += d2 * s
                # dfdx_spring(dir, length, 0, k) = ((I - dd^T) * 0 - I) * k
                o00 = (ONE - d0 * d0) * (ZERO / ln)
                o11 = (ONE - d1 * d1) * (ZERO / ln)
                o22 = (ONE - d2 * d2) * (ZERO / ln)
                o01 = (ZERO - d1 * d0) * (ZERO / ln)
                o02 = (ZERO - d2 * d0) * (ZERO / ln)
                o12 = (ZERO - d2 * d1) * (ZERO / ln)
                _add_block(Xd, v, l, (o00 - ONE) * k, (o01 - ZERO) * k, (o02 - ZERO) * k, (o11 - ONE) * k,
                           (o12 - ZERO) * k, (o22 - ONE) * k)
    # air drag
    for v in range(V):
        for l in range(L):
            nd = -par[l, P_DRAG]
            F[v, 0, l] += Vel[v, 0, l] * nd
            F[v, 1, l] += Vel[v, 1, l] * nd
            F[v, 2, l] += Vel[v, 2, l] * nd
            Vd[v, 0, l] += nd
            Vd[v, 1, l] += ZERO * nd
            Vd[v, 2, l] += ZERO * nd
            Vd[v, 3, l] += nd
            Vd[v, 4, l] += ZERO * nd
            Vd[v, 5, l] += nd
    # springs, in Blender's list order
    for s in range(S):
        i = sp_i[s]
        j = sp_j[s]
        kind = sp_kind[s]
        L0 = restlen[s]
        hb = sp_hinge[s]
        for l in range(L):
            act[s, l] = False
            for q in range(6):
                Xo[s, q, l] = ZERO
                Vo[s, q, l] = ZERO
        if hb >= 0 and angular:
            pa = h_pa[hb]
            pb = h_pb[hb]
            la = h_la[hb]
            lb = h_lb[hb]
            for l in range(L):
                ang, a0, a1, a2, b0, b1, b2 = _hinge_angle(X, i, j, pa, la, pb, lb, l)
                va0, va1, va2 = _poly_avg(Vel, pa, la, l)
                vb0, vb1, vb2 = _poly_avg(Vel, pb, lb, l)
                ve0 = (Vel[i, 0, l] + Vel[j, 0, l]) * HALF
                ve1 = (Vel[i, 1, l] + Vel[j, 1, l]) * HALF
                ve2 = (Vel[i, 2, l] + Vel[j, 2, l]) * HALF
                va0 -= ve0
                va1 -= ve1
                va2 -= ve2
                vb0 -= ve0
                vb1 -= ve1
                vb2 -= ve2
                k = par[l, P_BEND] * L0 * TENTH
                force = k * (ang - restang[hb])
                force += -par[l, P_BDAMP] * ((va0 * a0 + va1 * a1 + va2 * a2) + (vb0 * b0 + vb1 * b1 + vb2 * b2))
                fa = force / F32(la)
                fb = force / F32(lb)
                for x in range(la):
                    u = pa[x]
                    F[u, 0, l] += a0 * fa
                    F[u, 1, l] += a1 * fa
                    F[u, 2, l] += a2 * fa
                for x in range(lb):
                    u = pb[x]
                    F[u, 0, l] += b0 * fb
                    F[u, 1, l] += b1 * fb
                    F[u, 2, l] += b2 * fb
                fh = force * HALF
                fe0 = a0 * fh + b0 * fh
                fe1 = a1 * fh + b1 * fh
                fe2 = a2 * fh + b2 * fh
                F[i, 0, l] -= fe0
                F[i, 1, l] -= fe1
                F[i, 2, l] -= fe2
                F[j, 0, l] -= fe0
                F[j, 1, l] -= fe1
                F[j, 2, l] -= fe2
        for l in range(L):
            e0 = X[j, 0, l] - X[i, 0, l]
            e1 = X[j, 1, l] - X[i, 1, l]
            e2 = X[j, 2, l] - X[i, 2, l]
            w0 = Vel[j, 0, l] - Vel[i, 0, l]
            w1 = Vel[j, 1, l] - Vel[i, 1, l]
            w2 = Vel[j, 2, l] - Vel[i, 2, l]
            ln = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            if ln > FLT_EPS:
                inv = ONE / ln
                d0 = e0 * inv
                d1 = e1 * inv
                d2 = e2 * inv
            else:
                d0 = ZERO
                d1 = ZERO
                d2 = ZERO
            # outer product d d^T
            p00 = d0 * d0
            p01 = d1 * d0
            p02 = d2 * d0
            p11 = d1 * d1
            p12 = d2 * d1
            p22 = d2 * d2
            damping = ZERO
            if kind == KIND_BEND:
                if not (ln < L0):
                    continue
                kb = par[l, P_KB]
                cb = par[l, P_CB]
                x = ln / L0
                tfb = kb * _fb(x)
                lin = cb * (ln - L0)
                if tfb < lin:
                    sf = lin
                    jac = -cb
                else:
                    sf = tfb
                    jac = -kb * _fbderiv(x)
                f0 = d0 * sf
                f1 = d1 * sf
                f2 = d2 * sf
                j00 = p00 * jac
                j01 = p01 * jac
                j02 = p02 * jac
                j11 = p11 * jac
                j12 = p12 * jac
                j22 = p22 * jac
                v00 = ZERO
                v01 = ZERO
                v02 = ZERO
                v11 = ZERO
                v12 = ZERO
                v22 = ZERO
            else:
                if kind == KIND_STRUCT:
                    kt = par[l, P_KT]
                    dt_ = par[l, P_DT]
                else:
                    kt = par[l, P_KS]
                    dt_ = par[l, P_DS]
                if ln >= L0 and ln > ZERO:
                    damping = dt_
                    sf = kt * (ln - L0)
                    f0 = d0 * sf
                    f1 = d1 * sf
                    f2 = d2 * sf
                    r = L0 / ln
                    j00 = (((ONE - p00) * r) - ONE) * kt
                    j11 = (((ONE - p11) * r) - ONE) * kt
                    j22 = (((ONE - p22) * r) - ONE) * kt
                    j01 = (((ZERO - p01) * r) - ZERO) * kt
                    j02 = (((ZERO - p02) * r) - ZERO) * kt
                    j12 = (((ZERO - p12) * r) - ZERO) * kt
                elif kind == KIND_STRUCT and angular:
                    kb = par[l, P_KC]
                    cb = kb
                    damping = par[l, P_DC]
                    x = ln / L0
                    tfb = kb * _fb(x)
                    lin = cb * (ln - L0)
                    if tfb < lin:
                        sf = lin
                        jac = -cb
                    else:
                        sf = tfb
                        jac = -kb * _fbderiv(x)
                    f0 = d0 * sf
                    f1 = d1 * sf
                    f2 = d2 * sf
                    j00 = p00 * jac
                    j01 = p01 * jac
                    j02 = p02 * jac
                    j11 = p11 * jac
                    j12 = p12 * jac
                    j22 = p22 * jac
                else:
                    continue
                dv = damping * (w0 * d0 + w1 * d1 + w2 * d2)
                f0 += d0 * dv
                f1 += d1 * dv
                f2 += d2 * dv
                nd = -damping
                v00 = p00 * nd
                v01 = p01 * nd
                v02 = p02 * nd
                v11 = p11 * nd
                v12 = p12 * nd
                v22 = p22 * nd
            act[s, l] = True
            F[i, 0, l] += f0
            F[i, 1, l] += f1
            F[i, 2, l] += f2
            F[j, 0, l] -= f0
            F[j, 1, l] -= f1
            F[j, 2, l] -= f2
            _add_block(Xd, i, l, j00, j01, j02, j11, j12, j22)
            _add_block(Xd, j, l, j00, j01, j02, j11, j12, j22)
            Xo[s, 0, l] = ZERO - j00
            Xo[s, 1, l] = ZERO - j01
            Xo[s, 2, l] = ZERO - j02
            Xo[s, 3, l] = ZERO - j11
            Xo[s, 4, l] = ZERO - j12
            Xo[s, 5, l] = ZERO - j22
            _add_block(Vd, i, l, v00, v01, v02, v11, v12, v22)
            _add_block(Vd, j, l, v00, v01, v02, v11, v12, v22)
            Vo[s, 0, l] = ZERO - v00
            Vo[s, 1, l] = ZERO - v01
            Vo[s, 2, l] = ZERO - v02
            Vo[s, 3, l] = ZERO - v11
            Vo[s, 4, l] = ZERO - v12
            Vo[s, 5, l] = ZERO - v22


@njit(**JIT)
def _dot(a, b, free, out, L):
    """Sequential float dot product over vertices (dot_lfvector), per lane."""
    V = a.shape[0]
    for l in range(L):
        out[l] = ZERO
    for v in range(V):
        for l in range(L):
            out[l] += a[v, 0, l] * b[v, 0, l] + a[v, 1, l] * b[v, 1, l] + a[v, 2, l] * b[v, 2, l]


@njit(**JIT)
def simulate_batch(rest, sp_i, sp_j, sp_kind, sp_hinge, restlen, h_pa, h_la, h_pb, h_lb, restang, angular,
                   hv, targets, weights, n_steps, dt, tg_steps, tp_steps, inv_ts, g, avg_eps, par, keep, out,
                   centre, limit, max_ratio, codes, iterations):
    """Simulate L = par.shape[0] candidates in lockstep through every frame of the plan.

    ``targets`` (n_frames + 1, H, 3) float32 pin targets per frame, ``weights`` (n_frames + 1, H)
    pin weights; ``tg_steps``/``tp_steps`` the goal and pin interpolation factors of each step;
    ``keep`` (n_frames + 1,) index into ``out`` (L, K, V, 3) of the frames to keep, or -1.
    ``codes[l]`` != 0: the lane exploded (it is reset to rest and ignored from then on)."""
    L = par.shape[0]
    V = rest.shape[0]
    S = sp_i.shape[0]
    H = hv.shape[0]
    n_frames = targets.shape[0] - 1
    X = np.empty((V, 3, L), dtype=np.float32)
    Vel = np.zeros((V, 3, L), dtype=np.float32)
    for v in range(V):
        for a in range(3):
            for l in range(L):
                X[v, a, l] = rest[v, a]
    for h in range(H):
        for a in range(3):
            for l in range(L):
                X[hv[h], a, l] = targets[0, h, a]
    F = np.zeros((V, 3, L), dtype=np.float32)
    Xd = np.zeros((V, 6, L), dtype=np.float32)
    Vd = np.zeros((V, 6, L), dtype=np.float32)
    Ad = np.zeros((V, 6, L), dtype=np.float32)
    Xo = np.zeros((S, 6, L), dtype=np.float32)
    Vo = np.zeros((S, 6, L), dtype=np.float32)
    Ao = np.zeros((S, 6, L), dtype=np.float32)
    act = np.zeros((S, L), dtype=np.bool_)
    B = np.zeros((V, 3, L), dtype=np.float32)
    dV = np.zeros((V, 3, L), dtype=np.float32)
    r = np.zeros((V, 3, L), dtype=np.float32)
    c = np.zeros((V, 3, L), dtype=np.float32)
    q = np.zeros((V, 3, L), dtype=np.float32)
    to = np.zeros((V, 3, L), dtype=np.float32)
    temp = np.zeros((V, 3, L), dtype=np.float32)
    free = np.ones(V, dtype=np.float32)
    xold = np.zeros((H, 3), dtype=np.float32)
    xconst = np.zeros((H, 3), dtype=np.float32)
    goal = np.zeros(H, dtype=np.float32)
    pinned = np.zeros(H, dtype=np.bool_)
    delta = np.zeros(L, dtype=np.float32)
    target = np.zeros(L, dtype=np.float32)
    cq = np.zeros(L, dtype=np.float32)
    alive = np.ones(L, dtype=np.bool_)
    running = np.zeros(L, dtype=np.bool_)
    eps2 = CG_EPS * CG_EPS
    dt2 = dt * dt
    for l in range(L):
        codes[l] = OK
        iterations[l] = 0
        alive[l] = True
    for h in range(H):
        for a in range(3):
            xconst[h, a] = targets[0, h, a]
    if keep[0] >= 0:
        for l in range(L):
            for v in range(V):
                for a in range(3):
                    out[l, keep[0], v, a] = X[v, a, l]
    for fr in range(1, n_frames + 1):
        # frame start: pin targets and weights of this frame; pinned velocities
        for v in range(V):
            free[v] = ONE
        for h in range(H):
            w = weights[fr, h]
            ww = w * w
            goal[h] = ww * ww
            pinned[h] = goal[h] >= SNAP
            for a in range(3):
                xold[h, a] = xconst[h, a]
                xconst[h, a] = targets[fr, h, a]
            if pinned[h]:
                free[hv[h]] = ZERO
                for a in range(3):
                    vv = (xconst[h, a] - xold[h, a]) * inv_ts
                    for l in range(L):
                        Vel[hv[h], a, l] = vv
        for st in range(n_steps):
            _assemble(X, Vel, F, Xd, Vd, Xo, Vo, act, sp_i, sp_j, sp_kind, sp_hinge, restlen, h_pa, h_la, h_pb,
                      h_lb, restang, angular, par, g, goal, pinned, xold, xconst, hv, tg_steps[st], avg_eps, L)
            # A = M - (dF/dv dt + dF/dx dt^2); B = F dt + (dF/dx v) dt^2
            for v in range(V):
                for qq in range(6):
                    for l in range(L):
                        mq = par[l, P_MASS] if (qq == 0 or qq == 3 or qq == 5) else ZERO
                        Ad[v, qq, l] = mq - (Vd[v, qq, l] * dt + Xd[v, qq, l] * dt2)
            for s in range(S):
                for qq in range(6):
                    for l in range(L):
                        Ao[s, qq, l] = ZERO - (Vo[s, qq, l] * dt + Xo[s, qq, l] * dt2)
            _matvec(Xd, Xo, sp_i, sp_j, Vel, to, temp, L)
            for v in range(V):
                for a in range(3):
                    for l in range(L):
                        B[v, a, l] = F[v, a, l] * dt + to[v, a, l] * dt2
            # cg_filtered: dV = 0, r = c = filter(B)
            for v in range(V):
                fv = free[v]
                for a in range(3):
                    for l in range(L):
                        dV[v, a, l] = ZERO
                        r[v, a, l] = B[v, a, l] * fv
                        c[v, a, l] = r[v, a, l] * fv
            _dot(r, r, free, target, L)
            for l in range(L):
                target[l] = eps2 * target[l]
            _dot(r, c, free, delta, L)
            anyrun = False
            for l in range(L):
                running[l] = alive[l] and delta[l] > target[l]
                anyrun = anyrun or running[l]
            it = 0
            while anyrun and it < CG_MAX:
                _matvec(Ad, Ao, sp_i, sp_j, c, q, temp, L)
                for v in range(V):
                    fv = free[v]
                    for a in range(3):
                        for l in range(L):
                            q[v, a, l] = q[v, a, l] * fv
                _dot(c, q, free, cq, L)
                for l in range(L):
                    if running[l]:
                        cq[l] = delta[l] / cq[l]       # alpha
                for v in range(V):
                    for a in range(3):
                        for l in range(L):
                            if running[l]:
                                dV[v, a, l] = dV[v, a, l] + c[v, a, l] * cq[l]
                                r[v, a, l] = r[v, a, l] + q[v, a, l] * (-cq[l])
                for l in range(L):
                    cq[l] = delta[l]                   # delta_old
                _dot(r, r, free, delta, L)
                for l in range(L):
                    if running[l]:
                        cq[l] = delta[l] / cq[l]       # delta_new / delta_old
                for v in range(V):
                    fv = free[v]
                    for a in range(3):
                        for l in range(L):
                            if running[l]:
                                c[v, a, l] = (r[v, a, l] + c[v, a, l] * cq[l]) * fv
                it += 1
                anyrun = False
                for l in range(L):
                    if running[l]:
                        iterations[l] += 1
                        running[l] = delta[l] > target[l]
                        anyrun = anyrun or running[l]
            # advance: v += dv, x += v dt; pinned vertices to their interpolated targets
            for v in range(V):
                for a in range(3):
                    for l in range(L):
                        Vel[v, a, l] = Vel[v, a, l] + dV[v, a, l]
                        X[v, a, l] = X[v, a, l] + Vel[v, a, l] * dt
            tp = tp_steps[st]
            sp = ONE - tp
            for h in range(H):
                if pinned[h]:
                    for a in range(3):
                        x = sp * xold[h, a] + tp * xconst[h, a]
                        for l in range(L):
                            X[hv[h], a, l] = x
        # explosion checks, once per frame
        for l in range(L):
            if not alive[l]:
                continue
            code = OK
            far = ZERO
            for v in range(V):
                for a in range(3):
                    xa = X[v, a, l]
                    if not (math.isfinite(xa) and math.isfinite(Vel[v, a, l])):
                        code = NONFINITE
                    else:
                        d = abs(xa - centre[a])
                        if d > far:
                            far = d
            if code == OK and far > limit:
                code = FLEW
            if code == OK:
                for s in range(S):
                    if sp_kind[s] == KIND_STRUCT:
                        i = sp_i[s]
                        j = sp_j[s]
                        e0 = X[j, 0, l] - X[i, 0, l]
                        e1 = X[j, 1, l] - X[i, 1, l]
                        e2 = X[j, 2, l] - X[i, 2, l]
                        if math.sqrt(e0 * e0 + e1 * e1 + e2 * e2) > max_ratio * restlen[s]:
                            code = STRETCHED
                            break
            if code != OK:
                codes[l] = code
                alive[l] = False
                for v in range(V):
                    for a in range(3):
                        X[v, a, l] = rest[v, a]
                        Vel[v, a, l] = ZERO
        k = keep[fr]
        if k >= 0:
            for l in range(L):
                for v in range(V):
                    for a in range(3):
                        out[l, k, v, a] = X[v, a, l]


@njit(**PARALLEL)
def simulate_population(rest, sp_i, sp_j, sp_kind, sp_hinge, restlen, h_pa, h_la, h_pb, h_lb, restang, angular,
                        hv, targets, weights, n_steps, dt, tg_steps, tp_steps, inv_ts, g, avg_eps, par, lane_start,
                        keep, out, centre, limit, max_ratio, codes, iterations):
    """Batches ``lane_start[b]:lane_start[b + 1]`` of the candidates ``par`` in parallel threads."""
    nb = lane_start.shape[0] - 1
    for b in prange(nb):
        a = lane_start[b]
        e = lane_start[b + 1]
        simulate_batch(rest, sp_i, sp_j, sp_kind, sp_hinge, restlen, h_pa, h_la, h_pb, h_lb, restang, angular, hv,
                       targets, weights, n_steps, dt, tg_steps, tp_steps, inv_ts, g, avg_eps, par[a:e], keep,
                       out[a:e], centre, limit, max_ratio, codes[a:e], iterations[a:e])


# --------------------------------------------------------------------------- the Python side

LANES = 16          # candidates per SIMD batch at most (one AVX-512 vector of float32)


class Prepared:
    """The float32 arrays of one network and frame plan, ready for ``simulate_population``."""

    def __init__(self, net, plan, quality: int, time_scale: float, gravity, all_frames: bool = False):
        from .blender import MAX_STRAIN, _explosion_limits
        self.net, self.plan = net, plan
        self.rest = np.ascontiguousarray(net.rest, dtype=np.float32)
        self.sp_i = np.ascontiguousarray(net.sp_i, dtype=np.int64)
        self.sp_j = np.ascontiguousarray(net.sp_j, dtype=np.int64)
        self.sp_kind = np.ascontiguousarray(net.sp_kind, dtype=np.int64)
        self.sp_hinge = np.ascontiguousarray(net.sp_hinge, dtype=np.int64)
        self.h_spring = np.full(len(net.hinge), -1, dtype=np.int64)
        for pos, hb in enumerate(self.sp_hinge):
            if hb >= 0:
                self.h_spring[hb] = pos
        self.h_pa = np.ascontiguousarray(net.hinge_pa, dtype=np.int64)
        self.h_pb = np.ascontiguousarray(net.hinge_pb, dtype=np.int64)
        self.h_la = (self.h_pa >= 0).sum(1).astype(np.int64)
        self.h_lb = (self.h_pb >= 0).sum(1).astype(np.int64)
        self.restlen, self.avg, self.restang = setup(self.rest, self.sp_i, self.sp_j,
                                                     np.ascontiguousarray(net.struct_creation, dtype=np.int64),
                                                     self.h_spring, self.h_pa, self.h_la, self.h_pb, self.h_lb)
        self.avg_eps = F32(self.avg + FLT_EPS)
        self.angular = net.bending_model == "ANGULAR"
        self.hv = np.ascontiguousarray(plan.handle_vertices, dtype=np.int64)
        self.targets = np.ascontiguousarray(plan.targets, dtype=np.float32)
        self.weights = np.ascontiguousarray(plan.weights, dtype=np.float32)
        ts = F32(time_scale)
        dt = F32(F32(1.0) / F32(int(quality))) * ts
        starts = []
        step = F32(0.0)
        while step < ts:
            starts.append(step)
            step = F32(step + dt)
        self.dt = dt
        self.tg = np.array([F32(st / ts) for st in starts], dtype=np.float32)
        self.tp = np.array([F32(F32(st + dt) / ts) for st in starts], dtype=np.float32)
        self.inv_ts = F32(F32(1.0) / ts)
        self.g = np.array([F32(gi) * (F32(0.001) * F32(1.0)) for gi in np.asarray(gravity, dtype=np.float64)],
                          dtype=np.float32)
        centre, limit = _explosion_limits(net, plan)
        self.centre = np.asarray(centre, dtype=np.float32)
        self.limit = F32(limit)
        self.max_ratio = F32(1.0 + MAX_STRAIN)
        frames = (np.arange(plan.n_frames + 1) if all_frames else np.unique(np.concatenate([plan.lo, plan.hi])))
        self.keep = np.full(plan.n_frames + 1, -1, dtype=np.int64)
        self.keep[frames] = np.arange(frames.size)
        self.kept = frames

    def lane_params(self, rows) -> np.ndarray:
        """float32 lane parameters from rows of FLOAT_SETTINGS values, computed as Blender does."""
        from .blender import FLOAT_SETTINGS
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, len(FLOAT_SETTINGS))
        col = {n: rows[:, k].astype(np.float32) for k, n in enumerate(FLOAT_SETTINGS)}
        P = np.zeros((rows.shape[0], N_LANE_PARAMS), dtype=np.float32)
        a = self.avg_eps
        P[:, P_MASS] = col["mass"]
        P[:, P_DRAG] = col["air_damping"] * F32(0.01)
        P[:, P_KT] = col["tension_stiffness"] / a
        P[:, P_KC] = col["compression_stiffness"] / a
        P[:, P_KS] = col["shear_stiffness"] / a
        P[:, P_DT] = col["tension_damping"]
        P[:, P_DC] = col["compression_damping"]
        P[:, P_DS] = col["shear_damping"]
        P[:, P_BEND] = col["bending_stiffness"]
        P[:, P_BDAMP] = col["bending_damping"]
        P[:, P_KGOAL] = col["pin_stiffness"]
        P[:, P_KB] = col["bending_stiffness"] / (F32(20.0) * a)
        P[:, P_CB] = P[:, P_KB] * col["bending_damping"]
        return P

    def run(self, rows, threads: int | None = None):
        """Simulate the candidates ``rows``: (frames kept (P, K, V, 3) float32, codes, CG iterations)."""
        import numba
        par = self.lane_params(rows)
        n = par.shape[0]
        threads = threads or numba.get_num_threads()
        nb = max(min(threads, n), -(-n // LANES))
        bounds = np.linspace(0, n, nb + 1).round().astype(np.int64)
        out = np.zeros((n, self.kept.size, self.rest.shape[0], 3), dtype=np.float32)
        codes = np.zeros(n, dtype=np.int64)
        its = np.zeros(n, dtype=np.int64)
        simulate_population(self.rest, self.sp_i, self.sp_j, self.sp_kind, self.sp_hinge, self.restlen, self.h_pa,
                            self.h_la, self.h_pb, self.h_lb, self.restang, self.angular, self.hv, self.targets,
                            self.weights, self.tg.size, self.dt, self.tg, self.tp, self.inv_ts, self.g,
                            self.avg_eps, par, bounds, self.keep, out, self.centre, self.limit, self.max_ratio,
                            codes, its)
        return out, codes, its

    def sample(self, out):
        """Positions at the capture times (P, F, V, 3) float64 from the kept frames."""
        plan = self.plan
        lo = self.keep[plan.lo]
        hi = self.keep[plan.hi]
        w = plan.w[None, :, None, None]
        o = out.astype(np.float64)
        return (1.0 - w) * o[:, lo] + w * o[:, hi]
