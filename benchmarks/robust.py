"""Robust placement benchmark: nominal optimum vs robust (expected-objective) optimum under pose error.

Run from the repository root::

    PYTHONPATH=src python benchmarks/robust.py [--candidates 1000] [--points 5000] [--scenarios 16]
        [--eval-scenarios 128] [--pose-error 0.1,5] [--time-limit 120] [--only bunker|volcano] [--json FILE]
        [--memory-budget-gb 6]

Cases: comet-67p-bunker multiview (views = 2, k = 3) and volcanic-eruption maxcover (k = 3), each
with position sigma 0.10 m per axis and rotation sigma 5 degrees (the ``[physical]`` model).
One robust :func:`camplace.pipeline.run` per case solves the nominal problem and the stacked
robust one on the same candidates and points; both chosen systems are then scored on
``--eval-scenarios`` fresh installations (another seed stream). Printed per case: both systems'
status and objective, the sampled (in-sample) mean and 10th percentile, and the out-of-sample mean
and 10th percentile, the paired difference of the fresh means with its standard error, and the
wall times; with ``--json`` the records are written too.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

CASES = {
    "bunker": {"instance": "comet-67p-bunker", "mode": "multiview", "views": 2},
    "volcano": {"instance": "volcanic-eruption", "mode": "maxcover", "views": 2},
}


def one_case(name: str, args: argparse.Namespace) -> dict:
    from camplace.instance import RobustSpec, resolve_instance
    from camplace.pipeline import run
    from camplace.robust import make_spec

    case = CASES[name]
    instance = resolve_instance(case["instance"])
    spec = replace(make_spec(RobustSpec(), args.pose_error, args.scenarios), eval_scenarios=args.eval_scenarios)
    t0 = time.perf_counter()
    sol = run(
        instance, candidates=args.candidates, points=args.points, mode=case["mode"], views=case["views"],
        time_limit_s=args.time_limit, robust=spec, cache=not args.no_cache, memory_budget_gb=args.memory_budget_gb,
    )
    wall = time.perf_counter() - t0
    r = sol.robust
    import numpy as np

    diff = np.asarray(r["out_of_sample"]["robust"]["values"]) - np.asarray(r["out_of_sample"]["nominal"]["values"])
    return {
        "case": name, "instance": case["instance"], "mode": case["mode"], "k": sol.k,
        "candidates": sol.n_candidates, "rows": sol.n_points, "settings": r["settings"],
        "nominal": {**r["nominal_solution"], "in_sample": r["in_sample"]["nominal"],
                    "out_of_sample": {k: v for k, v in r["out_of_sample"]["nominal"].items() if k != "values"}},
        "robust": {"selected": sol.selected, "status": sol.status, "objective": sol.objective, "bound": sol.bound,
                   "gap": sol.gap, "in_sample": r["in_sample"]["robust"],
                   "out_of_sample": {k: v for k, v in r["out_of_sample"]["robust"].items() if k != "values"}},
        "timings_s": {k: round(v, 2) for k, v in sol.timings_s.items() if not k.startswith("solver.")},
        "wall_s": round(wall, 1),
        # paired over the same fresh installations (a camera in both systems is installed alike)
        "out_of_sample_difference": {"mean": float(diff.mean()), "se": float(diff.std(ddof=1) / np.sqrt(diff.size))},
    }


def show(rec: dict) -> None:
    s = rec["settings"]
    print(f"\n{rec['instance']} {rec['mode']} k={rec['k']}: {rec['candidates']} candidates x {rec['rows']} rows, "
          f"S={s['scenarios']} in-sample, {s['eval_scenarios']} fresh; sigma {s['position_sigma_m']} m / {s['rotation_sigma_deg']} deg")
    print(f"{'system':<8} {'status':<9} {'nominal obj':>11} {'in mean':>9} {'in p10':>9} {'out mean':>9} {'out p10':>9}  cameras")
    for name in ("nominal", "robust"):
        d = rec[name]
        nominal_obj = d["objective"] if name == "nominal" else float("nan")
        print(f"{name:<8} {d['status']:<9} {nominal_obj:>11.4f} {d['in_sample']['mean']:>9.4f} {d['in_sample']['p10']:>9.4f} "
              f"{d['out_of_sample']['mean']:>9.4f} {d['out_of_sample']['p10']:>9.4f}  {d['selected']}")
    d = rec["out_of_sample_difference"]
    print(f"fresh mean robust - nominal: {d['mean']:+.5f} (standard error {d['se']:.5f})")
    print(f"timings (s): {rec['timings_s']}, wall {rec['wall_s']} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--candidates", type=int, default=1000)
    ap.add_argument("--points", type=int, default=5000)
    ap.add_argument("--scenarios", type=int, default=16)
    ap.add_argument("--eval-scenarios", type=int, default=128, dest="eval_scenarios")
    ap.add_argument("--pose-error", default="0.1,5", dest="pose_error")
    ap.add_argument("--time-limit", type=float, default=120.0, dest="time_limit")
    ap.add_argument("--only", choices=sorted(CASES), default=None)
    ap.add_argument("--no-cache", action="store_true", dest="no_cache")
    ap.add_argument("--memory-budget-gb", type=float, default=6.0, dest="memory_budget_gb",
                    help="stop (one line) before a matrix would need more (default 6)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    records = []
    for name in ([args.only] if args.only else list(CASES)):
        rec = one_case(name, args)
        show(rec)
        records.append(rec)
    if args.json is not None:
        args.json.write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
