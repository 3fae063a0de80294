"""Max coverage with OR-Tools: a SCIP MIP (``pywraplp``) and CP-SAT.

Both engines work on the presolved instance (merged rows, dominance-reduced columns)::

    maximise  sum_i c_i y_i
    s.t.      y_i <= sum_{j covers i} x_j      for every row i
              sum_j x_j = k
              x_j in {0, 1},  y_i in [0, 1] (MIP) or {0, 1} (CP-SAT)

Objective coefficients: the integer merged-row counts when all original weights are equal (exact;
``c_i * unit`` is the weight). Otherwise the MIP uses ``weights / max(weights)``; CP-SAT uses
integral weights as they are, and otherwise ``round(weights * s)`` with ``s`` chosen so the total
is 2**50; the rounding error ``E`` is recorded in ``stats`` (``weight_scale``, ``rounding_error``)
and added to the mapped-back bound, so the bound stays valid. A CP-SAT result then counts as
optimal only if that bound is within a relative 1e-9 of the objective.

Both engines get the greedy + swap solution as a hint and report the solver's best bound.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from camplace._cores import thread_count
from camplace.solver._support.deadline import Deadline, as_deadline, stopwatch
from camplace.solver._support.greedy import greedy_incumbent
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, note_memory
from camplace.solver.engines.mip.linear import _int_objective, model_bytes, run_cpsat, run_scip, scip_proto
from camplace.solver.problem.presolve import Presolved
from camplace.solver.result import EngineOutcome

__all__ = ["solve_mip", "solve_cpsat", "maxcover_model_bytes", "maxcover_model_size"]

log = logging.getLogger(__name__)

_OPT_TOL = 1e-9  # relative gap under which a result counts as optimal


def _trivial(pre: Presolved) -> EngineOutcome | None:
    """Outcome for instances with nothing to decide (no rows, or no more columns than k)."""
    m, n = pre.shape
    if m == 0 or n <= pre.k:
        value = float(pre.weights.sum()) if n <= pre.k else 0.0
        sel = tuple(range(min(pre.k, n)))
        return EngineOutcome(selected=sel, status="optimal", bound=value, stats={"trivial": True})
    return None


def _objective_coefficients(pre: Presolved) -> tuple[np.ndarray, float]:
    """Objective coefficients and the factor mapping them back to weights.

    Returns
    -------
    coef : (m',) float64
    scale : float
        ``weights ~= coef * scale``.
    """
    if pre.weight_unit is not None:
        return pre.counts.astype(np.float64), float(pre.weight_unit)
    wmax = float(pre.weights.max())
    return pre.weights / wmax, wmax


def _integer_weights(pre: Presolved) -> tuple[np.ndarray, float, float]:
    """Integer CP-SAT objective coefficients.

    Returns
    -------
    cint : (m',) int64
        Coefficients; ``weights ~= cint * unit``.
    unit : float
        Weight of one coefficient unit.
    err : float
        ``sum_i |weights_i - cint_i * unit|`` (0.0 when exact): any set's true weight is within
        ``err`` of its scaled weight, so ``bound * unit + err`` is a valid bound.
    """
    if pre.weight_unit is not None:
        return pre.counts.astype(np.int64), float(pre.weight_unit), 0.0
    return _int_objective(np.asarray(pre.weights, dtype=np.float64))


def maxcover_model_bytes(pre: Presolved, backend: str) -> int:
    """Estimated peak memory of the max-coverage model of ``pre`` (``backend`` "mip" or "cpsat"),
    from the sizes alone (the reduced matrix is not built): n + m variables, m + 1 rows and at most
    the source rows' entries plus m + n nonzeros."""
    from camplace.solver.problem.presolve_bits import BitPresolved

    m, n = pre.shape
    if isinstance(pre, BitPresolved):  # counted on its bitsets: its CSR is made only for a model that fits
        nnz = pre.nnz
    else:
        a, rows, _ = pre.source
        nnz = int(np.diff(a.indptr)[rows].sum()) if rows.size else 0
    return model_bytes(backend, *maxcover_model_size(m, n, nnz))


def maxcover_model_size(m: int, n: int, nnz: int) -> tuple[int, int, int]:
    """Variables, constraints and nonzeros of the max-coverage model of an (m, n) instance of
    ``nnz`` entries: n + m variables, m + 1 rows, at most nnz + m + n nonzeros (given the whole
    matrix's sizes, an upper bound for its presolved instance's model)."""
    m, n, nnz = int(m), int(n), int(nnz)
    return n + m, m + 1, nnz + m + n


def _check_memory(pre: Presolved, backend: str) -> None:
    """Raise :class:`OverBudget` before building a model that would not fit in memory."""
    need, budget = maxcover_model_bytes(pre, backend), memory_budget_bytes()
    note_memory("model", need, refused=need > budget)
    if need > budget:
        raise OverBudget(need, budget, "the SCIP model" if backend == "mip" else "the CP-SAT model")


def _value(pre: Presolved, sel: tuple[int, ...]) -> float:
    """Weight covered by reduced columns ``sel`` on the reduced instance."""
    if not sel:
        return 0.0
    sub = pre.matrix[:, list(sel)]
    covered = np.diff(sub.tocsr().indptr) > 0
    return float(pre.weights[covered].sum())


def _pick_k(values: np.ndarray, k: int) -> tuple[int, ...]:
    """The ``k`` columns with the largest (relaxed) values, sorted."""
    order = np.argsort(-values, kind="stable")[:k]
    return tuple(sorted(int(j) for j in order))


_BUILD_CHECK = 256  # model rows built between deadline checks
#: SCIP's fixed cost a model nonzero, whatever its time limit: measured on a 3,000 x 16,000 max-coverage
#: model (13.3 M nonzeros) on 2 cores: building the proto 0.55 s, loading it 0.71 s, solving with a
#: 0.1 s limit 4.19 s (the root LP does not look at the clock), freeing it 2.68 s; 8.1 s in all
_SCIP_S_PER_NONZERO = 6e-7


def scip_too_slow(nonzeros: int, deadline: Deadline) -> str | None:
    """Why SCIP cannot end inside ``deadline`` on a model of ``nonzeros`` (its fixed cost,
    :data:`_SCIP_S_PER_NONZERO` a nonzero, is more than the time left), or None when it can or
    there is no limit."""
    left = deadline.remaining()
    need = _SCIP_S_PER_NONZERO * nonzeros
    if left is None or need <= left:
        return None
    return (f"the time left ({left:.1f} s) is shorter than SCIP's fixed cost on a model of {nonzeros:,} nonzeros "
            f"(about {need:.1f} s: building, loading, the root LP and freeing it)")


def _build_stopped(pre: Presolved, hint: tuple[int, ...], backend: str, build_s: float,
                   why: str = "interrupted by the time limit") -> EngineOutcome:
    """The time limit passed while the model was being built (or would pass before the solver
    could end): the greedy answer and the trivial bound (every remaining row's weight)."""
    log.info("%s: %s: greedy answer, trivial bound", backend, why)
    stats = {"backend": backend, "model_build": why, "hint_value": _value(pre, hint),
             "time_build_s": build_s}
    return EngineOutcome(selected=tuple(hint), status="feasible", bound=max(float(pre.weights.sum()), _value(pre, hint)),
                         stats=stats)


def solve_mip(pre: Presolved, *, deadline: Deadline | None = None) -> EngineOutcome:
    """Solve the presolved instance with SCIP through ``ortools.linear_solver.pywraplp``.

    Parameters
    ----------
    pre : Presolved
        Presolved instance.
    deadline : Deadline, optional
        The solve's deadline (default: none); building the model counts.

    Returns
    -------
    EngineOutcome
        Reduced column indices, status, SCIP's best bound (original weight units) and stats.

    Raises
    ------
    OverBudget
        When :func:`maxcover_model_bytes` exceeds the memory budget (before anything is built).
    """
    from ortools.linear_solver import pywraplp

    triv = _trivial(pre)
    if triv is not None:
        return triv
    _check_memory(pre, "mip")
    deadline = as_deadline(deadline)
    since = stopwatch(deadline)
    m, n = pre.shape
    k = pre.k
    coef, scale = _objective_coefficients(pre)
    hint = greedy_incumbent(pre.matrix, pre.weights, k)

    csr = pre.matrix.tocsr()
    indptr, indices = csr.indptr, csr.indices

    def covers():  # y_i <= sum of the x_j that observe row i
        for i in range(m):
            cols = indices[indptr[i] : indptr[i + 1]].tolist()
            yield 0.0, math.inf, cols + [n + i], [1.0] * len(cols) + [-1.0]

    too_slow = scip_too_slow(int(pre.matrix.nnz) + m + n, deadline)
    if too_slow is not None:  # it would end past the limit whatever limit SCIP is given
        return _build_stopped(pre, hint, "SCIP", since(), why=too_slow)
    var_specs = [(0.0, 1.0, True, 0.0)] * n + [(0.0, 1.0, False, float(c)) for c in coef]  # x, then y
    proto = scip_proto(True, var_specs, covers(), stop=deadline.expired, check_every=_BUILD_CHECK)
    if proto is None:
        return _build_stopped(pre, hint, "SCIP", since())
    card = proto.constraint.add()
    card.lower_bound = card.upper_bound = float(k)
    card.var_index.extend(range(n))
    card.coefficient.extend([1.0] * n)

    run = run_scip(proto, deadline, range(n), [1.0 if j in hint else 0.0 for j in range(n)],
                   no_scip="use engine='cpsat' or 'exact'", since=since)
    code = run.code

    stats: dict[str, Any] = {
        "backend": "SCIP",
        "time_build_s": run.build_s,
        "time_solve_s": since() - run.build_s,
        "objective_scale": scale,
        "variables": int(n + m),
        "constraints": int(m + 1),
        "nonzeros": int(pre.matrix.nnz + m + n),
        "hint_value": _value(pre, hint),
    }
    if run.stopped:
        stats["stopped"] = run.stopped
    if run.values is not None:
        sel = _pick_k(run.values[:n], k)
        raw_bound = min(run.bound * scale, float(pre.weights.sum()))  # SCIP says 1e20 before its root LP ends
        stats["nodes"] = run.nodes
    else:
        sel = hint
        raw_bound = float(pre.weights.sum())
    stats["solver_bound"] = raw_bound
    stats["solver_status"] = int(code)
    value = _value(pre, sel)
    if value < stats["hint_value"]:
        sel, value = hint, stats["hint_value"]
    bound = max(raw_bound, value)
    if code == pywraplp.Solver.OPTIMAL:
        status = "optimal"
        bound = value
    elif code == pywraplp.Solver.INFEASIBLE:
        status = "infeasible"
    else:
        status = "feasible"
    log.info("mip: %s value %.9g bound %.9g (%dx%d) in %.3f s", status, value, bound, m, n, since())
    return EngineOutcome(selected=sel, status=status, bound=bound, stats=stats)


def solve_cpsat(pre: Presolved, *, deadline: Deadline | None = None, workers: int | None = None) -> EngineOutcome:
    """Solve the presolved instance with CP-SAT (integer-scaled weights).

    Parameters
    ----------
    pre : Presolved
        Presolved instance.
    deadline : Deadline, optional
        The solve's deadline (default: none); building the model counts.
    workers : int, optional
        CP-SAT search workers (default :func:`camplace._cores.thread_count`: ``--threads`` /
        ``SolveOptions.threads``, else the cores this process may use).

    Returns
    -------
    EngineOutcome
        Reduced column indices, status, bound (original weight units, including the rounding
        error of the integer weights) and stats.

    Raises
    ------
    OverBudget
        When :func:`maxcover_model_bytes` exceeds the memory budget (before anything is built).
    """
    from ortools.sat.python import cp_model

    triv = _trivial(pre)
    if triv is not None:
        return triv
    _check_memory(pre, "cpsat")
    deadline = as_deadline(deadline)
    since = stopwatch(deadline)
    m, n = pre.shape
    k = pre.k
    cint, unit, err = _integer_weights(pre)
    hint = greedy_incumbent(pre.matrix, pre.weights, k)

    model = cp_model.CpModel()
    x = [model.new_bool_var(f"x{j}") for j in range(n)]
    y = [model.new_bool_var(f"y{i}") for i in range(m)]
    csr = pre.matrix.tocsr()
    indptr, indices = csr.indptr, csr.indices
    for i in range(m):
        if i % _BUILD_CHECK == 0 and deadline.expired():
            return _build_stopped(pre, hint, "CP-SAT", since())
        lits = [x[j] for j in indices[indptr[i] : indptr[i + 1]].tolist()]
        lits.append(~y[i])
        model.add_bool_or(lits)
    model.add(sum(x) == k)
    model.maximize(cp_model.LinearExpr.weighted_sum(y, cint.tolist()))
    for j in range(n):
        model.add_hint(x[j], j in hint)

    solver, code, build_s = run_cpsat(model, workers, deadline, since)

    stats: dict[str, Any] = {
        "backend": "CP-SAT",
        "workers": thread_count(workers),
        "time_build_s": build_s,
        "time_solve_s": since() - build_s,
        "weight_unit": unit,
        "weight_scale": 1.0 / unit,
        "weights_integer_exact": err == 0.0,
        "rounding_error": err,
        "hint_value": _value(pre, hint),
        "solver_status": solver.status_name(code),
    }
    if code in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        xs = np.array([solver.boolean_value(v) for v in x], dtype=np.float64)
        sel = _pick_k(xs, k)
        int_bound = float(solver.best_objective_bound)
        stats["branches"] = int(solver.num_branches)
    else:
        sel = hint
        int_bound = math.inf
    raw_bound = int_bound * unit + err if math.isfinite(int_bound) else float(pre.weights.sum())
    stats["solver_bound"] = raw_bound
    value = _value(pre, sel)
    if value < stats["hint_value"]:
        sel, value = hint, stats["hint_value"]
    bound = max(min(raw_bound, float(pre.weights.sum())), value)
    if code == cp_model.INFEASIBLE:
        status = "infeasible"
    elif code in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        tight = bound - value <= _OPT_TOL * max(abs(bound), 1e-12)
        status = "optimal" if (code == cp_model.OPTIMAL and err == 0.0) or tight else "feasible"
        if status == "optimal":
            bound = value
    else:
        status = "feasible"
    log.info("cpsat: %s value %.9g bound %.9g (%dx%d) in %.3f s", status, value, bound, m, n, since())
    return EngineOutcome(selected=sel, status=status, bound=bound, stats=stats)
