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
  The search (:func:`_roots_search`) runs best-first over the open tuples, with a depth-first
  search of a few thousand bounds from each of the best ones (the roots) in parallel, one root
  per task on a thread pool of :func:`camplace._cores.thread_count` threads (the serial search's
  cache-friendly order on every core), so the reported bound falls as it goes. Every root of a
  round starts from the round's incumbent and without a time limit the roots per round double
  from 4 to 64 whatever the timing, so the answer (and the number of bounds) is the same at every
  thread count; on comet-67p-bunker at 10,000 x 50,000, k = 3, it computes 3 % more bounds than
  one serial depth-first search.
  For ``views > 1`` a tuple's bound is also at most the sum of its nodes' heaviest column
  weights divided by ``views`` (a counted row is observed ``views`` times), and the search
  splits the node whose union most exceeds its heaviest column (where the bound is loosest; on
  comet-67p-bunker with every surface point, 3 views, k = 6: 4.8 million bounds instead of 20.5
  million with the largest node); for ``views = 1`` it splits the largest node.
* **Opposite pairs** (``views > 1`` and ``k < 2 views``, e.g. stereo with 3 cameras). Points that
  no candidate observes together are matched (:mod:`camplace.solver.engines.bitset.pair_cap`); at most one point
  of a pair can count, so each pair is laid out as two rows 64 ``pw`` bits apart carrying one
  weight, and a tuple's bound counts a pair once if either row may reach ``views``. Leaves stay
  exact, and near-flat instances (a convex target seen from all sides, where about half the surface
  counts for any three cameras) get bounds that can prune: on comet-67p-bunker with every surface
  point, 10,000 x 50,000, the root bound falls from 0.706 to 0.502. Used when it matches at least
  5 % of the weight; the search is then depth-first over batches of tuples, each batch expanded in
  parallel (numba ``prange``).
* **Incumbent.** Greedy from several starts plus 1-swap local search on the bitsets (each pass over
  the columns on fixed column blocks of the thread pool: :mod:`camplace.solver._support.parkernels`).
* **Exactness.** When every original weight is equal, weights are the merged-row counts (exact
  integers in float64) and pruning is exact; otherwise pruning keeps a margin of
  ``1e-9 * total weight``.
* **Time limit.** The compiled search runs in rounds of roots, each root for a slice of bound
  evaluations (``_SLICE`` for views = 1, ``_ROOT_BUDGET`` beyond); between rounds the deadline is
  checked (a round doubles the roots of the last, up to ``_ROUND_EVALS`` bound evaluations; with a
  time limit it is cut to about ``_ROUND_S`` seconds and a quarter of the time left). On expiry the incumbent is returned with status ``feasible`` and the bound
  ``max(incumbent, bounds of the tuples still on the stack / frontier)``.
* **Memory.** ``n' * m' / 8`` bytes of column bitsets and ``2 min(views, k)`` times that for the
  tree levels, plus the open tuples (at most ``_FRONTIER_MAX``, and the parallel stacks) in
  :func:`bitset_bytes`.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from typing import Any

import numba
import numpy as np
from numba import prange

from camplace._signals import ctrl_c_deferred
from camplace.solver._support import bitkernels as K
from camplace.solver._support import parkernels as P
from camplace._blocks import run_blocks
from camplace.solver._support.deadline import Deadline, as_deadline, stopwatch
from camplace.solver._support.frontier import Frontier, best_first
from camplace.solver._support.greedy import greedy_swap
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, note_memory
from camplace.solver.engines.bitset.pair_cap import match_opposite
from camplace.solver.problem.checks import kernel_data
from camplace.solver.problem.presolve import Presolved
from camplace.solver.problem.presolve_bits import layout_bits
from camplace.solver.result import EngineOutcome

__all__ = ["solve_bitset", "bitset_bytes", "pairs_layout_bytes", "BITSET_MAX_K"]

log = logging.getLogger(__name__)

