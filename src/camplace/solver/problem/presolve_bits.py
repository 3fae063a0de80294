"""The presolve of :mod:`camplace.solver.problem.presolve`, read from column bitsets instead of CSR.

A binary visibility matrix arrives as :class:`camplace.visibility.bits.BitMatrix` (one bit a
cell, ``words`` (n, ceil(m / 64)) uint64). The same three reductions are made, with the same
results (the reduced instance is unique: the live rows, the dominated columns and the partition of
rows into identical patterns do not depend on how they are found; groups are numbered by first
occurrence):

1. live rows: weight > 0 and some column observes them (read from the rows' column counts, which
   the dominance needs anyway; without the dominance, an OR of all columns, in column blocks);
2. dominated columns: the candidate dominators of column ``a`` are the columns observing ``a``'s
   rarest live row (found by one scan of that row's bit over all columns, shared by the columns
   with the same rarest row), each tested word by word against the live-row mask (each column's
   live rows are counted in the pass that finds its rarest row);
3. identical rows over the kept columns are merged: each live row's bitset over the kept columns is
   built (a transposition, 64 x 64 bits at a time, ``m_live * ceil(n' / 64) * 8`` bytes), hashed,
   and grouped with exact word comparison.

The reduced column bitsets (:attr:`Presolved.bits`) are the transposition of the groups' first
rows. No CSR is made unless an engine asks for :attr:`Presolved.matrix` (the
OR-Tools models, the greedy fallback). The kernels are GIL-free and run on a thread pool over
fixed blocks, so the result is the same at every thread count.
"""

from __future__ import annotations

import functools
import logging
import time
from typing import Any, Callable

import numba
import numpy as np
import scipy.sparse as sp

from camplace._bitops import ctz as _ctz, fill_lists, popcount as _popc, transpose64 as _transpose64
from camplace._cores import thread_count
from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.solver._support.bitkernels import renumber_by_first
from camplace._blocks import cuts, run_blocks, work_cuts
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback, note_memory
from camplace.solver.problem.presolve import Presolved, check_weights, restore_columns

__all__ = ["BitPresolved", "presolve_bits", "presolve_bits_bytes", "covered_weight",
           "row_counts_of", "row_bitsets", "layout_bits", "layout_bits_bytes", "rows_csr",
           "rows_csr_bytes", "reduced_csr", "reduced_csr_bytes", "reduced_pattern", "reduced_pattern_bytes",
           "identical_rows", "identical_rows_bytes"]

log = logging.getLogger(__name__)

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}
_BLOCKS = 64  # blocks a round of the dominance runs at once (the time limit is checked between rounds)
_DOMINANCE_BLOCKS = 8 * _BLOCKS  # the dominance's blocks of equal work


@numba.njit(**_JIT)
def _or_columns(words, lo, hi, out):  # pragma: no cover - compiled
    """``out |=`` the OR of columns ``lo:hi``."""
    for j in range(lo, hi):
        for w in range(words.shape[1]):
            out[w] |= words[j, w]


@numba.njit(**_JIT)
def _rarest(words, live, tiers, row_nnz, lo, hi, out, size):  # pragma: no cover - compiled
    """Each column's live row observed by the fewest columns (the first on ties; -1: none), and
    ``size[j]``, its live rows (in the same pass: the column's words are in the cache).

    ``tiers`` (t, nw) uint64 are nested masks of the live rows observed by at most a threshold of
    columns (rising thresholds); a column's rarest row lies in the first tier it meets (every row
    outside that tier is observed more often than every row inside it, and every row of the
    rarest count is inside), so only that tier's bits of the column are read. No tier met: all of
    the column's live rows are read."""
    nw = words.shape[1]
    n_tiers = tiers.shape[0]
    for j in range(lo, hi):
        s = np.int64(0)
        for w in range(nw):
            s += np.int64(_popc(words[j, w] & live[w]))
        size[j] = s
        t_hit = n_tiers
        for t in range(n_tiers):
            acc = np.uint64(0)
            for w in range(nw):
                acc |= words[j, w] & tiers[t, w]
            if acc:
                t_hit = t
                break
        best = np.int64(-1)
        best_cnt = np.int64(1) << 62
        for w in range(nw):
            x = words[j, w] & (tiers[t_hit, w] if t_hit < n_tiers else live[w])
            base = np.int64(w) << 6
            while x:
                i = base + np.int64(_ctz(x))
                if row_nnz[i] < best_cnt:
                    best_cnt = row_nnz[i]
                    best = i
                x &= x - np.uint64(1)
        out[j] = best


def _rarity_tiers(live_rows: np.ndarray, row_nnz: np.ndarray, nw: int) -> np.ndarray:
    """(t, nw) uint64: nested masks of the live rows observed by at most the count of the rarest
    1/256, 1/32 and 1/4 of the live rows (see :func:`_rarest`); thresholds that repeat are kept once."""
    m_live = live_rows.size
    if m_live == 0:
        return np.zeros((0, nw), dtype=np.uint64)
    counts = row_nnz[live_rows]
    ranked = np.sort(counts)
    tiers = []
    last = None
    for frac in (1 / 256, 1 / 32, 1 / 4):
        thr = ranked[min(m_live - 1, int(frac * m_live))]
        if last is not None and thr == last:
            continue
        last = thr
        mask = np.zeros(nw * 64, dtype=bool)
        mask[live_rows[counts <= thr]] = True
        tiers.append(np.packbits(mask, bitorder="little").view(np.uint64))
    return np.stack(tiers) if tiers else np.zeros((0, nw), dtype=np.uint64)


