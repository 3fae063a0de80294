"""A plan for a run folder: settings (command line over the instance's ``[agents]``), solve, write.

Used by ``camplace plan OUTDIR`` and ``camplace run ... --phases N --speed M_S``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace.errors import CamplaceError
from camplace.plan.phases import phase_of_frame, reach_m, split_phases, start_reach_m

__all__ = ["AgentSettings", "agent_settings", "static_from_solution", "plan_run_folder"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AgentSettings:
    """The resolved agent settings of one plan.

    Attributes
    ----------
    phases : tuple of Phase
    speed_m_s : float
    reach_m : (P - 1,) float64
    start_positions_m : (k, 3) float64 or None
    start_time_s : float or None
    start_reach_m : float
    """

    phases: tuple
    speed_m_s: float
    reach_m: np.ndarray
    start_positions_m: np.ndarray | None
    start_time_s: float | None
    start_reach_m: float


def agent_settings(
    instance,
    k: int,
    *,
    phases: int | None = None,
    phase_starts_s: Sequence[float] | None = None,
    speed_m_s: float | None = None,
    start_positions_m: Any = None,
    start_time_s: float | None = None,
) -> AgentSettings:
    """Command-line values where given, else the instance's ``[agents]`` table.

    Raises
    ------
    CamplaceError
        When the phases or the speed are given nowhere, or do not fit the event.
    """
    spec = getattr(instance, "agents", None)
    src = f"{instance.source}: [agents]" if spec is not None else "the command line"
    if phases is not None and phase_starts_s is not None:
        raise CamplaceError("--phases and --phase-starts: give one of them")
    if phases is None and phase_starts_s is None and spec is not None:
        phases, phase_starts_s = spec.phases, spec.phase_starts_s
    if phases is None and phase_starts_s is None:
        raise CamplaceError("--phases: how many phases? (give --phases N, --phase-starts T0,T1,..., or an [agents] table)")
    if speed_m_s is None:
        if spec is None:
            raise CamplaceError("--speed: how fast can the agents travel, m/s? (give --speed M_S or [agents] speed_m_s)")
        speed_m_s = spec.speed_m_s
    if not (speed_m_s >= 0):
        raise CamplaceError(f"--speed: must be >= 0 m/s, got {speed_m_s}")
    times = [f.time_s for f in instance.frames]
    field = "--phases" if phases is not None else "--phase-starts"
    ph = split_phases(times, phases, phase_starts_s, field=field if spec is None else f"{src} / {field}")
    if start_positions_m is None and spec is not None and spec.start_positions_m is not None:
        start_positions_m = spec.start_positions_m
        if start_time_s is None:
            start_time_s = spec.start_time_s
    start = None
    t_start, r_start = None, math.inf
    if start_positions_m is None and start_time_s is not None:
        raise CamplaceError("--start-time: needs start positions (--start-positions or [agents] start_positions_m)")
    if start_positions_m is not None:
        start = np.asarray(start_positions_m, dtype=np.float64)
        if start.shape != (k, 3) or not np.all(np.isfinite(start)):
            raise CamplaceError(f"start positions: need one [x, y, z] per agent (k = {k}), got {start.shape[0] if start.ndim else 0}")
        t_start, r_start = start_reach_m(ph, float(speed_m_s), start_time_s)
    return AgentSettings(ph, float(speed_m_s), reach_m(ph, float(speed_m_s)), start, t_start, r_start)


def static_from_solution(solution: dict, mode: str, k: int, views: int):
    """The run's own system as the static reference, when it answered the same question.

    Same mode (and views), same k, all frames weighted (event mode ``all``), no fixed, forbidden,
    minimum distance or angle: then ``solution.json``'s cameras are the best static system (when
    its status is optimal). Otherwise None (the planner solves the static problem itself).
    """
    from camplace.plan.planner import StaticReference

    opts = solution.get("options") or {}
    cams = solution.get("cameras") or []
    same = (
        solution.get("mode", "maxcover") == mode
        and (mode != "multiview" or opts.get("views") == views)
        and len(cams) == k
        and (solution.get("event_mode", "all") or "all") == "all"
        and not opts.get("fixed") and not opts.get("forbidden")
        and opts.get("min_distance_m") is None and opts.get("min_angle_deg") is None
        and solution.get("status") in ("optimal", "feasible")
    )
    if not same:
        return None
    bound = solution.get("bound")
    return StaticReference(tuple(int(c["candidate"]) for c in cams), str(solution["status"]),
                           float(bound) if bound is not None else math.inf, "solution.json")


def plan_run_folder(
    outdir: str | Path,
    *,
    phases: int | None = None,
    phase_starts_s: Sequence[float] | None = None,
    speed_m_s: float | None = None,
    start_positions_m: Any = None,
    start_time_s: float | None = None,
    mode: str | None = None,
    views: int | None = None,
    k: int | None = None,
    engine: str = "auto",
    time_limit_s: float | None = None,
    out: str | Path | None = None,
    exact: bool = True,
):
    """Plan moving agents on a run folder and write plan.json, plan.csv, plan_light_curves.csv, plan_timeline.csv.

    Parameters
    ----------
    outdir : path
        A ``camplace run`` output folder.
    phases, phase_starts_s, speed_m_s, start_positions_m, start_time_s : optional
        Agent settings (default: the instance's ``[agents]`` table).
    mode, views, k : optional
        Default: the run's (mode maxcover when the run's mode has no plan).
    engine : {"auto", "mip", "cpsat"}
    time_limit_s : float, optional
        Default: the instance's ``run.time_limit_s``.
    out : path, optional
        Folder for the plan files (default ``outdir``).
    exact : bool

    Returns
    -------
    (PlanResult, dict)
        The result and the ``plan.json`` document.
    """
    from camplace.plan.io import (
        light_curves_csv,
        load_run_folder,
        plan_csv,
        plan_document,
        plan_matrix,
        timeline_csv,
        write_plan,
    )
    from camplace.plan.model import PLAN_MODES, make_problem
    from camplace.plan.planner import solve_plan

    run = load_run_folder(outdir)
    sol = run.solution_record
    opts = sol.get("options") or {}
    if mode is None:
        mode = sol.get("mode", "maxcover") if sol.get("mode", "maxcover") in PLAN_MODES else "maxcover"
    if mode not in PLAN_MODES:
        raise CamplaceError(f"--mode: {mode} has no moving-agents plan (use one of {', '.join(PLAN_MODES)})")
    if views is None:
        views = int(opts.get("views") or 2)
    if k is None:
        k = opts.get("k") if isinstance(opts.get("k"), int) else len(sol.get("cameras") or [])
        if not k:
            k = run.instance.k
    if time_limit_s is None:
        time_limit_s = float(run.instance.defaults.time_limit_s)
    settings = agent_settings(run.instance, int(k), phases=phases, phase_starts_s=phase_starts_s, speed_m_s=speed_m_s,
                              start_positions_m=start_positions_m, start_time_s=start_time_s)
    n_frames = len(run.instance.frames)
    row_phase = phase_of_frame(settings.phases, n_frames)[np.asarray(run.points.frame, dtype=np.int64)]
    matrix = plan_matrix(run)  # a binary run's column bitsets, else its CSR matrix
    problem = make_problem(matrix, run.points.weight, row_phase, run.candidates.positions, int(k), mode=mode,
                           views=int(views), reach_m=settings.reach_m, start_positions_m=settings.start_positions_m,
                           start_reach_m=settings.start_reach_m)
    static = static_from_solution(sol, mode, int(k), int(views))
    result = solve_plan(problem, static=static, engine=engine, time_limit_s=time_limit_s, exact=exact)
    options = {"phases": phases, "phase_starts_s": None if phase_starts_s is None else [float(t) for t in phase_starts_s],
               "speed_m_s": speed_m_s, "mode": mode, "views": views, "k": int(k), "engine": engine,
               "time_limit_s": time_limit_s, "exact": exact, "source": str(outdir)}
    doc = plan_document(result, phases=settings.phases, speed_m_s=settings.speed_m_s, problem=problem,
                        instance_name=run.instance.name, start_time_s=settings.start_time_s, options=options)
    files = {}
    if result.plan is not None:
        times = [f.time_s for f in run.instance.frames]
        files = {
            "plan.csv": plan_csv(result.plan, settings.phases, run.candidates, settings.start_positions_m),
            "plan_light_curves.csv": light_curves_csv(result.plan, settings.phases, matrix, run.points, times),
            "plan_timeline.csv": timeline_csv(result.plan, result.static_candidates, settings.phases, matrix, run.points,
                                              mode, int(views), times),
        }
    dest = Path(out) if out is not None else Path(outdir)
    if result.plan is None:  # no plan: no CSVs of an earlier plan left beside this plan.json
        for name in ("plan.csv", "plan_light_curves.csv", "plan_timeline.csv"):
            (dest / name).unlink(missing_ok=True)
    write_plan(dest, doc, files)
    return result, doc
