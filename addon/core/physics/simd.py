"""Lane-vector primitives for the batch kernels: numba intrinsics that emit LLVM vector code.

A *lane array* is a C-contiguous float32 array of shape ``(rows, W)``: row k holds one scalar of
the model for the W candidates simulated together (one candidate per lane). Every primitive below
works on whole rows as ``<W x float>`` vectors with plain IEEE operations (one rounding per
multiply, add, divide or square root; no fused multiply-add, no reassociation), in the same order
as the scalar code it replaces, so a lane computes exactly what the scalar code computes for that
candidate. LLVM's own loop vectoriser does not vectorise the short lane loops (W iterations), hence
these explicit vectors.

numba is required (the callers are numba kernels); without numba the module still imports.

Why by hand, what it gains, how to run without it (``docs/kernels.md``): the lanes must compute
Blender's float32 operations in Blender's order (its CG's stopping iteration depends on rounding),
which rules out ``fastmath``, and without it LLVM leaves the lane loops scalar. Measured by
``python lab/simd_bench.py`` (``docs/figures/simd.json``): the Blender model takes about 14 times
less CPU per candidate than on the plain numba twins (``simd_plain.py``), with the same trajectory
to the bit. ``CLOTHFIT_NO_SIMD=1`` runs those twins instead (``ENABLED`` below).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import SupportsFloat

from .jit import available

W = 8  # lanes per vector: 8 float32 = 256 bits (AVX2; two per AVX-512 register on Zen 4)
# CLOTHFIT_NO_SIMD=1: the Blender kernel runs on simd_plain.py's numba loops instead (docs/kernels.md)
ENABLED = available() and os.environ.get("CLOTHFIT_NO_SIMD", "") in ("", "0")

if available():  # pragma: no branch
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    _F = ir.FloatType()
    _VEC = ir.VectorType(_F, W)
    _I64 = ir.IntType(64)

    def array_data(context, builder, aryty, val):
        return context.make_array(aryty)(context, builder, val).data

    def _rowp(builder, data, row):
        """Pointer to row ``row`` (i64) of a (rows, W) float32 lane array as <W x float>*."""
        p = builder.gep(data, [builder.mul(row, ir.Constant(_I64, W))])
        return builder.bitcast(p, _VEC.as_pointer())

    def _ld(builder, data, row):
        return builder.load(_rowp(builder, data, row), align=4)

    def _st(builder, data, row, val):
        builder.store(val, _rowp(builder, data, row), align=4)

    def _i(builder, data, k):
        """Element k of an int64 array."""
        return builder.load(builder.gep(data, [k]))

    def _splat(builder, x):
        v = builder.insert_element(ir.Constant(_VEC, ir.Undefined), x, ir.Constant(ir.IntType(32), 0))
        return builder.shuffle_vector(
            v, ir.Constant(_VEC, ir.Undefined), ir.Constant(ir.VectorType(ir.IntType(32), W), [0] * W)
        )

    def _c(i):
        return ir.Constant(_I64, i)

    def _row3(builder, m, x, a):
        """Row a of a symmetric block (m00, m01, m02, m11, m12, m22) times x: ((ma0 x0 + ma1 x1) + ma2 x2)."""
        idx = ((0, 1, 2), (1, 3, 4), (2, 4, 5))[a]
        p = builder.fadd(builder.fmul(m[idx[0]], x[0]), builder.fmul(m[idx[1]], x[1]))
        return builder.fadd(p, builder.fmul(m[idx[2]], x[2]))

    @intrinsic
    def matvec(typingctx, Md, Mo, sp_i, sp_j, x, to, temp):
        """Blender's mul_bfmatrix_lfvector on lane arrays: ``to = (sum of transposed off-diagonal
        blocks times x) + (diagonal blocks, then off-diagonal blocks, times x)``, each output
        accumulated in Blender's order. Md (V*6, W), Mo (S*6, W) symmetric blocks; x/to/temp (V*3, W)."""
        sig = types.void(Md, Mo, sp_i, sp_j, x, to, temp)

        def codegen(context, builder, signature, args):
            md, mo, si, sj, xx, tt, tp = (array_data(context, builder, t, a) for t, a in zip(signature.args, args))
            xs = context.make_array(signature.args[4])(context, builder, args[4]).shape
            S = context.make_array(signature.args[2])(context, builder, args[2]).shape
            rows = builder.extract_value(xs, 0)
            nspr = builder.extract_value(S, 0)
            zero = ir.Constant(_VEC, [0.0] * W)
            with cgutils.for_range(builder, rows) as lp:
                _st(builder, tt, lp.index, zero)
                _st(builder, tp, lp.index, zero)
            nv = builder.udiv(rows, _c(3))
            with cgutils.for_range(builder, nv) as lp:
                v3 = builder.mul(lp.index, _c(3))
                v6 = builder.mul(lp.index, _c(6))
                m = [_ld(builder, md, builder.add(v6, _c(q))) for q in range(6)]
                xv = [_ld(builder, xx, builder.add(v3, _c(a))) for a in range(3)]
                for a in range(3):
                    row = builder.add(v3, _c(a))
                    _st(builder, tp, row, builder.fadd(_ld(builder, tp, row), _row3(builder, m, xv, a)))
            with cgutils.for_range(builder, nspr) as lp:
                s = lp.index
                r3 = builder.mul(_i(builder, si, s), _c(3))
                c3 = builder.mul(_i(builder, sj, s), _c(3))
                s6 = builder.mul(s, _c(6))
                m = [_ld(builder, mo, builder.add(s6, _c(q))) for q in range(6)]
                xr = [_ld(builder, xx, builder.add(r3, _c(a))) for a in range(3)]
                xc = [_ld(builder, xx, builder.add(c3, _c(a))) for a in range(3)]
                for a in range(3):
                    row = builder.add(c3, _c(a))
                    _st(builder, tt, row, builder.fadd(_ld(builder, tt, row), _row3(builder, m, xr, a)))
                for a in range(3):
                    row = builder.add(r3, _c(a))
                    _st(builder, tp, row, builder.fadd(_ld(builder, tp, row), _row3(builder, m, xc, a)))
            with cgutils.for_range(builder, rows) as lp:
                _st(builder, tt, lp.index, builder.fadd(_ld(builder, tt, lp.index), _ld(builder, tp, lp.index)))
            return context.get_dummy_value()

        return sig, codegen

    @intrinsic
    def dot(typingctx, a, b, out):
        """out[0] = sum over vertices v (in order) of (a_v0 b_v0 + a_v1 b_v1) + a_v2 b_v2, per lane
        (dot_lfvector). a, b (V*3, W); out (1, W)."""
        sig = types.void(a, b, out)

        def codegen(context, builder, signature, args):
            ad, bd, od = (array_data(context, builder, t, x) for t, x in zip(signature.args, args))
            rows = builder.extract_value(context.make_array(signature.args[0])(context, builder, args[0]).shape, 0)
            nv = builder.udiv(rows, _c(3))
            acc = cgutils.alloca_once_value(builder, ir.Constant(_VEC, [0.0] * W))
            with cgutils.for_range(builder, nv) as lp:
                v3 = builder.mul(lp.index, _c(3))
                p0 = builder.fmul(_ld(builder, ad, v3), _ld(builder, bd, v3))
                r1 = builder.add(v3, _c(1))
                r2 = builder.add(v3, _c(2))
                p = builder.fadd(p0, builder.fmul(_ld(builder, ad, r1), _ld(builder, bd, r1)))
                p = builder.fadd(p, builder.fmul(_ld(builder, ad, r2), _ld(builder, bd, r2)))
                builder.store(builder.fadd(builder.load(acc), p), acc)
            _st(builder, od, _c(0), builder.load(acc))
            return context.get_dummy_value()

        return sig, codegen

    @intrinsic
    def scale_rows(typingctx, x, free):
        """x[3v + a] = x[3v + a] * free[v] for every vertex (Blender's constraint filter with S = I
        or 0). x (V*3, W) float32; free (V,) float32."""
        sig = types.void(x, free)

        def codegen(context, builder, signature, args):
            xd, fd = (array_data(context, builder, t, v) for t, v in zip(signature.args, args))
            rows = builder.extract_value(context.make_array(signature.args[0])(context, builder, args[0]).shape, 0)
            with cgutils.for_range(builder, builder.udiv(rows, _c(3))) as lp:
                f = _splat(builder, builder.load(builder.gep(fd, [lp.index])))
                v3 = builder.mul(lp.index, _c(3))
                for a in range(3):
                    row = builder.add(v3, _c(a))
                    _st(builder, xd, row, builder.fmul(_ld(builder, xd, row), f))
            return context.get_dummy_value()

        return sig, codegen

    @intrinsic
    def cg_step(typingctx, dV, r, c, q, alpha, mask):
        """Where mask != 0: dV = dV + c * alpha; r = r + q * (-alpha). alpha/mask (1, W)."""
        sig = types.void(dV, r, c, q, alpha, mask)

        def codegen(context, builder, signature, args):
            dv, rr, cc, qq, al, mk = (array_data(context, builder, t, v) for t, v in zip(signature.args, args))
            rows = builder.extract_value(context.make_array(signature.args[0])(context, builder, args[0]).shape, 0)
            a = _ld(builder, al, _c(0))
            na = builder.fneg(a)
            m = builder.fcmp_unordered("!=", _ld(builder, mk, _c(0)), ir.Constant(_VEC, [0.0] * W))
            with cgutils.for_range(builder, rows) as lp:
                k = lp.index
                cv = _ld(builder, cc, k)
                qv = _ld(builder, qq, k)
                d0 = _ld(builder, dv, k)
                r0 = _ld(builder, rr, k)
                _st(builder, dv, k, builder.select(m, builder.fadd(d0, builder.fmul(cv, a)), d0))
                _st(builder, rr, k, builder.select(m, builder.fadd(r0, builder.fmul(qv, na)), r0))
            return context.get_dummy_value()

        return sig, codegen

    @intrinsic
    def cg_direction(typingctx, c, r, ratio, mask, free):
        """Where mask != 0: c = (r + c * ratio) * free[v] (the new search direction, filtered)."""
        sig = types.void(c, r, ratio, mask, free)

        def codegen(context, builder, signature, args):
            cc, rr, ra, mk, fd = (array_data(context, builder, t, v) for t, v in zip(signature.args, args))
            rows = builder.extract_value(context.make_array(signature.args[0])(context, builder, args[0]).shape, 0)
            rt = _ld(builder, ra, _c(0))
            m = builder.fcmp_unordered("!=", _ld(builder, mk, _c(0)), ir.Constant(_VEC, [0.0] * W))
            with cgutils.for_range(builder, builder.udiv(rows, _c(3))) as lp:
                f = _splat(builder, builder.load(builder.gep(fd, [lp.index])))
                v3 = builder.mul(lp.index, _c(3))
                for a in range(3):
                    k = builder.add(v3, _c(a))
                    c0 = _ld(builder, cc, k)
                    nc = builder.fmul(builder.fadd(_ld(builder, rr, k), builder.fmul(c0, rt)), f)
                    _st(builder, cc, k, builder.select(m, nc, c0))
            return context.get_dummy_value()

        return sig, codegen


