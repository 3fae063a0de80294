"""Benchmark: camplace's maxcover solver side by side with Chama (Sandia) + GLPK, same matrix.

Not a test. Builds one visibility matrix from the built-in ``comet-67p-bunker`` instance (not
random) with a narrow lens, so that the best k = 3 cameras observe clearly less than every
coverable point (default: 1,000 candidates x 20,000 points, 100 mm focal length instead of 8 mm,
the instance's 40 m far plane: every candidate observes part of the comet, the optimum is 94.1 %
of the weight, 99.9 % is coverable). Then solves the same max-coverage problem twice:

- camplace: ``camplace.solver.api.solve(matrix, weights, k, mode="maxcover")`` in this process;
- Chama: ``chama.optimize.CoverageFormulation().solve(coverage, entity=..., sensor_budget=k,
  use_entity_weight=True, mip_solver_name="glpk")`` in a subprocess (Pyomo writes an LP file and
  runs Debian's ``glpsol``). Its coverage table has a row per candidate (``Sensor``) with the
  list of points it observes (``Coverage``), built from the ``Entity``/``Sensor`` pairs of the
  matrix; every candidate is listed, even one that observes nothing.

Timed (wall clock, ``time.perf_counter``): our ``solve`` call; Chama's ``solve`` call (Pyomo model
build, LP file, GLPK, reading the solution back). Loading the matrix and building the DataFrames
are not timed on either side. It prints the load average, both times, both objectives (Chama's
chosen candidates are re-scored on the same matrix and must match ours to 1e-6 relative), GLPK's
own status line and time, and the ratio Chama/camplace (``>=`` when Chama was stopped by its time
limit). Exit code 1 when our solve is not proven optimal or the two proven optima differ.

Usage::

    pip install ".[bench]" && apt-get install glpk-utils
    PYTHONPATH=src python benchmarks/chama_compare.py
    PYTHONPATH=src python benchmarks/chama_compare.py --focal-mm 50 --far-m 3   # + range limit: quicker
    PYTHONPATH=src python benchmarks/chama_compare.py --chama-python /tmp/venv-chama/bin/python

The matrix is computed once per run by ``camplace run`` (in a subprocess, from an instance file
written to a temporary folder) and reused from the visibility cache on later runs.
``--chama-python`` runs Chama with another interpreter (a virtual environment with chama, pyomo,
numpy, scipy and pandas; it needs no camplace). GLPK gets ``--chama-time-limit`` seconds (less
the time spent loading the data) and the Chama subprocess is ended 60 s past that limit.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

if "--blas-threads" in sys.argv:  # must happen before numpy is imported
    os.environ["OPENBLAS_NUM_THREADS"] = sys.argv[sys.argv.index("--blas-threads") + 1]

INSTANCE = "comet-67p-bunker"
_KILL_GRACE_S = 60.0  # Chama subprocess: seconds past --chama-time-limit before it is ended


# ----------------------------------------------------------------------------------------------
# Chama side (runs in the subprocess: imports numpy, scipy, pandas, chama and pyomo, no camplace)
# ----------------------------------------------------------------------------------------------


def _glpk_log_facts(log_text: str) -> dict[str, Any]:
    """GLPK's own final status line, time and best bound from a ``glpsol`` log."""
    status = None
    for line in log_text.splitlines():
        s = line.strip()
        if s and s.upper() == s and any(c.isalpha() for c in s) and not s.startswith(("+", "*", "GLPK", "GLPSOL")):
            status = s  # glpsol prints its status lines in capitals, e.g. INTEGER OPTIMAL SOLUTION FOUND
    used = re.findall(r"Time used:\s+([0-9.]+)\s+secs", log_text)
    mips = re.findall(r"mip =\s+(.+?)\s+<=\s+(.+?)\s{2,}", log_text)
    return {
        "glpk_status": status,
        "glpk_time_s": float(used[-1]) if used else None,
        "glpk_last_mip_line": {"incumbent": mips[-1][0], "bound": mips[-1][1]} if mips else None,
    }


