"""A feasible camera team fast, and a cheap valid bound (issue 31): the team model's hint, and the
answer when the time limit passes before the model is built or solved.

:func:`team_greedy` adds one free column at a time by marginal gain (gain per cost under a budget
cardinality), every step kept within the limits that only grow (models' and zones' maxima, the
budget, one camera per pose, conflicting pairs, the count); while a model or zone minimum is unmet it
picks only among the columns that help one (the cheapest help first when the budget is tight), so the
minimums are met before the rest is filled. Gains: the uncovered weight a column observes
(maxcover), ``sum_i w_i max(q_ij - best_i, 0)`` (quality), and for multiview the rows a column
brings closer to ``views`` observers (weighted by how close; the minimum angle is not counted: the
caller scores the answer exactly). Several variants run (plain gain, gain per cost, cheapest first)
and the best feasible team by the caller's objective is kept; None when none is feasible (the team
model or the exact engines then decide).

:func:`team_bound` is an upper bound on any feasible team's objective without solving: for
maxcover and quality (submodular, weights >= 0) the fixed cameras' value plus the ``r`` largest
marginal gains over them, ``r`` the most new cameras a team may hold, capped by the weight every
allowed column together reaches; for multiview the same on ``f(S) = sum_i w_i min(1, c_i / views)``
(``c_i`` the chosen observers of row ``i``: at least the objective, submodular), capped by the weight
of the rows that the fixed cameras and at most ``r`` allowed columns could bring to ``views``
observers, and by :func:`shared_bound` (the weight pairs of columns observe together: a counted
row is seen by ``views`` chosen cameras, each of which shares it with ``views - 1`` others).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np
import scipy.sparse as sp

from camplace.solver.problem.team import TeamConstraints

__all__ = ["team_greedy", "team_bound", "largest_team", "shared_bound"]


def largest_team(team: TeamConstraints, k: int | None, fixed: tuple[int, ...], free_cols: np.ndarray) -> int:
    """The most new cameras a feasible team may hold: the count, the models' maxima, the budget,
    and (under a budget) the cheapest free columns taken first within each model's room, which is
    the cheapest way to hold that many cameras (a partition matroid: the greedy is optimal)."""
    from camplace.solver.engines.team.enumeration import _largest_team

    free_cols = np.asarray(free_cols, dtype=np.int64)
    fixed_cost = float(team.cost[list(fixed)].sum()) if fixed else 0.0
    top = _largest_team(team, k, int(len(free_cols)), fixed_cost, team.cost[free_cols])
    if team.budget is None or top == 0:
        return top
    room = _model_room(team, fixed)
    left = float(team.budget) * (1 + 1e-12) + 1e-9 - fixed_cost
    fc, fm = team.cost[free_cols], team.model[free_cols]
    held = 0
    for i in np.argsort(fc, kind="stable").tolist():
        if held >= top or fc[i] > left:
            break
        if room[fm[i]] > 0:
            room[fm[i]] -= 1
            left -= float(fc[i])
            held += 1
    return held


def _model_room(team: TeamConstraints, fixed: tuple[int, ...]) -> np.ndarray:
    """(models,) int64: new cameras each model may still take (its maximum less the fixed ones)."""
    nm = len(team.model_names)
    fm = np.bincount(team.model[list(fixed)], minlength=nm) if fixed else np.zeros(nm, dtype=np.int64)
    big = np.iinfo(np.int64).max // 4
    return np.array([big if h is None else max(0, int(h) - int(fm[i])) for i, h in enumerate(team.model_max)],
                    dtype=np.int64)


#: The shared-sighting bound of :func:`shared_bound` is skipped above this many row pair products
#: (``sum_i deg_i^2``, one multiply-add each) or when its (c, c) float64 matrix is over the memory budget.
SHARED_MAX_WORK = 50_000_000


def shared_bound(q: sp.csr_matrix, w: np.ndarray, team: TeamConstraints, cols: np.ndarray, size: int,
                 views: int) -> float:
    """An upper bound on multiview (``views >= 2``) of any set of at most ``size`` columns of ``cols``
    with at most ``model_max`` columns of each model, from the weights two columns see together.

    ``W_ab = sum_i w_i [a and b observe i]`` (``w_i > 0`` only). For a set S and a column a of it,
    let ``g_a`` be the weight of the rows a observes that ``views - 1`` other columns of S observe
    too. A row S counts is in ``g_a`` for each of its ``>= views`` observers, so the objective is at
    most ``sum_{a in S} g_a / views``; and ``g_a <= W_aa`` and ``(views - 1) g_a <= sum_{b in S, b != a}
    W_ab <=`` the ``size - 1`` largest ``W_ab``. So with ``u_a = min(W_aa, (size - 1 largest W_ab) /
    (views - 1))`` the bound is the largest sum of ``size`` of the ``u_a`` (at most ``model_max`` of
    each model) over ``views``. Valid with a minimum angle too (it only removes counted rows).

    Returns ``+inf`` when ``views < 2`` or the work (``sum_i deg_i^2``) is over
    :data:`SHARED_MAX_WORK` or the (c, c) matrix over the memory budget.
    """
    from camplace.solver._support.memory import memory_budget_bytes

    cols = np.asarray(cols, dtype=np.int64)
    c = cols.size
    if views < 2 or c == 0:
        return math.inf
    if size < views:
        return 0.0
    wp = np.maximum(np.asarray(w, dtype=np.float64), 0.0)
    pat = q[:, cols].tocsr()
    keep = np.flatnonzero((wp > 0) & (np.diff(pat.indptr) > 0))
    pat = pat[keep]
    deg = np.diff(pat.indptr).astype(np.float64)
    if float(deg @ deg) > SHARED_MAX_WORK or 3 * 8 * c * c > memory_budget_bytes():
        return math.inf
    p = sp.csr_matrix((np.ones(pat.nnz), pat.indices, pat.indptr), shape=pat.shape)
    pw = sp.csr_matrix((np.repeat(wp[keep], np.diff(pat.indptr)), pat.indices, pat.indptr), shape=pat.shape)
    pair = (p.T @ pw).toarray()  # (c, c): W_ab
    own = np.diag(pair).copy()
    np.fill_diagonal(pair, 0.0)
    r = min(size - 1, c - 1)
    top = -np.partition(-pair, r - 1, axis=1)[:, :r].sum(axis=1) if r > 0 else np.zeros(c)
    u = np.minimum(own, top / (views - 1))
    cm = team.model[cols]
    picked = []
    for mi, hi in enumerate(team.model_max):
        mine = np.sort(u[cm == mi])[::-1]
        picked.append(mine if hi is None else mine[:int(hi)])
    best = np.sort(np.concatenate(picked))[::-1][:size]
    return float(best.sum()) / views


def _column_sums(csc: sp.csc_matrix, values: np.ndarray) -> np.ndarray:
    """Per column, the sum of ``values`` (one per stored entry of ``csc``)."""
    col = np.repeat(np.arange(csc.shape[1]), np.diff(csc.indptr))
    return np.bincount(col, weights=values, minlength=csc.shape[1])


def _base_quality(q: sp.csr_matrix, fixed: tuple[int, ...]) -> np.ndarray:
    if not fixed:
        return np.zeros(q.shape[0])
    return np.asarray(q[:, list(fixed)].max(axis=1).toarray(), dtype=np.float64).ravel()


def _base_count(q: sp.csr_matrix, fixed: tuple[int, ...]) -> np.ndarray:
    if not fixed:
        return np.zeros(q.shape[0], dtype=np.int64)
    return np.asarray((q[:, list(fixed)] > 0).sum(axis=1), dtype=np.int64).ravel()


def team_bound(q: sp.csr_matrix, w: np.ndarray, team: TeamConstraints, *, mode: str, k: int | None,
               fixed: tuple[int, ...], free_cols: np.ndarray, views: int = 2) -> float:
    """An upper bound on the objective of every feasible team (module docstring); ``+inf`` for a
    mode it does not know (setcover minimises: its caller uses 0)."""
    free_cols = np.asarray(free_cols, dtype=np.int64)
    w = np.asarray(w, dtype=np.float64)
    wp = np.maximum(w, 0.0)
    r = largest_team(team, k, fixed, free_cols)
    qf = q[:, free_cols].tocsc()
    if mode in ("maxcover", "quality"):
        if mode == "maxcover":
            base = (_base_count(q, fixed) > 0).astype(np.float64)
            vals = (qf.data > 0).astype(np.float64)
        else:
            base = _base_quality(q, fixed)
            vals = np.asarray(qf.data, dtype=np.float64)
        best_all = base.copy()
        if qf.nnz:
            np.maximum.at(best_all, qf.indices, vals)
        cap = float(wp @ best_all)
        if np.any(w < 0):
            return cap
        gains = _column_sums(qf, np.maximum(vals - base[qf.indices], 0.0) * w[qf.indices])
        top = float(np.sort(gains)[::-1][:r].sum()) if r > 0 else 0.0
        return min(cap, float(w @ base) + top)
    if mode == "multiview":
        seen = np.asarray((qf > 0).sum(axis=1), dtype=np.int64).ravel()
        b = _base_count(q, fixed)
        cap = float(wp[b + np.minimum(seen, r) >= int(views)].sum())
        if np.any(w < 0):
            return cap
        # f(S) = sum_i w_i min(1, c_i / views) >= the objective, and f is submodular (concave of a count)
        v = float(views)
        f0 = float(w @ np.minimum(1.0, b / v))
        gains = _column_sums(qf, np.where(b[qf.indices] < views, w[qf.indices] / v, 0.0) * (qf.data > 0))
        top = float(np.sort(gains)[::-1][:r].sum()) if r > 0 else 0.0
        # the fixed cameras and at most r new ones: a set of at most r + |fixed| allowed columns
        cols = np.union1d(free_cols, np.asarray(fixed, dtype=np.int64))
        return min(cap, f0 + top, shared_bound(q, w, team, cols, r + len(fixed), int(views)))
    return math.inf


def team_greedy(q: sp.csr_matrix, w: np.ndarray, team: TeamConstraints, *, mode: str, k: int | None,
                fixed: tuple[int, ...], free_cols: np.ndarray, conflicts: np.ndarray, views: int = 2,
                value: Callable[[tuple[int, ...]], float] | None = None) -> tuple[int, ...] | None:
    """A feasible team (original columns, fixed included) by greedy marginal gain (module
    docstring), or None. ``value`` scores a full selection (default: the greedy's own gain sum);
    the best of the variants by it is returned. Maximising modes only (None for setcover)."""
    if mode not in ("maxcover", "quality", "multiview"):
        return None
    fixed = tuple(int(j) for j in fixed)
    free_cols = np.asarray(free_cols, dtype=np.int64)
    if _over_max(team, fixed):  # the fixed cameras already break a limit that only grows
        return None
    best: tuple[int, ...] | None = None
    best_v = -math.inf
    for variant in ("gain", "ratio", "cheap"):
        if variant != "gain" and team.budget is None:
            continue
        sel = _greedy_once(q, w, team, mode, k, fixed, free_cols, conflicts, views, variant)
        if sel is None or team.violations(sel, k=k, fixed=fixed):
            continue
        v = value(sel) if value is not None else float(len(sel))
        if v > best_v:
            best, best_v = sel, v
    return best


def _over_max(team: TeamConstraints, fixed: tuple[int, ...]) -> bool:
    """Whether the fixed cameras break a limit that only grows (a maximum, the budget, a pose)."""
    u = team.uses(fixed)
    if team.budget is not None and u["cost"] > float(team.budget) * (1 + 1e-12) + 1e-9:
        return True
    if team.pose is not None and fixed and np.unique(team.pose[list(fixed)]).size < len(fixed):
        return True
    for name, hi in zip(team.model_names, team.model_max):
        if hi is not None and u["models"][name] > hi:
            return True
    for name, hi in zip(team.zone_names, team.zone_max):
        if hi is not None and u["zones"][name] > hi:
            return True
    return False


def _greedy_once(q: sp.csr_matrix, w: np.ndarray, team: TeamConstraints, mode: str, k: int | None,
                 fixed: tuple[int, ...], free_cols: np.ndarray, conflicts: np.ndarray, views: int,
                 variant: str) -> tuple[int, ...] | None:
    nf = free_cols.size
    w = np.asarray(w, dtype=np.float64)
    qf = q[:, free_cols].tocsc()
    rows = qf.indices
    vals = np.asarray(qf.data, dtype=np.float64)
    col_of = np.repeat(np.arange(nf), np.diff(qf.indptr))
    if mode == "quality":
        state = _base_quality(q, fixed)
    elif mode == "maxcover":
        state = (_base_count(q, fixed) > 0).astype(np.float64)
        vals = (vals > 0).astype(np.float64)
    else:
        state = _base_count(q, fixed).astype(np.float64)
        vals = (vals > 0).astype(np.float64)
    nm, nz = len(team.model_names), len(team.zone_names)
    fm = team.model[free_cols]
    fz = team.zone_member[free_cols]
    fc = team.cost[free_cols]
    fp = team.pose[free_cols] if team.pose is not None else None
    mcount = np.bincount(team.model[list(fixed)], minlength=nm).astype(np.int64) if fixed else np.zeros(nm, np.int64)
    zcount = team.zone_member[list(fixed)].sum(axis=0).astype(np.int64) if fixed else np.zeros(nz, np.int64)
    cost = float(team.cost[list(fixed)].sum()) if fixed else 0.0
    mmin, zmin = np.asarray(team.model_min, np.int64), np.asarray(team.zone_min, np.int64)
    mmax = np.array([np.iinfo(np.int64).max if h is None else h for h in team.model_max], dtype=np.int64)
    zmax = np.array([np.iinfo(np.int64).max if h is None else h for h in team.zone_max], dtype=np.int64)
    budget = math.inf if team.budget is None else float(team.budget) * (1 + 1e-12) + 1e-9
    ok = np.ones(nf, dtype=bool)
    if fp is not None and fixed:
        ok &= ~np.isin(fp, team.pose[list(fixed)])
    pos_of = np.full(q.shape[1], -1, dtype=np.int64)
    pos_of[free_cols] = np.arange(nf)
    clash: list[list[int]] = [[] for _ in range(nf)]
    for a, b in np.asarray(conflicts, dtype=np.int64).reshape(-1, 2).tolist():
        ia, ib = int(pos_of[a]), int(pos_of[b])
        if ia >= 0 and ib >= 0:
            clash[ia].append(ib)
            clash[ib].append(ia)
    exact = team.cardinality == "exact" and k is not None
    cap = nf if k is None else min(nf, int(k))
    chosen: list[int] = []
    while len(chosen) < cap:
        allowed = ok & (mcount[fm] < mmax[fm]) & (cost + fc <= budget)
        if nz:
            allowed &= ~np.any(fz & (zcount >= zmax)[None, :], axis=1)
        if not allowed.any():
            break
        if mode == "multiview":
            need = state[rows] < views
            step = np.where(need, (state[rows] + 1.0) / views, 0.0)
            gain = _col_sum(col_of, w[rows] * step * vals, nf)
        else:
            gain = _col_sum(col_of, w[rows] * np.maximum(vals - state[rows], 0.0), nf)
        unmet_m = mcount < mmin
        unmet_z = zcount < zmin
        helps = unmet_m[fm]
        if nz:
            helps = helps | np.any(fz & unmet_z[None, :], axis=1)
        filling = bool(unmet_m.any() or unmet_z.any())
        pool = allowed & helps if filling and (allowed & helps).any() else allowed
        if filling and not (allowed & helps).any():
            return None  # a minimum no allowed column can meet any more
        if variant == "cheap" or (variant == "ratio" and math.isfinite(budget)):
            score = gain / np.maximum(fc, 1e-12) if variant == "ratio" else -fc + 1e-9 * gain
        else:
            score = gain
        if filling:  # prefer columns that help more minimums at once
            nh = unmet_m[fm].astype(np.float64) + (np.sum(fz & unmet_z[None, :], axis=1) if nz else 0.0)
            score = nh * (abs(score).max() + 1.0) * 2 + score
        score = np.where(pool, score, -np.inf)
        i = int(np.argmax(score))
        if not np.isfinite(score[i]):
            break
        if not filling and not exact and gain[i] <= 0:
            break
        chosen.append(i)
        ok[i] = False
        if fp is not None:
            ok &= fp != fp[i]
        for c in clash[i]:
            ok[c] = False
        mcount[fm[i]] += 1
        if nz:
            zcount += fz[i]
        cost += float(fc[i])
        lo, hi = qf.indptr[i], qf.indptr[i + 1]
        if mode == "multiview":
            state[rows[lo:hi]] += vals[lo:hi]
        else:
            state[rows[lo:hi]] = np.maximum(state[rows[lo:hi]], vals[lo:hi])
    if np.any(mcount < mmin) or np.any(zcount < zmin) or (exact and len(chosen) != k):
        return None
    return tuple(sorted(set(fixed) | {int(free_cols[i]) for i in chosen}))


def _col_sum(col_of: np.ndarray, values: np.ndarray, nf: int) -> np.ndarray:
    return np.bincount(col_of, weights=values, minlength=nf)


def improve_team(sel: tuple[int, ...], team: TeamConstraints, *, k: int | None, fixed: tuple[int, ...],
                 free_cols: np.ndarray, conflicts: np.ndarray, value: Callable[[tuple[int, ...]], float],
                 deadline, max_evals: int = 5000) -> tuple[tuple[int, ...], dict]:
    """1-swap local search from the feasible team ``sel``: replace a new camera by an allowed free
    column when the team stays feasible (``TeamConstraints.violations``, conflicting pairs) and
    ``value`` grows; first improvement, passes until none or ``deadline`` (checked before each
    evaluation) or ``max_evals`` evaluations. Returns the team and ``{"evals", "swaps"}``."""
    fixed_s = {int(j) for j in fixed}
    clash: dict[int, set[int]] = {}
    for a, b in np.asarray(conflicts, dtype=np.int64).reshape(-1, 2).tolist():
        clash.setdefault(a, set()).add(b)
        clash.setdefault(b, set()).add(a)
    cur = tuple(sorted(sel))
    best = value(cur)
    evals, swaps = 1, 0
    cands = [int(j) for j in np.asarray(free_cols, dtype=np.int64)]
    improved = True
    while improved:
        improved = False
        for out_j in [j for j in cur if j not in fixed_s]:
            rest = [j for j in cur if j != out_j]
            rest_s = set(rest)
            for in_j in cands:
                if in_j in rest_s or in_j == out_j or (clash.get(in_j, set()) & rest_s):
                    continue
                new = tuple(sorted(rest + [in_j]))
                if team.violations(new, k=k, fixed=fixed):
                    continue
                if evals >= max_evals or deadline.expired():
                    return cur, {"evals": evals, "swaps": swaps}
                v = value(new)
                evals += 1
                if v > best + 1e-12 * max(1.0, abs(best)):
                    cur, best, swaps, improved = new, v, swaps + 1, True
                    break
            if improved:
                break
    return cur, {"evals": evals, "swaps": swaps}
