"""Multiview on column bitsets (issue 32): the bits route's answer is the CSR route's and the
enumerated optimum, its helpers equal the CSR kernels they replace, and no CSR is made."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.solver.bits_route as bits_route
from camplace.solver._support import bitkernels as K
from camplace.solver._support import parkernels as P
from camplace.solver.api import solve
from camplace.solver.engines.bitset.pair_cap import match_opposite, opposite_pair_bound
from camplace.solver.problem.objectives import bits_views_value, mode_value
from camplace.solver.problem.presolve_bits import layout_bits, row_bitsets, row_counts_of
from camplace.solver.result import EngineOutcome
from camplace.visibility.bits import BitMatrix, bits_from_csr
from tests.solver.test_solver_pair_cap import circle


def _matrices():
    """(csr, weights): random densities, row counts on and off word boundaries, opposite points."""
    rng = np.random.default_rng(32)
    for m, n, dens in [(1, 2, 0.5), (63, 5, 0.4), (64, 70, 0.3), (130, 129, 0.2), (200, 9, 0.6), (50, 7, 0.0)]:
        a = (rng.random((m, n)) < dens).astype(np.float32)
        w = rng.random(m)
        w[::4] = 0.0
        yield sp.csr_matrix(a), w
    c = circle(90, 11)
    c[rng.random(c.shape) < 0.1] = 0.0
    yield sp.csr_matrix(c), np.where(rng.random(90) < 0.2, 0.0, 0.5)


def test_row_helpers_equal_the_csr_kernels() -> None:
    """row_counts_of / row_bitsets / layout_bits of the bits equal selected_row_stats / row_bits /
    build_bits of the CSR (column subsets, repeated rows and padding included)."""
    rng = np.random.default_rng(1)
    for a, _ in _matrices():
        m, n = a.shape
        bits = bits_from_csr(a)
        for cols in (np.arange(n), np.sort(rng.choice(n, size=max(1, n // 2), replace=False))):
            cols = cols.astype(np.int64)
            chosen = np.zeros(n, dtype=bool)
            chosen[cols] = True
            seen, _ = K.selected_row_stats(a.indptr, a.indices, a.data, chosen)
            for workers in (1, 2):
                np.testing.assert_array_equal(row_counts_of(bits, cols, workers), seen)
            col_map = np.full(n, -1, dtype=np.int64)
            col_map[cols] = np.arange(cols.size)
            rows = rng.permutation(m)[: max(1, m // 2)].astype(np.int64)
            np.testing.assert_array_equal(row_bitsets(bits, rows, cols),
                                          K.row_bits(a.indptr, a.indices, a.data, rows, col_map, cols.size))
            layout = np.concatenate([rows, rows[::-1], np.full(3, -1), rng.integers(0, m, size=70)]).astype(np.int64)
            for workers in (1, 2):
                np.testing.assert_array_equal(layout_bits(bits, layout, col_map, cols.size, workers),
                                              P.build_bits(a.indptr, a.indices, a.data, layout, col_map, cols.size))


def test_match_opposite_on_bits_equals_csr() -> None:
    for a, w in _matrices():
        n = a.shape[1]
        bits = bits_from_csr(a)
        for views, columns, seed in [(1, None, None), (2, None, 0), (2, list(range(0, n, 2)), None), (3, None, 5)]:
            ref = match_opposite(a, w, views, columns=columns, order_seed=seed)
            got = match_opposite(bits, w, views, columns=columns, order_seed=seed)
            np.testing.assert_array_equal(got.pairs, ref.pairs)
            assert got.amount.tobytes() == ref.amount.tobytes()
            np.testing.assert_array_equal(got.rows, ref.rows)
            assert got.residual.tobytes() == ref.residual.tobytes()
            assert got.countable == ref.countable
        assert opposite_pair_bound(bits, w, 2, 3)[0] == opposite_pair_bound(a, w, 2, 3)[0]


def test_bits_views_value_is_mode_value() -> None:
    rng = np.random.default_rng(3)
    for a, w in _matrices():
        n = a.shape[1]
        bits = bits_from_csr(a)
        for views in (1, 2, 3):
            for sel in ([0], [0, 0], list(rng.choice(n, size=min(n, 4), replace=False))):
                assert bits_views_value(bits, w, sel, views) == mode_value(a, w, sel, mode="multiview", views=views)


def _brute(dense: np.ndarray, w: np.ndarray, k: int, views: int) -> float:
    return max(float(w[(dense[:, list(c)] > 0).sum(axis=1) >= views].sum())
               for c in itertools.combinations(range(dense.shape[1]), k))


def _no_csr(monkeypatch) -> None:
    def refuse(self, *args, **kwargs):
        raise AssertionError("the multiview bits route made a CSR copy")

    monkeypatch.setattr(BitMatrix, "tocsr", refuse)


@pytest.mark.parametrize("views", [1, 2, 3])
@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_multiview_on_bits_equals_csr_and_enumeration(views: int, k: int, monkeypatch) -> None:
    """Random instances and half circles (the opposite-pairs layout, k < 2 views), weights with
    zeros, equal weights (integer arithmetic) too: the same selection, status, objective and
    bound as the CSR route, the optimum by enumeration, and no tocsr on the way."""
    rng = np.random.default_rng(10 * views + k)
    cases = []
    for _ in range(2):
        dense = (rng.random((120, 11)) < rng.choice([0.2, 0.5])).astype(np.float32)
        cases.append((dense, np.where(rng.random(120) < 0.2, 0.0, rng.random(120))))
    c = circle(70, 10)
    c[rng.random(c.shape) < 0.1] = 0.0
    cases.append((c, np.where(rng.random(70) < 0.2, 0.0, 0.25)))
    layouts = set()
    for dense, w in cases:
        ref = solve(sp.csr_matrix(dense), w, k, mode="multiview", views=views)
        with monkeypatch.context() as mp:
            _no_csr(mp)
            got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, mode="multiview", views=views)
        assert got.stats["matrix"] == "column bitsets (no CSR copy)"
        assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective,
                                                                         ref.bound)
        assert got.status == "optimal"
        assert got.objective == pytest.approx(_brute(dense, w, k, views), rel=1e-12, abs=1e-12)
        layouts.add(got.stats["engine_stats"].get("search"))
    if 1 < views and k < 2 * views and k > 1:
        assert "opposite pairs" in layouts  # the half circles took the opposite-pairs layout on the bits


def test_multiview_bits_caps_an_unproven_bound_as_the_csr_route(monkeypatch) -> None:
    """An engine stopped with a loose bound: the bits route caps it with the opposite pairs matched
    on the bits, to the CSR route's bound (here the optimum), keeping 5 % of the limit for it."""
    dense = circle(40, 12)
    w = np.full(40, 0.025)
    best = max(itertools.combinations(range(12), 3), key=lambda c: mode_value(dense, w, c, mode="multiview", views=2))
    seen = {}

    def loose(pre, views, deadline, start=None):
        seen["limit"] = deadline.limit
        return EngineOutcome(best, "feasible", 1.0, {}, engine="exact")  # no column dropped: reduced = original

    monkeypatch.setattr(bits_route, "solve_bitset", loose)
    _no_csr(monkeypatch)
    res = solve(bits_from_csr(sp.csr_matrix(dense)), w, 3, mode="multiview", views=2, time_limit_s=10.0)
    assert seen["limit"] == pytest.approx(9.5)
    assert res.stats["opposite_pairs"]["bound_before"] == 1.0
    assert res.status == "optimal" and res.bound == pytest.approx(0.5) and res.objective == pytest.approx(0.5)
    cap = res.stats["opposite_pairs"]
    assert cap["countable"] - cap["matched"] == opposite_pair_bound(dense, w, 2, 3)[0]  # the CSR matching's bound


