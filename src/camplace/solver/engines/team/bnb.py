"""The exact max-coverage engine for camera teams at full size: branch and bound on marginal gains
(issue 31).

Works on the free columns' row lists (int32 indices of the CSC matrix, no copy when every column
is free; of a binary matrix held as column bitsets, :class:`camplace.visibility.bits.BitMatrix`,
read straight from the bits by :func:`camplace.visibility.bits.column_rows`: the same ascending lists, no CSR or CSC copy of
the whole matrix) with the rows that do not count (covered by a fixed camera, weight 0) weighted 0: the
gains of every column against the uncovered rows are one gather and one segmented sum, in chunks
with reused buffers. Depth first; at a
node with ``r`` more cameras possible (the count, the budget at the cheapest allowed costs and the
models' maxima), the bound is ``min(value + sum of the r largest gains of the columns that may
still be added, value + weight not yet covered)`` (valid: coverage is submodular). Children are
the allowed columns in decreasing gain, child ``i`` excluding children ``1..i-1``; the loop stops
at the first child whose bound cannot beat the incumbent. Leaves check the minimums (models,
zones) and the cardinality. The incumbent starts from a greedy that first fills the minimums.

With an incumbent to beat (a count pattern of :mod:`camplace.solver.engines.team.patterns`) on
a BitMatrix, :func:`count_bound` (column counts x the largest weight, per model) is tried first:
when it cannot beat the incumbent, the pattern is proven dominated without reading a row.

No column is dropped by dominance. On the time limit the answer is the incumbent with the largest
bound of the open nodes (the root's when the search ran out in it).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import scipy.sparse as sp

from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget, memory_budget_bytes, memory_fallback
from camplace.solver.problem.team import TeamConstraints
from camplace.visibility.bits import column_rows

__all__ = ["team_branch_and_bound", "count_bound", "row_lists_bytes"]

_EPS = 1e-12


class _State:
    """The partial team: counts, cost, poses, zones and the chosen local columns."""

    def __init__(self, team: TeamConstraints, fixed: tuple[int, ...]):
        nm, nz = len(team.model_names), len(team.zone_names)
        self.mcount = np.bincount(team.model[list(fixed)], minlength=nm).astype(np.int64) if fixed else np.zeros(nm, np.int64)
        self.zcount = (team.zone_member[list(fixed)].sum(axis=0).astype(np.int64) if fixed else np.zeros(nz, np.int64))
        self.cost = float(team.cost[list(fixed)].sum()) if fixed else 0.0
        self.poses: set[int] = set(team.pose[list(fixed)].tolist()) if (team.pose is not None and fixed) else set()
        self.chosen: list[int] = []


def row_lists_bytes(nnz: int) -> int:
    """Bytes of the branch and bound's row lists read from column bitsets
    (:func:`camplace.visibility.bits.column_rows`): int32 row indices, 4 bytes a pair of the free
    columns."""
    return 4 * int(nnz)


def _csc_rows(q, fixed: tuple[int, ...], free_cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The free columns' row lists of a scipy matrix (``indptr`` (nf + 1,) int64, ``indices`` int32:
    no copy when every column is free) and the (m,) bool rows the fixed columns observe."""
    m, n = q.shape
    nf = free_cols.size
    csc = q.tocsc() if sp.issparse(q) else sp.csc_matrix(q)
    if csc.dtype != np.bool_:
        csc.eliminate_zeros()  # values in (0, 1]: a stored entry observes
    base_rows = np.zeros(m, dtype=bool)
    for f in fixed:
        base_rows[csc.indices[csc.indptr[f]:csc.indptr[f + 1]]] = True
    # the free columns' row lists (no copy when every column is free), rows that do not count: weight 0
    if nf == n and np.array_equal(free_cols, np.arange(n)):
        indices = csc.indices.astype(np.int32, copy=False)
        indptr = csc.indptr.astype(np.int64)
    else:
        starts = csc.indptr[free_cols].astype(np.int64)
        lens = csc.indptr[free_cols + 1].astype(np.int64) - starts
        indptr = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
        src = np.repeat(starts - indptr[:-1], lens) + np.arange(int(indptr[-1]), dtype=np.int64)
        indices = csc.indices[src].astype(np.int32, copy=False)
        del src
    return indptr, indices, base_rows


