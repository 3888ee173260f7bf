"""The spring part of Blender's ``cloth_calc_force`` for W candidates (lanes) at once, as
hand-written LLVM IR through a numba intrinsic (``springs_v``, on ``simd.py``'s lane vectors).
``springs_plain`` is its plain numba twin (the same float32 operations in the same order, lane by
lane), which the kernel runs with ``CLOTHFIT_NO_SIMD=1``. Why the IR is hand-written, what it gains
(``python lab/simd_bench.py``) and how to run without it: ``docs/kernels.md``.
"""

from __future__ import annotations

import math

import numpy as np

from . import simd
from .blender_constants import (
    C4,
    D3,
    F32,
    FLT_EPS,
    HALF,
    KIND_BEND,
    KIND_STRUCT,
    NORM_EPS,
    ONE,
    P_BDAMP,
    P_BEND,
    P_CB,
    P_DC,
    P_DS,
    P_DT,
    P_KB,
    P_KC,
    P_KS,
    P_KT,
    TENTH,
    ZERO,
)
from .jit import JIT, njit

if simd.available():  # pragma: no branch
    from llvmlite import ir as _ir
    from numba import types as _types
    from numba.core import cgutils as _cg
    from numba.extending import intrinsic as _intrinsic

    def _fb_v(vb, x):
        xx = vb.mul(x, x)
        xxx = vb.mul(xx, x)
        xxxx = vb.mul(xxx, x)
        r = vb.add(vb.mul(vb.k(C4[0]), xxxx), vb.mul(vb.k(C4[1]), xxx))
        r = vb.add(vb.add(r, vb.mul(vb.k(C4[2]), xx)), vb.mul(vb.k(C4[3]), x))
        return vb.add(r, vb.k(C4[4]))

    def _fbderiv_v(vb, x):
        xx = vb.mul(x, x)
        xxx = vb.mul(xx, x)
        r = vb.add(vb.mul(vb.k(D3[0]), xxx), vb.mul(vb.k(D3[1]), xx))
        return vb.add(vb.add(r, vb.mul(vb.k(D3[2]), x)), vb.k(D3[3]))

    def _choi_ko(vb, ln, L0, kb, cb):
        """fbstar and fbstar_jacobi: (force along the spring, its -d/dlength), lane by lane."""
        x = vb.div(ln, L0)
        tfb = vb.mul(kb, _fb_v(vb, x))
        lin = vb.mul(cb, vb.sub(ln, L0))
        use_lin = vb.lt(tfb, lin)
        return vb.sel(use_lin, lin, tfb), vb.sel(use_lin, vb.neg(cb), vb.mul(vb.neg(kb), _fbderiv_v(vb, x)))

    def _poly_avg_v(vb, P, pa_row, n):
        """poly_avg over the n corners listed at pa_row (pointer to int64), lane vectors."""
        b = vb.b
        fact = vb.splat(b.fdiv(_ir.Constant(_ir.FloatType(), 1.0), b.sitofp(n, _ir.FloatType())))
        acc = [vb.var(vb.zero) for _ in range(3)]
        with _cg.for_range(b, n) as lp:
            v3 = b.mul(b.load(b.gep(pa_row, [lp.index])), _ir.Constant(_ir.IntType(64), 3))
            x = vb.ld3(P, v3)
            for a in range(3):
                vb.set(acc[a], vb.add(vb.get(acc[a]), vb.mul(x[a], fact)))
        return [vb.get(a) for a in acc]

    def _addrow(vb, data, row, v, mask=None):
        old = vb.ld(data, row)
        new = vb.add(old, v)
        vb.st(data, row, new if mask is None else vb.sel(mask, new, old))

    def _subrow(vb, data, row, v, mask=None):
        old = vb.ld(data, row)
        new = vb.sub(old, v)
        vb.st(data, row, new if mask is None else vb.sel(mask, new, old))

    def _hinge_ir(vb, b, c, x_, v_, f_, pa_, pb_, la_, lb_, ra_, prow, hb, maxl, i3, j3, L0):
        """The angular bending force across hinge ``hb`` (explicit; Blender's cloth_calc_force), lane by
        lane, into the force rows ``f_``: the IR ``springs_v`` emits for a spring that carries a hinge."""
        pa_row = b.gep(pa_, [b.mul(hb, maxl)])
        pb_row = b.gep(pb_, [b.mul(hb, maxl)])
        la = vb.i(la_, hb)
        lb = vb.i(lb_, hb)
        Xi = vb.ld3(x_, i3)
        Xj = vb.ld3(x_, j3)
        ma = _poly_avg_v(vb, x_, pa_row, la)
        da = vb.normal_tri(Xj, Xi, ma)
        mb = _poly_avg_v(vb, x_, pb_row, lb)
        db = vb.normal_tri(Xi, Xj, mb)
        e = vb.normalize3([vb.sub(Xi[a], Xj[a]) for a in range(3)])
        cos = vb.dot3(da, db)
        sin = vb.dot3(vb.cross3(da, db), e)
        ang = vb.atan2(sin, cos)
        va = _poly_avg_v(vb, v_, pa_row, la)
        vbb = _poly_avg_v(vb, v_, pb_row, lb)
        Vi = vb.ld3(v_, i3)
        Vj = vb.ld3(v_, j3)
        ve = [vb.mul(vb.add(Vi[a], Vj[a]), vb.k(0.5)) for a in range(3)]
        va = [vb.sub(va[a], ve[a]) for a in range(3)]
        vbb = [vb.sub(vbb[a], ve[a]) for a in range(3)]
        k = vb.mul(vb.mul(prow(P_BEND), L0), vb.k(0.1))
        force = vb.mul(k, vb.sub(ang, vb.ld(ra_, hb)))
        force = vb.add(force, vb.mul(vb.neg(prow(P_BDAMP)), vb.add(vb.dot3(va, da), vb.dot3(vbb, db))))
        fa = vb.div(force, vb.splat(b.sitofp(la, _ir.FloatType())))
        fbv = vb.div(force, vb.splat(b.sitofp(lb, _ir.FloatType())))
        with _cg.for_range(b, la) as lq:
            u3 = b.mul(b.load(b.gep(pa_row, [lq.index])), c(3))
            for a in range(3):
                _addrow(vb, f_, b.add(u3, c(a)), vb.mul(da[a], fa))
        with _cg.for_range(b, lb) as lq:
            u3 = b.mul(b.load(b.gep(pb_row, [lq.index])), c(3))
            for a in range(3):
                _addrow(vb, f_, b.add(u3, c(a)), vb.mul(db[a], fbv))
        fh = vb.mul(force, vb.k(0.5))
        fe = [vb.add(vb.mul(da[a], fh), vb.mul(db[a], fh)) for a in range(3)]
        for a in range(3):
            _subrow(vb, f_, b.add(i3, c(a)), fe[a])
        for a in range(3):
            _subrow(vb, f_, b.add(j3, c(a)), fe[a])

    @_intrinsic
    def springs_v(
        typingctx,
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
        par,
        angular,
    ):
        """The spring part of cloth_calc_force for W lanes at once, spring by spring in Blender's list
        order: the hinge's angular bending force (explicit), then the spring's linear force, its
        Jacobian blocks (diagonal into Xd/Vd, off-diagonal into Xo/Vo) and damping; per-lane
        branches (tension or compression, active or not) become selections."""
        sig = _types.void(
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
            par,
            angular,
        )

        def codegen(context, builder, signature, args):
            from .simd import VB, array_data

            vb = VB(context, builder)
            b = builder
            I64 = _ir.IntType(64)

            def c(i):
                return _ir.Constant(I64, i)

            (x_, v_, f_, xd_, vd_, xo_, vo_, si_, sj_, sk_, sh_, rl_, pa_, la_, pb_, lb_, ra_, par_) = (
                array_data(context, builder, t, a) for t, a in zip(signature.args[:18], args[:18])
            )
            ang_on = b.icmp_signed("!=", args[18], c(0))
            S = b.extract_value(context.make_array(signature.args[7])(context, builder, args[7]).shape, 0)
            maxl = b.extract_value(context.make_array(signature.args[12])(context, builder, args[12]).shape, 1)
            prow = lambda k: vb.ld(par_, c(k))  # noqa: E731  lane parameter rows
            with _cg.for_range(b, S) as lp:
                s = lp.index
                i = vb.i(si_, s)
                j = vb.i(sj_, s)
                kind = vb.i(sk_, s)
                hb = vb.i(sh_, s)
                i3 = b.mul(i, c(3))
                j3 = b.mul(j, c(3))
                i6 = b.mul(i, c(6))
                j6 = b.mul(j, c(6))
                s6 = b.mul(s, c(6))
                L0 = vb.ld(rl_, s)
                # ---- angular bending across the hinge this spring carries
                with b.if_then(b.and_(ang_on, b.icmp_signed(">=", hb, c(0)))):
                    _hinge_ir(vb, b, c, x_, v_, f_, pa_, pb_, la_, lb_, ra_, prow, hb, maxl, i3, j3, L0)
                # ---- the linear spring
                Xi = vb.ld3(x_, i3)
                Xj = vb.ld3(x_, j3)
                Vi = vb.ld3(v_, i3)
                Vj = vb.ld3(v_, j3)
                ext = [vb.sub(Xj[a], Xi[a]) for a in range(3)]
                w = [vb.sub(Vj[a], Vi[a]) for a in range(3)]
                ln = vb.sqrt(vb.dot3(ext, ext))
                okd = vb.gt(ln, vb.k(FLT_EPS))
                inv = vb.div(vb.k(1.0), ln)
                d = [vb.sel(okd, vb.mul(ext[a], inv), vb.zero) for a in range(3)]
                pp = [
                    vb.mul(d[0], d[0]),
                    vb.mul(d[1], d[0]),
                    vb.mul(d[2], d[0]),
                    vb.mul(d[1], d[1]),
                    vb.mul(d[2], d[1]),
                    vb.mul(d[2], d[2]),
                ]
                diag = (True, False, False, True, False, True)
                is_struct = b.icmp_signed("==", kind, c(KIND_STRUCT))
                is_bend = b.icmp_signed("==", kind, c(KIND_BEND))
                # tension (structural or shear)
                kt = vb.sel(vb.splat_bool(is_struct), prow(P_KT), prow(P_KS))
                dtn = vb.sel(vb.splat_bool(is_struct), prow(P_DT), prow(P_DS))
                tension = vb.land(vb.ge(ln, L0), vb.gt(ln, vb.zero))
                sf_t = vb.mul(kt, vb.sub(ln, L0))
                r_ = vb.div(L0, ln)
                one = vb.k(1.0)
                jt = [
                    vb.mul(
                        vb.sub(vb.mul(vb.sub(one if diag[q] else vb.zero, pp[q]), r_), one if diag[q] else vb.zero), kt
                    )
                    for q in range(6)
                ]
                # compression: Choi & Ko (structural springs with angular bending; linear bending springs)
                kb = vb.sel(vb.splat_bool(is_bend), prow(P_KB), prow(P_KC))
                cb = vb.sel(vb.splat_bool(is_bend), prow(P_CB), prow(P_KC))
                sf_c, jac = _choi_ko(vb, ln, L0, kb, cb)
                jc = [vb.mul(pp[q], jac) for q in range(6)]
                # which lanes have a force, and which branch
                struct_compress = b.and_(is_struct, ang_on)
                act_lin = vb.sel(vb.splat_bool(struct_compress), vb.true(), tension)
                act_bend = vb.lt(ln, L0)
                act = vb.sel(vb.splat_bool(is_bend), act_bend, act_lin)
                use_t = vb.land(tension, vb.splat_bool(b.not_(is_bend)))
                sf = vb.sel(use_t, sf_t, sf_c)
                damping = vb.sel(use_t, dtn, prow(P_DC))
                fv = [vb.mul(d[a], sf) for a in range(3)]
                jx = [vb.sel(use_t, jt[q], jc[q]) for q in range(6)]
                # damping along the spring (not for linear bending springs)
                dv = vb.mul(damping, vb.dot3(w, d))
                fd = [vb.add(fv[a], vb.mul(d[a], dv)) for a in range(3)]
                fv = [vb.sel(vb.splat_bool(is_bend), fv[a], fd[a]) for a in range(3)]
                nd = vb.neg(damping)
                jv = [vb.sel(vb.splat_bool(is_bend), vb.zero, vb.mul(pp[q], nd)) for q in range(6)]
                for a in range(3):
                    _addrow(vb, f_, b.add(i3, c(a)), fv[a], act)
                for a in range(3):
                    _subrow(vb, f_, b.add(j3, c(a)), fv[a], act)
                for q in range(6):
                    _addrow(vb, xd_, b.add(i6, c(q)), jx[q], act)
                    _addrow(vb, xd_, b.add(j6, c(q)), jx[q], act)
                    vb.st(xo_, b.add(s6, c(q)), vb.sel(act, vb.sub(vb.zero, jx[q]), vb.zero))
                    _addrow(vb, vd_, b.add(i6, c(q)), jv[q], act)
                    _addrow(vb, vd_, b.add(j6, c(q)), jv[q], act)
                    vb.st(vo_, b.add(s6, c(q)), vb.sel(act, vb.sub(vb.zero, jv[q]), vb.zero))
            return context.get_dummy_value()

        return sig, codegen


