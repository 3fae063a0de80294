"""The ``camplace`` command line: argparse, then one call into the API per verb.

Exit codes (the same on every verb) are defined once, in :mod:`camplace.errors`.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from camplace._signals import ctrl_c_noted
from camplace.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_IO, EXIT_NO_SOLUTION, EXIT_OK, CamplaceError
from camplace.names import EVENT_MODES, SAMPLERS
from camplace.robust.cli import add_robust_options, print_oos, spec_from_args
from camplace.solver.options import add_solver_options, options_from_args

MATRIX_FORMATS = ("cpm", "npz")  # camplace.visibility.store.MATRIX_FORMATS (not imported: startup time)



class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors and exit code 2."""

    def error(self, message: str) -> None:  # pragma: no cover - exercised through main()
        self.print_usage(sys.stderr)
        raise SystemExit(f"error: {message}") from None


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """The options of ``camplace run``, in one argument group per stage (``run --help``)."""
    g = p.add_argument_group("instance")
    g.add_argument("instance", help="a built-in instance name (see 'camplace instances') or an instance .toml file")
    g.add_argument("--seed", type=int, default=None, help="random seed (default: the instance's, usually 0)")
    g.add_argument("--event-mode", choices=EVENT_MODES, default="all", dest="event_mode",
                   help="all: expected coverage over all frames (default); peak: the maximum-likelihood frame")
    g = p.add_argument_group("sampling")
    g.add_argument("--candidates", type=int, default=None, help="number of candidate camera positions")
    g.add_argument("--points", type=int, default=None, help="number of target surface points")
    g.add_argument("--sampler", choices=SAMPLERS, default=None, help="candidate sampler")
    g.add_argument("--orientations", type=int, default=None, help="poses per candidate position (default: instance)")
    _add_compute_options(p.add_argument_group("visibility"))
    add_solver_options(p.add_argument_group("solver"), k_default="the instance's k", memory_budget=False)
    add_robust_options(p.add_argument_group("robust placement"))
    g = p.add_argument_group("outputs")
    g.add_argument("-o", "--out", required=True, type=Path, help="output folder (created if missing)")
    _add_matrix_format(g)
    g.add_argument("--report", action="store_true",
                   help="then run a uniform and a chaotic campaign of random systems and write OUTDIR/report.html "
                        "(needs the report extra: pip install 'camplace[report]')")
    g.add_argument("--report-systems", type=int, default=200, dest="report_systems", help="systems per campaign (default 200)")
    from camplace.plan.cli import add_agent_options

    add_agent_options(p, for_run=True)


def _add_matrix_format(p) -> None:
    """``--matrix-format`` (``run`` and ``visibility``)."""
    p.add_argument("--matrix-format", choices=MATRIX_FORMATS, default="cpm", dest="matrix_format",
                   help="matrix file: visibility.cpm (compact, fast; default) or visibility.npz (scipy.sparse.load_npz, zlib: slower, larger)")


