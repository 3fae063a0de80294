"""The SCIP / CP-SAT models of the modes, built on :class:`camplace.solver.engines.mip.linear.LinearModel`.

:func:`model_size` states a k-camera model's size before :func:`build_model` builds it (the caller
compares :func:`~camplace.solver.engines.mip.linear.model_bytes` of it with the memory budget);
:func:`setcover_model` is the minimum-cost cover with minimum-distance conflicts
(:func:`check_setcover_memory` first). :func:`add_quality_rows` and :func:`add_multiview_rows`
are the objective rows of quality and multiview, shared with the camera-team model
(:mod:`camplace.solver.engines.mip.team_model`). The generic 0/1 model and its two OR-Tools backends stay in
:mod:`camplace.solver.engines.mip.linear`, which :mod:`camplace.plan` uses as well.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback
from camplace.solver.engines.angle._kernels import count_bad_pairs
from camplace.solver.engines.mip.linear import LinearModel, model_bytes
from camplace.solver.problem.objectives import angle_ok_pairs, selected_row_stats
from camplace.solver.problem.presolve import as_pattern

__all__ = ["BuildTimeout", "add_level_chain", "add_quality_rows", "add_multiview_rows", "merge_rows", "cover_model_size", "model_size",
           "build_model", "check_setcover_memory", "setcover_model"]

_MODEL_BYTES_PER_ROW_MIN = 1000  # no model row costs less (see camplace.solver.engines.mip.linear.model_bytes)


class BuildTimeout(Exception):
    """The time limit passed while the general model was being built."""


def merge_rows(a: sp.csr_matrix, w: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Merge rows with identical indices AND values, summing their weights."""
    seen: dict[bytes, int] = {}
    first: list[int] = []
    wsum: list[float] = []
    for i in range(a.shape[0]):
        s, e = a.indptr[i], a.indptr[i + 1]
        key = a.indices[s:e].astype(np.int32).tobytes() + b"|" + a.data[s:e].tobytes()
        g = seen.get(key)
        if g is None:
            seen[key] = len(first)
            first.append(i)
            wsum.append(float(w[i]))
        else:
            wsum[g] += float(w[i])
    return a[first].tocsr() if first else a[:0], np.asarray(wsum, dtype=np.float64)


def cover_model_size(rows: int, n_free: int, entries: int, conflicts: int, n_fixed: int = 0) -> tuple[int, int, int]:
    """Variables, constraints and nonzeros of the max-coverage or multiview model (no angle) of
    ``rows`` counted rows with ``entries`` matrix entries over ``n_free`` free and ``n_fixed``
    fixed columns, with ``conflicts`` minimum-distance pairs: a variable per column and per row,
    a row per counted row, per conflict and the cardinality row. Given the whole matrix's rows and
    entries it is an upper bound on :func:`model_size` (what the memory guard counts before the
    matrix exists)."""
    rows, entries, conflicts = int(rows), int(entries), int(conflicts)
    return (int(n_free) + int(n_fixed) + rows, 1 + conflicts + rows, int(n_free) + 2 * conflicts + entries + rows)


def model_size(
    q: sp.csr_matrix, resid: sp.csr_matrix, resid_w: np.ndarray, w: np.ndarray, mode: str, views: int,
    min_angle_deg: float | None, pos: np.ndarray | None, pts: np.ndarray | None, fixed_t: tuple[int, ...],
    free_cols: np.ndarray, conflicts: np.ndarray, budget: int,
) -> tuple[int, int, int]:
    """Variables, rows and nonzeros of the model :func:`build_model` would build (upper bounds),
    computed without building it. With the angle, the pairs of observers closer than the angle (one
    row each) are counted per point, stopping once the model could not fit in ``budget`` anyway.
    """
    nf = free_cols.size
    n_conf = int(conflicts.shape[0])
    n_vars, n_rows, nnz = nf, 1 + n_conf, nf + 2 * n_conf
    if mode in ("maxcover", "quality"):
        cnt = np.diff(resid.indptr)
        live = (resid_w > 0) & (cnt > 0)
        entries = int(cnt[live].sum())
        if mode == "maxcover":
            return cover_model_size(int(live.sum()), nf, entries, n_conf)
        rows = entries  # quality: a row per distinct level
        return n_vars + rows, n_rows + rows, nnz + entries + 2 * rows
    allowed = np.zeros(q.shape[1], dtype=bool)
    allowed[free_cols] = True
    allowed[list(fixed_t)] = True
    nobs, _ = selected_row_stats(q, np.flatnonzero(allowed))
    live = np.flatnonzero((w > 0) & (nobs >= views))
    s = nobs[live].astype(np.int64)
    if pts is None:
        return cover_model_size(live.size, nf, int(s.sum()), n_conf, len(fixed_t))
    n_vars += len(fixed_t)
    assert pos is not None
    limit = budget // _MODEL_BYTES_PER_ROW_MIN
    data = q.data.view(np.uint8) if q.data.dtype.kind == "b" else q.data
    with ctrl_c_deferred():
        bad = int(count_bad_pairs(q.indptr, q.indices, data, live.astype(np.int64), allowed, pos, pts,
                                  float(min_angle_deg or 0.0), limit))
    extra = int(views > 2)
    return (n_vars + int((s + 1).sum()), n_rows + int((s + 1 + extra).sum()) + bad,
            nnz + int((3 * s + 1 + extra * (s + 1)).sum()) + 2 * bad)


