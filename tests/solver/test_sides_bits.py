"""Fixed and forbidden cameras on column bitsets (issue 32): max coverage and multiview with a
minimum angle with fixed and / or forbidden cameras, multiview without the angle with forbidden
ones, are solved on the allowed columns' bits; the answer is the CSR route's and the enumerated
optimum, and no CSR is made. Multiview with fixed cameras and no angle, and a copy over the
budget, go through CSR as before."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.solver.api as api
from camplace.solver.api import solve
from camplace.solver.problem.objectives import mode_value
from camplace.visibility.bits import BitMatrix, bits_from_csr
from tests.solver._oracle import brute_force_mode


def _no_csr(mp) -> None:
    def refuse(self, *args, **kwargs):
        raise AssertionError("the bits route made a CSR copy")

    mp.setattr(BitMatrix, "tocsr", refuse)


def _cases(seed: int):
    """(dense (m, n) float32, weights (m,)): random densities, row counts on and off word
    boundaries, zero weights, equal weights (integer arithmetic) too."""
    rng = np.random.default_rng(seed)
    for m, n, dens in [(64, 9, 0.3), (130, 12, 0.15), (200, 11, 0.4)]:
        dense = (rng.random((m, n)) < dens).astype(np.float32)
        yield dense, np.where(rng.random(m) < 0.2, 0.0, rng.random(m))
    dense = (rng.random((90, 10)) < 0.25).astype(np.float32)
    yield dense, np.full(90, 0.5)


_SIDES = [((1,), ()), ((0, 4), ()), ((), (2,)), ((), (0, 3, 5)), ((6,), (1, 2)), ((2, 3, 7), (8,)),
          ((), (0, 1, 2))]  # (0, 1, 2): the allowed columns are one range, a view of the bits


@pytest.mark.parametrize("k", [1, 2, 3, 4])
@pytest.mark.parametrize("fixed, forbidden", _SIDES)
def test_maxcover_sides_on_bits_equal_csr_and_enumeration(k: int, fixed, forbidden, monkeypatch) -> None:
    """The same selection (fixed included), status, objective and bound as the CSR route, the
    optimum by enumeration over the allowed columns with the fixed ones kept, no tocsr."""
    for dense, w in _cases(10 * k + len(fixed) + 3 * len(forbidden)):
        ref = solve(sp.csr_matrix(dense), w, k, fixed=fixed, forbidden=forbidden)
        with monkeypatch.context() as mp:
            _no_csr(mp)
            got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, fixed=fixed, forbidden=forbidden)
        assert got.stats["matrix"].startswith("column bitsets of the ")
        assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective,
                                                                         ref.bound)
        assert got.status == "optimal"
        assert set(fixed) <= set(got.selected) and not set(forbidden) & set(got.selected)
        assert len(got.selected) == k + len(fixed)
        assert got.stats["fixed"] == list(fixed) and got.stats["forbidden"] == list(forbidden)
        best = brute_force_mode(dense, w, k, "maxcover", fixed=fixed, forbidden=forbidden)
        assert got.objective == pytest.approx(best, rel=1e-12, abs=1e-12)
        assert got.objective == mode_value(dense, w, got.selected, mode="maxcover")


def test_only_fixed_cameras_on_bits(monkeypatch) -> None:
    """k = 0 with fixed cameras: the fixed cameras, optimal, their covered weight (the CSR route's)."""
    dense, w = next(_cases(5))
    ref = solve(sp.csr_matrix(dense), w, 0, fixed=(1, 3))
    with monkeypatch.context() as mp:
        _no_csr(mp)
        got = solve(bits_from_csr(sp.csr_matrix(dense)), w, 0, fixed=(1, 3))
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)
    assert got.selected == (1, 3) and got.status == "optimal"


