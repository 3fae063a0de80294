"""Which engine solves a k-camera problem: :func:`choose_engine`, a pure function of the problem's
sizes, the options and the memory budget.

The decision reads only numbers: the engines' memory estimates are functions of the sizes
(:func:`~camplace.solver.engines.quality.tree.quality_tree_bytes`,
:func:`~camplace.solver.engines.quality.min_gram.quality_exact_bytes`,
:func:`~camplace.solver.problem.objectives.expand_bytes`). What can only be known while solving stays a
fallback of :func:`camplace.solver.solve` (recorded in ``stats["memory_fallback"]``): the exact
engines' memory after presolve (multiview, maxcover) and inside the angle engine, and the
SCIP / CP-SAT model's size (:func:`camplace.solver.engines.mip.mode_models.model_size`).

The rules (``k`` new cameras, ``EXACT_MAX_K = 4``):

==========================================  ==================================================
problem                                     ``auto`` chooses
==========================================  ==================================================
maxcover, no minimum distance, k <= 4       ``exact`` (bitset engine on the presolved matrix)
quality, no minimum distance                ``exact``: the tree / min-Gram portfolio where one
                                            fits (tree: k <= 4; min-Gram: k = 2, 3, n <= 3,000),
                                            else the level rows when k <= 4 and they fit
multiview, no fixed cameras, no minimum     ``exact`` (bitset engine)
distance, no angle, k <= 4
multiview with angle, no minimum distance,  ``exact`` (angle engine)
k <= 4
maxcover / quality, no minimum distance;    ``exact`` (:mod:`camplace.solver.engines.large_k.search`: local
multiview without fixed cameras, angle or   search and a Lagrangian bound; maxcover then
minimum distance; 4 < k <= 8                SCIP, multiview then bitsets and SCIP)
anything else                               ``mip`` (SCIP; maxcover without minimum distance
                                            through the presolved max-coverage model)
==========================================  ==================================================

An explicit ``exact`` outside these cases (or past the memory budget) is a one-line error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from camplace.errors import CamplaceError
from camplace.solver._support.memory import OverBudget, memory_fallback
from camplace.solver.engines.bitset.search import BITSET_MAX_K as EXACT_MAX_K
from camplace.solver.engines.large_k.search import LARGE_K_MAX
from camplace.solver.engines.quality.min_gram import QUALITY_EXACT_MAX_N, QUALITY_EXACT_MAX_PAIRS, quality_exact_bytes
from camplace.solver.engines.quality.tree import quality_tree_bytes
from camplace.solver.options import SolveOptions
from camplace.solver.problem.objectives import expand_bytes

__all__ = ["ProblemSizes", "EngineChoice", "choose_engine", "problem_sizes", "EXACT_MAX_K", "ROUTES"]

_QUALITY_EXPAND_MAX = 20_000_000  # auto uses the exact engine for quality up to this expanded nnz

#: How :func:`camplace.solver.solve` runs the chosen engine.
ROUTES: tuple[str, ...] = ("large-k", "quality-portfolio", "angle", "multiview", "maxcover", "quality-levels", "model")


@dataclass(frozen=True)
class ProblemSizes:
    """The sizes of a k-camera problem that the engine choice reads (after fixed and forbidden
    cameras and minimum-distance conflicts are taken out).

    Attributes
    ----------
    k : int
        New cameras to choose.
    points : int
        Rows of the matrix (m).
    free : int
        Candidates the new cameras may be chosen from.
    nnz : int
        Entries of the residual matrix (points x free candidates).
    fixed : int
        Fixed cameras.
    conflicts : int
        Pairs of free candidates closer than the minimum distance.
    min_gram_pairs : float
        quality: ``sum_i s_i (s_i - 1) / 2`` over the residual rows (``s_i`` observers), the work
        of the min-Gram engine; 0 for the other modes.
    expanded_nnz : float
        quality: ``sum_i s_i (s_i + 1) / 2``, an upper bound on the entries of the level rows; 0
        for the other modes.
    """

    k: int
    points: int
    free: int
    nnz: int
    fixed: int = 0
    conflicts: int = 0
    min_gram_pairs: float = 0.0
    expanded_nnz: float = 0.0


@dataclass(frozen=True)
class EngineChoice:
    """The answer of :func:`choose_engine`.

    Attributes
    ----------
    engine : {"exact", "mip", "cpsat"}
        The engine that runs (``solve`` may still fall back when a size known only after presolve
        does not fit).
    reason : str
        Why, in one line (recorded in ``stats["engine_choice"]``).
    route : str
        One of :data:`ROUTES`: the large-k engines, the quality portfolio, the angle engine, the multiview bitset
        engine, presolved max coverage (of the points, or of quality's level rows), or
        the SCIP / CP-SAT model of the mode.
    tree, gram : bool
        quality portfolio: the tree engine / the min-Gram engine apply.
    stats : dict
        Entries for the result's stats (``quality_expanded_nnz_estimate``; ``memory_fallback``
        when the level rows of quality do not fit and ``auto`` falls back).
    """

    engine: str
    reason: str
    route: str
    tree: bool = False
    gram: bool = False
    stats: dict[str, Any] = field(default_factory=dict)

    def __iter__(self):
        """``engine, reason = choose_engine(...)``."""
        return iter((self.engine, self.reason))


def problem_sizes(resid: Any, k: int, free: int, fixed: int, conflicts: int, mode: str) -> ProblemSizes:
    """Measure the :class:`ProblemSizes` of a residual matrix (points x free candidates, CSR).

    Parameters
    ----------
    resid : (m, free) scipy.sparse.csr_matrix
        What the new cameras can add (:func:`camplace.solver.solve` builds it).
    k, free, fixed, conflicts : int
    mode : str
        The row statistics of the quality engines are measured for ``quality`` only.

    Returns
    -------
    ProblemSizes
    """
    import numpy as np

    gram = expanded = 0.0
    if mode == "quality":
        s = np.diff(resid.indptr).astype(np.float64)
        gram = float(np.sum(s * (s - 1) / 2))  # camplace.solver.engines.quality.min_gram.min_gram_cost
        expanded = float(np.sum(s * (s + 1) / 2))
    return ProblemSizes(k=int(k), points=int(resid.shape[0]), free=int(free), nnz=int(resid.nnz), fixed=int(fixed),
                        conflicts=int(conflicts), min_gram_pairs=gram, expanded_nnz=expanded)


def choose_engine(problem: ProblemSizes, options: SolveOptions, budget_bytes: int, large_k: bool = True) -> EngineChoice:
    """Choose the engine of a maxcover / quality / multiview problem (pure: sizes in, choice out).

    Parameters
    ----------
    problem : ProblemSizes
    options : SolveOptions
        Reads ``mode``, ``views``, ``min_angle_deg`` and ``engine`` (``problem.k`` is the k).
    budget_bytes : int
        Memory the engine may use (:func:`camplace.solver._support.memory.memory_budget_bytes`).
    large_k : bool
        Consider the engines for ``4 < k <= 8`` (:mod:`camplace.solver.engines.large_k.search`); ``solve`` asks
        again without them when they do not fit in memory (they measure that themselves).

    Returns
    -------
    EngineChoice
        Unpacks as ``engine, reason``.

    Raises
    ------
    CamplaceError
        ``exact`` asked for where it does not apply, or where its memory would not fit.
    """
    engine, mode, k = options.engine, options.mode, problem.k
    m, nf, nnz = problem.points, problem.free, problem.nnz
    exact_ok = mode in ("maxcover", "quality") and problem.conflicts == 0
    stats: dict[str, Any] = {}
    expanded = False
    why_not = ""
    if large_k and EXACT_MAX_K < k <= LARGE_K_MAX and engine in ("auto", "exact") and problem.conflicts == 0 and (
            mode != "multiview" or (options.min_angle_deg is None and not problem.fixed)):
        return EngineChoice("exact", f"{'requested' if engine == 'exact' else 'auto'}: {mode} with "
                            f"{EXACT_MAX_K} < k = {k} <= {LARGE_K_MAX}: the large-k engine", "large-k")
    if mode == "quality" and exact_ok and engine in ("auto", "exact"):
        tree_ok = (engine == "exact" or k <= EXACT_MAX_K) and quality_tree_bytes(m, nf, nnz) <= budget_bytes
        gram_ok = (k in (2, 3) and nf <= QUALITY_EXACT_MAX_N and problem.min_gram_pairs <= QUALITY_EXACT_MAX_PAIRS
                   and quality_exact_bytes(m, nf) <= budget_bytes)
        if tree_ok or gram_ok:
            which = " then ".join(n for n, ok in (("quantised tree", tree_ok), ("min-Gram", gram_ok)) if ok)
            return EngineChoice("exact", f"{'requested' if engine == 'exact' else 'auto'}: quality without minimum "
                                f"distance, k = {k}: the {which} engine fits", "quality-portfolio", tree_ok, gram_ok)
        if engine == "exact" or k <= EXACT_MAX_K:
            # Expanded nnz = sum_i s_i (s_i + 1) / 2 at most; estimate before building.
            est = problem.expanded_nnz
            stats["quality_expanded_nnz_estimate"] = est
            if est <= _QUALITY_EXPAND_MAX and expand_bytes(est, nnz) <= budget_bytes:
                expanded = True
            else:
                memory_fallback(OverBudget(quality_tree_bytes(m, nf, nnz), budget_bytes, "the exact engine"), stats,
                                asked=engine == "exact", then="falling back to the general model",
                                fix="use engine mip (or fewer candidates / points)", warn=False)
                why_not = "the quality engines and level rows do not fit in memory"
    multiview_ok = mode == "multiview" and options.min_angle_deg is None and not problem.fixed and problem.conflicts == 0
    angle_ok = mode == "multiview" and options.min_angle_deg is not None and problem.conflicts == 0
    if engine == "exact" and not (exact_ok or multiview_ok or angle_ok):
        raise CamplaceError(
            "the exact engine solves maxcover and quality without min_distance_m, and multiview without fixed "
            "cameras or minimum distance (with or without a minimum angle); use engine mip or cpsat"
        )
    name = engine
    if engine == "auto":
        name = "exact" if (exact_ok and k <= EXACT_MAX_K and (mode == "maxcover" or expanded)) or (
            (multiview_ok or angle_ok) and k <= EXACT_MAX_K) else "mip"
    if name == "exact" and angle_ok:
        route = "angle"
    elif name == "exact" and multiview_ok:
        route = "multiview"
    elif name == "exact" or (exact_ok and mode == "maxcover"):
        route = "maxcover" if mode == "maxcover" else "quality-levels"
    else:
        route = "model"
    return EngineChoice(name, _reason(engine, name, mode, k, problem, exact_ok, multiview_ok, angle_ok, why_not),
                        route, stats=stats)


def _reason(engine: str, name: str, mode: str, k: int, p: ProblemSizes, exact_ok: bool, multiview_ok: bool,
            angle_ok: bool, why_not: str) -> str:
    """One line: why ``name`` runs."""
    if engine != "auto":
        return f"requested: engine {engine}"
    if name == "exact":
        return f"auto: {mode} with k = {k} <= {EXACT_MAX_K}" + (
            " without fixed cameras" if multiview_ok else " with the minimum angle" if angle_ok else
            "" if mode == "multiview" else " without minimum distance")
    if why_not:
        return f"auto: {why_not}"
    if k > EXACT_MAX_K and (exact_ok or multiview_ok or angle_ok):
        return f"auto: k = {k} > {EXACT_MAX_K}, beyond the exact engines"
    if p.conflicts:
        return f"auto: min_distance_m ({p.conflicts} conflicting pairs) needs the model"
    return f"auto: {mode} with fixed cameras ({p.fixed}) needs the model"
