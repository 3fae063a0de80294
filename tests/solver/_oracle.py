"""Test oracles for the solver: exhaustive enumeration and instance generators."""

from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp
from hypothesis import strategies as st


def brute_force(matrix: sp.spmatrix | np.ndarray, weights: np.ndarray, k: int) -> tuple[float, list[tuple[int, ...]]]:
    """Optimum of max coverage by enumerating every k-subset.

    Parameters
    ----------
    matrix : (m, n) sparse or dense
        Values > 0 mean "observes".
    weights : (m,) float64
    k : int

    Returns
    -------
    best : float
        Optimal covered weight.
    optimal_sets : list of tuple of int
        Every k-subset attaining it (to within 1e-12 relative).
    """
    dense = (matrix.toarray() if sp.issparse(matrix) else np.asarray(matrix)) > 0
    m, n = dense.shape
    w = np.asarray(weights, dtype=np.float64)
    combos = np.array(list(itertools.combinations(range(n), k)), dtype=np.int64).reshape(-1, k)
    values = np.zeros(combos.shape[0])
    for c0 in range(0, combos.shape[0], 4096):
        block = combos[c0 : c0 + 4096]
        covered = dense[:, block].any(axis=2)  # (m, b)
        values[c0 : c0 + 4096] = w @ covered
    best = float(values.max()) if values.size else 0.0
    tol = 1e-12 * max(1.0, abs(best))
    sets = [tuple(int(j) for j in combos[i]) for i in np.flatnonzero(values >= best - tol)]
    return best, sets


def tolerance(weights: np.ndarray) -> float:
    """Comparison tolerance: the exact engine's float64 pruning margin plus rounding."""
    return 2e-9 * float(np.sum(weights)) + 1e-12


@st.composite
def small_instances(
    draw: st.DrawFn, max_n: int = 30, max_m: int = 40, max_k: int = 4
) -> tuple[sp.csr_matrix, np.ndarray, int]:
    """Random small instances with near-duplicate columns, identical rows and zero weights."""
    n0 = draw(st.integers(1, max_n))
    m = draw(st.integers(0, max_m))
    k = draw(st.integers(1, min(max_k, n0)))
    density = draw(st.sampled_from([0.05, 0.15, 0.3, 0.5, 0.8]))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    dense = (rng.random((m, n0)) < density) * rng.uniform(0.01, 1.0, size=(m, n0))
    # Near-duplicate and exact duplicate columns (neighbouring camera positions).
    n_dup = draw(st.integers(0, max(0, max_n - n0)))
    for _ in range(n_dup):
        col = dense[:, rng.integers(0, n0)].copy() if n0 else np.zeros(m)
        flips = int(rng.integers(0, 3)) if m else 0
        for i in rng.integers(0, max(m, 1), size=flips):
            col[i] = 0.0 if col[i] > 0 else 0.7
        dense = np.column_stack([dense, col])
    # Identical rows.
    if m >= 2:
        for _ in range(draw(st.integers(0, m // 2))):
            dense[rng.integers(0, m)] = dense[rng.integers(0, m)]
    kind = draw(st.sampled_from(["equal", "integer", "float", "tiny"]))
    if kind == "equal":
        w = np.full(m, 1.0 / max(m, 1))
    elif kind == "integer":
        w = rng.integers(0, 6, size=m).astype(np.float64)
    elif kind == "float":
        w = rng.uniform(0.0, 1.0, size=m)
    else:
        w = rng.uniform(0.0, 1e-6, size=m)
    for i in rng.choice(m, size=min(m, draw(st.integers(0, 5))), replace=False) if m else []:
        w[i] = 0.0
    return sp.csr_matrix(dense), w, k
