"""The exact team engine for small instances: every feasible team, depth first (issue 31).

Columns are added in index order; a partial team is cut as soon as it breaks a limit that can only
get worse (a model's or a zone's maximum, the budget, a pose taken twice, a conflicting pair, more
new cameras than allowed); complete teams are checked against the minimums and the cardinality and
scored on the original matrix: covered weight (maxcover), ``sum_i w_i max_j q_ij`` (quality),
the weight of the rows at least ``views`` chosen cameras observe, two of them at least
``min_angle_deg`` apart when given (multiview), or the cost of the new cameras (setcover). Every
feasible team is visited, so the best is optimal (or the team is infeasible when there is none).
:func:`team_count` bounds the number of teams visited, which :func:`camplace.solver.routes.run_team`
compares with :data:`ENUMERATION_LIMIT` to choose this engine.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

from camplace.solver._support.deadline import Deadline
from camplace.solver.problem.team import TeamConstraints

__all__ = ["ENUMERATION_LIMIT", "team_count", "enumerate_teams"]

#: ``auto`` enumerates when at most this many teams (by :func:`team_count`) are possible.
ENUMERATION_LIMIT = 20_000


def _largest_team(team: TeamConstraints, k: int | None, nf: int, fixed_cost: float, free_cost: np.ndarray) -> int:
    """An upper bound on the number of new cameras of a feasible team."""
    top = nf if k is None else min(nf, k)
    if team.cardinality == "exact" and k is not None:
        return min(nf, k)
    if all(h is not None for h in team.model_max):
        top = min(top, int(sum(h for h in team.model_max)))  # type: ignore[misc]
    if team.budget is not None and free_cost.size:
        cs = np.sort(free_cost)
        fits = int(np.searchsorted(np.cumsum(cs), team.budget - fixed_cost + 1e-9, side="right"))
        top = min(top, fits)
    return max(0, top)


def team_count(team: TeamConstraints, k: int | None, fixed: tuple[int, ...], free_cols: np.ndarray) -> float:
    """Upper bound on the teams the enumeration visits: ``sum_s C(f, s)`` over the possible sizes."""
    nf = int(len(free_cols))
    fixed_cost = float(team.cost[list(fixed)].sum()) if fixed else 0.0
    top = _largest_team(team, k, nf, fixed_cost, team.cost[free_cols])
    if team.cardinality == "exact" and k is not None:
        return float(math.comb(nf, top)) if top == k else 0.0
    return float(sum(math.comb(nf, s) for s in range(top + 1)))


def enumerate_teams(
    q: sp.csr_matrix, w: np.ndarray, team: TeamConstraints, *, mode: str, k: int | None, fixed: tuple[int, ...],
    free_cols: np.ndarray, conflicts: np.ndarray, costs: np.ndarray | None, required_fraction: float,
    deadline: Deadline, views: int = 2, min_angle_deg: float | None = None, pos: np.ndarray | None = None,
    pts: np.ndarray | None = None,
) -> tuple[tuple[int, ...] | None, str, float, dict[str, Any]]:
    """Visit every feasible team (module docstring).

    Parameters
    ----------
    q : (m, n) csr_matrix
        Observation quality (> 0 observes; quality reads the values, in [0, 1]).
    w : (m,) float64
    team : TeamConstraints
    mode : {"maxcover", "quality", "multiview", "setcover"}
    k : int or None
        New cameras (exactly, or at most for cardinality ``budget``); None: no count.
    fixed : tuple of int
    free_cols : (f,) int64
    conflicts : (c, 2) int64
        Pairs of free columns that may not both be chosen.
    costs : (n,) float64 or None
        setcover objective costs (default: the team's).
    required_fraction : float
    deadline : Deadline
    views : int, optional
        multiview: observers a row needs.
    min_angle_deg : float, optional
        multiview: two of them at least this far apart (degrees; needs ``pos`` and ``pts``).
    pos : (n, 3) float64, optional
        Camera positions, metres.
    pts : (m, 3) float64, optional
        Point positions, metres.

    Returns
    -------
    selected : tuple of int or None
        The best team (original columns, fixed included); None when none is feasible or time ran out first.
    status : {"optimal", "infeasible", "unknown", "feasible"}
    objective : float
        The mode's value (maxcover, quality, multiview) or cost of the new cameras (setcover).
    stats : dict
    """
    m, n = q.shape
    fixed = tuple(int(j) for j in fixed)
    free_cols = np.asarray(free_cols, dtype=np.int64)
    nf = free_cols.size
    pat = (q > 0).tocsc() if q.dtype != np.bool_ else q.tocsc()
    dense = np.asarray(pat[:, free_cols].toarray(), dtype=bool)
    base = np.asarray(pat[:, list(fixed)].toarray(), dtype=bool).any(axis=1) if fixed else np.zeros(m, dtype=bool)
    c_obj = team.cost if costs is None else np.asarray(costs, dtype=np.float64)
    coverable = base | dense.any(axis=1)
    total = float(w[(w > 0) & coverable].sum())
    need = required_fraction * total
    nm, nz = len(team.model_names), len(team.zone_names)
    mcount = np.bincount(team.model[list(fixed)], minlength=nm) if fixed else np.zeros(nm, dtype=np.int64)
    zcount = team.zone_member[list(fixed)].sum(axis=0).astype(np.int64) if fixed else np.zeros(nz, dtype=np.int64)
    cost0 = float(team.cost[list(fixed)].sum()) if fixed else 0.0
    used_poses = set(team.pose[list(fixed)].tolist()) if (team.pose is not None and fixed) else set()
    fm = team.model[free_cols]
    fz = team.zone_member[free_cols]
    fc = team.cost[free_cols]
    fp = team.pose[free_cols] if team.pose is not None else None
    pos_of = {int(j): i for i, j in enumerate(free_cols)}
    clash: list[set[int]] = [set() for _ in range(nf)]
    for a, b in np.asarray(conflicts, dtype=np.int64).reshape(-1, 2).tolist():
        ia, ib = pos_of[a], pos_of[b]
        clash[ia].add(ib)
        clash[ib].add(ia)
    mmax = [math.inf if h is None else h for h in team.model_max]
    zmax = [math.inf if h is None else h for h in team.zone_max]
    budget = math.inf if team.budget is None else float(team.budget) * (1 + 1e-12) + 1e-9
    top = _largest_team(team, k, nf, cost0, fc)
    exact = team.cardinality == "exact" and k is not None
    maximize = mode != "setcover"
    score = _scorer(q, w, mode, fixed, free_cols, dense, base, views, min_angle_deg, pos, pts)
    best: list[Any] = [None, -math.inf if maximize else math.inf]
    visited = [0]
    timed_out = [False]
    chosen: list[int] = []

    # the fixed cameras alone may already break a limit that only grows
    fixed_ok = (cost0 <= budget and all(mcount[i] <= mmax[i] for i in range(nm))
                and all(zcount[i] <= zmax[i] for i in range(nz))
                and (team.pose is None or len(used_poses) == len(fixed)))

    def leaf() -> None:
        visited[0] += 1
        if exact and len(chosen) != k:
            return
        if any(mcount[i] < team.model_min[i] for i in range(nm)) or any(zcount[i] < team.zone_min[i] for i in range(nz)):
            return
        if maximize:
            value = score(chosen)
            if value > best[1] + 1e-12:
                best[0], best[1] = tuple(chosen), value
        else:
            cov = base | (dense[:, chosen].any(axis=1) if chosen else False)
            if float(w[cov & (w > 0)].sum()) < need * (1 - 1e-12) - 1e-12:
                return
            value = float(c_obj[free_cols[chosen]].sum()) if chosen else 0.0
            if value < best[1] - 1e-12:
                best[0], best[1] = tuple(chosen), value

    def dfs(start: int, cost: float) -> None:
        if timed_out[0]:
            return
        if visited[0] % 1024 == 0 and deadline.expired():
            timed_out[0] = True
            return
        leaf()
        if len(chosen) >= top:
            return
        for i in range(start, nf):
            mi = int(fm[i])
            if mcount[mi] + 1 > mmax[mi] or cost + fc[i] > budget:
                continue
            zi = fz[i]
            if nz and np.any(zcount[zi] + 1 > np.asarray(zmax)[zi]):
                continue
            if fp is not None and int(fp[i]) in used_poses:
                continue
            if clash[i] and any(c in clash[i] for c in chosen):
                continue
            chosen.append(i)
            mcount[mi] += 1
            zcount[zi] += 1
            if fp is not None:
                used_poses.add(int(fp[i]))
            dfs(i + 1, cost + fc[i])
            chosen.pop()
            mcount[mi] -= 1
            zcount[zi] -= 1
            if fp is not None:
                used_poses.discard(int(fp[i]))

    if fixed_ok:
        dfs(0, cost0)
    stats = {"teams_visited": int(visited[0]), "timed_out": bool(timed_out[0])}
    if best[0] is None:
        return None, ("unknown" if timed_out[0] else "infeasible"), best[1], stats
    sel = tuple(sorted(set(fixed) | {int(free_cols[i]) for i in best[0]}))
    return sel, ("feasible" if timed_out[0] else "optimal"), float(best[1]), stats


#: The minimum-angle scorer keeps the rows of at most this many bytes of camera pairs.
_PAIR_CACHE_BYTES = 1 << 27


def _scorer(q: sp.csr_matrix, w: np.ndarray, mode: str, fixed: tuple[int, ...], free_cols: np.ndarray,
            dense: np.ndarray, base: np.ndarray, views: int, min_angle_deg: float | None, pos: np.ndarray | None,
            pts: np.ndarray | None) -> Callable[[list[int]], float]:
    """The objective of a maximising mode as a function of the chosen free columns (positions in
    ``free_cols``), fixed cameras included.

    Parameters
    ----------
    q : (m, n) csr_matrix
    w : (m,) float64
    mode : {"maxcover", "quality", "multiview", "setcover"}
        setcover: none (returns a function that is never called).
    fixed : tuple of int
    free_cols : (f,) int64
    dense : (m, f) bool
        Which free column observes which row.
    base : (m,) bool
        Rows a fixed camera observes.
    views, min_angle_deg, pos, pts
        multiview (see :func:`enumerate_teams`).
    """
    if mode == "maxcover":
        return lambda chosen: float(w[base | (dense[:, chosen].any(axis=1) if chosen else False)].sum())
    if mode == "quality":
        qd = q[:, free_cols].toarray()
        qbest = q[:, list(fixed)].max(axis=1).toarray().ravel() if fixed else np.zeros(q.shape[0])

        def quality(chosen: list[int]) -> float:
            best = np.maximum(qbest, qd[:, chosen].max(axis=1)) if chosen else qbest
            return float(w @ best)

        return quality
    if mode != "multiview":
        return lambda chosen: math.nan
    pat = (q > 0).tocsc() if q.dtype != np.bool_ else q.tocsc()
    fixed_seen = np.asarray(pat[:, list(fixed)].toarray(), dtype=bool) if fixed else np.zeros((q.shape[0], 0), bool)
    base_count = fixed_seen.sum(axis=1)
    if min_angle_deg is None or pos is None or pts is None:
        return lambda chosen: float(w[base_count + (dense[:, chosen].sum(axis=1) if chosen else 0) >= views].sum())
    # the angle: a row counts when two chosen cameras that both observe it make >= min_angle_deg at it
    seen = np.concatenate([fixed_seen, dense], axis=1)  # columns: fixed ones, then the free ones
    cols = np.concatenate([np.asarray(fixed, dtype=np.int64), np.asarray(free_cols, dtype=np.int64)])
    nfix = len(fixed)
    cache: dict[tuple[int, int], np.ndarray] = {}
    used = [0]

    def pair(a: int, b: int) -> np.ndarray:
        got = cache.get((a, b))
        if got is not None:
            return got
        both = seen[:, a] & seen[:, b]
        rows = np.flatnonzero(both)
        da = pos[cols[a]][None, :] - pts[rows]
        db = pos[cols[b]][None, :] - pts[rows]
        da /= np.maximum(np.linalg.norm(da, axis=1, keepdims=True), 1e-300)
        db /= np.maximum(np.linalg.norm(db, axis=1, keepdims=True), 1e-300)
        ang = np.degrees(np.arccos(np.clip(np.sum(da * db, axis=1), -1.0, 1.0)))
        out = np.zeros(both.size, dtype=bool)
        out[rows[ang >= float(min_angle_deg)]] = True
        if used[0] + out.size <= _PAIR_CACHE_BYTES:
            cache[(a, b)] = out
            used[0] += out.size
        return out

    fixed_pairs = np.zeros(q.shape[0], dtype=bool)
    for a in range(nfix):
        for b in range(a + 1, nfix):
            fixed_pairs |= pair(a, b)

    def multiview(chosen: list[int]) -> float:
        ok = base_count + (dense[:, chosen].sum(axis=1) if chosen else 0) >= views
        paired = fixed_pairs.copy()
        sel = list(range(nfix)) + [nfix + i for i in chosen]
        for t, a in enumerate(sel):
            for b in sel[max(t + 1, nfix):]:
                paired |= pair(a, b)
        return float(w[ok & paired].sum())

    return multiview
