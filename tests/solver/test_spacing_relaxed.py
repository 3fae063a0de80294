"""A minimum distance relaxed first (api._relaxed_first): the problem without the spacing between
new cameras is solved on its exact route; a proven optimum whose cameras are spaced is the spaced
optimum, returned without the general model; otherwise the spaced route runs and keeps the smaller
of the two valid bounds. Checked against the enumeration of every spaced set, on CSR and on bits."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.solver.api as api
from camplace.solver.api import bits_solve_bytes, solve
from camplace.solver.options import SolveOptions
from camplace.solver.result import SolverResult
from camplace.visibility.bits import bits_from_csr
from tests.solver._oracle import brute_force_mode, random_observations, spaced


def _case(seed: int, graded: bool = False):
    """(dense (m, n) float32, weights (m,), positions (n, 3) m): 10 cameras, half of them in
    close pairs (so that a distance of 1-2 m binds on some optima and not on others)."""
    rng = np.random.default_rng(seed)
    m, n = 36, 10
    base = rng.normal(size=(n // 2, 3)) * 4.0
    pos = np.concatenate([base, base + rng.normal(size=base.shape) * 0.4])
    dense, w = random_observations(rng, m, n, 0.35, graded)
    return dense, w, pos


_KWS = [
    dict(mode="maxcover", k=3),
    dict(mode="maxcover", k=3, fixed=(1,)),
    dict(mode="quality", k=3),
    dict(mode="multiview", k=3, views=2),
]


# (bits hold binary matrices only: quality, graded here, on CSR)
@pytest.mark.parametrize("layout,kw", [(lay, kw) for kw in _KWS for lay in ("csr", "bits")
                                       if not (lay == "bits" and kw["mode"] == "quality")])
def test_relaxed_first_against_enumeration(layout, kw) -> None:
    seen = set()
    graded = kw["mode"] == "quality"
    for seed, dmin in itertools.product(range(4), (0.9, 2.0, 4.0)):
        dense, w, pos = _case(seed, graded)
        q = sp.csr_matrix(dense)
        mat = bits_from_csr(q) if layout == "bits" else q
        o = SolveOptions(min_distance_m=dmin, time_limit_s=60, **kw)
        got = solve(mat, w, positions=pos, options=o)
        best = brute_force_mode(dense, w, kw["k"], kw["mode"], views=kw.get("views", 2), pos=pos,
                                fixed=kw.get("fixed", ()), dmin=dmin)
        info = got.stats["spacing_relaxed"]
        seen.add(info["spaced"])
        assert got.status == "optimal" and spaced(got.selected, pos, dmin)
        assert got.objective == pytest.approx(best, rel=1e-12, abs=1e-12)
        assert info["bound"] >= best * (1 - 1e-12)  # the relaxation bounds the spaced problem
        assert got.stats["forbidden"] == [] and got.stats["fixed"] == list(kw.get("fixed", ()))
        if info["spaced"]:  # proven at once, without the general model
            assert "model_estimate" not in got.stats and got.engine == "exact"
            assert info["objective"] == pytest.approx(best, rel=1e-12, abs=1e-12)
        else:
            assert info["objective"] >= best * (1 - 1e-12)
    assert seen == {True, False}  # both branches taken


def _res(objective: float, bound: float, status: str = "feasible", sel=(1, 2)) -> SolverResult:
    return SolverResult(selected=sel, status=status, objective=objective, bound=bound, gap=0.0, engine="x",
                        time_s=0.0, stats={})


def test_spaced_best_keeps_the_better_answer_and_the_smaller_bound() -> None:
    info = {"spaced": True}
    # the spaced route stopped below a spaced relaxed answer (stopped too): the relaxed answer, the smaller bound
    got = api._spaced_best(_res(0.5, 0.9), _res(0.6, 0.8, sel=(3, 4)), True, info, 1.0, 2.0)
    assert (got.selected, got.status, got.objective, got.bound) == ((3, 4), "feasible", 0.6, 0.8)
    assert got.gap == pytest.approx(0.25) and got.stats["spaced_route"]["objective"] == 0.5 and got.time_s == 2.0
    # relaxed answer not spaced: the route's answer, its bound lowered to the relaxed optimum
    got = api._spaced_best(_res(0.5, 0.9), _res(0.7, 0.7, "optimal", sel=(3, 4)), False, {"spaced": False}, 1.0, 2.0)
    assert (got.selected, got.status, got.bound) == ((1, 2), "feasible", 0.7)
    # the bounds meet the answer: optimal
    got = api._spaced_best(_res(0.7, 0.9), _res(0.7, 0.7, "optimal", sel=(3, 4)), False, {"spaced": False}, 1.0, 2.0)
    assert (got.status, got.bound, got.gap) == ("optimal", 0.7, 0.0)
    # nothing spaced found: the route's status as it is
    none = SolverResult(selected=(), status="infeasible", objective=float("nan"), bound=float("inf"),
                        gap=float("inf"), engine="x", time_s=0.0, stats={})
    got = api._spaced_best(none, _res(0.7, 0.7, "optimal"), False, {"spaced": False}, 1.0, 2.0)
    assert got.status == "infeasible"


def test_relaxation_applies_only_where_it_helps() -> None:
    assert api._relaxation_applies(SolveOptions(mode="maxcover", k=3, min_distance_m=1.0))
    assert api._relaxation_applies(SolveOptions(mode="setcover", min_distance_m=1.0))
    for o in (SolveOptions(mode="maxcover", k=3), SolveOptions(mode="maxcover", k=3, min_distance_m=1.0, engine="mip"),
              SolveOptions(mode="multiview", k=3, min_distance_m=1.0, min_angle_deg=20.0),
              SolveOptions(mode="setcover", min_distance_m=1.0, engine="cpsat")):
        assert not api._relaxation_applies(o)


def test_guard_counts_both_routes() -> None:
    m, n, nnz, conflicts = 5_000, 300, 400_000, 2_000
    o = SolveOptions(mode="maxcover", k=3, min_distance_m=1.0)
    want = max(api._route_bytes(m, n, replace(o, min_distance_m=None), nnz, 0), api._route_bytes(m, n, o, nnz, conflicts))
    assert bits_solve_bytes(m, n, o, nnz, conflicts) == want
    assert want >= api._route_bytes(m, n, o, nnz, conflicts)


@pytest.mark.parametrize("layout", ["csr", "bits"])
def test_relaxed_first_set_cover_against_enumeration(layout) -> None:
    """Set cover with a minimum distance: the cheapest spaced cover (unit costs), the relaxed
    optimum a valid lower bound; both branches taken."""
    from tests.solver._oracle import brute_force_setcover

    seen = set()
    for seed, dmin in itertools.product(range(4), (2.0, 6.0, 8.0)):
        dense, w, pos = _case(seed)
        dense[:, 0] = np.where(dense.sum(axis=1) == 0, 1.0, dense[:, 0])  # every row coverable
        q = sp.csr_matrix(dense)
        mat = bits_from_csr(q) if layout == "bits" else q
        o = SolveOptions(mode="setcover", min_distance_m=dmin, required_fraction=0.8, time_limit_s=60)
        got = solve(mat, w, positions=pos, options=o)
        best = brute_force_setcover(dense, w, np.ones(dense.shape[1]), 0.8, pos=pos, dmin=dmin)
        info = got.stats["spacing_relaxed"]
        if best is None:  # no spaced cover (the relaxed one is not spaced)
            assert got.status == "infeasible" and not info["spaced"]
            continue
        seen.add(info["spaced"])
        assert got.status == "optimal" and spaced(got.selected, pos, dmin)
        assert got.objective == pytest.approx(best)
        assert info["bound"] <= got.objective + 1e-9  # a lower bound on the spaced cover
    assert seen == {True, False}


@pytest.mark.parametrize("seed", range(6))
def test_free_columns_against_the_pairs_one_by_one(seed: int) -> None:
    """The columns a spaced solve may add and the conflicts among them (``api._free_columns``, numpy
    masks) equal the pairs read one by one: neither fixed, forbidden nor closer than the minimum
    distance to a fixed camera; two fixed cameras closer than it are a one-line error naming the
    first such pair."""
    from camplace.errors import CamplaceError
    from camplace.solver import api

    rng = np.random.default_rng(seed)
    n = 60
    pairs = np.unique(np.sort(rng.integers(0, n, size=(150, 2)), axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]].astype(np.int64)
    conflicted = set(pairs.ravel().tolist())
    lonely = [j for j in range(n) if j not in conflicted]
    fixed = tuple(sorted({int(pairs[0, 0]), *(lonely[:1])}))
    forbidden = tuple(int(j) for j in rng.choice(n, 5, replace=False) if j not in fixed)
    banned = set(forbidden)
    for a, b in pairs.tolist():
        if a in fixed:
            banned.add(b)
        elif b in fixed:
            banned.add(a)
    want_free = [j for j in range(n) if j not in fixed and j not in banned]
    free, kept = api._free_columns(n, fixed, forbidden, pairs, 1.0)
    assert free.tolist() == want_free and int(pairs[0, 1]) not in want_free
    assert kept.tolist() == [[a, b] for a, b in pairs.tolist() if a in want_free and b in want_free]
    free0, kept0 = api._free_columns(n, fixed, forbidden, np.zeros((0, 2), dtype=np.int64), 1.0)
    assert free0.tolist() == [j for j in range(n) if j not in fixed and j not in forbidden] and kept0.size == 0
    with pytest.raises(CamplaceError, match=rf"fixed cameras {pairs[1, 0]} and {pairs[1, 1]} are closer"):
        api._free_columns(n, (*fixed, *(int(x) for x in pairs[1])), (), pairs, 1.0)


def test_neighbours_are_the_pairs_read_one_by_one() -> None:
    """``spaced.neighbours`` (adjacency lists over the candidate index) gives, for every candidate,
    the set a dict of sets filled pair by pair gives, and the default for one with no pair."""
    from camplace.solver.engines.angle.spaced import neighbours

    rng = np.random.default_rng(3)
    pairs = rng.integers(0, 40, size=(120, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    want: dict[int, set[int]] = {}
    for a, b in pairs.tolist():
        want.setdefault(a, set()).add(b)
        want.setdefault(b, set()).add(a)
    nbr = neighbours(pairs)
    for j in range(-1, 45):
        assert nbr.get(j, set()) == want.get(j, set()), j
    assert nbr.get(999) is None and neighbours(np.zeros((0, 2), dtype=np.int64)).get(0, "none") == "none"
