"""Plain maximum coverage: exactly k columns maximising the weight of the covered rows."""

from __future__ import annotations

import logging
import numbers
import time
from typing import Any

from camplace.errors import CamplaceError
from camplace.names import ENGINES
from camplace.solver._common import check_engine_and_limit, coverage_weight
from camplace.solver._dispatch import run_maxcover_engine
from camplace.solver.bitset_exact import BITSET_MAX_K as EXACT_MAX_K
from camplace.solver.presolve import canonical_csr, check_weights, presolve
from camplace.solver.result import SolverResult, jsonable, relative_gap

__all__ = ["solve_maxcover"]

log = logging.getLogger(__name__)

def _check_k(k: Any, n: int) -> int:
    if isinstance(k, bool) or not isinstance(k, numbers.Integral):
        raise CamplaceError(f"k must be an integer number of cameras, got {k!r}")
    k = int(k)
    if k < 1:
        raise CamplaceError(f"k must be at least 1, got {k}")
    if k > n:
        raise CamplaceError(f"cannot choose k={k} cameras from only {n} candidates (lower k or add candidates)")
    return k


def solve_maxcover(
    matrix: Any,
    weights: Any,
    k: int,
    *,
    engine: str = "auto",
    time_limit_s: float | None = None,
) -> SolverResult:
    """Choose exactly ``k`` columns maximising the weight of the covered rows.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Visibility / observation quality; any value > 0 means "the candidate observes the point".
    weights : (m,) array_like of float64
        Non-negative point weights.
    k : int
        Number of cameras to choose, ``1 <= k <= n``.
    engine : {"auto", "exact", "mip", "cpsat"}
        ``auto`` uses ``exact`` for ``k <= 4`` and ``mip`` otherwise.
    time_limit_s : float, optional
        Wall-clock limit for the whole solve (presolve included). When it expires the best
        solution found is returned with status ``"feasible"`` and a valid bound.

    Returns
    -------
    SolverResult
        ``selected`` are sorted original column indices; ``objective`` is recomputed in float64 on
        the original matrix.

    Raises
    ------
    CamplaceError
        For ``k < 1``, ``k > n``, an unknown engine, a non-positive time limit, or malformed input.
    """
    t0 = time.perf_counter()
    check_engine_and_limit(engine, ENGINES, time_limit_s)
    pattern = canonical_csr(matrix)
    m, n = pattern.shape
    if n == 0:
        raise CamplaceError("the visibility matrix has no candidate columns")
    k = _check_k(k, n)
    w = check_weights(weights, m)

    pre = presolve(pattern, w, k)
    name = engine if engine != "auto" else ("exact" if k <= EXACT_MAX_K else "mip")
    remaining = None if time_limit_s is None else max(1e-3, float(time_limit_s) - (time.perf_counter() - t0))
    fallback: dict[str, Any] = {}
    name, out = run_maxcover_engine(name, engine, pre, remaining, fallback)

    selected = pre.original_columns(out.selected) if out.selected else ()
    if selected and len(selected) != k:
        raise RuntimeError(f"engine {name} returned {len(selected)} columns instead of {k}")
    objective = coverage_weight(pattern, w, selected) if selected else 0.0
    status = out.status
    if status == "optimal":
        bound = objective
        gap = 0.0
    elif selected:
        bound = max(float(out.bound), objective)
        gap = relative_gap(bound, objective)
    else:
        bound = float(out.bound)
        gap = float("inf")
    stats: dict[str, Any] = {
        "engine_requested": engine,
        "k": k,
        "rows_in": int(m),
        "cols_in": int(n),
        "rows_after": pre.shape[0],
        "cols_after": pre.shape[1],
        "presolve": dict(pre.stats),
        "engine_stats": dict(out.stats),
        "engine_bound": float(out.bound),
        **fallback,
    }
    elapsed = time.perf_counter() - t0
    log.info(
        "maxcover k=%d (%dx%d -> %dx%d) engine=%s: %s objective %.9g bound %.9g gap %.3g in %.3f s",
        k,
        m,
        n,
        pre.shape[0],
        pre.shape[1],
        name,
        status,
        objective,
        bound,
        gap,
        elapsed,
    )
    return SolverResult(
        selected=tuple(int(j) for j in selected),
        status=status,
        objective=float(objective),
        bound=float(bound),
        gap=float(gap),
        engine=name,
        time_s=elapsed,
        stats=jsonable(stats),
    )
