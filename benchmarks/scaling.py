"""Whole commands at 1, 2, ... threads: per-stage times, speed-ups and the serial fraction they imply.

Runs ``camplace run INSTANCE --candidates N --points M --no-cache`` as a user would, once per
thread count T, pinned to the first T allowed cores (``taskset``) with ``--threads T`` (which also
sets numba's thread count), after one warm-up run that fills numba's cache. Prints, per stage of
``solution.json``'s ``timings_s`` and for the whole process (wall clock of the subprocess): the
seconds at each T, the speed-up against T = 1 and the serial fraction that speed-up implies
(Amdahl's law read backwards, the Karp-Flatt metric: ``f = (1/S - 1/T) / (1 - 1/T)``; 0 is perfectly
parallel, 1 is serial). It also checks that every thread count gives the same matrix bytes and the
same objective, bound and cameras.

Two more lines read the serial fractions for a larger machine. ``machine``: a compiled loop with
no serial part and no memory traffic (:data:`_CALIBRATE`), run under the same ``taskset`` at each
T: the speed-up the cores themselves give (a shared or virtual machine gives less than T); the
``fc`` column is then the stage's serial fraction against that ceiling instead of against T (what
the code itself keeps serial). ``predicted``: the whole process's time at ``--predict`` threads
(default 16) from Amdahl's law with the fraction measured at the largest T, as a ratio to the
time at 2 threads (issue 29's goal: >= 6x from 2 to 16). ``embree``: Embree's own speed-up,
6,000,000 occlusion segments of the instance cast through the visibility stage's packet path from
T Python threads (:data:`_CALIBRATE_EMBREE`): the ceiling of the visibility stage on these cores.

    python benchmarks/scaling.py                       # 10,000 x 50,000 on comet-67p-bunker
    python benchmarks/scaling.py --candidates 2000 --points 20000 --threads 1,2
    python benchmarks/scaling.py --mode multiview --min-angle 20
    python benchmarks/scaling.py --threads 1,2 --repeat 2 --baseline /work/main/src   # + main at 1 thread

Targets (issue 29, on the 2-core machine): visibility, presolve and search >= 1.8x at 2 threads,
the whole process >= 1.7x.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STAGES = (
    ("startup", "startup"),
    ("setup", "setup"),
    ("sampling", "sampling"),
    ("visibility", "visibility"),
    ("  cast", "visibility.cast"),
    ("solve", "solve"),
    ("  presolve", "solver.presolve.time_s"),
    ("  search", "solver.engine_stats.time_search_s"),
    ("  incumbent", "solver.engine_stats.time_incumbent_s"),
    ("summary", "summary"),
    ("write", "write"),
    ("untimed", "process.untimed"),
)


def run_once(args: argparse.Namespace, threads: int, cores: list[int], out: Path,
             src: str | None = None) -> tuple[float, dict, dict]:
    """One whole command on ``threads`` cores (``src``: another source tree on PYTHONPATH):
    (wall seconds, timings_s, solution.json)."""
    env = {**os.environ, "NUMBA_NUM_THREADS": str(threads), **({"PYTHONPATH": src} if src else {})}
    cmd = [sys.executable, "-m", "camplace", "run", args.instance, "-o", str(out), "--no-cache",
           "--candidates", str(args.candidates), "--points", str(args.points), "--threads", str(threads),
           *args.extra]
    if shutil.which("taskset"):
        cmd = ["taskset", "-c", ",".join(map(str, cores[:threads])), *cmd]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    sol = json.loads((out / "solution.json").read_text())
    return wall, sol["timings_s"], sol


#: the calibration loop (``python -c``): T threads of pure arithmetic, best of five, seconds
_CALIBRATE = """
import time, numba, numpy as np
@numba.njit(parallel=True, cache=False)
def work(n, reps):
    out = np.zeros(n)
    for i in numba.prange(n):
        s = 0.0
        x = i * 1e-7
        for r in range(reps):
            s += np.sin(x + r * 1e-3)
        out[i] = s
    return out
work(64, 10)
best = 1e9
for _ in range(5):
    t = time.perf_counter(); work(1 << 15, 2000); best = min(best, time.perf_counter() - t)
