"""A binary visibility matrix as column bitsets: one bit a (point, candidate) cell.

A binary instance (``[quality] mode = "binary"``) only needs to know which pairs are observed, so
its matrix is kept as :class:`BitMatrix`: ``words`` of shape ``(n, ceil(m / 64))`` uint64, column
``j``'s bitset in ``words[j]``, row ``i`` in bit ``i % 64`` (least significant first) of word
``i // 64``; bits beyond row ``m - 1`` are zero. That is ``m * n / 8`` bytes whatever the density
(62.5 MB for 50,000 points x 10,000 candidates), against 8 bytes an observed pair for a float32
CSR matrix (1.7 GB at 42 % density). It is also the layout the solver's presolve and bitset
engines read (:attr:`camplace.solver.presolve.Presolved.bits`), and the ``colbits`` structure of
the ``.cpm`` store (:mod:`camplace.visibility.store`).

The engine fills it chunk by chunk (:func:`scatter_chunk`): a chunk owns a range of columns, so
the worker threads write disjoint rows of ``words`` and the result does not depend on the thread
count. Conversions to scipy CSR (:meth:`BitMatrix.tocsr`) are for users who ask for it.

The kernels are compiled with numba (``nogil``: the callers run them on a thread pool).
"""

from __future__ import annotations

import functools
from typing import Sequence

import numba
import numpy as np
import scipy.sparse as sp

from camplace._bitops import ctz as _ctz, fill_lists, popcount as _popcount, transpose64 as _transpose64
from camplace._blocks import cuts, run_blocks
from camplace._cores import thread_count

__all__ = ["BitMatrix", "bit_words", "bits_from_csr", "scatter_chunk", "take_rows", "row_range", "stack_rows", "column_sums",
           "column_rows"]

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}

def bit_words(m: int) -> int:
    """uint64 words of one column's bitset over ``m`` rows: ``ceil(m / 64)``."""
    return (int(m) + 63) // 64


@numba.njit(**_JIT)
def scatter_chunk(rowids, offsets, lcols, col0, words):  # pragma: no cover - compiled
    """Set the bits of a chunk's observed pairs (:class:`camplace.visibility.chunk.ChunkResult`).

    Parameters
    ----------
    rowids : (r,) int32
        Global rows with observed pairs.
    offsets : (r + 1,) int64
        Row ``t``'s pairs are ``lcols[offsets[t]:offsets[t + 1]]``.
    lcols : (o,) uint8 or uint16
        Chunk-local columns (global ``col0 + lcols``).
    col0 : int
    words : (n, W) uint64
        Written in place: only the chunk's columns.
    """
    for t in range(rowids.shape[0]):
        r = rowids[t]
        w = r >> 6
        b = np.uint64(1) << np.uint64(r & 63)
        for p in range(offsets[t], offsets[t + 1]):
            c = col0 + np.int64(lcols[p])
            words[c, w] |= b


@numba.njit(**_JIT)
def _column_counts(words, lo, hi, out):  # pragma: no cover - compiled
    for j in range(lo, hi):
        s = 0
        for w in range(words.shape[1]):
            s += np.int64(_popcount(words[j, w]))
        out[j] = s


@numba.njit(**_JIT)
def _row_counts(words, w0, w1, counts):  # pragma: no cover - compiled
    """Entries of the rows of words ``w0:w1`` (rows ``64 * w0`` to ``64 * w1 - 1``): the popcounts
    of the row words after 64 x 64 bit transposes of 64 columns' words at a time (read in order)."""
    n = words.shape[0]
    a = np.empty(64, dtype=np.uint64)
    for c0 in range(0, n, 64):
        cnt = min(64, n - c0)
        for wd in range(w0, w1):
            base = np.int64(wd) << 6
            for t in range(cnt):
                a[t] = words[c0 + t, wd]
            for t in range(cnt, 64):
                a[t] = 0
            _transpose64(a)  # a[r]: the columns c0 .. c0 + 63 observing row base + r
            for r in range(64):
                counts[base + r] += np.int64(_popcount(a[r]))


@numba.njit(**_JIT)
def _fill_indices(words, w0, w1, cursor, indices):  # pragma: no cover - compiled
    """CSR column indices of the rows of words ``w0:w1``; ``cursor`` starts at each row's indptr."""
    for j in range(words.shape[0]):
        for w in range(w0, w1):
            x = words[j, w]
            base = w << 6
            while x:
                t = np.int64(_ctz(x))
                r = base + t
                indices[cursor[r]] = j
                cursor[r] += 1
                x &= x - np.uint64(1)


