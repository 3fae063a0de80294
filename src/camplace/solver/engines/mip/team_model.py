"""The camera-team model (issue 31): max coverage, best quality, multiview coverage or minimum-cost
cover under :class:`~camplace.solver.problem.team.TeamConstraints`, for SCIP or CP-SAT.

Variables ``x_j`` for every allowed column (fixed ones with ``x_j = 1``), no column dropped (a
dominance argument across models, zones or costs would be wrong once these constraints apply)::

    maxcover   maximise  sum_r w_r y_r      y_r <= sum_{j observes r, j free} x_j, y_r in [0, 1]
    setcover   minimise  sum_{j free} c_j x_j
               s.t.      sum_{j observes r} x_j >= 1   (every coverable row of positive weight), or
                         sum_r w_r y_r >= f * W           (required_fraction f < 1)
    quality    maximise  sum_i w_i max_{j chosen} q_ij    (the level chains of
                         :func:`~camplace.solver.engines.mip.mode_models.add_quality_rows`, over what a
                         free column adds to the fixed cameras' best quality)
    multiview  maximise  sum_i w_i y_i      y_i = 1 only when >= views chosen cameras (fixed ones
                         included) observe i, and with a minimum angle two of them far enough apart
                         (:func:`~camplace.solver.engines.mip.mode_models.add_multiview_rows`)

and the team rows: ``sum_{j free} x_j = k`` (cardinality ``exact``; ``<= k`` for ``budget`` with
a k), ``lo_m <= sum_{j of model m} x_j <= hi_m``, ``sum_j cost_j x_j <= budget``,
``lo_z <= sum_{j in zone z} x_j <= hi_z``, ``sum_{j at pose p} x_j <= 1`` and ``x_a + x_b <= 1``
for every pair closer than ``min_distance_m``. Rows covered by a fixed camera leave the objective
(their weight is the constant ``base``); identical rows are merged (weights summed).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline, as_deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes
from camplace.solver.engines.mip.linear import LinearModel, model_bytes, solve_model
from camplace.solver.engines.mip.mode_models import (BuildTimeout, add_multiview_rows, add_quality_rows, merge_rows,
                                                     model_size)
from camplace.solver.problem.team import TeamConstraints
from camplace.solver.result import EngineOutcome

__all__ = ["solve_team_model", "add_team_rows"]


def _integral(values: np.ndarray) -> bool:
    return bool(np.all(np.abs(values - np.round(values)) <= 1e-9 * np.maximum(1.0, np.abs(values))))


def solve_team_model(
    q: sp.csr_matrix, w: np.ndarray, team: TeamConstraints, *, mode: str, k: int | None, fixed: tuple[int, ...],
    free_cols: np.ndarray, conflicts: np.ndarray, costs: np.ndarray | None, required_fraction: float,
    backend: str, deadline: Deadline | None = None, hint: tuple[int, ...] | None = None, views: int = 2,
    min_angle_deg: float | None = None, pos: np.ndarray | None = None, pts: np.ndarray | None = None,
) -> EngineOutcome:
    """Build and solve the team model (see the module docstring).

    Parameters
    ----------
    q : (m, n) csr_matrix
    w : (m,) float64
    team : TeamConstraints
    mode : {"maxcover", "quality", "multiview", "setcover"}
    k : int or None
        New cameras (exactly, or at most for cardinality ``budget``); None: no count.
    fixed : tuple of int
    free_cols : (f,) int64
        Columns that may be chosen (not fixed, not forbidden, not in conflict with a fixed one).
    conflicts : (c, 2) int64
        Pairs of free columns that may not both be chosen.
    costs : (n,) float64 or None
        setcover objective costs (default: the team's).
    required_fraction : float
    backend : {"mip", "cpsat"}
    deadline : Deadline, optional
        The solve's deadline (default: none).
    hint : tuple of int, optional
        A feasible selection (original columns) given to the solver.
    views : int, optional
        multiview: observers a row needs.
    min_angle_deg : float, optional
        multiview: the smallest angle between two of them (needs ``pos`` and ``pts``).
    pos : (n, 3) float64, optional
        Camera positions, metres (multiview with a minimum angle).
    pts : (m, 3) float64, optional
        Point positions, metres (multiview with a minimum angle; None: no angle).

    Returns
    -------
    EngineOutcome
        ``selected``: original columns, fixed included (None: none found); the model's ``status``
        and ``bound`` (objective units: coverage weight including ``base``, or cost of the new
        cameras); ``engine``: ``backend``; ``stats``. Status ``"unknown"`` with no selection when the
        time limit passes while the model is being built (quality, multiview); the caller,
        :func:`camplace.solver.routes.run_team`, then answers with its greedy team (the ``hint``).
    """
    m, n = q.shape
    if backend == "cpsat" and mode == "setcover" and required_fraction < 1.0:
        raise CamplaceError("engine cpsat: a team set cover with required_fraction < 1 has a weighted row; use engine mip")
    cols = np.concatenate([np.asarray(fixed, dtype=np.int64), np.asarray(free_cols, dtype=np.int64)])
    nfix = len(fixed)
    deadline = as_deadline(deadline)
    model = LinearModel(maximize=mode != "setcover")
    x = model.add_vars(cols.size, integer=True)
    for i in range(nfix):
        model.lb[int(x[i])] = 1.0
    pos_of = np.full(n, -1, dtype=np.int64)
    pos_of[cols] = np.arange(cols.size)
    stats: dict[str, Any] = {"columns": int(cols.size)}
    q_free = q[:, free_cols].tocsr()
    pat = (q_free > 0).astype(np.int8).tocsr() if q_free.dtype != np.bool_ else q_free.astype(np.int8).tocsr()
    if nfix:
        covered_fixed = np.asarray((q[:, list(fixed)] > 0).sum(axis=1)).ravel() > 0
    else:
        covered_fixed = np.zeros(m, dtype=bool)
    const = 0.0
    if mode == "maxcover":
        const = float(w[covered_fixed].sum())
        keep = np.flatnonzero(~covered_fixed & (w > 0) & (np.diff(pat.indptr) > 0))
        a, wa = merge_rows(pat[keep].tocsr(), w[keep])
        stats["rows"] = int(a.shape[0])
        wmax = float(wa.max()) if wa.size else 1.0
        y = model.add_vars(a.shape[0], integer=False, obj=wa / wmax)
        for r in range(a.shape[0]):
            idx = a.indices[a.indptr[r]:a.indptr[r + 1]]
            model.add_row(np.r_[y[r], x[nfix + idx]], np.r_[1.0, -np.ones(idx.size)], hi=0.0)
        scale = wmax
    elif mode in ("quality", "multiview"):
        if mode == "multiview" and min_angle_deg is None:
            pts = None
        _check_memory(q, w, mode, views, min_angle_deg, pos, pts, tuple(fixed), free_cols, conflicts, backend)
        wpos = w[w > 0]
        scale = float(wpos.max()) if wpos.size else 1.0

        def check(r: int) -> None:
            if (r & 255) == 0 and deadline.expired():
                raise BuildTimeout

        try:
            if mode == "quality":
                base = q[:, list(fixed)].max(axis=1).toarray().ravel() if nfix else np.zeros(m)
                resid = q_free.astype(np.float64)
                if nfix:  # what a new camera adds over the fixed cameras' best quality
                    resid.data = np.maximum(resid.data - np.repeat(base, np.diff(resid.indptr)), 0.0)
                    resid.eliminate_zeros()
                const = float(w @ base)
                add_quality_rows(model, x[nfix:], resid, w, scale, check)
            else:
                add_multiview_rows(model, x[nfix:], q, w, int(views), min_angle_deg, pos, pts, tuple(fixed),
                                   np.asarray(free_cols, dtype=np.int64), scale, check, x_fixed=x[:nfix])
        except BuildTimeout:
            stats["model_build"] = "interrupted by the time limit"
            return EngineOutcome(None, "unknown", math.inf, stats, engine=backend)
        stats["model_variables"] = len(model.lb)
    else:
        c = team.cost if costs is None else np.asarray(costs, dtype=np.float64)
        cf = c[free_cols]
        for i, j in enumerate(free_cols):
            model.obj[int(x[nfix + i])] = float(cf[i])
        coverable = (np.diff(pat.indptr) > 0) & (w > 0) & ~covered_fixed
        stats["uncoverable_points"] = int(((w > 0) & ~covered_fixed & ~coverable).sum())
        keep = np.flatnonzero(coverable)
        a, wa = merge_rows(pat[keep].tocsr(), w[keep])
        stats["rows"] = int(a.shape[0])
        if required_fraction >= 1.0:
            for r in range(a.shape[0]):
                idx = a.indices[a.indptr[r]:a.indptr[r + 1]]
                model.add_row(x[nfix + idx], np.ones(idx.size), lo=1.0)
        else:
            total = float(w[(w > 0) & (covered_fixed | (np.diff(pat.indptr) > 0))].sum())
            need = required_fraction * total - float(w[covered_fixed].sum())
            if need > 0:
                y = model.add_vars(a.shape[0], integer=False)
                for r in range(a.shape[0]):
                    idx = a.indices[a.indptr[r]:a.indptr[r + 1]]
                    model.add_row(np.r_[y[r], x[nfix + idx]], np.r_[1.0, -np.ones(idx.size)], hi=0.0)
                wmax = float(wa.max())
                model.add_row(y, wa / wmax, lo=need / wmax * (1 - 1e-12))
        scale = 1.0
    # the team rows
    pose_rows = add_team_rows(model, x, cols, np.arange(cols.size) >= nfix, team, k, backend)
    if pose_rows is not None:
        stats["pose_rows"] = pose_rows
    for a_, b_ in np.asarray(conflicts, dtype=np.int64).reshape(-1, 2).tolist():
        model.add_row([x[pos_of[a_]], x[pos_of[b_]]], [1.0, 1.0], hi=1.0)
    hint_d = None
    if hint is not None:
        hs = set(hint)
        hint_d = {int(x[i]): (1.0 if int(cols[i]) in hs else 0.0) for i in range(cols.size)}
    out = solve_model(model, backend, deadline=deadline, hint=hint_d)
    stats["engine_stats"] = dict(out.stats)
    if out.values is None:
        bound = out.bound
        return EngineOutcome(None, out.status, bound, stats, engine=backend)
    chosen = tuple(sorted(int(cols[i]) for i in range(cols.size) if out.values[int(x[i])] > 0.5))
    raw = out.bound if abs(out.bound) < 1e19 else math.copysign(math.inf, out.bound)  # SCIP's "no bound yet" is 1e20
    bound = raw * scale + const if math.isfinite(raw) else raw
    return EngineOutcome(chosen, out.status, bound, stats, engine=backend)


def add_team_rows(model: LinearModel, x: np.ndarray, cols: np.ndarray, new: np.ndarray, team: TeamConstraints,
                  k: int | None, backend: str = "mip") -> int | None:
    """Add the team rows of the module docstring to ``model`` (the one home of them: the team model
    and the robust p10 model, :mod:`camplace.robust.p10`, both call it).

    Parameters
    ----------
    model : LinearModel
    x : (c,) int
        The variable of each column of ``cols``.
    cols : (c,) int64
        Original columns (fixed ones included).
    new : (c,) bool
        The columns the count ``k`` counts (not fixed).
    team : TeamConstraints
    k : int or None
        New cameras (exactly, or at most for cardinality ``budget``); None: no count row.
    backend : {"mip", "cpsat"}
        CP-SAT needs whole-number costs and budget (a one-line error otherwise).

    Returns
    -------
    int or None
        Pose rows added (None without the one-camera-per-pose limit).
    """
    x = np.asarray(x)
    xn = x[np.asarray(new, dtype=bool)]
    if k is not None:
        if team.cardinality == "exact":
            model.add_row(xn, np.ones(xn.size), lo=float(k), hi=float(k))
        else:
            model.add_row(xn, np.ones(xn.size), hi=float(k))
    cm = team.model[cols]
    for mi, (lo, hi) in enumerate(zip(team.model_min, team.model_max)):
        sel = np.flatnonzero(cm == mi)
        if lo > 0 or hi is not None:
            model.add_row(x[sel], np.ones(sel.size), lo=float(lo), hi=math.inf if hi is None else float(hi))
    if team.budget is not None:
        cc = team.cost[cols]
        variant = None
        if not _integral(cc) or not _integral(np.array([team.budget])):
            if backend == "cpsat":
                raise CamplaceError("engine cpsat needs whole-number costs and budget under team constraints; use engine mip")
        else:
            variant = (np.round(cc).astype(np.int64), -math.inf, float(math.floor(team.budget + 1e-9)))
        model.add_row(x, cc, hi=float(team.budget) * (1 + 1e-12) + 1e-9, int_variant=variant)
    zm = team.zone_member[cols]
    for zi, (lo, hi) in enumerate(zip(team.zone_min, team.zone_max)):
        sel = np.flatnonzero(zm[:, zi])
        if lo > 0 or hi is not None:
            model.add_row(x[sel], np.ones(sel.size), lo=float(lo), hi=math.inf if hi is None else float(hi))
    if team.pose is None:
        return None
    pc = team.pose[cols]
    order = np.argsort(pc, kind="stable")
    bounds = np.flatnonzero(np.r_[True, np.diff(pc[order]) != 0, True])
    groups = 0
    for s, e in zip(bounds[:-1], bounds[1:]):
        if e - s > 1:
            model.add_row(x[order[s:e]], np.ones(e - s), hi=1.0)
            groups += 1
    return groups


def _check_memory(q: sp.csr_matrix, w: np.ndarray, mode: str, views: int, min_angle_deg: float | None,
                  pos: np.ndarray | None, pts: np.ndarray | None, fixed: tuple[int, ...], free_cols: np.ndarray,
                  conflicts: np.ndarray, backend: str) -> None:
    """Raise :class:`~camplace.solver._support.memory.OverBudget` before building a quality /
    multiview team model that would not fit in memory (the size of the k-camera model of
    :func:`~camplace.solver.engines.mip.mode_models.model_size`; the team rows add a handful); the
    caller applies the memory policy."""
    budget = memory_budget_bytes()
    qf = q[:, np.asarray(free_cols, dtype=np.int64)].tocsr()
    size = model_size(q, qf, w, w, mode, int(views), min_angle_deg, pos, pts, fixed, np.asarray(free_cols),
                      np.asarray(conflicts, dtype=np.int64).reshape(-1, 2), budget)
    need = model_bytes(backend, *size)
    if need > budget:
        raise OverBudget(need, budget, f"the {'SCIP' if backend == 'mip' else 'CP-SAT'} team model of mode {mode}")
