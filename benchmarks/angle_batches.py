"""The angle engine's bound after a fixed number of batches: a load-independent measure of the
bound side of issue 30 (comet-flyby, multiview, 2 views, minimum angle 20 degrees).

``solve_angle`` alone on a ladder matrix (:mod:`flyby_ladder`, cached), every column free, the
incumbent fixed (the columns given, or found once by greedy and swaps without a time limit and
cached under ``--cache``), batches of ``--batch`` tuples, the search stopped after the largest of
``--batches``; printed per checkpoint: the bound (a fraction of the total weight, as the ladder
prints it), the open tuples and the process CPU time of the search so far (both cores busy: CPU
is about 1.9 times the wall time). Not a test.

    PYTHONPATH=src python benchmarks/angle_batches.py --positions 32000 --batches 60 150
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--positions", type=int, default=32000)
    ap.add_argument("--batches", nargs="*", type=int, default=[60, 150])
    ap.add_argument("--cpu", nargs="*", type=float, default=[],
                    help="also the bound at the first batch after these seconds of search CPU (the search stops "
                         "after the last of them or of --batches)")
    ap.add_argument("--batch", type=int, default=8192)
    ap.add_argument("--start", nargs="*", type=int, default=None, help="the incumbent's columns (default: cached greedy)")
    ap.add_argument("--cache", default="/tmp/angle_batches_incumbent.json")
    args = ap.parse_args(argv)
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from flyby_ladder import MIN_ANGLE_DEG, flyby_inputs

    import camplace.solver.engines.angle.search as S
    from camplace.solver._support.deadline import Deadline

    got = flyby_inputs(args.positions)
    bits, w, pos, pts = got["matrix"], np.asarray(got["weights"], dtype=np.float64), got["positions"], got["points"]
    n = bits.shape[1]
    free = np.arange(n, dtype=np.int64)
    fixed = np.zeros(0, dtype=np.int64)
    k, views = 3, 2
    start = args.start
    if start is None:
        cache = json.load(open(args.cache)) if os.path.exists(args.cache) else {}
        start = cache.get(str(args.positions))
        if start is None:
            t = time.perf_counter()
            start = list(S.greedy_angle(bits, w, k, views, MIN_ANGLE_DEG, pos, pts, fixed, free))
            cache[str(args.positions)] = start
            json.dump(cache, open(args.cache, "w"))
            print(f"greedy and climb without a limit: {start} in {time.perf_counter() - t:.1f} s", flush=True)
    total_w = float(w[w > 0].sum())

    # the incumbent is the start alone
    S._Incumbent.run = lambda self, k, colw: None
    S._Incumbent.climb = lambda self, sel, stop, round_s=0.0: None
    S._BATCH = S._BATCH_MIN = args.batch
    want = sorted(set(args.batches)) or [0]
    cpus = sorted(set(args.cpu))
    rows: list[str] = []
    orig = S.best_first

    class Stop(Deadline):
        """No time limit; expired once the last batch is done."""

        def __init__(self) -> None:
            super().__init__(None)
            self.done = False

        def expired(self) -> bool:
            return self.done

    def best_first(front, expand, offer, threshold, deadline, stats, **kw):
        stop = Stop()
        state = {"i": 0, "cpu": time.process_time(), "wall": time.perf_counter()}

        def counted(tup, tup_bound):
            i = state["i"]
            cpu = time.process_time() - state["cpu"]
            due = [c for c in cpus if cpu >= c]
            for c in due:
                cpus.remove(c)
            if i in want or due:  # the bound after i batches: this batch's tuples are open too
                b = max(float(tup_bound.max()), front.top(), threshold())
                rows.append(f"{args.positions:6d} {i:5d} {b / total_w:.5f} {front.n_open + tup.shape[0]:9d} "
                            f"{time.process_time() - state['cpu']:7.1f} {time.perf_counter() - state['wall']:7.1f}")
                print(rows[-1], flush=True)
            state["i"] = i + 1
            if state["i"] >= want[-1] + 1 and not cpus:
                stop.done = True
            return expand(tup, tup_bound)

        return orig(front, counted, offer, threshold, stop, stats, **kw)

    S.best_first = best_first
    print(f"positions  batch   bound  open_tuples  cpu_s  wall_s   (load {os.getloadavg()[0]:.2f})", flush=True)
    t = time.perf_counter()
    out = S.solve_angle(bits, w, k, views, MIN_ANGLE_DEG, pos, pts, fixed, free, budget_bytes=8 << 30, start=start)
    st = out.stats
    print(f"incumbent {st.get('initial_incumbent', float('nan')) / total_w:.5f} {out.status} set-up "
          f"{st['time_setup_s']:.1f} s, search cpu {st['cpu_search_s']:.1f} s, {st['bound_evaluations']} bounds, "
          f"{st['refined']} refined, total {time.perf_counter() - t:.1f} s, load {os.getloadavg()[0]:.2f}", flush=True)
    print("refinement per level (log2 columns: tries, prunes, summed margin share removed, on):",
          {v: x for v, x in st.get("refine_levels", {}).items()}, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
