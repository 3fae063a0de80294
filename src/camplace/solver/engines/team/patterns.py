"""Max coverage of a camera team by per-model count patterns (issue 31).

With a cost per model (every column of a model costs the same), a team is a count pattern ``c``
(new cameras per model) with ``min_m <= fixed_m + c_m <= max_m``, ``fixed cost + sum_m c_m cost_m
<= budget`` and ``sum_m c_m = k`` (cardinality ``exact``; ``<= k`` for ``budget`` with a k). The
best team is the best over the feasible patterns, and each pattern is a smaller problem:

* one model only, no zone quotas: plain max coverage of ``c_m`` new columns of that model (its
  poses are distinct, the columns at a fixed camera's pose are removed beforehand), solved by
  :func:`camplace.solver.api.solve` with the other columns forbidden: the bitset engine and its
  presolve (dominance within the model is then safe), the large-k engines or the MIP, as
  :func:`~camplace.solver.choose.choose_engine` decides;
* otherwise the team branch and bound (:mod:`camplace.solver.engines.team.bnb`) with the model
  counts pinned to the pattern (its bound at depth 1 is much tighter than with free counts).

Patterns are solved largest first, each with the best value so far as its incumbent. The answer is
optimal when every pattern was proven; its bound is the largest pattern bound.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

from camplace.solver._support.deadline import Deadline
from camplace.solver.problem.team import TeamConstraints

__all__ = ["model_costs", "count_patterns", "maximal_patterns", "solve_by_patterns", "MAX_PATTERNS"]

#: More patterns than this: the branch and bound on the whole team instead.
MAX_PATTERNS = 200


def model_costs(team: TeamConstraints) -> np.ndarray | None:
    """(models,) cost of each model, or None when a model's columns do not all cost the same."""
    out = np.zeros(len(team.model_names))
    for mi in range(len(team.model_names)):
        c = team.cost[team.model == mi]
        if c.size and np.any(c != c[0]):
            return None
        out[mi] = c[0] if c.size else 0.0
    return out


