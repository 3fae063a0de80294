"""Exact, optimum-preserving reductions of a max-coverage instance.

Three reductions, all on the 0/1 pattern of the matrix (any value > 0 counts as "observes"):

1. rows with zero weight or no observer are dropped (they can never add weight);
2. dominated columns are dropped: column ``a`` is dominated when its row set is a subset of the row
   set of another column ``b`` (for identical columns the lowest index is kept). Replacing a
   dominated column by its dominator never lowers the covered weight, so some optimal ``k``-subset
   uses kept columns only -- provided at least ``k`` columns are kept (if not, the best dropped
   columns are restored). Subset tests run on column bitsets (compiled): the candidate
   dominators of a column are the columns observing its rarest row, each tested word by word.
   When the bitsets would exceed :data:`BITSET_BYTES`, exact integer counts ``|a & b|`` from
   ``A^T A`` are used instead (a BLAS product of 0/1 data in float32 over row chunks of fewer
   than 2**24 rows, so every partial sum is an exactly representable integer, or a sparse
   integer product);
3. rows with identical patterns (over the kept columns) are merged, summing their weights and
   recording how many original rows each merged row stands for (64-bit hashes of the row
   patterns, confirmed by exact comparison).

Everything runs in compiled kernels on the CSR arrays (no copy of a canonical CSR input), so a
10,000 x 50,000 matrix with 2e8 nonzeros presolves in a few seconds.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.solver._support import bitkernels as _bk
from camplace.solver._support.deadline import Deadline
from camplace.solver._support import parkernels as _par
from camplace._blocks import cuts, run_blocks, threads_for
from camplace.solver.problem.checks import kernel_data

__all__ = ["Presolved", "presolve", "as_pattern", "canonical_csr", "check_weights"]

log = logging.getLogger(__name__)

_ROW_CHUNK = 1 << 15  # rows per dense float32 GEMM chunk (far below 2**24: integer-exact)
_DENSE_BYTES = 256 * 1024 * 1024  # max bytes of one dense float32 working block
_SPARSE_SPEEDUP = 40.0  # how much faster BLAS is per multiply-add than a sparse product
BITSET_BYTES = 1 << 30  # column dominance on bitsets up to this many bytes of bitsets (else a Gram product)
#: With a deadline, column dominance stops (keeping the columns not yet tested: still exact) after
#: this share of the time left when presolve starts, so that the search keeps the rest.
DOMINANCE_SHARE = 0.2
_DOMINANCE_BLOCK = 1024  # columns per compiled dominance call between deadline checks


def as_pattern(matrix: Any) -> sp.csr_matrix:
    """0/1 pattern of a visibility matrix.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Values > 0 mean "the candidate observes the point".

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix of float64
        1.0 where ``matrix > 0``, with sorted indices and no explicit zeros.
    """
    if sp.issparse(matrix):
        a = sp.csr_matrix(matrix, copy=True)
    else:
        arr = np.asarray(matrix)
        if arr.ndim != 2:
            raise CamplaceError(f"visibility matrix must be 2-D, got shape {arr.shape}")
        a = sp.csr_matrix(arr)
    if a.ndim != 2:
        raise CamplaceError(f"visibility matrix must be 2-D, got shape {a.shape}")
    data = np.asarray(a.data)
    if data.size and not np.all(np.isfinite(data.astype(np.float64, copy=False))):
        raise CamplaceError("visibility matrix contains NaN or infinite values")
    a.data = (data > 0).astype(np.float64)
    a.eliminate_zeros()
    a.sum_duplicates()
    a.sort_indices()
    return a


def check_weights(weights: Any, m: int) -> np.ndarray:
    """Validate point weights.

    Parameters
    ----------
    weights : (m,) array_like
        Non-negative finite weights.
    m : int
        Number of matrix rows.

    Returns
    -------
    (m,) float64
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or w.shape[0] != m:
        raise CamplaceError(f"weights must have shape ({m},) to match the matrix rows, got {w.shape}")
    if not np.all(np.isfinite(w)):
        raise CamplaceError("weights contain NaN or infinite values")
    if np.any(w < 0):
        raise CamplaceError(f"weights must be >= 0, got min {float(w.min())!r}")
    return w