@pytest.mark.parametrize("k", [1, 2, 3])
def test_quality_of_a_binary_matrix_with_fixed_cameras_on_bits(k: int, monkeypatch) -> None:
    """quality on a binary matrix is max coverage: the enumerated optimum of either objective, no tocsr."""
    for dense, w in _cases(k):
        with monkeypatch.context() as mp:
            _no_csr(mp)
            got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, mode="quality", fixed=(2,), forbidden=(0,))
        assert got.status == "optimal" and 2 in got.selected and 0 not in got.selected
        best = brute_force_mode(dense, w, k, "quality", fixed=(2,), forbidden=(0,))
        assert got.objective == pytest.approx(best, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("views, k", [(1, 2), (2, 2), (2, 3), (3, 4)])
def test_multiview_forbidden_on_bits_equals_csr_and_enumeration(views: int, k: int, monkeypatch) -> None:
    for dense, w in _cases(views + 7 * k):
        for forbidden in ((1,), (0, 4, 5), (6, 7, 8)):
            ref = solve(sp.csr_matrix(dense), w, k, mode="multiview", views=views, forbidden=forbidden)
            with monkeypatch.context() as mp:
                _no_csr(mp)
                got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, mode="multiview", views=views,
                            forbidden=forbidden)
            assert got.stats["matrix"].startswith("column bitsets of the ")
            assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective,
                                                                             ref.bound)
            assert got.status == "optimal" and not set(forbidden) & set(got.selected)
            best = brute_force_mode(dense, w, k, "multiview", views=views, forbidden=forbidden)
            assert got.objective == pytest.approx(best, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("views, k, angle", [(2, 2, 20.0), (2, 3, 35.0), (3, 4, 25.0)])
def test_min_angle_forbidden_on_bits_equals_csr_and_enumeration(views: int, k: int, angle: float,
                                                                 monkeypatch) -> None:
    """The angle engine on the allowed columns' bits, their positions with them."""
    from tests.solver.test_multiview_bits import _angle_cases

    for dense, w, pos, pts in _angle_cases(views * 10 + k):
        forbidden = (1, 4)
        kw = dict(mode="multiview", views=views, min_angle_deg=angle, positions=pos, points=pts, forbidden=forbidden)
        ref = solve(sp.csr_matrix(dense), w, k, **kw)
        with monkeypatch.context() as mp:
            _no_csr(mp)
            got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, **kw)
        assert got.stats["engine_choice"]["route"] == "angle"
        assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective,
                                                                         ref.bound)
        assert got.status == "optimal" and not set(forbidden) & set(got.selected)
        best = brute_force_mode(dense, w, k, "multiview", views=views, min_angle_deg=angle, pos=pos, pts=pts,
                                forbidden=forbidden)
        assert got.objective == pytest.approx(best, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("views, k, angle", [(2, 1, 20.0), (2, 2, 35.0), (3, 2, 12.5), (2, 3, 25.0)])
@pytest.mark.parametrize("fixed, forbidden", [((3,), ()), ((0, 9), ()), ((5,), (1, 2))])
def test_min_angle_fixed_on_bits_equals_csr_and_enumeration(views: int, k: int, angle: float, fixed, forbidden,
                                                            monkeypatch) -> None:
    """The angle engine with fixed cameras on the bitsets of the columns not forbidden (the fixed
    ones among them): the CSR route's selection, status, objective and bound, the enumerated optimum."""
    from tests.solver.test_multiview_bits import _angle_cases

    for dense, w, pos, pts in _angle_cases(views * 10 + k + len(fixed)):
        kw = dict(mode="multiview", views=views, min_angle_deg=angle, positions=pos, points=pts, fixed=fixed,
                  forbidden=forbidden)
        ref = solve(sp.csr_matrix(dense), w, k, **kw)
        with monkeypatch.context() as mp:
            _no_csr(mp)
            got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, **kw)
        assert got.stats["engine_choice"]["route"] == "angle"
        assert got.stats["matrix"] == f"column bitsets of the {dense.shape[1] - len(forbidden)} allowed columns (no CSR copy)"
        assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective,
                                                                         ref.bound)
        assert got.status == "optimal" and set(fixed) <= set(got.selected) and not set(forbidden) & set(got.selected)
        assert len(got.selected) == k + len(fixed)
        best = brute_force_mode(dense, w, k, "multiview", views=views, min_angle_deg=angle, pos=pos, pts=pts,
                                fixed=fixed, forbidden=forbidden)
        assert got.objective == pytest.approx(best, rel=1e-9, abs=1e-12)


def test_min_angle_fixed_on_bits_warm_start_as_the_csr_route(monkeypatch) -> None:
    """With a time limit and more than WARM_MIN_COLS free columns (lowered to 8): both routes solve
    every fourth free position's poses and the fixed cameras first, then the whole: the same answer
    and warm-start figures; only the k + fixed cameras count for the opposite-pairs cap."""
    import camplace.solver.bits_route as bits_route
    import camplace.solver.routes as routes
    from tests.solver.test_solver_angle import _sphere_instance

    monkeypatch.setattr(routes, "WARM_MIN_COLS", 8)
    monkeypatch.setattr(bits_route, "WARM_MIN_COLS", 8)
    dense, w, pos, pts = _sphere_instance(160, 24, 3)
    pos[1::2] = pos[0::2]  # two poses a position
    for k, fixed, forbidden in [(2, (4,), ()), (3, (4, 11), (0, 1)), (1, (6,), (20,))]:
        kw = dict(mode="multiview", views=2, min_angle_deg=20.0, positions=pos, points=pts, fixed=fixed,
                  forbidden=forbidden, time_limit_s=1000.0)
        ref = solve(sp.csr_matrix(dense), w, k, **kw)
        with monkeypatch.context() as mp:
            _no_csr(mp)
            got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k, **kw)
        assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective,
                                                                         ref.bound)
        keys = ("columns", "status", "objective", "engine")
        assert {key: got.stats["warm_start"][key] for key in keys} == {key: ref.stats["warm_start"][key] for key in keys}
        assert set(fixed) <= set(got.selected)


def _counting_tocsr(mp) -> list[int]:
    """BitMatrix.tocsr made to count its calls (and still convert)."""
    calls: list[int] = []
    real = BitMatrix.tocsr

    def counted(self, *args, **kwargs):
        calls.append(1)
        return real(self, *args, **kwargs)

    mp.setattr(BitMatrix, "tocsr", counted)
    return calls