# ------------------------------------------------------------------ the plain numba twin (CLOTHFIT_NO_SIMD=1)


@njit(**JIT)
def _fb_p(x):
    xx = x * x
    xxx = xx * x
    xxxx = xxx * x
    r = C4[0] * xxxx + C4[1] * xxx
    r = (r + C4[2] * xx) + C4[3] * x
    return r + C4[4]


@njit(**JIT)
def _fbderiv_p(x):
    xx = x * x
    xxx = xx * x
    r = D3[0] * xxx + D3[1] * xx
    return (r + D3[2] * x) + D3[3]


@njit(**JIT)
def _normalize3_p(a0, a1, a2):
    d = (a0 * a0 + a1 * a1) + a2 * a2
    f = ONE / math.sqrt(d)
    if d > NORM_EPS:
        return a0 * f, a1 * f, a2 * f
    return ZERO, ZERO, ZERO


@njit(**JIT)
def _normal_tri_p(p0, p1, p2, q0, q1, q2, r0, r1, r2):
    n10, n11, n12 = p0 - q0, p1 - q1, p2 - q2
    n20, n21, n22 = q0 - r0, q1 - r1, q2 - r2
    return _normalize3_p(n11 * n22 - n12 * n21, n12 * n20 - n10 * n22, n10 * n21 - n11 * n20)


