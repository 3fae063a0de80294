"""Benchmark: ``camplace setcover`` on the public set-cover instances, against their best known values.

Not a test. For every OR-Library file in ``../shared/data/setcover/`` (weighted costs as in the file,
best known = ``weighted_BKS`` of ``known_optima.csv``; with ``--unicost`` every column costs 1 and the
best known is ``unicost_BKS_fontanf``) and the GECCO 2020 camera-placement instance AC_01 (unicost,
best known = the size in ``AC_01_best_known_solution.txt``), runs

    camplace setcover FILE --format orlib|gecco --time-limit T --json

in a fresh process for every time limit (default 10 and 60 s), as a user runs it, and prints a
markdown table: per time limit the cost found (``=`` when it equals the best known value), the
lower bound, the status, the time at which the returned cover was found ("to best s": ``time_to_best_s``
of the JSON, from the start of the set-cover engine, reductions included, to the chunk of search,
about 20 ms, that found it), the solve time (``time_s`` of the JSON: reading excluded, reductions
included) and the whole process's wall time (Python start-up, imports, reading the file and
compiled-kernel cache loading included), next to the instance's size and best known value. The
data are read from ``../shared/data`` beside the repository, never copied. ``--synthetic`` adds generated camera-placement-like instances (2-D
rooms with box occluders, candidates = random positions x 8 headings, limited field of view and
range; no best known value) to check robustness on sparser instances than AC_01.

The load average is printed: the machine is shared, timings depend on it.

Usage::

    PYTHONPATH=src python benchmarks/setcover.py                    # 10 s and 60 s, every instance
    PYTHONPATH=src python benchmarks/setcover.py --limits 10 --only scp41 AC_01
    PYTHONPATH=src python benchmarks/setcover.py --unicost --limits 10
    PYTHONPATH=src python benchmarks/setcover.py --synthetic --limits 10 60
    PYTHONPATH=src python benchmarks/setcover.py --no-shared --files DIR/AC_10_cover.txt=20
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
SETCOVER = DATA / "setcover"
CAMERA = DATA / "camera_placement"

# generated camera-like instances: (name, points, candidate positions, range, seed)
SYNTHETIC = [
    ("room-605pts-363pos-r0.25", 605, 363, 0.25, 1),
    ("room-3000pts-1000pos-r0.20", 3000, 1000, 0.20, 3),
    ("room-3000pts-1500pos-r0.15", 3000, 1500, 0.15, 5),
    ("room-6000pts-2500pos-r0.12", 6000, 2500, 0.12, 6),
]


def camera_like(m: int, n_pos: int, *, n_dir: int = 8, fov_deg: float = 70.0, range_: float = 0.35,
                n_boxes: int = 6, seed: int = 0):
    """A unicost camera-placement set-cover matrix in the unit square.

    ``m`` points and ``n_pos`` camera positions are drawn outside ``n_boxes`` random boxes; every
    position has ``n_dir`` headings; a camera sees a point within ``range_``, within half the field
    of view of its heading, and with no box on the segment between them. Points no camera sees are
    dropped.

    Returns
    -------
    (m', n_pos' * n_dir) scipy.sparse.csr_matrix of float64 (0/1)
    """
    import numpy as np
    import scipy.sparse as sp

    rng = np.random.default_rng(seed)
    boxes = []
    for _ in range(n_boxes):
        c = rng.uniform(0.15, 0.85, 2)
        h = rng.uniform(0.03, 0.12, 2)
        boxes.append((c - h, c + h))

    def inside(p):
        ok = np.zeros(len(p), dtype=bool)
        for lo, hi in boxes:
            ok |= np.all((p >= lo) & (p <= hi), axis=1)
        return ok

    pts = rng.uniform(0, 1, (4 * m, 2))
    pts = pts[~inside(pts)][:m]
    pos = rng.uniform(0, 1, (4 * n_pos, 2))
    pos = pos[~inside(pos)][:n_pos]
    heads = np.arange(n_dir) * 2 * np.pi / n_dir
    rows, cols = [], []
    for a, p in enumerate(pos):
        d = pts - p
        dist = np.linalg.norm(d, axis=1)
        ang = np.arctan2(d[:, 1], d[:, 0])
        blocked = np.zeros(len(pts), dtype=bool)
        for lo, hi in boxes:  # slab test of the segment p -> point against the box
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (lo - p) / d, (hi - p) / d
            tmin = np.nanmax(np.minimum(t1, t2), axis=1)
            tmax = np.nanmin(np.maximum(t1, t2), axis=1)
            blocked |= (tmax >= np.maximum(tmin, 0)) & (tmin <= 1)
        ok = (dist < range_) & ~blocked
        for k, h in enumerate(heads):
            off = np.abs((ang - h + np.pi) % (2 * np.pi) - np.pi)
            sel = np.flatnonzero(ok & (off <= np.radians(fov_deg) / 2))
            rows.append(sel)
            cols.append(np.full(sel.size, a * n_dir + k))
    r, c = np.concatenate(rows), np.concatenate(cols)
    a = sp.csr_matrix((np.ones(r.size), (r, c)), shape=(len(pts), len(pos) * n_dir))
    a.sum_duplicates()
    a.data[:] = 1.0
    return a[np.diff(a.indptr) > 0].tocsr()


def write_gecco(matrix, path: Path) -> None:
    """Write a 0/1 matrix in the GECCO 2020 cover format (read by ``camplace setcover --format gecco``)."""
    lines = [f"{matrix.shape[0]} {matrix.shape[1]}"]
    for i in range(matrix.shape[0]):
        cols = matrix.indices[matrix.indptr[i] : matrix.indptr[i + 1]]
        lines += [str(i), str(cols.size), " ".join(str(int(j)) for j in cols)]
    path.write_text("\n".join(lines) + "\n")


def instances(unicost: bool) -> list[tuple[str, Path, str, float | None]]:
    """(name, file, format, best known) of every shared instance."""
    out = []
    with open(SETCOVER / "known_optima.csv", newline="") as fh:
        for row in csv.DictReader(fh):
            best = float(row["unicost_BKS_fontanf" if unicost else "weighted_BKS"])
            out.append((row["file"].removesuffix(".txt"), SETCOVER / row["file"], "orlib", best))
    best_ac = float((CAMERA / "AC_01_best_known_solution.txt").read_text().split()[0])
    out.append(("AC_01", CAMERA / "AC_01_cover.txt", "gecco", best_ac))
    return out


def run(path: Path, fmt: str, limit: float, unicost: bool) -> dict:
    """One ``camplace setcover`` process; its JSON answer plus ``wall_s``, the process's wall time."""
    cmd = [sys.executable, "-m", "camplace", "setcover", str(path), "--format", fmt, "--time-limit", str(limit), "--json"]
    if unicost:
        cmd.append("--unicost")
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    wall_s = time.perf_counter() - t0
    if out.returncode not in (0, 3):
        raise SystemExit(f"{' '.join(cmd)} failed:\n{out.stderr}")
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["wall_s"] = wall_s
    return res


