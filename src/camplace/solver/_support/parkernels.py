"""The presolve and incumbent kernels of :mod:`camplace.solver._support.bitkernels` on every allowed core.

Same arguments and the same results (bit for bit, at every thread count) as the serial kernels of
the same names: each runs the kernel's block version on fixed row or column blocks
(:mod:`camplace._blocks`) from a thread pool; every block writes only its own rows
or columns. Small inputs stay on the calling thread.
"""

from __future__ import annotations

import numpy as np

from camplace.solver._support import bitkernels as K
from camplace._blocks import cuts, run_blocks, threads_for

__all__ = ["build_bits", "column_sizes", "dominated_columns", "group_rows", "live_rows", "row_hashes",
           "selected_row_stats", "shortfall_all"]

_WORD_ROWS = 512  # row blocks of bitsets start on a multiple of 8 words (64 bytes: no shared cache line)


def live_rows(indptr, indices, data, w, threads: int | None = None):
    """:func:`camplace.solver._support.bitkernels.live_rows` on row blocks."""
    m = indptr.shape[0] - 1
    live = np.zeros(m, dtype=np.bool_)
    cnt = np.zeros(m, dtype=np.int64)
    run_blocks(lambda lo, hi: K.live_rows_block(lo, hi, indptr, data, w, live, cnt), cuts(m),
               threads or threads_for(data.shape[0]))
    return live, cnt


def selected_row_stats(indptr, indices, data, chosen, threads: int | None = None):
    """:func:`camplace.solver._support.bitkernels.selected_row_stats` on row blocks."""
    m = indptr.shape[0] - 1
    count = np.zeros(m, dtype=np.int64)
    vmax = np.zeros(m, dtype=np.float64)
    run_blocks(lambda lo, hi: K.selected_row_stats_block(lo, hi, indptr, indices, data, chosen, count, vmax), cuts(m),
               threads or threads_for(indices.shape[0]))
    return count, vmax


def build_bits(indptr, indices, data, rows, col_map, n_cols, threads: int | None = None):
    """:func:`camplace.solver._support.bitkernels.build_bits`: word blocks (each block of rows sets
    only its own words), then the transpose on column blocks."""
    rows = np.asarray(rows, dtype=np.int64)
    n_words = (rows.shape[0] + 63) // 64
    out_t = np.zeros((n_words, n_cols), dtype=np.uint64)
    t = threads or threads_for(data.shape[0])
    run_blocks(lambda lo, hi: K.build_bits_block(lo, hi, indptr, indices, data, rows, col_map, out_t),
               cuts(rows.shape[0], align=_WORD_ROWS), t)
    out = np.empty((n_cols, n_words), dtype=np.uint64)
    run_blocks(lambda lo, hi: K.transpose_block(lo, hi, out_t, out), cuts(n_cols), threads or threads_for(out.size))
    return out


def column_sizes(bits, threads: int | None = None):
    """:func:`camplace.solver._support.bitkernels.column_sizes` on column blocks."""
    size = np.zeros(bits.shape[0], dtype=np.int64)
    run_blocks(lambda lo, hi: K.column_sizes_block(lo, hi, bits, size), cuts(bits.shape[0]),
               threads or threads_for(bits.size))
    return size


def dominated_columns(bits, size, row_nnz, indptr, indices, data, rows, threads: int | None = None):
    """:func:`camplace.solver._support.bitkernels.dominated_columns` on column blocks."""
    out = np.zeros(bits.shape[0], dtype=np.bool_)
    K.dominated_empty(size, out)
    run_blocks(lambda lo, hi: K.dominated_block(lo, hi, bits, size, row_nnz, indptr, indices, data, rows, out),
               cuts(bits.shape[0]), threads or threads_for(bits.size))
    return out


def row_hashes(indptr, indices, data, rows, col_map, salt, threads: int | None = None):
    """:func:`camplace.solver._support.bitkernels.row_hashes` on row blocks."""
    h = np.zeros(rows.shape[0], dtype=np.uint64)
    has = np.zeros(rows.shape[0], dtype=np.bool_)
    run_blocks(lambda lo, hi: K.row_hashes_block(lo, hi, indptr, indices, data, rows, col_map, salt, h, has),
               cuts(rows.shape[0]), threads or threads_for(data.shape[0]))
    return h, has


def group_rows(indptr, indices, data, rows, col_map, h, threads: int | None = None):
    """:func:`camplace.solver._support.bitkernels.group_rows`: the hash sort on the calling thread,
    the exact comparisons within buckets on blocks of whole buckets, the numbering serial."""
    rows = np.asarray(rows, dtype=np.int64)
    m = rows.shape[0]
    order = np.argsort(h, kind="mergesort")
    hs = h[order]
    local = np.zeros(m, dtype=np.int64)
    rep = np.zeros(m, dtype=np.int64)
    if m:
        starts = np.flatnonzero(np.r_[True, hs[1:] != hs[:-1]])
        at = np.searchsorted(starts, np.asarray(cuts(m)[1:-1], dtype=np.int64))
        bounds = sorted({0, m, *(int(starts[i]) if i < starts.size else m for i in at)})
        run_blocks(lambda q0, q1: K.group_rows_block(q0, q1, order, hs, indptr, indices, data, rows, col_map, local, rep),
                   bounds, threads or threads_for(data.shape[0]))
    return K.group_rows_finish(order, hs, local)


def shortfall_all(bits, sel_bits, m, w, last_mask, threads: int | None = None):
    """:func:`camplace.solver._support.bitkernels.shortfall_all` on column blocks (each column's sum
    is the serial one)."""
    done, near = K.selection_levels(sel_bits, m, bits.shape[1])
    out = np.zeros(bits.shape[0], dtype=np.float64)
    run_blocks(lambda lo, hi: K.shortfall_all_block(lo, hi, bits, done, near, w, last_mask, out), cuts(bits.shape[0]),
               threads or threads_for(bits.size))
    return out
