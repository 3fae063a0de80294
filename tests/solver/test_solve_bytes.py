"""The solve's bytes the memory guard counts on column bitsets (issue 32, deliverable 5), in
stages: before the cast :func:`camplace.solver.api.bits_solve_bytes` follows the route
:func:`camplace.solver.solve` takes on a BitMatrix (checked against the route the solve reports)
and counts what runs on the whole matrix; the engines on the presolved instance note their own
estimates on its sizes (``stats["memory_estimates"]``). The largest of the stages bounds what the
solve allocates (numpy arrays traced by tracemalloc), and a budget between the old whole-matrix
figure and the new one refuses nothing."""

from __future__ import annotations

import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

import camplace.solver.api as api
from camplace.solver.api import bits_solve_bytes, solve
from camplace.solver.bits_route import large_k_reduced_bytes
from camplace.solver.engines.angle.search import angle_bytes
from camplace.solver.engines.bitset.pair_cap import opposite_pair_bytes
from camplace.solver.engines.bitset.search import pairs_layout_bytes
from camplace.solver.engines.large_k.search import large_k_bytes
from camplace.solver.engines.mip.linear import model_bytes
from camplace.solver.engines.mip.mode_models import cover_model_size
from camplace.solver.engines.setcover.reduce_bits import setcover_bits_bytes
from camplace.solver.engines.team.bnb import row_lists_bytes
from camplace.solver.options import SolveOptions
from camplace.solver.problem.checks import conflict_count
from camplace.solver.problem.presolve_bits import presolve_bits_bytes, reduced_pattern_bytes
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
    """What runs on the whole matrix on the route each case takes (the oracle of the dispatch):
    the engines on the presolved instance are noted by the solve, not counted before the cast."""
    pre = presolve_bits_bytes(m, n)
    # the presolve; its engine checks itself (multiview, k = 3 < 2 views: the opposite-pairs matching
    # and layout on the original rows too, checked and noted once their sizes are known)
    if name in ("maxcover", "k6", "k6-multiview", "mip", "multiview"):
        return pre
    if name == "angle":
        return angle_bytes(m, n, 0, 3, 2, layout_rows=m)
    if name == "angle-fixed":
        return (n - 1) * _col(m) + 8 * m + angle_bytes(m, n - 2, 1, 3, 2, layout_rows=m)  # forbidden 5: the others copied, 4 fixed
    if name == "fixed":
        return (n - 2) * _col(m) + 8 * m + presolve_bits_bytes(m, n - 2)
    if name == "setcover":
        return setcover_bits_bytes(m, n)
    if name == "team":  # the branch and bound's row lists, or the CSR another team engine reads
        return max(row_lists_bytes(nnz) + 8 * m, 5 * nnz + 8 * (m + 1))
    if name == "multiview-fixed":  # the angle engine at 0 degrees on the allowed columns (2 fixed)
        return n * _col(m) + 8 * m + angle_bytes(m, n - 1, 1, 3, 2, layout_rows=m)
    if name == "multiview-fixed-mip":  # asked for the model: the merged rows' CSR and model, noted by the solve
        return pre
    if name == "mindist":  # the merged rows' CSR and model: noted by the solve
        return max(pre, _PAIR_BYTES * conflicts)
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
                        ("route", "angle")),
    "multiview-fixed-mip": (SolveOptions(mode="multiview", k=3, views=2, fixed=(2,), engine="mip", time_limit_s=1.0),
                            ("matrix", "column bitsets, rows presolved to")),
}


@pytest.fixture(scope="module")
def inst():
    return _instance(_M, _N)


def _reported(res, key: str) -> str:
    return str(res.stats["engine_choice"]["route"] if key == "route" else res.stats[key])


