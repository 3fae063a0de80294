"""Issue 29: presolve, the incumbent and the exact search on every allowed core, with the same bits at
every thread count; ``threads`` in the API and OR-Tools' workers follow it."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camplace._cores import allowed_cores, set_threads, thread_count, using_threads
from camplace.errors import CamplaceError
from camplace.solver import SolveOptions, presolve, solve
from camplace.solver._support import bitkernels as K
from camplace import _blocks as blocks
from camplace.solver._support import parkernels as P
from camplace.solver._support.deadline import Deadline
from camplace.solver.engines.bitset import search as bitset_mod
from camplace.solver.engines.bitset.search import solve_bitset
from camplace.solver.engines.setcover.local_search import search_threads
from tests.solver._oracle import small_instances, tolerance

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                       HealthCheck.function_scoped_fixture])
two_cores = pytest.mark.skipif(allowed_cores() < 2, reason="needs 2 allowed cores")


@pytest.fixture
def pool_always(monkeypatch):
    """Every pass on the thread pool, however small (the default keeps small passes on one thread)."""
    monkeypatch.setattr(blocks, "PARALLEL_MIN_WORK", 0)
    yield
    set_threads(None)


def _presolve_bytes(pre) -> tuple:
    a, rows, col_map = pre.source
    return tuple(np.ascontiguousarray(x).tobytes() for x in
                 (pre.weights, pre.counts, pre.columns, pre.row_groups, rows, col_map, pre.bits)) + (pre.weight_unit,)


def _solve_at(threads: int, matrix, w, k: int, views: int, poor_start: bool):
    with using_threads(threads):
        assert thread_count() == threads
        pre = presolve(matrix, w, k, dominance=views == 1)
        # a poor first incumbent (the first k columns) makes the search improve it as it goes,
        # so that the order in which roots are searched could show in the answer
        start = tuple(range(k)) if poor_start and pre.shape[1] > k else None
        out = solve_bitset(pre, views=views, start=start)
        return _presolve_bytes(pre), (out.status, out.bound, pre.original_columns(out.selected),
                                      out.stats.get("bound_evaluations"))


@two_cores
@settings(max_examples=100, **_SETTINGS)
@given(inst=small_instances(max_n=30, max_k=4), views=st.sampled_from([1, 1, 2, 3]), slice_=st.integers(1, 6),
       integer=st.booleans(), poor_start=st.booleans())
def test_same_presolve_and_answer_at_one_and_two_threads(pool_always, monkeypatch, inst, views: int, slice_: int,
                                                         integer: bool, poor_start: bool) -> None:
    """Presolve's output (every array, bit for bit) and the exact engine's answer (status, bound,
    cameras, even the number of bounds) are the same at 1 and 2 threads, and equal enumeration; the
    search is cut into many roots (a few bound evaluations each) so that rounds run in parallel."""
    matrix, weights, k = inst
    w = np.where(weights > 0, 0.25, 0.0) if integer else weights
    monkeypatch.setattr(bitset_mod, "_SLICE", slice_)
    monkeypatch.setattr(bitset_mod, "_ROOT_BUDGET", slice_)
    one = _solve_at(1, matrix, w, k, views, poor_start)
    two = _solve_at(2, matrix, w, k, views, poor_start)
    assert one == two
    dense = matrix.toarray() > 0
    best = max(float(w[dense[:, list(c)].sum(axis=1) >= views].sum()) for c in combinations(range(dense.shape[1]), k))
    sel = list(one[1][2])
    assert one[1][0] == "optimal"
    assert abs(float(w[dense[:, sel].sum(axis=1) >= views].sum()) - best) <= tolerance(w)


class _Clock:
    """A clock for the search's rate: each reading ``step`` seconds after the last."""

    def __init__(self, step: float) -> None:
        self.now, self.step = 0.0, step

    def perf_counter(self) -> float:
        self.now += self.step
        return self.now


@two_cores
@settings(max_examples=40, **_SETTINGS)
@given(inst=small_instances(max_n=40, max_k=4), views=st.sampled_from([1, 1, 2]))
def test_with_a_time_limit_the_rounds_do_not_depend_on_the_speed_or_the_thread_count(pool_always, monkeypatch, inst,
                                                                                      views: int) -> None:
    """With a time limit (the verbs' default 60 s) a round of the roots search still takes twice the
    roots of the last, up to its cap, whatever the bounds-per-second: the same rounds, bounds and
    answer at 1 and 2 threads and on a machine where each round reads as 0.5 s,
    so that a tie between optima is broken the same way (the rate once sized every round)."""
    matrix, w, k = inst
    monkeypatch.setattr(bitset_mod, "_SLICE", 2)
    monkeypatch.setattr(bitset_mod, "_ROOT_BUDGET", 2)
    monkeypatch.setattr(bitset_mod, "_ROUND_EVALS", 64)  # at most 32 roots a round

    def run(threads: int, step: float):
        monkeypatch.setattr(bitset_mod, "time", _Clock(step))
        with using_threads(threads):
            pre = presolve(matrix, w, k, dominance=views == 1)
            start = tuple(range(k)) if pre.shape[1] > k else None  # a poor start: the search improves it
            out = solve_bitset(pre, views=views, deadline=Deadline(60.0), start=start)
        return (out.status, out.bound, pre.original_columns(out.selected), out.stats.get("bound_evaluations"),
                out.stats.get("rounds"))

    fast = run(1, 1e-6)
    assert fast == run(2, 1e-6) == run(1, 0.5) == run(2, 0.5)


