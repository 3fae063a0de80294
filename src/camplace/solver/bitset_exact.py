"""Exact bound-pruned engine on row bitsets: max coverage and m-view coverage for small k.

Every column of the presolved instance becomes a bitset of its rows (one bit per merged row), so a
set of columns is scored with a few word operations per 64 rows.

* **Objective.** A row counts when at least ``views`` of the ``k`` chosen columns observe it
  (``views = 1``: max coverage; ``views = 2``: stereo coverage). Per 64-row word the rows reaching
  ``views`` are ``atleast_m(x_1, ..., x_k)`` (a bit-parallel counter).
* **Tree.** The columns are ordered by recursive balanced bisection on the Hamming distance of
  their bitsets (similar columns adjacent) and form an implicit binary tree over that order; node
  ``v`` stores level bitsets ``L_j(v)``: the rows observed by at least ``j`` of its columns
  (``j = 1``: the union; ``j <= min(views, k)``).
* **Search.** A tuple of ``k`` tree nodes (non-decreasing in the order; a node may repeat) stands
  for every ``k``-subset with one column in each node. A node repeated ``c`` times can give a row
  at most ``j <= c`` views where the row is in ``L_j``, so counting these per row (a bit-parallel
  counter) bounds every subset of the tuple; for ``views = 1`` the bound is the weight of the
  union of the nodes' unions. A tuple of leaves is one subset and the bound is its exact value.
  Depth-first search splits the largest node of a tuple into its two children (every
  non-decreasing mix for a repeated node, a leaf never twice) and drops tuples whose bound cannot
  beat the incumbent. The weight of the rows that miss is summed (popcounts of the weights'
  binary digits for integer weights with ``views > 1``, set bits one by one otherwise) and the
  sum stops as soon as it proves the tuple cannot win, so near-complete coverage is cheap to
  evaluate.
  For ``views > 1`` a tuple's bound is also at most the sum of its nodes' heaviest column
  weights divided by ``views`` (a counted row is observed ``views`` times).
* **Incumbent.** Greedy from several starts plus 1-swap local search on the bitsets.
* **Exactness.** When every original weight is equal, weights are the merged-row counts (exact
  integers in float64) and pruning is exact; otherwise pruning keeps a margin of
  ``1e-9 * total weight``.
* **Time limit.** The compiled search runs in slices of bound evaluations; between slices the
  deadline is checked. On expiry the incumbent is returned with status ``feasible`` and the bound
  ``max(incumbent, bounds of the tuples still on the stack)``.
* **Memory.** ``n' * m' / 8`` bytes of column bitsets and ``2 min(views, k)`` times that for the
  tree levels.
"""

from __future__ import annotations

import functools
import logging
import math
from typing import Any

import numpy as np

from camplace._signals import ctrl_c_deferred
from camplace.solver import _bitkernels as K
from camplace.solver._common import Deadline, EngineOutcome, greedy_swap
from camplace.solver.presolve import Presolved

__all__ = ["solve_bitset", "bitset_bytes", "BITSET_MAX_K"]

log = logging.getLogger(__name__)

BITSET_MAX_K = 4  # auto uses this engine up to this k (it is exact for any k, but slow for large k)
_FLOAT_MARGIN = 1e-9
_SLICE = 50_000  # bound evaluations per compiled call (0.02-0.5 s): the deadline is checked between calls
_STACK = 1 << 14
_STARTS = 2  # greedy starts (the best columns), besides the plain greedy
_SWAP_ROUNDS = 50


