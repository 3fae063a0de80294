"""Compiled (numba, GIL-free) kernels of the matrix store (:mod:`camplace.visibility.store`):
CSR <-> row bitsets.

A row bitset holds row i of an (m, n) matrix in bytes ``i * row_bytes : (i + 1) * row_bytes``
(``row_bytes = ceil(n / 8)``), column j in bit ``j % 8`` (least significant first) of byte
``j // 8``, like ``np.packbits(..., bitorder="little")``. The kernels work on a range of rows
``lo:hi`` so that threads can share a matrix. Importing this module imports numba but compiles
nothing (kernels load from numba's cache on first call).
"""

from __future__ import annotations

import numba
import numpy as np

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}

#: Set bits of every byte value.
POPCOUNT = np.array([bin(v).count("1") for v in range(256)], dtype=np.int64)
#: (256, 8) int32: the positions of the set bits of every byte value, ascending (then zeros).
BIT_POSITIONS = np.array([[t for t in range(8) if v >> t & 1] + [0] * (8 - bin(v).count("1")) for v in range(256)],
                         dtype=np.int32)


@numba.njit(**_JIT)
def all_ones(data):  # pragma: no cover - compiled
    """True when every value of ``data`` (1-d float32) is exactly 1.0 (stops at the first other)."""
    one = data.dtype.type(1.0)
    for i in range(data.size):
        if data[i] != one:
            return False
    return True


@numba.njit(**_JIT)
def csr_to_bits(indptr, indices, lo, hi, row_bytes, bits):  # pragma: no cover - compiled
    """Set the bits of rows ``lo:hi``.

    Parameters
    ----------
    indptr : (m + 1,) int32 or int64
    indices : (nnz,) int32 or int64
        Column of every stored entry (all < n).
    lo, hi : int
    row_bytes : int
    bits : (m * row_bytes,) uint8
        Output; rows ``lo:hi`` must come in zeroed.
    """
    for i in range(lo, hi):
        base = i * row_bytes
        for k in range(indptr[i], indptr[i + 1]):
            j = np.int64(indices[k])
            bits[base + (j >> 3)] |= np.uint8(1 << (j & 7))


@numba.njit(**_JIT)
def bits_row_counts(bits, lo, hi, row_bytes, last_mask, popcount, counts):  # pragma: no cover - compiled
    """Set bits of rows ``lo:hi`` into ``counts[lo:hi]``, and the number of rows whose padding
    bits (columns >= n in the last byte) are set (0 for a valid bitset).

    Parameters
    ----------
    bits : (m * row_bytes,) uint8
    lo, hi, row_bytes : int
    last_mask : int
        The valid bits of a row's last byte (``0xFF`` when n is a multiple of 8).
    popcount : (256,) int64
    counts : (m,) int64
        Output.

    Returns
    -------
    int
        Rows with padding bits set.
    """
    bad = 0
    for i in range(lo, hi):
        base = i * row_bytes
        c = 0
        for b in range(row_bytes):
            c += popcount[bits[base + b]]
        if row_bytes > 0:
            last = np.int64(bits[base + row_bytes - 1])
            if last & ~last_mask & 0xFF:
                bad += 1
        counts[i] = c
    return bad


@numba.njit(**_JIT)
def bits_to_indices(bits, lo, hi, row_bytes, indptr, positions, popcount, indices):  # pragma: no cover - compiled
    """Column indices of rows ``lo:hi``, ascending within a row, at ``indptr[i]:indptr[i + 1]``.

    A nonzero byte writes all 8 slots of its ``positions`` row and advances by its popcount
    (branch-free); the slots past its bits are overwritten by the next byte, or belong to the
    next row (written later by this call), so only the bytes whose 8 slots would pass
    ``indptr[hi]`` (another thread's rows) take the exact loop.

    Parameters
    ----------
    bits : (m * row_bytes,) uint8
    lo, hi, row_bytes : int
    indptr : (m + 1,) int32 or int64
        From the row counts of :func:`bits_row_counts`.
    positions : (256, 8) int32 or int64
        :data:`BIT_POSITIONS`.
    popcount : (256,) int64
        :data:`POPCOUNT`.
    indices : (nnz,) int32 or int64
        Output.
    """
    end = np.int64(indptr[hi])
    for i in range(lo, hi):
        k = np.int64(indptr[i])
        base = i * row_bytes
        for b in range(row_bytes):
            v = bits[base + b]
            if v == 0:
                continue
            col = b * 8
            c = popcount[v]
            if k + 8 <= end:
                for t in range(8):
                    indices[k + t] = col + positions[v, t]
            else:
                for t in range(c):
                    indices[k + t] = col + positions[v, t]
            k += c
