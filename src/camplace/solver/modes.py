"""All placement formulations behind one function, :func:`solve`.

Modes (``Q`` is the (m, n) points x candidates matrix, values in (0, 1], > 0 means "observes";
``w`` the point weights; ``S`` the chosen new cameras, ``F`` the fixed existing ones):

``maxcover``
    maximise ``sum_i w_i [some camera of S u F observes i]``, ``|S| = k``.
``quality``
    maximise ``sum_i w_i max_{j in S u F} Q_ij`` (0 for unobserved points), ``|S| = k``.
    Exact reformulation used by every engine: with the distinct values ``q_1 > ... > q_L`` of row
    ``i``, ``max_j Q_ij = sum_l (q_l - q_{l+1}) [some chosen j has Q_ij >= q_l]`` (``q_{L+1}=0``),
    i.e. max coverage of "level rows" ``(i, l)``. The exact engine gets the expanded matrix; the
    MIP/CP-SAT models use the compact chain ``y_il <= y_i,l-1 + sum_{j: Q_ij = q_l} x_j``.
``multiview``
    maximise the weight of points observed by at least ``views`` cameras of ``S u F``; with
    ``min_angle_deg`` a point also needs two of those cameras whose view rays (point -> camera)
    make an angle >= ``min_angle_deg`` at the point (needs ``positions`` and ``points``). Model:
    ``views * y_i <= sum_{j observes i} x_j``; with the angle, witness variables
    ``u_ia <= x_a``, ``sum_a u_ia = 2 y_i``, ``u_ia + u_ib <= 1`` for every pair closer than the
    angle.
``setcover``
    minimise the cost of ``S`` (``costs``, default 1 each; fixed cameras cost nothing) such that
    every coverable point of positive weight is observed (or, with ``required_fraction < 1``,
    that fraction of the coverable weight). Points no allowed camera observes are reported as
    uncoverable in ``stats``. ``objective`` is the cost and ``bound`` a LOWER bound. Solved by
    :mod:`camplace.solver.setcover_ls` (reductions, local search, Lagrangian bound; ``auto`` then
    runs SCIP on small reduced instances, ``mip`` / ``cpsat`` always; engine ``local-search`` in
    the result when no model ran); with ``min_distance_m`` conflicts, by the SCIP / CP-SAT model
    directly. ``seed`` and ``iterations`` set the local search.

Side constraints for every mode: ``fixed`` (kept, in ``selected``, not counted in ``k``),
``forbidden`` (never chosen) and ``min_distance_m`` (chosen cameras, fixed included, pairwise at
least that far apart; needs ``positions``).

Engines: ``exact`` (the bound-pruned bitset engine of :mod:`camplace.solver.bitset_exact` for
maxcover without minimum distance and multiview (any ``views``) without fixed cameras, minimum
angle or minimum distance -- with ``views = 2`` and ``k = 2, 3`` on up to 4,000 candidates (any
number when ``exact`` is requested) the pair-Gram stereo engine of
:mod:`camplace.solver.multiview_exact`, which is faster there; quality runs the quantised-tree
engine of :mod:`camplace.solver.quality_tree` and, for k = 2 or 3 new cameras on up to 3,000
candidates, hands over to the min-Gram triple engine of :mod:`camplace.solver.quality_exact` if the
tree has not finished within its share of the time (see :func:`_quality_engines`); when neither
fits in memory, the bitset engine on the level rows while that expansion stays small), ``mip``
(SCIP) and ``cpsat``.
``auto`` picks ``exact`` where it applies and ``k <= 4`` (``4 < k <= 8``: :mod:`camplace.solver.large_k`),
otherwise ``mip``. Each exact engine
first checks that its working memory fits in :func:`camplace.solver._common.memory_budget_bytes`;
if not, ``auto`` falls back to the general model (``stats["memory_fallback"]`` says why) and an
explicit ``exact`` is a one-line error.

For ``multiview`` with fewer cameras (new and fixed) than ``2 * views``, an answer the engine could
not prove gets its bound tightened by :func:`camplace.solver.pair_cap.opposite_pair_bound` (pairs of
points no allowed camera observes together, of which at most one can count); the engines then run
with 95 % of the time limit (all but 2 s at most), the bound with the rest
(``stats["opposite_pairs"]``). The bitset engine uses the same pairs inside its search.
"""

from __future__ import annotations

import logging
import math
import numbers
import time
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.solver._anglekernels import count_bad_pairs, selected_pattern
from camplace.solver._common import (
    OverBudget, check_engine_and_limit, coverage_weight, memory_budget, memory_budget_bytes, selected_row_stats,
)
from camplace.solver._dispatch import memory_fallback, run_maxcover_engine
from camplace.solver._model import LinearModel, model_bytes, solve_model
from camplace.solver.angle_exact import greedy_angle, solve_angle
from camplace.solver.bitset_exact import BITSET_MAX_K as EXACT_MAX_K
from camplace.solver.bitset_exact import bitset_bytes, solve_bitset
from camplace.solver.multiview_exact import solve_multiview_exact, stereo_bytes
from camplace.solver.large_k import LARGE_K_MAX, run_large_k
from camplace.solver.pair_cap import opposite_pair_bound
from camplace.solver.quality_exact import (
    QUALITY_EXACT_MAX_N, QUALITY_EXACT_MAX_PAIRS, min_gram_cost, quality_exact_bytes, solve_quality_exact,
)
from camplace.solver.quality_tree import quality_tree_bytes, solve_quality_tree
from camplace.solver.presolve import as_pattern, check_weights, presolve
from camplace.solver.result import SolverResult, jsonable, relative_gap
from camplace.solver.setcover_ls import solve_cover

__all__ = ["MODES", "solve", "mode_value", "conflict_pairs", "conflict_count"]

log = logging.getLogger(__name__)

MODES: tuple[str, ...] = ("maxcover", "quality", "multiview", "setcover")
_ENGINES = ("auto", "exact", "mip", "cpsat")
_STEREO_AUTO_MAX_N = 4000  # the pair-Gram stereo engine (views=2, k<=3) up to this many candidates, bitsets above
_QUALITY_EXPAND_MAX = 20_000_000  # auto uses the exact engine for quality up to this expanded nnz
_OPT_TOL = 1e-9
_CAP_SHARE = 0.05  # multiview: share of the time limit kept for the opposite-pairs bound ...
_CAP_MAX_S = 2.0  # ... at most this many seconds (a matching stopped early is still a valid bound)
# quality portfolio: the tree engine's share of the time when the min-Gram engine could follow
_TREE_FIRST_S = 30.0  # without a time limit
_TREE_FIRST_SHARE = 0.25
_TREE_FIRST_MIN_S = 2.0
_GREEDY_BLOCK_NNZ = 4_000_000  # matrix entries per column block in the greedy heuristic
_MODEL_BYTES_PER_ROW_MIN = 1000  # no model row costs less (see camplace.solver._model.model_bytes)
_CONFLICT_PAIR_BYTES = 200  # a conflicting pair: its array row, the greedy's adjacency sets, temporaries


# ----------------------------------------------------------------------------------------------
# input checks
# ----------------------------------------------------------------------------------------------


