"""Command line of robust placement: its options (``run`` and ``solve``: ``--pose-error``,
``--scenarios``, ``--robust-objective``) and the ``solve`` verb, registered here like the verbs of
:mod:`camplace.plan.cli` and :mod:`camplace.validation.cli` (:func:`register`): the solver's own
arguments and plain solve (:mod:`camplace.solver.cli`), and the robust solve of a stored run when a
robust option is given.

Imports nothing heavy at module level.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, Callable

from camplace.errors import CamplaceError, EXIT_OK, EXIT_NO_SOLUTION
from camplace.names import ROBUST_OBJECTIVES



def add_robust_options(p: argparse.ArgumentParser) -> None:
    """The robust options of ``run`` and ``solve``."""
    p.add_argument("--pose-error", default=None, dest="pose_error", metavar="POS_M,ROT_DEG",
                   help="optimise for cameras installed off by this much: position sigma per axis (m) and rotation "
                        "sigma (deg), e.g. 0.1,5 (default: the instance's [robust] table; 0,0 = nominal)")
    p.add_argument("--scenarios", type=int, default=None, help="sampled installations per candidate (default 32)")
    p.add_argument("--robust-objective", choices=ROBUST_OBJECTIVES, default=None, dest="robust_objective",
                   help="mean: expected objective (default); p10: the value reached in 90%% of installations")


def spec_from_args(instance, args: argparse.Namespace):
    """The RobustSpec of a run (instance table overridden by the options), or None."""
    from camplace.robust.stage import make_spec

    return make_spec(getattr(instance, "robust", None), args.pose_error, args.scenarios, args.robust_objective)


def wants_robust(args: argparse.Namespace) -> bool:
    """True when a ``solve`` command line asks for a robust solve."""
    return any(getattr(args, name, None) is not None for name in ("pose_error", "scenarios", "robust_objective"))


def register(subparsers, add_run_options: Callable[[argparse.ArgumentParser], None]) -> dict[str, Callable[[argparse.Namespace], int]]:
    """Add the ``solve`` verb to ``subparsers``; returns {verb: handler}."""
    from camplace.solver.cli import add_solve_arguments

    p = subparsers.add_parser("solve", help="choose cameras on a stored visibility matrix (any mode, side constraints)")
    add_solve_arguments(p)
    add_robust_options(p)
    return {"solve": cmd_solve}


def cmd_solve(args: argparse.Namespace) -> int:
    """``solve``: the robust solve when a robust option is given, else the solver's plain solve."""
    if wants_robust(args):
        return cmd_solve_robust(args)
    from camplace.solver.cli import cmd_solve as plain_solve

    return plain_solve(args)


def cmd_solve_robust(args: argparse.Namespace) -> int:
    """``camplace solve RUN_DIR --pose-error P,R``: robust re-solve of a stored run (needs its folder)."""
    import numpy as np

    from camplace._io import write_json_atomic
    from camplace.robust.stage import check_request, robust_stage, spec_record
    from camplace.runfolder import RunFolder
    from camplace.solver.api import solve
    from camplace.solver.cli import _with_team, run_defaults, solve_out
    from camplace.solver.options import options_from_args

    solve_out(args)
    folder: Path = args.source if args.source.is_dir() else args.source.parent
    for name in ("instance.toml", "candidates.csv", "points.csv"):
        if not (folder / name).is_file():
            raise CamplaceError(f"{folder / name}: missing (a robust solve re-casts rays: give the -o folder of 'camplace run')")
    if not ((folder / "visibility.cpm").is_file() or (folder / "visibility.npz").is_file()):
        raise CamplaceError(f"{folder}: no visibility.cpm or visibility.npz (a robust solve re-casts rays: give the -o folder of 'camplace run')")
    run_folder = RunFolder(folder)
    instance = run_folder.instance
    spec = spec_from_args(instance, args)
    run = run_defaults(folder)
    k = args.k if args.k is not None else run.get("k")
    if k is None:
        raise CamplaceError(f"--k: required (no solution.json in {folder} to take it from)")
    event_mode = args.event_mode or run.get("event_mode", "all")
    if args.time_limit is None:
        args.time_limit = run.get("time_limit_s")
    cands, matrix, pts = run_folder.candidates, _nominal_matrix(run_folder), run_folder.points
    weights = run_folder.weights(event_mode)
    seed = _run_seed(folder, instance.defaults.seed)
    opts = options_from_args(args, k=int(k))
    opts = _with_team(folder, opts)  # the instance's team (issue 31): the nominal and the robust solve enforce it
    options = {**opts.record(), "event_mode": event_mode, "source": str(args.source)}
    check_request(spec, opts.mode, opts.min_angle_deg, opts.engine)
    options["robust"] = spec_record(spec)
    geometric = opts.reads_geometry
    nominal = solve(matrix, weights, positions=cands.positions if geometric else None,
                    points=pts.positions if geometric else None, options=opts)
    res, record = robust_stage(instance, cands, pts, matrix, np.asarray(weights, dtype=np.float64), nominal, spec, opts,
                               seed=seed)
    out = res.to_dict()
    out["options"] = options
    out["robust"] = record
    write_json_atomic(args.out, out)
    _print_summary(res, record)
    print(f"wrote {args.out}")
    return EXIT_OK if res.status in ("optimal", "feasible") else EXIT_NO_SOLUTION


def _nominal_matrix(run_folder) -> Any:
    """The run's matrix for the nominal solve and the robust stage: a binary one stored as column
    bitsets (``colbits``) as those bits (:class:`camplace.visibility.bits.BitMatrix`: the solver and
    the robust stage read them, no CSR), any other as its CSR matrix."""
    path = run_folder.matrix_path
    if path.suffix == ".cpm":
        from camplace.visibility.store import describe, load_bits

        if describe(path).get("structure") == "colbits":
            return load_bits(path)
    return run_folder.matrix


def _run_seed(folder: Path, default: int) -> int:
    """The seed of the run in ``folder`` (its solution.json), else ``default``."""
    from camplace.runfolder import RunFolder

    try:
        return int(RunFolder(folder).solution_record.get("seed", default))
    except (CamplaceError, ValueError, TypeError):
        return int(default)


def _print_summary(res, record: dict) -> None:
    s = record["settings"]
    print(f"{res.status}: robust {s['objective']} objective {res.objective:.6f}, bound {res.bound:.6g}, gap {100 * res.gap:.3f}%, "
          f"engine {res.engine} (pose error {s['position_sigma_m']:g} m, {s['rotation_sigma_deg']:g} deg, {s['scenarios']} scenarios)")
    print(f"  cameras: {', '.join(str(j) for j in res.selected)}")
    print_oos(record)


def print_oos(record: dict) -> None:
    """Two lines: both systems' objective on fresh installations."""
    oos = record.get("out_of_sample") or {}
    n = (record.get("settings") or {}).get("eval_scenarios")
    for name in ("robust", "nominal"):
        if name in oos:
            print(f"  {name:>7} system on {n} fresh installations: mean {oos[name]['mean']:.6f}, 10th percentile {oos[name]['p10']:.6f}")
