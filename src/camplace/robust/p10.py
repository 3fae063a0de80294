"""The 10th-percentile robust objective: the value a camera system reaches in 90 % of installations.

Given S sampled installations (scenarios) of every candidate, stacked as the rows of one matrix
(row ``s * m + i`` is point ``i`` in scenario ``s``, column ``j`` candidate ``j`` as installed in
that scenario; see :func:`camplace.robust.stack_scenarios`), the per-scenario objective of a system
``x`` is ``f_s(x)`` (maxcover: the weight of the points of block ``s`` some chosen camera observes;
multiview: the weight of those ``views`` chosen cameras observe). The objective maximised here is

    p10(x) = the largest t such that f_s(x) >= t in at least q = ceil(0.9 S) scenarios,

the (S - q + 1)-th smallest ``f_s(x)`` (:func:`order_p10`). Model (SCIP through
:mod:`camplace.solver.engines.mip.linear`): binary ``x_j`` with ``sum x = k`` (fixed cameras at 1, forbidden
at 0, pairs closer than the minimum distance excluded), per scenario and (merged) row
``views * y_r <= sum_{j observes r} x_j`` with ``y_r`` in [0, 1] (binary for multiview), binary
scenario indicators ``z_s`` with ``sum z >= q`` and ``t <= sum_r w_r y_r + M (1 - z_s)``
(``M`` the total weight of a scenario); maximise ``t``. Rows of one scenario with the same
cameras are merged (weights summed) first.

Bounds (the smallest is reported): the solver's own bound; ``(S / q) * B`` for ``B`` a proven bound
of the mean objective (``q * p10(x)`` is at most the sum of x's q best scenarios, at most S times its
mean); and the q-th largest of the S per-scenario optima ``f*_s`` (each scenario's own problem,
solved by :func:`camplace.solver.api.solve` with its proven bound; x reaches ``p10(x)`` in q
scenarios and ``f_s(x) <= f*_s`` in each, side constraints other than fixed/forbidden relaxed). Incumbent: the best of the given systems (the mean optimum, the nominal optimum), improved by
best-improvement single swaps on the p10 objective (:func:`_swap_search`, every candidate's swap
value in one pass over the column bitsets). When the model would be too large it is not built and that incumbent
is reported with the bounds above (``stats["model"]`` says why); when an incumbent meets a bound
it is not needed.

Memory: everything reads the stacked scenarios as column bitsets
(:class:`camplace.visibility.bits.BitMatrix`, one bit a cell; a CSR input is converted to them).
Besides them the solve holds a few arrays of one number a stacked row (:func:`p10_bytes`, checked
before the solve), one scenario's rows at a time (its bits for its own solve and its rows' bitsets
to merge identical rows, :func:`camplace.solver.problem.presolve_bits.identical_rows`), and, only
when the model is built (at most ``P10_MODEL_MAX_NNZ`` nonzeros, counted before), the merged rows as
CSR. No CSR of the whole stacked matrix is made.
"""

from __future__ import annotations

import math
import time
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback
from camplace.solver.engines.mip.linear import LinearModel, solve_model
from camplace.solver.options import SolveOptions
from camplace.solver.problem.objectives import selected_row_stats
from camplace.solver.result import SolverResult, relative_gap

__all__ = ["P10_MODES", "order_p10", "p10_bytes", "scenario_values", "solve_p10"]

P10_MODES = ("maxcover", "multiview")
#: Largest model (nonzeros of the merged scenario rows) that is built; SCIP slows to a crawl above.
P10_MODEL_MAX_NNZ = 3_000_000
QUANTILE = 0.9
_TOL = 1e-9


def order_p10(values: Sequence[float] | np.ndarray) -> float:
    """The value reached in at least 90 % of the scenarios.

    Parameters
    ----------
    values : (S,) float64
        Per-scenario objective values.

    Returns
    -------
    float
        The (S - q + 1)-th smallest value, q = ceil(0.9 S) (S = 32: the 4th smallest; S = 128:
        the 13th smallest), so that at least q scenarios reach it.
    """
    v = np.sort(np.asarray(values, dtype=np.float64))
    if v.size == 0:
        return 0.0
    q = math.ceil(QUANTILE * v.size - 1e-9)
    return float(v[v.size - q])