def count_patterns(team: TeamConstraints, k: int | None, fixed: tuple[int, ...], avail: np.ndarray,
                   costs: np.ndarray) -> list[tuple[int, ...]]:
    """Every feasible pattern of new cameras per model (``avail[m]``: model m's free columns),
    largest total first; [] when more than :data:`MAX_PATTERNS` (or none)."""
    nm = len(team.model_names)
    fm = np.bincount(team.model[list(fixed)], minlength=nm) if fixed else np.zeros(nm, dtype=np.int64)
    fixed_cost = float(team.cost[list(fixed)].sum()) if fixed else 0.0
    budget = math.inf if team.budget is None else float(team.budget) * (1 + 1e-12) + 1e-9
    exact = team.cardinality == "exact" and k is not None
    total_cap = int(avail.sum()) if k is None else int(k)
    ranges = []
    for mi in range(nm):
        hi = int(avail[mi])
        if team.model_max[mi] is not None:
            hi = min(hi, team.model_max[mi] - int(fm[mi]))
        hi = min(hi, total_cap)
        if costs[mi] > 0 and math.isfinite(budget):
            hi = min(hi, int(max(0.0, budget - fixed_cost) // costs[mi]) + 1)
        lo = max(0, team.model_min[mi] - int(fm[mi]))
        if hi < lo:
            return []
        ranges.append(range(lo, hi + 1))
        if math.prod(len(r) for r in ranges) > 50 * MAX_PATTERNS:
            return []
    out = []
    for c in itertools.product(*ranges):
        s = sum(c)
        if (exact and s != k) or (k is not None and s > k):
            continue
        if fixed_cost + float(np.dot(c, costs)) > budget:
            continue
        out.append(tuple(int(v) for v in c))
        if len(out) > MAX_PATTERNS:
            return []
    out.sort(key=lambda c: (-sum(c), c))
    return out


def maximal_patterns(team: TeamConstraints, patterns: list[tuple[int, ...]], avail: np.ndarray) -> list[tuple[int, ...]]:
    """The patterns no other one dominates (max coverage only; all of them under zone maxima).

    ``c`` is dominated by a feasible ``c' >= c`` (``c' != c``) when every model that ``c'`` adds
    has at least ``sum(c')`` free columns: any team of ``c`` (on at most ``sum(c) < sum(c')``
    poses) then extends to one of ``c'`` on free poses, and coverage never drops when cameras are
    added; the budget, the model maxima and the zone minimums hold for ``c'`` by construction.
    A zone maximum could break the extension, so none is dropped then."""
    if any(v is not None for v in team.zone_max):
        return patterns
    keep = []
    for c in patterns:
        dominated = False
        for d in patterns:
            if d == c or any(dv < cv for dv, cv in zip(d, c)):
                continue
            if all(avail[mi] >= sum(d) for mi in range(len(c)) if d[mi] > c[mi]):
                dominated = True
                break
        if not dominated:
            keep.append(c)
    return keep


def _covered(q: Any, w: np.ndarray, sel: tuple[int, ...]) -> float:
    """The covered weight of ``sel`` on a scipy matrix or a BitMatrix (summed the same way)."""
    if getattr(q, "format", None) == "bits":
        from camplace.solver.problem.presolve_bits import covered_weight

        return covered_weight(q, w, sel)
    from camplace.solver.problem.objectives import mode_value

    return mode_value(q, w, sel, mode="maxcover")


def solve_by_patterns(
    q: sp.csr_matrix, w: np.ndarray, team: TeamConstraints, *, k: int | None, fixed: tuple[int, ...],
    free_cols: np.ndarray, deadline: Deadline, patterns: list[tuple[int, ...]], k_solver: Callable[[Any], Any],
) -> tuple[tuple[int, ...] | None, str, float, float, dict[str, Any]]:
    """The best team over ``patterns`` (module docstring): ``(selected, status, objective, bound, stats)``.

    ``q`` is a scipy matrix or a :class:`camplace.visibility.bits.BitMatrix` (the branch and bound
    reads either). ``k_solver(options)`` solves the same matrix and weights without a team (the
    caller's :func:`camplace.solver.api.solve`, passed in: this module does not import the api)."""
    from camplace.solver.engines.team.bnb import team_branch_and_bound
    from camplace.solver.options import SolveOptions

    n = q.shape[1]
    nm = len(team.model_names)
    fm = np.bincount(team.model[list(fixed)], minlength=nm) if fixed else np.zeros(nm, dtype=np.int64)
    no_zones = all(v == 0 for v in team.zone_min) and all(v is None for v in team.zone_max)
    best_sel: tuple[int, ...] | None = None
    best_val = -math.inf
    bound = -math.inf
    proven = True
    log: list[dict[str, Any]] = []
    for pi, c in enumerate(patterns):
        left = deadline.left()
        if left is not None and left <= 0:
            proven = False
            bound = math.inf  # patterns left unsolved: no bound better than none
            log.append({"pattern": list(c), "status": "skipped (time limit)"})
            continue
        used = [mi for mi in range(nm) if c[mi] > 0]
        entry: dict[str, Any] = {"pattern": list(c)}
        if sum(c) == 0:
            sel = tuple(sorted(fixed))
            if not team.violations(sel):
                v = _covered(q, w, sel) if sel else 0.0
                entry.update(status="optimal", value=v, engine="none")
                bound = max(bound, v)
                if v > best_val:
                    best_val, best_sel = v, sel
            else:
                entry.update(status="infeasible")
            log.append(entry)
            continue
        if len(used) == 1 and no_zones:
            mi = used[0]
            mine = free_cols[team.model[free_cols] == mi]
            forbidden = np.setdiff1d(np.arange(n), np.concatenate([mine, np.asarray(fixed, dtype=np.int64)]))
            res = k_solver(SolveOptions(mode="maxcover", k=int(c[mi]), fixed=fixed,
                                                   forbidden=tuple(int(j) for j in forbidden), time_limit_s=left))
            entry.update(status=res.status, value=res.objective, bound=res.bound, engine=res.engine,
                         route=(res.stats.get("engine_choice") or {}).get("route"))
            sel, status, value, pbound = (res.selected if res.status in ("optimal", "feasible") else None), res.status, \
                res.objective, res.bound
        else:
            pinned = replace(team, model_min=tuple(int(fm[mi] + c[mi]) for mi in range(nm)),
                             model_max=tuple(int(fm[mi] + c[mi]) for mi in range(nm)), cardinality="exact")
            sel, status, value, pbound, st = team_branch_and_bound(q, w, pinned, k=int(sum(c)), fixed=fixed,
                                                                    free_cols=free_cols, deadline=deadline,
                                                                    incumbent=best_val)
            entry.update(status=status, value=value, bound=pbound, engine="bnb", nodes=st.get("nodes"))
        log.append(entry)
        if status == "dominated":  # proven no better than the best so far
            continue
        if status not in ("optimal", "infeasible"):
            proven = False
        if status != "infeasible":
            bound = max(bound, pbound)
        if sel is not None and value > best_val:
            best_val, best_sel = value, tuple(sel)
    stats = {"patterns": log, "n_patterns": len(patterns)}
    if best_sel is None:
        return None, ("infeasible" if proven else "unknown"), math.nan, bound, stats
    return best_sel, ("optimal" if proven else "feasible"), best_val, max(bound, best_val), stats