@dataclass(frozen=True, eq=False)
class Presolved:
    """A reduced instance and the maps back to the original one.

    The reduced matrix is built on first use, from the kept rows of the source matrix, as a CSR
    pattern (:attr:`matrix`, for the OR-Tools engines) or as column bitsets (:attr:`bits`, for
    the exact engine); presolving a large visibility matrix never copies it.

    Attributes
    ----------
    weights : (m',) float64
        Summed weight of the original rows merged into each reduced row.
    counts : (m',) int64
        Number of original rows merged into each reduced row.
    columns : (n',) int64
        Original index of each kept column, ascending.
    row_groups : (m,) int64
        Reduced row of each original row, -1 if the row was dropped.
    k : int
        Number of columns to choose.
    shape_in : tuple of int
        ``(m, n)`` of the original matrix.
    weight_unit : float or None
        If every positive original weight equals ``weight_unit``, then
        ``weights == counts * weight_unit`` and integer counts can be used as exact weights.
    stats : dict
        JSON-serialisable sizes and timings.
    source : tuple
        ``(csr, rows, col_map)``: the canonical source matrix, the source row of each reduced
        row and the reduced index of each source column (-1: dropped).
    """

    weights: np.ndarray
    counts: np.ndarray
    columns: np.ndarray
    row_groups: np.ndarray
    k: int
    shape_in: tuple[int, int]
    weight_unit: float | None
    source: tuple[sp.csr_matrix, np.ndarray, np.ndarray] = field(repr=False)
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        """``(m', n')`` of the reduced matrix."""
        return (int(self.weights.shape[0]), int(self.columns.shape[0]))

    @functools.cached_property
    def matrix(self) -> sp.csr_matrix:
        """(m', n') scipy.sparse.csr_matrix of float64: 0/1 pattern of the reduced instance."""
        a, rows, col_map = self.source
        with ctrl_c_deferred():
            ptr, idx = _bk.extract_rows(a.indptr, a.indices, kernel_data(a), rows, col_map)
        return sp.csr_matrix((np.ones(idx.size), idx, ptr), shape=self.shape)

    @functools.cached_property
    def bits(self) -> np.ndarray:
        """(n', ceil(m' / 64)) uint64: column bitsets of the reduced instance (bit i = reduced row i)."""
        a, rows, col_map = self.source
        with ctrl_c_deferred():
            return _par.build_bits(a.indptr, a.indices, kernel_data(a), rows, col_map, self.shape[1])

    def original_columns(self, selected: Sequence[int]) -> tuple[int, ...]:
        """Map reduced column indices to sorted original column indices.

        Parameters
        ----------
        selected : sequence of int
            0-based indices into the reduced columns.

        Returns
        -------
        tuple of int
        """
        return tuple(sorted(int(self.columns[int(j)]) for j in selected))

    def reduced_columns(self, selected: Sequence[int]) -> tuple[int, ...] | None:
        """Map original column indices to reduced ones, or None if one was dropped."""
        pos = {int(c): i for i, c in enumerate(self.columns)}
        out = [pos.get(int(j)) for j in selected]
        if any(o is None for o in out):
            return None
        return tuple(sorted(int(o) for o in out if o is not None))


