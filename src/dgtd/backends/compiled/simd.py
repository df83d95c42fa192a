"""Generic vector primitives for the compiled kernels, written in explicit vector instructions: no algorithm's maths.

- `dot`: a dot product in a fixed lane order, so that every process (and every compiled specialisation) gets
  the same bits; without fastmath LLVM may not reorder a floating-point sum, so a plain loop `acc += x[f] * y[f]`
  stays scalar;
- `neighbour_sums`: the neighbour sums (L(k) X)_i of a row, the Laplacian's product, with the neighbours' rows
  streaming past registers (a plain loop over neighbours would store the row once per neighbour);
- `weighted_sums`: the same with a weight per neighbour, sum_n c_n (X_i - X_jn) (the Metropolis weights').

Both take rows of C-contiguous arrays by index (X[*at, :]) rather than as views: numba counts references to every
view with an atomic update, and two threads updating the same count stall each other. They are tested against
NumPy in tests/backends/test_simd.py. The vector width is the machine's (`LANES`): 8 doubles with AVX-512, else 4.
"""

from __future__ import annotations

import llvmlite.binding as llvm
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_LANE = ir.IntType(32)


def _host_lanes() -> int:
    """Doubles per vector register of the machine numba compiles for."""
    try:
        return 8 if llvm.get_host_cpu_features().get("avx512f") else 4
    except RuntimeError:  # features unknown: the width every x86-64 vector unit of the last decade has
        return 4


LANES = _host_lanes()
UNROLLED_NEIGHBOURS = 8  # up to this many neighbours, `neighbour_sums` runs straight-line code for each count


def _c_contiguous(*arrays) -> bool:
    return all(isinstance(a, types.Array) and a.layout == "C" for a in arrays)


def _index(context, builder, ty, value) -> list:
    """The int64 values of an index: an integer or a tuple of integers."""
    if isinstance(ty, (types.UniTuple, types.Tuple)):
        return [
            context.cast(builder, v, t, types.int64) for v, t in zip(cgutils.unpack_tuple(builder, value), ty.types)
        ]
    return [context.cast(builder, value, ty, types.int64)]


def _index_type_ok(ty) -> bool:
    return isinstance(ty, types.Integer) or (
        isinstance(ty, (types.UniTuple, types.Tuple)) and all(isinstance(t, types.Integer) for t in ty.types)
    )


def _row(context, builder, aryty, ary, index):
    """Pointer to element [*index, 0] of a numba array value: the start of a row."""
    arr = context.make_array(aryty)(context, builder, ary)
    zero = ir.Constant(ir.IntType(64), 0)
    return cgutils.get_item_pointer(context, builder, aryty, arr, [*index, zero], wraparound=False)


def _vector_at(builder, p, k, ty):
    """Pointer to the vector of type ty (or the scalar) starting at element k of the row at p."""
    g = builder.gep(p, [k])
    return builder.bitcast(g, ty.as_pointer()) if isinstance(ty, ir.VectorType) else g


def _pairwise(builder, x, width):
    """((x0 + x1) + (x2 + x3)) + ((x4 + x5) + (x6 + x7)): the lanes of vector x added in a fixed tree."""
    terms = [builder.extract_element(x, ir.Constant(_LANE, k)) for k in range(width)]
    while len(terms) > 1:
        terms = [builder.fadd(terms[k], terms[k + 1]) for k in range(0, len(terms), 2)]
    return terms[0]


def _splat(builder, x, ty):
    """Scalar x in every lane of vector type ty (x itself for a scalar type)."""
    if not isinstance(ty, ir.VectorType):
        return x
    v = ir.Constant(ty, ir.Undefined)
    for lane in range(ty.count):
        v = builder.insert_element(v, x, ir.Constant(_LANE, lane))
    return v


def _row_length(context, builder, aryty, ary):
    """The length of a numba array's last axis."""
    return cgutils.unpack_tuple(builder, context.make_array(aryty)(context, builder, ary).shape)[aryty.ndim - 1]


def _over_row(builder, K, element):
    """element(k, ty) for the vector chunks of LANES elements of a row of K, then for its last K mod LANES one by
    one (ty the vector type, then double)."""
    i64, f64 = ir.IntType(64), ir.DoubleType()
    kv = builder.and_(K, ir.Constant(i64, ~(LANES - 1)))
    with cgutils.for_range_slice(builder, ir.Constant(i64, 0), kv, ir.Constant(i64, LANES)) as (k, _):
        element(k, ir.VectorType(f64, LANES))
    with cgutils.for_range_slice(builder, kv, K, ir.Constant(i64, 1)) as (k, _):
        element(k, f64)


