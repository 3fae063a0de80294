"""Benchmark (issue 31): a two-model team under a budget on comet-67p-bunker, against the
single-model run of the same size.

Not a test. Writes ``comet-67p-bunker-team`` (the built-in comet-67p-bunker, its one camera
replaced by two models: ``wide``, the bunker's own camera, cost 1; ``tele``, twice the focal
length, cost 2, at most 2; ``[team] budget = 3``: any number of cameras within it, e.g. three
wide ones or one of each, as the single run's k = 3) and runs, each in its own process (so that
the peak RSS is that run's alone):

1. ``camplace run`` of the single-model instance and of the team at the same size (default: the
   instance's, 2000 candidate positions x 10000 points; the team offers each position with both
   models, so its matrix has twice the columns);
2. ``camplace solve`` on each stored run (the solve alone: load + solve).

and prints wall time and peak RSS of each, the team / single ratios (target: within 2x), and the
team's status, objective, engine and the constraints it used (the answer must be proven optimal).

Usage::

    PYTHONPATH=src python benchmarks/team.py                         # default size
    PYTHONPATH=src python benchmarks/team.py --candidates 200 --points 2000 --workdir /tmp/teambench
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TEAM_TABLES = """
[[cameras]]
name = "wide"
cost = 1.0
sensor_width_mm = 7.18
sensor_height_mm = 5.32
focal_length_mm = 8.0
width_px = 1280
height_px = 960
near_m = 0.1
far_m = 40.0

[[cameras]]
name = "tele"
cost = 2.0
max_count = 2
sensor_width_mm = 7.18
sensor_height_mm = 5.32
focal_length_mm = 16.0
width_px = 1280
height_px = 960
near_m = 0.1
far_m = 40.0

[team]
budget = 3.0
"""

_CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from camplace.cli import main
rc = main(sys.argv[1:])
print("BENCH " + json.dumps({"rc": rc, "wall_s": time.perf_counter() - t0,
                             "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def write_team_instance(workdir: Path) -> Path:
    """``comet-67p-bunker-team.toml`` in ``workdir`` (with the bunker's meshes beside it)."""
    src = workdir / "bunker.toml"
    subprocess.run([sys.executable, "-m", "camplace", "init", "comet-67p-bunker", "-o", str(src)], check=True,
                   capture_output=True)
    text = src.read_text()
    camera = re.search(r"\n\[camera\]\n(?:[^\[\n][^\n]*\n)*", text)
    assert camera is not None, "no [camera] table in the bunker instance"
    text = text[:camera.start()] + "\n" + text[camera.end():]
    text = text.replace('name = "comet-67p-bunker"', 'name = "comet-67p-bunker-team"')
    path = workdir / "comet-67p-bunker-team.toml"
    path.write_text(text + TEAM_TABLES)
    return path


def child(args: list[str], env: dict, cwd: Path) -> dict:
    """Run ``camplace ARGS`` in a fresh process; its rc, wall time and peak RSS."""
    r = subprocess.run([sys.executable, "-c", _CHILD, *args], capture_output=True, text=True, env=env, cwd=cwd)
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("BENCH ")]
    if not line:
        raise SystemExit(f"camplace {' '.join(args)} failed:\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}")
    out = json.loads(line[-1][6:])
    out["stdout"] = r.stdout
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--candidates", type=int, default=None, help="candidate positions (default: the instance's, 2000)")
    ap.add_argument("--points", type=int, default=None, help="target points (default: the instance's, 10000)")
    ap.add_argument("--time-limit", type=float, default=None, help="solver time limit, seconds (default: the instance's)")
    ap.add_argument("--workdir", type=Path, default=None, help="where to write the runs (default: a temporary folder)")
    a = ap.parse_args()
    workdir = a.workdir or Path(tempfile.mkdtemp(prefix="camplace-team-bench-"))
    workdir.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "CAMPLACE_CACHE_DIR": str(workdir / "cache")}
    sizes: list[str] = []
    if a.candidates is not None:
        sizes += ["--candidates", str(a.candidates)]
    if a.points is not None:
        sizes += ["--points", str(a.points)]
    if a.time_limit is not None:
        sizes += ["--time-limit", str(a.time_limit)]
    team_toml = write_team_instance(workdir)
    print(f"workdir {workdir}; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    rows = {}
    for name, inst in (("single", "comet-67p-bunker"), ("team", str(team_toml))):
        out = workdir / name
        run = child(["run", inst, "-o", str(out), "--no-cache", *sizes], env, workdir)
        sol_args = ["solve", str(out), "-o", str(workdir / f"{name}-solve.json")]
        if a.time_limit is not None:
            sol_args += ["--time-limit", str(a.time_limit)]
        solo = child(sol_args, env, workdir)
        sol = json.loads((out / "solution.json").read_text())
        again = json.loads((workdir / f"{name}-solve.json").read_text())
        rows[name] = (run, solo, sol, again)
        print(f"{name:>6}: run {run['wall_s']:.1f} s, peak {run['peak_rss_mb']:.0f} MB (solve stage "
              f"{sol['timings_s'].get('solve', float('nan')):.2f} s); camplace solve {solo['wall_s']:.2f} s, "
              f"peak {solo['peak_rss_mb']:.0f} MB; {sol['status']} objective {sol['objective']:.6f} bound {sol['bound']:.6f} "
              f"engine {sol['engine']}, {len(sol['cameras'])} cameras, {sol['n_candidates']} columns")
        if name == "team":
            t = sol["team"]
            print(f"        team: enforced {t['enforced']}, cardinality {t.get('cardinality')}, uses {t['uses']}, "
                  f"broken {t['broken']}; choice: {sol['solver_stats']['engine_choice']['reason']}")
            print(f"        camplace solve: {again['status']} objective {again['objective']:.6f} engine {again['engine']}")
    (r1, s1, sol1, _), (r2, s2, sol2, _) = rows["single"], rows["team"]
    ratio = lambda x, y: x / y if y > 0 else float("inf")  # noqa: E731
    st1, st2 = sol1["timings_s"].get("solve", 0.0), sol2["timings_s"].get("solve", 0.0)
    print(f"team / single: run time {ratio(r2['wall_s'], r1['wall_s']):.2f}x, run peak RSS "
          f"{ratio(r2['peak_rss_mb'], r1['peak_rss_mb']):.2f}x, solve stage {ratio(st2, st1):.2f}x, "
          f"camplace solve time {ratio(s2['wall_s'], s1['wall_s']):.2f}x, peak RSS {ratio(s2['peak_rss_mb'], s1['peak_rss_mb']):.2f}x "
          "(target: within 2x)")
    ok = sol2["status"] == "optimal" and sol2["team"]["enforced"] and not sol2["team"]["broken"]
    print("team answer proven optimal with every constraint enforced" if ok else "TEAM ANSWER NOT PROVEN OPTIMAL")
    return 0 if ok else 1


if __name__ == "__main__":
    started = time.perf_counter()
    rc = main()
    print(f"benchmark wall {time.perf_counter() - started:.1f} s")
    sys.exit(rc)