print(best)
"""


#: Embree's own ceiling (``python -c``, argv: instance, threads): 6,000,000 occlusion segments from
#: the sampling volume to target vertices of the instance's first frame, cast through the same packet
#: path as the visibility stage (:meth:`RayScene.occluded_dir`) from ``threads`` Python threads in
#: chunks of 65,536; best of three, seconds
_CALIBRATE_EMBREE = """
import sys, time
from concurrent.futures import ThreadPoolExecutor
import numpy as np
from camplace.instance import resolve_instance
from camplace.visibility.engine import frame_scene
inst = resolve_instance(sys.argv[1], seed=None)
threads = int(sys.argv[2])
scene = frame_scene(inst, 0)
rng = np.random.default_rng(0)
n = 6_000_000
lo, hi = np.asarray(inst.volume.min_m), np.asarray(inst.volume.max_m)
o = (lo + rng.random((n, 3)) * (hi - lo)).astype(np.float32)
v, _ = inst.target_world(0)
d = (np.asarray(v)[rng.integers(0, len(v), n)] - o).astype(np.float32)
out = np.empty(n, dtype=bool)
step = 65_536
def cast(a):
    scene.occluded_dir(o[a:a + step], d[a:a + step], out[a:a + step])
cast(0)
best = 1e9
with ThreadPoolExecutor(threads) as pool:
    for _ in range(3):
        t = time.perf_counter(); list(pool.map(cast, range(0, n, step))); best = min(best, time.perf_counter() - t)
