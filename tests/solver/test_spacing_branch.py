"""A minimum distance by branching on the relaxed optimum's conflicting pairs
(camplace.solver.spacing_branch, api._spacing_branched): where the relaxed optimum is not spaced,
the parts with one camera of a close pair forbidden are solved on the same exact route until the
best spaced answer is proven, without the general model. Checked against the enumeration of every
spaced set."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.solver.api as api
from camplace.errors import CamplaceError
from camplace.solver.api import solve
from camplace.solver.options import SolveOptions
from camplace.solver.result import SolverResult
from camplace.solver.spacing_branch import branch_on_conflicts, conflict
from camplace.visibility.bits import bits_from_csr
from tests.solver._oracle import brute_force_mode, random_observations, spaced


def _case(seed: int, m: int = 40, n: int = 14, graded: bool = False):
    """(dense (m, n) float32, weights (m,), positions (n, 3) m): cameras in tight clusters of two or
    three around a few places, so that the relaxed optimum often takes two of one cluster."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(5, 3)) * 4.0
    pos = centres[rng.integers(0, 5, size=n)] + rng.normal(size=(n, 3)) * 0.3
    dense, w = random_observations(rng, m, n, 0.3, graded)
    return dense, w, pos


_KWS = [
    dict(mode="maxcover", k=3),
    dict(mode="maxcover", k=4),
    dict(mode="maxcover", k=3, fixed=(2,)),
    dict(mode="quality", k=3),
    dict(mode="multiview", k=3, views=2),
    dict(mode="multiview", k=4, views=3),
]


@pytest.mark.parametrize("layout,kw", [(lay, kw) for kw in _KWS for lay in ("csr", "bits")
                                       if not (lay == "bits" and kw["mode"] == "quality")])
def test_branching_proves_the_spaced_optimum_against_enumeration(layout, kw) -> None:
    branched = 0
    graded = kw["mode"] == "quality"
    for seed, dmin in itertools.product(range(12), (1.5, 3.0)):
        dense, w, pos = _case(seed, graded=graded)
        q = sp.csr_matrix(dense)
        mat = bits_from_csr(q) if layout == "bits" else q
        got = solve(mat, w, positions=pos, options=SolveOptions(min_distance_m=dmin, time_limit_s=60, **kw))
        best = brute_force_mode(dense, w, kw["k"], kw["mode"], views=kw.get("views", 2), pos=pos,
                                fixed=kw.get("fixed", ()), dmin=dmin)
        if best is None:  # no spaced set at all
            assert got.status == "infeasible"
            continue
        assert got.status == "optimal" and spaced(got.selected, pos, dmin)
        assert got.objective == pytest.approx(best, rel=1e-12, abs=1e-12)
        assert got.stats["forbidden"] == [] and got.stats["fixed"] == list(kw.get("fixed", ()))
        info = got.stats["spacing_relaxed"]
        if not info["spaced"]:  # the relaxed optimum had a close pair: branched, proven without the model
            branched += 1
            assert info["branching"]["closed"] and info["branching"]["solves"] >= 2
            assert "model_estimate" not in got.stats and got.engine == "exact"
            assert info["branching"]["bound"] == pytest.approx(best, rel=1e-12, abs=1e-12)
    assert branched >= 3  # the cases do bind


def test_a_cut_short_branching_keeps_a_valid_bound_and_the_route_finishes(monkeypatch) -> None:
    """With one relaxed solve allowed (no branching) the spaced route runs as before and proves the
    optimum; the branching's bound, from its open parts, is never below the spaced optimum."""
    monkeypatch.setattr(api, "SPACING_BRANCH_SOLVES", 2)
    seen = 0
    for seed in range(6):
        dense, w, pos = _case(seed)
        got = solve(sp.csr_matrix(dense), w, positions=pos, options=SolveOptions(mode="maxcover", k=3,
                                                                                 min_distance_m=1.5, time_limit_s=60))
        best = brute_force_mode(dense, w, 3, "maxcover", pos=pos, dmin=1.5)
        assert got.status == "optimal" and got.objective == pytest.approx(best, rel=1e-12)
        br = got.stats["spacing_relaxed"].get("branching")
        if br is not None and not br["closed"]:
            seen += 1
            assert br["stopped"] == "solve budget" and br["bound"] >= best * (1 - 1e-12)
    assert seen >= 1


