"""The set-cover engine (:mod:`camplace.solver.engines.setcover.local_search`) against enumeration and published optima.

Oracles: exhaustive enumeration of column subsets (small random instances, full and partial
covers, unit / integer / fractional costs) and the proven optima of the OR-Library instances and
the best known size of GECCO 2020 AC_01 in ``../shared/data``.
"""

from __future__ import annotations

import csv
import itertools
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline
from camplace.solver.api import solve
from camplace.solver.engines.setcover import local_search as S
from camplace.solver.problem.formats import read_gecco, read_orlib
from tests._floats import assert_ge, assert_le

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


@st.composite
def covers(draw, max_n: int = 9, max_m: int = 16):
    """(dense 0/1 (m, n) with every row covered, costs (n,), row weights (m,) > 0, need or None)."""
    n = draw(st.integers(1, max_n))
    m = draw(st.integers(1, max_m))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    dense = rng.random((m, n)) < draw(st.sampled_from([0.15, 0.3, 0.6]))
    if draw(st.booleans()) and n >= 3:
        dense[:, 1] = dense[:, 0]  # duplicate column
    if draw(st.booleans()) and m >= 3:
        dense[1] = dense[0] | dense[2]  # a superset row
    dense = dense[dense.any(axis=1)]
    if dense.shape[0] == 0:
        dense = np.ones((1, n), dtype=bool)
    kind = draw(st.sampled_from(["unit", "int", "float", "zero"]))
    costs = {"unit": np.ones(n), "int": rng.integers(1, 6, n).astype(float),
             "float": rng.uniform(0.1, 2.0, n), "zero": rng.integers(0, 3, n).astype(float)}[kind]
    w = rng.uniform(0.1, 1.0, dense.shape[0])
    frac = draw(st.sampled_from([None, None, 0.5, 0.8]))
    need = None if frac is None else frac * float(w.sum())
    return dense, costs, w, need


def enumerate_cover(dense: np.ndarray, costs: np.ndarray, w: np.ndarray, need: float | None) -> float:
    """Cheapest column subset covering every row (or row weight >= need), by enumeration."""
    n = dense.shape[1]
    best = np.inf
    for r in range(n + 1):
        for cols in itertools.combinations(range(n), r):
            hit = dense[:, list(cols)].any(axis=1)
            ok = hit.all() if need is None else float(w[hit].sum()) >= need * (1 - 1e-12)
            if ok:
                best = min(best, float(costs[list(cols)].sum()))
    return best


def _reduced_dense(red: S.CoverReduction) -> np.ndarray:
    return red.csr().toarray() > 0


def _covers(dense: np.ndarray, w: np.ndarray, need: float | None, cols) -> bool:
    hit = dense[:, list(cols)].any(axis=1) if len(cols) else np.zeros(dense.shape[0], dtype=bool)
    return bool(hit.all()) if need is None else float(w[hit].sum()) >= need * (1 - 1e-12)


@settings(max_examples=80, **_SETTINGS)
@given(inst=covers())
def test_reduction_keeps_the_optimum(inst) -> None:
    dense, costs, w, need = inst
    best = enumerate_cover(dense, costs, w, need)
    red = S.reduce_cover(sp.csr_matrix(dense.astype(float)), costs, None if need is None else w, need)
    assert np.all(costs[red.forced] == 0) or need is None  # partial covers only force free columns
    assert np.all(red.cost > 0)
    rd = _reduced_dense(red)
    assert rd.shape == red.shape
    if red.shape[0] == 0 or (red.partial and red.need <= 0):
        reduced_best = 0.0
    else:
        reduced_best = enumerate_cover(rd, red.cost, red.roww, red.need if red.partial else None)
    assert reduced_best + red.forced_cost == pytest.approx(best, rel=1e-9)
    # the reduced columns map back to input columns that cover the same rows of the reduced rows
    for j, col in enumerate(red.columns):
        assert costs[col] == red.cost[j]