def test_multiview_with_fixed_cameras_goes_through_csr(monkeypatch) -> None:
    """Multiview with fixed cameras and no minimum angle (rows needing views of their own) stays on
    the CSR route, on the CSR of the presolved rows only: the CSR route's answer."""
    from tests.solver.test_large_k_bits import watch_tocsr

    dense, w = next(_cases(2))
    ref = solve(sp.csr_matrix(dense), w, 2, mode="multiview", views=2, fixed=(3,))
    bits = bits_from_csr(sp.csr_matrix(dense))
    with monkeypatch.context() as mp:
        shapes = watch_tocsr(mp, bits)
        got = solve(bits, w, 2, mode="multiview", views=2, fixed=(3,))
    assert shapes == [(got.stats["rows_presolve"]["rows_after"], dense.shape[1])]
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)


def test_allowed_columns_over_the_budget_go_through_csr(monkeypatch) -> None:
    """The allowed columns' bitsets (not one range) over the memory budget: no copy, the CSR route's answer."""
    dense, w = next(_cases(4))
    ref = solve(sp.csr_matrix(dense), w, 2, fixed=(1,), forbidden=(4,))
    with monkeypatch.context() as mp:
        calls = _counting_tocsr(mp)
        mp.setattr(api, "memory_budget_bytes", lambda: 8)
        got = solve(bits_from_csr(sp.csr_matrix(dense)), w, 2, fixed=(1,), forbidden=(4,))
    assert calls == [1]
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)


def test_large_k_with_fixed_cameras_reads_the_presolved_bits(monkeypatch) -> None:
    """k > 4 with fixed cameras: the allowed columns' bits presolved, the large-k engines on the
    reduced instance (never a CSR of the whole matrix); the CSR route's answer."""
    from tests.solver.test_large_k_bits import watch_tocsr

    dense, w = next(_cases(6))
    ref = solve(sp.csr_matrix(dense), w, 5, fixed=(0,), forbidden=(1,))
    bits = bits_from_csr(sp.csr_matrix(dense))
    with monkeypatch.context() as mp:
        shapes = watch_tocsr(mp, bits)
        got = solve(bits, w, 5, fixed=(0,), forbidden=(1,))
    assert got.stats["matrix"].startswith("column bitsets of the ")
    assert all(s == (got.stats["rows_after"], got.stats["cols_after"]) for s in shapes)
    assert (got.selected, got.status, got.objective) == (ref.selected, ref.status, ref.objective)


@pytest.mark.parametrize("kw, message", [
    (dict(k=-1, fixed=(1,)), "k must be at least 0"),
    (dict(k=0, forbidden=(1,)), "k must be at least 1"),
    (dict(k=8, fixed=(1,), forbidden=(2,)), "cannot choose k=8"),
    (dict(k=2, fixed=(1,), forbidden=(1,)), "both fixed and forbidden"),
])
def test_sides_on_bits_errors_are_the_csr_routes(kw, message) -> None:
    from camplace.errors import CamplaceError

    dense, w = next(_cases(1))  # 9 columns
    for matrix in (sp.csr_matrix(dense), bits_from_csr(sp.csr_matrix(dense))):
        with pytest.raises(CamplaceError, match=message):
            solve(matrix, w, **kw)


@pytest.mark.parametrize("kw", [
    dict(k=2, fixed=(3, 17)),
    dict(k=3, forbidden=(5, 6)),
    dict(k=2, fixed=(4,), forbidden=(0, 9)),
    dict(mode="multiview", k=3, forbidden=(1, 2)),
    dict(mode="multiview", k=3, min_angle_deg=20.0, forbidden=(7,)),
    dict(mode="multiview", k=2, min_angle_deg=20.0, fixed=(8,), forbidden=(7,)),
])
def test_binary_run_with_fixed_or_forbidden_cameras_solves_on_the_bits(kw, monkeypatch) -> None:
    """A binary instance's run with --fixed / --forbidden: the solver takes the bits route on the
    allowed columns (no tocsr), fixed cameras kept, forbidden ones not chosen."""
    import camplace

    _no_csr(monkeypatch)
    sol = camplace.run("comet-67p-bunker", candidates=60, points=500, time_limit_s=30, cache=False, **kw)
    angle_fixed = "min_angle_deg" in kw and kw.get("fixed")  # the angle engine keeps the fixed columns
    n_allowed = 60 - (0 if angle_fixed else len(kw.get("fixed", ()))) - len(kw.get("forbidden", ()))
    assert sol.solver_stats["matrix"] == f"column bitsets of the {n_allowed} allowed columns (no CSR copy)"
    assert sol.status in ("optimal", "feasible")
    assert set(kw.get("fixed", ())) <= set(sol.selected) and not set(kw.get("forbidden", ())) & set(sol.selected)
    assert len(sol.selected) == kw["k"] + len(kw.get("fixed", ()))
