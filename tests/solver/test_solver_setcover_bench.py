"""``camplace setcover`` reaches the published optima of OR-Library and GECCO 2020 instances.

Data are read from ``<repo>/../shared/data`` (never copied into the repository). Oracles: the
``weighted_BKS`` column of ``known_optima.csv`` (proven optima) and ``AC_01_best_known_solution.txt``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from camplace.solver.cli import register
from camplace.solver.problem.formats import read_gecco, read_orlib

REPO = Path(__file__).resolve().parents[2]
DATA = REPO.parent / "shared" / "data"
SETCOVER = DATA / "setcover"
CAMERA = DATA / "camera_placement"
if not (SETCOVER / "known_optima.csv").exists() or not (CAMERA / "AC_01_cover.txt").exists():
    pytest.skip(f"the shared set-cover data are not beside the repository ({DATA})", allow_module_level=True)


def _known() -> list[tuple[str, float, bool]]:
    with open(SETCOVER / "known_optima.csv", newline="") as fh:
        return [(r["file"], float(r["weighted_BKS"]), r["weighted_proven_optimal"] == "True") for r in csv.DictReader(fh)]


def _run_cli(argv: list[str], capsys) -> dict:
    import argparse

    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="verb")
    handlers = register(sub, lambda p: None)
    args = ap.parse_args(argv)
    code = handlers[args.verb](args)
    out = capsys.readouterr().out
    assert code == 0
    return json.loads(out)


def _covers(matrix, selected) -> bool:
    return bool(np.all(np.diff(matrix[:, list(selected)].tocsr().indptr) > 0))


FAST = [name for name, _, _ in _known() if name != "scpnre1.txt"]


@pytest.mark.parametrize("name", FAST)
def test_orlib_proven_optimum(name: str, capsys) -> None:
    best = {n: v for n, v, _ in _known()}[name]
    res = _run_cli(["setcover", str(SETCOVER / name), "--format", "orlib", "--json"], capsys)
    inst = read_orlib(SETCOVER / name)
    assert res["status"] == "optimal"
    assert res["cost"] == best
    assert res["bound"] == best
    assert _covers(inst.matrix, res["selected"])
    assert float(inst.costs[res["selected"]].sum()) == best
    assert set(res) >= {"cost", "bound", "status", "time_s", "selected"}


@pytest.mark.slow
def test_orlib_scpnre1_reaches_optimum_within_limit(capsys) -> None:
    """scpnre1: SCIP alone proves 29 in ~100 s on 2 cores; the search reaches it in about 0.5 s
    (docs/solver.md: 0.6 s, "to best s"); CI checks the value within an 8 s limit (a margin of
    more than ten times for a loaded runner) and that it was found inside the limit."""
    best = {n: v for n, v, _ in _known()}["scpnre1.txt"]
    res = _run_cli(["setcover", str(SETCOVER / "scpnre1.txt"), "--format", "orlib", "--json", "--time-limit", "8"], capsys)
    inst = read_orlib(SETCOVER / "scpnre1.txt")
    assert res["cost"] == best
    assert res["time_to_best_s"] <= 8.0
    assert _covers(inst.matrix, res["selected"])
    assert res["status"] in ("optimal", "feasible")
    assert res["bound"] <= best
    if res["status"] == "optimal":
        assert res["bound"] == best


@pytest.mark.slow
def test_gecco_ac01_size_seven(capsys) -> None:
    """AC_01 proven at its best known size, 7, and that cover found within ten seconds (the
    ten-second target as the time-limited runs of ``test_best_known_within_ten_seconds`` check it on
    the OR-Library instances: here the search alone finds it in about 1.5 s of a 20 s proof)."""
    lines = (CAMERA / "AC_01_best_known_solution.txt").read_text().split("\n")
    best_size = int(lines[0])
    res = _run_cli(["setcover", str(CAMERA / "AC_01_cover.txt"), "--format", "gecco", "--json"], capsys)
    inst = read_gecco(CAMERA / "AC_01_cover.txt")
    assert best_size == 7
    assert res["status"] == "optimal"
    assert res["cost"] == best_size == len(res["selected"])
    assert res["bound"] == best_size
    assert _covers(inst.matrix, res["selected"])
    assert res["time_to_best_s"] <= 10.0


@pytest.mark.slow
@pytest.mark.parametrize("name,fmt", [("scp41.txt", "orlib"), ("scp61.txt", "orlib")])  # AC_01: its proof, above
def test_best_known_within_ten_seconds(name: str, fmt: str, capsys) -> None:
    """The issue's target as the user runs it, ``camplace setcover FILE --time-limit 10``, on a fast
    subset: the weighted OR-Library optimum, a valid cover, a bound not above it, and the answer
    inside the time limit."""
    path, best = SETCOVER / name, {n: v for n, v, _ in _known()}[name]
    inst = read_orlib(path)
    costs = inst.costs
    res = _run_cli(["setcover", str(path), "--format", fmt, "--time-limit", "10", "--json"], capsys)
    assert _covers(inst.matrix, res["selected"])
    assert float(costs[res["selected"]].sum()) == res["cost"] == best
    assert res["bound"] <= best
    assert res["time_s"] <= 10.0 * 1.1