@settings(max_examples=80, **_SETTINGS)
@given(inst=covers(), seed=st.integers(0, 3))
def test_local_search_and_bound_bracket_the_optimum(inst, seed) -> None:
    dense, costs, w, need = inst
    best = enumerate_cover(dense, costs, w, need)
    red = S.reduce_cover(sp.csr_matrix(dense.astype(float)), costs, None if need is None else w, need)
    if red.shape[0] == 0 or (red.partial and red.need <= 0):
        return
    sel, cost, stats = S.local_search(red, seed=seed, max_iterations=3000)
    cols = red.input_columns(sel)
    assert _covers(dense, w, need, cols)
    assert float(costs[list(cols)].sum()) == pytest.approx(cost + red.forced_cost, rel=1e-9, abs=1e-12)
    assert_ge(cost + red.forced_cost, best, what="local search cost vs optimum")
    lb, _ = S.lagrangian_bound(red, cost)
    assert_le(lb + red.forced_cost, best, what="Lagrangian bound vs optimum")


@pytest.mark.parametrize("engine", ["mip", "cpsat", "auto", "search-only"])
@settings(max_examples=30, **_SETTINGS)
@given(inst=covers())
def test_solve_cover_equals_enumeration(engine, inst) -> None:
    """mip / cpsat (SCIP or CP-SAT after the search) prove the optimum; auto and the search alone
    (the large-instance path) return a valid cover and a valid lower bound, 'optimal' only when it is."""
    dense, costs, w, need = inst
    best = enumerate_cover(dense, costs, w, need)
    old = S.AUTO_MODEL_NNZ
    if engine == "search-only":
        S.AUTO_MODEL_NNZ = 0
    try:
        out = S.solve_cover(sp.csr_matrix(dense.astype(float)), costs, None if need is None else w, need,
                            engine="auto" if engine == "search-only" else engine, max_iterations=2000)
    finally:
        S.AUTO_MODEL_NNZ = old
    assert _covers(dense, w, need, out.selected)
    assert out.objective == pytest.approx(float(costs[list(out.selected)].sum()), rel=1e-12, abs=1e-12)
    assert_ge(out.objective, best)
    assert_le(out.bound, best)
    if engine in ("mip", "cpsat"):
        assert out.status == "optimal"
    if out.status == "optimal":
        assert out.objective == pytest.approx(best, rel=1e-9, abs=1e-12)
    if engine == "search-only":
        assert out.engine == "local-search"


def test_same_seed_and_iterations_same_answer_in_any_number_of_calls() -> None:
    rng = np.random.default_rng(5)
    dense = rng.random((300, 400)) < 0.03
    dense = dense[dense.any(axis=1)]
    red = S.reduce_cover(sp.csr_matrix(dense.astype(float)), np.ones(400))
    a = S.LocalSearch(red, seed=7)
    a.run(max_iterations=4000)
    b = S.LocalSearch(red, seed=7)
    for stop in (1, 17, 1000, 4000):  # the same iterations in four calls
        b.run(max_iterations=stop)
    assert a.iterations == b.iterations == 4000
    assert np.array_equal(a.best, b.best) and np.array_equal(a.x, b.x)
    assert np.array_equal(a.pw, b.pw) and np.array_equal(a.score, b.score)
    small = dense[:40, :60]  # small enough for SCIP to prove quickly after the search
    small = small[small.any(axis=1)]
    r1 = solve(small, np.ones(small.shape[0]), mode="setcover", search_seed=3, iterations=3000)
    r2 = solve(small, np.ones(small.shape[0]), mode="setcover", search_seed=3, iterations=3000)
    assert r1.selected == r2.selected and r1.objective == r2.objective