BITSET_MAX_K = 4  # auto uses this engine up to this k (it is exact for any k, but slow for large k)
_FLOAT_MARGIN = 1e-9
_SLICE = 2_000  # bound evaluations of the depth-first search from each root for views = 1 (_ROOT_BUDGET beyond)
_STACK = 1 << 14
_STARTS = 2  # greedy starts (the best columns), besides the plain greedy
_SWAP_ROUNDS = 50
_PAIRS_MIN_SHARE = 0.05  # the opposite-pairs layout when it matches at least this share of the weight
#: the search's set-up (bisection order, tree) costs about this many times building the bitsets: with
#: less time left than that the incumbent comes back at once (the set-up is not interruptible)
_TREE_COST = 5.0
_PAIRS_TIME_SHARE = 0.1  # ... and the matching stops after this share of the time limit
_CHUNK = 8192  # tuples per stack entry of the opposite-pairs search
_BATCH = 1 << 16  # tuples expanded per parallel call there at most ...
_BATCH_MIN = 256  # ... and at least
_ROOT_CHUNK = 16  # tuples per frontier entry of the search for views > 1 on the plain layout ...
_ROOT_BUDGET = 20_000  # ... bound evaluations of the depth-first search from each root there ...
_ROOTS_MIN, _ROOTS_MAX = 4, 1024  # ... roots per parallel call: doubling from _ROOTS_MIN while a
_ROUND_EVALS = 512_000  # round spends at most this many bound evaluations (roots x budget), a
# schedule that depends neither on the timing nor on the thread count, so every count and every run
# gives the same answer; with a time limit a round is cut to what the rate just seen does in
_ROUND_S = 4.0  # ... this many seconds and in a quarter of the time left (the deadline is checked between calls)
_BATCH_S = 0.5  # seconds a batch of the opposite-pairs search should take
_FRONTIER_MAX = 5_000_000  # open tuples at most in either search (8 k + 8 bytes each); the roots search goes ...
_DEPTH_FIRST_OPEN = 1_000_000  # ... depth-first (newest chunks) while more than this many are open
_PJIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False, "parallel": True}
_NJIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}


