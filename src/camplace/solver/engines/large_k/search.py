"""Engine for many cameras (k > 4): local search, a Lagrangian bound, reduced-cost fixing, and an
exact search of what is left.

Objective (``maxcover`` is the 0/1 case): ``value(S) = sum_i max_{j in S} wq_ij`` for ``k``
columns ``S``, with ``wq_ij = w_i Q_ij``.

* **Incumbent.** Greedy, then 1-swap local search: for every position of the chosen set the best
  replacement over all columns is found with one pass over the matrix (per row the best and second
  best chosen values give the set without that position). The Lagrangian columns (below) seed a
  second greedy + swap run.
* **Bound.** The linear relaxation of the k-median formulation (``z_ij <= x_j``,
  ``sum_j z_ij <= 1``, ``sum_j x_j = k``), through its Lagrangian dual: for multipliers
  ``lam >= 0``, ``L(lam) = sum_i lam_i + (sum of the k largest rho_j)``,
  ``rho_j = sum_i max(0, wq_ij - lam_i)``, is an upper bound on every k-set. The multipliers start
  at the incumbent's per-row values (so the first bound is "incumbent + the k largest marginal
  gains", the submodular bound) and follow projected subgradient steps (Polyak step towards the
  incumbent, halved when the bound stalls). Any ``lam`` gives a valid bound, so stopping at the
  time limit keeps it valid.
* **Reduced-cost fixing.** A set containing column ``j`` outside the Lagrangian top k is worth at
  most ``L - rho_(k) + rho_j``; if that cannot beat the incumbent, ``j`` is dropped. A top-k column
  ``j`` with ``L - rho_j + rho_(k+1)`` below the incumbent is in every better set and is fixed.
* **Exact rest.** With the fixed columns' values as the base, the surviving columns form a residual
  instance with ``k - |fixed|`` columns to choose; it goes to the exact engines (the bitset engine
  for 0/1 values, the quantised tree for qualities), which are exact for any k and return a valid
  bound at the time limit. The answer's bound is ``min(L, max(incumbent, base + residual bound))``.
* **Memory.** :func:`large_k_bytes` (a CSC copy with weighted values, a few row and column vectors)
  is checked by the caller before the engine runs; the residual engines check their own estimate
  and are skipped (bound = Lagrangian) when they do not fit.

Multiview (``views`` sightings per point) has no useful linear relaxation (on comet-67p-bunker with
every surface point, 3 views, k = 6, it is no better than the k heaviest columns / ``views``), so
:func:`run_large_k` combines :func:`views_incumbent` (the same local search with exact m-view
values) with the bitset engine of :mod:`camplace.solver.engines.bitset.search` started from its set (it
proves that instance, 2,000 x 10,000, with 5 million bounds in 20-30 s of CPU), and, under ``auto``
on sparse enough merged rows, SCIP hinted with the best set.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace.solver._support.deadline import Deadline, as_deadline, stopwatch
from camplace.solver._support.memory import memory_budget_bytes
from camplace.solver.engines.large_k import _kernels as LK
from camplace.solver.result import EngineOutcome

__all__ = ["solve_large_k", "large_k_bytes", "views_incumbent", "LARGE_K_MAX"]

log = logging.getLogger(__name__)

LARGE_K_MAX = 8  # auto uses this engine for 4 < k <= LARGE_K_MAX
_MARGIN = 1e-9  # relative to the total weight: pruning margin for floating-point sums
_SWAP_ROUNDS = 100
_LAGR_CHUNK = 100  # subgradient steps between rounds of perturbed local search
_LAGR_STALL = 15  # steps without a better bound before the step factor is halved
_LAGR_MIN_STEP = 1e-4
_ILS_TRIES = 5  # perturbed local-search runs per round
_ILS_PATIENCE = 30  # stop after this many runs without improvement once the bound has converged
_RESIDUAL_MAX_COLS = 400  # the exact residual search: at most this many surviving columns for k <= 4 left ...
_RESIDUAL_MAX_SETS = 10**8  # ... or at most this many subsets of them


def large_k_bytes(m: int, n: int, nnz: int, pattern: bool = False) -> int:
    """Working memory for an (m, n) instance with ``nnz`` entries: the input's float64 CSC copy
    (12 bytes an entry), 64-bit row indices and weighted values (16) and their temporaries (16),
    and about a dozen row and column vectors. With ``pattern`` (the caller's CSC pattern arrays,
    :func:`run_large_k`): the weighted values alone (8 bytes an entry) and the vectors."""
    return (8 if pattern else 48) * int(nnz) + 8 * (n + 1) + 12 * 8 * (int(m) + int(n))


class _IteratedSearch:
    """The perturbation step shared by the local searches (subclasses give ``n``, ``greedy`` and ``swap``)."""

    n: int

    def perturb(self, sel: list[int], k: int, rng: np.random.Generator, deadline: Deadline) -> tuple[list[int], float]:
        """One iterated-local-search step: drop two chosen columns, refill one greedily and one at
        random, then swap to a local optimum."""
        cand = list(sel)
        for t in sorted(rng.choice(k, size=min(2, k), replace=False).tolist(), reverse=True):
            cand.pop(t)
        if len(cand) < k - 1:
            cand = self.greedy(cand, k - 1)
        pick = int(rng.integers(self.n))
        while pick in cand:
            pick = int(rng.integers(self.n))
        return self.swap(cand + [pick], deadline)


class _Quality(_IteratedSearch):
    """A CSC matrix with weighted values and the local search over it."""

    def __init__(self, matrix: sp.spmatrix, weights: np.ndarray) -> None:
        qc = sp.csc_matrix(matrix, dtype=np.float64)
        qc.sum_duplicates()
        qc.sort_indices()
        self.m, self.n = qc.shape
        w = np.asarray(weights, dtype=np.float64)
        self.indptr = qc.indptr.astype(np.int64)
        self.indices = qc.indices.astype(np.int64)
        self.wq = np.maximum(qc.data, 0.0) * w[self.indices]
        self.total = float(self.row_max().sum())
        self.margin = _MARGIN * max(self.total, 1e-300)

    @classmethod
    def from_pattern(cls, pattern: tuple[np.ndarray, np.ndarray], m: int, weights: np.ndarray) -> "_Quality":
        """The same object as ``_Quality(matrix of ones, weights)`` from the pattern's CSC arrays
        (:func:`run_large_k`'s ``pattern``; kept, not copied): ``wq = w[indices]`` (8 bytes an entry)."""
        self = cls.__new__(cls)
        self.indptr, self.indices = pattern
        self.m, self.n = int(m), self.indptr.size - 1
        self.wq = np.asarray(weights, dtype=np.float64)[self.indices]
        self.total = float(self.row_max().sum())
        self.margin = _MARGIN * max(self.total, 1e-300)
        return self

    def row_max(self) -> np.ndarray:
        """(m,) float64: each row's largest weighted value (0 if unobserved)."""
        out = np.zeros(self.m)
        np.maximum.at(out, self.indices, self.wq)
        return out

    def value(self, sel: list[int] | tuple[int, ...]) -> float:
        with ctrl_c_deferred():
            return float(LK.value_quality(self.indptr, self.indices, self.wq, np.asarray(sel, dtype=np.int64), self.m)[0])

    def gains(self, cur: np.ndarray) -> np.ndarray:
        with ctrl_c_deferred():
            return LK.gains(self.indptr, self.indices, self.wq, cur)

    def greedy(self, start: list[int], k: int, cur: np.ndarray | None = None) -> list[int]:
        """Complete ``start`` greedily to ``k`` columns."""
        sel = list(start)
        with ctrl_c_deferred():
            base = LK.value_quality(self.indptr, self.indices, self.wq, np.asarray(sel, dtype=np.int64), self.m)[1]
        if cur is not None:
            base = np.maximum(base, cur)
        while len(sel) < k:
            g = self.gains(base)
            g[sel] = -np.inf
            j = int(np.argmax(g))
            sel.append(j)
            s, e = self.indptr[j], self.indptr[j + 1]
            base[self.indices[s:e]] = np.maximum(base[self.indices[s:e]], self.wq[s:e])
        return sel

    def swap(self, sel: list[int], deadline: Deadline, rounds: int = _SWAP_ROUNDS) -> tuple[list[int], float]:
        """First-improvement 1-swap local search (every position tried against every column)."""
        sel = list(sel)
        k = len(sel)
        idx = np.asarray(sel, dtype=np.int64)
        with ctrl_c_deferred():
            val, b1, b2, a1 = LK.value_quality(self.indptr, self.indices, self.wq, idx, self.m)
        for _ in range(rounds):
            improved = False
            for t in range(k):
                if deadline.expired():
                    return sel, float(val)
                cur = np.where(a1 == t, b2, b1)
                g = self.gains(cur)
                g[sel] = -np.inf
                j = int(np.argmax(g))
                new = float(cur.sum()) + float(g[j])
                if new > val + self.margin:
                    sel[t] = j
                    idx = np.asarray(sel, dtype=np.int64)
                    with ctrl_c_deferred():
                        val, b1, b2, a1 = LK.value_quality(self.indptr, self.indices, self.wq, idx, self.m)
                    improved = True
            if not improved:
                break
        return sel, float(val)



class _Views(_IteratedSearch):
    """A 0/1 CSC pattern and the local search for "observed by at least ``views`` chosen columns"."""

    def __init__(self, matrix: sp.spmatrix, weights: np.ndarray, views: int) -> None:
        pc = sp.csc_matrix(matrix)
        pc.sum_duplicates()
        pc.sort_indices()
        pos = pc.data > 0
        self.m, self.n = pc.shape
        rows = pc.indices[pos].astype(np.int64)
        cols = np.repeat(np.arange(self.n, dtype=np.int64), np.diff(pc.indptr))[pos]
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(cols, minlength=self.n))]).astype(np.int64)
        self.indices = rows
        self.w = np.asarray(weights, dtype=np.float64)
        self.views = int(views)
        self.margin = _MARGIN * max(float(self.w.sum()), 1e-300)

    @classmethod
    def from_pattern(cls, pattern: tuple[np.ndarray, np.ndarray], m: int, weights: np.ndarray, views: int) -> "_Views":
        """The same object as ``_Views(matrix, weights, views)`` from the pattern's CSC arrays
        (:func:`run_large_k`'s ``pattern``; kept, not copied)."""
        self = cls.__new__(cls)
        self.indptr, self.indices = pattern
        self.m, self.n = int(m), self.indptr.size - 1
        self.w = np.asarray(weights, dtype=np.float64)
        self.views = int(views)
        self.margin = _MARGIN * max(float(self.w.sum()), 1e-300)
        return self

    def counts(self, sel: list[int]) -> np.ndarray:
        with ctrl_c_deferred():
            return LK.view_counts(self.indptr, self.indices, np.asarray(sel, dtype=np.int64), self.m)

    def value(self, sel: list[int] | tuple[int, ...]) -> float:
        return float(self.w[self.counts(list(sel)) >= self.views].sum())

    def _scores(self, row_gain: np.ndarray) -> np.ndarray:
        with ctrl_c_deferred():
            return LK.view_gains(self.indptr, self.indices, row_gain)

    def greedy(self, start: list[int], k: int) -> list[int]:
        """Complete ``start`` to ``k`` columns; a row's score rewards reaching ``views`` and, a
        little, getting closer to it."""
        sel = list(start)
        cnt = self.counts(sel).astype(np.float64)
        v = self.views
        while len(sel) < k:
            g = self._scores(self.w * np.where(cnt + 1 >= v, (cnt + 1 == v) * 1.0, 1e-3 * (cnt + 1) / v))
            g[sel] = -np.inf
            j = int(np.argmax(g))
            sel.append(j)
            cnt[self.indices[self.indptr[j] : self.indptr[j + 1]]] += 1
        return sel

    def swap(self, sel: list[int], deadline: Deadline, rounds: int = _SWAP_ROUNDS) -> tuple[list[int], float]:
        """First-improvement 1-swap local search (exact values)."""
        sel = list(sel)
        cnt = self.counts(sel)
        v = self.views
        val = float(self.w[cnt >= v].sum())
        for _ in range(rounds):
            improved = False
            for t in range(len(sel)):
                if deadline.expired():
                    return sel, val
                c = cnt.copy()
                c[self.indices[self.indptr[sel[t]] : self.indptr[sel[t] + 1]]] -= 1
                g = self._scores(self.w * (c == v - 1))
                g[sel] = -np.inf
                j = int(np.argmax(g))
                new = float(self.w[c >= v].sum()) + float(g[j])
                if new > val + self.margin:
                    c[self.indices[self.indptr[j] : self.indptr[j + 1]]] += 1
                    sel[t], cnt, val = j, c, new
                    improved = True
            if not improved:
                break
        return sel, float(self.w[cnt >= v].sum())



