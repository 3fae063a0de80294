"""The ``setcover`` mode of :func:`camplace.solver.solve`: the cameras' costs, the credit of the
fixed cameras, the coverable rows, then :func:`camplace.solver.engines.setcover.local_search.solve_cover` (or, with
minimum-distance conflicts, the model of :func:`camplace.solver.engines.mip.mode_models.setcover_model`).
"""

from __future__ import annotations

import logging
import math
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback
from camplace.solver.engines.mip.linear import solve_model
from camplace.solver.engines.mip.mode_models import setcover_model
from camplace.solver.engines.setcover.local_search import solve_cover
from camplace.solver.engines.setcover.reduce_bits import RowBits, row_bits_bytes
from camplace.solver.problem.objectives import coverage_weight
from camplace.solver.problem.presolve import as_pattern
from camplace.solver.problem.presolve_bits import (covered_weight, row_bitsets, row_counts_of, rows_csr,
                                                    rows_csr_bytes)
from camplace.solver.result import EngineOutcome

__all__ = ["setcover"]

log = logging.getLogger(__name__)


def setcover(
    q: sp.csr_matrix, w: np.ndarray, costs: Any, required_fraction: float, fixed_t: tuple[int, ...],
    free_cols: np.ndarray, conflicts: np.ndarray, engine: str, deadline: Deadline,
    seed: int = 0, iterations: int | None = None,
) -> EngineOutcome:
    """Minimum-cost cover: the cost of the new cameras and a LOWER bound.

    Without minimum-distance conflicts: :func:`camplace.solver.engines.setcover.local_search.solve_cover`
    (reductions, local search, Lagrangian bound, then SCIP / CP-SAT with the local-search cover as
    hint and cutoff where it applies). With conflicts: the SCIP / CP-SAT model directly.

    ``q`` is the (m, n) CSR matrix, or a binary matrix as column bitsets
    (:class:`camplace.visibility.bits.BitMatrix`): then the coverable and fixed-covered rows are
    counted from the bits and only the rows left to cover become row bitsets
    (:func:`_bits_row_sets`), which :func:`solve_cover` reduces on bitsets (the same reduced
    instance as the CSR route's); with minimum-distance conflicts (the model reads CSR rows) the
    CSR pattern of those rows (:func:`_bits_rows`). Never the whole matrix's pattern.
    """
    m, n = q.shape
    if engine == "exact":
        raise CamplaceError("the exact engine does not solve setcover; use engine auto, mip or cpsat")
    name = "mip" if engine == "auto" else engine
    c = np.ones(n) if costs is None else np.asarray(costs, dtype=np.float64)
    if c.shape != (n,) or not np.all(np.isfinite(c)) or np.any(c < 0):
        raise CamplaceError(f"costs must be ({n},) finite values >= 0, got shape {c.shape}")
    frac = float(required_fraction)
    bits = getattr(q, "format", None) == "bits"
    if bits:  # a binary matrix as column bitsets: the counts from the bits, the rows to cover as row bitsets
        covered_f = q.union(fixed_t) if fixed_t else np.zeros(m, dtype=bool)
        free_count = row_counts_of(q, free_cols)
        obs_allowed = (free_count > 0) | covered_f  # allowed = free and fixed columns
    else:
        pat = as_pattern(q)
        allowed = np.zeros(n, dtype=bool)
        allowed[free_cols] = True
        allowed[list(fixed_t)] = True
        if allowed.all():  # no column copy of a large matrix when every camera may be used
            obs_allowed = np.diff(pat.indptr) > 0
        else:
            obs_allowed = np.diff(pat[:, np.flatnonzero(allowed)].tocsr().indptr) > 0
        covered_f = (np.diff(pat[:, list(fixed_t)].tocsr().indptr) > 0) if fixed_t else np.zeros(m, dtype=bool)
    pos_w = w > 0
    unc = pos_w & ~obs_allowed
    coverable_w = float(w[pos_w & obs_allowed].sum())
    stats: dict[str, Any] = {
        "uncoverable_points": int(unc.sum()),
        "uncoverable_weight": float(w[unc].sum()),
        "coverable_weight": coverable_w,
        "required_fraction": frac,
    }
    credit = float(w[covered_f & pos_w].sum())
    need = frac * coverable_w - credit
    rows = pos_w & obs_allowed & ~covered_f
    if bits and conflicts.size == 0:  # the search reduces the row bitsets itself: no CSR of the rows
        sub = _bits_row_sets(q, rows, free_cols)
    elif bits:
        sub = _bits_rows(q, rows, free_cols, int(free_count[rows].sum()))
    else:
        sub = (pat if free_cols.size == n else pat[:, free_cols].tocsr())[rows]
    sw = w[rows]

    def finish(sel_free: Sequence[int], status: str, bound: float,
               used: str = name) -> EngineOutcome:
        sel = tuple(sorted(set(fixed_t) | {int(free_cols[j]) for j in sel_free}))
        cov = (covered_weight(q, w, sel) if bits else coverage_weight(pat, w, sel)) if sel else 0.0
        stats["covered_fraction"] = cov / coverable_w if coverable_w > 0 else 1.0
        stats["covered_weight"] = cov
        cost = float(sum(c[j] for j in sel if j not in set(fixed_t)))
        return EngineOutcome(sel, status, bound, stats, engine=used, objective=cost)

    if sub.shape[0] == 0 or need <= 1e-12 * max(coverable_w, 1e-300):
        return finish((), "optimal", 0.0)
    if conflicts.size == 0:
        out = solve_cover(sub, c[free_cols], sw if frac < 1.0 else None, need if frac < 1.0 else None, engine=engine,
                          deadline=deadline, seed=seed, max_iterations=iterations)
        stats["setcover"] = out.stats
        if out.selected is None:
            return EngineOutcome(None, "unknown", out.bound, stats, engine=out.engine, objective=math.nan)
        return finish(out.selected, out.status, out.bound, out.engine)
    model, x, rows_after = setcover_model(sub, sw, c[free_cols], free_cols, conflicts, frac, need, coverable_w)
    out = solve_model(model, name, deadline=deadline)
    stats["engine_stats"] = dict(out.stats)
    stats["rows_after"] = rows_after
    if out.values is None:
        st = "infeasible" if out.status == "infeasible" else "unknown"
        finish((), st, -math.inf)  # the coverage entries of stats
        return EngineOutcome(None, st, out.bound, stats, engine=name, objective=math.nan)
    sel_free = [int(j) for j in np.flatnonzero(out.values[x] > 0.5)]
    bound = out.bound
    if np.all(c == np.rint(c)) and math.isfinite(bound):
        bound = math.ceil(bound - 1e-6)  # integral costs: the optimum is an integer
    status = out.status
    if frac < 1.0:
        got = float(sw[np.diff(sub[:, sel_free].tocsr().indptr) > 0].sum()) if sel_free else 0.0
        if got < need - 1e-9 * max(coverable_w, 1e-300):
            log.warning("setcover: the %s answer misses the required weight by %.3g (integer rounding)", name, need - got)
            status = "unknown"
    return finish(sel_free, status, bound)


