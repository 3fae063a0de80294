"""Time limits: early stops return an honest status, a valid bound and the right gap."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.solver import SolverResult, solve_maxcover
from camplace.solver.engines.bitset import search as bitset_mod
from camplace.solver.problem._synthetic import structured_instance
from camplace.solver.result import relative_gap
from tests.solver._oracle import CountingDeadline, solve_deadline


@pytest.fixture(scope="module")
def instance() -> tuple[sp.csr_matrix, np.ndarray]:
    return structured_instance(1200, 260, seed=2, shape="bilobed", corridor=True, fov_deg=70.0)


@pytest.fixture(scope="module")
def optimum(instance: tuple[sp.csr_matrix, np.ndarray]) -> dict[int, float]:
    matrix, weights = instance
    out = {}
    for k in (3, 4):
        res = solve_maxcover(matrix, weights, k, engine="exact")
        assert res.status == "optimal"
        out[k] = res.objective
    return out


def _check_honest(res: SolverResult, opt: float) -> None:
    assert res.status in ("optimal", "feasible")
    assert res.objective <= opt + 1e-12
    assert res.bound >= opt - 1e-12, "bound must be a valid upper bound on the optimum"
    assert res.bound >= res.objective
    if res.status == "optimal":
        assert res.objective == pytest.approx(opt, abs=1e-12)
        assert res.gap == 0.0
    else:
        assert res.gap == pytest.approx(relative_gap(res.bound, res.objective), abs=1e-15)
        assert res.gap == pytest.approx((res.bound - res.objective) / max(abs(res.bound), 1e-12), abs=1e-15)


@pytest.mark.parametrize("k", [3, 4])
@pytest.mark.parametrize("after", [0, 1, 2, 3, 5, 8, 13, 30, 80, 200])
def test_exact_interrupted_anywhere_has_valid_bound(instance, optimum, monkeypatch, k: int, after: int) -> None:
    matrix, weights = instance
    solve_deadline(monkeypatch, CountingDeadline(after))  # the solve's one deadline
    monkeypatch.setattr(bitset_mod, "_SLICE", 3)  # deadline checks every 3 bound evaluations
    res = solve_maxcover(matrix, weights, k, engine="exact", time_limit_s=10.0)
    _check_honest(res, optimum[k])
    assert len(res.selected) == k


def test_exact_tiny_real_time_limit(instance, optimum) -> None:
    matrix, weights = instance
    res = solve_maxcover(matrix, weights, 3, engine="exact", time_limit_s=1e-4)
    _check_honest(res, optimum[3])


@pytest.mark.parametrize("engine", ["mip", "cpsat"])
def test_ortools_tiny_time_limit(instance, optimum, engine: str) -> None:
    matrix, weights = instance
    res = solve_maxcover(matrix, weights, 3, engine=engine, time_limit_s=0.05)
    _check_honest(res, optimum[3])
    assert len(res.selected) == 3
    assert math.isfinite(res.bound)


def test_time_limit_reported_in_time_s(instance) -> None:
    matrix, weights = instance
    res = solve_maxcover(matrix, weights, 3, engine="mip", time_limit_s=0.5)
    assert res.time_s < 20.0  # model building is not interruptible, but the solve is