@numba.njit(**_JIT)
def _from_csr(indptr, indices, lo, hi, words):  # pragma: no cover - compiled
    """Set the bits of rows ``lo:hi`` of a canonical CSR pattern (all its entries observe)."""
    for r in range(lo, hi):
        w = r >> 6
        b = np.uint64(1) << np.uint64(r & 63)
        for t in range(indptr[r], indptr[r + 1]):
            words[indices[t], w] |= b


@numba.njit(**_JIT)
def _column_sums(words, values, lo, hi, out):  # pragma: no cover - compiled
    """``out[j]``: ``values`` summed over column j's rows, in increasing row order from 0.0."""
    for j in range(lo, hi):
        s = 0.0
        for w in range(words.shape[1]):
            x = words[j, w]
            base = np.int64(w) << 6
            while x:
                s += values[base + np.int64(_ctz(x))]
                x &= x - np.uint64(1)
        out[j] = s


class BitMatrix:
    """An (m, n) 0/1 matrix stored as column bitsets (see the module docstring).

    Parameters
    ----------
    words : (n, ceil(m / 64)) uint64
        Column bitsets; bits past row ``m - 1`` must be zero.
    m : int
        Rows.

    Attributes
    ----------
    words : (n, W) uint64
    shape : (m, n)
    dtype : numpy.dtype
        ``bool`` (the matrix is a pattern).
    """

    format = "bits"
    dtype = np.dtype(np.bool_)

    def __init__(self, words: np.ndarray, m: int):
        words = np.asarray(words)
        if words.dtype != np.uint64 or words.ndim != 2 or words.shape[1] != bit_words(m):
            raise ValueError(f"column bitsets must be (n, {bit_words(m)}) uint64, got {words.shape} {words.dtype}")
        self.words = words
        self.shape = (int(m), int(words.shape[0]))

    def release_columns(self, lo: int, hi: int) -> None:
        """Drop columns ``lo:hi`` from this process's memory when the bitsets are a scratch file's
        mapping (out of core, :mod:`camplace.visibility.scratch`); a no-op in memory."""
        from camplace.visibility.scratch import release_pages

        row = self.words.shape[1] * 8
        release_pages(self.words, int(lo) * row, int(hi) * row)

    @property
    def nbytes(self) -> int:
        """Bytes of ``words``."""
        return int(self.words.nbytes)

    @functools.cached_property
    def column_counts(self) -> np.ndarray:
        """(n,) int64: rows each column observes."""
        out = np.zeros(self.shape[1], dtype=np.int64)
        run_blocks(lambda lo, hi: (_column_counts(self.words, lo, hi, out), self.release_columns(lo, hi)),
                   cuts(self.shape[1]))
        return out

    @property
    def nnz(self) -> int:
        """Observed pairs."""
        return int(self.column_counts.sum())

    def row_counts(self, workers: int | None = None) -> np.ndarray:
        """(m,) int64: candidates observing each row."""
        m = self.shape[0]
        counts = np.zeros(bit_words(m) * 64, dtype=np.int64)
        run_blocks(lambda a, b: (_row_counts(self.words, a, b, counts), self.release_columns(0, self.shape[1])),
             cuts(self.words.shape[1], 64),
             thread_count(workers))
        return counts[:m]

    def column(self, j: int) -> np.ndarray:
        """(m,) bool: the rows column ``j`` observes."""
        return unpack_rows(self.words[j], self.shape[0])

    def union(self, cols: Sequence[int]) -> np.ndarray:
        """(m,) bool: the rows some column of ``cols`` observes."""
        cols = np.asarray(list(cols), dtype=np.int64)
        acc = np.zeros(self.words.shape[1], dtype=np.uint64)
        for j in cols:
            acc |= self.words[int(j)]
        return unpack_rows(acc, self.shape[0])

    def tocsr(self, dtype=np.float32, workers: int | None = None) -> sp.csr_matrix:
        """The canonical scipy CSR matrix: ones of ``dtype``, sorted column indices, int32 indices
        unless int64 is needed. Needs ``(index bytes + value bytes)`` an observed pair."""
        m, n = self.shape
        counts = self.row_counts(workers)
        nnz = int(counts.sum())
        idt = np.int32 if max(m, n, nnz) < 2**31 - 1 else np.int64
        indptr = np.zeros(m + 1, dtype=np.int64)
        np.cumsum(counts, out=indptr[1:])
        indices = np.empty(nnz, dtype=idt)
        cursor = np.zeros(bit_words(m) * 64, dtype=np.int64)
        cursor[:m] = indptr[:-1]
        run_blocks(lambda a, b: _fill_indices(self.words, a, b, cursor, indices), cuts(self.words.shape[1], 64),
             thread_count(workers))
        data = np.ones(nnz, dtype=dtype)
        out = sp.csr_matrix((data, indices, indptr.astype(idt)), shape=(m, n), copy=False)
        out.has_canonical_format = True
        return out

    def __repr__(self) -> str:
        return f"BitMatrix(shape={self.shape}, {self.nbytes / 2**20:.1f} MiB)"


