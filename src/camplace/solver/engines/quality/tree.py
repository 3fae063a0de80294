"""Exact engine for the ``quality`` mode on large instances: a tree of per-cluster best qualities.

``value(S) = sum_i w_i max_{j in S} Q_ij`` for a set ``S`` of ``k`` columns.

* **Quantised bound values.** Every entry becomes ``q8 = ceil(255 Q_ij / qmax)`` (uint8, at least
  1 for an observation), so ``qmax * q8 / 255 >= Q_ij``: bounds computed from them are upper
  bounds, and scores of actual camera sets are always taken from the exact values.
* **Tree.** Columns are ordered by recursive bisection on the Hamming distance of their patterns
  (similar cameras adjacent) and form the implicit binary tree of
  :func:`camplace.solver._support.bitkernels.tree_shape`; node ``v`` stores ``T[v, i]``, the largest ``q8``
  of its columns in row ``i`` (``(2 n - 1) x m'`` bytes).
* **Bound.** A tuple of ``k`` nodes (non-decreasing; a node may repeat) stands for every k-subset
  with one column in each node, and ``sum_i w_i qmax / 255 * max_t T[v_t, i]`` bounds all of them.
  A tuple of leaves is one camera set and is scored exactly (a merge of its sparse columns).
* **Search.** Depth-first over chunks of tuples, each chunk expanded in parallel (numba
  ``prange``): the largest node of a tuple is split into its two children (every non-decreasing
  mix for a repeated node, a leaf never twice, as in
  :func:`camplace.solver._support.bitkernels.tuple_search`), children whose bound cannot beat the
  incumbent are dropped, and the survivors are pushed as chunks in increasing bound order, so the
  most promising chunk is expanded next. Open tuples stay below about ``k^2 log2(n)`` chunks.
* **Incumbent.** Greedy plus 1-swap local search from the best single columns (exact values).
* **Time limit.** Checked between chunks; on expiry the incumbent is returned with status
  ``feasible`` and the bound ``max(incumbent, bounds of the tuples not yet expanded)``. The same
  happens if more than :data:`FRONTIER_MAX` tuples are open (a guard; depth-first keeps far fewer).
* **Exactness.** Pruning keeps a margin of ``1e-9 * total weight`` (floating-point sums). With
  equal row weights a bound is an integer sum of bytes, scaled once.
* **Quantised columns** (:func:`solve_quality_tree_dense`, issue 32): when the matrix already is
  bytes (``values`` (n, m) uint8, a graded run's ``ByteMatrix``), those columns are the leaves as
  they are and only the inner nodes' table is made ((n - 1) x m bytes): no CSC copy, no rounding
  of its own, a tuple of leaves' bound is its value (exact for the quantised values), and the
  incumbent heuristics read the bytes. The search is the same (:func:`_search`).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp
from numba import prange

from camplace._signals import ctrl_c_deferred
from camplace.solver._support import bitkernels as K
from camplace.solver._support.deadline import Deadline, as_deadline, stopwatch
from camplace.solver._support.frontier import best_leaf, push_chunks
from camplace.solver._support.greedy import greedy_swap
from camplace.solver.result import EngineOutcome

__all__ = ["solve_quality_tree", "solve_quality_tree_dense", "quality_tree_bytes", "quality_tree_bytes_dense",
           "dense_table_group", "FRONTIER_MAX", "GROUP_MAX"]

log = logging.getLogger(__name__)

FRONTIER_MAX = 5_000_000  # open tuples at most (about 40 bytes each for k = 3)
_CHUNK = 8192  # tuples expanded per compiled call; the deadline is checked between calls
_MARGIN = 1e-9
_STARTS = 1  # greedy starts: the best single columns (the search soon finds better sets)
_SWAP_ROUNDS = 50
_PJIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False, "parallel": True}
_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}


def quality_tree_bytes(m: int, n: int, nnz: int) -> int:
    """Approximate peak working memory for ``m`` rows, ``n`` columns and ``nnz`` entries: the node
    table ((2 n - 1) x m bytes), the pattern bitsets and a CSC copy of the matrix."""
    return (2 * max(n, 1) - 1) * m + n * ((m + 63) // 64) * 8 + 12 * nnz + 8 * FRONTIER_MAX


@numba.njit(**_PJIT)
def _gains(indptr, indices, data, w, cur):  # pragma: no cover - compiled
    """(n,) float64: ``sum_i w_i max(0, Q_ij - cur_i)`` for every column j (CSC arrays)."""
    n = indptr.shape[0] - 1
    out = np.zeros(n)
    for j in prange(n):
        s = 0.0
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            d = data[p] - cur[i]
            if d > 0:
                s += w[i] * d
        out[j] = s
    return out


@numba.njit(**_JIT)
def _exact(indptr, indices, data, w, cols):  # pragma: no cover - compiled
    """``sum_i w_i max_{j in cols} Q_ij`` by merging the (row-sorted) CSC columns."""
    k = cols.shape[0]
    pos = np.empty(k, dtype=np.int64)
    end = np.empty(k, dtype=np.int64)
    for t in range(k):
        pos[t] = indptr[cols[t]]
        end[t] = indptr[cols[t] + 1]
    s = 0.0
    big = np.iinfo(np.int64).max
    while True:
        r = big
        for t in range(k):
            if pos[t] < end[t] and indices[pos[t]] < r:
                r = indices[pos[t]]
        if r == big:
            return s
        mx = 0.0
        for t in range(k):
            if pos[t] < end[t] and indices[pos[t]] == r:
                if data[pos[t]] > mx:
                    mx = data[pos[t]]
                pos[t] += 1
        s += w[r] * mx


@numba.njit(**_PJIT)
def _node_table(indptr, indices, data, rowmap, m, order, lo, left, right, scale):  # pragma: no cover - compiled
    """(N, m) uint8: per node and compact row the largest quantised value of its columns."""
    n_nodes = lo.shape[0]
    t = np.zeros((n_nodes, m), dtype=np.uint8)
    for v in prange(n_nodes):
        if left[v] < 0:
            j = order[lo[v]]
            for p in range(indptr[j], indptr[j + 1]):
                r = rowmap[indices[p]]
                if r >= 0 and data[p] > 0:
                    x = math.ceil(data[p] * scale)
                    t[v, r] = np.uint8(min(255.0, max(1.0, x)))
    block = 4096
    for b in prange((m + block - 1) // block):
        i0 = b * block
        i1 = min(m, i0 + block)
        for v in range(n_nodes - 1, -1, -1):  # children are numbered after their parent
            if left[v] >= 0:
                a = left[v]
                c = right[v]
                for i in range(i0, i1):
                    t[v, i] = max(t[a, i], t[c, i])
    return t


@numba.njit(**_JIT)
def _bound(t, nodes, wq):  # pragma: no cover - compiled
    """``sum_i wq_i max_t T[nodes_t, i]`` (the loops for k <= 4 are written out to vectorise)."""
    k = nodes.shape[0]
    m = t.shape[1]
    s = 0.0
    ra = t[nodes[0]]
    if k == 1:
        for i in range(m):
            s += wq[i] * ra[i]
        return s
    rb = t[nodes[1]]
    if k == 2:
        for i in range(m):
            s += wq[i] * max(ra[i], rb[i])
        return s
    rc = t[nodes[2]]
    if k == 3:
        for i in range(m):
            s += wq[i] * max(ra[i], max(rb[i], rc[i]))
        return s
    rd = t[nodes[3]]
    if k == 4:
        for i in range(m):
            s += wq[i] * max(max(ra[i], rd[i]), max(rb[i], rc[i]))
        return s
    for i in range(m):
        x = ra[i]
        for q in range(1, k):
            x = max(x, t[nodes[q], i])
        s += wq[i] * x
    return s


@numba.njit(**_JIT)
def _bound_equal(t, nodes, wq):  # pragma: no cover - compiled
    """:func:`_bound` when every live row has the same weight ``wq[0]``: an integer sum (vectorises
    over bytes), scaled once."""
    k = nodes.shape[0]
    m = t.shape[1]
    s = 0
    ra = t[nodes[0]]
    if k == 1:
        for i in range(m):
            s += np.int64(ra[i])
    elif k == 2:
        rb = t[nodes[1]]
        for i in range(m):
            s += np.int64(max(ra[i], rb[i]))
    elif k == 3:
        rb = t[nodes[1]]
        rc = t[nodes[2]]
        for i in range(m):
            s += np.int64(max(ra[i], max(rb[i], rc[i])))
    else:
        return _bound(t, nodes, wq)
    return wq[0] * float(s)


@numba.njit(**_PJIT)
def _expand(front, lo, hi, left, right, t, wq, equal, best, margin, indptr, indices, data, w, order):  # pragma: no cover - compiled
    """Split every tuple of ``front`` (F, k) once (:func:`camplace.solver._support.bitkernels.split_tuple`).

    Returns ``children`` (F, k + 1, k), ``value`` (F, k + 1) (bound, or the exact value for a
    tuple of leaves; -inf where no child was made or its bound cannot beat ``best``) and
    ``leaf`` (F, k + 1) bool.
    """
    f_count, k = front.shape
    children = np.zeros((f_count, k + 1, k), dtype=np.int64)
    value = np.full((f_count, k + 1), -np.inf)
    leaf = np.zeros((f_count, k + 1), dtype=np.bool_)
    for f in prange(f_count):
        n_kids = K.split_tuple(front[f], lo, hi, left, right, children[f])
        cols = np.empty(k, dtype=np.int64)
        for q in range(n_kids):
            child = children[f, q]
            b = _bound_equal(t, child, wq) if equal else _bound(t, child, wq)
            if b <= best + margin:
                continue
            is_leaf = K.all_leaves(child, lo, hi)
            if is_leaf:
                for j in range(k):
                    cols[j] = order[lo[child[j]]]
                b = _exact(indptr, indices, data, w, cols)
            value[f, q] = b
            leaf[f, q] = is_leaf
    return children, value, leaf


class _Columns:
    """Exact column access for the incumbent heuristics (CSC arrays, dead rows weigh 0)."""

    def __init__(self, qc: sp.csc_matrix, w: np.ndarray) -> None:
        self.indptr, self.indices, self.data = qc.indptr, qc.indices, qc.data
        self.w = w
        self.m = qc.shape[0]
        self.margin = _MARGIN * float(w.sum())

    def state(self, sel: list[int]) -> np.ndarray:
        cur = np.zeros(self.m)
        for j in sel:
            s, e = self.indptr[j], self.indptr[j + 1]
            r = self.indices[s:e]
            cur[r] = np.maximum(cur[r], self.data[s:e])
        return cur

    def value(self, sel: list[int]) -> float:
        return float(_exact(self.indptr, self.indices, self.data, self.w, np.asarray(sel, dtype=np.int64)))

    def gains(self, sel: list[int]) -> np.ndarray:
        with ctrl_c_deferred():
            return _gains(self.indptr, self.indices, self.data, self.w, self.state(sel))

    def greedy_swap(self, start: list[int], k: int, deadline: Deadline) -> list[int]:
        """Greedy completion of ``start``, then 1-swaps until none improves or the deadline passes."""
        return greedy_swap(self.gains, start, k, self.margin, _SWAP_ROUNDS, deadline.expired)


def solve_quality_tree(matrix: sp.spmatrix, weights: np.ndarray, k: int, *,
                       deadline: Deadline | None = None) -> EngineOutcome:
    """Best ``k`` columns for ``sum_i w_i max_{j in S} Q_ij`` (tree bound, exact leaves).

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix
        Quality values >= 0 (0 = not observed).
    weights : (m,) float64
        Non-negative row weights.
    k : int
        Columns to choose (1 <= k).
    deadline : Deadline, optional
        The solve's deadline (default: none); on expiry the incumbent is returned with status
        "feasible" and a valid bound.

    Returns
    -------
    EngineOutcome
        ``selected`` are column indices of ``matrix``; ``bound`` an upper bound on the optimum.
    """
    deadline = as_deadline(deadline)
    since = stopwatch(deadline)
    qc = sp.csc_matrix(matrix)
    if not np.issubdtype(qc.dtype, np.floating):
        qc = qc.astype(np.float64)
    qc.sort_indices()
    m, n = qc.shape
    w = np.asarray(weights, dtype=np.float64)
    if k < 1:
        raise ValueError("k must be >= 1")
    if n <= k:
        cols = list(range(n))
        val = float(_exact(qc.indptr, qc.indices, qc.data, w, np.asarray(cols, dtype=np.int64))) if n else 0.0
        return EngineOutcome(selected=tuple(cols), status="optimal", bound=val, stats={"trivial": True})
    colsrc = _Columns(qc, w)
    margin = colsrc.margin
    stats: dict[str, Any] = {}

    # incumbent: greedy + swaps from the best single columns
    single = colsrc.gains([])
    best, best_set = -math.inf, ()
    for j in np.argsort(-single, kind="stable")[: min(_STARTS, n)]:
        sel = colsrc.greedy_swap([int(j)], k, deadline)
        v = colsrc.value(sel)
        if v > best:
            best, best_set = v, tuple(sorted(sel))
        if deadline.expired():
            break
    stats["initial_incumbent"] = best
    stats["time_incumbent_s"] = since()
    if deadline.expired():  # no time for the tree: every point gets its best quality
        with ctrl_c_deferred():
            bound = float(w @ _row_max(qc.indptr, qc.indices, qc.data, m))  # each point's best camera
        status = "optimal" if bound <= best + margin else "feasible"
        return EngineOutcome(selected=best_set, status=status, bound=best if status == "optimal" else bound,
                             stats=stats)

    # live rows (positive weight, observed), quantised node table over the bisection order
    with ctrl_c_deferred():
        rmax = _row_max(qc.indptr, qc.indices, qc.data, m)
    live = (w > 0) & (rmax > 0)
    rowmap = np.full(m, -1, dtype=np.int64)
    rowmap[live] = np.arange(int(live.sum()), dtype=np.int64)
    m_live = int(live.sum())
    qmax = float(rmax.max()) if m else 0.0
    if m_live == 0 or qmax <= 0:
        stats["trivial"] = True  # nothing observed: every set is worth 0
        return EngineOutcome(selected=best_set, status="optimal", bound=best, stats=stats)
    with ctrl_c_deferred():
        pattern_bits = _pattern_bits(qc, rowmap, m_live)
        order = K.bisection_order(pattern_bits)
        del pattern_bits
        lo, hi, left, right = K.tree_shape(n)
        table = _node_table(qc.indptr, qc.indices, qc.data, rowmap, m_live, order, lo, left, right, 255.0 / qmax)
    wq = w[live] * (qmax / 255.0)
    equal = bool(np.all(wq == wq[0]))
    stats["time_setup_s"] = since()
    stats["table_bytes"] = int(table.nbytes)

    def expand(tup: np.ndarray, best: float):
        return _expand(tup, lo, hi, left, right, table, wq, equal, best, margin, qc.indptr, qc.indices, qc.data, w,
                       order)

    best, best_set, bound, status = _search(expand, _bound(table, np.zeros(k, dtype=np.int64), wq), k, lo, order,
                                            best, best_set, margin, deadline, stats)
    log.info("quality tree: k=%d on %dx%d, %s value %.9g bound %.9g, %d bound evaluations, %.3f s", k, m_live, n,
             status, best, bound, stats["bound_evaluations"], since())
    return EngineOutcome(selected=best_set, status=status, bound=float(bound), stats=stats)


def _search(expand, root_bound: float, k: int, lo: np.ndarray, order: np.ndarray, best: float, best_set: tuple,
            margin: float, deadline: Deadline, stats: dict[str, Any]) -> tuple[float, tuple, float, str]:
    """Depth-first over chunks of node tuples: pop the top chunk, expand it in parallel
    (``expand(tuples, best)`` -> children, value, leaf as :func:`_expand`), push its surviving
    children as chunks in increasing bound order (the most promising on top).

    Returns (best value, best set, bound, status); fills ``stats``."""
    since = stopwatch(deadline)
    t0 = since()
    root = np.zeros((1, k), dtype=np.int64)
    stack_t: list[np.ndarray] = [root]
    stack_b: list[np.ndarray] = [np.array([root_bound])]
    evaluated = exact_evals = chunks = 0
    n_open = peak = 1
    status = "optimal"
    open_bound = -math.inf
    while stack_t:
        if deadline.expired() or n_open > FRONTIER_MAX:
            if n_open > FRONTIER_MAX:
                log.warning("quality tree: over %d open tuples; stopping with a bound", FRONTIER_MAX)
            status = "feasible"
            open_bound = max(float(b.max()) for b in stack_b if b.size)
            break
        tup, tb = stack_t.pop(), stack_b.pop()
        n_open -= tb.shape[0]
        tup = tup[tb > best + margin]
        if tup.shape[0] == 0:
            continue
        chunks += 1
        with ctrl_c_deferred():
            children, value, leaf = expand(tup, best)
        made = np.isfinite(value)
        evaluated += int(made.sum())
        exact_evals += int((leaf & made).sum())
        top = best_leaf(children, value, leaf)
        if top is not None and top[0] > best:
            best = top[0]
            best_set = tuple(sorted(int(order[lo[x]]) for x in top[1]))
            log.debug("quality tree: incumbent %.9g %s", best, best_set)
        n_open += push_chunks(stack_t, stack_b, children, value, leaf, best + margin, _CHUNK)
        peak = max(peak, n_open)
    bound = max(best, open_bound) if status == "feasible" else best
    if bound <= best + margin:
        status, bound = "optimal", best
    stats.update({"bound_evaluations": evaluated, "exact_evaluations": exact_evals, "chunks": chunks,
                  "peak_open": int(peak), "time_search_s": since() - t0})
    return best, best_set, bound, status


@numba.njit(**_JIT)
def _row_max(indptr, indices, data, m):  # pragma: no cover - compiled
    """(m,) float64: the largest value of every row (CSC arrays)."""
    out = np.zeros(m)
    for p in range(indices.shape[0]):
        if data[p] > out[indices[p]]:
            out[indices[p]] = data[p]
    return out


def _pattern_bits(qc: sp.csc_matrix, rowmap: np.ndarray, m_live: int) -> np.ndarray:
    """(n, ceil(m_live / 64)) uint64 column bitsets of the live rows (for the bisection order)."""
    return _pattern_bits_kernel(qc.indptr, qc.indices, qc.data, rowmap, m_live)


@numba.njit(**_PJIT)
def _pattern_bits_kernel(indptr, indices, data, rowmap, m_live):  # pragma: no cover - compiled
    n = indptr.shape[0] - 1
    out = np.zeros((n, (m_live + 63) // 64), dtype=np.uint64)
    for j in prange(n):
        for p in range(indptr[j], indptr[j + 1]):
            r = rowmap[indices[p]]
            if r >= 0 and data[p] > 0:
                out[j, r >> 6] |= np.uint64(1) << np.uint64(r & 63)
    return out


# ---------------------------------------------------------------------------------------------
# The same search on quantised columns (issue 32): the stored bytes are the tree's leaves.


#: the largest clusters whose bytes a budgeted table leaves out (their bound reads their columns)
GROUP_MAX = 64


def quality_tree_bytes_dense(m: int, n: int, group: int = 1) -> int:
    """Approximate peak working memory of :func:`solve_quality_tree_dense` beside its input: the
    table of the inner nodes of more than ``group`` columns ((n - 1) x m bytes for ``group = 1``,
    about ``n / group`` rows otherwise), the pattern bitsets and the open tuples."""
    stored = max(n, 1) - 1 if group <= 1 else _stored_inner(n, group)
    return stored * m + n * ((m + 63) // 64) * 8 + 8 * FRONTIER_MAX


def _stored_inner(n: int, group: int) -> int:
    """Inner nodes of the bisection tree over ``n`` columns with more than ``group`` columns."""
    if n <= group:
        return 0
    a, b = n // 2, n - n // 2
    return 1 + _stored_inner(a, group) + _stored_inner(b, group)


def dense_table_group(m: int, n: int, budget: int) -> int | None:
    """The smallest ``group`` (1, 2, 4, ..., :data:`GROUP_MAX`) whose table fits ``budget`` bytes
    (:func:`quality_tree_bytes_dense`), or None when none does."""
    group = 1
    while group <= GROUP_MAX:
        if quality_tree_bytes_dense(m, n, group) <= budget:
            return group
        group *= 2
    return None


@numba.njit(**_JIT)
def _row_d(inner, leaves, slot, v):  # pragma: no cover - compiled
    """Node ``v``'s bytes: an inner node's row of ``inner``, a leaf's column of ``leaves``."""
    s = slot[v]
    if s >= 0:
        return inner[s]
    return leaves[-s - 1]


