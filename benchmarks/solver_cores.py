"""The k = 3 max-coverage path's kernels alone at 1 and 2 threads, interleaved (issue 29).

Loads a run folder's matrix once, then times, per repetition and thread count (1, 2, 1, 2, ...):
presolve (its kernels on the thread pool), the incumbent (``shortfall_all`` passes of greedy +
swap) and the search of the bitset engine (views = 1), in this process with
:func:`camplace._cores.set_threads`. Prints the median seconds, the ratio 1 thread / T threads, the
load average, and checks that every thread count gives the same presolve output and answer.

    python benchmarks/solver_cores.py RUN_FOLDER [--k 3] [--repeat 3] [--threads 1,2]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", type=Path)
    ap.add_argument("--k", type=int, default=3)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", default="1,2")
    args = ap.parse_args()
    from camplace._cores import set_threads
    from camplace.solver.cli import load_problem
    from camplace.solver.engines.bitset.search import solve_bitset
    from camplace.solver.problem.presolve import presolve

    matrix, weights, _, _ = load_problem(args.folder)
    counts = [int(t) for t in args.threads.split(",")]
    print(f"{args.folder}: {matrix.shape[0]} x {matrix.shape[1]}, k = {args.k}; load average {os.getloadavg()[0]:.2f} at start")
    times: dict[int, dict[str, list[float]]] = {t: {"presolve": [], "bitsets": [], "incumbent": [], "search": [],
                                                    "solve": []} for t in counts}
    answers = {}
    for rep in range(args.repeat + 1):  # the first round warms numba's cache and is not counted
        for t in counts:
            set_threads(t)
            t0 = time.perf_counter()
            pre = presolve(matrix, weights, args.k)
            t1 = time.perf_counter()
            out = solve_bitset(pre, views=1)
            t2 = time.perf_counter()
            digest = hashlib.sha256(b"".join(np.ascontiguousarray(x).tobytes() for x in
                                             (pre.weights, pre.counts, pre.columns, pre.row_groups))).hexdigest()[:16]
            answers[t] = (digest, out.status, out.bound, pre.original_columns(out.selected))
            if rep:
                s = out.stats
                for name, v in (("presolve", t1 - t0), ("bitsets", s["time_bitsets_s"]),
                                ("incumbent", s["time_incumbent_s"]),
                                ("search", s["time_search_s"]), ("solve", t2 - t0)):
                    times[t][name].append(v)
            print(f"  round {rep} threads {t}: presolve {t1 - t0:.2f} s, engine {t2 - t1:.2f} s "
                  f"(search {out.stats['time_search_s']:.2f} s, {out.stats['bound_evaluations']} bounds), "
                  f"load {os.getloadavg()[0]:.2f}", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f} at end")
    base = counts[0]
    print(f"{'stage (s)':<12}" + "".join(f"{f'{t} thr':>9}" for t in counts) + "".join(f"{f'x{t}':>8}" for t in counts[1:]))
    for name in times[base]:
        med = {t: statistics.median(times[t][name]) for t in counts}
        print(f"{name:<12}" + "".join(f"{med[t]:>9.3f}" for t in counts)
              + "".join(f"{med[base] / med[t]:>8.2f}" for t in counts[1:]))
    same = len(set(answers.values())) == 1
    print(f"same presolve output and answer at every thread count: {'yes' if same else 'NO'} {answers[base][1:]}")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
