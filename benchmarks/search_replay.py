"""The exact max-coverage search's rounds replayed at T threads from its roots' measured times (issue 29).

A round of the roots search (:func:`camplace.solver.engines.bitset.search._roots_search`) ends with
its slowest root, so on many cores the size of the roots, not the cores, can set the search's
time. This script solves a run folder's matrix (``camplace solve`` as a user runs it) in one
process on one thread, times every root of every round, and lets each round's clock advance by the
time the round would take on T threads (the roots handed out in order to the first free thread,
as :func:`camplace._blocks.run_blocks` does), so the schedule (which, near a deadline only, reads
the rate) is the one a T-thread run makes. It prints per T the rounds, roots, the summed root
times, the replayed search time and the speed-up over the first T, for each ``--slice`` (bound
evaluations per root, ``_SLICE``). Memory bandwidth and clock speed are not modelled: a machine's
own ceiling is ``benchmarks/scaling.py``'s ``machine`` row.

On comet-67p-bunker 10,000 x 50,000 (a 2-core machine): 2,000 (the default) replays 6.9x from 2 to
16 threads, 20,000 3.9x (its rounds hold at most 25 roots). The schedule before (20,000 a root,
rounds sized by the rate) replayed 5.6x, where a lent 16-core machine measured 5.9x
(docs/performance.md).

    python benchmarks/search_replay.py RUN_FOLDER                     # --threads 2,16 --slice 20000,2000
    python benchmarks/search_replay.py RUN_FOLDER --threads 2,8,16,32 --slice 2000
"""

from __future__ import annotations

import argparse
import contextlib
import heapq
import io
import json
import os
import subprocess
import sys
import tempfile
import time
import types


def makespan(durations: list[float], threads: int) -> float:
    """Seconds the blocks of ``durations`` take when each goes, in order, to the first free of ``threads``."""
    free = [0.0] * threads
    for d in durations:
        heapq.heappush(free, heapq.heappop(free) + d)
    return max(free)


def replay(folder: str, threads: int, slice_: int) -> dict:
    """One solve of ``folder`` in this process at one thread, replayed at ``threads``."""
    from camplace._cores import set_threads
    from camplace.solver.engines.bitset import search

    set_threads(1)
    search._SLICE = slice_
    shift = [0.0]  # the replayed clock runs behind the real one by the rounds' saved time
    search.time = types.SimpleNamespace(perf_counter=lambda: time.perf_counter() - shift[0])
    real_blocks = search.run_blocks
    stat = {"rounds": 0, "roots": 0, "cpu_s": 0.0, "search_s": 0.0}

    def run_blocks(fn, bounds, _threads=None):
        times: list[float] = []

        def timed(lo, hi):
            t0 = time.perf_counter()
            out = fn(lo, hi)
            times.append(time.perf_counter() - t0)
            return out

        t0 = time.perf_counter()
        out = real_blocks(timed, bounds, 1)
        real = time.perf_counter() - t0
        replayed = makespan(times, threads)
        shift[0] += real - replayed
        stat["rounds"] += 1
        stat["roots"] += len(times)
        stat["cpu_s"] += sum(times)
        stat["search_s"] += replayed
        return out

    search.run_blocks = run_blocks
    from camplace.cli import console

    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "solve.json")
        sys.argv = ["camplace", "solve", folder, "-o", out, "--threads", "1"]
        with contextlib.redirect_stdout(io.StringIO()):
            try:
                console()
            except SystemExit as e:
                if e.code:
                    raise
        sol = json.load(open(out))
    stat.update(objective=sol["objective"], selected=sol["selected"], status=sol["status"])
    return stat


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder", help="a run folder (camplace run ... -o FOLDER) or its matrix file")
    ap.add_argument("--threads", default="2,16", help="comma-separated thread counts to replay")
    ap.add_argument("--slice", default="20000,2000", help="comma-separated bound evaluations per root")
    ap.add_argument("--worker", nargs=2, type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(replay(args.folder, *args.worker)))
        return
    counts = [int(x) for x in args.threads.split(",")]
    print(f"search of {args.folder} replayed from one thread's root times; {os.cpu_count()} cores here")
    print(f"{'slice':>7s} {'T':>3s} {'rounds':>6s} {'roots':>6s} {'cpu s':>7s} {'search s':>8s} {'x':>6s}  answer")
    for s in (int(x) for x in args.slice.split(",")):
        first = None
        for t in counts:
            proc = subprocess.run([sys.executable, __file__, args.folder, "--worker", str(t), str(s)],
                                  capture_output=True, text=True, check=True)
            r = json.loads(proc.stdout.strip().splitlines()[-1])
            first = first or r["search_s"]
            print(f"{s:7d} {t:3d} {r['rounds']:6d} {r['roots']:6d} {r['cpu_s']:7.3f} {r['search_s']:8.3f} "
                  f"{first / r['search_s']:6.2f}  {r['status']} {r['objective']:.6f} {r['selected']}")


if __name__ == "__main__":
    main()
