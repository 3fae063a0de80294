"""Many cameras (4 < k <= 8) on column bitsets (issue 32): the large-k engines run on the bit
presolve's reduced instance (dead rows dropped, identical rows merged, dominated columns dropped
for max coverage), made into CSR itself; the whole matrix is never converted. The answer is the CSR
route's (objective, status, bound) and the enumerated optimum."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.solver.api import solve
from camplace.solver.problem.objectives import mode_value
from camplace.visibility.bits import BitMatrix, bits_from_csr
from tests.solver._oracle import brute_force_mode


def watch_tocsr(mp, bits: BitMatrix) -> list[tuple[int, int]]:
    """BitMatrix.tocsr made to refuse the whole matrix ``bits`` (any BitMatrix sharing its words)
    and to record the shape of every other conversion (which it still makes)."""
    shapes: list[tuple[int, int]] = []
    real = BitMatrix.tocsr

    def watched(self, *args, **kwargs):
        if np.shares_memory(self.words, bits.words):
            raise AssertionError("the whole matrix was converted to CSR")
        shapes.append(self.shape)
        return real(self, *args, **kwargs)

    mp.setattr(BitMatrix, "tocsr", watched)
    return shapes


def _cases(seed: int, count: int = 2):
    """(dense (m, n) float32, weights (m,), k): 9 to 12 columns, duplicated columns and rows (to
    merge and to dominate), zero weights, equal weights."""
    rng = np.random.default_rng(seed)
    for t in range(count):
        m, n = int(rng.integers(30, 140)), int(rng.integers(9, 13))
        dense = (rng.random((m, n)) < rng.choice([0.15, 0.3, 0.5])).astype(np.float32)
        dense[:, 3] = dense[:, 5]  # identical columns
        dense[m // 2:m // 2 + 5] = dense[0]  # identical rows
        w = np.full(m, 0.25) if t == 1 else np.where(rng.random(m) < 0.2, 0.0, rng.random(m))
        yield dense, w, int(rng.integers(5, min(8, n - 1) + 1))


@pytest.mark.parametrize("mode, views", [("maxcover", 1), ("multiview", 1), ("multiview", 2), ("multiview", 3)])
def test_large_k_on_bits_equals_csr_and_enumeration(mode: str, views: int, monkeypatch) -> None:
    for dense, w, k in _cases(7 * views + len(mode)):
        ref = solve(sp.csr_matrix(dense), w, k, mode=mode, views=views)
        bits = bits_from_csr(sp.csr_matrix(dense))
        with monkeypatch.context() as mp:
            shapes = watch_tocsr(mp, bits)
            got = solve(bits, w, k, mode=mode, views=views)
        assert got.stats["matrix"].startswith("column bitsets, presolved to ")
        reduced = (got.stats["rows_after"], got.stats["cols_after"])
        assert all(s == reduced for s in shapes)  # only the reduced instance, for a SCIP model that fits
        assert (got.status, got.objective, got.bound) == (ref.status, ref.objective, ref.bound)
        assert got.status == "optimal" and len(got.selected) == k
        best = brute_force_mode(dense, w, k, mode, views=views)
        assert got.objective == pytest.approx(best, rel=1e-12, abs=1e-12)
        assert got.objective == mode_value(dense, w, got.selected, mode=mode, views=views)


def test_large_k_quality_of_bits_is_maxcover(monkeypatch) -> None:
    """quality on a binary matrix, k > 4: solved as max coverage on the reduced bits, the
    enumerated optimum of either objective."""
    for dense, w, k in _cases(3):
        bits = bits_from_csr(sp.csr_matrix(dense))
        with monkeypatch.context() as mp:
            watch_tocsr(mp, bits)
            got = solve(bits, w, k, mode="quality")
        assert got.status == "optimal" and "binary_matrix" in got.stats
        assert got.objective == pytest.approx(brute_force_mode(dense, w, k, "quality"), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("fixed, forbidden", [((0,), (1,)), ((), (2, 4)), ((2, 6), ())])
def test_large_k_with_fixed_and_forbidden_on_bits(fixed, forbidden, monkeypatch) -> None:
    """Max coverage with fixed / forbidden cameras and k > 4: the allowed columns' bits, presolved,
    the CSR route's answer, the enumerated optimum with the fixed cameras kept."""
    for dense, w, k in _cases(11 + len(fixed)):
        k = min(k, dense.shape[1] - len(fixed) - len(forbidden) - 1)
        ref = solve(sp.csr_matrix(dense), w, k, fixed=fixed, forbidden=forbidden)
        bits = bits_from_csr(sp.csr_matrix(dense))
        with monkeypatch.context() as mp:
            watch_tocsr(mp, bits)
            got = solve(bits, w, k, fixed=fixed, forbidden=forbidden)
        assert got.stats["matrix"].startswith("column bitsets of the ")
        assert (got.status, got.objective, got.bound) == (ref.status, ref.objective, ref.bound)
        assert got.status == "optimal" and set(fixed) <= set(got.selected) and not set(forbidden) & set(got.selected)
        best = brute_force_mode(dense, w, k, "maxcover", fixed=fixed, forbidden=forbidden)
        assert got.objective == pytest.approx(best, rel=1e-12, abs=1e-12)


