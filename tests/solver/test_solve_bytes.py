"""The solve's bytes the visibility guard counts on column bitsets (issue 32, deliverable 5):
:func:`camplace.solver.api.bits_solve_bytes` follows the route :func:`camplace.solver.solve` takes
on a BitMatrix (checked against the route the solve reports), each from the engine's own estimate,
and is an upper bound of what the solve allocates (numpy arrays traced by tracemalloc)."""

from __future__ import annotations

import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

from camplace.solver.api import bits_solve_bytes, solve
from camplace.solver.bits_route import large_k_bits_bytes
from camplace.solver.engines.angle.search import angle_bytes
from camplace.solver.engines.bitset.search import pairs_layout_bytes
from camplace.solver.engines.mip.linear import model_bytes
from camplace.solver.engines.mip.mode_models import cover_model_size
from camplace.solver.engines.setcover.reduce_bits import setcover_bits_bytes
from camplace.solver.engines.team.bnb import row_lists_bytes
from camplace.solver.options import SolveOptions
from camplace.solver.problem.checks import conflict_count
from camplace.solver.problem.presolve_bits import presolve_bits_bytes, reduced_csr_bytes
from camplace.visibility.bits import BitMatrix

_PAIR_BYTES = 200  # camplace.solver.api._CONFLICT_PAIR_BYTES