def unpack_rows(word_row: np.ndarray, m: int) -> np.ndarray:
    """(m,) bool from one bitset of ``ceil(m / 64)`` uint64 words."""
    return np.unpackbits(np.ascontiguousarray(word_row).view(np.uint8), bitorder="little", count=m).astype(bool)


def pack_rows(mask: np.ndarray) -> np.ndarray:
    """(ceil(m / 64),) uint64 bitset of an (m,) bool mask."""
    m = len(mask)
    out = np.zeros(bit_words(m) * 8, dtype=np.uint8)
    packed = np.packbits(np.asarray(mask, dtype=bool), bitorder="little")
    out[:packed.size] = packed
    return out.view(np.uint64)


def bits_from_csr(matrix, workers: int | None = None) -> BitMatrix:
    """The pattern (entries > 0) of a scipy sparse matrix as a :class:`BitMatrix`."""
    a = sp.csr_matrix(matrix)
    if a.nnz and np.any(a.data <= 0):
        a = a.copy()
        a.data = (a.data > 0).astype(np.float32)
        a.eliminate_zeros()
    m, n = a.shape
    words = np.zeros((n, bit_words(m)), dtype=np.uint64)
    # rows in blocks of 64 (whole words), so no two threads write one word
    blocks = cuts(bit_words(m), 64)
    run_blocks(lambda a0, b0: _from_csr(a.indptr, a.indices, 64 * a0, min(m, 64 * b0), words), blocks, thread_count(workers))
    return BitMatrix(words, m)


#: Cells (rows x columns) unpacked to one byte each at a time by the row helpers below.
_BLOCK_CELLS = 1 << 22