def chama_worker(npz: str, points_csv: str, out_json: str, budget: int, time_limit_s: float) -> int:
    """Solve the max-coverage problem with Chama + GLPK and write a JSON summary to ``out_json``."""
    t_start = time.perf_counter()
    import chama
    import numpy as np
    import pandas as pd
    import pyomo.environ as pe
    import pyomo.version
    import scipy.sparse as sp

    a = sp.load_npz(npz).tocsc()
    weights = pd.read_csv(points_csv)["weight"].to_numpy(dtype=np.float64)
    a.eliminate_zeros()
    pairs = pd.DataFrame(
        {
            "Entity": a.indices.astype(np.int64),
            "Sensor": np.repeat(np.arange(a.shape[1], dtype=np.int64), np.diff(a.indptr)),
        }
    )
    lists = pairs.groupby("Sensor")["Entity"].apply(list)
    coverage = pd.DataFrame({"Sensor": np.arange(a.shape[1], dtype=np.int64)})
    coverage["Coverage"] = [lists.get(j, []) for j in coverage["Sensor"]]
    entity = pd.DataFrame({"Entity": np.arange(a.shape[0], dtype=np.int64), "Weight": weights})
    prep_s = time.perf_counter() - t_start

    log_path = str(Path(out_json).with_suffix(".glpk.log"))
    # GLPK's own limit: what is left of the budget after loading (the model build comes on top;
    # the parent ends this process at time_limit_s + a grace period)
    glpk_limit = max(1, int(time_limit_s - prep_s))
    cf = chama.optimize.CoverageFormulation()
    t0 = time.perf_counter()
    error = None
    try:
        cf.solve(
            coverage,
            entity=entity,
            sensor_budget=budget,
            use_entity_weight=True,
            mip_solver_name="glpk",
            pyomo_options={"timelimit": glpk_limit, "logfile": log_path},
        )
    except RuntimeError as exc:  # Chama raises when GLPK did not prove optimality
        error = str(exc)
    solve_s = time.perf_counter() - t0

    model = cf._model  # the Pyomo model Chama built (read back the incumbent, if any)
    selected: list[int] = []
    if model is not None:
        for key in model.y:
            val = model.y[key].value
            if val is not None and val > 0.5:
                selected.append(int(key))
    chama_obj = pe.value(model.obj, exception=False) if model is not None else None
    log_text = Path(log_path).read_text() if Path(log_path).exists() else ""
    glpsol = shutil.which("glpsol")
    glpk_version = None
    if glpsol:
        first = subprocess.run([glpsol, "--version"], check=False, capture_output=True, text=True).stdout.splitlines()
        glpk_version = first[0] if first else None
    out = {
        "solved": bool(model is not None and model.solved),
        "error": error,
        "selected": selected,
        "chama_objective": chama_obj,
        "prep_s": prep_s,
        "solve_s": solve_s,
        "glpk_time_limit_s": glpk_limit,
        "n_sensors": int(a.shape[1]),
        "n_entities": int(a.shape[0]),
        "n_pairs": len(pairs),
        "versions": {"chama": chama.__version__, "pyomo": pyomo.version.version, "glpk": glpk_version},
        **_glpk_log_facts(log_text),
    }
    Path(out_json).write_text(json.dumps(out, indent=1))
    return 0


def run_chama(python: str, npz: Path, points_csv: Path, workdir: Path, budget: int, time_limit_s: float) -> dict[str, Any]:
    """Run :func:`chama_worker` in a subprocess (own process group, ended past the time limit)."""
    out_json = workdir / "chama.json"
    out_json.unlink(missing_ok=True)
    env = dict(os.environ, TMPDIR=str(workdir))  # Pyomo's LP/solution files go to the work folder
    cmd = [python, str(Path(__file__).resolve()), "--chama-worker", str(npz), str(points_csv), str(out_json),
           "--k", str(budget), "--chama-time-limit", str(time_limit_s)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, start_new_session=True)
    try:
        rc = proc.wait(timeout=time_limit_s + _KILL_GRACE_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGTERM)  # the worker and its glpsol child
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        return {"killed": True, "wall_s": time.perf_counter() - t0}
    wall = time.perf_counter() - t0
    if rc != 0 or not out_json.exists():
        return {"failed": True, "rc": rc, "wall_s": wall}
    res = json.loads(out_json.read_text())
    res["wall_s"] = wall
    return res