@njit(**JIT)
def _poly_avg_p(P, row, n, l):
    fact = ONE / F32(n)
    a0 = ZERO
    a1 = ZERO
    a2 = ZERO
    for k in range(n):
        v3 = row[k] * 3
        a0 = a0 + P[v3, l] * fact
        a1 = a1 + P[v3 + 1, l] * fact
        a2 = a2 + P[v3 + 2, l] * fact
    return a0, a1, a2


@njit(**JIT)
def _hinge_p(X, Vel, F, i3, j3, L0, hb, h_pa, h_la, h_pb, h_lb, restang, par, l):
    """``_hinge_ir`` for lane l, operation by operation."""
    la, lb = h_la[hb], h_lb[hb]
    pa_row, pb_row = h_pa[hb], h_pb[hb]
    xi0, xi1, xi2 = X[i3, l], X[i3 + 1, l], X[i3 + 2, l]
    xj0, xj1, xj2 = X[j3, l], X[j3 + 1, l], X[j3 + 2, l]
    m0, m1, m2 = _poly_avg_p(X, pa_row, la, l)
    da0, da1, da2 = _normal_tri_p(xj0, xj1, xj2, xi0, xi1, xi2, m0, m1, m2)
    m0, m1, m2 = _poly_avg_p(X, pb_row, lb, l)
    db0, db1, db2 = _normal_tri_p(xi0, xi1, xi2, xj0, xj1, xj2, m0, m1, m2)
    e0, e1, e2 = _normalize3_p(xi0 - xj0, xi1 - xj1, xi2 - xj2)
    cos = (da0 * db0 + da1 * db1) + da2 * db2
    c0, c1, c2 = da1 * db2 - da2 * db1, da2 * db0 - da0 * db2, da0 * db1 - da1 * db0
    sin = (c0 * e0 + c1 * e1) + c2 * e2
    ang = math.atan2(sin, cos)
    va0, va1, va2 = _poly_avg_p(Vel, pa_row, la, l)
    vb0, vb1, vb2 = _poly_avg_p(Vel, pb_row, lb, l)
    ve0 = (Vel[i3, l] + Vel[j3, l]) * HALF
    ve1 = (Vel[i3 + 1, l] + Vel[j3 + 1, l]) * HALF
    ve2 = (Vel[i3 + 2, l] + Vel[j3 + 2, l]) * HALF
    va0, va1, va2 = va0 - ve0, va1 - ve1, va2 - ve2
    vb0, vb1, vb2 = vb0 - ve0, vb1 - ve1, vb2 - ve2
    k = (par[P_BEND, l] * L0) * TENTH
    force = k * (ang - restang[hb, l])
    force = force + (-par[P_BDAMP, l]) * (((va0 * da0 + va1 * da1) + va2 * da2) + ((vb0 * db0 + vb1 * db1) + vb2 * db2))
    fa = force / F32(la)
    fbv = force / F32(lb)
    for q in range(la):
        u3 = pa_row[q] * 3
        F[u3, l] = F[u3, l] + da0 * fa
        F[u3 + 1, l] = F[u3 + 1, l] + da1 * fa
        F[u3 + 2, l] = F[u3 + 2, l] + da2 * fa
    for q in range(lb):
        u3 = pb_row[q] * 3
        F[u3, l] = F[u3, l] + db0 * fbv
        F[u3 + 1, l] = F[u3 + 1, l] + db1 * fbv
        F[u3 + 2, l] = F[u3 + 2, l] + db2 * fbv
    fh = force * HALF
    fe0, fe1, fe2 = da0 * fh + db0 * fh, da1 * fh + db1 * fh, da2 * fh + db2 * fh
    F[i3, l] = F[i3, l] - fe0
    F[i3 + 1, l] = F[i3 + 1, l] - fe1
    F[i3 + 2, l] = F[i3 + 2, l] - fe2
    F[j3, l] = F[j3, l] - fe0
    F[j3 + 1, l] = F[j3 + 1, l] - fe1
    F[j3 + 2, l] = F[j3 + 2, l] - fe2


