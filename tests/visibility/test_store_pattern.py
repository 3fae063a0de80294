"""``load_visibility(..., pattern=True)``: a binary matrix read as its bool pattern (no float copy),
identical in structure to the float32 read; a graded matrix read as float32 either way."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.runfolder import RunFolder
from camplace.visibility import store


def _binary(m: int, n: int, density: float, seed: int) -> sp.csr_matrix:
    rng = np.random.default_rng(seed)
    return sp.random(m, n, density=density, format="csr", random_state=rng, data_rvs=np.ones, dtype=np.float32)


LAYOUTS = {
    "bits (dense)": lambda: _binary(40, 70, 0.5, 1),
    "csr (sparse)": lambda: _binary(60, 500, 0.01, 2),
    "empty columns": lambda: sp.csr_matrix(np.array([[1, 0, 0, 1], [0, 0, 0, 1], [1, 0, 0, 0]], dtype=np.float32)),
    "empty": lambda: sp.csr_matrix((5, 3), dtype=np.float32),
    "1 x 1": lambda: sp.csr_matrix(np.ones((1, 1), dtype=np.float32)),
    "over 65,535 rows": lambda: _binary(70_000, 3, 0.3, 3),
}


def _save(path, matrix, fmt):
    if fmt == "cpm":
        store.save_visibility(path / "m.cpm", matrix)
        return path / "m.cpm"
    sp.save_npz(path / "m.npz", matrix)
    return path / "m.npz"


@pytest.mark.parametrize("fmt", ["cpm", "npz"])
@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_binary_matrix_reads_back_as_its_bool_pattern(tmp_path, layout, fmt) -> None:
    original = LAYOUTS[layout]().tocsr()
    original.sort_indices()
    path = _save(tmp_path, original, fmt)
    pat = store.load_visibility(path, pattern=True)
    assert pat.dtype == np.bool_ and pat.shape == original.shape and pat.has_canonical_format
    assert np.array_equal(pat.indptr, original.indptr) and np.array_equal(pat.indices, original.indices)
    assert pat.data.size == original.nnz and bool(np.all(pat.data))
    dense = original.toarray()
    assert np.array_equal(pat.toarray(), dense > 0)
    flt = store.load_visibility(path)  # the float read is unchanged
    assert flt.dtype == np.float32 and np.array_equal(flt.toarray(), dense)


@pytest.mark.parametrize("fmt", ["cpm", "npz"])
def test_graded_matrix_keeps_its_float_values(tmp_path, fmt) -> None:
    rng = np.random.default_rng(4)
    graded = sp.random(50, 80, density=0.2, format="csr", random_state=rng, dtype=np.float32)
    graded.data = rng.uniform(0.05, 1.0, graded.nnz).astype(np.float32)
    graded.data[0] = 1.0  # some values 1, not all
    path = _save(tmp_path, graded, fmt)
    got = store.load_visibility(path, pattern=True)
    assert got.dtype == np.float32
    assert np.array_equal(got.toarray(), graded.toarray())


def test_pattern_read_estimates_one_byte_a_pair(tmp_path) -> None:
    matrix = _binary(300, 2000, 0.01, 5)
    store.save_visibility(tmp_path / "m.cpm", matrix)
    footer = store._footer(tmp_path / "m.cpm")
    assert store.read_bytes_estimate(footer) - store.read_bytes_estimate(footer, pattern=True) == 3 * matrix.nnz


def test_run_folder_pattern(tmp_path) -> None:
    binary = _binary(30, 20, 0.3, 6)
    store.save_matrix(tmp_path, binary)
    run = RunFolder(tmp_path)
    assert run.pattern.dtype == np.bool_
    assert np.array_equal(run.pattern.toarray(), binary.toarray() > 0)
    assert "matrix" not in run.__dict__  # the float matrix was not read
    # once the float matrix is read, the pattern shares its index arrays
    run2 = RunFolder(tmp_path)
    flt = run2.matrix
    assert np.shares_memory(run2.pattern.indices, flt.indices) and run2.pattern.dtype == np.bool_
    graded = binary.copy()
    graded.data = np.linspace(0.1, 1.0, graded.nnz, dtype=np.float32)
    store.save_matrix(tmp_path, graded)
    assert RunFolder(tmp_path).pattern.dtype == np.float32
