"""The bitset engine's search for views > 1 on the plain layout (best-first roots, depth-first
below, the node with the loosest union split first): every column set lies in exactly one branch,
the answer equals enumeration (views 2-3, k 5-6), and an interrupted search keeps a valid bound."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camplace.solver._support import bitkernels as K
from camplace.solver.engines.bitset import search as bitset_mod
from camplace.solver.engines.bitset.search import solve_bitset
from camplace.solver.problem._synthetic import structured_instance
from camplace.solver.problem.presolve import presolve
from tests.solver._oracle import CountingDeadline, tolerance

_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _best(dense: np.ndarray, w: np.ndarray, k: int, views: int) -> float:
    """Enumeration: the best weight of rows seen by >= views of k columns."""
    combos = np.array(list(itertools.combinations(range(dense.shape[1]), k)), dtype=np.int64)
    return float((w @ (dense[:, combos].sum(axis=2) >= views)).max())


def _value(dense: np.ndarray, w: np.ndarray, sel, views: int) -> float:
    return float(w[dense[:, list(sel)].sum(axis=1) >= views].sum())


@settings(max_examples=60, **_SETTINGS)
@given(n=st.integers(1, 12), k=st.integers(1, 5), seed=st.integers(0, 2**31 - 1))
def test_split_by_score_reaches_every_set_once(n: int, k: int, seed: int) -> None:
    """Splitting any node (random scores) from the root tuple down to leaves lists every k-subset
    of the n columns exactly once (the search misses no set and repeats none)."""
    k = min(k, n)
    lo, hi, left, right = K.tree_shape(n)
    score = np.random.default_rng(seed).uniform(-1.0, 1.0, lo.shape[0])
    found: list[tuple[int, ...]] = []
    todo = [np.zeros(k, dtype=np.int64)]
    out = np.empty((k + 1, k), dtype=np.int64)
    while todo:
        cur = todo.pop()
        n_kids = K.split_tuple_by(cur, score, lo, hi, left, right, out)
        if n_kids == 0:
            assert K.all_leaves(cur, lo, hi)
            found.append(tuple(sorted(int(lo[x]) for x in cur)))
            continue
        for q in range(n_kids):
            child = out[q].copy()
            assert np.all(np.diff(child) >= 0), "children are sorted (equal nodes adjacent)"
            todo.append(child)
    assert sorted(found) == list(itertools.combinations(range(n), k))


@st.composite
def _instances(draw: st.DrawFn):
    n = draw(st.integers(7, 13))
    m = draw(st.integers(1, 40))
    views = draw(st.integers(2, 3))
    k = draw(st.integers(5, 6))
    density = draw(st.sampled_from([0.3, 0.5, 0.7, 0.9]))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    dense = rng.random((m, n)) < density
    for _ in range(draw(st.integers(0, 3))):  # duplicate and nested cameras
        a, b = rng.integers(n, size=2)
        dense[:, a] = dense[:, b] if rng.random() < 0.5 else dense[:, a] & dense[:, b]
    equal = draw(st.booleans())
    w = np.full(m, 0.25) if equal else rng.uniform(0.0, 1.0, m)
    return dense, w, k, views


@settings(max_examples=60, **_SETTINGS)
@given(inst=_instances(), budget=st.integers(1, 40))
def test_views_search_equals_enumeration(inst, budget: int) -> None:
    """Proven optimum = enumeration, with depth-first slices of a few bound evaluations each."""
    dense, w, k, views = inst
    pre = presolve(sp.csr_matrix(dense.astype(np.float64)), w, k, dominance=False)
    mp = pytest.MonkeyPatch()
    mp.setattr(bitset_mod, "_ROOT_BUDGET", budget)
    try:
        out = solve_bitset(pre, views=views)
    finally:
        mp.undo()
    best = _best(dense, w, k, views)
    sel = pre.original_columns(out.selected)
    assert out.status == "optimal"
    assert len(sel) == k == len(set(sel))
    assert abs(_value(dense, w, sel, views) - best) <= tolerance(w)
    assert abs(out.bound - best) <= tolerance(w)
    if "search" in out.stats and k >= 2 * views:  # no opposite-pairs layout: the search under test ran
        assert out.stats["search"] == "best-first roots, depth-first below"


@settings(max_examples=40, **_SETTINGS)
@given(inst=_instances(), after=st.integers(0, 12), budget=st.integers(1, 5))
def test_views_search_interrupted_keeps_a_valid_bound(inst, after: int, budget: int) -> None:
    dense, w, k, views = inst
    pre = presolve(sp.csr_matrix(dense.astype(np.float64)), w, k, dominance=False)
    mp = pytest.MonkeyPatch()
    mp.setattr(bitset_mod, "_ROOT_BUDGET", budget)
    try:
        out = solve_bitset(pre, views=views, deadline=CountingDeadline(after))
    finally:
        mp.undo()
    best = _best(dense, w, k, views)
    sel = pre.original_columns(out.selected)
    assert len(sel) == k == len(set(sel))
    assert _value(dense, w, sel, views) <= best + tolerance(w)
    assert out.bound >= best - tolerance(w), "the bound must stay valid when interrupted"
    if out.status == "optimal":
        assert abs(_value(dense, w, sel, views) - best) <= tolerance(w)


@pytest.mark.parametrize("after", [0, 1, 2, 4, 8, 30])
@pytest.mark.parametrize("views,k", [(3, 6), (2, 5)])
def test_views_search_structured(after: int, views: int, k: int, monkeypatch) -> None:
    """A structured (bilobed target, corridor) instance: the bound stays above the enumerated
    optimum at any interruption, and the uninterrupted search proves it."""
    matrix, w = structured_instance(300, 16, seed=5, shape="bilobed", corridor=True, fov_deg=70.0)
    dense = matrix.toarray() > 0
    best = _best(dense, w, k, views)
    pre = presolve(matrix, w, k, dominance=False)
    monkeypatch.setattr(bitset_mod, "_ROOT_BUDGET", 3)
    out = solve_bitset(pre, views=views, deadline=CountingDeadline(after))
    assert out.bound >= best - tolerance(w)
    assert _value(dense, w, pre.original_columns(out.selected), views) <= best + tolerance(w)
    out = solve_bitset(pre, views=views)
    assert out.status == "optimal" and abs(out.bound - best) <= tolerance(w)
    assert abs(_value(dense, w, pre.original_columns(out.selected), views) - best) <= tolerance(w)
