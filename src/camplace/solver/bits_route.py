"""Max coverage and multiview straight from column bitsets: the binary run's matrix as the
visibility stage made it (:class:`camplace.visibility.bits.BitMatrix`, one bit a cell), without a
CSR copy.

:func:`bits_outcome` takes the cases without fixed, forbidden, minimum-distance, minimum-angle or
team constraints, on the routes of :func:`~camplace.solver.choose.choose_engine` that read bits:

``maxcover`` (and ``quality``, the same objective on a binary matrix)
    plain max coverage (``exact`` for k <= 4 under ``auto``): the presolve of
    :func:`~camplace.solver.problem.presolve_bits.presolve_bits` (the same reduced instance as the
    CSR presolve), then the same max-coverage engines.
``multiview``
    the ``multiview`` route (the bitset engine, ``exact`` for k <= 4): the bit presolve without
    column dominance (dropping dead rows and merging identical ones keeps every column's view
    counts; dominance keeps only coverage), :func:`~camplace.solver.engines.bitset.search.solve_bitset`
    with ``views`` (its opposite-pairs layout transposed from the bits,
    :func:`~camplace.solver.problem.presolve_bits.layout_bits`), and, for fewer cameras than
    ``2 * views``, an unproven bound capped by the opposite pairs matched on the bits
    (:func:`~camplace.solver.engines.bitset.pair_cap.cap_bound`), as the CSR route does.

The objective is summed as :func:`~camplace.solver.problem.objectives.mode_value` sums it
(:func:`~camplace.solver.problem.presolve_bits.covered_weight`,
:func:`~camplace.solver.problem.presolve_bits.views_weight`), so without a time limit the answer
is the CSR route's. With one, the CSR route first solves a quarter of the candidates when there
are more than :data:`camplace.solver.routes.WARM_MIN_COLS` (its warm start); this route does not
(the engines' own greedy gives the first incumbent). Any other case (another engine choice, the
bitset engine over the memory budget) returns None and :func:`camplace.solver.api.solve` converts
the bits to a bool CSR pattern (5 bytes an observed pair) and goes on as before.
"""

from __future__ import annotations

import logging
import numbers
from dataclasses import replace
from typing import Any

import numpy as np

from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import memory_budget_bytes
from camplace.solver.choose import choose_engine, problem_sizes
from camplace.solver.engines.bitset.pair_cap import cap_applies, cap_bound, cap_deadline
from camplace.solver.engines.bitset.search import bitset_bytes, solve_bitset
from camplace.solver.engines.maxcover import run_maxcover_engine
from camplace.solver.options import SolveOptions
from camplace.solver.problem.presolve import check_weights
from camplace.solver.problem.presolve_bits import covered_weight, presolve_bits, views_weight
from camplace.solver.result import EngineOutcome

__all__ = ["bits_applies", "bits_outcome"]

log = logging.getLogger(__name__)


def bits_applies(o: SolveOptions) -> bool:
    """True for plain max coverage or multiview without a minimum angle (no fixed, forbidden,
    distance, angle or team).

    ``quality`` on a binary matrix is plain max coverage too: every value is 1, so
    ``max_{j in S} Q_ij`` is 1 exactly when some chosen camera observes row i, and the two
    objectives are the same number."""
    return (o.mode in ("maxcover", "quality", "multiview") and not o.fixed and not o.forbidden
            and o.min_distance_m is None and o.min_angle_deg is None and getattr(o, "team", None) is None)


def bits_outcome(bits, weights: Any, o: SolveOptions, deadline: Deadline):
    """Solve plain max coverage or multiview on column bitsets.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n) observed pairs.
    weights : (m,) array_like of float64
    o : SolveOptions
        Checked options with :func:`bits_applies`.
    deadline : Deadline

    Returns
    -------
    (EngineOutcome, (m,) float64 weights) or None
        None when the engine choice is not one this route runs (large k, the general model) or
        the bitset engine would not fit in the memory budget.
    """
    m, n = bits.shape
    if n == 0:
        raise CamplaceError("the visibility matrix has no candidate columns")
    w = check_weights(weights, m)
    k = o.k
    if k is None or isinstance(k, bool) or not isinstance(k, numbers.Integral):
        raise CamplaceError(f"k must be an integer number of cameras for mode {o.mode!r}, got {k!r}")
    k = int(k)
    if k < 1:
        raise CamplaceError(f"k must be at least 1, got {k}")
    if k > n:
        raise CamplaceError(f"cannot choose k={k} new cameras from {n} allowed candidates "
                            "(lower k, or forbid/fix fewer cameras)")
    if o.mode == "multiview":
        got = _multiview(bits, w, k, o, deadline)
    else:
        got = _maxcover(bits, w, k, o, deadline)
    return None if got is None else (got, w)


