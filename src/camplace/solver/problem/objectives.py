"""The objective of each mode (its definition, :func:`mode_value`), a bound that needs no model
(:func:`cheap_bound`) and the level rows of the quality reformulation (:func:`expand_levels`).

See :mod:`camplace.solver.api` for the formulations.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.names import MODES
from camplace.solver._support import bitkernels as _bk
from camplace.solver._support import parkernels as _pk
from camplace.solver.engines.angle._kernels import selected_pattern
from camplace.solver.problem.checks import coords, values_matrix
from camplace.solver.problem.presolve import as_pattern, check_weights

__all__ = ["mode_value", "angle_ok_pairs", "angle_paired", "bits_views_value", "cheap_bound", "expand_bytes", "expand_levels", "coverage_weight", "selected_row_stats"]


def angle_ok_pairs(pt: np.ndarray, cams: np.ndarray, min_angle_deg: float) -> np.ndarray:
    """(s, s) bool: the view rays point->camera of the two cameras make an angle >= min_angle."""
    d = cams - pt[None, :]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    ang = np.degrees(np.arccos(np.clip(d @ d.T, -1.0, 1.0)))
    return ang >= float(min_angle_deg)


def mode_value(
    matrix: Any,
    weights: Any,
    selected: Sequence[int],
    *,
    mode: str = "maxcover",
    views: int = 2,
    min_angle_deg: float | None = None,
    positions: Any = None,
    points: Any = None,
) -> float:
    """Objective value of a camera set for the covering modes (weight credited to the points).

    Parameters
    ----------
    matrix : (m, n) sparse or array_like
        Observation quality (> 0 observes).
    weights : (m,) array_like
    selected : sequence of int
        All cameras in use (fixed ones included).
    mode : {"maxcover", "quality", "multiview", "setcover"}
        ``setcover`` returns the covered weight (like ``maxcover``).
    views, min_angle_deg, positions, points
        As in :func:`solve` (multiview only).

    Returns
    -------
    float
    """
    q = values_matrix(matrix)
    m, n = q.shape
    w = check_weights(weights, m)
    cols = sorted({int(j) for j in selected})
    if not cols:
        return 0.0
    if mode not in MODES:
        raise CamplaceError(f"unknown mode {mode!r} (choose one of {', '.join(MODES)})")
    count, vmax = selected_row_stats(q, cols)
    if mode in ("maxcover", "setcover"):
        return float(np.sum(w[count > 0], dtype=np.float64))
    if mode == "quality":
        return float(w @ vmax)
    ok = count >= int(views)
    if min_angle_deg is not None:
        rows = np.flatnonzero(ok)
        data = q.data.view(np.uint8) if q.data.dtype.kind == "b" else q.data
        with ctrl_c_deferred():
            seen = selected_pattern(q.indptr, q.indices, data, rows, np.asarray(cols, dtype=np.int64), n)
        pos = coords(positions, n, "positions", "camera positions")[cols]
        pts = coords(points, m, "points", "point positions")[rows]
        ok[rows] = angle_paired(seen, pos, pts, float(min_angle_deg))
    return float(w[ok].sum())


def angle_paired(seen: np.ndarray, pos: np.ndarray, pts: np.ndarray, min_angle_deg: float) -> np.ndarray:
    """(r,) bool: rows where two of the cameras observing them make the angle (the rule of
    :func:`angle_ok_pairs`, for every row and pair of cameras at once).

    Parameters
    ----------
    seen : (r, s) bool
        Which of the ``s`` cameras observe each of the ``r`` rows.
    pos : (s, 3) float64
        The cameras' positions.
    pts : (r, 3) float64
        The rows' points.
    min_angle_deg : float
    """
    paired = np.zeros(seen.shape[0], dtype=bool)
    for a in range(pos.shape[0]):
        da = _unit_rays(pts, pos[a])
        for b in range(a + 1, pos.shape[0]):
            db = _unit_rays(pts, pos[b])
            dot = da[:, 0] * db[:, 0] + da[:, 1] * db[:, 1] + da[:, 2] * db[:, 2]
            ang = np.degrees(np.arccos(np.clip(dot, -1.0, 1.0)))
            paired |= seen[:, a] & seen[:, b] & (ang >= float(min_angle_deg))
    return paired


def bits_views_value(bits: Any, weights: np.ndarray, selected: Sequence[int], views: int,
                     min_angle_deg: float | None = None, positions: np.ndarray | None = None,
                     points: np.ndarray | None = None) -> float:
    """:func:`mode_value` of ``multiview`` on a binary matrix held as column bitsets
    (:class:`camplace.visibility.bits.BitMatrix`): the same float64 number, read from the
    selected columns' bits.

    Parameters
    ----------
    bits : BitMatrix
        (m, n).
    weights : (m,) float64
        Checked weights.
    selected : sequence of int
    views : int
    min_angle_deg : float, optional
    positions : (n, 3) float64, optional
        Checked camera positions (with the angle).
    points : (m, 3) float64, optional
        Checked point positions (with the angle).
    """
    cols = sorted({int(j) for j in selected})
    if not cols:
        return 0.0
    seen_all = np.stack([bits.column(j) for j in cols], axis=1)  # (m, s) bool
    ok = seen_all.sum(axis=1) >= int(views)
    if min_angle_deg is not None:
        rows = np.flatnonzero(ok)
        ok[rows] = angle_paired(seen_all[rows], np.asarray(positions)[cols], np.asarray(points)[rows],
                                float(min_angle_deg))
    return float(np.asarray(weights, dtype=np.float64)[ok].sum())


def _unit_rays(pts: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """(r, 3) unit vectors point -> camera (zero vectors stay zero)."""
    d = cam[None, :] - pts
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)


def cheap_bound(q: sp.csr_matrix, qf: sp.csr_matrix, w: np.ndarray, base: np.ndarray, k: int, mode: str, views: int) -> float:
    """A valid upper bound on the objective (fixed cameras included) without any model: every
    point gets the best any allowed camera could give it (multiview: at most k new views)."""
    if mode == "maxcover":
        return float(w @ ((base > 0) | (np.diff(qf.indptr) > 0)))
    if mode == "quality":
        best = qf.max(axis=1).toarray().ravel() if qf.shape[1] else np.zeros(q.shape[0])
        return float(w @ np.maximum(base, best))
    return float(w @ (base + np.minimum(np.diff(qf.indptr), k) >= views))


def expand_bytes(expanded_nnz: float, levels: int) -> int:
    """Memory of :func:`expand_levels`: its index arrays and CSR (24 bytes an entry) and a small
    array per level row (at most one per entry of the matrix)."""
    return int(24 * expanded_nnz + 150 * levels)


def expand_levels(q: sp.csr_matrix, w: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Level rows of the quality reformulation: (sum_i L_i, n) 0/1 pattern and their weights."""
    indptr_out = [0]
    idx_out: list[np.ndarray] = []
    w_out: list[float] = []
    for i in range(q.shape[0]):
        s, e = q.indptr[i], q.indptr[i + 1]
        if e == s or w[i] <= 0:
            continue
        vals, cols = q.data[s:e], q.indices[s:e]
        levels = np.unique(vals)[::-1]
        nxt = np.append(levels[1:], 0.0)
        for lv, lo in zip(levels, nxt):
            sel = cols[vals >= lv]
            idx_out.append(sel)
            indptr_out.append(indptr_out[-1] + sel.size)
            w_out.append(float(w[i]) * float(lv - lo))
    idx = np.concatenate(idx_out) if idx_out else np.zeros(0, dtype=np.int64)
    e = sp.csr_matrix((np.ones(idx.size), idx, np.asarray(indptr_out)), shape=(len(w_out), q.shape[1]))
    return e, np.asarray(w_out, dtype=np.float64)


