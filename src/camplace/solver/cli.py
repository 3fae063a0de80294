"""Verbs of the solver stage: ``setcover`` (public set-cover benchmark files), and the plain
``solve`` (re-solve a run's visibility matrix; the verb itself is registered by
:mod:`camplace.robust.cli`, which adds the robust options).

Imports nothing heavy at module level (numpy, scipy and OR-Tools load when a verb runs).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, Callable

from camplace.errors import CamplaceError, EXIT_OK, EXIT_NO_SOLUTION
from camplace.names import EVENT_MODES, SETCOVER_ENGINES
from camplace.solver.options import SolveOptions, add_solver_options, options_from_args

SOLVE_NAME = "solve.json"  # the default -o of 'camplace solve', in the run folder



def register(subparsers, add_run_options: Callable[[argparse.ArgumentParser], None]) -> dict[str, Callable[[argparse.Namespace], int]]:
    """Add the solver's own verb, ``setcover``, to ``subparsers``; returns {verb: handler}.

    The ``solve`` verb is registered by :mod:`camplace.robust.cli` (a later stage: it also solves
    robustly) with :func:`add_solve_arguments` and :func:`cmd_solve` from here.
    """
    p = subparsers.add_parser("setcover", help="solve a public set-cover benchmark file (OR-Library or GECCO 2020)")
    p.add_argument("file", type=Path, help="instance file")
    p.add_argument("--format", choices=["orlib", "gecco"], required=True, dest="fmt", help="file format")
    p.add_argument("--engine", choices=SETCOVER_ENGINES, default="auto",
                   help="auto: local search + Lagrangian bound, then SCIP on small reduced instances; mip / cpsat: "
                        "always that model after the local search (default auto)")
    p.add_argument("--time-limit", type=float, default=None, dest="time_limit", help="time limit, seconds")
    p.add_argument("--unicost", action="store_true", help="ignore the file's column costs (every column costs 1)")
    p.add_argument("--search-seed", "--seed", type=int, default=0, dest="search_seed",
                   help="seed of the local search (default 0; --seed is the old name)")
    p.add_argument("--iterations", type=int, default=None,
                   help="iteration budget of the local search (with it and no time limit the answer is reproducible)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object: cost, bound, status, time_s, selected, engine, uncoverable_rows, "
                        "time_to_best_s")
    return {"setcover": _cmd_setcover}


def add_solve_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of the ``solve`` verb (a run folder or matrix, the solver's options, ``-o``)."""
    p.add_argument("source", type=Path, help="output folder of 'camplace run' (or 'visibility') or its matrix file (visibility.cpm or .npz)")
    add_solver_options(p, k_default="the run's k")
    p.add_argument("--event-mode", choices=EVENT_MODES, default=None, dest="event_mode",
                   help="row weights: all frames, or the maximum-likelihood frame alone (default: the run's, else all)")
    p.add_argument("-o", "--out", type=Path, default=None,
                   help=f"solution JSON to write (default: {SOLVE_NAME} in the run folder)")




def load_problem(source: Path, pattern: bool = True) -> tuple[Any, Any, Any, Any]:
    """Matrix, weights, camera positions and point positions from a run folder or its matrix file.

    Read through :class:`camplace.RunFolder` (which loads no Embree): the matrix is
    ``visibility.cpm`` or ``visibility.npz``, with ``pattern`` a binary one read as its bool
    pattern (:attr:`RunFolder.pattern`: no float copy; for the modes whose engines read only
    the pattern), or, stored as column bitsets (``colbits``), as those bits
    (:class:`camplace.visibility.bits.BitMatrix`, which :func:`camplace.solver.api.solve` takes); a
    graded matrix stored as quantised columns (``colbytes``) is read as those bytes whatever
    ``pattern`` (:class:`camplace.visibility.qbytes.ByteMatrix`, which ``solve`` takes for every
    mode); ``points.csv`` (index,x,y,z,...,weight) must sit beside it; ``candidates.csv``
    (index,x,y,z,...) is optional (positions are then None).
    """
    import numpy as np

    from camplace.runfolder import CANDIDATES_NAME, POINTS_NAME, RunFolder

    run = RunFolder(source)
    matrix = None
    path = run.matrix_path
    if path.suffix == ".cpm":
        from camplace.visibility.store import describe, load_bits, load_bytes

        structure = describe(path).get("structure")
        if pattern and structure == "colbits":  # a binary matrix as column bitsets, read as it is (one bit a cell)
            matrix = load_bits(path)
        elif structure == "colbytes":  # a graded one as quantised columns (one byte a cell): solve takes them
            matrix = load_bytes(path)
    if matrix is None:
        matrix = run.pattern if pattern else run.matrix
    cols = run.point_columns(["x", "y", "z", "weight"])
    weights = cols["weight"]
    points = np.column_stack([cols["x"], cols["y"], cols["z"]])
    if weights.shape[0] != matrix.shape[0]:
        raise CamplaceError(f"{run.file(POINTS_NAME)}: {weights.shape[0]} points but the matrix has {matrix.shape[0]} rows")
    positions = run.candidate_positions()
    if positions is not None and positions.shape[0] != matrix.shape[1]:
        raise CamplaceError(f"{run.file(CANDIDATES_NAME)}: {positions.shape[0]} candidates but the matrix has {matrix.shape[1]} columns")
    return matrix, weights, positions, points