def _gram_column_blocks(b: sp.csr_matrix, block: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Exact integer Gram blocks ``(B^T B)[cols, :]`` of a 0/1 matrix.

    Parameters
    ----------
    b : (m, n) scipy.sparse.csr_matrix
        0/1 matrix.
    block : int
        Columns per yielded block.

    Yields
    ------
    cols : (c,) int64
        Column indices of the block.
    gram : (c, n) int64
        ``|col_a & col_j|`` for ``a`` in ``cols`` and every column ``j``.
    """
    m, n = b.shape
    row_nnz = np.diff(b.indptr).astype(np.float64)
    sparse_cost = float(np.sum(row_nnz * row_nnz))
    dense_cost = float(n) * float(n) * float(m) / _SPARSE_SPEEDUP
    if sparse_cost <= dense_cost:
        bc = b.tocsc().astype(np.int64)
        bt = b.T.tocsr().astype(np.int64)
        for c0 in range(0, n, block):
            cols = np.arange(c0, min(n, c0 + block), dtype=np.int64)
            g = (bt[cols] @ bc).toarray().astype(np.int64)
            yield cols, g
        return
    rows_per_chunk = int(max(1, min(_ROW_CHUNK, _DENSE_BYTES // (4 * max(n, 1)))))
    single = m <= rows_per_chunk
    dense_all = b.toarray().astype(np.float32) if single else None
    for c0 in range(0, n, block):
        cols = np.arange(c0, min(n, c0 + block), dtype=np.int64)
        if dense_all is not None:
            g = (dense_all[:, cols].T @ dense_all).astype(np.int64)
        else:
            g = np.zeros((cols.size, n), dtype=np.int64)
            for r0 in range(0, m, rows_per_chunk):
                d = b[r0 : r0 + rows_per_chunk].toarray().astype(np.float32)
                g += (d[:, cols].T @ d).astype(np.int64)
        yield cols, g


def _dominated_columns(b: sp.csr_matrix, stop: Deadline | None = None) -> np.ndarray:
    """Boolean mask of dominated columns of a 0/1 matrix.

    Column ``a`` is dominated if some other column ``j`` contains its row set and either has more
    rows or is identical with a lower index. Every dominated column is then contained in a
    non-dominated one (follow the dominance chain to a maximal element).

    Parameters
    ----------
    b : (m, n) scipy.sparse.csr_matrix
        0/1 matrix.
    stop : Deadline, optional
        Stop testing (the columns not yet tested are kept) once it has expired.

    Returns
    -------
    (n,) bool
    """
    m, n = b.shape
    size = np.asarray(b.sum(axis=0)).ravel().astype(np.int64)
    out = np.zeros(n, dtype=bool)
    idx = np.arange(n, dtype=np.int64)
    block = int(max(1, min(n, (64 * 1024 * 1024) // (8 * max(n, 1)))))
    for cols, g in _gram_column_blocks(b, block):
        if stop is not None and stop.expired():
            break
        da = size[cols][:, None]
        subset = g == da  # |a & j| == |a|  <=>  a is a subset of j
        stronger = (size[None, :] > da) | ((size[None, :] == da) & (idx[None, :] < cols[:, None]))
        out[cols] = np.any(subset & stronger, axis=1)
    return out


def canonical_csr(matrix: Any) -> sp.csr_matrix:
    """The matrix as CSR with sorted, unique indices and finite values, copied only when needed.

    Unlike :func:`as_pattern` the values are kept (kernels test ``value > 0``), which avoids
    copying a large visibility matrix.
    """
    if sp.issparse(matrix):
        a = matrix.tocsr()
        if a.ndim != 2:
            raise CamplaceError(f"visibility matrix must be 2-D, got shape {a.shape}")
        if not a.has_canonical_format:
            return as_pattern(a)
        data = np.asarray(a.data)
        if data.dtype.kind not in "biuf":
            return as_pattern(a)
        if data.dtype.kind == "f" and data.size and not (np.isfinite(data.min()) and np.isfinite(data.max())):
            raise CamplaceError("visibility matrix contains NaN or infinite values")  # min/max propagate NaN
        return a
    return as_pattern(matrix)


def dominated_bitsets(a: sp.csr_matrix, rows: np.ndarray, row_nnz: np.ndarray,
                      stop: Deadline | None = None) -> np.ndarray:
    """Dominated columns of the pattern of ``a[rows]`` (same rule as :func:`_dominated_columns`).

    Each column becomes a bitset of ``rows``; the candidate dominators of a column are the
    columns observing its rarest row, each tested word by word (compiled; about
    ``n * rows / 8`` bytes).

    Parameters
    ----------
    a : (m, n) scipy.sparse.csr_matrix
        Canonical CSR (values > 0 mean "observes").
    rows : (r,) int64
        Rows to consider.
    row_nnz : (m,) int64
        Number of values > 0 of every row.
    stop : Deadline, optional
        Test the columns in blocks and stop once it has expired: the columns not yet tested are
        kept (every dropped column is still inside a kept one, so the optimum is unchanged).

    Returns
    -------
    (n,) bool
    """
    n = a.shape[1]
    with ctrl_c_deferred():
        data = kernel_data(a)
        bits = _par.build_bits(a.indptr, a.indices, data, rows, np.arange(n, dtype=np.int64), n)
        size = _par.column_sizes(bits)
        if stop is None or stop.limit is None:
            return _par.dominated_columns(bits, size, row_nnz, a.indptr, a.indices, data, rows)
        # in ranges of columns, each on the thread pool, stopping between ranges at the deadline:
        # columns never tested stay kept, which is still valid
        out = np.zeros(n, dtype=np.bool_)
        _bk.dominated_empty(size, out)
        for a0 in range(0, n, _DOMINANCE_BLOCK):
            if stop.expired():
                break
            a1 = min(n, a0 + _DOMINANCE_BLOCK)
            run_blocks(lambda lo, hi: _bk.dominated_block(lo, hi, bits, size, row_nnz, a.indptr, a.indices, data, rows, out),
                       [a0 + c for c in cuts(a1 - a0)], threads_for(bits.shape[1] * (a1 - a0)))
        return out


def restore_columns(dominated: np.ndarray, k: int, cover: Callable[[], np.ndarray]) -> tuple[np.ndarray, int]:
    """The columns kept: all but the dominated ones, and, when fewer than ``k`` are left, the
    dominated ones observing the most weight (``cover()``: (n,) float64, computed only then; ties
    to the lower index) until there are ``k``.

    Returns
    -------
    keep : (n,) bool
    restored : int
        Dominated columns kept to reach ``k``.
    """
    keep = ~dominated
    need = k - int(keep.sum())
    if need <= 0:
        return keep, 0
    cov = cover()
    cand = np.flatnonzero(dominated)
    keep[cand[np.lexsort((cand, -cov[cand]))][:need]] = True
    return keep, need


def presolve(matrix: Any, weights: Any, k: int, *, dominance: bool = True,
             deadline: Deadline | None = None) -> Presolved:
    """Reduce a max-coverage instance without changing its optimum value.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Visibility; values > 0 mean "observes".
    weights : (m,) array_like of float64
        Non-negative point weights.
    k : int
        Number of columns that will be chosen (at least ``k`` columns are always kept).
    dominance : bool
        Drop dominated columns (default True).
    deadline : Deadline, optional
        The solve's deadline: the dominance tests stop after :data:`DOMINANCE_SHARE` of the time
        left (the columns not yet tested are kept, which keeps the optimum; ``stats``
        ``dominance_stopped``).

    Returns
    -------
    Presolved
        The reduced instance; ``original_columns`` maps a reduced selection back.
    """
    t0 = time.perf_counter()
    a = canonical_csr(matrix)
    m, n = a.shape
    w = check_weights(weights, m)
    if k < 1 or k > n:
        raise CamplaceError(f"k must be between 1 and the number of candidates ({n}), got {k}")

    with ctrl_c_deferred():
        live, row_nnz = _par.live_rows(a.indptr, a.indices, kernel_data(a), w)
    live_rows = np.flatnonzero(live).astype(np.int64)
    stats: dict[str, Any] = {
        "rows_in": int(m),
        "cols_in": int(n),
        "nnz_in": int(a.nnz),
        "rows_live": int(live_rows.size),
        "time_live_s": time.perf_counter() - t0,
    }

    # Column dominance (weights are irrelevant once dead rows are gone).
    t1 = time.perf_counter()
    stop = None if deadline is None or deadline.limit is None else deadline.share(DOMINANCE_SHARE)
    if dominance and n > k and live_rows.size > 0 and not (stop is not None and stop.expired()):
        if float(n) * live_rows.size / 8.0 <= BITSET_BYTES:
            dominated = dominated_bitsets(a, live_rows, row_nnz, stop)
            stats["dominance_method"] = "bitsets"
        else:
            dominated = _dominated_columns(as_pattern(a[live_rows]), stop)
            stats["dominance_method"] = "gram"
        if stop is not None and stop.expired():
            stats["dominance_stopped"] = True
    else:
        dominated = np.zeros(n, dtype=bool)
    keep, restored = restore_columns(dominated, k, lambda: np.asarray(as_pattern(a[live_rows]).T @ w[live_rows]).ravel()
                                     if live_rows.size else np.zeros(n))
    columns = np.flatnonzero(keep).astype(np.int64)
    stats["time_dominance_s"] = time.perf_counter() - t1
    stats["cols_dominated"] = int(dominated.sum())
    stats["cols_restored"] = int(restored)

    # Restrict to kept columns, drop rows no kept column observes, merge identical rows.
    col_map = np.full(n, -1, dtype=np.int64)
    col_map[columns] = np.arange(columns.size, dtype=np.int64)
    salt = np.random.default_rng(0x5EED).integers(0, np.iinfo(np.int64).max, size=max(1, columns.size), dtype=np.int64)
    with ctrl_c_deferred():
        data = kernel_data(a)
        h, has = _par.row_hashes(a.indptr, a.indices, data, live_rows, col_map, salt.astype(np.uint64))
        orig_rows = live_rows[has]
        groups, n_groups = _par.group_rows(a.indptr, a.indices, data, orig_rows, col_map, h[has])
    stats["time_merge_s"] = time.perf_counter() - t1 - stats["time_dominance_s"]
    first = np.full(n_groups, -1, dtype=np.int64)
    first[groups[::-1]] = np.arange(groups.size - 1, -1, -1, dtype=np.int64)
    wsum = np.bincount(groups, weights=w[orig_rows], minlength=n_groups).astype(np.float64)
    counts = np.bincount(groups, minlength=n_groups).astype(np.int64)
    row_groups = np.full(m, -1, dtype=np.int64)
    row_groups[orig_rows] = groups

    pos = w[w > 0]
    unit = float(pos[0]) if pos.size and np.all(pos == pos[0]) else None

    stats.update(
        {
            "rows_after": int(n_groups),
            "cols_after": int(columns.size),
            "time_s": time.perf_counter() - t0,
        }
    )
    log.info(
        "presolve: rows %d -> %d, cols %d -> %d (%d dominated, %d restored) in %.3f s",
        m,
        n_groups,
        n,
        columns.size,
        stats["cols_dominated"],
        restored,
        stats["time_s"],
    )
    return Presolved(
        weights=wsum,
        counts=counts,
        columns=columns,
        row_groups=row_groups,
        k=int(k),
        shape_in=(int(m), int(n)),
        weight_unit=unit,
        source=(a, orig_rows[first], col_map),
        stats=stats,
    )
