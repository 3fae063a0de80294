"""The quantised-tree quality engine and the memory guard, against exhaustive enumeration."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import camplace.solver.choose as choose
import camplace.solver.api as modes
import camplace.solver.routes as routes
import camplace.solver.engines.quality.portfolio as portfolio
import camplace.solver.engines.quality.tree as qt
from camplace.errors import CamplaceError
from camplace.solver.api import solve
from tests._floats import assert_ge
from tests.solver._oracle import ExpiringDeadline, brute_force_mode, mode_objective

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@st.composite
def graded(draw, max_n: int = 10, max_m: int = 40):
    n = draw(st.integers(1, max_n))
    m = draw(st.integers(1, max_m))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    levels = draw(st.sampled_from([None, 2, 300]))  # ties; values finer than the 255 quantisation steps
    q = rng.uniform(0.001, 1.0, size=(m, n))
    if levels:
        q = np.ceil(q * levels) / levels
    dense = (rng.random((m, n)) < draw(st.sampled_from([0.15, 0.5, 0.9]))) * q
    if draw(st.booleans()) and n >= 2:
        dense[:, -1] = dense[:, 0]  # duplicate camera
    kind = draw(st.sampled_from(["int", "float", "equal"]))  # equal weights: the integer bound path
    if kind == "equal":
        w = np.full(m, 0.1)
    else:
        w = rng.integers(0, 3, size=m).astype(float) if kind == "int" else rng.uniform(0.0, 1.0, size=m)
    return dense, w


def _value(dense: np.ndarray, w: np.ndarray, cols) -> float:
    return float(w @ dense[:, list(cols)].max(axis=1)) if len(cols) else 0.0


@settings(max_examples=150, **_SETTINGS)
@given(data=graded(), k=st.integers(1, 4))
def test_tree_engine_equals_enumeration(data, k) -> None:
    dense, w = data
    n = dense.shape[1]
    out = qt.solve_quality_tree(sp.csr_matrix(dense), w, k)
    best = brute_force_mode(dense, w, min(k, n), "quality")
    tol = 1e-9 * max(1.0, float(w.sum()))
    assert out.status == "optimal"
    assert len(out.selected) == min(k, n) == len(set(out.selected))
    assert abs(_value(dense, w, out.selected) - best) <= tol
    assert abs(out.bound - best) <= tol


@pytest.mark.parametrize("checks", [0, 1, 3, 8, 12, 20])
def test_tree_engine_interrupted_keeps_a_valid_bound(monkeypatch, checks) -> None:
    rng = np.random.default_rng(checks)
    dense = (rng.random((60, 14)) < 0.5) * rng.uniform(0.05, 1.0, (60, 14))
    w = rng.uniform(0.0, 1.0, 60)
    best = brute_force_mode(dense, w, 3, "quality")
    monkeypatch.setattr(qt, "_CHUNK", 1)
    out = qt.solve_quality_tree(sp.csr_matrix(dense), w, 3, deadline=ExpiringDeadline(checks))
    v = _value(dense, w, out.selected)
    assert len(set(out.selected)) == 3
    # v (BLAS dot) and best (a loop over the rows) are sums of the same terms in different orders;
    # the engine's bound is valid to its pruning margin, 1e-9 x the total weight.
    assert_ge(out.bound, best, scale=w.sum(), what="bound vs optimum")
    assert_ge(best, v, what="optimum vs value of the returned set")
    if out.status == "optimal":
        assert v == pytest.approx(best) and out.bound == pytest.approx(best)


def test_tree_engine_frontier_cap_keeps_a_valid_bound(monkeypatch) -> None:
    rng = np.random.default_rng(5)
    dense = (rng.random((80, 16)) < 0.6) * rng.uniform(0.05, 1.0, (80, 16))
    w = rng.uniform(0.0, 1.0, 80)
    best = brute_force_mode(dense, w, 3, "quality")
    monkeypatch.setattr(qt, "FRONTIER_MAX", 2)
    monkeypatch.setattr(qt, "_STARTS", 0)  # no incumbent before the search: the frontier must grow
    out = qt.solve_quality_tree(sp.csr_matrix(dense), w, 3)
    assert out.status == "feasible"
    assert_ge(out.bound, best, scale=w.sum(), what="bound vs optimum")  # valid to the pruning margin


@settings(max_examples=40, **_SETTINGS)
@given(data=st.data())
def test_solve_routes_large_quality_to_the_tree_engine(data) -> None:
    """With the small-instance engines switched off, ``solve`` (fixed and forbidden cameras
    included) answers through the tree engine and equals enumeration."""
    dense, w = data.draw(graded(max_n=9))
    n = dense.shape[1]
    fixed = tuple(sorted(data.draw(st.sets(st.integers(0, n - 1), max_size=2))))
    forbidden = tuple(sorted(data.draw(st.sets(st.integers(0, n - 1), max_size=2)) - set(fixed)))
    free = n - len(fixed) - len(forbidden)
    if free < 1:
        return
    k = data.draw(st.integers(1, min(4, free)))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(choose, "QUALITY_EXACT_MAX_N", 0)
        mp.setattr(choose, "_QUALITY_EXPAND_MAX", -1)
        res = solve(dense, w, k, mode="quality", fixed=fixed, forbidden=forbidden)
    best = brute_force_mode(dense, w, k, "quality", fixed=fixed, forbidden=forbidden)
    tol = 1e-9 * max(1.0, float(w.sum()))
    assert res.engine == "exact" and res.status == "optimal"
    assert "peak_open" in res.stats["engine_stats"] or res.stats["engine_stats"].get("trivial")
    assert set(fixed) <= set(res.selected) and not set(forbidden) & set(res.selected)
    assert len(res.selected) == len(fixed) + k
    assert abs(mode_objective(dense, w, res.selected, "quality") - res.objective) <= tol
    assert abs(res.objective - best) <= tol and res.bound == res.objective


@pytest.mark.parametrize("mode", ["maxcover", "quality", "multiview"])
def test_memory_guard(monkeypatch, mode) -> None:
    """When the exact engine's memory would not fit: a one-line error if it was asked for, the
    general model (still optimal here) under ``auto``."""
    rng = np.random.default_rng(11)
    dense = (rng.random((40, 10)) < 0.5) * rng.uniform(0.05, 1.0, (40, 10))
    w = rng.uniform(0.0, 1.0, 40)
    import camplace.solver.engines.maxcover as dispatch

    def huge(*args, **kwargs):  # the exact engines' estimates (models are checked separately)
        return 1 << 60

    for mod, name in [(routes, "bitset_bytes"), (choose, "quality_tree_bytes"),
                      (choose, "quality_exact_bytes"), (dispatch, "bitset_bytes")]:
        monkeypatch.setattr(mod, name, huge)
    monkeypatch.setattr(choose, "_QUALITY_EXPAND_MAX", -1)  # quality: the tree engine would be next
    with pytest.raises(CamplaceError, match="GiB") as err:
        solve(dense, w, 3, mode=mode, engine="exact")
    assert "\n" not in str(err.value)
    res = solve(dense, w, 3, mode=mode)
    assert res.engine == "mip" and "memory_fallback" in res.stats
    best = brute_force_mode(dense, w, 3, mode, views=2)
    assert res.status == "optimal" and res.objective == pytest.approx(best)


def test_memory_budget_is_positive() -> None:
    from camplace.solver._support.memory import memory_budget_bytes

    assert memory_budget_bytes() > 0


def test_solve_time_limit_on_the_tree_engine(monkeypatch) -> None:
    from camplace.solver.problem._synthetic import structured_instance

    a, w = structured_instance(3000, 150, seed=3)
    rng = np.random.default_rng(3)
    a = a.astype(np.float32)
    a.data = rng.uniform(0.05, 1.0, a.nnz).astype(np.float32)  # graded qualities
    monkeypatch.setattr(choose, "QUALITY_EXACT_MAX_N", 0)
    monkeypatch.setattr(choose, "_QUALITY_EXPAND_MAX", -1)
    full = solve(a, w, 3, mode="quality")
    assert full.status == "optimal" and "peak_open" in full.stats["engine_stats"]
    cut = solve(a, w, 3, mode="quality", time_limit_s=1e-6)  # stops after the first greedy start
    assert len(cut.selected) == 3 and cut.stats["engine_stats"]["time_incumbent_s"] >= 0
    # "optimal" and the bound both hold to the engine's pruning margin, 1e-9 x the total weight
    assert_ge(cut.bound, full.objective, scale=w.sum(), what="cut bound vs optimum")
    assert_ge(full.objective, cut.objective, scale=w.sum(), what="optimum vs cut objective")
    assert cut.objective == pytest.approx(mode_objective(a.toarray(), w, cut.selected, "quality"))


@settings(max_examples=30, **_SETTINGS)
@given(data=graded(max_n=9), k=st.integers(2, 3))
def test_portfolio_hands_over_to_the_min_gram_engine(data, k) -> None:
    """When the tree engine's share of the time runs out first, the min-Gram engine finishes the
    proof; the answer still equals enumeration."""
    dense, w = data
    if dense.shape[1] <= k:
        return
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(portfolio, "_TREE_FIRST_S", 0.0)
        mp.setattr(portfolio, "_TREE_FIRST_MIN_S", 0.0)
        res = solve(dense, w, k, mode="quality")
    best = brute_force_mode(dense, w, k, "quality")
    tol = 1e-9 * max(1.0, float(w.sum()))
    assert res.stats["quality_engines"][0] == "tree"
    assert res.status == "optimal" and abs(res.objective - best) <= tol and res.bound == res.objective