def _values_matrix(matrix: Any) -> sp.csr_matrix:
    """(m, n) CSR keeping only entries > 0 (the observation qualities).

    A canonical CSR matrix of float32/float64 values, all finite and >= 0, is used as it is (a
    visibility matrix can hold 10^8 entries; no copy); anything else is converted to float64.
    """
    if sp.issparse(matrix) and matrix.format == "csr" and matrix.dtype in (np.float32, np.float64) \
            and matrix.has_canonical_format:
        data = matrix.data
        if data.size == 0:
            return matrix
        lo, hi = data.min(), data.max()  # NaN propagates into both
        if np.isfinite(lo) and np.isfinite(hi) and lo >= 0:
            return matrix
    if sp.issparse(matrix):
        a = sp.csr_matrix(matrix, dtype=np.float64, copy=True)
    else:
        arr = np.asarray(matrix, dtype=np.float64)
        if arr.ndim != 2:
            raise CamplaceError(f"visibility matrix must be 2-D, got shape {arr.shape}")
        a = sp.csr_matrix(arr)
    if a.data.size and not np.all(np.isfinite(a.data)):
        raise CamplaceError("visibility matrix contains NaN or infinite values")
    a.data[a.data < 0] = 0.0
    a.eliminate_zeros()
    a.sum_duplicates()
    a.sort_indices()
    return a


def _index_set(values: Any, n: int, name: str) -> tuple[int, ...]:
    out = []
    for v in values or ():
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise CamplaceError(f"{name}: candidate indices must be integers, got {v!r}")
        if not 0 <= int(v) < n:
            raise CamplaceError(f"{name}: candidate index {int(v)} out of range 0..{n - 1}")
        out.append(int(v))
    return tuple(sorted(set(out)))


def _coords(arr: Any, rows: int, name: str, what: str) -> np.ndarray:
    a = np.asarray(arr, dtype=np.float64)
    if a.shape != (rows, 3) or not np.all(np.isfinite(a)):
        raise CamplaceError(f"{name} must be a finite ({rows}, 3) array of {what}, got shape {a.shape}")
    return a


