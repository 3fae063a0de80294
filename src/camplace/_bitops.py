"""Bit instructions for numba kernels on uint64 words: one home for the visibility and solver bitsets."""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic

__all__ = ["popcount", "ctz", "transpose64", "fill_lists"]


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


@numba.njit(inline="always", nogil=True, cache=True)
def transpose64(a):  # pragma: no cover - compiled
    """Transpose a 64 x 64 bit block in place: bit c of ``a[r]`` becomes bit r of ``a[c]``.

    Parameters
    ----------
    a : (64,) uint64
        Bit b of a word is index b (the least significant bit first, as every bitset here).

    Notes
    -----
    The recursive block swap of Warren's *Hacker's Delight* (7-3), written for least significant
    bit first: 6 rounds of 32 masked swaps, 192 word operations instead of 4,096 bit moves.
    """
    j = 32
    m = np.uint64(0x00000000FFFFFFFF)
    while j != 0:
        sj = np.uint64(j)
        for k in range(64):
            if k & j == 0:
                t = ((a[k] >> sj) ^ a[k + j]) & m
                a[k] ^= t << sj
                a[k + j] ^= t
        j >>= 1
        m ^= m << np.uint64(j)


@numba.njit(nogil=True, cache=True, error_model="numpy", boundscheck=False)
def fill_lists(words, which, indptr, lo, hi, indices):  # pragma: no cover - compiled
    """The set bits of bitsets ``words[which[i]]`` for ``i`` in ``lo:hi``, ascending, into
    ``indices[indptr[i]:indptr[i + 1]]`` (compressed lists: a CSC matrix's rows of some columns,
    a CSR matrix's columns of some rows). ``words`` (r, w) uint64, ``which`` (c,) int64,
    ``indptr`` (c + 1,) int64 from the bitsets' counts, ``indices`` int32 or int64."""
    for i in range(lo, hi):
        j = which[i]
        p = indptr[i]
        for w in range(words.shape[1]):
            x = words[j, w]
            base = np.int64(w) << 6
            while x:
                indices[p] = base + np.int64(ctz(x))
                p += 1
                x &= x - np.uint64(1)