print(best)
"""


def machine_seconds(threads: int, cores: list[int], script: str = _CALIBRATE, args: tuple = ()) -> float:
    """Seconds of a calibration script (:data:`_CALIBRATE`, :data:`_CALIBRATE_EMBREE`) on the first
    ``threads`` allowed cores."""
    cmd = [sys.executable, "-c", script, *map(str, args)]
    if shutil.which("taskset"):
        cmd = ["taskset", "-c", ",".join(map(str, cores[:threads])), *cmd]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=True,
                          env={**os.environ, "NUMBA_NUM_THREADS": str(threads)})
    return float(proc.stdout.split()[-1])


def karp_flatt(speedup: float, scale: float) -> float:
    """The serial fraction that ``speedup`` implies on ``scale`` times the cores (Karp-Flatt):
    ``(1/S - 1/p) / (1 - 1/p)``; NaN when undefined."""
    if not (speedup == speedup and speedup > 0 and scale > 1):
        return float("nan")
    return (1 / speedup - 1 / scale) / (1 - 1 / scale)


def amdahl(f: float, threads: float) -> float:
    """Speed-up on ``threads`` cores of work whose serial fraction is ``f`` (Amdahl's law)."""
    return 1 / (f + (1 - f) / threads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--instance", default="comet-67p-bunker")
    ap.add_argument("--candidates", type=int, default=10_000)
    ap.add_argument("--points", type=int, default=50_000)
    ap.add_argument("--threads", default=None, help="comma-separated thread counts (default: 1, 2, all allowed)")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of runs, thread counts interleaved (median shown)")
    ap.add_argument("--baseline", default=None,
                    help="another source tree (e.g. /work/main/src) run at the first thread count in every round, "
                         "shown as the column 'base'")
    ap.add_argument("--predict", type=int, default=16, help="threads to predict the whole process's speed-up at")
    args, extra = ap.parse_known_args()
    args.extra = extra
    cores = sorted(os.sched_getaffinity(0))
    counts = [int(t) for t in args.threads.split(",")] if args.threads else sorted({1, 2, len(cores)} & set(range(1, len(cores) + 1)))
    print(f"camplace run {args.instance} --candidates {args.candidates} --points {args.points} {' '.join(extra)}")
    print(f"{len(cores)} allowed cores, load average {os.getloadavg()[0]:.1f} at start")
    plan: list[tuple[object, int, str | None]] = [(t, t, None) for t in counts]
    if args.baseline:
        plan.append(("base", counts[0], args.baseline))
    with tempfile.TemporaryDirectory() as tmp:
        run_once(args, counts[-1], cores, Path(tmp) / "warm")  # fills numba's cache
        if args.baseline:
            run_once(args, counts[-1], cores, Path(tmp) / "warm-base", args.baseline)
        runs: dict[object, list[dict[str, float]]] = {key: [] for key, _, _ in plan}
        answers, matrices, base_answer = {}, {}, None
        for r in range(args.repeat):  # thread counts interleaved: 1, 2, [base], 1, 2, ...
            for key, t, src in plan:
                out = Path(tmp) / f"t{key}-{r}"
                wall, timings, sol = run_once(args, t, cores, out, src)
                runs[key].append({"whole": wall, **{name: float(timings.get(k, float("nan"))) for name, k in STAGES}})
                answer = (sol["status"], sol["objective"], sol["bound"], tuple(c["candidate"] for c in sol["cameras"]))
                if src is None:
                    answers.setdefault(t, answer)
                    matrices.setdefault(t, hashlib.sha256((out / "visibility.cpm").read_bytes()).hexdigest())
                else:
                    base_answer = answer
                shutil.rmtree(out)
                print(f"  round {r} {key}: whole {wall:.1f} s, load {os.getloadavg()[0]:.1f}", flush=True)
        rows = {key: {k: statistics.median(x[k] for x in v) for k in v[0]} for key, v in runs.items()}
        machine = {t: min(machine_seconds(t, cores) for _ in range(max(1, args.repeat))) for t in counts}
        embree = {t: machine_seconds(t, cores, _CALIBRATE_EMBREE, (args.instance, t)) for t in counts}
    print(f"load average {os.getloadavg()[0]:.1f} at end")
    if args.baseline:
        print(f"baseline {args.baseline} at {counts[0]} thread(s), against this tree at {counts[0]}: "
              + ", ".join(f"{name.strip()} {rows['base'][name]:.2f}/{rows[counts[0]][name]:.2f} s" for name in
                          ("whole", "visibility", "solve", "  presolve", "  search", "  incumbent"))
              + f"; same answer: {'yes' if base_answer == answers[counts[0]] else 'NO ' + str(base_answer)}")
    base = counts[0]
    ceiling = {t: machine[base] / machine[t] for t in counts}  # the cores' own speed-up over `base`
    head = "".join(f"{f'{t} thr':>9}" for t in counts) + "".join(f"{f'x{t}':>8}{f'f{t}':>7}{f'fc{t}':>7}"
                                                                 for t in counts[1:])
    print(f"{'stage (s)':<14}{head}")
    for name in ["whole", *(n for n, _ in STAGES)]:
        line = f"{name:<14}" + "".join(f"{rows[t][name]:>9.2f}" for t in counts)
        for t in counts[1:]:
            s = rows[base][name] / rows[t][name] if rows[t][name] > 0 else float("nan")
            line += f"{s:>8.2f}{karp_flatt(s, t / base):>7.2f}{karp_flatt(s, ceiling[t]):>7.2f}"
        print(line)
    print(f"{'machine':<14}" + "".join(f"{machine[t]:>9.3f}" for t in counts)
          + "".join(f"{ceiling[t]:>8.2f}{karp_flatt(ceiling[t], t / base):>7.2f}{'':>7}" for t in counts[1:]))
    print(f"{'embree':<14}" + "".join(f"{embree[t]:>9.3f}" for t in counts)
          + "".join(f"{embree[base] / embree[t]:>8.2f}{karp_flatt(embree[base] / embree[t], t / base):>7.2f}{'':>7}"
                    for t in counts[1:]))
    top = counts[-1]
    if 2 in counts and top > 2 and base != 2:  # the goal is read from 2 threads
        print(f"from 2 to {top} threads: " + ", ".join(
            f"{name.strip()} {rows[2][name] / rows[top][name]:.2f}x" for name in ("whole", "visibility", "solve")
            if rows[top][name] > 0) + f" (the cores: {machine[2] / machine[top]:.2f}x, Embree: {embree[2] / embree[top]:.2f}x)")
    if base == 1 and top > 1 and args.predict > top:
        s = rows[base]["whole"] / rows[top]["whole"]
        for label, f in (("f", karp_flatt(s, top)), ("fc", karp_flatt(s, ceiling[top]))):
            if f == f:
                print(f"predicted whole at {args.predict} threads from {label}{top} = {f:.3f} (Amdahl): "
                      f"{amdahl(f, args.predict):.1f}x of 1 thread, {amdahl(f, args.predict) / amdahl(f, 2):.1f}x "
                      f"of 2 threads")
    same = len(set(answers.values())) == 1 and len(set(matrices.values())) == 1
    print(f"same matrix bytes and answer at every thread count: {'yes' if same else 'NO'} "
          f"({answers[base][0]} {answers[base][1]:.6f}, bound {answers[base][2]:.6f})")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
