"""The p10 objective on stacked scenario bits (issue 32): the swap search's completion weights,
the merge of identical rows, the per-scenario row slices and the whole solve read the column
bitsets, with the CSR route's results to the last bit.

Oracles: the CSR computations the p10 path made before (kept here: ``pattern.T @ U`` of the
stacked CSR pattern, the per-scenario merge over row bytes, the swap search on CSR rows), CSR row
slicing, and enumeration of the p10 objective over every k-subset."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.robust.p10 as p10mod
from camplace._cores import allowed_cores, using_threads
from camplace.errors import CamplaceError
from camplace.robust.kernels import completion_weights
from camplace.robust.p10 import (QUANTILE, _merged_csr, _scenario_groups, _swap_search, order_p10, scenario_values,
                                 solve_p10)
from camplace.solver.options import SolveOptions
from camplace.solver.problem.objectives import selected_row_stats
from camplace.solver.problem.presolve_bits import identical_rows
from camplace.visibility.bits import BitMatrix, bits_from_csr, row_range


def _no_csr(mp) -> None:
    def refuse(self, *args, **kwargs):
        raise AssertionError("a CSR of the bits was made")

    mp.setattr(BitMatrix, "tocsr", refuse)


def _stacked(rng, m: int, n: int, s: int, dens: float) -> sp.csr_matrix:
    return sp.csr_matrix((rng.random((s * m, n)) < dens).astype(np.float32))


# ---------------------------------------------------------------------------------------------------
# the CSR route as it was (the oracle)

def _csr_completion(stacked: sp.csr_matrix, u: np.ndarray, s_count: int) -> np.ndarray:
    m = stacked.shape[0] // s_count
    pattern = sp.csr_matrix((np.ones(stacked.nnz, dtype=np.float64), stacked.indices, stacked.indptr), shape=stacked.shape)
    block = np.arange(s_count * m) // m
    U = sp.csr_matrix((u, (np.arange(s_count * m), block)), shape=(s_count * m, s_count))
    return (pattern.T @ U).toarray()


def _csr_merged_blocks(stacked: sp.csr_matrix, weights: np.ndarray, scenarios: int):
    m = len(weights)
    out = []
    for s in range(scenarios):
        block = stacked[s * m:(s + 1) * m]
        keep = np.flatnonzero((np.diff(block.indptr) > 0) & (weights > 0))
        block = block[keep]
        groups: dict[bytes, int] = {}
        first, wsum = [], []
        for r in range(block.shape[0]):
            key = block.indices[block.indptr[r]:block.indptr[r + 1]].tobytes()
            g = groups.get(key)
            if g is None:
                groups[key] = len(first)
                first.append(r)
                wsum.append(float(weights[keep[r]]))
            else:
                wsum[g] += float(weights[keep[r]])
        out.append((block[first], np.asarray(wsum, dtype=np.float64)))
    return out


def _csr_swap_search(stacked, w, scenarios, start, *, mode, views, fixed, banned, conflicts):
    m = len(w)
    need = 1 if mode == "maxcover" else int(views)
    block = np.arange(scenarios * m) // m
    w_all = np.tile(w, scenarios)
    q_need = math.ceil(QUANTILE * scenarios - 1e-9)
    sel = sorted(int(j) for j in start)
    best = order_p10(scenario_values(stacked, w, scenarios, sel, mode=mode, views=views))
    swaps = 0
    improved = True
    while improved:
        improved = False
        for pos in [p for p, j in enumerate(sel) if j not in fixed]:
            others = sel[:pos] + sel[pos + 1:]
            count, _ = selected_row_stats(stacked, others) if others else (np.zeros(scenarios * m, dtype=np.int64), None)
            base = np.bincount(block, weights=w_all * (count >= need), minlength=scenarios)
            u = w_all * (count == need - 1)
            vals = _csr_completion(stacked, u, scenarios) + base[None, :]
            p10s = np.partition(vals, scenarios - q_need, axis=1)[:, scenarios - q_need]
            ok = ~banned.copy()
            ok[others] = False
            for a, b in conflicts:
                if a in others:
                    ok[b] = False
                if b in others:
                    ok[a] = False
            p10s[~ok] = -np.inf
            j = int(np.argmax(p10s))
            if p10s[j] > best + 1e-9 * max(1.0, abs(best)):
                sel = sorted(others + [j])
                best = order_p10(scenario_values(stacked, w, scenarios, sel, mode=mode, views=views))
                swaps += 1
                improved = True
    return tuple(sel), best, swaps


# ---------------------------------------------------------------------------------------------------
# the pieces

@pytest.mark.parametrize("m, n, s", [(1, 1, 1), (5, 3, 4), (64, 7, 3), (63, 4, 5), (130, 9, 2), (37, 70, 6)])
def test_completion_weights_equal_the_sparse_product(m: int, n: int, s: int) -> None:
    rng = np.random.default_rng(m + 7 * n + 31 * s)
    stacked = _stacked(rng, m, n, s, 0.35)
    bits = bits_from_csr(stacked)
    w = np.where(rng.random(m) < 0.2, 0.0, rng.random(m))
    for need in (1, 2):
        count = selected_row_stats(stacked, list(range(0, n, 2)))[0]
        u = np.tile(w, s) * (count == need - 1)
        ref = _csr_completion(stacked, u, s)
        for workers in (1, 2, 3):
            got = completion_weights(bits, u, s, workers=workers)
            assert got.shape == (n, s) and got.tobytes() == ref.tobytes()
    assert not completion_weights(bits, np.zeros(s * m), s).any()


@pytest.mark.parametrize("lo, hi", [(0, 0), (0, 300), (0, 64), (64, 128), (5, 69), (63, 64), (100, 300), (299, 300),
                                    (1, 255), (130, 131)])
def test_row_range_is_the_csr_row_slice(lo: int, hi: int) -> None:
    rng = np.random.default_rng(lo + hi)
    csr = _stacked(rng, 300, 70, 1, 0.4)
    bits = bits_from_csr(csr)
    for workers in (1, 2):
        got = row_range(bits, lo, hi, workers=workers)
        assert got.shape == (hi - lo, 70)
        np.testing.assert_array_equal(got.words, bits_from_csr(csr[lo:hi]).words)  # padding bits zero too
    with pytest.raises(IndexError):
        row_range(bits, 10, 301)


def test_identical_rows_group_as_a_dict_of_row_bytes() -> None:
    rng = np.random.default_rng(4)
    # few distinct rows, many repeats: real groups
    base = (rng.random((9, 130)) < 0.3).astype(np.float32)
    csr = sp.csr_matrix(base[rng.integers(0, 9, 400)])
    bits = bits_from_csr(csr)
    rows = np.sort(rng.choice(400, 250, replace=False)).astype(np.int64)
    ref: dict[bytes, int] = {}
    want = [ref.setdefault(csr.indices[csr.indptr[r]:csr.indptr[r + 1]].tobytes(), len(ref)) for r in rows]
    for workers in (1, 2):
        groups, n_groups = identical_rows(bits, rows, workers=workers)
        assert n_groups == len(ref) and groups.tolist() == want
    assert identical_rows(bits, np.zeros(0, dtype=np.int64))[1] == 0


@pytest.mark.parametrize("m, n, s", [(40, 9, 5), (130, 12, 3), (64, 5, 4)])
def test_merged_rows_equal_the_csr_merge(m: int, n: int, s: int) -> None:
    rng = np.random.default_rng(m * n * s)
    # rows drawn from a few patterns, so that merging happens; some empty, some of weight 0
    pats = (rng.random((6, n)) < 0.4).astype(np.float32)
    pats[0] = 0
    stacked = sp.csr_matrix(pats[rng.integers(0, 6, s * m)])
    bits = bits_from_csr(stacked)
    w = np.where(rng.random(m) < 0.15, 0.0, rng.random(m))
    ref = _csr_merged_blocks(stacked, w, s)
    count = bits.row_counts()
    reps, wsums, nnzs = [], [], []
    for sc in range(s):
        rep, wsum, nnz = _scenario_groups(row_range(bits, sc * m, (sc + 1) * m), w, count[sc * m:(sc + 1) * m])
        reps.append(rep)
        wsums.append(wsum)
        nnzs.append(nnz)
    blocks = _merged_csr(bits, m, reps, nnzs)
    for (rb, rw), got, gw, nnz in zip(ref, blocks, wsums, nnzs, strict=True):
        assert gw.tobytes() == rw.tobytes()
        assert nnz == rb.nnz and got.shape == rb.shape
        np.testing.assert_array_equal(got.indptr, rb.indptr)
        np.testing.assert_array_equal(got.indices, rb.indices)
    assert sum(b.shape[0] for b, _ in ref) < int(sum((np.tile(w, s) > 0) & (count > 0)))  # something merged


@pytest.mark.parametrize("mode, fixed, banned, conflicts", [
    ("maxcover", set(), (), ()), ("multiview", set(), (), ()), ("maxcover", {1}, (5, 7), ((2, 9), (0, 3))),
    ("multiview", {0}, (8,), ((1, 4),)),
])
def test_swap_search_equals_the_csr_swap_search(mode, fixed, banned, conflicts, monkeypatch) -> None:
    rng = np.random.default_rng(len(mode) + len(fixed) + 3 * len(banned))
    m, n, s = 23, 14, 10
    stacked = _stacked(rng, m, n, s, 0.25)
    w = rng.uniform(0.1, 1.0, m)
    ban = np.zeros(n, dtype=bool)
    ban[list(banned)] = True
    cf = np.asarray(conflicts, dtype=np.int64).reshape(-1, 2)
    start = (0, 1, 2)
    ref = _csr_swap_search(stacked, w, s, start, mode=mode, views=2, fixed=fixed, banned=ban, conflicts=cf)
    bits = bits_from_csr(stacked)
    with monkeypatch.context() as mp:
        _no_csr(mp)
        got = []
        for threads in sorted({1, min(2, allowed_cores())}):
            with using_threads(threads):
                got.append(_swap_search(bits, w, s, start, mode=mode, views=2, fixed=fixed, banned=ban, conflicts=cf,
                                        deadline=None))
    for g in got:
        assert g == ref
    assert ref[2] > 0  # swaps were made: the search was exercised


# ---------------------------------------------------------------------------------------------------
# the whole solve

def _enumerate(stacked, w, s, k, mode):
    n = stacked.shape[1]
    return max(order_p10(scenario_values(stacked, w, s, c, mode=mode, views=2)) for c in itertools.combinations(range(n), k))


@pytest.mark.parametrize("mode, k", [("maxcover", 2), ("maxcover", 3), ("multiview", 3)])
def test_p10_on_bits_is_the_enumerated_optimum_without_a_csr(mode: str, k: int, monkeypatch) -> None:
    rng = np.random.default_rng(k + len(mode))
    m, n, s = 14, 9, 10
    stacked = _stacked(rng, m, n, s, 0.25)
    w = rng.uniform(0.1, 1.0, m)
    bits = bits_from_csr(stacked)
    best = _enumerate(stacked, w, s, k, mode)
    results = []
    with monkeypatch.context() as mp:
        _no_csr(mp)
        for threads in sorted({1, min(2, allowed_cores())}):
            opts = SolveOptions(mode=mode, k=k, views=2, time_limit_s=60, threads=threads)
            results.append(solve_p10(bits, w, s, opts, incumbents=[tuple(range(k))]))
    ref = solve_p10(stacked, w, s, SolveOptions(mode=mode, k=k, views=2, time_limit_s=60), incumbents=[tuple(range(k))])
    merged = _csr_merged_blocks(stacked, w, s)
    for res in results:
        assert isinstance(res.stats["model"], dict)  # the model was built from the merged rows (not skipped)
        assert res.status == "optimal"
        assert res.objective == pytest.approx(best, rel=1e-12)
        assert res.bound >= best - 1e-12
        assert order_p10(scenario_values(stacked, w, s, res.selected, mode=mode, views=2)) == res.objective
        assert res.stats["model_nonzeros"] == sum(b.nnz for b, _ in merged)
        assert (res.selected, res.objective, res.bound) == (ref.selected, ref.objective, ref.bound)
        assert res.stats["values"] == results[0].stats["values"]


def test_p10_without_the_model_keeps_the_bounds_on_bits() -> None:
    """Model size limit 0: the per-scenario bounds (each scenario's own solve on its row slice of
    the bits) are the enumerated per-scenario optima."""
    rng = np.random.default_rng(5)
    m, n, s, k = 10, 8, 10, 2
    stacked = _stacked(rng, m, n, s, 0.3)
    w = rng.uniform(0.1, 1.0, m)
    old = p10mod.P10_MODEL_MAX_NNZ
    p10mod.P10_MODEL_MAX_NNZ = 0
    try:
        res = solve_p10(bits_from_csr(stacked), w, s, SolveOptions(k=k), incumbents=[(0, 1)])
    finally:
        p10mod.P10_MODEL_MAX_NNZ = old
    per_s = [max(scenario_values(stacked, w, s, c)[i] for c in itertools.combinations(range(n), k)) for i in range(s)]
    assert res.stats["bound_per_scenario"] == pytest.approx(sorted(per_s)[::-1][8], rel=1e-12)
    assert res.objective <= _enumerate(stacked, w, s, k, "maxcover") + 1e-12 <= res.bound + 2e-12


def test_p10_over_the_budget_is_one_line() -> None:
    rng = np.random.default_rng(2)
    m, n, s = 30, 5, 3
    bits = bits_from_csr(_stacked(rng, m, n, s, 0.5))
    need = p10mod.p10_bytes(m, n, s)
    with pytest.raises(CamplaceError, match="p10 objective's working arrays"):
        solve_p10(bits, rng.random(m), s, SolveOptions(k=2, memory_budget_bytes=need - 1))
    with pytest.raises(CamplaceError, match="expected 4 x 30"):
        solve_p10(bits, rng.random(m), 4, SolveOptions(k=2))
