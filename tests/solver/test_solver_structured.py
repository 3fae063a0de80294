"""Exact engine vs OR-Tools MIP / CP-SAT on medium STRUCTURED instances, and vs enumeration."""

from __future__ import annotations

import pytest

from camplace.solver import solve_maxcover
from camplace.solver.problem._synthetic import structured_instance
from tests.solver._oracle import brute_force, tolerance

CASES = [
    (400, 80, 3, dict(shape="bilobed", corridor=True)),
    (500, 100, 3, dict(dmax=4.0)),
    (500, 100, 2, dict(fov_deg=40.0, max_range=6.0)),
    (300, 60, 4, dict(shape="bilobed", corridor=True, fov_deg=60.0)),
    (400, 120, 3, dict(corridor=True, fov_deg=50.0)),
    (500, 150, 4, dict(shape="bilobed", fov_deg=45.0, max_range=5.0)),
]


@pytest.mark.parametrize(("m", "n", "k", "kw"), CASES)
def test_exact_matches_mip_and_cpsat(m: int, n: int, k: int, kw: dict[str, float | bool | str]) -> None:
    matrix, weights = structured_instance(m, n, seed=7, **kw)
    ex = solve_maxcover(matrix, weights, k, engine="exact")
    mip = solve_maxcover(matrix, weights, k, engine="mip", time_limit_s=60)
    cps = solve_maxcover(matrix, weights, k, engine="cpsat", time_limit_s=60)
    assert ex.status == mip.status == cps.status == "optimal"
    assert ex.objective == pytest.approx(mip.objective, abs=1e-12)
    assert ex.objective == pytest.approx(cps.objective, abs=1e-12)
    assert ex.stats["cols_after"] <= n


@pytest.mark.slow
def test_exact_matches_mip_larger() -> None:
    """~8-15 s: SCIP needs several seconds on 2,789 merged rows x 375 columns."""
    matrix, weights = structured_instance(4000, 800, seed=3, shape="bilobed", corridor=True, fov_deg=60.0)
    ex = solve_maxcover(matrix, weights, 3, engine="exact")
    mip = solve_maxcover(matrix, weights, 3, engine="mip", time_limit_s=120)
    assert ex.status == mip.status == "optimal"
    assert ex.objective == pytest.approx(mip.objective, abs=1e-12)


@pytest.mark.parametrize("k", [2, 3, 4])
@pytest.mark.parametrize("kw", [dict(), dict(shape="bilobed", corridor=True), dict(dmax=3.0, fov_deg=50.0)])
def test_exact_matches_enumeration_on_structured(k: int, kw: dict[str, float | bool | str]) -> None:
    matrix, weights = structured_instance(300, 36, seed=11, **kw)
    best, _ = brute_force(matrix, weights, k)
    res = solve_maxcover(matrix, weights, k, engine="exact")
    assert res.status == "optimal"
    assert abs(res.objective - best) <= tolerance(weights)


def test_non_uniform_weights_structured() -> None:
    """Float64 arithmetic path (weights not all equal) on a structured instance."""
    import numpy as np

    matrix, weights = structured_instance(600, 120, seed=5, shape="bilobed")
    weights = weights * np.random.default_rng(0).uniform(0.2, 1.8, size=weights.size)
    ex = solve_maxcover(matrix, weights, 3, engine="exact")
    mip = solve_maxcover(matrix, weights, 3, engine="mip", time_limit_s=60)
    assert ex.stats["engine_stats"]["arithmetic"] == "float64"
    assert ex.status == mip.status == "optimal"
    assert ex.objective == pytest.approx(mip.objective, abs=tolerance(weights))


def test_generator_is_deterministic() -> None:
    a1, w1 = structured_instance(200, 30, seed=4, shape="bilobed", corridor=True, fov_deg=60.0)
    a2, w2 = structured_instance(200, 30, seed=4, shape="bilobed", corridor=True, fov_deg=60.0)
    assert (a1 != a2).nnz == 0
    assert (w1 == w2).all()
    assert a1.data.min() > 0 and a1.data.max() <= 1.0
