"""Public API: errors, edge cases, result serialisation, coverage helper."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.solver import ENGINES, SolverResult, coverage_weight, solve_maxcover

A = sp.csr_matrix(np.array([[1.0, 0.0, 0.3], [0.0, 0.5, 0.0], [0.2, 0.2, 0.0]]))
W = np.array([1.0, 2.0, 3.0])


@pytest.mark.parametrize("k", [0, -1, 4, 100])
def test_k_out_of_range(k: int) -> None:
    with pytest.raises(CamplaceError) as exc:
        solve_maxcover(A, W, k)
    assert "\n" not in str(exc.value)
    assert "k" in str(exc.value)


@pytest.mark.parametrize("k", [2.5, "2", True, None])
def test_k_not_integer(k) -> None:
    with pytest.raises(CamplaceError):
        solve_maxcover(A, W, k)  # type: ignore[arg-type]


def test_k_numpy_integer_accepted() -> None:
    assert solve_maxcover(A, W, np.int64(2)).status == "optimal"


@pytest.mark.parametrize(
    ("weights", "match"),
    [(np.ones(2), "shape"), (np.array([1.0, -1.0, 1.0]), ">= 0"), (np.array([1.0, np.nan, 1.0]), "NaN")],
)
def test_bad_weights(weights, match: str) -> None:
    with pytest.raises(CamplaceError, match=match):
        solve_maxcover(A, weights, 1)


def test_bad_engine_and_time_limit() -> None:
    with pytest.raises(CamplaceError, match="engine"):
        solve_maxcover(A, W, 1, engine="gurobi")
    with pytest.raises(CamplaceError, match="time_limit_s"):
        solve_maxcover(A, W, 1, time_limit_s=0.0)
    with pytest.raises(CamplaceError, match="NaN"):
        solve_maxcover(np.array([[np.nan, 1.0]]), np.ones(1), 1)
    with pytest.raises(CamplaceError, match="2-D"):
        solve_maxcover(np.ones(3), np.ones(3), 1)


@pytest.mark.parametrize("engine", ["auto", "exact", "mip", "cpsat"])
def test_all_weights_zero(engine: str) -> None:
    res = solve_maxcover(A, np.zeros(3), 2, engine=engine)
    assert res.status == "optimal"
    assert res.objective == 0.0 and res.bound == 0.0 and res.gap == 0.0
    assert len(res.selected) == 2 and len(set(res.selected)) == 2


@pytest.mark.parametrize("engine", ["exact", "mip", "cpsat"])
def test_no_coverable_point(engine: str) -> None:
    res = solve_maxcover(sp.csr_matrix((5, 4)), np.ones(5), 3, engine=engine)
    assert res.status == "optimal"
    assert res.objective == 0.0
    assert res.selected == (0, 1, 2)


def test_zero_rows_and_k_equals_n() -> None:
    res = solve_maxcover(np.zeros((0, 3)), np.zeros(0), 2)
    assert res.status == "optimal" and res.objective == 0.0 and len(res.selected) == 2
    res = solve_maxcover(A, W, 3)
    assert res.selected == (0, 1, 2)
    assert res.objective == pytest.approx(6.0)


def test_negative_values_do_not_observe_and_dense_input() -> None:
    dense = np.array([[-1.0, 0.5], [0.9, 0.0]])
    res = solve_maxcover(dense, np.array([10.0, 1.0]), 1)
    assert res.selected == (1,)
    assert res.objective == 10.0


def test_known_answer_and_stats_json() -> None:
    res = solve_maxcover(A, W, 2)
    assert res.selected == (0, 1)
    assert res.objective == pytest.approx(6.0)
    assert res.engine == "exact"
    json.dumps(res.to_dict())
    for key in ("rows_in", "cols_in", "rows_after", "cols_after", "presolve", "engine_stats"):
        assert key in res.stats


def test_result_roundtrip() -> None:
    res = solve_maxcover(A, W, 2, engine="mip")
    back = SolverResult.from_dict(json.loads(json.dumps(res.to_dict())))
    assert back == SolverResult.from_dict(res.to_dict())
    assert back.selected == res.selected and back.status == res.status
    assert back.objective == res.objective and back.bound == res.bound and back.gap == res.gap
    with pytest.raises(ValueError):
        SolverResult(selected=(), status="great", objective=0.0, bound=0.0, gap=0.0, engine="x", time_s=0.0)
    inf = SolverResult(
        selected=(), status="unknown", objective=0.0, bound=float("inf"), gap=float("inf"), engine="x", time_s=0.0
    )
    d = inf.to_dict()
    json.dumps(d, allow_nan=False)
    assert SolverResult.from_dict(d).bound == float("inf")


def test_coverage_weight() -> None:
    assert coverage_weight(A, W, []) == 0.0
    assert coverage_weight(A, W, [2, 2]) == 1.0
    assert coverage_weight(A, W, (0, 1)) == pytest.approx(6.0)
    with pytest.raises(CamplaceError):
        coverage_weight(A, W, [3])


@pytest.mark.parametrize("engine", ["exact", "mip", "cpsat"])
def test_stats_are_plain_json(engine: str) -> None:
    rng = np.random.default_rng(1)
    dense = (rng.random((60, 12)) < 0.3).astype(float)
    res = solve_maxcover(dense, rng.uniform(0.1, 1.0, 60), 3, engine=engine)
    json.dumps(res.stats, allow_nan=False)
    assert res.stats["cols_in"] == 12 and res.stats["rows_in"] == 60


def test_engines_listed() -> None:
    assert set(ENGINES) == {"auto", "exact", "mip", "cpsat"}