@intrinsic
def dot(typingctx, X, x_at, Y, y_at, n):
    """sum_f X[*x_at, f] Y[*y_at, f] over f < n, in this order: two vector accumulators of LANES lanes take the
    products in chunks of 2 LANES (the first chunk half into a0, the second into a1), a last whole chunk of LANES
    goes into a0, then a0 + a1, its lanes added pairwise (`_pairwise`), and the n mod LANES last products in order.
    Two accumulators halve the chain of dependent additions."""
    if not (_c_contiguous(X, Y) and _index_type_ok(x_at) and _index_type_ok(y_at)):
        return None
    sig = types.float64(X, x_at, Y, y_at, n)

    def codegen(context, builder, signature, args):
        i64, f64 = ir.IntType(64), ir.DoubleType()
        vec = ir.VectorType(f64, LANES)
        px = _row(context, builder, signature.args[0], args[0], _index(context, builder, signature.args[1], args[1]))
        py = _row(context, builder, signature.args[2], args[2], _index(context, builder, signature.args[3], args[3]))
        n_ = context.cast(builder, args[4], signature.args[4], types.int64)
        n2 = builder.and_(n_, ir.Constant(i64, ~(2 * LANES - 1)))
        nv = builder.and_(n_, ir.Constant(i64, ~(LANES - 1)))
        zero = ir.Constant(vec, [0.0] * LANES)
        a0, a1 = cgutils.alloca_once_value(builder, zero), cgutils.alloca_once_value(builder, zero)

        def product(f, ty):
            return builder.fmul(
                builder.load(_vector_at(builder, px, f, ty), align=8),
                builder.load(_vector_at(builder, py, f, ty), align=8),
            )

        with cgutils.for_range_slice(builder, ir.Constant(i64, 0), n2, ir.Constant(i64, 2 * LANES)) as (f, _):
            builder.store(builder.fadd(builder.load(a0), product(f, vec)), a0)
            builder.store(builder.fadd(builder.load(a1), product(builder.add(f, ir.Constant(i64, LANES)), vec)), a1)
        with cgutils.for_range_slice(builder, n2, nv, ir.Constant(i64, LANES)) as (f, _):  # at most once
            builder.store(builder.fadd(builder.load(a0), product(f, vec)), a0)
        lanes = builder.fadd(builder.load(a0), builder.load(a1))
        total = cgutils.alloca_once_value(builder, _pairwise(builder, lanes, LANES))
        with cgutils.for_range_slice(builder, nv, n_, ir.Constant(i64, 1)) as (f, _):
            builder.store(builder.fadd(builder.load(total), product(f, f64)), total)
        return builder.load(total)

    return sig, codegen