def _bits_row_sets(bits: Any, rows: np.ndarray, free_cols: np.ndarray) -> RowBits:
    """The rows to cover (``rows`` (m,) bool) over the free columns of a BitMatrix as row bitsets
    (:class:`~camplace.solver.engines.setcover.reduce_bits.RowBits`, ``r x ceil(c / 64)`` words,
    bit ``t`` = column ``free_cols[t]``), which :func:`solve_cover` reduces without CSR lists;
    checked against the memory budget first."""
    r = int(np.count_nonzero(rows))
    need, budget = row_bits_bytes(r, free_cols.size), memory_budget_bytes()
    if need > budget:  # nothing answers without it: a one-line error
        memory_fallback(OverBudget(need, budget, f"the set-cover rows as bitsets ({r} x {free_cols.size})"),
                        None, asked=True, then=None, fix="use fewer candidates / points")
    return RowBits(row_bitsets(bits, np.flatnonzero(rows), free_cols), free_cols.size)


def _bits_rows(bits: Any, rows: np.ndarray, free_cols: np.ndarray, nnz: int) -> sp.csr_matrix:
    """The rows to cover (``rows`` (m,) bool) over the free columns of a BitMatrix as the CSR
    pattern the search reads (the CSR route's ``as_pattern(q)[:, free_cols][rows]``, the same
    arrays), checked against the memory budget first (``nnz``: its observed pairs)."""
    r = int(np.count_nonzero(rows))
    need, budget = rows_csr_bytes(r, free_cols.size, nnz), memory_budget_bytes()
    if need > budget:  # nothing answers without it: a one-line error
        memory_fallback(OverBudget(need, budget, f"the set-cover rows as CSR ({r} x {free_cols.size}, {nnz} nonzeros)"),
                        None, asked=True, then=None, fix="use fewer candidates / points")
    return rows_csr(bits, np.flatnonzero(rows), free_cols)
