"""How much a thread holding the interpreter's lock slows the casting threads, with no CPU contention.

One casting worker (``workers=1``) on the first allowed core; the visibility stage's waiting thread
(its ``idle`` work) moves itself to the second core and does one of:

- ``none``: nothing (no idle work at all);
- ``sleep``: sleeps 3 s (holds no lock: the baseline for the rest);
- ``python``: 3 s of pure Python (holds the lock but for the switch interval);
- ``real``: what a run does there (``camplace.pipeline._while_casting``: the solver's kernels
  loaded, the CSV text formatted).

``--switch`` adds the same with the interpreter's switch interval set (``sys.setswitchinterval``).
The two threads never share a core, so what the cast loses is the wait for the lock after each
compiled kernel (the convoy effect), which grows with the thread count on a machine with the
cores. Prints the cast's seconds (``visibility.cast``), median of ``--repeat``. Needs 2 cores.

    python benchmarks/gil_contention.py --repeat 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys

_CHILD = """
import os, sys, time
cores = sorted(os.sched_getaffinity(0))
os.sched_setaffinity(0, {cores[0]})
from camplace._cores import set_threads
set_threads(1)
import camplace.pipeline as P
from camplace.instance import resolve_instance
from camplace.visibility import engine as E
inst = resolve_instance(sys.argv[1], seed=None)
settings = P.resolve_settings(inst, candidates=int(sys.argv[2]), points=int(sys.argv[3]))
cands, pts = P.sampling_stage(inst, settings)
few, _ = P.sampling_stage(inst, P.resolve_settings(inst, candidates=64, points=int(sys.argv[3])))
E.compute_visibility(inst, few, pts, workers=1)
mode, switch = sys.argv[4], float(sys.argv[5])
if switch > 0:
    sys.setswitchinterval(switch)
def idle():
    os.sched_setaffinity(0, {cores[1]})
    t = time.perf_counter()
    if mode == "python":
        x = 0
        while time.perf_counter() - t < 3.0:
            for i in range(1000):
                x += i * i
    elif mode == "sleep":
        time.sleep(3.0)
    elif mode == "real":
        P._while_casting(inst, settings, cands, pts, True)()
vis = E.compute_visibility(inst, cands, pts, workers=1, idle=None if mode == "none" else idle)
print(vis.timings_s["visibility.cast"])
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--instance", default="comet-67p-bunker")
    ap.add_argument("--candidates", type=int, default=4_000)
    ap.add_argument("--points", type=int, default=50_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--switch", type=float, default=5e-4, help="the other switch interval, seconds")
    args = ap.parse_args()
    if len(os.sched_getaffinity(0)) < 2:
        raise SystemExit("gil_contention.py needs 2 allowed cores")
    plan = [(m, 0.0) for m in ("none", "sleep", "python", "real")] + [(m, args.switch) for m in ("python", "real")]
    secs: dict[tuple[str, float], list[float]] = {key: [] for key in plan}
    for _ in range(args.repeat):
        for mode, switch in plan:  # interleaved rounds
            out = subprocess.run([sys.executable, "-c", _CHILD, args.instance, str(args.candidates), str(args.points),
                                  mode, str(switch)], capture_output=True, text=True, check=True,
                                 env={**os.environ, "NUMBA_NUM_THREADS": "1"})
            secs[(mode, switch)].append(float(out.stdout.split()[-1]))
    base = statistics.median(secs[("sleep", 0.0)])
    print(f"one casting worker, {args.candidates} x {args.points}; the waiting thread on another core; "
          f"median of {args.repeat}")
    for (mode, switch), v in secs.items():
        label = f"{mode}" + (f", switch {switch * 1e3:g} ms" if switch else ", switch 5 ms")
        print(f"  {label:<26} cast {statistics.median(v):6.3f} s  ({statistics.median(v) - base:+.3f} s against sleep)")


if __name__ == "__main__":
    main()
