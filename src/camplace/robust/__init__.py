"""Robust placement: choose the cameras that still work when they are installed a little off.

A stage of the pipeline after the solver (it re-casts rays through :mod:`camplace.visibility` and
solves through :mod:`camplace.solver`): :mod:`~camplace.robust.stage` (the scenarios, the robust
solve, the out-of-sample check: :func:`robust_stage`, the hook of :func:`camplace.pipeline.run`),
:mod:`~camplace.robust.p10` (the 10th-percentile objective and its SCIP model) and
:mod:`~camplace.robust.cli` (``--pose-error``, ``--scenarios``, ``--robust-objective`` and the
``solve`` verb, registered like the verbs of :mod:`camplace.plan` and :mod:`camplace.validation`).

Imports nothing heavy at import time.

A robust run samples S installations (scenarios) of every candidate
(:func:`camplace.sampling.perturb.perturb_poses`: position error ``N(0, sigma_p^2)`` per axis,
rotation ``R @ Exp(w)``, ``w ~ N(0, sigma_r^2 I)``, the ``[physical]`` model) and optimises

``mean``
    the expected objective over the scenarios. It is the run's formulation (maxcover, quality,
    multiview) on the scenarios' rows stacked: row ``s * m + i`` is point ``i`` in scenario
    ``s`` with weight ``w_i / S``, column ``j`` candidate ``j`` as installed in scenario ``s``
    (:func:`stack_scenarios`). Every exact engine of :func:`camplace.solver.solve` applies
    unchanged, so the answer is proven optimal for the sampled objective like a nominal run.
``p10``
    the value reached in at least 90 % of the installations, by the scenario-indicator model of
    :mod:`camplace.robust.p10` (status, bound and gap as reported there).

The visibility of the S * n perturbed poses is computed in one pass of the visibility engine on the
run's points (a CandidateSet of ``S * n`` poses, scenario-major), then its columns are restacked
into rows by index arithmetic on the sparse entries (:func:`stack_scenarios`); a binary
instance's, in the robust stage, as column bitsets (:func:`~camplace.robust.stage.stack_bit_scenarios`,
no CSR: the mean solve, the per-scenario values and the p10 solve read the bits; a p10 model
under its size cap makes the CSR of its merged rows only).

Out of sample: the chosen system and the nominal optimum are compared on ``eval_scenarios`` fresh
installations (another seed stream, :data:`~camplace.sampling.perturb.OUT_OF_SAMPLE_STREAM`):
expected objective and 10th percentile (:func:`camplace.robust.p10.order_p10`), written to
``solution.json`` under ``robust``.

With zero sigma every scenario is the nominal installation, so the robust problem is the nominal
one: the run then keeps the nominal answer as it is (no stacking, the same cameras and figures).
"""

from __future__ import annotations

from camplace._lazy import lazy_getattr

_LAZY = {
    "ROBUST_MODES": "camplace.robust.stage",
    "make_spec": "camplace.robust.stage",
    "spec_record": "camplace.robust.stage",
    "check_request": "camplace.robust.stage",
    "stack_scenarios": "camplace.robust.stage",
    "scenario_matrix": "camplace.robust.stage",
    "solve_robust": "camplace.robust.stage",
    "out_of_sample": "camplace.robust.stage",
    "robust_stage": "camplace.robust.stage",
    "order_p10": "camplace.robust.p10",
    "scenario_values": "camplace.robust.p10",
    "solve_p10": "camplace.robust.p10",
}

__getattr__ = lazy_getattr(__name__, _LAZY)

__all__ = sorted(_LAZY)