def _column_blocks(bits: BitMatrix, cells: int = _BLOCK_CELLS) -> list[tuple[int, int]]:
    """Consecutive column ranges of about ``cells`` unpacked cells each (at least one column)."""
    n = bits.shape[1]
    step = max(1, cells // max(1, bits.shape[0]))
    return [(c, min(n, c + step)) for c in range(0, n, step)]


def _unpack_block(bits: BitMatrix, lo: int, hi: int) -> np.ndarray:
    """(hi - lo, m) uint8 0/1: columns ``lo:hi`` unpacked (1 byte a cell)."""
    block = np.ascontiguousarray(bits.words[lo:hi]).view(np.uint8)
    return np.unpackbits(block, axis=1, bitorder="little", count=bits.shape[0])


def _pack_into(words: np.ndarray, lo: int, cells: np.ndarray) -> None:
    """Write (c, m') 0/1 cells as the bitsets of columns ``lo:lo + c`` of ``words`` (n, ceil(m' / 64))."""
    packed = np.packbits(cells, axis=1, bitorder="little")
    words[lo:lo + cells.shape[0]].view(np.uint8)[:, :packed.shape[1]] = packed


def take_rows(bits: BitMatrix, rows: np.ndarray) -> BitMatrix:
    """The rows ``rows`` of a bit matrix, in that order: ``bits.tocsr()[rows]`` without CSR.

    Parameters
    ----------
    bits : BitMatrix
        (m, n).
    rows : (r,) int64
        Row indices in 0..m-1 (any order, repeats allowed).

    Returns
    -------
    BitMatrix
        (r, n); ``n * ceil(r / 64) * 8`` bytes, plus an unpacked block of about 4 MiB at a time.
    """
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    m, n = bits.shape
    if rows.size and (rows.min() < 0 or rows.max() >= m):
        raise IndexError(f"rows out of range 0..{m - 1}")
    out = np.zeros((n, bit_words(rows.size)), dtype=np.uint64)
    if rows.size:
        for lo, hi in _column_blocks(bits):
            _pack_into(out, lo, _unpack_block(bits, lo, hi)[:, rows])
            bits.release_columns(lo, hi)
    return BitMatrix(out, rows.size)


@numba.njit(**_JIT)
def _shift_rows(words, lo, hi, c0, c1, out):  # pragma: no cover - compiled
    """Rows ``lo:hi`` of columns ``c0:c1`` of ``words`` into ``out`` (bit ``r - lo``): each output
    word is two input words shifted by ``lo % 64``, the last one masked past ``hi - lo``."""
    nw_in = words.shape[1]
    nw = out.shape[1]
    w0 = lo >> 6
    sh = np.uint64(lo & 63)
    back = np.uint64(64) - sh
    rest = (hi - lo) & 63
    last = (np.uint64(1) << np.uint64(rest)) - np.uint64(1) if rest else ~np.uint64(0)
    for j in range(c0, c1):
        for w in range(nw):
            x = words[j, w0 + w] >> sh
            if sh and w0 + w + 1 < nw_in:
                x |= words[j, w0 + w + 1] << back
            if w == nw - 1:
                x &= last
            out[j, w] = x


def row_range(bits: BitMatrix, lo: int, hi: int, workers: int | None = None) -> BitMatrix:
    """Rows ``lo:hi`` of a bit matrix (``bits.tocsr()[lo:hi]`` as bits): word shifts, no unpacking.

    Parameters
    ----------
    bits : BitMatrix
        (m, n).
    lo, hi : int
        ``0 <= lo <= hi <= m``.
    workers : int, optional
        Threads over blocks of columns (the result does not depend on it).

    Returns
    -------
    BitMatrix
        (hi - lo, n): ``n * ceil((hi - lo) / 64) * 8`` bytes (a view-free copy; the caller checks the
        memory). With ``lo`` a multiple of 64 it is a plain copy of whole words.
    """
    m, n = bits.shape
    lo, hi = int(lo), int(hi)
    if not 0 <= lo <= hi <= m:
        raise IndexError(f"row range {lo}:{hi} out of 0:{m}")
    out = np.empty((n, bit_words(hi - lo)), dtype=np.uint64)
    if out.size:
        run_blocks(lambda c0, c1: (_shift_rows(bits.words, lo, hi, c0, c1, out), bits.release_columns(c0, c1)),
                   cuts(n), thread_count(workers))
    return BitMatrix(out, hi - lo)


def stack_rows(blocks: Sequence[BitMatrix]) -> BitMatrix:
    """The row blocks one under the other (``scipy.sparse.vstack`` of their CSR forms), as bits.

    Parameters
    ----------
    blocks : sequence of (m_b, n) BitMatrix
        At least one; all with ``n`` columns.

    Returns
    -------
    BitMatrix
        (sum of m_b, n).
    """
    n = blocks[0].shape[1]
    if any(b.shape[1] != n for b in blocks):
        raise ValueError("stack_rows: the blocks must have the same number of columns")
    m = sum(b.shape[0] for b in blocks)
    out = np.zeros((n, bit_words(m)), dtype=np.uint64)
    step = max(1, _BLOCK_CELLS // max(1, m))
    for lo in range(0, n, step):
        hi = min(n, lo + step)
        _pack_into(out, lo, np.concatenate([_unpack_block(b, lo, hi) for b in blocks], axis=1))
    return BitMatrix(out, m)


def column_sums(bits: BitMatrix, values: np.ndarray, workers: int | None = None) -> np.ndarray:
    """(n,) float64: ``values`` summed over the rows each column observes.

    The sums are taken row after row in increasing order from 0.0 (``np.bincount`` of the CSR
    column indices with per-entry weights ``values[row]`` gives the very same floats), so a reader
    of the bits agrees with the CSR reader to the last bit. A compiled kernel walks each column's
    set bits (no unpacked copy).

    Parameters
    ----------
    bits : BitMatrix
        (m, n).
    values : (m,) float64
        Per-row values (weights, gains).
    workers : int, optional
        Threads over ranges of columns (default: the allowed cores; the sums do not depend on it).

    Returns
    -------
    (n,) float64
    """
    m, n = bits.shape
    v = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    if v.shape != (m,):
        raise ValueError(f"column_sums: values must be ({m},), got {v.shape}")
    out = np.zeros(n, dtype=np.float64)
    if m == 0 or not np.any(v):
        return out
    run_blocks(lambda lo, hi: (_column_sums(bits.words, v, lo, hi, out), bits.release_columns(lo, hi)),
               cuts(n), thread_count(workers))
    return out


def column_rows(bits, cols: np.ndarray, dtype=np.int32) -> tuple[np.ndarray, np.ndarray]:
    """The row lists of columns ``cols`` of a BitMatrix, as the CSC matrix of those columns holds them.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n).
    cols : (nf,) int64
        Columns, in the order wanted.
    dtype : numpy integer dtype
        Of ``indices`` (int32 needs ``m < 2**31``).

    Returns
    -------
    indptr : (nf + 1,) int64
    indices : (nnz,) ``dtype``
        Column ``cols[i]``'s rows, ascending, in ``indices[indptr[i]:indptr[i + 1]]`` (4 or 8 bytes
        an observed pair of those columns; the caller checks the memory), filled in blocks of
        columns on the pool.
    """
    cols = np.ascontiguousarray(cols, dtype=np.int64)
    indptr = np.zeros(cols.size + 1, dtype=np.int64)
    np.cumsum(bits.column_counts[cols], out=indptr[1:])
    indices = np.empty(int(indptr[-1]), dtype=dtype)
    if indices.size:  # disjoint slices of indices per block: the same at every thread count
        run_blocks(lambda lo, hi: fill_lists(bits.words, cols, indptr, lo, hi, indices), cuts(cols.size))
    return indptr, indices
