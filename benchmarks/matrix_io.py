"""Matrix I/O benchmark: the matrix store (visibility.cpm) against what it replaces, in one run.

Three measurements, each printing ratios against a baseline measured in the same run:

``matrix OUTDIR``
    The run's own stage timings (solution.json ``timings_s``): matrix write + cache store against
    the visibility stage (target <= 0.25). Then, in this process on OUTDIR's matrix: writing and
    reading the store against ``scipy.sparse.save_npz`` (zlib, the former ``visibility.npz``) and
    ``load_npz``, and the file sizes (target: the store no larger than the npz).
``solve OUTDIR``
    The whole ``camplace solve OUTDIR`` process (start-up, loading, solving, writing) against the
    solver's own ``time_s`` that it prints (target <= 1.3), --repeat times, median; and the peak
    RSS of the largest ``camplace solve`` process so far.
``visibility CANDIDATES_CSV --points M``
    The whole ``camplace visibility comet-67p-bunker --candidates CANDIDATES_CSV --points M --no-cache``
    process (writing included) against the naive baseline of benchmarks/visibility.py: a segment for
    every (point, candidate) pair cast with raw embreex on 2 threads (target >= 2x), alternated
    --repeat times, median.

Usage::

    PYTHONPATH=src python benchmarks/matrix_io.py matrix OUT
    PYTHONPATH=src python benchmarks/matrix_io.py solve OUT --repeat 3
    PYTHONPATH=src python benchmarks/matrix_io.py visibility OUT/candidates.csv --points 20000 --repeat 2
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np


def load_line() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.1f} (1 min), {five:.1f} (5 min) on {os.cpu_count()} cores"


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def cmd_matrix(args: argparse.Namespace) -> None:
    import scipy.sparse as sp

    from camplace.visibility import store

    out = Path(args.outdir)
    sol_path = out / "solution.json"
    if sol_path.is_file():
        t = json.loads(sol_path.read_text()).get("timings_s", {})
        vis = t.get("visibility", float("nan"))
        io = t.get("write.matrix", 0.0) + t.get("cache.store", 0.0)
        print(f"run stage timings: visibility {vis:.2f} s (cache.store {t.get('cache.store', 0.0):.2f} s inside), "
              f"write.matrix {t.get('write.matrix', float('nan')):.2f} s, whole write {t.get('write', float('nan')):.2f} s, "
              f"solve {t.get('solve', float('nan')):.2f} s")
        print(f"  (write.matrix + cache.store) / (visibility - cache.store) = {io / max(vis - t.get('cache.store', 0.0), 1e-9):.3f}"
              "  (target <= 0.25)")
    src = store.matrix_path(out)
    t_load, a = timed(lambda: store.load_visibility(src))
    print(f"{src}: {a.shape[0]:,} x {a.shape[1]:,}, {a.nnz:,} pairs ({100 * a.nnz / max(1, a.shape[0] * a.shape[1]):.1f}%), "
          f"read in {t_load:.2f} s")
    with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
        tmp = Path(tmp)
        rows = []
        for rep in range(args.repeat):
            w_npz, _ = timed(lambda: sp.save_npz(tmp / "m.npz", a, compressed=True))
            r_npz, b = timed(lambda: sp.load_npz(tmp / "m.npz").tocsr())
            del b
            w_cpm, _ = timed(lambda: store.save_visibility(tmp / "m.cpm", a))
            r_cpm, b = timed(lambda: store.load_visibility(tmp / "m.cpm"))
            assert all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("indptr", "indices", "data"))
            del b
            rows.append((w_npz, w_cpm, r_npz, r_cpm))
            print(f"  run {rep + 1}: write npz {w_npz:.2f} s / cpm {w_cpm:.2f} s; read npz {r_npz:.2f} s / cpm {r_cpm:.2f} s")
        med = [statistics.median(c) for c in zip(*rows)]
        size_npz, size_cpm = (tmp / "m.npz").stat().st_size, (tmp / "m.cpm").stat().st_size
    print(f"write: npz {med[0]:.2f} s, cpm {med[1]:.2f} s = {med[0] / med[1]:.1f}x faster")
    print(f"read:  npz {med[2]:.2f} s, cpm {med[3]:.2f} s = {med[2] / med[3]:.1f}x faster")
    print(f"size:  npz {size_npz / 1e6:.1f} MB, cpm {size_cpm / 1e6:.1f} MB = {size_cpm / size_npz:.3f} of the npz (target <= 1)")
    print(load_line())


def cmd_solve(args: argparse.Namespace) -> None:
    ratios = []
    for rep in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "camplace", "solve", str(args.outdir), "-o", f"{tmp}/s.json"],
                                  capture_output=True, text=True, check=True)
            wall = time.perf_counter() - t0
            res = json.loads(Path(f"{tmp}/s.json").read_text())
        solver_s = float(res["time_s"])
        load_s = res.get("timings_s", {}).get("load", float("nan"))
        ratios.append(wall / solver_s)
        peak_gib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20  # KiB: the largest child so far
        print(f"  run {rep + 1}: process {wall:.2f} s, solver time_s {solver_s:.2f} s, load {load_s:.2f} s, "
              f"ratio {wall / solver_s:.2f}, peak RSS {peak_gib:.2f} GiB  [{proc.stdout.splitlines()[0]}]")
    print(f"camplace solve: whole process / solver time_s = {statistics.median(ratios):.2f} (median; target <= 1.3)")
    print(load_line())


def naive_baseline(inst, cands, pts) -> float:
    """Seconds to cast a segment for every (point, candidate) pair with raw embreex on 2 threads
    against frame 0's full scene, no culling (as benchmarks/visibility.py)."""
    from camplace.visibility import frame_scene
    from camplace.visibility.engine import EPS_REL

    scene = frame_scene(inst, 0)._scene
    tv = inst.target_world(0)[0]
    eps = EPS_REL * float(np.linalg.norm(np.ptp(tv, axis=0)))
    ends = (pts.positions + eps * pts.normals).astype(np.float32)
    pos32 = cands.positions.astype(np.float32)
    m = len(ends)

    def naive(j0: int):
        c = pos32[j0:j0 + 32]
        o = np.repeat(c, m, axis=0)
        d = np.tile(ends, (len(c), 1)) - o
        return scene.run(o, d, dists=np.ones(len(o), np.float32), query="OCCLUDED")

    with ThreadPoolExecutor(2) as pool:
        t0 = time.perf_counter()
        list(pool.map(naive, range(0, len(pos32), 32)))
        return time.perf_counter() - t0


