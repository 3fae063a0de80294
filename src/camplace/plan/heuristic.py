"""Good feasible plans fast: one agent's whole path re-optimised at a time, and a DP over pose sets.

* :func:`best_agent_path`: with the other agents' paths fixed, the best path of one agent is a
  longest path in the time-expanded graph (phase, candidate), each node worth the pose's marginal
  gain over the others in that phase, arcs between positions within reach; a dynamic programme
  over the phases, exact for that agent.
* :func:`agent_ascent`: block-coordinate ascent with it, agent after agent, until no path improves.
* :func:`set_sequence_dp`: the best sequence of pose sets, one per phase, from a pool of sets (the
  per-phase optima, the static system, earlier plans), whose consecutive sets admit a matching
  within reach.

Every plan returned is feasible (each move within reach, distinct poses per phase).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from camplace.plan.model import PlanProblem, paths_from_sets, phase_value, sets_compatible, single_values, within

__all__ = ["ReachIndex", "column_gains", "best_agent_path", "agent_ascent", "set_sequence_dp"]

_MASK_MAX_BYTES = 64 * 2**20  # cached "within reach" masks between positions, all transitions together
_CHUNK_CELLS = 4_000_000  # (rows x positions) cells per temporary distance block
_TIE = 1e-6  # multiview: weight of "one view closer" in the path choice (ties between zero gains)


class ReachIndex:
    """"Best value within reach" queries over the distinct candidate positions.

    Parameters
    ----------
    problem : PlanProblem
    """

    def __init__(self, problem: PlanProblem) -> None:
        self.upos = problem.unique_positions
        self.n = int(self.upos.shape[0])
        span = self.upos.max(axis=0) - self.upos.min(axis=0) if self.n else np.zeros(3)
        self.diameter_m = float(np.linalg.norm(span))
        self._masks: dict[float, np.ndarray] = {}
        self._mask_bytes = 0

    def covers_all(self, reach: float) -> bool:
        """Every position within reach of every other."""
        return bool(within(self.diameter_m, reach))

    def _mask(self, reach: float) -> np.ndarray | None:
        if reach in self._masks:
            return self._masks[reach]
        if self._mask_bytes + self.n * self.n > _MASK_MAX_BYTES:
            return None
        mask = np.empty((self.n, self.n), dtype=bool)
        step = max(1, _CHUNK_CELLS // max(1, self.n))
        for s in range(0, self.n, step):
            d = np.linalg.norm(self.upos[s:s + step, None, :] - self.upos[None, :, :], axis=2)
            mask[s:s + step] = within(d, reach)
        self._masks[reach] = mask
        self._mask_bytes += mask.size
        return mask

    def ball_max(self, reach: float, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For every position u: the largest ``values[v]`` over positions v within ``reach`` of u.

        Parameters
        ----------
        reach : float
        values : (N,) float64
            One value per distinct position (-inf: unusable).

        Returns
        -------
        best : (N,) float64
        arg : (N,) int64
            The position attaining it.
        """
        if self.covers_all(reach):
            i = int(np.argmax(values))
            return np.full(self.n, values[i]), np.full(self.n, i, dtype=np.int64)
        mask = self._mask(reach)
        best = np.empty(self.n)
        arg = np.empty(self.n, dtype=np.int64)
        step = max(1, _CHUNK_CELLS // max(1, self.n))
        for s in range(0, self.n, step):
            if mask is not None:
                m = mask[s:s + step]
            else:
                m = within(np.linalg.norm(self.upos[s:s + step, None, :] - self.upos[None, :, :], axis=2), reach)
            vals = np.where(m, values[None, :], -np.inf)
            a = vals.argmax(axis=1)
            arg[s:s + step] = a
            best[s:s + step] = vals[np.arange(a.size), a]
        return best, arg


def _group_best(problem: PlanProblem, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per distinct position: the best candidate value there and that candidate."""
    pid = problem.pos_id
    order = np.lexsort((-values, pid))
    first = np.ones(order.size, dtype=bool)
    first[1:] = pid[order][1:] != pid[order][:-1]
    cand = np.empty(problem.unique_positions.shape[0], dtype=np.int64)
    cand[pid[order[first]]] = order[first]
    return values[cand], cand


def _csc(problem: PlanProblem, p: int):
    """Phase p's matrix in CSC form (cached on the problem; as large as the phase's matrix)."""
    key = ("csc", p)
    if key not in problem._cache:
        problem._cache[key] = problem.matrices[p].tocsc()
    return problem._cache[key]


def column_gains(problem: PlanProblem, p: int, others: Sequence[int]) -> tuple[float, np.ndarray, np.ndarray]:
    """What each pose adds to phase p's value on top of the poses ``others``.

    Returns
    -------
    base : float
        Value of ``others`` alone.
    gain : (n,) float64
        ``value(others + j) - base`` (-inf for the poses in ``others``).
    score : (n,) float64
        ``gain`` plus, in multiview, a tie-breaking reward for bringing rows one view closer.
    """
    q, w = problem.matrices[p], problem.weights[p]
    m, n = q.shape
    cols = sorted({int(j) for j in others})
    if problem.bits:
        return _column_gains_bits(problem, p, cols)
    rowlen = np.diff(q.indptr)
    extra = None
    csc = _csc(problem, p)
    count = np.zeros(m, dtype=np.int64)
    best = np.zeros(m)
    for j in cols:  # the others' rows, column by column (a CSC slice each: no scan of the whole matrix)
        r = csc.indices[csc.indptr[j]:csc.indptr[j + 1]]
        count[r] += 1
        if problem.mode == "quality":
            np.maximum.at(best, r, csc.data[csc.indptr[j]:csc.indptr[j + 1]])
    if problem.mode == "quality":
        base = float(w @ best)
        contrib = np.repeat(w, rowlen) * np.maximum(q.data - np.repeat(best, rowlen), 0.0)
    elif problem.mode == "maxcover":
        base = float(w[count > 0].sum())
        contrib = np.repeat(np.where(count > 0, 0.0, w), rowlen)
    else:
        views = problem.views
        base = float(w[count >= views].sum())
        contrib = np.repeat(np.where(count == views - 1, w, 0.0), rowlen)
        extra = np.repeat(np.where(count < views - 1, w * (count + 1) / views, 0.0), rowlen)
    # float64 even for a phase without entries (np.bincount of nothing returns integers)
    gain = np.bincount(q.indices, weights=contrib, minlength=n).astype(np.float64)
    score = gain if extra is None else gain + _TIE * np.bincount(q.indices, weights=extra, minlength=n)
    if cols:
        gain[cols] = -np.inf
        score = score.copy()
        score[cols] = -np.inf
    return base, gain, score


def _column_gains_bits(problem: PlanProblem, p: int, cols: list[int]) -> tuple[float, np.ndarray, np.ndarray]:
    """:func:`column_gains` on phase p's column bitsets: the others' rows from their bitsets, each
    pose's gain a sum over the rows its bitset holds (:func:`camplace.visibility.bits.column_sums`,
    the same floats as the CSR route's ``np.bincount``). Every value is 1, so quality is maxcover."""
    from camplace.visibility.bits import column_sums

    q, w = problem.matrices[p], problem.weights[p]
    count = np.zeros(q.shape[0], dtype=np.int64)
    for j in cols:
        count += q.column(j)
    extra = None
    if problem.mode == "quality":
        best = (count > 0).astype(np.float64)
        base = float(w @ best)
        row_gain = w * np.maximum(1.0 - best, 0.0)
    elif problem.mode == "maxcover":
        base = float(w[count > 0].sum())
        row_gain = np.where(count > 0, 0.0, w)
    else:
        views = problem.views
        base = float(w[count >= views].sum())
        row_gain = np.where(count == views - 1, w, 0.0)
        extra = np.where(count < views - 1, w * (count + 1) / views, 0.0)
    gain = column_sums(q, row_gain)
    score = gain if extra is None else gain + _TIE * column_sums(q, extra)
    if cols:
        gain[cols] = -np.inf
        score = score.copy()
        score[cols] = -np.inf
    return base, gain, score


def best_agent_path(
    problem: PlanProblem, index: ReachIndex, scores: Sequence[np.ndarray], start: np.ndarray | None = None,
) -> tuple[np.ndarray, float] | None:
    """The path maximising ``sum_p scores[p][path[p]]`` with every move within reach.

    Parameters
    ----------
    problem : PlanProblem
    index : ReachIndex
    scores : sequence of P (n,) float64
        Value of holding each pose in each phase (-inf: not allowed).
    start : (3,) float64, optional
        The agent's start position (its first pose within ``start_reach_m``).

    Returns
    -------
    (path (P,) int64, value) or None when no path exists.
    """
    P = problem.n_phases
    v = np.asarray(scores[P - 1], dtype=np.float64).copy()
    nxt: list[np.ndarray] = [np.empty(0, dtype=np.int64)] * P
    for p in range(P - 2, -1, -1):
        vpos, cand = _group_best(problem, v)
        best, arg = index.ball_max(float(problem.reach_m[p]), vpos)
        nxt[p] = cand[arg]  # per position: the next pose to go to
        v = np.asarray(scores[p], dtype=np.float64) + best[problem.pos_id]
    if start is not None:
        d = np.linalg.norm(problem.positions - start[None, :], axis=1)
        v = np.where(within(d, problem.start_reach_m), v, -np.inf)
    j = int(np.argmax(v))
    if not np.isfinite(v[j]):
        return None
    path = [j]
    for p in range(P - 1):
        path.append(int(nxt[p][problem.pos_id[path[-1]]]))
    return np.asarray(path, dtype=np.int64), float(v[j])


def _start(problem: PlanProblem, a: int) -> np.ndarray | None:
    return None if problem.start_positions_m is None else problem.start_positions_m[a]


def insert_agents(problem: PlanProblem, index: ReachIndex, plan: np.ndarray | None = None) -> np.ndarray | None:
    """Complete a partial plan (rows of agents already placed) agent by agent with :func:`best_agent_path`."""
    k, P = problem.k, problem.n_phases
    rows = [] if plan is None else [np.asarray(r, dtype=np.int64) for r in plan]
    while len(rows) < k:
        a = len(rows)
        scores = [column_gains(problem, p, [r[p] for r in rows])[2] for p in range(P)]
        found = best_agent_path(problem, index, scores, _start(problem, a))
        if found is None:
            return None
        rows.append(found[0])
    return np.vstack(rows)


def agent_ascent(
    problem: PlanProblem, index: ReachIndex, plan: np.ndarray, expired=lambda: False, max_rounds: int = 50,
) -> tuple[np.ndarray, float]:
    """Re-optimise one agent's path at a time until no path improves the plan.

    Parameters
    ----------
    plan : (k, P) int64
        A feasible plan.
    expired : callable
        Stops early when it returns True.

    Returns
    -------
    (plan, objective)
    """
    from camplace.plan.model import plan_value

    plan = np.array(plan, dtype=np.int64)
    k, P = plan.shape
    value = plan_value(problem, plan)
    tol = 1e-12 * max(1.0, abs(value))
    for _ in range(max_rounds):
        improved = False
        for a in range(k):
            if expired():
                return plan, value
            others = np.delete(plan, a, axis=0)
            parts = [column_gains(problem, p, others[:, p]) for p in range(P)]
            found = best_agent_path(problem, index, [g[2] for g in parts], _start(problem, a))
            if found is None:
                continue
            path = found[0]
            new = sum(g[0] + g[1][path[p]] for p, g in enumerate(parts))
            if new > value + tol and not np.array_equal(path, plan[a]):
                plan[a] = path
                value = plan_value(problem, plan)  # recomputed, not accumulated
                improved = True
        if not improved:
            break
    return plan, value


def set_sequence_dp(problem: PlanProblem, pool: Sequence[Sequence[int]], expired=lambda: False) -> np.ndarray | None:
    """Best plan whose pose set in every phase comes from ``pool`` (consecutive sets matched within reach).

    Parameters
    ----------
    pool : sequence of k-sets of candidate columns

    Returns
    -------
    (k, P) int64 plan, or None if no sequence is feasible.
    """
    k, P, pos = problem.k, problem.n_phases, problem.positions
    sets = sorted({tuple(sorted(int(j) for j in s)) for s in pool if len(set(s)) == k})
    if not sets:
        return None
    L = len(sets)
    vals = np.array([[phase_value(problem, p, s) for s in sets] for p in range(P)])
    compat: dict[float, np.ndarray] = {}

    def ok(reach: float) -> np.ndarray:
        if reach not in compat:
            c = np.zeros((L, L), dtype=bool)
            for i, a in enumerate(sets):
                for j, b in enumerate(sets):
                    c[i, j] = sets_compatible(pos[list(a)], pos[list(b)], reach) is not None
            compat[reach] = c
        return compat[reach]

    score = vals[0].copy()
    if problem.start_positions_m is not None:
        for i, s in enumerate(sets):
            if sets_compatible(problem.start_positions_m, pos[list(s)], problem.start_reach_m) is None:
                score[i] = -np.inf
    back = []
    for p in range(1, P):
        if expired():
            return None
        c = ok(float(problem.reach_m[p - 1]))
        cand = np.where(c, score[:, None], -np.inf)
        arg = cand.argmax(axis=0)
        back.append(arg)
        score = cand[arg, np.arange(L)] + vals[p]
    i = int(np.argmax(score))
    if not math.isfinite(score[i]):
        return None
    seq = [i]
    for arg in reversed(back):
        seq.append(int(arg[seq[-1]]))
    seq.reverse()
    return paths_from_sets(problem, [sets[i] for i in seq])


def neighbourhood(problem: PlanProblem, plan: np.ndarray, extra_sets: Sequence[Sequence[int]], top: int) -> list[np.ndarray]:
    """Poses of a restricted problem around a plan (large-neighbourhood search).

    Per phase: every pose of the plan (any phase), of ``extra_sets``, the ``top`` best poses alone,
    the ``top`` best additions to each agent's companions in that phase, and every other aim at the
    positions of those poses.

    Returns
    -------
    list of (n_p,) int64
        Sorted candidate columns per phase.
    """
    base = set(int(j) for j in np.asarray(plan).ravel())
    for s in extra_sets:
        base |= {int(j) for j in s}
    k, P = problem.k, problem.n_phases
    out = []
    for p in range(P):
        chosen = set(base)
        sv = single_values(problem, p)
        chosen |= set(np.argsort(-sv, kind="stable")[:top].tolist())
        for a in range(k):
            _, gain, _ = column_gains(problem, p, np.delete(plan[:, p], a))
            chosen |= set(np.argsort(-np.where(np.isfinite(gain), gain, -1.0), kind="stable")[:top].tolist())
        at = np.isin(problem.pos_id, problem.pos_id[sorted(chosen)])
        out.append(np.flatnonzero(at).astype(np.int64))
    return out
