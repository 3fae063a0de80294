"""Scale benchmark (issue 32): ``camplace run`` at growing sizes, column bitsets against the float32
CSR layout, in the same invocation.

For every size ``CANDIDATESxPOINTS`` it runs ``camplace run comet-67p-bunker`` (no cache) in a
child process, once with the matrix as column bitsets (the default for a binary instance) and,
unless ``--no-baseline``, once with ``CAMPLACE_VISIBILITY_LAYOUT=csr`` (the float32 CSR of before),
and prints per run:

- the size, the wall time, the peak RSS of the process tree (the run and any children, e.g. a
  ``local:N`` Dask cluster, sampled every 50 ms with psutil; a separate scheduler / worker started
  outside is not counted), the observed pairs (from ``solution.json``) and bytes per observed pair;
- the memory guard's estimate before the cast (``guard MB``:
  :func:`camplace.visibility.engine.estimate_matrix_bytes`, the function the run checks its budget
  with, evaluated for the same size, thread count and, on column bitsets, the same solve:
  :func:`camplace.solver.api.bits_solve_bytes` of the run's options, the observed pairs and the
  conflicting pairs the run counted, as the pipeline passes it at the pilot's check), the solve's
  part of it (``solve MB``), the estimate the solve itself made of its model once the presolved
  instance was known (``model MB``: a set-cover SCIP / CP-SAT model's
  ``solver_stats["setcover"]["model_bytes"]``, added to the guard; the general model's
  ``solver_stats["model_estimate"]``, shown only), that figure's ratio to the measured peak
  (``pre/peak``);
- the guard's later stages (column bitsets): each estimate the solve noted before allocating,
  with what it knew then (``solver_stats["memory_estimates"]``: the step's bytes and the bytes held
  then, the matrix included), plus the process's base (``BASE_BYTES`` and 16 bytes a point; the
  cast's threads' arrays are freed by then); the largest (``stage``, ``stage MB``), refused steps
  left out;
- the run's estimate, the largest of the stages it made (before the cast and after), and its
  ratio to the measured peak (target: within 25 %), and when the peak was reached (seconds after
  the start);
- the objective and status, and the peak's ratio to the baseline's.

With ``--graded`` the instance is a copy of comet-67p-bunker with ``[quality] mode = "graded"``
(written by ``camplace init`` into a temporary folder): the matrix is then quantised to a byte a
cell (``[quality] precision = "byte"``, the default), and the baseline is the float32 CSR
(``CAMPLACE_VISIBILITY_LAYOUT=csr``); use ``--mode quality`` for the graded objective.

``--case`` picks a route of the solve on the bits (one row each, several allowed: ``plain``, the
options given; ``angle``: multiview with a minimum angle of 20 degrees; ``k6``: k = 6, the
large-k engines; ``fixed``: cameras 3 and 17 fixed; ``multiview``: multiview, 2 views, the bitset
engine on the opposite-pairs layout; ``mindist``: a minimum distance of 0.5 m, the general model on
the merged rows).

Usage::

    python benchmarks/scale.py [--sizes 2000x10000,10000x50000] [--k 3] [--mode maxcover]
                               [--no-baseline] [--dask ADDRESS] [--threads N] [--graded]
                               [--case plain,angle,k6,fixed,multiview,mindist] [--time-limit S]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil


def tree_rss(proc: psutil.Process) -> int:
    total = 0
    for p in [proc, *proc.children(recursive=True)]:
        try:
            total += p.memory_info().rss
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            pass
    return total


#: the routes ``--case`` picks: the run's extra arguments and the same as SolveOptions fields
CASES = {
    "plain": ([], {}),
    "angle": (["--mode", "multiview", "--min-angle", "20"], {"mode": "multiview", "min_angle_deg": 20.0}),
    "k6": (["--k", "6"], {"k": 6}),
    "fixed": (["--fixed", "3,17"], {"fixed": (3, 17)}),
    "multiview": (["--mode", "multiview"], {"mode": "multiview"}),
    "mindist": (["--min-distance", "0.5"], {"min_distance_m": 0.5}),
}


def case_options(args, case: str):
    """The SolveOptions of a run of ``case`` (the pipeline's, as far as the guard reads them)."""
    from camplace.solver.options import SolveOptions

    kw = {"mode": args.mode, "k": None if args.mode == "setcover" else args.k, "views": 2}
    kw.update(CASES[case][1])
    return SolveOptions(**kw)


def run_once(n_cand: int, n_pts: int, args, layout: str, case: str = "plain") -> dict:
    out = Path(tempfile.mkdtemp(prefix="camplace-scale-"))
    cmd = [sys.executable, "-m", "camplace", "run", args.instance, "--candidates", str(n_cand), "--points",
           str(n_pts), "--k", str(args.k), "--mode", args.mode, "--no-cache", "-o", str(out / "run")]
    cmd += CASES[case][0]
    if args.time_limit is not None:
        cmd += ["--time-limit", str(args.time_limit)]
    if args.dask:
        cmd += ["--dask", args.dask]
    if args.threads:
        cmd += ["--threads", str(args.threads)]
    env = {**os.environ, "CAMPLACE_VISIBILITY_LAYOUT": layout}
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    proc = psutil.Process(child.pid)
    peak = 0
    peak_at = 0.0
    while child.poll() is None:
        try:
            rss = tree_rss(proc)
        except psutil.NoSuchProcess:
            break
        if rss > peak:
            peak, peak_at = rss, time.perf_counter() - t0
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    text = child.stdout.read() if child.stdout else ""
    if child.returncode != 0:
        return {"layout": layout, "error": text.strip().splitlines()[-1] if text.strip() else f"exit {child.returncode}"}
    from camplace.visibility.store import describe

    sol = json.loads((out / "run" / "solution.json").read_text())
    observed = describe(out / "run" / "visibility.cpm")["nnz"]  # the footer alone
    subprocess.run(["rm", "-rf", str(out)], check=False)
    selected = [c.get("index", c.get("candidate")) for c in sol.get("cameras", [])]
    stats = sol.get("solver_stats") or {}
    model = int(stats.get("setcover", {}).get("model_bytes", 0))
    general = int((stats.get("model_estimate") or {}).get("bytes", 0))
    return {"layout": layout, "wall_s": wall, "peak": peak, "peak_at": peak_at, "observed": observed,
            "model": model, "general": general, "conflicts": int(stats.get("conflict_pairs", 0)),
            "stages": stats.get("memory_estimates") or {},
            "objective": sol.get("objective"), "status": sol.get("status"), "selected": selected,
            "engine": sol.get("engine")}


def guard_estimate(n_cand: int, n_pts: int, layout: str, density: float, threads: int | None,
                   graded: bool = False, options=None, conflicts: int = 0) -> tuple[int, int]:
    """The guard's estimate of a run and its solve's part (bytes): what the pipeline passes at the
    pilot's check, with the run's density and conflicting pairs."""
    from camplace._cores import set_threads
    from camplace.solver.api import bits_solve_bytes
    from camplace.visibility.engine import estimate_matrix_bytes

    set_threads(threads)
    name = layout_name(layout, graded)
    solve = 0
    kw = {}
    if name == "bits" and options is not None:
        solve = bits_solve_bytes(n_pts, n_cand, options, int(round(density * n_pts * n_cand)), conflicts)
        kw = {"solve_bytes": solve}
    mode = "maxcover" if options is None else options.mode
    return estimate_matrix_bytes(n_pts, n_cand, density, name, tree=1.0 if mode == "quality" else 0.0, **kw), solve


def stage_estimates(n_cand: int, n_pts: int, stages: dict, threads: int | None) -> dict[str, int]:
    """The run's estimate at each step the solve noted (``solver_stats["memory_estimates"]``: the
    step's bytes and the bytes held then, the matrix included), as the whole process's: plus the
    process's base as the guard counts it (:data:`~camplace.visibility.engine.BASE_BYTES` and 16
    bytes a point; the threads' work arrays are freed with the cast, before the solve)."""
    from camplace.visibility.engine import BASE_BYTES

    base = BASE_BYTES + 16 * n_pts
    return {name: base + int(v["held"]) + int(v["bytes"]) for name, v in stages.items()
            if not name.endswith("(refused)")}  # a step over the budget did not allocate


def layout_name(layout: str, graded: bool) -> str:
    """The matrix layout of a run: ``auto`` is column bitsets (binary) or quantised bytes (graded)."""
    return ("bytes" if graded else "bits") if layout == "auto" else "csr"


def graded_instance(folder: Path) -> str:
    """A copy of comet-67p-bunker with graded quality, written into ``folder``; returns its path."""
    path = folder / "graded.toml"
    subprocess.run([sys.executable, "-m", "camplace", "init", "comet-67p-bunker", "-o", str(path)], check=True,
                   stdout=subprocess.DEVNULL)
    with open(path, "a") as fh:
        fh.write('\n[quality]\nmode = "graded"\n')
    return str(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="2000x10000,10000x50000")
    ap.add_argument("--k", type=int, default=3)
    ap.add_argument("--mode", default="maxcover")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--dask", default=None)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--graded", action="store_true", help="graded quality (quantised bytes against float32 CSR)")
    ap.add_argument("--case", default="plain", help="comma-separated routes: " + ",".join(CASES))
    ap.add_argument("--time-limit", type=float, default=None)
    args = ap.parse_args()
    args.instance = graded_instance(Path(tempfile.mkdtemp(prefix="camplace-graded-"))) if args.graded else \
        "comet-67p-bunker"
    print(f"{'size':>16} {'case':>9} {'layout':>6} {'wall s':>8} {'peak MB':>9} {'at s':>6} {'pairs':>12} "
          f"{'B/pair':>7} {'guard MB':>8} {'solve MB':>8} {'model MB':>8} {'pre/peak':>8} {'stage':>9} "
          f"{'stage MB':>8} {'est MB':>8} {'est/peak':>8} {'vs base':>8}  result")
    for size in args.sizes.split(","):
        n_cand, n_pts = (int(v) for v in size.lower().split("x"))
        for case in args.case.split(","):
            runs = [run_once(n_cand, n_pts, args, "auto", case)]
            if not args.no_baseline:
                runs.append(run_once(n_cand, n_pts, args, "csr", case))
            base = runs[1]["peak"] if len(runs) > 1 and "peak" in runs[1] else None
            for r in runs:
                if "error" in r:
                    print(f"{size:>16} {case:>8} {r['layout']:>6}  failed: {r['error']}")
                    continue
                pairs = r["observed"] or 0
                density = pairs / (n_cand * n_pts) if pairs else 0.0
                guard, solve = guard_estimate(n_cand, n_pts, r["layout"], density, args.threads, args.graded,
                                              case_options(args, case), r["conflicts"])
                pre = guard + r["model"]  # a set-cover model's own estimate (made before building it) on top
                stages = stage_estimates(n_cand, n_pts, r["stages"], args.threads) if r["layout"] == "auto" else {}
                top = max(stages, key=stages.get) if stages else "-"
                est = max(pre, stages.get(top, 0))  # the largest estimate the run made, before the cast or after
                shown = r["model"] or r["general"]
                vs = f"{r['peak'] / base:.2f}" if base else "-"
                bpp = r["peak"] / pairs if pairs else float("nan")
                print(f"{size:>16} {case:>9} {layout_name(r['layout'], args.graded):>6} {r['wall_s']:8.1f} "
                      f"{r['peak'] / 2**20:9.0f} {r['peak_at']:6.1f} {pairs:12,d} {bpp:7.2f} {guard / 2**20:8.0f} "
                      f"{solve / 2**20:8.0f} {shown / 2**20:8.0f} {pre / r['peak']:8.2f} {top:>9} "
                      f"{stages.get(top, 0) / 2**20:8.0f} {est / 2**20:8.0f} {est / r['peak']:8.2f} {vs:>8}  "
                      f"{r['status']} {r['engine']} {r['objective']:.6f} {r['selected']}", flush=True)


if __name__ == "__main__":
    main()