def coverage_weight(matrix: Any, weights: Any, selected: Sequence[int]) -> float:
    """Total weight of the rows observed by at least one selected column.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Visibility; values > 0 mean "observes".
    weights : (m,) array_like of float64
        Point weights.
    selected : sequence of int
        0-based column indices (duplicates are ignored).

    Returns
    -------
    float
        ``sum(weights[i] for rows i covered by selected)`` in float64.
    """
    if sp.issparse(matrix) and matrix.format == "csr":
        count, _ = selected_row_stats(matrix, selected)
        w = check_weights(weights, matrix.shape[0])
        return float(np.sum(w[count > 0], dtype=np.float64))
    a = sp.csc_matrix(matrix) if sp.issparse(matrix) else sp.csc_matrix(np.asarray(matrix))
    m, n = a.shape
    w = check_weights(weights, m)
    cols = sorted({int(j) for j in selected})
    if any(j < 0 or j >= n for j in cols):
        raise CamplaceError(f"selected column index out of range 0..{n - 1}: {cols}")
    if not cols:
        return 0.0
    sub = as_pattern(a[:, cols])
    covered = np.diff(sub.indptr) > 0
    return float(np.sum(w[covered], dtype=np.float64))


def selected_row_stats(matrix: sp.csr_matrix, selected: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a CSR matrix: number of selected columns with a value > 0, and their largest value.

    One compiled pass over the matrix (no copy), so it suits large visibility matrices.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix
        Values > 0 mean "observes" (canonical or not: duplicates count separately).
    selected : sequence of int
        0-based column indices (duplicates are ignored).

    Returns
    -------
    count : (m,) int64
    vmax : (m,) float64
    """
    m, n = matrix.shape
    cols = sorted({int(j) for j in selected})
    if any(j < 0 or j >= n for j in cols):
        raise CamplaceError(f"selected column index out of range 0..{n - 1}: {cols}")
    chosen = np.zeros(n, dtype=bool)
    chosen[cols] = True
    data = np.asarray(matrix.data)
    if data.dtype.kind == "b":
        data = data.view(np.uint8)
    with ctrl_c_deferred():
        return _pk.selected_row_stats(matrix.indptr, matrix.indices, data, chosen)
