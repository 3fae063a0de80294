"""Visibility benchmark: camplace's matrix against raw embreex, on comet-67p-bunker.

Prints, from one run on this machine:

- raw embreex throughput: OCCLUDED segment queries on 2 threads over exactly the segments
  camplace casts, each against the scene camplace casts it against (prebuilt float32 arrays,
  nothing else timed);
- camplace's throughput per cast segment: segments cast / the wall time of the whole matrix
  computation (culling, casting, assembly), and its ratio to the raw figure (target >= 0.8);
  timed on the second call in the process (warm memory, kernels loaded; the first call is printed
  too);
- the naive baseline: build and cast a segment for every (point, candidate) pair with raw embreex
  on 2 threads against the full scene, no culling; camplace's end-to-end speed-up over it
  (target >= 2x);
- peak memory (RSS) of the visibility stage, measured in a fresh child process.

Usage: python benchmarks/visibility.py [--candidates 5000] [--points 20000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np


def setup(n_cand: int, n_points: int):
    from camplace.instance import builtin
    from camplace.event import event_aims
    from camplace.visibility.stages import compute_points, stage_seeds
    from camplace.sampling import make_candidates

    inst = builtin("comet-67p-bunker")
    pts = compute_points(inst, n_points, 0)
    cands = make_candidates("chaotic", n_cand, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=stage_seeds(0)[0])
    return inst, cands, pts


def peak_rss_mib() -> float:
    """This process's peak resident set size (VmHWM; unlike ru_maxrss it is not inherited through fork)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child_rss(n_cand: int, n_points: int) -> None:
    """Run only the visibility stage and print its wall time and the process's peak RSS."""
    from camplace.visibility import compute_visibility

    inst, cands, pts = setup(n_cand, n_points)
    before = peak_rss_mib()
    t0 = time.perf_counter()
    vis = compute_visibility(inst, cands, pts, workers=2)
    wall = time.perf_counter() - t0
    print(json.dumps({"wall_s": wall, "peak_rss_mib": peak_rss_mib(), "rss_before_mib": before, "nnz": int(vis.matrix.nnz)}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--candidates", type=int, default=5000)
    ap.add_argument("--points", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=3, help="steady-state runs of camplace and of raw embreex (median)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child_rss(args.candidates, args.points)
        return

    from camplace.visibility import compute_visibility
    from camplace.visibility.engine import chunk_plan, compute_chunk, default_chunk_size, make_task
    from camplace.visibility.raycast import RayScene

    inst, cands, pts = setup(args.candidates, args.points)
    m, n = len(pts), len(cands)
    print(f"comet-67p-bunker: {n:,} candidates x {m:,} points = {m * n:,} pairs; 2 threads")

    # 1. camplace end to end (culling + casting + assembly), no cache. The first call in a process
    #    also loads the compiled kernels and touches fresh memory (on this VM a first touch of a
    #    page costs about 2-3 ms per MB); it is printed apart. The steady-state figure is the median
    #    of --repeat calls, each followed by one raw embreex run (2.), so both see the same load.
    t0 = time.perf_counter()
    vis = compute_visibility(inst, cands, pts, workers=2)
    cold_s = time.perf_counter() - t0
    cast = vis.stats["cast"]
    print(f"camplace matrix, first call in the process (kernels loaded, fresh memory): {cold_s:.2f} s, "
          f"{cast:,} segments cast ({100 * cast / (m * n):.1f}% of pairs), {vis.matrix.nnz:,} observed")
    nnz = vis.matrix.nnz
    del vis

    # 2. the exact segments camplace casts (each with the scene it is cast against), recorded by
    #    replaying the computation chunk by chunk as compute_visibility does, then cast with raw
    #    embreex on 2 threads
    from camplace.visibility.engine import FrameScenes

    task, scenes = make_task(inst, cands, pts)
    batches: list[tuple[object, np.ndarray, np.ndarray]] = []

    class Replay(RayScene):
        def __init__(self, inner: RayScene) -> None:
            self.__dict__.update(inner.__dict__)

        def occluded_dir(self, origins, directions, out=None):
            batches.append((self._scene, np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(directions, np.float32)))
            return super().occluded_dir(origins, directions, out=out)

    rep_scenes = {f: FrameScenes(Replay(s.full), Replay(s.rest)) for f, s in scenes.items()}
    for a, b in chunk_plan(n, default_chunk_size(task), 2):  # the chunks compute_visibility casts
        compute_chunk(task, rep_scenes, a, b)
    n_seg = sum(len(o) for _, o, _ in batches)
    assert n_seg == cast, (n_seg, cast)
    ones = [np.ones(len(o), np.float32) for _, o, _ in batches]
    raw_scene = scenes[0].full._scene

    def raw(i: int):
        sc, o, d = batches[i]
        return sc.run(o, d, dists=ones[i], query="OCCLUDED")

    ours_runs, raw_runs = [], []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        vis = compute_visibility(inst, cands, pts, workers=2)
        ours_runs.append(time.perf_counter() - t0)
        assert vis.matrix.nnz == nnz
        del vis
        with ThreadPoolExecutor(2) as pool:
            t0 = time.perf_counter()
            list(pool.map(raw, range(len(batches))))
            raw_runs.append(time.perf_counter() - t0)
    ours_s, raw_s = statistics.median(ours_runs), statistics.median(raw_runs)
    runs = ", ".join(f"{a:.2f}/{b:.2f}" for a, b in zip(ours_runs, raw_runs))
    print(f"steady state, {args.repeat} runs (camplace/raw s): {runs}")
    raw_tp = n_seg / raw_s
    ours_tp = cast / ours_s
    print(f"camplace matrix (median): {ours_s:.2f} s")
    print(f"raw embreex OCCLUDED on the same segments (median): {raw_s:.2f} s = {raw_tp / 1e6:.2f} M segments/s")
    print(f"camplace per cast segment (end to end):   {ours_tp / 1e6:.2f} M segments/s = {ours_tp / raw_tp:.2f} x raw "
          f"(target >= 0.8)")

    # 3. naive baseline: a segment for every pair, raw embreex, 2 threads, no culling
    eps = float(task.eps_m[0])
    ends = (pts.positions + eps * pts.normals).astype(np.float32)
    pos32 = cands.positions.astype(np.float32)

    def naive(j0: int):
        c = pos32[j0:j0 + 32]
        o = np.repeat(c, m, axis=0)
        d = np.tile(ends, (len(c), 1)) - o
        return raw_scene.run(o, d, dists=np.ones(len(o), np.float32), query="OCCLUDED")

    with ThreadPoolExecutor(2) as pool:
        t0 = time.perf_counter()
        list(pool.map(naive, range(0, n, 32)))
        naive_s = time.perf_counter() - t0
    print(f"naive baseline (every pair cast, no culling): {naive_s:.2f} s for {m * n:,} segments")
    print(f"camplace end-to-end speed-up over naive:      {naive_s / ours_s:.2f} x (target >= 2)")

    # 4. peak RSS of the visibility stage alone, in a fresh process
    out = subprocess.run(
        [sys.executable, __file__, "--child", "--candidates", str(n), "--points", str(m)],
        capture_output=True, text=True, check=True,
    )
    child = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"visibility stage in a fresh process: {child['wall_s']:.2f} s, peak RSS {child['peak_rss_mib']:.0f} MiB "
          f"(process before the stage: {child['rss_before_mib']:.0f} MiB); matrix {nnz:,} nnz = "
          f"{(8 * nnz + 4 * (m + 1)) / 2**20:.0f} MiB as float32 CSR")


if __name__ == "__main__":
    main()
