"""Quality straight from quantised columns: a graded run's matrix as the visibility stage made it
(``camplace.visibility.qbytes.ByteMatrix``: ``values`` (n, m) uint8, a byte q standing for the
quality ``q * scale``, ``scale = 1 / 255``), without a CSR copy (issue 32).

:func:`bytes_outcome` takes plain ``quality`` (no fixed, forbidden, minimum-distance or
minimum-angle constraints, no team) with ``k <= 4`` where :func:`~camplace.solver.choose.choose_engine`
would run the quantised tree alone (the min-Gram engine does not apply): the tree engine
(:func:`~camplace.solver.engines.quality.tree.solve_quality_tree_dense`) reads the columns as its
leaves and adds only its inner nodes' table (over the memory budget: rows for the clusters of
more than 2, 4, ..., 64 cameras only, whichever fits; the smaller clusters' bounds read their
columns). The answer is exact for the quantised values: the
objective is ``sum_i w_i max_{j in S} q_ij / 255`` in float64, and the bound an upper bound on the
same. (For the float qualities the bytes stand for, every value differs by at most 1 / 510, so
every objective by at most ``sum_i w_i / 510``: see :mod:`camplace.visibility.qbytes`.)

:func:`bytes_pattern` gives the modes that read only the pattern (``maxcover``, ``multiview``,
``setcover``) its column bitsets; any other case converts to CSR float32 (``q / 255``, 8 bytes an
observed pair, checked against the memory budget first).
"""

from __future__ import annotations

import logging
import numbers
from typing import Any

import numpy as np

from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback
from camplace.solver.choose import EXACT_MAX_K
from camplace.solver.engines.quality.min_gram import QUALITY_EXACT_MAX_N
from camplace.solver.engines.quality.tree import (GROUP_MAX, dense_table_group, quality_tree_bytes_dense,
                                                  solve_quality_tree_dense)
from camplace.solver.options import SolveOptions
from camplace.solver.problem.presolve import check_weights
from camplace.solver.result import EngineOutcome

__all__ = ["bytes_applies", "bytes_outcome", "bytes_fallback"]

log = logging.getLogger(__name__)

PATTERN_MODES = ("maxcover", "multiview", "setcover")


def bytes_applies(o: SolveOptions, n: int) -> bool:
    """True for plain quality (no fixed, forbidden, distance, angle or team) with ``k <= 4``, under
    engine ``auto`` or ``exact``, where the quantised tree runs alone (``k`` of 1 or 4, or more
    than :data:`~camplace.solver.engines.quality.min_gram.QUALITY_EXACT_MAX_N` candidates)."""
    k = o.k
    if o.mode != "quality" or o.fixed or o.forbidden or o.min_distance_m is not None or o.min_angle_deg is not None:
        return False
    if getattr(o, "team", None) is not None or o.engine not in ("auto", "exact"):
        return False
    if k is None or isinstance(k, bool) or not isinstance(k, numbers.Integral) or not 1 <= int(k) <= EXACT_MAX_K:
        return False
    return int(k) not in (2, 3) or n > QUALITY_EXACT_MAX_N


def bytes_outcome(qbytes, weights: Any, o: SolveOptions, deadline: Deadline):
    """Solve plain quality on quantised columns with the quantised tree.

    Parameters
    ----------
    qbytes : camplace.visibility.qbytes.ByteMatrix
        (m, n) quantised qualities (``values`` (n, m) uint8, ``scale``).
    weights : (m,) array_like of float64
    o : SolveOptions
        Checked options with :func:`bytes_applies`.
    deadline : Deadline

    Returns
    -------
    (EngineOutcome, (m,) float64 weights) or None
        None when the tree's table does not fit in the memory budget (the caller converts).
    """
    m, n = qbytes.shape
    if n == 0:
        raise CamplaceError("the visibility matrix has no candidate columns")
    w = check_weights(weights, m)
    k = int(o.k)
    if k > n:
        raise CamplaceError(f"cannot choose k={k} new cameras from {n} allowed candidates "
                            "(lower k, or forbid/fix fewer cameras)")
    budget = memory_budget_bytes()
    group = dense_table_group(m, n, budget)  # the full table when it fits, else rows for larger clusters only
    stats: dict[str, Any] = {"k": k}
    if group is None:
        need = quality_tree_bytes_dense(m, n, GROUP_MAX)
        memory_fallback(OverBudget(need, budget, "the quantised tree"), stats, asked=o.engine == "exact",
                        then="converting the matrix for the other engines", fix="use fewer candidates / points")
        return None
    if group > 1:
        log.info("quality tree (bytes): the full table (%.2f GiB) is over the memory budget (%.2f GiB): rows for "
                 "clusters of more than %d cameras only (%.2f GiB)", quality_tree_bytes_dense(m, n) / 2**30,
                 budget / 2**30, group, quality_tree_bytes_dense(m, n, group) / 2**30)
    stats["engine_choice"] = {"engine": "exact", "route": "quality-bytes",
                              "reason": f"{'requested' if o.engine == 'exact' else 'auto'}: quality without side "
                                        f"constraints, k = {k}: the quantised tree on the stored bytes"}
    out = solve_quality_tree_dense(qbytes.values, qbytes.scale, w, k, deadline=deadline, group=group)
    sel = tuple(sorted(int(j) for j in out.selected))
    top = np.zeros(m, dtype=np.uint8)
    for j in sel:
        np.maximum(top, qbytes.values[j], out=top)
    objective = float(w @ (top.astype(np.float64) * qbytes.scale))
    stats.update({"quality_engines": ["tree-bytes"], "engine_stats": dict(out.stats),
                  "quantised": {"step": qbytes.scale, "max_error_per_value": qbytes.scale / 2}})
    return EngineOutcome(sel, out.status, float(out.bound), stats, engine="exact", objective=objective), w


def bytes_fallback(qbytes, o: SolveOptions):
    """What the other routes read instead of quantised columns: the pattern's column bitsets for the
    modes that read only the pattern, else CSR float32 values ``q * scale`` (checked against the
    memory budget: 8 bytes an observed pair)."""
    if o.mode in PATTERN_MODES:
        return qbytes.bits()
    need, budget = 8 * int(qbytes.nnz), memory_budget_bytes()
    if need > budget:
        memory_fallback(OverBudget(need, budget, "the float32 values of the quantised matrix"), None, asked=False,
                        then=None, fix="use fewer candidates / points")
    return qbytes.tocsr(np.float32)