def add_level_chain(model: LinearModel, x: np.ndarray, cols: np.ndarray, vals: np.ndarray, weight: float,
                    wmax: float) -> tuple[np.ndarray, np.ndarray]:
    """The quality chain of one point: with its distinct values ``q_1 > ... > q_L``, variables
    ``y_l <= y_(l-1) + sum_(j: Q_ij = q_l) x_j`` of objective ``weight (q_l - q_(l+1)) / wmax``.

    Parameters
    ----------
    model : LinearModel
    x : (n,) int64
        The camera variables.
    cols : (s,) int
        Columns observing the point.
    vals : (s,) float
        Their qualities.
    weight, wmax : float
        The point's weight and the objective's scale.

    Returns
    -------
    ys : (L,) int64
        The level variables.
    coef : (L,) float64
        Their objective coefficients.
    """
    levels = np.unique(vals)[::-1]
    nxt = np.append(levels[1:], 0.0)
    coef = weight * (levels - nxt) / wmax
    ys = model.add_vars(levels.size, integer=False, obj=coef)
    for li, lv in enumerate(levels):
        at = cols[vals == lv]
        idx = np.append(x[at], ys[li])
        row = np.append(np.ones(at.size), -1.0)
        if li > 0:
            idx, row = np.append(idx, ys[li - 1]), np.append(row, 1.0)
        model.add_row(idx, row, lo=0.0)
    return ys, coef


def build_model(
    q: sp.csr_matrix, resid: sp.csr_matrix, resid_w: np.ndarray, w: np.ndarray, base: np.ndarray, k: int,
    mode: str, views: int,
    min_angle_deg: float | None, pos: np.ndarray | None, pts: np.ndarray | None, fixed_t: tuple[int, ...],
    free_cols: np.ndarray, conflicts: np.ndarray, fixed_value: float, deadline: Deadline,
) -> tuple[LinearModel, np.ndarray, float, float]:
    """The SCIP / CP-SAT model of a k-camera mode: (model, x variables, objective scale, constant).

    Raises :class:`BuildTimeout` when the time limit passes while rows are being added.
    """

    def check(r: int) -> None:
        if (r & 255) == 0 and deadline.expired():
            raise BuildTimeout

    model = LinearModel(maximize=True)
    nf = free_cols.size
    x = model.add_vars(nf)
    model.add_row(x, np.ones(nf), float(k), float(k))
    for a, b in np.searchsorted(free_cols, conflicts).tolist() if conflicts.size else []:
        model.add_row([x[a], x[b]], [1.0, 1.0], hi=1.0)
    wmax = float(resid_w.max()) if resid_w.size and resid_w.max() > 0 else 1.0
    const = 0.0
    if mode == "maxcover":
        live = (resid_w > 0) & (np.diff(resid.indptr) > 0)
        pr, pw = merge_rows(as_pattern(resid[live]), resid_w[live])
        y = model.add_vars(pr.shape[0], integer=False, obj=pw / wmax)
        for r in range(pr.shape[0]):
            check(r)
            cols = pr.indices[pr.indptr[r] : pr.indptr[r + 1]]
            model.add_row(np.append(x[cols], y[r]), np.append(np.ones(cols.size), -1.0), lo=0.0)
        const = fixed_value
    elif mode == "quality":
        add_quality_rows(model, x, resid, resid_w, wmax, check)
        const = float(w @ base)
    else:
        add_multiview_rows(model, x, q, w, views, min_angle_deg, pos, pts, fixed_t, free_cols, wmax, check)

    return model, x, wmax, const


