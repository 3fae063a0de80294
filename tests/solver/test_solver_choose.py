"""choose_engine: the documented table of cases -> engine (a pure function of sizes, options, budget)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.solver import solve
from camplace.solver.choose import ProblemSizes, choose_engine, problem_sizes
from camplace.solver.options import SolveOptions

BIG = 1 << 40  # bytes: everything fits
MB = 1 << 20


def _p(k, free=100, fixed=0, conflicts=0, points=1000, nnz=10_000, gram=1e4, expanded=2e4) -> ProblemSizes:
    return ProblemSizes(k=k, points=points, free=free, nnz=nnz, fixed=fixed, conflicts=conflicts,
                        min_gram_pairs=gram, expanded_nnz=expanded)


# (problem, options, budget) -> (engine, route): the rules of docs/solver.md, "Which engine runs"
CASES = [
    ("maxcover k=3", _p(3), SolveOptions(k=3), BIG, "exact", "maxcover"),
    ("maxcover k=4", _p(4), SolveOptions(k=4), BIG, "exact", "maxcover"),
    ("maxcover k=5", _p(5), SolveOptions(k=5), BIG, "exact", "large-k"),
    ("maxcover k=8", _p(8), SolveOptions(k=8), BIG, "exact", "large-k"),
    ("maxcover k=9", _p(9), SolveOptions(k=9), BIG, "mip", "maxcover"),
    ("maxcover k=6 spaced", _p(6, conflicts=4), SolveOptions(k=6), BIG, "mip", "model"),
    ("maxcover k=6 mip", _p(6), SolveOptions(k=6, engine="mip"), BIG, "mip", "maxcover"),
    ("maxcover spaced", _p(3, conflicts=4), SolveOptions(k=3), BIG, "mip", "model"),
    ("maxcover mip", _p(3), SolveOptions(k=3, engine="mip"), BIG, "mip", "maxcover"),
    ("maxcover cpsat", _p(3), SolveOptions(k=3, engine="cpsat"), BIG, "cpsat", "maxcover"),
    ("maxcover fixed", _p(3, fixed=2), SolveOptions(k=3), BIG, "exact", "maxcover"),
    ("quality k=3", _p(3), SolveOptions(mode="quality", k=3), BIG, "exact", "quality-portfolio"),
    ("quality k=4", _p(4), SolveOptions(mode="quality", k=4), BIG, "exact", "quality-portfolio"),
    ("quality k=5", _p(5), SolveOptions(mode="quality", k=5), BIG, "exact", "large-k"),
    ("quality k=5 exact", _p(5), SolveOptions(mode="quality", k=5, engine="exact"), BIG, "exact", "large-k"),
    ("quality k=9", _p(9), SolveOptions(mode="quality", k=9), BIG, "mip", "model"),
    ("quality k=9 exact", _p(9), SolveOptions(mode="quality", k=9, engine="exact"), BIG, "exact", "quality-portfolio"),
    ("quality k=6 fixed", _p(6, fixed=2), SolveOptions(mode="quality", k=6), BIG, "exact", "large-k"),
    ("quality levels", _p(4, free=5000), SolveOptions(mode="quality", k=4), 5 * MB, "exact", "quality-levels"),
    ("quality nothing fits", _p(4, free=5000), SolveOptions(mode="quality", k=4), MB, "mip", "model"),
    ("quality spaced", _p(3, conflicts=1), SolveOptions(mode="quality", k=3), BIG, "mip", "model"),
    ("quality cpsat", _p(3), SolveOptions(mode="quality", k=3, engine="cpsat"), BIG, "cpsat", "model"),
    ("multiview k=3", _p(3), SolveOptions(mode="multiview", k=3), BIG, "exact", "multiview"),
    ("multiview k=5", _p(5), SolveOptions(mode="multiview", k=5), BIG, "exact", "large-k"),
    ("multiview k=6 fixed", _p(6, fixed=1), SolveOptions(mode="multiview", k=6), BIG, "mip", "model"),
    ("multiview k=9", _p(9), SolveOptions(mode="multiview", k=9), BIG, "mip", "model"),
    ("multiview fixed", _p(3, fixed=1), SolveOptions(mode="multiview", k=3), BIG, "mip", "model"),
    ("multiview spaced", _p(3, conflicts=2), SolveOptions(mode="multiview", k=3), BIG, "mip", "model"),
    ("angle k=3", _p(3), SolveOptions(mode="multiview", k=3, min_angle_deg=20.0), BIG, "exact", "angle"),
    ("angle fixed", _p(3, fixed=2), SolveOptions(mode="multiview", k=3, min_angle_deg=20.0), BIG, "exact", "angle"),
    ("angle k=6", _p(6), SolveOptions(mode="multiview", k=6, min_angle_deg=20.0), BIG, "mip", "model"),
    ("angle exact k=6", _p(6), SolveOptions(mode="multiview", k=6, min_angle_deg=20.0, engine="exact"), BIG, "exact",
     "angle"),
    ("angle spaced", _p(3, conflicts=3), SolveOptions(mode="multiview", k=3, min_angle_deg=20.0), BIG, "mip", "model"),
]


@pytest.mark.parametrize(("problem", "options", "budget", "engine", "route"), [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_engine_table(problem, options, budget, engine, route) -> None:
    choice = choose_engine(problem, options, budget)
    assert (choice.engine, choice.route) == (engine, route)
    name, reason = choice  # unpacks as (engine, reason)
    assert name == engine and reason and "\n" not in reason
    assert reason.startswith("requested" if options.engine != "auto" else "auto")


@pytest.mark.parametrize(("problem", "options", "engine", "route"), [
    (_p(5), SolveOptions(k=5), "mip", "maxcover"),
    (_p(5), SolveOptions(mode="quality", k=5), "mip", "model"),
    (_p(5), SolveOptions(mode="quality", k=5, engine="exact"), "exact", "quality-portfolio"),
    (_p(6), SolveOptions(mode="multiview", k=6), "mip", "model"),
])
def test_choice_when_large_k_does_not_fit(problem, options, engine, route) -> None:
    """The large-k engines measure their own memory; when they do not fit, solve asks again
    without them and gets the rules for k > 4 of the other engines."""
    choice = choose_engine(problem, options, BIG, large_k=False)
    assert (choice.engine, choice.route) == (engine, route)


def test_quality_portfolio_members() -> None:
    opts = SolveOptions(mode="quality", k=3)
    both = choose_engine(_p(3), opts, BIG)
    assert both.tree and both.gram
    assert not choose_engine(_p(4), SolveOptions(mode="quality", k=4), BIG).gram  # min-Gram: k = 2, 3 only
    assert not choose_engine(_p(3, free=3001), opts, BIG).gram  # ... and n <= 3000
    assert not choose_engine(_p(3, gram=6e9), opts, BIG).gram  # ... and at most 5e9 pair terms


def test_quality_fallback_is_recorded_and_exact_is_an_error() -> None:
    choice = choose_engine(_p(4, free=5000), SolveOptions(mode="quality", k=4), MB)
    assert "GiB" in choice.stats["memory_fallback"]
    assert choice.stats["quality_expanded_nnz_estimate"] == 2e4
    with pytest.raises(CamplaceError, match="GiB") as exc:
        choose_engine(_p(4, free=5000), SolveOptions(mode="quality", k=4, engine="exact"), MB)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize(("problem", "options"), [
    (_p(3, fixed=1), SolveOptions(mode="multiview", k=3, engine="exact")),
    (_p(3, conflicts=1), SolveOptions(k=3, engine="exact")),
    (_p(3, conflicts=1), SolveOptions(mode="multiview", k=3, min_angle_deg=10.0, engine="exact")),
])
def test_exact_where_it_does_not_apply(problem, options) -> None:
    with pytest.raises(CamplaceError, match="use engine mip or cpsat"):
        choose_engine(problem, options, BIG)


def test_problem_sizes_counts_the_quality_rows() -> None:
    a = sp.csr_matrix(np.array([[1.0, 0.5, 0.0], [0.0, 0.0, 0.2], [0.0, 0.0, 0.0]]))
    p = problem_sizes(a, 2, 3, 0, 0, "quality")
    assert (p.points, p.free, p.nnz) == (3, 3, 3)
    assert p.min_gram_pairs == 1.0  # row 0: one pair of observers
    assert p.expanded_nnz == 3.0 + 1.0  # s (s + 1) / 2 for s = 2 and 1


def test_solve_records_the_choice() -> None:
    rng = np.random.default_rng(3)
    dense = (rng.random((30, 8)) < 0.4).astype(float)
    res = solve(dense, np.ones(30), 2, mode="multiview", fixed=[1])
    assert res.engine == "mip"
    assert res.stats["engine_choice"]["route"] == "model"
    assert "fixed" in res.stats["engine_choice"]["reason"]