def bitset_bytes(m: int, n: int, levels: int, k: int = BITSET_MAX_K, tuples: bool = True) -> int:
    """Approximate working memory for ``m`` reduced rows and ``n`` columns: the column bitsets,
    their ordered copy and ``levels`` level bitsets per tree node (2 n - 1 nodes), and (``tuples``)
    the open tuples of ``k`` nodes at most (the search stack, or the frontier and the parallel
    stacks for views > 1; they grow with the search, up to 160 MiB at k = 3)."""
    open_b = (_STACK + _FRONTIER_MAX + max((k + 1) * _BATCH, _roots_cap(_SLICE) * _dfs_stack(k, n))) * (8 * k + 8)
    return n * ((m + 63) // 64) * 8 * (2 + 2 * max(1, levels)) + (open_b if tuples else 0)


def pairs_layout_bytes(m: int, n: int, levels: int, k: int = BITSET_MAX_K) -> int:
    """Working memory of the search on the opposite-pairs layout (``views > 1`` and
    ``k < 2 views``: :func:`_pair_layout`) for ``m`` reduced rows and ``n`` columns: the matching
    (:func:`~camplace.solver.engines.bitset.pair_cap.opposite_pair_bytes`), the layout's row order,
    weights and sort keys (up to two layout rows a row, 48 bytes each) and its bitsets
    (:func:`bitset_bytes` of up to ``2 m + 128`` layout rows, without the open tuples)."""
    from camplace.solver.engines.bitset.pair_cap import opposite_pair_bytes

    rows = 2 * int(m) + 128
    return int(opposite_pair_bytes(m, n) + 48 * rows + bitset_bytes(rows, n, levels, k, tuples=False))


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
            short = P.shortfall_all(self.bits, np.ascontiguousarray(sb), views or self.views, self.w, self.mask)
        return self.total - short

    def value(self, sel: list[int]) -> float:
        sb = np.ascontiguousarray(self.bits[np.asarray(sel, dtype=np.int64)])[None]
        nodes = np.arange(len(sel), dtype=np.int64)
        acc = np.zeros(self.views + 1, dtype=np.uint64)
        return self.total - float(K.shortfall(sb, nodes, len(sel), self.views, self.w, self.planes, self.mask,
                                              math.inf, acc, 0))

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


@numba.njit(**_PJIT)
def _expand_pairs(front, lo, hi, left, right, levels, views, w, planes, mask, total, best, margin, colmax,
                  pw):  # pragma: no cover - compiled
    """Split every tuple of ``front`` (F, k) once and bound the children on the opposite-pairs layout.

    Returns ``children`` (F, k + 1, k), ``value`` (F, k + 1) (the bound, which for a tuple of
    leaves is its exact value; -inf where no child was made or it cannot beat ``best``),
    ``leaf`` (F, k + 1) bool and the number of children bounded.
    """
    f_count, k = front.shape
    children = np.zeros((f_count, k + 1, k), dtype=np.int64)
    value = np.full((f_count, k + 1), -np.inf)
    leaf = np.zeros((f_count, k + 1), dtype=np.bool_)
    made = np.zeros(f_count, dtype=np.int64)
    for f in prange(f_count):
        acc = np.zeros(views + 1, dtype=np.uint64)
        n_kids = K.split_tuple(front[f], lo, hi, left, right, children[f])
        made[f] = n_kids
        for q in range(n_kids):
            child = children[f, q]
            b = K.child_bound(levels, child, views, w, planes, mask, total, best + margin, colmax, acc, pw)
            if b == -np.inf:
                continue
            value[f, q] = b
            leaf[f, q] = K.all_leaves(child, lo, hi)
    return children, value, leaf, made.sum()


@numba.njit(**_NJIT)
def _dfs_roots_block(f0, f1, roots, lo, hi, left, right, levels, views, w, planes, mask, total, best, margin, colmax, pw,
                     budget, score, stacks, bounds, found, found_pos, evals, overflow):  # pragma: no cover - compiled
    """Depth-first search (:func:`camplace.solver._support.bitkernels.tuple_search`) from the tuples
    ``f0 .. f1 - 1`` of ``roots`` (F, k), each for at most ``budget`` bound evaluations from the
    incumbent value ``best`` (the same for every root, so a root's search does not depend on the
    others'), into the arrays of :func:`_dfs_roots` (each root writes only its own entries)."""
    cap = stacks.shape[1]
    for f in range(f0, f1):
        stacks[f, 0] = roots[f]
        bounds[f, 0] = np.inf  # popped: it beats the incumbent
        sp, b, ev = K.tuple_search(lo, hi, left, right, levels, views, w, planes, mask, total, margin, stacks[f],
                                   bounds[f], 1, best, found_pos[f], budget, colmax, pw, score)
        evals[f] = ev
        if sp < 0:
            overflow[f] = True
            sp = 0
        for i in range(sp, cap):
            bounds[f, i] = -np.inf
        if b > best:
            found[f] = b


def bind_search_kernel() -> None:
    """Load :func:`_dfs_roots_block`'s machine code before any other kernel that holds the same
    compiled helpers (``bitkernels.shortfall`` itself, called from Python by the incumbent; the
    incumbent's kernels), so that the search calls its own copies of them.

    Each cached kernel carries its own copy of the kernels it calls, under the same symbol name
    when they were compiled in one process (as a fresh install compiles them), and when it is
    loaded, a call to a name already loaded goes to that earlier copy. The search spends about
    70 % of its time in ``bitkernels.shortfall``; calling the copy loaded first by the incumbent it
    evaluated a bound in 0.78-0.84 us, calling its own in 0.58-0.59 us (comet-67p-bunker
    10,000 x 50,000, 2 threads, fresh compiles; docs/performance.md). The call does no work (``f0 = f1``); its argument types are
    those of :func:`_dfs_roots` (``tests/solver/test_bitset_bind.py`` checks that a solve adds no
    second signature).
    """
    if _dfs_roots_block.signatures:
        return
    i1 = np.zeros(1, dtype=np.int64)
    with ctrl_c_deferred():
        _dfs_roots_block(0, 0, np.zeros((1, 1), dtype=np.int64), i1, i1, i1, i1, np.zeros((1, 1, 1), dtype=np.uint64),
                         1, np.zeros(1), np.zeros((0, 1), dtype=np.uint64), np.uint64(0), 0.0, 0.0, 0.0, np.zeros(0),
                         0, 1, np.zeros(0), np.zeros((1, 1, 1), dtype=np.int64), np.zeros((1, 1)), np.zeros(1),
                         np.zeros((1, 1), dtype=np.int64), np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.bool_))