def _add_compute_options(p: argparse.ArgumentParser) -> None:
    """Where and how the visibility matrix is computed (run and visibility)."""
    p.add_argument("--no-cache", action="store_true", help="do not reuse or store cached visibility matrices")
    p.add_argument("--dask", default=None, metavar="ADDRESS", help="compute visibility on a Dask cluster: a scheduler address or local:N")
    p.add_argument("--memory-budget-gb", type=float, default=None,
                   help="memory budget (default: half the RAM): a binary matrix over it goes out of core (to --scratch), "
                        "any other stops with an error")
    p.add_argument("--scratch", default=None, metavar="DIR",
                   help="folder for out-of-core files (default: beside the output folder); removed when the run ends")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every verb."""
    parser = _Parser(prog="camplace", description="Optimal placement of cameras to observe a dynamic event.")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)

    p = sub.add_parser("run", help="sample candidates, compute visibility, choose the proven-best k cameras")
    _add_run_options(p)

    p = sub.add_parser("visibility", help="compute the visibility matrix of given candidates")
    p.add_argument("instance", help="a built-in instance name or an instance .toml file")
    p.add_argument("--candidates", required=True, type=Path, help="candidates.csv (as written by 'camplace run')")
    p.add_argument("-o", "--out", required=True, type=Path, help="output folder")
    p.add_argument("--points", type=int, default=None, help="number of target surface points")
    p.add_argument("--seed", type=int, default=None, help="random seed for the points")
    _add_compute_options(p)
    _add_matrix_format(p)

    p = sub.add_parser("convert-matrix", help="rewrite a folder's visibility matrix as visibility.npz (scipy) or visibility.cpm")
    p.add_argument("source", type=Path, help="output folder of 'camplace run', 'visibility' or 'campaign', or a matrix file")
    p.add_argument("--format", choices=MATRIX_FORMATS, required=True, dest="fmt", help="npz: scipy.sparse.load_npz; cpm: the compact store")

    sub.add_parser("instances", help="list the built-in instances")

    p = sub.add_parser("init", help="write a built-in instance (and its mesh files) to disk for editing")
    p.add_argument("name", help="built-in instance name")
    p.add_argument("-o", "--out", required=True, type=Path, help="instance file to write (.toml)")
    p.add_argument("--seed", type=int, default=None, help="seed that draws a generated event (comet-flyby, volcanic-eruption)")
    p.add_argument("--force", action="store_true", help="replace FILE (and its mesh folder) when it exists")

    for module in _verb_modules():
        COMMANDS.update(module.register(sub, _add_run_options))
    for verb in COMPUTE_VERBS:
        if verb in sub.choices:
            _add_threads_option(sub.choices[verb])
    return parser


#: Verbs that compute (cast rays, solve, render, store matrices): each takes ``--threads``.
COMPUTE_VERBS: tuple[str, ...] = ("run", "visibility", "convert-matrix", "solve", "render", "validate", "campaign",
                                  "report", "plan")


def _threads(text: str) -> int:
    """argparse type of ``--threads``: a whole number from 1 to the cores this process may use."""
    from camplace._cores import allowed_cores, check_threads

    try:
        return check_threads(int(text))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a whole number from 1 to {allowed_cores()} (the cores this process may use)") from None


def _add_threads_option(p: argparse.ArgumentParser) -> None:
    p.add_argument_group("cores").add_argument("--threads", type=_threads, default=None, metavar="N",
                   help="use at most N threads in every stage (default: every core this process may use, "
                        "its CPU affinity)")


# Stage packages that add verbs: each has ``register(subparsers, add_run_options) -> {verb: handler}``
# and imports nothing heavy at module level. ``solve`` is the robust stage's verb (it solves robustly
# when asked; camplace.robust.cli), ``setcover`` the solver's.
VERB_MODULES: tuple[str, ...] = ("camplace.validation.cli", "camplace.report.cli", "camplace.robust.cli", "camplace.solver.cli",
                                 "camplace.plan.cli")


def _verb_modules():
    import importlib

    return [importlib.import_module(name) for name in VERB_MODULES]


def _check_run_out(args: argparse.Namespace) -> None:
    """``camplace run``: the output folder, and the report extra with ``--report``, before any work."""
    from camplace.instance import mesh_folder
    from camplace.outpaths import check_out_folder
    from camplace.runfolder import CANDIDATES_NAME, INSTANCE_NAME, POINTS_NAME, SOLUTION_NAME

    files = [SOLUTION_NAME, CANDIDATES_NAME, POINTS_NAME, INSTANCE_NAME, f"visibility.{args.matrix_format}",
             "light_curves.csv", "scene.ply"]
    folders = [mesh_folder(INSTANCE_NAME).name]
    if args.report:
        from camplace.report.build import BUNDLE_SAMPLERS, REPORT_NAME
        from camplace.report.figures import require_matplotlib

        if args.report_systems < 1:
            raise CamplaceError(f"--report-systems: must be >= 1, got {args.report_systems}")
        require_matplotlib()
        files.append(REPORT_NAME)
        folders += [f"campaign-{s}" for s in BUNDLE_SAMPLERS]
    check_out_folder(args.out, files=files, folders=folders)


def _cmd_run(args: argparse.Namespace) -> int:
    _check_run_out(args)
    from camplace._progress import ConsoleReporter
    from camplace.instance import resolve_instance
    from camplace.pipeline import run

    instance = resolve_instance(args.instance, seed=args.seed)
    from camplace.plan.cli import check_agent_options

    check_agent_options(args, instance)  # moving agents: bad options fail before the run
    sol = run(
        instance,
        seed=args.seed,
        candidates=args.candidates,
        points=args.points,
        sampler=args.sampler,
        k=args.k,
        orientations=args.orientations,
        outdir=args.out,
        reporter=ConsoleReporter(),
        cache=not args.no_cache,
        dask_address=args.dask,
        memory_budget_gb=args.memory_budget_gb,
        scratch=args.scratch,
        event_mode=args.event_mode,
        solve_options=options_from_args(args, k=None if args.mode == "setcover" else args.k),
        matrix_format=args.matrix_format,
        robust=spec_from_args(instance, args),
    )
    print(
        f"{sol.status}: {sol.k} cameras observe {100 * sol.coverage_fraction:.2f}% of the event "
        f"({sol.mode} objective {sol.objective:.6f}, bound {sol.bound:.6f}, gap {100 * sol.gap:.3f}%, engine {sol.engine})"
    )
    if sol.robust is not None:
        print_oos(sol.robust)
    for note in sol.warnings:
        print(f"warning: {note}", file=sys.stderr)
    for cam in sol.cameras:
        x, y, z = cam["position"]
        model = f" [{cam['model']}]" if "model" in cam else ""
        print(f"  camera {cam['candidate']:>6}: position ({x:.3f}, {y:.3f}, {z:.3f}) m{model}")
    if len(instance.frames) > 1:
        print(f"  event mode {sol.event_mode}: expected coverage {100 * sol.expected_coverage:.2f}%, "
              f"peak frame {sol.peak_frame} coverage {100 * sol.peak_coverage:.2f}%")
    print(f"wrote {args.out}/solution.json, candidates.csv, points.csv, visibility.{args.matrix_format}, light_curves.csv, scene.ply")
    ok = sol.status in ("optimal", "feasible")
    from camplace.plan.cli import plan_after_run, plan_requested

    if ok and plan_requested(args, instance):
        ok = plan_after_run(args, sol) == EXIT_OK
    if args.report and ok:
        from camplace.report import run_report_bundle

        path = run_report_bundle(args.out, systems=args.report_systems, cache=not args.no_cache, reporter=ConsoleReporter())
        print(f"wrote {path} (campaigns in {args.out}/campaign-uniform, campaign-chaotic)")
    return EXIT_OK if ok else EXIT_NO_SOLUTION


def _cmd_visibility(args: argparse.Namespace) -> int:
    from camplace._progress import ConsoleReporter
    from camplace.instance import resolve_instance
    from camplace.outpaths import check_out_folder
    from camplace.visibility.stages import compute_points, visibility_stage
    from camplace.runfolder import RunFolder
    from camplace.sampling import CandidateSet
    from camplace.visibility import frame_scene, write_ply

    check_out_folder(args.out, files=["scene.ply", "points.csv", f"visibility.{args.matrix_format}"])
    instance = resolve_instance(args.instance, seed=args.seed)
    cands = CandidateSet.load(args.candidates)
    pts = compute_points(instance, args.points, args.seed)
    from camplace.visibility.scratch import Scratch

    with Scratch(args.scratch if args.scratch is not None else Path(args.out).resolve().parent) as scratch:
        vis = visibility_stage(
            instance, cands, pts, reporter=ConsoleReporter(), cache=not args.no_cache, dask_address=args.dask,
            memory_budget_gb=args.memory_budget_gb, scratch=scratch,
        )
        folder = RunFolder(args.out)
        folder.path.mkdir(parents=True, exist_ok=True)
        write_ply(folder.file("scene.ply"), frame_scene(instance, 0).triangles)
        path = folder.save_visibility(vis, args.matrix_format)
        folder.save_points(vis.points)
    shape = vis.pattern.shape
    print(f"{shape[0]} points x {shape[1]} candidates, {vis.pattern.nnz} observed pairs")
    print(f"wrote {path}, points.csv, scene.ply")
    return EXIT_OK


def _cmd_convert_matrix(args: argparse.Namespace) -> int:
    from camplace.visibility.store import convert_matrix

    src, dst = convert_matrix(args.source, args.fmt)
    print(f"{dst}: already in format {args.fmt}" if src == dst else f"wrote {dst} (removed {src})")
    return EXIT_OK


def _cmd_instances(args: argparse.Namespace) -> int:
    from camplace.instance import BUILTINS

    for name, desc in BUILTINS.items():
        print(f"{name:<22} {desc}")
    return EXIT_OK


def _cmd_init(args: argparse.Namespace) -> int:
    from camplace.instance import mesh_folder, write_builtin

    out: Path = args.out
    if out.suffix != ".toml":
        raise CamplaceError(f"--out: {out} should end in .toml (for example {out.with_suffix('.toml')})")
    if args.seed is not None and args.seed < 0:
        raise CamplaceError(f"--seed: must be >= 0, got {args.seed}")
    from camplace.outpaths import check_new_file, check_out_folder

    check_new_file(out, force=args.force)
    check_out_folder(mesh_folder(out), "-o/--out (mesh folder)")
    write_builtin(args.name, out, seed=args.seed)
    print(f"wrote {out} (run it with: camplace run {out} -o OUTDIR)")
    return EXIT_OK


COMMANDS = {"run": _cmd_run, "visibility": _cmd_visibility, "convert-matrix": _cmd_convert_matrix,
            "instances": _cmd_instances, "init": _cmd_init}


def console() -> int:
    """The ``camplace`` console script and ``python -m camplace``: :func:`main`, then a quick exit.

    After the command, the garbage collector is frozen: the interpreter's teardown otherwise walks
    every object the imports made (numba's types, scipy, the kernels' libraries) one last time,
    0.2 s of a 1-2 s command measured on the quick start, for nothing (files are closed and
    folders cleaned by then; ``atexit`` and ``weakref.finalize`` handlers still run). Only the
    process's end is affected: :func:`main` called in a longer-lived process collects as usual.
    """
    import gc

    code = main()
    gc.disable()
    gc.freeze()
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``camplace`` console script; returns the exit code."""
    from camplace._clock import mark_main

    mark_main()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        if isinstance(exc.code, str):
            print(exc.code, file=sys.stderr)
            return EXIT_BAD_INPUT
        return int(exc.code or 0)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2), format="%(levelname)s %(name)s: %(message)s"
    )
    if args.version:
        from camplace import __version__

        print(f"camplace {__version__}")
        return EXIT_OK
    if args.verb is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    if getattr(args, "threads", None) is not None:
        from camplace._cores import set_threads

        set_threads(args.threads)
    try:
        with ctrl_c_noted():
            return COMMANDS[args.verb](args)
    except CamplaceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print("error: out of memory (lower --points or --candidates, or set --memory-budget-gb)", file=sys.stderr)
        return EXIT_IO
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"error: {where}{exc.strerror or exc} (free disk space or fix permissions; no partial output was kept)", file=sys.stderr)
        return EXIT_IO
    except KeyboardInterrupt:
        print("interrupted: no partial output was written", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