def test_large_k_column_lists_over_the_budget_go_through_csr(monkeypatch) -> None:
    """The reduced instance's column lists one byte over the memory budget: the bits route declines
    and the CSR route answers as before."""
    import camplace.solver.problem.presolve_bits as pb

    dense, w, k = next(_cases(5))
    bits = bits_from_csr(sp.csr_matrix(dense))
    pre = pb.presolve_bits(bits, w, k)
    need = 8 * (pre.nnz + pre.shape[1] + 1)  # reduced_pattern's estimate (int64 lists and pointers)
    with monkeypatch.context() as mp:
        mp.setattr(pb, "memory_budget_bytes", lambda: need - 1)
        got = solve(bits, w, k)
    ref = solve(sp.csr_matrix(dense), w, k)
    assert "matrix" not in got.stats
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)


def test_pattern_from_bits_is_the_engines_own_copy() -> None:
    """The column lists read from the reduced bits make the same local-search objects as the
    engines' copies of the CSR, and the same search: the same set, status and bound."""
    from camplace.solver.engines.large_k.search import _Quality, _Views, solve_large_k
    from camplace.solver.problem.presolve_bits import presolve_bits, reduced_csr, reduced_pattern

    for dense, w, k in _cases(9):
        pre = presolve_bits(bits_from_csr(sp.csr_matrix(dense)), w, k)
        resid = reduced_csr(pre, np.bool_)
        pattern = reduced_pattern(pre)
        ref_q, got_q = _Quality(resid, pre.weights), _Quality.from_pattern(pattern, resid.shape[0], pre.weights)
        for name in ("indptr", "indices", "wq"):
            a, b = getattr(ref_q, name), getattr(got_q, name)
            assert a.dtype == b.dtype and np.array_equal(a, b)
        assert (ref_q.m, ref_q.n, ref_q.total, ref_q.margin) == (got_q.m, got_q.n, got_q.total, got_q.margin)
        ref_v, got_v = _Views(resid, pre.weights, 2), _Views.from_pattern(pattern, resid.shape[0], pre.weights, 2)
        for name in ("indptr", "indices", "w"):
            assert np.array_equal(getattr(ref_v, name), getattr(got_v, name))
        kk = min(k, pre.shape[1])
        ref = solve_large_k(resid, pre.weights, kk, binary=True)
        got = solve_large_k(resid, pre.weights, kk, binary=True, pattern=pattern)
        assert (got.selected, got.status, got.bound) == (ref.selected, ref.status, ref.bound)


def test_large_k_on_bits_then_scip_maps_its_columns(monkeypatch) -> None:
    """Max coverage, k > 4, the large-k search made to stop unproven at a poor set (the first k
    columns, the total weight as its bound): SCIP then runs on the bit presolve itself, and its
    answer (reduced columns) comes back as the matrix's columns: the enumerated optimum, as the
    CSR route gives it."""
    from camplace.solver.engines.large_k import search
    from camplace.solver.result import EngineOutcome

    real = search.solve_large_k

    def unproven(matrix, weights, k, **kw):
        out = real(matrix, weights, k, **kw)
        return EngineOutcome(tuple(range(k)), "feasible", 2.0 * float(np.sum(weights)) + 1.0, out.stats)

    monkeypatch.setattr(search, "solve_large_k", unproven)
    for dense, w, k in _cases(13):
        dense[:, 0] = 0.0  # the poor set is not optimal: SCIP's answer must replace it
        dense[:, 4] = dense[:, 1]  # a dominated column: the bit presolve drops it, reduced != original columns
        ref = solve(sp.csr_matrix(dense), w, k)
        got = solve(bits_from_csr(sp.csr_matrix(dense)), w, k)
        best = brute_force_mode(dense, w, k, "maxcover")
        assert got.stats["cols_after"] < dense.shape[1]
        assert got.stats["engine_stats"]["then"]["engine"] == "mip"
        assert got.status == ref.status == "optimal"
        assert got.objective == ref.objective == pytest.approx(best, rel=1e-12, abs=1e-12)
        assert got.objective == mode_value(dense, w, got.selected, mode="maxcover")
