"""The visibility stage alone at T threads, with and without what shares the process with its rays.

At 16 threads the visibility stage of ``camplace run comet-67p-bunker --candidates 10000 --points
50000`` ran 4.8x faster than at 2 on a lent 16-core machine, while Embree alone, on the same machine
and the same packet path, ran 7.7x faster (``benchmarks/scaling.py``'s ``embree`` row;
docs/performance.md). Two things share the interpreter's lock with the casting threads there: the
waiting thread's work beside the rays (the solver's kernels loaded, the CSV text formatted:
``camplace.pipeline._while_casting``, about 0.4 s of Python on this machine) and each chunk's own
Python around its compiled call (0.4 ms of a 47-49 ms chunk, 0.6 ms before the camera-by-camera
cast). This script times the stage in one process per (T, variant), pinned to the first T allowed
cores, so that a machine with the cores can say which of them costs what:

- ``idle``: as a run does it (the waiting thread's work beside the rays);
- ``no-idle``: that work left out (a run would do it after the stage, serially);
- ``idle-0.5ms``: as a run, with the interpreter's switch interval at 0.5 ms instead of 5 ms (a
  thread that wants the lock back after a kernel waits at most that long);
- ``chunk-x4``: no waiting work, chunks four times the default (a quarter of the Python steps);
- ``chunk-quarter``: no waiting work, chunks a quarter of the default (a quarter of the cameras
  a chunk's compiled call walks);
- ``whole-chunk``: no waiting work, each chunk cast as a whole as before (culling, segments, Embree
  and the bits in four compiled calls over all its pairs, work arrays of about 34 bytes a kept pair
  of the chunk) instead of camera by camera in one call (``_kernels.cast_chunk``, work arrays of one
  camera's pairs): whether the camera-by-camera cast closes part of the gap at 16 threads.

``benchmarks/gil_contention.py`` measures the first effect alone on 2 cores.

Prints the cast's seconds (``visibility.cast``, median of ``--repeat``) per variant and thread
count and the speed-up over the first count; checks that every variant gives the same bits.

    python benchmarks/visibility_threads.py --threads 1,2 --repeat 2
    python benchmarks/visibility_threads.py --threads 2,16 --repeat 2     # on a machine with the cores
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys

VARIANTS = ("idle", "no-idle", "idle-0.5ms", "chunk-x4", "chunk-quarter", "whole-chunk")

_CHILD = """
import hashlib, sys, time
import numpy as np
instance_name, candidates, points, threads, variant = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
from camplace._cores import set_threads
set_threads(threads)
import camplace.pipeline as P
from camplace.instance import resolve_instance
from camplace.visibility import engine as E
inst = resolve_instance(instance_name, seed=None)
settings = P.resolve_settings(inst, candidates=candidates, points=points)
cands, pts = P.sampling_stage(inst, settings)
few, _ = P.sampling_stage(inst, P.resolve_settings(inst, candidates=64, points=points))
E.compute_visibility(inst, few, pts, workers=threads)  # the kernels loaded, as a run's first chunk does
idle = P._while_casting(inst, settings, cands, pts, True) if variant.startswith("idle") else None
if variant == "idle-0.5ms":
    sys.setswitchinterval(5e-4)
if variant == "whole-chunk":
    from camplace.visibility import chunk as C
    C._packet_scenes = lambda *a: None  # the chunk's steps over all its pairs, then set_bits
chunk = None
if variant.startswith("chunk"):
    task, _ = E.make_task(inst, cands, pts, quantised=False)
    chunk = 4 * E.default_chunk_size(task) if variant == "chunk-x4" else max(1, E.default_chunk_size(task) // 4)
vis = E.compute_visibility(inst, cands, pts, workers=threads, idle=idle, chunk_size=chunk)
print(vis.timings_s["visibility.cast"], hashlib.sha256(vis.bits.words.tobytes()).hexdigest()[:16])
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--instance", default="comet-67p-bunker")
    ap.add_argument("--candidates", type=int, default=10_000)
    ap.add_argument("--points", type=int, default=50_000)
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    args = ap.parse_args()
    cores = sorted(os.sched_getaffinity(0))
    counts = [int(t) for t in args.threads.split(",")]
    variants = args.variants.split(",")
    print(f"visibility of {args.instance}, {args.candidates} x {args.points}; {len(cores)} allowed cores, "
          f"load {os.getloadavg()[0]:.1f}")
    secs: dict[tuple[str, int], list[float]] = {}
    digests = set()
    for r in range(args.repeat):
        for t in counts:
            for v in variants:
                cmd = [sys.executable, "-c", _CHILD, args.instance, str(args.candidates), str(args.points), str(t), v]
                if shutil.which("taskset"):
                    cmd = ["taskset", "-c", ",".join(map(str, cores[:t])), *cmd]
                proc = subprocess.run(cmd, capture_output=True, text=True,
                                      env={**os.environ, "NUMBA_NUM_THREADS": str(t)})
                if proc.returncode:
                    raise SystemExit(f"T={t} {v} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
                out = proc.stdout.split()
                secs.setdefault((v, t), []).append(float(out[-2]))
                digests.add(out[-1])
                print(f"  round {r} T={t} {v}: cast {float(out[-2]):.2f} s", flush=True)
    print(f"{'variant':<12}" + "".join(f"{f'{t} thr':>9}" for t in counts) + "".join(f"{f'x{t}':>8}" for t in counts[1:]))
    for v in variants:
        med = [statistics.median(secs[(v, t)]) for t in counts]
        print(f"{v:<12}" + "".join(f"{m:>9.2f}" for m in med) + "".join(f"{med[0] / m:>8.2f}" for m in med[1:]))
    print(f"same bits in every variant and count: {'yes' if len(digests) == 1 else 'NO'}")
    if len(digests) != 1:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