@njit(**JIT)
def springs_plain(
    X, Vel, F, Xd, Vd, Xo, Vo, sp_i, sp_j, sp_kind, sp_hinge, restlen, h_pa, h_la, h_pb, h_lb, restang, par, angular
):
    """``springs_v`` as ordinary numba loops, lane by lane, with the same operations in the same order."""
    pp = np.empty(6, dtype=np.float32)
    jx = np.empty(6, dtype=np.float32)
    jv = np.empty(6, dtype=np.float32)
    d = np.empty(3, dtype=np.float32)
    fv = np.empty(3, dtype=np.float32)
    for s in range(sp_i.shape[0]):
        i3, j3, i6, j6, s6 = 3 * sp_i[s], 3 * sp_j[s], 6 * sp_i[s], 6 * sp_j[s], 6 * s
        kind, hb = sp_kind[s], sp_hinge[s]
        is_struct, is_bend = kind == KIND_STRUCT, kind == KIND_BEND
        for l in range(X.shape[1]):
            L0 = restlen[s, l]
            if angular != 0 and hb >= 0:
                _hinge_p(X, Vel, F, i3, j3, L0, hb, h_pa, h_la, h_pb, h_lb, restang, par, l)
            ext0, ext1, ext2 = X[j3, l] - X[i3, l], X[j3 + 1, l] - X[i3 + 1, l], X[j3 + 2, l] - X[i3 + 2, l]
            w0, w1, w2 = Vel[j3, l] - Vel[i3, l], Vel[j3 + 1, l] - Vel[i3 + 1, l], Vel[j3 + 2, l] - Vel[i3 + 2, l]
            ln = math.sqrt((ext0 * ext0 + ext1 * ext1) + ext2 * ext2)
            inv = ONE / ln
            okd = ln > FLT_EPS
            d[0] = ext0 * inv if okd else ZERO
            d[1] = ext1 * inv if okd else ZERO
            d[2] = ext2 * inv if okd else ZERO
            pp[0], pp[1], pp[2] = d[0] * d[0], d[1] * d[0], d[2] * d[0]
            pp[3], pp[4], pp[5] = d[1] * d[1], d[2] * d[1], d[2] * d[2]
            kt = par[P_KT, l] if is_struct else par[P_KS, l]
            dtn = par[P_DT, l] if is_struct else par[P_DS, l]
            tension = ln >= L0 and ln > ZERO
            sf_t = kt * (ln - L0)
            r_ = L0 / ln
            kb = par[P_KB, l] if is_bend else par[P_KC, l]
            cb = par[P_CB, l] if is_bend else par[P_KC, l]
            x = ln / L0
            tfb = kb * _fb_p(x)
            lin = cb * (ln - L0)
            use_lin = tfb < lin
            sf_c = lin if use_lin else tfb
            jac = -cb if use_lin else (-kb) * _fbderiv_p(x)
            act_lin = True if (is_struct and angular != 0) else tension
            act = (ln < L0) if is_bend else act_lin
            use_t = tension and not is_bend
            sf = sf_t if use_t else sf_c
            damping = dtn if use_t else par[P_DC, l]
            for q in range(6):
                dg = ONE if (q == 0 or q == 3 or q == 5) else ZERO
                jx[q] = (((dg - pp[q]) * r_) - dg) * kt if use_t else pp[q] * jac
            dv = damping * ((w0 * d[0] + w1 * d[1]) + w2 * d[2])
            for a in range(3):
                fv[a] = d[a] * sf if is_bend else d[a] * sf + d[a] * dv
            nd = -damping
            for q in range(6):
                jv[q] = ZERO if is_bend else pp[q] * nd
            for a in range(3):
                if act:
                    F[i3 + a, l] = F[i3 + a, l] + fv[a]
            for a in range(3):
                if act:
                    F[j3 + a, l] = F[j3 + a, l] - fv[a]
            for q in range(6):
                if act:
                    Xd[i6 + q, l] = Xd[i6 + q, l] + jx[q]
                    Xd[j6 + q, l] = Xd[j6 + q, l] + jx[q]
                Xo[s6 + q, l] = (ZERO - jx[q]) if act else ZERO
                if act:
                    Vd[i6 + q, l] = Vd[i6 + q, l] + jv[q]
                    Vd[j6 + q, l] = Vd[j6 + q, l] + jv[q]
                Vo[s6 + q, l] = (ZERO - jv[q]) if act else ZERO