def count_bound(bits, w: np.ndarray, team: TeamConstraints, k: int | None, fixed: tuple[int, ...],
                free_cols: np.ndarray) -> float:
    """An upper bound on the covered weight of any team from column counts alone (no row is read).

    A column covers at most ``popcount x max(w)``; a team holds at most ``k`` new cameras and at
    most ``model_max - fixed`` of each model, and its value is at most the fixed cameras' weight
    plus the sum of its new columns' caps (coverage is subadditive) and at most the total weight.
    So the bound is that weight plus the ``k`` largest caps among each model's ``model_max -
    fixed`` largest, capped by the total.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n).
    w : (m,) float64
    team : TeamConstraints
    k : int or None
        New cameras at most (None: no limit but the models').
    fixed : tuple of int
    free_cols : (nf,) int64

    Returns
    -------
    float
    """
    pos = w[w > 0]
    total = float(pos.sum())
    if free_cols.size == 0 or pos.size == 0:
        return total
    cap = bits.column_counts[free_cols].astype(np.float64) * float(pos.max())
    fm = team.model[free_cols]
    fcount = np.bincount(team.model[list(fixed)], minlength=len(team.model_names)) if fixed else None
    picked = []
    for mi, hi in enumerate(team.model_max):
        mine = np.sort(cap[fm == mi])[::-1]
        if hi is not None:
            mine = mine[:max(0, int(hi) - (int(fcount[mi]) if fcount is not None else 0))]
        picked.append(mine)
    top = np.sort(np.concatenate(picked))[::-1]
    if k is not None:
        top = top[:int(k)]
    base = float(w[bits.union(fixed)].sum()) if fixed else 0.0
    return min(base + float(top.sum()), total)