def _recount_scores(red: S.CoverReduction, x: np.ndarray, pw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coverage counts and scores from their definition: a column of S loses the penalty of the rows
    only it covers, a column outside gains the penalty of the uncovered rows it covers."""
    a = red.csr().toarray() > 0
    cov = a[:, x > 0].sum(axis=1)
    gain = a.T.astype(float) @ (pw * (cov == 0))
    loss = a.T.astype(float) @ (pw * (cov == 1))
    return cov, np.where(x > 0, -loss, gain)


@pytest.mark.parametrize("mode,cc_mode,step,rwls",
                         [(0, 1, 0, True), (1, 1, 10_000, True), (2, 2, 10_000, True), (1, 0, 7, True),
                          (1, 1, 10_000, False)])
def test_unicost_incremental_state_matches_a_recount(monkeypatch, mode: int, cc_mode: int, step: int,
                                                     rwls: bool) -> None:
    """Unit costs use the RWLS moves by default (the joint swaps on request); after any number of
    iterations (the three penalty schemes, configuration checking off, on additions, on both, unit
    or per-row penalty steps, restarts) the
    incremental coverage and scores equal a recount, the uncovered-row list is exact, and the best
    solution is a cover of the recorded size."""
    monkeypatch.setattr(S, "RWLS_PENALTY_MODE", mode)
    monkeypatch.setattr(S, "RWLS_CC_MODE", cc_mode)
    monkeypatch.setattr(S, "RWLS_ROW_STEP", step)
    rng = np.random.default_rng(11)
    dense = rng.random((120, 150)) < 0.05
    dense = dense[dense.any(axis=1)]
    red = S.reduce_cover(sp.csr_matrix(dense.astype(float)), np.ones(150))
    ls = S.LocalSearch(red, seed=1, rwls=None if rwls else False)
    assert ls.rwls == rwls
    deg = np.diff(red.rptr)
    assert np.array_equal(ls.pinc, np.maximum(1, step // deg) if step else np.ones(deg.size))
    ls.restart_work = 20_000
    for stop in (1, 50, 777, 5000):
        ls.run(max_iterations=stop)
        cov, score = _recount_scores(red, ls.x, ls.pw)
        assert np.array_equal(ls.cov, cov)
        np.testing.assert_allclose(ls.score, score, rtol=1e-12, atol=1e-9)
        unc = np.sort(ls.unc[: int(ls.ist[S.K.NUNC])])
        assert np.array_equal(unc, np.flatnonzero(cov == 0))
        assert int(ls.ist[S.K.NSEL]) == int(ls.x.sum()) == float(red.cost[ls.x > 0].sum()) == ls.fst[S.K.COST]
        best_cov, _ = _recount_scores(red, ls.best, ls.pw)
        assert np.all(best_cov > 0) and float(ls.best.sum()) == ls.best_cost
    assert not np.array_equal(ls.pw, ls.pinc)  # the penalties did move
    assert ls.ist[S.K.RESTARTS] > 0


def test_weighted_or_partial_covers_keep_the_weighted_search() -> None:
    rng = np.random.default_rng(3)
    dense = rng.random((40, 30)) < 0.2
    dense = dense[dense.any(axis=1)]
    a = sp.csr_matrix(dense.astype(float))
    assert not S.LocalSearch(S.reduce_cover(a, rng.integers(1, 5, 30).astype(float)), seed=0).rwls
    w = np.ones(dense.shape[0])
    assert not S.LocalSearch(S.reduce_cover(a, np.ones(30), w, 0.5 * w.sum()), seed=0).rwls


def test_memory_estimate_stops_with_one_line(monkeypatch) -> None:
    monkeypatch.setattr(S, "memory_budget_bytes", lambda: 1000)
    with pytest.raises(CamplaceError) as ei:
        solve(np.eye(20), np.ones(20), mode="setcover")
    assert "\n" not in str(ei.value) and "GiB" in str(ei.value)


def _shared() -> list:
    if not (DATA / "setcover" / "known_optima.csv").exists():
        return [pytest.param("-", 0.0, marks=pytest.mark.skip(reason=f"the shared set-cover data are not at {DATA}"))]
    with open(DATA / "setcover" / "known_optima.csv", newline="") as fh:
        rows = [(r["file"], float(r["weighted_BKS"])) for r in csv.DictReader(fh)]
    return rows + [("AC_01", float((DATA / "camera_placement" / "AC_01_best_known_solution.txt").read_text().split()[0]))]


@pytest.mark.parametrize("name,best", _shared())
def test_local_search_alone_reaches_the_published_optimum(name: str, best: float) -> None:
    """Every shared instance (weighted OR-Library, unicost AC_01): the search alone, seed 0 and an
    iteration budget (so the outcome does not depend on the machine), finds the optimum; the
    Lagrangian bound stays below it."""
    inst = read_gecco(DATA / "camera_placement" / "AC_01_cover.txt") if name == "AC_01" else \
        read_orlib(DATA / "setcover" / name)
    red = S.reduce_cover(inst.matrix, inst.costs)
    ls = S.LocalSearch(red, seed=0)
    ls.run(max_iterations=2_000_000, target=best - red.forced_cost)
    sel = ls.best_cover()
    cols = red.input_columns(sel)
    assert bool(np.all(np.diff(inst.matrix[:, list(cols)].tocsr().indptr) > 0))
    assert float(inst.costs[list(cols)].sum()) == best
    lb, _ = S.lagrangian_bound(red, ls.best_cost)
    assert lb + red.forced_cost <= best


def test_model_too_big_for_memory_falls_back_to_the_search(monkeypatch) -> None:
    rng = np.random.default_rng(2)
    dense = rng.random((30, 12)) < 0.3
    dense = dense[dense.any(axis=1)]
    best = enumerate_cover(dense, np.ones(12), np.ones(dense.shape[0]), None)
    monkeypatch.setattr(S, "cover_model_bytes", lambda red, backend: 1 << 60)
    monkeypatch.setattr(S, "lagrangian_bound", lambda red, upper, **kw: (0.0, {}))  # no proof without the model
    monkeypatch.setattr(S, "EXACT_MAX_COLUMNS", -1)  # nor by the exact test of small covers
    res = solve(dense, np.ones(dense.shape[0]), mode="setcover", engine="mip", iterations=2000)
    assert "memory_fallback" in res.stats["setcover"] and "\n" not in res.stats["setcover"]["memory_fallback"]
    assert res.engine == "local-search"
    assert _covers(dense, np.ones(dense.shape[0]), None, res.selected)
    assert res.objective >= best and res.bound <= best


def test_luby_sequence_doubles_its_prefix_then_adds_a_power_of_two() -> None:
    """The Luby sequence (restart schedule): its first 2^k - 1 terms are the first 2^(k-1) - 1 terms
    twice, then 2^(k-1) (Luby, Sinclair and Zuckerman 1993)."""
    seq = [S._luby(i) for i in range(1, 2**9)]
    assert seq[0] == 1
    for k in range(2, 10):
        half = seq[: 2 ** (k - 1) - 1]
        assert seq[: 2**k - 1] == half + half + [2 ** (k - 1)]


def _hard_unicost(seed: int, m: int = 200, n: int = 400, density: float = 0.03) -> sp.csr_matrix:
    rng = np.random.default_rng(seed)
    dense = rng.random((m, n)) < density
    dense = dense[dense.any(axis=1)]
    return sp.csr_matrix(dense.astype(float))


def test_restarts_and_side_by_side_searches_same_seed_same_answer(monkeypatch) -> None:
    """Without a time limit the second phase (restarts, searches side by side in threads) stops on
    patience, counted in work: the same seed gives the same cover; another seed is another run."""
    monkeypatch.setattr(S, "AUTO_MODEL_NNZ", 0)  # no SCIP: the search phases only
    monkeypatch.setattr(S, "RESTART_WORK_MIN", 100_000)
    monkeypatch.setattr(S, "RESTART_WORK_PER_NNZ", 50)
    a = _hard_unicost(4)
    out = [S.solve_cover(a, np.ones(a.shape[1]), seed=s) for s in (5, 5)]
    ls = out[0].stats["local_search"]
    assert ls.get("resumed") and ls["searches"] == S.search_threads() and ls["restarts"] > 0
    assert out[0].selected == out[1].selected and out[0].objective == out[1].objective
    assert out[0].stats["local_search"]["iterations"] == out[1].stats["local_search"]["iterations"]
    assert bool(np.all(np.diff(a[:, list(out[0].selected)].tocsr().indptr) > 0))
    assert out[0].objective == len(out[0].selected) >= out[0].bound


def test_time_limit_is_kept_and_the_answer_is_a_cover() -> None:
    a = _hard_unicost(9, m=300, n=2000, density=0.02)
    S.solve_cover(a[:30], np.ones(a.shape[1]), max_iterations=100)  # compile (or load) the kernels first
    t0 = __import__("time").perf_counter()
    out = S.solve_cover(a, np.ones(a.shape[1]), deadline=Deadline(1.0), seed=1)
    elapsed = __import__("time").perf_counter() - t0
    assert elapsed < 1.0 + 0.5, elapsed
    assert out.stats["local_search"].get("resumed") and out.status == "feasible"
    assert bool(np.all(np.diff(a[:, list(out.selected)].tocsr().indptr) > 0))
    assert out.objective == len(out.selected) >= out.bound


@settings(max_examples=25, **_SETTINGS)
@given(inst=covers())
def test_timed_solve_with_searches_side_by_side_equals_enumeration_bounds(inst) -> None:
    """A short time limit (the second phase runs its searches side by side, with restarts): the
    answer is a cover (or partial cover) no cheaper than the optimum, the bound no higher."""
    dense, costs, w, need = inst
    best = enumerate_cover(dense, costs, w, need)
    old = S.AUTO_MODEL_NNZ, S.RESTART_WORK_MIN
    S.AUTO_MODEL_NNZ, S.RESTART_WORK_MIN = 0, 1000
    try:
        out = S.solve_cover(sp.csr_matrix(dense.astype(float)), costs, None if need is None else w, need,
                            deadline=Deadline(0.05))
    finally:
        S.AUTO_MODEL_NNZ, S.RESTART_WORK_MIN = old
    assert _covers(dense, w, need, out.selected)
    assert out.objective == pytest.approx(float(costs[list(out.selected)].sum()), rel=1e-12, abs=1e-12)
    assert_ge(out.objective, best)
    assert_le(out.bound, best)
    if out.status == "optimal":
        assert out.objective == pytest.approx(best, rel=1e-9, abs=1e-12)


def test_side_by_side_searches_stop_together_at_the_target() -> None:
    """With a time limit, the first search to reach the target (here the enumerated optimum of a
    small instance) stops the other long before the limit."""
    rng = np.random.default_rng(8)
    dense = rng.random((25, 12)) < 0.3
    dense = dense[dense.any(axis=1)]
    best = enumerate_cover(dense, np.ones(12), np.ones(dense.shape[0]), None)
    red = S.reduce_cover(sp.csr_matrix(dense.astype(float)), np.ones(12))
    searches = [S.LocalSearch(red, seed=2, stream=k) for k in range(2)]
    t0 = __import__("time").perf_counter()
    whys = S.run_searches(searches, deadline=Deadline(30.0), target=best - red.forced_cost)
    assert __import__("time").perf_counter() - t0 < 10.0
    assert "target" in whys and set(whys) <= {"target", "stopped"}
    assert min(s.best_cost for s in searches) + red.forced_cost == best


def test_a_partial_cover_one_column_reaches_is_proven_without_subgradient_steps() -> None:
    """A partial cover that one camera reaches (comet-flyby at --required-fraction 0.8 spent 6 s
    bounding it at 1 before): the cheapest column's cost is a lower bound, so the cover is proven
    at once; the oracle is the weight each single column covers."""
    rng = np.random.default_rng(5)
    m, n = 3000, 400
    dense = rng.random((m, n)) < 0.05
    dense[: int(0.9 * m), 17] = True  # column 17 alone observes 90 % of the rows
    dense = dense[dense.any(axis=1)]
    w = rng.random(dense.shape[0]) + 0.5
    need = 0.8 * float(w.sum())
    single = np.array([float(w[dense[:, j]].sum()) for j in range(n)])
    assert single.max() >= need and np.sort(single)[-2] < need  # the oracle: exactly one column suffices
    out = S.solve_cover(sp.csr_matrix(dense.astype(float)), np.ones(n), w, need)
    assert out.status == "optimal" and out.objective == 1.0 and out.bound == 1.0
    assert tuple(out.selected) == (17,)
    assert out.stats["lagrangian"]["iterations"] == 0


@pytest.mark.parametrize("seed", [0, 1, 4, 5])
def test_integer_costs_stop_the_bound_once_it_rounds_up_to_the_cover(seed: int) -> None:
    """With integer costs the subgradient steps stop once the rounded bound reaches the cover's
    cost (checked between the kernel's batches of 4, 8, 16, ... steps), not when the value itself
    does: these four took 124-508 steps before, now at most 60; the bound proves the optimum found
    by enumeration."""
    rng = np.random.default_rng(seed)
    dense = rng.random((60, 12)) < 0.35
    dense = dense[dense.any(axis=1)]
    costs = rng.integers(1, 4, 12).astype(float)
    best = enumerate_cover(dense, costs, np.ones(dense.shape[0]), None)
    red = S.reduce_cover(sp.csr_matrix(dense.astype(float)), costs, None, None)
    lb, st_ = S.lagrangian_bound(red, best - red.forced_cost)
    assert lb + red.forced_cost == best  # proves the optimum (integer costs: exact)
    assert 0 < st_["iterations"] <= 60


def test_auto_tries_scip_briefly_on_a_tiny_instance_with_a_wide_gap() -> None:
    """Equal costs and a gap of 3 columns after the search and the Lagrangian bound: auto used to
    skip SCIP (it closes no such gap on a large instance) and answer 'feasible'; on a reduced
    instance this small SCIP gets a short trial and proves the optimum, the same cost SCIP finds
    when asked for (engine='mip', the oracle)."""
    M = sp.random(400, 60, density=0.1, format="csr", random_state=1)
    M = M[np.diff(M.indptr) > 0]
    w = np.ones(M.shape[0])
    auto = solve(M, w, mode="setcover")
    mip = solve(M, w, mode="setcover", engine="mip")
    assert mip.status == "optimal"
    st_ = auto.stats["setcover"]
    assert st_["reduction"]["nnz_after"] <= S.AUTO_TRIAL_NNZ
    assert st_["local_search"]["greedy_cost"] - st_["lagrangian"]["bound"] > S.AUTO_MODEL_GAP_COLUMNS
    assert st_["model_trial_s"] == S.AUTO_TRIAL_S
    assert auto.status == "optimal" and auto.objective == mip.objective == auto.bound
    # a gap of 5 columns (200 x 320 reduced): SCIP does not close such gaps in a trial, none is made
    from tests.solver.test_setcover_reduce_bits import _dense_instance

    wide = S.solve_cover(_dense_instance(), np.ones(320), seed=3, max_iterations=3000)
    assert wide.stats["local_search"]["cost"] - wide.stats["lagrangian"]["bound"] > S.AUTO_TRIAL_GAP_COLUMNS
    assert "model_trial_s" not in wide.stats and "model" not in wide.stats