def views_incumbent(matrix: sp.spmatrix, weights: np.ndarray, k: int, views: int, *, deadline: Deadline | None = None,
                    seed: int = 0, patience: int = 10,
                    prepared: _Views | None = None) -> tuple[tuple[int, ...], float, dict[str, Any]]:
    """A good k-set for m-view coverage: greedy, 1-swap local search, then perturbed local search
    until ``deadline`` or ``patience`` runs without improvement.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix
        Values > 0 mean "observes".
    weights : (m,) float64
    k, views : int
    deadline : Deadline, optional
        When to stop (default: no limit).
    seed : int
        Seed of the perturbations.
    patience : int
        Perturbed runs without improvement before it stops.
    prepared : _Views, optional
        The same instance already converted (saves a copy of the matrix).

    Returns
    -------
    selected : tuple of int
        Column indices (sorted).
    value : float
        Weight of the rows observed by at least ``views`` of them.
    stats : dict
    """
    deadline = as_deadline(deadline)
    clock = stopwatch(deadline)
    vs = prepared if prepared is not None else _Views(matrix, weights, views)
    if vs.n <= k:
        sel = list(range(vs.n))
        return tuple(sel), vs.value(sel), {"local_search_tries": 0}
    sel, best = vs.swap(vs.greedy([], k), deadline)
    first = best
    rng = np.random.default_rng(seed)
    tries = since = 0
    while since < patience and not deadline.expired():
        cand, v = vs.perturb(sel, k, rng, deadline)
        tries += 1
        since += 1
        if v > best + vs.margin:
            sel, best, since = cand, v, 0
    return tuple(sorted(sel)), best, {"greedy_swap": first, "local_search": best, "local_search_tries": tries,
                                      "time_local_search_s": clock()}