@pytest.mark.parametrize("name", sorted(_CASES))
def test_bytes_follow_the_route_the_solve_takes(inst, name: str, monkeypatch) -> None:
    """The estimate is the engine's own for the route the solve then reports taking (a minimum
    distance: its spaced route; the relaxation that runs first counts the plain route's bytes,
    not more here)."""
    bits, w, pos, pts = inst
    monkeypatch.setattr(api, "_relaxation_applies", lambda o: False)
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
    """nnz = 0 (before the cast) is the part that does not grow with them: the routes on the
    presolved instance count only what runs on the whole matrix (no change); a route that makes
    the whole matrix's CSR (a minimum angle on the general model) grows by 9 bytes a pair at least."""
    for name in ("maxcover", "multiview", "angle", "fixed", "setcover", "k6", "mindist", "multiview-fixed"):
        o = _CASES[name][0]
        assert bits_solve_bytes(_M, _N, o, 0) == bits_solve_bytes(_M, _N, o, 10**5)
    o = SolveOptions(mode="multiview", k=3, views=2, min_angle_deg=20.0, engine="mip")
    assert bits_solve_bytes(_M, _N, o, 10**5) - bits_solve_bytes(_M, _N, o, 0) >= 9 * 10**5


def _stages(res, input_bytes: int) -> dict[str, int]:
    """The solve's noted estimates, each as bytes allocated by the solve at that step (the step's
    bytes and what the solve held then, less the input matrix, which its caller made)."""
    notes = res.stats["memory_estimates"]
    return {k: v["held"] + v["bytes"] - input_bytes for k, v in notes.items()}


@pytest.mark.parametrize("name", ["maxcover", "multiview", "angle", "angle-fixed", "k6", "k6-multiview", "fixed",
                                  "setcover", "mindist"])
def test_stages_bound_the_traced_allocation(name: str) -> None:
    """The numpy (and Python) memory the solve allocates, traced, stays under the largest of the
    guard's stages (the estimate before the cast and those the solve noted once the presolved sizes
    were known); and that estimate is not vacuous: within 8x of it (a taller matrix, so that the
    rows' terms count). The engines on the presolved instance noted their step."""
    bits, w, pos, pts = _instance(12_000, 64, seed=1)
    o, _ = _CASES[name]
    if name != "setcover":  # the searches stopped early (the memory is allocated up front); no SCIP after them
        o = replace(o, engine="exact" if name != "mindist" else "mip", time_limit_s=2.0)
    m, n = bits.shape
    solve(bits, w, positions=pos, points=pts, options=o)  # compiled and loaded before tracing
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        res = solve(bits, w, positions=pos, points=pts, options=o)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    conflicts = conflict_count(pos, o.min_distance_m) if o.min_distance_m is not None else 0
    stages = _stages(res, bits.words.nbytes)
    est = max(bits_solve_bytes(m, n, o, bits.nnz, conflicts), *stages.values())
    want = {"maxcover": "bitset", "multiview": "bitset", "k6": "large-k", "k6-multiview": "large-k",
            "fixed": "bitset", "mindist": "model", "angle": "angle", "angle-fixed": "angle", "setcover": "setcover"}
    assert want[name] in stages
    if name == "mindist":  # SCIP runs in a child process: the model's bytes are its, not traced here
        assert stages["model"] >= res.stats["model_estimate"]["bytes"]
        return
    assert peak - base <= est, f"{name}: traced {peak - base} > estimated {est} ({stages})"
    assert est <= 8 * (peak - base), f"{name}: estimated {est} over 8x the traced {peak - base}"


