"""A graded visibility matrix quantised to a byte a cell, column by column (issue 32).

A graded quality ``Q`` in (0, 1] (:mod:`camplace.visibility.engine`) is stored as the byte
``q = quantise(Q) = max(1, floor(255 Q + 1/2))`` and stands for the value ``q / 255``: an
observed pair keeps a nonzero byte (the pattern is the float matrix's), and

    |q / 255 - Q| <= 1 / 510    for Q >= 1 / 510   (below that, q = 1 and q / 255 - Q < 1 / 255).

:class:`ByteMatrix` holds ``values`` of shape ``(n, m)`` uint8, column ``j``'s bytes in
``values[j]`` (the layout the quality-tree engine reads: its leaves are these rows, so it needs no
copy of the matrix), ``n * m`` bytes whatever the density: 500 MB for 50,000 points x 10,000
candidates, against 8 bytes an observed pair for the float32 CSR (1.7 GB at 42 % density). It is
the ``colbytes`` structure of the ``.cpm`` store (:mod:`camplace.visibility.store`).

For every camera set ``S`` the quality objective ``sum_i w_i max_{j in S} Q_ij`` on the bytes
differs from the one on the float values by at most ``sum_i w_i / 510`` (``|max a - max b| <=
max |a - b|``; ``/ 255`` for rows whose only values are below 1 / 510), so the optimum on the
bytes is within twice that of the float optimum.

The engine fills it chunk by chunk (:func:`camplace.visibility._kernels.scatter_chunk_quality`; a chunk owns a range of
columns, so the result does not depend on the thread count). The kernels are compiled with numba
(``nogil``: the callers run them on a thread pool).
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np
import scipy.sparse as sp

from camplace._blocks import cuts, run_blocks

__all__ = ["ByteMatrix", "quantise", "bytes_from_csr", "QUANT_STEP", "QUANT_ERROR"]

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}

#: the value of one step of a byte: a byte q stands for q * QUANT_STEP
QUANT_STEP = 1.0 / 255.0
#: the largest difference between a value >= 1 / 510 and its byte's value (half a step)
QUANT_ERROR = 0.5 / 255.0


@numba.njit(**_JIT)
def quantise(v):  # pragma: no cover - compiled
    """The byte of a quality ``v`` in [0, 1]: 0 for ``v <= 0``, else ``max(1, floor(255 v + 1/2))``
    (at most 255)."""
    if v <= 0.0:
        return np.uint8(0)
    x = math.floor(255.0 * v + 0.5)
    return np.uint8(min(255.0, max(1.0, x)))


@numba.njit(**_JIT)
def _quantise_csr(indptr, indices, data, lo, hi, values):  # pragma: no cover - compiled
    for r in range(lo, hi):
        for p in range(indptr[r], indptr[r + 1]):
            values[indices[p], r] = quantise(np.float64(data[p]))


@numba.njit(**_JIT)
def _row_counts(values, lo, hi, counts):  # pragma: no cover - compiled
    for j in range(values.shape[0]):
        for i in range(lo, hi):
            if values[j, i] != 0:
                counts[i] += 1


@numba.njit(**_JIT)
def _fill(values, lo, hi, cursor, indices, data, steps):  # pragma: no cover - compiled
    """CSR entries of rows ``lo:hi``: column indices and the float32 nearest ``q / steps``."""
    for j in range(values.shape[0]):
        for i in range(lo, hi):
            q = values[j, i]
            if q != 0:
                at = cursor[i]
                indices[at] = j
                data[at] = np.float32(q / steps)
                cursor[i] = at + 1


@numba.njit(**_JIT)
def _pack(values, lo, hi, words):  # pragma: no cover - compiled
    m = values.shape[1]
    for j in range(lo, hi):
        for i in range(m):
            if values[j, i] != 0:
                words[j, i >> 6] |= np.uint64(1) << np.uint64(i & 63)


@numba.njit(**_JIT)
def _column_counts(values, lo, hi, out):  # pragma: no cover - compiled
    for j in range(lo, hi):
        s = 0
        for i in range(values.shape[1]):
            s += values[j, i] != 0
        out[j] = s


@numba.njit(**_JIT)
def _only_ones(values):  # pragma: no cover - compiled
    """True when every nonzero byte is 255 (every observed value is 1)."""
    flat = values.reshape(-1)
    for p in range(flat.shape[0]):
        if flat[p] != 0 and flat[p] != 255:
            return False
    return True


class ByteMatrix:
    """An (m, n) quality matrix quantised to a byte a cell, stored column by column (see the module
    docstring).

    Parameters
    ----------
    values : (n, m) uint8
        Column ``j``'s bytes in ``values[j]``; the value of a byte ``q`` is ``q / 255`` (0: not
        observed).

    Attributes
    ----------
    values : (n, m) uint8
    shape : (m, n)
    dtype : numpy.dtype
        ``float32``: the values it stands for (:meth:`tocsr`).
    """

    format = "bytes"
    dtype = np.dtype(np.float32)
    scale = QUANT_STEP

    def __init__(self, values: np.ndarray):
        values = np.asarray(values)
        if values.dtype != np.uint8 or values.ndim != 2 or not values.flags.c_contiguous:
            raise ValueError(f"quantised columns must be C-contiguous (n, m) uint8, got {values.shape} {values.dtype}")
        self.values = values
        self.shape = (int(values.shape[1]), int(values.shape[0]))

    @property
    def nbytes(self) -> int:
        """Bytes of ``values``."""
        return int(self.values.nbytes)

    @functools.cached_property
    def column_counts(self) -> np.ndarray:
        """(n,) int64: rows each column observes."""
        out = np.zeros(self.shape[1], dtype=np.int64)
        run_blocks(lambda lo, hi: _column_counts(self.values, lo, hi, out), cuts(self.shape[1]))
        return out

    @property
    def nnz(self) -> int:
        """Observed pairs."""
        return int(self.column_counts.sum())

    def all_ones(self) -> bool:
        """True when every observed value is 1 (byte 255): a binary matrix in effect."""
        return bool(_only_ones(self.values))

    def bits(self):
        """The pattern (nonzero bytes) as :class:`~camplace.visibility.bits.BitMatrix` (``m n / 8``
        bytes): what the binary modes and the run's summary read."""
        from camplace.visibility.bits import BitMatrix, bit_words

        m, n = self.shape
        words = np.zeros((n, bit_words(m)), dtype=np.uint64)
        run_blocks(lambda lo, hi: _pack(self.values, lo, hi, words), cuts(n))
        return BitMatrix(words, m)

    def row_counts(self, workers: int | None = None) -> np.ndarray:
        """(m,) int64: candidates observing each row."""
        m = self.shape[0]
        counts = np.zeros(m, dtype=np.int64)
        run_blocks(lambda lo, hi: _row_counts(self.values, lo, hi, counts), cuts(m), workers)
        return counts

    def tocsr(self, dtype=np.float32, workers: int | None = None) -> sp.csr_matrix:
        """The canonical scipy CSR matrix of the values ``q / 255`` (the nearest float32; bool: the pattern),
        int32 indices unless int64 is needed. Needs ``(index bytes + value bytes)`` an observed pair."""
        m, n = self.shape
        counts = self.row_counts(workers)
        nnz = int(counts.sum())
        idt = np.int32 if max(m, n, nnz) < 2**31 - 1 else np.int64
        indptr = np.zeros(m + 1, dtype=np.int64)
        np.cumsum(counts, out=indptr[1:])
        indices = np.empty(nnz, dtype=idt)
        data = np.empty(nnz, dtype=np.float32)
        cursor = indptr[:-1].copy()
        run_blocks(lambda lo, hi: _fill(self.values, lo, hi, cursor, indices, data, 255.0), cuts(m), workers)
        if np.dtype(dtype) == np.bool_:
            data = np.ones(nnz, dtype=np.bool_)
        elif np.dtype(dtype) != np.float32:
            data = data.astype(dtype)
        out = sp.csr_matrix((data, indices, indptr.astype(idt)), shape=(m, n), copy=False)
        out.has_canonical_format = True
        return out

    def __repr__(self) -> str:
        return f"ByteMatrix(shape={self.shape}, {self.nbytes / 2**20:.1f} MiB)"


def bytes_from_csr(matrix, workers: int | None = None) -> ByteMatrix:
    """A quality matrix with values in [0, 1] quantised to a :class:`ByteMatrix` (:func:`quantise`).

    Raises
    ------
    ValueError
        On a value above 1 or below 0 (such a matrix keeps its float values).
    """
    a = sp.csr_matrix(matrix)
    if a.nnz and (float(a.data.min()) < 0.0 or float(a.data.max()) > 1.0):
        raise ValueError("only qualities in [0, 1] are quantised to a byte")
    m, n = a.shape
    values = np.zeros((n, m), dtype=np.uint8)
    # rows in ranges: every thread writes its own rows of every column
    run_blocks(lambda lo, hi: _quantise_csr(a.indptr, a.indices, a.data, lo, hi, values), cuts(m), workers)
    return ByteMatrix(values)
