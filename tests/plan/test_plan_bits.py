"""The planner on a binary matrix's column bitsets against the CSR route on the same matrix.

Oracles: scipy's row slicing / ``vstack`` / ``np.bincount`` of the CSR matrix for the bit helpers,
and the whole planner (every reader, the heuristic, the exact model, the plan files) on the CSR
matrix for the bits route, which must give the very same numbers. ``BitMatrix.tocsr`` raises on the
bits route except where the exact model builds its coverage rows (:func:`camplace.plan.model._kept_columns`).
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.cli import main
from camplace.plan import io as plan_io
from camplace.plan.heuristic import column_gains
from camplace.plan.model import _phase_block, flow_model_size, make_problem, row_values, single_values
from camplace.plan.planner import solve_plan
from camplace.visibility.bits import BitMatrix, bits_from_csr, column_sums, stack_rows, take_rows


def _random_pattern(rng, m: int, n: int, density: float) -> sp.csr_matrix:
    return sp.csr_matrix((rng.random((m, n)) < density).astype(np.float32))


def _same_csr(a: sp.csr_matrix, b: sp.csr_matrix) -> None:
    a, b = sp.csr_matrix(a), sp.csr_matrix(b)
    a.sort_indices()
    b.sort_indices()
    assert a.shape == b.shape
    np.testing.assert_array_equal(a.indptr, b.indptr)
    np.testing.assert_array_equal(a.indices, b.indices)
    np.testing.assert_array_equal(a.data > 0, b.data > 0)


@pytest.mark.parametrize("m", [0, 1, 63, 64, 65, 130, 300])
def test_take_rows_is_csr_row_slicing(m):
    rng = np.random.default_rng(m)
    q = _random_pattern(rng, m, 37, 0.3)
    bits = bits_from_csr(q)
    choices = [np.arange(m), np.arange(m // 3, m), rng.permutation(m), np.sort(rng.choice(m, size=m // 2, replace=False))]
    if m:
        choices.append(rng.integers(0, m, size=2 * m))  # repeats
    choices.append(np.zeros(0, dtype=np.int64))
    for rows in choices:
        got = take_rows(bits, rows)
        assert got.shape == (rows.size, 37)
        _same_csr(got.tocsr(), q[rows])
        # bits past the last row stay zero (BitMatrix's invariant)
        tail = rows.size % 64
        if tail and got.words.size:
            assert not np.any(got.words[:, -1] >> np.uint64(tail))


def test_take_rows_rejects_rows_out_of_range():
    bits = bits_from_csr(_random_pattern(np.random.default_rng(0), 10, 4, 0.5))
    with pytest.raises(IndexError):
        take_rows(bits, np.array([10]))


def test_stack_rows_is_vstack():
    rng = np.random.default_rng(1)
    blocks = [_random_pattern(rng, m, 29, 0.4) for m in (5, 64, 0, 71, 1)]
    got = stack_rows([bits_from_csr(b) for b in blocks])
    _same_csr(got.tocsr(), sp.vstack(blocks).tocsr())


@pytest.mark.parametrize("m", [0, 1, 64, 200, 1000])
def test_column_sums_are_the_csr_bincount_to_the_last_bit(m):
    rng = np.random.default_rng(m + 7)
    q = _random_pattern(rng, m, 53, 0.45)
    v = rng.uniform(0.0, 1.0, size=m) ** 3 * (rng.random(m) < 0.8)
    want = np.bincount(q.indices, weights=np.repeat(v, np.diff(q.indptr)), minlength=53).astype(np.float64)
    for workers in (1, 2):
        got = column_sums(bits_from_csr(q), v, workers=workers)
        assert got.dtype == np.float64
        np.testing.assert_array_equal(got, want)  # exact: the same additions in the same order


def _problem_pair(seed: int, mode: str, *, P: int = 3, n_pos: int = 12, orient: int = 2, k: int = 3,
                  speed: float = 1.5, start: bool = False):
    rng = np.random.default_rng(seed)
    n = n_pos * orient
    pos = np.repeat(rng.uniform(0.0, 10.0, size=(n_pos, 3)), orient, axis=0)
    rows_per = rng.integers(40, 120, size=P)
    m = int(rows_per.sum())
    q = _random_pattern(rng, m, n, 0.25)
    w = rng.uniform(0.0, 1.0, size=m) * (rng.random(m) < 0.9)
    w /= w.sum()
    # rows of a phase need not be contiguous: shuffle the phase of each row
    row_phase = rng.permutation(np.repeat(np.arange(P), rows_per))
    reach = np.full(P - 1, speed * 1.0)
    # start near k distinct positions, so that a plan exists
    sp0 = pos[rng.choice(n_pos, size=k, replace=False) * orient] + rng.uniform(-0.5, 0.5, size=(k, 3)) if start else None
    kw = dict(mode=mode, views=2, reach_m=reach, start_positions_m=sp0, start_reach_m=4.0 if start else np.inf)
    return (make_problem(q, w, row_phase, pos, k, **kw), make_problem(bits_from_csr(q), w, row_phase, pos, k, **kw))


@pytest.fixture
def no_whole_csr(monkeypatch):
    """BitMatrix.tocsr raises, except when the exact model expands its kept columns."""
    original = BitMatrix.tocsr
    calls = []

    def guarded(self, *args, **kwargs):
        caller = sys._getframe(1).f_code.co_name
        if caller != "_kept_columns":
            raise AssertionError(f"BitMatrix.tocsr called from {caller} on the bits route")
        calls.append(self.shape)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(BitMatrix, "tocsr", guarded)
    return calls


@pytest.mark.parametrize("mode", ["maxcover", "quality", "multiview"])
def test_readers_on_bits_equal_the_csr_readers(mode, no_whole_csr):
    csr, bits = _problem_pair(11, mode)
    assert bits.bits and not csr.bits
    rng = np.random.default_rng(3)
    for p in range(csr.n_phases):
        np.testing.assert_array_equal(csr.rows[p], bits.rows[p])
        np.testing.assert_array_equal(single_values(csr, p), single_values(bits, p))
        for others in ([], [0], rng.choice(csr.n_candidates, size=3, replace=False), [5, 5, 7]):
            a, b = column_gains(csr, p, others), column_gains(bits, p, others)
            assert a[0] == b[0]
            np.testing.assert_array_equal(a[1], b[1])
            np.testing.assert_array_equal(a[2], b[2])
            np.testing.assert_array_equal(row_values(csr.matrices[p], csr.weights[p], others, mode, 2),
                                          row_values(bits.matrices[p], bits.weights[p], others, mode, 2))
    kept = [np.sort(rng.choice(csr.n_candidates, size=10, replace=False)) for _ in range(csr.n_phases)]
    assert flow_model_size(csr, kept) == flow_model_size(bits, kept)
    for p in range(csr.n_phases):
        qa, wa = _phase_block(csr, p, kept[p])
        qb, wb = _phase_block(bits, p, kept[p])
        _same_csr(qa, qb)
        np.testing.assert_array_equal(qa.data, qb.data)
        np.testing.assert_array_equal(wa, wb)
    assert no_whole_csr and all(shape[1] == 10 for shape in no_whole_csr)


def _same_result(a, b, mode: str) -> None:
    np.testing.assert_array_equal(a.plan, b.plan)
    assert (a.status, a.engine, a.objective) == (b.status, b.engine, b.objective)
    np.testing.assert_array_equal(a.phase_objectives, b.phase_objectives)
    assert a.static_candidates == b.static_candidates and a.static_objective == b.static_objective
    if mode == "quality":  # the solver answers a binary quality solve on bits as maxcover: bounds to rounding
        np.testing.assert_allclose(a.phase_bounds, b.phase_bounds, rtol=1e-12, atol=0)
        assert a.bound == pytest.approx(b.bound, rel=1e-12, abs=0)
    else:
        np.testing.assert_array_equal(a.phase_bounds, b.phase_bounds)
        assert a.bound == b.bound


@pytest.mark.parametrize("mode", ["maxcover", "quality", "multiview"])
@pytest.mark.parametrize("exact", [False, True])
def test_plan_on_bits_is_the_plan_on_csr(mode, exact, no_whole_csr):
    # multiview's exact model is slow to close: fewer positions there
    csr, bits = _problem_pair(5, mode, start=(mode == "maxcover"), n_pos=12 if mode != "multiview" else 7)
    want = solve_plan(csr, exact=exact, time_limit_s=60)  # (a CSR: BitMatrix.tocsr is not called)
    assert no_whole_csr == []
    got = solve_plan(bits, exact=exact, time_limit_s=60)
    assert want.plan is not None
    _same_result(want, got, mode)
    if not exact:
        assert no_whole_csr == []


def test_pruned_model_and_neighbourhood_search_on_bits_are_the_csr_ones(no_whole_csr):
    """A model limit below the whole model's size: the kept-pose pruning, then the
    large-neighbourhood search, on both layouts."""
    csr, bits = _problem_pair(8, "maxcover", n_pos=40, k=3, speed=1.0)
    want = solve_plan(csr, time_limit_s=60, max_nonzeros=3500)  # the whole model: 5,113 coverage nonzeros
    got = solve_plan(bits, time_limit_s=60, max_nonzeros=3500)
    assert want.plan is not None and want.stats["kept_poses"] and want.stats["lns"]  # both paths walked
    assert want.stats["kept_poses"] == got.stats["kept_poses"]
    assert want.stats["model_size"] == got.stats["model_size"]
    assert want.stats["lns"] == got.stats["lns"]
    _same_result(want, got, "maxcover")


@pytest.mark.parametrize("mode", ["maxcover", "quality", "multiview"])
def test_a_phase_without_rows_on_bits(mode, no_whole_csr):
    rng = np.random.default_rng(2)
    n, m = 10, 70
    pos = rng.uniform(0.0, 10.0, size=(n, 3))
    q = _random_pattern(rng, m, n, 0.3)
    w = rng.uniform(0.0, 1.0, size=m)
    row_phase = np.r_[np.zeros(30, dtype=np.int64), np.full(40, 2)]  # phase 1 has no rows
    kw = dict(mode=mode, reach_m=[3.0, 3.0])
    bits = make_problem(bits_from_csr(q), w, row_phase, pos, 2, **kw)
    assert bits.matrices[1].shape == (0, n)
    _same_result(solve_plan(make_problem(q, w, row_phase, pos, 2, **kw), time_limit_s=30),
                 solve_plan(bits, time_limit_s=30), mode)


# ------------------------------------------------------------------------------------------------
# the plan verb on a binary run: the bitsets as stored, the same files as the CSR route

SMALL = ["--candidates", "20", "--orientations", "2", "--points", "200", "--time-limit", "20"]


@pytest.fixture(scope="module")
def binary_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("plan_bits") / "flyby"
    assert main(["run", "comet-flyby", "-o", str(out), *SMALL]) == 0
    return out


def _without_times(doc):
    if isinstance(doc, dict):
        return {k: _without_times(v) for k, v in doc.items() if not k.startswith("time")}
    if isinstance(doc, list):
        return [_without_times(v) for v in doc]
    return doc


@pytest.mark.parametrize("mode", ["maxcover", "multiview"])
def test_plan_verb_reads_the_bitsets_and_writes_the_csr_routes_files(binary_run, tmp_path, monkeypatch, mode):
    run = plan_io.RunFolder(binary_run)
    assert plan_io._colbits(run) and isinstance(plan_io.plan_matrix(run), BitMatrix)
    argv = ["plan", str(binary_run), "--phases", "4", "--speed", "5", "--mode", mode, "--time-limit", "20"]
    with monkeypatch.context() as mp:  # the CSR route: the run's matrix as CSR
        mp.setattr(plan_io, "_colbits", lambda run: False)
        assert main([*argv, "-o", str(tmp_path / "csr")]) == 0
    original = BitMatrix.tocsr

    def guarded(self, *args, **kwargs):
        if sys._getframe(1).f_code.co_name != "_kept_columns":
            raise AssertionError("BitMatrix.tocsr called on the bits route")
        return original(self, *args, **kwargs)

    monkeypatch.setattr(BitMatrix, "tocsr", guarded)
    monkeypatch.setattr(type(run), "matrix", property(lambda self: (_ for _ in ()).throw(AssertionError("run.matrix read"))))
    assert main([*argv, "-o", str(tmp_path / "bits")]) == 0
    for name in ("plan.csv", "plan_light_curves.csv", "plan_timeline.csv"):
        assert (tmp_path / "bits" / name).read_bytes() == (tmp_path / "csr" / name).read_bytes(), name
    a = json.loads((tmp_path / "csr" / "plan.json").read_text())
    b = json.loads((tmp_path / "bits" / "plan.json").read_text())
    assert a["status"] in ("optimal", "feasible")
    assert _without_times(a) == _without_times(b)
    with open(tmp_path / "bits" / "plan.csv", newline="", encoding="utf-8") as fh:
        assert len(list(csv.DictReader(fh))) == 4 * len(a["agents"])
