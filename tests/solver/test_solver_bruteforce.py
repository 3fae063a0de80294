"""Every engine equals exhaustive enumeration on small random instances."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camplace.solver import coverage_weight, presolve, solve_maxcover
from camplace.solver import exact as exact_mod
from camplace.solver.exact import solve_exact
from tests.solver._oracle import brute_force, small_instances, tolerance

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _check(result, matrix, weights, k: int) -> None:
    best, sets = brute_force(matrix, weights, k)
    tol = tolerance(weights)
    assert result.status == "optimal"
    assert len(result.selected) == k == len(set(result.selected))
    assert list(result.selected) == sorted(result.selected)
    assert all(0 <= j < matrix.shape[1] for j in result.selected)
    assert result.objective == pytest.approx(coverage_weight(matrix, weights, result.selected), abs=0.0)
    assert abs(result.objective - best) <= tol, (result.objective, best, result.selected, sets[:5])
    assert result.bound == result.objective
    assert result.gap == 0.0


@settings(max_examples=120, **_SETTINGS)
@given(small_instances())
def test_exact_equals_enumeration(inst) -> None:
    matrix, weights, k = inst
    _check(solve_maxcover(matrix, weights, k, engine="exact"), matrix, weights, k)


@settings(max_examples=40, **_SETTINGS)
@given(small_instances())
def test_mip_equals_enumeration(inst) -> None:
    matrix, weights, k = inst
    _check(solve_maxcover(matrix, weights, k, engine="mip"), matrix, weights, k)


@settings(max_examples=40, **_SETTINGS)
@given(small_instances())
def test_cpsat_equals_enumeration(inst) -> None:
    matrix, weights, k = inst
    _check(solve_maxcover(matrix, weights, k, engine="cpsat"), matrix, weights, k)


@settings(max_examples=30, **_SETTINGS)
@given(small_instances(max_k=3))
def test_auto_equals_enumeration(inst) -> None:
    matrix, weights, k = inst
    res = solve_maxcover(matrix, weights, k)
    assert res.engine == "exact"
    _check(res, matrix, weights, k)


@settings(max_examples=80, **_SETTINGS)
@given(inst=small_instances(max_k=4), segments=st.integers(1, 8))
def test_exact_internal_screening_paths(inst, segments: int) -> None:
    """Force the segment screening and segment bounds on tiny instances (normally > 48 columns)."""
    matrix, weights, k = inst
    best, _ = brute_force(matrix, weights, k)
    pre = presolve(matrix, weights, k)
    mp = pytest.MonkeyPatch()
    mp.setattr(exact_mod, "_SCREEN_MIN", 1)
    try:
        out = solve_exact(pre, n_segments=segments)
    finally:
        mp.undo()
    sel = pre.original_columns(out.selected)
    assert out.status == "optimal"
    assert len(sel) == k
    assert abs(coverage_weight(matrix, weights, sel) - best) <= tolerance(weights)
    assert out.bound >= best - tolerance(weights)


@pytest.mark.parametrize("k", [1, 2, 3, 4, 5])
def test_exact_engine_any_k(k: int) -> None:
    """The exact engine also works (slowly) beyond k = 4."""
    rng = np.random.default_rng(k)
    dense = (rng.random((40, 16)) < 0.2).astype(float)
    w = rng.uniform(0.1, 1.0, 40)
    res = solve_maxcover(dense, w, k, engine="exact")
    best, _ = brute_force(dense, w, k)
    assert res.status == "optimal"
    assert abs(res.objective - best) <= tolerance(w)