def test_multiview_bits_off_its_routes_goes_through_csr() -> None:
    """A fixed camera is not the bits route's: the CSR of the presolved rows
    (tests/solver/test_rows_presolve_bits.py) gives the CSR route's answer; k = 5 (the large-k
    engines) runs on the presolved bits (tests/solver/test_large_k_bits.py) with the CSR route's
    answer."""
    rng = np.random.default_rng(5)
    dense = (rng.random((80, 9)) < 0.4).astype(np.float32)
    w = rng.random(80)
    a = sp.csr_matrix(dense)
    for kw in (dict(k=5), dict(k=2, fixed=[1])):
        ref = solve(a, w, mode="multiview", views=2, **kw)
        got = solve(bits_from_csr(a), w, mode="multiview", views=2, **kw)
        if kw["k"] == 5:
            assert got.stats["matrix"].startswith("column bitsets, presolved to ")
        else:
            assert got.stats["matrix"].startswith("column bitsets, rows presolved to ")
        assert (got.selected, got.status, got.objective) == (ref.selected, ref.status, ref.objective)


def test_column_weights_equal_the_csr_product() -> None:
    """The warm start's ranking: the same float64 numbers as the CSR route's ``resid.T @ w`` on the
    bool pattern."""
    from camplace.visibility.bits import column_sums as column_weights

    for a, w in _matrices():
        bits = bits_from_csr(a)
        ref = np.asarray(bits.tocsr(np.bool_).T @ w).ravel()
        for workers in (1, 2):
            assert column_weights(bits, w, workers).tobytes() == ref.tobytes()


