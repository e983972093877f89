"""What the compiled kernels use to make LLVM vectorise them (docs/performance.md).

Two kinds of SIMD lanes run through pkmctl's kernels: the four limbs of one state
(:mod:`pkmctl.model.dynamics`, where a loop over the limbs computes each limb's terms
four at a time) and L independent runs of a campaign (:mod:`pkmctl.model.lanes`). Both
write their per-lane intermediate values into scratch on the stack
(:func:`stack_block`), which LLVM knows no argument points into, so that its loop
vectoriser needs no run-time overlap checks; and both say how wide a vector they want
(:func:`limb_vectors`, :func:`wide_vectors`), because LLVM's tuning for a CPU chooses a
width of its own that may not fit the number of lanes.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = [
    "disjoint_arrays",
    "flat_view",
    "limb_vectors",
    "stack_block",
    "unsigned",
    "wide_vectors",
]


@intrinsic
def stack_block(typingctx, size):
    """A 1-D float64 array of ``size`` (a literal int) elements on the stack, 64-byte
    aligned and uninitialised: scratch that LLVM knows no argument points into."""
    if not isinstance(size, types.IntegerLiteral):
        return None
    count = size.literal_value
    arr = types.Array(types.float64, 1, "C")

    def codegen(context, builder, sig, args):
        data = cgutils.alloca_once(builder, ir.DoubleType(), size=count)
        data.align = 64
        intp = context.get_value_type(types.intp)
        ary = context.make_array(arr)(context, builder)
        context.populate_array(
            ary,
            data=data,
            shape=[ir.Constant(intp, count)],
            strides=[ir.Constant(intp, 8)],
            itemsize=ir.Constant(intp, 8),
            meminfo=None,
        )
        return ary._getvalue()

    return arr(size), codegen


def _vector_width(bits: int, doc: str):
    """An intrinsic that sets the calling function's ``"prefer-vector-width"`` to ``bits``."""

    @intrinsic
    def prefer(typingctx):
        def codegen(context, builder, sig, args):
            # llvmlite's FunctionAttributes accepts only attributes without a value
            set.add(builder.function.attributes, f'"prefer-vector-width"="{bits}"')
            return context.get_dummy_value()

        return types.none(), codegen

    prefer.__doc__ = doc
    return prefer


wide_vectors = _vector_width(
    512,
    """Let LLVM vectorise the calling function with 512-bit vectors on a CPU that has
    them: LLVM's tuning for some AVX-512 CPUs (the Xeon of docs/performance.md, which it
    takes for a Rocket Lake) prefers 256-bit ones, so a block of 8 lanes would be two
    vectors. Sets the function attribute ``"prefer-vector-width"="512"``, which overrides
    that tuning for this function only (no effect where the CPU has no 512-bit vectors).""",
)

limb_vectors = _vector_width(
    256,
    """Let LLVM vectorise the calling function's loops over the four limbs with vectors of
    four doubles (256 bits): with its tuning for a CPU that prefers 512-bit vectors it
    would choose 8 lanes, more than a loop of 4 has, and leave the loop scalar. Sets
    ``"prefer-vector-width"="256"`` for this function only (a CPU without AVX uses the
    widest it has).""",
)


@intrinsic
def disjoint_arrays(typingctx):
    """Promise LLVM that the calling function's array arguments do not overlap (each
    pointer argument ``noalias``), so that it vectorises the function's lane loops over
    several arrays without run-time overlap checks. Call it only where that holds: the
    lane controller steps and the lane metrics, whose arrays are separate allocations of
    the lane loop (not the lane loop itself: its ``EachLane`` tuples repeat a bundle)."""

    def codegen(context, builder, sig, args):
        for a in context.call_conv.get_arguments(builder.function):
            if isinstance(a.type, ir.PointerType):
                a.add_attribute("noalias")
        return context.get_dummy_value()

    return types.none(), codegen


@intrinsic
def flat_view(typingctx, a):
    """The elements of a C-contiguous array as a 1-D view of the same memory, without the
    call into Numba's reshape helper that ``a.reshape(a.size)`` makes each time (it showed
    in the lane loop's profile). The lane code loops over rows x lanes of its (rows, L)
    arrays as one flat loop on these views: a loop per row of L = 8 lanes ran LLVM's
    remainder code (docs/performance.md). No reference is taken: use it where ``a``
    outlives the view. A layout other than C is a typing error."""
    if not (isinstance(a, types.Array) and a.layout == "C"):
        return None
    flat = types.Array(a.dtype, 1, "C")

    def codegen(context, builder, sig, args):
        src = context.make_array(sig.args[0])(context, builder, args[0])
        intp = context.get_value_type(types.intp)
        size = ir.Constant(intp, 1)
        for extent in cgutils.unpack_tuple(builder, src.shape):
            size = builder.mul(size, extent)
        item = context.get_abi_sizeof(context.get_data_type(a.dtype))
        out = context.make_array(flat)(context, builder)
        context.populate_array(
            out,
            data=src.data,
            shape=[size],
            strides=[ir.Constant(intp, item)],
            itemsize=ir.Constant(intp, item),
            meminfo=None,
        )
        return out._getvalue()

    return flat(a), codegen


@intrinsic
def unsigned(typingctx, i):
    """An index as unsigned, ``np.uint64(i)``: Numba then emits no test for a negative
    (wraparound) index, which it does for every signed one; in a hot loop that is a
    compare and a conditional move per access, and it can keep LLVM from seeing that
    consecutive accesses are consecutive (docs/performance.md). For indices that are
    never negative: table offsets, flat lane indices. An intrinsic, so that Numba does
    not copy and re-type a function's IR at each of its many call sites."""
    if not isinstance(i, types.Integer):
        return None

    def codegen(context, builder, sig, args):
        return context.cast(builder, args[0], sig.args[0], types.uint64)

    return types.uint64(i), codegen
