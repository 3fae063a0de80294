"""One read-only pass over a run's matrix for what the run reports besides the optimum.

The warnings (how many candidates observe a live point), the coverage figures (the rows the chosen
cameras observe) and ``light_curves.csv`` (what each chosen camera observes, frame by frame) all
come from one compiled pass over the CSR arrays, on every allowed core (row blocks on a thread
pool; the kernel releases the GIL), without a copy or a transpose of the matrix (:func:`summarise`).
Rows are cut into a fixed number of blocks that does not depend on the thread count, and the
blocks' partial sums are added in block order, so the figures are the same bits at every thread
count. (A thread pool rather than numba's ``prange``: measured on the shared 2-core machine under
load, an OpenMP region around this 15 ms pass took 0.6-0.9 s waiting at its barrier.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numba
import numpy as np

from camplace._blocks import cuts, run_blocks
from camplace._cores import thread_count

__all__ = ["MatrixSummary", "summarise"]

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}
#: row blocks of the pass (fixed, so that sums do not depend on the thread count)
BLOCKS = 64
#: below this many entries one thread reads the matrix (about 15 ms for 16 million entries)
PARALLEL_MIN_NNZ = 8_000_000


@dataclass(frozen=True)
class MatrixSummary:
    """What :func:`summarise` reads from a matrix.

    Attributes
    ----------
    useful_columns : int
        Columns that observe at least one row of positive weight.
    covered : (m,) bool
        Rows observed by at least one of the selected columns.
    seen : (s, n_frames) float64
        Per selected column (in the given order) and frame, the weight of the rows it observes.
    """

    useful_columns: int
    covered: np.ndarray
    seen: np.ndarray


@numba.njit(**_JIT)
def _block(lo, hi, indptr, indices, live, slot, frame, weight, col_live, seen, covered):  # pragma: no cover - compiled
    """Rows ``lo:hi``: mark the columns that touch a live row, the covered rows, and add per-slot frame weights."""
    for r in range(lo, hi):
        lv = live[r]
        hit = False
        for t in range(indptr[r], indptr[r + 1]):
            c = indices[t]
            if lv:
                col_live[c] = True
            s = slot[c]
            if s >= 0:
                hit = True
                seen[s, frame[r]] += weight[r]
        covered[r] = hit


def summarise(matrix, weights: np.ndarray, selected: Sequence[int], frame: np.ndarray | None = None,
              frame_weight: np.ndarray | None = None, n_frames: int = 1) -> MatrixSummary:
    """Read the warnings' column count, the covered rows and the light curves in one pass.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix or camplace.visibility.bits.BitMatrix
        Any values; an entry counts as observed (stored zeros do not occur in camplace's matrices).
        Column bitsets are read word by word (the useful columns) and the selected columns alone
        are unpacked, without a CSR copy; quantised columns (``ByteMatrix``) through their
        pattern's bitsets.
    weights : (m,) float64
        The solver's row weights: columns count as useful when they observe a row of positive weight.
    selected : sequence of int
        The chosen columns (distinct).
    frame : (m,) int or None
        Each row's event frame (default: all in frame 0).
    frame_weight : (m,) float64 or None
        The weight summed per frame in ``seen`` (default ``weights``).
    n_frames : int

    Returns
    -------
    MatrixSummary
    """
    if getattr(matrix, "format", None) == "bytes":  # quantised columns: the figures read the pattern
        matrix = matrix.bits()
    if getattr(matrix, "format", None) == "bits":
        return _summarise_bits(matrix, weights, selected, frame, frame_weight, n_frames)
    m, n = matrix.shape
    sel = np.asarray(list(selected), dtype=np.int64)
    slot = np.full(n, -1, dtype=np.int64)
    slot[sel] = np.arange(len(sel))
    frame = np.zeros(m, dtype=np.int64) if frame is None else np.asarray(frame, dtype=np.int64)
    fw = np.asarray(weights if frame_weight is None else frame_weight, dtype=np.float64)
    n_frames = max(1, int(n_frames))
    bounds = cuts(m, BLOCKS)
    blocks = len(bounds) - 1
    live = np.asarray(weights) > 0
    col_live = np.zeros((blocks, n), dtype=np.bool_)
    seen = np.zeros((blocks, max(1, len(sel)), n_frames), dtype=np.float64)
    covered = np.zeros(m, dtype=np.bool_)

    def one(lo: int, hi: int) -> None:
        b = bounds.index(lo)
        _block(lo, hi, matrix.indptr, matrix.indices, live, slot, frame, fw, col_live[b], seen[b], covered)

    run_blocks(one, bounds, thread_count() if matrix.nnz >= PARALLEL_MIN_NNZ else 1)
    total = np.zeros(seen.shape[1:], dtype=np.float64)
    for b in range(blocks):  # in block order: the same sums at every thread count
        total += seen[b]
    return MatrixSummary(useful_columns=int(np.count_nonzero(col_live.any(axis=0))), covered=covered,
                         seen=total[:len(sel)])


@numba.njit(**_JIT)
def _touch_live(words, live, lo, hi, out):  # pragma: no cover - compiled
    """Columns ``lo:hi`` whose bitset meets the ``live`` row bitset."""
    for j in range(lo, hi):
        for w in range(words.shape[1]):
            if words[j, w] & live[w]:
                out[j] = True
                break


@numba.njit(**_JIT)
def _seen_blocks(rows, frame, weight, cuts, out):  # pragma: no cover - compiled
    for b in range(cuts.shape[0] - 1):
        for r in range(cuts[b], cuts[b + 1]):
            if rows[r]:
                out[b, frame[r]] += weight[r]


def _summarise_bits(bits, weights, selected, frame, frame_weight, n_frames) -> MatrixSummary:
    """:func:`summarise` of a :class:`~camplace.visibility.bits.BitMatrix` (same figures: each
    selected column's frame sums are added in row order)."""
    from camplace.visibility.bits import pack_rows

    m, n = bits.shape
    sel = [int(j) for j in selected]
    frame = np.zeros(m, dtype=np.int64) if frame is None else np.asarray(frame, dtype=np.int64)
    fw = np.asarray(weights if frame_weight is None else frame_weight, dtype=np.float64)
    n_frames = max(1, int(n_frames))
    live = pack_rows(np.asarray(weights) > 0)
    col_live = np.zeros(n, dtype=np.bool_)
    run_blocks(lambda lo, hi: (_touch_live(bits.words, live, lo, hi, col_live), bits.release_columns(lo, hi)),
               cuts(n, 64), thread_count() if m * n >= 8 * PARALLEL_MIN_NNZ else 1)
    covered = np.zeros(m, dtype=np.bool_)
    seen = np.zeros((max(1, len(sel)), n_frames), dtype=np.float64)
    row_cuts = np.array(cuts(m, BLOCKS), dtype=np.int64)
    for s, j in enumerate(sel):
        rows = bits.column(j)
        covered |= rows
        part = np.zeros((row_cuts.size - 1, n_frames), dtype=np.float64)
        _seen_blocks(rows, frame, fw, row_cuts, part)
        for b in range(row_cuts.size - 1):  # the CSR pass's order: rows within a block, then blocks in order
            seen[s] += part[b]
    return MatrixSummary(useful_columns=int(np.count_nonzero(col_live)), covered=covered, seen=seen[:len(sel)])