@pytest.mark.parametrize("views, k", [(2, 3), (2, 2), (3, 4), (1, 2)])
def test_multiview_bits_warm_start_as_the_csr_route(views: int, k: int, monkeypatch) -> None:
    """With a time limit and more than WARM_MIN_COLS columns (lowered to 8 here; a limit the solve
    does not reach, so nothing depends on timing) both routes solve the heaviest quarter first,
    nested (40 -> 10 -> 3 columns): the same rungs and the same answer."""
    import camplace.solver.routes as routes

    monkeypatch.setattr(routes, "WARM_MIN_COLS", 8)
    monkeypatch.setattr(bits_route, "WARM_MIN_COLS", 8)
    rng = np.random.default_rng(views * 7 + k)
    dense = (rng.random((150, 40)) < 0.3).astype(np.float32)
    w = np.where(rng.random(150) < 0.2, 0.0, rng.random(150))
    ref = solve(sp.csr_matrix(dense), w, k, mode="multiview", views=views, time_limit_s=1000.0)
    with monkeypatch.context() as mp:
        _no_csr(mp)
        got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, mode="multiview", views=views, time_limit_s=1000.0)
    assert got.stats["matrix"] == "column bitsets (no CSR copy)"
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)

    def rungs(stats):
        out = []
        while stats:
            out.append({key: stats[key] for key in ("columns", "status", "objective", "engine")})
            stats = stats.get("inner")
        return out

    assert rungs(got.stats["warm_start"]) == rungs(ref.stats["warm_start"])
    assert [r["columns"] for r in rungs(got.stats["warm_start"])] == [10, max(k, 3)]
    assert got.objective == pytest.approx(_brute(dense, w, k, views), rel=1e-12, abs=1e-12)


# ---- multiview with a minimum angle on bits ---------------------------------------------------


def test_angle_kernels_on_bits_equal_the_csr_kernels() -> None:
    """row_status_bits / gains_bits give the CSR kernels' numbers (gains to the last bit: the same
    chunks, summed in the same order)."""
    from camplace.solver.engines.angle import _kernels as AK

    rng = np.random.default_rng(4)
    for a, w in _matrices():
        m, n = a.shape
        bits = bits_from_csr(a)
        pos, pts = rng.normal(size=(n, 3)) * 4.0, rng.normal(size=(m, 3))
        for sel in ([0], list(range(min(n, 3))), list(rng.choice(n, size=min(n, 5), replace=False))):
            sel = np.unique(np.asarray(sel, dtype=np.int64))
            for views, theta in [(2, 30.0), (3, 12.5), (2, 0.0)]:
                c1, o1 = AK.row_status(a.indptr, a.indices, a.data, sel, pos, pts, views, theta)
                c2, o2 = AK.row_status_bits(bits.words, m, sel, pos, pts, views, theta)
                np.testing.assert_array_equal(c2, c1)
                np.testing.assert_array_equal(o2, o1)
                g1 = AK.gains(a.indptr, a.indices, a.data, w, sel, pos, pts, views, theta, c1, o1, 4)
                g2 = AK.gains_bits(bits.words, m, w, sel, pos, pts, views, theta, c1, o1, 4)
                assert g2.tobytes() == g1.tobytes()


def _angle_cases(seed: int):
    """Random patterns with random positions, and cameras around a sphere (opposite points: the
    pairs layout); weights with zeros, equal weights too."""
    from tests.solver.test_solver_angle import _sphere_instance

    rng = np.random.default_rng(seed)
    dense = (rng.random((110, 10)) < 0.5).astype(np.float32)
    yield dense, np.where(rng.random(110) < 0.2, 0.0, rng.random(110)), rng.normal(size=(10, 3)) * 3.0, rng.normal(
        size=(110, 3))
    dense, w, pos, pts = _sphere_instance(150, 11, seed)
    w[::6] = 0.0
    yield dense, w, pos, pts


