"""The moving-agents planner: reference values, a heuristic incumbent, and the exact flow model.

:func:`solve_plan` returns the best plan it finds with a proven upper bound:

1. **Per-phase optima** ``U_p`` (the solver's exact engines on each phase's rows): their sum is the
   value at infinite speed, an upper bound on every plan (``unconstrained_bound``).
2. **The best static system** (one pose set for the whole event, the solver on all rows): a
   feasible plan at any speed without start positions (``static_objective``).
3. **Shortcuts.** When every move is within reach (speed above every distance) the per-phase optima
   are the plan; when no agent can move or re-aim (every position has one pose and the reach is
   below the closest pair of positions) the static system is.
4. **Heuristic.** Agent-path ascent (:mod:`camplace.plan.heuristic`) from the static system, from
   agents inserted one by one, and from the best sequence of pose sets drawn from the per-phase
   optima: a feasible incumbent ``I``.
5. **Exact model.** Any plan better than ``I`` holds, in each phase p, only poses j with
   ``F_p(j) + sum_{q != p} U_q > I``, where ``F_p(j) = min(U_p, U_p^(k-1) + single_p(j))`` bounds
   every phase-p set holding j (``U_p^(k-1)``: the phase's optimum with k - 1 agents; not in
   multiview, whose engines are slow to give it). The flow model
   (:func:`camplace.plan.model.build_flow_model`) over the kept poses is solved with SCIP or CP-SAT
   (the incumbent as a hint) when its estimated size fits; its bound, or I if it is infeasible,
   is then a bound on every plan. When it is too large, a large-neighbourhood search solves it
   restricted to poses around the incumbent (:func:`camplace.plan.heuristic.neighbourhood`) while
   that improves; the bound is then the sum of the per-phase optima.

``status`` is "optimal" when the bound meets the objective (relative 1e-9), else "feasible".
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from camplace.errors import CamplaceError
from camplace.plan.model import (
    PlanProblem,
    build_flow_model,
    check_plan,
    flow_model_size,
    paths_from_sets,
    phase_value,
    plan_value,
    single_values,
    within,
)

__all__ = ["PLAN_ENGINES", "StaticReference", "PlanResult", "solve_plan", "relative_gap"]

log = logging.getLogger(__name__)

#: Backends of the exact model (``auto``: SCIP).
PLAN_ENGINES: tuple[str, ...] = ("auto", "mip", "cpsat")
_OPT_TOL = 1e-9
#: Largest exact model attempted: coverage nonzeros (before merging rows) and flow arcs.
MODEL_MAX_NONZEROS = 1_500_000
MODEL_MAX_ARCS = 1_000_000
#: Large-neighbourhood search: first "top" poses per phase, and the time limit of one restricted solve.
LNS_FIRST_TOP = 10
LNS_SOLVE_MAX_S = 30.0


def relative_gap(bound: float, objective: float) -> float:
    """``(bound - objective) / max(|bound|, 1e-12)``, never negative (inf without an objective)."""
    if not (math.isfinite(bound) and math.isfinite(objective)):
        return math.inf
    return max(0.0, (bound - objective) / max(abs(bound), 1e-12))


@dataclass(frozen=True)
class StaticReference:
    """A static system to compare with (e.g. the run's ``solution.json``).

    Attributes
    ----------
    candidates : tuple of int
        Its k poses.
    status : str
        The solver's status for it (``optimal``: it is the best static system).
    bound : float
        The solver's upper bound on any static system (same weights and mode).
    source : str
        Where it came from.
    """

    candidates: tuple[int, ...]
    status: str
    bound: float
    source: str = ""


@dataclass(frozen=True, eq=False)
class PlanResult:
    """The chosen plan and how good it provably is.

    Attributes
    ----------
    plan : (k, P) int64 or None
        Candidate column of agent a in phase p (None if no feasible plan was found).
    status : str
        "optimal" | "feasible" | "infeasible" | "unknown".
    objective, bound, gap : float
        Plan value (sum over phases of the mode value), proven upper bound, relative gap.
    phase_objectives, phase_bounds : (P,) float64
        The plan's value per phase, and each phase's optimum (upper bound) ``U_p``.
    unconstrained_objective, unconstrained_bound : float
        Sum of the per-phase optima found / proven (the infinite-speed plan; the bound holds for
        every plan).
    static_objective, static_bound : float
        The best static system's value, and the bound on any static system.
    static_status : str
    static_candidates : tuple of int
    static_feasible : bool
        Whether the static system is a feasible plan (not always with start positions).
    engine : str
        What produced the plan: "unconstrained", "static", "heuristic", "mip" or "cpsat".
    time_s : float
    stats : dict
    """

    plan: np.ndarray | None
    status: str
    objective: float
    bound: float
    gap: float
    phase_objectives: np.ndarray
    phase_bounds: np.ndarray
    unconstrained_objective: float
    unconstrained_bound: float
    static_objective: float
    static_bound: float
    static_status: str
    static_candidates: tuple[int, ...]
    static_feasible: bool
    engine: str
    time_s: float
    stats: dict = field(default_factory=dict)


class _Clock:
    def __init__(self, limit_s: float | None) -> None:
        self.t0 = time.perf_counter()
        self.limit = limit_s

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def remaining(self) -> float | None:
        return None if self.limit is None else max(0.0, self.limit - self.elapsed())

    def expired(self) -> bool:
        return self.limit is not None and self.elapsed() >= self.limit

    def share(self, fraction: float, minimum: float = 0.5) -> float | None:
        rem = self.remaining()
        return None if rem is None else max(minimum, fraction * rem)


def _solve_phase(problem: PlanProblem, p: int, k: int, limit: float | None) -> tuple[tuple[int, ...], float, float, str]:
    """Per-phase optimum with k agents: (poses, value, bound, status)."""
    from camplace.solver.api import solve

    q, w = problem.matrices[p], problem.weights[p]
    if k <= 0:
        return (), 0.0, 0.0, "optimal"
    if q.shape[0] == 0 or not np.any(w > 0):
        return tuple(range(k)), 0.0, 0.0, "optimal"
    res = solve(q, w, k, mode=problem.mode, views=problem.views, time_limit_s=limit)
    sel = tuple(int(j) for j in res.selected)
    value = phase_value(problem, p, sel)
    bound = float(res.bound) if math.isfinite(res.bound) else _all_poses_value(problem, p)
    return sel, value, max(bound, value), res.status


def _all_poses_value(problem: PlanProblem, p: int) -> float:
    """An upper bound on phase p's value: the weight of its rows (quality: times each row's best
    quality; of a binary matrix's bitsets, 1 where some pose observes the row)."""
    q, w = problem.matrices[p], problem.weights[p]
    if problem.mode != "quality":
        return float(w.sum())
    if problem.bits:
        return float((w * (q.row_counts() > 0)).sum())
    return float((w * q.max(axis=1).toarray().ravel()).sum())


def _static(problem: PlanProblem, static: StaticReference | None, limit: float | None) -> StaticReference:
    """The best static system: the given one, or the solver's answer on all rows."""
    import scipy.sparse as sp

    from camplace.solver.api import solve

    if static is not None:
        return static
    if problem.bits:  # the phase blocks stacked as bits (the solver reads a BitMatrix)
        from camplace.visibility.bits import stack_rows

        q = stack_rows(problem.matrices)
    else:
        q = sp.vstack(problem.matrices).tocsr()
    w = np.concatenate(problem.weights)
    res = solve(q, w, problem.k, mode=problem.mode, views=problem.views, time_limit_s=limit)
    return StaticReference(tuple(int(j) for j in res.selected), res.status, float(res.bound), "solved")


def _frozen(problem: PlanProblem) -> bool:
    """No agent can move or re-aim: one pose per position, reach below the closest pair of positions."""
    if problem.start_positions_m is not None or problem.n_phases == 1:
        return False
    if problem.unique_positions.shape[0] != problem.n_candidates:
        return False
    from scipy.spatial import cKDTree

    d, _ = cKDTree(problem.unique_positions).query(problem.unique_positions, k=2)
    closest = float(d[:, 1].min()) if problem.n_candidates > 1 else math.inf
    return all(not within(closest, float(r)) for r in problem.reach_m)


def _unconstrained(problem: PlanProblem, index) -> bool:
    """Every move within reach (every transition, and from every start to every candidate)."""
    if not all(index.covers_all(float(r)) for r in problem.reach_m):
        return False
    if problem.start_positions_m is None:
        return True
    d = np.linalg.norm(problem.positions[:, None, :] - problem.start_positions_m[None, :, :], axis=2)
    return bool(np.all(within(d, problem.start_reach_m)))


def _kept_poses(problem: PlanProblem, incumbent: float, U: np.ndarray, U_less: np.ndarray) -> list[np.ndarray]:
    """Poses that can appear in a plan better than ``incumbent`` (see the module docstring)."""
    total = float(U.sum())
    kept = []
    for p in range(problem.n_phases):
        f = np.minimum(U[p], U_less[p] + single_values(problem, p))
        slack = (total - U[p]) + f - incumbent
        kept.append(np.flatnonzero(slack > _OPT_TOL * max(1.0, abs(incumbent))))
    return kept


def solve_plan(
    problem: PlanProblem,
    *,
    static: StaticReference | None = None,
    engine: str = "auto",
    time_limit_s: float | None = None,
    exact: bool = True,
    heuristic: bool = True,
    max_nonzeros: int = MODEL_MAX_NONZEROS,
    max_arcs: int = MODEL_MAX_ARCS,
) -> PlanResult:
    """Plan the k agents' poses, phase by phase (see the module docstring).

    Parameters
    ----------
    problem : PlanProblem
    static : StaticReference, optional
        The best static system, when known (else solved here on all rows).
    engine : {"auto", "mip", "cpsat"}
        Backend of the exact model (auto: SCIP).
    time_limit_s : float, optional
        Wall-clock limit of the whole planner (the exact model gets what is left).
    exact : bool
        Try the exact model (False: heuristic and bounds only).
    heuristic : bool
        Look for an incumbent before the exact model (False: the exact model alone, over every pose;
        for tests of the model).
    max_nonzeros, max_arcs : int
        Largest exact model attempted (estimated before building).

    Returns
    -------
    PlanResult
    """
    from camplace.plan.heuristic import ReachIndex, agent_ascent, insert_agents, set_sequence_dp

    if engine not in PLAN_ENGINES:
        raise CamplaceError(f"plan engine: unknown {engine!r} (use one of {', '.join(PLAN_ENGINES)})")
    if time_limit_s is not None and not time_limit_s > 0:
        raise CamplaceError(f"time limit: must be > 0 seconds, got {time_limit_s}")
    clock = _Clock(time_limit_s)
    k, P = problem.k, problem.n_phases
    stats: dict[str, Any] = {"phases": P, "k": k, "mode": problem.mode, "candidates": problem.n_candidates,
                             "positions": int(problem.unique_positions.shape[0]),
                             "reach_m": [float(r) for r in problem.reach_m]}
    timings: dict[str, float] = {}

    # 1. per-phase optima
    t0 = time.perf_counter()
    opt_sets, opt_vals, U, phase_status = [], [], np.zeros(P), []
    for p in range(P):
        sel, val, bnd, st = _solve_phase(problem, p, k, clock.share(0.35 / max(1, P - p)))
        opt_sets.append(sel)
        opt_vals.append(val)
        U[p] = bnd
        phase_status.append(st)
    timings["time_phase_optima_s"] = time.perf_counter() - t0
    stats["phase_status"] = phase_status
    unc_obj, unc_bound = float(sum(opt_vals)), float(U.sum())

    # 2. the static system
    t0 = time.perf_counter()
    ref = _static(problem, static, clock.share(0.3))
    timings["time_static_s"] = time.perf_counter() - t0
    if len(set(ref.candidates)) != k or min(ref.candidates, default=0) < 0 or max(ref.candidates, default=0) >= problem.n_candidates:
        raise CamplaceError(f"static system: needs {k} distinct candidate columns in range, got {list(ref.candidates)}")
    static_plan = np.tile(np.asarray(sorted(ref.candidates), dtype=np.int64)[:, None], (1, P))
    static_plan = paths_from_sets(problem, [ref.candidates] * P) if problem.start_positions_m is not None else static_plan
    static_obj = plan_value(problem, np.tile(np.asarray(sorted(ref.candidates))[:, None], (1, P)))
    static_feasible = static_plan is not None and not check_plan(problem, static_plan)
    static_bound = max(float(ref.bound), static_obj) if math.isfinite(ref.bound) else math.inf
    stats["static"] = {"status": ref.status, "source": ref.source}

    index = ReachIndex(problem)

    def finish(plan, engine_name: str, bound: float, status: str | None = None) -> PlanResult:
        timings["time_total_s"] = clock.elapsed()
        stats["timings"] = timings
        if plan is None:
            return PlanResult(None, status or "unknown", -math.inf, bound, math.inf, np.zeros(P), U, unc_obj, unc_bound,
                              static_obj, static_bound, ref.status, tuple(ref.candidates), static_feasible, engine_name,
                              clock.elapsed(), stats)
        problems = check_plan(problem, plan)
        if problems:  # never hand out an infeasible plan
            raise AssertionError("planner produced an infeasible plan: " + "; ".join(problems))
        values = np.array([phase_value(problem, p, plan[:, p]) for p in range(P)])
        obj = float(values.sum())
        bound = max(min(bound, unc_bound), obj)
        gap = relative_gap(bound, obj)
        st = status or ("optimal" if gap <= _OPT_TOL else "feasible")
        if st == "optimal":
            bound, gap = obj, 0.0
        return PlanResult(np.asarray(plan, dtype=np.int64), st, obj, bound, gap, values, U, unc_obj, unc_bound,
                          static_obj, static_bound, ref.status, tuple(ref.candidates), static_feasible, engine_name,
                          clock.elapsed(), stats)

    # 3. shortcuts
    if _unconstrained(problem, index):
        plan = paths_from_sets(problem, opt_sets)
        if plan is not None:
            stats["shortcut"] = "every move within reach: the per-phase optima"
            return finish(plan, "unconstrained", unc_bound)
    if _frozen(problem):
        stats["shortcut"] = "no agent can move or re-aim: the static system"
        return finish(static_plan, "static", min(static_bound, unc_bound))

    # 4. heuristic incumbent
    t0 = time.perf_counter()
    starts: list[tuple[str, np.ndarray]] = []
    if heuristic and static_feasible:
        starts.append(("static", static_plan))
    greedy = insert_agents(problem, index) if heuristic else None
    if greedy is not None:
        starts.append(("insertion", greedy))
    pooled = set_sequence_dp(problem, list(opt_sets) + [ref.candidates]) if heuristic else None
    if pooled is not None:
        starts.append(("set-sequence", pooled))
    best_plan, best_val, best_from = None, -math.inf, ""
    plans_seen = []
    for name, start in starts:
        plan, val = agent_ascent(problem, index, start, expired=lambda: clock.limit is not None and clock.elapsed() > 0.8 * clock.limit)
        plans_seen.append(plan)
        if val > best_val:
            best_plan, best_val, best_from = plan, val, name
    if plans_seen and not clock.expired():  # recombine: pose sets of every plan so far, every phase
        pool = list(opt_sets) + [ref.candidates] + [tuple(pl[:, p]) for pl in plans_seen for p in range(P)]
        mixed = set_sequence_dp(problem, pool, expired=clock.expired)
        if mixed is not None:
            plan, val = agent_ascent(problem, index, mixed, expired=clock.expired)
            if val > best_val:
                best_plan, best_val, best_from = plan, val, "recombined"
    timings["time_heuristic_s"] = time.perf_counter() - t0
    stats["heuristic"] = {"starts": [n for n, _ in starts], "best_from": best_from,
                          "objective": best_val if best_plan is not None else None}
    bound = unc_bound
    if best_plan is None and not exact:
        return finish(None, "heuristic", bound)
    if best_plan is not None and relative_gap(bound, best_val) <= _OPT_TOL:
        return finish(best_plan, "heuristic", bound)
    if not exact:
        return finish(best_plan, "heuristic", bound)

    # 5. exact model over the poses that can still improve
    t0 = time.perf_counter()
    incumbent = best_val if best_plan is not None else -math.inf
    every = [np.arange(problem.n_candidates) for _ in range(P)]
    kept, size = every, flow_model_size(problem, every)
    fits = size["coverage_nonzeros"] <= max_nonzeros and size["flow_arcs"] <= max_arcs
    rem = clock.remaining()
    # prune by the per-pose bounds F_p(j): needs each phase's optimum with k - 1 agents, which the
    # multiview engines do not give within short time limits (and their bound is weak there)
    if not fits and math.isfinite(incumbent) and problem.mode != "multiview" and (rem is None or rem > 0.5 * float(clock.limit)):
        U_less = np.zeros(P)
        if k > 1:
            for p in range(P):
                _, _, U_less[p], _ = _solve_phase(problem, p, k - 1, clock.share(0.05 / max(1, P - p), minimum=0.2))
        kept = _kept_poses(problem, incumbent, U, U_less)
        stats["kept_poses"] = [int(kp.size) for kp in kept]
        if any(kp.size < k for kp in kept):
            # some phase cannot hold k poses of an improving plan: the incumbent is optimal
            stats["exact"] = "no plan can beat the incumbent (a phase keeps fewer than k poses)"
            timings["time_prune_s"] = time.perf_counter() - t0
            return finish(best_plan, "heuristic", incumbent, "optimal")
        size = flow_model_size(problem, kept)
    timings["time_prune_s"] = time.perf_counter() - t0
    stats["model_size"] = size
    backend = "mip" if engine == "auto" else engine
    if size["coverage_nonzeros"] > max_nonzeros or size["flow_arcs"] > max_arcs:
        stats["exact"] = (f"skipped: the model would have {size['coverage_nonzeros']:,} coverage nonzeros and "
                          f"{size['flow_arcs']:,} flow arcs (limits {max_nonzeros:,}, {max_arcs:,}); bound = sum of per-phase optima")
        log.info("plan: %s", stats["exact"])
        name = "heuristic"
        if best_plan is not None and heuristic and not clock.expired():
            t0 = time.perf_counter()
            extra = list(opt_sets) + [ref.candidates]
            plan, val, rounds = _lns(problem, index, best_plan, best_val, extra, U, backend, clock, max_nonzeros, max_arcs)
            timings["time_lns_s"] = time.perf_counter() - t0
            stats["lns"] = rounds
            if val > best_val:
                best_plan, best_val, name = plan, val, "lns"
        return finish(best_plan, name, bound)
    if clock.expired():
        stats["exact"] = "skipped: no time left"
        return finish(best_plan, "heuristic", bound)
    return _exact(problem, kept, U, best_plan, incumbent, backend, clock, stats, timings, finish)


def _lns(problem, index, plan, value, extra_sets, U, backend, clock, max_nonzeros, max_arcs):
    """Large-neighbourhood search: the exact model restricted to poses around the plan, re-solved
    while it improves (the neighbourhood doubles when its optimum is the plan itself).

    Returns (plan, objective, rounds); no bound (a restricted model bounds nothing).
    """
    from camplace.plan.heuristic import agent_ascent, neighbourhood
    from camplace.solver._support.deadline import Deadline
    from camplace.solver.engines.mip.linear import solve_model

    top, rounds = LNS_FIRST_TOP, []
    while not clock.expired():
        kept = neighbourhood(problem, plan, extra_sets, top)
        size = flow_model_size(problem, kept)
        if size["coverage_nonzeros"] > max_nonzeros or size["flow_arcs"] > max_arcs:
            break
        fm = build_flow_model(problem, kept, U)
        rem = clock.remaining()
        out = solve_model(fm.model, backend, deadline=Deadline(LNS_SOLVE_MAX_S if rem is None else min(rem, LNS_SOLVE_MAX_S)),
                          hint=_hint(fm, plan))
        found = None
        if out.values is not None:
            found = paths_from_sets(problem, [fm.kept[p][out.values[fm.x[p]] > 0.5] for p in range(problem.n_phases)])
        val = plan_value(problem, found) if found is not None else -math.inf
        improved = val > value * (1 + 1e-12) + 1e-15
        rounds.append({"top": top, "poses": int(sum(kp.size for kp in kept)), "status": out.status, "objective": val,
                       "improved": bool(improved)})
        if improved:
            plan, value = agent_ascent(problem, index, found, expired=clock.expired)
        elif out.status == "optimal":
            top *= 2
        else:
            break
    return plan, value, rounds


def _hint(fm, plan) -> dict[int, float] | None:
    """The plan as a solver hint on the model's pose variables."""
    if plan is None:
        return None
    hint = {}
    for p in range(len(fm.kept)):
        chosen = set(int(j) for j in plan[:, p])
        for j, var in zip(fm.kept[p].tolist(), fm.x[p].tolist()):
            hint[var] = 1.0 if j in chosen else 0.0
    return hint


def _exact(problem, kept, U, best_plan, incumbent, backend, clock, stats, timings, finish) -> PlanResult:
    """Solve the flow model; combine its answer and bound with the incumbent."""
    from camplace.solver._support.deadline import Deadline
    from camplace.solver.engines.mip.linear import solve_model

    t0 = time.perf_counter()
    fm = build_flow_model(problem, kept, U)
    timings["time_model_build_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = solve_model(fm.model, backend, deadline=Deadline(clock.remaining()), hint=_hint(fm, best_plan))
    timings["time_model_solve_s"] = time.perf_counter() - t0
    stats["exact"] = {"backend": backend, "status": out.status, **fm.stats,
                      **{k: v for k, v in out.stats.items() if not str(k).startswith("time")}}
    plan, engine_name = best_plan, "heuristic"
    matched = False
    if out.values is not None:
        sets = [tuple(int(j) for j in fm.kept[p][out.values[fm.x[p]] > 0.5]) for p in range(problem.n_phases)]
        found = paths_from_sets(problem, sets)
        if found is not None:
            matched = True
            val = plan_value(problem, found)
            if plan is None or val > incumbent:
                plan, engine_name = found, backend
        else:
            log.warning("plan: the %s answer could not be matched into agent paths (ignored)", backend)
    if out.status == "infeasible":
        # no plan over the kept poses at all: nothing beats the incumbent
        return finish(plan, engine_name, incumbent if plan is not None else -math.inf,
                      "optimal" if plan is not None else "infeasible")
    if out.status == "optimal" and matched:
        # the model's optimum over every pose that could beat the incumbent, or the incumbent
        return finish(plan, engine_name, -math.inf, "optimal")
    bound = max(incumbent, out.bound * fm.scale) if math.isfinite(out.bound) else float(U.sum())
    return finish(plan, engine_name, bound)
