"""Plain max coverage straight from column bitsets: the binary run's matrix as the visibility stage
made it (:class:`camplace.visibility.bits.BitMatrix`, one bit a cell), without a CSR copy.

:func:`bits_outcome` takes the cases the bit presolve covers: ``maxcover`` without fixed,
forbidden, minimum-distance or minimum-angle constraints, on the route
:func:`~camplace.solver.choose.choose_engine` gives plain max coverage (``exact`` for k <= 4 under
``auto``). It presolves with :func:`~camplace.solver.problem.presolve_bits.presolve_bits` (the same
reduced instance as the CSR presolve) and runs the same max-coverage engines; the objective is
summed as :func:`~camplace.solver.problem.objectives.mode_value` sums it, so the answer is the
CSR route's. Any other case returns None and :func:`camplace.solver.api.solve` converts the bits
to a bool CSR pattern (5 bytes an observed pair) and goes on as before.
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
from camplace.solver.engines.maxcover import run_maxcover_engine
from camplace.solver.options import SolveOptions
from camplace.solver.problem.presolve import check_weights
from camplace.solver.problem.presolve_bits import covered_weight, presolve_bits
from camplace.solver.result import EngineOutcome

__all__ = ["bits_applies", "bits_outcome", "load_kernels"]


def bits_applies(o: SolveOptions) -> bool:
    """True when the options are plain max coverage (no fixed, forbidden, distance, angle or team).

    ``quality`` on a binary matrix is plain max coverage too: every value is 1, so
    ``max_{j in S} Q_ij`` is 1 exactly when some chosen camera observes row i, and the two
    objectives are the same number."""
    return (o.mode in ("maxcover", "quality") and not o.fixed and not o.forbidden and o.min_distance_m is None
            and o.min_angle_deg is None and getattr(o, "team", None) is None)


def bits_outcome(bits, weights: Any, o: SolveOptions, deadline: Deadline):
    """Solve plain max coverage on column bitsets.

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
        None when the engine choice is not plain max coverage (large k, the general model).
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
    budget = memory_budget_bytes()
    asked = o.mode
    o = replace(o, mode="maxcover")  # quality of a binary matrix: the same objective (see bits_applies)
    choice = choose_engine(problem_sizes(bits, k, n, 0, 0, "maxcover"), o, budget)
    if choice.route != "maxcover":
        return None
    stats: dict[str, Any] = {"k": k, "engine_choice": {"engine": choice.engine, "route": choice.route,
                                                       "reason": choice.reason}}
    stats.update(choice.stats)
    if asked != "maxcover":
        stats["binary_matrix"] = f"{asked} of a binary matrix (every value 1) is max coverage: solved as maxcover"
    pre = presolve_bits(bits, w, k, deadline=deadline.share(0.5))  # at least half the time left to the search
    name, out = run_maxcover_engine(choice.engine, o.engine, pre, deadline, stats, budget)
    sel = tuple(sorted(int(j) for j in pre.original_columns(out.selected))) if out.selected else None
    objective = covered_weight(bits, w, sel) if sel else 0.0
    stats.update({"rows_after": pre.shape[0], "cols_after": pre.shape[1], "presolve": dict(pre.stats),
                  "engine_stats": dict(out.stats)})
    return EngineOutcome(sel, out.status if sel else "unknown", float(out.bound), stats, engine=name,
                         objective=objective), w


#: :func:`load_kernels` solves a random instance of this many rows and columns (density 0.3,
#: k = 3): small enough to take about a millisecond once loaded, large enough that the presolve
#: and the bitset engine call every kernel the k <= 4 route calls (measured against the
#: kernels a 50,000 x 10,000 solve loads).
_LOAD_SHAPE = (200, 100)


def load_kernels(o: SolveOptions) -> bool:
    """Load the compiled kernels of plain max coverage on column bitsets (the bit presolve and the
    bitset engine) before the solve needs them, by solving a small seeded random instance.

    numba loads a kernel's machine code from its cache on the kernel's first call (about 0.03 s
    for the presolve's and as much for the engine's, one thread at a time): the pipeline calls
    this from the thread that waits while the visibility chunks are cast, so that the solve
    stage does not. It never changes a result.

    Parameters
    ----------
    o : SolveOptions
        The run's options: nothing is done unless they take :func:`bits_applies`'s route with the
        exact engine (``auto`` or ``exact``, 1 <= k <= 4).

    Returns
    -------
    bool
        True when the kernels were called.
    """
    from camplace.solver.engines.bitset.search import solve_bitset
    from camplace.visibility.bits import BitMatrix, bit_words

    k = o.k
    if (not bits_applies(o) or o.engine not in ("auto", "exact") or isinstance(k, bool)
            or not isinstance(k, numbers.Integral) or not 1 <= int(k) <= 4):
        return False
    rng = np.random.default_rng(0)
    m, n = _LOAD_SHAPE
    cells = np.zeros((n, bit_words(m) * 64), dtype=bool)  # column bitsets, rows past m empty
    cells[:, :m] = rng.random((n, m)) < 0.3
    words = np.packbits(cells, axis=1, bitorder="little").view(np.uint64)  # no kernel of its own to load
    quiet = logging.getLogger("camplace.solver")  # the user's log shows their solve, not this one
    level = quiet.level
    quiet.setLevel(logging.WARNING)
    try:
        solve_bitset(presolve_bits(BitMatrix(words, m), rng.random(m), int(k)))
    finally:
        quiet.setLevel(level)
    return True
