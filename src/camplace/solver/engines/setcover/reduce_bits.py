"""The set-cover reductions of :func:`camplace.solver.engines.setcover.reduce.reduce_cover` on
bitsets: the rows to cover of a binary matrix held as column bitsets, without CSR lists.

:func:`reduce_cover` holds the instance twice as compressed lists (int32 indices, int64 pointers)
and, in its first round, also a float64 CSR copy and its CSC: about 44 bytes an observed pair. On
comet-67p-bunker 10,000 x 50,000 (2.08e8 observed pairs, 42 % dense) that was 8.8 GiB of the set
cover's peak. Here the instance is held as row bitsets (``m x ceil(n / 64)`` words) and their
transposition, the column bitsets (``n x ceil(m / 64)`` words): 1 bit a cell each, 125 MB in all at
that size, whatever the density. The rounds make the same reductions in the same order, read from
the bitsets by kernels that visit the same elements in the same (ascending) order as the list
kernels (:func:`_kernels.subset_marks_bits`, :func:`_kernels.cheaper_cover_marks_bits`), so the
reduced instance is the same, array for array; only the reduced instance (3,164 x 2,276 and 3.1e6
pairs at that size) becomes the lists the search reads.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
import scipy.sparse as sp

from camplace._cores import thread_count
from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback
from camplace.solver.engines.setcover import _kernels as K

__all__ = ["RowBits", "reduce_cover_bits", "row_bits_bytes", "reduce_bits_bytes", "lists_bytes", "setcover_bits_bytes"]

log = logging.getLogger(__name__)

_BLOCKS = 64


def _words(bits: int) -> int:
    return max(1, (int(bits) + 63) // 64)


def row_bits_bytes(m: int, n: int) -> int:
    """Bytes of the row bitsets of an (m, n) instance: ``m x ceil(n / 64)`` uint64 words."""
    return int(m) * _words(n) * 8


def reduce_bits_bytes(m: int, n: int) -> int:
    """Peak working bytes of :func:`reduce_cover_bits` on an (m, n) instance besides its row
    bitsets (:attr:`RowBits.rb`, held by the caller): the column bitsets (their transposition), a
    round's shrunken copies of both (at most as large again), per-row and per-column state (about
    80 bytes each) and 16 MiB of temporaries."""
    b = row_bits_bytes(m, n)
    col = int(n) * _words(m) * 8
    return int(2 * col + b + 80 * (int(m) + int(n)) + (16 << 20))


def setcover_bits_bytes(m: int, n: int) -> int:
    """Working bytes of set cover on an (m, n) binary matrix held as column bitsets, besides the
    bitsets: the rows to cover as row bitsets (at most ``m x ceil(n / 64)`` words, kept to the
    end), their transposition (``n x ceil(m / 64)`` words, the reductions' column bitsets), the
    per-row masks and counts (about 48 bytes a row), per-row and per-column state of the
    reductions (80 bytes each) and 16 MiB of temporaries. The reductions' shrunken copies and the
    reduced instance's lists are not counted: on a visibility matrix the first round drops most
    rows (comet-67p-bunker 10,000 x 50,000: 49,999 x 10,000 -> 3,164 x 2,276 after 8 rounds), so
    they are small beside the first round's bitsets; :func:`reduce_cover_bits` checks its own
    worst case (:func:`reduce_bits_bytes`, :func:`lists_bytes`) before allocating."""
    return int(row_bits_bytes(m, n) + int(n) * _words(m) * 8 + 48 * int(m) + 80 * (int(m) + int(n)) + (16 << 20))


def lists_bytes(m: int, n: int, nnz: int, partial: bool) -> int:
    """Bytes of the compressed lists the search reads for an (m, n) instance with ``nnz`` pairs:
    column-major and row-major int32 indices and int64 pointers (8 bytes a pair in all), and for a
    partial cover the float64 CSR copy that merges identical rows and its CSC (24 bytes a pair
    more, freed before the search)."""
    return int((32 if partial else 8) * int(nnz) + 16 * (int(m) + int(n) + 2))


class RowBits:
    """The rows to cover of a set-cover instance as row bitsets (the input of
    :func:`reduce_cover_bits`, and of :func:`~camplace.solver.engines.setcover.local_search.solve_cover`
    in place of a CSR pattern).

    Parameters
    ----------
    rb : (m, ceil(n / 64)) uint64
        Bit ``j`` of row ``i``: column ``j`` covers row ``i``; bits past ``n - 1`` zero.
    n : int
        Columns.
    """

    format = "rowbits"

    def __init__(self, rb: np.ndarray, n: int) -> None:
        rb = np.asarray(rb)
        if rb.dtype != np.uint64 or rb.ndim != 2 or rb.shape[1] != _words(n):
            raise ValueError(f"row bitsets must be (m, {_words(n)}) uint64, got {rb.shape} {rb.dtype}")
        self.rb = rb
        self.shape = (int(rb.shape[0]), int(n))
        self._nnz: int | None = None

    @property
    def nnz(self) -> int:
        """Pairs (set bits)."""
        if self._nnz is None:
            self._nnz = int(K.bit_counts(self.rb).sum())
        return self._nnz

    def column_rows(self, j: int) -> np.ndarray:
        """(k,) int64: the rows column ``j`` covers, ascending."""
        j = int(j)
        return np.flatnonzero((self.rb[:, j >> 6] >> np.uint64(j & 63)) & np.uint64(1)).astype(np.int64)

    @classmethod
    def from_csr(cls, pattern: sp.csr_matrix) -> "RowBits":
        """Row bitsets of a 0/1 CSR matrix (entries > 0), for tests and small instances."""
        a = sp.csr_matrix(pattern)
        m, n = a.shape
        rb = np.zeros((m, _words(n)), dtype=np.uint64)
        for i in range(m):
            cols = a.indices[a.indptr[i]:a.indptr[i + 1]][a.data[a.indptr[i]:a.indptr[i + 1]] > 0].astype(np.int64)
            np.bitwise_or.at(rb[i], cols >> 6, np.left_shift(np.uint64(1), (cols & 63).astype(np.uint64)))
        return cls(rb, n)


def _cuts(n: int, blocks: int) -> list[int]:
    """Block boundaries of ``range(n)`` (the solver's, through the bit presolve's import)."""
    from camplace.solver.problem import presolve_bits

    return presolve_bits.cuts(n, blocks)


def _transpose(rb: np.ndarray, n: int, workers: int) -> np.ndarray:
    """(n, ceil(m / 64)) uint64: the column bitsets of row bitsets ``rb`` (m, ceil(n / 64))."""
    from camplace.solver.problem.presolve_bits import _gather, _run

    m = rb.shape[0]
    out = np.zeros((n, _words(m)), dtype=np.uint64)
    sel = np.arange(m, dtype=np.int64)
    _run(lambda w0, w1: _gather(rb, sel, n, w0, w1, out), _cuts(rb.shape[1], _BLOCKS), workers)
    return out


def _compact(bits: np.ndarray, items: np.ndarray, keep_bits: np.ndarray, workers: int) -> np.ndarray:
    """The items ``items`` of ``bits`` over the bits ``keep_bits`` ((nbits,) bool), renumbered."""
    from camplace.solver.problem.presolve_bits import _run

    bit_map = np.full(bits.shape[1] * 64, -1, dtype=np.int64)
    kept = np.flatnonzero(keep_bits)
    bit_map[kept] = np.arange(kept.size, dtype=np.int64)
    items = np.asarray(items, dtype=np.int64)
    out = np.zeros((items.size, _words(kept.size)), dtype=np.uint64)
    _run(lambda lo, hi: K.compact_bits(bits, items, bit_map, lo, hi, out), _cuts(items.size, _BLOCKS), workers)
    return out


def _lists_of(bits: np.ndarray, workers: int) -> tuple[np.ndarray, np.ndarray]:
    """Compressed lists (int64 pointers, int32 indices, ascending) of bitsets."""
    from camplace._bitops import fill_lists
    from camplace.solver.problem.presolve_bits import _row_lengths, _run

    r = bits.shape[0]
    lengths = np.zeros(r, dtype=np.int64)
    blocks = _cuts(r, _BLOCKS)
    _run(lambda lo, hi: _row_lengths(bits, lo, hi, lengths), blocks, workers)
    ptr = np.zeros(r + 1, dtype=np.int64)
    np.cumsum(lengths, out=ptr[1:])
    idx = np.empty(int(ptr[-1]), dtype=np.int32)
    rows = np.arange(r, dtype=np.int64)
    _run(lambda lo, hi: fill_lists(bits, rows, ptr, lo, hi, idx), blocks, workers)
    return ptr, idx


def _union_rows(cbits: np.ndarray, cols: np.ndarray, m: int) -> np.ndarray:
    """(m,) bool: the rows some column of ``cols`` covers."""
    acc = np.zeros(cbits.shape[1], dtype=np.uint64)
    for j in np.asarray(cols, dtype=np.int64).tolist():
        acc |= cbits[j]
    return np.unpackbits(acc.view(np.uint8), bitorder="little", count=m).astype(bool)


def reduce_cover_bits(inst: RowBits, costs: np.ndarray, weights: np.ndarray | None = None,
                      need: float | None = None, workers: int | None = None):
    """:func:`~camplace.solver.engines.setcover.reduce.reduce_cover` on row bitsets: the same
    reductions in the same order, the same :class:`CoverReduction` (array for array), read from
    the bitsets.

    Parameters
    ----------
    inst : RowBits
        (m, n) instance; every row is covered by some column.
    costs : (n,) float64
        Column costs, finite and >= 0.
    weights : (m,) float64, optional
        Row weights (> 0) of a partial cover.
    need : float, optional
        Row weight a partial cover must reach; None for a full cover.
    workers : int, optional
        Threads of the transpositions and copies (the result does not depend on them).

    Returns
    -------
    CoverReduction

    Raises
    ------
    CamplaceError
        When the column bitsets and a round's copies (:func:`reduce_bits_bytes`) or the reduced
        instance's lists (:func:`lists_bytes`) would not fit the memory budget (before allocating).
    """
    from camplace.solver.engines.setcover.reduce import (
        _REDUCE_ROUNDS, CoverReduction, _bitset_ok, _lists, _merge_identical_rows)

    t0 = time.perf_counter()
    workers = thread_count(workers)
    m, n = inst.shape
    need_b, budget = reduce_bits_bytes(m, n), memory_budget_bytes()
    if need_b > budget:
        memory_fallback(OverBudget(need_b, budget, f"the set-cover reductions on bitsets ({m} x {n})"),
                        None, asked=True, then=None)
    cost = np.asarray(costs, dtype=np.float64)
    partial = need is not None
    w = np.zeros(m) if weights is None else np.asarray(weights, dtype=np.float64)
    stats: dict[str, Any] = {"rows_in": int(m), "cols_in": int(n), "nnz_in": int(inst.nnz), "rounds": 0,
                             "forced": 0, "rows_dominated": 0, "cols_dominated": 0, "cols_cheaper_cover": 0,
                             "layout": "bitsets"}
    with ctrl_c_deferred():
        rbits = inst.rb
        cbits = _transpose(rbits, n, workers)
        col_nnz = K.bit_counts(cbits)
        forced = (cost <= 0) & (col_nnz > 0)
        covered = np.zeros(m, dtype=bool)
        if forced.any():
            covered = _union_rows(cbits, np.flatnonzero(forced), m)
        left = -1.0
        if partial:
            left = float(need) - float(w[covered].sum())
        rows = np.flatnonzero(~covered)
        cols = np.flatnonzero((col_nnz > 0) & ~forced)
        equal_costs = cols.size == 0 or bool(np.all(cost[cols] == cost[cols[0]]))

        def shrink(rkeep: np.ndarray, ckeep: np.ndarray) -> None:
            nonlocal rows, cols, rbits, cbits
            rk, ck = np.flatnonzero(rkeep), np.flatnonzero(ckeep)
            rb2 = _compact(rbits, rk, ckeep, workers)
            cb2 = _compact(cbits, ck, rkeep, workers)
            rbits, cbits = rb2, cb2
            rows, cols = rows[rkeep], cols[ckeep]

        # the instance restricted to the rows and columns left (as _restrict does)
        if rows.size < m or cols.size < n:
            rk = np.zeros(m, dtype=bool)
            rk[rows] = True
            ck = np.zeros(n, dtype=bool)
            ck[cols] = True
            rbits, cbits = _compact(rbits, rows, ck, workers), _compact(cbits, cols, rk, workers)
        for rnd in range(_REDUCE_ROUNDS):
            stats["rounds"] = rnd + 1
            if rows.size == 0 or cols.size == 0 or (partial and left <= 0):
                break
            mr, nr = rows.size, cols.size
            csize = K.bit_counts(cbits)
            rlen = K.bit_counts(rbits)
            rkeep = np.ones(mr, dtype=bool)
            ckeep = csize > 0
            if not partial:
                single = rlen == 1
                if single.any():  # the only column of a row is in every cover
                    fc = np.unique(K.lowest_bits(rbits, np.flatnonzero(single)))
                    forced[cols[fc]] = True
                    stats["forced"] += int(fc.size)
                    hit = _union_rows(cbits, fc, mr)
                    ckeep[fc] = False
                    shrink(~hit, ckeep)
                    continue
                if _bitset_ok(mr, nr, stats, "row dominance"):
                    drop = K.subset_marks_bits(rbits, rlen, cbits, csize, np.zeros(mr), True)
                    stats["rows_dominated"] += int(drop.sum())
                    rkeep &= ~drop
            if _bitset_ok(nr, mr, stats, "column dominance"):
                dom = K.subset_marks_bits(cbits, csize, rbits, rlen, cost[cols], False)
            else:
                dom = np.zeros(nr, dtype=bool)
            if not equal_costs:
                dear = K.cheaper_cover_marks_bits(cbits, rbits, cost[cols], ~dom)
                stats["cols_cheaper_cover"] += int(dear.sum())
                dom |= dear
            stats["cols_dominated"] += int(dom.sum())
            ckeep &= ~dom
            if rkeep.all() and ckeep.all():
                break
            shrink(rkeep, ckeep)
        ckeep = K.bit_counts(cbits) > 0
        if not ckeep.all():
            shrink(np.ones(rows.size, dtype=bool), ckeep)
        mr, nr = rows.size, cols.size
        nnz = int(K.bit_counts(rbits).sum())
        need_l, budget = lists_bytes(mr, nr, nnz, partial), memory_budget_bytes()
        if need_l > budget:
            memory_fallback(OverBudget(need_l, budget, f"the reduced {mr} x {nr} set-cover instance's lists "
                                                       f"({nnz} pairs)"), None, asked=True, then=None)
        roww = w[rows] if partial else np.zeros(rows.size)
        if partial and mr > 1:  # identical rows merged on the reduced instance's CSR (as reduce_cover does)
            rptr, rcol = _lists_of(rbits, workers)
            del rbits, cbits
            sub = sp.csr_matrix((np.ones(rcol.size), rcol, rptr), shape=(mr, nr))
            sub, roww = _merge_identical_rows(sub, roww)
            if sub.shape[0] and np.any(np.diff(sub.indptr) == 0):
                raise CamplaceError("setcover reduction: a row lost every column (internal error)")
            cptr, crow, rptr, rcol = _lists(sub)
            shape_r = sub.shape
            del sub
        else:
            rptr, rcol = _lists_of(rbits, workers)
            if mr and np.any(np.diff(rptr) == 0):
                raise CamplaceError("setcover reduction: a row lost every column (internal error)")
            cptr, crow = _lists_of(cbits, workers)
            shape_r = (mr, nr)
            del rbits, cbits
    fc = np.flatnonzero(forced)
    nnz_after = int(crow.size)
    stats.update({"rows_after": int(shape_r[0]), "cols_after": int(shape_r[1]), "nnz_after": nnz_after,
                  "forced_cols": int(fc.size), "time_s": time.perf_counter() - t0})
    log.info("setcover reduction (bitsets): %dx%d (%d nnz) -> %dx%d (%d nnz), %d forced, in %.2f s", m, n,
             stats["nnz_in"], shape_r[0], shape_r[1], nnz_after, fc.size, stats["time_s"])
    return CoverReduction(cptr=cptr, crow=crow, rptr=rptr, rcol=rcol, cost=cost[cols].copy(),
                          roww=np.asarray(roww, dtype=np.float64), need=max(left, 0.0) if partial else -1.0,
                          columns=cols.astype(np.int64), forced=fc, forced_cost=float(cost[fc].sum()),
                          shape_in=(int(m), int(n)), stats=stats)
