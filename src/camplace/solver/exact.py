"""Exact bound-pruned max-coverage engine for small k (designed for k <= 4).

Design (for STRUCTURED matrices, where neighbouring candidates see nearly the same points and the
naive submodular bound ``f(S) + sum of top marginal gains`` is far above the optimum):

* Everything runs on the presolved instance as a dense 0/1 matrix ``D`` (merged rows x kept
  columns) with BLAS products. When every original weight is equal, the merged-row multiplicities
  are integers and ``D``/weights are float32 integers: every GEMM/GEMV result and stored pair
  value is an integer below 2**24, hence exact, and pruning is exact. Otherwise float64 is used
  and pruning keeps an absolute margin of ``1e-9 * total weight`` (far above float64 rounding),
  so "optimal" then means optimal to within that margin.
* Incumbent: greedy from several starts (best pair, top singles) plus 1-swap local search.
* Column order: recursive balanced bisection on the weighted symmetric-difference distance
  ``f_a + f_b - 2 w(a & b)``, so that every contiguous range of the order (a node of the implicit
  bisection tree) holds similar columns. Every k-subset is enumerated once, from its first column.
* ``k = 1, 2``: exact from ``f = D^T w`` and the Gram matrix ``G = D^T diag(w) D``.
* ``k = 3`` (and every level with 3 columns left): a tree search over the first column ``a``.
  A node (a range of first columns) keeps ``N`` = rows covered by ALL its columns and the exact
  pair values ``P(b, c) = w_{R - N}(b | c)`` of the still-relevant later columns; since
  ``value(a, b, c) = f_a + w_{R - a}(b | c) <= f_a + P(b, c)``, the node is pruned when
  ``max f_a + max P <= incumbent``, and columns with no promising partner are dropped. A child
  range only subtracts a correction computed by one small GEMM over the rows that became common
  (``N_child - N``); at a single column ``N = a`` and ``f_a + P`` is the exact triple value. Rows
  shared by many similar columns are thus processed once per group instead of once per column.
* ``k >= 4``: columns are cut into segments (bisection-tree nodes); for each first segment a
  bound on all segment multisets (union of member columns, a recursion of small GEMMs) prunes whole
  segments; each surviving column ``a`` recurses on the rows it does not cover.
* Time limit: the search stops at the next node and returns the incumbent, status "feasible" and
  a valid bound (the maximum of the incumbent and the bounds of all open tree nodes / segments,
  or the cheap bound ``max_a f_a + top-(k-1) residual gains`` before the search has started).
  The setup (one Gram GEMM ``n'^2 m'``, greedy incumbent, ordering) is not interruptible.
* Memory: a dense ``m' x n'`` copy (4 bytes per entry in integer mode, 8 otherwise; two copies
  briefly during setup) plus a few ``n' x n'`` matrices.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from scipy.linalg import blas

from camplace.solver._blas import limit_blas_threads
from camplace.solver._common import Deadline, EngineOutcome
from camplace.solver.presolve import Presolved

__all__ = ["solve_exact", "EXACT_MAX_K"]

log = logging.getLogger(__name__)

EXACT_MAX_K = 4  # the auto engine uses the exact engine up to this k (it works for any k, slowly)
_INT_EXACT_LIMIT = 1 << 22  # total count limit: stored pair values stay below 2**24 (exact in float32)
_FLOAT_MARGIN = 1e-9  # relative pruning margin for float64 weights
_SCREEN_MIN = 48  # pair screening by segments only above this many columns
_SWAP_ROUNDS = 50
# OpenBLAS threads during a solve (None: leave BLAS alone). One thread is ~1.3x slower on an idle
# 2-core machine but avoids 5-15x slowdowns when the cores are oversubscribed (see _blas.py).
BLAS_THREADS: int | None = 1


class _Timeout(Exception):
    """Raised inside the search when the deadline passes."""


def _top_sum(values: np.ndarray, r: int) -> float:
    """Sum of the ``r`` largest entries (all of them if fewer)."""
    if r <= 0 or values.size == 0:
        return 0.0
    if values.size <= r:
        return float(values.sum(dtype=np.float64))
    return float(np.partition(values, values.size - r)[values.size - r :].sum(dtype=np.float64))


def _bisection_order(f: np.ndarray, gram: np.ndarray) -> np.ndarray:
    """Column order from recursive balanced bisection (similar columns end up adjacent).

    A range of size ``s`` is split into its first ``s // 2`` and last ``s - s // 2`` columns, the
    same rule :func:`_segment_starts` and the tree search use.

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


