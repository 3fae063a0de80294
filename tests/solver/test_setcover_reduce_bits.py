"""Set cover's reductions on row bitsets (:mod:`camplace.solver.engines.setcover.reduce_bits`): the
same reduced instance as the list reductions, array for array, at 1 and 2 threads; the same answer
from :func:`solve_cover`; and less working memory than a byte an observed pair on a dense instance
(the list reductions need 20 to 44 besides the input CSR)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.solver.engines.setcover import local_search as S
from camplace.solver.engines.setcover.reduce_bits import RowBits, reduce_bits_bytes, reduce_cover_bits, row_bits_bytes

_FIELDS = ("cptr", "crow", "rptr", "rcol", "cost", "roww", "columns", "forced")
_COUNTS = ("rounds", "forced", "rows_dominated", "cols_dominated", "cols_cheaper_cover", "rows_after", "cols_after",
           "nnz_after", "forced_cols")


def _instance(seed: int):
    rng = np.random.default_rng(seed)
    m, n = int(rng.integers(1, 120)), int(rng.integers(1, 140))
    dense = rng.random((m, n)) < rng.uniform(0.02, 0.6)
    dense[np.arange(m), rng.integers(0, n, m)] = True  # every row coverable
    kind = seed % 4
    costs = np.ones(n) if kind in (0, 2) else rng.integers(0, 4, n).astype(float)  # cost 0: forced columns
    w = need = None
    if kind >= 2:  # partial covers: identical rows merged
        w = rng.uniform(0.1, 1.0, m)
        need = float(w.sum() * rng.uniform(0.3, 1.0))
    return sp.csr_matrix(dense.astype(float)), costs, w, need


@pytest.mark.parametrize("block", range(4))
def test_reduce_cover_bits_is_reduce_cover(block: int) -> None:
    """Full and partial covers, equal and unequal costs, zero costs: the same reduced instance (every
    array, its dtype, the forced columns and the counts of each reduction) at 1 and 2 threads."""
    reduced = 0
    for seed in range(60 * block, 60 * block + 60):
        a, costs, w, need = _instance(seed)
        ref = S.reduce_cover(a, costs, w, need)
        reduced += ref.shape != a.shape
        for workers in (1, 2):
            got = reduce_cover_bits(RowBits.from_csr(a), costs, w, need, workers=workers)
            for f in _FIELDS:
                x, y = getattr(got, f), getattr(ref, f)
                assert x.dtype == y.dtype, (seed, f)
                np.testing.assert_array_equal(x, y, err_msg=f"seed {seed}: {f}")
            assert (got.need, got.forced_cost, got.shape, got.shape_in) == (ref.need, ref.forced_cost, ref.shape,
                                                                            ref.shape_in)
            for k in _COUNTS:
                assert got.stats[k] == ref.stats[k], (seed, k)
    assert reduced > 30  # the reductions did something on most instances


def _dense_instance() -> sp.csr_matrix:
    """200 sparse core rows and 5,800 dense rows, each a core row plus 40 % of the columns (row
    dominance drops them: the reduced instance is small, as on the visibility matrices)."""
    rng = np.random.default_rng(5)
    n = 320
    core = rng.random((200, n)) < 0.05
    core[np.arange(200), rng.integers(0, n, 200)] = True
    extra = core[rng.integers(0, 200, 5800)] | (rng.random((5800, n)) < 0.4)
    return sp.csr_matrix(np.vstack([core, extra]).astype(float))


def test_solve_cover_on_bits_same_answer_and_less_than_a_byte_a_pair() -> None:
    """A dense 6,000 x 320 instance (8e5 pairs): the same cover, cost, bound and search as the
    list route, and a traced peak under a byte an observed pair and under the estimate
    (:func:`reduce_bits_bytes` plus the row bitsets); the list route's (the input CSR aside) is over 20 bytes a pair."""
    a = _dense_instance()
    costs = np.ones(a.shape[1])
    rows = RowBits.from_csr(a)
    kw = dict(seed=3, max_iterations=3000)
    S.solve_cover(rows, costs, **kw)  # kernels compiled before tracing
    tracemalloc.start()
    try:
        ref = S.solve_cover(a, costs, **kw)
        _, peak_lists = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        base, _ = tracemalloc.get_traced_memory()
        got = S.solve_cover(rows, costs, **kw)
        _, peak_bits = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)
    assert got.stats["local_search"] == ref.stats["local_search"]
    assert got.stats["reduction"]["layout"] == "bitsets" and got.stats["reduction"]["rows_dominated"] > 5000
    m, n = a.shape
    assert peak_lists > 20 * a.nnz
    assert peak_bits - base < a.nnz
    assert peak_bits - base <= reduce_bits_bytes(m, n) + row_bits_bytes(m, n)


