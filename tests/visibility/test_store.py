"""The matrix store (camplace.visibility.store): exact round trips of every layout, the documented
bit layout against numpy's packbits, corrupt files, the npz option and the one-copy cache link."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import camplace
from camplace.cli import main
from camplace.errors import CamplaceError
from camplace.visibility import store


def random_csr(m: int, n: int, density: float, graded: bool, seed: int = 0, empty_every: int = 0) -> sp.csr_matrix:
    """A canonical float32 CSR built by scipy (the in-memory matrix the store must reproduce);
    with ``empty_every`` = e, every e-th column (0, e, 2e, ...) is empty."""
    rng = np.random.default_rng(seed)
    dense = (rng.random((m, n)) < density).astype(np.float32)
    if graded:
        dense *= rng.random((m, n), dtype=np.float32) + np.float32(1e-7)
    if empty_every:
        dense[:, ::empty_every] = 0
    return sp.csr_matrix(dense)


def assert_identical(a: sp.csr_matrix, b: sp.csr_matrix) -> None:
    assert isinstance(b, sp.csr_matrix) and b.shape == a.shape
    for name in ("indptr", "indices", "data"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    assert b.dtype == np.float32 and b.has_sorted_indices


def footer(path: Path) -> dict:
    raw = path.read_bytes()
    size, magic = struct.unpack("<Q8s", raw[-16:])
    assert magic == store.TAIL_MAGIC
    return json.loads(raw[-16 - size:-16])


CASES = {
    "binary dense (bits)": (300, 70, 0.4, False),
    "graded dense (bits + values)": (300, 70, 0.4, True),
    "binary sparse (csr)": (400, 900, 0.002, False),
    "graded sparse (csr + values)": (400, 900, 0.002, True),
    "empty columns": (50, 40, 0.3, True),
    "empty matrix": (20, 30, 0.0, False),
    "1 x 1": (1, 1, 1.0, False),
    "over 65,535 rows": (70_000, 3, 0.5, True),
    "over 65,535 columns": (3, 70_000, 0.3, False),
    "over 65,535 columns, sparse": (4, 70_000, 0.0005, True),
}


@pytest.mark.parametrize("codec", store.CODECS)
@pytest.mark.parametrize("case", sorted(CASES))
def test_round_trip_is_bit_identical(case: str, codec: str, tmp_path: Path) -> None:
    m, n, density, graded = CASES[case]
    a = random_csr(m, n, density, graded, empty_every=3 if case == "empty columns" else 0)
    if case == "empty columns":
        assert np.diff(a.tocsc().indptr)[::3].sum() == 0 and a.nnz > 0
    path = store.save_visibility(tmp_path / "m.cpm", a, codec=codec)
    b = store.load_visibility(path)
    assert_identical(a, b)
    f = footer(path)
    assert f["values"] == ("float32" if graded and a.nnz else "ones")
    assert f["shape"] == [m, n] and f["nnz"] == a.nnz and f["codec"] == codec


def test_layout_choice_and_narrow_types(tmp_path: Path) -> None:
    dense = store.save_visibility(tmp_path / "d.cpm", random_csr(100, 70, 0.4, False))
    sparse = store.save_visibility(tmp_path / "s.cpm", random_csr(100, 70_000, 0.0005, False))
    assert footer(dense)["structure"] == "bits" and set(footer(dense)["sections"]) == {"bits"}
    s = footer(sparse)
    assert s["structure"] == "csr" and s["sections"]["indices"]["dtype"] == "<u4"
    small = footer(store.save_visibility(tmp_path / "n.cpm", random_csr(100, 900, 0.002, False)))
    assert small["sections"]["indices"]["dtype"] == "<u2" and small["sections"]["counts"]["dtype"] == "|u1"


def test_bits_section_is_numpy_packbits(tmp_path: Path) -> None:
    """The documented bit layout: row-major np.packbits(dense, axis=1, bitorder="little")."""
    a = random_csr(37, 29, 0.5, False, seed=3)
    path = store.save_visibility(tmp_path / "m.cpm", a, codec="none")
    f = footer(path)
    (offset, stored, raw, _crc), = f["sections"]["bits"]["blocks"]
    bits = np.frombuffer(path.read_bytes()[offset:offset + stored], dtype=np.uint8)
    oracle = np.packbits(a.toarray() != 0, axis=1, bitorder="little").reshape(-1)
    np.testing.assert_array_equal(bits, oracle)


def test_many_blocks_and_shuffled_values(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(store, "BLOCK_BYTES", 4096)  # many blocks, decoded by several threads
    a = random_csr(500, 300, 0.3, True, seed=5)
    path = store.save_visibility(tmp_path / "m.cpm", a, workers=3)
    f = footer(path)
    assert len(f["sections"]["values"]["blocks"]) > 10 and f["sections"]["values"]["shuffle"] == 4
    assert_identical(a, store.load_visibility(path, workers=3))


def test_non_canonical_input_is_stored_canonical(tmp_path: Path) -> None:
    coo = sp.coo_matrix((np.array([1.0, 2.0, 0.5], dtype=np.float64), ([2, 0, 2], [1, 3, 1])), shape=(3, 4))
    b = store.load_visibility(store.save_visibility(tmp_path / "m.cpm", coo))
    assert_identical(sp.csr_matrix(np.array([[0, 0, 0, 2], [0, 0, 0, 0], [0, 1.5, 0, 0]], dtype=np.float32)), b)


def _corruptions(raw: bytes, data_offset: int) -> dict[str, bytes]:
    flipped = bytearray(raw)
    flipped[data_offset + 2] ^= 0x5A
    bad_footer = bytearray(raw)
    bad_footer[-20] ^= 0x01
    return {
        "empty": b"",
        "header only": raw[:8],
        "truncated half": raw[: len(raw) // 2],
        "truncated by one": raw[:-1],
        "flipped block byte": bytes(flipped),
        "flipped footer byte": bytes(bad_footer),
        "not a matrix": b"hello, world" * 10,
    }


@pytest.mark.parametrize("codec", store.CODECS)
def test_corrupt_files_give_one_line_errors(codec: str, tmp_path: Path) -> None:
    path = store.save_visibility(tmp_path / "visibility.cpm", random_csr(60, 50, 0.4, True), codec=codec)
    raw = path.read_bytes()
    for what, data in _corruptions(raw, 8).items():
        bad = tmp_path / f"{what.replace(' ', '_')}.cpm"
        bad.write_bytes(data)
        with pytest.raises(CamplaceError) as info:
            store.load_visibility(bad)
        msg = str(info.value)
        assert "\n" not in msg and str(bad) in msg and "re-create it" in msg, (what, msg)


def test_corrupt_matrix_through_the_cli_exits_2(tmp_path: Path, capsys) -> None:
    a = random_csr(40, 20, 0.4, False)
    store.save_matrix(tmp_path, a)
    rows = "\n".join(f"{i},0,0,{i},0,0,1,0,1" for i in range(40))
    (tmp_path / "points.csv").write_text("index,x,y,z,nx,ny,nz,frame,weight\n" + rows + "\n")
    path = tmp_path / "visibility.cpm"
    path.write_bytes(path.read_bytes()[:-5])
    code = main(["solve", str(tmp_path), "--k", "2", "-o", str(tmp_path / "s.json")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(path) in lines[0]


def test_npz_files_and_folders_are_read(tmp_path: Path) -> None:
    a = random_csr(30, 20, 0.3, True)
    sp.save_npz(tmp_path / "visibility.npz", sp.csr_matrix(a.astype(np.float64)))
    assert_identical(a, camplace.load_visibility(tmp_path))
    assert_identical(a, camplace.load_visibility(tmp_path / "visibility.npz"))
    (tmp_path / "sub").mkdir()
    with pytest.raises(CamplaceError, match="no visibility.cpm or visibility.npz"):
        camplace.load_visibility(tmp_path / "sub")
    (tmp_path / "sub" / "visibility.npz").write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(CamplaceError, match="not a readable visibility matrix"):
        camplace.load_visibility(tmp_path / "sub")


def test_convert_matrix_both_ways(tmp_path: Path) -> None:
    a = random_csr(30, 20, 0.3, False)
    store.save_matrix(tmp_path, a)
    assert main(["convert-matrix", str(tmp_path), "--format", "npz"]) == 0
    assert not (tmp_path / "visibility.cpm").exists()
    assert_identical(a, store.canonical_csr(sp.load_npz(tmp_path / "visibility.npz")))
    assert main(["convert-matrix", str(tmp_path), "--format", "cpm"]) == 0
    assert not (tmp_path / "visibility.npz").exists()
    assert_identical(a, store.load_visibility(tmp_path / "visibility.cpm"))


def test_run_matrix_format_npz_and_the_cache_link(tmp_path: Path, monkeypatch) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setenv("CAMPLACE_CACHE_DIR", str(cache))
    args = ["comet-67p-bunker", "--candidates", "40", "--points", "300", "--time-limit", "30"]
    assert main(["run", *args, "-o", str(tmp_path / "a")]) == 0
    entry, = cache.rglob("*.cpm")
    linked = tmp_path / "a" / "visibility.cpm"
    assert os.path.samefile(entry, linked)  # one copy on disk
    sol = json.loads((tmp_path / "a" / "solution.json").read_text())
    assert {"cache.load", "cache.store", "write.matrix", "visibility"} <= set(sol["timings_s"])
    assert main(["run", *args, "-o", str(tmp_path / "b"), "--matrix-format", "npz"]) == 0
    assert not (tmp_path / "b" / "visibility.cpm").exists()
    b = sp.load_npz(tmp_path / "b" / "visibility.npz")
    assert_identical(store.load_visibility(linked), store.canonical_csr(b))
    # no cache: the written file equals the linked cache entry byte for byte
    assert main(["run", *args, "-o", str(tmp_path / "c"), "--no-cache"]) == 0
    assert (tmp_path / "c" / "visibility.cpm").read_bytes() == linked.read_bytes()


def test_store_module_imports_no_embree() -> None:
    code = ("import sys, camplace, camplace.visibility.store; camplace.load_visibility; "
            "bad = [m for m in sys.modules if 'embree' in m or m in ('camplace.visibility.engine', "
            "'camplace.visibility._kernels', 'camplace.visibility.raycast')]; print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert out.stdout.strip() == "[]"


def test_a_matrix_too_big_for_memory_stops_before_allocating(tmp_path: Path, monkeypatch) -> None:
    a = random_csr(200, 100, 0.4, True)
    path = store.save_visibility(tmp_path / "m.cpm", a)
    # decoded: bits 200 * 13 + values 4 * nnz; CSR: 8 * nnz + 12 * 201 (int32 indices and indptr)
    assert store.read_bytes_estimate(footer(path)) == 200 * 13 + 4 * a.nnz + 8 * a.nnz + 201 * 12
    monkeypatch.setattr(store, "_physical_memory_bytes", lambda: 1000)
    with pytest.raises(CamplaceError, match="needs about .* GiB, over this machine's"):
        store.load_visibility(path)


def _resident_bytes(array: np.ndarray) -> int:
    """Bytes of ``array``'s pages present in memory (``/proc/self/pagemap``: bit 63 of each page's
    entry)."""
    page = os.sysconf("SC_PAGE_SIZE")
    addr = array.__array_interface__["data"][0]
    first, last = addr // page, (addr + array.nbytes - 1) // page
    with open("/proc/self/pagemap", "rb") as fh:
        fh.seek(first * 8)
        entries = np.frombuffer(fh.read((last - first + 1) * 8), dtype=np.uint64)
    return int(np.count_nonzero(entries >> np.uint64(63))) * page


@pytest.mark.skipif(not Path("/proc/self/pagemap").exists(), reason="needs Linux /proc")
def test_first_touch_arrays_are_faulted_in_by_populate_alone() -> None:
    """A first-touch array is an anonymous mapping without pages (numpy 2 hides the mapping behind a
    memoryview: populate and the presolve's zero fill must still find it); populate faults in
    exactly the range asked for."""
    from camplace.visibility.scratch import mapping_of
    from camplace.visibility.store import first_touch_empty, populate

    n = 16 << 20  # 16 MiB of uint8: above the mapping threshold
    a = first_touch_empty(n, np.uint8)
    assert mapping_of(a) is not None and mapping_of(a[5:]) is not None
    assert mapping_of(np.empty(10)) is None
    assert _resident_bytes(a) < (1 << 20)
    populate(a, 0, n // 2)
    got = _resident_bytes(a)
    if got < (1 << 20):
        pytest.skip("the kernel lacks MADV_POPULATE_WRITE")
    assert n // 2 <= got <= n // 2 + (2 << 20)  # a transparent huge page may round it up
    assert int(a.max()) == 0


def test_presolve_rows_are_not_zeroed_by_the_main_thread(monkeypatch) -> None:
    """The presolve's fresh row arrays stay unfaulted until the workers populate their blocks."""
    from camplace.solver.problem import presolve_bits as pb

    rows, touch = pb._fresh_rows(4096, 512)  # 16 MiB
    if Path("/proc/self/pagemap").exists():
        assert _resident_bytes(rows) < (1 << 20)
    touch(0, 8)
    assert not rows[:8].any()
