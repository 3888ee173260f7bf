"""numba kernels of Blender's cloth (``blender.py`` is the model and its float64 numpy reference).

The kernel follows Blender's solver operation by operation *in float32*, in Blender's order: the
spring list order of cloth.cc (newest spring first), force and Jacobian accumulation in
``cloth_calc_force``'s order, the block order of the sparse matrix and the two-section sparse
product of ``mul_bfmatrix_lfvector``, sequential float dot products and the filtered conjugate
gradient of ``cg_filtered``. The CG stops at a 1 % residual, so its iteration count, and with it
the motion, depends on rounding: doing the same operations on the same floats keeps the kernel on
Blender's trajectory (measured: ``python -m clothfit blender-agreement``), where a float64 solver
drifts by up to millimetres on soft cloth.

Candidates run as SIMD lanes: every array has the lane (candidate) axis last, and every operation
is a loop over the lanes, so one batch of L candidates costs about as much as one candidate;
each lane keeps its own CG (a lane that has converged stops changing). ``simulate_population``
runs the batches in parallel threads. The lane operations are hand-written LLVM IR (``simd.py``,
``blender_springs.py``; why, what they gain, and ``CLOTHFIT_NO_SIMD=1`` to run their plain numba
twins instead: ``docs/kernels.md``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from . import simd as _simd_ir
from . import simd_plain
from .blender_collide import collide
from .blender_constants import (
    C4,
    CG_EPS,
    CG_MAX,
    D3,
    F32,
    FLEW,
    FLT_EPS,
    KIND_STRUCT,
    N_LANE_PARAMS,
    NONFINITE,
    NORM_EPS,
    OK,
    ONE,
    P_AVG,
    P_BDAMP,
    P_BEND,
    P_CB,
    P_DC,
    P_DRAG,
    P_DS,
    P_DT,
    P_KB,
    P_KC,
    P_KGOAL,
    P_KS,
    P_KT,
    P_MASS,
    REASONS,  # noqa: F401  (blender_kernels.REASONS: models.py)
    SNAP,
    STRETCHED,
    ZERO,
)
from .blender_rest import setup
from .blender_springs import springs_plain
from .jit import JIT, PARALLEL, njit, prange

# The lane operations: simd.py's and blender_springs.py's hand-written LLVM IR, or with CLOTHFIT_NO_SIMD=1
# their plain numba twins (docs/kernels.md). The kernels that call them are then not cached, so that a cached
# build of the other path is never loaded for them.
if _simd_ir.ENABLED:  # pragma: no branch
    from .blender_springs import springs_v

    simd, LANES_JIT, LANES_PARALLEL = _simd_ir, JIT, PARALLEL
else:
    springs_v, simd = springs_plain, simd_plain
    LANES_JIT, LANES_PARALLEL = dict(JIT, cache=False), dict(PARALLEL, cache=False)


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
def _add_block(Mb, k, l, o00, o01, o02, o11, o12, o22):
    Mb[6 * k, l] += o00
    Mb[6 * k + 1, l] += o01
    Mb[6 * k + 2, l] += o02
    Mb[6 * k + 3, l] += o11
    Mb[6 * k + 4, l] += o12
    Mb[6 * k + 5, l] += o22


@njit(**LANES_JIT)
def _assemble(X, Vel, F, Xd, Vd, Xo, Vo, act, mesh, restlen, restang, par, parT, g, goal, pinned, xold, xconst, tg, L):
    """cloth_calc_force for every lane: forces F and the blocks of dF/dx (Xd diagonal, Xo per spring)
    and dF/dv (Vd, Vo); ``act[s, l]`` = spring s has a block in lane l."""
    _, sp_i, sp_j, sp_kind, sp_hinge, h_pa, h_la, h_pb, h_lb, angular, hv, _, _, _ = mesh
    V = X.shape[0] // 3
    for v in range(V):
        for a in range(3):
            for l in range(L):
                F[3 * v + a, l] = ZERO
        for q in range(6):
            for l in range(L):
                Xd[6 * v + q, l] = ZERO
                Vd[6 * v + q, l] = ZERO
    # gravity (and goal springs, vertex by vertex)
    for v in range(V):
        for l in range(L):
            m = par[l, P_MASS]
            F[3 * v, l] += g[0] * m
            F[3 * v + 1, l] += g[1] * m
            F[3 * v + 2, l] += g[2] * m
    for h in range(hv.shape[0]):
        v = hv[h]
        gw = goal[h]
        if pinned[h] or not (gw > FLT_EPS):
            continue
        # interp_v3_v3v3(goal_x, xold, xconst, t); goal_v = xconst - xold
        sfac = ONE - tg
        for l in range(L):
            gx0 = sfac * xold[h, 0, l] + tg * xconst[h, 0, l]
            gx1 = sfac * xold[h, 1, l] + tg * xconst[h, 1, l]
            gx2 = sfac * xold[h, 2, l] + tg * xconst[h, 2, l]
            k = gw * par[l, P_KGOAL] / par[l, P_AVG]
            e0 = gx0 - X[3 * v, l]
            e1 = gx1 - X[3 * v + 1, l]
            e2 = gx2 - X[3 * v + 2, l]
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
                F[3 * v, l] += d0 * s
                F[3 * v + 1, l] += d1 * s
                F[3 * v + 2, l] += d2 * s
                # dfdx_spring(dir, length, 0, k) = ((I - dd^T) * 0 - I) * k
                o00 = (ONE - d0 * d0) * (ZERO / ln)
                o11 = (ONE - d1 * d1) * (ZERO / ln)
                o22 = (ONE - d2 * d2) * (ZERO / ln)
                o01 = (ZERO - d1 * d0) * (ZERO / ln)
                o02 = (ZERO - d2 * d0) * (ZERO / ln)
                o12 = (ZERO - d2 * d1) * (ZERO / ln)
                _add_block(
                    Xd,
                    v,
                    l,
                    (o00 - ONE) * k,
                    (o01 - ZERO) * k,
                    (o02 - ZERO) * k,
                    (o11 - ONE) * k,
                    (o12 - ZERO) * k,
                    (o22 - ONE) * k,
                )
    # air drag
    for v in range(V):
        for l in range(L):
            nd = -par[l, P_DRAG]
            F[3 * v, l] += Vel[3 * v, l] * nd
            F[3 * v + 1, l] += Vel[3 * v + 1, l] * nd
            F[3 * v + 2, l] += Vel[3 * v + 2, l] * nd
            Vd[6 * v, l] += nd
            Vd[6 * v + 1, l] += ZERO * nd
            Vd[6 * v + 2, l] += ZERO * nd
            Vd[6 * v + 3, l] += nd
            Vd[6 * v + 4, l] += ZERO * nd
            Vd[6 * v + 5, l] += nd
    # springs, in Blender's list order (vectorised over the lanes)
    springs_v(
        X,
        Vel,
        F,
        Xd,
        Vd,
        Xo,
        Vo,
        sp_i,
        sp_j,
        sp_kind,
        sp_hinge,
        restlen,
        h_pa,
        h_la,
        h_pb,
        h_lb,
        restang,
        parT,
        angular,
    )


@njit(**LANES_JIT)
def simulate_batch(mesh, clock, restlen, restang, targets, par, out, codes, iterations):
    """Simulate the W = simd.W lanes of ``par`` (W, N_LANE_PARAMS) in lockstep through every frame.

    The manipulation may differ between lanes (a fit of uncertain pins): ``targets``
    (n_frames + 1, H, 3, W) float32 pin targets per frame and lane, ``restlen`` (S, W) and
    ``restang`` (B, W) each lane's rest lengths and angles (of its first frame), the mean structural
    rest length in ``par[:, P_AVG]``; ``weights`` (n_frames + 1, H) pin weights; ``tg_steps``/``tp_steps`` the goal and pin interpolation factors of each step;
    ``keep`` (n_frames + 1,) index into ``out`` (L, K, V, 3) of the frames to keep, or -1.
    ``codes[l]`` != 0: the lane exploded (it is reset to rest and ignored from then on)."""
    rest, sp_i, sp_j, sp_kind, sp_hinge, h_pa, h_la, h_pb, h_lb, angular, hv, weights, tris, col = mesh
    n_steps, dt, tg_steps, tp_steps, inv_ts, g, keep, centre, limit, max_ratio = clock
    L = simd.W
    V = rest.shape[0]
    S = sp_i.shape[0]
    H = hv.shape[0]
    n_frames = targets.shape[0] - 1
    X = np.empty((3 * V, L), dtype=np.float32)
    Vel = np.zeros((3 * V, L), dtype=np.float32)
    for v in range(V):
        for a in range(3):
            for l in range(L):
                X[3 * v + a, l] = rest[v, a]
    for h in range(H):
        for a in range(3):
            for l in range(L):
                X[3 * hv[h] + a, l] = targets[0, h, a, l]
    F = np.zeros((3 * V, L), dtype=np.float32)
    Xd = np.zeros((6 * V, L), dtype=np.float32)
    Vd = np.zeros((6 * V, L), dtype=np.float32)
    Ad = np.zeros((6 * V, L), dtype=np.float32)
    Xo = np.zeros((6 * S, L), dtype=np.float32)
    Vo = np.zeros((6 * S, L), dtype=np.float32)
    Ao = np.zeros((6 * S, L), dtype=np.float32)
    act = np.zeros((S, L), dtype=np.bool_)
    B = np.zeros((3 * V, L), dtype=np.float32)
    dV = np.zeros((3 * V, L), dtype=np.float32)
    r = np.zeros((3 * V, L), dtype=np.float32)
    c = np.zeros((3 * V, L), dtype=np.float32)
    q = np.zeros((3 * V, L), dtype=np.float32)
    to = np.zeros((3 * V, L), dtype=np.float32)
    temp = np.zeros((3 * V, L), dtype=np.float32)
    free = np.ones(V, dtype=np.float32)
    xold = np.zeros((H, 3, L), dtype=np.float32)
    xconst = np.zeros((H, 3, L), dtype=np.float32)
    goal = np.zeros(H, dtype=np.float32)
    pinned = np.zeros(H, dtype=np.bool_)
    delta = np.zeros((1, L), dtype=np.float32)
    target = np.zeros((1, L), dtype=np.float32)
    cq = np.zeros((1, L), dtype=np.float32)
    ratio = np.zeros((1, L), dtype=np.float32)
    run = np.zeros((1, L), dtype=np.float32)
    alive = np.ones(L, dtype=np.bool_)
    parT = np.empty((N_LANE_PARAMS, L), dtype=np.float32)
    for k in range(N_LANE_PARAMS):
        for l in range(L):
            parT[k, l] = par[l, k]
    eps2 = CG_EPS * CG_EPS
    dt2 = dt * dt
    for l in range(L):
        codes[l] = OK
        iterations[l] = 0
        alive[l] = True
    for h in range(H):
        for a in range(3):
            for l in range(L):
                xconst[h, a, l] = targets[0, h, a, l]
    if keep[0] >= 0:
        for l in range(L):
            for v in range(V):
                for a in range(3):
                    out[l, keep[0], v, a] = X[3 * v + a, l]
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
                for l in range(L):
                    xold[h, a, l] = xconst[h, a, l]
                    xconst[h, a, l] = targets[fr, h, a, l]
            if pinned[h]:
                free[hv[h]] = ZERO
                for a in range(3):
                    for l in range(L):
                        Vel[3 * hv[h] + a, l] = (xconst[h, a, l] - xold[h, a, l]) * inv_ts
        for st in range(n_steps):
            _assemble(
                X,
                Vel,
                F,
                Xd,
                Vd,
                Xo,
                Vo,
                act,
                mesh,
                restlen,
                restang,
                par,
                parT,
                g,
                goal,
                pinned,
                xold,
                xconst,
                tg_steps[st],
                L,
            )
            # A = M - (dF/dv dt + dF/dx dt^2); B = F dt + (dF/dx v) dt^2
            for v in range(V):
                for qq in range(6):
                    for l in range(L):
                        mq = par[l, P_MASS] if (qq == 0 or qq == 3 or qq == 5) else ZERO
                        Ad[6 * v + qq, l] = mq - (Vd[6 * v + qq, l] * dt + Xd[6 * v + qq, l] * dt2)
            for s in range(S):
                for qq in range(6):
                    for l in range(L):
                        Ao[6 * s + qq, l] = ZERO - (Vo[6 * s + qq, l] * dt + Xo[6 * s + qq, l] * dt2)
            simd.matvec(Xd, Xo, sp_i, sp_j, Vel, to, temp)
            for k in range(3 * V):
                for l in range(L):
                    B[k, l] = F[k, l] * dt + to[k, l] * dt2
            # cg_filtered: dV = 0, r = c = filter(B)
            for v in range(V):
                fv = free[v]
                for a in range(3):
                    for l in range(L):
                        dV[3 * v + a, l] = ZERO
                        r[3 * v + a, l] = B[3 * v + a, l] * fv
                        c[3 * v + a, l] = r[3 * v + a, l] * fv
            simd.dot(r, r, target)
            for l in range(L):
                target[0, l] = eps2 * target[0, l]
            simd.dot(r, c, delta)
            anyrun = False
            for l in range(L):
                on = alive[l] and delta[0, l] > target[0, l]
                run[0, l] = ONE if on else ZERO
                anyrun = anyrun or on
            it = 0
            while anyrun and it < CG_MAX:
                simd.matvec(Ad, Ao, sp_i, sp_j, c, q, temp)
                simd.scale_rows(q, free)
                simd.dot(c, q, cq)
                for l in range(L):
                    cq[0, l] = delta[0, l] / cq[0, l]  # alpha
                simd.cg_step(dV, r, c, q, cq, run)
                for l in range(L):
                    ratio[0, l] = delta[0, l]  # delta_old
                simd.dot(r, r, delta)
                for l in range(L):
                    ratio[0, l] = delta[0, l] / ratio[0, l]  # delta_new / delta_old
                simd.cg_direction(c, r, ratio, run, free)
                it += 1
                anyrun = False
                for l in range(L):
                    if run[0, l] != ZERO:
                        iterations[l] += 1
                        on = delta[0, l] > target[0, l]
                        run[0, l] = ONE if on else ZERO
                        anyrun = anyrun or on
            # advance: v += dv (then the colliders' impulses), x += v dt; pinned vertices to their targets
            for k in range(3 * V):
                for l in range(L):
                    Vel[k, l] = Vel[k, l] + dV[k, l]
            collide(X, Vel, free, tris, col, dt)
            for k in range(3 * V):
                for l in range(L):
                    X[k, l] = X[k, l] + Vel[k, l] * dt
            tp = tp_steps[st]
            sp = ONE - tp
            for h in range(H):
                if pinned[h]:
                    for a in range(3):
                        for l in range(L):
                            X[3 * hv[h] + a, l] = sp * xold[h, a, l] + tp * xconst[h, a, l]
        # explosion checks, once per frame
        for l in range(L):
            if not alive[l]:
                continue
            code = OK
            far = ZERO
            for v in range(V):
                for a in range(3):
                    xa = X[3 * v + a, l]
                    if not (math.isfinite(xa) and math.isfinite(Vel[3 * v + a, l])):
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
                        e0 = X[3 * j, l] - X[3 * i, l]
                        e1 = X[3 * j + 1, l] - X[3 * i + 1, l]
                        e2 = X[3 * j + 2, l] - X[3 * i + 2, l]
                        if math.sqrt(e0 * e0 + e1 * e1 + e2 * e2) > max_ratio * restlen[s, l]:
                            code = STRETCHED
                            break
            if code != OK:
                codes[l] = code
                alive[l] = False
                for v in range(V):
                    for a in range(3):
                        X[3 * v + a, l] = rest[v, a]
                        Vel[3 * v + a, l] = ZERO
        k = keep[fr]
        if k >= 0:
            for l in range(L):
                for v in range(V):
                    for a in range(3):
                        out[l, k, v, a] = X[3 * v + a, l]


@njit(**LANES_PARALLEL)
def simulate_population(mesh, clock, restlen, restang, targets, par, lane_start, out, codes, iterations):
    """Batches of simd.W lanes ``lane_start[b]:lane_start[b] + W`` of ``par`` in parallel threads;
    ``restlen`` (NB, S, W), ``restang`` (NB, B, W) and ``targets`` (NB, n_frames + 1, H, 3, W) per batch."""
    nb = lane_start.shape[0]
    for b in prange(nb):
        a = lane_start[b]
        e = a + simd.W
        simulate_batch(mesh, clock, restlen[b], restang[b], targets[b], par[a:e], out[a:e], codes[a:e], iterations[a:e])


# --------------------------------------------------------------------------- the Python side


class Mesh(NamedTuple):
    """The cloth's network as the kernel reads it, the same for every candidate (built once: ``Prepared``):
    rest positions (V, 3); springs' ends, kinds and hinges; the hinges' faces (``h_pa``/``h_pb``, their vertex
    counts ``h_la``/``h_lb``); ``angular`` (1: Blender's angular bending); the pinned vertices ``hv`` and
    their weights per frame (n_frames + 1, H); the triangles; the colliders' packed rows."""

    rest: np.ndarray
    sp_i: np.ndarray
    sp_j: np.ndarray
    sp_kind: np.ndarray
    sp_hinge: np.ndarray
    h_pa: np.ndarray
    h_la: np.ndarray
    h_pb: np.ndarray
    h_lb: np.ndarray
    angular: int
    hv: np.ndarray
    weights: np.ndarray
    tris: np.ndarray
    col: np.ndarray


class Clock(NamedTuple):
    """The steps through the frames: ``n_steps`` steps of ``dt`` per frame, each step's goal and pin
    interpolation factors, ``inv_ts`` (1 / time scale), gravity ``g``; the frames to keep (``keep``: index
    into the output or -1); the explosion test's centre, distance limit and largest spring stretch."""

    n_steps: int
    dt: np.float32
    tg_steps: np.ndarray
    tp_steps: np.ndarray
    inv_ts: np.float32
    g: np.ndarray
    keep: np.ndarray
    centre: np.ndarray
    limit: np.float32
    max_ratio: np.float32


class Prepared:
    """The float32 arrays of one network and frame plan, ready for ``simulate_population``."""

    def __init__(self, net, plan, quality: int, time_scale: float, gravity, all_frames: bool = False, colliders=None):
        from .blender import MAX_STRAIN, explosion_limits
        from .colliders import packed_or_empty

        self.col = packed_or_empty(colliders)  # the colliders' rows (blender_collide), (0, ...) without
        self.tris = np.ascontiguousarray(net.triangles, dtype=np.int64)

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
        self.struct_creation = np.ascontiguousarray(net.struct_creation, dtype=np.int64)
        self.restlen, self.avg, self.restang = self._setup(self.rest)
        self.avg_eps = F32(self.avg + FLT_EPS)
        self.angular = 1 if net.bending_model == "ANGULAR" else 0
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
        self.g = np.array(
            [F32(gi) * (F32(0.001) * F32(1.0)) for gi in np.asarray(gravity, dtype=np.float64)], dtype=np.float32
        )
        centre, limit = explosion_limits(net, plan)
        self.centre = np.asarray(centre, dtype=np.float32)
        self.limit = F32(limit)
        self.max_ratio = F32(1.0 + MAX_STRAIN)
        frames = np.arange(plan.n_frames + 1) if all_frames else np.unique(np.concatenate([plan.lo, plan.hi]))
        self.keep = np.full(plan.n_frames + 1, -1, dtype=np.int64)
        self.keep[frames] = np.arange(frames.size)
        self.kept = frames
        self.mesh = Mesh(*(getattr(self, n) for n in Mesh._fields))
        self.clock = Clock(
            self.tg.size,
            self.dt,
            self.tg,
            self.tp,
            self.inv_ts,
            self.g,
            self.keep,
            self.centre,
            self.limit,
            self.max_ratio,
        )

    def _setup(self, first):
        """(rest lengths, mean structural rest length, rest angles) of a first frame (V, 3) float32."""
        return setup(
            first, self.sp_i, self.sp_j, self.struct_creation, self.h_spring, self.h_pa, self.h_la, self.h_pb, self.h_lb
        )

    def manipulation(self, offsets: ArrayLike | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Each candidate's pin targets (P, n_frames + 1, H, 3), rest lengths (P, S), rest angles (P, B)
        and ``avg_spring_len + FLT_EPSILON`` (P,), float32, for handle offsets (P, H, 3) [m] (None: the
        plan's own handles for every candidate). An offset moves the handle's held positions; with a
        settle ramp (``blender.settle_ramp``) the handle comes there from the flat cloth as the plan's
        own does, so the rest shape stays the flat sheet; without one it moves the first frame too, and
        the candidate's rest shape is that of a Blender mesh built with the handles there (Blender's
        rest lengths are the first frame's)."""
        if offsets is None:
            return None
        offsets = np.asarray(offsets, dtype=np.float64)
        P = offsets.shape[0]
        H = self.hv.size
        if offsets.shape != (P, H, 3):
            raise ValueError(f"handle offsets must be (P, {H}, 3), got {offsets.shape}")
        base = np.asarray(self.plan.targets, dtype=np.float64)
        ramp = self.plan.ramp
        gain = np.ones(base.shape[0]) if ramp is None else np.asarray(ramp, dtype=np.float64)
        targets = np.empty((P,) + base.shape, dtype=np.float32)
        restlen = np.empty((P, self.restlen.size), dtype=np.float32)
        restang = np.empty((P, self.restang.size), dtype=np.float32)
        avg = np.empty(P, dtype=np.float32)
        first = np.asarray(self.net.rest, dtype=np.float64).copy()
        moves_first = bool(gain[0] != 0.0)  # with a settle ramp the first frame, and the rest shape, is the plan's
        for p in range(P):
            t = base + gain[:, None, None] * offsets[p][None]
            targets[p] = t
            if moves_first:
                first[self.hv] = t[0]
                restlen[p], a, restang[p] = self._setup(np.ascontiguousarray(first, dtype=np.float32))
                avg[p] = F32(a + FLT_EPS)
            else:
                restlen[p], restang[p], avg[p] = self.restlen, self.restang, self.avg_eps
        return targets, restlen, restang, avg

    def lane_params(self, rows: ArrayLike, avg_eps: ArrayLike | None = None) -> np.ndarray:
        """float32 lane parameters from rows of FLOAT_SETTINGS values, computed as Blender does
        (``avg_eps``: per row, for candidates with their own rest shape; default the plan's)."""
        from .blender import FLOAT_SETTINGS

        rows = np.asarray(rows, dtype=np.float64).reshape(-1, len(FLOAT_SETTINGS))
        col = {n: rows[:, k].astype(np.float32) for k, n in enumerate(FLOAT_SETTINGS)}
        P = np.zeros((rows.shape[0], N_LANE_PARAMS), dtype=np.float32)
        a = (
            np.full(rows.shape[0], self.avg_eps, dtype=np.float32)
            if avg_eps is None
            else np.asarray(avg_eps, dtype=np.float32)
        )
        P[:, P_AVG] = a
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

    def run(self, rows: ArrayLike, offsets: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Simulate the candidates ``rows`` (with handle ``offsets`` (P, H, 3) [m], see
        ``manipulation``): (frames kept (P, K, V, 3) float32, codes, CG iterations).

        The candidates are padded to whole batches of ``simd.W`` lanes (copies of the last one)."""
        man = self.manipulation(offsets)
        n = np.asarray(rows).reshape(-1, np.asarray(rows).shape[-1]).shape[0]
        W = simd.W
        nb = -(-n // W)
        pad = np.concatenate([np.arange(n), np.full(nb * W - n, n - 1)])
        if man is None:
            par = self.lane_params(rows)
            restlen = np.ascontiguousarray(
                np.broadcast_to(self.restlen[None, :, None], (nb,) + self.restlen.shape + (W,))
            )
            restang = np.ascontiguousarray(
                np.broadcast_to(self.restang[None, :, None], (nb,) + self.restang.shape + (W,))
            )
            targets = np.ascontiguousarray(
                np.broadcast_to(self.targets[None, ..., None], (nb,) + self.targets.shape + (W,))
            )
        else:
            tg, rl, ra, avg = man
            par = self.lane_params(rows, avg)

            def lanes(a):  # (P, ...) -> (NB, ..., W): the candidates of each batch on the last axis
                a = a[pad].reshape((nb, W) + a.shape[1:])
                return np.ascontiguousarray(np.moveaxis(a, 1, -1))

            restlen, restang, targets = lanes(rl), lanes(ra), lanes(tg)
        padded = np.ascontiguousarray(par[pad])
        out = np.zeros((nb * W, self.kept.size, self.rest.shape[0], 3), dtype=np.float32)
        codes = np.zeros(nb * W, dtype=np.int64)
        its = np.zeros(nb * W, dtype=np.int64)
        simulate_population(
            self.mesh,
            self.clock,
            restlen,
            restang,
            targets,
            padded,
            np.arange(nb, dtype=np.int64) * W,
            out,
            codes,
            its,
        )
        return out[:n], codes[:n], its[:n]

    def sample(self, out: np.ndarray, frames: ArrayLike | None = None) -> np.ndarray:
        """Positions (P, F, V, 3) float64 from the kept frames: at the capture times, or at
        ``frames`` (P, F) fractional frame numbers from the start frame (a candidate's own reading
        of the capture times, e.g. shifted by its time offset), linear between whole frames."""
        o = out.astype(np.float64)
        if frames is None:
            plan = self.plan
            w = plan.w[None, :, None, None]
            return (1.0 - w) * o[:, self.keep[plan.lo]] + w * o[:, self.keep[plan.hi]]
        frames = np.asarray(frames, dtype=np.float64)
        lo = np.floor(frames + 1e-9).astype(np.int64)
        w = np.clip(frames - lo, 0.0, 1.0)
        hi = np.where(w > 1e-9, lo + 1, lo)
        klo, khi = self.keep[lo], self.keep[hi]
        if (klo < 0).any() or (khi < 0).any():
            raise ValueError("a frame to read was not kept (all_frames=True reads any frame)")
        p = np.arange(o.shape[0])[:, None]
        w = w[..., None, None]
        return (1.0 - w) * o[p, klo] + w * o[p, khi]