def add_quality_rows(model: LinearModel, x: np.ndarray, resid: sp.csr_matrix, resid_w: np.ndarray, wmax: float,
                     check: Callable[[int], None] = lambda r: None) -> None:
    """The quality objective: one :func:`add_level_chain` per live row of ``resid`` (identical rows merged).

    Parameters
    ----------
    model : LinearModel
    x : (f,) int64
        The variables of the free columns (the columns of ``resid``).
    resid : (m, f) csr_matrix
        What each free column adds over the fixed cameras' best quality (values in (0, 1]).
    resid_w : (m,) float64
        Row weights.
    wmax : float
        The objective's scale (objective coefficients are divided by it).
    check : callable, optional
        Called with the row number as rows are added (raises :class:`BuildTimeout` at the time limit).
    """
    live = (resid_w > 0) & (np.diff(resid.indptr) > 0)
    pr, pw = merge_rows(resid[live].tocsr(), resid_w[live])
    for r in range(pr.shape[0]):
        check(r)
        s, e = pr.indptr[r], pr.indptr[r + 1]
        add_level_chain(model, x, pr.indices[s:e], pr.data[s:e], pw[r], wmax)


def add_multiview_rows(
    model: LinearModel, x: np.ndarray, q: sp.csr_matrix, w: np.ndarray, views: int, min_angle_deg: float | None,
    pos: np.ndarray | None, pts: np.ndarray | None, fixed_t: tuple[int, ...], free_cols: np.ndarray, wmax: float,
    check: Callable[[int], None] = lambda r: None, x_fixed: np.ndarray | None = None,
) -> None:
    """The multiview objective: ``y_i`` (0/1, objective ``w_i / wmax``) only when at least ``views``
    chosen cameras observe row ``i`` (fixed ones included) and, with ``pts`` (the minimum angle),
    two of them whose view rays make at least ``min_angle_deg``.

    Parameters
    ----------
    model : LinearModel
    x : (f,) int64
        The variables of the free columns.
    q : (m, n) csr_matrix
    w : (m,) float64
    views : int
    min_angle_deg : float or None
    pos : (n, 3) float64 or None
        Camera positions (with ``pts``), metres.
    pts : (m, 3) float64 or None
        Point positions, metres; None: no angle.
    fixed_t : tuple of int
    free_cols : (f,) int64
    wmax : float
    check : callable, optional
        As in :func:`add_quality_rows`.
    x_fixed : (len(fixed_t),) int64, optional
        Variables of the fixed columns already in the model (fixed to 1 by the caller); default:
        new variables fixed to 1.
    """
    fx = np.array(fixed_t, dtype=np.int64)
    allc = np.concatenate([free_cols, fx])  # model columns: free ones then fixed
    xf = model.add_vars(fx.size, lb=1.0, ub=1.0) if x_fixed is None else np.asarray(x_fixed, dtype=np.int64)
    xall = np.concatenate([x, xf])
    qa = q[:, allc].tocsr()
    nobs = np.diff(qa.indptr)
    live = (w > 0) & (nobs >= views)
    if pts is None:
        pr, pw = merge_rows(as_pattern(qa[live]), w[live])
        y = model.add_vars(pr.shape[0], obj=pw / wmax)
        for r in range(pr.shape[0]):
            check(r)
            cols = pr.indices[pr.indptr[r] : pr.indptr[r + 1]]
            model.add_row(np.append(xall[cols], y[r]), np.append(np.ones(cols.size), -float(views)), lo=0.0)
    else:
        assert pos is not None
        for r, i in enumerate(np.flatnonzero(live)):
            check(r)
            cols = qa.indices[qa.indptr[i] : qa.indptr[i + 1]]
            good = angle_ok_pairs(pts[i], pos[allc[cols]], float(min_angle_deg or 0.0))
            if not np.any(np.triu(good, 1)):
                continue
            yi = int(model.add_vars(1, obj=w[i] / wmax)[0])
            if views > 2:
                model.add_row(np.append(xall[cols], yi), np.append(np.ones(cols.size), -float(views)), lo=0.0)
            u = model.add_vars(cols.size)
            for t, c in enumerate(cols):
                model.add_row([u[t], xall[c]], [1.0, -1.0], hi=0.0)
            model.add_row(np.append(u, yi), np.append(np.ones(cols.size), -2.0), 0.0, 0.0)
            bad_a, bad_b = np.nonzero(np.triu(~good, 1))
            for a, b in zip(bad_a.tolist(), bad_b.tolist()):
                model.add_row([u[a], u[b]], [1.0, 1.0], hi=1.0)


