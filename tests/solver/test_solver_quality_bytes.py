"""Quality on quantised columns (issue 32): the tree engine on the stored bytes and the bytes route
of ``solve``, against exhaustive enumeration of the quantised values (and the float ones within
the stated bound)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import camplace.solver.bytes_route as bytes_route
import camplace.solver.engines.quality.tree as qt
from camplace.solver.api import solve
from camplace.visibility.qbytes import QUANT_ERROR, bytes_from_csr
from tests._floats import assert_ge
from tests.solver._oracle import ExpiringDeadline, brute_force_mode, mode_objective
from tests.solver.test_solver_quality_tree import graded

_F32 = 2.0**-24  # relative rounding of the float32 nearest a value (ByteMatrix.tocsr: float32(q / 255))
_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _bytes_of(dense: np.ndarray) -> np.ndarray:
    """Oracle quantisation (numpy): round to the nearest 1/255, an observed value at least 1/255."""
    q = np.floor(255.0 * dense.astype(np.float32).astype(np.float64) + 0.5)
    q = np.where(dense > 0, np.maximum(q, 1.0), 0.0)
    return np.ascontiguousarray(q.T.astype(np.uint8))  # (n, m): column j in row j


@settings(max_examples=150, **_SETTINGS)
@given(data=graded(), k=st.integers(1, 4))
def test_dense_tree_equals_enumeration(data, k) -> None:
    dense, w = data
    n = dense.shape[1]
    values = _bytes_of(dense)
    quant = values.T.astype(np.float64) / 255.0  # the values the bytes stand for, (m, n)
    out = qt.solve_quality_tree_dense(values, 1 / 255, w, k)
    best = brute_force_mode(quant, w, min(k, n), "quality")
    tol = 1e-9 * max(1.0, float(w.sum()))
    assert out.status == "optimal"
    assert len(out.selected) == min(k, n) == len(set(out.selected))
    assert abs(mode_objective(quant, w, out.selected, "quality") - best) <= tol
    assert abs(out.bound - best) <= tol
    # the float optimum lies within sum(w) / 255 of the quantised one (each value within 1 / 255,
    # 1 / 510 above 1 / 510)
    best_float = brute_force_mode(dense, w, min(k, n), "quality")
    assert abs(best_float - best) <= float(w.sum()) / 255 + tol


@pytest.mark.parametrize("checks", [0, 1, 3, 8, 12, 20])
def test_dense_tree_interrupted_keeps_a_valid_bound(monkeypatch, checks) -> None:
    rng = np.random.default_rng(checks)
    dense = (rng.random((60, 14)) < 0.5) * rng.uniform(0.05, 1.0, (60, 14))
    w = rng.uniform(0.0, 1.0, 60)
    values = _bytes_of(dense)
    quant = values.T.astype(np.float64) / 255.0
    best = brute_force_mode(quant, w, 3, "quality")
    monkeypatch.setattr(qt, "_CHUNK", 1)
    out = qt.solve_quality_tree_dense(values, 1 / 255, w, 3, deadline=ExpiringDeadline(checks))
    v = mode_objective(quant, w, out.selected, "quality")
    assert len(set(out.selected)) == 3
    assert_ge(out.bound, best, scale=w.sum(), what="bound vs optimum")
    assert_ge(best, v, what="optimum vs value of the returned set")
    if out.status == "optimal":
        assert v == pytest.approx(best) and out.bound == pytest.approx(best)


def test_dense_tree_frontier_cap_keeps_a_valid_bound(monkeypatch) -> None:
    rng = np.random.default_rng(5)
    dense = (rng.random((80, 16)) < 0.6) * rng.uniform(0.05, 1.0, (80, 16))
    w = rng.uniform(0.0, 1.0, 80)
    values = _bytes_of(dense)
    best = brute_force_mode(values.T / 255.0, w, 3, "quality")
    monkeypatch.setattr(qt, "FRONTIER_MAX", 2)
    monkeypatch.setattr(qt, "_SWAP_ROUNDS", 0)
    out = qt.solve_quality_tree_dense(values, 1 / 255, w, 3)
    assert_ge(out.bound, best, scale=w.sum(), what="bound vs optimum")


@settings(max_examples=60, **_SETTINGS)
@given(data=graded(max_n=9), k=st.integers(1, 4))
def test_solve_on_bytes_equals_enumeration(data, k) -> None:
    """``solve`` on a ByteMatrix (the bytes route, and the routes it converts for) equals
    enumeration on the values the bytes stand for."""
    dense, w = data
    n = dense.shape[1]
    k = min(k, n)
    qb = bytes_from_csr(sp.csr_matrix(dense.astype(np.float32)))
    np.testing.assert_array_equal(qb.values, _bytes_of(dense))
    quant = qb.values.T.astype(np.float64) / 255.0
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bytes_route, "QUALITY_EXACT_MAX_N", 0)  # the tree on the bytes for k = 2, 3 too
        res = solve(qb, w, k, mode="quality")
    tol = 1e-9 * max(1.0, float(w.sum()))
    assert res.status == "optimal" and res.stats["engine_choice"]["route"] == "quality-bytes"
    best = brute_force_mode(quant, w, k, "quality")
    assert abs(res.objective - best) <= tol and res.bound == res.objective
    assert abs(mode_objective(quant, w, res.selected, "quality") - res.objective) <= tol
    # the other routes: the CSR float32 of the bytes (k = 2, 3 on few candidates) and the pattern
    other = solve(qb, w, k, mode="quality")
    assert abs(other.objective - best) <= _F32 * float(w.sum()) + tol
    cover = solve(qb, w, k, mode="maxcover")
    assert abs(cover.objective - brute_force_mode(dense, w, k, "maxcover")) <= tol


@settings(max_examples=100, **_SETTINGS)
@given(data=graded(max_n=40), k=st.integers(1, 4), group=st.sampled_from([2, 3, 4, 8, 64]))
def test_dense_tree_with_a_budgeted_table_equals_enumeration(data, k, group) -> None:
    """Rows only for the clusters of more than ``group`` columns: the same optimum and bound."""
    dense, w = data
    n = dense.shape[1]
    k = min(k, n, 3 if n > 25 else 4)
    values = _bytes_of(dense)
    quant = values.T.astype(np.float64) / 255.0
    out = qt.solve_quality_tree_dense(values, 1 / 255, w, k, group=group)
    best = brute_force_mode(quant, w, k, "quality")
    tol = 1e-9 * max(1.0, float(w.sum()))
    assert out.status == "optimal" and len(set(out.selected)) == k
    assert abs(mode_objective(quant, w, out.selected, "quality") - best) <= tol
    assert abs(out.bound - best) <= tol


@pytest.mark.parametrize("checks", [0, 2, 5, 11])
def test_budgeted_table_interrupted_keeps_a_valid_bound(monkeypatch, checks) -> None:
    rng = np.random.default_rng(40 + checks)
    dense = (rng.random((70, 30)) < 0.5) * rng.uniform(0.05, 1.0, (70, 30))
    w = rng.uniform(0.0, 1.0, 70)
    values = _bytes_of(dense)
    best = brute_force_mode(values.T / 255.0, w, 3, "quality")
    monkeypatch.setattr(qt, "_CHUNK", 1)
    out = qt.solve_quality_tree_dense(values, 1 / 255, w, 3, deadline=ExpiringDeadline(checks), group=4)
    assert_ge(out.bound, best, scale=w.sum(), what="bound vs optimum")


def test_bytes_route_budgets_the_table(monkeypatch) -> None:
    """Over the budget for the full table, the route keeps rows for larger clusters only (and says so)."""
    rng = np.random.default_rng(8)
    dense = (rng.random((60, 40)) < 0.5) * rng.uniform(0.05, 1.0, (60, 40))
    w = rng.uniform(0.1, 1.0, 60)
    qb = bytes_from_csr(sp.csr_matrix(dense))
    full = qt.quality_tree_bytes_dense(60, 40)
    monkeypatch.setattr(bytes_route, "memory_budget_bytes", lambda: full - 1)
    monkeypatch.setattr(bytes_route, "QUALITY_EXACT_MAX_N", 0)
    res = solve(qb, w, 3, mode="quality")
    assert res.stats["engine_choice"]["route"] == "quality-bytes" and res.stats["engine_stats"]["table_group"] == 2
    best = brute_force_mode(qb.values.T / 255.0, w, 3, "quality")
    assert res.status == "optimal" and abs(res.objective - best) <= 1e-9 * float(w.sum())


def test_bytes_route_over_budget_converts(monkeypatch) -> None:
    rng = np.random.default_rng(3)
    dense = (rng.random((50, 12)) < 0.5) * rng.uniform(0.05, 1.0, (50, 12))
    w = rng.uniform(0.1, 1.0, 50)
    qb = bytes_from_csr(sp.csr_matrix(dense))
    monkeypatch.setattr(bytes_route, "dense_table_group", lambda m, n, budget: None)
    monkeypatch.setattr(bytes_route, "QUALITY_EXACT_MAX_N", 0)
    res = solve(qb, w, 4, mode="quality")
    best = brute_force_mode(qb.values.T / 255.0, w, 4, "quality")
    assert res.stats["engine_choice"]["route"] != "quality-bytes"
    # the other engines read the float32 values of q / 255 (each within 2**-24 relative)
    assert abs(res.objective - best) <= _F32 * float(w.sum()) + 1e-9 * max(1.0, float(w.sum()))


def test_quant_error_constant() -> None:
    assert QUANT_ERROR == 0.5 / 255
