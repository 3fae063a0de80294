"""The visibility matrix on disk: a compact file (``visibility.cpm``) that costs little next to the
compute, and ``scipy.sparse.load_npz`` files on request.

Imports neither Embree nor the visibility engine, so a process that only reads a run folder
loads neither (the CSR <-> bitset kernels of :mod:`camplace.visibility._bitkernels` load on
first use). Every reader of a matrix goes through :func:`load_visibility`, which takes a run,
visibility or campaign folder, a ``.cpm`` file or a ``.npz`` file, and returns the canonical
scipy CSR matrix (float32 values, sorted column indices, no duplicates; int32 index arrays
unless the matrix needs int64). With ``pattern=True`` a binary matrix comes back with bool data
instead (1 byte a pair, no float copy), which is what the solver's bitset engines need.

The ``.cpm`` format (version 1), little-endian::

    b"CAMPLMX1"                       8 bytes
    blocks                            each section's bytes, cut into blocks of 4 MiB (raw)
    footer                            UTF-8 JSON, see below
    footer length                     uint64
    b"CAMPLEND"                       8 bytes

The footer holds ``shape`` [m, n], ``nnz``, ``structure``, ``values``, ``codec`` and
``sections``: for each section its ``dtype`` (numpy ``dtype.str``), element ``count``,
``shuffle`` (0, or the element size when the bytes were shuffled: all first bytes of the
block's elements, then all second bytes, ...) and ``blocks`` ``[[offset, stored_bytes,
raw_bytes, crc32], ...]``. With codec ``zstd`` each block is one zstd frame with its content
checksum (crc32 null); with ``none`` the block is the raw bytes and crc32 their zlib CRC.
``meta`` holds free-form JSON (the cache keeps the engine's pair counts there).

Structure (the sparsity pattern):

- ``bits``: section ``bits``, uint8, m * ceil(n / 8) bytes: row i's bitset at
  ``i * ceil(n / 8)``, column j in bit ``j % 8`` (least significant first) of byte ``j // 8``
  (``np.packbits(dense, axis=1, bitorder="little")``). Chosen when it is no larger than the CSR
  arrays (above about 1 / (8 * index bytes) density).
- ``colbits`` (binary matrices held as column bitsets, :mod:`camplace.visibility.bits`): section
  ``colbits``, uint64, n * ceil(m / 64) words: column j's bitset at ``j * ceil(m / 64)``, row i in
  bit ``i % 64`` (least significant first) of word ``i // 64``; bits past row m - 1 are zero.
  Values are always ``ones``. Written for a binary run's matrix whatever its density (it is what
  the solver reads; :func:`load_bits` returns it without a CSR copy, :func:`load_visibility`
  converts it to CSR). Files of the other structures stay readable by both.
- ``colbytes`` (graded matrices quantised to a byte, :mod:`camplace.visibility.qbytes`): section
  ``colbytes``, uint8, n * m bytes: column j's bytes at ``j * m``, row i at ``j * m + i``; a byte
  q stands for the quality q / 255 (0: not observed). Values are always ``byte255``. Written for a
  graded run with ``[quality] precision = "byte"`` (:func:`load_bytes` returns it as it is,
  :func:`load_visibility` converts it to CSR float32 values q / 255).
- ``csr``: section ``counts`` (entries per row, the narrowest unsigned type that holds the
  largest) and ``indices`` (column of every entry, row by row, ascending within a row, the
  narrowest unsigned type that holds n - 1).

Values: ``ones`` (every stored value is exactly 1.0: nothing stored) or ``float32`` (section
``values``, the float32 values in CSR order, byte-shuffled before compression). Values always
round-trip bit-identically.
"""

from __future__ import annotations

import json
import mmap
import os
import struct
import threading
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np
import scipy.sparse as sp

from camplace._cores import thread_count
from camplace.errors import CamplaceError
from camplace.visibility.scratch import mapping_of, release_pages

HEAD_MAGIC = b"CAMPLMX1"
TAIL_MAGIC = b"CAMPLEND"
FORMAT_VERSION = 1
MATRIX_NAME = "visibility.cpm"
NPZ_NAME = "visibility.npz"
#: ``--matrix-format`` choices: the compact store (default) or scipy's ``save_npz`` (zlib).
MATRIX_FORMATS = ("cpm", "npz")
CODECS = ("zstd", "none")
BLOCK_BYTES = 4 << 20
ZSTD_LEVEL = 1
_TAIL = struct.Struct("<Q8s")
_FIX = "re-create it with the command that wrote it (e.g. 'camplace run' or 'camplace visibility')"

__all__ = [
    "MATRIX_FORMATS",
    "MATRIX_NAME",
    "NPZ_NAME",
    "canonical_csr",
    "convert_matrix",
    "as_pattern_if_binary",
    "load_bits",
    "load_bytes",
    "load_visibility",
    "matrix_path",
    "read_meta",
    "save_matrix",
    "save_visibility",
]


# --------------------------------------------------------------------------------------------
# small helpers


_POPULATE_MIN_BYTES = 8 << 20


