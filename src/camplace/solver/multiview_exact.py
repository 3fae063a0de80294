"""Exact bound-pruned engine for stereo coverage: the best 3 (or 2) cameras when a point needs 2 views.

For a triple ``{a, b, c}`` the weight of the points seen by at least two of them is

    value(a, b, c) = G_ab + G_ac + G_bc - 2 T_abc,

with ``G = D^T diag(w) D`` (weighted pair intersections) and ``T_abc = w(a & b & c)``.

The search mirrors the max-coverage tree of :mod:`camplace.solver.exact`. Columns are put in a
bisection order, so similar cameras are adjacent, and a tree over ranges of the first column
``a`` is explored depth-first. A node keeps the rows ``N`` that every camera of its range sees,
and the exact values ``P_bc = G_bc - 2 w_N(b & c)`` of the later columns. Since
``T_abc >= w_N(b & c)`` for every ``a`` of the range,

    value(a, b, c) <= gmax_b + gmax_c + P_bc,   gmax_b = max over a < b in the range of G_ab,

which prunes whole ranges and drops columns with no promising partner. A child subtracts
``2 X^T diag(w) X`` over the rows that became common. At a single column ``N`` is ``a``'s rows and
the bound is the exact value.

Arithmetic and pruning margins are those of :mod:`camplace.solver.exact`: with equal original
weights, everything is exact integer arithmetic in float32. A time limit returns the incumbent
with the largest bound of the nodes still open.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from camplace.solver._blas import limit_blas_threads
from camplace.solver._common import Deadline, EngineOutcome
from camplace.solver.presolve import Presolved

__all__ = ["solve_multiview_exact", "stereo_bytes"]

log = logging.getLogger(__name__)

_INT_EXACT_LIMIT = 1 << 22
_FLOAT_MARGIN = 1e-9
_SWAP_ROUNDS = 50
# OpenBLAS threads during a solve (None: leave BLAS alone). One thread is ~1.3x slower on an idle
# 2-core machine but avoids 5-15x slowdowns when the cores are oversubscribed (see _blas.py).
BLAS_THREADS: int | None = 1


def stereo_bytes(m: int, n: int) -> int:
    """Approximate working memory for ``m`` reduced rows and ``n`` columns: the dense matrix and
    its weighted copy (float32), the pair Gram in several precisions and the per-node pair values."""
    return 8 * m * n + 32 * n * n


def _bisection_order(f: np.ndarray, gram: np.ndarray) -> np.ndarray:
    """Column order from recursive balanced bisection (similar columns end up adjacent).

    A range of size ``s`` is split into its first ``s // 2`` and last ``s - s // 2`` columns, the
    same rule as the search tree.

    Parameters
    ----------
    f : (n,) float64
        Column weights ``w(a)``.
    gram : (n, n) float64
        Weighted intersections ``w(a & b)``.

    Returns
    -------
    (n,) int64
        Permutation of ``0..n-1``.
    """
    out: list[np.ndarray] = []
    stack = [np.arange(f.size, dtype=np.int64)]
    while stack:
        s = stack.pop()
        if s.size <= 2:
            out.append(s[np.argsort(-f[s], kind="stable")])
            continue
        a0 = s[int(np.argmax(f[s]))]
        d0 = f[a0] + f[s] - 2.0 * gram[a0, s]
        s1 = s[int(np.argmax(d0))]
        d1 = f[s1] + f[s] - 2.0 * gram[s1, s]
        s2 = s[int(np.argmax(d1))]
        d2 = f[s2] + f[s] - 2.0 * gram[s2, s]
        idx = np.argsort(d1 - d2, kind="stable")
        half = s.size // 2
        stack.append(s[idx[half:]])  # popped second
        stack.append(s[idx[:half]])  # popped first
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


def _lower(pv: np.ndarray) -> np.ndarray:
    """Keep the strict lower triangle of a square matrix, -inf elsewhere (in place)."""
    pv[np.triu_indices(pv.shape[0])] = -np.inf
    return pv


def _rowcol_max(pv: np.ndarray) -> np.ndarray:
    """Best partner value of each column of a strict-lower-triangular pair matrix."""
    return np.maximum(pv.max(axis=1), pv.max(axis=0))




class _Timeout(Exception):
    pass


class _Stereo:
    """Search state (positions are indices in the bisection order)."""

    def __init__(self, d: np.ndarray, w: np.ndarray, margin: float, deadline: Deadline) -> None:
        self.w = w
        self.dt = d.dtype
        self.margin = margin
        self.deadline = deadline
        self.m, self.n = d.shape
        gram = d.T @ (d * w[:, None])
        f = np.diagonal(gram).astype(np.float64)
        self.order = _bisection_order(f, gram.astype(np.float64))
        self.d = np.ascontiguousarray(d[:, self.order])
        self.g = np.ascontiguousarray(gram[self.order][:, self.order])
        self.best = -math.inf
        self.best_set: tuple[int, ...] = ()
        self.open: dict[int, float] = {}
        self._key = 0
        self.stats: dict[str, Any] = {"tree_nodes": 0, "tree_leaves": 0, "gemms": 0}

    # -- values and incumbent ------------------------------------------------------------------
    def value(self, cols: tuple[int, ...]) -> float:
        cnt = self.d[:, list(cols)].sum(axis=1)
        return float(self.w[cnt >= 2].sum(dtype=np.float64))

    def offer(self, value: float, cols: tuple[int, ...]) -> None:
        """A new incumbent (``cols`` are search positions; ``best_set`` keeps dense columns)."""
        if value > self.best:
            self.best = value
            self.best_set = tuple(sorted(int(self.order[c]) for c in cols))

    def _best_third(self, a: int, b: int) -> tuple[float, int]:
        """Best third column for the pair (a, b): one product over the rows seen exactly once."""
        cnt = self.d[:, a] + self.d[:, b]
        base = float(self.w[cnt >= 2].sum(dtype=np.float64))
        gain = (self.d.T @ np.where(cnt == 1, self.w, 0).astype(self.dt)).astype(np.float64)
        gain[[a, b]] = -1.0
        x = int(np.argmax(gain))
        return base + float(gain[x]), x

    def incumbent(self) -> None:
        """Best third column for the heaviest pairs, then 1-swap local search."""
        pairs = _lower(self.g.astype(np.float64))
        top = np.argsort(pairs, axis=None)[::-1][:8]
        for flat in top:
            a, b = divmod(int(flat), self.n)
            if not np.isfinite(pairs[a, b]):
                continue
            _, c = self._best_third(a, b)
            sel = [a, b, c]
            for _ in range(_SWAP_ROUNDS):
                improved = False
                for p in range(3):
                    others = [sel[q] for q in range(3) if q != p]
                    val, x = self._best_third(*others)
                    if val > self.value(tuple(sel)) + self.margin:
                        sel[p] = x
                        improved = True
                if not improved:
                    break
            self.offer(self.value(tuple(sel)), tuple(sel))
        self.stats["initial_incumbent"] = self.best

    # -- search --------------------------------------------------------------------------------
    def _check(self) -> None:
        if self.deadline.expired():
            raise _Timeout

    def root(self) -> None:
        n = self.n
        cols = np.arange(1, n, dtype=np.int64)
        pv = _lower(self.g[1:, 1:].astype(self.dt, copy=True))
        in_n = np.zeros(self.m, dtype=bool)
        delta = np.flatnonzero(self.d.min(axis=1) > 0)  # rows every camera sees
        self._key += 1
        self.open[self._key] = math.inf
        self.node(0, n - 2, cols, pv, in_n, delta, self._key)

    def node(self, lo: int, hi: int, cols: np.ndarray, pv: np.ndarray, in_n: np.ndarray, delta: np.ndarray,
             key: int) -> None:
        """Explore first columns ``lo..hi-1``; its bound stays in ``open`` if the deadline interrupts."""
        self._node(lo, hi, cols, pv, in_n, delta)
        self.open.pop(key, None)

    def _node(self, lo: int, hi: int, cols: np.ndarray, pv: np.ndarray, in_n: np.ndarray, delta: np.ndarray) -> None:
        self._check()
        self.stats["tree_nodes"] += 1
        j0 = int(np.searchsorted(cols, lo, side="right"))
        if cols.size - j0 < 2:
            return
        cols = cols[j0:]
        pv = pv[j0:, j0:]
        if delta.size:
            x = self.d[delta][:, cols]
            wd = self.w[delta]
            self.stats["gemms"] += 1
            pv = pv - 2 * (x.T @ (x * wd[:, None]))
            in_n = in_n.copy()
            in_n[delta] = True
        firsts = np.arange(lo, hi)
        gsub = self.g[lo:hi][:, cols].astype(np.float64)
        gsub[firsts[:, None] >= cols[None, :]] = -math.inf
        gmax = gsub.max(axis=0)
        bnd = gmax[:, None] + gmax[None, :] + pv.astype(np.float64)  # -inf outside the lower triangle
        rmax = _rowcol_max(bnd)
        bound = float(rmax.max())
        thr = self.best + self.margin
        if bound <= thr:
            return
        if hi - lo == 1:
            self.stats["tree_leaves"] += 1
            flat = int(np.argmax(bnd))
            i, j = divmod(flat, bnd.shape[1])
            self.offer(float(bnd[i, j]), (lo, int(cols[i]), int(cols[j])))
            return
        keep = rmax > thr
        if not keep.all():
            idx = np.flatnonzero(keep)
            cols = cols[idx]
            pv = pv[idx][:, idx]
        mid = lo + (hi - lo) // 2
        children = [(lo, mid), (mid, hi)]
        keys = []
        for _ in children:
            self._key += 1
            keys.append(self._key)
            self.open[self._key] = bound
        free = np.flatnonzero(~in_n)
        for (cl, ch), k in zip(children, keys):
            dchild = free[self.d[free, cl:ch].min(axis=1) > 0] if free.size else free
            self.node(cl, ch, cols, pv, in_n, dchild, k)

    def open_bound(self) -> float:
        return max([self.best, *self.open.values()])


def solve_multiview_exact(pre: Presolved, *, time_limit_s: float | None = None) -> EngineOutcome:
    """Best 3 (or 2) columns of a presolved instance (presolve with ``dominance=False``) when a
    row counts only if at least 2 chosen columns observe it.

    Parameters
    ----------
    pre : Presolved
        Merged rows x all columns; ``pre.k`` must be 3 (the tree search) or 2 (the best pair,
        read off the weighted Gram matrix).
    time_limit_s : float, optional
        On expiry the incumbent comes back with status "feasible" and a valid bound.

    Returns
    -------
    EngineOutcome
        Reduced column indices, status, bound (original weight units) and stats.
    """
    if pre.k not in (2, 3):
        raise ValueError("the stereo engine chooses 2 or 3 cameras")
    with limit_blas_threads(BLAS_THREADS):
        deadline = Deadline(time_limit_s)
        m, n = pre.shape
        k = pre.k
        if n <= k or m == 0:
            return EngineOutcome(selected=tuple(range(min(k, n))), status="optimal",
                                 bound=float(pre.weights[np.diff(pre.matrix.indptr) >= 2].sum()) if n <= k else 0.0,
                                 stats={"trivial": True})
        if k == 2:  # the value of a pair is its weighted intersection: the best off-diagonal Gram entry
            d = pre.matrix.astype(np.float64)
            gram = _lower((d.T @ d.multiply(pre.weights[:, None]).tocsc()).toarray())
            a, b = divmod(int(np.argmax(gram)), n)
            return EngineOutcome(selected=(b, a), status="optimal", bound=float(gram[a, b]),
                                 stats={"pair": True, "time_s": deadline.elapsed()})
        integer = pre.weight_unit is not None and int(pre.counts.sum()) < _INT_EXACT_LIMIT
        if integer:
            d = pre.matrix.astype(np.float32).toarray()
            w = pre.counts.astype(np.float32)
            scale, margin = float(pre.weight_unit), 0.0  # type: ignore[arg-type]
        else:
            d = pre.matrix.toarray()
            w = pre.weights.astype(np.float64)
            scale, margin = 1.0, _FLOAT_MARGIN * float(w.sum())
        cheap = float(w[(d > 0).sum(axis=1) >= 2].sum(dtype=np.float64))
        srch = _Stereo(d, w, margin, deadline)
        del d
        status = "optimal"
        try:
            srch.incumbent()
            srch.root()
            bound = srch.best
        except _Timeout:
            status = "feasible"
            bound = srch.open_bound()
        bound = min(bound, cheap)
        if bound <= srch.best + margin:
            status, bound = "optimal", srch.best
        stats = dict(srch.stats, arithmetic="float32-integer" if integer else "float64", time_s=deadline.elapsed())
        stats["initial_incumbent"] = float(stats.get("initial_incumbent", -math.inf)) * scale
        log.info("stereo exact: %dx%d %s value %.9g bound %.9g, %d nodes, %.3f s", m, n, status,
                 srch.best * scale, bound * scale, stats["tree_nodes"], deadline.elapsed())
        return EngineOutcome(selected=srch.best_set, status=status, bound=float(bound) * scale, stats=stats)
