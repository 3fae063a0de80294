"""SCIP in a child process that is stopped at the time limit.

SCIP reads its clock between steps of its search, not inside the root LP: measured on a
max-coverage model of 13.3 million nonzeros (2 cores), a solve given 0.1 s took 4.2 s and one given
30 s took 51 s. A run with ``--time-limit`` must end within the limit, so a large model is solved
in a child Python process (the same interpreter, importing only OR-Tools): the parent sends the
serialised ``MPModelProto``, the hint and the deadline (an absolute time of the wall clock), and
waits until the deadline plus a short grace; a child still running then is killed and the caller
answers as if SCIP had found nothing (its own incumbent, its own valid bound). The child's answer,
when it comes in time, is exactly what SCIP in the parent would have returned.

Usage (inside the package): :func:`solve_in_child`; ``python -m
camplace.solver.engines.mip.scip_process`` is the child's side (it reads stdin, writes stdout).
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np

__all__ = ["ScipRun", "solve_in_child", "grace_s"]

#: the child's command line after the interpreter (a module attribute so that tests can give it one
#: that never answers)
CHILD_ARGS = ("-m", __name__)


@dataclass(frozen=True)
class ScipRun:
    """What a SCIP solve returned.

    Attributes
    ----------
    code : int
        ``pywraplp.Solver`` result status (OPTIMAL 0, FEASIBLE 1, INFEASIBLE 2, NOT_SOLVED 6, ...).
    values : (n_vars,) float64 or None
        The solution's variable values, when ``code`` is OPTIMAL or FEASIBLE.
    bound : float
        SCIP's best objective bound (nan without a solution).
    nodes : int
        Branch-and-bound nodes.
    build_s : float
        Seconds from the caller's stopwatch start until the solve began.
    stopped : str or None
        Why the child process was stopped before it answered (the time limit), else None.
    """

    code: int
    values: np.ndarray | None
    bound: float
    nodes: int
    build_s: float
    stopped: str | None = None


def grace_s(left_s: float) -> float:
    """Seconds the parent waits past the deadline for the child's answer: 0.2 s plus 1 % of the
    time that was left when the solve began (the answer's transfer; SCIP stops at its limit when it
    reads the clock)."""
    return 0.2 + 0.01 * max(0.0, left_s)


def limit_scip_memory(solver, memory_mb: int) -> bool:
    """Set SCIP's ``limits/memory`` (MiB) on an OR-Tools SCIP ``solver``; False (and a warning in the
    log) when SCIP does not take it."""
    ok = bool(solver.SetSolverSpecificParametersAsString(f"limits/memory = {int(memory_mb)}\n"))
    if not ok:
        logging.getLogger(__name__).warning("SCIP did not take its memory limit (%d MiB): it runs without one", int(memory_mb))
    return ok


def solve_in_child(data: bytes, deadline_epoch: float, hint_vars, hint_values, rel_gap: float,
                   build_s: float, memory_mb: int | None = None) -> ScipRun:
    """Solve a serialised ``MPModelProto`` with SCIP in a child process, stopped at the deadline.

    Parameters
    ----------
    data : bytes
        ``MPModelProto.SerializeToString()``.
    deadline_epoch : float
        ``time.time()`` at which the solve must end (the child gives SCIP what is left of it).
    hint_vars, hint_values : sequence
        Variable indices and hinted values.
    rel_gap : float
        SCIP's relative MIP gap.
    build_s : float
        Passed through to :attr:`ScipRun.build_s`.
    memory_mb : int or None
        SCIP's ``limits/memory`` (MiB): past it SCIP stops with its best solution (None: SCIP's default).

    Returns
    -------
    ScipRun
        ``stopped`` set (and ``code`` NOT_SOLVED) when the child had not answered by the deadline
        plus :func:`grace_s`.

    Raises
    ------
    RuntimeError
        The child failed (OR-Tools without SCIP: the message starts with ``no SCIP``; a model SCIP
        would not load; a crash).
    """
    header = pickle.dumps({"deadline_epoch": float(deadline_epoch), "hint_vars": [int(i) for i in hint_vars],
                           "hint_values": [float(v) for v in hint_values], "rel_gap": float(rel_gap),
                           "memory_mb": None if memory_mb is None else int(memory_mb)})
    payload = len(header).to_bytes(8, "little") + header + data
    left = max(0.0, deadline_epoch - time.time())
    proc = subprocess.Popen([sys.executable, *CHILD_ARGS], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        out, err = proc.communicate(payload, timeout=left + grace_s(left))
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return ScipRun(6, None, float("nan"), 0, build_s,
                       stopped=f"SCIP had not answered {grace_s(left):.2f} s after the time limit (its root LP "
                               "does not read the clock): its process was stopped")
    finally:
        if proc.poll() is None:  # Ctrl-C or another error while waiting
            proc.kill()
            proc.wait()
    if proc.returncode in (-signal.SIGINT, 130) or b"KeyboardInterrupt" in err:
        raise KeyboardInterrupt  # Ctrl-C reached the child too (one process group): the run stops
    if proc.returncode != 0 or not out:
        lines = err.decode("utf-8", "replace").strip().splitlines()
        raise RuntimeError(f"SCIP's process failed (exit {proc.returncode}): {lines[-1] if lines else 'no message'}")
    res = pickle.loads(out)
    if "error" in res:
        raise RuntimeError(res["error"])
    values = None if res["values"] is None else np.frombuffer(res["values"], dtype=np.float64).copy()
    return ScipRun(int(res["code"]), values, float(res["bound"]), int(res["nodes"]), build_s)


def _child() -> None:
    """The child's side: read the request on stdin, solve, write the pickled answer on stdout."""
    raw = sys.stdin.buffer.read()
    size = int.from_bytes(raw[:8], "little")
    req = pickle.loads(raw[8:8 + size])
    from ortools.linear_solver import linear_solver_pb2, pywraplp

    proto = linear_solver_pb2.MPModelProto.FromString(raw[8 + size:])
    del raw
    solver = pywraplp.Solver.CreateSolver("SCIP")
    if solver is None:
        answer = {"error": "no SCIP in this OR-Tools build"}
    else:
        err = solver.LoadModelFromProto(proto)
        del proto
        if err:
            answer = {"error": f"SCIP model load failed: {err}"}
        else:
            solver.SetNumThreads(1)
            if req.get("memory_mb"):
                limit_scip_memory(solver, req["memory_mb"])
            variables = solver.variables()
            if req["hint_vars"]:
                solver.SetHint([variables[i] for i in req["hint_vars"]], req["hint_values"])
            solver.SetTimeLimit(max(1, int((req["deadline_epoch"] - time.time()) * 1000)))
            params = pywraplp.MPSolverParameters()
            params.SetDoubleParam(pywraplp.MPSolverParameters.RELATIVE_MIP_GAP, req["rel_gap"])
            code = solver.Solve(params)
            has = code in (pywraplp.Solver.OPTIMAL, pywraplp.Solver.FEASIBLE)
            values = np.array([v.solution_value() for v in variables], dtype=np.float64).tobytes() if has else None
            answer = {"code": int(code), "values": values, "nodes": int(solver.nodes()) if has else 0,
                      "bound": float(solver.Objective().BestBound()) if has else float("nan")}
    sys.stdout.buffer.write(pickle.dumps(answer))
    sys.stdout.buffer.flush()
    os._exit(0)  # no teardown: freeing a large SCIP model takes seconds (2.7 s for 13 M nonzeros)


if __name__ == "__main__":
    _child()
