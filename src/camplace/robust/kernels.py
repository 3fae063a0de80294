"""Compiled passes of the p10 objective over stacked scenario bits (:mod:`camplace.robust.p10`).

The stacked matrix is a :class:`camplace.visibility.bits.BitMatrix` of ``S * m`` rows (row
``s * m + i``: point ``i`` in scenario ``s``) and ``n`` columns. The kernels are GIL-free and run on
the block pool (:func:`camplace._blocks.run_blocks`) over fixed blocks of columns; each column's
sums are made by one thread in increasing row order, so the result is the same at every thread count.
"""

from __future__ import annotations

import numba
import numpy as np

from camplace._bitops import ctz as _ctz
from camplace._blocks import cuts, run_blocks
from camplace._cores import thread_count

__all__ = ["completion_weights", "completion_weights_bytes"]

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}


@numba.njit(**_JIT)
def _completion_sums(words, mask, u, m, lo, hi, out):  # pragma: no cover - compiled
    """``out[j, s] = sum of u[r]`` over the rows r of mask in column j with ``r // m == s``, for
    columns ``lo:hi``, each sum from 0.0 in increasing row order."""
    nw = words.shape[1]
    for j in range(lo, hi):
        for w in range(nw):
            x = words[j, w] & mask[w]
            base = np.int64(w) << 6
            while x:
                r = base + np.int64(_ctz(x))
                out[j, r // m] += u[r]
                x &= x - np.uint64(1)


def completion_weights_bytes(rows: int, n: int, scenarios: int) -> int:
    """Bytes of :func:`completion_weights`'s output and row mask: ``8 n S`` and ``rows / 8``."""
    return int(8 * n * scenarios + 8 * ((rows + 63) // 64))


def completion_weights(bits, u: np.ndarray, scenarios: int, workers: int | None = None) -> np.ndarray:
    """Per column and scenario, the weight of that scenario's rows the column observes: ``P^T U``
    for ``P`` the stacked pattern and ``U[r, s] = u[r]`` when row r is in scenario s.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (S * m, n) stacked scenario bits.
    u : (S * m,) float64
        Row values (>= 0; rows at 0 are skipped: a bit mask of the rows with ``u != 0`` is ANDed
        with each column's words).
    scenarios : int
        S.
    workers : int, optional
        Threads over blocks of columns (the sums do not depend on it).

    Returns
    -------
    (n, S) float64
        Each sum taken from 0.0 in increasing row order: the floats scipy's ``(P.T @ U)`` of the
        CSR pattern gives (it adds the entries of U's column s in row order).
    """
    rows, n = bits.shape
    s_count = int(scenarios)
    u = np.ascontiguousarray(u, dtype=np.float64).reshape(-1)
    if u.shape != (rows,) or s_count < 1 or rows % s_count:
        raise ValueError(f"completion_weights: u must be ({rows},) over {s_count} equal scenario blocks, got {u.shape}")
    m = rows // s_count
    out = np.zeros((n, s_count), dtype=np.float64)
    nz = u != 0
    if rows == 0 or not nz.any():
        return out
    mask = np.zeros(bits.words.shape[1] * 8, dtype=np.uint8)
    packed = np.packbits(nz, bitorder="little")
    mask[:packed.size] = packed
    mask = mask.view(np.uint64)
    run_blocks(lambda lo, hi: (_completion_sums(bits.words, mask, u, m, lo, hi, out), bits.release_columns(lo, hi)),
               cuts(n), thread_count(workers))
    return out