def solve_out(args: argparse.Namespace) -> Path:
    """``solve``'s ``-o``: as given, else :data:`SOLVE_NAME` in the run folder; checked before any work.

    Sets ``args.out`` and returns it.
    """
    from camplace.outpaths import check_out_file
    from camplace.runfolder import RunFolder

    if args.out is None:
        args.out = RunFolder(args.source).path / SOLVE_NAME
    return check_out_file(args.out, example=SOLVE_NAME)


def run_defaults(source: Path) -> dict[str, Any]:
    """``k`` (new cameras), ``event_mode`` and ``time_limit_s`` (seconds; None: none) of the run
    whose folder holds the matrix, if any: ``camplace solve`` takes them where not given, so a
    re-solve keeps to the run's time limit as ``camplace run`` did."""
    from camplace.runfolder import SOLUTION_NAME, RunFolder

    run = RunFolder(source)
    if not run.has(SOLUTION_NAME):
        return {}
    sol = run.solution_record
    opts = sol.get("options") or {}
    k = opts.get("k")
    if k is None and sol.get("mode") != "setcover" and isinstance(sol.get("cameras"), list):
        k = len(sol["cameras"]) - len(opts.get("fixed") or [])
    limit = opts.get("time_limit_s")
    return {"k": k, "event_mode": sol.get("event_mode", "all"), "peak_frame": sol.get("peak_frame"),
            "time_limit_s": float(limit) if isinstance(limit, (int, float)) and limit > 0 else None}


def _peak_weights(source: Path, weights: Any, peak: int | None) -> Any:
    """points.csv weights restricted to the maximum-likelihood frame and rescaled to sum 1 (as run --event-mode peak).

    ``peak`` is the run's ``peak_frame``; without a run, the frame of largest total weight.
    """
    import numpy as np

    from camplace.runfolder import RunFolder

    frames = RunFolder(source).point_columns(["frame"])["frame"].astype(np.int64)
    if peak is None:
        peak = int(np.argmax(np.bincount(frames, weights=weights)))
    w = np.where(frames == peak, weights, 0.0)
    return w / w.sum() if w.sum() > 0 else w


def _with_team(source: Path, opts: SolveOptions) -> SolveOptions:
    """``opts`` with the team constraints of the run folder's instance (issue 31), when it has a team
    (``instance.toml`` and ``candidates.csv`` beside the matrix); unchanged otherwise."""
    from camplace.runfolder import CANDIDATES_NAME, INSTANCE_NAME, RunFolder
    from camplace.solver.problem.team import team_options

    run = RunFolder(source)
    if not (run.has(INSTANCE_NAME) and run.has(CANDIDATES_NAME)):
        return opts
    team = getattr(run.instance, "team", None)
    if team is None:
        return opts
    return team_options(team, run.candidates, opts)