@pytest.mark.parametrize("views, k, angle", [(2, 2, 20.0), (2, 3, 35.0), (3, 3, 12.5), (2, 4, 50.0), (3, 4, 25.0)])
def test_min_angle_on_bits_equals_csr_and_enumeration(views: int, k: int, angle: float, monkeypatch) -> None:
    """The angle engine on the bitsets: the CSR route's selection, status, objective and bound
    (its incumbent's gains bit-equal), the enumerated optimum, and no CSR made."""
    from tests.solver._oracle import brute_force_mode

    for dense, w, pos, pts in _angle_cases(views * 10 + k):
        ref = solve(sp.csr_matrix(dense), w, k, mode="multiview", views=views, min_angle_deg=angle, positions=pos,
                    points=pts)
        with monkeypatch.context() as mp:
            _no_csr(mp)
            got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, mode="multiview", views=views, min_angle_deg=angle,
                        positions=pos, points=pts)
        assert got.stats["matrix"] == "column bitsets (no CSR copy)"
        assert got.stats["engine_choice"]["route"] == "angle"
        assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective,
                                                                         ref.bound)
        assert got.status == "optimal"
        best = brute_force_mode(dense, w, k, "multiview", views=views, min_angle_deg=angle, pos=pos, pts=pts)
        assert got.objective == pytest.approx(best, rel=1e-9, abs=1e-12)
        assert got.objective == mode_value(dense, w, got.selected, mode="multiview", views=views, min_angle_deg=angle,
                                           positions=pos, points=pts)


def test_min_angle_on_bits_warm_start_as_the_csr_route(monkeypatch) -> None:
    """With a time limit and more than WARM_MIN_COLS columns (lowered to 8): both routes solve every
    fourth position's poses first (spread_subset), then the whole: the same rungs and answer."""
    import camplace.solver.routes as routes
    from tests.solver.test_solver_angle import _sphere_instance

    monkeypatch.setattr(routes, "WARM_MIN_COLS", 8)
    monkeypatch.setattr(bits_route, "WARM_MIN_COLS", 8)
    dense, w, pos, pts = _sphere_instance(160, 24, 3)
    pos[1::2] = pos[0::2]  # two poses a position
    ref = solve(sp.csr_matrix(dense), w, 3, mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts,
                time_limit_s=1000.0)
    with monkeypatch.context() as mp:
        _no_csr(mp)
        got = solve(bits_from_csr(sp.csr_matrix(dense)), w, 3, mode="multiview", views=2, min_angle_deg=20.0,
                    positions=pos, points=pts, time_limit_s=1000.0)
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)
    keys = ("columns", "status", "objective", "engine")
    assert {key: got.stats["warm_start"][key] for key in keys} == {key: ref.stats["warm_start"][key] for key in keys}
    assert got.stats["warm_start"]["columns"] == 6  # every fourth of the 12 positions, both poses


def test_min_angle_on_bits_needs_positions() -> None:
    from camplace.errors import CamplaceError

    a = sp.csr_matrix(np.ones((4, 3), dtype=np.float32))
    with pytest.raises(CamplaceError, match="min_angle_deg needs camera positions"):
        solve(bits_from_csr(a), np.ones(4), 2, mode="multiview", min_angle_deg=10.0)


# ---- set cover on bits ------------------------------------------------------------------------