def bitset_bytes(m: int, n: int, levels: int) -> int:
    """Approximate working memory for ``m`` reduced rows and ``n`` columns: the column bitsets,
    their ordered copy and ``levels`` level bitsets per tree node (2 n - 1 nodes)."""
    return n * ((m + 63) // 64) * 8 * (2 + 2 * max(1, levels))


def _last_mask(m: int) -> np.uint64:
    rem = m % 64
    return np.uint64((1 << rem) - 1) if rem else np.uint64(0xFFFFFFFFFFFFFFFF)


class _State:
    """Bitsets, weights and the incumbent of one solve."""

    def __init__(self, pre: Presolved, views: int) -> None:
        self.k, self.views = pre.k, views
        self.integer = pre.weight_unit is not None
        if self.integer:
            self.w = pre.counts.astype(np.float64)
            self.scale = float(pre.weight_unit)  # type: ignore[arg-type]
            self.margin = 0.0
        else:
            self.w = pre.weights.astype(np.float64)
            self.scale = 1.0
            self.margin = _FLOAT_MARGIN * float(self.w.sum())
        self.total = float(self.w.sum())
        self.bits = pre.bits
        self.n_words = self.bits.shape[1]
        self.planes = K.weight_planes(self.w) if (self.integer and views > 1) else np.zeros((0, self.n_words), np.uint64)
        self.mask = _last_mask(pre.shape[0])
        self.best = -math.inf
        self.best_set: tuple[int, ...] = ()

    def value_all(self, sel: list[int], views: int | None = None) -> np.ndarray:
        """``value(sel + [x])`` for every column x (x in sel gives a meaningless number)."""
        sb = self.bits[np.asarray(sel, dtype=np.int64)] if sel else np.zeros((0, self.n_words), dtype=np.uint64)
        with ctrl_c_deferred():
            short = K.shortfall_all(self.bits, np.ascontiguousarray(sb), views or self.views, self.w, self.mask)
        return self.total - short

    def value(self, sel: list[int]) -> float:
        sb = np.ascontiguousarray(self.bits[np.asarray(sel, dtype=np.int64)])[None]
        nodes = np.arange(len(sel), dtype=np.int64)
        acc = np.zeros(self.views + 1, dtype=np.uint64)
        return self.total - float(K.shortfall(sb, nodes, len(sel), self.views, self.w, self.planes, self.mask,
                                              math.inf, acc))

    def offer(self, value: float, sel: list[int] | tuple[int, ...]) -> None:
        if value > self.best:
            self.best = value
            self.best_set = tuple(sorted(int(j) for j in sel))
            log.debug("bitset: incumbent %.9g %s", value * self.scale, self.best_set)

    def greedy_swap(self, start: list[int]) -> list[int]:
        return greedy_swap(self.value_all, start, self.k, self.margin, _SWAP_ROUNDS)

    @functools.cached_property
    def column_weights(self) -> np.ndarray:
        """(n',) float64: the weight each column observes."""
        return self.value_all([], views=1)

    def incumbent(self) -> None:
        f = self.column_weights
        starts: list[list[int]] = [[]] if self.views == 1 else []
        for j in np.argsort(-f, kind="stable")[:_STARTS]:
            starts.append([int(j)])
        for st in starts:
            sel = self.greedy_swap(st)
            self.offer(self.value(sel), sel)


def solve_bitset(pre: Presolved, *, views: int = 1, time_limit_s: float | None = None) -> EngineOutcome:
    """Choose ``pre.k`` columns maximising the weight of rows observed by at least ``views`` of them.

    Parameters
    ----------
    pre : Presolved
        Output of :func:`camplace.solver.presolve.presolve` (for ``views > 1`` without column
        dominance, which is only valid for ``views = 1``).
    views : int
        Chosen columns a row needs (1: max coverage).
    time_limit_s : float, optional
        Wall-clock limit; on expiry the incumbent is returned with status "feasible" and a valid
        bound.

    Returns
    -------
    EngineOutcome
        Reduced column indices, status, bound (original weight units) and stats.
    """
    deadline = Deadline(time_limit_s)
    k = pre.k
    m, n = pre.shape
    if views < 1:
        raise ValueError("views must be >= 1")
    if m == 0 or n <= k:
        sel = tuple(range(min(k, n)))
        # n == k: every column is chosen, so a row's views are its entries in the reduced matrix
        value = float(pre.weights[np.diff(pre.matrix.indptr) >= views].sum()) if n <= k else 0.0
        return EngineOutcome(selected=sel, status="optimal", bound=value, stats={"trivial": True})

    st = _State(pre, views)
    stats: dict[str, Any] = {"arithmetic": "integer" if st.integer else "float64", "views": views, "words": st.n_words,
                             "time_bitsets_s": deadline.elapsed()}
    st.incumbent()
    stats["initial_incumbent"] = st.best * st.scale
    stats["time_incumbent_s"] = deadline.elapsed() - stats["time_bitsets_s"]
    with ctrl_c_deferred():
        perm = K.bisection_order(st.bits)
        lo, hi, left, right, levels = K.build_tree(np.ascontiguousarray(st.bits[perm]), min(views, k))
    stats["time_setup_s"] = deadline.elapsed()
    # views > 1: per node the largest column weight (m x value <= the chosen columns' weights)
    colmax = np.zeros(0)
    if views > 1:
        f = st.column_weights[perm]
        colmax = np.empty(lo.shape[0])
        for v in range(lo.shape[0] - 1, -1, -1):
            colmax[v] = f[lo[v]] if left[v] < 0 else max(colmax[left[v]], colmax[right[v]])
    stack = np.zeros((_STACK, k), dtype=np.int64)
    stack_bound = np.zeros(_STACK, dtype=np.float64)
    stack_bound[0] = st.total
    if views > 1:  # the k heaviest columns, each row counted views times
        stack_bound[0] = min(st.total, float(np.sort(f)[-k:].sum()) / views)
    sp = 1
    best_pos = np.zeros(k, dtype=np.int64)
    evaluated = 0
    status = "optimal"
    while sp > 0:
        if deadline.expired():
            status = "feasible"
            break
        with ctrl_c_deferred():
            sp, best, ev = K.tuple_search(lo, hi, left, right, levels, views, st.w, st.planes, st.mask, st.total, st.margin,
                                          stack, stack_bound, sp, st.best, best_pos, _SLICE, colmax)
        evaluated += ev
        if sp < 0:
            raise RuntimeError("bitset search stack overflow")  # cannot happen: depth <= k * log2(n) levels
        if best > st.best:
            st.offer(best, tuple(int(perm[p]) for p in best_pos))
    bound = max(st.best, float(stack_bound[:sp].max(initial=-math.inf)))
    if bound <= st.best + st.margin:
        status, bound = "optimal", st.best
    stats.update({"bound_evaluations": int(evaluated), "time_search_s": deadline.elapsed() - stats["time_setup_s"]})
    log.info("bitset: k=%d views=%d on %dx%d, %s value %.9g bound %.9g, %d bound evaluations, %.3f s", k, views, m, n,
             status, st.best * st.scale, bound * st.scale, evaluated, deadline.elapsed())
    return EngineOutcome(selected=st.best_set, status=status, bound=float(bound) * st.scale, stats=stats)
