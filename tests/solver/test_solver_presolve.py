"""Presolve: exact reductions, index maps, and optimum preservation."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings

from camplace.solver import coverage_weight, presolve
from tests.solver._oracle import brute_force, small_instances, tolerance

# The package exports the function ``presolve``, which shadows the submodule attribute.
presolve_mod = importlib.import_module("camplace.solver.problem.presolve")


def _m(rows: list[list[float]]) -> sp.csr_matrix:
    return sp.csr_matrix(np.array(rows, dtype=np.float64))


def test_dominance_identical_and_subset_columns() -> None:
    # cols: 0 subset of 1; 2 == 3 (keep 2); 4 empty; 5 independent
    a = _m(
        [
            [1, 1, 0, 0, 0, 0],
            [0, 1, 0.5, 0.2, 0, 0],
            [0, 0, 1, 1, 0, 1],
            [0, 0, 0, 0, 0, 1],
        ]
    )
    pre = presolve(a, np.ones(4), 2)
    assert pre.columns.tolist() == [1, 2, 5]
    assert pre.stats["cols_dominated"] == 3
    assert pre.k == 2
    assert pre.shape_in == (4, 6)


def test_never_fewer_than_k_columns_restores_best_dropped() -> None:
    # All columns are subsets of column 0; with k=3 the two best dropped ones come back.
    a = _m([[1, 1, 0, 1], [1, 1, 1, 0], [1, 0, 0, 0], [1, 0, 0, 1]])
    w = np.array([1.0, 1.0, 1.0, 5.0])
    pre = presolve(a, w, 3)
    assert pre.stats["cols_restored"] == 2
    assert pre.columns.tolist() == [0, 1, 3]  # col 3 covers 6.0, col 1 covers 2.0, col 2 covers 1.0
    assert pre.shape[1] == 3


def test_rows_dropped_and_merged_with_summed_weights() -> None:
    a = _m([[1, 0, 1], [0, 0, 0], [1, 0, 1], [0, 1, 0], [1, 0, 1]])
    w = np.array([0.5, 9.0, 0.25, 0.0, 1.0])
    pre = presolve(a, w, 1, dominance=False)
    # row 1 has no observer, row 3 has zero weight; rows 0, 2, 4 are identical.
    assert pre.shape == (1, 3)
    assert pre.weights.tolist() == [1.75]
    assert pre.counts.tolist() == [3]
    assert pre.row_groups.tolist() == [0, -1, 0, -1, 0]
    assert pre.weight_unit is None


def test_weight_unit_for_equal_weights() -> None:
    a = _m([[1, 0], [1, 0], [0, 1]])
    pre = presolve(a, np.full(3, 0.1), 1, dominance=False)
    assert pre.weight_unit == pytest.approx(0.1)
    np.testing.assert_allclose(pre.weights, pre.counts * 0.1)


def test_original_and_reduced_columns_maps() -> None:
    a = _m([[1, 1, 0, 0], [0, 1, 0, 1], [0, 0, 1, 1], [0, 0, 1, 0]])
    pre = presolve(a, np.ones(4), 2)
    assert pre.columns.tolist() == [1, 2, 3]
    assert pre.original_columns([2, 0]) == (1, 3)
    assert pre.reduced_columns([3, 1]) == (0, 2)
    assert pre.reduced_columns([0, 1]) is None


@pytest.mark.parametrize("mode", ["sparse", "dense", "dense_chunked", "bitsets"])
def test_gram_paths_agree(mode: str) -> None:
    rng = np.random.default_rng(5)
    base = (rng.random((300, 40)) < 0.3).astype(float)
    dup = base[:, :20].copy()
    dup[rng.integers(0, 300, 20), np.arange(20)] = 1.0  # supersets of the first 20 columns
    a = sp.csr_matrix(np.column_stack([base, dup, base[:, :5]]))
    mp = pytest.MonkeyPatch()
    if mode == "sparse":
        mp.setattr(presolve_mod, "_SPARSE_SPEEDUP", 1e-12)
    else:
        mp.setattr(presolve_mod, "_SPARSE_SPEEDUP", 1e12)
    if mode == "dense_chunked":
        mp.setattr(presolve_mod, "_DENSE_BYTES", 4 * 65 * 7)  # 7-row chunks
    try:
        if mode == "bitsets":
            rows = np.arange(a.shape[0], dtype=np.int64)
            dominated = presolve_mod.dominated_bitsets(a, rows, np.diff(a.indptr).astype(np.int64))
        else:
            dominated = presolve_mod._dominated_columns(presolve_mod.as_pattern(a))
    finally:
        mp.undo()
    # Reference: explicit set comparisons.
    sets = [frozenset(np.flatnonzero(a[:, j].toarray().ravel())) for j in range(a.shape[1])]
    ref = np.array(
        [
            any(sets[i] <= sets[j] and (len(sets[j]) > len(sets[i]) or j < i) for j in range(len(sets)) if j != i)
            for i in range(len(sets))
        ]
    )
    np.testing.assert_array_equal(dominated, ref)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_instances(max_n=20))
def test_presolve_preserves_optimum_and_maps_back(inst) -> None:
    matrix, weights, k = inst
    best, _ = brute_force(matrix, weights, k)
    pre = presolve(matrix, weights, k)
    m2, n2 = pre.shape
    assert n2 >= k
    assert np.all(np.diff(pre.columns) > 0)
    # Merged weights add up to the coverable weight of the original instance.
    coverable = coverage_weight(matrix, weights, range(matrix.shape[1]))
    assert float(pre.weights.sum()) == pytest.approx(coverable, rel=1e-12, abs=1e-15)
    if m2 == 0:
        assert best == 0.0
        return
    best2, sets2 = brute_force(pre.matrix, pre.weights, k)
    assert abs(best2 - best) <= tolerance(weights)
    for s in sets2[:10]:
        orig = pre.original_columns(s)
        assert len(orig) == k
        assert abs(coverage_weight(matrix, weights, orig) - best) <= tolerance(weights)
    # row_groups: each kept original row maps to a reduced row with the same observers.
    a = matrix.tocsr()
    for i in np.flatnonzero(pre.row_groups >= 0)[:20]:
        obs = set(a.indices[a.indptr[i] : a.indptr[i + 1]][a.data[a.indptr[i] : a.indptr[i + 1]] > 0].tolist())
        red = pre.matrix.indices[pre.matrix.indptr[pre.row_groups[i]] : pre.matrix.indptr[pre.row_groups[i] + 1]]
        assert {int(pre.columns[j]) for j in red} == obs & set(pre.columns.tolist())


def test_row_merge_survives_hash_collisions() -> None:
    """Every row in one hash bucket: grouping must still come from exact comparison."""
    from camplace.solver._support import bitkernels as bk

    rng = np.random.default_rng(11)
    base = (rng.random((6, 9)) < 0.4).astype(float)
    dense = base[rng.integers(0, 6, size=40)]
    a = sp.csr_matrix(dense)
    rows = np.arange(40, dtype=np.int64)
    col_map = np.arange(9, dtype=np.int64)
    groups, n_groups = bk.group_rows(a.indptr, a.indices, a.data, rows, col_map, np.zeros(40, dtype=np.uint64))
    keys = [dense[i].tobytes() for i in range(40)]
    ref = {key: g for g, key in enumerate(dict.fromkeys(keys))}
    assert n_groups == len(ref)
    assert groups.tolist() == [ref[key] for key in keys]
