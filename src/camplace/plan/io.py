"""Plan files: reading a run folder, writing ``plan.json`` / ``plan.csv`` / light curves, reading them back.

Files written into the run folder (or ``-o``):

``plan.json``
    ``status``, ``objective``, ``bound``, ``gap``, ``static_objective``, ``unconstrained_bound``,
    ``speed_m_s``, ``phases`` (``{index, frames, start_s, end_s}``), ``agents`` (``{agent,
    candidates}``, one candidate column per phase in phase order), and the details: ``mode``,
    ``views``, ``k``, ``engine``, ``phase_objectives``, ``phase_bounds``, ``reach_m``,
    ``unconstrained_objective``, ``static_bound``, ``static_status``, ``static_candidates``,
    ``static_feasible``, start positions, ``stats``, ``timings_s``, ``options``.
``plan.csv``
    One row per agent and phase: ``agent,phase,candidate,x,y,z,aim_x,aim_y,aim_z,start_s,end_s,travel_m``
    (``travel_m``: distance from the agent's previous pose, or from its start position, 0 without).
``plan_light_curves.csv``
    Per agent and frame: ``agent,frame,phase,candidate,observed_weight,observed_fraction,time_s``
    (the weight the agent's pose of that frame's phase observes alone; fraction of the frame's weight).
``plan_timeline.csv``
    Per frame: ``frame,time_s,phase,frame_weight,plan_value,static_value`` (the frame's share of
    the objective, plan and static system).

Objective convention: the weights of ``points.csv`` (all frames together sum to 1), so the plan's
``objective`` and the static run's ``objective`` are on one scale.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace._io import read_json, write_json_atomic, write_text_atomic
from camplace.errors import CamplaceError, plural
from camplace.plan.phases import Phase
from camplace.runfolder import RunFolder

__all__ = [
    "RunFolder",
    "load_run_folder",
    "plan_matrix",
    "plan_document",
    "plan_csv",
    "light_curves_csv",
    "timeline_csv",
    "write_plan",
    "load_plan",
    "phase_camera_records",
    "PLAN_FILES",
]

PLAN_FILES = ("plan.json", "plan.csv", "plan_light_curves.csv", "plan_timeline.csv")


def load_run_folder(outdir: str | Path) -> RunFolder:
    """A run folder (:class:`camplace.RunFolder`) with every file the planner reads checked.

    Reads instance.toml, solution.json, candidates.csv, points.csv and the matrix (visibility.cpm
    or .npz); the planner uses ``solution_record``, ``instance``, ``candidates``, ``matrix``,
    ``points``.

    Raises
    ------
    CamplaceError
        When a file is missing or the sizes disagree.
    """
    run = RunFolder(outdir)
    run.solution_record  # noqa: B018  (solution.json first: the clearest error for a wrong folder)
    instance = run.instance
    matrix = plan_matrix(run)
    if len(run.candidates) != matrix.shape[1]:
        raise CamplaceError(f"{run.file('candidates.csv')}: {len(run.candidates)} candidates but the matrix has "
                            f"{matrix.shape[1]} columns (re-run)")
    points = run.points
    if len(points) != matrix.shape[0]:
        raise CamplaceError(f"{run.path}: {run.matrix_path.name} has {matrix.shape[0]} rows but points.csv "
                            f"has {len(points)} (re-run)")
    if points.frame.size and int(points.frame.max()) >= len(instance.frames):
        raise CamplaceError(f"{run.file('points.csv')}: frame {int(points.frame.max())} but the instance has "
                            f"{plural(len(instance.frames), 'frame')} (re-run)")
    return run


def _colbits(run) -> bool:
    """Whether the run's matrix is stored as column bitsets (a binary run's ``colbits`` .cpm)."""
    path = run.matrix_path
    if path.suffix != ".cpm" or not path.is_file():
        return False
    from camplace.visibility.store import describe

    return describe(path).get("structure") == "colbits"


def plan_matrix(run):
    """The matrix the planner reads: a binary run's column bitsets as they are stored
    (:class:`camplace.visibility.bits.BitMatrix`, ``m * n / 8`` bytes, no CSR copy), any other
    run's CSR matrix (``run.matrix``). Read once per run folder object."""
    if "_plan_matrix" not in run.__dict__:
        if _colbits(run):
            from camplace.visibility.store import load_bits

            run.__dict__["_plan_matrix"] = load_bits(run.matrix_path)
        else:
            run.__dict__["_plan_matrix"] = run.matrix
    return run.__dict__["_plan_matrix"]


