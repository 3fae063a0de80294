"""A newcomer's first run: ``pip install .`` into a fresh virtual environment, then the README's
quick start twice (the first with the kernels as installed, the second with whatever the first
cached), whole processes timed as a user runs them.

Target (issue 29): the first run <= 1.5x the second. The second run finds the first one's
visibility matrix in camplace's cache and casts no rays, so a third run with ``--no-cache`` (the
same work as the first, compiled kernels and all) is timed too: first / that is what compiling
costs. ``--baseline`` also installs with
``CAMPLACE_NO_PRECOMPILE=1`` (kernels compiled on first use, as before) and times its first run in
the same session, so the saving is a ratio measured on one machine at one load.

    python benchmarks/first_run.py [--baseline]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _timed(cmd: list[str], cwd: Path, env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def measure(tmp: Path, precompile: bool) -> dict[str, float]:
    """Install into a new venv under ``tmp`` and time the install and two quick starts."""
    venv = tmp / ("venv" if precompile else "venv-plain")
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}:{env['PATH']}"
    env["CAMPLACE_CACHE_DIR"] = str(venv / "camplace-cache")  # empty, as on a newcomer's machine
    if not precompile:
        env["CAMPLACE_NO_PRECOMPILE"] = "1"
    src = tmp / ("src" if precompile else "src-plain")  # a clean copy: no build/ folder of an earlier install
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", "build", "*.egg-info", "__pycache__", ".venv"))
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet"]
    install = _timed(pip + [str(src)], tmp, env)
    cmd = [str(venv / "bin" / "camplace"), "run", "comet-67p-bunker", "-o"]  # the README's quick start
    first = _timed(cmd + [str(tmp / "first")], tmp, env)
    again = _timed(cmd + [str(tmp / "again")], tmp, env)
    same = _timed(cmd + [str(tmp / "same"), "--no-cache"], tmp, env)  # the first run's work, nothing compiled
    return {"install": install, "first": first, "again": again, "same": same}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", action="store_true", help="also install without precompiled kernels")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f}, {len(os.sched_getaffinity(0))} cores")
    with tempfile.TemporaryDirectory() as tmp:
        rows = [("precompiled at install", measure(Path(tmp), True))]
        if args.baseline:
            rows.append(("compiled on first use", measure(Path(tmp), False)))
    print(f"{'install':<24} {'pip install .':>14} {'first run':>10} {'run again':>10} {'first/again':>12} "
          f"{'--no-cache':>11} {'first/that':>11}")
    for name, r in rows:
        print(f"{name:<24} {r['install']:>12.1f} s {r['first']:>8.2f} s {r['again']:>8.2f} s "
              f"{r['first'] / r['again']:>11.2f}x {r['same']:>9.2f} s {r['first'] / r['same']:>10.2f}x")


if __name__ == "__main__":
    main()
