"""Input checks of :func:`camplace.solver.solve`: the matrix, index sets, coordinates, and the
candidate pairs closer than the minimum distance.

Every check fails with a one-line :class:`~camplace.errors.CamplaceError`.
"""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError

__all__ = ["values_matrix", "kernel_data", "float_values", "index_set", "coords", "conflict_count", "conflict_pairs",
           "CONFLICT_PAIR_BYTES"]


def values_matrix(matrix: Any) -> sp.csr_matrix:
    """(m, n) CSR keeping only entries > 0 (the observation qualities).

    A canonical CSR matrix of float32/float64 values, all finite and >= 0, is used as it is (a
    visibility matrix can hold 10^8 entries; no copy), and so is a canonical CSR pattern of bool
    data (``load_visibility(..., pattern=True)`` of a binary matrix: True observes); anything else
    is converted to float64.
    """
    if sp.issparse(matrix) and matrix.format == "csr" and matrix.dtype == np.bool_ and matrix.has_canonical_format:
        return matrix
    if sp.issparse(matrix) and matrix.format == "csr" and matrix.dtype in (np.float32, np.float64) \
            and matrix.has_canonical_format:
        data = matrix.data
        if data.size == 0:
            return matrix
        lo, hi = data.min(), data.max()  # NaN propagates into both
        if np.isfinite(lo) and np.isfinite(hi) and lo >= 0:
            return matrix
    if sp.issparse(matrix):
        a = sp.csr_matrix(matrix, dtype=np.float64, copy=True)
    else:
        arr = np.asarray(matrix, dtype=np.float64)
        if arr.ndim != 2:
            raise CamplaceError(f"visibility matrix must be 2-D, got shape {arr.shape}")
        a = sp.csr_matrix(arr)
    if a.data.size and not np.all(np.isfinite(a.data)):
        raise CamplaceError("visibility matrix contains NaN or infinite values")
    a.data[a.data < 0] = 0.0
    a.eliminate_zeros()
    a.sum_duplicates()
    a.sort_indices()
    return a


def kernel_data(matrix: sp.csr_matrix) -> np.ndarray:
    """The values of a checked CSR matrix as the compiled kernels take them: bool data viewed as
    uint8 (no copy), any other as it is."""
    data = np.asarray(matrix.data)
    return data.view(np.uint8) if data.dtype.kind == "b" else data


def float_values(matrix: sp.csr_matrix) -> sp.csr_matrix:
    """A bool pattern from :func:`values_matrix` as float32 ones (the engines that read values:
    quality, the angle engines); any other matrix as it is."""
    if matrix.dtype != np.bool_:
        return matrix
    out = sp.csr_matrix((matrix.data.astype(np.float32), matrix.indices, matrix.indptr), shape=matrix.shape,
                        copy=False)
    out.has_canonical_format = True
    return out


def index_set(values: Any, n: int, name: str) -> tuple[int, ...]:
    out = []
    for v in values or ():
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise CamplaceError(f"{name}: candidate indices must be integers, got {v!r}")
        if not 0 <= int(v) < n:
            raise CamplaceError(f"{name}: candidate index {int(v)} out of range 0..{n - 1}")
        out.append(int(v))
    return tuple(sorted(set(out)))


def coords(arr: Any, rows: int, name: str, what: str) -> np.ndarray:
    a = np.asarray(arr, dtype=np.float64)
    if a.shape != (rows, 3) or not np.all(np.isfinite(a)):
        raise CamplaceError(f"{name} must be a finite ({rows}, 3) array of {what}, got shape {a.shape}")
    return a


#: bytes of a conflicting candidate pair while a solve keeps them: its array row, the greedy's
#: adjacency sets, temporaries
CONFLICT_PAIR_BYTES = 200


def conflict_count(positions: np.ndarray, min_distance_m: float) -> int:
    """Upper bound on the number of candidate pairs closer than ``min_distance_m`` (pairs at most
    that far apart), counted without listing them."""
    from scipy.spatial import cKDTree

    n = positions.shape[0]
    if n < 2 or min_distance_m <= 0:
        return 0
    tree = cKDTree(positions)
    return max(0, (int(tree.count_neighbors(tree, float(min_distance_m))) - n) // 2)


def conflict_pairs(positions: np.ndarray, min_distance_m: float) -> np.ndarray:
    """Candidate pairs closer than ``min_distance_m``.

    Parameters
    ----------
    positions : (n, 3) float64
    min_distance_m : float

    Returns
    -------
    (p, 2) int64
        Pairs ``a < b`` with ``|pos_a - pos_b| < min_distance_m``.
    """
    from scipy.spatial import cKDTree

    if positions.shape[0] < 2 or min_distance_m <= 0:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = cKDTree(positions).query_pairs(float(min_distance_m), output_type="ndarray").astype(np.int64)
    if pairs.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    d = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1)
    pairs = np.sort(pairs[d < min_distance_m], axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
