"""Every mode of :func:`camplace.solver.api.solve` equals exhaustive enumeration."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camplace.errors import CamplaceError
from camplace.solver.api import solve
from tests._floats import assert_ge, assert_le
from tests.solver._oracle import brute_force_mode, brute_force_setcover, mode_objective, spaced, usable

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@st.composite
def instances(draw, max_n: int = 9, max_m: int = 14):
    n = draw(st.integers(2, max_n))
    m = draw(st.integers(1, max_m))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    density = draw(st.sampled_from([0.2, 0.4, 0.7]))
    levels = draw(st.sampled_from([None, 3]))  # few distinct qualities -> ties
    q = rng.uniform(0.05, 1.0, size=(m, n))
    if levels:
        q = np.ceil(q * levels) / levels
    dense = (rng.random((m, n)) < density) * q
    if draw(st.booleans()) and n >= 3:
        dense[:, 1] = dense[:, 0]  # duplicate camera
    w = draw(st.sampled_from(["int", "float"]))
    w = rng.integers(0, 4, size=m).astype(float) if w == "int" else rng.uniform(0.0, 1.0, size=m)
    pos = rng.normal(size=(n, 3)) * 3.0
    pts = rng.normal(size=(m, 3))
    return dense, w, pos, pts, rng


def _side(draw, n: int, k_max: int):
    fixed = tuple(sorted(draw(st.sets(st.integers(0, n - 1), max_size=2))))
    forbidden = tuple(sorted(draw(st.sets(st.integers(0, n - 1), max_size=2)) - set(fixed)))
    return fixed, forbidden


def _check_max(res, best, dense, w, k, mode, fixed, forbidden, pos=None, dmin=None, **kw):
    tol = 1e-7 * max(1.0, float(w.sum()))
    if best is None:
        assert res.status in ("infeasible", "unknown")
        return
    assert res.status == "optimal", res
    sel = res.selected
    assert set(fixed) <= set(sel) and not (set(forbidden) & set(sel))
    assert len(sel) == len(fixed) + k == len(set(sel))
    assert spaced(sel, pos, dmin)
    assert abs(mode_objective(dense, w, sel, mode, pos=pos, **kw) - res.objective) <= tol
    assert abs(res.objective - best) <= tol, (res.objective, best)
    assert res.bound == res.objective and res.gap == 0.0


@pytest.mark.parametrize("engine", ["exact", "mip", "cpsat", "auto"])
@settings(max_examples=25, **_SETTINGS)
@given(data=st.data())
def test_quality_and_maxcover_equal_enumeration(engine, data) -> None:
    dense, w, pos, pts, rng = data.draw(instances())
    n = dense.shape[1]
    mode = data.draw(st.sampled_from(["quality", "maxcover"]))
    fixed, forbidden = _side(data.draw, n, 3)
    free = n - len(fixed) - len(forbidden)
    if free < 1:
        return
    k = data.draw(st.integers(1, min(3, free)))
    res = solve(dense, w, k, mode=mode, fixed=fixed, forbidden=forbidden, engine=engine)
    best = brute_force_mode(dense, w, k, mode, fixed=fixed, forbidden=forbidden)
    _check_max(res, best, dense, w, k, mode, fixed, forbidden)


@pytest.mark.parametrize("engine", ["mip", "cpsat"])
@settings(max_examples=25, **_SETTINGS)
@given(data=st.data())
def test_multiview_equals_enumeration(engine, data) -> None:
    dense, w, pos, pts, rng = data.draw(instances())
    n = dense.shape[1]
    views = data.draw(st.integers(1, 3))
    angle = data.draw(st.sampled_from([None, 20.0, 60.0])) if views >= 2 else None
    fixed, forbidden = _side(data.draw, n, 3)
    free = n - len(fixed) - len(forbidden)
    if free < 1:
        return
    k = data.draw(st.integers(1, min(3, free)))
    kw = dict(views=views, min_angle_deg=angle, pts=pts)
    res = solve(dense, w, k, mode="multiview", views=views, min_angle_deg=angle, positions=pos, points=pts,
                fixed=fixed, forbidden=forbidden, engine=engine)
    best = brute_force_mode(dense, w, k, "multiview", pos=pos, fixed=fixed, forbidden=forbidden, **kw)
    _check_max(res, best, dense, w, k, "multiview", fixed, forbidden, pos=pos, **kw)


@pytest.mark.parametrize("mode", ["maxcover", "quality", "multiview"])
@pytest.mark.parametrize("engine", ["mip", "cpsat"])
@settings(max_examples=15, **_SETTINGS)
@given(data=st.data())
def test_min_distance_equals_enumeration(mode, engine, data) -> None:
    dense, w, pos, pts, rng = data.draw(instances())
    n = dense.shape[1]
    dmin = data.draw(st.sampled_from([2.0, 4.0, 6.0]))
    fixed, forbidden = _side(data.draw, n, 3)
    if not spaced(fixed, pos, dmin):
        with pytest.raises(CamplaceError):
            solve(dense, w, 1, mode=mode, positions=pos, min_distance_m=dmin, fixed=fixed, engine=engine)
        return
    free = n - len(fixed) - len(forbidden)
    if free < 1:
        return
    k = data.draw(st.integers(1, min(3, free)))
    best = brute_force_mode(dense, w, k, mode, pos=pos, fixed=fixed, forbidden=forbidden, dmin=dmin)
    try:
        res = solve(dense, w, k, mode=mode, positions=pos, min_distance_m=dmin, fixed=fixed, forbidden=forbidden,
                    engine=engine)
    except CamplaceError:
        # Only when fewer than k candidates remain once those too close to fixed ones are removed.
        assert best is None
        return
    _check_max(res, best, dense, w, k, mode, fixed, forbidden, pos=pos, dmin=dmin)


@pytest.mark.parametrize("engine", ["auto", "mip", "cpsat"])
@settings(max_examples=30, **_SETTINGS)
@given(data=st.data())
def test_setcover_equals_enumeration(engine, data) -> None:
    dense, w, pos, pts, rng = data.draw(instances(max_n=8))
    n = dense.shape[1]
    costs = rng.integers(1, 5, size=n).astype(float) if data.draw(st.booleans()) else np.ones(n)
    fraction = data.draw(st.sampled_from([1.0, 0.5, 0.8]))
    fixed, forbidden = _side(data.draw, n, 0)
    dmin = data.draw(st.sampled_from([None, 3.0]))
    if dmin is not None and not spaced(fixed, pos, dmin):
        return
    res = solve(dense, w, mode="setcover", costs=costs, required_fraction=fraction, fixed=fixed, forbidden=forbidden,
                positions=pos, min_distance_m=dmin, engine=engine)
    best = brute_force_setcover(dense, w, costs, fraction, fixed=fixed, forbidden=forbidden, pos=pos, dmin=dmin)
    allowed = usable(n, fixed, forbidden, pos, dmin)  # uncoverable: no usable camera observes it
    unc = (w > 0) & ~(dense[:, allowed] > 0).any(axis=1)
    assert res.stats["uncoverable_points"] == int(unc.sum())
    assert res.stats["uncoverable_weight"] == pytest.approx(float(w[unc].sum()))
    if best is None:
        assert res.status == "infeasible"
        return
    assert res.status == "optimal"
    assert set(fixed) <= set(res.selected) and not (set(forbidden) & set(res.selected))
    assert spaced(res.selected, pos, dmin)
    assert res.objective == pytest.approx(best)
    assert res.objective == pytest.approx(sum(costs[j] for j in res.selected if j not in fixed))
    coverable = float(w[(w > 0) & ~unc].sum())
    got = mode_objective(dense, w, res.selected, "maxcover")
    assert got >= fraction * coverable - 1e-6 * max(1.0, coverable)


def test_errors_are_one_line() -> None:
    q = np.eye(3)
    w = np.ones(3)
    cases = [
        dict(k=1, mode="bogus"),
        dict(k=1, fixed=[0], forbidden=[0]),
        dict(k=1, min_distance_m=1.0),
        dict(k=None, mode="maxcover"),
        dict(k=2, mode="setcover"),
        dict(k=3, forbidden=[1]),
        dict(k=1, mode="multiview", min_angle_deg=30.0),
        dict(k=1, mode="multiview", engine="exact", fixed=[0]),
    ]
    for kw in cases:
        k = kw.pop("k")
        with pytest.raises(CamplaceError) as ei:
            solve(q, w, k, **kw)
        assert "\n" not in str(ei.value)


def test_time_limit_returns_best_with_gap() -> None:
    rng = np.random.default_rng(3)
    dense = (rng.random((400, 120)) < 0.1) * rng.uniform(0.1, 1.0, (400, 120))
    w = rng.uniform(0.0, 1.0, 400)
    res = solve(dense, w, 8, mode="quality", engine="mip", time_limit_s=1.0)
    assert res.status in ("optimal", "feasible")
    assert len(res.selected) == 8
    assert res.bound >= res.objective
    assert res.objective == pytest.approx(mode_objective(dense, w, res.selected, "quality"))
    if res.status == "feasible":
        assert res.gap > 0.0


@pytest.mark.parametrize("mode", ["quality", "multiview"])
@settings(max_examples=20, **_SETTINGS)
@given(data=st.data())
def test_time_limit_during_model_build_keeps_a_valid_bound(mode, data) -> None:
    """When the limit passes while the MIP model is built, the greedy answer comes back with a
    bound that is still >= the enumerated optimum (fixed and forbidden cameras respected)."""
    import camplace.solver.choose as choose
    import camplace.solver.api as modes

    dense, w, pos, pts, rng = data.draw(instances())
    n = dense.shape[1]
    fixed, forbidden = _side(data.draw, n, 2)
    free = n - len(fixed) - len(forbidden)
    if free < 1:
        return
    k = data.draw(st.integers(1, min(3, free)))
    clock = iter(range(0, 10**8, 100))  # every reading of the clock is 100 s later
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(modes.time, "perf_counter", lambda: float(next(clock)))
        res = solve(dense, w, k, mode=mode, views=2, fixed=fixed, forbidden=forbidden, engine="mip", time_limit_s=50)
    best = brute_force_mode(dense, w, k, mode, views=2, fixed=fixed, forbidden=forbidden)
    if best is None:
        return
    if "model_build" in res.stats:  # (a model with no row to add is built before any clock check)
        assert res.stats["model_build"].startswith("interrupted")
    assert res.status == "feasible" or res.objective == pytest.approx(best)  # "optimal" must be true
    assert set(fixed) <= set(res.selected) and not (set(forbidden) & set(res.selected))
    assert res.objective == pytest.approx(mode_objective(dense, w, res.selected, mode, views=2))
    assert res.bound >= best - 1e-9 * max(1.0, float(w.sum()))
    assert res.bound >= res.objective - 1e-12


@pytest.mark.parametrize("engine", ["exact", "auto"])
@settings(max_examples=60, **_SETTINGS)
@given(data=st.data())
def test_stereo_exact_engine_equals_enumeration(engine, data) -> None:
    """multiview with 2 views and k = 2 or 3 (stereo): the exact (bitset) engine against enumeration."""
    dense, w, pos, pts, rng = data.draw(instances(max_n=10, max_m=18))
    n = dense.shape[1]
    _, forbidden = _side(data.draw, n, 0)
    k = data.draw(st.sampled_from([2, 3]))
    if n - len(forbidden) < k:
        return
    res = solve(dense, w, k, mode="multiview", views=2, forbidden=forbidden, engine=engine)
    assert res.engine == "exact"
    best = brute_force_mode(dense, w, k, "multiview", views=2, forbidden=forbidden)
    _check_max(res, best, dense, w, k, "multiview", (), forbidden, views=2)


def test_stereo_time_limit_keeps_a_valid_bound() -> None:
    from camplace.solver.problem._synthetic import structured_instance

    a, w = structured_instance(3000, 200, seed=4)
    full = solve(a, w, 3, mode="multiview", views=2, engine="exact")
    assert full.status == "optimal"
    cut = solve(a, w, 3, mode="multiview", views=2, engine="exact", time_limit_s=1e-6)  # stops at the root
    assert cut.status == "feasible" and cut.gap > 0 and len(cut.selected) == 3
    assert_ge(cut.bound, full.objective, what="cut bound vs optimum")
    assert_ge(full.objective, cut.objective, what="optimum vs cut objective")  # ties: sums over other rows
    assert cut.objective == pytest.approx(mode_objective(a.toarray(), w, cut.selected, "multiview", views=2))


def test_too_large_model_is_not_built(monkeypatch) -> None:
    """Past the memory budget (model size estimated before building) the greedy answer comes back
    with a valid bound under ``auto``, and an explicitly requested engine is a one-line error;
    either way no memory goes into a model."""
    import camplace.solver.choose as choose
    import camplace.solver.routes as routes

    rng = np.random.default_rng(7)
    dense = (rng.random((30, 8)) < 0.4) * rng.uniform(0.1, 1.0, (30, 8))
    w = rng.uniform(0.0, 1.0, 30)
    monkeypatch.setattr(routes, "model_bytes", lambda *a: 1 << 60)

    def never(*args, **kwargs):
        raise AssertionError("the model was built")

    monkeypatch.setattr(routes, "build_model", never)
    monkeypatch.setattr(choose, "LARGE_K_MAX", 4)  # k = 5 takes the general model's path (not the large-k engine)
    for mode in ("quality", "multiview"):
        res = solve(dense, w, 5, mode=mode, views=3)  # auto with k = 5: the SCIP model
        assert res.stats["model_build"].startswith("skipped")
        assert "memory_fallback" in res.stats
        best = brute_force_mode(dense, w, 5, mode, views=3)
        assert res.objective == pytest.approx(mode_objective(dense, w, res.selected, mode, views=3))
        assert_ge(res.bound, best, what=f"{mode} cheap bound vs optimum")
        assert_le(res.objective, best, what=f"{mode} greedy objective vs optimum")
        with pytest.raises(CamplaceError) as ei:
            solve(dense, w, 3, mode=mode, views=3, engine="mip")
        assert "\n" not in str(ei.value)


def test_setcover_fraction_cpsat_regression() -> None:
    """CP-SAT once claimed cost 3 optimal here (optimum 2): weights scaled to 2**40 broke it."""
    pattern = np.array([
        [1, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 1, 0, 1], [1, 1, 1, 1, 1, 0, 0], [0, 0, 1, 0, 0, 0, 0],
        [0, 0, 0, 0, 1, 0, 0], [0, 1, 0, 0, 0, 1, 0], [0, 1, 1, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0, 0],
        [0, 0, 0, 0, 1, 0, 0], [0, 1, 1, 0, 0, 1, 0], [0, 1, 0, 0, 0, 1, 0], [0, 0, 1, 1, 0, 0, 1],
    ], dtype=float)
    w = np.array([0.3881222, 0.82926972, 0.79469306, 0.20247959, 0.80943139, 0.3868496,
                  0.99653288, 0.31626606, 0.2774125, 0.13696664, 0.05430517, 0.71728347])
    best = brute_force_setcover(pattern, w, np.ones(7), 0.8)
    for engine in ("cpsat", "mip"):
        res = solve(pattern, w, mode="setcover", required_fraction=0.8, engine=engine)
        assert res.status == "optimal" and res.objective == best == 2.0


def test_quality_engine_time_limit_keeps_a_valid_bound() -> None:
    from camplace.solver.problem._synthetic import structured_instance

    a, w = structured_instance(3000, 150, seed=2)
    rng = np.random.default_rng(2)
    a = a.astype(np.float32)
    a.data = rng.uniform(0.05, 1.0, a.nnz).astype(np.float32)  # graded qualities
    full = solve(a, w, 3, mode="quality", engine="exact")
    assert full.status == "optimal" and full.engine == "exact"
    cut = solve(a, w, 3, mode="quality", engine="exact", time_limit_s=1e-6)
    assert len(cut.selected) == 3
    # "optimal" and the bound both hold to the engine's pruning margin, 1e-9 x the total weight
    assert_ge(cut.bound, full.objective, scale=w.sum(), what="cut bound vs optimum")
    assert_ge(full.objective, cut.objective, scale=w.sum(), what="optimum vs cut objective")
    assert cut.objective == pytest.approx(mode_objective(a.toarray(), w, cut.selected, "quality"))