def check_setcover_memory(q: Any, w: np.ndarray, free_cols: np.ndarray, conflicts: np.ndarray,
                           engine: str) -> None:
    """One-line error before building a set-cover model that would not fit in memory (there is no
    cheaper engine to fall back to)."""
    backend = "cpsat" if engine == "cpsat" else "mip"
    if getattr(q, "format", None) == "bits":  # column bitsets: the counts from the bits (no CSR)
        from camplace.solver.problem.presolve_bits import row_counts_of

        cnt = row_counts_of(q, free_cols)
    else:
        cnt, _ = selected_row_stats(q, free_cols)
    rows = int(np.count_nonzero((w > 0) & (cnt > 0)))
    entries = int(cnt.sum())
    n_conf = int(conflicts.shape[0])
    need = model_bytes(backend, free_cols.size + rows, rows + 1 + n_conf, entries + rows + 2 * n_conf)
    budget = memory_budget_bytes()
    if need > budget:
        memory_fallback(OverBudget(need, budget, f"the {'SCIP' if backend == 'mip' else 'CP-SAT'} set-cover model"),
                        None, asked=engine != "auto", then=None)  # no cheaper engine to fall back to


def setcover_model(
    sub: sp.csr_matrix, sw: np.ndarray, costs_free: np.ndarray, free_cols: np.ndarray, conflicts: np.ndarray,
    frac: float, need: float, coverable_w: float,
) -> tuple[LinearModel, np.ndarray, int]:
    """The SCIP / CP-SAT model of a minimum-cost cover with minimum-distance conflicts.

    Parameters
    ----------
    sub : (r, nf) csr_matrix
        0/1 pattern of the rows still to cover over the free columns.
    sw : (r,) float64
        Their weights.
    costs_free : (nf,) float64
        Costs of the free columns.
    free_cols : (nf,) int64
        Original indices of the free columns (sorted).
    conflicts : (p, 2) int64
        Pairs of original columns that may not both be chosen.
    frac : float
        Required fraction (1: every row; below 1 a weighted cover of at least ``need``).
    need : float
        Weight the new cameras must cover (``frac < 1``).
    coverable_w : float
        Coverable weight (scales the fractional requirement).

    Returns
    -------
    model : LinearModel
    x : (nf,) int64
        The camera variables.
    rows_after : int
        Cover rows after merging identical ones.
    """
    model = LinearModel(maximize=False)
    nf = free_cols.size
    x = model.add_vars(nf, obj=costs_free)
    for a, b in np.searchsorted(free_cols, conflicts).tolist() if conflicts.size else []:
        model.add_row([x[a], x[b]], [1.0, 1.0], hi=1.0)
    if frac >= 1.0:
        pr, _ = merge_rows(sub, sw)
        for r in range(pr.shape[0]):
            cols = pr.indices[pr.indptr[r] : pr.indptr[r + 1]]
            model.add_row(x[cols], np.ones(cols.size), lo=1.0)
    else:
        pr, pw = merge_rows(sub, sw)
        y = model.add_vars(pr.shape[0])
        for r in range(pr.shape[0]):
            cols = pr.indices[pr.indptr[r] : pr.indptr[r + 1]]
            model.add_row(np.append(x[cols], y[r]), np.append(np.ones(cols.size), -1.0), lo=0.0)
        scale_f = 1.0 / max(coverable_w, 1e-300)
        s_int = 2.0**30 / max(float(pw.sum()), 1e-300)
        # CP-SAT needs integers: rounding the weights UP keeps every truly feasible cover feasible
        # (sum ceil(w s) >= sum w s >= need s), so CP-SAT's optimum is never worse than the true
        # one; :func:`camplace.solver.engines.setcover.mode.setcover` checks the answer against the exact requirement
        cint = np.ceil(pw * s_int).astype(np.int64)
        model.add_row(y, pw * scale_f, lo=need * scale_f,
                      int_variant=(cint, float(math.ceil(need * s_int)), math.inf))
    return model, x, int(pr.shape[0])
