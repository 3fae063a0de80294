"""The engine table of the k-camera modes (maxcover, quality, multiview): one problem object, one
runner per route of :func:`~camplace.solver.choose.choose_engine`, one outcome type
(:class:`~camplace.solver.result.EngineOutcome`, the engines' too).

:func:`run_cover` builds nothing itself: it asks :func:`~camplace.solver.choose.choose_engine`
for a route and looks the route up in :data:`ROUTES`. Every runner takes the same
:class:`CoverProblem` and the :class:`~camplace.solver.choose.EngineChoice`, and returns a
:class:`~camplace.solver.result.EngineOutcome`, or None when its engine does not fit in memory
under ``auto``: the run then goes on with the general model (``model``), or, for the large-k
engines, with the choice made without them.

The problem carries the solve's one :class:`~camplace.solver._support.deadline.Deadline`; each
runner hands it (or a slice of it) to its engines, which check it themselves (the bitset engine
alone still takes the seconds left of it).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.greedy import greedy
from camplace.solver._support.memory import OverBudget, matrix_bytes, memory_budget_bytes, memory_fallback, note_memory
from camplace.solver.problem.checks import CONFLICT_PAIR_BYTES
from camplace.solver.choose import EngineChoice, choose_engine, problem_sizes
from camplace.solver.engines.angle.search import greedy_angle, solve_angle
from camplace.solver.engines.angle.spaced import neighbours, solve_spaced_angle, spaced_greedy
from camplace.solver.engines.bitset.search import bitset_bytes, solve_bitset
from camplace.solver.engines.large_k.search import run_large_k
from camplace.solver.engines.maxcover import run_maxcover_engine
from camplace.solver.engines.mip.linear import model_bytes, solve_model
from camplace.solver.engines.mip.mode_models import BuildTimeout, build_model, model_size
from camplace.solver.engines.quality.portfolio import quality_engines
from camplace.solver.options import SolveOptions
from camplace.solver.problem.objectives import cheap_bound, expand_levels, mode_value
from camplace.solver.problem.presolve import presolve
from camplace.solver.problem.presolve_bits import covered_weight
from camplace.solver.result import EngineOutcome

__all__ = ["CoverProblem", "ROUTES", "run_cover", "fixed_base"]

log = logging.getLogger(__name__)


def fixed_base(q: sp.csr_matrix, w: np.ndarray, fixed: Sequence[int], mode: str) -> tuple[np.ndarray, np.ndarray]:
    """What the fixed cameras already give every row, and the row weights left to the new cameras.

    Parameters
    ----------
    q : (m, n) scipy.sparse.csr_matrix
    w : (m,) float64
    fixed : sequence of int
    mode : {"maxcover", "quality", "multiview"}

    Returns
    -------
    base : (m,) float64
        maxcover: 1.0 where a fixed camera observes the row; quality: the best fixed value;
        multiview: how many fixed cameras observe the row (zeros without fixed cameras).
    weights : (m,) float64
        maxcover: ``w`` with the rows the fixed cameras cover set to 0; otherwise ``w``.
    """
    m = q.shape[0]
    fx = list(fixed)
    if not fx:
        return np.zeros(m), w
    if mode == "maxcover":
        covered = np.diff(q[:, fx].tocsr().indptr) > 0
        return covered.astype(np.float64), np.where(covered, 0.0, w)
    if mode == "quality":
        return q[:, fx].max(axis=1).toarray().ravel(), w
    return np.asarray((q[:, fx] > 0).sum(axis=1)).ravel().astype(np.float64), w


@dataclass
class CoverProblem:
    """One k-camera problem after :func:`camplace.solver.solve`'s checks, as every route runner sees it.

    Attributes
    ----------
    q : (m, n) scipy.sparse.csr_matrix
        The checked matrix (values > 0 observe).
    w : (m,) float64
        Point weights.
    k : int
        New cameras (>= 1).
    mode : {"maxcover", "quality", "multiview"}
    views : int
    min_angle_deg : float or None
    pos : (n, 3) float64 or None
        Camera positions.
    pts : (m, 3) float64 or None
        Point positions (minimum angle only).
    fixed_t : tuple of int
        Fixed cameras.
    free_cols : (nf,) int64
        Candidates the new cameras may be chosen from.
    conflicts : (p, 2) int64
        Pairs of free candidates closer than the minimum distance.
    options : SolveOptions
        The caller's options, unchanged (the engine choice reads them; ``engine`` is the engine
        asked for: ``auto``, ``exact``, ``mip``, ``cpsat``).
    deadline : Deadline
        The solve's deadline (made once by ``solve``).
    stats : dict
        The result's stats, filled by the runners.
    start : tuple of int, optional
        New cameras (original column indices, all free) found by a cheaper solve on a subset of the
        candidates (:func:`run_cover`'s warm start): the engines that take a first incumbent start
        from it, and the route's answer is never worse than it.

    The residual instance the new cameras see is derived once: ``qf`` (the free columns),
    ``base`` and ``resid_w`` (:func:`fixed_base`), ``resid`` (quality with fixed cameras: what a
    new camera adds over their best value) and ``fixed_value``; ``budget`` is the memory budget
    (:func:`~camplace.solver._support.memory.memory_budget_bytes`) the engine choice and the exact
    engines read.
    """

    q: sp.csr_matrix
    w: np.ndarray
    k: int
    mode: str
    views: int
    min_angle_deg: float | None
    pos: np.ndarray | None
    pts: np.ndarray | None
    fixed_t: tuple[int, ...]
    free_cols: np.ndarray
    conflicts: np.ndarray
    options: SolveOptions
    deadline: Deadline
    stats: dict[str, Any] = field(default_factory=dict)
    start: tuple[int, ...] | None = None
    rung: bool = False

    def __post_init__(self) -> None:
        n = self.q.shape[1]
        self.qf = self.q if self.free_cols.size == n else self.q[:, self.free_cols].tocsr()
        self.base, self.resid_w = fixed_base(self.q, self.w, self.fixed_t, self.mode)
        self.resid = self.qf
        if self.mode == "quality" and self.fixed_t:  # what a new camera adds over the fixed ones' best quality
            self.resid = self.qf.copy()
            self.resid.data = np.maximum(self.resid.data - np.repeat(self.base, np.diff(self.resid.indptr)), 0.0)
            self.resid.eliminate_zeros()
        self.fixed_value = self.value(self.fixed_t)
        self.budget = memory_budget_bytes()

    @property
    def engine(self) -> str:
        """The engine asked for (``options.engine``)."""
        return self.options.engine

    def value(self, sel: Sequence[int]) -> float:
        """The mode's objective of the cameras ``sel`` (original indices)."""
        return mode_value(self.q, self.w, list(sel), mode=self.mode, views=self.views, min_angle_deg=self.min_angle_deg,
                          positions=self.pos, points=self.pts)

    def with_fixed(self, local: Sequence[int]) -> tuple[int, ...]:
        """Fixed cameras and the new ones given as free-column positions, sorted original indices."""
        return tuple(sorted(set(self.fixed_t) | {int(self.free_cols[j]) for j in local}))

    def choose(self, large_k: bool = True) -> EngineChoice:
        """:func:`~camplace.solver.choose.choose_engine` on this problem's sizes."""
        sizes = problem_sizes(self.resid, self.k, self.free_cols.size, len(self.fixed_t), self.conflicts.shape[0],
                              self.mode)
        return choose_engine(sizes, self.options, self.budget, large_k=large_k)

    def start_local(self) -> np.ndarray | None:
        """``start`` as free-column positions (None without one)."""
        if self.start is None:
            return None
        loc = np.searchsorted(self.free_cols, np.asarray(self.start, dtype=np.int64))
        return loc if loc.size == self.k and np.array_equal(self.free_cols[np.minimum(loc, self.free_cols.size - 1)],
                                                            np.asarray(self.start)) else None

    @property
    def angle_ok(self) -> bool:
        """multiview with a minimum angle and no minimum-distance conflicts: the angle engine applies."""
        return self.mode == "multiview" and self.min_angle_deg is not None and self.conflicts.shape[0] == 0

    @property
    def spaced_angle(self) -> bool:
        """multiview with a minimum angle and minimum-distance conflicts: the angle engine applies to
        the problem without the spacing (:func:`_angle_spaced`)."""
        return self.mode == "multiview" and self.min_angle_deg is not None and self.conflicts.shape[0] > 0


Runner = Callable[[CoverProblem, EngineChoice], "EngineOutcome | None"]


def _large_k(p: CoverProblem, choice: EngineChoice) -> EngineOutcome | None:
    """The engines for 4 < k <= 8 (:func:`~camplace.solver.engines.large_k.search.run_large_k`)."""
    got = run_large_k(p.resid, p.resid_w, p.k, p.mode, p.views, p.engine, p.deadline, p.stats)
    if got is None:
        return None
    p.stats["engine_choice"] = {"engine": choice.engine, "route": choice.route, "reason": choice.reason}
    sel = p.with_fixed(got.selected)
    const = p.fixed_value if p.mode == "maxcover" else float(p.w @ p.base) if p.mode == "quality" else 0.0
    return EngineOutcome(sel, got.status, got.bound + const, p.stats, engine=got.engine, objective=p.value(sel))


def _quality_portfolio(p: CoverProblem, choice: EngineChoice) -> EngineOutcome:
    """The exact quality engines (:func:`~camplace.solver.engines.quality.portfolio.quality_engines`)."""
    return quality_engines(p.resid, p.resid_w, p.k, choice.tree, choice.gram, p.fixed_t, p.free_cols, p.value,
                           float(p.w @ p.base), p.deadline, p.stats)


def _angle(p: CoverProblem, choice: EngineChoice | None = None) -> EngineOutcome | None:
    """The exact angle engine (:mod:`camplace.solver.engines.angle.search`); None when it does not fit in
    memory and ``auto`` may fall back (``exact`` requested: a one-line error)."""
    assert p.pos is not None and p.pts is not None and p.min_angle_deg is not None
    try:
        out = solve_angle(p.q, p.w, p.k, p.views, float(p.min_angle_deg), p.pos, p.pts,
                          np.asarray(p.fixed_t, dtype=np.int64), p.free_cols, deadline=p.deadline,
                          budget_bytes=memory_budget_bytes(), start=p.start, rung=p.rung)
    except OverBudget as exc:
        _exact_fallback(p, exc)
        return None
    sel = tuple(sorted(set(p.fixed_t) | set(out.selected)))
    p.stats["engine_stats"] = dict(out.stats)
    return EngineOutcome(sel, out.status, float(out.bound), p.stats, engine="exact", objective=p.value(sel))


def spaced_angle_greedy(p: CoverProblem, keep: Sequence[int], deadline: Deadline) -> tuple[int, ...] | None:
    """:func:`~camplace.solver.engines.angle.spaced.spaced_greedy` on ``p`` (its conflicting pairs
    the minimum distance): ``p.k`` pairwise spaced new cameras starting from ``keep``, or None."""
    assert p.pos is not None and p.pts is not None and p.min_angle_deg is not None
    return spaced_greedy(p.q, p.w, p.k, p.views, float(p.min_angle_deg), p.pos, p.pts, p.fixed_t, p.free_cols,
                         neighbours(p.conflicts), keep, deadline)


def _angle_spaced(p: CoverProblem, hint: tuple[int, ...] | None) -> EngineOutcome | None:
    """Multiview with a minimum angle and a minimum distance when the general model does not fit
    (``auto``): :func:`~camplace.solver.engines.angle.spaced.solve_spaced_angle` (the angle engine
    without the spacing, a valid bound; then spaced answers with exact angles, the distance-aware
    greedy ``hint`` among them); the bound is the smaller of its and the cheap one. None when the
    angle engine does not fit in memory either (the caller returns the greedy answer)."""
    assert p.pos is not None and p.pts is not None and p.min_angle_deg is not None
    try:
        got = solve_spaced_angle(p.q, p.w, p.k, p.views, float(p.min_angle_deg), p.pos, p.pts, p.fixed_t, p.free_cols,
                                 p.conflicts, p.value, p.deadline, memory_budget_bytes(), start=p.start,
                                 hints=() if hint is None else (hint,))
    except OverBudget as exc:
        log.info("%s: the greedy answer", exc.message)
        return None
    if got is None:
        return None
    p.stats["engine_stats"] = got.stats.pop("engine_stats")
    p.stats["spacing_relaxed"] = got.stats
    bound = min(got.bound, cheap_bound(p.q, p.qf, p.w, p.base, p.k, p.mode, p.views))
    return EngineOutcome(got.selected, got.status, max(bound, got.objective), p.stats, engine="exact",
                         objective=got.objective)


def _multiview(p: CoverProblem, choice: EngineChoice) -> EngineOutcome | None:
    """The bitset engine with ``views`` per point (:func:`~camplace.solver.engines.bitset.search.solve_bitset`)."""
    pre = presolve(p.resid, p.resid_w, p.k, dominance=False, deadline=p.deadline)  # dominance: one view only
    mp, np_ = pre.shape
    need = bitset_bytes(mp, np_, min(p.views, p.k), p.k)
    if need > p.budget:
        _exact_fallback(p, OverBudget(need, p.budget, "the exact engine"))
        return None
    out = solve_bitset(pre, views=p.views, deadline=p.deadline, start=_reduced_start(p, pre))
    sel = tuple(int(p.free_cols[j]) for j in pre.original_columns(out.selected)) if out.selected else None
    p.stats.update({"rows_after": mp, "cols_after": np_, "engine_stats": dict(out.stats)})
    return EngineOutcome(sel, out.status if sel else "unknown", float(out.bound), p.stats, engine=choice.engine,
                         objective=p.value(sel) if sel else 0.0)


def _exact_fallback(p: CoverProblem, exc: OverBudget) -> None:
    """An exact engine does not fit: :func:`~camplace.solver._support.memory.memory_fallback` to
    the general model (an error when ``exact`` was asked for)."""
    memory_fallback(exc, p.stats, asked=p.engine == "exact", then="falling back to the general model",
                    fix="use engine mip (or fewer candidates / points)")


def _presolved_maxcover(p: CoverProblem, choice: EngineChoice) -> EngineOutcome:
    """Plain max coverage (of the points, or of quality's level rows): presolve, then the max-coverage
    engines within the memory budget (:func:`~camplace.solver.engines.maxcover.run_maxcover_engine`)."""
    pat, pw = (p.resid, p.resid_w) if p.mode == "maxcover" else expand_levels(p.resid, p.resid_w)
    pre = presolve(pat, pw, p.k, deadline=p.deadline)
    name, out = run_maxcover_engine(choice.engine, p.engine, pre, p.deadline, p.stats, p.budget,
                                    start=_reduced_start(p, pre))
    new = tuple(int(p.free_cols[j]) for j in pre.original_columns(out.selected)) if out.selected else ()
    sel = tuple(sorted(set(p.fixed_t) | set(new))) if new else None
    objective = p.value(sel) if sel else p.fixed_value
    const = p.fixed_value if p.mode == "maxcover" else float(p.w @ p.base)
    p.stats.update({"rows_after": pre.shape[0], "cols_after": pre.shape[1], "presolve": dict(pre.stats),
                    "engine_stats": dict(out.stats)})
    return EngineOutcome(sel, out.status if sel else "unknown", float(out.bound) + const, p.stats, engine=name,
                         objective=objective)


def _model(p: CoverProblem, choice: EngineChoice, name: str | None = None, angle_tried: bool = False) -> EngineOutcome:
    """The general model (SCIP / CP-SAT). The greedy answer comes first: it is the hint, and the
    answer (with a cheap valid bound) when the time limit passes while the model is still being
    built, or when the model would not fit in memory."""
    name = choice.engine if name is None else name
    q, w, k, mode, views, stats = p.q, p.w, p.k, p.mode, p.views, p.stats
    m = q.shape[0]
    nf = p.free_cols.size
    adj: list[set[int]] | None = None
    if p.conflicts.size:
        adj = [set() for _ in range(nf)]
        for a, b in np.searchsorted(p.free_cols, p.conflicts).tolist():
            adj[a].add(b)
            adj[b].add(a)
    g_base = np.zeros(m) if mode == "quality" else p.base
    src = p.resid if mode != "multiview" else p.qf
    # the greedy hint reads a CSC copy (as many bytes as the CSR), made while the conflicting pairs are kept
    note_memory("greedy hint", matrix_bytes(src),
                extra_held=CONFLICT_PAIR_BYTES * int(p.conflicts.shape[0]))
    hint_local = greedy(src.tocsc(), p.resid_w, mode, views, g_base, k, np.ones(nf, dtype=bool), adj)
    hint_sel = None
    if hint_local is not None:
        hint_sel = p.with_fixed(hint_local)
    start = p.start_local()
    if start is not None and (hint_sel is None or p.value(p.with_fixed(start)) > p.value(hint_sel)):
        hint_local, hint_sel = [int(j) for j in start], p.with_fixed(start)  # the warm start is the better hint
    budget = memory_budget_bytes()
    size = model_size(q, p.resid, p.resid_w, w, mode, views, p.min_angle_deg, p.pos, p.pts, p.fixed_t, p.free_cols,
                      p.conflicts, budget)
    need = model_bytes(name, *size)
    stats["model_estimate"] = {"variables": size[0], "rows": size[1], "nonzeros": size[2], "bytes": need}
    # the pairs kept meanwhile are held
    note_memory("model", need, extra_held=CONFLICT_PAIR_BYTES * int(p.conflicts.shape[0]), refused=need > budget)
    try:
        if need > budget:
            exc = OverBudget(need, budget, f"the {'SCIP' if name == 'mip' else 'CP-SAT'} model of mode {mode}")
            fix = "use fewer candidates / points" + (", or engine exact" if p.angle_ok else "")
            if p.angle_ok and not angle_tried:  # auto, k > 4: the angle engine gives a valid bound at the limit
                memory_fallback(exc, stats, asked=p.engine == name, then="falling back to the exact angle engine",
                                fix=fix)
                got = _angle(p)
                if got is not None:
                    return got
            if p.spaced_angle:  # the angle engine without the spacing (a relaxation), then spaced answers
                memory_fallback(exc, stats, asked=p.engine == name, fix=fix,
                                then="the exact angle engine without the minimum distance (its bound holds), "
                                     "then spaced answers with exact angles")
                got = _angle_spaced(p, hint_sel)
                if got is not None:
                    return got
            memory_fallback(exc, stats, asked=p.engine == name, then="returning the greedy answer with a cheap bound",
                            fix=fix)
            raise BuildTimeout(f"skipped: {exc.message}")
        model, x, wmax, const = build_model(q, p.resid, p.resid_w, w, p.base, k, mode, views, p.min_angle_deg, p.pos,
                                            p.pts, p.fixed_t, p.free_cols, p.conflicts, p.fixed_value, p.deadline)
    except BuildTimeout as exc:
        stats["model_build"] = (str(exc) or "interrupted by the time limit") + ": greedy answer, cheap bound"
        bound = cheap_bound(q, p.qf, w, p.base, k, mode, views)
        if p.angle_ok or p.spaced_angle:  # the greedy above ignores the angle; this one counts it (O(m + n) memory)
            assert p.pos is not None and p.pts is not None and p.min_angle_deg is not None
            if p.angle_ok:
                new = greedy_angle(q, w, k, views, float(p.min_angle_deg), p.pos, p.pts,
                                   np.asarray(p.fixed_t, dtype=np.int64), p.free_cols, deadline=p.deadline)
            else:
                new = spaced_angle_greedy(p, (), p.deadline) or ()
            cand = tuple(sorted(set(p.fixed_t) | set(new)))
            if new and (hint_sel is None or p.value(cand) > p.value(hint_sel)):
                hint_sel = cand
        if hint_sel is None:
            return EngineOutcome(None, "unknown", bound, stats, engine=name, objective=p.fixed_value)
        return EngineOutcome(hint_sel, "feasible", bound, stats, engine=name, objective=p.value(hint_sel))
    hint = None
    if hint_local is not None:
        hint = {int(x[j]): (1.0 if j in hint_local else 0.0) for j in range(nf)}
    out = solve_model(model, name, deadline=p.deadline, hint=hint)
    stats["engine_stats"] = dict(out.stats)
    sel = None
    if out.values is not None:
        sel = p.with_fixed(np.flatnonzero(out.values[x] > 0.5))
    objective = p.value(sel) if sel is not None else -math.inf
    status = out.status
    if hint_sel is not None:
        hv = p.value(hint_sel)
        stats["hint_value"] = hv
        if sel is None or hv > objective:
            sel, objective = hint_sel, hv
            if status in ("unknown", "optimal"):
                status = "feasible"
    if sel is None:
        return EngineOutcome(None, status, math.inf, stats, engine=name, objective=p.fixed_value)
    if math.isfinite(out.bound):
        bound = out.bound * wmax + const
    else:  # no bound from the model (e.g. SCIP stopped before its root LP ended): the cheap one
        bound = cheap_bound(q, p.qf, w, p.base, k, mode, views)
        stats["bound_from"] = "cheap bound (the model gave none)"
    return EngineOutcome(sel, status, bound, stats, engine=name, objective=objective)


def _reduced_start(p: CoverProblem, pre) -> tuple[int, ...] | None:
    """``p.start`` as reduced columns of ``pre`` (None without one, or when presolve dropped one)."""
    loc = p.start_local()
    return None if loc is None else pre.reduced_columns(loc)


#: The runner of every route of :data:`camplace.solver.choose.ROUTES`.
ROUTES: dict[str, Runner] = {
    "large-k": _large_k,
    "quality-portfolio": _quality_portfolio,
    "angle": _angle,
    "multiview": _multiview,
    "maxcover": _presolved_maxcover,
    "quality-levels": _presolved_maxcover,
    "model": _model,
}


#: Warm start (issue 30: more candidates must never mean a worse answer): a problem with more free
#: candidates than this, k <= WARM_MAX_K and a time limit, is first solved on a subset of them ...
WARM_MIN_COLS = 4000
WARM_MAX_K = 4
#: ... the best 1 / WARM_SHRINK of its free candidates by the weight they observe (that solve
#: warm-starts itself the same way while it is still large: a coarse-to-fine ladder) ...
WARM_SHRINK = 4
#: ... within this share of the time left (ANGLE_WARM_SHARE with a minimum angle); its answer is the
#: full search's first incumbent. With a minimum angle a rung (a warm start's solve, which the angle
#: engine does not search when it is warm-started itself) gives its own warm start RUNG_WARM_SHARE of
#: its time: the smaller rungs are not starved by shares of shares
WARM_SHARE = 0.1
ANGLE_WARM_SHARE = 0.15
RUNG_WARM_SHARE = 0.4


def warm_share(angle: bool, rung: bool) -> float:
    """The share of the time left that a warm start's solve gets: :data:`WARM_SHARE`, with a
    minimum angle :data:`ANGLE_WARM_SHARE`, or :data:`RUNG_WARM_SHARE` when that solve is for a
    rung itself (``rung``)."""
    if not angle:
        return WARM_SHARE
    return RUNG_WARM_SHARE if rung else ANGLE_WARM_SHARE


def warm_subset(p: CoverProblem) -> np.ndarray:
    """The free candidates of the warm start's smaller solve: the ``1 / WARM_SHRINK`` observing the
    most weight (``p.resid_w`` times the matrix values, a heuristic ranking; ties: the lower index),
    sorted original column indices; with a minimum angle, every pose of the first
    ``1 / WARM_SHRINK`` of the positions instead (:func:`spread_subset`: the coarser run)."""
    if p.angle_ok and p.pos is not None:
        spread = spread_subset(p.free_cols, p.pos, WARM_SHRINK)
        if spread.size >= p.k:
            return spread
    wr = np.where(p.resid_w > 0, p.resid_w, 0.0)
    if p.resid.dtype.kind == "f" and p.resid.dtype != wr.dtype:
        wr = wr.astype(p.resid.dtype)  # a ranking: no float64 copy of a float32 matrix
    # a bool pattern's values are cast to float64 for the product (8 bytes a pair: 852 MiB for the
    # 1.1e8 pairs of comet-67p-bunker's merged rows at 10,000 x 50,000, the peak of that solve)
    note_memory("warm ranking", 8 * int(p.resid.nnz) if p.resid.dtype != wr.dtype else 0)
    colw = np.asarray(p.resid.T @ wr).ravel()  # values x weights
    size = max(p.k, -(-p.free_cols.size // WARM_SHRINK))
    top = np.lexsort((np.arange(p.free_cols.size), -colw))[:size]
    return np.sort(p.free_cols[top])


def spread_subset(free_cols: np.ndarray, pos: np.ndarray, shrink: int) -> np.ndarray:
    """Every pose of the first ``1 / shrink`` of the free candidates' distinct positions, in the
    order the columns first show them (at least one position): the candidates a run with
    ``shrink`` times fewer positions draws, since every sampler's sequence for a larger count
    starts with its sequence for a smaller one (:func:`camplace.visibility.stages.make_run_candidates`),
    so the warm start's rungs are the coarser runs themselves (comet-flyby: 32,000 positions go
    8,000 -> 2,000 -> 500, the ladder of issue 30) and a thinner sample of the same spread. The
    heaviest columns instead crowd where the target passes closest, where pairs seldom make a
    minimum angle (comet-flyby at 2,000 positions: their warm start 0.5123 against 0.5275 from the
    engine's own greedy). Until issue 30's eighth round every ``shrink``-th position in
    lexicographic order, not the coarser run.

    Parameters
    ----------
    free_cols : (f,) int64
        Free candidates (original column indices, sorted).
    pos : (n, 3) float64
        Positions of all candidates.
    shrink : int

    Returns
    -------
    (s,) int64
        Sorted original column indices, at least one position's poses.
    """
    _, first, group = np.unique(pos[free_cols], axis=0, return_index=True, return_inverse=True)
    rank = np.empty(first.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)  # positions in the columns' order
    keep = max(1, -(-first.size // shrink))
    return np.sort(free_cols[rank[group.ravel()] < keep])


def _warm_started(p: CoverProblem) -> EngineOutcome:
    """Solve ``p`` on :func:`warm_subset` first (:func:`warm_share` of the time left), offer that
    answer to the full search as its first incumbent (``p.start``), and keep the better of the
    two: the answer is at least as good as the subset's, and the bound is the full search's."""
    sub_free = warm_subset(p)
    # the smaller problem on its own columns (the fixed cameras and the subset): one slice of the
    # matrix, so that its own warm start slices a smaller one
    cols = np.union1d(sub_free, np.asarray(p.fixed_t, dtype=np.int64))
    keep = np.isin(p.conflicts, sub_free).all(axis=1) if p.conflicts.size else np.zeros(0, dtype=bool)
    conflicts = np.searchsorted(cols, p.conflicts[keep]) if p.conflicts.size else p.conflicts
    sub = CoverProblem(p.q[:, cols].tocsr(), p.w, p.k, p.mode, p.views, p.min_angle_deg,
                       None if p.pos is None else p.pos[cols], p.pts,
                       tuple(int(j) for j in np.searchsorted(cols, np.asarray(p.fixed_t, dtype=np.int64))),
                       np.searchsorted(cols, sub_free), conflicts, p.options,
                       p.deadline.share(warm_share(p.angle_ok and p.pos is not None, p.rung)),
                       stats={"k": p.k}, rung=True)
    got = run_cover(sub)
    got_sel = None if got.selected is None else tuple(sorted(int(cols[j]) for j in got.selected))
    warm = {"columns": int(sub_free.size), "status": got.status, "objective": float(got.objective),
            "engine": got.engine, "time_s": p.deadline.elapsed()}
    if "warm_start" in got.stats:
        warm["inner"] = got.stats["warm_start"]
    p.stats["warm_start"] = warm
    del sub
    if got_sel is not None:
        p.start = tuple(sorted(set(got_sel) - set(p.fixed_t)))
    return keep_warm(_run_cover(p), got_sel, got.objective, warm)


def keep_warm(out: EngineOutcome, got_sel: tuple[int, ...] | None, got_objective: float,
              warm: dict) -> EngineOutcome:
    """The full search's answer ``out``, or the warm start's (``got_sel``, original columns, of
    value ``got_objective``) when the search found nothing better within the limit (then
    ``warm["kept"]``); the bound is the larger of the two, the status optimal only when the
    search proved the warm answer."""
    if got_sel is None or (out.selected is not None and got_objective <= out.objective):
        return out
    warm["kept"] = True
    status = "optimal" if out.status == "optimal" and out.bound <= got_objective else "feasible"
    return EngineOutcome(got_sel, status, max(out.bound, got_objective), out.stats, engine=out.engine,
                         objective=got_objective)


def run_cover(p: CoverProblem) -> EngineOutcome:
    """Choose the engine of ``p`` and run it from :data:`ROUTES`; a runner that does not fit in
    memory under ``auto`` hands over to the general model (the large-k engines: to the choice
    made without them). A large problem with a time limit is warm-started from a solve on a
    subset of its candidates (:func:`_warm_started`)."""
    if (p.k and p.k <= WARM_MAX_K and p.start is None and p.free_cols.size > WARM_MIN_COLS
            and p.deadline.limit is not None):
        return _warm_started(p)
    return _run_cover(p)


def _run_cover(p: CoverProblem) -> EngineOutcome:
    """:func:`run_cover` without the warm start."""
    if p.k == 0:
        return EngineOutcome(tuple(p.fixed_t), "optimal", p.fixed_value, p.stats, engine="exact",
                             objective=p.fixed_value)
    choice = p.choose()
    if choice.route == "large-k":
        got = ROUTES["large-k"](p, choice)
        if got is not None:
            return got
        choice = p.choose(large_k=False)  # it does not fit in memory (auto): the choice without the large-k engines
    p.stats["engine_choice"] = {"engine": choice.engine, "route": choice.route, "reason": choice.reason}
    p.stats.update(choice.stats)
    if "memory_fallback" in choice.stats:  # recorded by the (pure) engine choice, logged here
        log.warning("%s", choice.stats["memory_fallback"])
    got = ROUTES[choice.route](p, choice)
    if got is not None:
        return got
    return _model(p, choice, name="mip", angle_tried=choice.route == "angle")


# ----------------------------------------------------------------------------------------------
# camera teams (issue 31)
# ----------------------------------------------------------------------------------------------


#: ``engine="exact"`` enumerates at most this many teams where the branch and bound does not apply.
_EXACT_TEAM_LIMIT = 2_000_000
#: ``auto`` enumerates up to this many teams in multiview with a minimum angle (about 30 us a team;
#: the team model has a row per pair of observers too close in angle, which SCIP does not get through).
_ANGLE_TEAM_LIMIT = 500_000


#: The greedy team's local search (before the team model, as its hint) takes at most this share
#: of the time left.
_TEAM_SEARCH_SHARE = 0.2


def choose_team_engine(engine: str, count: float, limit: int, mode: str = "maxcover",
                       conflicts: int = 0, angle: bool = False) -> tuple[str, str]:
    """The engine of a team solve and why (pure): ``("enumerate" | "bnb" | "mip" | "cpsat", reason)``.

    ``count`` is :func:`~camplace.solver.engines.team.enumeration.team_count`, the teams the exact
    enumeration would visit at most; ``bnb`` is the branch and bound of
    :mod:`camplace.solver.engines.team.bnb` (maxcover without minimum-distance conflicts); ``angle``:
    multiview with a minimum angle, enumerated up to :data:`_ANGLE_TEAM_LIMIT` teams."""
    if engine in ("mip", "cpsat"):
        return engine, f"engine {engine} requested: the team model"
    if count <= limit:
        return "enumerate", f"at most {count:.3g} teams (<= {limit}): the exact enumeration proves the answer"
    if angle and engine == "auto" and count <= _ANGLE_TEAM_LIMIT:
        return "enumerate", (f"at most {count:.3g} teams (<= {_ANGLE_TEAM_LIMIT}), multiview with a minimum angle: "
                             "the exact enumeration proves the answer (the team model's pairwise angle rows are "
                             "too many for SCIP)")
    if mode == "maxcover" and conflicts == 0:
        return "bnb", (f"{count:.3g} possible teams (> {limit}), maxcover: the team branch and bound on marginal "
                       "gains proves the answer (no column dropped by dominance)")
    why = mode if mode != "maxcover" else "minimum-distance conflicts"
    if engine == "exact":
        if count > _EXACT_TEAM_LIMIT:
            raise CamplaceError(f"engine exact: no exact team engine for this case ({count:.3g} possible teams, "
                                f"{why}); use engine auto or mip")
        return "enumerate", f"engine exact requested: enumeration of at most {count:.3g} teams"
    return "mip", (f"{count:.3g} possible teams (> {limit}), {why}: the team model (SCIP) enforces the counts, "
                   "the budget, the zone quotas and one camera per pose")


def run_team(q: sp.csr_matrix, w: np.ndarray, o: SolveOptions, k: int | None, fixed_t: tuple[int, ...],
             free_cols: np.ndarray, conflicts: np.ndarray, deadline: Deadline,
             k_solver: Callable[[SolveOptions], Any] | None = None, pos: np.ndarray | None = None,
             pts: np.ndarray | None = None) -> EngineOutcome | None:
    """Solve under :attr:`SolveOptions.team` (:class:`~camplace.solver.problem.team.TeamConstraints`):
    the exact enumeration on small instances, else the team model of
    :mod:`camplace.solver.engines.mip.team_model` with the greedy team of
    :mod:`camplace.solver.engines.team.greedy` as its hint (and as the answer, with that module's
    cheap bound, when the time limit leaves the model no better team); no column is dropped by
    dominance (a column may be the only one of its model, zone, cost or pose class that meets a
    constraint). Every mode:
    maxcover, quality, multiview (``pos`` (n, 3) and ``pts`` (m, 3), metres, for the minimum
    angle) and setcover.

    ``q`` may also be a binary matrix held as column bitsets
    (:class:`camplace.visibility.bits.BitMatrix`, maxcover without conflicts): the branch and bound
    and its per-model count patterns read the bits; for any other engine the result is None and
    the caller converts the bits to CSR."""
    from camplace.solver.engines.mip.team_model import solve_team_model
    from camplace.solver.engines.team.enumeration import ENUMERATION_LIMIT, enumerate_teams, team_count

    team = o.team
    mode = o.mode
    if team.pose is not None and len(fixed_t):  # a pose a fixed camera holds takes no other model
        free_cols = free_cols[~np.isin(team.pose[free_cols], team.pose[list(fixed_t)])]
    count = team_count(team, k, fixed_t, free_cols)
    name, reason = choose_team_engine(o.engine, count, ENUMERATION_LIMIT, mode, int(np.asarray(conflicts).shape[0]),
                                      angle=mode == "multiview" and o.min_angle_deg is not None)
    bits = getattr(q, "format", None) == "bits"
    if bits and name != "bnb":
        return None
    stats: dict[str, Any] = {"k": k, "team": team.record(),
                             "engine_choice": {"engine": name, "route": "team", "reason": reason}}
    if bits:
        stats["matrix"] = "column bitsets (no CSR copy)"
    costs = None if o.costs is None else np.asarray(o.costs, dtype=np.float64)
    maximize = mode != "setcover"
    view = dict(views=int(o.views), min_angle_deg=o.min_angle_deg, pos=pos, pts=pts)

    def value(sel: tuple[int, ...]) -> float:
        if bits:
            return covered_weight(q, w, sel)
        if maximize:
            return mode_value(q, w, sel, mode=mode, views=int(o.views), min_angle_deg=o.min_angle_deg, positions=pos,
                              points=pts)
        c = team.cost if costs is None else costs
        return float(sum(c[j] for j in sel if j not in fixed_t))

    def greedy_team() -> tuple[int, ...] | None:
        from camplace.solver.engines.team.greedy import team_greedy

        return team_greedy(q, w, team, mode=mode, k=k, fixed=fixed_t, free_cols=free_cols, conflicts=conflicts,
                           views=int(o.views), value=value)

    def cheap_bound() -> float:
        """A valid bound without solving: the team's (maximising modes) or 0 (set cover: costs >= 0)."""
        if not maximize:
            return 0.0
        from camplace.solver.engines.team.greedy import team_bound

        return team_bound(q, w, team, mode=mode, k=k, fixed=fixed_t, free_cols=free_cols, views=int(o.views))

    if name == "enumerate":
        sel, status, _, est = enumerate_teams(q, w, team, mode=mode, k=k, fixed=fixed_t, free_cols=free_cols,
                                              conflicts=conflicts, costs=costs, required_fraction=o.required_fraction,
                                              deadline=deadline, **view)
        stats["engine_stats"] = est
        engine = "exact"
        bound = (math.inf if maximize else -math.inf) if status != "optimal" else math.nan
        if status in ("feasible", "unknown"):  # timed out: a cheap valid bound instead of an infinite one
            bound = cheap_bound()
            if sel is None and maximize:
                sel = greedy_team()
                if sel is not None:
                    status = "feasible"
                    stats["answer"] = "greedy team: the enumeration ran out of time before finding one"
    elif name == "bnb":
        from camplace.solver.engines.team.bnb import team_branch_and_bound
        from camplace.solver.engines.team.patterns import count_patterns, maximal_patterns, model_costs, solve_by_patterns

        mc = model_costs(team)
        patterns = []
        if mc is not None:
            avail = np.bincount(team.model[free_cols], minlength=len(team.model_names))
            patterns = count_patterns(team, k, fixed_t, avail, mc)
            n_all = len(patterns)
            patterns = maximal_patterns(team, patterns, avail)
        if patterns and k_solver is not None:  # per-model count patterns: single-model ones by the k-camera engines
            stats["engine_choice"]["reason"] += (f"; {n_all} per-model count patterns, {len(patterns)} not dominated "
                                                 "by a larger one")
            sel, status, _, bound, est = solve_by_patterns(q, w, team, k=k, fixed=fixed_t, free_cols=free_cols,
                                                           deadline=deadline, patterns=patterns, k_solver=k_solver)
        else:
            sel, status, _, bound, est = team_branch_and_bound(q, w, team, k=k, fixed=fixed_t, free_cols=free_cols,
                                                               deadline=deadline)
        stats["engine_stats"] = est
        engine = "exact"
    else:
        hint = greedy_team() if maximize else None
        if hint is not None and not deadline.expired():  # a short 1-swap local search on it
            from camplace.solver.engines.team.greedy import improve_team

            stats["greedy_value"] = value(hint)
            hint, stats["local_search"] = improve_team(hint, team, k=k, fixed=fixed_t, free_cols=free_cols,
                                                       conflicts=conflicts, value=value,
                                                       deadline=deadline.share(_TEAM_SEARCH_SHARE),
                                                       max_evals=int(min(5000, max(20, 2e8 / max(q.nnz, 1)))))
        stats["hint_value"] = None if hint is None else value(hint)
        try:
            out = solve_team_model(q, w, team, mode=mode, k=k, fixed=fixed_t, free_cols=free_cols,
                                   conflicts=conflicts, costs=costs, required_fraction=o.required_fraction, backend=name,
                                   deadline=deadline, hint=hint, **view)
        except OverBudget as exc:  # the one memory policy: the greedy team, unless the model was asked for
            memory_fallback(exc, stats, asked=o.engine in ("mip", "cpsat"),
                            then=None if hint is None else "the greedy team and a cheap bound")
            out = EngineOutcome(None, "unknown", math.inf, {"model_build": "over the memory budget"}, engine=name)
        stats.update(out.stats)
        sel, status, bound, engine = out.selected, out.status, out.bound, name
        if hint is not None and status in ("feasible", "unknown", "optimal") and (
                sel is None or stats["hint_value"] > value(sel) + 1e-12):
            # the model found nothing (time limit while building or solving) or worse: the greedy team
            stats["answer"] = ("greedy team: " + ("the model found no team in time" if sel is None and
                                                 out.stats.get("model_build") != "over the memory budget" else
                                                 "the model does not fit in memory" if sel is None else
                                                 "better than the model's"))
            sel = hint
            if status != "optimal":
                status = "feasible"
        if maximize and status != "optimal":  # the model's bound and the cheap one are both valid
            cb = cheap_bound()
            bound = cb if not math.isfinite(bound) or math.isnan(bound) else min(bound, cb)
    if sel is None:
        return EngineOutcome(None, status, bound, stats, engine=engine, objective=math.nan)
    objective = value(sel)
    if status == "optimal":
        bound = objective
    stats["team_uses"] = team.uses(sel)
    broken = team.violations(sel, k=k, fixed=fixed_t)
    if broken:  # never expected: the engines enforce them
        raise CamplaceError(f"internal error: the team solve broke its constraints: {'; '.join(broken)}")
    return EngineOutcome(sel, status, bound, stats, engine=engine, objective=objective)
