"""The bit presolve gives the CSR presolve's reduced instance (an oracle), at 1 and 2 threads."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.solver.problem.presolve import presolve
from camplace.solver.problem.presolve_bits import covered_weight, presolve_bits
from camplace.visibility.bits import bits_from_csr


def _cases():
    rng = np.random.default_rng(7)
    for m, n, dens, k in [(1, 3, 0.5, 1), (70, 9, 0.3, 2), (130, 40, 0.2, 3), (300, 64, 0.05, 3), (200, 65, 0.6, 4),
                          (64, 12, 0.0, 2), (90, 30, 0.9, 3)]:
        a = (rng.random((m, n)) < dens).astype(np.float32)
        a[: m // 3] = a[m // 3: 2 * (m // 3)]  # identical rows to merge
        if n > 4:
            a[:, 1] = a[:, 0] * (rng.random(m) < 0.5)  # a dominated column
            a[:, 3] = a[:, 2]  # identical columns
            a[:, 4] = 0.0  # an empty column
        w = rng.random(m)
        w[::5] = 0.0
        if m % 2:
            w[:] = 2.5  # one unit weight
        yield sp.csr_matrix(a), w, k
    col = (rng.random((40, 1)) < 0.5).astype(np.float32)
    nested = np.hstack([col * (rng.random((40, 1)) < 0.7) for _ in range(5)] + [col])
    yield sp.csr_matrix(nested), rng.random(40), 4  # dominated columns restored to reach k


@pytest.mark.parametrize("dominance", [True, False])
def test_presolve_bits_equals_csr(dominance: bool) -> None:
    for a, w, k in _cases():
        ref = presolve(a, w, k, dominance=dominance)
        bits = bits_from_csr(a)
        for workers in (1, 2):
            got = presolve_bits(bits, w, k, dominance=dominance, workers=workers)
            np.testing.assert_array_equal(got.columns, ref.columns)
            np.testing.assert_array_equal(got.row_groups, ref.row_groups)
            np.testing.assert_array_equal(got.counts, ref.counts)
            assert got.weights.tobytes() == ref.weights.tobytes()
            assert got.weight_unit == ref.weight_unit
            np.testing.assert_array_equal(got.bits, ref.bits)
            assert (got.matrix != ref.matrix).nnz == 0


def test_covered_weight_is_mode_value() -> None:
    from camplace.solver.problem.objectives import mode_value

    for a, w, k in _cases():
        bits = bits_from_csr(a)
        for sel in ([0], list(range(min(3, a.shape[1])))):
            assert covered_weight(bits, w, sel) == mode_value(a, w, sel, mode="maxcover")


@pytest.mark.parametrize("k", [1, 2, 3])
def test_solve_on_bits_equals_csr_and_enumeration(k: int) -> None:
    from itertools import combinations

    from camplace.solver.api import solve
    from camplace.solver.problem.objectives import mode_value

    rng = np.random.default_rng(k)
    a = sp.csr_matrix((rng.random((150, 14)) < 0.2).astype(np.float32))
    w = rng.random(150)
    ref = solve(a, w, k=k)
    got = solve(bits_from_csr(a), w, k=k)
    best = max(mode_value(a, w, list(c), mode="maxcover") for c in combinations(range(14), k))
    assert got.status == "optimal" and got.objective == ref.objective
    assert got.objective == pytest.approx(best, rel=1e-12)
    assert got.selected == ref.selected
    assert got.stats["presolve"]["layout"] == "column bitsets"
    # a case the bit route does not take goes through the CSR conversion
    fixed = solve(bits_from_csr(a), w, k=k, fixed=[0])
    assert fixed.selected == solve(a, w, k=k, fixed=[0]).selected


def test_quality_of_bits_is_maxcover_and_equals_the_csr_quality_route() -> None:
    from camplace.solver.api import solve

    rng = np.random.default_rng(11)
    a = sp.csr_matrix((rng.random((120, 12)) < 0.25).astype(np.float32))
    w = rng.random(120)
    ref = solve(a, w, k=3, mode="quality")
    got = solve(bits_from_csr(a), w, k=3, mode="quality")
    assert got.status == ref.status == "optimal"
    assert got.objective == pytest.approx(ref.objective, rel=1e-12, abs=1e-12)
    assert got.stats["mode"] == "quality" and "binary_matrix" in got.stats


def test_dominance_stopped_by_the_deadline_keeps_the_optimum() -> None:
    """An expired deadline stops the dominance between rounds: the columns found dominated so far
    (none here) are dropped, the rest kept, and the reduced instance still holds the optimum
    (checked by enumeration); rows are merged as before."""
    from itertools import combinations

    from camplace.solver._support.deadline import Deadline
    from camplace.solver.engines.bitset.search import solve_bitset
    from camplace.solver.problem.objectives import mode_value

    rng = np.random.default_rng(4)
    a = (rng.random((200, 16)) < 0.2).astype(np.float32)
    a[:, 1] = a[:, 0] * (rng.random(200) < 0.5)  # dominated by column 0
    a[:50] = a[50:100]  # identical rows
    a = sp.csr_matrix(a)
    w = rng.random(200)
    full = presolve_bits(bits_from_csr(a), w, 3)
    cut = presolve_bits(bits_from_csr(a), w, 3, deadline=Deadline(0.0))
    assert "dominance_stopped" not in full.stats and full.stats["cols_dominated"] >= 1
    assert "dominance_stopped" in cut.stats and cut.stats["cols_dominated"] == 0
    assert cut.shape[1] == 16 and cut.shape[0] == full.shape[0]  # no column dropped; the same row groups
    best = max(mode_value(a, w, list(c), mode="maxcover") for c in combinations(range(16), 3))
    for pre in (full, cut):
        out = solve_bitset(pre)
        sel = list(pre.original_columns(out.selected))
        assert out.status == "optimal"
        assert mode_value(a, w, sel, mode="maxcover") == pytest.approx(best, rel=1e-12)


def test_rarest_row_with_tiers_equals_numpy() -> None:
    """Each column's rarest live row (fewest observing columns, first index on ties), read through the
    rarity tiers, against a numpy oracle over rows of widely spread counts (so that every tier, and
    the fall-back to all live rows, is used)."""
    from camplace.solver.problem import presolve_bits as pb

    rng = np.random.default_rng(11)
    m, n = 3000, 150
    dens = np.linspace(0.0, 0.7, m)[:, None]  # rare rows first, common rows last
    a = rng.random((m, n)) < dens
    a[:, 7] = False  # an empty column
    a[: m // 4, 9] = False
    a[: m // 2, 9] = False  # a column observing common rows only (no tier met)
    live_mask = rng.random(m) < 0.9
    bits = bits_from_csr(sp.csr_matrix(a.astype(np.float32)))
    nw = bits.words.shape[1]
    live = pb._pack(live_mask, nw)
    row_nnz = a.sum(axis=1).astype(np.int64)
    tiers = pb._rarity_tiers(np.flatnonzero(live_mask).astype(np.int64), row_nnz, nw)
    assert tiers.shape[0] == 3
    got = np.zeros(n, dtype=np.int64)
    size = np.full(n, -1, dtype=np.int64)
    pb._rarest(bits.words, live, tiers, row_nnz, 0, n, got, size)
    np.testing.assert_array_equal(size, (a & live_mask[:, None]).sum(axis=0))
    want = np.full(n, -1, dtype=np.int64)
    for j in range(n):
        rows = np.flatnonzero(a[:, j] & live_mask)
        if rows.size:
            want[j] = rows[np.argmin(row_nnz[rows])]  # argmin: the first of the smallest
    np.testing.assert_array_equal(got, want)
    assert want[7] == -1 and want[9] >= m // 2


def test_presolve_bits_on_arrays_faulted_in_by_the_workers(monkeypatch) -> None:
    """Every working array as an anonymous mapping whose pages the block workers fault in (the path
    of large matrices, forced here on small ones): the same reduced instance as the CSR presolve."""
    from camplace.visibility import store

    monkeypatch.setattr(store, "_POPULATE_MIN_BYTES", 0)
    for a, w, k in _cases():
        ref = presolve(a, w, k)
        for workers in (1, 2):
            got = presolve_bits(bits_from_csr(a), w, k, workers=workers)
            np.testing.assert_array_equal(got.columns, ref.columns)
            np.testing.assert_array_equal(got.row_groups, ref.row_groups)
            np.testing.assert_array_equal(got.bits, ref.bits)


def test_hash_buckets_are_one_stable_sort_at_every_thread_count() -> None:
    """The hashes split by their top bits and sorted part by part on the pool give numpy's stable
    argsort and its runs of equal hashes: uniform hashes, many repeats, every hash in one part
    (small values), one part much heavier than the rest, and none."""
    from camplace.solver.problem import presolve_bits as pb

    rng = np.random.default_rng(11)
    uniform = rng.integers(0, 2**64 - 1, size=5000, dtype=np.uint64)
    cases = [uniform, uniform[rng.integers(0, 300, size=5000)], uniform % np.uint64(7),
             np.concatenate([uniform[:100], (uniform[100:] >> np.uint64(8)) | np.uint64(3 << 58)]),
             np.zeros(0, dtype=np.uint64)]
    for h in cases:
        want = np.argsort(h, kind="stable")
        cut = np.flatnonzero(np.diff(h[want]) != 0) + 1
        want_starts = np.concatenate([[0], cut, [h.size]]) if h.size else np.zeros(1, dtype=np.int64)
        for workers in (1, 2, 3):
            order, starts = pb._hash_buckets(h, workers)
            assert order.tolist() == want.tolist() and starts.tolist() == want_starts.tolist()


@pytest.mark.parametrize("collide", [False, True])
def test_grouped_rows_equal_a_dict_of_row_bytes_at_every_thread_count(collide: bool) -> None:
    """The parallel grouping of identical rows: the groups a dict of the rows' bytes gives
    (numbered by first occurrence), with real hashes and with every row in three hash buckets
    (exact comparison decides), at 1, 2 and 3 workers."""
    from camplace.solver.problem import presolve_bits as pb

    rng = np.random.default_rng(5)
    base = rng.integers(0, 2**63, size=(40, 5), dtype=np.uint64)
    rb = base[rng.integers(0, 40, size=900)]
    rb[rng.random(900) < 0.1, 2] ^= np.uint64(1)  # near-duplicates: one bit apart
    idx = np.sort(rng.choice(900, size=700, replace=False)).astype(np.int64)
    h = np.zeros(900, dtype=np.uint64)
    has = np.zeros(900, dtype=bool)
    pb._hash_rows(rb, 0, 900, h, has)
    hs = h[idx] % np.uint64(3) if collide else h[idx]
    keys = [rb[i].tobytes() for i in idx]
    ref = {key: g for g, key in enumerate(dict.fromkeys(keys))}
    want = [ref[key] for key in keys]
    assert 40 < len(ref) < 700
    for workers in (1, 2, 3):
        groups, n_groups = pb._grouped_rows(rb, idx, hs, workers)
        assert n_groups == len(ref) and groups.tolist() == want
