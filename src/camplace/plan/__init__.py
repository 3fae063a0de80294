"""Agents that move: one pose set per phase of the event, within how fast each agent can travel.

The event's frames are split into consecutive phases (:mod:`camplace.plan.phases`); k identical
agents (drones, rovers, people with tripods) each hold one candidate pose per phase and travel in a
straight line between the starts of consecutive phases, at most ``speed x (start of next phase -
start of this phase)``. :func:`solve_plan` maximises the sum over phases of the solver's mode value
(maxcover, quality, multiview) on that phase's rows, with a proven bound, and reports the best
static system and the sum of the per-phase optima as references (:mod:`camplace.plan.planner`).

Imports only the solver and positions as arrays (no geometry); nothing heavy at import time.
"""

from __future__ import annotations

from camplace._lazy import lazy_getattr

_LAZY = {
    "Phase": "camplace.plan.phases",
    "split_phases": "camplace.plan.phases",
    "PlanProblem": "camplace.plan.model",
    "make_problem": "camplace.plan.model",
    "plan_value": "camplace.plan.model",
    "check_plan": "camplace.plan.model",
    "PLAN_MODES": "camplace.plan.model",
    "PlanResult": "camplace.plan.planner",
    "StaticReference": "camplace.plan.planner",
    "solve_plan": "camplace.plan.planner",
    "plan_run_folder": "camplace.plan.workflow",
    "load_plan": "camplace.plan.io",
    "phase_camera_records": "camplace.plan.io",
}

__getattr__ = lazy_getattr(__name__, _LAZY)

__all__ = sorted(_LAZY)
