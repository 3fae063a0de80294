"""The general model's cases on column bitsets (issue 32): a minimum distance, engine mip / cpsat
for multiview, multiview with fixed cameras and no angle. Their CSR is made only of the rows the
bit presolve leaves (dead rows dropped, identical rows merged with their weights summed, every
column kept: no dominance), never of the whole matrix; the answer (objective, status, bound) is the
CSR route's and the enumerated optimum, and the same at 1 and 2 threads."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.solver.api as api
from camplace.solver.api import solve
from camplace.solver.options import SolveOptions
from camplace.solver.problem.objectives import mode_value
from camplace.visibility.bits import bits_from_csr
from tests.solver._oracle import brute_force_mode
from tests.solver.test_large_k_bits import watch_tocsr


@pytest.fixture(autouse=True)
def _spaced_route_only(monkeypatch):
    """These tests are of the spaced route itself: the relaxation first (api._relaxed_first, a
    proven spaced optimum returned before it) is tested in tests/solver/test_spacing_relaxed.py."""
    monkeypatch.setattr(api, "_relaxation_applies", lambda o: False)


def _cases(seed: int):
    """(dense (m, n) float32, weights (m,), camera positions (n, 3) m): duplicated rows to merge,
    zero weights (dead rows), a row no camera observes, equal weights once."""
    rng = np.random.default_rng(seed)
    for t, (m, n, dens) in enumerate([(70, 9, 0.3), (130, 10, 0.15), (64, 8, 0.45)]):
        dense = (rng.random((m, n)) < dens).astype(np.float32)
        dense[m // 2:m // 2 + 6] = dense[1]
        dense[3] = 0.0
        w = np.full(m, 0.5) if t == 2 else np.where(rng.random(m) < 0.2, 0.0, rng.random(m))
        yield dense, w, rng.random((n, 3)) * 10.0


_KWS = [
    dict(mode="maxcover", k=3, min_distance_m=3.0),
    dict(mode="maxcover", k=2, min_distance_m=3.0, fixed=(1,), forbidden=(4,)),
    dict(mode="quality", k=2, min_distance_m=4.0, fixed=(0,)),
    dict(mode="multiview", views=2, k=3, min_distance_m=3.0),
    dict(mode="multiview", views=2, k=3, engine="mip"),
    dict(mode="multiview", views=2, k=3, engine="cpsat"),
    dict(mode="multiview", views=2, k=2, fixed=(0,)),
    dict(mode="multiview", views=3, k=2, fixed=(0, 2), forbidden=(5,)),
]


@pytest.mark.parametrize("kw", _KWS)
def test_general_model_on_presolved_rows_equals_csr_and_enumeration(kw, monkeypatch) -> None:
    for dense, w, pos in _cases(len(str(kw))):
        ref = solve(sp.csr_matrix(dense), w, positions=pos, **kw)
        bits = bits_from_csr(sp.csr_matrix(dense))
        with monkeypatch.context() as mp:
            shapes = watch_tocsr(mp, bits)
            got = solve(bits, w, positions=pos, **kw)
        rows = got.stats["rows_presolve"]["rows_after"]
        assert got.stats["matrix"] == f"column bitsets, rows presolved to {rows} x {dense.shape[1]} (that as CSR)"
        assert shapes == [(rows, dense.shape[1])] and rows < dense.shape[0]  # the merged rows only
        assert (got.status, got.objective, got.bound, got.gap) == (ref.status, ref.objective, ref.bound, ref.gap)
        assert got.status == "optimal"
        assert got.stats["rows_in"] == dense.shape[0] and got.stats["cols_in"] == dense.shape[1]
        assert got.stats["fixed"] == list(kw.get("fixed", ())) and got.stats["forbidden"] == list(kw.get("forbidden", ()))
        views = kw.get("views", 2)
        best = brute_force_mode(dense, w, kw["k"], kw["mode"], views=views, pos=pos, fixed=kw.get("fixed", ()),
                                forbidden=kw.get("forbidden", ()), dmin=kw.get("min_distance_m"))
        assert got.objective == pytest.approx(best, rel=1e-12, abs=1e-12)
        assert got.objective == mode_value(dense, w, got.selected, mode=kw["mode"], views=views)


def test_presolve_over_the_budget_converts_the_whole_matrix(monkeypatch) -> None:
    """The rows' presolve over the memory budget: the whole matrix's CSR as before, the CSR route's answer."""
    dense, w, pos = next(_cases(1))
    kw = dict(mode="maxcover", k=3, min_distance_m=3.0)
    with monkeypatch.context() as mp:
        mp.setattr(api, "memory_budget_bytes", lambda: 64)  # (the spacing's pairs too: the greedy answer)
        ref = solve(sp.csr_matrix(dense), w, positions=pos, **kw)
        got = solve(bits_from_csr(sp.csr_matrix(dense)), w, positions=pos, **kw)
    assert "matrix" not in got.stats and "memory_fallback" in got.stats
    assert (got.selected, got.status, got.objective, got.bound) == (ref.selected, ref.status, ref.objective, ref.bound)


def test_no_live_row_converts_the_whole_matrix() -> None:
    """Every weight 0: nothing to merge, the whole matrix's CSR as before (the CSR route's answer)."""
    dense, _, pos = next(_cases(2))
    w = np.zeros(dense.shape[0])
    kw = dict(mode="multiview", k=2, fixed=(1,))
    ref = solve(sp.csr_matrix(dense), w, positions=pos, **kw)
    got = solve(bits_from_csr(sp.csr_matrix(dense)), w, positions=pos, **kw)
    assert "matrix" not in got.stats
    assert (got.status, got.objective, got.bound) == (ref.status, ref.objective, ref.bound)


@pytest.mark.parametrize("kw", [dict(mode="maxcover", k=5), dict(mode="multiview", views=2, k=6),
                                dict(mode="multiview", views=2, k=2, fixed=(3,)),
                                dict(mode="maxcover", k=3, min_distance_m=3.0)])
def test_bits_routes_same_at_one_and_two_threads(kw) -> None:
    """The presolved routes (large k, the merged rows) give the same answer at 1 and 2 threads."""
    dense, w, pos = next(_cases(4))
    bits = bits_from_csr(sp.csr_matrix(dense))
    one, two = (solve(bits, w, positions=pos, options=SolveOptions(**kw, threads=t)) for t in (1, 2))
    assert one.stats["matrix"].startswith("column bitsets, ")
    assert (one.selected, one.status, one.objective, one.bound) == (two.selected, two.status, two.objective, two.bound)
