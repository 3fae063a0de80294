"""Exact bound-pruned max-coverage engine for small k (designed for k <= 4).

Design (for STRUCTURED matrices, where neighbouring candidates see nearly the same points and the
naive submodular bound ``f(S) + sum of top marginal gains`` is far above the optimum):

* Everything runs on the presolved instance as a dense 0/1 matrix ``D`` (merged rows x kept
  columns) with BLAS products. When every original weight is equal, the merged-row multiplicities
  are integers and ``D``/weights are float32 integers: every GEMM/GEMV result is an integer below
  2**24, hence exact, and pruning is exact. Otherwise float64 is used and pruning keeps an absolute
  margin of ``1e-9 * total weight`` (far above float64 rounding), so "optimal" means optimal to
  within that margin.
* Incumbent: greedy from several starts (best pair, top singles) plus swap local search.
* Columns are grouped into clusters of near-identical columns (k-center on the weighted symmetric
  difference ``f_a + f_b - 2 |a & b|_w``). The global column order is cluster-contiguous.
  For a cluster tuple, the weight of the union of the clusters' unions bounds every member tuple.
* Search: each k-subset is enumerated once, from its first column in the global order. At a level
  with ``r`` columns still to choose, residual rows ``R`` (not covered by the prefix) and allowed
  columns ``L`` (after the prefix's last column):

  - ``r == 1``: the best residual gain (one GEMV);
  - ``r == 2``: cluster-pair bounds ``min(w(U_i | U_j), max g_i + max g_j)`` on ``R`` screen out
    clusters; the surviving members' exact pair values ``g_b + g_c - |b & c|_w`` come from one
    GEMM, i.e. the best pair on the residual is computed exactly;
  - ``r >= 3``: per first cluster ``i``, a bound on every cluster multiset starting at ``i``
    (recursively, one small GEMM per cluster) prunes whole clusters; each surviving member ``a``
    recurses on ``R \\ a`` with the columns after ``a``.

* Time limit: the engine stops between first-level columns and returns the incumbent, status
  "feasible" and a valid bound: the maximum of the incumbent and the cluster bounds of all
  first-level clusters not yet finished (or the cheap bound ``max_a f_a + top-(k-1) residual gains``
  if the limit hits before those are known).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from camplace.solver._common import Deadline, EngineOutcome
from camplace.solver.presolve import Presolved

__all__ = ["solve_exact", "EXACT_MAX_K"]

log = logging.getLogger(__name__)

EXACT_MAX_K = 4  # auto engine uses the exact engine up to this k (it works for any k, slowly)
_INT_EXACT_LIMIT = 1 << 24  # float32 integer arithmetic is exact below this
_FLOAT_MARGIN = 1e-9  # relative pruning margin for float64 weights
_SCREEN_MIN = 48  # pair leaf: screen with clusters only above this many columns
_SWAP_ROUNDS = 50


class _Timeout(Exception):
    """Raised inside the search when the deadline passes."""


def _top_sum(values: np.ndarray, r: int) -> float:
    """Sum of the ``r`` largest entries (all of them if fewer)."""
    if r <= 0 or values.size == 0:
        return 0.0
    if values.size <= r:
        return float(values.sum(dtype=np.float64))
    return float(np.partition(values, values.size - r)[values.size - r :].sum(dtype=np.float64))


def _kcenter(f: np.ndarray, gram: np.ndarray, q: int) -> np.ndarray:
    """Cluster labels by farthest-point (k-center) clustering.

    Parameters
    ----------
    f : (n,) float64
        Column weights ``w(a)``.
    gram : (n, n) float64
        Weighted intersections ``w(a & b)``.
    q : int
        Number of centres.

    Returns
    -------
    (n,) int64
        Index of the nearest centre for each column.
    """
    n = f.size
    q = max(1, min(q, n))
    centres = [int(np.argmax(f))]
    dist = f + f[centres[0]] - 2.0 * gram[centres[0]]
    label = np.zeros(n, dtype=np.int64)
    for c in range(1, q):
        j = int(np.argmax(dist))
        if dist[j] <= 0.0:
            break
        centres.append(j)
        dj = f + f[j] - 2.0 * gram[j]
        closer = dj < dist
        label[closer] = c
        dist = np.minimum(dist, dj)
    return label


class _Search:
    """Depth-first exact search state (see the module docstring)."""

    def __init__(
        self,
        dense: np.ndarray,
        weights: np.ndarray,
        k: int,
        margin: float,
        deadline: Deadline,
        n_clusters: int | None,
    ) -> None:
        self.d = dense  # (m, n) 0/1, float32 (integer mode) or float64
        self.w = weights  # (m,) same dtype
        self.k = k
        self.margin = margin
        self.deadline = deadline
        m, n = dense.shape
        self.m, self.n = m, n
        self.f = (dense.T @ weights).astype(np.float64)  # (n,)
        self.total = float(weights.sum(dtype=np.float64))
        self.best_value = -math.inf
        self.best_set: tuple[int, ...] = ()
        self.stats: dict[str, Any] = {
            "gemms": 0,
            "gemm_madds": 0.0,
            "first_level_columns": 0,
            "first_level_pruned": 0,
            "nodes": 0,
            "pair_leaves": 0,
            "pair_leaf_cols_before": 0,
            "pair_leaf_cols_after": 0,
            "cluster_blocks": 0,
            "triple_members": 0,
        }
        self.n_clusters = n_clusters
        self.top_bounds: np.ndarray | None = None
        self.top_segment = 0
        self.ub0 = math.inf

    # -- helpers -------------------------------------------------------------------------------
    def _gram(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``x^T diag(w) x`` as float64.

        Parameters
        ----------
        x : (r, c) 0/1 matrix
        w : (r,) weights

        Returns
        -------
        (c, c) float64
        """
        self.stats["gemms"] += 1
        self.stats["gemm_madds"] += float(x.shape[0]) * x.shape[1] * x.shape[1]
        return (x.T @ (x * w[:, None])).astype(np.float64)

    def _check_time(self) -> None:
        if self.deadline.expired():
            raise _Timeout

    def _offer(self, value: float, cols: tuple[int, ...]) -> None:
        if value > self.best_value:
            self.best_value = value
            self.best_set = tuple(sorted(cols))
            log.debug("exact: incumbent %.9g %s", value, self.best_set)

    def _offer_pos(self, value: float, positions: tuple[int, ...]) -> None:
        """Offer a set given by search positions (see :meth:`prepare`)."""
        self._offer(value, tuple(int(self.order[p]) for p in positions))

    def _thr(self, base: float) -> float:
        """Bounds at or below this (for a prefix of value ``base``) cannot improve the incumbent."""
        return self.best_value - base + self.margin

    # -- incumbent -----------------------------------------------------------------------------
    def _value(self, cols: list[int]) -> float:
        covered = self.d[:, cols].max(axis=1) > 0
        return float(self.w[covered].sum(dtype=np.float64))

    def _greedy(self, start: list[int]) -> list[int]:
        sel = list(start)
        resid = self.w.copy()
        if sel:
            resid[self.d[:, sel].max(axis=1) > 0] = 0
        while len(sel) < self.k:
            g = (self.d.T @ resid).astype(np.float64)
            g[sel] = -1.0
            j = int(np.argmax(g))
            sel.append(j)
            resid[self.d[:, j] > 0] = 0
        return sel

    def _swap(self, sel: list[int]) -> list[int]:
        """First-improvement 1-swap local search."""
        sel = list(sel)
        cnt = self.d[:, sel].sum(axis=1)
        for _ in range(_SWAP_ROUNDS):
            improved = False
            for p in range(len(sel)):
                s = sel[p]
                others = cnt - self.d[:, s]
                resid = np.where(others > 0, 0, self.w).astype(self.w.dtype)
                g = (self.d.T @ resid).astype(np.float64)
                cur = g[s]
                g[sel] = -1.0
                j = int(np.argmax(g))
                if g[j] > cur + self.margin:
                    sel[p] = j
                    cnt = others + self.d[:, j]
                    improved = True
            if not improved:
                break
        return sel

    def initial_incumbent(self, gram: np.ndarray) -> None:
        """Greedy from several starts, each followed by swap local search."""
        starts: list[list[int]] = [[]]
        if self.k >= 2:
            pair = self.f[:, None] + self.f[None, :] - gram
            np.fill_diagonal(pair, -np.inf)
            i, j = np.unravel_index(int(np.argmax(pair)), pair.shape)
            starts.append([int(i), int(j)])
        for j in np.argsort(-self.f, kind="stable")[:5]:
            starts.append([int(j)])
        for st in starts:
            sel = self._swap(self._greedy(st))
            self._offer(self._value(sel), tuple(sel))
        self.stats["initial_incumbent"] = self.best_value

    # -- bounds --------------------------------------------------------------------------------
    def cheap_bound(self, gram: np.ndarray) -> float:
        """``max_a f_a + top-(k-1) (f_b - w(a & b))``: valid for every k-subset."""
        if self.k == 1:
            return float(self.f.max())
        gain = self.f[None, :] - gram
        np.fill_diagonal(gain, -np.inf)
        r = self.k - 1
        if r >= self.n - 1:
            tops = np.where(np.isfinite(gain), gain, 0.0).sum(axis=1)
        else:
            part = np.partition(gain, self.n - r, axis=1)[:, self.n - r :]
            tops = part.sum(axis=1)
        return float(min(self.total, np.max(self.f + tops)))

    def _coarse(self, u: np.ndarray, w: np.ndarray, r: int, thr: float) -> np.ndarray:
        """Upper bounds on cluster multisets by their first cluster.

        Parameters
        ----------
        u : (rows, q) 0/1 cluster unions on the residual rows
        w : (rows,) weights
        r : int
            Multiset size.
        thr : float
            Bounds known to be ``<= thr`` may be returned loosely (still valid).

        Returns
        -------
        (q,) float64
            ``out[i] >= max w(U_i | U_j | ...)`` over multisets ``i <= j <= ...`` of size ``r``.
        """
        h = (u.T @ w).astype(np.float64)
        q = h.size
        if r == 1 or q == 0:
            return h
        if r == 2:
            pb = h[:, None] + h[None, :] - self._gram(u, w)
            pb[np.tril_indices(q, -1)] = -np.inf
            return pb.max(axis=1)
        out = np.empty(q, dtype=np.float64)
        for i in range(q):
            quick = h[i] + _top_sum(h[i:], r - 1)
            if quick <= thr:
                out[i] = quick
                continue
            keep = u[:, i] == 0
            sub = self._coarse(u[keep][:, i:], w[keep], r - 1, thr - h[i])
            out[i] = h[i] + float(sub.max())
        return out

    # -- search --------------------------------------------------------------------------------
    def prepare(self, order: np.ndarray, labels: np.ndarray, gram: np.ndarray) -> None:
        """Fix the cluster-contiguous search order and the cluster unions.

        Parameters
        ----------
        order : (n,) int64
            Search order of the dense columns (cluster-contiguous).
        labels : (n,) int64
            Cluster rank of each dense column (ascending along ``order``).
        gram : (n, n) float64
            Weighted intersections of the dense columns.
        """
        self.order = order
        self.do = np.ascontiguousarray(self.d[:, order])  # (m, n) columns in search order
        self.fo = self.f[order]
        self.go = gram[np.ix_(order, order)]
        lab = labels[order]
        self.seg_start = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]]).astype(np.int64)
        self.seg_end = np.r_[self.seg_start[1:], self.n].astype(np.int64)
        self.seg_of = np.repeat(np.arange(self.seg_start.size), self.seg_end - self.seg_start)
        self.u = np.ascontiguousarray(np.maximum.reduceat(self.do, self.seg_start, axis=1))  # (m, q)

    def _screen_pairs(self, wm: np.ndarray, q0: int, g: np.ndarray, thr: float) -> np.ndarray:
        """Columns that can be in a pair of value ``> thr`` on the residual weights ``wm``.

        Parameters
        ----------
        wm : (m,) residual weights
        q0 : int
            First allowed search position.
        g : (n - q0,) float64
            Residual gains of the allowed columns.
        thr : float

        Returns
        -------
        (c,) int64
            Surviving offsets (relative to ``q0``), ascending.
        """
        nl = g.size
        if nl < 2:
            return np.zeros(0, dtype=np.int64)
        # Member filter: b can only be in an improving pair if g_b + max_{c != b} g_c > thr.
        top = np.argpartition(-g, 1)[:2] if nl > 2 else np.arange(nl)
        top = top[np.argsort(-g[top], kind="stable")]
        best_other = np.full(nl, g[top[0]])
        best_other[top[0]] = g[top[1]]
        alive = g + best_other > thr
        if nl > _SCREEN_MIN and int(alive.sum()) > _SCREEN_MIN:
            s0 = int(self.seg_of[q0])
            rows = np.flatnonzero(wm)
            ur = self.u[rows, s0:]
            wr = wm[rows]
            hu = (ur.T @ wr).astype(np.float64)
            pu = hu[:, None] + hu[None, :] - self._gram(ur, wr)
            starts = np.maximum(self.seg_start[s0:], q0) - q0
            sizes = np.diff(np.r_[starts, nl])
            gmax = np.maximum.reduceat(g, starts)
            pb = np.minimum(pu, gmax[:, None] + gmax[None, :])
            same = np.where(sizes >= 2, np.minimum(hu, 2.0 * gmax), -np.inf)
            np.fill_diagonal(pb, same)
            partner = np.where(pb > thr, gmax[None, :], -np.inf).max(axis=1)
            alive &= g + np.repeat(partner, sizes) > thr
        return np.flatnonzero(alive)

    def _pair_leaf(self, wm: np.ndarray, p: int, g: np.ndarray, base: float, prefix: tuple[int, ...]) -> None:
        """Exact best pair among search positions ``p..n-1`` on the residual weights ``wm``.

        Parameters
        ----------
        wm : (m,) residual weights (0 on covered rows)
        p : int
            First allowed search position.
        g : (n - p,) float64
            Residual gains of the allowed columns.
        base : float
            Weight covered by the prefix.
        prefix : tuple of int
            Search positions chosen so far.
        """
        thr = self._thr(base)
        if g.size < 2 or _top_sum(g, 2) <= thr:
            return
        self.stats["pair_leaves"] += 1
        idx = self._screen_pairs(wm, p, g, thr)
        self.stats["pair_leaf_cols_before"] += int(g.size)
        self.stats["pair_leaf_cols_after"] += int(idx.size)
        if idx.size < 2:
            return
        rows = np.flatnonzero(wm)
        x = self.do[np.ix_(rows, idx + p)]
        gi = g[idx]
        pv = gi[:, None] + gi[None, :] - self._gram(x, wm[rows])
        pv[np.tril_indices(idx.size)] = -np.inf
        flat = int(np.argmax(pv))
        i, j = divmod(flat, idx.size)
        val = float(pv[i, j])
        if val > thr - self.margin:
            self._offer_pos(base + val, prefix + (int(idx[i]) + p, int(idx[j]) + p))

    def _cluster_triples(
        self, wm: np.ndarray, p: int, g: np.ndarray, lo: int, hi: int, base: float, prefix: tuple[int, ...]
    ) -> None:
        """All triples whose first column is a search position in ``lo..hi-1`` (one cluster).

        With ``N`` the residual rows every cluster member covers and ``R'`` the other residual rows,
        ``value(a, b, c) = f_a + w_R'(b | c) - w_(R' & a)(b | c)``: one GEMM gives the exact pair
        values on ``R'`` for the whole cluster, and each member only needs a correction on the
        (few) rows ``R' & a``.

        Parameters
        ----------
        wm : (m,) residual weights
        p : int
            First allowed search position of the level (``g`` is indexed from ``p``).
        g : (n - p,) float64
            Residual gains.
        lo, hi : int
            Search positions of the cluster members.
        base : float
            Weight covered by the prefix.
        prefix : tuple of int
            Search positions chosen so far.
        """
        q0 = lo + 1
        if self.n - q0 < 2:
            return
        rows = np.flatnonzero(wm)
        in_all = self.do[rows, lo:hi].min(axis=1) > 0
        wprime = wm.copy()
        wprime[rows[in_all]] = 0
        rp = rows[~in_all]
        fa = g[lo - p : hi - p]
        thr = self._thr(base)
        gp = (self.do[:, q0:].T @ wprime).astype(np.float64)
        idx = self._screen_pairs(wprime, q0, gp, thr - float(fa.max()))
        self.stats["cluster_blocks"] += 1
        self.stats["pair_leaf_cols_before"] += int(gp.size)
        self.stats["pair_leaf_cols_after"] += int(idx.size)
        if idx.size < 2:
            return
        pos_idx = idx + q0  # search positions of the surviving pair columns
        x = self.do[np.ix_(rp, pos_idx)]
        gi = gp[idx]
        pv = gi[:, None] + gi[None, :] - self._gram(x, wm[rp])
        pv[np.tril_indices(idx.size)] = -np.inf
        for a in range(lo, hi):
            self._check_time()
            self.stats["triple_members"] += 1
            ta = self._thr(base) - float(fa[a - lo])
            j0 = int(np.searchsorted(pos_idx, a + 1))
            if idx.size - j0 < 2:
                break
            sub = pv[j0:, j0:]
            cand = sub > ta
            if not cand.any():
                continue
            mi = np.flatnonzero(cand.any(axis=0) | cand.any(axis=1))
            da = rp[self.do[rp, a] > 0]
            xd = self.do[np.ix_(da, pos_idx[j0:][mi])]
            wd = wm[da]
            gd = (xd.T @ wd).astype(np.float64)
            val = sub[np.ix_(mi, mi)] - (gd[:, None] + gd[None, :] - self._gram(xd, wd))
            val[~cand[np.ix_(mi, mi)]] = -np.inf
            flat = int(np.argmax(val))
            i, j = divmod(flat, mi.size)
            v = float(val[i, j])
            if v > ta - self.margin:
                bpos = int(pos_idx[j0 + mi[i]])
                cpos = int(pos_idx[j0 + mi[j]])
                self._offer_pos(base + float(fa[a - lo]) + v, prefix + (a, bpos, cpos))

    def search(
        self,
        wm: np.ndarray,
        p: int,
        r: int,
        base: float,
        prefix: tuple[int, ...],
        g: np.ndarray | None = None,
        top: bool = False,
    ) -> None:
        """Explore the r-subsets of search positions ``p..n-1`` on residual weights ``wm``.

        Parameters
        ----------
        wm : (m,) residual weights (0 on rows covered by the prefix)
        p : int
            First allowed search position.
        r : int
            Columns still to choose.
        base : float
            Weight covered by the prefix.
        prefix : tuple of int
            Search positions chosen so far.
        g : (n - p,) float64, optional
            Residual gains of the allowed columns, if already known.
        top : bool
            First level (records bounds for the time-limit report).
        """
        self.stats["nodes"] += 1
        nl = self.n - p
        if nl < r:
            return
        if g is None:
            g = (self.do[:, p:].T @ wm).astype(np.float64)
        thr = self._thr(base)
        if _top_sum(g, r) <= thr:
            return
        if r == 1:
            j = int(np.argmax(g))
            if g[j] > thr - self.margin:
                self._offer_pos(base + float(g[j]), prefix + (j + p,))
            return
        if r == 2:
            self._pair_leaf(wm, p, g, base, prefix)
            return
        s0 = int(self.seg_of[p])
        rows = np.flatnonzero(wm)
        cb = self._coarse(self.u[rows, s0:], wm[rows], r, thr)
        if top:
            self.top_bounds = cb + base
            self.top_segment = 0
            self.stats["clusters_first_level_open"] = int(np.sum(cb > thr))
        for s in range(cb.size):
            if top:
                self.top_segment = s
            if cb[s] <= self._thr(base):
                continue
            lo = max(p, int(self.seg_start[s0 + s]))
            hi = int(self.seg_end[s0 + s])
            if r == 3:
                self._cluster_triples(wm, p, g, lo, hi, base, prefix)
                continue
            for pos in range(lo, hi):
                if self.n - pos - 1 < r - 1:
                    break
                self._check_time()
                thr = self._thr(base)
                if cb[s] <= thr:
                    break
                if top:
                    self.stats["first_level_columns"] += 1
                ga = float(g[pos - p])
                if ga + _top_sum(g[pos - p + 1 :], r - 1) <= thr:
                    if top:
                        self.stats["first_level_pruned"] += 1
                    continue
                col = self.do[:, pos]
                wsub = np.where(col > 0, 0, wm).astype(wm.dtype)
                gsub = None
                if top and base == 0.0:
                    # On all rows the residual gains come free from the global Gram matrix.
                    gsub = self.fo[pos + 1 :] - self.go[pos, pos + 1 :]
                self.search(wsub, pos + 1, r - 1, base + ga, prefix + (pos,), gsub)
        if top:
            self.top_segment = cb.size

    def open_bound(self) -> float:
        """Valid upper bound on the optimum given the progress so far."""
        b = self.best_value + self.margin
        if self.top_bounds is None:
            return max(b, self.ub0)
        rest = self.top_bounds[self.top_segment :]
        if rest.size:
            b = max(b, float(rest.max()))
        return b


