"""The opposite-pairs multiview bound: valid against enumeration, exact on an analytic case."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import camplace.solver.engines.bitset.search as bitset_mod
import camplace.solver.api as modes
from camplace.solver.api import solve
from camplace.solver._support.deadline import Deadline
from camplace.solver.engines.bitset.pair_cap import opposite_pair_bound
from camplace.solver.engines.bitset.search import solve_bitset
from camplace.solver.problem.presolve import presolve
from camplace.solver.result import EngineOutcome
from tests.solver._oracle import ExpiringDeadline, mode_objective, small_instances, tolerance


def circle(n_points: int, n_cams: int) -> np.ndarray:
    """Points on a circle, each camera seeing the open half circle it faces (cos > 0).

    Angles are offset so that no point lies on a camera's boundary. Only antipodal points are never
    seen together (for ``n_cams`` well above 2), and of any three cameras exactly half of the points
    are seen by at least two: a point is seen by two or more exactly when its antipode is seen by
    one or none.
    """
    phi = 2 * np.pi * (np.arange(n_points) + 0.5) / n_points
    theta = 2 * np.pi * (np.arange(n_cams) + 0.25) / n_cams
    return (np.cos(phi[:, None] - theta[None, :]) > 1e-9).astype(float)


def best_multiview(dense: np.ndarray, w: np.ndarray, cameras: int, views: int, allowed, fixed=()) -> float:
    best = 0.0
    free = [j for j in allowed if j not in fixed]
    for new in itertools.combinations(free, cameras - len(fixed)):
        best = max(best, mode_objective(dense, w, tuple(sorted(set(fixed) | set(new))), "multiview", views))
    return best


@st.composite
def instances(draw):
    n = draw(st.integers(2, 9))
    m = draw(st.integers(1, 30))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    if draw(st.booleans()):  # half circles: many opposite pairs
        dense = circle(m, n)
        dense[rng.random(dense.shape) < 0.1] = 0.0
    else:
        dense = (rng.random((m, n)) < draw(st.sampled_from([0.2, 0.4, 0.6]))).astype(float)
    w = rng.integers(0, 4, size=m).astype(float) if draw(st.booleans()) else rng.uniform(0, 1, size=m)
    views = draw(st.integers(1, 3))
    forbidden = [j for j in range(n) if rng.random() < 0.2]
    allowed = [j for j in range(n) if j not in forbidden]
    if not allowed:
        allowed = [0]
    cameras = draw(st.integers(1, min(len(allowed), 2 * views - 1)))
    fixed = tuple(int(j) for j in rng.choice(allowed, size=draw(st.integers(0, cameras)), replace=False))
    return dense, w, views, cameras, allowed, fixed


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(inst=instances())
def test_bound_is_never_below_the_enumerated_optimum(inst) -> None:
    dense, w, views, cameras, allowed, fixed = inst
    bound, stats = opposite_pair_bound(sp.csr_matrix(dense), w, views, cameras, columns=allowed)
    best = best_multiview(dense, w, cameras, views, allowed, fixed)
    countable = float(w[(dense[:, allowed] > 0).sum(axis=1) >= views].sum())
    tol = 1e-9 * max(1.0, float(w.sum()))
    assert stats["complete"]
    assert best <= bound + tol
    assert abs(stats["countable"] - countable) <= tol
    assert countable / 2 - tol <= bound <= countable + tol  # each matched unit removes one of two


@pytest.mark.parametrize("n_points,n_cams", [(40, 12), (64, 9), (30, 30)])
def test_half_circles_bound_equals_the_optimum(n_points, n_cams) -> None:
    dense = circle(n_points, n_cams)
    w = np.full(n_points, 1.0 / n_points)
    bound, stats = opposite_pair_bound(dense, w, views=2, cameras=3)
    assert best_multiview(dense, w, 3, 2, range(n_cams)) == pytest.approx(0.5, abs=1e-12)
    assert bound == pytest.approx(0.5, abs=1e-12)
    assert stats["matched"] == pytest.approx(0.5, abs=1e-12)


def test_time_limit_keeps_a_valid_bound() -> None:
    dense = circle(40, 12)
    w = np.full(40, 0.025)
    bound, stats = opposite_pair_bound(dense, w, views=2, cameras=3, deadline=Deadline(0.0))
    assert not stats["complete"]
    assert bound == pytest.approx(1.0)  # nothing matched: the countable weight


def test_too_many_cameras_is_refused() -> None:
    with pytest.raises(ValueError, match="4 cameras and 2 views"):
        opposite_pair_bound(circle(8, 6), np.ones(8), views=2, cameras=4)


def test_solve_tightens_an_unproven_multiview_bound(monkeypatch) -> None:
    """An engine that stops with a loose bound: solve() caps it, here down to the optimum."""
    dense = circle(40, 12)
    w = np.full(40, 0.025)
    seen = {}
    real = modes.run_cover

    def loose(problem):
        seen["limit"] = problem.deadline.limit
        return EngineOutcome((0, 4, 8), "feasible", 1.0, {"k": problem.k}, engine="exact", objective=0.5)

    monkeypatch.setattr(modes, "run_cover", loose)
    res = solve(dense, w, 3, mode="multiview", views=2, time_limit_s=10.0)
    assert seen["limit"] == pytest.approx(9.5)  # 5 % of the time is kept for the cap ...
    solve(dense, w, 3, mode="multiview", views=2, time_limit_s=100.0)
    assert seen["limit"] == pytest.approx(98.0)  # ... at most 2 s
    assert res.status == "optimal" and res.gap == 0.0
    assert res.objective == pytest.approx(0.5)
    assert res.stats["opposite_pairs"]["bound_before"] == 1.0

    # Fixed cameras count towards the system size: 2 new + 1 fixed = 3 < 4 still caps ...
    res = solve(dense, w, 2, mode="multiview", views=2, fixed=[1], time_limit_s=10.0)
    assert res.bound == pytest.approx(0.5) and "opposite_pairs" in res.stats
    # ... 3 new + 1 fixed = 4 does not (two opposite points could both count).
    res = solve(dense, w, 3, mode="multiview", views=2, fixed=[1], time_limit_s=10.0)
    assert res.bound == pytest.approx(1.0) and "opposite_pairs" not in res.stats
    assert seen["limit"] == pytest.approx(10.0)

    monkeypatch.setattr(modes, "run_cover", real)
    res = solve(dense, w, 3, mode="multiview", views=2)  # the real engine proves it without the cap
    assert res.status == "optimal" and res.objective == pytest.approx(0.5)
    assert "opposite_pairs" not in res.stats


@st.composite
def engine_instances(draw):
    """Small instances for the bitset engine's opposite-pairs search: k < 2 views."""
    views = draw(st.integers(2, 3))
    if draw(st.booleans()):
        matrix, w, k = draw(small_instances(max_k=min(4, 2 * views - 1)))
        dense = np.asarray(matrix.toarray() if hasattr(matrix, "toarray") else matrix)
    else:  # half circles, some sightings removed, random weights
        rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
        dense = circle(draw(st.integers(4, 40)), draw(st.integers(3, 12)))
        dense[rng.random(dense.shape) < draw(st.sampled_from([0.0, 0.1]))] = 0.0
        w = rng.uniform(0.0, 1.0, dense.shape[0])
        k = draw(st.integers(1, min(dense.shape[1], 2 * views - 1, 4)))
    if draw(st.booleans()):
        w = np.where(w > 0, 0.25, 0.0)  # equal weights: integer arithmetic
    return dense, w, min(k, 2 * views - 1), views


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(inst=engine_instances(), chunk=st.integers(1, 3), checks=st.sampled_from([None, 0, 1, 2, 5]),
       incumbent=st.booleans())
