"""``camplace solve`` of one run folder by this tree and a baseline tree, paired and interleaved (issue 29).

Each measurement is the whole command as a user runs it, in a fresh process pinned to the first T
allowed cores (``taskset``) with ``--threads T`` and ``NUMBA_NUM_THREADS``. Every round runs both
trees at every T, in alternating order (ABBA), after one warm-up solve per tree that fills its
numba cache. Prints each solve (stage seconds from the solution file, bound evaluations, rounds,
cameras), the medians, each tree's speed-up from the first T to the last, and the paired ratios
baseline / this tree per T (on a shared machine the pairs, not the medians, carry the comparison).
Checks that both trees and every T give the same objective.

A lent 16-core machine (docs/performance.md), comet-67p-bunker 10,000 x 50,000, four rounds: the
search at 16 threads 0.881 s (the baseline: roots of 20,000 bounds, rounds sized by the rate) and
0.810 s (this tree), paired ratio 1.108; at 2 threads 1.061.

    python benchmarks/solve_pairs.py RUN_FOLDER --baseline /path/to/main/src --threads 2,16 --rounds 4
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SRC = str(Path(__file__).resolve().parents[1] / "src")
KEYS = ("solve", "search", "incumbent", "presolve", "wall")


def once(folder: str, src: str, threads: int, tmp: str) -> dict:
    """One ``camplace solve`` of ``folder`` with ``src`` first on PYTHONPATH at ``threads`` threads."""
    path = os.pathsep.join([src, *filter(None, [os.environ.get("PYTHONPATH")])])
    env = {**os.environ, "PYTHONPATH": path, "NUMBA_NUM_THREADS": str(threads)}
    out = os.path.join(tmp, "solve.json")
    cmd = [sys.executable, "-m", "camplace", "solve", folder, "-o", out, "--threads", str(threads)]
    cores = sorted(os.sched_getaffinity(0))[:threads]
    t0 = time.perf_counter()
    proc = subprocess.run(["taskset", "-c", ",".join(map(str, cores)), *cmd], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode:
        sys.exit(f"solve failed ({src}, {threads} threads): {proc.stderr.strip()[-500:]}")
    d = json.loads(Path(out).read_text())
    es = d["stats"]["engine_stats"]
    return dict(wall=wall, solve=d["time_s"], search=es.get("time_search_s", 0.0),
                incumbent=es.get("time_incumbent_s", 0.0), presolve=d["stats"]["presolve"].get("time_s", 0.0),
                selected=tuple(d["selected"]), objective=d["objective"], evals=es.get("bound_evaluations"),
                rounds=es.get("rounds"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder", help="a run folder (camplace run ... -o FOLDER) or its matrix file")
    ap.add_argument("--baseline", required=True, help="another source tree (its src folder)")
    ap.add_argument("--threads", default="1,2", help="comma-separated thread counts (default 1,2)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    counts = [int(x) for x in args.threads.split(",")]
    if max(counts) > len(os.sched_getaffinity(0)):
        sys.exit(f"--threads: at most {len(os.sched_getaffinity(0))} cores are allowed here")
    trees = {"this": SRC, "baseline": str(Path(args.baseline).resolve())}
    res: dict[tuple[str, int], list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for src in trees.values():
            once(args.folder, src, counts[-1], tmp)
        for r in range(args.rounds):
            for t in counts:
                for name in (list(trees) if (r + t) % 2 == 0 else list(trees)[::-1]):
                    x = once(args.folder, trees[name], t, tmp)
                    res.setdefault((name, t), []).append(x)
                    print(f"round {r} T={t:2d} {name:8s}: " + " ".join(f"{k} {x[k]:.3f}" for k in KEYS)
                          + f" evals {x['evals']} rounds {x['rounds']} {x['selected']} {x['objective']}", flush=True)
    print(f"{'median (s)':10s} " + " ".join(f"{n}@{t:<3d}".rjust(12) for t in counts for n in trees))
    for key in KEYS:
        print(f"{key:10s} " + " ".join(f"{statistics.median(v[key] for v in res[(n, t)]):12.3f}"
                                       for t in counts for n in trees))
    a, b = counts[0], counts[-1]
    for n in trees:
        for key in ("solve", "search"):
            s = statistics.median(v[key] for v in res[(n, a)]) / statistics.median(v[key] for v in res[(n, b)])
            print(f"{n} {key} x{b}/{a}: {s:.2f}")
    for t in counts:
        for key in ("solve", "search"):
            q = [o[key] / m[key] for m, o in zip(res[("this", t)], res[("baseline", t)], strict=True)]
            print(f"T={t} {key} baseline / this, paired: " + " ".join(f"{x:.3f}" for x in q)
                  + f"  median {statistics.median(q):.3f}")
    objectives = {round(v["objective"], 12) for vs in res.values() for v in vs}
    print("same objective everywhere:", "yes" if len(objectives) == 1 else f"NO {sorted(objectives)}")


if __name__ == "__main__":
    main()