@numba.njit(**_JIT)
def _bound_d(inner, leaves, slot, nodes, wq):  # pragma: no cover - compiled
    """:func:`_bound` on the split table (rows from :func:`_row_d`)."""
    k = nodes.shape[0]
    m = leaves.shape[1]
    s = 0.0
    ra = _row_d(inner, leaves, slot, nodes[0])
    if k == 1:
        for i in range(m):
            s += wq[i] * ra[i]
        return s
    rb = _row_d(inner, leaves, slot, nodes[1])
    if k == 2:
        for i in range(m):
            s += wq[i] * max(ra[i], rb[i])
        return s
    rc = _row_d(inner, leaves, slot, nodes[2])
    if k == 3:
        for i in range(m):
            s += wq[i] * max(ra[i], max(rb[i], rc[i]))
        return s
    rd = _row_d(inner, leaves, slot, nodes[3])
    if k == 4:
        for i in range(m):
            s += wq[i] * max(max(ra[i], rd[i]), max(rb[i], rc[i]))
        return s
    for i in range(m):
        x = ra[i]
        for q in range(1, k):
            x = max(x, _row_d(inner, leaves, slot, nodes[q])[i])
        s += wq[i] * x
    return s


@numba.njit(**_JIT)
def _bound_equal_d(inner, leaves, slot, nodes, wq):  # pragma: no cover - compiled
    """:func:`_bound_equal` on the split table: every row weighs ``wq[0]``."""
    k = nodes.shape[0]
    m = leaves.shape[1]
    s = 0
    ra = _row_d(inner, leaves, slot, nodes[0])
    if k == 1:
        for i in range(m):
            s += np.int64(ra[i])
    elif k == 2:
        rb = _row_d(inner, leaves, slot, nodes[1])
        for i in range(m):
            s += np.int64(max(ra[i], rb[i]))
    elif k == 3:
        rb = _row_d(inner, leaves, slot, nodes[1])
        rc = _row_d(inner, leaves, slot, nodes[2])
        for i in range(m):
            s += np.int64(max(ra[i], max(rb[i], rc[i])))
    else:
        return _bound_d(inner, leaves, slot, nodes, wq)
    return wq[0] * float(s)


