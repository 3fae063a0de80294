"""The k = 3 max-coverage solve's stages alone at 1 and 2 threads, interleaved (issue 29).

Each measurement is a fresh process (``--worker``) that loads a run folder's matrix, runs presolve
(the bit presolve on a binary folder's column bitsets, as ``camplace run`` does)
and the exact engine (views = 1) once to warm up and then ``--inner`` more times at ``--threads T``
(:func:`camplace._cores.set_threads`), and reports per stage: wall seconds, the main thread's CPU
seconds and the pool's CPU seconds (every worker, and the busiest one:
:class:`camplace._blocks.PoolProfile`). The driver runs these processes interleaved
(1 thread, 2 threads, 1, 2, ...; with ``--baseline SRC`` also that source tree, e.g. main, at 1
thread in the same rounds), prints the load average, the median wall times and ratios, and a
load-independent estimate: ``main CPU + busiest worker's CPU`` is about what a stage takes on idle
cores (on a shared machine the wall ratio mostly shows how busy the other core was). It checks
that every thread count gives the same presolve output and answer.

    python benchmarks/solver_cores.py RUN_FOLDER [--k 3] [--repeat 3] [--baseline /work/main/src]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

STAGES = ("presolve", "incumbent", "search", "solve")


def worker(args: argparse.Namespace) -> None:
    import numpy as np

    from camplace._cores import set_threads
    from camplace.solver.cli import load_problem
    from camplace.solver.engines.bitset.search import solve_bitset
    from camplace.solver.problem.presolve import presolve

    try:
        from camplace._blocks import PoolProfile
    except ImportError:  # a tree without the pool (main before issue 29)
        PoolProfile = None
    matrix, weights, _, _ = load_problem(args.folder)
    if getattr(matrix, "format", None) == "bits":  # a binary run folder: the bit presolve the run uses
        from camplace.solver.problem.presolve_bits import presolve_bits as presolve
    set_threads(args.threads)
    rec: dict[str, list[float]] = {}
    for it in range(args.inner + 1):
        prof = PoolProfile() if PoolProfile else None
        if prof:
            prof.__enter__()
        w0, c0 = time.perf_counter(), time.thread_time()
        pre = presolve(matrix, weights, args.k)
        w1, c1 = time.perf_counter(), time.thread_time()
        p1 = (prof.cpu, prof.critical) if prof else (0.0, 0.0)
        out = solve_bitset(pre, views=1)
        w2, c2 = time.perf_counter(), time.thread_time()
        p2 = (prof.cpu, prof.critical) if prof else (0.0, 0.0)
        if prof:
            prof.__exit__()
        if it == 0:
            continue  # warm-up (numba's cache, page cache)
        s = out.stats
        vals = {"presolve": w1 - w0, "incumbent": s["time_incumbent_s"], "search": s["time_search_s"], "solve": w2 - w0,
                "presolve_est": (c1 - c0) + p1[1], "engine_est": (c2 - c1) + p2[1] - p1[1],
                "presolve_pool_cpu": p1[0], "engine_pool_cpu": p2[0] - p1[0]}
        for key, v in vals.items():
            rec.setdefault(key, []).append(v)
    digest = hashlib.sha256(b"".join(np.ascontiguousarray(x).tobytes() for x in
                                     (pre.weights, pre.counts, pre.columns, pre.row_groups))).hexdigest()[:16]
    print(json.dumps({"times": rec, "answer": [digest, out.status, out.bound, list(pre.original_columns(out.selected))],
                      "bounds": int(out.stats["bound_evaluations"])}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--k", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=3, help="rounds of processes (1, 2, [baseline 1]) interleaved")
    ap.add_argument("--inner", type=int, default=1, help="timed solves per process, after one warm-up")
    ap.add_argument("--baseline", default=None, help="another source tree (e.g. /work/main/src) timed at 1 thread")
    ap.add_argument("--threads", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args)
        return
    here = str(Path(__file__).resolve().parents[1] / "src")
    runs = [("1 thr", here, 1), ("2 thr", here, 2)] + ([("base 1", args.baseline, 1)] if args.baseline else [])
    print(f"{args.folder}, k = {args.k}; {len(os.sched_getaffinity(0))} allowed cores; "
          f"load average {os.getloadavg()[0]:.2f} at start")
    res: dict[str, dict[str, list[float]]] = {name: {} for name, _, _ in runs}
    answers = {}
    loads = []
    for rnd in range(args.repeat):
        for name, src, t in runs:
            env = {**os.environ, "PYTHONPATH": src, "NUMBA_NUM_THREADS": str(t)}
            cmd = [sys.executable, __file__, str(args.folder), "--worker", "--threads", str(t), "--k", str(args.k),
                   "--inner", str(args.inner)]
            proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
            if proc.returncode:
                raise SystemExit(proc.stderr[-3000:])
            out = json.loads(proc.stdout.strip().splitlines()[-1])
            loads.append(os.getloadavg()[0])
            for key, v in out["times"].items():
                res[name].setdefault(key, []).extend(v)
            answers[name] = tuple(json.dumps(out["answer"]).split()) + (out["bounds"],)
            print(f"  round {rnd} {name}: " + ", ".join(f"{s} {statistics.median(out['times'][s]):.2f}" for s in STAGES)
                  + f" s; load {loads[-1]:.2f}", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f} at end (during: {min(loads):.2f} .. {max(loads):.2f})")
    names = [n for n, _, _ in runs]
    med = {n: {k: statistics.median(v) for k, v in res[n].items()} for n in names}
    print(f"{'median s':<22}" + "".join(f"{n:>9}" for n in names) + f"{'1/2':>8}" + (f"{'base/1':>8}" if args.baseline else ""))
    for key in (*STAGES, "presolve_est", "engine_est", "presolve_pool_cpu", "engine_pool_cpu"):
        if key not in med["1 thr"]:
            continue
        row = f"{key:<22}" + "".join(f"{med[n].get(key, float('nan')):>9.3f}" for n in names)
        row += f"{med['1 thr'][key] / med['2 thr'][key]:>8.2f}" if med["2 thr"][key] > 0 else f"{'-':>8}"
        if args.baseline and key in med["base 1"] and med["1 thr"][key] > 0:
            row += f"{med['base 1'][key] / med['1 thr'][key]:>8.2f}"
        print(row)
    same = answers["1 thr"][:-1] == answers["2 thr"][:-1] and answers["1 thr"][-1] == answers["2 thr"][-1]
    print(f"same presolve output, answer and bound count at 1 and 2 threads: {'yes' if same else 'NO'} {answers['1 thr']}")
    if args.baseline:
        print(f"baseline answer: {answers['base 1']}")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