@numba.njit(**_JIT)
def _dominated_groups(words, live, size, order, starts, rows, rowsets, g0, g1, out):  # pragma: no cover - compiled
    """Columns ``order[starts[g]:starts[g + 1]]`` for groups ``g0:g1`` (one rarest row ``rows[g]``
    each): dominated when a column observing that row holds them (more rows, or identical and a
    lower index). The columns observing row ``rows[g]`` are the set bits of ``rowsets[g]`` (its
    row bitset over all columns, :func:`_row_bits`), or, when ``rowsets`` has no rows (over the
    memory budget), found by reading that row's bit in every column."""
    n = words.shape[0]
    cand = np.empty(n, dtype=np.int64)
    have_sets = rowsets.shape[0] > 0
    for g in range(g0, g1):
        nc = 0
        if have_sets:
            for cw in range(rowsets.shape[1]):
                x = rowsets[g, cw]
                base = np.int64(cw) << 6
                while x:
                    cand[nc] = base + np.int64(_ctz(x))
                    nc += 1
                    x &= x - np.uint64(1)
        else:
            r = rows[g]
            wd = r >> 6
            bit = np.uint64(1) << np.uint64(r & 63)
            for b in range(n):
                if words[b, wd] & bit:
                    cand[nc] = b
                    nc += 1
        for q in range(starts[g], starts[g + 1]):
            a = order[q]
            for t in range(nc):
                b = cand[t]
                if b == a or size[b] < size[a] or (size[b] == size[a] and b > a):
                    continue
                ok = True
                for w in range(words.shape[1]):
                    if words[a, w] & live[w] & ~words[b, w]:
                        ok = False
                        break
                if ok:
                    out[a] = True
                    break