def cmd_solve(args: argparse.Namespace) -> int:
    """``camplace solve SOURCE -o OUT``: choose cameras on a stored visibility matrix."""
    import time
    from concurrent.futures import ThreadPoolExecutor

    solve_out(args)
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=1) as pool:
        # the matrix decodes (GIL-free) while the solver's modules import
        # quality and the minimum-angle engines read values: they take the float32 matrix
        pattern = args.mode != "quality" and args.min_angle is None
        loading = pool.submit(load_problem, args.source, pattern)
        from camplace._io import write_json_atomic
        from camplace.solver.api import solve

        matrix, weights, positions, points = loading.result()
    load_s = time.perf_counter() - t0
    if (args.min_distance is not None or args.min_angle is not None) and positions is None:
        raise CamplaceError(f"--min-distance/--min-angle need candidates.csv beside {args.source}")
    run = run_defaults(args.source)
    if args.k is None and args.mode != "setcover":
        args.k = run.get("k")
    if args.mode != "setcover" and args.k is None:
        raise CamplaceError(f"--k: required for mode {args.mode} (no solution.json beside the matrix to take it from)")
    if args.event_mode is None:
        args.event_mode = run.get("event_mode", "all")
    if args.time_limit is None:
        args.time_limit = run.get("time_limit_s")
    if args.event_mode == "peak":
        weights = _peak_weights(args.source, weights, run.get("peak_frame"))
    opts = options_from_args(args)
    opts = _with_team(args.source, opts)
    res = solve(matrix, weights, positions=positions, points=points if opts.reads_geometry else None, options=opts)
    out = res.to_dict()
    out["timings_s"] = {**(out.get("timings_s") or {}), "load": load_s, "solve": res.time_s}
    # how the answer was asked for (the same record as solution.json's "options")
    out["options"] = {**opts.record(), "event_mode": args.event_mode, "source": str(args.source)}
    out["warnings"] = binary_quality_warnings(args.mode, matrix)
    write_json_atomic(args.out, out)
    total = float(weights.sum())
    what = "cost" if args.mode == "setcover" else "objective"
    frac = "" if args.mode == "setcover" or total <= 0 else f" ({100 * res.objective / total:.2f}% of the weight)"
    print(f"{res.status}: {args.mode} {what} {res.objective:.6g}{frac}, bound {res.bound:.6g}, gap {100 * res.gap:.3f}%, "
          f"engine {res.engine}, {res.time_s:.2f} s")
    print(f"  cameras: {', '.join(str(j) for j in res.selected)}")
    for note in out["warnings"]:
        print(f"warning: {note}", file=sys.stderr)
    print(f"wrote {args.out}")
    return EXIT_OK if res.status in ("optimal", "feasible") else EXIT_NO_SOLUTION


def binary_quality_warnings(mode: str, matrix) -> list[str]:
    """A warning when ``--mode quality`` meets a matrix whose every observed pair has quality 1.

    The objective is then the observed weight, exactly as ``--mode maxcover`` (the run's instance had
    ``[quality] mode = "binary"``); the solver's numbers are left as they are.

    Parameters
    ----------
    mode : str
    matrix : (m, n) scipy.sparse matrix or camplace.visibility.qbytes.ByteMatrix
    """
    import numpy as np

    if mode != "quality" or matrix.nnz == 0:
        return []
    ones = matrix.all_ones() if getattr(matrix, "format", None) == "bytes" else np.all(matrix.data == 1)
    if not ones:
        return []
    return ["--mode quality on a matrix whose every observed pair has quality 1 (the run's [quality] mode is "
            '"binary"): the objective is the observed weight, exactly as --mode maxcover (run with [quality] '
            'mode = "graded" to weigh resolution and incidence)']


def _cmd_setcover(args: argparse.Namespace) -> int:
    import numpy as np

    from camplace.solver.api import solve
    from camplace.solver.problem.formats import read_cover

    inst = read_cover(args.file, args.fmt)
    if args.iterations is not None and args.iterations < 1:
        raise CamplaceError(f"--iterations: must be a positive number of iterations, got {args.iterations}")
    costs = np.ones(inst.matrix.shape[1]) if args.unicost else inst.costs
    opts = SolveOptions(mode="setcover", costs=costs, engine=args.engine, time_limit_s=args.time_limit,
                        search_seed=args.search_seed, iterations=args.iterations)
    res = solve(inst.matrix, np.ones(inst.matrix.shape[0]), options=opts)
    unc = int(res.stats.get("uncoverable_points", 0))
    if args.json:
        out = {
            "cost": res.objective if math.isfinite(res.objective) else None,
            "bound": res.bound if math.isfinite(res.bound) else None,
            "status": res.status,
            "time_s": res.time_s,
            "selected": list(res.selected),
            "engine": res.engine,
            "uncoverable_rows": unc,
            "time_to_best_s": (res.stats.get("setcover") or {}).get("time_to_best_s"),
        }
        print(json.dumps(out))
    else:
        print(f"{inst.name}: {res.status}, cost {res.objective:g}, lower bound {res.bound:g}, "
              f"{len(res.selected)} columns, engine {res.engine}, {res.time_s:.2f} s"
              + (f", {unc} uncoverable rows" if unc else ""))
    return EXIT_OK if res.status in ("optimal", "feasible") else EXIT_NO_SOLUTION