def cmd_visibility(args: argparse.Namespace) -> None:
    from camplace.instance import builtin
    from camplace.visibility.stages import compute_points
    from camplace.sampling import CandidateSet

    inst = builtin("comet-67p-bunker")
    cands = CandidateSet.load(args.candidates_csv)
    pts = compute_points(inst, args.points, args.seed)
    print(f"comet-67p-bunker: {len(cands):,} candidates x {len(pts):,} points")
    ratios = []
    for rep in range(args.repeat):
        with tempfile.TemporaryDirectory(dir=args.tmp) as tmp:
            t0 = time.perf_counter()
            proc = subprocess.run(
                [sys.executable, "-m", "camplace", "visibility", "comet-67p-bunker", "--candidates", str(args.candidates_csv),
                 "--points", str(args.points), "--seed", str(args.seed), "--no-cache", "-o", tmp],
                capture_output=True, text=True, check=True,
            )
            ours = time.perf_counter() - t0
            size = sum(p.stat().st_size for p in Path(tmp).iterdir() if p.name.startswith("visibility."))
        naive = naive_baseline(inst, cands, pts)
        ratios.append(naive / ours)
        pairs = re.search(r"(\d+) observed pairs", proc.stdout)
        print(f"  run {rep + 1}: camplace visibility (whole process, matrix {size / 1e6:.1f} MB written) {ours:.2f} s; "
              f"naive raw embreex {naive:.2f} s; speed-up {naive / ours:.2f}x ({pairs.group(1) if pairs else '?'} pairs)")
    print(f"camplace visibility whole process vs naive raw embreex: {statistics.median(ratios):.2f}x (median; target >= 2)")
    print(load_line())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    p = sub.add_parser("matrix")
    p.add_argument("outdir", type=Path)
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--tmp", default=None, help="folder for the temporary files (default: the system's)")
    p = sub.add_parser("solve")
    p.add_argument("outdir", type=Path)
    p.add_argument("--repeat", type=int, default=3)
    p = sub.add_parser("visibility")
    p.add_argument("candidates_csv", type=Path)
    p.add_argument("--points", type=int, default=20000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--tmp", default=None)
    args = ap.parse_args()
    print(load_line())
    {"matrix": cmd_matrix, "solve": cmd_solve, "visibility": cmd_visibility}[args.what](args)


if __name__ == "__main__":
    main()
