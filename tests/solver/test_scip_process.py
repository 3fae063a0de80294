"""Issue 30: SCIP in a child process stopped at the time limit (its root LP ignores the clock).

The child's answers are SCIP's (the same selection, objective and bound as SCIP in the process,
and the enumerated optimum); a child that does not answer is stopped at the deadline plus the
grace, and the solve then returns its own incumbent with a valid bound."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.solver.api import solve
from camplace.solver.engines.mip import linear, scip_process


def _instance(seed: int) -> tuple[sp.csr_matrix, np.ndarray]:
    rng = np.random.default_rng(seed)
    m, n = 60, 14
    a = (rng.random((m, n)) < rng.uniform(0.1, 0.4, size=n)).astype(np.float32)
    return sp.csr_matrix(a), rng.uniform(0.5, 1.5, m)


def _enumerated(a: sp.csr_matrix, w: np.ndarray, k: int, views: int = 1) -> float:
    dense = a.toarray() > 0
    best = 0.0
    for sel in itertools.combinations(range(a.shape[1]), k):
        seen = dense[:, list(sel)].sum(axis=1)
        best = max(best, float(w[seen >= views].sum()))
    return best


@pytest.mark.parametrize("mode", ["maxcover", "multiview"])
def test_child_answers_as_scip_in_the_process(monkeypatch, mode: str) -> None:
    """Max coverage (the MIP engine) and multiview (a mode model through ``solve_model``): the child
    gives the selection, status, objective and bound SCIP gives in the process, and the optimum."""
    kw = {"k": 3, "engine": "mip", "time_limit_s": 30.0}
    views = 1
    if mode == "multiview":
        kw.update(mode="multiview", views=2)
        views = 2
    for seed in (1, 2):
        a, w = _instance(seed)
        inproc = solve(a, w, **kw)
        monkeypatch.setattr(linear, "CHILD_MIN_NONZEROS", 0)
        calls = []
        real = scip_process.solve_in_child
        monkeypatch.setattr(scip_process, "solve_in_child", lambda *args: calls.append(1) or real(*args))
        child = solve(a, w, **kw)
        monkeypatch.undo()
        assert calls, "the child process was not used"
        assert child.status == inproc.status == "optimal"
        assert child.selected == inproc.selected
        assert child.objective == inproc.objective
        assert child.bound == inproc.bound
        assert child.objective == pytest.approx(_enumerated(a, w, 3, views), rel=1e-12)


def test_a_child_that_does_not_answer_is_stopped_at_the_deadline(monkeypatch) -> None:
    monkeypatch.setattr(scip_process, "CHILD_ARGS", ("-c", "import time; time.sleep(60)"))
    left = 0.8
    t = time.perf_counter()
    run = scip_process.solve_in_child(b"", time.time() + left, [], [], 1e-9, 0.0)
    wall = time.perf_counter() - t
    assert run.stopped and run.values is None and run.code == 6
    assert left <= wall <= left + scip_process.grace_s(left) + 0.5


def test_solve_answers_with_its_incumbent_when_scip_is_stopped(monkeypatch) -> None:
    """The MIP engine with a child that never answers: the greedy team and a bound at least the
    optimum, within the limit plus 5 % (and a small constant)."""
    a, w = _instance(3)
    monkeypatch.setattr(linear, "CHILD_MIN_NONZEROS", 0)
    monkeypatch.setattr(scip_process, "CHILD_ARGS", ("-c", "import time; time.sleep(60)"))
    limit = 1.5
    t = time.perf_counter()
    res = solve(a, w, k=3, engine="mip", time_limit_s=limit)
    wall = time.perf_counter() - t
    assert wall <= limit * 1.05 + 0.5
    opt = _enumerated(a, w, 3)
    assert res.status in ("feasible", "optimal") and len(res.selected) == 3
    assert res.objective <= opt + 1e-12 <= res.bound + 2e-12
    assert "stopped" in str(res.stats)


def test_a_failing_child_is_an_error_not_an_answer(monkeypatch) -> None:
    monkeypatch.setattr(scip_process, "CHILD_ARGS", ("-c", "import sys; sys.exit('boom')"))
    with pytest.raises(RuntimeError, match="boom"):
        scip_process.solve_in_child(b"", time.time() + 5.0, [], [], 1e-9, 0.0)


def test_ctrl_c_in_the_child_stops_the_run(monkeypatch) -> None:
    """Ctrl-C reaches the whole process group: a child ended by it ends the solve as Ctrl-C does.
    (The child restores SIGINT's default action first: a test run started in the background of a
    non-interactive shell inherits SIGINT ignored, and the child would then outlive the signal.)"""
    monkeypatch.setattr(scip_process, "CHILD_ARGS", ("-c", "import os, signal, time; signal.signal(signal.SIGINT, "
                                                           "signal.SIG_DFL); os.kill(os.getpid(), signal.SIGINT); time.sleep(30)"))
    with pytest.raises(KeyboardInterrupt):
        scip_process.solve_in_child(b"", time.time() + 5.0, [], [], 1e-9, 0.0)


def test_scip_keeps_to_the_memory_budget(monkeypatch) -> None:
    """SCIP gets ``limits/memory`` from the memory budget (its tree grows with the time it is
    given): the value follows ``--memory-budget-gb``, SCIP takes the parameter, the child process
    receives it, and a model still solves to the enumerated optimum under it."""
    from camplace.solver._support.memory import memory_budget
    from ortools.linear_solver import pywraplp

    with memory_budget(300 * 2**20):
        assert 64 <= linear.scip_memory_mb() <= 300
    assert scip_process.limit_scip_memory(pywraplp.Solver.CreateSolver("SCIP"), 300)
    echo = ("import pickle, sys; raw = sys.stdin.buffer.read(); n = int.from_bytes(raw[:8], 'little'); "
            "sys.stdout.buffer.write(pickle.dumps({'error': 'memory_mb=%s' % pickle.loads(raw[8:8 + n])['memory_mb']}))")
    monkeypatch.setattr(scip_process, "CHILD_ARGS", ("-c", echo))
    with pytest.raises(RuntimeError, match="memory_mb=321"):
        scip_process.solve_in_child(b"", time.time() + 5.0, [], [], 1e-9, 0.0, 321)
    monkeypatch.undo()
    a, w = _instance(4)
    monkeypatch.setattr(linear, "CHILD_MIN_NONZEROS", 0)
    with memory_budget(400 * 2**20):
        res = solve(a, w, k=3, engine="mip", time_limit_s=30.0)
    assert res.status == "optimal" and res.objective == pytest.approx(_enumerated(a, w, 3), rel=1e-12)