def scenario_values(
    stacked: sp.csr_matrix, weights: np.ndarray, scenarios: int, selected: Sequence[int], *,
    mode: str = "maxcover", views: int = 2,
) -> np.ndarray:
    """Objective of a camera system in each scenario.

    Parameters
    ----------
    stacked : (S * m, n) scipy.sparse.csr_matrix or camplace.visibility.bits.BitMatrix
        Scenario-stacked observation quality (row ``s * m + i``: point i in scenario s); column
        bitsets are read for the selected columns only (their values are 1).
    weights : (m,) float64
        Point weights (of one scenario).
    scenarios : int
        S.
    selected : sequence of int
        The system's columns (fixed cameras included).
    mode : {"maxcover", "quality", "multiview"}
    views : int

    Returns
    -------
    (S,) float64
    """
    m = len(weights)
    if stacked.shape[0] != m * scenarios:
        raise CamplaceError(f"stacked matrix has {stacked.shape[0]} rows, expected {scenarios} x {m}")
    if len(selected) == 0:
        return np.zeros(scenarios)
    count, vmax = _row_stats(stacked, selected)
    if mode == "quality":
        per_row = vmax.reshape(scenarios, m)
    elif mode == "multiview":
        per_row = (count >= int(views)).reshape(scenarios, m).astype(np.float64)
    else:
        per_row = (count > 0).reshape(scenarios, m).astype(np.float64)
    return per_row @ np.asarray(weights, dtype=np.float64)