@numba.njit(**_JIT)
def _has_group(nodes, slot, n):  # pragma: no cover - compiled
    """True when a node of the tuple has no row of its own (a small cluster of a budgeted table)."""
    for q in range(nodes.shape[0]):
        if slot[nodes[q]] < -n:
            return True
    return False


@numba.njit(**_JIT)
def _bound_groups(inner, leaves, slot, nodes, wq, lo, hi, order, n, buf):  # pragma: no cover - compiled
    """:func:`_bound_d` when some node keeps no row (``slot < -n``): its columns' bytes are read
    (``order[lo[v]:hi[v]]``) and maxed into ``buf`` ((m,) uint8) with the other nodes' rows."""
    m = leaves.shape[1]
    for i in range(m):
        buf[i] = 0
    for q in range(nodes.shape[0]):
        v = nodes[q]
        s = slot[v]
        if s >= -n:
            r = _row_d(inner, leaves, slot, v)
            for i in range(m):
                buf[i] = max(buf[i], r[i])
        else:
            for p in range(lo[v], hi[v]):
                r = leaves[order[p]]
                for i in range(m):
                    buf[i] = max(buf[i], r[i])
    t = 0.0
    for i in range(m):
        t += wq[i] * buf[i]
    return t


@numba.njit(**_PJIT)
def _inner_table(leaves, slot, left, right, n_inner, lo, hi, order, n):  # pragma: no cover - compiled
    """(n_inner, m) uint8: per stored inner node the largest byte of its columns (row by row
    blocks); a node with a child that keeps no row reads its columns."""
    m = leaves.shape[1]
    t = np.empty((n_inner, m), dtype=np.uint8)
    n_nodes = slot.shape[0]
    block = 4096
    for b in prange((m + block - 1) // block):
        i0 = b * block
        i1 = min(m, i0 + block)
        for v in range(n_nodes - 1, -1, -1):  # children are numbered after their parent
            if left[v] >= 0 and slot[v] >= 0:
                a = left[v]
                c = right[v]
                sa = slot[a]
                sc = slot[c]
                dst = slot[v]
                if sa < -n or sc < -n:  # a child without a row: the node's columns
                    for i in range(i0, i1):
                        t[dst, i] = 0
                    for p in range(lo[v], hi[v]):
                        r = leaves[order[p]]
                        for i in range(i0, i1):
                            t[dst, i] = max(t[dst, i], r[i])
                elif sa >= 0 and sc >= 0:
                    for i in range(i0, i1):
                        t[dst, i] = max(t[sa, i], t[sc, i])
                elif sa >= 0:
                    lc = -sc - 1
                    for i in range(i0, i1):
                        t[dst, i] = max(t[sa, i], leaves[lc, i])
                elif sc >= 0:
                    la = -sa - 1
                    for i in range(i0, i1):
                        t[dst, i] = max(leaves[la, i], t[sc, i])
                else:
                    la = -sa - 1
                    lc = -sc - 1
                    for i in range(i0, i1):
                        t[dst, i] = max(leaves[la, i], leaves[lc, i])
    return t


@numba.njit(**_JIT)
def _bound_any(inner, leaves, slot, nodes, wq, equal, lo, hi, order, n, buf):  # pragma: no cover - compiled
    """The bound of a tuple on the split table, whichever kinds of nodes it holds."""
    if _has_group(nodes, slot, n):
        return _bound_groups(inner, leaves, slot, nodes, wq, lo, hi, order, n, buf)
    if equal:
        return _bound_equal_d(inner, leaves, slot, nodes, wq)
    return _bound_d(inner, leaves, slot, nodes, wq)


@numba.njit(**_PJIT)
def _expand_d(front, lo, hi, left, right, inner, leaves, slot, wq, equal, best, margin, order,
              grouped):  # pragma: no cover - compiled
    """:func:`_expand` on the split table; a tuple of leaves' bound is its exact value (the bytes
    are the values). ``grouped``: some nodes keep no row (a budgeted table)."""
    f_count, k = front.shape
    n = leaves.shape[0]
    children = np.zeros((f_count, k + 1, k), dtype=np.int64)
    value = np.full((f_count, k + 1), -np.inf)
    leaf = np.zeros((f_count, k + 1), dtype=np.bool_)
    for f in prange(f_count):
        n_kids = K.split_tuple(front[f], lo, hi, left, right, children[f])
        buf = np.empty(leaves.shape[1] if grouped else 0, dtype=np.uint8)
        for q in range(n_kids):
            child = children[f, q]
            b = _bound_any(inner, leaves, slot, child, wq, equal, lo, hi, order, n, buf)
            if b <= best + margin:
                continue
            value[f, q] = b
            leaf[f, q] = K.all_leaves(child, lo, hi)
    return children, value, leaf


@numba.njit(**_PJIT)
def _gains_d(leaves, wq, cur):  # pragma: no cover - compiled
    """(n,) float64: ``sum_i wq_i max(0, q_ji - cur_i)`` for every column j (bytes)."""
    n, m = leaves.shape
    out = np.zeros(n)
    for j in prange(n):
        s = 0.0
        row = leaves[j]
        for i in range(m):
            d = np.int64(row[i]) - np.int64(cur[i])
            if d > 0:
                s += wq[i] * d
        out[j] = s
    return out


@numba.njit(**_PJIT)
def _pack_d(leaves):  # pragma: no cover - compiled
    """(n, ceil(m / 64)) uint64: the nonzero bytes of every column as a bitset."""
    n, m = leaves.shape
    out = np.zeros((n, (m + 63) // 64), dtype=np.uint64)
    for j in prange(n):
        for i in range(m):
            if leaves[j, i] != 0:
                out[j, i >> 6] |= np.uint64(1) << np.uint64(i & 63)
    return out


class _DenseColumns:
    """Column access on quantised columns for the incumbent heuristics."""

    def __init__(self, leaves: np.ndarray, wq: np.ndarray, margin: float) -> None:
        self.leaves, self.wq, self.margin = leaves, wq, margin

    def state(self, sel: list[int]) -> np.ndarray:
        cur = np.zeros(self.leaves.shape[1], dtype=np.uint8)
        for j in sel:
            np.maximum(cur, self.leaves[j], out=cur)
        return cur

    def value(self, sel: list[int]) -> float:
        return float(self.wq @ self.state(sel).astype(np.float64))

    def gains(self, sel: list[int]) -> np.ndarray:
        with ctrl_c_deferred():
            return _gains_d(self.leaves, self.wq, self.state(sel))

    def greedy_swap(self, start: list[int], k: int, deadline: Deadline) -> list[int]:
        return greedy_swap(self.gains, start, k, self.margin, _SWAP_ROUNDS, deadline.expired)


def solve_quality_tree_dense(values: np.ndarray, scale: float, weights: np.ndarray, k: int, *,
                             deadline: Deadline | None = None, group: int = 1) -> EngineOutcome:
    """:func:`solve_quality_tree` on quantised columns: best ``k`` columns for
    ``sum_i w_i max_{j in S} scale * values[j, i]``.

    The columns are the tree's leaves as they are (no copy); only the inner nodes' table is made
    ((n - 1) x m bytes). Bounds are exact sums of the same bytes, so a tuple of leaves' bound is
    its value and no rounding enters: the answer is exact for the quantised values.

    Parameters
    ----------
    values : (n, m) uint8, C-contiguous
        Column ``j``'s bytes in ``values[j]`` (0: not observed).
    scale : float
        The value of one step of a byte (1 / 255 for :mod:`camplace.visibility.qbytes`).
    weights : (m,) float64
        Non-negative row weights.
    k : int
        Columns to choose (1 <= k).
    deadline : Deadline, optional
        The solve's deadline; on expiry the incumbent comes back with status "feasible" and a
        valid bound.
    group : int
        The table keeps rows for the inner nodes of more than ``group`` columns only (1: every
        inner node); the bound of a tuple with a smaller cluster reads that cluster's columns
        (slower, the same bound). :func:`dense_table_group` picks it for a memory budget.

    Returns
    -------
    EngineOutcome
        ``selected`` are column indices; ``bound`` an upper bound on the optimum.
    """
    deadline = as_deadline(deadline)
    since = stopwatch(deadline)
    values = np.ascontiguousarray(values, dtype=np.uint8)
    n, m = values.shape
    w = np.asarray(weights, dtype=np.float64)
    if k < 1:
        raise ValueError("k must be >= 1")
    wq = w * float(scale)
    margin = _MARGIN * float(w.sum())
    leaves = values if not values.flags.writeable else values.view()
    leaves.setflags(write=False)  # one numba type for the leaves and the inner table
    cols = _DenseColumns(leaves, wq, margin)
    if n <= k:
        sel = list(range(n))
        return EngineOutcome(selected=tuple(sel), status="optimal", bound=cols.value(sel) if n else 0.0,
                             stats={"trivial": True})
    stats: dict[str, Any] = {}
    single = cols.gains([])
    best_set = tuple(sorted(cols.greedy_swap([int(np.argmax(single))], k, deadline)))
    best = cols.value(list(best_set))
    stats["initial_incumbent"] = best
    stats["time_incumbent_s"] = since()
    if deadline.expired():  # no time for the tree: every point gets its best quality
        top = np.zeros(m, dtype=np.uint8)
        for j in range(n):
            np.maximum(top, leaves[j], out=top)
        bound = float(wq @ top.astype(np.float64))
        status = "optimal" if bound <= best + margin else "feasible"
        return EngineOutcome(selected=best_set, status=status, bound=best if status == "optimal" else bound,
                             stats=stats)
    with ctrl_c_deferred():
        order = K.bisection_order(_pack_d(leaves))
        lo, hi, left, right = K.tree_shape(n)
        n_nodes = lo.shape[0]
        slot = np.empty(n_nodes, dtype=np.int64)
        is_leaf = left < 0
        stored = ~is_leaf & (hi - lo > max(1, int(group)))
        slot[stored] = np.arange(int(stored.sum()), dtype=np.int64)
        slot[is_leaf] = -order[lo[is_leaf]] - 1
        slot[~is_leaf & ~stored] = -n - 1  # a small cluster without a row: its bound reads its columns
        grouped = bool(np.any(~is_leaf & ~stored))
        inner = _inner_table(leaves, slot, left, right, int(stored.sum()), lo, hi, order, n)
    inner.setflags(write=False)
    positive = wq[w > 0]
    equal = bool(positive.size == m and np.all(wq == wq[0]))
    stats["time_setup_s"] = since()
    stats["table_bytes"] = int(inner.nbytes)

    stats["table_group"] = int(group)

    def expand(tup: np.ndarray, best: float):
        return _expand_d(tup, lo, hi, left, right, inner, leaves, slot, wq, equal, best, margin, order, grouped)

    root = _bound_any(inner, leaves, slot, np.zeros(k, dtype=np.int64), wq, equal, lo, hi, order, n,
                      np.empty(m, dtype=np.uint8))
    best, best_set, bound, status = _search(expand, root, k, lo, order, best, best_set, margin, deadline, stats)
    log.info("quality tree (bytes): k=%d on %dx%d, %s value %.9g bound %.9g, %d bound evaluations, %.3f s", k, m, n,
             status, best, bound, stats["bound_evaluations"], since())
    return EngineOutcome(selected=best_set, status=status, bound=float(bound), stats=stats)