def _res(objective: float, bound: float, selected, status: str = "optimal") -> SolverResult:
    return SolverResult(status=status, objective=objective, bound=bound, gap=0.0, selected=tuple(selected),
                        engine="exact", time_s=0.0, stats={})


def test_branching_on_a_toy_problem() -> None:
    """Three cameras, 0 and 1 close together: the relaxed optimum {0, 1} splits into {1, 2} (0
    forbidden) and {0, 2} (1 forbidden); the better is the optimum, the worse part is dropped."""
    pos = np.array([[0.0, 0, 0], [0.5, 0, 0], [5.0, 0, 0]])
    answers = {(0,): _res(0.7, 0.7, (1, 2)), (1,): _res(0.8, 0.8, (0, 2))}
    calls = []

    def solve_forbidding(forb):
        calls.append(forb)
        return answers[forb]

    out = branch_on_conflicts(_res(0.9, 0.9, (0, 1)), solve_forbidding, pos, 1.0, (), 3, 2, lambda: False, 1e-12, 50, 50)
    assert out.closed and out.best.selected == (0, 2) and out.bound == pytest.approx(0.8)
    assert sorted(calls) == [(0,), (1,)] and out.stats["solves"] == 3
    assert conflict((0, 2), pos, 1.0) is None and conflict((2, 0, 1), pos, 1.0) == (0, 1)


def test_branching_stops_on_time_with_the_open_bound() -> None:
    pos = np.array([[0.0, 0, 0], [0.5, 0, 0], [5.0, 0, 0]])
    out = branch_on_conflicts(_res(0.9, 0.9, (0, 1)), lambda forb: pytest.fail("no solve after the time"),
                              pos, 1.0, (), 3, 2, lambda: True, 1e-12, 50, 50)
    assert not out.closed and out.best is None and out.bound == 0.9 and out.stats["stopped"] == "time limit"


def test_a_failed_part_stays_open() -> None:
    pos = np.array([[0.0, 0, 0], [0.5, 0, 0], [5.0, 0, 0]])

    def solve_forbidding(forb):
        if forb == (1,):
            raise CamplaceError("over the memory budget")
        return _res(0.7, 0.7, (1, 2))

    out = branch_on_conflicts(_res(0.9, 0.9, (0, 1)), solve_forbidding, pos, 1.0, (), 3, 2, lambda: False, 1e-12, 50, 50)
    assert not out.closed and out.bound == 0.9 and out.best.selected == (1, 2)


def test_no_part_is_solved_after_the_time() -> None:
    """The time ends after the first part's solve: the second part is not started, the pair's node
    stays open at its bound (a route called with no time left may still take its set-up's time)."""
    pos = np.array([[0.0, 0, 0], [0.5, 0, 0], [5.0, 0, 0]])
    calls = []

    def solve_forbidding(forb):
        calls.append(forb)
        return _res(0.7, 0.7, (1, 2))

    out = branch_on_conflicts(_res(0.9, 0.9, (0, 1)), solve_forbidding, pos, 1.0, (), 3, 2, lambda: bool(calls),
                              1e-12, 50, 50)
    assert calls == [(0,)] and not out.closed and out.bound == 0.9 and out.stats["stopped"] == "time limit"
    assert out.best.selected == (1, 2)


def test_a_part_not_proven_stops_the_branching() -> None:
    """A part's solve that stops before its proof (its time ran out): its answer and bound are
    kept, and no further part is started (the rest would be no easier)."""
    pos = np.array([[0.0, 0, 0], [0.5, 0, 0], [5.0, 0, 0]])
    calls = []

    def solve_forbidding(forb):
        calls.append(forb)
        return _res(0.7, 0.85, (1, 2), status="feasible")

    out = branch_on_conflicts(_res(0.9, 0.9, (0, 1)), solve_forbidding, pos, 1.0, (), 3, 2, lambda: False, 1e-12, 50, 50)
    assert calls == [(0,)] and not out.closed and out.stats["stopped"] == "a part not proven"
    assert out.best.selected == (1, 2) and out.bound == 0.9  # the pair's node, its second part unsolved
