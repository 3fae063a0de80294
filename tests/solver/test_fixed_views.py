"""Multiview with fixed cameras and no angle, solved exactly by the angle engine at 0 degrees.

A row needs ``views`` less its fixed views; the multiview bitset engine does not model that, and
the general model behind it did not fit at the default scale (comet-67p-bunker 10,000 x 50,000,
``--mode multiview --fixed 3``: a 52 GiB SCIP model refused, the greedy answer 0.510 with a bound
of 1.000). At 0 degrees every pair of views passes the angle engine's test, so its optimum is this
problem's. Oracle: every k-subset of the free columns counted in numpy (views of the chosen and
the fixed columns per row); cameras at one position (one candidate's orientations) count as two
views, as plain multiview counts them.
"""

from __future__ import annotations

import itertools
import json
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.solver.api import solve
from camplace.visibility.bits import bits_from_csr
from tests._package import subprocess_env


def _enumerated(dense: np.ndarray, w: np.ndarray, k: int, views: int, fixed: tuple[int, ...]) -> float:
    """The best weight of rows seen by >= ``views`` of the k chosen and the fixed columns."""
    n = dense.shape[1]
    free = [j for j in range(n) if j not in fixed]
    base = dense[:, list(fixed)].sum(axis=1) if fixed else np.zeros(dense.shape[0])
    best = 0.0
    for cols in itertools.combinations(free, k):
        seen = base + dense[:, list(cols)].sum(axis=1)
        best = max(best, float(w[seen >= views].sum()))
    return best


def _case(seed: int, m: int = 90, n: int = 10, colocated: bool = False):
    rng = np.random.default_rng(seed)
    dense = (rng.random((m, n)) < rng.choice([0.2, 0.35, 0.5])).astype(np.float32)
    w = np.where(rng.random(m) < 0.15, 0.0, rng.random(m))
    positions = rng.normal(size=(n, 3)) * 5.0
    if colocated:  # cameras 0-3 at one position (orientations of one candidate)
        positions[1:4] = positions[0]
    points = rng.normal(size=(m, 3))
    return dense, w, positions, points


@pytest.mark.parametrize("seed,views,k,fixed,colocated", [
    (0, 2, 2, (3,), False), (1, 2, 3, (0, 5), False), (2, 3, 2, (1, 2), False), (3, 3, 3, (4,), False),
    (4, 2, 1, (7,), False), (5, 2, 2, (2,), True), (6, 3, 2, (0,), True), (7, 2, 4, (9,), False),
])
def test_fixed_multiview_is_the_angle_engine_at_zero_degrees_and_the_enumerated_optimum(
        seed: int, views: int, k: int, fixed: tuple[int, ...], colocated: bool) -> None:
    dense, w, positions, points = _case(seed, colocated=colocated)
    best = _enumerated(dense, w, k, views, fixed)
    for matrix in (sp.csr_matrix(dense), bits_from_csr(sp.csr_matrix(dense))):
        res = solve(matrix, w, k, mode="multiview", views=views, fixed=fixed, positions=positions, points=points)
        assert res.status == "optimal"
        assert res.stats["engine_choice"]["route"] == "angle" and "fixed_views" in res.stats
        assert res.objective == pytest.approx(best, rel=1e-9, abs=1e-12)
        assert res.bound == pytest.approx(best, rel=1e-9, abs=1e-12)
        sel = [j for j in res.selected if j not in fixed]
        assert len(sel) == k and set(fixed) <= set(res.selected)
        seen = dense[:, list(res.selected)].sum(axis=1)
        assert float(w[seen >= views].sum()) == pytest.approx(best, rel=1e-9, abs=1e-12)


def test_engine_exact_takes_the_same_route() -> None:
    """Asked for the exact engine by name (it refused multiview with fixed cameras before)."""
    dense, w, positions, points = _case(12)
    res = solve(sp.csr_matrix(dense), w, 2, mode="multiview", views=2, fixed=(3,), engine="exact",
                positions=positions, points=points)
    assert res.status == "optimal" and res.stats["engine_choice"]["reason"] == "requested: engine exact"
    assert res.objective == pytest.approx(_enumerated(dense, w, 2, 2, (3,)), rel=1e-9, abs=1e-12)


def test_without_the_geometry_the_general_model_answers_the_same() -> None:
    """No positions: the route needs them to run, so the general model answers (the same optimum)."""
    dense, w, positions, points = _case(11)
    best = _enumerated(dense, w, 2, 2, (3,))
    res = solve(sp.csr_matrix(dense), w, 2, mode="multiview", views=2, fixed=(3,))
    assert res.stats["engine_choice"]["route"] == "model" and "fixed_views" not in res.stats
    assert res.objective == pytest.approx(best, rel=1e-9, abs=1e-12)


def test_solve_verb_proves_multiview_with_a_fixed_camera(tmp_path) -> None:
    """The user path: ``camplace solve FOLDER --mode multiview --fixed 3`` on a run folder proves the
    optimum with the exact engine, and its answer is the enumerated one over the folder's matrix."""
    env = subprocess_env()
    out = tmp_path / "run"
    subprocess.run([sys.executable, "-m", "camplace", "run", "comet-67p-bunker", "--candidates", "12", "--points",
                    "400", "-o", str(out), "--no-cache"], check=True, env=env, capture_output=True, timeout=300)
    proc = subprocess.run([sys.executable, "-m", "camplace", "solve", str(out), "--mode", "multiview", "--k", "2",
                           "--fixed", "3", "-o", str(tmp_path / "s.json")], env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    got = json.loads((tmp_path / "s.json").read_text())
    assert got["status"] == "optimal" and got["engine"] == "exact", got["stats"]["engine_choice"]
    from camplace.runfolder import RunFolder

    run = RunFolder(out)
    dense = run.matrix.toarray() > 0
    assert got["objective"] == pytest.approx(_enumerated(dense, run.weights(), 2, 2, (3,)), rel=1e-9, abs=1e-12)
