"""Eight-double vectors for the numeric kernels, written out where LLVM's vectoriser would not pick them.

numba compiles for the host CPU with LLVM's tuning for it, which on AVX-512 machines prefers 256-bit vectors: a
loop it vectorises takes four doubles at a time, and one whose working set is a tile of a matrix (a register tile
of ``C += A Bᵀ`` kept in registers across all of its terms) is not vectorised as a tile at all. ``Vec8`` is an LLVM
``<8 x double>`` held in a register: :func:`load8` and :func:`store8` move eight neighbouring doubles of a row of a
C-contiguous 2-D float64 array, :func:`splat8` broadcasts a scalar, :func:`fma8` is ``a * b + c`` with one rounding
(LLVM's ``fma`` intrinsic: in each lane the bits of a scalar ``a * b + c`` contracted into one multiply-add,
whatever the vector width of the machine; without AVX-512 LLVM splits each vector into two 256-bit halves).
Nothing is checked: the caller keeps ``j + 8`` within the row (riekf pads its rows to whole vectors,
``riekf.PAD``).

:func:`prefetch` asks the CPU for an array's cache line ahead of its use (LLVM's ``llvm.prefetch``): the readers'
compiled walks read messages scattered over a chunk or a db3 window that is no longer in cache.
"""

from __future__ import annotations

from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic, models, register_model

__all__ = ["add8", "fma", "fma8", "load8", "mul8", "prefetch", "splat8", "store8", "sub8", "vec8"]

_LLVM_VEC8 = ir.VectorType(ir.DoubleType(), 8)


class Vec8(types.Type):
    """numba's type of eight doubles in one vector register."""

    def __init__(self) -> None:
        super().__init__(name="vec8")


vec8 = Vec8()


@register_model(Vec8)
class _Vec8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type) -> None:
        super().__init__(dmm, fe_type, _LLVM_VEC8)


def _is_rows(ary) -> bool:
    return isinstance(ary, types.Array) and ary.ndim == 2 and ary.dtype == types.float64 and ary.layout == "C"


def _address(context, builder, aryty, ary, i, j):
    """Pointer to ``ary[i, j]`` as a pointer to eight doubles."""
    a = context.make_array(aryty)(context, builder, ary)
    shape = cgutils.unpack_tuple(builder, a.shape, 2)
    strides = cgutils.unpack_tuple(builder, a.strides, 2)
    p = cgutils.get_item_pointer2(context, builder, a.data, shape, strides, aryty.layout, [i, j])
    return builder.bitcast(p, _LLVM_VEC8.as_pointer())


@intrinsic
def load8(typingctx, ary, i, j):
    """``ary[i, j : j + 8]`` as a vector."""
    if not _is_rows(ary):
        return None

    def codegen(context, builder, sig, args):
        i_, j_ = (context.cast(builder, v, t, types.intp) for v, t in zip(args[1:], sig.args[1:]))
        return builder.load(_address(context, builder, sig.args[0], args[0], i_, j_), align=8)

    return vec8(ary, i, j), codegen


@intrinsic
def store8(typingctx, ary, i, j, v):
    """``ary[i, j : j + 8] = v``."""
    if not _is_rows(ary) or v != vec8:
        return None

    def codegen(context, builder, sig, args):
        i_, j_ = (context.cast(builder, v, t, types.intp) for v, t in zip(args[1:3], sig.args[1:3]))
        builder.store(args[3], _address(context, builder, sig.args[0], args[0], i_, j_), align=8)
        return context.get_dummy_value()

    return types.none(ary, i, j, v), codegen


@intrinsic
def splat8(typingctx, x):
    """``x`` in all eight lanes."""
    if not isinstance(x, types.Float):
        return None

    def codegen(context, builder, sig, args):
        x_ = context.cast(builder, args[0], sig.args[0], types.float64)
        v = builder.insert_element(ir.Constant(_LLVM_VEC8, ir.Undefined), x_, ir.Constant(ir.IntType(32), 0))
        zeros = ir.Constant(ir.VectorType(ir.IntType(32), 8), [0] * 8)
        return builder.shuffle_vector(v, ir.Constant(_LLVM_VEC8, ir.Undefined), zeros)

    return vec8(x), codegen


@intrinsic
def fma(typingctx, a, b, c):
    """``a * b + c`` of three doubles rounded once (LLVM's ``llvm.fma``), for kernels that round their 3×3 products
    as NumPy's stacked ``matmul`` does through OpenBLAS on an FMA CPU: ``fma(a₂, b₂, fma(a₁, b₁, a₀ b₀))`` per
    entry (every 3×3 product form the report uses, measured against NumPy 2.4's OpenBLAS 0.3.31, Haswell kernels);
    a ``(N, 3) @ (3, 3)`` gemm sums from 0.0 instead (``output_frame.moved``)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@intrinsic
def fma8(typingctx, a, b, c):
    """``a * b + c`` lane by lane, rounded once."""
    if not (a == b == c == vec8):
        return None

    def codegen(context, builder, sig, args):
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(_LLVM_VEC8, [_LLVM_VEC8] * 3), "llvm.fma.v8f64"
        )
        return builder.call(fn, list(args))

    return vec8(a, b, c), codegen


def _lanewise(op: str):
    """An intrinsic applying LLVM's ``op`` (``fadd``, ``fsub``, ``fmul``) lane by lane to two vectors."""

    @intrinsic
    def apply(typingctx, a, b):
        if not (a == b == vec8):
            return None

        def codegen(context, builder, sig, args):
            return getattr(builder, op)(*args)

        return vec8(a, b), codegen

    return apply


#: ``a + b``, ``a − b`` and ``a * b`` lane by lane (each rounded as the scalar operation).
add8, sub8, mul8 = _lanewise("fadd"), _lanewise("fsub"), _lanewise("fmul")


@intrinsic
def prefetch(typingctx, ary, i):
    """Ask the CPU to bring the cache line of ``ary[i]`` (a 1-D array) closer (LLVM's ``llvm.prefetch``: a read,
    kept in every cache level). A hint only: nothing is read into the program, an index outside the array is
    harmless (a prefetch never faults), so nothing is checked."""
    if not (isinstance(ary, types.Array) and ary.ndim == 1 and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        a = context.make_array(sig.args[0])(context, builder, args[0])
        i_ = context.cast(builder, args[1], sig.args[1], types.intp)
        p = builder.bitcast(builder.gep(a.data, [i_]), ir.IntType(8).as_pointer())
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [p.type, i32, i32, i32]), "llvm.prefetch.p0i8"
        )
        builder.call(fn, [p, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return types.none(ary, i), codegen