def _dfs_roots(roots, lo, hi, left, right, levels, views, w, planes, mask, total, best, margin, colmax, pw, budget,
               cap, score, threads: int | None = None):
    """Depth-first search from every tuple of ``roots`` (F, k), one root per task on a thread pool
    of :func:`camplace._cores.thread_count` threads (:func:`_dfs_roots_block`, GIL-free): the same
    result at every thread count.

    Returns ``stacks`` (F, cap, k) and ``bounds`` (F, cap) (the tuples left open, -inf past each
    stack's top), ``found`` (F,) (a better leaf's value, -inf if none), ``found_pos`` (F, k) (its
    column positions), the number of bounds computed, and whether a stack overflowed.
    """
    f_count, k = roots.shape
    stacks = np.zeros((f_count, cap, k), dtype=np.int64)
    bounds = np.full((f_count, cap), -np.inf)
    found = np.full(f_count, -np.inf)
    found_pos = np.zeros((f_count, k), dtype=np.int64)
    evals = np.zeros(f_count, dtype=np.int64)
    overflow = np.zeros(f_count, dtype=np.bool_)
    run_blocks(lambda f0, f1: _dfs_roots_block(f0, f1, roots, lo, hi, left, right, levels, views, w, planes, mask, total,
                                               best, margin, colmax, pw, budget, score, stacks, bounds, found,
                                               found_pos, evals, overflow),
               list(range(f_count + 1)), threads)  # one root per task: subtrees vary in size
    return stacks, bounds, found, found_pos, int(evals.sum()), bool(overflow.any())


def _pair_layout(pre: Presolved, views: int, deadline: Deadline, stats: dict[str, Any]):
    """Rows and weights of the opposite-pairs layout of ``pre``, or None when it would not pay.

    The layout reads the original rows: of ``pre.source``'s CSR, or, for a presolve of column
    bitsets, of the BitMatrix itself (``pre.origin``, transposed; no CSR is made)."""
    origin = getattr(pre, "origin", None)
    if origin is not None:
        a = origin
        col_map = np.full(a.shape[1], -1, dtype=np.int64)
        col_map[pre.columns] = np.arange(pre.columns.size, dtype=np.int64)
    else:
        a, _, col_map = pre.source
    g = pre.row_groups
    live = g >= 0
    if pre.weight_unit is not None:
        w = np.where(live, float(pre.weight_unit), 0.0)
        seed = None  # equal weights: the matrix order
    else:  # rows of one group are observed together: share its weight evenly (the bound stays valid)
        gg = np.where(live, g, 0)
        w = np.where(live, pre.weights[gg] / np.maximum(pre.counts[gg], 1), 0.0)
        seed = 0
    match = match_opposite(a, w, views, columns=np.flatnonzero(col_map >= 0), order_seed=seed,
                           deadline=deadline.share(_PAIRS_TIME_SHARE))
    share = match.matched / match.countable if match.countable > 0 else 0.0
    stats["opposite_pairs"] = dict(match.stats, matched_share=share)
    if share < _PAIRS_MIN_SHARE:
        return None
    rows, lw, pw = match.layout(unit=pre.weight_unit)
    # Rarely observed rows first: a tuple that cannot win misses most there, so its sum stops early.
    seen = a.row_counts() if origin is not None else np.diff(a.indptr)
    n_pairs = int(np.count_nonzero(rows[: 64 * pw] >= 0))
    o = np.argsort(seen[rows[:n_pairs]] + seen[rows[64 * pw : 64 * pw + n_pairs]], kind="stable")
    rows[:n_pairs], rows[64 * pw : 64 * pw + n_pairs], lw[:n_pairs] = (
        rows[:n_pairs][o], rows[64 * pw : 64 * pw + n_pairs][o], lw[:n_pairs][o])
    o = 128 * pw + np.argsort(seen[rows[128 * pw :]], kind="stable")
    rows[128 * pw :], lw[128 * pw :] = rows[o], lw[o]
    need = bitset_bytes(rows.size, pre.shape[1], min(views, pre.k), pre.k)
    if need > memory_budget_bytes():
        stats["opposite_pairs"]["skipped"] = f"layout bitsets need {need / 2**30:.1f} GiB"
        note_memory("pairs layout", need, refused=True)
        return None
    # the layout's size, known now (up to two rows a point before the matching): its bitsets and
    # tree without the open tuples, beside its row order, weights and sort keys (48 bytes a layout row)
    note_memory("pairs layout", bitset_bytes(rows.size, pre.shape[1], min(views, pre.k), pre.k, tuples=False)
                + 48 * rows.size)
    if origin is not None:
        try:
            bits = layout_bits(origin, rows, col_map, pre.shape[1])
        except OverBudget as exc:  # the plain layout instead (valid, only less tight)
            stats["opposite_pairs"]["skipped"] = exc.message
            return None
    else:
        with ctrl_c_deferred():
            bits = P.build_bits(a.indptr, a.indices, kernel_data(a), rows, col_map, pre.shape[1])
    return bits, lw, pw, _last_mask(rows.size)