# ----------------------------------------------------------------------------------------------
# camplace side
# ----------------------------------------------------------------------------------------------


def build_matrix(workdir: Path, focal_mm: float, far_m: float, candidates: int, points: int, seed: int) -> Path:
    """Write the edited built-in instance to ``workdir`` and run it there; return the run folder."""
    toml = workdir / "instance.toml"
    run_dir = workdir / "run"
    camplace = [sys.executable, "-m", "camplace"]
    subprocess.run([*camplace, "init", INSTANCE, "-o", str(toml)], check=True, capture_output=True, text=True)
    text = toml.read_text()
    text, n_f = re.subn(r"(?m)^focal_length_mm = .*$", f"focal_length_mm = {focal_mm!r}", text)
    text, n_r = re.subn(r"(?m)^far_m = .*$", f"far_m = {far_m!r}", text)
    if n_f != 1 or n_r != 1:
        raise RuntimeError(f"{toml}: expected one focal_length_mm and one far_m line in [camera]")
    toml.write_text(text)
    subprocess.run(
        [*camplace, "run", str(toml), "-o", str(run_dir), "--candidates", str(candidates),
         "--points", str(points), "--seed", str(seed), "--matrix-format", "npz"],  # Chama's side reads it with scipy
        check=True, capture_output=True, text=True,
    )
    return run_dir