def _enumerated_min_columns(dense: np.ndarray) -> int:
    import itertools

    m, n = dense.shape
    for r in range(1, n + 1):
        if any(dense[:, list(c)].any(axis=1).all() for c in itertools.combinations(range(n), r)):
            return r
    raise AssertionError("no cover")


def test_small_cover_test_equals_enumeration() -> None:
    """The exact test of a unicost cover (:func:`small_cover_test`) from the greedy cover and a zero
    bound: its answer is a cover, and 'proven' exactly when its size is the enumerated minimum."""
    proven = 0
    for seed in range(120):
        rng = np.random.default_rng(1000 + seed)
        m, n = int(rng.integers(2, 30)), int(rng.integers(2, 13))
        dense = rng.random((m, n)) < rng.uniform(0.1, 0.5)
        dense[np.arange(m), rng.integers(0, n, m)] = True
        red = S.reduce_cover(sp.csr_matrix(dense.astype(float)), np.ones(n))
        if red.shape[0] == 0:
            continue
        rd = np.zeros(red.shape, dtype=bool)
        for j in range(red.shape[1]):
            rd[red.crow[red.cptr[j]:red.cptr[j + 1]], j] = True
        start = S.LocalSearch(red, seed=seed).best_cover()
        sel, bound, st = S.small_cover_test(red, start, 0.0)
        assert sel.size <= start.size and rd[:, sel].any(axis=1).all()
        best = _enumerated_min_columns(rd)
        assert st["result"] == "proven" and bound == sel.size == best, (seed, st, best)
        proven += 1
    assert proven > 25  # the others reduce to nothing (forced columns)


def test_small_cover_test_work_limit_keeps_the_lower_bound() -> None:
    """Out of work before an answer: the cover and the given bound come back unchanged."""
    a = _dense_instance()
    red = S.reduce_cover(a, np.ones(a.shape[1]))
    start = S.LocalSearch(red, seed=1).best_cover()
    old = S.EXACT_WORK
    try:
        S.EXACT_WORK = 1
        sel, bound, st = S.small_cover_test(red, start, 1.0)
    finally:
        S.EXACT_WORK = old
    assert st["result"] in ("work limit", f"skipped ({start.size} columns, tested up to {S.EXACT_MAX_COLUMNS + 1})")
    np.testing.assert_array_equal(sel, start)
    assert bound == 1.0


def test_setcover_on_bits_stays_within_the_guard_term() -> None:
    """Set cover through :func:`camplace.solver.solve` on column bitsets: the traced peak stays
    under the term the visibility guard adds for it (:func:`setcover_bits_bytes`)."""
    from camplace.solver.api import solve
    from camplace.solver.engines.setcover.reduce_bits import setcover_bits_bytes
    from camplace.visibility.bits import bits_from_csr

    a = _dense_instance()
    bits = bits_from_csr(a)
    w = np.ones(a.shape[0])
    solve(bits, w, mode="setcover", iterations=2000)  # kernels loaded before tracing
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        res = solve(bits, w, mode="setcover", iterations=2000)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert res.stats["setcover"]["reduction"]["layout"] == "bitsets"
    assert bool(np.all(np.diff(a[:, list(res.selected)].tocsr().indptr) > 0))  # a cover
    assert peak - base <= setcover_bits_bytes(*a.shape)


@pytest.mark.parametrize("seed", [5, 6, 11])
def test_exact_test_proves_what_the_lagrangian_bound_leaves_open(seed: int, monkeypatch) -> None:
    """Unicost covers whose Lagrangian bound is one camera short (no SCIP: the search-only path of
    large instances): the exact test proves the search's cover optimal (was 'feasible'), the
    enumerated minimum."""
    monkeypatch.setattr(S, "AUTO_MODEL_NNZ", 0)
    rng = np.random.default_rng(seed)
    dense = rng.random((40, 16)) < 0.3
    dense[np.arange(40), rng.integers(0, 16, 40)] = True
    out = S.solve_cover(sp.csr_matrix(dense.astype(float)), np.ones(16), seed=0, max_iterations=500)
    assert out.stats["lagrangian"]["bound"] < out.objective
    assert out.stats["exact_test"]["result"] == "proven" and out.engine == "local-search"
    assert out.status == "optimal" and out.bound == out.objective == _enumerated_min_columns(dense)
