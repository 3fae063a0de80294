"""The greedy heuristic of the k-camera modes (the models' hint, and the answer when no model fits).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

__all__ = ["greedy", "NearCandidates", "greedy_swap", "greedy_incumbent"]

_GREEDY_BLOCK_NNZ = 4_000_000  # matrix entries per column block in the greedy heuristic


def greedy(
    q: sp.csc_matrix, w: np.ndarray, mode: str, views: int, base: np.ndarray, k: int, allowed: np.ndarray,
    conflict_adj: list[set[int]] | None,
) -> tuple[int, ...] | None:
    """Greedy k new cameras (respecting conflicts); None if no conflict-free k-set was found.

    ``base`` is the current per-point state: best quality (quality), covered flag (maxcover) or
    view count (multiview) from the fixed cameras. The angle condition is ignored (heuristic).
    """
    cur = base.astype(np.float64).copy()
    ok = allowed.copy()
    chosen: list[int] = []
    rows, ptr = q.indices, q.indptr
    n = q.shape[1]
    # column blocks of at most _GREEDY_BLOCK_NNZ entries: no temporary is as large as the matrix
    edges = [0]
    while edges[-1] < n:
        edges.append(max(edges[-1] + 1, int(np.searchsorted(ptr, ptr[edges[-1]] + _GREEDY_BLOCK_NNZ, side="right")) - 1))
    edges[-1] = n
    for _ in range(k):
        if not ok.any():
            return None
        if mode == "maxcover":
            per_row = w * (cur <= 0)
        elif mode == "multiview":
            per_row = w * np.where(cur + 1 >= views, (cur + 1 == views) * 1.0, 1e-3 * (cur + 1) / views)
        gain = np.empty(n, dtype=np.float64)
        for c0, c1 in zip(edges[:-1], edges[1:]):
            s, e = ptr[c0], ptr[c1]
            r = rows[s:e]
            if mode == "quality":
                contrib = w[r] * np.maximum(q.data[s:e] - cur[r], 0.0)
            else:
                contrib = per_row[r]
            col = np.repeat(np.arange(c1 - c0), np.diff(ptr[c0 : c1 + 1]))
            gain[c0:c1] = np.bincount(col, weights=contrib, minlength=c1 - c0)
        gain[~ok] = -np.inf
        j = int(np.argmax(gain))
        chosen.append(j)
        ok[j] = False
        if conflict_adj is not None:
            for b in conflict_adj[j]:
                ok[b] = False
        r = rows[ptr[j] : ptr[j + 1]]
        if mode == "quality":
            cur[r] = np.maximum(cur[r], q.data[ptr[j] : ptr[j + 1]])
        elif mode == "maxcover":
            cur[r] = 1.0
        else:
            cur[r] += 1.0
    return tuple(sorted(chosen))


class NearCandidates:
    """``adj[j]``: the free candidates closer than ``dmin`` to free candidate ``j``, found with a k-d
    tree when asked (the greedy's conflicts without listing every pair)."""

    def __init__(self, pos_free: np.ndarray, dmin: float) -> None:
        from scipy.spatial import cKDTree

        self.pos, self.dmin, self.tree = pos_free, dmin, cKDTree(pos_free)

    def __getitem__(self, j: int) -> list[int]:
        near = np.asarray(self.tree.query_ball_point(self.pos[j], self.dmin), dtype=np.int64)
        d = np.linalg.norm(self.pos[near] - self.pos[j], axis=1)
        return [int(b) for b in near[(d < self.dmin) & (near != j)]]


def greedy_swap(scores: Callable[[list[int]], np.ndarray], start: Sequence[int], k: int, margin: float,
                rounds: int, expired: Callable[[], bool] | None = None) -> list[int]:
    """Greedy completion of ``start`` to ``k`` columns, then 1-swap local search.

    Parameters
    ----------
    scores : callable
        ``scores(sel)`` is an (n,) array ranking every column x by the value of ``sel + [x]``
        (values or gains over ``sel``; entries of ``sel`` itself are ignored).
    start : sequence of int
        Columns to start from.
    k : int
        Columns wanted.
    margin : float
        A swap must improve by more than this.
    rounds : int
        Swap rounds at most (a round tries every position once).
    expired : callable, optional
        Stops the swaps when it returns True.

    Returns
    -------
    list of int
    """
    sel = list(start)
    while len(sel) < k:
        v = scores(sel)
        v[sel] = -np.inf
        sel.append(int(np.argmax(v)))
    for _ in range(rounds):
        if expired is not None and expired():
            break
        improved = False
        for p in range(k):
            others = sel[:p] + sel[p + 1 :]
            v = scores(others)
            cur = v[sel[p]]
            v[sel] = -np.inf
            j = int(np.argmax(v))
            if v[j] > cur + margin:
                sel[p] = j
                improved = True
        if not improved:
            break
    return sel


def greedy_incumbent(matrix: sp.spmatrix, weights: np.ndarray, k: int, rounds: int = 20) -> tuple[int, ...]:
    """Greedy max coverage followed by first-improvement 1-swap local search (sparse).

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix
        0/1 pattern.
    weights : (m,) float64
        Row weights.
    k : int
        Number of columns (``<= n``).
    rounds : int
        Maximum swap passes.

    Returns
    -------
    tuple of int
        ``k`` distinct column indices, sorted.
    """
    a = sp.csc_matrix(matrix)
    at = a.T.tocsr()
    m, n = a.shape
    w = np.asarray(weights, dtype=np.float64)
    sel: list[int] = []
    resid = w.copy()
    for _ in range(k):
        g = at @ resid
        if sel:
            g[sel] = -1.0
        j = int(np.argmax(g))
        sel.append(j)
        resid[a.indices[a.indptr[j] : a.indptr[j + 1]]] = 0.0
    cnt = np.asarray(a[:, sel].sum(axis=1)).ravel()
    for _ in range(rounds):
        improved = False
        for p in range(k):
            s = sel[p]
            col = np.zeros(m)
            col[a.indices[a.indptr[s] : a.indptr[s + 1]]] = 1.0
            others = cnt - col
            g = at @ np.where(others > 0, 0.0, w)
            cur = g[s]
            g[sel] = -1.0
            j = int(np.argmax(g))
            if g[j] > cur * (1.0 + 1e-12) + 1e-300:
                newcol = np.zeros(m)
                newcol[a.indices[a.indptr[j] : a.indptr[j + 1]]] = 1.0
                cnt = others + newcol
                sel[p] = j
                improved = True
        if not improved:
            break
    return tuple(sorted(sel))
