"""Binary matrices as column bitsets: the engine's bit layout equals its CSR, at every thread count,
through the cache and the ``.cpm`` store (``colbits``), and old files stay readable as bits."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from camplace._cores import allowed_cores
from camplace.instance import builtin
from camplace.event import event_aims
from camplace.sampling import make_candidates
from camplace.visibility import compute_visibility, make_target_points
from camplace.visibility.bits import BitMatrix, bits_from_csr, pack_rows
from camplace.visibility.store import describe, load_bits, load_visibility, save_visibility


@pytest.fixture(scope="module")
def problem():
    inst = builtin("comet-67p-bunker")
    assert inst.quality.mode == "binary"
    pts = make_target_points(inst, 1500, seed=1)
    cands = make_candidates("uniform", 300, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=2)
    return inst, pts, cands


def test_bits_equal_csr_at_every_thread_count(problem) -> None:
    inst, pts, cands = problem
    ref = compute_visibility(inst, cands, pts, layout="csr", chunk_size=32)
    assert ref.bits is None
    for workers in sorted({1, min(2, allowed_cores())}):
        got = compute_visibility(inst, cands, pts, layout="auto", chunk_size=32, workers=workers)
        assert got.bits is not None and got._matrix is None  # no CSR made
        assert got.stats == ref.stats
        assert got.bits.nnz == ref.matrix.nnz
        diff = got.matrix != ref.matrix
        assert diff.nnz == 0
        np.testing.assert_array_equal(got.bits.row_counts(), np.diff(ref.matrix.indptr))
        np.testing.assert_array_equal(got.bits.column_counts, np.diff(ref.matrix.tocsc().indptr))


@pytest.mark.parametrize("m", [1, 63, 64, 65, 200])
def test_bit_matrix_round_trips(m: int) -> None:
    rng = np.random.default_rng(m)
    dense = rng.random((m, 37)) < 0.3
    bits = bits_from_csr(sp.csr_matrix(dense.astype(np.float32)))
    assert bits.nnz == int(dense.sum())
    np.testing.assert_array_equal(bits.tocsr().toarray() > 0, dense)
    np.testing.assert_array_equal(bits.union([0, 5]), dense[:, 0] | dense[:, 5])
    np.testing.assert_array_equal(bits.column(3), dense[:, 3])
    np.testing.assert_array_equal(np.unpackbits(pack_rows(dense[:, 3]).view(np.uint8), bitorder="little", count=m),
                                  dense[:, 3])


def test_store_colbits_round_trip_and_old_files(problem, tmp_path: Path) -> None:
    inst, pts, cands = problem
    vis = compute_visibility(inst, cands, pts)
    path = save_visibility(tmp_path / "a.cpm", vis.bits)
    assert describe(path)["structure"] == "colbits"
    back = load_bits(path)
    np.testing.assert_array_equal(back.words, vis.bits.words)
    csr = load_visibility(path)
    assert csr.dtype == np.float32 and (csr != vis.matrix).nnz == 0
    pat = load_visibility(path, pattern=True)
    assert pat.dtype == np.bool_ and pat.nnz == vis.bits.nnz
    old = save_visibility(tmp_path / "b.cpm", vis.matrix)  # CSR / row-bits structure: still read as bits
    assert describe(old)["structure"] in ("bits", "csr")
    np.testing.assert_array_equal(load_bits(old).words, vis.bits.words)


def test_cache_hit_returns_bits(problem, tmp_path: Path) -> None:
    inst, pts, cands = problem
    a = compute_visibility(inst, cands, pts, cache_dir=tmp_path)
    b = compute_visibility(inst, cands, pts, cache_dir=tmp_path)
    assert b.stats["cache"] == "hit" and isinstance(b.bits, BitMatrix)
    np.testing.assert_array_equal(a.bits.words, b.bits.words)


def test_corrupt_colbits_is_one_line(problem, tmp_path: Path) -> None:
    from camplace.errors import CamplaceError

    inst, pts, cands = problem
    vis = compute_visibility(inst, cands, pts)
    path = save_visibility(tmp_path / "a.cpm", vis.bits, codec="none")
    raw = bytearray(path.read_bytes())
    raw[100] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(CamplaceError, match="corrupt"):
        load_bits(path)


def test_summary_of_bits_equals_csr(problem) -> None:
    from camplace.visibility.summary import summarise

    inst, pts, cands = problem
    vis = compute_visibility(inst, cands, pts)
    w = pts.weight.copy()
    w[::7] = 0.0
    for sel in ([], [3], [5, 17, 120]):
        a = summarise(vis.bits, w, sel, pts.frame, pts.weight, len(inst.frames))
        b = summarise(vis.matrix, w, sel, pts.frame, pts.weight, len(inst.frames))
        assert a.useful_columns == b.useful_columns
        np.testing.assert_array_equal(a.covered, b.covered)
        assert a.seen.tobytes() == b.seen.tobytes()


def test_release_pages_only_touches_scratch_files(tmp_path: Path) -> None:
    from camplace.visibility.scratch import Scratch, release_pages
    from camplace.visibility.store import populated_empty

    anon = populated_empty(4 << 20, np.uint8)  # an anonymous private mapping: must keep its data
    anon[:] = 7
    release_pages(anon, 0, anon.nbytes)
    assert int(anon.min()) == 7
    with Scratch(tmp_path) as s:
        a = s.array("x", (64, 4096))
        a[:] = 3
        release_pages(a, 0, a.nbytes)  # dropped from memory, kept in the file
        assert int(a.min()) == 3 and s.path is not None and s.path.parent == tmp_path
        folder = s.path
    assert not folder.exists()


def test_out_of_core_equals_in_memory(problem, tmp_path: Path) -> None:
    from camplace.solver.problem.presolve_bits import presolve_bits
    from camplace.visibility.scratch import Scratch

    inst, pts, cands = problem
    ref = compute_visibility(inst, cands, pts, chunk_size=32)
    with Scratch(tmp_path) as s:
        # a budget below the in-memory estimate but above the out-of-core one
        from camplace.visibility.engine import estimate_matrix_bytes

        m, n = ref.bits.shape
        budget = (estimate_matrix_bytes(m, n, 1.0, "bits") + estimate_matrix_bytes(m, n, 1.0, "bits-disk")) // 2
        got = compute_visibility(inst, cands, pts, chunk_size=32, memory_budget_bytes=budget, scratch=s)
        assert s.path is not None and (s.path / "colbits.u64").exists()
        np.testing.assert_array_equal(np.asarray(got.bits.words), ref.bits.words)
        assert got.stats == ref.stats
        w = pts.weight
        a, b = presolve_bits(got.bits, w, 3), presolve_bits(ref.bits, w, 3)
        np.testing.assert_array_equal(a.bits, b.bits)
        np.testing.assert_array_equal(a.columns, b.columns)
        path = save_visibility(tmp_path / "ooc.cpm", got.bits)
        np.testing.assert_array_equal(load_bits(path).words, ref.bits.words)
    with pytest.raises(Exception, match="memory budget"):
        compute_visibility(inst, cands, pts, memory_budget_bytes=budget)  # no scratch: an error before the work


def test_guard_counts_the_solve_on_bits(problem) -> None:
    """The guard's bits estimate counts the solve the run makes (issue 32) after the cast, whose
    threads' work arrays are freed before it: the base, the bitsets and the larger of the threads'
    arrays and the solve's bytes. A budget between the threads' figure and a larger solve's lets
    the run without that solve cast its rays and stops the one with it before the work."""
    from camplace._cores import thread_count
    from camplace.visibility.engine import BASE_BYTES, estimate_matrix_bytes, thread_bytes

    inst, pts, cands = problem
    m, n = len(pts), len(cands)
    words = n * ((m + 63) // 64) * 8
    threads = thread_bytes("bits", m) * thread_count()
    assert estimate_matrix_bytes(m, n, 1.0, "bits", solve_bytes=0) == words + 16 * m + BASE_BYTES + threads
    for solve in (threads // 2, threads + 12345):
        got = estimate_matrix_bytes(m, n, 1.0, "bits", solve_bytes=solve)
        assert got == words + 16 * m + BASE_BYTES + max(threads, solve)
        # a function of the density is evaluated at the density given
        assert estimate_matrix_bytes(m, n, 0.3, "bits", solve_bytes=lambda d: solve + int(d * 1000)) == \
            words + 16 * m + BASE_BYTES + max(threads, solve + 300)
    small, large = estimate_matrix_bytes(m, n, 1.0, "bits", solve_bytes=0), threads + (64 << 20)
    budget = small + (32 << 20)  # the cast fits; the cast and then a solve 64 MiB over the threads' arrays do not
    compute_visibility(inst, cands, pts, chunk_size=32, memory_budget_bytes=budget, solve_bytes=threads // 2)
    with pytest.raises(Exception, match="memory budget"):
        compute_visibility(inst, cands, pts, chunk_size=32, memory_budget_bytes=budget, solve_bytes=large)


def test_guard_checks_the_solve_with_the_pilots_density(problem) -> None:
    """A solve whose working memory grows with the observed pairs (a function of the density) is
    not counted before the work (density 0) but is at the pilot's check, with the pilot's density:
    a budget that the density-free part fits stops the run at the pilot."""
    from camplace.visibility.engine import estimate_matrix_bytes

    inst, pts, cands = problem
    m, n = len(pts), len(cands)
    seen: list[float] = []

    def grows(density: float) -> int:
        seen.append(density)
        return int(density * 10**12)  # a terabyte at any observed share: never fits

    budget = estimate_matrix_bytes(m, n, 0.0, "bits", solve_bytes=0) + (1 << 20)
    with pytest.raises(Exception, match="memory budget"):
        compute_visibility(inst, cands, pts, chunk_size=32, memory_budget_bytes=budget, solve_bytes=grows)
    assert seen[0] == 0.0 and any(d > 0 for d in seen[1:])