@intrinsic
def neighbour_sums(typingctx, Z, z_at, i, J, j_at, count, out, out_at):
    """out[*out_at, k] = count Z[*z_at, i, k] - Z[*z_at, J[j_at, 0], k] - ... - Z[*z_at, J[j_at, count - 1], k] for
    every element k of the row Z[*z_at, i] (length Z.shape[-1], at most out's): (L(k) X)_i of the rows of seed b
    (``z_at`` = (message, b)) when J[j_at] lists agent i's neighbours up at step k. J and out are scratch with a row
    per thread, allocated once per block rather than once per chunk and step. Every element takes the subtractions
    in this order, so the result does not depend on the vector width. Up to UNROLLED_NEIGHBOURS neighbours the code
    branches on the count once and runs straight-line code for it (a loop over a count that changes from agent to
    agent is mispredicted)."""
    if not (_c_contiguous(Z, J, out) and J.ndim == 2 and _index_type_ok(z_at) and _index_type_ok(out_at)):
        return None
    sig = types.void(Z, z_at, i, J, j_at, count, out, out_at)

    def codegen(context, builder, signature, args):
        i64, f64 = ir.IntType(64), ir.DoubleType()
        ta = signature.args
        zi = _index(context, builder, ta[1], args[1])
        i_, ja_, n_ = (context.cast(builder, args[k], ta[k], types.int64) for k in (2, 4, 5))
        K = _row_length(context, builder, ta[0], args[0])
        pz = _row(context, builder, ta[0], args[0], [*zi, i_])
        pout = _row(context, builder, ta[6], args[6], _index(context, builder, ta[7], args[7]))
        pj = _row(context, builder, ta[3], args[3], [ja_])
        c = builder.sitofp(n_, f64)

        def neighbour_row(n):
            return _row(context, builder, ta[0], args[0], [*zi, builder.load(builder.gep(pj, [n]))])

        def element(k, ty, rows):
            at = lambda p: _vector_at(builder, p, k, ty)  # noqa: E731
            acc = builder.fmul(_splat(builder, c, ty), builder.load(at(pz), align=8))
            if rows is not None:
                for p in rows:
                    acc = builder.fsub(acc, builder.load(at(p), align=8))
            else:
                slot = cgutils.alloca_once_value(builder, acc)
                with cgutils.for_range(builder, n_) as loop:
                    builder.store(
                        builder.fsub(builder.load(slot), builder.load(at(neighbour_row(loop.index)), align=8)), slot
                    )
                acc = builder.load(slot)
            builder.store(acc, at(pout), align=8)

        def loops(rows):
            _over_row(builder, K, lambda k, ty: element(k, ty, rows))

        done = builder.append_basic_block("sums_done")
        other = builder.append_basic_block("sums_any_count")
        switch = builder.switch(n_, other)
        for n in range(UNROLLED_NEIGHBOURS + 1):
            case = builder.append_basic_block(f"sums_{n}_neighbours")
            switch.add_case(ir.Constant(i64, n), case)
            builder.position_at_end(case)
            loops([neighbour_row(ir.Constant(i64, m)) for m in range(n)])
            builder.branch(done)
        builder.position_at_end(other)
        loops(None)
        builder.branch(done)
        builder.position_at_end(done)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def weighted_sums(typingctx, Z, z_at, i, J, C, j_at, count, out, out_at):
    """out[*out_at, k] = (Z[*z_at, i, k] - Z[*z_at, J[j_at, 0], k]) C[j_at, 0] + ... for the ``count`` neighbours
    listed in J[j_at], with their weights in C[j_at]: sum_j c_ij (x_i - x_j), added from 0 in the order of the list
    (as `dgtd.channels.Inbox.metropolis` adds its terms), in vector chunks of LANES elements with the accumulator in
    a register across the neighbours."""
    if not (
        _c_contiguous(Z, J, C, out) and J.ndim == 2 and C.ndim == 2 and _index_type_ok(z_at) and _index_type_ok(out_at)
    ):
        return None
    sig = types.void(Z, z_at, i, J, C, j_at, count, out, out_at)

    def codegen(context, builder, signature, args):
        f64 = ir.DoubleType()
        ta = signature.args
        zi = _index(context, builder, ta[1], args[1])
        i_, ja_, n_ = (context.cast(builder, args[k], ta[k], types.int64) for k in (2, 5, 6))
        K = _row_length(context, builder, ta[0], args[0])
        pz = _row(context, builder, ta[0], args[0], [*zi, i_])
        pout = _row(context, builder, ta[7], args[7], _index(context, builder, ta[8], args[8]))
        pj = _row(context, builder, ta[3], args[3], [ja_])
        pc = _row(context, builder, ta[4], args[4], [ja_])

        def element(k, ty):
            at = lambda p: _vector_at(builder, p, k, ty)  # noqa: E731
            zero = ir.Constant(ty, [0.0] * ty.count) if isinstance(ty, ir.VectorType) else ir.Constant(f64, 0.0)
            slot = cgutils.alloca_once_value(builder, zero)
            own = builder.load(at(pz), align=8)
            with cgutils.for_range(builder, n_) as loop:
                row = _row(context, builder, ta[0], args[0], [*zi, builder.load(builder.gep(pj, [loop.index]))])
                c = _splat(builder, builder.load(builder.gep(pc, [loop.index])), ty)
                term = builder.fmul(builder.fsub(own, builder.load(at(row), align=8)), c)
                builder.store(builder.fadd(builder.load(slot), term), slot)
            builder.store(builder.load(slot), at(pout), align=8)

        _over_row(builder, K, element)
        return context.get_dummy_value()

    return sig, codegen