def main(argv: list[str] | None = None) -> int:
    """Build the matrix, solve it with camplace and with Chama, print the comparison."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--candidates", type=int, default=1000, help="matrix columns (default 1000)")
    ap.add_argument("--points", type=int, default=20000, help="matrix rows (default 20000)")
    ap.add_argument("--focal-mm", type=float, default=100.0, help="camera focal length, mm (default 100: narrow lens)")
    ap.add_argument("--far-m", type=float, default=40.0, help="camera range limit (far plane), m (default 40, the instance's)")
    ap.add_argument("--k", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--time-limit", type=float, default=60.0, help="camplace solver limit, s (default 60)")
    ap.add_argument("--chama-time-limit", type=float, default=1800.0, help="Chama + GLPK limit, s (default 1800)")
    ap.add_argument("--chama-python", default=sys.executable, help="interpreter that has chama and pyomo")
    ap.add_argument("--workdir", default=None, help="keep the instance, run and Chama files here (default: a temporary folder)")
    ap.add_argument("--blas-threads", default=None, help="OPENBLAS_NUM_THREADS for this run")
    ap.add_argument("--chama-worker", nargs=3, metavar=("NPZ", "POINTS_CSV", "OUT_JSON"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.chama_worker:
        return chama_worker(*args.chama_worker, budget=args.k, time_limit_s=args.chama_time_limit)

    print(
        f"cpus={os.cpu_count()} OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'default')} "
        f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    if shutil.which("glpsol") is None:
        print("error: glpsol not found (apt-get install glpk-utils)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="chama_compare_") as tmp:
        workdir = Path(args.workdir) if args.workdir else Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        return _compare(args, workdir)


def _compare(args: argparse.Namespace, workdir: Path) -> int:
    import numpy as np
    import pandas as pd
    import scipy.sparse as sp

    from camplace.solver.api import solve
    from camplace.solver.problem.objectives import coverage_weight

    t = time.perf_counter()
    run_dir = build_matrix(workdir, args.focal_mm, args.far_m, args.candidates, args.points, args.seed)
    npz, points_csv = run_dir / "visibility.npz", run_dir / "points.csv"
    matrix = sp.load_npz(npz).tocsr()
    weights = pd.read_csv(points_csv)["weight"].to_numpy(dtype=np.float64)
    m, n = matrix.shape
    coverable = float(weights[np.diff(matrix.indptr) > 0].sum())
    useful = int((np.diff(matrix.tocsc().indptr) > 0).sum())
    print(
        f"instance: {INSTANCE}, focal {args.focal_mm:g} mm, far {args.far_m:g} m, seed {args.seed}: "
        f"{m} points x {n} candidates, {matrix.nnz} observed pairs (density {matrix.nnz / (m * n):.4f}), "
        f"{useful} candidates observe something, coverable weight {coverable:.6f} "
        f"(matrix built or read from cache in {time.perf_counter() - t:.1f} s)"
    )
    sys.stdout.flush()

    t = time.perf_counter()
    ours = solve(matrix, weights, args.k, mode="maxcover", time_limit_s=args.time_limit)
    ours_s = time.perf_counter() - t
    print(f"camplace: {ours_s:.3f} s, {ours.status}, objective {ours.objective:.9f}, engine {ours.engine}")
    sys.stdout.flush()

    ch = run_chama(args.chama_python, npz, points_csv, workdir, args.k, args.chama_time_limit)
    chama_obj: float | None = None
    if ch.get("killed") or ch.get("failed"):
        what = "ended at its time limit" if ch.get("killed") else f"failed (exit code {ch.get('rc')})"
        print(f"chama   : {what} after {ch['wall_s']:.1f} s, no solution")
        chama_s, chama_opt = ch["wall_s"], False
        chama_status = "time limit" if ch.get("killed") else "failed"
    else:
        chama_s = ch["solve_s"]
        chama_opt = bool(ch["solved"])
        if ch["selected"]:  # re-score Chama's choice on our matrix
            chama_obj = coverage_weight(matrix, weights, ch["selected"])
        glpk = ch["glpk_status"] or "?"
        chama_status = "optimal" if chama_opt else ("time limit" if "TIME LIMIT" in glpk else "not optimal")
        print(
            f"chama   : {chama_s:.3f} s, {chama_status}, selected {ch['selected']}, "
            f"Chama's objective {ch['chama_objective']}; GLPK: {glpk}, {ch['glpk_time_s']} s "
            f"(GLPK limit {ch['glpk_time_limit_s']} s); {ch['n_pairs']} Entity/Sensor pairs; "
            f"versions {ch['versions']}"
        )
        if not chama_opt:
            print(f"          {ch.get('error')} GLPK's last progress line: {ch.get('glpk_last_mip_line')}")
    same = None
    if chama_obj is not None:
        same = abs(chama_obj - ours.objective) <= 1e-6 * max(abs(ours.objective), 1e-300)
    rel = "" if chama_opt else ">="
    ratio = chama_s / ours_s
    if ratio >= 50:
        verdict = "met"
    else:
        verdict = "NOT met" if chama_opt else "not shown: Chama stopped early (raise --chama-time-limit)"
    print()
    print(f"{'solver':28s} {'time s':>10s} {'status':>12s} {'objective':>14s}")
    print(f"{'camplace maxcover (' + ours.engine + ')':28s} {ours_s:10.3f} {ours.status:>12s} {ours.objective:14.9f}")
    obj_txt = f"{chama_obj:14.9f}" if chama_obj is not None else f"{'-':>14s}"
    print(f"{'chama Coverage + GLPK':28s} {chama_s:10.3f} {chama_status:>12s} {obj_txt}")
    print(f"ratio chama/camplace: {rel}{ratio:.1f}x   (target >= 50x: {verdict})")
    print(
        f"same objective (1e-6 relative): {'-' if same is None else same}"
        f"{'' if chama_opt else ' (Chama not optimal: its best system so far)'}; "
        f"optimum {ours.objective:.6f} of coverable {coverable:.6f}"
    )
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if ours.status != "optimal" or (chama_opt and same is False):
        print("CHECK FAILED: camplace not proven optimal, or the two optima differ")
        return 1
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
