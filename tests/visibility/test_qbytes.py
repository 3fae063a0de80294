"""Graded matrices quantised to a byte a cell (issue 32): the quantisation against a numpy oracle,
the conversions, the ``colbytes`` store structure, and the engine's quantised columns against its
float32 values."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

import camplace
from camplace.errors import CamplaceError
from camplace.event import event_aims
from camplace.instance import builtin
from camplace.sampling import make_candidates
from camplace.visibility import compute_visibility, make_target_points
from camplace.visibility import store
from camplace.visibility.qbytes import QUANT_ERROR, ByteMatrix, bytes_from_csr


def oracle_bytes(values: np.ndarray) -> np.ndarray:
    """numpy: the nearest multiple of 1/255, at least 1/255 for a positive value, 0 for 0."""
    v = np.asarray(values, dtype=np.float64)
    q = np.clip(np.floor(255.0 * v + 0.5), 1.0, 255.0)
    return np.where(v > 0, q, 0.0).astype(np.uint8)


def graded_csr(m: int, n: int, density: float, seed: int) -> sp.csr_matrix:
    rng = np.random.default_rng(seed)
    a = sp.random(m, n, density=density, format="csr", random_state=rng, dtype=np.float32)
    a.data = rng.uniform(0.0, 1.0, a.nnz).astype(np.float32)
    a.data[rng.random(a.nnz) < 0.05] = 1.0
    a.data[a.data == 0] = 1e-3
    special = np.array([1e-30, 1e-4, 0.5 / 255 - 1e-6, 0.5 / 255 + 1e-6, 1.5 / 255, 0.5, 254.5 / 255, 1.0],
                       dtype=np.float32)
    a.data[: min(a.nnz, special.size)] = special[: min(a.nnz, special.size)]
    return a


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_quantisation_round_trip(seed) -> None:
    a = graded_csr(120, 70, 0.3, seed)
    qb = bytes_from_csr(a)
    dense = a.toarray()
    want = oracle_bytes(dense).T  # (n, m)
    np.testing.assert_array_equal(qb.values, want)
    assert qb.shape == a.shape and qb.nnz == a.nnz
    back = qb.tocsr()
    assert back.dtype == np.float32 and back.has_canonical_format
    np.testing.assert_array_equal(back.indptr, a.indptr)
    np.testing.assert_array_equal(back.indices, a.indices)
    np.testing.assert_array_equal(back.data, (want.T[dense > 0] / 255.0).astype(np.float32))
    err = np.abs(back.data.astype(np.float64) - a.data.astype(np.float64))
    big = a.data >= 0.5 / 255
    assert err[big].max() <= QUANT_ERROR + 1e-7  # half a step (plus the float32 of q / 255)
    assert err.max() <= 1 / 255 + 1e-7
    # the pattern and the counts
    np.testing.assert_array_equal(qb.bits().tocsr(np.bool_).toarray(), dense > 0)
    np.testing.assert_array_equal(qb.row_counts(), (dense > 0).sum(axis=1))
    np.testing.assert_array_equal(qb.column_counts, (dense > 0).sum(axis=0))


def test_values_outside_zero_one_are_not_quantised() -> None:
    a = sp.csr_matrix(np.array([[0.5, 1.5]], dtype=np.float32))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        bytes_from_csr(a)
    with pytest.raises(ValueError, match="uint8"):
        ByteMatrix(np.zeros((3, 4), dtype=np.float32))


@pytest.mark.parametrize("codec", ["zstd", "none"])
def test_store_round_trip(tmp_path, codec) -> None:
    a = graded_csr(300, 90, 0.25, 7)
    qb = bytes_from_csr(a)
    path = store.save_visibility(tmp_path / "m.cpm", qb, codec=codec)
    d = store.describe(path)
    assert d["structure"] == "colbytes" and d["values"] == "byte255" and d["nnz"] == a.nnz
    got = store.load_bytes(path)
    assert isinstance(got, ByteMatrix)
    np.testing.assert_array_equal(got.values, qb.values)
    users = camplace.load_visibility(path)  # users still get scipy CSR float32
    assert sp.isspmatrix_csr(users) and users.dtype == np.float32
    want = oracle_bytes(a.toarray()) / 255.0
    np.testing.assert_array_equal(users.toarray(), want.astype(np.float32))
    # npz and back: the same bytes
    store.save_matrix(tmp_path, qb, fmt="npz")
    np.testing.assert_array_equal(store.load_bytes(tmp_path / "visibility.npz").values, qb.values)
    # a float32 file read as bytes is quantised on the way
    fpath = store.save_visibility(tmp_path / "f.cpm", a)
    np.testing.assert_array_equal(store.load_bytes(fpath).values, qb.values)


def test_corrupt_colbytes_is_one_line(tmp_path) -> None:
    qb = bytes_from_csr(graded_csr(100, 40, 0.3, 3))
    path = store.save_visibility(tmp_path / "m.cpm", qb)
    raw = bytearray(path.read_bytes())
    raw[20] ^= 0xFF  # inside the first block
    bad = tmp_path / "bad.cpm"
    bad.write_bytes(bytes(raw))
    for read in (store.load_bytes, store.load_visibility):
        with pytest.raises(CamplaceError) as err:
            read(bad)
        assert "\n" not in str(err.value) and "corrupt" in str(err.value)


def _bunker_graded(precision: str = "byte", min_target_px: float = 0.0):
    inst = builtin("comet-67p-bunker")
    q = dataclasses.replace(inst.quality, mode="graded", max_incidence_deg=80.0, precision=precision,
                            min_target_px=min_target_px)
    inst = dataclasses.replace(inst, quality=q)
    pts = make_target_points(inst, 1500, seed=3)
    cands = make_candidates("uniform", 60, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=4)
    return inst, pts, cands


@pytest.mark.parametrize("min_target_px", [0.0, 400.0])
def test_engine_columns_are_the_quantised_float_values(tmp_path, min_target_px) -> None:
    inst, pts, cands = _bunker_graded(min_target_px=min_target_px)
    ref = compute_visibility(inst, cands, pts, layout="csr", chunk_size=16)  # float32 values
    assert ref.qbytes is None and ref.matrix.dtype == np.float32
    got = compute_visibility(inst, cands, pts, chunk_size=16, cache_dir=tmp_path)
    assert got.qbytes is not None and got.pattern is got.qbytes and got.stats == {**ref.stats, "cache": "miss"}
    dense = ref.matrix.toarray()
    assert np.ptp(ref.matrix.data) > 0.1  # really graded
    np.testing.assert_array_equal(got.qbytes.values, oracle_bytes(dense).T)
    again = compute_visibility(inst, cands, pts, chunk_size=16, cache_dir=tmp_path)  # a cache hit, as bytes
    assert again.stats["cache"] == "hit"
    np.testing.assert_array_equal(again.qbytes.values, got.qbytes.values)
    # the float32 instance keeps float32 values, under its own cache key
    inst32 = _bunker_graded("float32", min_target_px)[0]
    f32 = compute_visibility(inst32, cands, pts, chunk_size=16, cache_dir=tmp_path)
    assert f32.qbytes is None and f32.stats["cache"] == "miss"
    np.testing.assert_array_equal(f32.matrix.toarray(), dense)
    got.save(tmp_path / "out")
    np.testing.assert_array_equal(camplace.load_visibility(tmp_path / "out").toarray(),
                                  (oracle_bytes(dense) / 255.0).astype(np.float32))


def test_bytes_layout_is_refused_for_a_binary_instance() -> None:
    inst = builtin("comet-67p-bunker")
    pts = make_target_points(inst, 200, seed=3)
    cands = make_candidates("uniform", 8, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=4)
    with pytest.raises(CamplaceError, match="binary"):
        compute_visibility(inst, cands, pts, layout="bytes")


def test_guard_allows_a_lean_tree_and_stops_below_it() -> None:
    from camplace.visibility.engine import LEAN_TREE, estimate_matrix_bytes

    inst, pts, cands = _bunker_graded()
    m, n = len(pts), len(cands)
    full = estimate_matrix_bytes(m, n, 1.0, "bytes")
    lean = estimate_matrix_bytes(m, n, 1.0, "bytes", tree=LEAN_TREE)
    pattern_only = estimate_matrix_bytes(m, n, 1.0, "bytes", tree=0.0)
    assert pattern_only < lean < full and full - pattern_only == m * n
    got = compute_visibility(inst, cands, pts, chunk_size=16, memory_budget_bytes=lean)  # the tree keeps less
    assert got.qbytes is not None
    with pytest.raises(CamplaceError, match="memory budget") as err:
        compute_visibility(inst, cands, pts, chunk_size=16, memory_budget_bytes=lean - 1)
    assert "\n" not in str(err.value)
    got = compute_visibility(inst, cands, pts, chunk_size=16, memory_budget_bytes=pattern_only, quality_tree=False)
    assert got.qbytes is not None


def test_out_of_core_bytes_equal_in_memory_and_solve_the_same(tmp_path) -> None:
    """A graded run over the budget in memory but within it out of core keeps its bytes in a
    scratch file (pages dropped chunk by chunk) and gives the same bytes, counts, stored file and
    quantised-tree answer as in memory; the scratch folder is gone afterwards."""
    from camplace.solver._support.deadline import Deadline
    from camplace.solver._support.memory import memory_budget
    from camplace.solver.bytes_route import bytes_outcome
    from camplace.solver.options import SolveOptions
    from camplace.visibility.engine import LEAN_TREE, estimate_matrix_bytes
    from camplace.visibility.scratch import Scratch, mapping_of

    inst, pts, cands = _bunker_graded()
    m, n = len(pts), len(cands)
    ref = compute_visibility(inst, cands, pts, chunk_size=16)
    lean = estimate_matrix_bytes(m, n, 1.0, "bytes", tree=LEAN_TREE)
    disk = estimate_matrix_bytes(m, n, 1.0, "bytes-disk", tree=LEAN_TREE)
    assert disk < lean
    with Scratch(tmp_path) as s:
        got = compute_visibility(inst, cands, pts, chunk_size=16, memory_budget_bytes=lean - 1, scratch=s)
        assert s.path is not None and (s.path / "colbytes.u8").exists()
        assert mapping_of(got.qbytes.values) is not None  # the file's mapping, not a copy
        np.testing.assert_array_equal(np.asarray(got.qbytes.values), ref.qbytes.values)
        assert got.stats == ref.stats
        folder = s.path
        opts = SolveOptions(mode="quality", k=3)
        with memory_budget(None):
            a = bytes_outcome(got.qbytes, pts.weight, opts, Deadline(None))[0]
            b = bytes_outcome(ref.qbytes, pts.weight, opts, Deadline(None))[0]
        assert a.selected == b.selected and a.status == b.status == "optimal" and a.objective == b.objective
        got.save(tmp_path / "out")
    assert not folder.exists()
    np.testing.assert_array_equal(camplace.load_visibility(tmp_path / "out").toarray(),
                                  ref.qbytes.tocsr(np.float32).toarray())
    with pytest.raises(CamplaceError, match="out of core") as err:  # below even the out-of-core estimate
        with Scratch(tmp_path) as s:
            compute_visibility(inst, cands, pts, chunk_size=16, memory_budget_bytes=disk - 1, scratch=s)
    assert "\n" not in str(err.value)
