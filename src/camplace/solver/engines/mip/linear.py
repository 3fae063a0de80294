"""A small 0/1 linear model and its two OR-Tools backends (SCIP via ``pywraplp``, CP-SAT).

Used by :mod:`camplace.solver.api` for every model the bound-pruned exact engine cannot solve
(multi-view coverage, set cover, minimum-distance constraints, ...). Variables are binary or
continuous in ``[lb, ub]``; constraints are ``lo <= sum coef * var <= hi``. CP-SAT needs integer
data: every variable becomes an integer variable in ``[lb, ub]`` (all models here only use 0/1
variables), every constraint must have integer coefficients (a constraint may carry an
integer-scaled variant for CP-SAT, see :class:`Row`), and a non-integral objective is scaled to
integers with the rounding error added to the reported bound (so the bound stays valid).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from camplace._cores import thread_count
from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline, as_deadline, stopwatch
from camplace.solver.result import EngineOutcome

__all__ = ["Row", "LinearModel", "solve_model", "model_bytes"]

log = logging.getLogger(__name__)

_CPSAT_TOTAL = 2.0**50  # total of the integer CP-SAT objective coefficients (non-integral objective)
_OPT_TOL = 1e-9  # relative gap under which a result counts as optimal


# Peak bytes per variable, per constraint and per nonzero of a model: this module's Python rows,
# the protocol buffer and the solver's own copy. Measured with OR-Tools 9.15 (peak RSS of 3 s
# solves of 10^5..10^6 rows / variables): SCIP about 2.7 kB a variable, 1.7 kB a row, 150 B a
# nonzero; CP-SAT (2 workers) 0.9 kB, 1.1 kB and 60 B.
_MODEL_BYTES = {"mip": (2800, 1700, 150), "cpsat": (900, 1100, 70)}
# Longer searches (LP, tree, cuts) grow beyond those 3 s peaks. SCIP on the min-distance max-coverage
# model of comet-67p-bunker with a 60 s limit (the quick start; RSS of the process and the SCIP child
# sampled each second, less the process's before the model was built): 1.19 GB at 1.58e6 nonzeros
# (1,000 x 5,000), 3.46 GB at 6.04e6 (2,000 x 10,000; 2.87 GB after 30 s): the child grows in steps
# with the search (load 1.2 GB, root LP 2.1 GB at 24 s, 2.4 GB at 29 s, 2.9 GB as it stops), about
# 3.3 times the 3 s figures plus the child's own interpreter and SCIP's fixed tables (250 MB, in a
# child only: models of CHILD_MIN_NONZEROS or more). CP-SAT: not measured beyond 3 s.
_MODEL_SEARCH_FACTOR = {"mip": 3.3, "cpsat": 1.5}
_MODEL_BASE_BYTES = 100 << 20
_CHILD_BASE_BYTES = 250 << 20


def model_bytes(backend: str, n_vars: int, n_rows: int, nnz: int) -> int:
    """Estimated peak memory of building and solving a model of this size (SCIP: within a 60 s
    search; it grows with the time given, up to ``limits/memory``, :func:`scip_memory_mb`).

    Parameters
    ----------
    backend : {"mip", "cpsat"}
    n_vars, n_rows, nnz : int
        Variables, constraints and constraint nonzeros.

    Returns
    -------
    int
        Bytes.
    """
    name = "cpsat" if backend == "cpsat" else "mip"
    per_var, per_row, per_nnz = _MODEL_BYTES[name]
    raw = per_var * float(n_vars) + per_row * float(n_rows) + per_nnz * float(nnz)
    child = _CHILD_BASE_BYTES if name == "mip" and nnz >= CHILD_MIN_NONZEROS else 0  # (with a time limit)
    return int(_MODEL_SEARCH_FACTOR[name] * raw) + _MODEL_BASE_BYTES + child


@dataclass(frozen=True)
class Row:
    """One linear constraint ``lo <= coef @ x[idx] <= hi``.

    Attributes
    ----------
    idx : (r,) int64
        Variable indices.
    coef : (r,) float64
        Coefficients (used by SCIP, and by CP-SAT when integral).
    lo, hi : float
        Bounds (``-inf`` / ``inf`` for none).
    int_variant : tuple or None
        ``(coef_int (r,) int64, lo_int, hi_int)`` used by CP-SAT instead (for rows with
        non-integral coefficients).
    """

    idx: np.ndarray
    coef: np.ndarray
    lo: float
    hi: float
    int_variant: tuple[np.ndarray, float, float] | None = None


@dataclass
class LinearModel:
    """A mixed 0/1 linear model (built incrementally, then solved once).

    Attributes
    ----------
    maximize : bool
        Objective sense.
    lb, ub : list of float
        Variable bounds.
    integer : list of bool
        Integrality of each variable (CP-SAT treats every variable as integer).
    obj : list of float
        Objective coefficients.
    rows : list of Row
        Constraints.
    """

    maximize: bool
    lb: list[float] = field(default_factory=list)
    ub: list[float] = field(default_factory=list)
    integer: list[bool] = field(default_factory=list)
    obj: list[float] = field(default_factory=list)
    rows: list[Row] = field(default_factory=list)

    def add_vars(self, count: int, *, lb: float = 0.0, ub: float = 1.0, integer: bool = True, obj: Any = 0.0) -> np.ndarray:
        """Add ``count`` variables; returns their (count,) int64 indices."""
        start = len(self.lb)
        objs = np.broadcast_to(np.asarray(obj, dtype=np.float64), (count,))
        self.lb.extend([float(lb)] * count)
        self.ub.extend([float(ub)] * count)
        self.integer.extend([bool(integer)] * count)
        self.obj.extend(objs.tolist())
        return np.arange(start, start + count, dtype=np.int64)

    def add_row(
        self,
        idx: Sequence[int] | np.ndarray,
        coef: Sequence[float] | np.ndarray,
        lo: float = -math.inf,
        hi: float = math.inf,
        int_variant: tuple[np.ndarray, float, float] | None = None,
    ) -> None:
        """Add the constraint ``lo <= sum coef * x[idx] <= hi``."""
        self.rows.append(
            Row(np.asarray(idx, dtype=np.int64), np.asarray(coef, dtype=np.float64), float(lo), float(hi), int_variant)
        )

    @property
    def n_vars(self) -> int:
        """Number of variables."""
        return len(self.lb)


def solve_model(
    model: LinearModel,
    backend: str,
    *,
    deadline: Deadline | None = None,
    hint: dict[int, float] | None = None,
    workers: int | None = None,
) -> EngineOutcome:
    """Solve a :class:`LinearModel` with SCIP (``backend="mip"``) or CP-SAT (``"cpsat"``).

    Parameters
    ----------
    model : LinearModel
    backend : {"mip", "cpsat"}
    deadline : Deadline, optional
        The solve's deadline (default: none); building the model counts.
    hint : dict, optional
        Partial solution ``{variable: value}`` given to the solver as a hint.
    workers : int, optional
        CP-SAT workers (default :func:`camplace._cores.thread_count`: ``--threads`` /
        ``SolveOptions.threads``, else the allowed cores; SCIP is single-threaded).

    Returns
    -------
    EngineOutcome
        ``values``: the variables' values of the best solution found (None if none; ``selected``
        is None); ``status``; ``bound``: the solver's proven bound on the objective (upper when
        maximising, lower when minimising) in the model's objective units, +-inf when unknown;
        ``engine``: ``backend``; ``stats``.
    """
    if backend == "mip":
        return _solve_scip(model, as_deadline(deadline), hint)
    if backend == "cpsat":
        return _solve_cpsat(model, as_deadline(deadline), hint, workers)
    raise CamplaceError(f"unknown model backend {backend!r} (use mip or cpsat)")


def scip_proto(maximize: bool, variables: Iterable[tuple[float, float, bool, float]],
               rows: Iterable[tuple[float, float, Sequence[int], Sequence[float]]],
               stop: Callable[[], bool] | None = None, check_every: int = 256):
    """The ``MPModelProto`` SCIP loads (the one model-building loop of the package: the mode
    models, through :func:`solve_model`, and the max-coverage MIP of
    :mod:`camplace.solver.engines.mip.ortools`).

    Parameters
    ----------
    maximize : bool
    variables : iterable of (lower, upper, integer, objective coefficient)
        One tuple per variable, in index order.
    rows : iterable of (lower, upper, variable indices, coefficients)
        One tuple per constraint (``lower <= sum coef * x[idx] <= upper``; +-inf for none).
    stop : callable, optional
        Checked before every ``check_every``-th row (the first included): building stops when it
        returns True (the time limit passed).

    Returns
    -------
    ortools.linear_solver.linear_solver_pb2.MPModelProto or None
        None when ``stop`` said so.
    """
    from ortools.linear_solver import linear_solver_pb2

    proto = linear_solver_pb2.MPModelProto()
    proto.maximize = bool(maximize)
    for lb, ub, integ, c in variables:
        v = proto.variable.add()
        v.lower_bound, v.upper_bound, v.is_integer, v.objective_coefficient = lb, ub, integ, c
    for i, (lo, hi, idx, coef) in enumerate(rows):
        if stop is not None and i % check_every == 0 and stop():
            return None
        ct = proto.constraint.add()
        ct.lower_bound = lo
        ct.upper_bound = hi
        ct.var_index.extend(idx)
        ct.coefficient.extend(coef)
    return proto


#: models with at least this many nonzeros are solved in a child process when there is a time limit
#: (:mod:`camplace.solver.engines.mip.scip_process`: SCIP's root LP ignores the clock; the child is
#: stopped at the limit). Below it SCIP ends its root LP quickly and the child's start-up (about
#: 0.2 s) would cost more than it saves.
CHILD_MIN_NONZEROS = 500_000


def scip_memory_mb() -> int:
    """SCIP's ``limits/memory`` (MiB): the memory budget an engine may allocate now
    (:func:`camplace.solver._support.memory.memory_budget_bytes`: a share of what the machine has
    available, at most ``--memory-budget-gb``), at least 64. SCIP's branch-and-bound tree grows with
    the time it is given (a 6e6-nonzero min-distance model of the quick start reached 3.3 GB in 60 s
    and 3.8 GB in 10 minutes; :func:`model_bytes` counts about 60 s of it): past the limit SCIP stops with its
    best solution and bound instead of growing until the machine runs out."""
    from camplace.solver._support.memory import memory_budget_bytes

    return max(64, int(memory_budget_bytes() // 2**20))


def run_scip(proto, deadline: Deadline, hint_vars: Sequence[int] = (), hint_values: Sequence[float] = (), *,
             no_scip: str = "use engine='cpsat'", since: Callable[[], float] | None = None):
    """Solve an ``MPModelProto`` with SCIP: one thread, the hint, the relative gap ``_OPT_TOL`` and
    what is left of ``deadline`` (the one SCIP set-up of the package: the mode models and the
    max-coverage MIP engine both run here).

    SCIP keeps to the memory budget (:func:`scip_memory_mb`). With a time limit and at least
    :data:`CHILD_MIN_NONZEROS` nonzeros, SCIP runs in a child
    process that is stopped at the limit (plus :func:`~camplace.solver.engines.mip.scip_process.grace_s`);
    the proto is consumed (cleared) to free its memory.

    Parameters
    ----------
    proto : ortools.linear_solver.linear_solver_pb2.MPModelProto
    deadline : Deadline
        The solve's deadline: SCIP gets what is left of it.
    hint_vars, hint_values : sequence
        Variable indices and their hinted values.
    no_scip : str
        What to do instead when OR-Tools has no SCIP (the end of the one-line error).
    since : callable, optional
        The caller's stopwatch (:func:`~camplace.solver._support.deadline.stopwatch`): the build
        time counts from its start (default: from the deadline's).

    Returns
    -------
    camplace.solver.engines.mip.scip_process.ScipRun
        Status code, variable values, best bound, nodes, build seconds, and why the child was
        stopped (None when SCIP answered).
    """
    from ortools.linear_solver import pywraplp

    from camplace.solver.engines.mip.scip_process import ScipRun, solve_in_child

    hint_vars = list(hint_vars)
    hint_values = [float(v) for v in hint_values]
    build_s = deadline.elapsed() if since is None else since()
    rem = deadline.remaining()
    nnz = sum(len(c.var_index) for c in proto.constraint)
    if rem is not None and nnz >= CHILD_MIN_NONZEROS:
        deadline_epoch = time.time() + rem  # before serialising: that time counts too
        data = proto.SerializeToString()
        proto.Clear()  # the child holds the model now
        try:
            return solve_in_child(data, deadline_epoch, hint_vars, hint_values, _OPT_TOL, build_s, scip_memory_mb())
        except RuntimeError as exc:
            if str(exc).startswith("no SCIP"):
                raise CamplaceError(f"OR-Tools was built without SCIP; {no_scip}") from None
            raise
    solver = pywraplp.Solver.CreateSolver("SCIP")
    if solver is None:
        raise CamplaceError(f"OR-Tools was built without SCIP; {no_scip}")
    err = solver.LoadModelFromProto(proto)
    if err:
        raise RuntimeError(f"SCIP model load failed: {err}")
    solver.SetNumThreads(1)
    from camplace.solver.engines.mip.scip_process import limit_scip_memory

    limit_scip_memory(solver, scip_memory_mb())
    variables = solver.variables()
    if hint_vars:
        solver.SetHint([variables[i] for i in hint_vars], hint_values)
    rem = deadline.remaining()
    if rem is not None:
        solver.SetTimeLimit(max(1, int(rem * 1000)))
    params = pywraplp.MPSolverParameters()
    params.SetDoubleParam(pywraplp.MPSolverParameters.RELATIVE_MIP_GAP, _OPT_TOL)
    code = solver.Solve(params)
    if code in (pywraplp.Solver.OPTIMAL, pywraplp.Solver.FEASIBLE):
        values = np.array([v.solution_value() for v in variables], dtype=np.float64)
        return ScipRun(int(code), values, float(solver.Objective().BestBound()), int(solver.nodes()), build_s)
    return ScipRun(int(code), None, float("nan"), 0, build_s)


def _solve_scip(model: LinearModel, deadline: Deadline, hint: dict[int, float] | None) -> EngineOutcome:
    from ortools.linear_solver import pywraplp

    since = stopwatch(deadline)
    proto = scip_proto(model.maximize, zip(model.lb, model.ub, model.integer, model.obj),
                       ((row.lo, row.hi, row.idx.tolist(), row.coef.tolist()) for row in model.rows))
    nnz = sum(row.idx.size for row in model.rows)
    keys = sorted(hint) if hint else []
    run = run_scip(proto, deadline, keys, [float(hint[i]) for i in keys] if hint else [],
                   no_scip="use engine='cpsat'", since=since)
    stats: dict[str, Any] = {
        "backend": "SCIP",
        "variables": model.n_vars,
        "constraints": len(model.rows),
        "nonzeros": int(nnz),
        "time_build_s": run.build_s,
        "time_solve_s": since() - run.build_s,
        "solver_status": int(run.code),
    }
    if run.stopped:
        stats["stopped"] = run.stopped
    values = run.values
    if values is not None:
        bound = run.bound
        stats["nodes"] = run.nodes
    else:
        bound = math.inf if model.maximize else -math.inf
    if run.code == pywraplp.Solver.OPTIMAL:
        status = "optimal"
    elif run.code == pywraplp.Solver.FEASIBLE:
        status = "feasible"
    elif run.code == pywraplp.Solver.INFEASIBLE:
        status = "infeasible"
    else:
        status = "unknown"
    return EngineOutcome(None, status, bound, stats, engine="mip", values=values)


def run_cpsat(model, workers: int | None, deadline: Deadline, since: Callable[[], float] | None = None):
    """Solve a built CP-SAT model with ``workers`` threads (None: :func:`camplace._cores.thread_count`)
    within the deadline's remaining time (``since``: the caller's stopwatch, which the build time
    is read from; default: the deadline's start).

    Returns
    -------
    solver : ortools CpSolver
    code : int
        CP-SAT status code.
    build_s : float
        Seconds spent before the solve started (model building).
    """
    from ortools.sat.python import cp_model

    solver = cp_model.CpSolver()
    solver.parameters.num_workers = thread_count(workers)
    build_s = deadline.elapsed() if since is None else since()
    rem = deadline.remaining()
    if rem is not None:
        solver.parameters.max_time_in_seconds = max(0.01, rem)
    return solver, solver.solve(model), build_s


def _int_objective(obj: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Integer objective ``cint`` with ``obj ~= cint * unit`` and total rounding error ``err``."""
    if obj.size == 0 or (np.all(obj == np.rint(obj)) and float(np.abs(obj).sum()) < 2.0**53):
        return obj.astype(np.int64), 1.0, 0.0
    s = _CPSAT_TOTAL / float(np.abs(obj).sum())
    cint = np.rint(obj * s).astype(np.int64)
    unit = 1.0 / s
    err = float(np.abs(obj * s - cint).sum()) * unit
    return cint, unit, err


def _solve_cpsat(
    model: LinearModel, deadline: Deadline, hint: dict[int, float] | None, workers: int | None
) -> EngineOutcome:
    from ortools.sat.python import cp_model

    since = stopwatch(deadline)
    cp = cp_model.CpModel()
    xs = []
    for i, (lb, ub) in enumerate(zip(model.lb, model.ub)):
        lo_i, hi_i = math.ceil(lb - 1e-9), math.floor(ub + 1e-9)
        xs.append(cp.new_bool_var(f"v{i}") if (lo_i, hi_i) == (0, 1) else cp.new_int_var(lo_i, hi_i, f"v{i}"))
    for row in model.rows:
        if row.int_variant is not None:
            coef, lo, hi = row.int_variant
            coef = np.asarray(coef, dtype=np.int64)
        else:
            if not np.all(row.coef == np.rint(row.coef)):
                raise RuntimeError("CP-SAT row with non-integral coefficients and no integer variant")
            coef, lo, hi = row.coef.astype(np.int64), row.lo, row.hi
        expr = cp_model.LinearExpr.weighted_sum([xs[i] for i in row.idx.tolist()], coef.tolist())
        if math.isfinite(lo) and math.isfinite(hi) and lo == hi:
            cp.add(expr == int(round(lo)))
            continue
        if math.isfinite(lo):
            cp.add(expr >= int(math.ceil(lo - 1e-9)))
        if math.isfinite(hi):
            cp.add(expr <= int(math.floor(hi + 1e-9)))
    obj = np.asarray(model.obj, dtype=np.float64)
    cint, unit, err = _int_objective(obj)
    nz = np.flatnonzero(cint)
    expr = cp_model.LinearExpr.weighted_sum([xs[i] for i in nz.tolist()], cint[nz].tolist())
    if model.maximize:
        cp.maximize(expr)
    else:
        cp.minimize(expr)
    if hint:
        for i, v in hint.items():
            cp.add_hint(xs[i], int(round(v)))
    solver, code, build_s = run_cpsat(cp, workers, deadline, since)
    stats: dict[str, Any] = {
        "backend": "CP-SAT",
        "workers": thread_count(workers),
        "variables": model.n_vars,
        "constraints": len(model.rows),
        "time_build_s": build_s,
        "time_solve_s": since() - build_s,
        "objective_unit": unit,
        "rounding_error": err,
        "solver_status": solver.status_name(code),
    }
    values = None
    if code in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        values = np.array([solver.value(v) for v in xs], dtype=np.float64)
        ib = float(solver.best_objective_bound)
        bound = ib * unit + err if model.maximize else ib * unit - err
        stats["branches"] = int(solver.num_branches)
    else:
        bound = math.inf if model.maximize else -math.inf
    if code == cp_model.OPTIMAL:
        status = "optimal" if err == 0.0 else "feasible"  # the caller re-checks the gap
    elif code == cp_model.FEASIBLE:
        status = "feasible"
    elif code == cp_model.INFEASIBLE:
        status = "infeasible"
    else:
        status = "unknown"
    return EngineOutcome(None, status, bound, stats, engine="cpsat", values=values)
