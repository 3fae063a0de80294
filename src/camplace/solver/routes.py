"""The engine table of the k-camera modes (maxcover, quality, multiview): one problem object, one
runner per route of :func:`~camplace.solver.choose.choose_engine`, one outcome type.

:func:`run_cover` builds nothing itself: it asks :func:`~camplace.solver.choose.choose_engine`
for a route and looks the route up in :data:`ROUTES`. Every runner takes the same
:class:`CoverProblem` and the :class:`~camplace.solver.choose.EngineChoice`, and returns a
:class:`~camplace.solver.result.ModeOutcome`, or None when its engine does not fit in memory
under ``auto``: the run then goes on with the general model (``model``), or, for the large-k
engines, with the choice made without them.

The problem carries the solve's one :class:`~camplace.solver._support.deadline.Deadline`; each
runner hands its engines what is left of it.
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
from camplace.solver._support.memory import OverBudget, exact_too_big, memory_budget_bytes, memory_fallback
from camplace.solver.choose import EngineChoice, choose_engine, problem_sizes
from camplace.solver.engines.angle.search import greedy_angle, solve_angle
from camplace.solver.engines.bitset.search import bitset_bytes, solve_bitset
from camplace.solver.engines.large_k.search import run_large_k
from camplace.solver.engines.maxcover import run_maxcover_engine
from camplace.solver.engines.mip.linear import model_bytes, solve_model
from camplace.solver.engines.mip.mode_models import BuildTimeout, build_model, model_size
from camplace.solver.engines.quality.portfolio import quality_engines
from camplace.solver.options import SolveOptions
from camplace.solver.problem.objectives import cheap_bound, expand_levels, mode_value
from camplace.solver.problem.presolve import presolve
from camplace.solver.result import ModeOutcome

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

    @property
    def angle_ok(self) -> bool:
        """multiview with a minimum angle and no minimum-distance conflicts: the angle engine applies."""
        return self.mode == "multiview" and self.min_angle_deg is not None and self.conflicts.shape[0] == 0


Runner = Callable[[CoverProblem, EngineChoice], "ModeOutcome | None"]


def _large_k(p: CoverProblem, choice: EngineChoice) -> ModeOutcome | None:
    """The engines for 4 < k <= 8 (:func:`~camplace.solver.engines.large_k.search.run_large_k`)."""
    got = run_large_k(p.resid, p.resid_w, p.k, p.mode, p.views, p.engine, p.deadline, p.stats)
    if got is None:
        return None
    p.stats["engine_choice"] = {"engine": choice.engine, "route": choice.route, "reason": choice.reason}
    sel = p.with_fixed(got.selected)
    const = p.fixed_value if p.mode == "maxcover" else float(p.w @ p.base) if p.mode == "quality" else 0.0
    return ModeOutcome(sel, got.status, p.value(sel), got.bound + const, got.engine, p.stats)


def _quality_portfolio(p: CoverProblem, choice: EngineChoice) -> ModeOutcome:
    """The exact quality engines (:func:`~camplace.solver.engines.quality.portfolio.quality_engines`)."""
    return quality_engines(p.resid, p.resid_w, p.k, choice.tree, choice.gram, p.fixed_t, p.free_cols, p.value,
                           float(p.w @ p.base), p.deadline, p.stats)


def _angle(p: CoverProblem, choice: EngineChoice | None = None) -> ModeOutcome | None:
    """The exact angle engine (:mod:`camplace.solver.engines.angle.search`); None when it does not fit in
    memory and ``auto`` may fall back (``exact`` requested: a one-line error)."""
    assert p.pos is not None and p.pts is not None and p.min_angle_deg is not None
    try:
        out = solve_angle(p.q, p.w, p.k, p.views, float(p.min_angle_deg), p.pos, p.pts,
                          np.asarray(p.fixed_t, dtype=np.int64), p.free_cols, time_limit_s=p.deadline.left(),
                          budget_bytes=memory_budget_bytes())
    except OverBudget as exc:
        exact_too_big(p.engine, p.stats, exc.need, exc.budget)
        return None
    sel = tuple(sorted(set(p.fixed_t) | set(out.selected)))
    p.stats["engine_stats"] = dict(out.stats)
    return ModeOutcome(sel, out.status, p.value(sel), float(out.bound), "exact", p.stats)


def _multiview(p: CoverProblem, choice: EngineChoice) -> ModeOutcome | None:
    """The bitset engine with ``views`` per point (:func:`~camplace.solver.engines.bitset.search.solve_bitset`)."""
    pre = presolve(p.resid, p.resid_w, p.k, dominance=False)  # dominance is only valid for one view
    mp, np_ = pre.shape
    need = bitset_bytes(mp, np_, min(p.views, p.k), p.k)
    if need > p.budget:
        exact_too_big(p.engine, p.stats, need, p.budget)
        return None
    out = solve_bitset(pre, views=p.views, time_limit_s=p.deadline.left())
    sel = tuple(int(p.free_cols[j]) for j in pre.original_columns(out.selected)) if out.selected else None
    p.stats.update({"rows_after": mp, "cols_after": np_, "engine_stats": dict(out.stats)})
    return ModeOutcome(sel, out.status if sel else "unknown", p.value(sel) if sel else 0.0, float(out.bound),
                       choice.engine, p.stats)


def _presolved_maxcover(p: CoverProblem, choice: EngineChoice) -> ModeOutcome:
    """Plain max coverage (of the points, or of quality's level rows): presolve, then the max-coverage
    engines within the memory budget (:func:`~camplace.solver.engines.maxcover.run_maxcover_engine`)."""
    pat, pw = (p.resid, p.resid_w) if p.mode == "maxcover" else expand_levels(p.resid, p.resid_w)
    pre = presolve(pat, pw, p.k)
    name, out = run_maxcover_engine(choice.engine, p.engine, pre, p.deadline.left(), p.stats, p.budget)
    new = tuple(int(p.free_cols[j]) for j in pre.original_columns(out.selected)) if out.selected else ()
    sel = tuple(sorted(set(p.fixed_t) | set(new))) if new else None
    objective = p.value(sel) if sel else p.fixed_value
    const = p.fixed_value if p.mode == "maxcover" else float(p.w @ p.base)
    p.stats.update({"rows_after": pre.shape[0], "cols_after": pre.shape[1], "presolve": dict(pre.stats),
                    "engine_stats": dict(out.stats)})
    return ModeOutcome(sel, out.status if sel else "unknown", objective, float(out.bound) + const, name, p.stats)


def _model(p: CoverProblem, choice: EngineChoice, name: str | None = None, angle_tried: bool = False) -> ModeOutcome:
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
    hint_local = greedy(p.resid.tocsc() if mode != "multiview" else p.qf.tocsc(), p.resid_w, mode, views, g_base, k,
                        np.ones(nf, dtype=bool), adj)
    hint_sel = None
    if hint_local is not None:
        hint_sel = p.with_fixed(hint_local)
    budget = memory_budget_bytes()
    size = model_size(q, p.resid, p.resid_w, w, mode, views, p.min_angle_deg, p.pos, p.pts, p.fixed_t, p.free_cols,
                      p.conflicts, budget)
    need = model_bytes(name, *size)
    stats["model_estimate"] = {"variables": size[0], "rows": size[1], "nonzeros": size[2], "bytes": need}
    try:
        if need > budget:
            exc = OverBudget(need, budget, f"the {'SCIP' if name == 'mip' else 'CP-SAT'} model of mode {mode}")
            if p.engine == name:
                raise CamplaceError(f"{exc.message}; use fewer candidates / points"
                                    + (", or engine exact" if p.angle_ok else ""))
            if p.angle_ok and not angle_tried:  # auto, k > 4: the angle engine gives a valid bound at the limit
                memory_fallback(exc, p.engine, name, stats, "falling back to the exact angle engine")
                got = _angle(p)
                if got is not None:
                    return got
            memory_fallback(exc, p.engine, name, stats, "returning the greedy answer with a cheap bound")
            raise BuildTimeout(f"skipped: {exc.message}")
        model, x, wmax, const = build_model(q, p.resid, p.resid_w, w, p.base, k, mode, views, p.min_angle_deg, p.pos,
                                            p.pts, p.fixed_t, p.free_cols, p.conflicts, p.fixed_value, p.deadline)
    except BuildTimeout as exc:
        stats["model_build"] = (str(exc) or "interrupted by the time limit") + ": greedy answer, cheap bound"
        bound = cheap_bound(q, p.qf, w, p.base, k, mode, views)
        if p.angle_ok:  # the greedy above ignores the angle; this one counts it (O(m + n) memory)
            assert p.pos is not None and p.pts is not None and p.min_angle_deg is not None
            new = greedy_angle(q, w, k, views, float(p.min_angle_deg), p.pos, p.pts,
                               np.asarray(p.fixed_t, dtype=np.int64), p.free_cols, time_limit_s=p.deadline.left())
            cand = tuple(sorted(set(p.fixed_t) | set(new)))
            if hint_sel is None or p.value(cand) > p.value(hint_sel):
                hint_sel = cand
        if hint_sel is None:
            return ModeOutcome(None, "unknown", p.fixed_value, bound, name, stats)
        return ModeOutcome(hint_sel, "feasible", p.value(hint_sel), bound, name, stats)
    hint = None
    if hint_local is not None:
        hint = {int(x[j]): (1.0 if j in hint_local else 0.0) for j in range(nf)}
    out = solve_model(model, name, time_limit_s=p.deadline.left(), hint=hint)
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
        return ModeOutcome(None, status, p.fixed_value, math.inf, name, stats)
    bound = out.bound * wmax + const if math.isfinite(out.bound) else math.inf
    return ModeOutcome(sel, status, objective, bound, name, stats)


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


def run_cover(p: CoverProblem) -> ModeOutcome:
    """Choose the engine of ``p`` and run it from :data:`ROUTES`; a runner that does not fit in
    memory under ``auto`` hands over to the general model (the large-k engines: to the choice
    made without them)."""
    if p.k == 0:
        return ModeOutcome(tuple(p.fixed_t), "optimal", p.fixed_value, p.fixed_value, "exact", p.stats)
    choice = p.choose()
    if choice.route == "large-k":
        got = ROUTES["large-k"](p, choice)
        if got is not None:
            return got
        choice = p.choose(large_k=False)  # it does not fit in memory (auto): the choice without the large-k engines
    p.stats["engine_choice"] = {"engine": choice.engine, "route": choice.route, "reason": choice.reason}
    p.stats.update(choice.stats)
    if "memory_fallback" in choice.stats:
        log.warning("%s; falling back to the general model", choice.stats["memory_fallback"])
    got = ROUTES[choice.route](p, choice)
    if got is not None:
        return got
    return _model(p, choice, name="mip", angle_tried=choice.route == "angle")