def _row_stats(stacked: Any, selected: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~camplace.solver.problem.objectives.selected_row_stats` of a CSR matrix or a
    BitMatrix ((rows,) int64 counts of the selected columns observing each row, (rows,) float64
    largest values: 1.0 where a bit is set)."""
    if getattr(stacked, "format", None) != "bits":
        return selected_row_stats(stacked, selected)
    from camplace.solver.problem.presolve_bits import row_counts_of

    n = stacked.shape[1]
    cols = np.array(sorted({int(j) for j in selected}), dtype=np.int64)
    if cols.size and (cols[0] < 0 or cols[-1] >= n):
        raise CamplaceError(f"selected column index out of range 0..{n - 1}: {cols.tolist()}")
    count = row_counts_of(stacked, cols)[:stacked.shape[0]]
    return count, (count > 0).astype(np.float64)


def _as_bits(stacked: Any) -> Any:
    """The stacked matrix as column bitsets: a BitMatrix as it is, a CSR matrix's pattern (entries
    > 0) converted (``n * ceil(S m / 64) * 8`` bytes, checked against the memory budget first)."""
    if getattr(stacked, "format", None) == "bits":
        return stacked
    from camplace.visibility.bits import bit_words, bits_from_csr

    rows, n = stacked.shape
    need, budget = 8 * n * bit_words(rows), memory_budget_bytes()
    if need > budget:
        memory_fallback(OverBudget(need, budget, "the p10 objective's column bitsets of the scenarios"), None,
                        asked=False, then=None, fix="use --robust-objective mean, or lower --scenarios, --candidates or --points")
    return bits_from_csr(stacked)


def p10_bytes(m: int, n: int, scenarios: int) -> int:
    """Working bytes of the p10 solve besides the stacked bits (the largest at once): the row
    counts of all rows (8 bytes a row), the swap search's counts, scenario numbers, row values and
    weights (32 bytes a row) and its (n, S) sums, one scenario's bitsets (``n * ceil(m / 64) * 8``) with its rows'
    bitsets for the merge (:func:`~camplace.solver.problem.presolve_bits.identical_rows_bytes`)."""
    from camplace.robust.kernels import completion_weights_bytes
    from camplace.solver.problem.presolve_bits import identical_rows_bytes
    from camplace.visibility.bits import bit_words

    rows = int(m) * int(scenarios)
    swap = 32 * rows + completion_weights_bytes(rows, n, scenarios)
    merge = 8 * n * bit_words(m) + identical_rows_bytes(m, n)
    return int(8 * rows + max(swap, merge))


def _check_p10_memory(m: int, n: int, scenarios: int) -> None:
    """A one-line error when :func:`p10_bytes` is over the memory budget (before anything is made)."""
    need, budget = p10_bytes(m, n, scenarios), memory_budget_bytes()
    if need > budget:
        memory_fallback(OverBudget(need, budget, "the p10 objective's working arrays"), None, asked=False, then=None,
                        fix="use --robust-objective mean, or lower --scenarios, --candidates or --points")


def _scenario_groups(sub: Any, w: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """One scenario's rows of positive weight with at least one camera, identical rows merged.

    Parameters
    ----------
    sub : (m, n) BitMatrix
        The scenario's rows.
    w : (m,) float64
        Point weights.
    count : (m,) int64
        Cameras observing each row.

    Returns
    -------
    reps : (g,) int64
        Each merged row's first row (ascending: groups in order of first occurrence).
    wsum : (g,) float64
        Its rows' weights, summed in row order.
    nnz : int
        Observed pairs of the merged rows.
    """
    from camplace.solver.problem.presolve_bits import identical_rows

    live = np.flatnonzero((count > 0) & (w > 0)).astype(np.int64)
    groups, n_groups = identical_rows(sub, live)
    first = np.full(n_groups, -1, dtype=np.int64)
    first[groups[::-1]] = np.arange(groups.size - 1, -1, -1, dtype=np.int64)
    reps = live[first]
    wsum = np.bincount(groups, weights=w[live], minlength=n_groups).astype(np.float64)
    return reps, wsum, int(count[reps].sum())


def _merged_csr(stacked: Any, m: int, reps: list[np.ndarray], nnzs: list[int]) -> list[sp.csr_matrix]:
    """Per scenario s, the rows ``s * m + reps[s]`` (``nnzs[s]`` observed pairs) of the stacked bits
    as a CSR pattern (sorted column indices), each checked against the memory budget first (an
    :class:`OverBudget`)."""
    from camplace.solver.problem.presolve_bits import rows_csr, rows_csr_bytes

    n = stacked.shape[1]
    cols = np.arange(n, dtype=np.int64)
    out = []
    for s, (r, nnz) in enumerate(zip(reps, nnzs, strict=True)):
        need, budget = rows_csr_bytes(r.size, n, nnz) + 8 * stacked.shape[0], memory_budget_bytes()
        if need > budget:
            raise OverBudget(need, budget, "the p10 model's merged rows")
        out.append(rows_csr(stacked, s * m + r, cols))
    return out


def _swap_search(
    stacked: Any, w: np.ndarray, scenarios: int, start: Sequence[int], *, mode: str, views: int,
    fixed: set[int], banned: np.ndarray, conflicts: np.ndarray | None, deadline: float | None,
    team: Any = None, k: int | None = None,
) -> tuple[tuple[int, ...], float, int]:
    """Best-improvement swaps of one camera at a time on the p10 objective (maxcover, multiview).

    With ``team`` (:class:`~camplace.solver.problem.team.TeamConstraints`) a swap is made only to
    a system that meets it (the best such candidate: candidates are tried in decreasing p10).

    For a system minus one camera, the per-scenario value with candidate j added is
    ``base_s + G[j, s]``, ``G = P^T U`` with P the stacked pattern and U the weights of the rows one
    more view would complete, summed per scenario: every candidate's p10 in one pass over the
    column bitsets (:func:`camplace.robust.kernels.completion_weights`).

    Parameters
    ----------
    stacked : (S * m, n) camplace.visibility.bits.BitMatrix
        Stacked scenario bits.

    Returns
    -------
    (system, its p10, swaps made)
    """
    from camplace.robust.kernels import completion_weights
    from camplace.solver.problem.presolve_bits import row_counts_of

    m = len(w)
    need = 1 if mode == "maxcover" else int(views)
    block = np.arange(scenarios * m) // m
    w_all = np.tile(w, scenarios)
    q_need = math.ceil(QUANTILE * scenarios - 1e-9)
    sel = sorted(int(j) for j in start)
    best = order_p10(scenario_values(stacked, w, scenarios, sel, mode=mode, views=views))
    swaps = 0
    improved = True
    while improved:
        improved = False
        for pos in [p for p, j in enumerate(sel) if j not in fixed]:
            if deadline is not None and time.perf_counter() > deadline:
                return tuple(sel), best, swaps
            others = sel[:pos] + sel[pos + 1:]
            count = (row_counts_of(stacked, np.array(sorted(set(others)), dtype=np.int64)) if others
                     else np.zeros(scenarios * m, dtype=np.int64))
            base = np.bincount(block, weights=w_all * (count >= need), minlength=scenarios)  # in row order
            u = w_all * (count == need - 1)
            vals = completion_weights(stacked, u, scenarios) + base[None, :]  # (n, S)
            p10s = np.partition(vals, scenarios - q_need, axis=1)[:, scenarios - q_need]
            ok = ~banned.copy()
            ok[others] = False
            if conflicts is not None and len(conflicts):
                for a, b in conflicts:
                    if a in others:
                        ok[b] = False
                    if b in others:
                        ok[a] = False
            p10s[~ok] = -np.inf
            j = int(np.argmax(p10s))
            if team is not None:  # the best swap whose system meets the team's constraints
                j = -1
                for c in np.argsort(-p10s, kind="stable").tolist():
                    if not p10s[c] > best + _TOL * max(1.0, abs(best)):
                        break
                    if not team.violations(others + [c], k=k, fixed=sorted(fixed)):
                        j = c
                        break
                if j < 0:
                    continue
            if p10s[j] > best + _TOL * max(1.0, abs(best)):
                sel = sorted(others + [j])
                best = order_p10(scenario_values(stacked, w, scenarios, sel, mode=mode, views=views))
                swaps += 1
                improved = True
    return tuple(sel), best, swaps


def solve_p10(
    stacked: Any,
    weights: np.ndarray,
    scenarios: int,
    options: SolveOptions,
    *,
    conflicts: np.ndarray | None = None,
    incumbents: Sequence[Sequence[int]] = (),
    mean_bound: float | None = None,
) -> SolverResult:
    """Maximise the 10th-percentile objective over the scenarios (see the module docstring).

    Parameters
    ----------
    stacked : (S * m, n) camplace.visibility.bits.BitMatrix or scipy.sparse.csr_matrix
        Stacked scenarios; a CSR matrix's pattern (entries > 0) is converted to column bitsets.
    weights : (m,) float64
        Point weights of one scenario.
    scenarios : int
        S.
    options : SolveOptions
        The run's solver options, unchanged: ``mode`` ("maxcover" or "multiview"), ``k`` (new
        cameras), ``views`` (multiview), ``fixed``, ``forbidden``, ``engine`` ("auto" or "mip":
        the p10 model runs on SCIP), ``time_limit_s`` (seconds, for the whole of it),
        ``memory_budget_bytes`` and ``threads`` (the per-scenario solves and the model keep to
        them). ``min_distance_m`` arrives as ``conflicts``.
    conflicts : (p, 2) int64 or None
        Candidate pairs that may not both be chosen (minimum distance).
    incumbents : sequence of systems
        Complete systems (fixed cameras included) to start from; the best is the fallback answer.
    mean_bound : float or None
        A proven upper bound of the mean objective over the same scenarios (gives a bound when
        the model is not built or not solved).

    Returns
    -------
    SolverResult
        ``objective`` the sampled p10 of ``selected``; ``stats["values"]`` its per-scenario values.
    """
    from camplace._cores import using_threads
    from camplace.solver._support.memory import memory_budget

    with memory_budget(options.memory_budget_bytes), using_threads(options.threads):
        return _solve_p10(stacked, weights, scenarios, options, conflicts, incumbents, mean_bound)


def _solve_p10(stacked: Any, weights: np.ndarray, scenarios: int, options: SolveOptions,
               conflicts: np.ndarray | None, incumbents: Sequence[Sequence[int]],
               mean_bound: float | None) -> SolverResult:
    """:func:`solve_p10` within the memory budget and the thread count of ``options``."""
    mode, engine, time_limit_s = options.mode, options.engine, options.time_limit_s
    team = options.team
    if options.k is None and team is None:
        raise CamplaceError("robust objective p10: k (the number of cameras) is required")
    k = None if options.k is None else int(options.k)
    views = options.views if mode == "multiview" else 2
    fixed, forbidden = options.fixed, options.forbidden
    t0 = time.perf_counter()
    if mode not in P10_MODES:
        raise CamplaceError(f"robust objective p10: mode {mode} is not supported (use {' or '.join(P10_MODES)}, or objective mean)")
    if engine not in ("auto", "mip"):
        raise CamplaceError(f"robust objective p10: engine {engine} does not apply (the p10 model runs on SCIP: use --engine auto or mip)")
    w = np.asarray(weights, dtype=np.float64)
    if stacked.shape[0] != len(w) * scenarios:
        raise CamplaceError(f"stacked matrix has {stacked.shape[0]} rows, expected {scenarios} x {len(w)}")
    _check_p10_memory(len(w), stacked.shape[1], scenarios)
    stacked = _as_bits(stacked)
    n = stacked.shape[1]
    total = float(w.sum())
    q_need = math.ceil(QUANTILE * scenarios - 1e-9)
    need = 1 if mode == "maxcover" else int(views)

    def p10_of(sel: Sequence[int]) -> float:
        return order_p10(scenario_values(stacked, w, scenarios, sel, mode=mode, views=views))

    stats: dict[str, Any] = {"objective": "p10", "scenarios": int(scenarios), "scenarios_required": int(q_need)}
    if team is not None:
        team.check_columns(n)
        stats["team"] = team.record()
    best_sel: tuple[int, ...] = ()
    best = -math.inf
    for sel in incumbents:
        if team is not None and team.violations(sel, k=k, fixed=fixed):
            continue  # not a team: no answer to start from
        v = p10_of(sel)
        if v > best:
            best, best_sel = v, tuple(sorted(int(j) for j in sel))
    bound = total
    if mean_bound is not None and math.isfinite(mean_bound):
        bound = min(bound, scenarios / q_need * float(mean_bound))
    stats["bound_from_mean"] = bound

    # improve the best incumbent by swaps (a fifth of the time)
    if best_sel:
        banned = np.zeros(n, dtype=bool)
        banned[[int(j) for j in forbidden]] = True
        dl = None if time_limit_s is None else t0 + time_limit_s / 5.0
        cf = None if conflicts is None else np.asarray(conflicts, dtype=np.int64).reshape(-1, 2)
        sel2, v2, swaps = _swap_search(stacked, w, scenarios, best_sel, mode=mode, views=views, fixed={int(j) for j in fixed},
                                       banned=banned, conflicts=cf, deadline=dl, team=team, k=k)
        stats["swaps"] = swaps
        if v2 > best:
            best, best_sel = v2, sel2

    # the q-th largest per-scenario optimum (a third of the time, shared by the scenarios)
    t_share = None if time_limit_s is None else max(0.5, time_limit_s / 3.0 / scenarios)
    m = len(w)
    from camplace.solver.api import solve as solve_mode

    # each scenario's own problem: fixed / forbidden and the team kept, the other side constraints relaxed
    scenario_options = SolveOptions(mode=mode, k=k, views=views, fixed=fixed, forbidden=forbidden, time_limit_s=t_share,
                                    memory_budget_bytes=options.memory_budget_bytes, threads=options.threads,
                                    team=team)
    # per scenario: its rows as bits (the solver's bits route reads them), then its merged rows
    from camplace.visibility.bits import row_range

    row_count = stacked.row_counts()  # (S * m,) cameras observing each row
    per_s, reps, wsums, nnzs = [], [], [], []
    for s in range(scenarios):
        sub = row_range(stacked, s * m, (s + 1) * m)
        r = solve_mode(sub, w, options=scenario_options)
        per_s.append(float(r.bound) if math.isfinite(r.bound) else total)
        rep, wsum, nnz_s = _scenario_groups(sub, w, row_count[s * m:(s + 1) * m])
        del sub
        reps.append(rep)
        wsums.append(wsum)
        nnzs.append(nnz_s)
    del row_count
    scen_bound = float(np.sort(per_s)[::-1][q_need - 1])
    stats["bound_per_scenario"] = scen_bound
    bound = min(bound, scen_bound)

    nnz = int(sum(nnzs))
    stats["model_nonzeros"] = nnz
    status = "feasible"
    blocks = None
    if best >= bound - _TOL * max(1.0, abs(bound)):
        stats["model"] = "not needed: an incumbent meets the bound"
    elif nnz > P10_MODEL_MAX_NNZ:
        stats["model"] = f"not built: {nnz} nonzeros > {P10_MODEL_MAX_NNZ} (fewer --scenarios, --points or --candidates)"
    else:
        try:  # only the merged rows become lists (the model's rows), under the cap just checked
            blocks = list(zip(_merged_csr(stacked, m, reps, nnzs), wsums, strict=True))
        except OverBudget as exc:
            stats["model"] = f"not built: {exc.message}"
    if blocks is not None:
        model = LinearModel(maximize=True)
        x = model.add_vars(n)
        fixed_set = {int(j) for j in fixed}
        for j in fixed_set:
            model.lb[int(x[j])] = 1.0
        for j in forbidden:
            model.ub[int(x[int(j)])] = 0.0
        if team is None:
            free = [int(x[j]) for j in range(n) if j not in fixed_set]
            model.add_row(free, np.ones(len(free)), k, k)
        else:  # the team's rows (counts, budget, zones, one camera a pose) in place of sum x = k
            from camplace.solver.engines.mip.team_model import add_team_rows

            add_team_rows(model, np.asarray(x), np.arange(n, dtype=np.int64),
                          np.array([j not in fixed_set for j in range(n)]), team, k)
        if conflicts is not None:
            for a, b in np.asarray(conflicts, dtype=np.int64).reshape(-1, 2):
                model.add_row([int(x[a]), int(x[b])], [1.0, 1.0], hi=1.0)
        t_var = int(model.add_vars(1, lb=0.0, ub=total, integer=False, obj=1.0)[0])
        z = model.add_vars(scenarios)
        model.add_row(z, np.ones(scenarios), lo=q_need)
        for s, (block, bw) in enumerate(blocks):
            y = model.add_vars(block.shape[0], integer=mode == "multiview")
            for r in range(block.shape[0]):
                cols = block.indices[block.indptr[r]:block.indptr[r + 1]]
                model.add_row(np.append(y[r], x[cols]), np.append(float(need), -np.ones(cols.size)), hi=0.0)
            # t <= sum_r w_r y_r + M (1 - z_s)
            model.add_row(np.concatenate([y, [t_var, z[s]]]), np.concatenate([bw, [-1.0, -total]]), lo=-total)
        hint = None
        if best_sel:
            chosen = set(best_sel)
            hint = {int(x[j]): (1.0 if j in chosen else 0.0) for j in range(n)}
        rem = None if time_limit_s is None else max(1.0, time_limit_s - (time.perf_counter() - t0))
        out = solve_model(model, "mip", deadline=Deadline(rem), hint=hint)
        stats["model"] = out.stats
        if out.values is not None:
            sel = tuple(int(j) for j in np.flatnonzero(out.values[x] > 0.5))
            v = p10_of(sel)
            if v > best:
                best, best_sel = v, sel
        if math.isfinite(out.bound):
            bound = min(bound, float(out.bound))
        stats["model_status"] = out.status
    if not best_sel:
        return SolverResult((), "unknown", 0.0, bound, math.inf, "mip", time.perf_counter() - t0, stats)
    bound = max(bound, best)
    if best >= bound - _TOL * max(1.0, abs(bound)):
        status = "optimal"
    gap = 0.0 if status == "optimal" else relative_gap(bound, best)
    stats["values"] = [float(v) for v in scenario_values(stacked, w, scenarios, best_sel, mode=mode, views=views)]
    return SolverResult(best_sel, status, float(best), float(bound), float(gap), "mip", time.perf_counter() - t0, stats)
