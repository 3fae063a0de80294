"""The exact quality engines as a portfolio (:func:`quality_engines`): the quantised tree of
:mod:`camplace.solver.engines.quality.tree`, then, if it has not finished within its share of the time,
the min-Gram triple engine of :mod:`camplace.solver.engines.quality.min_gram`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from camplace.solver._support.deadline import Deadline
from camplace.solver.engines.quality.min_gram import min_gram_cost, solve_quality_exact
from camplace.solver.engines.quality.tree import solve_quality_tree
from camplace.solver.result import EngineOutcome

__all__ = ["quality_engines"]

_OPT_TOL = 1e-9
# the tree engine's share of the time when the min-Gram engine could follow
_TREE_FIRST_S = 30.0  # without a time limit
_TREE_FIRST_SHARE = 0.25
_TREE_FIRST_MIN_S = 2.0
# the min-Gram's (row, camera, camera) terms per second, on one thread: it starts only where it
# ends within the time left (it is not interrupted; measured 2.4e8/s, comet-67p-bunker 2,000 x 10,000)
_MIN_GRAM_TERMS_PER_S = 1.0e8


def quality_engines(
    resid: sp.csr_matrix, resid_w: np.ndarray, k: int, tree_ok: bool, gram_ok: bool, fixed_t: tuple[int, ...],
    free_cols: np.ndarray, value: Any, const: float, deadline: Deadline, stats: dict[str, Any],
) -> EngineOutcome:
    """The exact quality engines as a portfolio: the quantised tree first (fast on the spatially
    coherent qualities of real scenes); if it has not proven the optimum within its share of the
    time and the min-Gram triple engine applies (k = 2, 3, small n), that one gets the rest (it does
    not depend on coherence). The better camera set wins; the smaller bound holds for both."""
    runs: list[tuple[str, Any]] = []
    if tree_ok:
        first = deadline
        if gram_ok:  # the tree's share: at most _TREE_FIRST_S without a limit
            left = deadline.remaining()
            first = deadline.within(_TREE_FIRST_S if left is None else max(_TREE_FIRST_MIN_S, _TREE_FIRST_SHARE * left))
        runs.append(("tree", solve_quality_tree(resid, resid_w, k, deadline=first)))
    if gram_ok and (not runs or runs[0][1].status != "optimal") and _gram_fits(resid, deadline, stats):
        runs.append(("min-gram", solve_quality_exact(resid, resid_w, k, deadline=deadline)))
    best = None
    for name, out in runs:
        sel = tuple(sorted(set(fixed_t) | {int(free_cols[j]) for j in out.selected}))
        v = value(sel)
        if best is None or v > best[1] or (out.status == "optimal" and best[2] != "optimal" and v >= best[1]):
            best = (sel, v, out.status)
    assert best is not None
    sel, objective, status = best
    bound = min(float(out.bound) for _, out in runs) + const
    if any(out.status == "optimal" for _, out in runs) or bound <= objective + _OPT_TOL * max(1.0, abs(objective)):
        status, bound = "optimal", objective
    stats["quality_engines"] = [name for name, _ in runs]
    stats["engine_stats"] = dict(runs[0][1].stats)
    if len(runs) > 1:
        stats["engine_stats"]["min_gram"] = dict(runs[1][1].stats)
    return EngineOutcome(sel, status, bound, stats, engine="exact", objective=objective)


def _gram_fits(resid: sp.csr_matrix, deadline: Deadline, stats: dict[str, Any]) -> bool:
    """Whether the min-Gram engine may start: time is left and its min-Gram (not interrupted)
    should end within it at ``_MIN_GRAM_TERMS_PER_S``; else ``stats["min_gram_skipped"]`` says why."""
    left = deadline.remaining()
    if left is None:
        return True
    need = min_gram_cost(resid) / _MIN_GRAM_TERMS_PER_S
    if need <= left:
        return True
    stats["min_gram_skipped"] = f"its min-Gram would take about {need:.1f} s, {left:.1f} s were left"
    return False