class _Lagrangian:
    """Projected subgradient on the k-median Lagrangian dual, resumable (:meth:`run`).

    Attributes
    ----------
    bound : float
        The best (smallest) ``L(lam)`` seen: an upper bound on every k-set.
    rho : (n,) float64
        The column values at that point.
    converged : bool
        The step has become negligible (more steps would not move the bound).
    """

    def __init__(self, qs: _Quality, k: int, lam: np.ndarray) -> None:
        self.qs, self.k, self.lam = qs, k, lam.copy()
        self.bound, self.rho = math.inf, np.zeros(qs.n)
        self.theta, self.stall, self.iterations = 1.0, 0, 0
        self.converged = False

    def run(self, best: float, deadline: Deadline, iterations: int) -> None:
        """Up to ``iterations`` steps with a Polyak step towards ``best`` (the incumbent)."""
        qs, k = self.qs, self.k
        for _ in range(iterations):
            self.iterations += 1
            with ctrl_c_deferred():
                rho = LK.gains(qs.indptr, qs.indices, qs.wq, self.lam)
            top = np.argpartition(-rho, k - 1)[:k] if k < qs.n else np.arange(qs.n)
            bound = float(self.lam.sum() + rho[top].sum())
            if bound < self.bound - 1e-12 * max(1.0, abs(bound)):
                self.bound, self.rho, self.stall = bound, rho, 0
            else:
                self.stall += 1
                if self.stall >= _LAGR_STALL:
                    self.theta, self.stall = self.theta / 2, 0
            self.converged = self.theta < _LAGR_MIN_STEP
            if self.bound <= best + qs.margin or self.converged or deadline.expired():
                return
            with ctrl_c_deferred():
                g = 1.0 - LK.hits_quality(qs.indptr, qs.indices, qs.wq, self.lam, top.astype(np.int64), qs.m)
            g[(self.lam <= 0) & (g > 0)] = 0.0  # projection onto lam >= 0
            gn = float(g @ g)
            if gn <= 0:  # lam is optimal for the dual
                self.converged = True
                return
            step = self.theta * max(bound - best, 1e-6 * max(best, 1e-300)) / gn
            self.lam = np.maximum(0.0, self.lam - step * g)


