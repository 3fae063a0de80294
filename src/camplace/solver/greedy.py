"""The greedy heuristic of the k-camera modes (the models' hint, and the answer when no model fits).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["greedy", "NearCandidates"]

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