def test_bitset_opposite_pairs_search_equals_enumeration(inst, chunk, checks, incumbent) -> None:
    """The bitset engine on the opposite-pairs layout (forced on, tiny chunks and batches), completed or
    interrupted after a few chunks, with or without a greedy incumbent (then the search alone
    must find the optimum), against enumeration of every k-subset."""
    dense, w, k, views = inst
    n = dense.shape[1]
    pre = presolve(sp.csr_matrix(dense), w, k, dominance=False)
    mp = pytest.MonkeyPatch()
    mp.setattr(bitset_mod, "_PAIRS_MIN_SHARE", 0.0)
    mp.setattr(bitset_mod, "_CHUNK", chunk)
    mp.setattr(bitset_mod, "_BATCH", chunk)  # best-first batches of a few tuples
    mp.setattr(bitset_mod, "_BATCH_MIN", 1)
    if not incumbent:
        mp.setattr(bitset_mod, "_STARTS", 0)
        checks = None
    try:
        out = solve_bitset(pre, views=views, deadline=None if checks is None else ExpiringDeadline(checks))
    finally:
        mp.undo()
    best = best_multiview(dense, w, k, views, range(n))
    tol = tolerance(w)
    if out.stats.get("trivial"):
        return
    sel = pre.original_columns(out.selected)
    got = mode_objective(dense, w, tuple(sel), "multiview", views)
    assert out.stats["search"] == "opposite pairs"
    assert len(sel) == k == len(set(sel))
    assert out.bound >= best - tol and best >= got - tol
    if checks is None:
        assert out.status == "optimal"
    if out.status == "optimal":
        assert abs(got - best) <= tol and abs(out.bound - best) <= tol