def populated_empty(n: int, dtype) -> np.ndarray:
    """``np.empty(n, dtype)`` whose pages are faulted in up front, in one ``mmap(MAP_POPULATE)`` call.

    Writing a fresh array page by page costs a page fault per page; on virtual machines that hand
    free memory back to the host (free-page reporting), each fault is far dearer (measured on the
    2-core VM: 0.4-0.7 s for 332 MB by page faults, 0.1 s populated). Falls back to ``np.empty``
    for small arrays and where ``MAP_POPULATE`` is not available. The mapping is released with the
    array.
    """
    dtype = np.dtype(dtype)
    nbytes = int(n) * dtype.itemsize
    flag = getattr(mmap, "MAP_POPULATE", None)
    if nbytes < _POPULATE_MIN_BYTES or flag is None:
        return np.empty(n, dtype=dtype)
    try:
        buf = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | flag)
    except (OSError, ValueError):  # pragma: no cover - e.g. no overcommit
        return np.empty(n, dtype=dtype)
    return np.frombuffer(buf, dtype=dtype, count=n)


#: ``madvise(MADV_POPULATE_WRITE)`` (Linux >= 5.14; Python's mmap does not name it)
_MADV_POPULATE_WRITE = 23


def first_touch_empty(n: int, dtype) -> np.ndarray:
    """``np.empty(n, dtype)`` whose pages are faulted in later, by the threads that fill them.

    A large array is an anonymous mapping without its pages; each worker calls :func:`populate`
    on the range it is about to write, so the pages are faulted in on every worker at once (and on
    a multi-socket machine land on the worker's memory node) rather than by one thread up front.
    Small arrays are plain ``np.empty``.
    """
    dtype = np.dtype(dtype)
    nbytes = int(n) * dtype.itemsize
    if nbytes < _POPULATE_MIN_BYTES:
        return np.empty(n, dtype=dtype)
    try:
        buf = mmap.mmap(-1, nbytes, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    except (OSError, ValueError):  # pragma: no cover - e.g. no overcommit
        return np.empty(n, dtype=dtype)
    return np.frombuffer(buf, dtype=dtype, count=n)


def populate(array: np.ndarray, lo: int, hi: int) -> None:
    """Fault in the pages of ``array[lo:hi]`` in one call (an array of :func:`first_touch_empty`).

    Costs one ``madvise`` per call instead of a page fault per 4 KiB (measured on the 2-core VM:
    0.4-0.7 s for 332 MB by page faults, 0.1 s populated). A no-op for other arrays and where the
    kernel lacks ``MADV_POPULATE_WRITE`` (the pages then fault in as they are written).
    """
    buf = mapping_of(array)
    if buf is None or hi <= lo:
        return
    page = mmap.PAGESIZE
    start = (int(lo) * array.itemsize) // page * page
    stop = min(len(buf), -(-(int(hi) * array.itemsize) // page) * page)
    try:
        buf.madvise(_MADV_POPULATE_WRITE, start, stop - start)
    except (OSError, ValueError):  # pragma: no cover - an older kernel
        pass


def _workers(workers: int | None) -> int:
    return thread_count(workers)


def _narrow_uint(max_value: int) -> np.dtype:
    """The narrowest unsigned dtype that holds ``max_value``."""
    for dt in (np.uint8, np.uint16, np.uint32):
        if max_value <= np.iinfo(dt).max:
            return np.dtype(dt)
    return np.dtype(np.uint64)


def index_dtype(shape: tuple[int, int], nnz: int) -> np.dtype:
    """int32 unless the matrix needs int64 (the engine's rule)."""
    return np.dtype(np.int32 if max(shape[0], shape[1], nnz) < 2**31 - 1 else np.int64)


def _row_ranges(indptr: np.ndarray | None, m: int, parts: int) -> list[tuple[int, int]]:
    """``parts`` contiguous row ranges with about the same number of entries (rows when no indptr)."""
    parts = max(1, min(parts, m))
    if indptr is None or indptr[-1] == 0:
        cuts = [m * t // parts for t in range(parts + 1)]
    else:
        nnz = int(indptr[-1])
        cuts = [0, *np.searchsorted(indptr, [nnz * (t + 1) / parts for t in range(parts - 1)]).tolist(), m]
    return [(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:], strict=True) if b > a]


def _run_rows(fn, ranges: list[tuple[int, int]], workers: int) -> list:
    if len(ranges) <= 1 or workers <= 1:
        return [fn(lo, hi) for lo, hi in ranges]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(lambda r: fn(*r), ranges))


def canonical_csr(matrix) -> sp.csr_matrix:
    """``matrix`` as canonical CSR float32: sorted column indices, no duplicate entries, int32
    index arrays unless int64 is needed (no copy when it already is)."""
    m = matrix if sp.issparse(matrix) else sp.csr_matrix(np.asarray(matrix))
    m = m.tocsr()
    if m.dtype != np.float32:
        m = m.astype(np.float32)
    if not m.has_canonical_format:
        m = m.copy()
        m.sum_duplicates()
    want = index_dtype(m.shape, m.nnz)
    if m.indptr.dtype != want or m.indices.dtype != want:
        m = sp.csr_matrix((m.data, m.indices.astype(want), m.indptr.astype(want)), shape=m.shape, copy=False)
        m.has_canonical_format = True
    return m


# --------------------------------------------------------------------------------------------
# layout: CSR <-> sections


def _to_bits(matrix: sp.csr_matrix, workers: int) -> np.ndarray:
    from camplace.visibility import _bitkernels

    m, n = matrix.shape
    row_bytes = (n + 7) // 8
    bits = np.zeros(m * row_bytes, dtype=np.uint8)
    _run_rows(
        lambda lo, hi: _bitkernels.csr_to_bits(matrix.indptr, matrix.indices, lo, hi, row_bytes, bits),
        _row_ranges(matrix.indptr, m, 4 * workers), workers,
    )
    return bits


def _layout(matrix: sp.csr_matrix, workers: int) -> tuple[str, str, list[tuple[str, np.ndarray, int]]]:
    """(structure, values, [(section name, 1-d array, shuffle), ...]) of a canonical CSR matrix."""
    m, n = matrix.shape
    nnz = matrix.nnz
    counts = np.diff(matrix.indptr)
    count_dt = _narrow_uint(int(counts.max()) if m else 0)
    col_dt = _narrow_uint(max(n - 1, 0))
    bits_bytes = m * ((n + 7) // 8)
    csr_bytes = nnz * col_dt.itemsize + m * count_dt.itemsize
    sections: list[tuple[str, np.ndarray, int]] = []
    if nnz and bits_bytes <= csr_bytes:
        structure = "bits"
        sections.append(("bits", _to_bits(matrix, workers), 0))
    else:
        structure = "csr"
        sections.append(("counts", counts.astype(count_dt), 0))
        sections.append(("indices", matrix.indices.astype(col_dt), 0))
    data = matrix.data
    from camplace.visibility import _bitkernels

    if nnz == 0 or bool(_bitkernels.all_ones(data)):
        values = "ones"
    else:
        values = "float32"
        sections.append(("values", np.ascontiguousarray(data, dtype=np.float32), 4))
    return structure, values, sections


def _is_bits(matrix) -> bool:
    return getattr(matrix, "format", None) == "bits"


def _is_bytes(matrix) -> bool:
    return getattr(matrix, "format", None) == "bytes"


def _colbytes(footer: dict, arrays: dict[str, np.ndarray]):
    """The :class:`~camplace.visibility.qbytes.ByteMatrix` of a ``colbytes`` file, checked."""
    from camplace.visibility.qbytes import ByteMatrix

    m, n = footer["shape"]
    if footer["values"] != "byte255":
        raise _Corrupt(f"colbytes with values {footer['values']!r}")
    values = arrays["colbytes"]
    if values.size != n * m:
        raise _Corrupt(f"colbytes section holds {values.size} bytes, expected {n * m}")
    out = ByteMatrix(values.reshape(n, m))
    if out.nnz != footer["nnz"]:
        raise _Corrupt(f"{out.nnz} entries, the footer says {footer['nnz']}")
    return out


def _colbits(footer: dict, arrays: dict[str, np.ndarray]):
    """The :class:`~camplace.visibility.bits.BitMatrix` of a ``colbits`` file, checked."""
    from camplace.visibility.bits import BitMatrix, bit_words

    m, n = footer["shape"]
    words = arrays["colbits"]
    nw = bit_words(m)
    if words.size != n * nw:
        raise _Corrupt(f"colbits section holds {words.size} words, expected {n * nw}")
    words = words.reshape(n, nw)
    if m % 64 and n and np.any(words[:, -1] >> np.uint64(m % 64)):
        raise _Corrupt(f"bits set beyond row {m - 1}")
    bits = BitMatrix(words, m)
    if bits.nnz != footer["nnz"]:
        raise _Corrupt(f"{bits.nnz} entries, the footer says {footer['nnz']}")
    return bits


def _from_layout(footer: dict, arrays: dict[str, np.ndarray], workers: int, pattern: bool = False) -> sp.csr_matrix:
    m, n = footer["shape"]
    nnz = footer["nnz"]
    if footer["structure"] == "colbits":
        if footer["values"] != "ones":
            raise _Corrupt(f"colbits with values {footer['values']!r}")
        return _colbits(footer, arrays).tocsr(np.bool_ if pattern else np.float32, workers)
    if footer["structure"] == "colbytes":
        matrix = _colbytes(footer, arrays).tocsr(np.float32, workers)
        return as_pattern_if_binary(matrix) if pattern else matrix
    idt = index_dtype((m, n), nnz)
    with ThreadPoolExecutor(max_workers=1) as side:
        # the all-ones values are allocated (page faults, 4 bytes a pair, or 1 for a pattern) beside
        # the decoding
        ones = side.submit(_ones, nnz, np.bool_ if pattern else np.float32) if footer["values"] == "ones" else None
        indptr, indices = _structure(footer, arrays, m, n, nnz, idt, workers)
        if ones is not None:
            data = ones.result()
        elif footer["values"] == "float32":
            data = arrays["values"]
            if data.size != nnz:
                raise _Corrupt(f"{data.size} values, expected {nnz}")
        else:
            raise _Corrupt(f"unknown values {footer['values']!r}")
    matrix = sp.csr_matrix((data, indices, indptr), shape=(m, n), copy=False)
    matrix.has_canonical_format = True
    return matrix


def _ones(nnz: int, dtype=np.float32) -> np.ndarray:
    data = populated_empty(nnz, dtype)
    data.fill(1)
    return data


def _structure(footer: dict, arrays: dict[str, np.ndarray], m: int, n: int, nnz: int, idt: np.dtype,
               workers: int) -> tuple[np.ndarray, np.ndarray]:
    """(indptr, indices) from the structure sections."""
    if footer["structure"] == "bits":
        from camplace.visibility import _bitkernels

        bits = arrays["bits"]
        row_bytes = (n + 7) // 8
        if bits.size != m * row_bytes:
            raise _Corrupt(f"bits section holds {bits.size} bytes, expected {m * row_bytes}")
        counts = np.zeros(m, dtype=np.int64)
        last_mask = (1 << (n % 8)) - 1 if n % 8 else 0xFF
        ranges = _row_ranges(None, m, 4 * workers)
        bad = _run_rows(
            lambda lo, hi: _bitkernels.bits_row_counts(bits, lo, hi, row_bytes, last_mask, _bitkernels.POPCOUNT, counts),
            ranges, workers,
        )
        if sum(bad):
            raise _Corrupt(f"{sum(bad)} rows have bits set beyond column {n - 1}")
        indptr = np.zeros(m + 1, dtype=idt)
        np.cumsum(counts, out=indptr[1:])
        if int(indptr[-1]) != nnz:
            raise _Corrupt(f"{int(indptr[-1])} entries, the footer says {nnz}")
        indices = populated_empty(nnz, idt)
        _run_rows(
            lambda lo, hi: _bitkernels.bits_to_indices(
                bits, lo, hi, row_bytes, indptr, _bitkernels.BIT_POSITIONS, _bitkernels.POPCOUNT, indices
            ),
            _row_ranges(indptr, m, 4 * workers), workers,
        )
    elif footer["structure"] == "csr":
        counts, cols = arrays["counts"], arrays["indices"]
        if counts.size != m or cols.size != nnz:
            raise _Corrupt(f"{counts.size} row counts and {cols.size} indices, expected {m} and {nnz}")
        indptr = np.zeros(m + 1, dtype=idt)
        np.cumsum(counts, out=indptr[1:], dtype=idt)
        if int(indptr[-1]) != nnz:
            raise _Corrupt(f"{int(indptr[-1])} entries, the footer says {nnz}")
        if nnz and int(cols.max()) >= n:
            raise _Corrupt(f"a column index {int(cols.max())} >= {n} columns")
        indices = populated_empty(nnz, idt)
        np.copyto(indices, cols, casting="unsafe")
    else:
        raise _Corrupt(f"unknown structure {footer['structure']!r}")
    return indptr, indices


# --------------------------------------------------------------------------------------------
# blocks: codec and checksums


class _Corrupt(Exception):
    """A problem with the file's content (turned into a CamplaceError naming the file)."""


_LOCAL = threading.local()


def _zstd():
    try:
        import zstandard
    except ImportError:  # pragma: no cover - a declared dependency
        raise CamplaceError("the zstandard package is missing (pip install zstandard)") from None
    return zstandard


def _compressor(level: int):
    c = getattr(_LOCAL, "cctx", None)
    if c is None or _LOCAL.level != level:
        c = _LOCAL.cctx = _zstd().ZstdCompressor(level=level, write_checksum=True, write_content_size=True)
        _LOCAL.level = level
    return c


def _decompressor():
    d = getattr(_LOCAL, "dctx", None)
    if d is None:
        d = _LOCAL.dctx = _zstd().ZstdDecompressor()
    return d


def _shuffle(raw: np.ndarray, size: int) -> np.ndarray:
    """Bytes of ``size``-byte elements regrouped by byte position (all first bytes, then ...)."""
    return np.ascontiguousarray(raw.reshape(-1, size).T).reshape(-1)


def _unshuffle(raw: np.ndarray, size: int) -> np.ndarray:
    return np.ascontiguousarray(raw.reshape(size, -1).T).reshape(-1)


def _encode_block(raw: np.ndarray, codec: str, level: int, shuffle: int) -> tuple[Any, int | None]:
    """(stored bytes, crc32 or None) of one raw uint8 block."""
    if codec == "none":
        return memoryview(raw), zlib.crc32(memoryview(raw))
    if shuffle > 1:
        raw = _shuffle(raw, shuffle)
    return _compressor(level).compress(memoryview(raw)), None


def _blocks(raw: np.ndarray, shuffle: int) -> Iterator[np.ndarray]:
    step = BLOCK_BYTES - BLOCK_BYTES % max(shuffle, 1)
    for a in range(0, raw.size, step):
        yield raw[a:a + step]


def _pipelined(fn, items: Iterable, workers: int) -> Iterator:
    """``map(fn, items)`` in order, on ``workers`` threads, at most ``2 * workers`` items ahead."""
    if workers <= 1:
        yield from map(fn, items)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending = []
        for item in items:
            pending.append(pool.submit(fn, item))
            if len(pending) >= 2 * workers:
                yield pending.pop(0).result()
        for fut in pending:
            yield fut.result()


def _write_file(path: Path, footer: dict, sections: list[tuple[str, np.ndarray, int]], codec: str, level: int,
                workers: int) -> None:
    with open(path, "wb") as fh:
        fh.write(HEAD_MAGIC)
        offset = len(HEAD_MAGIC)
        described = {}
        for name, arr, shuffle in sections:
            shuffle = shuffle if codec == "zstd" else 0  # shuffling only helps the compressor
            raw = np.ascontiguousarray(arr).reshape(-1).view(np.uint8)
            blocks = []
            encoded = _pipelined(lambda b, s=shuffle: (b.size, *_encode_block(b, codec, level, s)), _blocks(raw, shuffle), workers)
            done = 0
            for raw_size, stored, crc in encoded:
                fh.write(stored)
                release_pages(raw, done, done + int(raw_size))  # out-of-core bitsets: back to disk
                done += int(raw_size)
                n_stored = len(stored) if not isinstance(stored, memoryview) else stored.nbytes
                blocks.append([offset, n_stored, int(raw_size), crc])
                offset += n_stored
            described[name] = {"dtype": arr.dtype.str, "count": int(arr.size), "shuffle": shuffle, "blocks": blocks}
        data = json.dumps({**footer, "sections": described}, separators=(",", ":")).encode()
        fh.write(data)
        fh.write(_TAIL.pack(len(data), TAIL_MAGIC))


def _read_footer(buf) -> dict:
    size = len(buf)
    if size < len(HEAD_MAGIC) + _TAIL.size or bytes(buf[:len(HEAD_MAGIC)]) != HEAD_MAGIC:
        raise _Corrupt("not a camplace matrix file (bad header)")
    footer_len, tail = _TAIL.unpack(bytes(buf[size - _TAIL.size:]))
    if tail != TAIL_MAGIC:
        raise _Corrupt("truncated (no end marker)")
    start = size - _TAIL.size - footer_len
    if footer_len <= 0 or start < len(HEAD_MAGIC):
        raise _Corrupt("truncated (bad footer length)")
    try:
        footer = json.loads(bytes(buf[start:size - _TAIL.size]))
        m, n = (int(v) for v in footer["shape"])
        footer["shape"] = [m, n]
        footer["nnz"] = int(footer["nnz"])
        for key in ("structure", "values", "codec", "sections"):
            footer[key]  # noqa: B018 - presence check
    except (ValueError, KeyError, TypeError) as exc:
        raise _Corrupt(f"unreadable footer ({exc})") from None
    if footer.get("version") != FORMAT_VERSION:
        raise _Corrupt(f"format version {footer.get('version')!r}, this camplace reads {FORMAT_VERSION}")
    if footer["codec"] not in CODECS:
        raise _Corrupt(f"unknown codec {footer['codec']!r}")
    footer["_data_end"] = start
    return footer


def _read_sections(buf, footer: dict, workers: int) -> dict[str, np.ndarray]:
    """Every section of a ``.cpm`` file, by name."""
    return {name: _read_section(buf, desc, footer["codec"], footer["_data_end"], workers)
            for name, desc in footer["sections"].items()}


def _read_error(path: Path, exc: Exception) -> CamplaceError:
    """The one-line error for a ``.cpm`` file that could not be read: corrupt (a bad section,
    footer or layout) or unreadable (the OS said why)."""
    if isinstance(exc, OSError):
        return CamplaceError(f"{path}: cannot read the visibility matrix ({exc.strerror or exc}); {_FIX}")
    return _corrupt_error(path, exc)


def _read_section(buf, desc: dict, codec: str, data_end: int, workers: int) -> np.ndarray:
    dtype = np.dtype(desc["dtype"])
    if dtype.kind not in "uif":
        raise _Corrupt(f"section dtype {dtype}")
    count = int(desc["count"])
    shuffle = int(desc.get("shuffle", 0))
    blocks = desc["blocks"]
    starts = np.cumsum([0] + [int(b[2]) for b in blocks])
    if int(starts[-1]) != count * dtype.itemsize or any(int(b[1]) > data_end for b in blocks):
        raise _Corrupt(f"blocks hold {int(starts[-1])} bytes, expected {count * dtype.itemsize}")
    out = populated_empty(count, dtype)
    raw_out = out.view(np.uint8)

    def decode(t: int) -> None:
        offset, stored, raw_size, crc = (blocks[t] + [None])[:4]
        if offset < 0 or offset + stored > data_end:
            raise _Corrupt("truncated (a block lies past the end)")
        src = buf[offset:offset + stored]
        if codec == "none":
            if zlib.crc32(src) != crc:
                raise _Corrupt(f"checksum mismatch in block {t}")
            block = np.frombuffer(src, dtype=np.uint8)
        else:
            try:
                block = np.frombuffer(_decompressor().decompress(src, max_output_size=raw_size), dtype=np.uint8)
            except _zstd().ZstdError as exc:
                raise _Corrupt(f"block {t}: {exc}") from None
        if block.size != raw_size:
            raise _Corrupt(f"block {t} holds {block.size} bytes, expected {raw_size}")
        if shuffle > 1:
            block = _unshuffle(block, shuffle)
        raw_out[starts[t]:starts[t + 1]] = block

    list(_pipelined(decode, range(len(blocks)), workers))
    return out


# --------------------------------------------------------------------------------------------
# public API


def save_visibility(path: str | Path, matrix, *, codec: str = "zstd", level: int = ZSTD_LEVEL,
                    meta: dict | None = None, workers: int | None = None) -> Path:
    """Write ``matrix`` as a ``.cpm`` file, atomically (temp file + rename).

    Parameters
    ----------
    path : path
        The file to write.
    matrix : (m, n) sparse or dense, or camplace.visibility.bits.BitMatrix
        Written as canonical CSR float32 (see :func:`canonical_csr`); values round-trip exactly.
        A :class:`~camplace.visibility.bits.BitMatrix` is written as its column bitsets
        (structure ``colbits``), a :class:`~camplace.visibility.qbytes.ByteMatrix` as its bytes
        (structure ``colbytes``), without a CSR copy.
    codec : {"zstd", "none"}
    level : int
        zstd level (1 is fast; higher is smaller and slower to write, as fast to read).
    meta : dict or None
        JSON-serialisable extra record kept in the footer (see :func:`read_meta`).
    workers : int or None
        Threads (default: number of CPUs, at most 8).

    Returns
    -------
    Path
    """
    from camplace._io import write_with_atomic

    if codec not in CODECS:
        raise CamplaceError(f"matrix codec: unknown {codec!r} (use one of {', '.join(CODECS)})")
    path = Path(path)
    workers = _workers(workers)
    if _is_bits(matrix):
        structure, values, sections = "colbits", "ones", [("colbits", matrix.words, 0)]
    elif _is_bytes(matrix):
        structure, values, sections = "colbytes", "byte255", [("colbytes", matrix.values.reshape(-1), 0)]
    else:
        matrix = canonical_csr(matrix)
        structure, values, sections = _layout(matrix, workers)
    footer = {
        "format": "camplace-matrix", "version": FORMAT_VERSION, "shape": list(matrix.shape), "nnz": int(matrix.nnz),
        "structure": structure, "values": values, "codec": codec, "level": level if codec == "zstd" else None,
        "meta": meta or {},
    }
    write_with_atomic(path, lambda tmp: _write_file(tmp, footer, sections, codec, level, workers))
    return path


def matrix_path(path: str | Path) -> Path:
    """The matrix file of a folder (``visibility.cpm``, else ``visibility.npz``), or ``path`` itself.

    Raises
    ------
    CamplaceError
        When a folder holds neither, or a file does not exist.
    """
    p = Path(path)
    if p.is_dir():
        for name in (MATRIX_NAME, NPZ_NAME):
            if (p / name).is_file():
                return p / name
        raise CamplaceError(f"{p}: no {MATRIX_NAME} or {NPZ_NAME} here (give the output folder of 'camplace run', "
                            "'camplace visibility' or 'camplace campaign', or the matrix file)")
    if not p.is_file():
        raise CamplaceError(f"{p}: no such file (give a 'camplace run' folder or its {MATRIX_NAME} / {NPZ_NAME})")
    return p


def _is_store(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(len(HEAD_MAGIC)) == HEAD_MAGIC


def _open(path: Path):
    """(mmap or b"", footer) of a ``.cpm`` file."""
    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        buf = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    return buf, _read_footer(buf)


def _physical_memory_bytes() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 8 << 30


def read_bytes_estimate(footer: dict, pattern: bool = False) -> int:
    """Peak bytes to read a ``.cpm`` file: its decoded sections plus the CSR arrays (values of 1
    byte a pair for a binary matrix read as a pattern, else 4)."""
    m, n = footer["shape"]
    nnz = footer["nnz"]
    idt = index_dtype((m, n), nnz)
    value_bytes = 1 if pattern and footer["values"] == "ones" else 4
    sections = sum(int(d["count"]) * np.dtype(d["dtype"]).itemsize for d in footer["sections"].values())
    return sections + nnz * (idt.itemsize + value_bytes) + (m + 1) * (idt.itemsize + 8)


def _check_memory(path: Path, footer: dict, pattern: bool = False) -> None:
    """Stop before allocating a matrix that cannot fit in this machine's memory."""
    need = read_bytes_estimate(footer, pattern)
    have = _physical_memory_bytes()
    if need > 0.9 * have:
        m, n = footer["shape"]
        raise CamplaceError(
            f"{path}: reading this {m:_} x {n:_} matrix ({footer['nnz']:_} pairs) needs about {need / 2**30:.1f} GiB, "
            f"over this machine's {have / 2**30:.1f} GiB (read it on a machine with more memory)"
        )


def _corrupt_error(path: Path, exc: Exception) -> CamplaceError:
    return CamplaceError(f"{path}: truncated or corrupt visibility matrix ({exc}); {_FIX}")


def load_visibility(path_or_outdir: str | Path, *, workers: int | None = None,
                    pattern: bool = False) -> sp.csr_matrix:
    """The visibility matrix of a run / visibility / campaign folder, or of a ``.cpm`` / ``.npz`` file.

    Parameters
    ----------
    path_or_outdir : path
        A folder holding ``visibility.cpm`` (preferred) or ``visibility.npz``, or the file.
    workers : int or None
        Decoding threads (default: number of CPUs, at most 8).
    pattern : bool
        When every stored value is 1 (a binary matrix), return its pattern: bool data (True, 1 byte
        a pair) instead of float32 ones, so no float copy of the matrix is made (the solver's
        bitset engines take it as it is). A graded matrix comes back as float32 either way.

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix of float32 (bool for a binary matrix with ``pattern=True``)
        Canonical: sorted column indices, no duplicates, int32 index arrays unless int64 is needed.

    Raises
    ------
    CamplaceError
        One line naming the file and the fix when it is missing, truncated or corrupt.
    """
    path = matrix_path(path_or_outdir)
    try:
        if not _is_store(path):
            matrix = _load_npz(path)
            return as_pattern_if_binary(matrix) if pattern else matrix
        buf, footer = _open(path)
        try:
            _check_memory(path, footer, pattern)
            w = _workers(workers)
            return _from_layout(footer, _read_sections(buf, footer, w), w, pattern)
        finally:
            if isinstance(buf, mmap.mmap):
                buf.close()
    except (_Corrupt, KeyError, TypeError, ValueError, OSError) as exc:
        raise _read_error(path, exc) from None


def load_bits(path_or_outdir: str | Path, *, workers: int | None = None):
    """A binary visibility matrix as column bitsets (:class:`~camplace.visibility.bits.BitMatrix`).

    A ``colbits`` file is read as it is (one bit a cell); a file of another structure, or a
    ``.npz``, is read as CSR and packed.

    Raises
    ------
    CamplaceError
        One line naming the file when it is missing, corrupt, or holds a graded matrix (values
        other than 1).
    """
    from camplace.visibility.bits import bits_from_csr

    path = matrix_path(path_or_outdir)
    try:
        if _is_store(path):
            buf, footer = _open(path)
            try:
                if footer["structure"] == "colbits":
                    return _colbits(footer, _read_sections(buf, footer, _workers(workers)))
            finally:
                if isinstance(buf, mmap.mmap):
                    buf.close()
    except (_Corrupt, KeyError, TypeError, ValueError, OSError) as exc:
        raise _read_error(path, exc) from None
    matrix = load_visibility(path, workers=workers, pattern=True)
    if matrix.dtype != np.bool_:
        raise CamplaceError(f"{path}: a graded matrix (values other than 1) has no bit layout; read it with load_visibility")
    return bits_from_csr(matrix, workers)


def load_bytes(path_or_outdir: str | Path, *, workers: int | None = None):
    """A graded visibility matrix quantised to bytes (:class:`~camplace.visibility.qbytes.ByteMatrix`).

    A ``colbytes`` file is read as it is (one byte a cell); a file of another structure, or a
    ``.npz``, is read as CSR and quantised (:func:`camplace.visibility.qbytes.bytes_from_csr`).

    Raises
    ------
    CamplaceError
        One line naming the file when it is missing, corrupt, or holds values outside [0, 1].
    """
    from camplace.visibility.qbytes import bytes_from_csr

    path = matrix_path(path_or_outdir)
    try:
        if _is_store(path):
            buf, footer = _open(path)
            try:
                if footer["structure"] == "colbytes":
                    return _colbytes(footer, _read_sections(buf, footer, _workers(workers)))
            finally:
                if isinstance(buf, mmap.mmap):
                    buf.close()
    except (_Corrupt, KeyError, TypeError, ValueError, OSError) as exc:
        raise _read_error(path, exc) from None
    try:
        return bytes_from_csr(load_visibility(path, workers=workers), workers)
    except ValueError as exc:
        raise CamplaceError(f"{path}: {exc}; read it with load_visibility") from None


def as_pattern_if_binary(matrix: sp.csr_matrix) -> sp.csr_matrix:
    """A canonical CSR matrix whose every value is 1 with bool data (its pattern, sharing the index
    arrays); any other matrix unchanged."""
    from camplace.visibility import _bitkernels

    if matrix.nnz and not bool(_bitkernels.all_ones(matrix.data)):
        return matrix
    out = sp.csr_matrix((_ones(matrix.nnz, np.bool_), matrix.indices, matrix.indptr), shape=matrix.shape, copy=False)
    out.has_canonical_format = True
    return out


def _load_npz(path: Path) -> sp.csr_matrix:
    try:
        matrix = sp.load_npz(path)
    except Exception as exc:  # noqa: BLE001 - zipfile, numpy and scipy raise many kinds
        raise CamplaceError(f"{path}: not a readable visibility matrix (neither a camplace .cpm file nor a scipy "
                            f".npz: {exc}); {_FIX}") from None
    return canonical_csr(matrix)


def _footer(path: Path) -> dict:
    """The footer of a ``.cpm`` file, without reading its blocks (one-line error when corrupt)."""
    try:
        buf, footer = _open(path)
        if isinstance(buf, mmap.mmap):
            buf.close()
    except _Corrupt as exc:
        raise _corrupt_error(path, exc) from None
    return footer


def read_meta(path: str | Path) -> dict:
    """The ``meta`` record of a ``.cpm`` file (the footer alone is read)."""
    return dict(_footer(Path(path)).get("meta") or {})


def describe(path: str | Path) -> dict:
    """Shape, nnz, structure, values, codec and size of a ``.cpm`` file (its footer, without the blocks)."""
    path = Path(path)
    footer = _footer(path)
    keep = ("shape", "nnz", "structure", "values", "codec", "level")
    return {**{k: footer.get(k) for k in keep}, "bytes": path.stat().st_size}


def _hard_link(src: Path, dst: Path) -> bool:
    """Hard-link ``src`` to ``dst`` atomically (temp name + rename); False when not possible
    (another file system, no hard links)."""
    from camplace._io import atomic_path

    try:
        if dst.exists() and os.path.samefile(src, dst):
            return True  # already the same file (rename would leave the temporary name behind)
        with atomic_path(dst) as tmp:
            tmp.unlink()
            os.link(src, tmp)
    except OSError:
        return False
    return True


def save_matrix(outdir: str | Path, matrix, *, fmt: str = "cpm", link_from: str | Path | None = None,
                meta: dict | None = None) -> Path:
    """Write a folder's matrix: ``visibility.cpm`` (``fmt="cpm"``) or ``visibility.npz`` (``"npz"``,
    ``scipy.sparse.save_npz`` with zlib, slower and larger), removing the other format's stale file.

    Parameters
    ----------
    outdir : path
    matrix : (m, n) sparse
    fmt : {"cpm", "npz"}
    link_from : path or None
        A ``.cpm`` file already holding this very matrix (the cache entry it came from): it is
        hard-linked in (one copy on disk) instead of written, when the file system allows.
    meta : dict or None
        ``meta`` of a written ``.cpm`` file.

    Returns
    -------
    Path
        The file written.
    """
    from camplace._io import write_with_atomic

    if fmt not in MATRIX_FORMATS:
        raise CamplaceError(f"--matrix-format: unknown format {fmt!r} (use one of {', '.join(MATRIX_FORMATS)})")
    outdir = Path(outdir)
    if fmt == "npz":
        dst = outdir / NPZ_NAME
        m = canonical_csr(matrix.tocsr() if _is_bits(matrix) or _is_bytes(matrix) else matrix)
        write_with_atomic(dst, lambda p: sp.save_npz(p, m, compressed=True))
    else:
        dst = outdir / MATRIX_NAME
        if link_from is None or not Path(link_from).is_file() or not _hard_link(Path(link_from), dst):
            save_visibility(dst, matrix, meta=meta)
    other = outdir / (NPZ_NAME if fmt == "cpm" else MATRIX_NAME)
    if other.exists():
        other.unlink()
    return dst


def convert_matrix(path_or_outdir: str | Path, fmt: str) -> tuple[Path, Path]:
    """Rewrite a folder's (or file's) matrix in format ``fmt``; returns (source, written file).

    The source file is removed once the new one is in place (a no-op when it is already in ``fmt``).
    """
    src = matrix_path(path_or_outdir)
    if fmt not in MATRIX_FORMATS:
        raise CamplaceError(f"--format: unknown format {fmt!r} (use one of {', '.join(MATRIX_FORMATS)})")
    is_store = _is_store(src)
    if (fmt == "cpm") == is_store:
        return src, src
    in_folder = src.name in (MATRIX_NAME, NPZ_NAME)
    from camplace.outpaths import check_out_file

    dst = check_out_file(src.parent / (NPZ_NAME if fmt == "npz" else MATRIX_NAME) if in_folder else src.with_suffix(f".{fmt}"),
                         "FOLDER_OR_FILE", fix="move that folder away")  # before the matrix is read
    matrix = load_visibility(src)
    if in_folder:
        dst = save_matrix(src.parent, matrix, fmt=fmt)
    else:
        if fmt == "npz":
            from camplace._io import write_with_atomic

            write_with_atomic(dst, lambda p: sp.save_npz(p, matrix, compressed=True))
        else:
            save_visibility(dst, matrix)
        src.unlink()
    return src, dst
