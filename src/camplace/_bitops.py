"""Bit instructions for numba kernels on uint64 words: one home for the visibility and solver bitsets."""

from __future__ import annotations

from numba import types
from numba.extending import intrinsic

__all__ = ["popcount", "ctz"]


@intrinsic
def popcount(typingctx, x):  # pragma: no cover - compiled
    """Number of set bits of a uint64 (the ``popcnt`` instruction)."""
    sig = types.uint64(types.uint64)

    def codegen(context, builder, signature, args):
        return builder.ctpop(args[0])

    return sig, codegen


@intrinsic
def ctz(typingctx, x):  # pragma: no cover - compiled
    """Index of the lowest set bit of a non-zero uint64 (the ``tzcnt`` instruction)."""
    sig = types.uint64(types.uint64)

    def codegen(context, builder, signature, args):
        return builder.cttz(args[0], context.get_constant(types.boolean, True))

    return sig, codegen