def _f(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def plan_document(result, *, phases: Sequence[Phase], speed_m_s: float, problem, instance_name: str = "",
                  start_time_s: float | None = None, options: dict | None = None) -> dict[str, Any]:
    """The content of ``plan.json`` for a :class:`~camplace.plan.planner.PlanResult`."""
    from camplace.solver.result import jsonable

    stats = dict(result.stats)
    timings = stats.pop("timings", {})
    agents = [] if result.plan is None else [
        {"agent": int(a), "candidates": [int(j) for j in result.plan[a]]} for a in range(result.plan.shape[0])]
    return {
        "status": result.status,
        "objective": _f(result.objective),
        "bound": _f(result.bound),
        "gap": _f(result.gap),
        "static_objective": _f(result.static_objective),
        "unconstrained_bound": _f(result.unconstrained_bound),
        "speed_m_s": float(speed_m_s),
        "phases": [ph.to_dict() for ph in phases],
        "agents": agents,
        "mode": problem.mode,
        "views": int(problem.views) if problem.mode == "multiview" else None,
        "k": int(problem.k),
        "engine": result.engine,
        "time_s": float(result.time_s),
        "phase_objectives": [float(v) for v in result.phase_objectives],
        "phase_bounds": [float(v) for v in result.phase_bounds],
        "reach_m": [_f(r) for r in problem.reach_m],
        "unconstrained_objective": _f(result.unconstrained_objective),
        "static_bound": _f(result.static_bound),
        "static_status": result.static_status,
        "static_candidates": [int(j) for j in result.static_candidates],
        "static_feasible": bool(result.static_feasible),
        "start_positions_m": None if problem.start_positions_m is None else problem.start_positions_m.tolist(),
        "start_time_s": None if problem.start_positions_m is None else _f(start_time_s if start_time_s is not None else math.nan),
        "start_reach_m": None if problem.start_positions_m is None else _f(problem.start_reach_m),
        "instance": instance_name,
        "n_candidates": int(problem.n_candidates),
        "n_points": int(sum(m.shape[0] for m in problem.matrices)),
        "stats": jsonable(stats),
        "timings_s": jsonable(timings),
        "options": jsonable(options or {}),
    }


def plan_csv(plan: np.ndarray, phases: Sequence[Phase], candidates, start_positions_m: np.ndarray | None = None) -> str:
    """``plan.csv`` text (see the module docstring)."""
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(["agent", "phase", "candidate", "x", "y", "z", "aim_x", "aim_y", "aim_z", "start_s", "end_s", "travel_m"])
    pos, aims = candidates.positions, candidates.aims
    for a in range(plan.shape[0]):
        for p, ph in enumerate(phases):
            j = int(plan[a, p])
            if p > 0:
                travel = float(np.linalg.norm(pos[j] - pos[int(plan[a, p - 1])]))
            elif start_positions_m is not None:
                travel = float(np.linalg.norm(pos[j] - start_positions_m[a]))
            else:
                travel = 0.0
            wr.writerow([a, p, j, *map(repr, map(float, pos[j])), *map(repr, map(float, aims[j])),
                         repr(float(ph.start_s)), repr(float(ph.end_s)), repr(travel)])
    return buf.getvalue()


def light_curves_csv(plan: np.ndarray, phases: Sequence[Phase], matrix, points, frame_times_s: Sequence[float]) -> str:
    """``plan_light_curves.csv`` text: what each agent's pose observes alone, frame by frame.

    ``matrix``: the run's (m, n) CSR matrix, or a binary run's column bitsets (BitMatrix).
    """
    n_frames = len(frame_times_s)
    frame = np.asarray(points.frame, dtype=np.int64)
    w = np.asarray(points.weight, dtype=np.float64)
    frame_total = np.bincount(frame, weights=w, minlength=n_frames)
    bits = getattr(matrix, "format", None) == "bits"  # column bitsets: a column's rows unpacked, no CSC copy
    csc = None if bits else matrix.tocsc()
    lines = ["agent,frame,phase,candidate,observed_weight,observed_fraction,time_s"]
    for a in range(plan.shape[0]):
        for ph in phases:
            j = int(plan[a, ph.index])
            rows = np.flatnonzero(matrix.column(j)) if bits else csc.indices[csc.indptr[j]:csc.indptr[j + 1]]
            seen = np.bincount(frame[rows], weights=w[rows], minlength=n_frames)
            for f in ph.frames:
                frac = seen[f] / frame_total[f] if frame_total[f] > 0 else 0.0
                lines.append(f"{a},{f},{ph.index},{j},{float(seen[f])!r},{float(frac)!r},{float(frame_times_s[f])!r}")
    return "\n".join(lines) + "\n"


def frame_values(matrix, points, sets_by_phase: Sequence[Sequence[int]], phases: Sequence[Phase], mode: str,
                 views: int, n_frames: int) -> np.ndarray:
    """(n_frames,) float64: each frame's share of the objective when phase p holds ``sets_by_phase[p]``."""
    from camplace.plan.model import row_values

    frame = np.asarray(points.frame, dtype=np.int64)
    w = np.asarray(points.weight, dtype=np.float64)
    out = np.zeros(n_frames)
    for ph in phases:
        rows = np.flatnonzero(np.isin(frame, ph.frames))
        vals = row_values(_rows_of(matrix, rows), w[rows], sets_by_phase[ph.index], mode, views)
        out += np.bincount(frame[rows], weights=vals, minlength=n_frames)
    return out


def _rows_of(matrix, rows: np.ndarray):
    """The rows ``rows`` of a CSR matrix, or of column bitsets as bitsets (no CSR copy)."""
    if getattr(matrix, "format", None) == "bits":
        from camplace.visibility.bits import take_rows

        return take_rows(matrix, rows)
    return matrix[rows].tocsr()


def timeline_csv(plan: np.ndarray, static: Sequence[int], phases: Sequence[Phase], matrix, points, mode: str, views: int,
                 frame_times_s: Sequence[float]) -> str:
    """``plan_timeline.csv`` text: per frame, its weight and its share of the plan's and the static system's objective."""
    n_frames = len(frame_times_s)
    frame = np.asarray(points.frame, dtype=np.int64)
    fw = np.bincount(frame, weights=np.asarray(points.weight, dtype=np.float64), minlength=n_frames)
    pv = frame_values(matrix, points, [plan[:, p] for p in range(plan.shape[1])], phases, mode, views, n_frames)
    sv = frame_values(matrix, points, [list(static)] * len(phases), phases, mode, views, n_frames)
    owner = {f: ph.index for ph in phases for f in ph.frames}
    lines = ["frame,time_s,phase,frame_weight,plan_value,static_value"]
    for f in range(n_frames):
        lines.append(f"{f},{float(frame_times_s[f])!r},{owner[f]},{float(fw[f])!r},{float(pv[f])!r},{float(sv[f])!r}")
    return "\n".join(lines) + "\n"


def write_plan(out: str | Path, doc: dict, files: dict[str, str]) -> list[Path]:
    """Write the CSV texts of ``files`` ({name: text}) then ``plan.json`` (last: its presence means complete)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in files.items():
        write_text_atomic(out / name, text)
        written.append(out / name)
    write_json_atomic(out / "plan.json", doc)
    return [*written, out / "plan.json"]


def load_plan(path: str | Path) -> dict[str, Any]:
    """Read ``plan.json`` (or the folder holding it) and check its shape.

    Returns
    -------
    dict
        The document; ``agents`` hold one candidate per phase.
    """
    doc = read_json(path, "plan.json", "plan")
    src = Path(path) / "plan.json" if Path(path).is_dir() else Path(path)
    for key in ("status", "objective", "phases", "agents", "speed_m_s"):
        if key not in doc:
            raise CamplaceError(f"{src}: missing key {key!r} (re-run 'camplace plan')")
    n = len(doc["phases"])
    for ag in doc["agents"]:
        if len(ag.get("candidates", [])) != n:
            raise CamplaceError(f"{src}: agent {ag.get('agent')} has {len(ag.get('candidates', []))} poses for {n} phases")
    return doc


def phase_camera_records(outdir: str | Path, phase: int) -> tuple[list[dict], list[int], dict]:
    """The plan's cameras in phase ``phase``, as ``solution.json`` camera records, and that phase's frames.

    Parameters
    ----------
    outdir : path
        A run folder holding ``plan.json``.
    phase : int

    Returns
    -------
    records : list of dict
        ``candidate, position, aim, rotation, K, width, height, near_m, far_m, agent`` per agent.
    frames : list of int
    doc : dict
        The plan document.
    """
    outdir = Path(outdir)
    if not (outdir / "plan.json").is_file():
        raise CamplaceError(f"--phase: {outdir} has no plan.json (make one: camplace plan {outdir} --phases N --speed M_S)")
    doc = load_plan(outdir)
    n = len(doc["phases"])
    if isinstance(phase, bool) or not 0 <= int(phase) < n:
        raise CamplaceError(f"--phase: the plan has phases 0..{n - 1}, got {phase}")
    if not doc["agents"]:
        raise CamplaceError(f"{outdir / 'plan.json'}: the plan has no agents (status {doc['status']})")
    run = RunFolder(outdir)
    instance, cands = run.instance, run.candidates
    from camplace.solution import camera_record

    records = []
    for ag in doc["agents"]:
        j = int(ag["candidates"][int(phase)])
        if not 0 <= j < len(cands):
            raise CamplaceError(f"{outdir / 'plan.json'}: candidate {j} out of range of candidates.csv (re-run the plan)")
        # the same record as solution.json's (a team's column: its model's intrinsics and name)
        records.append({**camera_record(instance, cands, j), "agent": int(ag["agent"])})
    return records, [int(f) for f in doc["phases"][int(phase)]["frames"]], doc


def phase_solution(outdir: str | Path, solution, phase: int):
    """A run's ``Solution`` with its cameras replaced by the plan's poses of ``phase`` (render, export).

    Returns
    -------
    solution : same type as ``solution``
        ``cameras`` are the agents' poses in that phase (agent order); ``objective`` that phase's value.
    frames : list of int
        The phase's frames.
    """
    import dataclasses

    records, frames, doc = phase_camera_records(outdir, phase)
    changes: dict[str, Any] = {"cameras": records}
    values = doc.get("phase_objectives") or []
    if int(phase) < len(values) and hasattr(solution, "objective"):
        changes["objective"] = float(values[int(phase)])
    if hasattr(solution, "status"):
        changes["status"] = str(doc.get("status", getattr(solution, "status", "")))
    return dataclasses.replace(solution, **changes), frames
