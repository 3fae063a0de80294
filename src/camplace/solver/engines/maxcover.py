"""Run a max-coverage engine on a presolved instance within the memory budget.

Every engine states its memory before allocating (:func:`~camplace.solver.engines.bitset.search.bitset_bytes`,
:func:`~camplace.solver.engines.mip.ortools.maxcover_model_bytes`). When the chosen engine does not fit,
an engine the caller asked for by name is a one-line :class:`~camplace.errors.CamplaceError`;
under ``auto`` the other engine is tried (the bitset engine is exact for any k and returns a valid
bound at the time limit), and as a last resort the greedy answer comes back with the trivial bound
(every observed row), with a logged warning and ``stats["memory_fallback"]`` (the policy:
:func:`camplace.solver._support.memory.memory_fallback`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback, note_memory
from camplace.solver.engines.bitset.search import bitset_bytes, solve_bitset
from camplace.solver.engines.mip.ortools import solve_cpsat, solve_mip
from camplace.solver.problem.presolve import Presolved
from camplace.solver.result import EngineOutcome

__all__ = ["run_maxcover_engine"]

#: What the user can do when an engine asked for by name does not fit.
_FIX = {"exact": "use engine mip, or fewer candidates / points",
        "mip": "use engine exact, or fewer candidates / points",
        "cpsat": "use engine exact, or fewer candidates / points"}

#: The max-coverage engines by name.
_FUNCS = {"exact": solve_bitset, "mip": solve_mip, "cpsat": solve_cpsat}


def run_maxcover_engine(name: str, requested: str, pre: Presolved, deadline: Deadline,
                        stats: dict[str, Any], budget: int | None = None,
                        start: tuple[int, ...] | None = None) -> tuple[str, EngineOutcome]:
    """Run engine ``name`` ("exact", "mip" or "cpsat") on ``pre`` within the memory budget
    (``budget`` bytes for the exact engine, default :func:`memory_budget_bytes`; the models check
    their own). ``start``, reduced column indices of a known selection, is the exact engine's
    first incumbent (a warm start). ``deadline`` is the solve's (the bitset engine is handed the
    seconds left of it: it does not take the deadline object yet).

    Returns
    -------
    name : str
        The engine that ran (the last one tried when none fitted; ``stats["memory_fallback"]``).
    outcome : EngineOutcome
    """
    tried: set[str] = set()
    while True:
        tried.add(name)
        try:
            if name == "exact":
                need = bitset_bytes(pre.shape[0], pre.shape[1], 1, pre.k)
                have = memory_budget_bytes() if budget is None else budget
                if need > have:
                    raise OverBudget(need, have, "the exact engine")
                # noted: what it allocates up front (the open tuples grow with the search, up to the cap checked)
                note_memory("bitset", bitset_bytes(pre.shape[0], pre.shape[1], 1, pre.k, tuples=False))
                return name, solve_bitset(pre, deadline=deadline, start=start)
            return name, _FUNCS[name](pre, deadline=deadline)
        except OverBudget as exc:
            nxt = next((e for e in ("exact", "mip") if e not in tried), None)
            memory_fallback(exc, stats, asked=requested == name, fix=_FIX[name],
                            then=f"falling back to engine {nxt}" if nxt else
                            "returning the greedy answer with the trivial bound")
            if nxt is None:
                break
            name = nxt
    from camplace.solver._support.greedy import greedy_incumbent

    sel = greedy_incumbent(pre.matrix, pre.weights, pre.k) if pre.shape[0] and pre.shape[1] > pre.k else \
        tuple(range(min(pre.k, pre.shape[1])))
    bound = float(pre.weights[np.diff(pre.matrix.indptr) > 0].sum())
    return name, EngineOutcome(selected=tuple(sel), status="feasible", bound=bound, stats={"greedy": True})
