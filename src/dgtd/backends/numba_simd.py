"""Dot products, neighbour sums and dense updates in explicit vector instructions, for the compiled kernels.

Without fastmath, LLVM may not reorder a floating-point sum, so a plain loop `acc += x[f] * y[f]` stays scalar.
`_dots3` writes the vector code itself: four lanes, lane l summing the products f = l, l + 4, l + 8, ... in
order, then (lane 0 + lane 1) + (lane 2 + lane 3), then the q mod 4 remaining products in order. The order is
fixed by the code, not by the compiler, so every process gets the same bits. `_laplacian_rows` and
`_dense_updates` keep each element's arithmetic as plain code writes it and only choose how many elements
travel together.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_LANE = ir.IntType(32)


def _all_c_contiguous(*arrays) -> bool:
    """The intrinsics read rows as contiguous memory: every array must be typed C-contiguous."""
    return all(isinstance(a, types.Array) and a.layout == "C" for a in arrays)


def _row(context, builder, aryty, ary, index):
    """Pointer to element [*index, 0] of a numba array value: the start of a row."""
    arr = context.make_array(aryty)(context, builder, ary)
    zero = ir.Constant(ir.IntType(64), 0)
    return cgutils.get_item_pointer(context, builder, aryty, arr, [*index, zero], wraparound=False)


def _splat(builder, x, vec):
    """The vector of type vec with x in every lane."""
    out = ir.Constant(vec, ir.Undefined)
    for k in range(vec.count):
        out = builder.insert_element(out, x, ir.Constant(_LANE, k))
    return out


@intrinsic
def _dots3(typingctx, Phi, s, sn, theta, Z, b, i, q):
    """(phi(s)^T theta[b, i], phi(s)^T w, phi(sn)^T w) with w = Z[b, i, :q], for C-contiguous Phi (S, q),
    theta (B, N, q) and Z (B, N, m >= q); the TD terms of Algorithm 1 line 7."""
    if not _all_c_contiguous(Phi, theta, Z):
        return None
    sig = types.UniTuple(types.float64, 3)(Phi, s, sn, theta, Z, b, i, q)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        vec = ir.VectorType(ir.DoubleType(), 4)
        zero = ir.Constant(i64, 0)
        s_, sn_, b_, i_, q_ = (context.cast(builder, args[k], signature.args[k], types.int64) for k in (1, 2, 5, 6, 7))
        row = lambda k, index: _row(context, builder, signature.args[k], args[k], index)
        p_s, p_sn, p_th, p_w = row(0, [s_]), row(0, [sn_]), row(3, [b_, i_]), row(4, [b_, i_])
        pairs = ((p_s, p_th), (p_s, p_w), (p_sn, p_w))
        lanes = [cgutils.alloca_once_value(builder, ir.Constant(vec, [0.0] * 4)) for _ in pairs]
        q4 = builder.and_(q_, ir.Constant(i64, ~3))
        with cgutils.for_range_slice(builder, zero, q4, ir.Constant(i64, 4)) as (f, _):
            load = lambda p: builder.load(builder.bitcast(builder.gep(p, [f]), vec.as_pointer()), align=8)
            for acc, (x, y) in zip(lanes, pairs):
                builder.store(builder.fadd(builder.load(acc), builder.fmul(load(x), load(y))), acc)
        sums = []
        for acc in lanes:
            v = builder.load(acc)
            e = [builder.extract_element(v, ir.Constant(_LANE, k)) for k in range(4)]
            total = builder.fadd(builder.fadd(e[0], e[1]), builder.fadd(e[2], e[3]))
            sums.append(cgutils.alloca_once_value(builder, total))
        with cgutils.for_range_slice(builder, q4, q_, ir.Constant(i64, 1)) as (f, _):
            for acc, (x, y) in zip(sums, pairs):
                prod = builder.fmul(builder.load(builder.gep(x, [f])), builder.load(builder.gep(y, [f])))
                builder.store(builder.fadd(builder.load(acc), prod), acc)
        return context.make_tuple(builder, signature.return_type, [builder.load(acc) for acc in sums])

    return sig, codegen


UNROLLED_NEIGHBOURS = 8  # up to this many neighbours, `_laplacian_rows` has a loop of its own for each count


@intrinsic
def _laplacian_rows(typingctx, Z, b, i, js, count, L, l):
    """L[l] = count Z[b, i] - Z[b, js[0]] - ... - Z[b, js[count - 1]], element by element in that order, for
    C-contiguous Z (B, N, m), L (., m) and js (int64): agent i's row of L(k) Z (Algorithm 1's neighbour sums).
    Sixteen elements at a time stay in vector registers while the neighbours' rows stream past, so the row of L
    is written once instead of once per neighbour. Up to UNROLLED_NEIGHBOURS neighbours, the code branches on
    the count once and then runs straight-line code for that count: a loop over a count that changes from agent
    to agent would be mispredicted at every block of sixteen elements."""
    if not _all_c_contiguous(Z, js, L):
        return None
    sig = types.void(Z, b, i, js, count, L, l)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        f64 = ir.DoubleType()
        vec = ir.VectorType(f64, 4)
        zero = ir.Constant(i64, 0)
        b_, i_, n_, l_ = (context.cast(builder, args[k], signature.args[k], types.int64) for k in (1, 2, 4, 6))
        zty, jty, lty = signature.args[0], signature.args[3], signature.args[5]
        m = builder.extract_value(context.make_array(zty)(context, builder, args[0]).shape, 2)
        p_i = _row(context, builder, zty, args[0], [b_, i_])
        p_l = _row(context, builder, lty, args[5], [l_])
        p_js = _row(context, builder, jty, args[3], [])  # js[0]
        c = builder.sitofp(n_, f64)
        cvec = _splat(builder, c, vec)

        def neighbour_row(n):
            return _row(context, builder, zty, args[0], [b_, builder.load(builder.gep(p_js, [n]))])

        vptr = lambda p, f: builder.bitcast(builder.gep(p, [f]), vec.as_pointer())
        m16 = builder.and_(m, ir.Constant(i64, ~15))

        def blocks(rows):
            """The blocks of sixteen elements, with the neighbours' rows ``rows`` (pointers, in order)."""
            with cgutils.for_range_slice(builder, zero, m16, ir.Constant(i64, 16)) as (f, _):
                offs = [builder.add(f, ir.Constant(i64, 4 * k)) for k in range(4)]
                acc = [builder.fmul(cvec, builder.load(vptr(p_i, o), align=8)) for o in offs]
                for p_j in rows:
                    acc = [builder.fsub(a, builder.load(vptr(p_j, o), align=8)) for a, o in zip(acc, offs)]
                for a, o in zip(acc, offs):
                    builder.store(a, vptr(p_l, o), align=8)

        def looped():
            """Any count: the neighbours in a loop inside each block."""
            with cgutils.for_range_slice(builder, zero, m16, ir.Constant(i64, 16)) as (f, _):
                offs = [builder.add(f, ir.Constant(i64, 4 * k)) for k in range(4)]
                acc = [cgutils.alloca_once_value(builder, builder.fmul(cvec, builder.load(vptr(p_i, o), align=8)))
                       for o in offs]
                with cgutils.for_range(builder, n_) as loop:
                    p_j = neighbour_row(loop.index)
                    for a, o in zip(acc, offs):
                        builder.store(builder.fsub(builder.load(a), builder.load(vptr(p_j, o), align=8)), a)
                for a, o in zip(acc, offs):
                    builder.store(builder.load(a), vptr(p_l, o), align=8)

        done = builder.append_basic_block("laplacian_done")
        other = builder.append_basic_block("laplacian_any_count")
        switch = builder.switch(n_, other)
        for n in range(UNROLLED_NEIGHBOURS + 1):
            case = builder.append_basic_block(f"laplacian_{n}_neighbours")
            switch.add_case(ir.Constant(i64, n), case)
            builder.position_at_end(case)
            blocks([neighbour_row(ir.Constant(i64, k)) for k in range(n)])
            builder.branch(done)
        builder.position_at_end(other)
        looped()
        builder.branch(done)
        builder.position_at_end(done)
        with cgutils.for_range_slice(builder, m16, m, ir.Constant(i64, 1)) as (f, _):
            acc = cgutils.alloca_once_value(builder, builder.fmul(c, builder.load(builder.gep(p_i, [f]))))
            with cgutils.for_range(builder, n_) as loop:
                x = builder.load(builder.gep(neighbour_row(loop.index), [f]))
                builder.store(builder.fsub(builder.load(acc), x), acc)
            builder.store(builder.load(acc), builder.gep(p_l, [f]))
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _dense_updates(typingctx, Z, Zo, b, i, V, MU, theta, sum_all, sum_tail, in_tail, L, l, Phi, s, sn, alpha, rho,
                   kappa, gamma, rt, c_theta, b_th, b_v, b_mu, b_w):
    """Algorithm 1 lines 7-9 for agent i of seed b with dense features, in one pass over the q features (the
    arithmetic of each element exactly as `numba_kernels._agent_step` writes it, four elements at a time):
    running sums of w; v and mu from L[l] = (L w, L (v + mu)), projected, their sum to Zo[b, i, q:]; w to
    Zo[b, i, :q]; theta. Zo may be Z itself: each element of w is read before it is written."""
    if not _all_c_contiguous(Z, Zo, V, MU, theta, sum_all, sum_tail, L, Phi):
        return None
    sig = types.void(Z, Zo, b, i, V, MU, theta, sum_all, sum_tail, in_tail, L, l, Phi, s, sn, alpha, rho, kappa,
                     gamma, rt, c_theta, b_th, b_v, b_mu, b_w)

    def codegen(context, builder, signature, args):
        i64, f64 = ir.IntType(64), ir.DoubleType()
        vec = ir.VectorType(f64, 4)
        zero = ir.Constant(i64, 0)
        ta = signature.args
        as_int = lambda k: context.cast(builder, args[k], ta[k], types.int64)
        as_f64 = lambda k: context.cast(builder, args[k], ta[k], types.float64)
        b_, i_, l_, s_, sn_ = (as_int(k) for k in (2, 3, 11, 13, 14))
        tail = context.cast(builder, args[9], ta[9], types.boolean)
        alpha_, rho_, kappa_, gamma_, rt_, ct_, bth, bv, bmu, bw = (as_f64(k) for k in range(15, 25))

        row = lambda k, index: _row(context, builder, ta[k], args[k], index)
        z, zo = row(0, [b_, i_]), row(1, [b_, i_])
        v, mu, th, sa, st = (row(k, [b_, i_]) for k in (4, 5, 6, 7, 8))
        lrow, ps, psn = row(10, [l_]), row(12, [s_]), row(12, [sn_])
        q = builder.extract_value(context.make_array(ta[6])(context, builder, args[6]).shape, 2)

        def elements(f, ty):
            """The updates of elements f, ..., f + width - 1, as values of type ty (double or <4 x double>)."""
            width = ty.count if isinstance(ty, ir.VectorType) else 1

            splat = (lambda x: _splat(builder, x, ty)) if width > 1 else (lambda x: x)

            def at(p, offset=None):
                g = builder.gep(p, [f if offset is None else builder.add(f, offset)])
                return builder.bitcast(g, ty.as_pointer()) if width > 1 else g

            ld = lambda p, offset=None: builder.load(at(p, offset), align=8)
            st_ = lambda x, p, offset=None: builder.store(x, at(p, offset), align=8)
            add, sub, mul = builder.fadd, builder.fsub, builder.fmul
            A, RHO, KAPPA, GAMMA, RT, CT = (splat(x) for x in (alpha_, rho_, kappa_, gamma_, rt_, ct_))

            def clip(x, bound):
                # `_clip`'s result for bound >= 0 or NaN, NaN x included; testing the inner result rather than x
                # lets LLVM emit one min and one max instruction instead of a min, a compare and a blend
                hi_, lo_ = splat(bound), splat(builder.fneg(bound))
                inner = builder.select(builder.fcmp_ordered(">", x, hi_), hi_, x)
                return builder.select(builder.fcmp_ordered("<", inner, lo_), lo_, inner)

            w = ld(z)
            st_(add(ld(sa), w), sa)
            with builder.if_then(tail):
                st_(add(ld(st), w), st)
            # Line 7 (v) and line 8 (mu), projected (line 9); neighbours will read their sum
            vf, muf, lw, lvm = ld(v), ld(mu), ld(lrow), ld(lrow, q)
            v_new = clip(sub(vf, mul(A, sub(vf, lw))), bv)
            mu_new = clip(sub(muf, mul(A, add(builder.fneg(lw), mul(RHO, muf)))), bmu)
            st_(v_new, v)
            st_(mu_new, mu)
            st_(add(v_new, mu_new), zo, q)
            # Line 8 (w): ratio (phi - gamma phi') phi^T theta - L v - L mu - kappa L w - rho w, projected (line 9)
            phs = ld(ps)
            g_w = sub(sub(sub(mul(RT, sub(phs, mul(GAMMA, ld(psn)))), lvm), mul(KAPPA, lw)), mul(RHO, w))
            st_(clip(add(w, mul(A, g_w)), bw), zo)
            # Line 7 (theta)
            st_(clip(sub(ld(th), mul(A, mul(phs, CT))), bth), th)

        q4 = builder.and_(q, ir.Constant(i64, ~3))
        with cgutils.for_range_slice(builder, zero, q4, ir.Constant(i64, 4)) as (f, _):
            elements(f, vec)
        with cgutils.for_range_slice(builder, q4, q, ir.Constant(i64, 1)) as (f, _):
            elements(f, f64)
        return context.get_dummy_value()

    return sig, codegen
