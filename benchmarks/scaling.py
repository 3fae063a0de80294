"""Whole commands at 1, 2, ... threads: per-stage times, speed-ups and the serial fraction they imply.

Runs ``camplace run INSTANCE --candidates N --points M --no-cache`` as a user would, once per
thread count T, pinned to the first T allowed cores (``taskset``) with ``--threads T`` (which also
sets numba's thread count), after one warm-up run that fills numba's cache. Prints, per stage of
``solution.json``'s ``timings_s`` and for the whole process (wall clock of the subprocess): the
seconds at each T, the speed-up against T = 1 and the serial fraction that speed-up implies
(Amdahl's law read backwards, the Karp-Flatt metric: ``f = (1/S - 1/T) / (1 - 1/T)``; 0 is perfectly
parallel, 1 is serial). It also checks that every thread count gives the same matrix bytes and the
same objective, bound and cameras.

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
    print(f"load average {os.getloadavg()[0]:.1f} at end")
    if args.baseline:
        print(f"baseline {args.baseline} at {counts[0]} thread(s), against this tree at {counts[0]}: "
              + ", ".join(f"{name.strip()} {rows['base'][name]:.2f}/{rows[counts[0]][name]:.2f} s" for name in
                          ("whole", "visibility", "solve", "  presolve", "  search", "  incumbent"))
              + f"; same answer: {'yes' if base_answer == answers[counts[0]] else 'NO ' + str(base_answer)}")
    base = counts[0]
    head = "".join(f"{f'{t} thr':>9}" for t in counts) + "".join(f"{f'x{t}':>8}{f'f{t}':>7}" for t in counts[1:])
    print(f"{'stage (s)':<14}{head}")
    for name in ["whole", *(n for n, _ in STAGES)]:
        line = f"{name:<14}" + "".join(f"{rows[t][name]:>9.2f}" for t in counts)
        for t in counts[1:]:
            s = rows[base][name] / rows[t][name] if rows[t][name] > 0 else float("nan")
            scale = t / base
            f = (1 / s - 1 / scale) / (1 - 1 / scale) if s == s and s > 0 else float("nan")
            line += f"{s:>8.2f}{f:>7.2f}"
        print(line)
    same = len(set(answers.values())) == 1 and len(set(matrices.values())) == 1
    print(f"same matrix bytes and answer at every thread count: {'yes' if same else 'NO'} "
          f"({answers[base][0]} {answers[base][1]:.6f}, bound {answers[base][2]:.6f})")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
