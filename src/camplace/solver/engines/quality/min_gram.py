"""Exact engine for the ``quality`` mode with k = 2 or 3 cameras: bound-pruned triple enumeration.

With ``q_j`` the quality column of camera j, ``f_j = sum_i w_i q_ij`` and the weighted min-Gram
``M_ab = sum_i w_i min(q_ia, q_ib)``:

* a pair is exact: ``value(a, b) = f_a + f_b - M_ab`` (``max = x + y - min``);
* a triple satisfies ``max(x, y, z) = x + y + z - min(x,y) - min(x,z) - min(y,z) + min(x,y,z)`` and
  ``min(x,y,z) <= min`` of any pair, so

      value(a, b, c) <= f_a + f_b + f_c - M_ab - M_ac - M_bc + min(M_ab, M_ac, M_bc),

  and for every camera a of the triple ``value <= f_a + (f_b - M_ab) + (f_c - M_ac)``.

Triples ``a < b < c`` are enumerated in a compiled loop; a triple whose bound beats the incumbent is
scored exactly on the dense quality matrix, and a first column a whose bound
``f_a + top-2 (f_b - M_ab)`` cannot beat the incumbent is skipped. The incumbent comes from the
best pair, a greedy third camera and swap local search. A time limit is checked between blocks of
first columns; the bound returned then is the largest first-column bound left.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace.solver._support.deadline import Deadline, as_deadline, stopwatch
from camplace.solver.result import EngineOutcome

__all__ = ["solve_quality_exact", "min_gram_cost", "quality_exact_bytes", "QUALITY_EXACT_MAX_N", "QUALITY_EXACT_MAX_PAIRS"]

log = logging.getLogger(__name__)

QUALITY_EXACT_MAX_N = 3000  # auto uses this engine up to this many candidates (n^3 / 6 triple loop)
QUALITY_EXACT_MAX_PAIRS = 5e9  # ... and up to this many (row, camera, camera) terms in the min-Gram
_MARGIN = 1e-9
_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}


@numba.njit(**_JIT)
def _min_gram(indptr, indices, data, w, n):  # pragma: no cover - compiled
    """(n, n) float64: ``M_ab = sum_i w_i min(q_ia, q_ib)`` (symmetric; diagonal ``f_a``)."""
    out = np.zeros((n, n))
    for i in range(indptr.shape[0] - 1):
        s, e = indptr[i], indptr[i + 1]
        wi = w[i]
        if wi == 0.0:
            continue
        for p in range(s, e):
            a = indices[p]
            qa = data[p]
            out[a, a] += wi * qa
            for r in range(p + 1, e):
                b = indices[r]
                v = wi * min(qa, data[r])
                out[a, b] += v
                out[b, a] += v
    return out


@numba.njit(**_JIT)
def _triple_value(qt, w, a, b, c):  # pragma: no cover - compiled
    """``sum_i w_i max(q_ia, q_ib, q_ic)`` with ``qt`` the (n, m) transposed dense matrix."""
    s = 0.0
    ra, rb, rc = qt[a], qt[b], qt[c]
    for i in range(w.shape[0]):
        s += w[i] * max(ra[i], max(rb[i], rc[i]))
    return s


@numba.njit(**_JIT)
def _scan(firsts, f, mg, qt, w, best, margin, out_set):  # pragma: no cover - compiled
    """Every triple ``a < b < c`` with a in ``firsts``: exact value where the bound beats ``best``.

    Returns the (possibly improved) best value; ``out_set`` receives its triple. Also the number
    of exact evaluations.
    """
    n = f.shape[0]
    evals = 0
    for t in range(firsts.shape[0]):
        a = firsts[t]
        fa = f[a]
        for b in range(a + 1, n):
            mab = mg[a, b]
            gb = f[b] - mab
            for c in range(b + 1, n):
                mac = mg[a, c]
                mbc = mg[b, c]
                bound = fa + gb + f[c] - mac - mbc + min(mab, min(mac, mbc))
                if bound > best + margin:
                    evals += 1
                    v = _triple_value(qt, w, a, b, c)
                    if v > best:
                        best = v
                        out_set[0] = a
                        out_set[1] = b
                        out_set[2] = c
    return best, evals


def quality_exact_bytes(m: int, n: int) -> int:
    """Approximate working memory for ``m`` rows and ``n`` columns: the dense transposed matrix
    (and its float64 temporary) and the (n, n) min-Gram with the pair table."""
    return 16 * m * n + 24 * n * n


def min_gram_cost(matrix: sp.csr_matrix) -> float:
    """Work of the min-Gram: ``sum_i s_i (s_i - 1) / 2`` over rows with ``s_i`` observers."""
    s = np.diff(sp.csr_matrix(matrix).indptr).astype(np.float64)
    return float(np.sum(s * (s - 1) / 2))


def _value(qt: np.ndarray, w: np.ndarray, cols: list[int]) -> float:
    return float(w @ qt[cols].max(axis=0))


def _local_search(qt: np.ndarray, w: np.ndarray, sel: list[int], rounds: int = 50) -> list[int]:
    """First-improvement 1-swap on exact values (one product per position)."""
    k = len(sel)
    cur = _value(qt, w, sel)
    for _ in range(rounds):
        improved = False
        for p in range(k):
            others = [sel[j] for j in range(k) if j != p]
            base = qt[others].max(axis=0) if others else np.zeros(qt.shape[1], dtype=qt.dtype)
            gains = np.maximum(qt - base[None, :], 0.0) @ w + float(w @ base)
            gains[others] = -math.inf
            j = int(np.argmax(gains))
            if gains[j] > cur * (1 + 1e-12) + 1e-300:
                sel[p] = j
                cur = float(gains[j])
                improved = True
        if not improved:
            break
    return sel


def solve_quality_exact(matrix: sp.csr_matrix, weights: np.ndarray, k: int, *,
                        deadline: Deadline | None = None) -> EngineOutcome:
    """Best ``k`` (2 or 3) columns for ``sum_i w_i max_{j in S} Q_ij``.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix
        Quality values >= 0 (0 = not observed).
    weights : (m,) float64
    k : int
        2 or 3 (at most n).
    deadline : Deadline, optional
        The solve's deadline (default: none); on expiry the best triple found comes back with
        status "feasible" and a valid bound.

    Returns
    -------
    EngineOutcome
        ``selected`` are column indices of ``matrix``; ``bound`` is an upper bound on the optimum.
    """
    if k not in (2, 3):
        raise ValueError("the quality engine chooses 2 or 3 cameras")
    deadline = as_deadline(deadline)
    since = stopwatch(deadline)
    q = sp.csr_matrix(matrix, dtype=np.float64)
    q.sort_indices()
    m, n = q.shape
    w = np.asarray(weights, dtype=np.float64)
    if n <= k:
        cols = list(range(n))
        val = float(w @ q.max(axis=1).toarray().ravel()) if n else 0.0
        return EngineOutcome(selected=tuple(cols), status="optimal", bound=val, stats={"trivial": True})
    margin = _MARGIN * float(w.sum())
    with ctrl_c_deferred():
        mg = _min_gram(q.indptr, q.indices, q.data, w, n)
    f = np.diagonal(mg).copy()
    stats: dict[str, Any] = {"time_min_gram_s": since()}
    if k == 2:
        pair = f[:, None] + f[None, :] - mg
        np.fill_diagonal(pair, -math.inf)
        a, b = divmod(int(np.argmax(pair)), n)
        return EngineOutcome(selected=tuple(sorted((a, b))), status="optimal", bound=float(pair[a, b]), stats=stats)
    # (n, m): a camera's qualities contiguous; float32 input (visibility matrices) stays float32
    exact32 = sp.issparse(matrix) and matrix.dtype == np.float32
    qt = np.ascontiguousarray(q.T.toarray(), dtype=np.float32 if exact32 else np.float64)
    # incumbent: the best pair completed greedily, then swaps
    pair = f[:, None] + f[None, :] - mg
    np.fill_diagonal(pair, -math.inf)
    a, b = divmod(int(np.argmax(pair)), n)
    base = np.maximum(qt[a], qt[b])
    third = np.maximum(qt - base[None, :], 0.0) @ w
    third[[a, b]] = -math.inf
    sel = _local_search(qt, w, [a, b, int(np.argmax(third))])
    best = _value(qt, w, sel)
    best_set = tuple(sorted(sel))
    stats["initial_incumbent"] = best
    # per-first-column bounds: f_a + the two largest (f_b - M_ab), b != a
    gain = f[None, :] - mg
    np.fill_diagonal(gain, -math.inf)
    top2 = -np.partition(-gain, 1, axis=1)[:, :2].sum(axis=1)
    ub_a = f + top2
    out_set = np.zeros(3, dtype=np.int64)
    evals = 0
    block = max(1, min(64, n // 16 + 1))
    bound = best
    # Triples a < b < c by their smallest member a, in blocks of first columns (the deadline is
    # checked between blocks); a first column is skipped when ub_a, valid for every triple
    # containing a, cannot beat the incumbent.
    status = "optimal"
    t_scan = since()
    for s0 in range(0, n, block):
        if deadline.expired():
            status = "feasible"
            rest = ub_a[s0:]
            bound = max(best, float(rest.max())) if rest.size else best
            break
        firsts = np.arange(s0, min(n, s0 + block), dtype=np.int64)
        firsts = firsts[ub_a[firsts] > best + margin]
        if firsts.size == 0:
            continue
        with ctrl_c_deferred():
            new_best, e = _scan(firsts, f, mg, qt, w, best, margin, out_set)
        evals += int(e)
        if new_best > best:
            best = float(new_best)
            best_set = tuple(sorted(int(x) for x in out_set))
    if status == "optimal":
        bound = best
    stats.update({"exact_evaluations": evals, "time_scan_s": since() - t_scan, "time_s": since()})
    log.info("quality exact: %dx%d %s value %.9g bound %.9g, %d exact triples, %.3f s", m, n, status, best, bound,
             evals, since())
    return EngineOutcome(selected=best_set, status=status, bound=float(bound), stats=stats)
