"""Benchmark: time to PROVE the k=3 max-coverage optimum, exact engine vs SCIP MIP.

Not a test. Builds deterministic structured visibility matrices (points on a sphere or a bilobed
object, cameras at random directions/distances or in a corridor, optional field of view / range
limits; see ``camplace.solver.problem._synthetic``) and prints, for each instance: rows/cols before and
after presolve, exact-engine time, MIP time (with a time limit), both objectives/statuses and the
MIP/exact time ratio.

Usage::

    PYTHONPATH=src python benchmarks/solver.py                     # all configurations
    PYTHONPATH=src python benchmarks/solver.py --mip-time-limit 60 --configs sphere bilobed
    PYTHONPATH=src python benchmarks/solver.py --skip-mip --repeat 3 --blas-threads 1
    PYTHONPATH=src python benchmarks/solver.py --modes                 # issue-8 mode targets, sphere
    PYTHONPATH=src python benchmarks/solver.py --modes multiview quality --source bunker
    PYTHONPATH=src python benchmarks/solver.py --modes multiview-angle --source bunker-all   # issue 16
    PYTHONPATH=src python benchmarks/solver.py --modes quality-k8 --source bunker-all   # issue 16, k = 8
    PYTHONPATH=src python benchmarks/solver.py --quality-engines     # min-Gram vs quantised tree
    PYTHONPATH=src python benchmarks/solver.py --ladder flyby        # issue 30: 500 .. 32,000 positions
    PYTHONPATH=src python benchmarks/solver.py --ladder flyby --ladder-positions 500 2000 --ladder-modes multiview

``--ladder flyby`` solves comet-flyby (seed 1, 5,000 requested points, 3 aims per position;
matrices from ``benchmarks/flyby_ladder.py``, cached) at 500 / 2,000 / 8,000 / 32,000 positions
in maxcover and in multiview (2 views, minimum angle 20 degrees), k = 3, ``--ladder-time-limit``
(default 60 s) each, and prints objective, bound, gap and the solve's wall time per row.

``--modes`` runs the issue's mode targets (maxcover 10,000 x 50,000; multiview and quality
1,000 x 20,000 and 10,000 x 50,000) with ``solve(..., engine="auto")`` and prints one line each,
on the structured sphere or on comet-67p-bunker visibility matrices (computed once, then cached;
quality on a graded version of the instance): ``--source bunker`` counts the lit side only, as the
issue's matrices do, ``--source bunker-all`` every surface point (a near-flat case for multiview).

OpenBLAS threading degrades badly when the cores are oversubscribed (other processes running);
``--blas-threads`` sets ``OPENBLAS_NUM_THREADS`` before numpy is imported. The load average is
printed so that figures can be judged.
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import sys
import time
from typing import Any

if "--blas-threads" in sys.argv:  # must happen before numpy is imported
    os.environ["OPENBLAS_NUM_THREADS"] = sys.argv[sys.argv.index("--blas-threads") + 1]

from camplace.solver import SolverResult, solve_maxcover  # noqa: E402
from camplace.solver.api import solve  # noqa: E402
from camplace.solver.problem._synthetic import structured_instance  # noqa: E402

# Issue 8 targets: (mode, candidates, points, time limit s, target); "multiview-angle" is multiview
# with a 20 degree minimum triangulation angle (issue 16; comet-67p-bunker sources only)
MODE_RUNS: list[tuple[str, int, int, float, str]] = [
    ("maxcover", 10000, 50000, 120.0, "proven optimal <= 10 s"),
    ("multiview", 1000, 20000, 60.0, "proven optimal <= 60 s"),
    ("quality", 1000, 20000, 60.0, "proven optimal <= 60 s"),
    ("multiview", 10000, 50000, 120.0, "gap <= 0.5 % within 120 s"),
    ("quality", 10000, 50000, 120.0, "gap <= 0.5 % within 120 s"),
    ("multiview-angle", 2000, 10000, 60.0, "proven optimal <= 60 s, peak RSS <= 4 GB"),
    ("multiview-angle", 10000, 50000, 120.0, "gap <= 1 % within 120 s, peak RSS <= 12 GB"),
    # issue 16, more cameras: "<mode>-v<views>-k<k>" overrides --k (and views); run with --source bunker-all
    ("multiview-v3-k6", 2000, 10000, 60.0, "gap <= 1 % within 60 s"),
    ("maxcover-k8", 2000, 10000, 60.0, "gap <= 0.5 % within 60 s"),
    ("quality-k8", 2000, 10000, 60.0, "gap <= 0.5 % within 60 s"),
]
MIN_ANGLE_DEG = 20.0


def builtin_matrix(mode: str, n_cams: int, m_pts: int, seed: int, lit: bool = True, geometry: bool = False):
    """A comet-67p-bunker visibility matrix (cached): chaotic candidates aimed at the comet.

    ``lit=True`` (the issue's matrices: "bilobed comet in the corridor, lit side only") counts only
    points the instance's lamp lights (``require_light``); ``lit=False`` counts every surface point,
    which makes ``multiview`` nearly flat (of three cameras seeing a convex body from afar, about
    half the surface is seen by at least two, whichever three they are).
    For ``quality`` the instance is switched to graded quality (resolution x incidence, max 80 deg),
    since the built-in's binary matrix would make it plain max coverage. ``geometry=True`` also
    returns the camera positions (n, 3) and point positions (m, 3).
    """
    import dataclasses

    from camplace.instance import builtin
    from camplace.event import event_aims
    from camplace.visibility.stages import compute_points, stage_seeds
    from camplace.sampling import make_candidates
    from camplace.visibility import compute_visibility
    from camplace.visibility.cache import default_cache_dir

    inst = builtin("comet-67p-bunker")
    quality = dataclasses.replace(inst.quality, require_light=lit)
    if mode == "quality":
        quality = dataclasses.replace(quality, mode="graded", max_incidence_deg=80.0)
    inst = dataclasses.replace(inst, quality=quality)
    pts = compute_points(inst, m_pts, seed)
    cands = make_candidates("chaotic", n_cams, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=stage_seeds(seed)[0])
    vis = compute_visibility(inst, cands, pts, cache_dir=default_cache_dir())
    if geometry:  # camera and point positions too (the angle)
        return vis.matrix, pts.weight, cands.positions, pts.positions
    return vis.matrix, pts.weight


def run_modes(seed: int, k: int, only: list[str] | None, source: str = "sphere") -> None:
    """The issue-8 mode benchmarks (one line per run) on the 'sphere' structured instance or on
    comet-67p-bunker matrices (``source="bunker"``: lit side only; ``"bunker-all"``: every surface
    point)."""
    import resource

    for mode, n_cams, m_pts, limit, target in MODE_RUNS:
        if only and mode not in only:
            continue
        angle = mode == "multiview-angle"
        base, views, k_run = mode, 2, k
        if "-k" in mode:  # e.g. "multiview-v3-k6": views 3, k = 6
            parts = mode.split("-")
            base, k_run = parts[0], int(parts[-1][1:])
            views = int(parts[1][1:]) if len(parts) == 3 else views
        geo: dict[str, Any] = {}
        if angle and not source.startswith("bunker"):
            print(f"   {mode}: needs --source bunker or bunker-all (camera and point positions)")
            continue
        if source.startswith("bunker"):
            got = builtin_matrix("multiview" if angle else base, n_cams, m_pts, seed, lit=source == "bunker",
                                 geometry=angle)
            matrix, weights = got[0], got[1]
            if angle:
                geo = {"min_angle_deg": MIN_ANGLE_DEG, "positions": got[2], "points": got[3]}
        else:
            matrix, weights = structured_instance(m_pts, n_cams, seed=seed)
        t = time.perf_counter()
        cpu = time.process_time()
        res = solve(matrix, weights, k_run, mode="multiview" if angle else base, views=views, time_limit_s=limit, **geo)
        wall = time.perf_counter() - t
        extra = ""
        if angle or "-k" in mode:
            es = res.stats.get("engine_stats", {})
            extra = (f" cpu {time.process_time() - cpu:.1f} s, {es.get('bound_evaluations', 0)} bound evaluations, "
                     f"peak RSS so far {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GB")
        print(
            f"   {source} {mode:9s} {n_cams:5d}x{m_pts:6d} k={k_run}: {wall:7.2f} s {res.engine:5s} {_fmt_result(res)}  "
            f"(limit {limit:.0f} s; target: {target}){extra}"
        )
        sys.stdout.flush()

def run_ladder(positions: list[int], modes: list[str], limit: float, k: int) -> None:
    """Issue 30's comet-flyby ladder: one line per (mode, positions) with objective, bound, gap and
    the solve's wall time (setup, presolve and model building included), and the load average."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from flyby_ladder import MIN_ANGLE_DEG as ANGLE, flyby_inputs

    print(f"   {'mode':9s} {'positions':>9s} {'columns':>7s} {'status':8s} {'objective':>9s} {'bound':>9s} "
          f"{'gap':>8s} {'time s':>7s} {'load':>5s}  engine")
    for n in positions:
        got = flyby_inputs(n)
        for mode in modes:
            geo: dict[str, Any] = {}
            if mode == "multiview":
                geo = {"min_angle_deg": ANGLE, "positions": got["positions"], "points": got["points"]}
            t = time.perf_counter()
            res = solve(got["matrix"], got["weights"], k, mode=mode, views=2, time_limit_s=limit, **geo)
            wall = time.perf_counter() - t
            name = "maxcover" if mode == "maxcover" else f"mv+{ANGLE:g}deg"
            print(f"   {name:9s} {n:9d} {got['matrix'].shape[1]:7d} {res.status:8s} {res.objective:9.5f} "
                  f"{res.bound:9.5f} {res.gap:8.2e} {wall:7.1f} {os.getloadavg()[0]:5.2f}  {res.engine}"
                  f"{' (warm start ' + format(res.stats['warm_start']['objective'], '.5f') + ')' if 'warm_start' in res.stats else ''}")
            sys.stdout.flush()
            del res
        del got


def run_quality_engines(seed: int, k: int) -> None:
    """The two exact quality engines on the same graded comet-67p-bunker matrices (same run):
    min-Gram triple enumeration vs the quantised tree, times and their ratio."""
    from camplace.solver._support.deadline import Deadline
    from camplace.solver.engines.quality.min_gram import QUALITY_EXACT_MAX_N, solve_quality_exact
    from camplace.solver.engines.quality.tree import solve_quality_tree

    for n_cams, m_pts in [(1000, 20000), (3000, 20000)]:
        matrix, weights = builtin_matrix("quality", n_cams, m_pts, seed, lit=False)  # every surface point
        out = {}
        for name, fn in (("min-gram", solve_quality_exact), ("tree", solve_quality_tree)):
            if name == "min-gram" and n_cams > QUALITY_EXACT_MAX_N:
                continue
            t = time.perf_counter()
            res = fn(matrix, weights, k, deadline=Deadline(120.0))
            out[name] = (time.perf_counter() - t, res)
            print(f"   quality {name:8s} {n_cams:5d}x{m_pts:6d} k={k}: {out[name][0]:7.2f} s {res.status:8s} "
                  f"bound={res.bound:.6f} selected={res.selected}")
        if len(out) == 2:
            print(f"   ratio min-gram/tree: {out['min-gram'][0] / out['tree'][0]:.1f}x "
                  f"(same bound: {abs(out['min-gram'][1].bound - out['tree'][1].bound) <= 1e-9})")
        sys.stdout.flush()


CONFIGS: dict[str, dict[str, Any]] = {
    "sphere": {},  # cameras 1.5..15 around a unit sphere: optimum ~99.8 %, many near-ties
    "sphere-near": {"dmax": 4.0},  # cameras 1.5..4: optimum ~95 %
    "bilobed": {"shape": "bilobed"},
    "bilobed-corridor": {"shape": "bilobed", "corridor": True},  # optimum ~79 %
    "fov-range": {"fov_deg": 40.0, "max_range": 8.0},
}
SIZES = [(2000, 10000), (1000, 20000)]  # (candidates, points)


def _fmt_result(res: SolverResult) -> str:
    return f"{res.status:8s} obj={res.objective:.6f} bound={res.bound:.6f} gap={res.gap:.2e}"


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print one block per instance."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", nargs="*", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--k", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--mip-time-limit", type=float, default=120.0, help="seconds for SCIP (default 120)")
    ap.add_argument("--skip-mip", action="store_true")
    ap.add_argument("--repeat", type=int, default=1, help="exact-engine repetitions (median reported)")
    ap.add_argument("--blas-threads", default=None, help="OPENBLAS_NUM_THREADS for this run")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--modes", nargs="*", default=None, help="run the issue-8 mode benchmarks (optionally only these modes) instead")
    ap.add_argument("--quality-engines", action="store_true",
                    help="compare the two exact quality engines on graded comet-67p-bunker matrices instead")
    ap.add_argument("--source", choices=["sphere", "bunker", "bunker-all"], default="sphere",
                    help="--modes matrices: the structured sphere, or comet-67p-bunker visibility (cached) of "
                         "its lit side only (bunker, as in the issue) or of every surface point (bunker-all)")
    ap.add_argument("--ladder", choices=["flyby"], default=None,
                    help="issue 30's candidate ladder on comet-flyby (objective, bound, gap, time per row) instead")
    ap.add_argument("--ladder-positions", nargs="*", type=int, default=[500, 2000, 8000, 32000])
    ap.add_argument("--ladder-modes", nargs="*", choices=["maxcover", "multiview"], default=["maxcover", "multiview"])
    ap.add_argument("--ladder-time-limit", type=float, default=60.0)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    print(
        f"cpus={os.cpu_count()} OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'default')} "
        f"load average at start: {os.getloadavg()[0]:.2f}"
    )

    if args.ladder:
        run_ladder(args.ladder_positions, args.ladder_modes, args.ladder_time_limit, args.k)
        print(f"load average at end: {os.getloadavg()[0]:.2f}")
        return 0
    if args.quality_engines:
        run_quality_engines(args.seed, args.k)
        return 0
    if args.modes is not None:
        run_modes(args.seed, args.k, args.modes, args.source)
        print(f"load average at end: {os.getloadavg()[0]:.2f}")
        return 0
    rows_out: list[str] = []
    for name in args.configs:
        for n_cams, m_pts in SIZES:
            t = time.perf_counter()
            matrix, weights = structured_instance(m_pts, n_cams, seed=args.seed, **CONFIGS[name])
            gen_s = time.perf_counter() - t
            times = []
            ex: SolverResult | None = None
            for _ in range(max(1, args.repeat)):
                t = time.perf_counter()
                ex = solve_maxcover(matrix, weights, args.k, engine="exact")
                times.append(time.perf_counter() - t)
            assert ex is not None
            ex_s = statistics.median(times)
            pre = ex.stats["presolve"]
            es = ex.stats["engine_stats"]
            print(f"== {name}: {n_cams} candidates x {m_pts} points, k={args.k} (generated in {gen_s:.1f} s)")
            print(
                f"   presolve: rows {ex.stats['rows_in']} -> {ex.stats['rows_after']}, "
                f"cols {ex.stats['cols_in']} -> {ex.stats['cols_after']} in {pre['time_s']:.2f} s"
            )
            print(
                f"   exact   : {ex_s:7.2f} s total ({'/'.join(f'{x:.2f}' for x in times)})  {_fmt_result(ex)}  "
                f"[{es.get('bound_evaluations', 0)} bound evaluations]"
            )
            after = f"{ex.stats['cols_after']:5d}x{ex.stats['rows_after']:6d}"
            line = f"{name:17s} {n_cams:5d}x{m_pts:6d} -> {after}  exact {ex_s:7.2f}s"
            if not args.skip_mip:
                t = time.perf_counter()
                mip = solve_maxcover(matrix, weights, args.k, engine="mip", time_limit_s=args.mip_time_limit)
                mip_s = time.perf_counter() - t
                ratio = mip_s / ex_s
                rel = ">=" if mip.status != "optimal" else ""
                same = abs(mip.objective - ex.objective) <= 1e-12
                print(f"   mip     : {mip_s:7.2f} s total  {_fmt_result(mip)}  (same objective: {same})")
                print(f"   ratio mip/exact: {rel}{ratio:.1f}x")
                line += f"  mip {mip_s:7.2f}s ({mip.status}, gap {mip.gap:.1e})  ratio {rel}{ratio:.1f}x"
            rows_out.append(line)
            sys.stdout.flush()
    print(f"\nload average at end: {os.getloadavg()[0]:.2f}")
    print("summary (candidates x points -> cols x rows after presolve):")
    for line in rows_out:
        print("  " + line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
