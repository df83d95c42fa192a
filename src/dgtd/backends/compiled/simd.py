"""The DGTD agent step in explicit vector instructions, for the compiled kernels, and the blocked rows it reads.

Layout. Inside the compiled DGTD kernels an agent's variables are interleaved four features at a time, so
that one pointer with constant offsets reaches all of them (with one array per variable, the loop over the
features needs a register for every array and spills): its state row S[b, i] holds, for each block of four
features f = 4k, ..., 4k + 3, theta, v, mu and the running sum of w (16 numbers, `STATE`), and its
neighbours' row Z[b, i] holds w and v + mu (8 numbers, `SHARED`). `state_index` and `shared_index` give
where feature f of a variable sits; a last, partial block is padded with zeros that nothing reads.

Order. Without fastmath, LLVM may not reorder a floating-point sum, so a plain loop `acc += x[f] * y[f]` stays
scalar. `_dots3` writes the vector code itself: four lanes, lane l summing the products f = l, l + 4, l + 8,
... in order, then (lane 0 + lane 1) + (lane 2 + lane 3), then the q mod 4 remaining products in order. The
order is fixed by the code, not by the compiler, so every process gets the same bits. `_agent_pass` keeps each
element's arithmetic as plain code writes it (`dgtd.backends.compiled.kernels.dgtd._sparse_td_feature` is the same arithmetic, one
feature at a time) and sums its dot products in `_dots3`'s order.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

_LANE = ir.IntType(32)
LANES = 4  # features per block
THETA, V, MU, SUM_W = range(4)  # the variables of a state row, in this order within each block
STATE = 4 * LANES  # numbers per block of a state row
W, VMU = range(2)  # w and v + mu, in this order within each block of a shared row
SHARED = 2 * LANES  # numbers per block of a shared row
UNROLLED_NEIGHBOURS = 8  # up to this many neighbours, `_agent_pass` has a loop of its own for each count
UNROLLED_WITHOUT_TD = 4  # the same for its variant without TD terms (sparse features: tabular problems, few agents)


def blocks(q: int) -> int:
    """Blocks of LANES features that hold q features."""
    return -(-q // LANES)


# Integer arguments only: LLVM inlines these itself, and numba's own inlining (a copy of the callee's IR at every
# call site) would cost compile time at their many call sites.
@njit(cache=True)
def state_index(f, var):
    """Where feature f of variable var (THETA, V, MU, SUM_W) sits in a state row (unsigned: numba then emits no
    wrap-around test for a negative index)."""
    u = np.uint64(f)
    return (u >> np.uint64(2)) * np.uint64(STATE) + np.uint64(var * LANES) + (u & np.uint64(LANES - 1))


@njit(cache=True)
def shared_index(f, half):
    """Where feature f of w (half W) or v + mu (half VMU) sits in a shared row (unsigned, as `state_index`)."""
    u = np.uint64(f)
    return (u >> np.uint64(2)) * np.uint64(SHARED) + np.uint64(half * LANES) + (u & np.uint64(LANES - 1))


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


class _Rows:
    """Element addresses in the blocked rows, for a vector block at feature f (a multiple of LANES) or one
    feature f."""

    def __init__(self, builder, f, ty):
        self.builder, self.ty = builder, ty
        self.width = ty.count if isinstance(ty, ir.VectorType) else 1
        i64 = ir.IntType(64)
        self.f = f
        base = builder.and_(f, ir.Constant(i64, ~(LANES - 1)))
        lane = builder.and_(f, ir.Constant(i64, LANES - 1))
        self.state0 = builder.add(builder.mul(base, ir.Constant(i64, STATE // LANES)), lane)
        self.shared0 = builder.add(builder.mul(base, ir.Constant(i64, SHARED // LANES)), lane)

    def _at(self, p, index):
        g = self.builder.gep(p, [index])
        return self.builder.bitcast(g, self.ty.as_pointer()) if self.width > 1 else g

    def state(self, p, var):
        return self._at(p, self.builder.add(self.state0, ir.Constant(ir.IntType(64), var * LANES)))

    def shared(self, p, half):
        return self._at(p, self.builder.add(self.shared0, ir.Constant(ir.IntType(64), half * LANES)))

    def phi(self, p):
        return self._at(p, self.f)


@intrinsic
def _dots3(typingctx, Phi, s, sn, S, Z, b, i, q):
    """(phi(s)^T theta, phi(s)^T w, phi(sn)^T w) of agent i of seed b, theta from its state row S[b, i] and w from
    its shared row Z[b, i]: the TD terms of Algorithm 1 line 7, for C-contiguous Phi (n_states, q), S and Z."""
    if not _all_c_contiguous(Phi, S, Z):
        return None
    sig = types.UniTuple(types.float64, 3)(Phi, s, sn, S, Z, b, i, q)

    def codegen(context, builder, signature, args):
        i64, f64 = ir.IntType(64), ir.DoubleType()
        vec = ir.VectorType(f64, LANES)
        zero = ir.Constant(i64, 0)
        s_, sn_, b_, i_, q_ = (context.cast(builder, args[k], signature.args[k], types.int64) for k in (1, 2, 5, 6, 7))
        row = lambda k, index: _row(context, builder, signature.args[k], args[k], index)
        p_s, p_sn, p_st, p_z = row(0, [s_]), row(0, [sn_]), row(3, [b_, i_]), row(4, [b_, i_])

        def products(f, ty):
            at = _Rows(builder, f, ty)
            ld = lambda p: builder.load(p, align=8)
            phi_s, w = ld(at.phi(p_s)), ld(at.shared(p_z, W))
            return (builder.fmul(phi_s, ld(at.state(p_st, THETA))), builder.fmul(phi_s, w),
                    builder.fmul(ld(at.phi(p_sn)), w))

        lanes = [cgutils.alloca_once_value(builder, ir.Constant(vec, [0.0] * LANES)) for _ in range(3)]
        q4 = builder.and_(q_, ir.Constant(i64, ~(LANES - 1)))
        with cgutils.for_range_slice(builder, zero, q4, ir.Constant(i64, LANES)) as (f, _):
            for acc, x in zip(lanes, products(f, vec)):
                builder.store(builder.fadd(builder.load(acc), x), acc)
        sums = _lane_totals(builder, lanes)
        with cgutils.for_range_slice(builder, q4, q_, ir.Constant(i64, 1)) as (f, _):
            for acc, x in zip(sums, products(f, f64)):
                builder.store(builder.fadd(builder.load(acc), x), acc)
        return context.make_tuple(builder, signature.return_type, [builder.load(acc) for acc in sums])

    return sig, codegen


def _lane_totals(builder, lanes):
    """(lane 0 + lane 1) + (lane 2 + lane 3) of each vector accumulator, as scalar accumulators (allocas)."""
    out = []
    for acc in lanes:
        x = builder.load(acc)
        e = [builder.extract_element(x, ir.Constant(_LANE, k)) for k in range(LANES)]
        out.append(cgutils.alloca_once_value(builder, builder.fadd(builder.fadd(e[0], e[1]), builder.fadd(e[2], e[3]))))
    return out


@intrinsic
def _agent_pass(typingctx, Zi, Zo, S, b, i, js, count, Phi, s, sn, s_next, sn_next, q, alpha, rho, kappa, gamma, rt,
                c_theta, b_th, b_v, b_mu, b_w):
    """Algorithm 1 lines 7-9 for agent i of seed b with dense features, in one pass over its q features, its
    neighbour sums included; returns the TD terms of its next step.

    Zi[b, j] are the shared rows (w_j, v_j + mu_j) at step k; Zo[b, i] receives agent i's at step k + 1 (a
    different array: the neighbours read step k); S[b, i] is its state row, updated in place. For each feature
    f, in this order: (L(k) w)_i and (L(k) (v + mu))_i as count Zi[b, i] - Zi[b, js[0]] - ... -
    Zi[b, js[count - 1]] (in registers, never stored); the running sum of w; v and mu, projected, and their sum;
    w; theta (the arithmetic of `dgtd.backends.compiled.kernels.dgtd._sparse_td_feature`). The new theta and w are still in registers when
    the next step's dot products need them: the pass returns (phi(s_next)^T theta, phi(s_next)^T w,
    phi(sn_next)^T w) at step k + 1, summed in `_dots3`'s order, so that the next step need not read them again;
    with s_next and sn_next None it computes none of them and returns zeros (each variant is compiled apart).
    Up to UNROLLED_NEIGHBOURS neighbours, the code branches on the count once and then runs straight-line code
    for it (a loop over a count that changes from agent to agent would be mispredicted at every block). With
    Phi None, the pass leaves out the TD terms (phi = phi' = 0) and theta, and unrolls UNROLLED_WITHOUT_TD
    counts: `dgtd.backends.compiled.kernels.dgtd._sparse_step` adds the TD terms for the few features where phi or phi' is not zero."""
    td = not isinstance(Phi, types.NoneType)
    if not _all_c_contiguous(Zi, Zo, S, js, *([Phi] if td else [])):
        return None
    with_next = not isinstance(s_next, types.NoneType)
    sig = types.UniTuple(types.float64, 3)(Zi, Zo, S, b, i, js, count, Phi, s, sn, s_next, sn_next, q, alpha, rho,
                                           kappa, gamma, rt, c_theta, b_th, b_v, b_mu, b_w)

    def codegen(context, builder, signature, args):
        i64, f64 = ir.IntType(64), ir.DoubleType()
        vec = ir.VectorType(f64, LANES)
        zero = ir.Constant(i64, 0)
        ta = signature.args
        as_int = lambda k: context.cast(builder, args[k], ta[k], types.int64)
        as_f64 = lambda k: context.cast(builder, args[k], ta[k], types.float64)
        b_, i_, n_, s_, sn_, q_ = (as_int(k) for k in (3, 4, 6, 8, 9, 12))
        sx_, snx_ = (as_int(k) for k in (10, 11)) if with_next else (None, None)
        alpha_, rho_, kappa_, gamma_, rt_, ct_, bth, bv, bmu, bw = (as_f64(k) for k in range(13, 23))

        row = lambda k, index: _row(context, builder, ta[k], args[k], index)
        zi, zo, st = row(0, [b_, i_]), row(1, [b_, i_]), row(2, [b_, i_])
        ps, psn = (row(7, [x]) for x in (s_, sn_)) if td else (None, None)
        pxs, pxsn = (row(7, [x]) for x in (sx_, snx_)) if td and with_next else (None, None)
        p_js = row(5, [])
        c = builder.sitofp(n_, f64)

        def neighbour_row(n):
            return _row(context, builder, ta[0], args[0], [b_, builder.load(builder.gep(p_js, [n]))])

        lanes = [cgutils.alloca_once_value(builder, ir.Constant(vec, [0.0] * LANES)) for _ in range(3)]

        def elements(f, ty, rows, dots):
            """Features f, ..., f + width - 1 as values of type ty (double or <4 x double>); ``rows``: the
            neighbours' shared rows (straight-line code) or None (a loop over js); ``dots``: accumulators of the
            next step's dot products (allocas of ty), or None."""
            at = _Rows(builder, f, ty)
            splat = (lambda x: _splat(builder, x, ty)) if at.width > 1 else (lambda x: x)
            ld = lambda p: builder.load(p, align=8)
            st_ = lambda x, p: builder.store(x, p, align=8)
            add, sub, mul = builder.fadd, builder.fsub, builder.fmul
            A, RHO, KAPPA, GAMMA, RT, CT, C = (splat(x) for x in (alpha_, rho_, kappa_, gamma_, rt_, ct_, c))

            def clip(x, bound):
                # `_clip`'s result for bound >= 0 or NaN, NaN x included; testing the inner result rather than x
                # lets LLVM emit one min and one max instruction instead of a min, a compare and a blend
                hi_, lo_ = splat(bound), splat(builder.fneg(bound))
                inner = builder.select(builder.fcmp_ordered(">", x, hi_), hi_, x)
                return builder.select(builder.fcmp_ordered("<", inner, lo_), lo_, inner)

            # Neighbour sums (L(k) w)_i and (L(k) (v + mu))_i, Algorithm 1 lines 7-8
            w, z = ld(at.shared(zi, W)), ld(at.shared(zi, VMU))
            lw, lvm = mul(C, w), mul(C, z)
            if rows is not None:
                for p_j in rows:
                    lw, lvm = sub(lw, ld(at.shared(p_j, W))), sub(lvm, ld(at.shared(p_j, VMU)))
            else:
                acc_w, acc_z = cgutils.alloca_once_value(builder, lw), cgutils.alloca_once_value(builder, lvm)
                with cgutils.for_range(builder, n_) as loop:
                    p_j = neighbour_row(loop.index)
                    builder.store(sub(builder.load(acc_w), ld(at.shared(p_j, W))), acc_w)
                    builder.store(sub(builder.load(acc_z), ld(at.shared(p_j, VMU))), acc_z)
                lw, lvm = builder.load(acc_w), builder.load(acc_z)
            vf, muf, sw = (ld(at.state(st, x)) for x in (V, MU, SUM_W))
            st_(add(sw, w), at.state(st, SUM_W))
            # Line 7 (v) and line 8 (mu), projected (line 9); neighbours will read their sum
            v_new = clip(sub(vf, mul(A, sub(vf, lw))), bv)
            mu_new = clip(sub(muf, mul(A, add(builder.fneg(lw), mul(RHO, muf)))), bmu)
            st_(v_new, at.state(st, V))
            st_(mu_new, at.state(st, MU))
            st_(add(v_new, mu_new), at.shared(zo, VMU))
            # Line 8 (w): ratio (phi - gamma phi') phi^T theta - L v - L mu - kappa L w - rho w, projected (line 9)
            if not td:
                g_w = sub(sub(builder.fneg(lvm), mul(KAPPA, lw)), mul(RHO, w))
                st_(clip(add(w, mul(A, g_w)), bw), at.shared(zo, W))
                return
            phs, phsn = ld(at.phi(ps)), ld(at.phi(psn))
            g_w = sub(sub(sub(mul(RT, sub(phs, mul(GAMMA, phsn))), lvm), mul(KAPPA, lw)), mul(RHO, w))
            w_new = clip(add(w, mul(A, g_w)), bw)
            st_(w_new, at.shared(zo, W))
            # Line 7 (theta)
            th_new = clip(sub(ld(at.state(st, THETA)), mul(A, mul(phs, CT))), bth)
            st_(th_new, at.state(st, THETA))
            if dots is not None:  # the next step's TD terms, from the values just written
                px = ld(at.phi(pxs))
                for acc, (x, y) in zip(dots, ((px, th_new), (px, w_new), (ld(at.phi(pxsn)), w_new))):
                    builder.store(add(builder.load(acc), mul(x, y)), acc)

        q4 = builder.and_(q_, ir.Constant(i64, ~(LANES - 1)))

        dots = lanes if td and with_next else None

        def vector_loops(rows):
            with cgutils.for_range_slice(builder, zero, q4, ir.Constant(i64, LANES)) as (f, _):
                elements(f, vec, rows, dots)

        done = builder.append_basic_block("pass_done")
        other = builder.append_basic_block("pass_any_count")
        switch = builder.switch(n_, other)
        for n in range((UNROLLED_NEIGHBOURS if td else UNROLLED_WITHOUT_TD) + 1):
            case = builder.append_basic_block(f"pass_{n}_neighbours")
            switch.add_case(ir.Constant(i64, n), case)
            builder.position_at_end(case)
            vector_loops([neighbour_row(ir.Constant(i64, k)) for k in range(n)])
            builder.branch(done)
        builder.position_at_end(other)
        vector_loops(None)
        builder.branch(done)
        builder.position_at_end(done)
        # lane totals in `_dots3`'s order, then the q mod 4 remaining features in order
        sums = _lane_totals(builder, lanes)
        with cgutils.for_range_slice(builder, q4, q_, ir.Constant(i64, 1)) as (f, _):
            elements(f, f64, None, sums if dots is not None else None)
        return context.make_tuple(builder, signature.return_type, [builder.load(acc) for acc in sums])

    return sig, codegen


def to_blocks(rows: list[np.ndarray], q: int) -> np.ndarray:
    """Interleave the (B, N, q) arrays ``rows`` (one per variable, in the order of a block) into blocked rows."""
    B, N = rows[0].shape[:2]
    nb = blocks(q)
    out = np.zeros((B, N, nb, len(rows), LANES))
    for var, x in enumerate(rows):
        padded = np.zeros((B, N, nb * LANES))
        padded[:, :, :q] = x
        out[:, :, :, var, :] = padded.reshape(B, N, nb, LANES)
    return out.reshape(B, N, nb * len(rows) * LANES)


def from_blocks(blocked: np.ndarray, var: int, n_vars: int, q: int) -> np.ndarray:
    """Variable ``var`` of blocked rows with ``n_vars`` variables per block, as a (B, N, q) array."""
    B, N = blocked.shape[:2]
    nb = blocks(q)
    out = blocked.reshape(B, N, nb, n_vars, LANES)[:, :, :, var, :].reshape(B, N, nb * LANES)
    return np.ascontiguousarray(out[:, :, :q])