def _segment_starts(n: int, depth: int) -> np.ndarray:
    """Start offsets of the bisection-tree nodes at ``depth`` (leaves above it stay whole)."""
    starts: list[int] = []
    stack = [(0, n, 0)]
    while stack:
        lo, hi, d = stack.pop()
        if d >= depth or hi - lo <= 1:
            starts.append(lo)
            continue
        mid = lo + (hi - lo) // 2
        stack.append((mid, hi, d + 1))
        stack.append((lo, mid, d + 1))
    return np.asarray(sorted(starts), dtype=np.int64)


class _Search:
    """Depth-first exact search state (see the module docstring)."""

    def __init__(self, dense: np.ndarray, weights: np.ndarray, k: int, margin: float, deadline: Deadline) -> None:
        self.d: Any = dense  # (m, n) 0/1, float32 (integer mode) or float64; None after prepare()
        self.w = weights  # (m,) same dtype
        self.dt = dense.dtype
        self.k = k
        self.margin = margin
        self.deadline = deadline
        self.m, self.n = dense.shape
        self.f = (dense.T @ weights).astype(np.float64)  # (n,)
        self.total = float(weights.sum(dtype=np.float64))
        self.best_value = -math.inf
        self.best_set: tuple[int, ...] = ()
        self.stats: dict[str, Any] = {
            "gemms": 0,
            "gemm_madds": 0.0,
            "nodes": 0,
            "tree_nodes": 0,
            "tree_leaves": 0,
            "first_level_columns": 0,
            "pair_leaves": 0,
        }
        self.ub0 = math.inf
        self.started = False
        self.top_bounds: np.ndarray | None = None
        self.top_segment = 0
        self.open_nodes: dict[int, float] = {}
        self._node_key = 0

    # -- helpers -------------------------------------------------------------------------------
    def _gram(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``x^T diag(w) x`` in the working dtype (exact integers in float32 integer mode).

        Parameters
        ----------
        x : (r, c) 0/1 matrix
        w : (r,) weights

        Returns
        -------
        (c, c) float32 or float64
        """
        self.stats["gemms"] += 1
        self.stats["gemm_madds"] += float(x.shape[0]) * x.shape[1] * x.shape[1]
        return x.T @ (x * w[:, None])

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

    # -- incumbent (before :meth:`prepare`, on dense column ids) --------------------------------
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
    def prepare(self, order: np.ndarray, gram: np.ndarray, n_segments: int) -> None:
        """Fix the search order, the segments and their column unions.

        Parameters
        ----------
        order : (n,) int64
            Search order of the dense columns (from :func:`_bisection_order`).
        gram : (n, n) float64
            Weighted intersections of the dense columns.
        n_segments : int
            Approximate number of segments (bisection-tree nodes) for segment bounds.
        """
        self.order = order
        self.do = np.ascontiguousarray(self.d[:, order])  # (m, n) columns in search order
        self.d = None  # the unordered copy is only needed by the incumbent heuristics
        self.fo = self.f[order]
        self.go = gram[order][:, order]
        depth = max(0, int(math.ceil(math.log2(max(1, n_segments)))))
        self.seg_start = _segment_starts(self.n, depth)
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
        # b can only be in an improving pair if g_b + max_{c != b} g_c > thr.
        top = np.argpartition(-g, 1)[:2] if nl > 2 else np.arange(nl)
        top = top[np.argsort(-g[top], kind="stable")]
        best_other = np.full(nl, g[top[0]])
        best_other[top[0]] = g[top[1]]
        alive = g + best_other > thr
        if nl > _SCREEN_MIN and int(alive.sum()) > _SCREEN_MIN:
            # Segment pairs: w(b | c) <= min(w(U_i | U_j), max g_i + max g_j) for b in i, c in j.
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

    def _pair_values(self, wm: np.ndarray, pos: np.ndarray, g: np.ndarray) -> np.ndarray:
        """Exact pair values ``g_b + g_c - w(b & c)`` on the residual weights.

        Parameters
        ----------
        wm : (m,) residual weights
        pos : (c,) int64
            Search positions.
        g : (c,) float64
            Their residual gains.

        Returns
        -------
        (c, c) working dtype
            Values in the strict lower triangle (``[i, j]`` with ``i > j``), -inf elsewhere.
        """
        rows = np.flatnonzero(wm)
        x = self.do[rows][:, pos]
        pv = self._gram(x, wm[rows])
        pv -= g[:, None].astype(self.dt)
        pv -= g[None, :].astype(self.dt)
        np.negative(pv, out=pv)
        return _lower(pv)

    def _best_pair(self, pv: np.ndarray) -> tuple[float, int, int]:
        """Maximum entry of a pair-value matrix (-inf marks invalid pairs) and its indices."""
        flat = int(np.argmax(pv))
        i, j = divmod(flat, pv.shape[1])
        return float(pv[i, j]), int(i), int(j)

    def _pair_leaf(self, wm: np.ndarray, p: int, g: np.ndarray, base: float, prefix: tuple[int, ...]) -> None:
        """Exact best pair among search positions ``p..n-1`` on the residual weights ``wm``."""
        thr = self._thr(base)
        if g.size < 2 or _top_sum(g, 2) <= thr:
            return
        self.stats["pair_leaves"] += 1
        idx = self._screen_pairs(wm, p, g, thr)
        if idx.size < 2:
            return
        pv = self._pair_values(wm, idx + p, g[idx])
        val, i, j = self._best_pair(pv)
        if val > thr - self.margin:
            self._offer_pos(base + val, prefix + (int(idx[i]) + p, int(idx[j]) + p))

    # -- tree search for three columns ---------------------------------------------------------
    def _triples(
        self,
        wm: np.ndarray,
        p: int,
        g: np.ndarray,
        base: float,
        prefix: tuple[int, ...],
        pv: np.ndarray | None = None,
        track: bool = False,
    ) -> None:
        """Best triple among search positions ``p..n-1`` on residual weights ``wm``.

        Parameters
        ----------
        wm : (m,) residual weights (0 on rows covered by the prefix)
        p : int
            First allowed search position.
        g : (n - p,) float64
            Residual gains of positions ``p..n-1``.
        base : float
            Weight covered by the prefix.
        prefix : tuple of int
            Search positions chosen so far.
        pv : (n-p-1, n-p-1) working dtype, optional
            Exact pair values of positions ``p+1..n-1`` on ``wm`` (strict lower triangle, -inf
            elsewhere), if known.
        track : bool
            Record open-node bounds for the time-limit report.
        """
        if self.n - p < 3:
            return
        thr = self._thr(base)
        fmax = float(g[: g.size - 2].max())
        if pv is None:
            idx = self._screen_pairs(wm, p + 1, g[1:], thr - fmax)
            if idx.size < 2:
                return
            cols = idx + p + 1
            pv = self._pair_values(wm, cols, g[idx + 1])
        else:
            cols = np.arange(p + 1, self.n, dtype=np.int64)
        rows = np.flatnonzero(wm)
        in_n = np.zeros(rows.size, dtype=bool)
        key = None
        if track:
            self._node_key += 1
            key = self._node_key
            self.open_nodes[key] = base + fmax + float(pv.max())
        no_rows = np.zeros(0, dtype=np.int64)
        self._node(wm, rows, in_n, p, self.n, cols, pv, 0.0, no_rows, g, p, base, prefix, track, key)

    def _accumulate(self, c: np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Add ``x^T diag(w) x`` to the strict lower triangle of ``c`` (in place if possible).

        Parameters
        ----------
        c : (s, s) C-contiguous working dtype
            Lower-triangular pair matrix (-inf above and on the diagonal stays -inf).
        x : (r, s) 0/1 working dtype
        w : (r,) weights

        Returns
        -------
        (s, s)
            The updated matrix (``c`` itself unless BLAS had to copy).
        """
        self.stats["gemms"] += 1
        self.stats["gemm_madds"] += 0.5 * float(x.shape[0]) * x.shape[1] * x.shape[1]
        ct = c.T  # Fortran view: its upper triangle is c's lower triangle
        if self.dt == np.float32:
            one = w == 1
            if one.all():
                ct = blas.ssyrk(1.0, x, beta=1.0, c=ct, trans=1, lower=0, overwrite_c=1)
            else:
                if one.any():
                    ct = blas.ssyrk(1.0, x[one], beta=1.0, c=ct, trans=1, lower=0, overwrite_c=1)
                x2 = x[~one]
                ct = blas.sgemm(1.0, x2 * w[~one][:, None], x2, beta=1.0, c=ct, trans_a=1, overwrite_c=1)
        else:
            xs = x * np.sqrt(w)[:, None]
            ct = blas.dsyrk(1.0, xs, beta=1.0, c=ct, trans=1, lower=0, overwrite_c=1)
        return ct.T

    def _node(
        self,
        wm: np.ndarray,
        rows: np.ndarray,
        in_n: np.ndarray,
        lo: int,
        hi: int,
        cols: np.ndarray,
        pv: np.ndarray,
        off: float,
        delta: np.ndarray,
        g: np.ndarray,
        p: int,
        base: float,
        prefix: tuple[int, ...],
        track: bool,
        key: int | None,
    ) -> None:
        """One node of the three-column tree search: first columns ``lo..hi-1``.

        Pair values are stored lower-triangular with a scalar offset: the value of the pair
        ``(cols[i], cols[j])``, ``i > j``, is ``pv[i, j] + off``. Moving to a child whose common rows
        grew by ``delta`` subtracts ``w_delta(b | c) = W_delta - xbar^T diag(w) xbar`` with
        ``xbar = 1 - x`` the complement of the columns on those rows: one SYRK into the child's copy
        plus ``off -= W_delta``.

        Parameters
        ----------
        wm : (m,) residual weights
        rows : (r,) int64
            Residual rows (``wm > 0``).
        in_n : (r,) bool
            Rows of ``rows`` covered by every column of the PARENT node (its ``N``).
        lo, hi : int
            Search positions of the node's first columns.
        cols : (c,) int64
            Candidate later columns (search positions, ascending).
        pv : (c, c)
            Parent's stored pair values on ``R - N_parent`` (not modified).
        off : float
            Parent's offset.
        delta : (d,) int64
            Indices into ``rows`` of the rows in ``N_node - N_parent``.
        g : (n - p,) float64
            Residual gains (indexed from ``p``).
        p : int
        base : float
        prefix : tuple of int
        track : bool
        key : int or None
            Key of this node's provisional bound in ``open_nodes``.
        """
        # A node's provisional bound stays in ``open_nodes`` if the deadline interrupts it; it is
        # removed only when the node is finished (or replaced by its children's bounds).
        self._node_body(wm, rows, in_n, lo, hi, cols, pv, off, delta, g, p, base, prefix, track, key)
        if key is not None:
            self.open_nodes.pop(key, None)

    def _node_body(
        self,
        wm: np.ndarray,
        rows: np.ndarray,
        in_n: np.ndarray,
        lo: int,
        hi: int,
        cols: np.ndarray,
        pv: np.ndarray,
        off: float,
        delta: np.ndarray,
        g: np.ndarray,
        p: int,
        base: float,
        prefix: tuple[int, ...],
        track: bool,
        key: int | None,
    ) -> None:
        """Body of :meth:`_node` (same parameters)."""
        self._check_time()
        self.stats["tree_nodes"] += 1
        thr = self._thr(base)
        fl = g[lo - p : hi - p]
        fmax = float(fl.max())
        j0 = int(np.searchsorted(cols, lo, side="right"))  # later columns only
        if cols.size - j0 < 2:
            return
        cols = cols[j0:]
        sub = pv[j0:, j0:]  # view of the parent's values (upper bounds here)
        keep = _rowcol_max(sub) + off > thr - fmax
        nk = int(keep.sum())
        if nk < 2:
            return
        owned = False
        if nk < keep.size:
            kidx = np.flatnonzero(keep)
            cols = cols[kidx]
            sub = sub[kidx][:, kidx]
            owned = True
        if delta.size:
            dr = rows[delta]
            wd = wm[dr]
            xbar = 1 - self.do[dr][:, cols]
            if not owned:
                sub = sub.copy()
            sub = self._accumulate(sub, xbar, wd)
            off -= float(wd.sum(dtype=np.float64))
            in_n = in_n.copy()
            in_n[delta] = True
        pv = sub
        rmax = _rowcol_max(pv) + off
        bound = fmax + float(rmax.max())
        if bound <= thr:
            return
        if hi - lo == 1:
            self.stats["tree_leaves"] += 1
            val, i, j = self._best_pair(pv)
            val += off
            if val > thr - fl[0] - self.margin:
                self._offer_pos(base + float(fl[0]) + val, prefix + (lo, int(cols[i]), int(cols[j])))
            return
        keep = rmax > thr - fmax
        if not keep.all():
            kidx = np.flatnonzero(keep)
            cols = cols[kidx]
            pv = pv[kidx][:, kidx]
            rmax = rmax[kidx]
        mid = lo + (hi - lo) // 2
        children = [(lo, mid), (mid, hi)]
        keys: list[int | None] = [None, None]
        if track:
            for t, (cl, ch) in enumerate(children):
                self._node_key += 1
                keys[t] = self._node_key
                ok = cols > cl
                cb = float(g[cl - p : ch - p].max()) + (float(rmax[ok].max()) if ok.sum() >= 2 else -math.inf)
                self.open_nodes[self._node_key] = base + cb
            if key is not None:
                self.open_nodes.pop(key, None)
        free = np.flatnonzero(~in_n)
        for t, (cl, ch) in enumerate(children):
            if free.size:
                cov = self.do[rows[free], cl:ch].min(axis=1) > 0
                dchild = free[cov]
            else:
                dchild = free
            self._node(wm, rows, in_n, cl, ch, cols, pv, off, dchild, g, p, base, prefix, track, keys[t])

    # -- general search ------------------------------------------------------------------------
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
        if r == 3:
            self._triples(wm, p, g, base, prefix, track=top)
            return
        s0 = int(self.seg_of[p])
        rows = np.flatnonzero(wm)
        cb = self._coarse(self.u[rows, s0:], wm[rows], r, thr)
        if top:
            self.top_bounds = cb + base
            self.top_segment = 0
        for s in range(cb.size):
            if top:
                self.top_segment = s
            if cb[s] <= self._thr(base):
                continue
            lo = max(p, int(self.seg_start[s0 + s]))
            hi = int(self.seg_end[s0 + s])
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
                    continue
                col = self.do[:, pos]
                wsub = np.where(col > 0, 0, wm).astype(wm.dtype)
                gsub = None
                if top and base == 0.0 and p == 0:
                    # On all rows the residual gains come free from the global Gram matrix.
                    gsub = self.fo[pos + 1 :] - self.go[pos, pos + 1 :]
                self.search(wsub, pos + 1, r - 1, base + ga, prefix + (pos,), gsub)
        if top:
            self.top_segment = cb.size

    def open_bound(self) -> float:
        """Valid upper bound on the optimum given the progress so far (after a timeout)."""
        b = self.best_value + self.margin
        if not self.started or (self.top_bounds is None and not self.open_nodes):
            return max(b, self.ub0)
        if self.top_bounds is not None:
            rest = self.top_bounds[self.top_segment :]
            if rest.size:
                b = max(b, float(rest.max()))
        if self.open_nodes:
            b = max(b, max(self.open_nodes.values()))
        return b


def solve_exact(
    pre: Presolved,
    *,
    time_limit_s: float | None = None,
    n_segments: int | None = None,
) -> EngineOutcome:
    """Solve a presolved max-coverage instance exactly (see :func:`_solve_exact`).

    OpenBLAS is limited to :data:`BLAS_THREADS` threads for the duration of the solve.
    """
    with limit_blas_threads(BLAS_THREADS):
        return _solve_exact(pre, time_limit_s=time_limit_s, n_segments=n_segments)


def _solve_exact(
    pre: Presolved,
    *,
    time_limit_s: float | None = None,
    n_segments: int | None = None,
) -> EngineOutcome:
    """Solve a presolved max-coverage instance exactly.

    Parameters
    ----------
    pre : Presolved
        Output of :func:`camplace.solver.presolve.presolve`.
    time_limit_s : float, optional
        Wall-clock limit; on expiry the incumbent is returned with status "feasible" and a valid
        bound.
    n_segments : int, optional
        Number of column segments used by segment bounds (default ``~2 sqrt(n')``).

    Returns
    -------
    EngineOutcome
        Reduced column indices, status, bound (original weight units) and stats.
    """
    deadline = Deadline(time_limit_s)
    k = pre.k
    m, n = pre.shape
    if m == 0 or n <= k:
        sel = tuple(range(min(k, n)))
        value = float(pre.weights.sum()) if n <= k else 0.0
        return EngineOutcome(selected=sel, status="optimal", bound=value, stats={"trivial": True})

    integer = pre.weight_unit is not None and int(pre.counts.sum()) < _INT_EXACT_LIMIT
    if integer:
        dense = pre.matrix.astype(np.float32).toarray()
        w = pre.counts.astype(np.float32)
        scale = float(pre.weight_unit)  # type: ignore[arg-type]
        margin = 0.0
    else:
        dense = pre.matrix.toarray()
        w = pre.weights.astype(np.float64)
        scale = 1.0
        margin = _FLOAT_MARGIN * float(w.sum())
    stats: dict[str, Any] = {"arithmetic": "float32-integer" if integer else "float64"}

    srch = _Search(dense, w, k, margin, deadline)
    del dense
    status = "optimal"
    try:
        # Setup (one Gram GEMM, incumbent, ordering) is not interruptible.
        gram = srch._gram(srch.d, w)
        srch.ub0 = srch.cheap_bound(gram)
        srch.initial_incumbent(gram)
        q = n_segments if n_segments is not None else int(max(1, min(n, round(2.0 * math.sqrt(n)))))
        order = _bisection_order(srch.f, gram)
        srch.prepare(order, gram, q)
        del gram
        stats["segments"] = int(srch.seg_start.size)
        stats["time_setup_s"] = deadline.elapsed()
        srch._check_time()
        srch.started = True
        if k == 1:
            j = int(np.argmax(srch.f))
            srch._offer(float(srch.f[j]), (j,))
        elif k == 2:
            pv = srch.fo[:, None] + srch.fo[None, :] - srch.go
            np.fill_diagonal(pv, -np.inf)
            val, i, j = srch._best_pair(pv)
            srch._offer_pos(val, (i, j))
        elif k == 3:
            pv = _lower((srch.fo[1:, None] + srch.fo[None, 1:] - srch.go[1:, 1:]).astype(srch.dt))
            srch._triples(w.copy(), 0, srch.fo.copy(), 0.0, (), pv=pv, track=True)
        else:
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
    stats["time_search_s"] = deadline.elapsed() - stats.get("time_setup_s", 0.0)
    stats["cheap_bound"] = srch.ub0 * scale
    stats["initial_incumbent"] = float(stats.get("initial_incumbent", -math.inf)) * scale
    log.info(
        "exact: k=%d on %dx%d, %s value %.9g bound %.9g, %d tree nodes, %d GEMMs, %.3f s",
        k,
        m,
        n,
        status,
        srch.best_value * scale,
        bound * scale,
        stats["tree_nodes"],
        stats["gemms"],
        deadline.elapsed(),
    )
    selected = tuple(int(j) for j in srch.best_set)
    return EngineOutcome(selected=selected, status=status, bound=float(bound) * scale, stats=stats)
