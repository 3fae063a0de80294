"""The set-cover reductions on lists and CSR (:func:`reduce_cover`) and the reduced instance they
give (:class:`CoverReduction`), which the local search, the Lagrangian bound and the models read
(:mod:`camplace.solver.engines.setcover.local_search`); the same reductions on row bitsets are
:mod:`camplace.solver.engines.setcover.reduce_bits`."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.solver._support.memory import memory_budget_bytes
from camplace.solver.engines.setcover import _kernels as K

__all__ = ["CoverReduction", "reduce_cover", "cover_bytes", "BITSET_MAX_BYTES"]

log = logging.getLogger(__name__)

BITSET_MAX_BYTES = 1 << 30  # a subset reduction is skipped when its bitsets would need more
_REDUCE_ROUNDS = 20




@dataclass(frozen=True, eq=False)
class CoverReduction:
    """A reduced set-cover instance and the way back to the input.

    Attributes
    ----------
    cptr, crow : (n' + 1,) int64, (nnz,) int32
        Rows of every reduced column (column-major lists).
    rptr, rcol : (m' + 1,) int64, (nnz,) int32
        Columns of every reduced row.
    cost : (n',) float64
        Column costs (all > 0).
    roww : (m',) float64
        Row weights (partial cover; zeros for a full cover).
    need : float
        Row weight the cover must reach (partial), or -1.0 for "every row".
    columns : (n',) int64
        Input column of every reduced column.
    forced : (f,) int64
        Input columns every returned cover contains (cost 0, or the only cover of a row).
    forced_cost : float
        Their total cost.
    shape_in : tuple of int
        ``(m, n)`` of the input.
    stats : dict
        Sizes and timings.
    """

    cptr: np.ndarray
    crow: np.ndarray
    rptr: np.ndarray
    rcol: np.ndarray
    cost: np.ndarray
    roww: np.ndarray
    need: float
    columns: np.ndarray
    forced: np.ndarray
    forced_cost: float
    shape_in: tuple[int, int]
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        """``(m', n')``."""
        return (int(self.rptr.shape[0] - 1), int(self.cptr.shape[0] - 1))

    @property
    def nnz(self) -> int:
        """Nonzeros of the reduced matrix."""
        return int(self.crow.shape[0])

    @property
    def partial(self) -> bool:
        """True for a partial cover."""
        return self.need >= 0

    def csr(self) -> sp.csr_matrix:
        """(m', n') 0/1 CSR matrix of the reduced instance."""
        return sp.csr_matrix((np.ones(self.rcol.size), self.rcol, self.rptr), shape=self.shape)

    def input_columns(self, selected: Any) -> tuple[int, ...]:
        """Input columns of a reduced cover, with the forced ones, sorted."""
        cols = {int(self.columns[int(j)]) for j in selected} | {int(j) for j in self.forced}
        return tuple(sorted(cols))


def cover_bytes(m: int, n: int, nnz: int) -> int:
    """Working memory of the reductions and the local search for an (m, n) matrix with ``nnz``
    nonzeros: during the first reduction round a row-major and a column-major copy (12 bytes a
    nonzero each), their int32 indices and the next, smaller, copy (about 44 bytes a nonzero in
    all), plus per-row and per-column state and a fixed 16 MiB for temporaries (the bitsets of
    the subset tests are checked separately, :data:`BITSET_MAX_BYTES`)."""
    return 48 * int(nnz) + 128 * (int(m) + int(n)) + (16 << 20)


def _lists(a: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Row and column lists (int64 pointers, int32 indices) of a canonical 0/1 CSR matrix."""
    c = a.tocsc()
    c.sort_indices()
    return (c.indptr.astype(np.int64), c.indices.astype(np.int32), a.indptr.astype(np.int64),
            a.indices.astype(np.int32))


def _restrict(a: sp.csr_matrix, rows: np.ndarray, cols: np.ndarray, n: int) -> sp.csr_matrix:
    """0/1 CSR of ``a[rows][:, cols]`` (entries > 0 only; column order kept), compiled."""
    from camplace.solver._support import bitkernels as _bk

    col_map = np.full(n, -1, dtype=np.int64)
    col_map[cols] = np.arange(cols.size, dtype=np.int64)
    data = a.data if a.data.dtype.kind != "b" else a.data.view(np.uint8)
    ptr, idx = _bk.extract_rows(a.indptr, a.indices, data, rows.astype(np.int64), col_map)
    return sp.csr_matrix((np.ones(idx.size), idx, ptr), shape=(rows.size, cols.size))


def _shrink(sub: sp.csr_matrix, rows: np.ndarray, cols: np.ndarray, rkeep: np.ndarray,
            ckeep: np.ndarray) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """Keep the rows ``rkeep`` and columns ``ckeep`` of the current matrix and of its index maps."""
    out = _restrict(sub, np.flatnonzero(rkeep), np.flatnonzero(ckeep), sub.shape[1])
    return rows[rkeep], cols[ckeep], out


def _bitset_ok(items: int, bits: int, stats: dict[str, Any], what: str) -> bool:
    need = items * ((bits + 63) // 64) * 8
    if need > min(BITSET_MAX_BYTES, memory_budget_bytes() // 2):
        stats.setdefault("skipped", []).append(f"{what}: bitsets would need {need / 2**20:.0f} MiB")
        return False
    return True


def reduce_cover(pattern: sp.csr_matrix, costs: np.ndarray, weights: np.ndarray | None = None,
                 need: float | None = None) -> CoverReduction:
    """Reduce a set-cover instance without losing its optimum (see the module docstring).

    Parameters
    ----------
    pattern : (m, n) scipy.sparse.csr_matrix
        1 where column ``j`` covers row ``i`` (canonical: sorted, no duplicates, no zeros). Every
        row must be covered by some column.
    costs : (n,) float64
        Column costs, finite and >= 0.
    weights : (m,) float64, optional
        Row weights (> 0) of a partial cover.
    need : float, optional
        Row weight a partial cover must reach; None for a full cover.

    Returns
    -------
    CoverReduction
    """
    t0 = time.perf_counter()
    a = sp.csr_matrix(pattern)
    m, n = a.shape
    cost = np.asarray(costs, dtype=np.float64)
    partial = need is not None
    w = np.zeros(m) if weights is None else np.asarray(weights, dtype=np.float64)
    stats: dict[str, Any] = {"rows_in": int(m), "cols_in": int(n), "nnz_in": int(a.nnz), "rounds": 0,
                             "forced": 0, "rows_dominated": 0, "cols_dominated": 0, "cols_cheaper_cover": 0}
    col_nnz = np.bincount(a.indices[a.data > 0], minlength=n)
    forced = (cost <= 0) & (col_nnz > 0)
    covered = np.zeros(m, dtype=bool)
    if forced.any():
        covered = np.diff(a[:, np.flatnonzero(forced)].tocsr().indptr) > 0
    left = -1.0
    if partial:
        left = float(need) - float(w[covered].sum())
    rows = np.flatnonzero(~covered)
    cols = np.flatnonzero((col_nnz > 0) & ~forced)
    equal_costs = cols.size == 0 or bool(np.all(cost[cols] == cost[cols[0]]))
    with ctrl_c_deferred():
        sub = _restrict(a, rows, cols, n)
        for rnd in range(_REDUCE_ROUNDS):
            stats["rounds"] = rnd + 1
            if rows.size == 0 or cols.size == 0 or (partial and left <= 0):
                break
            mr, nr = sub.shape
            cptr, crow, rptr, rcol = _lists(sub)
            csize = np.diff(cptr).astype(np.int64)
            rkeep = np.ones(mr, dtype=bool)
            ckeep = csize > 0
            if not partial:
                rlen = np.diff(rptr)
                single = rlen == 1
                if single.any():  # the only column of a row is in every cover
                    fc = np.unique(rcol[rptr[:-1][single]])
                    forced[cols[fc]] = True
                    stats["forced"] += int(fc.size)
                    hit = np.zeros(mr, dtype=bool)
                    for j in fc.tolist():
                        hit[crow[cptr[j] : cptr[j + 1]]] = True
                    ckeep[fc] = False
                    rows, cols, sub = _shrink(sub, rows, cols, ~hit, ckeep)
                    continue
                if _bitset_ok(mr, nr, stats, "row dominance"):
                    rbits = K.bitsets(rptr, rcol, mr, nr)
                    drop = K.subset_marks(rbits, rlen.astype(np.int64), rptr, rcol, cptr, crow, np.zeros(mr), True)
                    del rbits
                    stats["rows_dominated"] += int(drop.sum())
                    rkeep &= ~drop
            if _bitset_ok(nr, mr, stats, "column dominance"):
                cbits = K.bitsets(cptr, crow, nr, mr)
                dom = K.subset_marks(cbits, csize, cptr, crow, rptr, rcol, cost[cols], False)
                del cbits
            else:
                dom = np.zeros(nr, dtype=bool)
            if not equal_costs:
                dear = K.cheaper_cover_marks(cptr, crow, rptr, rcol, cost[cols], ~dom)
                stats["cols_cheaper_cover"] += int(dear.sum())
                dom |= dear
            stats["cols_dominated"] += int(dom.sum())
            ckeep &= ~dom
            if rkeep.all() and ckeep.all():
                break
            rows, cols, sub = _shrink(sub, rows, cols, rkeep, ckeep)
        ckeep = np.diff(sub.tocsc().indptr) > 0
        if not ckeep.all():
            rows, cols, sub = _shrink(sub, rows, cols, np.ones(sub.shape[0], dtype=bool), ckeep)
        roww = w[rows] if partial else np.zeros(rows.size)
        if partial and sub.shape[0] > 1:
            sub, roww = _merge_identical_rows(sub, roww)
        if sub.shape[0] and np.any(np.diff(sub.indptr) == 0):
            raise CamplaceError("setcover reduction: a row lost every column (internal error)")
        cptr, crow, rptr, rcol = _lists(sub)
    fc = np.flatnonzero(forced)
    stats.update({"rows_after": int(sub.shape[0]), "cols_after": int(sub.shape[1]), "nnz_after": int(sub.nnz),
                  "forced_cols": int(fc.size), "time_s": time.perf_counter() - t0})
    log.info("setcover reduction: %dx%d (%d nnz) -> %dx%d (%d nnz), %d forced, in %.2f s", m, n, a.nnz,
             sub.shape[0], sub.shape[1], sub.nnz, fc.size, stats["time_s"])
    return CoverReduction(cptr=cptr, crow=crow, rptr=rptr, rcol=rcol, cost=cost[cols].copy(),
                          roww=roww.astype(np.float64), need=max(left, 0.0) if partial else -1.0,
                          columns=cols.astype(np.int64), forced=fc, forced_cost=float(cost[fc].sum()),
                          shape_in=(int(m), int(n)), stats=stats)


def _merge_identical_rows(sub: sp.csr_matrix, roww: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Merge rows with the same columns, summing their weights (first occurrence kept)."""
    from camplace.solver._support import bitkernels as _bk

    mr, nr = sub.shape
    salt = np.random.default_rng(0x5EED).integers(0, np.iinfo(np.int64).max, size=max(1, nr), dtype=np.int64)
    ones = np.ones(sub.nnz)
    rows = np.arange(mr, dtype=np.int64)
    ident = np.arange(nr, dtype=np.int64)
    h, has = _bk.row_hashes(sub.indptr, sub.indices, ones, rows, ident, salt.astype(np.uint64))
    groups, n_groups = _bk.group_rows(sub.indptr, sub.indices, ones, rows[has], ident, h[has])
    if n_groups == mr:
        return sub, roww
    first = np.full(n_groups, -1, dtype=np.int64)
    first[groups[::-1]] = np.arange(groups.size - 1, -1, -1, dtype=np.int64)
    wsum = np.bincount(groups, weights=roww[has], minlength=n_groups)
    return sub[rows[has][first]].tocsr(), wsum
