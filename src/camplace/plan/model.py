"""The moving-agents problem on a visibility matrix: data, objective, feasibility and the flow model.

Problem. The rows of the visibility matrix ``Q`` (points x candidate poses) are split by phase (each
row belongs to the phase of its frame). ``k`` identical agents each hold one candidate pose per
phase; the poses held in one phase are distinct. The value of phase ``p`` with the pose set ``S_p``
is the solver's mode value on that phase's rows (:func:`row_values`): ``maxcover`` the weight of the
rows observed, ``quality`` the weight times the best quality, ``multiview`` the weight of the rows
observed at least ``views`` times. A plan maximises ``sum_p value_p(S_p)`` subject to every agent
moving at most ``reach_m[p]`` metres between phase ``p`` and ``p + 1`` (straight-line distance of the
poses' positions; re-aiming at one position is free) and, with start positions, at most
``start_reach_m`` from its start position to its first pose.

Since the agents are identical, consecutive pose sets are compatible exactly when the bipartite
"within reach" graph between them has a perfect matching (:func:`sets_compatible`); the exact model
(:func:`build_flow_model`) sends ``k`` units of flow through the time-expanded graph of (phase,
candidate position) nodes. This module imports no geometry beyond positions as arrays.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError

__all__ = [
    "PLAN_MODES",
    "PlanProblem",
    "is_bits",
    "make_problem",
    "row_values",
    "phase_value",
    "plan_value",
    "within",
    "sets_compatible",
    "check_plan",
    "paths_from_sets",
    "single_values",
    "FlowModel",
    "flow_model_size",
    "build_flow_model",
]

#: Modes a plan can maximise per phase (setcover minimises cameras: no plan).
PLAN_MODES: tuple[str, ...] = ("maxcover", "quality", "multiview")
_REL_TOL = 1e-9  # relative slack of the reach test (distances are recomputed in float64)
_ABS_TOL_M = 1e-9


def within(dist_m: np.ndarray | float, reach: float) -> np.ndarray | bool:
    """``dist_m <= reach`` with a relative tolerance of 1e-9 (and 1 nm) for float rounding."""
    if math.isinf(reach):
        return np.ones(np.shape(dist_m), dtype=bool) if np.ndim(dist_m) else True
    return np.asarray(dist_m) <= reach * (1.0 + _REL_TOL) + _ABS_TOL_M


@dataclass(frozen=True, eq=False)
class PlanProblem:
    """A moving-agents problem (see the module docstring).

    Attributes
    ----------
    matrices : tuple of (m_p, n) scipy.sparse.csr_matrix or BitMatrix
        Each phase's rows of the visibility matrix (observation quality, > 0 observes); for a
        binary matrix given as column bitsets (:class:`camplace.visibility.bits.BitMatrix`),
        each phase's rows as bitsets (every reader here has a bits branch: no CSR copy).
    weights : tuple of (m_p,) float64
        Their weights (as in ``points.csv``: all phases together sum to the event's total).
    rows : tuple of (m_p,) int64
        Their row indices in the full matrix.
    positions : (n, 3) float64
        Candidate positions, metres.
    k : int
        Agents.
    mode : str
        One of :data:`PLAN_MODES`.
    views : int
        multiview: observations a row needs.
    reach_m : (P - 1,) float64
        How far an agent travels between phase p and p + 1 (``inf`` allowed).
    start_positions_m : (k, 3) float64 or None
        Start positions (agent a starts at row a).
    start_reach_m : float
        How far an agent travels from its start position to its first pose.
    pos_id : (n,) int64
        Distinct position of each candidate (candidates at one position differ only by aim).
    unique_positions : (N, 3) float64
    """

    matrices: tuple
    weights: tuple
    rows: tuple
    positions: np.ndarray
    k: int
    mode: str
    views: int
    reach_m: np.ndarray
    start_positions_m: np.ndarray | None
    start_reach_m: float
    pos_id: np.ndarray
    unique_positions: np.ndarray
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def bits(self) -> bool:
        """Whether the phase matrices are column bitsets (a binary run)."""
        return is_bits(self.matrices[0]) if self.matrices else False

    @property
    def n_phases(self) -> int:
        """Number of phases P."""
        return len(self.matrices)

    @property
    def n_candidates(self) -> int:
        """Number of candidate poses n."""
        return int(self.positions.shape[0])


def is_bits(matrix) -> bool:
    """Whether ``matrix`` is a :class:`camplace.visibility.bits.BitMatrix` (a binary pattern)."""
    return getattr(matrix, "format", None) == "bits"


def make_problem(
    matrix: sp.spmatrix,
    weights: np.ndarray,
    row_phase: np.ndarray,
    positions: np.ndarray,
    k: int,
    *,
    mode: str = "maxcover",
    views: int = 2,
    reach_m: Sequence[float] | np.ndarray = (),
    start_positions_m: np.ndarray | None = None,
    start_reach_m: float = math.inf,
) -> PlanProblem:
    """Check the inputs and split the matrix rows by phase.

    Parameters
    ----------
    matrix : (m, n) sparse or BitMatrix
        Visibility (quality > 0 observes), or a binary matrix's column bitsets (the phase blocks
        are then bitsets too, ``n * ceil(m_p / 64) * 8`` bytes each).
    weights : (m,) float64
        Row weights, >= 0.
    row_phase : (m,) int64
        Phase of each row, 0..P-1 (P = len(reach_m) + 1).
    positions : (n, 3) float64
    k : int
    mode, views : as :func:`camplace.solver.solve`
    reach_m : (P - 1,) float64
    start_positions_m : (k, 3) float64, optional
    start_reach_m : float

    Returns
    -------
    PlanProblem
    """
    if mode not in PLAN_MODES:
        raise CamplaceError(f"mode {mode!r} has no moving-agents plan (use one of {', '.join(PLAN_MODES)})")
    if is_bits(matrix):
        return _make_problem_bits(matrix, weights, row_phase, positions, k, mode=mode, views=views, reach_m=reach_m,
                                  start_positions_m=start_positions_m, start_reach_m=start_reach_m)
    q = sp.csr_matrix(matrix)
    if q.dtype not in (np.float32, np.float64):
        q = q.astype(np.float64)
    if not q.has_canonical_format:
        q = q.copy()
        q.sum_duplicates()
    if q.data.size and (not np.all(np.isfinite(q.data)) or q.data.min() < 0):
        raise CamplaceError("visibility matrix: values must be finite and >= 0")
    if q.data.size and q.data.min() == 0:
        q = q.copy()
        q.eliminate_zeros()
    m, n = q.shape
    w, pos, reach, ph, k, start = _checked_inputs(m, n, weights, row_phase, positions, k, mode, views, reach_m,
                                                  start_positions_m, start_reach_m)
    n_phases = reach.size + 1
    # the phase blocks, and later their CSC copies (heuristic), each as large as the matrix
    need = 2 * q.nnz * (q.data.itemsize + q.indices.itemsize) + 2 * (m + n_phases) * 8 + 3 * n * 8
    _check_budget(need, "the phase copies of the visibility matrix")
    mats, ws, rows = [], [], []
    for p in range(n_phases):
        r = np.flatnonzero(ph == p)
        mats.append(q[r].tocsr())
        ws.append(w[r])
        rows.append(r)
    upos, pos_id = np.unique(pos, axis=0, return_inverse=True)
    return PlanProblem(tuple(mats), tuple(ws), tuple(rows), pos, k, mode, int(views), reach, start, float(start_reach_m),
                       pos_id.reshape(-1).astype(np.int64), upos)


def _make_problem_bits(bits, weights, row_phase, positions, k, *, mode, views, reach_m, start_positions_m,
                       start_reach_m) -> PlanProblem:
    """:func:`make_problem` of a binary matrix's column bitsets: each phase's rows taken from the
    bitsets (:func:`camplace.visibility.bits.take_rows`), never a CSR copy of the matrix."""
    from camplace.visibility.bits import bit_words, take_rows

    m, n = bits.shape
    w, pos, reach, ph, k, start = _checked_inputs(m, n, weights, row_phase, positions, k, mode, views, reach_m,
                                                  start_positions_m, start_reach_m)
    n_phases = reach.size + 1
    counts = np.bincount(ph, minlength=n_phases)
    # the phase blocks' bitsets, the row lists and weights, and the unpacked block take_rows works in
    need = sum(n * bit_words(int(c)) * 8 for c in counts) + 2 * (m + n_phases) * 8 + 3 * n * 8 + 2**23
    _check_budget(need, "the phase blocks of the visibility bitsets")
    mats, ws, rows = [], [], []
    for p in range(n_phases):
        r = np.flatnonzero(ph == p)
        mats.append(take_rows(bits, r))
        ws.append(w[r])
        rows.append(r)
    upos, pos_id = np.unique(pos, axis=0, return_inverse=True)
    return PlanProblem(tuple(mats), tuple(ws), tuple(rows), pos, k, mode, int(views), reach, start, float(start_reach_m),
                       pos_id.reshape(-1).astype(np.int64), upos)


def _check_budget(need: int, what: str) -> None:
    """Raise a one-line CamplaceError when ``need`` bytes exceed the memory budget."""
    from camplace.solver._support.memory import memory_budget_bytes

    budget = memory_budget_bytes()
    if need > budget:
        raise CamplaceError(f"plan: {what} need about {need / 2**30:.1f} GiB but only "
                            f"{budget / 2**30:.1f} GiB may be used (fewer --points or --candidates)")


def _checked_inputs(m, n, weights, row_phase, positions, k, mode, views, reach_m, start_positions_m, start_reach_m):
    """The checked inputs of :func:`make_problem` as arrays: (w, positions, reach, row phases, k, start)."""
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (m,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise CamplaceError(f"weights must be ({m},) finite values >= 0")
    pos = np.asarray(positions, dtype=np.float64)
    if pos.shape != (n, 3) or not np.all(np.isfinite(pos)):
        raise CamplaceError(f"positions must be a finite ({n}, 3) array, got shape {pos.shape}")
    reach = np.asarray(reach_m, dtype=np.float64).reshape(-1)
    if np.any(np.isnan(reach)) or np.any(reach < 0):
        raise CamplaceError("reach: every travel distance must be >= 0")
    n_phases = reach.size + 1
    ph = np.asarray(row_phase, dtype=np.int64)
    if ph.shape != (m,) or (m and (ph.min() < 0 or ph.max() >= n_phases)):
        raise CamplaceError(f"row phases must be ({m},) integers in 0..{n_phases - 1}")
    if isinstance(k, bool) or int(k) != k or k < 1:
        raise CamplaceError(f"k: the number of agents must be an integer >= 1, got {k!r}")
    k = int(k)
    if k > n:
        raise CamplaceError(f"k: {k} agents cannot hold distinct poses among {n} candidates")
    if mode == "multiview" and (isinstance(views, bool) or int(views) != views or views < 1):
        raise CamplaceError(f"views must be an integer >= 1, got {views!r}")
    start = None
    if start_positions_m is not None:
        start = np.asarray(start_positions_m, dtype=np.float64)
        if start.shape != (k, 3) or not np.all(np.isfinite(start)):
            raise CamplaceError(f"start positions: need one finite [x, y, z] per agent ({k}), got shape {start.shape}")
    if not (start_reach_m >= 0):
        raise CamplaceError("start reach must be >= 0")
    return w, pos, reach, ph, k, start


# ------------------------------------------------------------------------------------------------
# values


def row_values(q: sp.csr_matrix, w: np.ndarray, cols: Sequence[int], mode: str, views: int = 2) -> np.ndarray:
    """(m,) float64: each row's contribution to the mode value of the pose set ``cols``.

    maxcover: ``w`` if some pose observes the row; quality: ``w`` times the best quality;
    multiview: ``w`` if at least ``views`` poses observe it. Duplicate columns count once.
    """
    cols = sorted({int(j) for j in cols})
    m = q.shape[0]
    if not cols:
        return np.zeros(m)
    if is_bits(q):
        return _row_values_bits(q, w, cols, mode, views)
    sub = q[:, cols].tocsr()
    if mode == "quality":
        best = sub.max(axis=1).toarray().ravel() if sub.nnz else np.zeros(m)
        return w * best
    count = np.diff(sub.indptr)
    need = 1 if mode == "maxcover" else int(views)
    return np.where(count >= need, w, 0.0)


def _row_values_bits(bits, w: np.ndarray, cols: list[int], mode: str, views: int) -> np.ndarray:
    """:func:`row_values` on column bitsets (every value 1: quality is ``w`` times 1.0 where observed)."""
    if mode == "multiview":
        count = np.zeros(bits.shape[0], dtype=np.int64)
        for j in cols:
            count += bits.column(j)
        return np.where(count >= int(views), w, 0.0)
    seen = bits.union(cols)
    return w * seen.astype(np.float64) if mode == "quality" else np.where(seen, w, 0.0)


def phase_value(problem: PlanProblem, p: int, cols: Sequence[int]) -> float:
    """Mode value of phase ``p`` with the poses ``cols``."""
    return float(row_values(problem.matrices[p], problem.weights[p], cols, problem.mode, problem.views).sum())


def plan_value(problem: PlanProblem, plan: np.ndarray) -> float:
    """Objective of a plan: ``sum_p`` value of phase p with the poses ``plan[:, p]``.

    Parameters
    ----------
    plan : (k, P) int64
        Candidate column of agent a in phase p.
    """
    plan = np.asarray(plan)
    return float(sum(phase_value(problem, p, plan[:, p]) for p in range(problem.n_phases)))


def single_values(problem: PlanProblem, p: int) -> np.ndarray:
    """(n,) float64: the weight each pose alone observes in phase p (quality: weight times quality).

    With ``v`` the mode value, ``v(T + j) <= v(T) + single_values[j]`` for every mode (multiview
    included: a row j observes can only gain what it weighs).
    """
    q, w = problem.matrices[p], problem.weights[p]
    if is_bits(q):  # every value 1: the weights summed per column, in the CSR order
        from camplace.visibility.bits import column_sums

        return column_sums(q, w)
    per_entry = np.repeat(w, np.diff(q.indptr))
    if problem.mode == "quality":
        per_entry = per_entry * q.data
    return np.bincount(q.indices, weights=per_entry, minlength=q.shape[1])


# ------------------------------------------------------------------------------------------------
# feasibility


def _perfect_matching(ok: np.ndarray) -> np.ndarray | None:
    """For a (k, k) bool "a may go to b" matrix: perm with ok[a, perm[a]] for every a, or None."""
    k = ok.shape[0]
    if k <= 6:
        for perm in itertools.permutations(range(k)):
            if all(ok[a, perm[a]] for a in range(k)):
                return np.asarray(perm, dtype=np.int64)
        return None
    from scipy.sparse.csgraph import maximum_bipartite_matching

    match = maximum_bipartite_matching(sp.csr_matrix(ok.astype(np.int8)), perm_type="column")
    return None if np.any(match < 0) else match.astype(np.int64)


def sets_compatible(pos_a: np.ndarray, pos_b: np.ndarray, reach: float) -> np.ndarray | None:
    """Can agents at ``pos_a`` move to ``pos_b`` (one each) within ``reach``? The assignment, or None.

    Parameters
    ----------
    pos_a, pos_b : (k, 3) float64
    reach : float

    Returns
    -------
    (k,) int64 or None
        ``perm[a]``: the row of ``pos_b`` agent a goes to.
    """
    d = np.linalg.norm(pos_a[:, None, :] - pos_b[None, :, :], axis=2)
    return _perfect_matching(np.asarray(within(d, reach)))


def paths_from_sets(problem: PlanProblem, sets: Sequence[Sequence[int]]) -> np.ndarray | None:
    """Agent paths (k, P) through the given pose sets, one set per phase, or None if none exists.

    With start positions, agent a starts at ``start_positions_m[a]``.
    """
    k, pos = problem.k, problem.positions
    cols = [np.asarray(sorted(int(j) for j in s), dtype=np.int64) for s in sets]
    if any(c.size != k or np.unique(c).size != k for c in cols):
        return None
    plan = np.empty((k, len(cols)), dtype=np.int64)
    if problem.start_positions_m is not None:
        perm = sets_compatible(problem.start_positions_m, pos[cols[0]], problem.start_reach_m)
        if perm is None:
            return None
        plan[:, 0] = cols[0][perm]
    else:
        plan[:, 0] = cols[0]
    for p in range(1, len(cols)):
        perm = sets_compatible(pos[plan[:, p - 1]], pos[cols[p]], float(problem.reach_m[p - 1]))
        if perm is None:
            return None
        plan[:, p] = cols[p][perm]
    return plan


def check_plan(problem: PlanProblem, plan: np.ndarray) -> list[str]:
    """Every way the plan breaks the rules (empty list: feasible).

    Checks: shape (k, P), columns in range, distinct poses per phase, each move within reach, the
    first pose within reach of the agent's start.
    """
    plan = np.asarray(plan)
    k, P, n = problem.k, problem.n_phases, problem.n_candidates
    if plan.shape != (k, P):
        return [f"plan shape {plan.shape}, expected ({k}, {P})"]
    bad = []
    if plan.min() < 0 or plan.max() >= n:
        return [f"candidate index out of range 0..{n - 1}"]
    pos = problem.positions
    for p in range(P):
        if np.unique(plan[:, p]).size != k:
            bad.append(f"phase {p}: two agents hold the same pose")
    for a in range(k):
        if problem.start_positions_m is not None:
            d = float(np.linalg.norm(pos[plan[a, 0]] - problem.start_positions_m[a]))
            if not within(d, problem.start_reach_m):
                bad.append(f"agent {a}: first pose {d:.6g} m from its start, reach {problem.start_reach_m:.6g} m")
        for p in range(P - 1):
            d = float(np.linalg.norm(pos[plan[a, p + 1]] - pos[plan[a, p]]))
            if not within(d, float(problem.reach_m[p])):
                bad.append(f"agent {a}: phase {p} -> {p + 1} moves {d:.6g} m, reach {problem.reach_m[p]:.6g} m")
    return bad


# ------------------------------------------------------------------------------------------------
# the exact flow model


@dataclass
class FlowModel:
    """A built time-expanded model: the LinearModel and how to read its solution.

    Attributes
    ----------
    model : camplace.solver.engines.mip.linear.LinearModel
    x : list of (n_p,) int64
        Variable index of each kept pose of phase p.
    kept : list of (n_p,) int64
        The kept poses (candidate columns) of phase p.
    scale : float
        Model objective * scale = plan objective.
    stats : dict
    """

    model: object
    x: list
    kept: list
    scale: float
    stats: dict


def _reach_pairs(pa: np.ndarray, pb: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j) with |pa[i] - pb[j]| within reach, chunked (no (|pa|, |pb|) float array at once)."""
    ii, jj = [], []
    step = max(1, 4_000_000 // max(1, pb.shape[0]))
    for s in range(0, pa.shape[0], step):
        d = np.linalg.norm(pa[s:s + step, None, :] - pb[None, :, :], axis=2)
        a, b = np.nonzero(within(d, reach))
        ii.append(a + s)
        jj.append(b)
    if not ii:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(ii).astype(np.int64), np.concatenate(jj).astype(np.int64)


def _phase_block(problem: PlanProblem, p: int, kept: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Phase p's live rows restricted to the kept poses, identical rows merged."""
    from camplace.solver.engines.mip.mode_models import merge_rows

    q = _kept_columns(problem, p, kept)
    live = (problem.weights[p] > 0) & (np.diff(q.indptr) > 0)
    return merge_rows(q[live].tocsr(), problem.weights[p][live])


def _kept_columns(problem: PlanProblem, p: int, kept: np.ndarray) -> sp.csr_matrix:
    """(m_p, |kept|) CSR: phase p's rows on the kept poses (the row lists the model's coverage rows
    need). From bitsets only those columns are expanded, float32 ones as a stored binary matrix
    reads; :func:`flow_model_size` bounds their entries before any model is built."""
    q = problem.matrices[p]
    if is_bits(q):
        from camplace.visibility.bits import BitMatrix

        return BitMatrix(q.words[np.asarray(kept, dtype=np.int64)], q.shape[0]).tocsr(np.float32)
    return q[:, kept].tocsr()


def _transition_arcs(problem: PlanProblem, kept: list, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """Kept positions of phases t, t+1 and their reachable pairs; ``free`` when every pair is reachable."""
    ua = np.unique(problem.pos_id[kept[t]])
    ub = np.unique(problem.pos_id[kept[t + 1]])
    reach = float(problem.reach_m[t])
    ii, jj = _reach_pairs(problem.unique_positions[ua], problem.unique_positions[ub], reach)
    return ua, ub, ii, jj, ii.size == ua.size * ub.size


def flow_model_size(problem: PlanProblem, kept: list) -> dict:
    """Size of :func:`build_flow_model` before building it: nonzeros of the coverage rows (before
    merging identical rows), flow arcs, binary pose variables."""
    nnz = 0
    for p, kp in enumerate(kept):
        live = problem.weights[p] > 0
        q = problem.matrices[p]
        if is_bits(q):  # the kept columns' live rows, counted on the bits
            from camplace.visibility.bits import column_sums

            nnz += int(column_sums(q, live.astype(np.float64))[np.asarray(kp, dtype=np.int64)].sum())
            continue
        nnz += int(np.diff(q[:, kp].tocsr().indptr)[live].sum())
    arcs = 0
    for t in range(problem.n_phases - 1):
        ua = np.unique(problem.pos_id[kept[t]])
        ub = np.unique(problem.pos_id[kept[t + 1]])
        if math.isinf(problem.reach_m[t]):
            continue
        arcs += int(_reach_pairs(problem.unique_positions[ua], problem.unique_positions[ub], float(problem.reach_m[t]))[0].size)
    return {"coverage_nonzeros": nnz, "flow_arcs": arcs, "pose_variables": int(sum(len(kp) for kp in kept))}


def build_flow_model(problem: PlanProblem, kept: list, phase_bounds: Sequence[float]) -> FlowModel:
    """The exact model over the kept poses of each phase.

    Variables: ``x[p, j]`` binary (pose j held in phase p), ``sum_j x[p, j] = k``; per transition a
    continuous flow ``f[u, v] >= 0`` between kept positions within reach, with
    ``sum_v f[u, v] = sum_{j at u} x[p, j]`` and ``sum_u f[u, v] = sum_{j at v} x[p + 1, j]`` (a
    transportation problem with integral supplies: a fractional flow exists exactly when an
    integral one does, i.e. when the agents can move; transitions where every pair is within reach
    get no flow). With start positions, unit sources at each start. Coverage per phase row as in the
    solver (maxcover ``y <= sum x``; quality the level chain; multiview ``views y <= sum x``), plus
    the valid cut ``value_p <= phase_bounds[p]``.

    Parameters
    ----------
    problem : PlanProblem
    kept : list of (n_p,) int64
        Poses allowed in phase p.
    phase_bounds : (P,) float64
        Upper bounds on each phase's value (the per-phase optima).

    Returns
    -------
    FlowModel
    """
    from camplace.solver.engines.mip.linear import LinearModel
    from camplace.solver.engines.mip.mode_models import add_level_chain

    k, P = problem.k, problem.n_phases
    model = LinearModel(maximize=True)
    blocks = [_phase_block(problem, p, kept[p]) for p in range(P)]
    wmax = max((float(b[1].max()) for b in blocks if b[1].size), default=1.0) or 1.0
    xs = []
    for p in range(P):
        x = model.add_vars(len(kept[p]))
        model.add_row(x, np.ones(x.size), float(k), float(k))
        xs.append(x)

    def position_groups(p: int, upos: np.ndarray) -> list[np.ndarray]:
        pid = problem.pos_id[kept[p]]
        order = np.argsort(pid, kind="stable")
        starts = np.searchsorted(pid[order], upos)
        ends = np.searchsorted(pid[order], upos, side="right")
        return [xs[p][order[s:e]] for s, e in zip(starts, ends)]

    arcs = 0
    for t in range(P - 1):
        if math.isinf(problem.reach_m[t]):
            continue
        ua, ub, ii, jj, free = _transition_arcs(problem, kept, t)
        if free:
            continue
        ga, gb = position_groups(t, ua), position_groups(t + 1, ub)
        # no arc capacities needed: the conservation rows bound each arc by its supply
        f = model.add_vars(ii.size, ub=float(k), integer=False)
        arcs += f.size
        order_a = np.argsort(ii, kind="stable")
        for u in range(ua.size):
            sel = f[order_a[np.searchsorted(ii[order_a], u):np.searchsorted(ii[order_a], u, side="right")]]
            model.add_row(np.concatenate([sel, ga[u]]), np.concatenate([np.ones(sel.size), -np.ones(ga[u].size)]), 0.0, 0.0)
        order_b = np.argsort(jj, kind="stable")
        for v in range(ub.size):
            sel = f[order_b[np.searchsorted(jj[order_b], v):np.searchsorted(jj[order_b], v, side="right")]]
            model.add_row(np.concatenate([sel, gb[v]]), np.concatenate([np.ones(sel.size), -np.ones(gb[v].size)]), 0.0, 0.0)
    if problem.start_positions_m is not None:
        ub0 = np.unique(problem.pos_id[kept[0]])
        g0 = position_groups(0, ub0)
        ii, jj = _reach_pairs(problem.start_positions_m, problem.unique_positions[ub0], problem.start_reach_m)
        f = model.add_vars(ii.size, ub=1.0, integer=False)
        arcs += f.size
        for a in range(k):
            model.add_row(f[ii == a], np.ones(int((ii == a).sum())), 1.0, 1.0)
        for v in range(ub0.size):
            sel = f[jj == v]
            model.add_row(np.concatenate([sel, g0[v]]), np.concatenate([np.ones(sel.size), -np.ones(g0[v].size)]), 0.0, 0.0)

    rows = 0
    for p, (q, w) in enumerate(blocks):
        obj_idx: list[np.ndarray] = []
        obj_coef: list[np.ndarray] = []
        x = xs[p]
        for r in range(q.shape[0]):
            s, e = q.indptr[r], q.indptr[r + 1]
            cols, vals = q.indices[s:e], q.data[s:e]
            if problem.mode == "maxcover":
                y = model.add_vars(1, integer=False, obj=w[r] / wmax)
                model.add_row(np.append(x[cols], y), np.append(np.ones(cols.size), -1.0), lo=0.0)
                obj_idx.append(y)
                obj_coef.append(np.array([w[r] / wmax]))
            elif problem.mode == "multiview":
                if cols.size < problem.views:
                    continue
                y = model.add_vars(1, obj=w[r] / wmax)
                model.add_row(np.append(x[cols], y), np.append(np.ones(cols.size), -float(problem.views)), lo=0.0)
                obj_idx.append(y)
                obj_coef.append(np.array([w[r] / wmax]))
            else:
                ys, c = add_level_chain(model, x, cols, vals, w[r], wmax)
                obj_idx.append(ys)
                obj_coef.append(c)
            rows += 1
        if obj_idx and math.isfinite(phase_bounds[p]):
            idx, coef = np.concatenate(obj_idx), np.concatenate(obj_coef)
            s_int = 2.0**30 / max(float(coef.sum()), 1e-300)
            # the integer variant (CP-SAT) rounds coefficients down and the bound down: still valid
            model.add_row(idx, coef, hi=float(phase_bounds[p]) / wmax * (1 + 1e-9),
                          int_variant=(np.floor(coef * s_int).astype(np.int64), -math.inf,
                                       float(math.floor(phase_bounds[p] / wmax * (1 + 1e-9) * s_int))))
    stats = {"variables": model.n_vars, "constraints": len(model.rows), "flow_arcs": arcs, "coverage_rows": rows}
    return FlowModel(model, xs, [np.asarray(kp, dtype=np.int64) for kp in kept], wmax, stats)
