"""k = 5..8 (camplace.solver.engines.large_k.search behind solve): enumeration on small random and structured
instances, fixed and forbidden cameras, interruption keeping a valid bound, the memory check."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from camplace.errors import CamplaceError
from camplace.solver.api import solve
from camplace.solver.engines.bitset import search as bitset_mod
from camplace.solver.engines.large_k.search import solve_large_k, views_incumbent
from camplace.solver.problem._synthetic import structured_instance
from tests.solver._oracle import CountingDeadline, brute_force_mode, solve_deadline

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
_TOL = 1e-9


def _enumerate(dense: np.ndarray, w: np.ndarray, k: int, mode: str, views: int = 1, free=None) -> float:
    """Vectorised enumeration (structured instances): the best value over k-subsets of ``free``."""
    free = list(range(dense.shape[1])) if free is None else list(free)
    combos = np.array(list(itertools.combinations(free, k)), dtype=np.int64)
    best = -np.inf
    for c0 in range(0, combos.shape[0], 2048):
        block = dense[:, combos[c0 : c0 + 2048]]  # (m, b, k)
        if mode == "maxcover":
            vals = w @ (block > 0).any(axis=2)
        elif mode == "quality":
            vals = w @ block.max(axis=2)
        else:
            vals = w @ ((block > 0).sum(axis=2) >= views)
        best = max(best, float(vals.max()))
    return best


@st.composite
def _instances(draw: st.DrawFn):
    n = draw(st.integers(7, 12))
    m = draw(st.integers(1, 30))
    k = draw(st.integers(5, min(8, n - 1)))
    density = draw(st.sampled_from([0.1, 0.3, 0.5, 0.8]))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    dense = (rng.random((m, n)) < density) * rng.uniform(0.05, 1.0, size=(m, n))
    for _ in range(draw(st.integers(0, 3))):  # duplicate cameras (ties, symmetric sets)
        dense[:, rng.integers(n)] = dense[:, rng.integers(n)]
    kind = draw(st.sampled_from(["equal", "float", "integer"]))
    w = {"equal": np.full(m, 1.0 / m), "float": rng.uniform(0, 1, m),
         "integer": rng.integers(0, 5, m).astype(np.float64)}[kind]
    return dense, w, k


def _check(res, best: float, k: int, n_fixed: int = 0) -> None:
    assert res.status == "optimal", (res.status, res.objective, res.bound, res.stats)
    assert len(res.selected) == k + n_fixed
    assert res.objective == pytest.approx(best, abs=_TOL)
    assert res.bound == res.objective and res.gap == 0.0


@settings(max_examples=60, **_SETTINGS)
@given(_instances(), st.sampled_from([("maxcover", 1), ("quality", 1), ("multiview", 1), ("multiview", 2),
                                      ("multiview", 3)]), st.sampled_from(["auto", "exact"]))
def test_large_k_equals_enumeration(inst, mode_views, engine: str) -> None:
    dense, w, k = inst
    mode, views = mode_views
    best = brute_force_mode(dense, w, k, mode, views=views)
    res = solve(sp.csr_matrix(dense), w, k, mode=mode, views=views, engine=engine)
    _check(res, best, k)
    assert res.engine in ("exact", "mip")


@settings(max_examples=40, **_SETTINGS)
@given(_instances(), st.sampled_from(["maxcover", "quality"]), st.data())
def test_large_k_fixed_and_forbidden(inst, mode: str, data) -> None:
    dense, w, k = inst
    n = dense.shape[1]
    cams = data.draw(st.permutations(range(n)))
    n_fixed = data.draw(st.integers(0, 2))
    n_forb = data.draw(st.integers(0, 2))
    fixed, forbidden = tuple(sorted(cams[:n_fixed])), tuple(sorted(cams[n_fixed : n_fixed + n_forb]))
    k = max(5, min(k, n - n_fixed - n_forb))
    assume(n - n_fixed - n_forb > k)  # k = 5..8 new cameras, and a choice among the allowed ones
    best = brute_force_mode(dense, w, k, mode, fixed=fixed, forbidden=forbidden)
    res = solve(sp.csr_matrix(dense), w, k, mode=mode, fixed=fixed, forbidden=forbidden)
    _check(res, best, k, len(fixed))
    assert set(fixed) <= set(res.selected) and not set(forbidden) & set(res.selected)


@pytest.mark.parametrize("mode,views,k", [("maxcover", 1, 6), ("quality", 1, 8), ("quality", 1, 6), ("multiview", 3, 6),
                                          ("multiview", 2, 5)])
def test_large_k_structured_equals_enumeration(mode: str, views: int, k: int) -> None:
    matrix, w = structured_instance(400, 18, seed=3, shape="bilobed", corridor=True, fov_deg=70.0)
    dense = matrix.toarray()
    if mode == "quality":  # graded qualities: distance-like values per entry
        dense = dense * np.random.default_rng(0).uniform(0.2, 1.0, size=dense.shape)
    best = _enumerate(dense, w, k, mode, views)
    res = solve(sp.csr_matrix(dense), w, k, mode=mode, views=views)
    _check(res, best, k)


@pytest.mark.parametrize("binary", [False, True])
@given(inst=_instances(), seed=st.integers(0, 3))
@settings(max_examples=20, **_SETTINGS)
def test_engine_equals_enumeration(inst, binary: bool, seed: int) -> None:
    dense, w, k = inst
    mode = "maxcover" if binary else "quality"
    best = brute_force_mode(dense, w, k, mode)
    out = solve_large_k(sp.csr_matrix(dense), w, k, binary=binary, seed=seed)
    assert out.status == "optimal"
    assert len(set(out.selected)) == k
    assert brute_force_mode(dense[:, list(out.selected)], w, k, mode) == pytest.approx(best, abs=_TOL)
    assert out.bound == pytest.approx(best, abs=_TOL)


@pytest.mark.parametrize("after", [0, 1, 2, 3, 5, 8, 13, 30, 80])
@pytest.mark.parametrize("mode", ["maxcover", "quality", "multiview"])
def test_interrupted_anywhere_keeps_a_valid_bound(monkeypatch, mode: str, after: int) -> None:
    matrix, w = structured_instance(300, 16, seed=5, shape="bilobed", corridor=True, fov_deg=70.0)
    dense = matrix.toarray()
    if mode == "quality":
        dense = dense * np.random.default_rng(1).uniform(0.2, 1.0, size=dense.shape)
    views, k = (3, 6) if mode == "multiview" else (1, 7)
    opt = _enumerate(dense, w, k, mode, views)
    solve_deadline(monkeypatch, CountingDeadline(after))  # the solve's one deadline
    monkeypatch.setattr(bitset_mod, "_SLICE", 3)  # deadline checks every 3 bound evaluations
    res = solve(sp.csr_matrix(dense), w, k, mode=mode, views=views, time_limit_s=30.0)
    assert res.status in ("optimal", "feasible")
    assert len(res.selected) == k
    assert res.objective <= opt + _TOL
    assert res.bound >= opt - _TOL, "the bound must stay valid when interrupted"
    if res.status == "optimal":
        assert res.objective == pytest.approx(opt, abs=_TOL)


@pytest.mark.parametrize("mode,views", [("maxcover", 1), ("quality", 1), ("multiview", 3)])
def test_tiny_time_limit_keeps_a_valid_bound(mode: str, views: int) -> None:
    matrix, w = structured_instance(300, 16, seed=6, shape="bilobed", corridor=True, fov_deg=70.0)
    opt = _enumerate(matrix.toarray(), w, 6, mode, views)
    res = solve(matrix, w, 6, mode=mode, views=views, time_limit_s=1e-3)
    assert res.objective <= opt + _TOL <= res.bound + 2 * _TOL


def test_memory_check_falls_back_or_errors(caplog) -> None:
    matrix, w = structured_instance(100, 14, seed=7)
    res = solve(matrix, w, 6, mode="quality", memory_budget_bytes=10_000)
    assert "memory_fallback" in res.stats  # (the general model did not fit either: greedy + cheap bound)
    assert any("large-k engine needs about" in r.getMessage() for r in caplog.records)
    assert res.bound >= _enumerate(matrix.toarray(), w, 6, "quality") - _TOL
    with pytest.raises(CamplaceError, match="large-k engine needs about .* GiB") as err:
        solve(matrix, w, 6, mode="quality", engine="exact", memory_budget_bytes=10_000)
    assert "\n" not in str(err.value)


def test_views_incumbent_is_a_local_optimum() -> None:
    """No single swap improves the local-search answer (checked by enumeration of every swap)."""
    matrix, w = structured_instance(300, 20, seed=8, shape="bilobed")
    dense = matrix.toarray() > 0
    sel, value, _ = views_incumbent(matrix, w, 6, 3, seed=0, patience=2)
    assert value == pytest.approx(float(w @ (dense[:, list(sel)].sum(axis=1) >= 3)), abs=_TOL)
    for t in range(6):
        for j in set(range(20)) - set(sel):
            other = list(sel)
            other[t] = j
            assert float(w @ (dense[:, other].sum(axis=1) >= 3)) <= value + _TOL
