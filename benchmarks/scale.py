"""Scale benchmark (issue 32): ``camplace run`` at growing sizes, column bitsets against the float32
CSR layout, in the same invocation.

For every size ``CANDIDATESxPOINTS`` it runs ``camplace run comet-67p-bunker`` (no cache) in a
child process, once with the matrix as column bitsets (the default for a binary instance) and,
unless ``--no-baseline``, once with ``CAMPLACE_VISIBILITY_LAYOUT=csr`` (the float32 CSR of before),
and prints per run:

- the size, the wall time, the peak RSS of the process tree (the run and any children, e.g. a
  ``local:N`` Dask cluster, sampled every 50 ms with psutil; a separate scheduler / worker started
  outside is not counted), the observed pairs (from ``solution.json``) and bytes per observed pair;
- the memory guard's estimate (:func:`camplace.visibility.engine.estimate_matrix_bytes`, the
  function the run checks its budget with, evaluated for the same size, thread count and, on
  column bitsets, the same solve: ``--mode setcover`` and ``--mode multiview`` count their own
  working memory, :func:`camplace.solver.bits_route.bits_solve_bytes`), the estimate of a set-cover
  SCIP / CP-SAT model when one ran (``solver_stats["setcover"]["model_bytes"]``, made before the
  model is built, once the reduced instance is known: the guard cannot know before the cast whether
  one will run), their sum and its ratio to the measured peak (target: within 25 %);
- the objective and status, and the peak's ratio to the baseline's.

With ``--graded`` the instance is a copy of comet-67p-bunker with ``[quality] mode = "graded"``
(written by ``camplace init`` into a temporary folder): the matrix is then quantised to a byte a
cell (``[quality] precision = "byte"``, the default), and the baseline is the float32 CSR
(``CAMPLACE_VISIBILITY_LAYOUT=csr``); use ``--mode quality`` for the graded objective.

Usage::

    python benchmarks/scale.py [--sizes 2000x10000,10000x50000] [--k 3] [--mode maxcover]
                               [--no-baseline] [--dask ADDRESS] [--threads N] [--graded]
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


def run_once(n_cand: int, n_pts: int, args, layout: str) -> dict:
    out = Path(tempfile.mkdtemp(prefix="camplace-scale-"))
    cmd = [sys.executable, "-m", "camplace", "run", args.instance, "--candidates", str(n_cand), "--points",
           str(n_pts), "--k", str(args.k), "--mode", args.mode, "--no-cache", "-o", str(out / "run")]
    if args.dask:
        cmd += ["--dask", args.dask]
    if args.threads:
        cmd += ["--threads", str(args.threads)]
    env = {**os.environ, "CAMPLACE_VISIBILITY_LAYOUT": layout}
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    proc = psutil.Process(child.pid)
    peak = 0
    while child.poll() is None:
        try:
            peak = max(peak, tree_rss(proc))
        except psutil.NoSuchProcess:
            break
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
    model = int((sol.get("solver_stats") or {}).get("setcover", {}).get("model_bytes", 0))
    return {"layout": layout, "wall_s": wall, "peak": peak, "observed": observed, "model": model,
            "objective": sol.get("objective"), "status": sol.get("status"), "selected": selected}


def guard_estimate(n_cand: int, n_pts: int, layout: str, density: float, threads: int | None,
                   graded: bool = False, mode: str = "maxcover", k: int = 3, views: int = 2) -> int:
    from camplace._cores import set_threads
    from camplace.solver.bits_route import bits_solve, bits_solve_bytes
    from camplace.solver.options import SolveOptions
    from camplace.visibility.engine import estimate_matrix_bytes

    set_threads(threads)
    plan = bits_solve(SolveOptions(mode=mode, k=None if mode == "setcover" else k, views=views))
    solve = {} if plan is None else {"solve_bytes": bits_solve_bytes(n_pts, n_cand, *plan)}  # what the run passes
    return estimate_matrix_bytes(n_pts, n_cand, density, layout_name(layout, graded),
                                 tree=1.0 if mode == "quality" else 0.0, **solve)


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
    args = ap.parse_args()
    args.instance = graded_instance(Path(tempfile.mkdtemp(prefix="camplace-graded-"))) if args.graded else \
        "comet-67p-bunker"
    print(f"{'size':>16} {'layout':>6} {'wall s':>8} {'peak MB':>9} {'pairs':>12} {'B/pair':>7} {'guard MB':>8} "
          f"{'model MB':>8} {'est MB':>8} {'est/peak':>8} {'vs base':>8}  result")
    for size in args.sizes.split(","):
        n_cand, n_pts = (int(v) for v in size.lower().split("x"))
        runs = [run_once(n_cand, n_pts, args, "auto")]
        if not args.no_baseline:
            runs.append(run_once(n_cand, n_pts, args, "csr"))
        base = runs[1]["peak"] if len(runs) > 1 and "peak" in runs[1] else None
        for r in runs:
            if "error" in r:
                print(f"{size:>16} {r['layout']:>6}  failed: {r['error']}")
                continue
            pairs = r["observed"] or 0
            density = pairs / (n_cand * n_pts) if pairs else 0.0
            guard = guard_estimate(n_cand, n_pts, r["layout"], density, args.threads, args.graded, args.mode, args.k)
            est = guard + r["model"]  # a set-cover model's own estimate (made before building it) on top
            vs = f"{r['peak'] / base:.2f}" if base else "-"
            bpp = r["peak"] / pairs if pairs else float("nan")
            print(f"{size:>16} {layout_name(r['layout'], args.graded):>6} {r['wall_s']:8.1f} "
                  f"{r['peak'] / 2**20:9.0f} {pairs:12,d} {bpp:7.2f} {guard / 2**20:8.0f} {r['model'] / 2**20:8.0f} "
                  f"{est / 2**20:8.0f} {est / r['peak']:8.2f} {vs:>8}  "
                  f"{r['status']} {r['objective']:.6f} {r['selected']}", flush=True)


if __name__ == "__main__":
    main()