def _maxcover(bits, w: np.ndarray, k: int, o: SolveOptions, deadline: Deadline) -> EngineOutcome | None:
    """Plain max coverage of ``k`` columns (quality solved as maxcover); None off the maxcover route."""
    n = bits.shape[1]
    budget = memory_budget_bytes()
    asked = o.mode
    o = replace(o, mode="maxcover")  # quality of a binary matrix: the same objective (see bits_applies)
    choice = choose_engine(problem_sizes(bits, k, n, 0, 0, "maxcover"), o, budget)
    if choice.route != "maxcover":
        return None
    stats = _choice_stats(k, choice)
    if asked != "maxcover":
        stats["binary_matrix"] = f"{asked} of a binary matrix (every value 1) is max coverage: solved as maxcover"
    pre = presolve_bits(bits, w, k, deadline=deadline.share(0.5))  # at least half the time left to the search
    name, out = run_maxcover_engine(choice.engine, o.engine, pre, deadline, stats, budget)
    sel = tuple(sorted(int(j) for j in pre.original_columns(out.selected))) if out.selected else None
    objective = covered_weight(bits, w, sel) if sel else 0.0
    stats.update({"rows_after": pre.shape[0], "cols_after": pre.shape[1], "presolve": dict(pre.stats),
                  "engine_stats": dict(out.stats)})
    return EngineOutcome(sel, out.status if sel else "unknown", float(out.bound), stats, engine=name,
                         objective=objective)


def _multiview(bits, w: np.ndarray, k: int, o: SolveOptions, deadline: Deadline) -> EngineOutcome | None:
    """``k`` columns maximising the weight of rows observed by at least ``o.views`` of them: the
    CSR route's :func:`camplace.solver.routes._multiview` and the opposite-pairs cap of
    :func:`camplace.solver.api.solve`, on the bits. None off the multiview route, or when the
    bitset engine's working memory (estimated on the reduced instance) is over the budget."""
    n = bits.shape[1]
    views = int(o.views)
    budget = memory_budget_bytes()
    choice = choose_engine(problem_sizes(bits, k, n, 0, 0, "multiview"), o, budget)
    if choice.route != "multiview":
        return None
    cap = cap_applies(k, views)
    inner = cap_deadline(deadline) if cap else deadline  # leaves the cap its share of the limit
    stats = _choice_stats(k, choice)
    pre = presolve_bits(bits, w, k, dominance=False, deadline=inner)  # dominance: one view only
    mp, np_ = pre.shape
    need = bitset_bytes(mp, np_, min(views, k), k)
    if need > budget:  # the CSR route makes the same estimate and falls back to the general model
        log.info("multiview on bits: the bitset engine needs %.3g GiB (budget %.3g GiB): the CSR route",
                 need / 2**30, budget / 2**30)
        return None
    out = solve_bitset(pre, views=views, deadline=inner)
    sel = tuple(int(j) for j in pre.original_columns(out.selected)) if out.selected else None
    stats.update({"rows_after": mp, "cols_after": np_, "presolve": dict(pre.stats), "engine_stats": dict(out.stats)})
    got = EngineOutcome(sel, out.status if sel else "unknown", float(out.bound), stats, engine=choice.engine,
                        objective=views_weight(bits, w, sel, views) if sel else 0.0)
    searched = out.stats.get("search") == "opposite pairs"  # already bounded by them
    if cap and sel is not None and got.status != "optimal" and not searched and not deadline.expired():
        got = cap_bound(got, bits, w, views, k, None, deadline)
    return got


def _choice_stats(k: int, choice) -> dict[str, Any]:
    """The result's first stats: ``k``, the engine choice and its own figures, and the layout."""
    stats: dict[str, Any] = {"k": k, "engine_choice": {"engine": choice.engine, "route": choice.route,
                                                       "reason": choice.reason},
                             "matrix": "column bitsets (no CSR copy)"}
    stats.update(choice.stats)
    return stats