@settings(max_examples=60, **_SETTINGS)
@given(inst=small_instances(max_n=40, max_m=200, max_k=4), threads=st.sampled_from([1, 2]), sel=st.integers(0, 3))
def test_block_kernels_equal_the_serial_kernels(pool_always, inst, threads: int, sel: int) -> None:
    """Each parallel pass gives the serial kernel's arrays bit for bit (blocks of 1 to 64 rows or
    columns, bitset rows in 512-row blocks across words)."""
    matrix, w, _ = inst
    threads = min(threads, allowed_cores())
    a = sp.csr_matrix(matrix)
    a.sort_indices()
    data = a.data
    args = (a.indptr, a.indices, data)
    for x, y in zip(P.live_rows(*args, w, threads=threads), K.live_rows(*args, w)):
        assert x.tobytes() == y.tobytes()
    m, n = a.shape
    rows = np.arange(m, dtype=np.int64)
    col_map = np.where(np.arange(n) % 3 == 1, -1, np.arange(n)).astype(np.int64)
    bits = P.build_bits(*args, rows, col_map, n, threads=threads)
    assert bits.tobytes() == K.build_bits(*args, rows, col_map, n).tobytes()
    size = P.column_sizes(bits, threads=threads)
    assert size.tobytes() == K.column_sizes(bits).tobytes()
    _, nnz = K.live_rows(*args, w)
    assert (P.dominated_columns(bits, size, nnz, *args, rows, threads=threads).tobytes()
            == K.dominated_columns(bits, size, nnz, *args, rows).tobytes())
    salt = np.random.default_rng(1).integers(0, 2**63 - 1, size=max(n, 1)).astype(np.uint64)
    for x, y in zip(P.row_hashes(*args, rows, col_map, salt, threads=threads), K.row_hashes(*args, rows, col_map, salt)):
        assert x.tobytes() == y.tobytes()
    h, _ = K.row_hashes(*args, rows, col_map, salt)
    for hh in (h, h % np.uint64(3)):  # ... and with many hash collisions (big buckets)
        g1, n1 = P.group_rows(*args, rows, col_map, hh, threads=threads)
        g0, n0 = K.group_rows(*args, rows, col_map, hh)
        assert n1 == n0 and g1.tobytes() == g0.tobytes()
    mask = np.uint64((1 << (m % 64)) - 1) if m % 64 else np.uint64(2**64 - 1)
    sb = np.ascontiguousarray(bits[: min(sel, n)])
    for views in (1, 2):
        assert (P.shortfall_all(bits, sb, views, w, mask, threads=threads).tobytes()
                == K.shortfall_all(bits, sb, views, w, mask).tobytes())


@two_cores
def test_two_threads_run_the_passes_and_the_search_on_a_pool_of_two(pool_always, monkeypatch) -> None:
    made = []

    class Spy(blocks.ThreadPoolExecutor):
        def __init__(self, max_workers=None, **kw):
            made.append(max_workers)
            super().__init__(max_workers=max_workers, **kw)

    monkeypatch.setattr(blocks, "ThreadPoolExecutor", Spy)
    monkeypatch.setattr(blocks, "_pools", {})  # the kept pools: made anew here
    monkeypatch.setattr(bitset_mod, "_SLICE", 2)
    rng = np.random.default_rng(3)
    dense = rng.random((300, 40)) < 0.1
    with using_threads(2):
        res = solve(sp.csr_matrix(dense.astype(float)), np.ones(300), 3, engine="exact")
    assert res.status == "optimal"
    assert made and set(made) == {2}
    made.clear()
    with using_threads(1):
        solve(sp.csr_matrix(dense.astype(float)), np.ones(300), 3, engine="exact")
    assert made == []  # one thread: no pool at all


def test_threads_option_scopes_the_solve_and_reaches_cpsat() -> None:
    set_threads(None)
    before = thread_count()
    with pytest.raises(CamplaceError, match="threads must be a whole number"):
        SolveOptions(k=2, threads=allowed_cores() + 1)
    with pytest.raises(CamplaceError, match="threads must be a whole number"):
        SolveOptions(k=2, threads=0)
    assert SolveOptions(k=2, threads=1) == SolveOptions(k=2)  # not compared: it does not change the answer
    rng = np.random.default_rng(0)
    dense = (rng.random((60, 12)) < 0.3).astype(float)
    res = solve(sp.csr_matrix(dense), np.ones(60), options=SolveOptions(k=3, engine="cpsat", threads=1))
    assert res.stats["engine_stats"]["workers"] == 1
    assert thread_count() == before  # restored after the call
    with using_threads(1):
        assert search_threads() == 1
        res = solve(sp.csr_matrix(dense), np.ones(60), options=SolveOptions(k=3, engine="cpsat"))
        assert res.stats["engine_stats"]["workers"] == 1
    assert thread_count() == before


def test_run_takes_threads() -> None:
    import camplace

    with pytest.raises(CamplaceError, match="threads must be a whole number"):
        camplace.run("comet-67p-bunker", candidates=50, points=200, threads=allowed_cores() + 1)
