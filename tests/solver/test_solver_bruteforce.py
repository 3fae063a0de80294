"""Every engine equals exhaustive enumeration on small random instances."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camplace.solver import coverage_weight, presolve, solve_maxcover
from camplace.solver.engines.bitset import search as bitset_mod
from camplace.solver.engines.bitset.search import solve_bitset
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


@settings(max_examples=120, **_SETTINGS)
@given(inst=small_instances(max_k=4), views=st.integers(1, 3), slice_=st.integers(1, 5), integer=st.booleans())
def test_bitset_engine_any_views_equals_enumeration(inst, views: int, slice_: int, integer: bool) -> None:
    """The bitset engine for ``views`` = 1..3 (k <= 4), its search resumed every few bound
    evaluations, with integer (equal) or float weights, against enumeration of every k-subset."""
    matrix, weights, k = inst
    dense = np.asarray(matrix.toarray() if hasattr(matrix, "toarray") else matrix) > 0
    w = np.where(weights > 0, 0.25, 0.0) if integer else weights
    pre = presolve(matrix, w, k, dominance=views == 1)
    mp = pytest.MonkeyPatch()
    mp.setattr(bitset_mod, "_SLICE", slice_)
    try:
        out = solve_bitset(pre, views=views)
    finally:
        mp.undo()
    sel = pre.original_columns(out.selected)
    best = max(float(w[dense[:, list(c)].sum(axis=1) >= views].sum()) for c in combinations(range(dense.shape[1]), k))
    got = float(w[dense[:, list(sel)].sum(axis=1) >= views].sum())
    assert out.status == "optimal"
    assert len(sel) == k == len(set(sel))
    assert abs(got - best) <= tolerance(w)
    assert abs(out.bound - best) <= tolerance(w)


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