def _pairs_search(st: _State, perm: np.ndarray, layout, root: float, colmax: np.ndarray, deadline: Deadline,
                  stats: dict[str, Any], since) -> tuple[str, float]:
    """Best-first over parallel batches of tuples on the opposite-pairs layout (views > 1, k < 2 views):
    the open tuples in chunks of similar bounds (:class:`camplace.solver._support.frontier.Frontier`), so
    the reported bound (the largest open) falls as the search goes; depth-first (newest chunks)
    while more than ``_DEPTH_FIRST_OPEN`` are open. A batch takes about ``_BATCH_S`` seconds at
    the rate of the previous one (at most a quarter of the time left).

    Returns the status and the bound (in ``st`` units); improvements go to ``st.offer``.
    """
    bits, lw, pw, mask = layout
    k, views = st.k, st.views
    with ctrl_c_deferred():
        lo, hi, left, right, levels = K.build_tree(np.ascontiguousarray(bits[perm]), min(views, k))
    del bits
    planes = K.weight_planes(lw) if st.integer else np.zeros((0, levels.shape[2]), np.uint64)
    total = float(lw.sum())
    stats["time_setup_s"] = since()
    front = Frontier(np.zeros((1, k), dtype=np.int64), np.array([min(root, total)]), _DEPTH_FIRST_OPEN, _CHUNK)
    evaluated = 0

    def expand(tup: np.ndarray, _bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nonlocal evaluated
        with ctrl_c_deferred():
            children, value, leaf, n_made = _expand_pairs(tup, lo, hi, left, right, levels, views, lw, planes, mask,
                                                          total, st.best, st.margin, colmax, pw)
        evaluated += int(n_made)
        return children, value, leaf

    status, open_bound, chunks, _ = best_first(
        front, expand, lambda v, nodes: st.offer(v, [int(perm[lo[x]]) for x in nodes]), lambda: st.best + st.margin,
        deadline, stats, max_open=_FRONTIER_MAX, batch=_BATCH_MIN, batch_min=_BATCH_MIN, batch_max=_BATCH,
        batch_s=_BATCH_S)
    stats.update({"search": "opposite pairs", "bound_evaluations": evaluated, "chunks": chunks, "peak_open": int(front.peak),
                  "depth_first_batches": front.lifo_batches,
                  "words": int(levels.shape[2])})
    return status, max(st.best, open_bound)


def _roots_search(st: _State, perm: np.ndarray, root: float, colmax: np.ndarray, deadline: Deadline,
                  stats: dict[str, Any], since) -> tuple[str, float]:
    """Best-first over the open tuples, depth-first below them, in parallel (max coverage, and
    views > 1 on the plain layout).

    The open tuples are kept in small chunks of similar bounds
    (:class:`camplace.solver._support.frontier.Frontier`). Each round pops the best ones (the roots) and runs
    a depth-first search from each root in parallel (``_SLICE`` bound evaluations each for views =
    1, ``_ROOT_BUDGET`` beyond; the cache-friendly order of the serial search); what is left on
    their stacks goes back to the frontier. The reported bound (the frontier's largest) falls as
    the search goes; while more than ``_DEPTH_FIRST_OPEN`` tuples are open the newest chunks are
    taken first (memory). Each round takes twice the roots of the last, up to ``_ROUND_EVALS``
    bound evaluations (:func:`_roots_cap`): a schedule that does not depend on the thread count or
    the timing, so the answer does not either (a tie between two optima is broken by the search
    order). With a time limit a round is cut to about ``_ROUND_S`` seconds and a quarter of the time
    left at the rate of the previous one; the deadline is checked between rounds.

    Small roots keep many cores busy: a round ends with its slowest root, and at 16 threads the
    comet-67p-bunker 10,000 x 50,000 search replayed from its roots' measured times (``_SLICE``
    20,000 with rounds sized by the rate: 5.6x from 2 to 16 threads, where a lent 16-core machine
    measured 5.9x) reaches 6.9x with 2,000 and this schedule (docs/performance.md).

    Returns the status and the bound (in ``st`` units); improvements go to ``st.offer``.
    """
    k, views = st.k, st.views
    with ctrl_c_deferred():
        lo, hi, left, right, levels = K.build_tree(np.ascontiguousarray(st.bits[perm]), min(views, k))
    cap = _dfs_stack(k, perm.size)
    budget = _ROOT_BUDGET if views > 1 else _SLICE
    cap_roots = _roots_cap(budget)
    if views > 1:
        # split the node whose union most exceeds its heaviest column: where the bound is loosest
        # (on comet-67p-bunker, every surface point, 3 views, k = 6: 4.2 times fewer bounds than the largest node)
        union = K.union_weights(levels[0], st.w, st.planes)
        score = union - colmax
    else:  # max coverage: the largest node, as the serial search
        score = np.zeros(0)
    stats["time_setup_s"] = since()
    front = Frontier(np.zeros((1, k), dtype=np.int64), np.array([min(root, st.total)]), _DEPTH_FIRST_OPEN, _ROOT_CHUNK)
    evaluated = rounds = 0
    n_roots = _ROOTS_MIN
    status, open_bound = "optimal", -math.inf
    while front.n_open:
        if deadline.expired() or front.n_open > _FRONTIER_MAX:
            status = "feasible"
            open_bound = front.top()
            stats["stopped"] = "time limit" if deadline.expired() else "open tuples"
            break
        roots, _ = front.pop_batch(n_roots, st.best + st.margin)
        if roots.shape[0] == 0:
            continue
        rounds += 1
        t_round = time.perf_counter()
        with ctrl_c_deferred():
            stacks, bounds, found, pos, n_made, overflow = _dfs_roots(
                roots, lo, hi, left, right, levels, views, st.w, st.planes, st.mask, st.total, st.best, st.margin, colmax,
                0, budget, cap, score)
        if overflow:
            raise RuntimeError("bitset search stack overflow")  # cannot happen: depth <= k * log2(n) levels
        # next round: twice as many roots, up to the cap (the same schedule at every thread count);
        # with a time limit at most what the bounds-per-second just seen do in _ROUND_S seconds
        # and in a quarter of the time left, if that is fewer (near the deadline only, as a rule)
        n_roots = min(cap_roots, 2 * n_roots)
        left_s = deadline.remaining()
        if left_s is not None:
            rate = int(n_made) / max(time.perf_counter() - t_round, 1e-9)
            n_roots = max(_ROOTS_MIN, min(n_roots, int(min(_ROUND_S, 0.25 * left_s) * rate / budget)))
        evaluated += int(n_made)
        f = int(np.argmax(found))
        if found[f] > st.best:
            st.offer(float(found[f]), [int(perm[p]) for p in pos[f]])
        front.push(stacks, bounds, np.zeros(bounds.shape, dtype=np.bool_), st.best + st.margin)
    stats.update({"search": "best-first roots, depth-first below",
                  "bound_evaluations": evaluated, "rounds": rounds, "peak_open": int(front.peak),
                  "depth_first_rounds": front.lifo_batches, "words": int(levels.shape[2])})
    return status, max(st.best, open_bound)


def _roots_cap(budget: int) -> int:
    """Roots of one round at most for a per-root ``budget`` of bound evaluations: ``_ROUND_EVALS``
    evaluations, between ``_ROOTS_MIN`` and ``_ROOTS_MAX`` roots."""
    return min(_ROOTS_MAX, max(_ROOTS_MIN, _ROUND_EVALS // max(1, budget)))


def _dfs_stack(k: int, n: int) -> int:
    """Stack entries a depth-first search over k-tuples of an n-leaf bisection tree needs at most:
    every split pushes at most k + 1 children, and a path has at most k ceil(log2 n) splits."""
    return (k + 1) * (k * max(1, math.ceil(math.log2(max(n, 2)))) + 1)


def _row_entries(bits: np.ndarray, m: int) -> np.ndarray:
    """(m,) int64: the columns of column bitsets ``bits`` ((n, ceil(m / 64)) uint64) observing each row."""
    out = np.zeros(m, dtype=np.int64)
    for c in range(bits.shape[0]):
        out += np.unpackbits(bits[c].view(np.uint8), bitorder="little", count=m)
    return out


def solve_bitset(pre: Presolved, *, views: int = 1, deadline: Deadline | None = None,
                 start: tuple[int, ...] | None = None) -> EngineOutcome:
    """Choose ``pre.k`` columns maximising the weight of rows observed by at least ``views`` of them.

    Parameters
    ----------
    pre : Presolved
        Output of :func:`camplace.solver.problem.presolve.presolve` (for ``views > 1`` without column
        dominance, which is only valid for ``views = 1``).
    views : int
        Chosen columns a row needs (1: max coverage).
    deadline : Deadline, optional
        The solve's deadline (default: none); on expiry the incumbent is returned with status
        "feasible" and a valid bound. The stats' times count from this call.
    start : tuple of int, optional
        ``k`` reduced column indices found elsewhere (e.g. by
        :func:`camplace.solver.engines.large_k.search.views_incumbent`): the first incumbent, instead of the
        engine's own greedy + swap.

    Returns
    -------
    EngineOutcome
        Reduced column indices, status, bound (original weight units) and stats.
    """
    bind_search_kernel()  # before the incumbent's kernels load their copies of the helpers
    deadline = as_deadline(deadline)
    since = stopwatch(deadline)
    k = pre.k
    m, n = pre.shape
    if views < 1:
        raise ValueError("views must be >= 1")
    if m == 0 or n <= k:
        sel = tuple(range(min(k, n)))
        # n == k: every column is chosen, so a row's views are its entries in the reduced matrix
        value = float(pre.weights[_row_entries(pre.bits, m) >= views].sum()) if n <= k else 0.0
        return EngineOutcome(selected=sel, status="optimal", bound=value, stats={"trivial": True})

    st = _State(pre, views)
    stats: dict[str, Any] = {"arithmetic": "integer" if st.integer else "float64", "views": views, "words": st.n_words,
                             "time_bitsets_s": since()}
    if start is not None and len(set(start)) == k:
        st.offer(st.value(list(start)), list(start))
    else:
        st.incumbent()
    stats["initial_incumbent"] = st.best * st.scale
    stats["time_incumbent_s"] = since() - stats["time_bitsets_s"]
    left = deadline.remaining()
    if left is not None and left <= _TREE_COST * stats["time_bitsets_s"]:
        # no time for the search's set-up (compiled, not interruptible): the incumbent, the trivial bound
        stats.update({"time_setup_s": since(), "bound_evaluations": 0, "skipped": "time limit"})
        return _finish(st, "feasible", st.total, stats, since, m, n)
    with ctrl_c_deferred():
        perm = K.bisection_order(st.bits)
    layout = _pair_layout(pre, views, deadline, stats) if 1 < views and k < 2 * views else None
    lo, hi, left, right = K.tree_shape(n)
    # views > 1: per node the largest column weight (m x value <= the chosen columns' weights)
    colmax = np.zeros(0)
    if views > 1:
        f = st.column_weights[perm]
        colmax = np.empty(lo.shape[0])
        for v in range(lo.shape[0] - 1, -1, -1):
            colmax[v] = f[lo[v]] if left[v] < 0 else max(colmax[left[v]], colmax[right[v]])
    if layout is not None:
        root = min(st.total, float(np.sort(f)[-k:].sum()) / views)
        status, bound = _pairs_search(st, perm, layout, root, colmax, deadline, stats, since)
        return _finish(st, status, bound, stats, since, m, n)
    # best-first roots, depth-first below, in parallel (the plain layout)
    root = min(st.total, float(np.sort(f)[-k:].sum()) / views) if views > 1 else st.total
    status, bound = _roots_search(st, perm, root, colmax, deadline, stats, since)
    return _finish(st, status, bound, stats, since, m, n)


def _finish(st: _State, status: str, bound: float, stats: dict[str, Any], since, m: int,
            n: int) -> EngineOutcome:
    if bound <= st.best + st.margin:
        status, bound = "optimal", st.best
    stats["time_search_s"] = since() - stats["time_setup_s"]
    log.info("bitset: k=%d views=%d on %dx%d, %s value %.9g bound %.9g, %d bound evaluations, %.3f s", st.k, st.views,
             m, n, status, st.best * st.scale, bound * st.scale, stats["bound_evaluations"], since())
    return EngineOutcome(selected=st.best_set, status=status, bound=float(bound) * st.scale, stats=stats)
