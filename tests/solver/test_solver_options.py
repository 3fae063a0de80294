"""SolveOptions: its checks, the command line that builds it, and solve(options=...)."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from camplace.errors import CamplaceError
from camplace.solver import solve
from camplace.solver.options import SolveOptions, add_solver_options, options_from_args

from ._oracle import brute_force_mode, brute_force_setcover

RNG = np.random.default_rng(7)
DENSE = (RNG.random((30, 9)) < 0.3) * RNG.uniform(0.2, 1.0, (30, 9))
W = RNG.uniform(0.5, 2.0, 30)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"mode": "bogus"}, "unknown mode 'bogus'"),
    ({"engine": "gurobi"}, "unknown solver engine 'gurobi'"),
    ({"time_limit_s": 0.0}, "time_limit_s must be > 0"),
    ({"memory_budget_bytes": 0}, "memory budget must be > 0"),
    ({"min_distance_m": -1.0}, "min_distance_m must be >= 0"),
    ({"min_angle_deg": 10.0}, "applies to mode 'multiview' only"),
    ({"mode": "multiview", "min_angle_deg": 190.0}, "within 0..180"),
    ({"mode": "multiview", "views": 0}, "views must be an integer >= 1"),
    ({"mode": "multiview", "views": True}, "views must be an integer >= 1"),
    ({"mode": "multiview", "views": 1, "min_angle_deg": 20.0}, "needs views >= 2"),
    ({"mode": "setcover", "k": 2}, "do not give k"),
    ({"mode": "setcover", "required_fraction": 0.0}, r"required_fraction must be in \(0, 1\]"),
    ({"k": 2.5}, "k must be an integer"),
    ({"k": True}, "k must be an integer"),
])
def test_bad_options_are_one_line_errors(kwargs, match) -> None:
    with pytest.raises(CamplaceError, match=match) as exc:
        SolveOptions(**kwargs)
    assert "\n" not in str(exc.value)


def test_options_that_only_matter_for_other_modes_are_not_checked() -> None:
    # as before: views is checked for multiview only, required_fraction for setcover only
    assert SolveOptions(mode="maxcover", k=2, views=0, required_fraction=5.0).views == 0


def test_solve_with_options_matches_enumeration_and_keywords() -> None:
    opts = SolveOptions(mode="multiview", k=3, views=2, fixed=(1,), forbidden=(4,))
    res = solve(DENSE, W, options=opts)
    best = brute_force_mode(DENSE > 0, W, 3, "multiview", views=2, fixed=(1,), forbidden=(4,))
    assert res.status == "optimal"
    assert res.objective == pytest.approx(best, rel=1e-9)
    same = solve(DENSE, W, 3, mode="multiview", views=2, fixed=(1,), forbidden=(4,))
    assert same.selected == res.selected and same.objective == res.objective


def test_solve_setcover_with_options_matches_enumeration() -> None:
    costs = np.arange(1, 10, dtype=float)
    res = solve(DENSE, W, options=SolveOptions(mode="setcover", costs=costs, required_fraction=0.8))
    assert res.status == "optimal"
    assert res.objective == pytest.approx(brute_force_setcover(DENSE > 0, W, costs, 0.8), rel=1e-9)


def test_options_beside_keywords_is_an_error() -> None:
    with pytest.raises(CamplaceError, match="engine, k inside options=SolveOptions"):
        solve(DENSE, W, 2, engine="mip", options=SolveOptions(k=2))


def test_command_line_builds_the_options() -> None:
    p = argparse.ArgumentParser()
    add_solver_options(p, k_default="the run's k")
    args = p.parse_args(["--mode", "multiview", "--k", "3", "--views", "3", "--min-angle", "20", "--fixed", "1, 2",
                         "--forbidden", "5", "--min-distance", "0.5", "--engine", "cpsat", "--time-limit", "9",
                         "--memory-budget-gb", "0.5"])
    assert options_from_args(args) == SolveOptions(
        mode="multiview", k=3, views=3, min_angle_deg=20.0, fixed=(1, 2), forbidden=(5,), min_distance_m=0.5,
        engine="cpsat", time_limit_s=9.0, memory_budget_bytes=2**29)
    assert options_from_args(args, k=4).k == 4
    bad = p.parse_args(["--time-limit", "-1"])
    with pytest.raises(CamplaceError, match="--time-limit: must be > 0"):
        options_from_args(bad)


def test_record_has_the_solution_json_keys() -> None:
    rec = SolveOptions(mode="multiview", k=2, views=3, fixed=(4, 1)).record()
    assert list(rec) == ["mode", "k", "views", "min_angle_deg", "required_fraction", "fixed", "forbidden",
                         "min_distance_m", "engine", "time_limit_s", "search_seed"]
    assert rec["views"] == 3 and rec["fixed"] == [1, 4] and rec["required_fraction"] is None
    assert rec["search_seed"] is None  # only setcover's local search has a seed
    rec = SolveOptions(mode="setcover", views=3, search_seed=5).record()
    assert rec["k"] is None and rec["views"] is None and rec["required_fraction"] == 1.0 and rec["search_seed"] == 5


def test_index_arrays_are_accepted() -> None:
    opts = SolveOptions(k=2, fixed=np.array([1, 2]), forbidden=np.array([4, 5]))
    assert opts.fixed == (1, 2) and opts.forbidden == (4, 5)
    res = solve(DENSE, W, 2, fixed=np.array([1, 2]), forbidden=np.array([4, 5]))
    best = brute_force_mode(DENSE > 0, W, 2, "maxcover", fixed=(1, 2), forbidden=(4, 5))
    assert res.objective == pytest.approx(best, rel=1e-9) and {1, 2} <= set(res.selected)
