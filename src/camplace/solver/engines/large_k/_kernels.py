"""Compiled kernels of the large-k engine (:mod:`camplace.solver.engines.large_k.search`).

All kernels read a CSC matrix (``indptr`` (n + 1,), ``indices`` (nnz,) row of each entry, sorted
within a column) whose values ``wq`` are already multiplied by the row weights
(``wq[p] = w_i Q_ij``) for the max-of-qualities objective, or a 0/1 pattern for the m-view one.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import prange

__all__ = ["gains", "hits_quality", "view_counts", "view_gains", "value_quality", "value_views"]

_PJIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False, "parallel": True}
_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}


@numba.njit(**_PJIT)
def gains(indptr, indices, wq, cur):  # pragma: no cover - compiled
    """(n,) float64: ``sum_i max(0, wq_ij - cur_i)`` for every column j (what it adds to ``cur``;
    with Lagrange multipliers for ``cur``, the Lagrangian column values ``rho_j``)."""
    n = indptr.shape[0] - 1
    out = np.zeros(n)
    for j in prange(n):
        s = 0.0
        for p in range(indptr[j], indptr[j + 1]):
            d = wq[p] - cur[indices[p]]
            if d > 0:
                s += d
        out[j] = s
    return out


@numba.njit(**_JIT)
def value_quality(indptr, indices, wq, cols, m):  # pragma: no cover - compiled
    """``sum_i max_{j in cols} wq_ij`` and the per-row best and second best values and the
    position (in ``cols``) of the best: ``(value, best1 (m,), best2 (m,), arg1 (m,))``."""
    b1 = np.zeros(m)
    b2 = np.zeros(m)
    a1 = np.full(m, -1, dtype=np.int64)
    for t in range(cols.shape[0]):
        j = cols[t]
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            x = wq[p]
            if x > b1[i]:
                b2[i] = b1[i]
                b1[i] = x
                a1[i] = t
            elif x > b2[i]:
                b2[i] = x
    return b1.sum(), b1, b2, a1


@numba.njit(**_JIT)
def hits_quality(indptr, indices, wq, lam, top, m):  # pragma: no cover - compiled
    """(m,) float64: per row, how many columns of ``top`` have ``wq_ij > lam_i`` (the rows they
    would serve in the Lagrangian subproblem)."""
    out = np.zeros(m)
    for t in range(top.shape[0]):
        j = top[t]
        for p in range(indptr[j], indptr[j + 1]):
            if wq[p] > lam[indices[p]]:
                out[indices[p]] += 1.0
    return out


@numba.njit(**_JIT)
def view_counts(indptr, indices, cols, m):  # pragma: no cover - compiled
    """(m,) int64: how many columns of ``cols`` observe each row."""
    out = np.zeros(m, dtype=np.int64)
    for t in range(cols.shape[0]):
        j = cols[t]
        for p in range(indptr[j], indptr[j + 1]):
            out[indices[p]] += 1
    return out


@numba.njit(**_PJIT)
def view_gains(indptr, indices, row_gain):  # pragma: no cover - compiled
    """(n,) float64: ``sum_{i observed by j} row_gain_i`` for every column j."""
    n = indptr.shape[0] - 1
    out = np.zeros(n)
    for j in prange(n):
        s = 0.0
        for p in range(indptr[j], indptr[j + 1]):
            s += row_gain[indices[p]]
        out[j] = s
    return out


@numba.njit(**_JIT)
def value_views(indptr, indices, w, cols, views):  # pragma: no cover - compiled
    """``sum_i w_i [at least views of cols observe i]``."""
    cnt = view_counts(indptr, indices, cols, w.shape[0])
    s = 0.0
    for i in range(w.shape[0]):
        if cnt[i] >= views:
            s += w[i]
    return s
