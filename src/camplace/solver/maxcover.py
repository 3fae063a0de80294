"""Plain maximum coverage: exactly k columns maximising the weight of the covered rows.

:func:`solve_maxcover` is the short form of ``solve(matrix, weights, k, mode="maxcover")``
(:func:`camplace.solver.modes.solve`): the same checks, engine choice, memory fallbacks and
result, without fixed / forbidden cameras or a minimum distance.
"""

from __future__ import annotations

from typing import Any

from camplace.solver.modes import solve
from camplace.solver.result import SolverResult

__all__ = ["solve_maxcover"]


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
        ``auto`` is :func:`camplace.solver.choose.choose_engine`'s choice: ``exact`` for
        ``k <= 4``, the large-k engines for ``4 < k <= 8`` and ``mip`` otherwise (and wherever
        an exact engine would not fit in memory).
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
    return solve(matrix, weights, k, mode="maxcover", engine=engine, time_limit_s=time_limit_s)