def _instance(m: int, n: int, seed: int = 0):
    """(BitMatrix (m, n), weights (m,), camera positions (n, 3), point positions (m, 3)): cameras on
    a sphere of radius 10 around points near the origin, a camera observing the points whose
    direction is within about 60 degrees of its own (so that views of a point come from different
    sides and angles bind), every row distinct."""
    rng = np.random.default_rng(seed)
    cams = rng.normal(size=(n, 3))
    cams *= 10.0 / np.linalg.norm(cams, axis=1, keepdims=True)
    pts = rng.normal(size=(m, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    seen = (pts @ (cams / 10.0).T) > 0.5
    seen |= rng.random((m, n)) < 0.02
    cells = np.zeros((n, ((m + 63) // 64) * 64), dtype=bool)
    cells[:, :m] = seen.T
    words = np.packbits(cells, axis=1, bitorder="little").view(np.uint64)
    return BitMatrix(words, m), rng.random(m) + 0.1, cams, pts


def _col(m: int) -> int:
    return ((m + 63) // 64) * 8


def _expected(name: str, m: int, n: int, nnz: int, conflicts: int) -> int:
    """The engine's own estimate of the route each case takes (the oracle of the dispatch)."""
    pre = presolve_bits_bytes(m, n)
    if name == "maxcover":  # the engine on the kept columns checks itself
        return pre
    if name == "multiview":  # k = 3 < 2 views: the opposite-pairs layout
        return max(pre, pairs_layout_bytes(m, n, 2, 3))
    if name == "angle":
        return angle_bytes(m, n, 0, 3, 2)
    if name == "angle-fixed":
        return (n - 1) * _col(m) + 8 * m + angle_bytes(m, n - 2, 1, 3, 2)  # forbidden 5: the others copied, 4 fixed
    if name == "k6":
        return max(pre, large_k_bits_bytes(m, n, nnz, 6, 0))
    if name == "k6-multiview":
        return max(pre, large_k_bits_bytes(m, n, nnz, 6, 2))
    if name == "fixed":
        return (n - 2) * _col(m) + 8 * m + presolve_bits_bytes(m, n - 2)
    if name == "setcover":
        return setcover_bits_bytes(m, n)
    if name == "team":  # the branch and bound's row lists, or the CSR another team engine reads
        return max(row_lists_bytes(nnz) + 8 * m, 5 * nnz + 8 * (m + 1))
    if name == "mip":  # the max-coverage model of the presolved instance (its sizes at most the matrix's)
        return max(pre, n * _col(m) + model_bytes("mip", n + m, m + 1, nnz + m + n))
    if name in ("mindist", "multiview-fixed"):
        fixed = 1 if name == "multiview-fixed" else 0
        model = model_bytes("mip", *cover_model_size(m, n - fixed, nnz, conflicts, fixed))
        return max(pre, n * _col(m) + reduced_csr_bytes(m, n, nnz, 1) + _PAIR_BYTES * conflicts + model)
    raise AssertionError(name)


_M, _N = 1500, 60

#: name: (options, the route the solve reports: (stats key, value or prefix))
_CASES = {
    "maxcover": (SolveOptions(mode="maxcover", k=3), ("route", "maxcover")),
    "multiview": (SolveOptions(mode="multiview", k=3, views=2), ("route", "multiview")),
    "angle": (SolveOptions(mode="multiview", k=3, views=2, min_angle_deg=20.0), ("route", "angle")),
    "angle-fixed": (SolveOptions(mode="multiview", k=3, views=2, min_angle_deg=20.0, fixed=(4,), forbidden=(5,)),
                    ("matrix", "column bitsets of the 59 allowed columns")),
    "k6": (SolveOptions(mode="maxcover", k=6), ("route", "large-k")),
    "k6-multiview": (SolveOptions(mode="multiview", k=6, views=2, time_limit_s=2.0), ("route", "large-k")),
    "fixed": (SolveOptions(mode="maxcover", k=3, fixed=(3, 17)), ("matrix", "column bitsets of the 58 allowed")),
    "setcover": (SolveOptions(mode="setcover", required_fraction=0.9), ("matrix", "column bitsets (the rows to cover")),
    "mindist": (SolveOptions(mode="maxcover", k=3, min_distance_m=3.0, time_limit_s=1.0),
                ("matrix", "column bitsets, rows presolved to")),
    "mip": (SolveOptions(mode="maxcover", k=3, engine="mip", time_limit_s=1.0), ("route", "maxcover")),
    "multiview-fixed": (SolveOptions(mode="multiview", k=3, views=2, fixed=(2,), time_limit_s=1.0),
                        ("matrix", "column bitsets, rows presolved to")),
}


@pytest.fixture(scope="module")
def inst():
    return _instance(_M, _N)


def _reported(res, key: str) -> str:
    return str(res.stats["engine_choice"]["route"] if key == "route" else res.stats[key])


@pytest.mark.parametrize("name", sorted(_CASES))
def test_bytes_follow_the_route_the_solve_takes(inst, name: str) -> None:
    """The estimate is the engine's own for the route the solve then reports taking."""
    bits, w, pos, pts = inst
    o, (key, want) = _CASES[name]
    m, n = bits.shape
    conflicts = conflict_count(pos, o.min_distance_m) if o.min_distance_m is not None else 0
    if name == "mindist":
        assert conflicts > 0  # the spacing binds
    assert bits_solve_bytes(m, n, o, bits.nnz, conflicts) == _expected(name, m, n, bits.nnz, conflicts)
    res = solve(bits, w, positions=pos, points=pts, options=o)
    assert _reported(res, key).startswith(want)


def test_team_bytes_count_the_bits_or_the_csr(inst) -> None:
    """A team in max coverage on bits: the branch and bound's row lists or, where another team
    engine runs, the CSR the solve makes: the larger."""
    from camplace.solver.problem.team import TeamConstraints

    bits, w, pos, pts = inst
    team = TeamConstraints(model=np.arange(_N) % 2, model_names=("a", "b"), model_min=(1, 1), model_max=(None, None),
                           cost=np.ones(_N))
    o = SolveOptions(mode="maxcover", k=2, team=team)
    assert bits_solve_bytes(_M, _N, o, bits.nnz) == _expected("team", _M, _N, bits.nnz, 0)


def test_bytes_grow_with_the_pairs_where_the_route_does() -> None:
    """nnz = 0 (before the cast) is the part that does not grow with them: the bitset routes do
    not change, the large-k, rows-presolved and team routes do."""
    for name in ("maxcover", "multiview", "angle", "fixed", "setcover"):
        o = _CASES[name][0]
        assert bits_solve_bytes(_M, _N, o, 0) == bits_solve_bytes(_M, _N, o, 10**5)
    for name in ("k6", "mindist", "multiview-fixed"):
        o = _CASES[name][0]
        assert bits_solve_bytes(_M, _N, o, 10**5) - bits_solve_bytes(_M, _N, o, 0) >= 8 * 10**5


@pytest.mark.parametrize("name", ["maxcover", "multiview", "angle", "angle-fixed", "k6", "k6-multiview", "fixed",
                                  "setcover"])
def test_bytes_bound_the_traced_allocation(name: str) -> None:
    """The numpy (and Python) memory the solve allocates, traced, stays under the estimate; and
    the estimate is not vacuous: within 8x of it (a taller matrix, so that the rows' terms count)."""
    bits, w, pos, pts = _instance(12_000, 64, seed=1)
    o, _ = _CASES[name]
    if name != "setcover":  # the searches stopped early (the memory is allocated up front); no SCIP after them
        o = replace(o, engine="exact", time_limit_s=2.0)
    m, n = bits.shape
    solve(bits, w, positions=pos, points=pts, options=o)  # compiled and loaded before tracing
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        solve(bits, w, positions=pos, points=pts, options=o)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    est = bits_solve_bytes(m, n, o, bits.nnz)
    assert peak - base <= est, f"{name}: traced {peak - base} > estimated {est}"
    assert est <= 8 * (peak - base), f"{name}: estimated {est} over 8x the traced {peak - base}"


def test_a_model_over_the_budget_is_not_counted_where_the_solve_falls_back(inst) -> None:
    """Under engine auto a general model over the solver's budget is not built (the greedy answer
    with a cheap bound, ``stats["memory_fallback"]``): the guard leaves it out, so that it does not
    stop a run that ends with that answer; asked for by name it is counted (the solve stops)."""
    bits, w, pos, pts = inst
    m, n = bits.shape
    o = replace(_CASES["mindist"][0], memory_budget_bytes=4 << 20)
    conflicts = conflict_count(pos, o.min_distance_m)
    model = model_bytes("mip", *cover_model_size(m, n, bits.nnz, conflicts, 0))
    assert model > 4 << 20
    counted = _expected("mindist", m, n, bits.nnz, conflicts)
    assert bits_solve_bytes(m, n, replace(o, engine="mip"), bits.nnz, conflicts) == counted
    assert bits_solve_bytes(m, n, o, bits.nnz, conflicts) == counted - model
    res = solve(bits, w, positions=pos, points=pts, options=o)
    assert "greedy answer" in res.stats["memory_fallback"] and res.status == "feasible"


def test_the_pipeline_passes_the_routes_bytes_at_the_pilots_density(inst) -> None:
    """``pipeline.guard_solve_bytes``: the run's options, the observed pairs from the density and
    the conflicting pairs counted from the candidates' positions."""
    from camplace.pipeline import guard_solve_bytes

    bits, w, pos, pts = inst
    m, n = bits.shape

    class Cands:  # what the guard reads of a CandidateSet
        positions = pos

        def __len__(self) -> int:
            return n

    for name in ("maxcover", "angle", "k6", "fixed", "mindist", "multiview-fixed", "setcover"):
        o = _CASES[name][0]
        conflicts = conflict_count(pos, o.min_distance_m) if o.min_distance_m is not None else 0
        f = guard_solve_bytes(m, Cands(), o)
        assert f(0.25) == bits_solve_bytes(m, n, o, round(0.25 * m * n), conflicts)
        assert f(0.0) == bits_solve_bytes(m, n, o, 0, conflicts)
