"""Report benchmark: ``run --report`` on comet-67p-bunker (target: <= 60 s for two 200-system campaigns on 2 cores).

Run from the repository root::

    PYTHONPATH=src python benchmarks/report.py [--outdir DIR] [--systems 200] [--keep]

1. A default run (2000 candidates x 10000 points) is made into ``--outdir`` unless one is already
   there (its time is printed but not part of the measure; the visibility cache is ``$CAMPLACE_CACHE_DIR``).
2. **Cold**: :func:`camplace.report.run_report_bundle` (a uniform and a chaotic campaign of
   ``--systems`` systems, the union comparison, the sampler study, the figures and report.html) with
   a fresh, empty visibility cache and no ``samplers.json``: every campaign and sampler matrix is ray cast.
3. **Warm**: the same call again (visibility cache and ``samplers.json`` reused).

Prints the wall time of each stage and the totals, and whether the cold total is within the target.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import tempfile
import time
from collections import defaultdict
from pathlib import Path

TARGET_S = 60.0


class StageTimes:
    """A silent progress reporter that adds up the wall time of each stage."""

    def __init__(self) -> None:
        self.times: dict[str, float] = defaultdict(float)
        self.order: list[str] = []

    @contextlib.contextmanager
    def stage(self, name: str, total: int | None = None):
        t0 = time.perf_counter()
        yield lambda n=1: None
        if name not in self.times:
            self.order.append(name)
        self.times[name] += time.perf_counter() - t0


def bundle(outdir: Path, systems: int) -> tuple[float, StageTimes]:
    from camplace.report import run_report_bundle

    rep = StageTimes()
    t0 = time.perf_counter()
    run_report_bundle(outdir, systems=systems, reporter=rep)
    return time.perf_counter() - t0, rep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--outdir", type=Path, default=None, help="run folder (default: a temporary one)")
    ap.add_argument("--systems", type=int, default=200)
    ap.add_argument("--keep", action="store_true", help="keep the temporary run folder")
    args = ap.parse_args()

    from camplace.pipeline import run

    tmp = None
    outdir = args.outdir
    if outdir is None:
        tmp = Path(tempfile.mkdtemp(prefix="camplace-bench-report-"))
        outdir = tmp / "run"
    cores = os.cpu_count() or 1
    if not (outdir / "solution.json").exists():
        t0 = time.perf_counter()
        sol = run("comet-67p-bunker", outdir=outdir)
        print(f"run (2000 x 10000, not measured): {time.perf_counter() - t0:.1f} s, objective {sol.objective:.4f}, {sol.status}")
    for p in [outdir / "samplers.json", outdir / "report.html"]:
        p.unlink(missing_ok=True)
    for p in outdir.glob("campaign-*"):
        shutil.rmtree(p)

    old_cache = os.environ.get("CAMPLACE_CACHE_DIR")
    cold_cache = tempfile.mkdtemp(prefix="camplace-bench-cache-")
    os.environ["CAMPLACE_CACHE_DIR"] = cold_cache
    try:
        cold, cold_rep = bundle(outdir, args.systems)
        warm, warm_rep = bundle(outdir, args.systems)
    finally:
        shutil.rmtree(cold_cache, ignore_errors=True)
        if old_cache is None:
            os.environ.pop("CAMPLACE_CACHE_DIR", None)
        else:
            os.environ["CAMPLACE_CACHE_DIR"] = old_cache

    size_kb = (outdir / "report.html").stat().st_size / 1024
    print(f"comet-67p-bunker, two campaigns x {args.systems} systems, {cores} CPU(s); report.html {size_kb:.0f} kB")
    print(f"{'stage':<16}{'cold (s)':>10}{'warm (s)':>10}")
    for name in cold_rep.order:
        print(f"{name:<16}{cold_rep.times[name]:>10.2f}{warm_rep.times.get(name, 0.0):>10.2f}")
    print(f"{'total':<16}{cold:>10.2f}{warm:>10.2f}")
    verdict = "within" if cold <= TARGET_S else "OVER"
    print(f"cold report bundle: {cold:.1f} s ({verdict} the {TARGET_S:.0f} s target); warm: {warm:.1f} s")
    if tmp is not None and not args.keep:
        shutil.rmtree(tmp, ignore_errors=True)
    elif tmp is not None:
        print(f"kept {outdir}")


if __name__ == "__main__":
    main()