def conflict_count(positions: np.ndarray, min_distance_m: float) -> int:
    """Upper bound on the number of candidate pairs closer than ``min_distance_m`` (pairs at most
    that far apart), counted without listing them."""
    from scipy.spatial import cKDTree

    n = positions.shape[0]
    if n < 2 or min_distance_m <= 0:
        return 0
    tree = cKDTree(positions)
    return max(0, (int(tree.count_neighbors(tree, float(min_distance_m))) - n) // 2)


def conflict_pairs(positions: np.ndarray, min_distance_m: float) -> np.ndarray:
    """Candidate pairs closer than ``min_distance_m``.

    Parameters
    ----------
    positions : (n, 3) float64
    min_distance_m : float

    Returns
    -------
    (p, 2) int64
        Pairs ``a < b`` with ``|pos_a - pos_b| < min_distance_m``.
    """
    from scipy.spatial import cKDTree

    if positions.shape[0] < 2 or min_distance_m <= 0:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = cKDTree(positions).query_pairs(float(min_distance_m), output_type="ndarray").astype(np.int64)
    if pairs.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    d = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1)
    pairs = np.sort(pairs[d < min_distance_m], axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


# ----------------------------------------------------------------------------------------------
# objective values (also the definition of each mode)
# ----------------------------------------------------------------------------------------------


def _angle_ok_pairs(pt: np.ndarray, cams: np.ndarray, min_angle_deg: float) -> np.ndarray:
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
    q = _values_matrix(matrix)
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
        pos = _coords(positions, n, "positions", "camera positions")[cols]
        pts = _coords(points, m, "points", "point positions")[rows]
        paired = np.zeros(rows.size, dtype=bool)
        for a in range(len(cols)):  # the rule of _angle_ok_pairs, for every row and pair of cameras at once
            da = _unit_rays(pts, pos[a])
            for b in range(a + 1, len(cols)):
                db = _unit_rays(pts, pos[b])
                dot = da[:, 0] * db[:, 0] + da[:, 1] * db[:, 1] + da[:, 2] * db[:, 2]
                ang = np.degrees(np.arccos(np.clip(dot, -1.0, 1.0)))
                paired |= seen[:, a] & seen[:, b] & (ang >= float(min_angle_deg))
        ok[rows] = paired
    return float(w[ok].sum())


def _unit_rays(pts: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """(r, 3) unit vectors point -> camera (zero vectors stay zero)."""
    d = cam[None, :] - pts
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------


def _merge_rows(a: sp.csr_matrix, w: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Merge rows with identical indices AND values, summing their weights."""
    seen: dict[bytes, int] = {}
    first: list[int] = []
    wsum: list[float] = []
    for i in range(a.shape[0]):
        s, e = a.indptr[i], a.indptr[i + 1]
        key = a.indices[s:e].astype(np.int32).tobytes() + b"|" + a.data[s:e].tobytes()
        g = seen.get(key)
        if g is None:
            seen[key] = len(first)
            first.append(i)
            wsum.append(float(w[i]))
        else:
            wsum[g] += float(w[i])
    return a[first].tocsr() if first else a[:0], np.asarray(wsum, dtype=np.float64)


def _greedy(
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


def _expand_bytes(expanded_nnz: float, levels: int) -> int:
    """Memory of :func:`_expand_levels`: its index arrays and CSR (24 bytes an entry) and a small
    array per level row (at most one per entry of the matrix)."""
    return int(24 * expanded_nnz + 150 * levels)


def _expand_levels(q: sp.csr_matrix, w: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
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


# ----------------------------------------------------------------------------------------------
# the entry point
# ----------------------------------------------------------------------------------------------


def solve(
    matrix: Any,
    weights: Any,
    k: int | None = None,
    *,
    mode: str = "maxcover",
    views: int = 2,
    min_angle_deg: float | None = None,
    positions: Any = None,
    points: Any = None,
    costs: Any = None,
    required_fraction: float = 1.0,
    fixed: Sequence[int] = (),
    forbidden: Sequence[int] = (),
    min_distance_m: float | None = None,
    engine: str = "auto",
    time_limit_s: float | None = None,
    memory_budget_bytes: int | None = None,
    seed: int = 0,
    iterations: int | None = None,
) -> SolverResult:
    """Choose cameras under one of the formulations (see the module docstring).

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Observation quality in (0, 1] (> 0 means "observes").
    weights : (m,) array_like of float64
        Non-negative point weights.
    k : int, optional
        Number of NEW cameras (required for every mode but ``setcover``, which must not get it).
    mode : {"maxcover", "quality", "multiview", "setcover"}
    views : int
        multiview: cameras needed per point (default 2).
    min_angle_deg : float, optional
        multiview: minimum angle at the point between two of its views (needs positions, points).
    positions : (n, 3) array_like, optional
        Camera positions (for ``min_distance_m`` and ``min_angle_deg``).
    points : (m, 3) array_like, optional
        Point positions (for ``min_angle_deg``).
    costs : (n,) array_like, optional
        setcover: non-negative camera costs (default 1).
    required_fraction : float
        setcover: fraction of the coverable weight to observe, in (0, 1] (default 1: every
        coverable point of positive weight).
    fixed, forbidden : sequence of int
        Cameras always kept / never chosen.
    min_distance_m : float, optional
        Minimum distance between any two chosen cameras (fixed included).
    engine : {"auto", "exact", "mip", "cpsat"}
    time_limit_s : float, optional
        Wall-clock limit; on expiry the best solution found is returned with its gap.
    memory_budget_bytes : int, optional
        Cap on the memory any engine or model may use (``--memory-budget-gb``); engines also stay
        within :data:`~camplace.solver._common.MEMORY_FRACTION` of the memory available.
    seed : int
        setcover: seed of the local search (:mod:`camplace.solver.setcover_ls`).
    iterations : int, optional
        setcover: iteration budget of the local search; with it and no time limit the answer is
        fully deterministic (with a time limit it depends on the machine's speed).

    Returns
    -------
    SolverResult
        ``selected`` holds fixed and new cameras (sorted original indices); ``objective`` is
        recomputed on the original data; for setcover it is the cost of the new cameras and
        ``bound`` a lower bound. ``stats`` has ``mode``, ``fixed``, ``new`` and, for setcover,
        ``uncoverable_points`` / ``uncoverable_weight`` / ``covered_fraction``.

    Raises
    ------
    CamplaceError
        On malformed input or an impossible request (one line).
    """
    with memory_budget(memory_budget_bytes):
        return _solve(matrix, weights, k, mode=mode, views=views, min_angle_deg=min_angle_deg, positions=positions,
                      points=points, costs=costs, required_fraction=required_fraction, fixed=fixed, forbidden=forbidden,
                      min_distance_m=min_distance_m, engine=engine, time_limit_s=time_limit_s, seed=seed,
                      iterations=iterations)


def _solve(
    matrix: Any, weights: Any, k: int | None, *, mode: str, views: int, min_angle_deg: float | None, positions: Any,
    points: Any, costs: Any, required_fraction: float, fixed: Sequence[int], forbidden: Sequence[int],
    min_distance_m: float | None, engine: str, time_limit_s: float | None, seed: int = 0, iterations: int | None = None,
) -> SolverResult:
    """:func:`solve` within the memory budget."""
    t0 = time.perf_counter()
    if mode not in MODES:
        raise CamplaceError(f"unknown mode {mode!r} (choose one of {', '.join(MODES)})")
    check_engine_and_limit(engine, _ENGINES, time_limit_s)
    q = _values_matrix(matrix)
    m, n = q.shape
    if n == 0:
        raise CamplaceError("the visibility matrix has no candidate columns")
    w = check_weights(weights, m)
    fixed_t = _index_set(fixed, n, "fixed")
    forbidden_t = _index_set(forbidden, n, "forbidden")
    both = sorted(set(fixed_t) & set(forbidden_t))
    if both:
        raise CamplaceError(f"candidates {both} are both fixed and forbidden")
    pos = None
    if positions is not None:
        pos = _coords(positions, n, "positions", "camera positions")
    conflicts = np.zeros((0, 2), dtype=np.int64)
    too_many: OverBudget | None = None  # conflicting pairs that would not fit in memory
    if min_distance_m is not None:
        if not (float(min_distance_m) >= 0.0):
            raise CamplaceError(f"min_distance_m must be >= 0, got {min_distance_m!r}")
        if pos is None:
            raise CamplaceError("min_distance_m needs the camera positions (positions, shape (n, 3))")
        n_pairs = conflict_count(pos, float(min_distance_m))
        need, budget = n_pairs * _CONFLICT_PAIR_BYTES, memory_budget_bytes()
        if need > budget:
            too_many = OverBudget(need, budget, f"min_distance_m={float(min_distance_m):g} ({n_pairs} candidate pairs "
                                                "closer than that)")
            if engine != "auto" or mode == "setcover":
                raise CamplaceError(f"{too_many.message}; lower min_distance_m or use fewer candidates")
        else:
            conflicts = conflict_pairs(pos, float(min_distance_m))
    pts = None
    if min_angle_deg is not None:
        if mode != "multiview":
            raise CamplaceError("min_angle_deg applies to mode 'multiview' only")
        if not (0.0 <= float(min_angle_deg) <= 180.0):
            raise CamplaceError(f"min_angle_deg must be within 0..180, got {min_angle_deg!r}")
        if pos is None or points is None:
            raise CamplaceError("min_angle_deg needs camera positions (positions (n, 3)) and point positions (points (m, 3))")
        pts = _coords(points, m, "points", "point positions")
    if mode == "multiview":
        if isinstance(views, bool) or not isinstance(views, numbers.Integral) or int(views) < 1:
            raise CamplaceError(f"views must be an integer >= 1, got {views!r}")
        views = int(views)
        if min_angle_deg is not None and views < 2:
            raise CamplaceError("min_angle_deg needs views >= 2")
    if too_many is not None:
        assert pos is not None and min_distance_m is not None
        return _spaced_fallback(q, w, k, mode, views, min_angle_deg, pos, pts, fixed_t, forbidden_t,
                                float(min_distance_m), engine, too_many, t0)

    fixed_set = set(fixed_t)
    banned = set(forbidden_t)
    for a, b in conflicts.tolist():
        if a in fixed_set and b in fixed_set:
            raise CamplaceError(f"fixed cameras {a} and {b} are closer than min_distance_m={min_distance_m}")
        if a in fixed_set:
            banned.add(b)
        elif b in fixed_set:
            banned.add(a)
    free = np.ones(n, dtype=bool)
    free[list(fixed_set | banned)] = False
    free_cols = np.flatnonzero(free)
    keep_conf = free[conflicts[:, 0]] & free[conflicts[:, 1]] if conflicts.size else np.zeros(0, dtype=bool)
    conflicts = conflicts[keep_conf]

    if mode == "setcover":
        if k is not None:
            raise CamplaceError("mode 'setcover' chooses the number of cameras itself: do not give k")
        if conflicts.size:  # the model runs directly (otherwise setcover_ls checks its own memory)
            _check_setcover_memory(q, w, free_cols, conflicts, engine)
        ctx = _setcover(q, w, costs, required_fraction, fixed_t, free_cols, conflicts, engine, time_limit_s, t0,
                        seed, iterations)
    else:
        if k is None or isinstance(k, bool) or not isinstance(k, numbers.Integral):
            raise CamplaceError(f"k must be an integer number of cameras for mode {mode!r}, got {k!r}")
        k = int(k)
        if k < (0 if fixed_t else 1):
            raise CamplaceError(f"k must be at least {0 if fixed_t else 1}, got {k}")
        if k > free_cols.size:
            raise CamplaceError(
                f"cannot choose k={k} new cameras from {free_cols.size} allowed candidates "
                "(lower k, or forbid/fix fewer cameras)"
            )
        # multiview with fewer cameras than 2 x views: opposite points cap the bound when the search
        # leaves a gap (pair_cap); the engines then leave a little of the time limit for the cap.
        cap = mode == "multiview" and k + len(fixed_t) < 2 * views
        inner = time_limit_s
        if cap and time_limit_s is not None:
            inner = time_limit_s - min(_CAP_SHARE * time_limit_s, _CAP_MAX_S)
        ctx = _cover_modes(q, w, k, mode, views, min_angle_deg, pos, pts, fixed_t, free_cols, conflicts, engine, inner, t0)
        searched = ctx[5].get("engine_stats", {}).get("search") == "opposite pairs"  # already bounded by them
        if cap and ctx[0] is not None and ctx[1] != "optimal" and not searched:
            ctx = _opposite_pair_cap(ctx, q, w, views, k + len(fixed_t), np.union1d(free_cols, fixed_t).astype(np.int64),
                                     _remaining(t0, time_limit_s))

    selected, status, objective, bound, name, stats = ctx
    minimize = mode == "setcover"
    if status == "optimal":
        bound, gap = objective, 0.0
    elif selected is None:
        gap = math.inf
    elif minimize:
        bound = min(bound, objective)
        gap = max(0.0, (objective - bound) / max(abs(objective), 1e-12))
    else:
        bound = max(bound, objective)
        gap = relative_gap(bound, objective)
    scale = 1.0 if minimize else float(w.sum())
    if selected is not None and status == "feasible" and abs(bound - objective) <= _OPT_TOL * max(abs(bound), scale):
        status, bound, gap = "optimal", objective, 0.0
    sel = tuple(sorted(int(j) for j in (selected or ())))
    stats.update({"mode": mode, "engine_requested": engine, "fixed": list(fixed_t), "forbidden": list(forbidden_t),
                  "new": [j for j in sel if j not in fixed_set], "conflict_pairs": int(conflicts.shape[0]),
                  "rows_in": int(m), "cols_in": int(n)})
    elapsed = time.perf_counter() - t0
    log.info("%s engine=%s: %s objective %.9g bound %.9g gap %.3g in %.3f s", mode, name, status, objective, bound, gap, elapsed)
    return SolverResult(
        selected=sel, status=status, objective=float(objective), bound=float(bound), gap=float(gap),
        engine=name, time_s=elapsed, stats=jsonable(stats),
    )


def _opposite_pair_cap(
    ctx: tuple[Any, str, float, float, str, dict[str, Any]], q: sp.csr_matrix, w: np.ndarray, views: int,
    cameras: int, allowed: np.ndarray, time_limit_s: float | None,
) -> tuple[Any, str, float, float, str, dict[str, Any]]:
    """Tighten an unproven multiview bound with :func:`~camplace.solver.pair_cap.opposite_pair_bound`."""
    selected, status, objective, bound, name, stats = ctx
    cap, cap_stats = opposite_pair_bound(q, w, views, cameras, columns=allowed, time_limit_s=time_limit_s)
    cap_stats["bound_before"] = float(bound)
    stats["opposite_pairs"] = cap_stats
    if cap < bound:
        bound = cap
    return selected, status, objective, bound, name, stats


def _remaining(t0: float, time_limit_s: float | None) -> float | None:
    return None if time_limit_s is None else max(1e-3, float(time_limit_s) - (time.perf_counter() - t0))


def _cover_modes(
    q: sp.csr_matrix, w: np.ndarray, k: int, mode: str, views: int, min_angle_deg: float | None,
    pos: np.ndarray | None, pts: np.ndarray | None, fixed_t: tuple[int, ...], free_cols: np.ndarray,
    conflicts: np.ndarray, engine: str, time_limit_s: float | None, t0: float,
) -> tuple[Any, str, float, float, str, dict[str, Any]]:
    """maxcover / quality / multiview. Returns (selected, status, objective, bound, engine, stats)."""
    m, n = q.shape
    stats: dict[str, Any] = {"k": k}

    def value(sel: Sequence[int]) -> float:
        return mode_value(q, w, list(sel), mode=mode, views=views, min_angle_deg=min_angle_deg, positions=pos, points=pts)

    fixed_value = value(fixed_t)
    if k == 0:
        return tuple(fixed_t), "optimal", fixed_value, fixed_value, "exact", stats

    # Residual instance on the free columns: what the new cameras add on top of the fixed ones.
    qf = q if free_cols.size == n else q[:, free_cols].tocsr()
    if mode == "maxcover":
        covered = (np.diff(q[:, list(fixed_t)].tocsr().indptr) > 0) if fixed_t else np.zeros(m, dtype=bool)
        resid_w = np.where(covered, 0.0, w)
        resid = qf
        base = covered.astype(np.float64)
    elif mode == "quality":
        base = q[:, list(fixed_t)].max(axis=1).toarray().ravel() if fixed_t else np.zeros(m)
        resid = qf
        if fixed_t:  # what a new camera adds over the fixed ones' best quality
            resid = qf.copy()
            resid.data = np.maximum(resid.data - np.repeat(base, np.diff(resid.indptr)), 0.0)
            resid.eliminate_zeros()
        resid_w = w
    else:
        base = np.asarray((q[:, list(fixed_t)] > 0).sum(axis=1)).ravel().astype(np.float64) if fixed_t else np.zeros(m)
        resid, resid_w = qf, w

    # -- issue 16: 4 < k <= 8 goes to camplace.solver.large_k (None: it does not fit, go on) --
    if EXACT_MAX_K < k <= LARGE_K_MAX and engine in ("auto", "exact") and conflicts.shape[0] == 0 and (
            mode != "multiview" or (min_angle_deg is None and not fixed_t)):
        got = run_large_k(resid, resid_w, k, mode, views, engine, _remaining(t0, time_limit_s), stats)
        if got is not None:
            sel = tuple(sorted(set(fixed_t) | {int(free_cols[j]) for j in got[0]}))
            const = fixed_value if mode == "maxcover" else float(w @ base) if mode == "quality" else 0.0
            return sel, got[1], value(sel), got[2] + const, got[3], stats
    # -- end of the issue-16 hook --

    exact_ok = mode in ("maxcover", "quality") and conflicts.shape[0] == 0
    budget = memory_budget_bytes()
    expanded = None
    if mode == "quality" and exact_ok and engine in ("auto", "exact"):
        nf = free_cols.size
        tree_ok = (engine == "exact" or k <= EXACT_MAX_K) and quality_tree_bytes(m, nf, resid.nnz) <= budget
        gram_ok = (k in (2, 3) and nf <= QUALITY_EXACT_MAX_N and min_gram_cost(resid) <= QUALITY_EXACT_MAX_PAIRS
                   and quality_exact_bytes(m, nf) <= budget)
        if tree_ok or gram_ok:
            return _quality_engines(resid, resid_w, k, tree_ok, gram_ok, fixed_t, free_cols, value,
                                    float(w @ base), t0, time_limit_s, stats)
        if engine == "exact" or k <= EXACT_MAX_K:
            # Expanded nnz = sum_i s_i (s_i + 1) / 2 at most; estimate before building.
            s = np.diff(resid.indptr).astype(np.float64)
            est = float(np.sum(s * (s + 1) / 2))
            stats["quality_expanded_nnz_estimate"] = est
            if est <= _QUALITY_EXPAND_MAX and _expand_bytes(est, resid.nnz) <= budget:
                expanded = _expand_levels(resid, resid_w)
            else:
                _too_big(engine, stats, quality_tree_bytes(m, nf, resid.nnz), budget)
    multiview_ok = mode == "multiview" and min_angle_deg is None and not fixed_t and conflicts.shape[0] == 0
    angle_ok = mode == "multiview" and min_angle_deg is not None and conflicts.shape[0] == 0
    if engine == "exact" and not (exact_ok or multiview_ok or angle_ok):
        raise CamplaceError(
            "the exact engine solves maxcover and quality without min_distance_m, and multiview without fixed "
            "cameras or minimum distance (with or without a minimum angle); use engine mip or cpsat"
        )
    name = engine
    if engine == "auto":
        name = "exact" if (exact_ok and k <= EXACT_MAX_K and (mode == "maxcover" or expanded is not None)) or (
            (multiview_ok or angle_ok) and k <= EXACT_MAX_K) else "mip"

    angle_tried = name == "exact" and angle_ok
    if angle_tried:
        got = _angle_engine(q, w, k, views, min_angle_deg, pos, pts, fixed_t, free_cols, engine, t0, time_limit_s,
                            value, stats)
        if got is not None:
            return got
        name = "mip"

    if name == "exact" and multiview_ok:
        pre = presolve(resid, resid_w, k, dominance=False)  # dominance is only valid for one view
        mp, np_ = pre.shape
        need = bitset_bytes(mp, np_, min(views, k), k)
        if need > budget:
            _too_big(engine, stats, need, budget)
            name = "mip"
        else:
            stereo = views == 2 and k in (2, 3) and (engine == "exact" or free_cols.size <= _STEREO_AUTO_MAX_N)
            if stereo and stereo_bytes(mp, np_) <= budget:
                out = solve_multiview_exact(pre, time_limit_s=_remaining(t0, time_limit_s))
            else:
                out = solve_bitset(pre, views=views, time_limit_s=_remaining(t0, time_limit_s))
            sel = tuple(int(free_cols[j]) for j in pre.original_columns(out.selected)) if out.selected else None
            stats.update({"rows_after": mp, "cols_after": np_, "engine_stats": dict(out.stats)})
            return sel, out.status if sel else "unknown", value(sel) if sel else 0.0, float(out.bound), name, stats

    if name == "exact" or (exact_ok and mode == "maxcover"):
        # Plain max coverage (possibly of quality level rows): presolve + the existing engines.
        pat, pw = (resid, resid_w) if mode == "maxcover" else (expanded if expanded is not None else _expand_levels(resid, resid_w))
        pre = presolve(pat, pw, k)
        name, out = run_maxcover_engine(name, engine, pre, _remaining(t0, time_limit_s), stats, budget)
        new = tuple(int(free_cols[j]) for j in pre.original_columns(out.selected)) if out.selected else ()
        sel = tuple(sorted(set(fixed_t) | set(new))) if new else None
        objective = value(sel) if sel else fixed_value
        const = fixed_value if mode == "maxcover" else float(w @ base)
        stats.update({"rows_after": pre.shape[0], "cols_after": pre.shape[1], "engine_stats": dict(out.stats)})
        return sel, out.status if sel else "unknown", objective, float(out.bound) + const, name, stats

    # General model (SCIP / CP-SAT). The greedy answer comes first: it is the hint, and the answer
    # (with a cheap valid bound) when the time limit passes while the model is still being built.
    nf = free_cols.size
    adj: list[set[int]] | None = None
    if conflicts.size:
        adj = [set() for _ in range(nf)]
        for a, b in np.searchsorted(free_cols, conflicts).tolist():
            adj[a].add(b)
            adj[b].add(a)
    g_base = np.zeros(m) if mode == "quality" else base
    hint_local = _greedy(resid.tocsc() if mode != "multiview" else qf.tocsc(), resid_w, mode, views, g_base, k,
                         np.ones(nf, dtype=bool), adj)
    hint_sel = None
    if hint_local is not None:
        hint_sel = tuple(sorted(set(fixed_t) | {int(free_cols[j]) for j in hint_local}))
    budget = memory_budget_bytes()
    size = _model_size(q, resid, resid_w, w, mode, views, min_angle_deg, pos, pts, fixed_t, free_cols, conflicts,
                       budget)
    need = model_bytes(name, *size)
    stats["model_estimate"] = {"variables": size[0], "rows": size[1], "nonzeros": size[2], "bytes": need}
    try:
        if need > budget:
            exc = OverBudget(need, budget, f"the {'SCIP' if name == 'mip' else 'CP-SAT'} model of mode {mode}")
            if engine == name:
                raise CamplaceError(f"{exc.message}; use fewer candidates / points"
                                    + (", or engine exact" if angle_ok else ""))
            if angle_ok and not angle_tried:  # auto, k > 4: the angle engine gives a valid bound at the limit
                memory_fallback(exc, engine, name, stats, "falling back to the exact angle engine")
                got = _angle_engine(q, w, k, views, min_angle_deg, pos, pts, fixed_t, free_cols, engine, t0,
                                    time_limit_s, value, stats)
                if got is not None:
                    return got
            memory_fallback(exc, engine, name, stats, "returning the greedy answer with a cheap bound")
            raise _BuildTimeout(f"skipped: {exc.message}")
        model, x, wmax, const = _build_model(q, resid, resid_w, w, base, k, mode, views, min_angle_deg, pos, pts,
                                             fixed_t, free_cols, conflicts, fixed_value, t0, time_limit_s)
    except _BuildTimeout as exc:
        stats["model_build"] = (str(exc) or "interrupted by the time limit") + ": greedy answer, cheap bound"
        bound = _cheap_bound(q, qf, w, base, k, mode, views)
        if angle_ok:  # the greedy above ignores the angle; this one counts it (O(m + n) memory)
            assert pos is not None and pts is not None and min_angle_deg is not None
            new = greedy_angle(q, w, k, views, float(min_angle_deg), pos, pts, np.asarray(fixed_t, dtype=np.int64),
                               free_cols, time_limit_s=_remaining(t0, time_limit_s))
            cand = tuple(sorted(set(fixed_t) | set(new)))
            if hint_sel is None or value(cand) > value(hint_sel):
                hint_sel = cand
        if hint_sel is None:
            return None, "unknown", fixed_value, bound, name, stats
        return hint_sel, "feasible", value(hint_sel), bound, name, stats
    hint = None
    if hint_local is not None:
        hint = {int(x[j]): (1.0 if j in hint_local else 0.0) for j in range(nf)}
    out = solve_model(model, name, time_limit_s=_remaining(t0, time_limit_s), hint=hint)
    stats["engine_stats"] = dict(out.stats)
    sel = None
    if out.values is not None:
        new = [int(free_cols[j]) for j in np.flatnonzero(out.values[x] > 0.5)]
        sel = tuple(sorted(set(fixed_t) | set(new)))
    objective = value(sel) if sel is not None else -math.inf
    status = out.status
    if hint_sel is not None:
        hv = value(hint_sel)
        stats["hint_value"] = hv
        if sel is None or hv > objective:
            sel, objective = hint_sel, hv
            if status in ("unknown", "optimal"):
                status = "feasible"
    if sel is None:
        return None, status, fixed_value, math.inf, name, stats
    bound = out.bound * wmax + const if math.isfinite(out.bound) else math.inf
    return sel, status, objective, bound, name, stats


def _quality_engines(
    resid: sp.csr_matrix, resid_w: np.ndarray, k: int, tree_ok: bool, gram_ok: bool, fixed_t: tuple[int, ...],
    free_cols: np.ndarray, value: Any, const: float, t0: float, time_limit_s: float | None, stats: dict[str, Any],
) -> tuple[Any, str, float, float, str, dict[str, Any]]:
    """The exact quality engines as a portfolio: the quantised tree first (fast on the spatially
    coherent qualities of real scenes); if it has not proven the optimum within its share of the
    time and the min-Gram triple engine applies (k = 2, 3, small n), that one gets the rest (it does
    not depend on coherence). The better camera set wins; the smaller bound holds for both."""
    runs: list[tuple[str, Any]] = []
    if tree_ok:
        limit = _remaining(t0, time_limit_s)
        if gram_ok:
            limit = _TREE_FIRST_S if limit is None else min(limit, max(_TREE_FIRST_MIN_S, _TREE_FIRST_SHARE * limit))
        runs.append(("tree", solve_quality_tree(resid, resid_w, k, time_limit_s=limit)))
    if gram_ok and (not runs or runs[0][1].status != "optimal"):
        runs.append(("min-gram", solve_quality_exact(resid, resid_w, k, time_limit_s=_remaining(t0, time_limit_s))))
    best = None
    for name, out in runs:
        sel = tuple(sorted(set(fixed_t) | {int(free_cols[j]) for j in out.selected}))
        v = value(sel)
        if best is None or v > best[1] or (out.status == "optimal" and best[2] != "optimal" and v >= best[1]):
            best = (sel, v, out.status)
    assert best is not None
    sel, objective, status = best
    bound = min(float(out.bound) for _, out in runs) + const
    if any(out.status == "optimal" for _, out in runs) or bound <= objective + _OPT_TOL * max(1.0, abs(objective)):
        status, bound = "optimal", objective
    stats["quality_engines"] = [name for name, _ in runs]
    stats["engine_stats"] = dict(runs[0][1].stats)
    if len(runs) > 1:
        stats["engine_stats"]["min_gram"] = dict(runs[1][1].stats)
    return sel, status, objective, bound, "exact", stats


def _angle_engine(
    q: sp.csr_matrix, w: np.ndarray, k: int, views: int, min_angle_deg: float | None, pos: np.ndarray | None,
    pts: np.ndarray | None, fixed_t: tuple[int, ...], free_cols: np.ndarray, engine: str, t0: float,
    time_limit_s: float | None, value: Any, stats: dict[str, Any],
) -> tuple[Any, str, float, float, str, dict[str, Any]] | None:
    """The exact angle engine (:mod:`camplace.solver.angle_exact`); None when it does not fit in
    memory and ``auto`` may fall back (``exact`` requested: a one-line error)."""
    assert pos is not None and pts is not None and min_angle_deg is not None
    try:
        out = solve_angle(q, w, k, views, float(min_angle_deg), pos, pts, np.asarray(fixed_t, dtype=np.int64),
                          free_cols, time_limit_s=_remaining(t0, time_limit_s), budget_bytes=memory_budget_bytes())
    except OverBudget as exc:
        _too_big(engine, stats, exc.need, exc.budget)
        return None
    sel = tuple(sorted(set(fixed_t) | set(out.selected)))
    stats["engine_stats"] = dict(out.stats)
    return sel, out.status, value(sel), float(out.bound), "exact", stats


def _too_big(engine: str, stats: dict[str, Any], need: int, budget: int) -> None:
    """The exact engine would need more memory than is free: an error when it was asked for,
    otherwise a logged fallback to the general model (recorded in ``stats``)."""
    msg = (f"the exact engine needs about {need / 2**30:.1f} GiB for this instance but only "
           f"{budget / 2**30:.1f} GiB may be used")
    if engine == "exact":
        raise CamplaceError(msg + "; use engine mip (or fewer candidates / points)")
    log.warning("%s; falling back to the general model", msg)
    stats["memory_fallback"] = msg


class _BuildTimeout(Exception):
    """The time limit passed while the general model was being built."""


class _NearCandidates:
    """``adj[j]``: the free candidates closer than ``dmin`` to free candidate ``j``, found with a k-d
    tree when asked (the greedy's conflicts without listing every pair)."""

    def __init__(self, pos_free: np.ndarray, dmin: float) -> None:
        from scipy.spatial import cKDTree

        self.pos, self.dmin, self.tree = pos_free, dmin, cKDTree(pos_free)

    def __getitem__(self, j: int) -> list[int]:
        near = np.asarray(self.tree.query_ball_point(self.pos[j], self.dmin), dtype=np.int64)
        d = np.linalg.norm(self.pos[near] - self.pos[j], axis=1)
        return [int(b) for b in near[(d < self.dmin) & (near != j)]]


def _spaced_fallback(
    q: sp.csr_matrix, w: np.ndarray, k: Any, mode: str, views: int, min_angle_deg: float | None, pos: np.ndarray,
    points: np.ndarray | None, fixed: Sequence[int], forbidden: Sequence[int], dmin: float, engine: str,
    exc: OverBudget, t0: float,
) -> SolverResult:
    """Too many conflicting pairs to list: the greedy answer (spacing checked with a k-d tree) and the
    cheap bound, which ignores the spacing and so stays valid."""
    m, n = q.shape
    if k is None or isinstance(k, bool) or not isinstance(k, numbers.Integral) or int(k) < 0:
        raise CamplaceError(f"k must be an integer number of cameras for mode {mode!r}, got {k!r}")
    k = int(k)
    fixed_t = _index_set(fixed, n, "fixed")
    banned = set(_index_set(forbidden, n, "forbidden"))
    near = _NearCandidates(pos, dmin)
    for f in fixed_t:
        for b in near[f]:
            if b in fixed_t:
                raise CamplaceError(f"fixed cameras {f} and {b} are closer than min_distance_m={dmin}")
            banned.add(b)
    free = np.ones(n, dtype=bool)
    free[list(set(fixed_t) | banned)] = False
    free_cols = np.flatnonzero(free)
    if k > free_cols.size:
        raise CamplaceError(f"cannot choose k={k} new cameras from {free_cols.size} allowed candidates "
                            "(lower k, or forbid/fix fewer cameras)")
    pts = points
    qf = q[:, free_cols].tocsr()
    fx = list(fixed_t)
    if mode == "maxcover":
        base = ((np.diff(q[:, fx].tocsr().indptr) > 0) if fx else np.zeros(m, dtype=bool)).astype(np.float64)
        gw = np.where(base > 0, 0.0, w)
    elif mode == "quality":
        base = q[:, fx].max(axis=1).toarray().ravel() if fx else np.zeros(m)
        gw = w
    else:
        base = np.asarray((q[:, fx] > 0).sum(axis=1)).ravel().astype(np.float64) if fx else np.zeros(m)
        gw = w
    msg = f"{exc.message}; returning the greedy answer with a bound that ignores the spacing"
    log.warning("%s", msg)
    local = _greedy(qf.tocsc(), gw, mode, views, base, k, np.ones(free_cols.size, dtype=bool),
                    _NearCandidates(pos[free_cols], dmin)) if k else ()
    sel = None if local is None else tuple(sorted(set(fixed_t) | {int(free_cols[j]) for j in local}))
    bound = _cheap_bound(q, qf, w, base, k, mode, views)
    objective = mode_value(q, w, sel, mode=mode, views=views, min_angle_deg=min_angle_deg, positions=pos,
                           points=pts) if sel else 0.0
    status = "feasible" if sel is not None else "unknown"
    gap = relative_gap(max(bound, objective), objective) if sel is not None else math.inf
    stats = {"memory_fallback": msg, "mode": mode, "engine_requested": engine, "fixed": list(fixed_t),
             "forbidden": list(_index_set(forbidden, n, "forbidden")), "new": [j for j in (sel or ()) if j not in fixed_t],
             "rows_in": int(m), "cols_in": int(n), "k": k}
    return SolverResult(selected=tuple(sel or ()), status=status, objective=float(objective),
                        bound=float(max(bound, objective)), gap=float(gap), engine="mip",
                        time_s=time.perf_counter() - t0, stats=jsonable(stats))


def _check_setcover_memory(q: sp.csr_matrix, w: np.ndarray, free_cols: np.ndarray, conflicts: np.ndarray,
                           engine: str) -> None:
    """One-line error before building a set-cover model that would not fit in memory (there is no
    cheaper engine to fall back to)."""
    backend = "cpsat" if engine == "cpsat" else "mip"
    cnt, _ = selected_row_stats(q, free_cols)
    rows = int(np.count_nonzero((w > 0) & (cnt > 0)))
    entries = int(cnt.sum())
    n_conf = int(conflicts.shape[0])
    need = model_bytes(backend, free_cols.size + rows, rows + 1 + n_conf, entries + rows + 2 * n_conf)
    budget = memory_budget_bytes()
    if need > budget:
        exc = OverBudget(need, budget, f"the {'SCIP' if backend == 'mip' else 'CP-SAT'} set-cover model")
        raise CamplaceError(f"{exc.message}; use fewer candidates / points")


def _model_size(
    q: sp.csr_matrix, resid: sp.csr_matrix, resid_w: np.ndarray, w: np.ndarray, mode: str, views: int,
    min_angle_deg: float | None, pos: np.ndarray | None, pts: np.ndarray | None, fixed_t: tuple[int, ...],
    free_cols: np.ndarray, conflicts: np.ndarray, budget: int,
) -> tuple[int, int, int]:
    """Variables, rows and nonzeros of the model :func:`_build_model` would build (upper bounds),
    computed without building it. With the angle, the pairs of observers closer than the angle (one
    row each) are counted per point, stopping once the model could not fit in ``budget`` anyway.
    """
    nf = free_cols.size
    n_conf = int(conflicts.shape[0])
    n_vars, n_rows, nnz = nf, 1 + n_conf, nf + 2 * n_conf
    if mode in ("maxcover", "quality"):
        cnt = np.diff(resid.indptr)
        live = (resid_w > 0) & (cnt > 0)
        entries = int(cnt[live].sum())
        rows = int(live.sum()) if mode == "maxcover" else entries  # quality: a row per distinct level
        return n_vars + rows, n_rows + rows, nnz + entries + (rows if mode == "maxcover" else 2 * rows)
    allowed = np.zeros(q.shape[1], dtype=bool)
    allowed[free_cols] = True
    allowed[list(fixed_t)] = True
    nobs, _ = selected_row_stats(q, np.flatnonzero(allowed))
    live = np.flatnonzero((w > 0) & (nobs >= views))
    s = nobs[live].astype(np.int64)
    n_vars += len(fixed_t)
    if pts is None:
        return n_vars + live.size, n_rows + live.size, nnz + int(s.sum()) + live.size
    assert pos is not None
    limit = budget // _MODEL_BYTES_PER_ROW_MIN
    data = q.data.view(np.uint8) if q.data.dtype.kind == "b" else q.data
    with ctrl_c_deferred():
        bad = int(count_bad_pairs(q.indptr, q.indices, data, live.astype(np.int64), allowed, pos, pts,
                                  float(min_angle_deg or 0.0), limit))
    extra = int(views > 2)
    return (n_vars + int((s + 1).sum()), n_rows + int((s + 1 + extra).sum()) + bad,
            nnz + int((3 * s + 1 + extra * (s + 1)).sum()) + 2 * bad)


def _cheap_bound(q: sp.csr_matrix, qf: sp.csr_matrix, w: np.ndarray, base: np.ndarray, k: int, mode: str, views: int) -> float:
    """A valid upper bound on the objective (fixed cameras included) without any model: every
    point gets the best any allowed camera could give it (multiview: at most k new views)."""
    if mode == "maxcover":
        return float(w @ ((base > 0) | (np.diff(qf.indptr) > 0)))
    if mode == "quality":
        best = qf.max(axis=1).toarray().ravel() if qf.shape[1] else np.zeros(q.shape[0])
        return float(w @ np.maximum(base, best))
    return float(w @ (base + np.minimum(np.diff(qf.indptr), k) >= views))


def _build_model(
    q: sp.csr_matrix, resid: sp.csr_matrix, resid_w: np.ndarray, w: np.ndarray, base: np.ndarray, k: int,
    mode: str, views: int,
    min_angle_deg: float | None, pos: np.ndarray | None, pts: np.ndarray | None, fixed_t: tuple[int, ...],
    free_cols: np.ndarray, conflicts: np.ndarray, fixed_value: float, t0: float, time_limit_s: float | None,
) -> tuple[LinearModel, np.ndarray, float, float]:
    """The SCIP / CP-SAT model of a k-camera mode: (model, x variables, objective scale, constant).

    Raises :class:`_BuildTimeout` when the time limit passes while rows are being added.
    """

    def check(r: int) -> None:
        if (r & 255) == 0 and time_limit_s is not None and time.perf_counter() - t0 >= time_limit_s:
            raise _BuildTimeout

    model = LinearModel(maximize=True)
    nf = free_cols.size
    x = model.add_vars(nf)
    model.add_row(x, np.ones(nf), float(k), float(k))
    for a, b in np.searchsorted(free_cols, conflicts).tolist() if conflicts.size else []:
        model.add_row([x[a], x[b]], [1.0, 1.0], hi=1.0)
    wmax = float(resid_w.max()) if resid_w.size and resid_w.max() > 0 else 1.0
    const = 0.0
    if mode == "maxcover":
        live = (resid_w > 0) & (np.diff(resid.indptr) > 0)
        pr, pw = _merge_rows(as_pattern(resid[live]), resid_w[live])
        y = model.add_vars(pr.shape[0], integer=False, obj=pw / wmax)
        for r in range(pr.shape[0]):
            check(r)
            cols = pr.indices[pr.indptr[r] : pr.indptr[r + 1]]
            model.add_row(np.append(x[cols], y[r]), np.append(np.ones(cols.size), -1.0), lo=0.0)
        const = fixed_value
    elif mode == "quality":
        live = (resid_w > 0) & (np.diff(resid.indptr) > 0)
        pr, pw = _merge_rows(resid[live].tocsr(), resid_w[live])
        for r in range(pr.shape[0]):
            check(r)
            s, e = pr.indptr[r], pr.indptr[r + 1]
            vals, cols = pr.data[s:e], pr.indices[s:e]
            levels = np.unique(vals)[::-1]
            nxt = np.append(levels[1:], 0.0)
            ys = model.add_vars(levels.size, integer=False, obj=pw[r] * (levels - nxt) / wmax)
            for li, lv in enumerate(levels):
                at = cols[vals == lv]
                idx = np.append(x[at], ys[li])
                coef = np.append(np.ones(at.size), -1.0)
                if li > 0:
                    idx, coef = np.append(idx, ys[li - 1]), np.append(coef, 1.0)
                model.add_row(idx, coef, lo=0.0)
        const = float(w @ base)
    else:
        fx = np.array(fixed_t, dtype=np.int64)
        allc = np.concatenate([free_cols, fx])  # model columns: free ones then fixed
        xf = model.add_vars(fx.size, lb=1.0, ub=1.0)
        xall = np.concatenate([x, xf])
        qa = q[:, allc].tocsr()
        nobs = np.diff(qa.indptr)
        live = (w > 0) & (nobs >= views)
        if pts is None:
            pr, pw = _merge_rows(as_pattern(qa[live]), w[live])
            y = model.add_vars(pr.shape[0], obj=pw / wmax)
            for r in range(pr.shape[0]):
                check(r)
                cols = pr.indices[pr.indptr[r] : pr.indptr[r + 1]]
                model.add_row(np.append(xall[cols], y[r]), np.append(np.ones(cols.size), -float(views)), lo=0.0)
        else:
            assert pos is not None
            for r, i in enumerate(np.flatnonzero(live)):
                check(r)
                cols = qa.indices[qa.indptr[i] : qa.indptr[i + 1]]
                good = _angle_ok_pairs(pts[i], pos[allc[cols]], float(min_angle_deg or 0.0))
                if not np.any(np.triu(good, 1)):
                    continue
                yi = int(model.add_vars(1, obj=w[i] / wmax)[0])
                if views > 2:
                    model.add_row(np.append(xall[cols], yi), np.append(np.ones(cols.size), -float(views)), lo=0.0)
                u = model.add_vars(cols.size)
                for t, c in enumerate(cols):
                    model.add_row([u[t], xall[c]], [1.0, -1.0], hi=0.0)
                model.add_row(np.append(u, yi), np.append(np.ones(cols.size), -2.0), 0.0, 0.0)
                bad_a, bad_b = np.nonzero(np.triu(~good, 1))
                for a, b in zip(bad_a.tolist(), bad_b.tolist()):
                    model.add_row([u[a], u[b]], [1.0, 1.0], hi=1.0)

    return model, x, wmax, const


def _setcover(
    q: sp.csr_matrix, w: np.ndarray, costs: Any, required_fraction: float, fixed_t: tuple[int, ...],
    free_cols: np.ndarray, conflicts: np.ndarray, engine: str, time_limit_s: float | None, t0: float,
    seed: int = 0, iterations: int | None = None,
) -> tuple[Any, str, float, float, str, dict[str, Any]]:
    """Minimum-cost cover. Returns (selected, status, cost, lower bound, engine, stats).

    Without minimum-distance conflicts: :func:`camplace.solver.setcover_ls.solve_cover`
    (reductions, local search, Lagrangian bound, then SCIP / CP-SAT with the local-search cover as
    hint and cutoff where it applies). With conflicts: the SCIP / CP-SAT model directly.
    """
    m, n = q.shape
    if engine == "exact":
        raise CamplaceError("the exact engine does not solve setcover; use engine auto, mip or cpsat")
    name = "mip" if engine == "auto" else engine
    c = np.ones(n) if costs is None else np.asarray(costs, dtype=np.float64)
    if c.shape != (n,) or not np.all(np.isfinite(c)) or np.any(c < 0):
        raise CamplaceError(f"costs must be ({n},) finite values >= 0, got shape {c.shape}")
    frac = float(required_fraction)
    if not (0.0 < frac <= 1.0):
        raise CamplaceError(f"required_fraction must be in (0, 1], got {required_fraction!r}")
    pat = as_pattern(q)
    allowed = np.zeros(n, dtype=bool)
    allowed[free_cols] = True
    allowed[list(fixed_t)] = True
    if allowed.all():  # no column copy of a large matrix when every camera may be used
        obs_allowed = np.diff(pat.indptr) > 0
    else:
        obs_allowed = np.diff(pat[:, np.flatnonzero(allowed)].tocsr().indptr) > 0
    pos_w = w > 0
    unc = pos_w & ~obs_allowed
    coverable_w = float(w[pos_w & obs_allowed].sum())
    stats: dict[str, Any] = {
        "uncoverable_points": int(unc.sum()),
        "uncoverable_weight": float(w[unc].sum()),
        "coverable_weight": coverable_w,
        "required_fraction": frac,
    }
    covered_f = (np.diff(pat[:, list(fixed_t)].tocsr().indptr) > 0) if fixed_t else np.zeros(m, dtype=bool)
    credit = float(w[covered_f & pos_w].sum())
    need = frac * coverable_w - credit
    rows = pos_w & obs_allowed & ~covered_f
    sub = (pat if free_cols.size == n else pat[:, free_cols].tocsr())[rows]
    sw = w[rows]

    def finish(sel_free: Sequence[int], status: str, bound: float,
               used: str = name) -> tuple[Any, str, float, float, str, dict[str, Any]]:
        sel = tuple(sorted(set(fixed_t) | {int(free_cols[j]) for j in sel_free}))
        cov = coverage_weight(pat, w, sel) if sel else 0.0
        stats["covered_fraction"] = cov / coverable_w if coverable_w > 0 else 1.0
        stats["covered_weight"] = cov
        cost = float(sum(c[j] for j in sel if j not in set(fixed_t)))
        return sel, status, cost, bound, used, stats

    if sub.shape[0] == 0 or need <= 1e-12 * max(coverable_w, 1e-300):
        return finish((), "optimal", 0.0)
    if conflicts.size == 0:
        out = solve_cover(sub, c[free_cols], sw if frac < 1.0 else None, need if frac < 1.0 else None, engine=engine,
                          time_limit_s=_remaining(t0, time_limit_s), seed=seed, max_iterations=iterations)
        stats["setcover"] = out.stats
        if out.selected is None:
            return None, "unknown", math.nan, out.bound, out.engine, stats
        return finish(out.selected, out.status, out.bound, out.engine)
    model = LinearModel(maximize=False)
    nf = free_cols.size
    x = model.add_vars(nf, obj=c[free_cols])
    for a, b in np.searchsorted(free_cols, conflicts).tolist() if conflicts.size else []:
        model.add_row([x[a], x[b]], [1.0, 1.0], hi=1.0)
    if frac >= 1.0:
        pr, _ = _merge_rows(sub, sw)
        for r in range(pr.shape[0]):
            cols = pr.indices[pr.indptr[r] : pr.indptr[r + 1]]
            model.add_row(x[cols], np.ones(cols.size), lo=1.0)
    else:
        pr, pw = _merge_rows(sub, sw)
        y = model.add_vars(pr.shape[0])
        for r in range(pr.shape[0]):
            cols = pr.indices[pr.indptr[r] : pr.indptr[r + 1]]
            model.add_row(np.append(x[cols], y[r]), np.append(np.ones(cols.size), -1.0), lo=0.0)
        scale_f = 1.0 / max(coverable_w, 1e-300)
        s_int = 2.0**30 / max(float(pw.sum()), 1e-300)
        # CP-SAT needs integers: rounding the weights UP keeps every truly feasible cover feasible
        # (sum ceil(w s) >= sum w s >= need s), so CP-SAT's optimum is never worse than the true
        # one; the answer is checked against the exact requirement below
        cint = np.ceil(pw * s_int).astype(np.int64)
        model.add_row(y, pw * scale_f, lo=need * scale_f,
                      int_variant=(cint, float(math.ceil(need * s_int)), math.inf))
    out = solve_model(model, name, time_limit_s=_remaining(t0, time_limit_s))
    stats["engine_stats"] = dict(out.stats)
    stats["rows_after"] = int(pr.shape[0])
    if out.values is None:
        st = "infeasible" if out.status == "infeasible" else "unknown"
        sel, _, _, _, _, _ = finish((), st, -math.inf)
        return None, st, math.nan, out.bound, name, stats
    sel_free = [int(j) for j in np.flatnonzero(out.values[x] > 0.5)]
    bound = out.bound
    if np.all(c == np.rint(c)) and math.isfinite(bound):
        bound = math.ceil(bound - 1e-6)  # integral costs: the optimum is an integer
    status = out.status
    if frac < 1.0:
        got = float(sw[np.diff(sub[:, sel_free].tocsr().indptr) > 0].sum()) if sel_free else 0.0
        if got < need - 1e-9 * max(coverable_w, 1e-300):
            log.warning("setcover: the %s answer misses the required weight by %.3g (integer rounding)", name, need - got)
            status = "unknown"
    return finish(sel_free, status, bound)