def _fixing(rho: np.ndarray, bound: float, k: int, best: float, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Reduced-cost fixing: (columns that may be in a better set, columns in every better set)."""
    n = rho.shape[0]
    order = np.argsort(-rho, kind="stable")
    in_top = np.zeros(n, dtype=bool)
    in_top[order[:k]] = True
    kth = rho[order[k - 1]]
    nxt = rho[order[k]] if k < n else 0.0
    with_j = np.where(in_top, bound, bound - kth + rho)
    keep = with_j > best + margin
    without_j = bound - rho + nxt
    forced = in_top & (without_j <= best + margin)
    return keep | forced, forced


def solve_large_k(matrix: sp.spmatrix, weights: np.ndarray, k: int, *, binary: bool = False,
                  deadline: Deadline | None = None, seed: int = 0,
                  pattern: tuple[np.ndarray, np.ndarray] | None = None) -> EngineOutcome:
    """Best ``k`` columns for ``sum_i w_i max_{j in S} Q_ij`` (``binary``: the 0/1 pattern, i.e.
    max coverage).

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix
        Values >= 0 (0 = not observed); with ``binary`` only the pattern counts.
    weights : (m,) float64
        Non-negative row weights.
    k : int
        Columns to choose, ``1 <= k <= n``.
    binary : bool
        Max coverage (every value > 0 counts as 1).
    deadline : Deadline, optional
        The solve's deadline (default: none); on expiry the incumbent comes back with status
        "feasible" and a valid bound. Without a limit the engine stops when the bound has converged and the perturbed local
        search has not improved for a while.
    seed : int
        Seed of the perturbations of the local search.
    pattern : ((n + 1,) int64, (nnz,) int64), optional
        With ``binary``: the CSC ``indptr`` and ``indices`` (sorted in each column) of ``matrix``'s
        pattern, read instead of a float64 CSC copy of ``matrix`` (the same search, 16 bytes an
        entry fewer).

    Returns
    -------
    EngineOutcome
        ``selected`` are column indices of ``matrix``; ``bound`` an upper bound on the optimum.
    """
    deadline = as_deadline(deadline)
    clock = stopwatch(deadline)
    if binary and pattern is not None:
        qs = _Quality.from_pattern(pattern, matrix.shape[0], weights)
    else:
        a = sp.csc_matrix(matrix, dtype=np.float64, copy=True)
        if binary:
            a.data = (a.data > 0).astype(np.float64)
        a.eliminate_zeros()
        qs = _Quality(a, weights)
        del a  # qs holds its own arrays
    m, n = qs.m, qs.n
    if not 1 <= k <= n:
        raise ValueError("k must be between 1 and the number of columns")
    stats: dict[str, Any] = {"k": k, "binary": binary}
    if n == k:
        sel = list(range(n))
        v = qs.value(sel)
        return EngineOutcome(selected=tuple(sel), status="optimal", bound=v, stats=dict(stats, trivial=True))

    sel, best = qs.swap(qs.greedy([], k), deadline)
    stats["initial_incumbent"] = best
    stats["time_incumbent_s"] = clock()
    total = qs.total
    if best >= total - qs.margin:  # everything is served at its best: optimal
        stats["time_s"] = clock()
        return EngineOutcome(selected=tuple(sorted(sel)), status="optimal", bound=best, stats=stats)

    with ctrl_c_deferred():
        lam = LK.value_quality(qs.indptr, qs.indices, qs.wq, np.asarray(sel, dtype=np.int64), m)[1]
    rng = np.random.default_rng(seed)
    lag = _Lagrangian(qs, k, lam)
    tries = since = 0
    rounds = 0
    residual = None
    while True:  # alternate: subgradient steps (towards the incumbent), then perturbed local search
        rounds += 1
        lag.run(best, deadline, _LAGR_CHUNK)
        if lag.bound <= best + qs.margin or deadline.expired():
            break
        if rounds == 1:  # Lagrangian heuristic: greedy + swap from the Lagrangian's favourite columns
            cand, v = qs.swap([int(j) for j in np.argsort(-lag.rho, kind="stable")[:k]], deadline)
            stats["lagrangian_heuristic"] = v
            if v > best + qs.margin:
                sel, best = cand, v
        keep, forced = _fixing(lag.rho, lag.bound, k, best, qs.margin)
        if _affordable(int((keep & ~forced).sum()), k - int(forced.sum())):
            residual = (keep, forced)  # small enough for the exact search: no more heuristics needed
            break
        for _ in range(_ILS_TRIES):
            if deadline.expired():
                break
            cand, v = qs.perturb(sel, k, rng, deadline)
            tries += 1
            since += 1
            if v > best + qs.margin:
                sel, best, since = cand, v, 0
        if lag.converged and since >= _ILS_PATIENCE:
            break
    bound = min(lag.bound, total)
    stats.update({"lagrangian_iterations": lag.iterations, "lagrangian_bound": lag.bound, "lagrangian_step": lag.theta,
                  "local_search_tries": tries, "time_lagrangian_s": clock()})
    status = "optimal" if bound <= best + qs.margin else "feasible"
    if status == "feasible" and not deadline.expired():
        keep, forced = residual if residual is not None else _fixing(lag.rho, lag.bound, k, best, qs.margin)
        stats.update({"cols_kept": int(keep.sum()), "cols_forced": int(forced.sum())})
        got = _residual(qs, keep, forced, k, best, binary, deadline, stats)
        if got is not None:
            rsel, rval, rbound = got
            if rval > best + qs.margin:
                sel, best = rsel, rval
            bound = min(bound, max(best, rbound))
            if bound <= best + qs.margin:
                status = "optimal"
    if status == "optimal":
        bound = best
    stats["time_s"] = clock()
    log.info("large-k: k=%d on %dx%d, %s value %.9g bound %.9g, %.3f s", k, m, n, status, best, bound, clock())
    return EngineOutcome(selected=tuple(sorted(int(j) for j in sel)), status=status, bound=float(bound), stats=stats)


def _affordable(n_free: int, k_left: int) -> bool:
    """The exact residual search is worth running: few subsets, or few columns to choose."""
    if k_left <= 0 or n_free < k_left:
        return True
    return math.comb(n_free, k_left) <= _RESIDUAL_MAX_SETS or (k_left <= 4 and n_free <= _RESIDUAL_MAX_COLS)


def _residual(qs: _Quality, keep: np.ndarray, forced: np.ndarray, k: int, best: float, binary: bool,
              deadline: Deadline, stats: dict[str, Any]) -> tuple[list[int], float, float] | None:
    """Exact search over the surviving columns with the forced ones fixed: (set, value, bound of
    every set within the survivors), or None when it does not run (too many columns, no memory)."""
    from camplace.solver.engines.bitset.search import bitset_bytes, solve_bitset
    from camplace.solver.engines.quality.tree import quality_tree_bytes, solve_quality_tree
    from camplace.solver.problem.presolve import presolve

    fixed = np.flatnonzero(forced)
    free = np.flatnonzero(keep & ~forced)
    kr = k - fixed.size
    if kr <= 0 or free.size < kr:
        # every better set would need more forced columns than k, or more columns than survive
        sel = [int(j) for j in fixed[:k]]
        if free.size < kr or fixed.size > k:
            stats["residual"] = "no better set exists"
            return sel + [int(j) for j in free][: max(0, k - len(sel))], best if len(sel) < k else qs.value(sel), best
        v = qs.value(sel)
        return sel, v, v
    if not _affordable(free.size, kr):
        stats["residual"] = f"skipped: {free.size} columns survive the fixing, {kr} to choose"
        return None
    with ctrl_c_deferred():
        base = LK.value_quality(qs.indptr, qs.indices, qs.wq, fixed.astype(np.int64), qs.m)[1]
    const = float(base.sum())
    sub = sp.csc_matrix((qs.wq, qs.indices, qs.indptr), shape=(qs.m, qs.n))[:, free].tocsr()
    if binary:
        sub = sub[base <= 0]  # rows the fixed columns already cover add nothing
        w = np.asarray(sub.max(axis=1).toarray()).ravel() if sub.shape[0] else np.zeros(0)
        sub = (sub > 0).astype(np.float64).tocsr()
        need = bitset_bytes(sub.shape[0], free.size, 1, kr)
    else:
        sub = sub.tocoo()
        d = np.maximum(sub.data - base[sub.row], 0.0)
        sub = sp.csr_matrix((d, (sub.row, sub.col)), shape=sub.shape)
        sub.eliminate_zeros()
        w = np.ones(qs.m)
        need = quality_tree_bytes(qs.m, free.size, sub.nnz)
    if need > memory_budget_bytes():
        stats["residual"] = f"skipped: needs {need / 2**30:.1f} GiB"
        return None
    if sub.nnz == 0:
        sel = [int(j) for j in fixed] + [int(j) for j in free[:kr]]
        return sel, qs.value(sel), const
    if binary:
        pre = presolve(sub, w, kr, deadline=deadline)
        out = solve_bitset(pre, deadline=deadline)
        local = pre.original_columns(out.selected)
    else:
        out = solve_quality_tree(sub, w, kr, deadline=deadline)
        local = out.selected
    sel = [int(j) for j in fixed] + [int(free[j]) for j in local]
    v = qs.value(sel)
    stats["residual"] = {"columns": int(free.size), "k": int(kr), "status": out.status, "bound": const + float(out.bound),
                         "engine_stats": out.stats}
    return sel, v, const + float(out.bound)


# maxcover under auto: this share of the time (this many seconds without a limit) for solve_large_k, the rest for
# SCIP, whose LP and branching prove max coverage better (bilobed corridor 10,000 x 2,000, k = 6: SCIP alone 4.7 s,
# after half of a 40 s limit here 24.5 s), while greedy + swaps prove it at once when they see every coverable point
_MAXCOVER_SHARE = 0.1
_MAXCOVER_FIRST_S = 5.0
_VIEWS_SHARE = 0.15  # multiview: this share of the time for the local search, ...
_VIEWS_SEARCH_SHARE = 0.4  # ... then this share of the rest for the bitset search (under auto SCIP gets the rest ...
# ... when the merged rows have at most this many entries: on comet-67p-bunker 2,000 x 10,000, k = 6, 3 views, the
# lit side (2.4e6) got its gap from 0.22 % to 0.12 % that way before the bitset search for views > 1 improved (it now
# proves it within its share, 25 s in all); with every surface point (6.3e6) SCIP's root LP does not finish in a
# minute, overruns the time limit by 10 s and takes 3 GB, for no better bound
_VIEWS_SCIP_MAX_NNZ = 4_000_000


def _views_scip(pre: Any, views: int, k: int, start: tuple[int, ...],
                deadline: Deadline) -> tuple[tuple[int, ...] | None, str, float, dict[str, Any]]:
    """SCIP on the merged rows of a presolved m-view instance (``views y_r <= sum_{j in r} x_j``,
    ``sum x = k``, y binary), hinted with ``start`` and stopped at ``deadline`` (building
    included): (reduced columns or None, status, bound, stats)."""
    from camplace.solver.engines.mip.linear import LinearModel, solve_model

    a, wr = pre.matrix, pre.weights
    wmax = float(wr.max()) if wr.size and wr.max() > 0 else 1.0
    model = LinearModel(maximize=True)
    x = model.add_vars(pre.shape[1])
    model.add_row(x, np.ones(pre.shape[1]), float(k), float(k))
    y = model.add_vars(pre.shape[0], obj=wr / wmax)
    for r in range(pre.shape[0]):
        if (r & 255) == 0 and deadline.expired():
            return None, "unknown", math.inf, {"model_build": "interrupted by the time limit"}
        cols = a.indices[a.indptr[r] : a.indptr[r + 1]]
        model.add_row(np.append(x[cols], y[r]), np.append(np.ones(cols.size), -float(views)), lo=0.0)
    chosen = set(start)
    out = solve_model(model, "mip", deadline=deadline,
                      hint={int(x[j]): (1.0 if j in chosen else 0.0) for j in range(pre.shape[1])})
    sel = None
    if out.values is not None:
        sel = tuple(int(j) for j in np.flatnonzero(out.values[x] > 0.5))
        if len(sel) != k:
            sel = None
    bound = out.bound * wmax if math.isfinite(out.bound) else math.inf
    return sel, out.status, bound, dict(out.stats)


def run_large_k(resid: sp.csr_matrix, resid_w: np.ndarray, k: int, mode: str, views: int, engine: str,
                deadline: Deadline, stats: dict[str, Any],
                seed: int = 0, pattern: tuple[np.ndarray, np.ndarray] | None = None,
                presolved: Any = None) -> EngineOutcome | None:
    """The engines for ``4 < k <= LARGE_K_MAX`` behind :func:`camplace.solver.api.solve`.

    ``maxcover`` and ``quality``: :func:`solve_large_k` (under ``auto``, maxcover gets a tenth of
    the time there, 5 s without a limit, and SCIP the rest on the presolved instance; the better set
    and the smaller bound are kept).
    ``multiview``: :func:`views_incumbent` for 15 % of the time, then the bitset engine of
    :mod:`camplace.solver.engines.bitset.search` started from that set (under ``auto``, when the merged rows have
    at most ``_VIEWS_SCIP_MAX_NNZ`` entries and SCIP's model fits in memory, for 40 % of the rest,
    then SCIP on the merged rows, hinted with the best set).

    Parameters
    ----------
    resid : (m, n) scipy.sparse.csr_matrix
        The residual instance on the free columns (qualities for quality, > 0 observes otherwise).
    resid_w : (m,) float64
    k, views : int
    mode : {"maxcover", "quality", "multiview"}
    engine : {"auto", "exact"}
        ``exact``: an engine that does not fit in memory is a one-line error.
    deadline : Deadline
        The solve's deadline (the shares above are of the time left at the call).
    stats : dict
        Filled with ``engine_stats`` (and ``memory_fallback`` when the engine is skipped).
    seed : int
        Seed of the local searches' perturbations.
    pattern : ((n + 1,) int64, (nnz,) int64), optional
        maxcover and multiview: the CSC ``indptr`` and ``indices`` (sorted in each column) of
        ``resid``'s pattern, made by the caller (the bits route, from column bitsets): the local
        searches read them instead of their own copies of ``resid`` (the same searches; their
        memory is then the weighted values alone, :func:`large_k_bytes` with ``pattern``).
    presolved : camplace.solver.problem.presolve.Presolved, optional
        A presolve for ``k`` (multiview: without dominance) whose REDUCED instance is ``resid``
        (rows and columns in its reduced order; the bits route's), given to the bitset engine and
        SCIP instead of presolving ``resid``; their answers are then already ``resid``'s columns.
        With ``pattern`` too, ``resid`` is read only for its ``shape`` and ``nnz`` (the bits route
        passes the reduced :class:`~camplace.visibility.bits.BitMatrix`).

    Returns
    -------
    EngineOutcome or None
        ``selected``: local (free-column) indices; ``bound`` in residual units; ``engine`` the one
        that found the set; ``stats`` the caller's ``stats``. None when the engine does not fit in
        memory under ``auto`` (the caller falls back to its general model).
    """
    from camplace.solver._support.memory import OverBudget, memory_fallback
    from camplace.solver.engines.bitset.search import bitset_bytes, solve_bitset
    from camplace.solver.engines.maxcover import run_maxcover_engine
    from camplace.solver.engines.mip.linear import model_bytes
    from camplace.solver.problem.presolve import presolve

    if presolved is None:  # resid's columns and those of its presolve
        def to_resid(cols) -> tuple[int, ...]:
            return tuple(int(j) for j in pre.original_columns(cols))

        def from_resid(cols) -> tuple[int, ...] | None:
            return pre.reduced_columns(cols)
    else:  # the presolve's reduced instance is resid: the same columns
        def to_resid(cols) -> tuple[int, ...]:
            return tuple(sorted(int(j) for j in cols))

        from_resid = to_resid
    # the steps' slices of the time left now
    views_dl = deadline.share(_VIEWS_SHARE)
    first_dl = deadline.within(_MAXCOVER_FIRST_S) if deadline.limit is None else deadline.share(_MAXCOVER_SHARE)
    m, n = resid.shape
    budget = memory_budget_bytes()
    if mode == "multiview":
        pre = presolve(resid, resid_w, k, dominance=False) if presolved is None else presolved  # (one view only)
        need = bitset_bytes(pre.shape[0], pre.shape[1], min(views, k), k) + large_k_bytes(m, n, resid.nnz,
                                                                                          pattern is not None)
        if need > budget:
            memory_fallback(OverBudget(need, budget, "the exact multiview engine"), stats, asked=engine == "exact",
                            then="falling back to the general model", fix="use engine mip, or fewer candidates / points")
            return None
        vs = _Views(resid, resid_w, views) if pattern is None else _Views.from_pattern(pattern, m, resid_w, views)
        # a counted row uses `views` of the views the k chosen columns give: the k heaviest columns
        # / views caps the bound (the search's open tuples are not capped by their parents')
        with ctrl_c_deferred():
            cap = float(np.sort(LK.view_gains(vs.indptr, vs.indices, vs.w))[-k:].sum()) / views
        start, _, ls = views_incumbent(resid, resid_w, k, views, deadline=views_dl, seed=seed, prepared=vs)
        del vs
        pre_nnz = int(pre.nnz) if hasattr(type(pre), "nnz") else int(pre.matrix.nnz)  # (bits: no CSR to count)
        scip_need = model_bytes("mip", pre.shape[0] + pre.shape[1], pre.shape[0] + 1,
                                pre_nnz + pre.shape[0] + pre.shape[1])
        scip = engine == "auto" and scip_need <= budget and pre_nnz <= _VIEWS_SCIP_MAX_NNZ
        search_dl = deadline.share(_VIEWS_SEARCH_SHARE) if scip else deadline  # SCIP gets the rest if the search does not finish
        out = solve_bitset(pre, views=views, deadline=search_dl, start=from_resid(start))
        sel, status, bound, name = tuple(out.selected), out.status, float(out.bound), "exact"
        es = dict(out.stats, local_search=ls, column_cap=cap)
        if status != "optimal":
            bound = min(bound, max(cap, 0.0))
            if scip and not deadline.expired():
                got = _views_scip(pre, views, k, sel, deadline)
                es["then"] = got[3]
                if got[0] is not None:
                    vs2 = _Views(pre.matrix, pre.weights, views)
                    if vs2.value(got[0]) > vs2.value(sel) + vs2.margin:
                        sel, name = got[0], "mip"
                bound = min(bound, got[2])
                if got[1] == "optimal":
                    status = "optimal"
        stats.update({"rows_after": pre.shape[0], "cols_after": pre.shape[1], "engine_stats": es})
        return EngineOutcome(to_resid(sel), status, bound, stats, engine=name)
    binary = mode == "maxcover"
    need = large_k_bytes(m, n, resid.nnz, binary and pattern is not None)
    if need > budget:
        memory_fallback(OverBudget(need, budget, "the large-k engine"), stats, asked=engine == "exact",
                        then="falling back to the general model", fix="use engine mip, or fewer candidates / points")
        return None
    share = first_dl if mode == "maxcover" and engine == "auto" else deadline
    out = solve_large_k(resid, resid_w, k, binary=binary, deadline=share, seed=seed,
                        pattern=pattern if binary else None)
    stats["engine_stats"] = dict(out.stats)
    sel, status, bound, name = tuple(out.selected), out.status, float(out.bound), "exact"
    if status != "optimal" and mode == "maxcover" and engine == "auto" and not deadline.expired():
        pre = presolve(resid, resid_w, k, deadline=deadline) if presolved is None else presolved
        used, mip = run_maxcover_engine("mip", engine, pre, deadline, stats)
        stats["engine_stats"]["then"] = dict(mip.stats, engine=used)
        if mip.selected and "model_build" not in mip.stats:  # (stopped while building: the greedy answer)
            cand = to_resid(mip.selected)
            vs = _Views(resid, resid_w, 1) if pattern is None else _Views.from_pattern(pattern, m, resid_w, 1)
            if vs.value(cand) > vs.value(sel) + vs.margin:
                sel, name = cand, used
        bound = min(bound, float(mip.bound))
        if mip.status == "optimal":
            status = "optimal"
    return EngineOutcome(sel, status, bound, stats, engine=name)
