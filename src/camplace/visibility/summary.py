"""One read-only pass over a run's matrix for what the run reports besides the optimum.

The warnings (how many candidates observe a live point), the coverage figures (the rows the chosen
cameras observe) and ``light_curves.csv`` (what each chosen camera observes, frame by frame) all
come from one compiled pass over the CSR arrays, on every allowed core, without a copy or a
transpose of the matrix (:func:`summarise`). Rows are cut into a fixed number of blocks that does
not depend on the thread count, and the blocks' partial sums are added in block order, so the
figures are the same bits at every thread count.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numba
import numpy as np

__all__ = ["MatrixSummary", "summarise"]

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}
_PJIT = dict(_JIT, parallel=True)
#: row blocks of the pass (fixed, so that sums do not depend on the thread count)
BLOCKS = 64


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


@numba.njit(**_PJIT)
def _pass(indptr, indices, live, slot, n_cols, n_sel, frame, weight, n_frames, cuts):  # pragma: no cover - compiled
    """The pass: per row block (in parallel), then the blocks' partial results added in block order."""
    n_blocks = len(cuts) - 1
    col_live = np.zeros((n_blocks, n_cols), dtype=np.bool_)
    seen = np.zeros((n_blocks, max(1, n_sel), n_frames), dtype=np.float64)
    covered = np.zeros(len(indptr) - 1, dtype=np.bool_)
    for b in numba.prange(n_blocks):
        _block(cuts[b], cuts[b + 1], indptr, indices, live, slot, frame, weight, col_live[b], seen[b], covered)
    useful = np.zeros(n_cols, dtype=np.bool_)
    total = np.zeros((max(1, n_sel), n_frames), dtype=np.float64)
    for b in range(n_blocks):  # in block order: the same sums at every thread count
        for c in range(n_cols):
            useful[c] |= col_live[b, c]
        total += seen[b]
    return int(useful.sum()), covered, total[:n_sel]


def summarise(matrix, weights: np.ndarray, selected: Sequence[int], frame: np.ndarray | None = None,
              frame_weight: np.ndarray | None = None, n_frames: int = 1) -> MatrixSummary:
    """Read the warnings' column count, the covered rows and the light curves in one pass.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix
        Any values; an entry counts as observed (stored zeros do not occur in camplace's matrices).
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
    m, n = matrix.shape
    sel = np.asarray(list(selected), dtype=np.int64)
    slot = np.full(n, -1, dtype=np.int64)
    slot[sel] = np.arange(len(sel))
    frame = np.zeros(m, dtype=np.int64) if frame is None else np.asarray(frame, dtype=np.int64)
    fw = np.asarray(weights if frame_weight is None else frame_weight, dtype=np.float64)
    blocks = max(1, min(BLOCKS, m))
    cuts = np.asarray([m * b // blocks for b in range(blocks + 1)], dtype=np.int64)
    useful, covered, seen = _pass(matrix.indptr, matrix.indices, np.asarray(weights) > 0, slot, n, len(sel), frame, fw,
                                  max(1, int(n_frames)), cuts)
    return MatrixSummary(useful_columns=int(useful), covered=covered, seen=seen)