def test_rows_csr_is_the_pattern_slice() -> None:
    from camplace.solver.problem.presolve import as_pattern
    from camplace.solver.problem.presolve_bits import rows_csr

    rng = np.random.default_rng(8)
    for a, _ in _matrices():
        m, n = a.shape
        bits = bits_from_csr(a)
        for cols in (np.arange(n), np.sort(rng.choice(n, size=max(1, n // 2), replace=False))):
            rows = np.flatnonzero(rng.random(m) < 0.6)
            ref = as_pattern(a)[:, cols].tocsr()[rows]
            for workers in (1, 2):
                got = rows_csr(bits, rows, cols.astype(np.int64), workers)
                assert got.shape == ref.shape and got.has_canonical_format
                for x, y in ((got.indptr, ref.indptr), (got.indices, ref.indices), (got.data, ref.data)):
                    assert x.dtype == y.dtype
                    np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("case", range(6))
def test_setcover_on_bits_equals_csr_and_enumeration(case: int, monkeypatch) -> None:
    """Costs, fixed and forbidden cameras, partial covers, uncoverable rows and zero weights: the
    CSR route's answer and coverage figures, the enumerated minimum cost, and no tocsr (nor a CSR of
    the rows to cover: the reductions read their row bitsets)."""
    rng = np.random.default_rng(100 + case)
    m, n = 90, 10
    dense = (rng.random((m, n)) < 0.25).astype(np.float32)
    dense[:3] = 0.0  # uncoverable rows
    w = np.where(rng.random(m) < 0.15, 0.0, rng.random(m))
    costs = rng.integers(1, 4, size=n).astype(float) if case % 2 else None
    fixed = (1,) if case in (2, 3) else ()
    forbidden = (4, 7) if case in (3, 4) else ()
    frac = 0.8 if case >= 4 else 1.0
    kw = dict(mode="setcover", costs=costs, fixed=fixed, forbidden=forbidden, required_fraction=frac, iterations=2000)
    ref = solve(sp.csr_matrix(dense), w, **kw)
    def no_rows_csr(*args, **kwargs):
        raise AssertionError("set cover on bits made a CSR of the rows to cover")

    with monkeypatch.context() as mp:
        _no_csr(mp)
        mp.setattr("camplace.solver.engines.setcover.mode.rows_csr", no_rows_csr)
        got = solve(bits_from_csr(sp.csr_matrix(dense)), w, **kw)
    assert got.stats["matrix"] == "column bitsets (the rows to cover as row bitsets)"
    assert got.stats["setcover"]["reduction"]["layout"] == "bitsets"
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)
    for key in ("uncoverable_points", "uncoverable_weight", "coverable_weight", "covered_weight", "covered_fraction"):
        assert got.stats[key] == ref.stats[key]
    # enumeration: the cheapest set of new cameras reaching the required weight
    c = np.ones(n) if costs is None else costs
    free = [j for j in range(n) if j not in fixed and j not in forbidden]
    obs = dense > 0
    coverable = (w > 0) & obs[:, list(fixed) + free].any(axis=1)
    target = frac * float(w[coverable].sum())
    best = min(float(sum(c[j] for j in new)) for r in range(len(free) + 1) for new in itertools.combinations(free, r)
               if float(w[(w > 0) & obs[:, list(fixed) + list(new)].any(axis=1)].sum()) >= target * (1 - 1e-12))
    assert got.status == "optimal" and got.objective == pytest.approx(best)


def test_layout_bits_over_the_budget(monkeypatch) -> None:
    """The transposed layout over the budget: the bitset engine keeps the plain layout (same
    optimum, the skip recorded); the angle engine's OverBudget sends the solve to the CSR route."""
    import camplace.solver.problem.presolve_bits as pb
    from tests.solver.test_solver_angle import _sphere_instance

    dense = circle(70, 10)
    w = np.full(70, 0.5)
    ref = solve(sp.csr_matrix(dense), w, 3, mode="multiview", views=2)
    monkeypatch.setattr(pb, "layout_bits_bytes", lambda *a: 1 << 62)
    with pytest.raises(Exception, match="layout's row bitsets"):
        layout_bits(bits_from_csr(sp.csr_matrix(dense)), np.arange(3), np.arange(10), 10)
    got = solve(bits_from_csr(sp.csr_matrix(dense)), w, 3, mode="multiview", views=2)
    assert got.stats["matrix"] == "column bitsets (no CSR copy)"
    assert "layout's row bitsets" in got.stats["engine_stats"]["opposite_pairs"]["skipped"]
    assert got.status == ref.status == "optimal" and got.objective == ref.objective
    dense, w, pos, pts = _sphere_instance(150, 11, 2)
    kw = dict(mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts)
    ref = solve(sp.csr_matrix(dense), w, 3, **kw)
    got = solve(bits_from_csr(sp.csr_matrix(dense)), w, 3, **kw)
    assert "matrix" not in got.stats  # the CSR route
    assert (got.selected, got.status, got.objective) == (ref.selected, ref.status, ref.objective)


@pytest.mark.parametrize("kw, matrix", [
    (dict(mode="multiview"), "column bitsets (no CSR copy)"),
    (dict(mode="multiview", min_angle_deg=20.0), "column bitsets (no CSR copy)"),
    (dict(mode="setcover", k=None), "column bitsets (the rows to cover as row bitsets)"),
])
def test_binary_run_solves_on_the_bits(kw, matrix, monkeypatch) -> None:
    """A binary instance's run hands its bitsets (and, for the angle, the candidates' and points'
    positions) to the solver, which takes the bits route: no tocsr on the way."""
    import camplace

    _no_csr(monkeypatch)
    sol = camplace.run("comet-67p-bunker", candidates=60, points=500, time_limit_s=30, cache=False, **kw)
    assert sol.solver_stats["matrix"] == matrix
    assert sol.status in ("optimal", "feasible") and sol.selected