def solve_exact(
    pre: Presolved,
    *,
    time_limit_s: float | None = None,
    n_clusters: int | None = None,
) -> EngineOutcome:
    """Solve a presolved max-coverage instance exactly.

    Parameters
    ----------
    pre : Presolved
        Output of :func:`camplace.solver.presolve.presolve`.
    time_limit_s : float, optional
        Wall-clock limit; on expiry the incumbent is returned with status "feasible" and a valid
        bound.
    n_clusters : int, optional
        Number of column clusters (default ``~2 sqrt(n')``).

    Returns
    -------
    EngineOutcome
        Reduced column indices, status, bound (original weight units) and stats.
    """
    deadline = Deadline(time_limit_s)
    k = pre.k
    m, n = pre.shape
    stats: dict[str, Any] = {}
    if m == 0 or n <= k:
        sel = tuple(range(min(k, n)))
        value = float(pre.weights.sum()) if n <= k else 0.0
        return EngineOutcome(selected=sel, status="optimal", bound=value, stats={"trivial": True})

    integer = pre.weight_unit is not None and int(pre.counts.sum()) < _INT_EXACT_LIMIT
    if integer:
        dense = pre.matrix.toarray().astype(np.float32)
        w = pre.counts.astype(np.float32)
        scale = float(pre.weight_unit)  # type: ignore[arg-type]
        margin = 0.0
    else:
        dense = pre.matrix.toarray()
        w = pre.weights.astype(np.float64)
        scale = 1.0
        margin = _FLOAT_MARGIN * float(w.sum())
    stats["arithmetic"] = "float32-integer" if integer else "float64"

    srch = _Search(dense, w, k, margin, deadline, n_clusters)
    gram = srch._gram(dense, w)
    srch.ub0 = srch.cheap_bound(gram)
    srch.initial_incumbent(gram)
    q = n_clusters if n_clusters is not None else int(max(1, min(n, round(2.0 * math.sqrt(n)))))
    labels = _kcenter(srch.f, gram, q)
    nq = int(labels.max()) + 1
    union_w = np.zeros(nq)
    for c in range(nq):
        members = np.flatnonzero(labels == c)
        union_w[c] = float(w[dense[:, members].max(axis=1) > 0].sum(dtype=np.float64))
    corder = np.argsort(-union_w, kind="stable")
    rank = np.empty(nq, dtype=np.int64)
    rank[corder] = np.arange(nq)
    order = np.lexsort((np.arange(n), -srch.f, rank[labels]))
    stats["clusters"] = nq
    srch.prepare(order.astype(np.int64), rank[labels], gram)
    stats["time_setup_s"] = deadline.elapsed()

    status = "optimal"
    try:
        if k == 1:
            j = int(np.argmax(srch.f))
            srch._offer(float(srch.f[j]), (j,))
        else:
            srch._check_time()
            srch.search(w.copy(), 0, k, 0.0, (), g=srch.fo.copy(), top=True)
        bound = srch.best_value
    except _Timeout:
        status = "feasible"
        bound = srch.open_bound()
    bound = min(bound, srch.ub0 + margin, srch.total)
    if bound <= srch.best_value + margin:
        status = "optimal"
        bound = srch.best_value
    stats.update(srch.stats)
    stats["time_search_s"] = deadline.elapsed() - stats["time_setup_s"]
    stats["cheap_bound"] = srch.ub0 * scale
    stats["initial_incumbent"] = float(stats["initial_incumbent"]) * scale
    log.info(
        "exact: k=%d on %dx%d, %s value %.9g bound %.9g, %d first-level columns, %d GEMMs, %.3f s",
        k,
        m,
        n,
        status,
        srch.best_value * scale,
        bound * scale,
        stats["first_level_columns"],
        stats["gemms"],
        deadline.elapsed(),
    )
    return EngineOutcome(selected=srch.best_set, status=status, bound=float(bound) * scale, stats=stats)