def team_branch_and_bound(
    q: sp.csr_matrix, w: np.ndarray, team: TeamConstraints, *, k: int | None, fixed: tuple[int, ...],
    free_cols: np.ndarray, deadline: Deadline, incumbent: float = -math.inf,
) -> tuple[tuple[int, ...] | None, str, float, float, dict[str, Any]]:
    """Maximum coverage under the team's constraints (module docstring); no conflicting pairs.

    With ``incumbent`` (a value some other team reaches) only better teams are looked for: when
    none exists the status is ``"dominated"`` (no selection, bound ``incumbent``).

    ``q`` is the (m, n) scipy matrix (a stored entry observes) or, for a binary matrix, the
    :class:`camplace.visibility.bits.BitMatrix` (read by :func:`camplace.visibility.bits.column_rows`).

    Returns
    -------
    selected : tuple of int or None
        Original columns, fixed included (None: no feasible team found).
    status : {"optimal", "feasible", "infeasible", "unknown"}
    objective, bound : float
        Covered weight (fixed cameras' rows included) and an upper bound on it.
    stats : dict
    """
    m, n = q.shape
    fixed = tuple(int(j) for j in fixed)
    free_cols = np.asarray(free_cols, dtype=np.int64)
    nf = free_cols.size
    if math.isfinite(incumbent) and getattr(q, "format", None) == "bits":
        cb = count_bound(q, w, team, k, fixed, free_cols)
        if cb <= incumbent + _EPS:  # no team beats the incumbent: proven before reading any row list
            return None, "dominated", math.nan, incumbent, {"columns": int(nf), "nodes": 0, "count_bound": cb}
    if getattr(q, "format", None) == "bits":  # column bitsets: the row lists straight from the bits
        need, budget = row_lists_bytes(int(q.column_counts[free_cols].sum())), memory_budget_bytes()
        if need > budget:
            memory_fallback(OverBudget(need, budget, "the team branch and bound's row lists"), None, asked=False,
                            then=None, fix="use engine mip (or fewer candidates / points)")
        base_rows = q.union(fixed) if fixed else np.zeros(m, dtype=bool)
        indptr, indices = column_rows(q, free_cols)
    else:
        indptr, indices, base_rows = _csc_rows(q, fixed, free_cols)
    base = float(w[base_rows].sum())
    wa = np.where(base_rows | ~(w > 0), 0.0, w).astype(np.float64)
    seen = np.zeros(m, dtype=bool)
    seen[indices] = True
    wa[~seen] = 0.0
    del seen
    empty = np.diff(indptr) == 0
    stats: dict[str, Any] = {"rows": int(np.count_nonzero(wa)), "columns": int(nf), "nnz": int(indices.size)}
    # the gains are computed in chunks of whole columns with reused buffers (no 8-byte copy of all
    # the indices, no fresh pages per node)
    chunk_nnz = 1 << 20
    bounds = [0]
    while bounds[-1] < nf:
        nxt = int(np.searchsorted(indptr, indptr[bounds[-1]] + chunk_nnz, side="right")) - 1
        bounds.append(min(nf, max(nxt, bounds[-1] + 1)))
    span = max([int(indptr[b] - indptr[a_]) for a_, b in zip(bounds[:-1], bounds[1:])] + [0])
    idx_buf = np.empty(span, dtype=np.intp)
    val_buf = np.empty(span + 1)

    def gains(uncovered_w: np.ndarray) -> np.ndarray:
        g = np.zeros(nf)
        if indices.size == 0:
            return g
        for c0, c1 in zip(bounds[:-1], bounds[1:]):
            s0, s1 = int(indptr[c0]), int(indptr[c1])
            if s1 == s0:
                continue
            ib = idx_buf[:s1 - s0]
            ib[...] = indices[s0:s1]
            vb = val_buf[:s1 - s0 + 1]
            np.take(uncovered_w, ib, out=vb[:-1])
            vb[-1] = 0.0
            g[c0:c1] = np.add.reduceat(vb, indptr[c0:c1] - s0)
        g[empty] = 0.0
        return g

    def col_rows(i: int) -> np.ndarray:
        return indices[indptr[i]:indptr[i + 1]]

    nm, nz = len(team.model_names), len(team.zone_names)
    fm = team.model[free_cols]
    fz = team.zone_member[free_cols]
    fc = team.cost[free_cols]
    fp = team.pose[free_cols] if team.pose is not None else None
    mmax = np.array([np.iinfo(np.int64).max if h is None else h for h in team.model_max], dtype=np.int64)
    zmax = np.array([np.iinfo(np.int64).max if h is None else h for h in team.zone_max], dtype=np.int64)
    mmin = np.array(team.model_min, dtype=np.int64)
    zmin = np.array(team.zone_min, dtype=np.int64)
    budget = math.inf if team.budget is None else float(team.budget) * (1 + 1e-12) + 1e-9
    exact = team.cardinality == "exact" and k is not None
    kmax = nf if k is None else int(k)

    def allowed(st: _State, banned: np.ndarray) -> np.ndarray:
        """Free columns that may join the partial team (its maxima, the budget, its poses)."""
        ok = ~banned
        ok &= st.mcount[fm] < mmax[fm]
        ok &= st.cost + fc <= budget
        if nz:
            ok &= ~np.any(fz & (st.zcount >= zmax)[None, :], axis=1)
        if fp is not None and st.poses:
            ok &= ~np.isin(fp, np.fromiter(st.poses, dtype=np.int64))
        return ok

    def slots(st: _State, ok: np.ndarray) -> int:
        """Most cameras that may still join (count, budget at the cheapest allowed costs, model maxima)."""
        r = kmax - len(st.chosen)
        if r <= 0 or not ok.any():
            return 0
        if math.isfinite(budget):
            cs = np.sort(fc[ok])
            r = min(r, int(np.searchsorted(np.cumsum(cs), budget - st.cost, side="right")))
        room = np.minimum(mmax - st.mcount, np.bincount(fm[ok], minlength=nm))
        return int(min(r, room.sum()))

    def can_finish(st: _State, r: int) -> bool:
        """The minimums and the exact count are still reachable with r more cameras."""
        need_m = int(np.maximum(mmin - st.mcount, 0).sum())
        if need_m > r:
            return False
        if nz and int(np.maximum(zmin - st.zcount, 0).max(initial=0)) > r:
            return False
        if exact and kmax - len(st.chosen) > r:
            return False
        return True

    def complete(st: _State) -> bool:
        if exact and len(st.chosen) != kmax:
            return False
        return bool(np.all(st.mcount >= mmin) and np.all(st.zcount >= zmin))

    def push(st: _State, i: int) -> None:
        st.chosen.append(i)
        st.mcount[fm[i]] += 1
        st.zcount += fz[i]
        st.cost += fc[i]
        if fp is not None:
            st.poses.add(int(fp[i]))

    def pop(st: _State, i: int) -> None:
        st.chosen.pop()
        st.mcount[fm[i]] -= 1
        st.zcount -= fz[i]
        st.cost -= fc[i]
        if fp is not None:
            st.poses.discard(int(fp[i]))

    def cover(cols: list[int]) -> np.ndarray:
        cov = np.zeros(wa.size, dtype=bool)
        for i in cols:
            cov[col_rows(i)] = True
        return cov

    # greedy incumbent: fill the minimums first (best gain among the columns that help), then the rest
    best_sel: list[int] | None = None
    best_val = -math.inf
    st = _State(team, fixed)
    # the fixed cameras alone may already break a limit that only grows: no team at all
    fixed_ok = bool(st.cost <= budget and np.all(st.mcount <= mmax) and np.all(st.zcount <= zmax)
                    and (team.pose is None or len(st.poses) == len(fixed)))
    unc = wa.copy()
    banned0 = np.zeros(nf, dtype=bool)
    for _ in range(kmax if (nf and fixed_ok and not math.isfinite(incumbent)) else 0):
        ok = allowed(st, banned0)
        if not ok.any():
            break
        helps = np.zeros(nf, dtype=bool)
        helps |= (st.mcount < mmin)[fm]
        if nz:
            helps |= np.any(fz & (st.zcount < zmin)[None, :], axis=1)
        pick_from = ok & helps if (ok & helps).any() else ok
        if not (ok & helps).any() and not exact and len(st.chosen) > 0 and complete(st):
            pick_from = ok
        g = gains(unc)
        score = g / np.maximum(fc, 1e-12) if (math.isfinite(budget) and not exact) else g
        score = np.where(pick_from, score, -np.inf)
        i = int(np.argmax(score))
        if not np.isfinite(score[i]):
            break
        if g[i] <= 0 and complete(st) and not exact:
            break
        push(st, i)
        banned0[i] = True
        unc[col_rows(i)] = 0.0
        if complete(st):
            v = float(wa.sum() - unc.sum())
            if v > best_val:
                best_val, best_sel = v, list(st.chosen)
    if fixed_ok and complete(st):
        v = float(wa.sum() - unc.sum())
        if v > best_val:
            best_val, best_sel = v, list(st.chosen)
    stats["greedy_value"] = None if best_sel is None else best_val + base
    if math.isfinite(incumbent) and incumbent - base > best_val:
        best_val, best_sel = incumbent - base, None  # beat it or nothing

    # depth-first branch and bound
    total = float(wa.sum())
    nodes = [0]
    timed_out = [False]
    root_bound = [math.inf]
    open_bound = [-math.inf]  # the largest bound of a subtree left unexplored on the time limit

    def node(st: _State, unc_w: np.ndarray, value: float, banned: np.ndarray, depth: int) -> None:
        nonlocal best_val, best_sel
        nodes[0] += 1
        if complete(st) and value > best_val + _EPS:
            best_val, best_sel = value, list(st.chosen)
        ok = allowed(st, banned)
        r = slots(st, ok)
        if r == 0 or not can_finish(st, r):
            if depth == 0:
                root_bound[0] = value
            return
        g = gains(unc_w)
        gi = np.where(ok, g, -1.0)
        order = np.argsort(-gi, kind="stable")
        order = order[gi[order] >= 0]
        top = np.sort(g[ok])[::-1]
        bound = min(value + float(top[:r].sum()), total)
        if depth == 0:
            root_bound[0] = bound
        if bound <= best_val + _EPS:
            return
        if timed_out[0] or deadline.expired():
            timed_out[0] = True
            open_bound[0] = max(open_bound[0], bound)
            return
        local_banned = banned.copy()
        og = gi[order]
        for pos, i in enumerate(order.tolist()):
            # child: i plus at most r - 1 of the later ones
            rest = og[pos + 1:pos + r]
            cb = min(value + og[pos] + float(rest[rest > 0].sum()), total)
            if cb <= best_val + _EPS:
                break
            if timed_out[0] or deadline.expired():  # before the child's gains: a pruned child costs them too
                timed_out[0] = True
                open_bound[0] = max(open_bound[0], cb)  # the siblings' bounds do not rise past it
                break
            rows = col_rows(i)
            saved = unc_w[rows].copy()
            local_banned[i] = True  # chosen in the child, excluded from the later siblings
            push(st, i)
            unc_w[rows] = 0.0
            node(st, unc_w, value + float(og[pos]), local_banned, depth + 1)
            unc_w[rows] = saved
            pop(st, i)

    st = _State(team, fixed)
    if fixed_ok:
        node(st, wa.copy(), 0.0, np.zeros(nf, dtype=bool), 0)
    stats.update({"nodes": int(nodes[0]), "timed_out": bool(timed_out[0]),
                  "root_bound": None if not math.isfinite(root_bound[0]) else root_bound[0] + base})
    if best_sel is None and math.isfinite(incumbent) and fixed_ok and not timed_out[0]:
        return None, "dominated", math.nan, incumbent, stats
    if best_sel is None:
        if timed_out[0]:
            return None, "unknown", math.nan, (root_bound[0] + base if math.isfinite(root_bound[0]) else math.inf), stats
        return None, "infeasible", math.nan, -math.inf, stats
    sel = tuple(sorted(set(fixed) | {int(free_cols[i]) for i in best_sel}))
    value = best_val + base
    if timed_out[0]:
        return sel, "feasible", value, max(value, open_bound[0] + base), stats
    return sel, "optimal", value, value, stats
