"""The ``plan`` verb (moving agents on a run folder), and the agent options of ``camplace run``.

Imports nothing heavy at module level (numpy, scipy and OR-Tools load when a verb runs).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Callable

from camplace.errors import CamplaceError, EXIT_OK, EXIT_NO_SOLUTION, plural


PLAN_MODES = ("maxcover", "quality", "multiview")  # camplace.plan.model.PLAN_MODES (no numpy import here)
PLAN_ENGINES = ("auto", "mip", "cpsat")


def add_agent_options(p: argparse.ArgumentParser, *, for_run: bool = False) -> None:
    """Options of the agents' movement (``camplace run`` and ``camplace plan``)."""
    g = p.add_argument_group("moving agents" + (" (plan after the run; default: the instance's [agents] table)" if for_run else ""))
    g.add_argument("--phases", type=int, default=None, help="split the event into N phases of about equal duration")
    g.add_argument("--phase-starts", default=None, dest="phase_starts", metavar="T0,T1,...",
                   help="phase start times in seconds instead of --phases")
    g.add_argument("--speed", type=float, default=None, metavar="M_S", help="agent travel speed, m/s (straight line between phase starts)")
    g.add_argument("--start-positions", default=None, dest="start_positions", metavar="X,Y,Z;X,Y,Z;...",
                   help="where the k agents stand before the event (one x,y,z per agent, ';'-separated)")
    g.add_argument("--start-time", type=float, default=None, dest="start_time",
                   help="when they stand there, s (default: one phase duration before the first phase)")
    if for_run:
        g.add_argument("--plan-time-limit", type=float, default=None, dest="plan_time_limit",
                       help="planner time limit, s (default: --time-limit)")


def register(subparsers, add_run_options: Callable[[argparse.ArgumentParser], None]) -> dict[str, Callable[[argparse.Namespace], int]]:
    """Add the ``plan`` verb to ``subparsers``; returns {verb: handler}."""
    p = subparsers.add_parser("plan", help="agents that move: one pose set per event phase, within the agents' travel speed")
    p.add_argument("outdir", type=Path, help="output folder of 'camplace run'")
    add_agent_options(p)
    p.add_argument("--mode", choices=PLAN_MODES, default=None, help="formulation per phase (default: the run's, maxcover if it has no plan)")
    p.add_argument("--views", type=int, default=None, help="multiview: cameras that must observe a point (default: the run's, else 2)")
    p.add_argument("--k", type=int, default=None, help="number of agents (default: the run's k)")
    p.add_argument("--engine", choices=PLAN_ENGINES, default="auto", help="backend of the exact model (default auto = SCIP)")
    p.add_argument("--time-limit", type=float, default=None, dest="time_limit", help="time limit, s (default: the instance's)")
    p.add_argument("--no-exact", action="store_false", dest="exact", help="heuristic and bounds only (no exact model)")
    p.add_argument("-o", "--out", type=Path, default=None, help="folder for plan.json and the CSVs (default OUTDIR)")
    return {"plan": _cmd_plan}


def parse_times(text: str | None, name: str) -> list[float] | None:
    """``"0,6,12"`` -> ``[0.0, 6.0, 12.0]``; None -> None."""
    if text is None:
        return None
    try:
        out = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise CamplaceError(f"{name}: expected comma-separated times in seconds, got {text!r}") from None
    if not out:
        raise CamplaceError(f"{name}: give at least one time")
    return out


def parse_positions(text: str | None, name: str = "--start-positions") -> list[list[float]] | None:
    """``"1,2,3;4,5,6"`` -> ``[[1, 2, 3], [4, 5, 6]]``; None -> None."""
    if text is None:
        return None
    rows = []
    for part in text.split(";"):
        if not part.strip():
            continue
        try:
            xyz = [float(x) for x in part.split(",")]
        except ValueError:
            raise CamplaceError(f"{name}: expected x,y,z;x,y,z;... in metres, got {part!r}") from None
        if len(xyz) != 3 or not all(math.isfinite(v) for v in xyz):
            raise CamplaceError(f"{name}: each position needs 3 finite numbers x,y,z, got {part!r}")
        rows.append(xyz)
    if not rows:
        raise CamplaceError(f"{name}: give one x,y,z per agent")
    return rows


