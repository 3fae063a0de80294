"""Multiview with a minimum angle and a minimum distance when the general model does not fit
(routes._angle_spaced): the angle engine on the problem without the spacing gives a valid bound
(and, when its proven answer is spaced, the spaced optimum); otherwise the answer is the best of
spaced answers with exact angles. Checked against the enumeration of every spaced set."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

import camplace.solver.engines.mip.linear as linear
import camplace.solver.routes as routes
from camplace.solver.api import solve
from camplace.solver.problem.objectives import mode_value
from camplace.visibility.bits import bits_from_csr
from tests.solver._oracle import brute_force_mode, spaced
from tests.solver.test_large_k_bits import watch_tocsr


def _case(seed: int):
    """(dense (m, n) float32 0/1, weights (m,), positions (n, 3) m, points (m, 3) m): cameras on a
    ring around the points, some of them close together (so that a minimum distance binds)."""
    rng = np.random.default_rng(seed)
    m, n = 40, 11
    ang = np.sort(rng.random(n)) * 2 * np.pi
    pos = np.column_stack([6 * np.cos(ang), 6 * np.sin(ang), rng.normal(size=n)])
    pts = rng.normal(size=(m, 3))
    dense = (rng.random((m, n)) < 0.5).astype(np.float32)
    w = rng.random(m) + 0.05
    return dense, w, pos, pts


def _refuse_model(mp) -> None:
    """Every general model over the memory budget (the angle engine still fits)."""
    mp.setattr(routes, "model_bytes", lambda *a, **k: 1 << 60)
    mp.setattr(linear, "model_bytes", lambda *a, **k: 1 << 60)


@pytest.mark.parametrize("layout", ["csr", "bits"])
@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("dmin", [1.0, 4.0, 7.0])
def test_spaced_angle_against_enumeration(layout, seed, dmin, monkeypatch) -> None:
    dense, w, pos, pts = _case(seed)
    fixed = (0,) if seed % 2 else ()
    k = 2 if fixed else 3
    kw = dict(k=k, mode="multiview", views=2, min_angle_deg=30.0, positions=pos, points=pts, min_distance_m=dmin,
              fixed=fixed, time_limit_s=60)
    best = brute_force_mode(dense, w, k, "multiview", views=2, min_angle_deg=30.0, pos=pos, pts=pts, fixed=fixed,
                            dmin=dmin)
    # the relaxation: new cameras spaced from the fixed ones (those columns are not free), not from each other
    near_fixed = tuple(j for j in range(pos.shape[0]) if j not in fixed
                       and any(np.linalg.norm(pos[j] - pos[f]) < dmin for f in fixed))
    relaxed = brute_force_mode(dense, w, k, "multiview", views=2, min_angle_deg=30.0, pos=pos, pts=pts, fixed=fixed,
                               forbidden=near_fixed)
    with monkeypatch.context() as mp:
        _refuse_model(mp)
        if layout == "bits":
            bits = bits_from_csr(sp.csr_matrix(dense))
            watch_tocsr(mp, bits)  # the whole matrix never becomes CSR
            got = solve(bits, w, **kw)
        else:
            got = solve(sp.csr_matrix(dense), w, **kw)
    if "spacing_relaxed" not in got.stats:  # no pair of free candidates closer: the angle engine itself
        assert got.stats.get("conflict_pairs", 0) == 0 and best == relaxed
        assert layout == "csr" or got.stats["matrix"].startswith("column bitsets")
        assert got.status == "optimal" and got.objective == pytest.approx(best, rel=1e-12)
        return
    info = got.stats["spacing_relaxed"]
    assert layout == "csr" or got.stats["matrix"] == "column bitsets (no CSR copy)"
    if best is None:  # no spaced set of k: no answer may be spaced
        assert got.selected is None or not spaced(got.selected, pos, dmin)
        return
    assert got.selected is not None and spaced(got.selected, pos, dmin) and set(fixed) <= set(got.selected)
    assert len(got.selected) == k + len(fixed)
    assert got.objective == pytest.approx(mode_value(dense, w, got.selected, mode="multiview", views=2,
                                                     min_angle_deg=30.0, positions=pos, points=pts), rel=1e-12)
    assert got.objective <= best * (1 + 1e-12)
    assert got.bound >= best * (1 - 1e-12)  # valid for the spaced problem
    assert info["bound"] == pytest.approx(relaxed, rel=1e-9) and info["status"] == "optimal"  # proven relaxation
    if info["spaced"]:  # the relaxed optimum is spaced: the spaced optimum, proven
        assert got.status == "optimal" and got.objective == pytest.approx(best, rel=1e-12)
        assert best == pytest.approx(relaxed, rel=1e-12)
    else:
        assert relaxed > best * (1 - 1e-12) and got.status == "feasible"
        assert got.bound == pytest.approx(relaxed, rel=1e-9)


def test_both_branches_are_taken(monkeypatch) -> None:
    """The cases above reach a spaced relaxed optimum and a repaired one (the test is not vacuous)."""
    seen = set()
    for seed, dmin in itertools.product([1, 2, 3, 4, 5], [1.0, 4.0, 7.0]):
        dense, w, pos, pts = _case(seed)
        with monkeypatch.context() as mp:
            _refuse_model(mp)
            got = solve(sp.csr_matrix(dense), w, k=3, mode="multiview", views=2, min_angle_deg=30.0, positions=pos,
                        points=pts, min_distance_m=dmin, time_limit_s=60)
        if "spacing_relaxed" in got.stats:
            seen.add(got.stats["spacing_relaxed"]["spaced"])
    assert seen == {True, False}


def test_spaced_greedy_keeps_the_spacing_and_the_start() -> None:
    dense, w, pos, pts = _case(7)
    from camplace.solver.api import _free_columns
    from camplace.solver.options import SolveOptions
    from camplace.solver._support.deadline import Deadline
    from camplace.solver.problem.checks import conflict_pairs

    dmin = 4.0
    conflicts = conflict_pairs(pos, dmin)
    free, conflicts = _free_columns(pos.shape[0], (), (), conflicts, dmin)
    p = routes.CoverProblem(sp.csr_matrix(dense), w, 3, "multiview", 2, 30.0, pos, pts, (), free, conflicts,
                            SolveOptions(k=3, mode="multiview"), Deadline(None))
    keep = (int(conflicts[0, 0]),)
    got = routes.spaced_angle_greedy(p, keep, Deadline(None))
    assert got is not None and len(got) == 3 and keep[0] in got and spaced(got, pos, dmin)
    # no spaced set of 3 at a distance larger than the ring: None
    far = conflict_pairs(pos, 100.0)
    free2, far = _free_columns(pos.shape[0], (), (), far, 100.0)
    p2 = routes.CoverProblem(sp.csr_matrix(dense), w, 3, "multiview", 2, 30.0, pos, pts, (), free2, far,
                             SolveOptions(k=3, mode="multiview"), Deadline(None))
    assert routes.spaced_angle_greedy(p2, (), Deadline(None)) is None


def test_guard_counts_the_relaxation() -> None:
    """Before the cast, a model over the budget with an angle and a distance (``auto``) is counted
    as the angle engine that runs instead on the bits, beside the conflicting pairs."""
    from camplace.solver.api import bits_solve_bytes
    from camplace.solver.engines.angle.search import angle_bytes
    from camplace.solver.options import SolveOptions

    m, n, nnz = 10_000, 2_000, 8_000_000
    o = SolveOptions(mode="multiview", k=3, views=2, min_angle_deg=20.0, min_distance_m=0.5,
                     memory_budget_bytes=1 << 30)  # the model (4.3 GiB without the angle's rows) over it
    got = bits_solve_bytes(m, n, o, nnz, conflicts=5_000)
    assert got == 200 * 5_000 + angle_bytes(m, n, 0, 3, 2, layout_rows=m)  # on the bits: no CSR


@pytest.mark.parametrize("m", [300, 6_000])
def test_model_estimate_on_bits_against_the_csr_count(m, monkeypatch) -> None:
    """The angle model's size counted on sampled rows of the bits equals the CSR route's count
    (every row taken: m = 300) or is within 10 % of it (2,048 of 6,000 rows sampled)."""
    import camplace.solver.api as api
    from camplace.solver.engines.mip.linear import model_bytes
    from camplace.solver.engines.mip.mode_models import model_size
    from camplace.solver.options import SolveOptions
    from camplace.solver.problem.checks import conflict_pairs

    rng = np.random.default_rng(m)
    n = 30
    dense = (rng.random((m, n)) < 0.4).astype(np.float32)
    w = np.where(rng.random(m) < 0.1, 0.0, rng.random(m))
    pos, pts = rng.normal(size=(n, 3)) * 5, rng.normal(size=(m, 3))
    o = SolveOptions(k=3, mode="multiview", views=2, min_angle_deg=25.0, min_distance_m=2.0)
    conflicts = conflict_pairs(pos, 2.0)
    free = np.arange(n, dtype=np.int64)
    monkeypatch.setattr(api, "memory_budget_bytes", lambda: 1 << 50)  # nothing truncates the counts
    q = sp.csr_matrix(dense)
    want = model_bytes("mip", *model_size(q, q, w, w, "multiview", 2, 25.0, pos, pts, (), free, conflicts, 1 << 50))
    got = api._angle_model_bytes(bits_from_csr(q), w, o, pos, pts, (), free, conflicts)
    if m <= api._MODEL_SAMPLE_ROWS:
        assert got == want
    else:
        assert got == pytest.approx(want, rel=0.1) and got != want


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_spaced_swaps_end_at_a_local_optimum(seed) -> None:
    """From a poor spaced start the swaps climb, stay spaced, value exactly, and end where no single
    spaced exchange of one camera (enumerated) gains."""
    from camplace.solver._support.deadline import Deadline
    from camplace.solver.engines.angle.spaced import neighbours, spaced_swaps
    from camplace.solver.problem.checks import conflict_pairs

    dense, w, pos, pts = _case(seed)
    n, dmin = pos.shape[0], 4.0
    conflicts = conflict_pairs(pos, dmin)
    nbr = neighbours(conflicts)
    free = np.arange(n, dtype=np.int64)
    q = sp.csr_matrix(dense)

    def value(sel):
        return mode_value(q, w, list(sel), mode="multiview", views=2, min_angle_deg=30.0, positions=pos, points=pts)

    spaced_sets = [c for c in itertools.combinations(range(n), 3) if spaced(c, pos, dmin)]
    start = min(spaced_sets, key=value)
    sel, val, rounds = spaced_swaps(q, w, 2, 30.0, pos, pts, (), free, nbr, list(start), value, value(start),
                                    Deadline(None))
    assert spaced(sel, pos, dmin) and len(sel) == 3 and val == value(sel) and val > value(start) and rounds >= 2
    for i in range(3):
        others = [j for t, j in enumerate(sel) if t != i]
        for j in range(n):
            c = tuple(sorted([*others, j]))
            if j not in sel and spaced(c, pos, dmin):
                assert value(c) <= val * (1 + 1e-12) + 1e-12, (sel, c)