def _repeated(m: int, n: int, times: int, seed: int = 2):
    """An instance of ``m`` distinct rows each repeated ``times`` times (so that the presolve
    merges them: its reduced instance has ``m`` rows at most)."""
    bits, w, pos, pts = _instance(m, n, seed)
    cells = np.unpackbits(bits.words.view(np.uint8), axis=1, bitorder="little")[:, :m].astype(bool)
    rows = np.repeat(cells, times, axis=1)  # (n, m * times)
    mm = m * times
    pad = np.zeros((n, ((mm + 63) // 64) * 64), dtype=bool)
    pad[:, :mm] = rows
    words = np.packbits(pad, axis=1, bitorder="little").view(np.uint64)
    return BitMatrix(words, mm), np.repeat(w, times), pos, np.repeat(pts, times, axis=0)


def test_a_budget_between_the_whole_matrix_figure_and_the_reduced_one_refuses_nothing() -> None:
    """k = 6 on rows that the presolve merges 8 to 1: the large-k engines' bytes counted on the whole
    matrix (the former guard) are over a budget that their bytes on the presolved sizes (the
    solve's check) fit: the solve runs them (the large-k route on the column lists, no fallback);
    a budget under the reduced figure makes it fall back instead (never the whole-matrix engines)."""
    bits, w, pos, pts = _repeated(1500, 60, 8)
    m, n = bits.shape
    o = replace(_CASES["k6"][0], time_limit_s=2.0)
    res = solve(bits, w, positions=pos, points=pts, options=o)
    assert res.stats["matrix"].endswith("(their column lists)")
    mp, np_ = res.stats["rows_after"], res.stats["cols_after"]
    assert mp <= 1500
    notes = res.stats["memory_estimates"]
    pre = BitMatrix(bits.words, m)  # the reduced instance's pairs, from the solve's own figure
    nnz_r = (notes["large-k"]["bytes"] - large_k_bytes(mp, np_, 0, pattern=True) - 8 * (np_ + 1)) // 16
    assert notes["large-k"]["bytes"] == large_k_reduced_bytes(mp, np_, nnz_r, 6)
    assert 0 < nnz_r <= pre.nnz // 8 + np_
    # each check on the route: the column lists, the engines
    reduced = max(reduced_pattern_bytes(np_, nnz_r), large_k_bytes(mp, np_, nnz_r, pattern=True))
    whole = max(reduced_pattern_bytes(n, pre.nnz), large_k_bytes(m, n, pre.nnz, pattern=True))
    assert whole > 4 * reduced
    budget = (reduced + whole) // 2
    got = solve(bits, w, positions=pos, points=pts, options=replace(o, memory_budget_bytes=budget))
    assert got.stats["matrix"].endswith("(their column lists)")  # the column lists were made
    assert "large-k engine" not in got.stats.get("memory_fallback", "")  # and the engines ran on them
    assert got.stats["engine_stats"]  # (a SCIP model after them may be skipped: a step of its own)
    assert got.objective == pytest.approx(res.objective, rel=1e-12)
    under = solve(bits, w, positions=pos, points=pts, options=replace(o, memory_budget_bytes=reduced // 2))
    assert not str(under.stats.get("matrix", "")).endswith("(their column lists)")


def test_a_model_over_the_budget_is_refused_once_its_size_is_known(inst, monkeypatch) -> None:
    """The merged rows' general model is not counted before the cast (its size is known after the
    presolve); the solve estimates it then, notes it and checks it: over the budget under engine
    auto, the greedy answer with a cheap bound (``stats["memory_fallback"]``); asked for by name,
    a one-line error."""
    from camplace.errors import CamplaceError

    bits, w, pos, pts = inst
    m, n = bits.shape
    monkeypatch.setattr(api, "_relaxation_applies", lambda o: False)  # the spaced route itself
    o = replace(_CASES["mindist"][0], memory_budget_bytes=4 << 20)
    conflicts = conflict_count(pos, o.min_distance_m)
    assert bits_solve_bytes(m, n, o, bits.nnz, conflicts) == bits_solve_bytes(m, n, replace(o, engine="mip"),
                                                                                bits.nnz, conflicts)
    res = solve(bits, w, positions=pos, points=pts, options=o)
    assert "greedy answer" in res.stats["memory_fallback"] and res.status == "feasible"
    notes = res.stats["memory_estimates"]
    assert "model" not in notes  # refused: not a peak the run reached
    model = notes["model (refused)"]["bytes"]
    assert model == res.stats["model_estimate"]["bytes"] > 4 << 20
    # on the merged rows: at most the model of every row
    assert model <= model_bytes("mip", *cover_model_size(m, n, bits.nnz, conflicts, 0))
    with pytest.raises(CamplaceError, match="needs about"):
        solve(bits, w, positions=pos, points=pts, options=replace(o, engine="mip"))


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


def test_an_engine_refused_inside_is_noted_refused(inst) -> None:
    """The angle engine checks its bytes inside (on its countable rows): under a budget it does not
    fit, the step noted before it is replaced by ``"angle (refused)"`` with the engine's figure, so
    that the run's estimate does not count an allocation that was not made."""
    from camplace.solver._support.deadline import Deadline
    from camplace.solver._support.memory import memory_budget, memory_notes
    from camplace.solver.bits_route import bits_outcome

    bits, w, pos, pts = inst
    o = replace(_CASES["angle"][0], memory_budget_bytes=1 << 20, engine="exact")
    m, n = bits.shape
    assert angle_bytes(m, n, 0, 3, 2) > 1 << 20
    with memory_budget(1 << 20), memory_notes() as notes:
        got = bits_outcome(bits, w, replace(o, time_limit_s=None), Deadline(None), pos, pts)
    assert got is None  # the bits route leaves it to the CSR route
    assert "angle" not in notes and notes["angle (refused)"]["bytes"] > 1 << 20


def test_the_pairs_layout_is_noted_at_the_size_the_matching_made() -> None:
    """Multiview with k = 3 < 2 views: the opposite-pairs matching and layout, on the original
    rows, are noted once their sizes are known (not counted before the cast, where only the
    bound of two layout rows a point is known): the layout's figure is the bitset engine's bytes
    of the rows it was built with, under that bound. A budget between the plain search's bytes
    on the presolved rows (merged 8 to 1 here) and the layout's on the original rows skips the
    layout (noted refused) and the search runs on the plain layout, to the same optimum."""
    from camplace.solver.engines.bitset.search import bitset_bytes

    bits, w, pos, pts = _repeated(1500, 64, 8)
    m, n = bits.shape
    o = replace(_CASES["multiview"][0], engine="exact")
    res = solve(bits, w, options=o)
    notes = res.stats["memory_estimates"]
    pairs = res.stats["engine_stats"]["opposite_pairs"]
    assert "skipped" not in pairs and pairs["matched_share"] >= 0.05  # the layout was built
    assert "opposite pairs" in notes and "pairs layout" in notes
    got = notes["pairs layout"]["bytes"]
    # its rows: between the countable rows and two a row plus the padding
    assert bitset_bytes(pairs["rows"], n, 2, 3, tuples=False) <= got < pairs_layout_bytes(m, n, 2, 3)
    assert notes["opposite pairs"]["bytes"] == opposite_pair_bytes(pairs["rows"], n)
    plain = bitset_bytes(res.stats["rows_after"], res.stats["cols_after"], 2, 3)  # the engine's check
    layout = bitset_bytes(pairs["rows"], n, 2, 3)  # the layout's check, at least
    assert plain < layout
    budget = (plain + layout) // 2
    again = solve(bits, w, options=replace(o, memory_budget_bytes=budget))
    assert "pairs layout (refused)" in again.stats["memory_estimates"]
    assert "pairs layout" not in again.stats["memory_estimates"]
    assert again.status == res.status == "optimal"
    assert again.objective == pytest.approx(res.objective, rel=1e-12)


def test_the_angle_engine_checks_its_layout_once_the_points_are_matched(inst) -> None:
    """The angle engine's bytes in two steps: on the plain layout (one bit row a countable row)
    before anything is allocated, then on the opposite-pairs layout's rows once the points are
    matched; the noted figure is the second. A budget between the two searches the plain layout
    instead (a valid, looser bound): the same proven optimum."""
    from camplace.solver.engines.angle.search import _FRONTIER_MIN

    bits, w, pos, pts = inst
    m, n = bits.shape
    o = replace(_CASES["angle"][0], engine="exact")
    res = solve(bits, w, positions=pos, points=pts, options=o)
    es = res.stats["engine_stats"]
    rows, bit_rows = es["rows"], es["bit_rows"]
    assert es["pair_words"] > 0 and bit_rows > rows  # the opposite-pairs layout, more bit rows than points
    plain = angle_bytes(rows, n, 0, 3, 2, _FRONTIER_MIN, rows)
    paired = angle_bytes(rows, n, 0, 3, 2, _FRONTIER_MIN, bit_rows)
    assert res.stats["memory_estimates"]["angle"]["bytes"] == paired
    assert plain < paired <= angle_bytes(rows, n, 0, 3, 2)  # at most the bound of two bit rows a row
    budget = (plain + paired) // 2
    again = solve(bits, w, positions=pos, points=pts, options=replace(o, memory_budget_bytes=budget))
    ea = again.stats["engine_stats"]
    assert "skipped" in ea["opposite_pairs"] and ea["pair_words"] == 0 and ea["bit_rows"] == rows
    assert again.stats["memory_estimates"]["angle"]["bytes"] == plain
    assert again.status == res.status == "optimal"
    assert again.objective == pytest.approx(res.objective, rel=1e-12)