def _check(args: argparse.Namespace) -> None:
    if args.phases is not None and args.phases < 1:
        raise CamplaceError(f"--phases: must be >= 1, got {args.phases}")
    if args.speed is not None and not args.speed >= 0:
        raise CamplaceError(f"--speed: must be >= 0 m/s, got {args.speed}")
    for name in ("time_limit", "plan_time_limit"):
        v = getattr(args, name, None)
        if v is not None and not v > 0:
            raise CamplaceError(f"--{name.replace('_', '-')}: must be > 0 seconds, got {v}")


def plan_requested(args: argparse.Namespace, instance) -> bool:
    """``camplace run`` plans when an agent option is given or the instance has an ``[agents]`` table."""
    given = any(getattr(args, n, None) is not None for n in ("phases", "phase_starts", "speed", "start_positions"))
    return given or getattr(instance, "agents", None) is not None


def check_agent_options(args: argparse.Namespace, instance) -> None:
    """``camplace run``: reject bad agent options before the run's work (the phases need the instance's frames)."""
    if not plan_requested(args, instance):
        return
    from camplace.plan.workflow import agent_settings

    _check(args)
    k = args.k if getattr(args, "k", None) is not None else instance.k
    agent_settings(instance, int(k), phases=args.phases, phase_starts_s=parse_times(args.phase_starts, "--phase-starts"),
                   speed_m_s=args.speed, start_positions_m=parse_positions(args.start_positions), start_time_s=args.start_time)


def _print(result, doc: dict, out: Path) -> None:
    if result.plan is None:
        print(f"{result.status}: no feasible plan (the agents cannot reach their first poses? check the start positions)")
        return
    gain = result.objective - result.static_objective
    rel = f" ({100 * gain / result.static_objective:+.2f}%)" if result.static_objective > 0 else ""
    print(f"{result.status}: {plural(doc['k'], 'agent')} over {plural(len(doc['phases']), 'phase')} at {doc['speed_m_s']:g} m/s: "
          f"{doc['mode']} objective {result.objective:.6f}, bound {result.bound:.6f}, gap {100 * result.gap:.3f}% "
          f"({result.engine}, {result.time_s:.1f} s)")
    print(f"  static system {result.static_objective:.6f} ({result.static_status}); plan {gain:+.6f}{rel}; "
          f"sum of per-phase optima {result.unconstrained_bound:.6f}")
    for ag in doc["agents"]:
        print(f"  agent {ag['agent']}: candidates {' -> '.join(str(j) for j in ag['candidates'])}")
    from camplace.plan.io import PLAN_FILES

    print(f"wrote {out}/{', '.join(PLAN_FILES)}")


def run_plan(args: argparse.Namespace, outdir: Path, *, time_limit: float | None, k: int | None = None,
             mode: str | None = None, views: int | None = None, engine: str = "auto", exact: bool = True,
             out: Path | None = None) -> int:
    """Plan on a run folder with the agent options of ``args``; prints a summary; returns the exit code."""
    from camplace.plan.workflow import plan_run_folder

    _check(args)
    result, doc = plan_run_folder(
        outdir, phases=args.phases, phase_starts_s=parse_times(args.phase_starts, "--phase-starts"), speed_m_s=args.speed,
        start_positions_m=parse_positions(args.start_positions), start_time_s=args.start_time, mode=mode, views=views, k=k,
        engine=engine, time_limit_s=time_limit, out=out, exact=exact,
    )
    _print(result, doc, out if out is not None else outdir)
    return EXIT_OK if result.plan is not None else EXIT_NO_SOLUTION


def plan_after_run(args: argparse.Namespace, solution) -> int:
    """``camplace run ... --phases N --speed M_S``: plan on the run's folder with its mode and k."""
    mode = solution.mode if solution.mode in PLAN_MODES else "maxcover"
    limit = args.plan_time_limit if getattr(args, "plan_time_limit", None) is not None else args.time_limit
    return run_plan(args, args.out, time_limit=limit, mode=mode, views=args.views)


def _cmd_plan(args: argparse.Namespace) -> int:
    if args.k is not None and args.k < 1:
        raise CamplaceError(f"--k: must be >= 1, got {args.k}")
    if args.views is not None and args.views < 1:
        raise CamplaceError(f"--views: must be >= 1, got {args.views}")
    from camplace.outpaths import check_out_folder
    from camplace.plan.io import PLAN_FILES

    check_out_folder(args.out if args.out is not None else args.outdir, "-o/--out" if args.out is not None else "OUTDIR",
                     files=PLAN_FILES)
    return run_plan(args, args.outdir, time_limit=args.time_limit, k=args.k, mode=args.mode, views=args.views,
                    engine=args.engine, exact=args.exact, out=args.out)