@numba.njit(**_JIT)
def _row_bits(words, columns, pos, w0, w1, out):  # pragma: no cover - compiled
    """Row bitsets ``out[pos[r]]`` (bit c = kept column ``columns[c]``) of the rows r of words
    ``w0:w1`` (``pos[r] = -1``: a row not kept), by 64 x 64 bit transposes (64 columns at a time,
    their words ``w0:w1`` read in order)."""
    nc = columns.shape[0]
    m = pos.shape[0]
    a = np.empty(64, dtype=np.uint64)
    wanted = np.zeros(w1 - w0, dtype=np.bool_)
    for wd in range(w0, w1):
        for r in range(min(64, m - wd * 64)):
            if pos[wd * 64 + r] >= 0:
                wanted[wd - w0] = True
                break
    for cb in range((nc + 63) // 64):
        c0 = cb * 64
        cnt = min(64, nc - c0)
        for wd in range(w0, w1):
            if not wanted[wd - w0]:
                continue
            base = wd * 64
            for t in range(cnt):
                a[t] = words[columns[c0 + t], wd]
            for t in range(cnt, 64):
                a[t] = 0
            _transpose64(a)  # a[r] bit t: column c0 + t observes row base + r
            for r in range(min(64, m - base)):
                i = pos[base + r]
                if i >= 0:
                    out[i, cb] = a[r]


@numba.njit(**_JIT)
def _hash_rows(rb, lo, hi, h, has):  # pragma: no cover - compiled
    for i in range(lo, hi):
        acc = np.uint64(0x9E3779B97F4A7C15)
        any_bit = False
        for w in range(rb.shape[1]):
            x = rb[i, w]
            if x:
                any_bit = True
            acc = (acc ^ x) * np.uint64(0x100000001B3) + np.uint64(w)
        h[i] = acc
        has[i] = any_bit


#: the hashes' top bits that split them into parts sorted on the pool (64 parts)
_HASH_PART_SHIFT = 58


@numba.njit(**_JIT)
def _hash_parts(h, shift):  # pragma: no cover - compiled
    """Positions of the hashes ``h`` (m,) uint64 grouped by their top bits ``h >> shift``, in
    increasing position within a part (a stable counting sort): ``(order (m,) int64, pstarts
    (P + 1,) int64)`` with ``P = 2 ** (64 - shift)`` parts."""
    m = h.shape[0]
    n_parts = np.int64(1) << (64 - shift)
    pstarts = np.zeros(n_parts + 1, dtype=np.int64)
    for i in range(m):
        pstarts[np.int64(h[i] >> np.uint64(shift)) + 1] += 1
    for p in range(n_parts):
        pstarts[p + 1] += pstarts[p]
    cursor = pstarts[:-1].copy()
    order = np.empty(m, dtype=np.int64)
    for i in range(m):
        p = np.int64(h[i] >> np.uint64(shift))
        order[cursor[p]] = i
        cursor[p] += 1
    return order, pstarts


@numba.njit(**_JIT)
def _sort_parts(h, order, pstarts, p0, p1):  # pragma: no cover - compiled
    """Sort parts ``p0:p1`` of :func:`_hash_parts`'s ``order`` by hash, stably (equal hashes keep
    increasing positions)."""
    for p in range(p0, p1):
        s, e = pstarts[p], pstarts[p + 1]
        if e - s > 1:
            sub = order[s:e].copy()
            o = np.argsort(h[sub], kind="mergesort")
            for q in range(e - s):
                order[s + q] = sub[o[q]]


@numba.njit(**_JIT)
def _bucket_starts(h, order):  # pragma: no cover - compiled
    """``starts`` (b + 1,): the runs of equal hash in ``order`` (sorted by hash)."""
    m = order.shape[0]
    starts = np.empty(m + 1, dtype=np.int64)
    nb = 0
    for q in range(m):
        if q == 0 or h[order[q]] != h[order[q - 1]]:
            starts[nb] = q
            nb += 1
    starts[nb] = m
    return starts[:nb + 1].copy()


def _hash_buckets(h: np.ndarray, workers: int) -> tuple[np.ndarray, np.ndarray]:
    """``order`` (the stable argsort of the hashes ``h`` (m,) uint64: by hash, then by position)
    and ``starts`` (b + 1,) int64: the runs of equal hash in ``order``, the buckets
    :func:`_bucket_reps` compares within. The hashes are split by their top bits (a serial
    counting pass) and the parts sorted on the pool: the same order as one stable sort."""
    order, pstarts = _hash_parts(h, _HASH_PART_SHIFT)
    _run(lambda p0, p1: _sort_parts(h, order, pstarts, p0, p1), work_cuts(np.diff(pstarts), _BLOCKS), workers)
    return order, _bucket_starts(h, order)


@numba.njit(**_JIT)
def _bucket_reps(rb, idx, order, starts, b0, b1, rep):  # pragma: no cover - compiled
    """For the rows of buckets ``b0:b1``: ``rep[q]`` = the first position ``p <= q`` of the same
    bucket (in ``order``) whose row ``rb[idx[order[p]]]`` equals row ``order[q]``'s (exact
    comparison against the bucket's representatives so far)."""
    nw = rb.shape[1]
    for b in range(b0, b1):
        s, e = starts[b], starts[b + 1]
        for q in range(s, e):
            bq = idx[order[q]]
            found = q
            for p in range(s, q):
                if rep[p] != p:
                    continue
                a = idx[order[p]]
                same = True
                for w in range(nw):
                    if rb[a, w] != rb[bq, w]:
                        same = False
                        break
                if same:
                    found = p
                    break
            rep[q] = found


@numba.njit(**_JIT)
def _label_groups(order, rep):  # pragma: no cover - compiled
    """Groups of the rows (positions of ``idx``) from :func:`_bucket_reps`, numbered by first
    occurrence in ``idx`` order: ``(groups (m,) int64, n_groups)``."""
    m = order.shape[0]
    groups = np.empty(m, dtype=np.int64)
    n_groups = 0
    for q in range(m):
        groups[order[q]] = rep[q]  # a label in 0..m-1: the representative's position
        if rep[q] == q:
            n_groups += 1
    renumber_by_first(groups, m)
    return groups, n_groups


def _grouped_rows(rb: np.ndarray, idx: np.ndarray, h: np.ndarray, workers: int) -> tuple[np.ndarray, int]:
    """Groups of identical rows ``rb[idx]`` (``h``: their hashes) numbered by first occurrence in
    ``idx`` order: the hashes sorted once, the exact comparisons within the hash
    buckets in blocks of about equal rows on the pool (the part that grows with duplicate rows),
    then the labels. The same groups at every thread count."""
    order, starts = _hash_buckets(h, workers)
    rep = np.empty(idx.size, dtype=np.int64)
    _run(lambda b0, b1: _bucket_reps(rb, idx, order, starts, b0, b1, rep), work_cuts(np.diff(starts), _BLOCKS),
         workers)
    return _label_groups(order, rep)


@numba.njit(**_JIT)
def _gather(rb, sel, nc, cw0, cw1, out):  # pragma: no cover - compiled
    """Reduced column bitsets ``out`` (nc, ceil(G / 64)) of the kept columns of column words
    ``cw0:cw1``: bit g of column c = row bitset ``rb[sel[g]]`` has bit c (a transposition of the
    groups' first rows, 64 x 64 bits at a time, each row's words ``cw0:cw1`` read in order)."""
    n_groups = sel.shape[0]
    a = np.empty(64, dtype=np.uint64)
    for gb in range((n_groups + 63) // 64):
        g0 = gb * 64
        cnt = min(64, n_groups - g0)
        for cw in range(cw0, cw1):
            c0 = cw * 64
            for t in range(cnt):
                a[t] = rb[sel[g0 + t], cw]
            for t in range(cnt, 64):
                a[t] = 0
            _transpose64(a)  # a[s] bit t: column c0 + s observes group g0 + t
            for q in range(min(64, nc - c0)):
                out[c0 + q, gb] = a[q]


@numba.njit(**_JIT)
def _count_rows(words, columns, w0, w1, counts):  # pragma: no cover - compiled
    """``counts[i] +=`` the columns of ``columns`` observing row i, for the rows of words ``w0:w1``."""
    for wd in range(w0, w1):
        base = np.int64(wd) << 6
        for c in range(columns.shape[0]):
            x = words[columns[c], wd]
            while x:
                counts[base + np.int64(_ctz(x))] += 1
                x &= x - np.uint64(1)


@numba.njit(**_JIT)
def _row_lengths(rb, lo, hi, out):  # pragma: no cover - compiled
    """Set bits of rows ``lo:hi`` of row bitsets ``rb``."""
    for i in range(lo, hi):
        s = np.int64(0)
        for w in range(rb.shape[1]):
            s += np.int64(_popc(rb[i, w]))
        out[i] = s


def _run(fn, bounds: list[int], workers: int) -> None:
    """``fn(lo, hi)`` for every block of ``bounds`` (:func:`~camplace._blocks.cuts`),
    on the solver's pool of ``workers`` threads."""
    with ctrl_c_deferred():
        run_blocks(fn, bounds, workers)


def _fresh_rows(rows: int, cols: int) -> tuple[np.ndarray, Callable[[int, int], None]]:
    """(rows, cols) uint64 zeros whose pages the workers fault in for the rows they fill, and the
    ``touch(r0, r1)`` that does it for rows ``r0:r1`` (one ``madvise`` per block instead of a page
    fault per 4 KiB, which on this VM made the merge's transposes 2-3 times slower on a fresh array:
    :func:`camplace.visibility.store.first_touch_empty`)."""
    from camplace.visibility.scratch import mapping_of
    from camplace.visibility.store import first_touch_empty, populate

    flat = first_touch_empty(rows * cols, np.uint64)
    if mapping_of(flat) is None:  # a small array: np.empty (an anonymous mapping is zeros)
        flat[:] = 0
    return flat.reshape(rows, cols), lambda r0, r1: populate(flat, r0 * cols, r1 * cols)


def _block_rows(sorted_rows: np.ndarray, w0: int, w1: int) -> tuple[int, int]:
    """The output rows ``r0:r1`` a block of row words ``w0:w1`` writes: the positions of the
    ``sorted_rows`` (ascending) in ``[64 w0, 64 w1)``."""
    return int(np.searchsorted(sorted_rows, 64 * w0)), int(np.searchsorted(sorted_rows, 64 * w1))


def _pack(mask: np.ndarray, n_words: int) -> np.ndarray:
    out = np.zeros(n_words * 8, dtype=np.uint8)
    packed = np.packbits(np.asarray(mask, dtype=bool), bitorder="little")
    out[:packed.size] = packed
    return out.view(np.uint64)


def presolve_bits_bytes(m: int, n: int) -> int:
    """Peak working bytes of :func:`presolve_bits` on an (m, n) matrix besides its bitsets: the
    live rows' bitsets over the columns and the reduced column bitsets (each at most
    ``R = m * ceil(n / 64) * 8`` bytes) with the merge's sorted copies (a quarter of ``R`` more),
    about 96 bytes a row (masks, indices, weights, the merge's keys and order) and 40 a column.
    Measured with tracemalloc (tests/solver/test_solve_bytes.py): 2.05 MB at 20,000 x 64 (2.28 MB
    estimated), 7.17 MB at 20,000 x 1,024 (7.68 MB), 1.86 MB at 5,000 x 1,024 (1.92 MB); the former
    ``2 R + 40 (m + n)`` was up to 1.8 times under at tall matrices."""
    rb = int(m) * ((int(n) + 63) // 64) * 8
    return int(2.25 * rb + 96 * int(m) + 40 * int(n))


class BitPresolved(Presolved):
    """A :class:`Presolved` made from column bitsets: :attr:`bits` is built by the presolve;
    :attr:`matrix` and :attr:`source` (the reduced CSR pattern, rows and columns in reduced
    order) are made from the bits on first use. :attr:`origin` is the BitMatrix it was made from
    (the original rows and columns, not copied): the readers of original rows (the bitset
    engine's opposite-pairs layout) take it instead of :attr:`source`, whose rows are the reduced
    ones."""

    @property
    def origin(self):
        """The :class:`camplace.visibility.bits.BitMatrix` presolved (None when not set)."""
        return self.__dict__.get("origin")

    @property
    def source(self):  # type: ignore[override]
        got = self.__dict__.get("_source")
        if got is None:
            m, n = self.shape
            got = (self.matrix, np.arange(m, dtype=np.int64), np.arange(n, dtype=np.int64))
            self.__dict__["_source"] = got
        return got

    @source.setter
    def source(self, value) -> None:
        if value is not None:
            self.__dict__["_source"] = value

    @functools.cached_property
    def nnz(self) -> int:
        """Observed pairs of the reduced instance, counted on :attr:`bits` (no CSR made)."""
        from camplace.visibility.bits import BitMatrix

        return BitMatrix(self.bits, self.shape[0]).nnz

    @functools.cached_property
    def matrix(self) -> sp.csr_matrix:
        """(m', n') scipy.sparse.csr_matrix of float64: 0/1 pattern of the reduced instance."""
        from camplace.visibility.bits import BitMatrix

        csr = BitMatrix(self.bits, self.shape[0]).tocsr(np.float64)
        return csr


def reduced_csr_bytes(m: int, n: int, nnz: int, value_bytes: int = 8) -> int:
    """Peak bytes of :func:`reduced_csr` on an (m, n) reduced instance of ``nnz`` observed pairs:
    int32 (int64 past 2**31) indices and ``value_bytes`` a pair, the row counts, pointers (and
    their cast) and cursors (8 bytes a row each, the cursors rounded up to a word of rows)."""
    idx = 4 if max(m, n, nnz) < 2**31 - 1 else 8
    return int((idx + value_bytes) * nnz + 8 * (4 * (m + 1) + 64))


def reduced_csr(pre: BitPresolved, dtype: Any = np.float64, what: str = "the reduced instance as CSR") -> sp.csr_matrix:
    """The reduced instance of :func:`presolve_bits` as a CSR pattern, checked against the memory
    budget before it is made: for the engines that read CSR rows, without a CSR of the whole matrix.

    Parameters
    ----------
    pre : BitPresolved
        (m', n') reduced instance (:attr:`BitPresolved.bits`, one bit a reduced row).
    dtype : numpy dtype
        Values (ones): float64 (12 bytes a pair with int32 indices; then also kept as
        :attr:`BitPresolved.matrix`) or bool (5 bytes a pair).
    what : str
        Names the copy in the over-budget message.

    Returns
    -------
    (m', n') scipy.sparse.csr_matrix
        Canonical (sorted int32 indices unless int64 is needed), rows and columns in reduced order.

    Raises
    ------
    OverBudget
        :func:`reduced_csr_bytes` is over :func:`~camplace.solver._support.memory.memory_budget_bytes`
        (nothing is allocated).
    """
    from camplace.visibility.bits import BitMatrix

    m, n = pre.shape
    red = BitMatrix(pre.bits, m)
    need, budget = reduced_csr_bytes(m, n, red.nnz, np.dtype(dtype).itemsize), memory_budget_bytes()
    if need > budget:
        raise OverBudget(need, budget, what)
    csr = red.tocsr(dtype)
    if np.dtype(dtype) == np.float64:
        pre.__dict__["matrix"] = csr  # what BitPresolved.matrix would make: made once
    return csr


def reduced_pattern_bytes(n: int, nnz: int) -> int:
    """Bytes of :func:`reduced_pattern`'s column lists of ``n`` columns and ``nnz`` pairs: int64
    pointers and row indices, ``8 * (nnz + n + 1)``."""
    return 8 * (int(nnz) + int(n) + 1)


def reduced_pattern(pre: BitPresolved, what: str = "the presolved instance's column lists") -> tuple[np.ndarray, np.ndarray]:
    """The CSC pattern of :func:`presolve_bits`'s reduced instance, read from its column bitsets
    (the rows each column observes, ascending), checked against the memory budget first.

    Parameters
    ----------
    pre : BitPresolved
        (m', n') reduced instance.
    what : str
        Names the arrays in the over-budget message.

    Returns
    -------
    indptr : (n' + 1,) int64
    indices : (nnz',) int64
        ``8 * (nnz' + n' + 1)`` bytes, filled on the pool (:func:`camplace.visibility.bits.column_rows`).

    Raises
    ------
    OverBudget
        Over :func:`~camplace.solver._support.memory.memory_budget_bytes` (nothing allocated).
    """
    from camplace.visibility.bits import BitMatrix, column_rows

    m, n = pre.shape
    red = BitMatrix(pre.bits, m)
    nnz = int(red.column_counts.sum())
    need, budget = reduced_pattern_bytes(n, nnz), memory_budget_bytes()
    if need > budget:
        raise OverBudget(need, budget, what)
    return column_rows(red, np.arange(n, dtype=np.int64), np.int64)


def covered_weight(bits, weights: np.ndarray, selected) -> float:
    """``sum_i w_i [some selected column observes i]`` of a BitMatrix (the maxcover objective,
    summed as :func:`camplace.solver.problem.objectives.mode_value` sums it)."""
    w = np.asarray(weights, dtype=np.float64)
    covered = bits.union(list(selected)) if len(selected) else np.zeros(bits.shape[0], dtype=bool)
    return float(np.sum(w[covered], dtype=np.float64))


def row_counts_of(bits, columns: np.ndarray, workers: int | None = None) -> np.ndarray:
    """(m,) int64: how many of ``columns`` ((c,) int64, distinct) observe each row of a BitMatrix
    (all columns: :meth:`~camplace.visibility.bits.BitMatrix.row_counts`)."""
    m, n = bits.shape
    columns = np.asarray(columns, dtype=np.int64)
    if columns.size == n:
        return bits.row_counts(workers)
    counts = np.zeros(bits.words.shape[1] * 64, dtype=np.int64)
    _run(lambda w0, w1: _count_rows(bits.words, columns, w0, w1, counts), cuts(bits.words.shape[1], _BLOCKS),
         thread_count(workers))
    return counts[:m]


def row_bitsets(bits, rows: np.ndarray, columns: np.ndarray, extra: int = 0, workers: int | None = None) -> np.ndarray:
    """Row bitsets of a BitMatrix over some of its columns (a transposition, 64 x 64 bits at a time).

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n).
    rows : (r,) int64
        Distinct rows, in output order.
    columns : (c,) int64
        Columns, in bit order: bit t of a row's bitset is column ``columns[t]``.
    extra : int
        Zero rows added after the ``r`` rows.
    workers : int, optional

    Returns
    -------
    (r + extra, ceil(c / 64)) uint64
        ``r * ceil(c / 64) * 8`` bytes (and the extra rows); the caller checks the budget.
    """
    m, n = bits.shape
    rows = np.asarray(rows, dtype=np.int64)
    columns = np.asarray(columns, dtype=np.int64)
    out = np.zeros((rows.size + int(extra), (columns.size + 63) // 64), dtype=np.uint64)
    pos = np.full(m, -1, dtype=np.int64)
    pos[rows] = np.arange(rows.size, dtype=np.int64)
    release = getattr(bits, "release_columns", None) or (lambda lo, hi: None)
    _run(lambda w0, w1: (_row_bits(bits.words, columns, pos, w0, w1, out), release(0, n)),
         cuts(bits.words.shape[1], _BLOCKS), thread_count(workers))
    return out


def identical_rows_bytes(r: int, n: int) -> int:
    """Peak bytes of :func:`identical_rows` on ``r`` rows of an (m, n) BitMatrix: the rows' bitsets
    over the n columns, the position map (8 bytes a row of the matrix is not counted: the caller
    holds that many already) and about 48 bytes a row (hashes, order, labels)."""
    return int(r * ((n + 63) // 64) * 8 + 48 * r)


def identical_rows(bits, rows: np.ndarray, workers: int | None = None) -> tuple[np.ndarray, int]:
    """Groups of identical rows (over all columns) among some rows of a BitMatrix: the presolve's
    merge of identical rows (row bitsets by transposes, hashed, compared exactly within a hash).

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n).
    rows : (r,) int64
        Distinct rows.
    workers : int, optional
        Threads (the groups do not depend on it).

    Returns
    -------
    groups : (r,) int64
        Group of ``rows[t]``, numbered by first occurrence in ``rows`` order (two rows share a
        group exactly when the same columns observe them).
    n_groups : int

    Notes
    -----
    Holds the rows' bitsets over all columns (:func:`identical_rows_bytes`); the caller checks the budget.
    """
    rows = np.asarray(rows, dtype=np.int64)
    n = bits.shape[1]
    if rows.size == 0:
        return np.zeros(0, dtype=np.int64), 0
    workers = thread_count(workers)
    rb = row_bitsets(bits, rows, np.arange(n, dtype=np.int64), workers=workers)
    h = np.zeros(rows.size, dtype=np.uint64)
    has = np.zeros(rows.size, dtype=bool)
    _run(lambda lo, hi: _hash_rows(rb, lo, hi, h, has), cuts(rows.size, _BLOCKS), workers)
    groups, n_groups = _grouped_rows(rb, np.arange(rows.size, dtype=np.int64), h, workers)
    return groups, int(n_groups)


def rows_csr(bits, rows: np.ndarray, columns: np.ndarray, workers: int | None = None) -> sp.csr_matrix:
    """Some rows and columns of a BitMatrix as the canonical CSR pattern :func:`camplace.solver.problem.presolve.as_pattern`
    makes (float64 ones, int32 indices, sorted): ``as_pattern(csr)[rows][:, columns]`` without the
    whole matrix's CSR.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n).
    rows : (r,) int64
        Distinct rows, in output order.
    columns : (c,) int64
        Columns, ascending: output column t is ``columns[t]``.
    workers : int, optional

    Returns
    -------
    (r, c) scipy.sparse.csr_matrix of float64
        Made through the rows' bitsets (``r * ceil(c / 64) * 8`` bytes, freed before return) and
        holding 12 bytes an observed pair; the caller checks the budget (:func:`rows_csr_bytes`).
    """
    rows = np.asarray(rows, dtype=np.int64)
    columns = np.asarray(columns, dtype=np.int64)
    r, c = rows.size, columns.size
    rb = row_bitsets(bits, rows, columns, workers=workers)
    workers = thread_count(workers)
    lengths = np.zeros(r, dtype=np.int64)
    blocks = cuts(r, _BLOCKS)
    _run(lambda lo, hi: _row_lengths(rb, lo, hi, lengths), blocks, workers)
    indptr = np.zeros(r + 1, dtype=np.int64)
    np.cumsum(lengths, out=indptr[1:])
    nnz = int(indptr[-1])
    idt = np.int32 if max(r, c, nnz) < 2**31 - 1 else np.int64
    indices = np.empty(nnz, dtype=idt)
    every = np.arange(r, dtype=np.int64)
    _run(lambda lo, hi: fill_lists(rb, every, indptr, lo, hi, indices), blocks, workers)
    rb = None  # freed before the caller goes on
    out = sp.csr_matrix((np.ones(nnz), indices, indptr.astype(idt)), shape=(r, c), copy=False)
    out.has_canonical_format = True
    return out


def rows_csr_bytes(r: int, c: int, nnz: int) -> int:
    """Peak bytes of :func:`rows_csr`: the rows' bitsets beside the CSR being filled."""
    return int(r * ((c + 63) // 64) * 8 + 12 * nnz + 16 * (r + 1))


def layout_bits_bytes(u: int, n_cols: int, length: int) -> int:
    """Peak bytes of :func:`layout_bits`: ``u`` distinct rows' bitsets over ``n_cols`` columns and
    the output (``n_cols`` columns over ``length`` bits)."""
    return int((u + 1) * ((n_cols + 63) // 64) * 8 + n_cols * ((length + 63) // 64) * 8)


def layout_bits(bits, rows: np.ndarray, col_map: np.ndarray, n_cols: int, workers: int | None = None) -> np.ndarray:
    """Column bitsets over a list of rows of a BitMatrix: what
    :func:`camplace.solver._support.parkernels.build_bits` makes of the matrix's CSR.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n).
    rows : (L,) int64
        The row of each output bit; a row may repeat, -1 is an empty bit (padding).
    col_map : (n,) int64
        Output column of each column, -1 to leave it out.
    n_cols : int
        Output columns.
    workers : int, optional

    Returns
    -------
    (n_cols, ceil(L / 64)) uint64
        Bit t of column c: ``rows[t] >= 0`` and column ``j`` with ``col_map[j] == c`` observes
        row ``rows[t]``. Working memory: the distinct rows' bitsets over the output columns
        (``u * ceil(n_cols / 64) * 8`` bytes) and the output (:func:`layout_bits_bytes`).

    Raises
    ------
    OverBudget
        When that is over :func:`~camplace.solver._support.memory.memory_budget_bytes` (before
        allocating).
    """
    rows = np.asarray(rows, dtype=np.int64)
    col_map = np.asarray(col_map, dtype=np.int64)
    mapped = np.flatnonzero(col_map >= 0)
    columns = np.empty(n_cols, dtype=np.int64)
    columns[col_map[mapped]] = mapped
    uniq = np.unique(rows[rows >= 0])
    need, budget = layout_bits_bytes(uniq.size, n_cols, rows.size), memory_budget_bytes()
    if need > budget:
        raise OverBudget(need, budget, "the layout's row bitsets (transposed from the column bitsets)")
    rb = row_bitsets(bits, uniq, columns, extra=1, workers=workers)  # the last row stays zero: the padding's
    sel = np.where(rows >= 0, np.searchsorted(uniq, rows), uniq.size).astype(np.int64)
    out = np.zeros((n_cols, (rows.size + 63) // 64), dtype=np.uint64)
    _run(lambda cw0, cw1: _gather(rb, sel, n_cols, cw0, cw1, out), cuts(rb.shape[1], _BLOCKS), thread_count(workers))
    return out


def presolve_bits(bits, weights: Any, k: int, *, dominance: bool = True, workers: int | None = None,
                  deadline: Deadline | None = None) -> BitPresolved:
    """:func:`camplace.solver.problem.presolve.presolve` of a matrix held as column bitsets.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n); ``bits.words`` (n, ceil(m / 64)) uint64.
    weights : (m,) array_like of float64
    k : int
    dominance : bool
    workers : int or None
        Threads (default: :func:`camplace._cores.thread_count`).
    deadline : Deadline or None
        When it expires during the column dominance (the part that grows fastest with the size),
        the dominance stops there: the columns found dominated so far are dropped (each has an
        undominated dominator, so the optimum is kept) and the rest kept; ``stats`` says so. The
        result then depends on timing; without expiry it is the same at every thread count.

    Returns
    -------
    BitPresolved
        The same reduced instance as :func:`~camplace.solver.problem.presolve.presolve` of the matrix's
        CSR (same weights, counts, columns, row groups and bitsets).
    """
    t0 = time.perf_counter()
    words = bits.words
    m, n = bits.shape
    nw = words.shape[1]
    w = check_weights(weights, m)
    note_memory("presolve", presolve_bits_bytes(m, n))
    if k < 1 or k > n:
        raise CamplaceError(f"k must be between 1 and the number of candidates ({n}), got {k}")
    workers = thread_count(workers)
    # out of core (a scratch file's mapping): each block's pages are dropped after it is read
    release = getattr(bits, "release_columns", None) or (lambda lo, hi: None)

    # 1. live rows: from the rows' column counts where the dominance reads them anyway (one pass
    # over the matrix, not two), else from the OR of the columns
    cb = cuts(n, _BLOCKS)
    with_dominance = dominance and n > k
    if with_dominance:
        row_nnz = bits.row_counts(workers)  # over all columns, as the CSR presolve counts
        any_obs = _pack(row_nnz > 0, nw)
    else:
        partial = np.zeros((_BLOCKS, nw), dtype=np.uint64)
        _run(lambda lo, hi: (_or_columns(words, lo, hi, partial[cb.index(lo)]), release(lo, hi)), cb, workers)
        any_obs = np.bitwise_or.reduce(partial, axis=0) if n else np.zeros(nw, dtype=np.uint64)
    live = any_obs & _pack(w > 0, nw)
    live_mask = np.unpackbits(live.view(np.uint8), bitorder="little", count=m).astype(bool)
    live_rows = np.flatnonzero(live_mask).astype(np.int64)
    stats: dict[str, Any] = {"rows_in": int(m), "cols_in": int(n), "nnz_in": int(bits.nnz),
                             "rows_live": int(live_rows.size), "time_live_s": time.perf_counter() - t0,
                             "layout": "column bitsets"}

    # 2. dominance
    t1 = time.perf_counter()
    dominated = np.zeros(n, dtype=bool)
    if with_dominance and live_rows.size > 0:
        rarest = np.zeros(n, dtype=np.int64)
        size = np.zeros(n, dtype=np.int64)  # each column's live rows
        tiers = _rarity_tiers(live_rows, row_nnz, nw)
        _run(lambda lo, hi: (_rarest(words, live, tiers, row_nnz, lo, hi, rarest, size), release(lo, hi)), cb,
             workers)
        empty = rarest < 0
        if empty.any():  # an empty column: dominated unless it is the first one and no column observes
            first_empty = int(np.flatnonzero(empty)[0])
            any_nonempty = bool((~empty).any())
            dominated[empty] = True
            if not any_nonempty:
                dominated[first_empty] = False
        nz = np.flatnonzero(~empty)
        order = nz[np.argsort(rarest[nz], kind="stable")]
        rows_sorted = rarest[order]
        cut = np.flatnonzero(np.diff(rows_sorted)) + 1
        starts = np.concatenate([[0], cut, [order.size]]).astype(np.int64)
        grows = rows_sorted[starts[:-1]] if order.size else np.zeros(0, dtype=np.int64)
        ng = grows.size
        # blocks of about equal work (columns of the group x columns observing its row), not of
        # equal group counts: one rare row observed by many columns is most of the work
        work = np.diff(starts) * np.maximum(row_nnz[grows], 1)
        gb = work_cuts(work, _DOMINANCE_BLOCKS)
        order = order.astype(np.int64)
        # each group's candidate dominators: its rarest row's bitset over all columns, by transposes
        # (one pass over the matrix), instead of reading that row's bit in every column per group
        rowsets = np.zeros((0, 1), dtype=np.uint64)
        if ng * ((n + 63) // 64) * 8 <= memory_budget_bytes() // 4:
            rowsets, touch = _fresh_rows(ng, (n + 63) // 64)
            gpos = np.full(m, -1, dtype=np.int64)
            gpos[grows] = np.arange(ng, dtype=np.int64)
            all_cols = np.arange(n, dtype=np.int64)
            _run(lambda w0, w1: (touch(*_block_rows(grows, w0, w1)), _row_bits(words, all_cols, gpos, w0, w1, rowsets),
                                 release(0, n)), cuts(nw, _BLOCKS), workers)
            del gpos, all_cols
        # a first round of _BLOCKS blocks; the rest at once when it would end well inside the time
        # limit at that round's rate, else in rounds with the limit checked between them
        r0, per_block = 0, 0.0
        n_blocks = len(gb) - 1
        while r0 < n_blocks:
            if deadline is not None and deadline.expired():
                stats["dominance_stopped"] = (f"time limit: {gb[r0]} of {ng} rarest-row groups checked (the "
                                              "columns found dominated so far are dropped, the rest kept)")
                break
            t_round = time.perf_counter()
            left = deadline.remaining() if deadline is not None else None
            rest = r0 > 0 and (left is None or 2.0 * per_block * (n_blocks - r0) < left)
            r1 = n_blocks if rest else min(n_blocks, r0 + _BLOCKS)
            _run(lambda g0, g1: _dominated_groups(words, live, size, order, starts, grows, rowsets, g0, g1, dominated)
                 or release(0, n), gb[r0:r1 + 1], workers)
            per_block = (time.perf_counter() - t_round) / max(1, r1 - r0)
            r0 = r1
        rowsets = None
        stats["dominance_method"] = "column bitsets"
    keep, restored = restore_columns(dominated, k, lambda: np.array([float(np.sum(w[live_mask & bits.column(j)]))
                                                                     for j in range(n)]) if live_rows.size else np.zeros(n))
    columns = np.flatnonzero(keep).astype(np.int64)
    stats["time_dominance_s"] = time.perf_counter() - t1
    stats["cols_dominated"] = int(dominated.sum())
    stats["cols_restored"] = int(restored)

    # 3. merge identical rows over the kept columns
    t2 = time.perf_counter()
    nc = columns.size
    need = live_rows.size * ((nc + 63) // 64) * 8  # the row bitsets; the reduced columns are at most as big
    budget = memory_budget_bytes()
    if need > budget:  # nothing to fall back to: a one-line error (the one memory policy)
        memory_fallback(OverBudget(need, budget, "the presolve (live rows x kept columns as bitsets)"), None,
                        asked=False, then=None, fix="lower --points or --candidates, or raise --memory-budget-gb")
    rb, touch = _fresh_rows(live_rows.size, (nc + 63) // 64)
    rbk = cuts(live_rows.size, _BLOCKS)
    pos = np.full(m, -1, dtype=np.int64)
    pos[live_rows] = np.arange(live_rows.size, dtype=np.int64)
    _run(lambda w0, w1: (touch(*_block_rows(live_rows, w0, w1)), _row_bits(words, columns, pos, w0, w1, rb),
                         release(0, n)), cuts(nw, _BLOCKS), workers)
    del pos
    h = np.zeros(live_rows.size, dtype=np.uint64)
    has = np.zeros(live_rows.size, dtype=bool)
    _run(lambda lo, hi: _hash_rows(rb, lo, hi, h, has), rbk, workers)
    idx = np.flatnonzero(has).astype(np.int64)
    groups, n_groups = _grouped_rows(rb, idx, h[idx], workers)
    orig_rows = live_rows[idx]
    first = np.full(n_groups, -1, dtype=np.int64)
    first[groups[::-1]] = np.arange(groups.size - 1, -1, -1, dtype=np.int64)
    wsum = np.bincount(groups, weights=w[orig_rows], minlength=n_groups).astype(np.float64)
    counts = np.bincount(groups, minlength=n_groups).astype(np.int64)
    row_groups = np.full(m, -1, dtype=np.int64)
    row_groups[orig_rows] = groups
    red, touch = _fresh_rows(nc, (int(n_groups) + 63) // 64)
    sel = idx[first]  # each group's first row, as a row of rb
    _run(lambda cw0, cw1: (touch(64 * cw0, min(nc, 64 * cw1)), _gather(rb, sel, nc, cw0, cw1, red)),
         cuts(rb.shape[1], _BLOCKS), workers)
    rb = None  # freed before the reduced instance is made (up to m x n / 8 bytes)
    stats["time_merge_s"] = time.perf_counter() - t2

    pos = w[w > 0]
    unit = float(pos[0]) if pos.size and np.all(pos == pos[0]) else None
    stats.update({"rows_after": int(n_groups), "cols_after": int(nc), "time_s": time.perf_counter() - t0})
    log.info("presolve (bits): rows %d -> %d, cols %d -> %d (%d dominated, %d restored) in %.3f s",
             m, n_groups, n, nc, stats["cols_dominated"], restored, stats["time_s"])
    out = BitPresolved(weights=wsum, counts=counts, columns=columns, row_groups=row_groups, k=int(k),
                       shape_in=(int(m), int(n)), weight_unit=unit, source=None, stats=stats)
    out.__dict__["bits"] = red
    out.__dict__["origin"] = bits
    return out