def size_of(path: Path, fmt: str) -> str:
    """``rows x columns`` from the file's first line (both formats start with them)."""
    with open(path) as fh:
        m, n = fh.readline().split()[:2]
    return f"{int(m):,} x {int(n):,}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--limits", type=float, nargs="+", default=[10.0, 60.0], help="time limits, seconds")
    ap.add_argument("--only", nargs="*", default=None, help="instance names to run (default: all)")
    ap.add_argument("--unicost", action="store_true", help="every column costs 1 (OR-Library unicost best known)")
    ap.add_argument("--synthetic", action="store_true", help="also generated camera-placement-like instances")
    ap.add_argument("--files", nargs="*", default=[], metavar="PATH[=BEST]",
                    help="other instance files (GECCO format when the name ends in _cover.txt, else OR-Library), "
                         "with their best known value after '='")
    ap.add_argument("--no-shared", action="store_true", help="skip the shared instances (only --files / --synthetic)")
    args = ap.parse_args()

    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    todo = [] if args.no_shared else instances(args.unicost)
    for spec in args.files:
        path, _, best = spec.partition("=")
        p = Path(path)
        todo.append((p.name.removesuffix(".txt"), p, "gecco" if p.name.endswith("_cover.txt") else "orlib",
                     float(best) if best else None))
    tmp = None
    if args.synthetic:
        tmp = tempfile.TemporaryDirectory()
        for name, m, n_pos, rng_, seed in SYNTHETIC:
            path = Path(tmp.name) / f"{name}.txt"
            write_gecco(camera_like(m, n_pos, range_=rng_, seed=seed), path)
            todo.append((name, path, "gecco", None))
    if args.only:
        todo = [t for t in todo if t[0] in args.only]
    run(todo[0][1], todo[0][2], 1.0, args.unicost)  # warm-up: the first run after a change compiles the kernels
    cols = ["value", "bound", "status", "to best s", "solve s", "wall s"]
    head = "| instance | rows x cols | best known | " + " | ".join(f"{c} ({t:g} s)" for t in args.limits for c in cols) + " |"
    print(head)
    print("|---|---|---|" + "---|" * (len(cols) * len(args.limits)))
    misses = []
    for name, path, fmt, best in todo:
        cells = []
        for limit in args.limits:
            r = run(path, fmt, limit, args.unicost)
            cost = "-" if r["cost"] is None else f"{r['cost']:g}"
            bound = "-" if r["bound"] is None else f"{r['bound']:g}"
            hit = best is not None and r["cost"] is not None and r["cost"] <= best
            if best is not None and not hit:
                misses.append(f"{name} at {limit:g} s")
            tb = r.get("time_to_best_s")
            cells += [f"{cost}{' =' if hit else ''}", bound, r["status"], "-" if tb is None else f"{tb:.1f}",
                      f"{r['time_s']:.1f}", f"{r['wall_s']:.1f}"]
        print(f"| {name} | {size_of(path, fmt)} | {'-' if best is None else f'{best:g}'} | " + " | ".join(cells) + " |",
              flush=True)
    print("best known value missed: " + (", ".join(misses) if misses else "none"))
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