if available():  # pragma: no branch

    class VB:
        """A small vector language over one IR builder: lane vectors of W float32, one IEEE rounding
        per operation (the order of operations is the caller's, as written)."""

        def __init__(self, context, builder):
            self.c, self.b = context, builder
            self.zero = ir.Constant(_VEC, [0.0] * W)

        # constants and scalars
        def k(self, x: SupportsFloat) -> ir.Constant:
            """A float32 constant in every lane (x is rounded to float32 first)."""
            import numpy as np

            return ir.Constant(_VEC, [float(np.float32(x))] * W)

        def splat(self, x: ir.Value) -> ir.Value:
            return _splat(self.b, x)

        def i(self, data: ir.Value, k: ir.Value) -> ir.Value:
            return _i(self.b, data, k)

        def f(self, data: ir.Value, k: ir.Value) -> ir.Value:
            """Element k of a float32 array, in every lane."""
            return _splat(self.b, self.b.load(self.b.gep(data, [k])))

        # memory: rows of lane arrays
        def ld(self, data: ir.Value, row: ir.Value) -> ir.Value:
            return _ld(self.b, data, row)

        def st(self, data: ir.Value, row: ir.Value, v: ir.Value) -> None:
            _st(self.b, data, row, v)

        def ld3(self, data: ir.Value, v3: ir.Value) -> list[ir.Value]:
            return [_ld(self.b, data, self.b.add(v3, _c(a))) for a in range(3)]

        # arithmetic
        def add(self, x: ir.Value, y: ir.Value) -> ir.Value:
            return self.b.fadd(x, y)

        def sub(self, x: ir.Value, y: ir.Value) -> ir.Value:
            return self.b.fsub(x, y)

        def mul(self, x: ir.Value, y: ir.Value) -> ir.Value:
            return self.b.fmul(x, y)

        def div(self, x: ir.Value, y: ir.Value) -> ir.Value:
            return self.b.fdiv(x, y)

        def neg(self, x: ir.Value) -> ir.Value:
            return self.b.fneg(x)

        def sqrt(self, x: ir.Value) -> ir.Value:
            fn = cgutils.get_or_insert_function(self.b.module, ir.FunctionType(_VEC, [_VEC]), f"llvm.sqrt.v{W}f32")
            return self.b.call(fn, [x])

        def atan2(self, y: ir.Value, x: ir.Value) -> ir.Value:
            """glibc's atan2f lane by lane (what Blender calls)."""
            fnty = ir.FunctionType(_F, [_F, _F])
            fn = cgutils.get_or_insert_function(self.b.module, fnty, "atan2f")
            out = ir.Constant(_VEC, ir.Undefined)
            for l in range(W):
                idx = ir.Constant(ir.IntType(32), l)
                r = self.b.call(fn, [self.b.extract_element(y, idx), self.b.extract_element(x, idx)])
                out = self.b.insert_element(out, r, idx)
            return out

        # comparisons (ordered: false when a NaN is involved, like C's <, >, >=) and selection
        def lt(self, x: ir.Value, y: ir.Value) -> ir.Value:
            return self.b.fcmp_ordered("<", x, y)

        def gt(self, x: ir.Value, y: ir.Value) -> ir.Value:
            return self.b.fcmp_ordered(">", x, y)

        def ge(self, x: ir.Value, y: ir.Value) -> ir.Value:
            return self.b.fcmp_ordered(">=", x, y)

        def land(self, m: ir.Value, n: ir.Value) -> ir.Value:
            return self.b.and_(m, n)

        def sel(self, m: ir.Value, x: ir.Value, y: ir.Value) -> ir.Value:
            return self.b.select(m, x, y)

        def true(self) -> ir.Constant:
            return ir.Constant(ir.VectorType(ir.IntType(1), W), [1] * W)

        def splat_bool(self, bit: ir.Value) -> ir.Value:
            """An i1 scalar in every lane."""
            m = ir.VectorType(ir.IntType(1), W)
            v = self.b.insert_element(ir.Constant(m, ir.Undefined), bit, ir.Constant(ir.IntType(32), 0))
            return self.b.shuffle_vector(
                v, ir.Constant(m, ir.Undefined), ir.Constant(ir.VectorType(ir.IntType(32), W), [0] * W)
            )

        # 3-vectors as lists of lane vectors
        def dot3(self, a: Sequence[ir.Value], b: Sequence[ir.Value]) -> ir.Value:
            return self.add(self.add(self.mul(a[0], b[0]), self.mul(a[1], b[1])), self.mul(a[2], b[2]))

        def cross3(self, a: Sequence[ir.Value], b: Sequence[ir.Value]) -> list[ir.Value]:
            return [
                self.sub(self.mul(a[1], b[2]), self.mul(a[2], b[1])),
                self.sub(self.mul(a[2], b[0]), self.mul(a[0], b[2])),
                self.sub(self.mul(a[0], b[1]), self.mul(a[1], b[0])),
            ]

        def normalize3(self, a: Sequence[ir.Value]) -> list[ir.Value]:
            """normalize_v3: a / |a| if |a|^2 > 1e-35, else 0."""
            d = self.dot3(a, a)
            ok = self.gt(d, self.k(1.0e-35))
            f = self.div(self.k(1.0), self.sqrt(d))
            return [self.sel(ok, self.mul(x, f), self.zero) for x in a]

        def normal_tri(self, p: Sequence[ir.Value], q: Sequence[ir.Value], r: Sequence[ir.Value]) -> list[ir.Value]:
            """normal_tri_v3(n, p, q, r) = normalize((p - q) x (q - r))."""
            n1 = [self.sub(p[a], q[a]) for a in range(3)]
            n2 = [self.sub(q[a], r[a]) for a in range(3)]
            return self.normalize3(
                [
                    self.sub(self.mul(n1[1], n2[2]), self.mul(n1[2], n2[1])),
                    self.sub(self.mul(n1[2], n2[0]), self.mul(n1[0], n2[2])),
                    self.sub(self.mul(n1[0], n2[1]), self.mul(n1[1], n2[0])),
                ]
            )

        def var(self, init: ir.Value) -> ir.Value:
            p = cgutils.alloca_once(self.b, _VEC)
            self.b.store(init, p)
            return p

        def get(self, p: ir.Value) -> ir.Value:
            return self.b.load(p)

        def set(self, p: ir.Value, v: ir.Value) -> None:
            self.b.store(v, p)
