"""All placement formulations behind one function, :func:`solve`.

Modes (``Q`` is the (m, n) points x candidates matrix, values in (0, 1], > 0 means "observes";
``w`` the point weights; ``S`` the chosen new cameras, ``F`` the fixed existing ones):

``maxcover``
    maximise ``sum_i w_i [some camera of S u F observes i]``, ``|S| = k``.
``quality``
    maximise ``sum_i w_i max_{j in S u F} Q_ij`` (0 for unobserved points), ``|S| = k``.
    Exact reformulation used by every engine: with the distinct values ``q_1 > ... > q_L`` of row
    ``i``, ``max_j Q_ij = sum_l (q_l - q_{l+1}) [some chosen j has Q_ij >= q_l]`` (``q_{L+1}=0``),
    i.e. max coverage of "level rows" ``(i, l)``. The exact engine gets the expanded matrix; the
    MIP/CP-SAT models use the compact chain ``y_il <= y_i,l-1 + sum_{j: Q_ij = q_l} x_j``.
``multiview``
    maximise the weight of points observed by at least ``views`` cameras of ``S u F``; with
    ``min_angle_deg`` a point also needs two of those cameras whose view rays (point -> camera)
    make an angle >= ``min_angle_deg`` at the point (needs ``positions`` and ``points``). Model:
    ``views * y_i <= sum_{j observes i} x_j``; with the angle, witness variables
    ``u_ia <= x_a``, ``sum_a u_ia = 2 y_i``, ``u_ia + u_ib <= 1`` for every pair closer than the
    angle.
``setcover``
    minimise the cost of ``S`` (``costs``, default 1 each; fixed cameras cost nothing) such that
    every coverable point of positive weight is observed (or, with ``required_fraction < 1``,
    that fraction of the coverable weight). Points no allowed camera observes are reported as
    uncoverable in ``stats``. ``objective`` is the cost and ``bound`` a LOWER bound. Solved by
    :mod:`camplace.solver.engines.setcover.local_search` (reductions, local search, Lagrangian bound; ``auto`` then
    runs SCIP on small reduced instances, ``mip`` / ``cpsat`` always; engine ``local-search`` in
    the result when no model ran); with ``min_distance_m`` conflicts, by the SCIP / CP-SAT model
    directly. ``search_seed`` and ``iterations`` set the local search.

Side constraints for every mode: ``fixed`` (kept, in ``selected``, not counted in ``k``),
``forbidden`` (never chosen) and ``min_distance_m`` (chosen cameras, fixed included, pairwise at
least that far apart; needs ``positions``).

Engines: ``exact`` (the bound-pruned bitset engine of :mod:`camplace.solver.engines.bitset.search` for
maxcover without minimum distance and multiview (any ``views``) without fixed cameras, minimum
angle or minimum distance; quality runs the quantised-tree
engine of :mod:`camplace.solver.engines.quality.tree` and, for k = 2 or 3 new cameras on up to 3,000
candidates, hands over to the min-Gram triple engine of :mod:`camplace.solver.engines.quality.min_gram` if the
tree has not finished within its share of the time (see :func:`camplace.solver.engines.quality.portfolio.quality_engines`); when neither
fits in memory, the bitset engine on the level rows while that expansion stays small), ``mip``
(SCIP) and ``cpsat``.
``auto`` picks ``exact`` where it applies and ``k <= 4`` (``4 < k <= 8``: :mod:`camplace.solver.engines.large_k.search`),
otherwise ``mip``: the decision is :func:`camplace.solver.choose.choose_engine` (pure; its reason
goes to ``stats["engine_choice"]``). Each exact engine
first checks that its working memory fits in :func:`camplace.solver._support.memory.memory_budget_bytes`;
if not, ``auto`` falls back to the general model (``stats["memory_fallback"]`` says why) and an
explicit ``exact`` is a one-line error.

For ``multiview`` with fewer cameras (new and fixed) than ``2 * views``, an answer the engine could
not prove gets its bound tightened by :func:`camplace.solver.engines.bitset.pair_cap.opposite_pair_bound` (pairs of
points no allowed camera observes together, of which at most one can count); the engines then run
with 95 % of the time limit (all but 2 s at most), the bound with the rest
(``stats["opposite_pairs"]``). The bitset engine uses the same pairs inside its search.
"""

from __future__ import annotations

import logging
import math
import numbers
import time
from dataclasses import replace
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from camplace.errors import CamplaceError
from camplace.names import MODES
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.greedy import NearCandidates, greedy
from camplace.solver._support.memory import (OverBudget, holding, matrix_bytes, memory_budget, memory_budget_bytes,
                                             memory_fallback, memory_notes, note_memory)
from camplace.solver.engines.bitset.pair_cap import cap_applies, cap_bound, cap_deadline
from camplace.solver.engines.mip.mode_models import check_setcover_memory
from camplace.solver.engines.setcover.mode import setcover
from camplace.solver.options import SolveOptions
from camplace.solver.problem.checks import (CONFLICT_PAIR_BYTES, conflict_count, conflict_pairs, coords, float_values,
                                            index_set, values_matrix)
from camplace.solver.problem.objectives import cheap_bound, mode_value
from camplace.solver.problem.presolve import check_weights
from camplace.solver.result import EngineOutcome, SolverResult, jsonable, relative_gap
from camplace.solver.routes import CoverProblem, fixed_base, run_cover, run_team
from camplace.solver.spacing_branch import branch_on_conflicts, conflict

__all__ = ["MODES", "solve", "mode_value", "conflict_pairs", "conflict_count", "bits_solve_bytes"]

log = logging.getLogger(__name__)

_OPT_TOL = 1e-9


def solve(
    matrix: Any,
    weights: Any,
    k: int | None = None,
    *,
    mode: str = "maxcover",
    views: int = 2,
    min_angle_deg: float | None = None,
    positions: Any = None,
    points: Any = None,
    costs: Any = None,
    required_fraction: float = 1.0,
    fixed: Sequence[int] = (),
    forbidden: Sequence[int] = (),
    min_distance_m: float | None = None,
    engine: str = "auto",
    time_limit_s: float | None = None,
    memory_budget_bytes: int | None = None,
    search_seed: int = 0,
    iterations: int | None = None,
    options: SolveOptions | None = None,
) -> SolverResult:
    """Choose cameras under one of the formulations (see the module docstring).

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Observation quality in (0, 1] (> 0 means "observes"). Also a binary run's column bitsets
        (``camplace.visibility.bits.BitMatrix``) or a graded run's quantised columns
        (``camplace.visibility.qbytes.ByteMatrix``: plain quality with the quantised tree on its
        bytes, exact for the quantised values, see :mod:`camplace.solver.bytes_route`), taken
        without a CSR copy where the route allows.
    weights : (m,) array_like of float64
        Non-negative point weights.
    k : int, optional
        Number of NEW cameras (required for every mode but ``setcover``, which must not get it).
    mode : {"maxcover", "quality", "multiview", "setcover"}
    views : int
        multiview: cameras needed per point (default 2).
    min_angle_deg : float, optional
        multiview: minimum angle at the point between two of its views (needs positions, points).
    positions : (n, 3) array_like, optional
        Camera positions (for ``min_distance_m`` and ``min_angle_deg``; with ``points``, multiview
        with fixed cameras and k <= 4 runs the exact angle engine at 0 degrees instead of the
        general model: :func:`_fixed_views_as_angle`).
    points : (m, 3) array_like, optional
        Point positions (for ``min_angle_deg``, and that route).
    costs : (n,) array_like, optional
        setcover: non-negative camera costs (default 1).
    required_fraction : float
        setcover: fraction of the coverable weight to observe, in (0, 1] (default 1: every
        coverable point of positive weight).
    fixed, forbidden : sequence of int
        Cameras always kept / never chosen.
    min_distance_m : float, optional
        Minimum distance between any two chosen cameras (fixed included).
    engine : {"auto", "exact", "mip", "cpsat"}
    time_limit_s : float, optional
        Wall-clock limit; on expiry the best solution found is returned with its gap.
    memory_budget_bytes : int, optional
        Cap on the memory any engine or model may use (``--memory-budget-gb``); engines also stay
        within :data:`~camplace.solver._support.memory.MEMORY_FRACTION` of the memory available.
    search_seed : int
        setcover: seed of the local search (:mod:`camplace.solver.engines.setcover.local_search`).
    iterations : int, optional
        setcover: iteration budget of the local search; with it and no time limit the answer is
        fully deterministic (with a time limit it depends on the machine's speed).
    options : SolveOptions, optional
        All of the above (``k`` to ``iterations``) in one checked object
        (:class:`~camplace.solver.options.SolveOptions`), e.g. built by the command line; then none
        of them may be given beside it. Its ``threads`` (no keyword of its own) caps the threads
        of this solve: ``options=SolveOptions(k=3, threads=2)``.

    Returns
    -------
    SolverResult
        ``selected`` holds fixed and new cameras (sorted original indices); ``objective`` is
        recomputed on the original data; for setcover it is the cost of the new cameras and
        ``bound`` a lower bound. ``stats`` has ``mode``, ``fixed``, ``new`` and, for setcover,
        ``uncoverable_points`` / ``uncoverable_weight`` / ``covered_fraction``; and
        ``memory_estimates`` (``step -> {"bytes", "held"}``: each step's estimate made before it
        allocated, with what was known then, beside the bytes the solve held then, the input
        matrix included; :func:`~camplace.solver._support.memory.note_memory`) when a step made one.

    Raises
    ------
    CamplaceError
        On malformed input or an impossible request (one line).
    """
    if options is None:
        options = SolveOptions(
            mode=mode, k=k, views=views, min_angle_deg=min_angle_deg, required_fraction=required_fraction,
            fixed=fixed, forbidden=forbidden, min_distance_m=min_distance_m, engine=engine,
            time_limit_s=time_limit_s, costs=costs, memory_budget_bytes=memory_budget_bytes, search_seed=search_seed,
            iterations=iterations,
        )
    else:
        given = dict(k=k, mode=mode, views=views, min_angle_deg=min_angle_deg, costs=costs,
                     required_fraction=required_fraction, fixed=fixed, forbidden=forbidden,
                     min_distance_m=min_distance_m, engine=engine, time_limit_s=time_limit_s,
                     memory_budget_bytes=memory_budget_bytes, search_seed=search_seed, iterations=iterations)
        mixed = sorted(name for name, value in given.items() if not _is_default(name, value))
        if mixed:
            raise CamplaceError(f"solve: give {', '.join(mixed)} inside options=SolveOptions(...), not beside it")
    from camplace._cores import using_threads

    with memory_budget(options.memory_budget_bytes), using_threads(options.threads), memory_notes() as notes, \
            holding(matrix_bytes(matrix)):
        every_pair = _fixed_views_as_angle(options, positions, points)
        res = _relaxed_first(matrix, weights, positions, points, every_pair or options)
    if every_pair is not None:
        _note_every_pair(res, options.engine)
    if notes:
        res.stats["memory_estimates"] = {stage: dict(v) for stage, v in notes.items()}
    return res


def _fixed_views_as_angle(o: SolveOptions, positions: Any, points: Any) -> SolveOptions | None:
    """Multiview with fixed cameras and no angle, as the angle engine's problem with a minimum
    angle of 0 degrees (None where that does not apply).

    A row's threshold is ``views`` less its fixed views, which the multiview bitset engine does not
    model (the general model did it: at 10,000 x 50,000 its SCIP model needed 52 GiB and the run
    got the greedy answer, 0.510 with a bound of 1.000). The angle engine takes fixed cameras, and
    at 0 degrees every pair of views passes its angle test (the cosine of two rays never exceeds
    1: :func:`~camplace.solver.engines.angle._kernels.angle_ok`), so its problem is this one, the
    same objective for every camera set; it needs the geometry only to run (auto or exact, k <= 4,
    ``views >= 2``, no minimum distance or team, ``positions`` and ``points`` given)."""
    if positions is not None and points is not None and _fixed_views_applies(o):
        return replace(o, min_angle_deg=0.0)
    return None


def _fixed_views_applies(o: SolveOptions) -> bool:
    """The options of :func:`_fixed_views_as_angle`'s route (given the geometry)."""
    from camplace.solver.choose import EXACT_MAX_K

    return (o.mode == "multiview" and o.min_angle_deg is None and bool(o.fixed) and o.min_distance_m is None
            and o.team is None and o.engine in ("auto", "exact") and o.k is not None and o.k <= EXACT_MAX_K
            and int(o.views) >= 2)


def _note_every_pair(res: SolverResult, engine: str) -> None:
    """Say in ``res.stats`` that :func:`_fixed_views_as_angle` chose the route (the objective is the
    plain multiview one: no angle was asked for)."""
    res.stats["fixed_views"] = "the angle engine at 0 degrees (every pair of views allowed)"
    choice = res.stats.get("engine_choice")
    if engine == "auto" and isinstance(choice, dict) and choice.get("route") == "angle":
        choice["reason"] = ("auto: multiview with fixed cameras, k <= 4: the angle engine with every pair of views "
                            "allowed (a row needs views less its fixed views)")


_DEFAULTS = SolveOptions()


def _is_default(name: str, value: Any) -> bool:
    """True when keyword option ``name`` of :func:`solve` was left at its default."""
    if name == "costs":
        return value is None
    if name in ("fixed", "forbidden"):
        return value is None or len(value) == 0
    return value is getattr(_DEFAULTS, name) or (type(value) is type(getattr(_DEFAULTS, name))
                                                  and value == getattr(_DEFAULTS, name))


#: The share of the time limit that :func:`_relaxed_first` gives the problem without its minimum
#: distance; the spaced route takes what is left.
RELAXED_SPACING_SHARE = 0.3
SPACING_BRANCH_SHARE = 0.3  # of the time left after it: branching on its conflicting pairs (maximisation) ...
SPACING_BRANCH_SOLVES = 400  # ... with at most this many relaxed solves, stopping when this many in a row
SPACING_BRANCH_STALL = 12  # ... have not lowered the bound


def _relaxation_applies(o: SolveOptions) -> bool:
    """A minimum distance in max coverage, quality, multiview without an angle or set cover, under
    ``auto``, without a team: :func:`_relaxed_first` solves without the distance first. (With an angle the
    angle route relaxes the distance itself: :mod:`camplace.solver.engines.angle.spaced`.)"""
    return (o.min_distance_m is not None and o.min_angle_deg is None and o.team is None and o.engine == "auto"
            and (o.mode == "setcover" or (o.mode in ("maxcover", "quality", "multiview") and o.k is not None)))


def _relaxed_first(matrix: Any, weights: Any, positions: Any, points: Any, o: SolveOptions) -> SolverResult:
    """:func:`_solve`, a minimum distance relaxed first (:func:`_relaxation_applies`): the same
    problem without the spacing between new cameras (those closer than the distance to a fixed
    camera forbidden), on the exact routes that read the bits, within
    :data:`RELAXED_SPACING_SHARE` of the time limit. Dropping a constraint only widens the choice:
    a proven optimum whose cameras are spaced is the spaced optimum (returned at once, without the
    general model), and otherwise the relaxed bound (its optimum, or its bound when stopped) bounds
    the spaced problem, so the spaced route's answer keeps the smaller bound.
    ``stats["spacing_relaxed"]`` gives the relaxed status, objective, bound, whether its cameras
    were spaced and its time."""
    deadline = Deadline(o.time_limit_s)
    if not _relaxation_applies(o) or positions is None:
        return _solve(matrix, weights, positions, points, o, deadline)
    n = matrix.shape[1]
    pos = coords(positions, n, "positions", "camera positions")
    d = float(o.min_distance_m)
    fixed = index_set(o.fixed, n, "fixed")
    near = set()
    for f in fixed:  # new cameras stay spaced from the fixed ones (the route's free columns)
        near.update(np.flatnonzero(np.linalg.norm(pos - pos[f], axis=1) < d).tolist())
    relaxed_o = replace(o, min_distance_m=None, forbidden=tuple(sorted((set(o.forbidden) | near) - set(fixed))))
    t = time.perf_counter()
    try:
        relaxed = _solve(matrix, weights, positions, points, relaxed_o, deadline.share(RELAXED_SPACING_SHARE))
    except CamplaceError:  # (e.g. too few candidates once spaced from the fixed ones): the route says it
        return _solve(matrix, weights, positions, points, o, deadline)
    relaxed.stats["forbidden"] = list(index_set(o.forbidden, n, "forbidden"))  # the caller's (not those near fixed)
    spaced = relaxed.status in ("optimal", "feasible") and conflict(relaxed.selected, pos, d) is None
    info = {"status": relaxed.status, "objective": relaxed.objective, "bound": relaxed.bound, "spaced": spaced,
            "time_s": time.perf_counter() - t}
    if spaced and relaxed.status == "optimal":
        relaxed.stats["spacing_relaxed"] = info
        relaxed.stats["min_distance_m"] = d
        return replace(relaxed, time_s=deadline.elapsed())
    if o.mode == "setcover":
        res = _solve(matrix, weights, positions, points, o, deadline)
        return _spaced_best(res, relaxed, spaced, info, 1.0, deadline.elapsed(), minimize=True)
    scale = float(check_weights(weights, matrix.shape[0]).sum())
    if relaxed.status == "optimal" and not spaced:  # (a relaxed problem not proven in its share: parts no easier)
        relaxed, spaced = _spacing_branched(matrix, weights, positions, points, relaxed_o, relaxed, pos, d,
                                            len(fixed), deadline, scale, info)
        if spaced and info["branching"]["closed"]:
            best = replace(relaxed, status="optimal", bound=relaxed.objective, gap=0.0, time_s=deadline.elapsed())
            best.stats.update({"spacing_relaxed": info, "min_distance_m": d})
            return best
    res = _solve(matrix, weights, positions, points, o, deadline)
    return _spaced_best(res, relaxed, spaced, info, scale, deadline.elapsed())


def _spacing_branched(matrix: Any, weights: Any, positions: Any, points: Any, relaxed_o: SolveOptions,
                      relaxed: SolverResult, pos: np.ndarray, d: float, n_fixed: int, deadline: Deadline,
                      scale: float, info: dict) -> tuple[SolverResult, bool]:
    """Branching on the relaxed optimum's conflicting pairs (:mod:`camplace.solver.spacing_branch`)
    within :data:`SPACING_BRANCH_SHARE` of the time left: each part the same relaxed problem with
    one more column forbidden, on its exact route. Returns the answer to hand to
    :func:`_spaced_best` as the relaxed one (the best spaced answer found with the branching's
    bound, or the relaxed answer with that bound when none was found) and whether it is spaced;
    ``info["branching"]`` gives the solves, the nodes left, whether the branching closed (then
    that answer is the spaced optimum) and its time."""
    t = time.perf_counter()
    share = deadline.share(SPACING_BRANCH_SHARE)
    n = matrix.shape[1]
    out = branch_on_conflicts(
        relaxed, lambda forb: _solve(matrix, weights, positions, points, replace(relaxed_o, forbidden=forb), share),
        pos, d, tuple(relaxed_o.forbidden), n - len(set(relaxed_o.forbidden)) - n_fixed, int(relaxed_o.k),
        share.expired, _OPT_TOL * max(abs(relaxed.bound), scale), SPACING_BRANCH_SOLVES, SPACING_BRANCH_STALL)
    info["branching"] = {**out.stats, "closed": out.closed, "bound": out.bound, "time_s": time.perf_counter() - t}
    if out.best is None:  # (no part gave a spaced answer; none exists at all where the bound is -inf)
        return replace(relaxed, bound=out.bound if math.isfinite(out.bound) else relaxed.bound), False
    out.best.stats["forbidden"] = relaxed.stats.get("forbidden", [])  # the caller's, not the branching's
    return replace(out.best, bound=out.bound), True


def _spaced_best(res: SolverResult, relaxed: SolverResult, spaced: bool, info: dict, scale: float,
                 elapsed: float, minimize: bool = False) -> SolverResult:
    """The answer of a problem with a minimum distance from its own route's result ``res`` and the
    relaxed one (:func:`_relaxed_first`): the better spaced answer (the relaxed one only when its
    cameras are ``spaced``), with the tighter of the two valid bounds (the smaller upper bound, or
    for set cover, ``minimize``, the larger lower bound); optimal when they meet.

    Parameters
    ----------
    res, relaxed : SolverResult
    spaced : bool
        Whether the relaxed answer's cameras are spaced.
    info : dict
        ``stats["spacing_relaxed"]``.
    scale : float
        The weights' sum (the optimality tolerance's scale, as :func:`_result`'s).
    elapsed : float
        The whole solve's seconds.
    """
    found = ("optimal", "feasible")
    sign = -1.0 if minimize else 1.0  # larger sign * objective is better
    best = res
    if spaced and (res.status not in found or sign * relaxed.objective > sign * res.objective):
        best = replace(relaxed, stats={**relaxed.stats, "spaced_route": {"status": res.status,
                                                                          "objective": res.objective,
                                                                          "bound": res.bound}})
    best.stats["spacing_relaxed"] = info
    if best.status not in found:
        return replace(best, time_s=elapsed)
    bound = sign * min(sign * res.bound if res.status in found else math.inf,
                       sign * relaxed.bound if relaxed.status in found else math.inf)
    bound = sign * max(sign * bound, sign * best.objective)
    if abs(bound - best.objective) <= _OPT_TOL * max(abs(bound), scale):
        return replace(best, status="optimal", bound=best.objective, gap=0.0, time_s=elapsed)
    gap = (max(0.0, (best.objective - bound) / max(abs(best.objective), 1e-12)) if minimize
           else relative_gap(bound, best.objective))
    return replace(best, status="feasible", bound=bound, gap=gap, time_s=elapsed)


def _solve(matrix: Any, weights: Any, positions: Any, points: Any, o: SolveOptions,
           deadline: Deadline | None = None) -> SolverResult:
    """:func:`solve` within the memory budget (``o`` is already checked); ``deadline`` is the
    solve's when it has begun already (:func:`_rows_presolved`), else made here."""
    if deadline is None:
        deadline = Deadline(o.time_limit_s)  # the solve's one deadline, passed down to the engines
    t0 = deadline.start
    k, mode, views, min_angle_deg, engine = o.k, o.mode, o.views, o.min_angle_deg, o.engine
    min_distance_m = o.min_distance_m
    if getattr(matrix, "format", None) == "bytes":  # a graded matrix quantised to a byte a cell
        from camplace.solver.bytes_route import bytes_applies, bytes_fallback, bytes_outcome

        got = bytes_outcome(matrix, weights, o, deadline) if bytes_applies(o, matrix.shape[1]) else None
        if got is not None:
            ctx, w = got
            return _result(ctx, o, w, (), (), np.zeros((0, 2), dtype=np.int64), matrix.shape, t0)
        matrix = bytes_fallback(matrix, o)  # the pattern's bitsets, or CSR float32 values
    if getattr(matrix, "format", None) == "bits":  # a binary matrix as column bitsets
        from camplace.solver.bits_route import bits_applies, bits_outcome

        got = bits_outcome(matrix, weights, o, deadline, positions, points) if bits_applies(o) else None
        if got is not None:
            ctx, w = got
            return _result(ctx, o, w, (), (), np.zeros((0, 2), dtype=np.int64), matrix.shape, t0)
        sided = _sides_bits(matrix, weights, o, deadline, positions, points) if _sides_bits_applies(o) else None
        if sided is not None:  # fixed / forbidden cameras: the bits route on the allowed columns
            ctx, w, fixed_t, forbidden_t = sided
            return _result(ctx, o, w, fixed_t, forbidden_t, np.zeros((0, 2), dtype=np.int64), matrix.shape, t0)
        team = _team_bits(matrix, weights, o, deadline) if _team_bits_applies(o) else None
        if team is not None:  # a team's branch and bound read the bits too
            ctx, w, fixed_t, forbidden_t = team
            return _result(ctx, o, w, fixed_t, forbidden_t, np.zeros((0, 2), dtype=np.int64), matrix.shape, t0)
        if o.mode == "setcover" and o.team is None:  # counts from the bits
            ctx, w, fixed_t, forbidden_t, conflicts = _setcover_bits(matrix, weights, positions, o, deadline)
            return _result(ctx, o, w, fixed_t, forbidden_t, conflicts, matrix.shape, t0)
        spaced = _spaced_angle_bits(matrix, weights, o, deadline, positions, points) if _spaced_angle_applies(o) else None
        if spaced is not None:  # an angle and a distance: the angle engine on the bits, without the spacing
            ctx, w, fixed_t, forbidden_t, conflicts = spaced
            return _result(ctx, o, w, fixed_t, forbidden_t, conflicts, matrix.shape, t0)
        if _rows_presolve_applies(o):  # the general model (and the rest): CSR of the merged rows only
            got = _rows_presolved(matrix, weights, positions, o, deadline)
            if got is not None:
                return got
        matrix = matrix.tocsr(np.bool_)  # the other routes read CSR (the bool pattern: 5 bytes a pair)
    q = values_matrix(matrix)
    if q.dtype == np.bool_ and mode == "quality":
        # quality's engines read values: a bool pattern becomes float32 ones (4 bytes a pair)
        need, budget = 4 * int(q.nnz), memory_budget_bytes()
        if need > budget:
            memory_fallback(OverBudget(need, budget, "the float32 values of the matrix"), None, asked=False, then=None,
                            fix="pass the float32 matrix (load_visibility without pattern=True)")
        q = float_values(q)
    m, n = q.shape
    w, fixed_t, forbidden_t = _checked_columns(weights, o, m, n)
    pos = None
    if positions is not None:
        pos = coords(positions, n, "positions", "camera positions")
    conflicts, too_many = _conflicts(pos, o)
    pts = None
    if min_angle_deg is not None:
        if pos is None or points is None:
            raise CamplaceError("min_angle_deg needs camera positions (positions (n, 3)) and point positions (points (m, 3))")
        pts = coords(points, m, "points", "point positions")
    if mode == "multiview":
        views = int(views)
    if too_many is not None:
        assert pos is not None and min_distance_m is not None
        return _spaced_fallback(q, w, k, mode, views, min_angle_deg, pos, pts, fixed_t, forbidden_t,
                                float(min_distance_m), engine, too_many, deadline)

    free_cols, conflicts = _free_columns(n, fixed_t, forbidden_t, conflicts, min_distance_m)

    if o.team is not None:  # a camera team (issue 31): its own route, every constraint enforced
        k_team = _team_k(o, n, free_cols)
        ctx = run_team(q, w, o, k_team, fixed_t, free_cols, conflicts, deadline,
                       k_solver=lambda sub: _solve(q, w, None, None, sub),  # single-model count patterns
                       pos=pos, pts=pts)
    elif mode == "setcover":
        if conflicts.size:  # the model runs directly (otherwise the local search checks its own memory)
            check_setcover_memory(q, w, free_cols, conflicts, engine)
        ctx = setcover(q, w, o.costs, o.required_fraction, fixed_t, free_cols, conflicts, engine, deadline,
                       o.search_seed, o.iterations)
    else:
        k = _checked_k(o, fixed_t, free_cols)
        # multiview with fewer cameras than 2 x views: opposite points cap the bound when the search
        # leaves a gap (pair_cap); the engines then leave a little of the time limit for the cap.
        cap = mode == "multiview" and cap_applies(k + len(fixed_t), views)
        inner = cap_deadline(deadline) if cap else deadline
        ctx = run_cover(CoverProblem(q, w, k, mode, views, min_angle_deg, pos, pts, fixed_t, free_cols, conflicts, o,
                                     inner, stats={"k": k}))
        searched = ctx.stats.get("engine_stats", {}).get("search") == "opposite pairs"  # already bounded by them
        if cap and ctx.selected is not None and ctx.status != "optimal" and not searched and not deadline.expired():
            ctx = cap_bound(ctx, q, w, views, k + len(fixed_t), np.union1d(free_cols, fixed_t).astype(np.int64), deadline)

    return _result(ctx, o, w, fixed_t, forbidden_t, conflicts, (m, n), t0)


def _conflicts(pos: np.ndarray | None, o: SolveOptions) -> tuple[np.ndarray, str | None]:
    """The candidate pairs closer than ``o.min_distance_m`` ((p, 2) int64; none without one) and,
    when they would not fit in the memory budget, the fallback's message instead (None otherwise;
    set cover, which has no fallback, and an engine asked by name stop with a one-line error).

    Parameters
    ----------
    pos : (n, 3) float64 or None
        Camera positions, metres.
    o : SolveOptions
    """
    none = np.zeros((0, 2), dtype=np.int64)
    if o.min_distance_m is None:
        return none, None
    if pos is None:
        raise CamplaceError("min_distance_m needs the camera positions (positions, shape (n, 3))")
    d = float(o.min_distance_m)
    n_pairs = conflict_count(pos, d)
    need, budget = n_pairs * CONFLICT_PAIR_BYTES, memory_budget_bytes()
    if need > budget:
        return none, memory_fallback(
            OverBudget(need, budget, f"min_distance_m={d:g} ({n_pairs} candidate pairs closer than that)"), None,
            asked=o.engine != "auto", warn=False,
            then=None if o.mode == "setcover" else "returning the greedy answer with a bound that ignores the spacing",
            fix="lower min_distance_m or use fewer candidates")  # logged by _spaced_fallback
    return conflict_pairs(pos, d), None


def _free_columns(n: int, fixed_t: tuple[int, ...], forbidden_t: tuple[int, ...], conflicts: np.ndarray,
                  min_distance_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The columns a solve may add ((f,) int64: neither fixed, forbidden nor closer than the minimum
    distance to a fixed camera) and the conflicting pairs among them ((p, 2) int64); a one-line
    error for two fixed cameras closer than the minimum distance."""
    is_fixed = np.zeros(n, dtype=bool)
    is_fixed[list(fixed_t)] = True
    fa = is_fixed[conflicts[:, 0]] if conflicts.size else np.zeros(0, dtype=bool)
    fb = is_fixed[conflicts[:, 1]] if conflicts.size else np.zeros(0, dtype=bool)
    both = np.flatnonzero(fa & fb)
    if len(both):
        a, b = (int(x) for x in conflicts[both[0]])
        raise CamplaceError(f"fixed cameras {a} and {b} are closer than min_distance_m={min_distance_m}")
    free = ~is_fixed
    free[list(forbidden_t)] = False
    if conflicts.size:  # a candidate closer than the minimum distance to a fixed camera
        free[conflicts[fa, 1]] = False
        free[conflicts[fb, 0]] = False
    keep_conf = free[conflicts[:, 0]] & free[conflicts[:, 1]] if conflicts.size else np.zeros(0, dtype=bool)
    return np.flatnonzero(free), conflicts[keep_conf]


def bits_solve_bytes(m: int, n: int, o: SolveOptions, nnz: int = 0, conflicts: int = 0) -> int:
    """Working bytes of :func:`solve` with the options ``o`` on an (m, n) binary matrix of ``nnz``
    observed pairs held as column bitsets (``B = n x ceil(m / 64) x 8`` bytes), besides the
    bitsets, as far as they are known before the matrix exists: what the visibility stage's memory
    guard adds for the solve the run makes next (the pipeline passes it), following
    :func:`_solve`'s routes on a BitMatrix in the same order, each from its engine's own estimate.

    The guard is checked in stages, each allocation against an estimate made with what is known
    just before it. This is the first stage, before the cast: it counts what runs on the whole
    matrix (the presolve, the allowed columns' copy, the angle engine, set cover's bitsets, a
    team's lists, the conflicting pairs, and the whole matrix's CSR and model on the routes that
    make them). The engines and models that run on the presolved instance (the bitset and large-k
    engines, the merged rows' CSR and general model, a max-coverage model) are not counted: its
    size is known only after the presolve, which the pilot's sample does not predict. Each of them
    estimates its bytes on the reduced sizes before allocating, checks them against the solver's
    memory budget (the memory available then: a general model over it gives the greedy answer
    under engine ``auto``, any other stops with a one-line message) and notes them
    (``stats["memory_estimates"]``, :func:`~camplace.solver._support.memory.note_memory`).

    * the bits route (:func:`camplace.solver.bits_route.outcome_bytes`): plain max coverage,
      multiview, ``4 < k <= 8``: the bit presolve; multiview with a minimum angle: the angle engine;
    * fixed or forbidden cameras there (:func:`_sides_bits`): the allowed columns' bitsets (a copy,
      at most ``B``), the residual weights and the bits route's bytes on them;
    * set cover without a minimum distance or team:
      :func:`camplace.solver.engines.setcover.reduce_bits.setcover_bits_bytes`;
    * a team in max coverage (:func:`_team_bits`): the branch and bound's row lists
      (:func:`camplace.solver.engines.team.bnb.row_lists_bytes`) or, where another team engine
      runs, the whole matrix as a bool CSR (5 bytes a pair): the larger (the team engines' own
      working memory is checked by them and not counted);
    * multiview with fixed cameras and no angle (k <= 4, engine auto or exact): as with a minimum angle of
      0 degrees (:func:`_fixed_views_as_angle`), the allowed columns' copy and the angle engine;
    * a minimum distance, engine mip / cpsat, multiview with fixed cameras and no angle otherwise
      (:func:`_rows_presolved`): the bit presolve, or the ``conflicts`` pairs
      (:data:`CONFLICT_PAIR_BYTES` each, counted from the candidates' positions): the larger; under
      ``auto`` with a minimum distance (:func:`_relaxed_first`), the larger of that and the route
      of the same options without the distance, which runs first;
    * set cover with a minimum distance (:func:`_setcover_bits`): the rows left to cover as the
      bool CSR the model reads, at most the whole matrix's (5 bytes a pair), the conflicting pairs
      and the model of every row (counted as below: an upper bound on the set-cover model's size);
    * the rest (a minimum angle on the general model, a team off the bits): the whole matrix as a
      bool CSR (5 bytes a pair; the angle's kernels and models read the pattern, no float values)
      and the general model of every row (without the angle's pair rows, counted by the model once
      the matrix is known); a model over the budget under ``auto`` with a minimum angle and a
      minimum distance: the conflicting pairs and the angle engine that runs instead on the bits,
      without the spacing (:func:`_spaced_angle_bits`;
      :func:`~camplace.solver.engines.angle.search.angle_bytes`).

    A general model over the solver's memory budget (``o.memory_budget_bytes`` and
    :func:`~camplace.solver._support.memory.memory_budget_bytes` now) under engine ``auto`` is
    not counted: the solve then returns the greedy answer with a cheap bound instead of building it
    (:func:`~camplace.solver._support.memory.memory_fallback`), so the guard does not stop a run
    that ends with that answer; asked for by name (mip, cpsat) it is counted, as the solve would
    stop there.

    Parameters
    ----------
    m, n : int
        Rows (points) and columns (candidate poses).
    o : SolveOptions
        The run's options.
    nnz : int
        Observed pairs (0 when not known yet: the parts that do not depend on them).
    conflicts : int
        Candidate pairs closer than ``o.min_distance_m``
        (:func:`~camplace.solver.problem.checks.conflict_count`; 0 without one).

    Returns
    -------
    int
        Bytes.
    """
    if _fixed_views_applies(o):  # the angle engine at 0 degrees (the run passes the geometry: o.reads_geometry)
        o = replace(o, min_angle_deg=0.0)
    if _relaxation_applies(o):  # the problem without the distance first (_relaxed_first), then the spaced route
        return max(_route_bytes(m, n, replace(o, min_distance_m=None), nnz, 0), _route_bytes(m, n, o, nnz, conflicts))
    return _route_bytes(m, n, o, nnz, conflicts)


def _route_bytes(m: int, n: int, o: SolveOptions, nnz: int, conflicts: int) -> int:
    """:func:`bits_solve_bytes` of the route :func:`_solve` takes with ``o`` (no relaxation first)."""
    from camplace.solver.bits_route import bits_applies, outcome_bytes
    from camplace.solver.engines.mip.linear import model_bytes
    from camplace.solver.engines.mip.mode_models import cover_model_size
    from camplace.solver.engines.setcover.reduce_bits import setcover_bits_bytes
    from camplace.solver.engines.team.bnb import row_lists_bytes
    from camplace.solver.problem.presolve_bits import presolve_bits_bytes

    m, n, nnz, conflicts = int(m), int(n), int(nnz), int(conflicts) if o.min_distance_m is not None else 0
    col_bytes = ((m + 63) // 64) * 8
    if o.team is None and o.mode == "setcover" and o.min_distance_m is None:
        return setcover_bits_bytes(m, n)
    if o.team is None and o.mode != "setcover" and o.k is not None:
        if bits_applies(o):
            got = outcome_bytes(m, n, o, nnz)
            if got is not None:
                return got
        if _sides_bits_applies(o):
            multiview = o.mode == "multiview"
            cols = n - len(set(o.forbidden)) - (0 if multiview else len(set(o.fixed)))
            local = replace(o, forbidden=(), fixed=tuple(range(len(o.fixed))) if multiview else ())
            got = outcome_bytes(m, cols, local, nnz)
            if got is not None:  # the allowed columns' copy, the residual weights, the route on them
                return cols * col_bytes + 8 * m + got
    if o.team is not None and _team_bits_applies(o):  # the branch and bound on the bits, or (another team engine) the CSR
        return max(row_lists_bytes(nnz) + 8 * m, 5 * nnz + 8 * (m + 1))
    pairs = CONFLICT_PAIR_BYTES * conflicts
    if o.team is None and _rows_presolve_applies(o):  # the merged rows' CSR and model: noted once they are known
        return max(presolve_bits_bytes(m, n), pairs)
    backend = "cpsat" if o.engine == "cpsat" else "mip"
    free, n_fixed = n - len(set(o.fixed)) - len(set(o.forbidden)), len(set(o.fixed))
    model = model_bytes(backend, *cover_model_size(m, free, nnz, conflicts, n_fixed))
    if o.engine == "auto" and o.mode != "setcover":
        with memory_budget(o.memory_budget_bytes):
            if model > memory_budget_bytes():  # the solve gives the greedy answer instead (routes._model)
                model = 0
    if model == 0 and o.team is None and _spaced_angle_applies(o) and o.k is not None:
        from camplace.solver.engines.angle.search import angle_bytes  # the spacing's relaxation on the bits

        fixed = len(set(o.fixed))
        return pairs + angle_bytes(m, n - fixed - len(set(o.forbidden)), fixed, int(o.k), int(o.views), layout_rows=m)
    return 5 * nnz + 8 * (m + 1) + pairs + model  # the bool pattern (the angle reads it too) and the model


def _checked_columns(weights: Any, o: SolveOptions, m: int, n: int) -> tuple[np.ndarray, tuple[int, ...], tuple[int, ...]]:
    """The weights ((m,) float64) and the fixed and forbidden columns of an (m, n) matrix, checked:
    a one-line error for no columns, bad weights, bad indices or a column both fixed and forbidden."""
    if n == 0:
        raise CamplaceError("the visibility matrix has no candidate columns")
    w = check_weights(weights, m)
    fixed_t = index_set(o.fixed, n, "fixed")
    forbidden_t = index_set(o.forbidden, n, "forbidden")
    both = sorted(set(fixed_t) & set(forbidden_t))
    if both:
        raise CamplaceError(f"candidates {both} are both fixed and forbidden")
    return w, fixed_t, forbidden_t


def _team_k(o: SolveOptions, n: int, free_cols: np.ndarray) -> int | None:
    """The team's checked new-camera count: None for set cover and for a budget team without k
    (after :meth:`~camplace.solver.problem.team.TeamConstraints.check_columns` on ``n`` columns)."""
    o.team.check_columns(n)
    k, mode = o.k, o.mode
    if mode == "setcover" or (k is None and o.team.cardinality == "budget"):
        return None
    if k is None or isinstance(k, bool) or not isinstance(k, numbers.Integral) or int(k) < 0:
        raise CamplaceError(f"k must be an integer number of cameras for mode {mode!r}, got {k!r}")
    if o.team.cardinality == "exact" and int(k) > free_cols.size:
        raise CamplaceError(f"cannot choose k={int(k)} new cameras from {free_cols.size} allowed candidates "
                            "(lower k, or forbid/fix fewer cameras)")
    return int(k)


def _team_bits_applies(o: SolveOptions) -> bool:
    """A team in max coverage without minimum distance or angle: its branch and bound and count
    patterns may read a BitMatrix (:func:`_team_bits`)."""
    return o.team is not None and o.mode == "maxcover" and o.min_distance_m is None and o.min_angle_deg is None


def _team_bits(bits: Any, weights: Any, o: SolveOptions, deadline: Deadline) -> tuple | None:
    """A team on a binary matrix held as column bitsets (:class:`camplace.visibility.bits.BitMatrix`)
    without a CSR copy, where :func:`~camplace.solver.routes.run_team` chooses the branch and bound:
    its single-model count patterns are solved on the model's columns of the bits (the bits route,
    :mod:`camplace.solver.bits_route`), the others by the branch and bound on the bits' row lists.

    Returns
    -------
    (EngineOutcome, (m,) float64 weights, fixed, forbidden) or None
        None when the team's engine is another one (the caller converts the bits to CSR).
    """
    m, n = bits.shape
    w, fixed_t, forbidden_t = _checked_columns(weights, o, m, n)
    free = np.ones(n, dtype=bool)
    free[list(set(fixed_t) | set(forbidden_t))] = False
    free_cols = np.flatnonzero(free)
    k_team = _team_k(o, n, free_cols)
    ctx = run_team(bits, w, o, k_team, fixed_t, free_cols, np.zeros((0, 2), dtype=np.int64), deadline,
                   k_solver=lambda sub: _bits_columns_solve(bits, w, sub))
    return None if ctx is None else (ctx, w, fixed_t, forbidden_t)


def _setcover_bits(bits: Any, weights: Any, positions: Any, o: SolveOptions, deadline: Deadline) -> tuple:
    """Set cover (no team) on a binary matrix held as column bitsets: the coverable and
    fixed-covered rows counted from the bits, and only the rows left to cover made into the
    structure the search reads (:func:`~camplace.solver.engines.setcover.mode.setcover`: their row
    bitsets, or with a minimum distance the bool CSR of those rows that the SCIP / CP-SAT model
    reads), instead of the whole matrix's CSR and its float64 pattern.

    Returns
    -------
    (EngineOutcome, (m,) float64 weights, fixed, forbidden, (p, 2) int64 conflicting free pairs)
    """
    m, n = bits.shape
    w, fixed_t, forbidden_t = _checked_columns(weights, o, m, n)
    pos = None if positions is None else coords(positions, n, "positions", "camera positions")
    conflicts, _ = _conflicts(pos, o)  # (set cover stops when they do not fit: no fallback)
    free_cols, conflicts = _free_columns(n, fixed_t, forbidden_t, conflicts, o.min_distance_m)
    if conflicts.size:  # the model runs directly (otherwise the local search checks its own memory)
        check_setcover_memory(bits, w, free_cols, conflicts, o.engine)
    else:
        from camplace.solver.engines.setcover.reduce_bits import setcover_bits_bytes

        note_memory("setcover", setcover_bits_bytes(m, n))
    ctx = setcover(bits, w, o.costs, o.required_fraction, fixed_t, free_cols, conflicts, o.engine, deadline,
                   o.search_seed, o.iterations)
    ctx.stats["matrix"] = ("column bitsets (the rows to cover as row bitsets)" if not conflicts.size else
                           "column bitsets (the rows to cover as a bool CSR for the model)")
    return ctx, w, fixed_t, forbidden_t, conflicts

def _sides_bits_applies(o: SolveOptions) -> bool:
    """Fixed or forbidden cameras that :func:`_sides_bits` takes on the bits: max coverage (and
    quality, the same objective on a binary matrix) and multiview with a minimum angle, with fixed
    and / or forbidden cameras; multiview without the angle with forbidden ones only; never with a
    minimum distance or a team.

    Multiview with fixed cameras and no angle stays on the CSR route: a row then needs ``views``
    minus its fixed views, a threshold of its own, which the bitset engine (one ``views`` for every
    row) does not model (the CSR route gives it to the general model, which reads CSR rows anyway).
    The angle engine takes fixed cameras itself."""
    if o.team is not None or o.min_distance_m is not None or not (o.fixed or o.forbidden):
        return False
    if o.mode in ("maxcover", "quality"):
        return o.min_angle_deg is None
    return o.mode == "multiview" and (not o.fixed or o.min_angle_deg is not None)


def _sides_bits(bits: Any, weights: Any, o: SolveOptions, deadline: Deadline, positions: Any, points: Any) -> tuple | None:
    """Fixed and forbidden cameras on a binary matrix held as column bitsets, without a CSR copy:
    the bits route (:func:`camplace.solver.bits_route.bits_outcome`) on the allowed columns (neither
    fixed nor forbidden; :func:`_column_bits`), the rows the fixed cameras cover weighted 0 (max
    coverage: their weight is the constant ``fixed_value`` added to the bound, as the CSR route's
    :func:`~camplace.solver.routes.fixed_base` does), with the same ``k``. Multiview with a minimum
    angle and fixed cameras: the columns not forbidden, the fixed ones among them passed on to the
    angle engine (its bound counts them).

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n) observed pairs.
    weights : (m,) array_like of float64
    o : SolveOptions
        Checked options with :func:`_sides_bits_applies`.
    deadline : Deadline
    positions : (n, 3) array_like, optional
        Camera positions (metres; multiview with a minimum angle).
    points : (m, 3) array_like, optional
        Point positions (metres; the same).

    Returns
    -------
    (EngineOutcome, (m,) float64 weights, fixed, forbidden) or None
        ``selected`` holds the fixed and new cameras (original columns), ``objective`` is
        recomputed on the whole matrix (fixed cameras included) and ``bound`` is the reduced
        problem's plus ``fixed_value``. None when the bits route does not take the reduced problem
        (another engine choice, over the memory budget) or the allowed columns' bitsets do not fit:
        the caller converts the bits to CSR as before.
    """
    from camplace.solver.bits_route import bits_outcome
    from camplace.solver.problem.objectives import bits_views_value
    from camplace.solver.problem.presolve_bits import covered_weight

    m, n = bits.shape
    w, fixed_t, forbidden_t = _checked_columns(weights, o, m, n)
    free = np.ones(n, dtype=bool)
    free[list(set(fixed_t) | set(forbidden_t))] = False
    free_cols = np.flatnonzero(free)
    k = _checked_k(o, fixed_t, free_cols)
    multiview = o.mode == "multiview"
    full_pos = pts = None
    if o.min_angle_deg is not None:
        if positions is None or points is None:
            raise CamplaceError("min_angle_deg needs camera positions (positions (n, 3)) and point positions "
                                "(points (m, 3))")
        full_pos = coords(positions, n, "positions", "camera positions")
        pts = coords(points, m, "points", "point positions")

    def value(sel: tuple[int, ...]) -> float:  # the mode's objective on the whole matrix
        if multiview:
            return bits_views_value(bits, w, sel, int(o.views), o.min_angle_deg, full_pos, pts) if sel else 0.0
        return covered_weight(bits, w, sel)

    if k == 0:  # the fixed cameras alone (the CSR route's answer)
        fixed_value = value(fixed_t)
        return (EngineOutcome(tuple(fixed_t), "optimal", fixed_value, {"k": 0}, engine="exact", objective=fixed_value),
                w, fixed_t, forbidden_t)
    # multiview (the angle) keeps the fixed columns for the engine; max coverage weights their rows 0
    cols = np.union1d(free_cols, np.asarray(fixed_t, dtype=np.int64)) if multiview else free_cols
    try:
        sub = _column_bits(bits, cols, "the bitsets of the allowed columns")
    except OverBudget as exc:
        log.info("%s: the CSR route", exc.message)
        return None
    const = 0.0 if multiview else covered_weight(bits, w, fixed_t)  # the fixed cameras' covered weight
    resid_w = np.where(bits.union(fixed_t), 0.0, w) if fixed_t and not multiview else w
    local = replace(o, forbidden=(), fixed=tuple(int(j) for j in np.searchsorted(cols, fixed_t)) if multiview else ())
    copied = 0 if np.shares_memory(sub.words, bits.words) else sub.words.nbytes
    with holding(copied + resid_w.nbytes):  # the allowed columns' copy, held while the route runs on it
        got = bits_outcome(sub, resid_w, local, deadline, None if full_pos is None else full_pos[cols], pts)
    if got is None:
        return None
    ctx = got[0]
    sel = None if ctx.selected is None else tuple(sorted(set(fixed_t) | {int(cols[j]) for j in ctx.selected}))
    objective = const if sel is None else value(sel)
    ctx.stats["matrix"] = f"column bitsets of the {cols.size} allowed columns (no CSR copy)"
    return (EngineOutcome(sel, ctx.status, float(ctx.bound) + const, ctx.stats, engine=ctx.engine,
                          objective=objective), w, fixed_t, forbidden_t)


def _spaced_angle_applies(o: SolveOptions) -> bool:
    """Multiview with a minimum angle and a minimum distance under ``auto``, without a team:
    :func:`_spaced_angle_bits` may take it on the bits."""
    return (o.team is None and o.mode == "multiview" and o.min_angle_deg is not None and o.min_distance_m is not None
            and o.engine == "auto")


def _spaced_angle_bits(bits: Any, weights: Any, o: SolveOptions, deadline: Deadline, positions: Any,
                       points: Any) -> tuple | None:
    """Multiview with a minimum angle and a minimum distance on a binary matrix held as column
    bitsets, without a CSR copy, where the general model would not fit:
    :func:`~camplace.solver.engines.angle.spaced.solve_spaced_angle` (the angle engine on the
    problem without the spacing, whose bound holds for it; then spaced answers with exact angles),
    reading the bits, valued on them (:func:`~camplace.solver.problem.objectives.bits_views_value`).

    Returns
    -------
    (EngineOutcome, (m,) float64 weights, fixed, forbidden, conflicts (p, 2) int64) or None
        None where the CSR route decides as before: the general model may fit in the memory budget
        (its size without the angle's pair rows under the budget: small instances, where SCIP
        proves the spaced optimum), too many conflicting pairs (its spaced fallback), or the angle
        engine does not fit.
    """
    from camplace.solver.engines.angle.spaced import solve_spaced_angle
    from camplace.solver.problem.objectives import bits_views_value

    m, n = bits.shape
    w, fixed_t, forbidden_t = _checked_columns(weights, o, m, n)
    if positions is None or points is None:
        raise CamplaceError("min_angle_deg needs camera positions (positions (n, 3)) and point positions (points (m, 3))")
    pos = coords(positions, n, "positions", "camera positions")
    pts = coords(points, m, "points", "point positions")
    conflicts, too_many = _conflicts(pos, o)
    if too_many is not None:
        return None
    free_cols, conflicts = _free_columns(n, fixed_t, forbidden_t, conflicts, o.min_distance_m)
    k = _checked_k(o, fixed_t, free_cols)
    if k == 0:
        return None
    model = _angle_model_bytes(bits, w, o, pos, pts, fixed_t, free_cols, conflicts)
    if model <= memory_budget_bytes():
        return None  # it may fit: the CSR route builds and checks it
    views = int(o.views)

    def value(sel: tuple[int, ...]) -> float:
        return bits_views_value(bits, w, sel, views, o.min_angle_deg, pos, pts) if sel else 0.0

    try:
        got = solve_spaced_angle(bits, w, k, views, float(o.min_angle_deg), pos, pts, fixed_t, free_cols, conflicts,
                                 value, deadline, memory_budget_bytes())
    except OverBudget as exc:
        log.info("%s: the CSR route", exc.message)
        return None
    if got is None:
        return None
    stats = {"k": k, "engine_choice": {"engine": "exact", "route": "angle",
                                       "reason": "auto: a minimum angle and a minimum distance, the general model "
                                                 "over the memory budget: the angle engine without the spacing (a "
                                                 "valid bound), then spaced answers"},
             "matrix": "column bitsets (no CSR copy)", "model_estimate": {"bytes": model},
             "engine_stats": got.stats.pop("engine_stats"), "spacing_relaxed": got.stats}
    ctx = EngineOutcome(got.selected, got.status, got.bound, stats, engine="exact", objective=got.objective)
    return ctx, w, fixed_t, forbidden_t, conflicts


#: :func:`_angle_model_bytes` counts the angle's rows on at most this many sampled points.
_MODEL_SAMPLE_ROWS = 2048


def _angle_model_bytes(bits: Any, w: np.ndarray, o: SolveOptions, pos: np.ndarray, pts: np.ndarray,
                       fixed_t: tuple[int, ...], free_cols: np.ndarray, conflicts: np.ndarray) -> int:
    """Estimated bytes of the general model of multiview with a minimum angle on a BitMatrix, without
    its CSR: :func:`~camplace.solver.engines.mip.mode_models.model_size` (a row for every pair of
    a point's observers that may make the angle) counted exactly on up to
    :data:`_MODEL_SAMPLE_ROWS` of the points that can count (weight > 0, at least ``views``
    allowed observers), drawn with a fixed seed and read as a bool CSR of those rows only, and
    scaled to all of them; the cameras' and the spacing's parts counted whole. Like the CSR
    route's count, it stops once the model could not fit in the memory budget (then a lower
    bound, over the budget)."""
    from camplace.solver.engines.mip.linear import model_bytes
    from camplace.solver.engines.mip.mode_models import model_size
    from camplace.solver.problem.presolve_bits import row_counts_of
    from camplace.visibility.bits import take_rows

    allowed = np.union1d(free_cols, np.asarray(fixed_t, dtype=np.int64))
    live = np.flatnonzero((w > 0) & (row_counts_of(bits, allowed) >= int(o.views)))
    if live.size == 0:
        return 0
    take = min(live.size, _MODEL_SAMPLE_ROWS)
    rows = live if take == live.size else np.sort(np.random.default_rng(0).choice(live, size=take, replace=False))
    sub = take_rows(bits, rows).tocsr(np.bool_)
    scale = live.size / rows.size
    # (the count stops, as the CSR route's, once the scaled model could not fit in the budget anyway)
    got = model_size(sub, sub, w[rows], w[rows], "multiview", int(o.views), o.min_angle_deg, pos, pts[rows], fixed_t,
                     free_cols, conflicts, int(memory_budget_bytes() / scale) + 1)
    n_conf = int(conflicts.shape[0])
    base = (free_cols.size + len(fixed_t), 1 + n_conf, free_cols.size + 2 * n_conf)  # the cameras and the spacing
    return model_bytes("mip", *(int(b + (g - b) * scale) for b, g in zip(base, got, strict=True)))


def _checked_k(o: SolveOptions, fixed_t: tuple[int, ...], free_cols: np.ndarray) -> int:
    """``o.k`` checked for a k-camera mode: an integer, at least 1 (0 with fixed cameras), at most
    the allowed candidates; a one-line error otherwise."""
    k = o.k
    if k is None or isinstance(k, bool) or not isinstance(k, numbers.Integral):
        raise CamplaceError(f"k must be an integer number of cameras for mode {o.mode!r}, got {k!r}")
    k = int(k)
    if k < (0 if fixed_t else 1):
        raise CamplaceError(f"k must be at least {0 if fixed_t else 1}, got {k}")
    if k > free_cols.size:
        raise CamplaceError(f"cannot choose k={k} new cameras from {free_cols.size} allowed candidates "
                            "(lower k, or forbid/fix fewer cameras)")
    return k


def _rows_presolve_applies(o: SolveOptions) -> bool:
    """The k-camera modes on a binary matrix that the bits routes left to CSR (a minimum distance,
    engine mip / cpsat where the bits route does not run it, multiview with fixed cameras and no
    angle, k > 8, a memory fallback): :func:`_rows_presolved` gives them the merged rows. Not with a
    minimum angle (rows with the same pattern are different points, whose views make different
    angles), not for a team or set cover (they count points)."""
    return o.mode in ("maxcover", "quality", "multiview") and o.min_angle_deg is None and o.team is None


def _rows_presolved(bits: Any, weights: Any, positions: Any, o: SolveOptions, deadline: Deadline) -> SolverResult | None:
    """:func:`_solve` on the CSR of a binary matrix's rows presolved from its bits, instead of the
    whole matrix's CSR: dead rows (weight 0, or no camera observes them) dropped and identical rows
    merged, their weights summed (:func:`~camplace.solver.problem.presolve_bits.presolve_bits`
    without column dominance, which a minimum distance, fixed cameras or several views would not
    keep valid). Every column stays, so fixed, forbidden and spaced cameras are the same indices,
    and every set of cameras has the same value on the merged rows (a merged row is observed by
    the same cameras as each of its rows): the route, its optimum and its bounds are the whole
    matrix's. The objective is then recomputed on the bits (the CSR route's sum), and the status
    and gap made from it as :func:`_result` makes them.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n) observed pairs.
    weights : (m,) array_like of float64
    positions : (n, 3) array_like, optional
        Camera positions (metres; a minimum distance needs them).
    o : SolveOptions
        Checked options with :func:`_rows_presolve_applies`.
    deadline : Deadline
        The solve's; the presolve's time counts against its limit.

    Returns
    -------
    SolverResult or None
        None when the presolve's working memory or the merged rows' CSR would not fit in the memory
        budget, or no row is left: the caller converts the whole matrix as before.
    """
    from camplace.solver.problem.presolve_bits import presolve_bits, presolve_bits_bytes, reduced_csr, reduced_csr_bytes

    m, n = bits.shape
    w, fixed_t, forbidden_t = _checked_columns(weights, o, m, n)
    need, budget = presolve_bits_bytes(m, n), memory_budget_bytes()
    if need > budget:
        log.info("the rows' presolve on bits needs %.3g GiB (budget %.3g GiB): the whole matrix as CSR",
                 need / 2**30, budget / 2**30)
        return None
    pre = presolve_bits(bits, w, 1, dominance=False)  # k: only the dominance reads it
    assert pre.shape[1] == n  # no dominance: every column kept, in order
    if pre.shape[0] == 0:
        return None
    with holding(pre.bits.nbytes + pre.weights.nbytes):
        note_memory("rows CSR", reduced_csr_bytes(pre.shape[0], n, int(pre.nnz), 1))
        try:
            csr = reduced_csr(pre, np.bool_, what="the merged rows as CSR")
        except OverBudget as exc:
            note_memory("rows CSR", exc.need, refused=True)
            log.info("%s: the whole matrix as CSR", exc.message)
            return None
        with holding(matrix_bytes(csr)):  # the model notes its own bytes
            res = _solve(csr, pre.weights, positions, None, o, deadline)
        del csr
    res.stats.update({"matrix": f"column bitsets, rows presolved to {pre.shape[0]} x {n} (that as CSR)",
                      "rows_presolve": dict(pre.stats)})
    return _on_the_bits(res, bits, w, o, fixed_t, forbidden_t, deadline)


def _on_the_bits(res: SolverResult, bits: Any, w: np.ndarray, o: SolveOptions, fixed_t: tuple[int, ...],
                 forbidden_t: tuple[int, ...], deadline: Deadline) -> SolverResult:
    """The result ``res`` of a solve on merged rows (:func:`_rows_presolved`) as the whole matrix's:
    the objective of its cameras recomputed on the (m, n) ``bits`` with the checked weights ``w``
    (``mode_value``'s sum), the status, bound and gap made from it by :func:`_result`, the stats'
    sizes the whole matrix's."""
    from camplace.solver.bits_route import binary_value
    from camplace.solver.problem.objectives import bits_views_value

    def value(sel: tuple[int, ...]) -> float:  # the mode's objective on the whole matrix
        if o.mode == "multiview":
            return bits_views_value(bits, w, sel, int(o.views))
        return binary_value(bits, w, sel, o.mode)

    sel = res.selected if res.selected else None
    objective = value(sel) if sel else value(fixed_t) if fixed_t else res.objective
    conflicts = res.stats.get("conflict_pairs", 0)
    ctx = EngineOutcome(sel, res.status, res.bound, dict(res.stats), engine=res.engine, objective=objective)
    out = _result(ctx, o, w, fixed_t, forbidden_t, np.zeros((0, 2), dtype=np.int64), bits.shape, deadline.start)
    out.stats["conflict_pairs"] = conflicts  # (counted by the solve on the merged rows)
    return out


def _column_bits(bits: Any, cols: np.ndarray, what: str) -> Any:
    """The :class:`~camplace.visibility.bits.BitMatrix` of the columns ``cols`` ((c,) int64,
    sorted, distinct) of ``bits``: a view when they are one range, else a copy of
    ``c x ceil(m / 64) x 8`` bytes, checked against the memory budget first.

    Raises
    ------
    OverBudget
        The copy would not fit (``what`` names it).
    """
    from camplace.visibility.bits import BitMatrix

    m = bits.shape[0]
    if cols.size and cols[-1] - cols[0] + 1 == cols.size:
        return BitMatrix(bits.words[int(cols[0]):int(cols[-1]) + 1], m)  # one range: a view
    need, budget = cols.size * bits.words.shape[1] * 8, memory_budget_bytes()
    note_memory("columns", need, refused=need > budget)
    if need > budget:
        raise OverBudget(need, budget, what)
    return BitMatrix(bits.words[cols], m)


def _bits_columns_solve(bits: Any, w: np.ndarray, sub: SolveOptions) -> SolverResult:
    """:func:`_solve` of ``sub`` (no team) on the columns of ``bits`` it does not forbid: the
    bitsets of those columns (:func:`_column_bits`: a view or a copy checked against the memory
    budget), so that the bits route applies; ``selected`` mapped back to the columns of ``bits``."""
    m, n = bits.shape
    allowed = np.setdiff1d(np.arange(n, dtype=np.int64), np.asarray(sub.forbidden, dtype=np.int64))
    try:
        cols = _column_bits(bits, allowed, "the bitsets of one camera model's columns")
    except OverBudget as exc:
        memory_fallback(exc, None, asked=False, then=None, fix="use fewer candidates / points")
        raise  # memory_fallback raises when there is nothing to fall back to
    local = replace(sub, forbidden=(), fixed=tuple(int(j) for j in np.searchsorted(allowed, sub.fixed)))
    res = _solve(cols, w, None, None, local)
    return replace(res, selected=tuple(int(allowed[j]) for j in res.selected))


def _result(ctx: EngineOutcome, o: SolveOptions, w: np.ndarray, fixed_t: tuple[int, ...], forbidden_t: tuple[int, ...],
            conflicts: np.ndarray, shape: tuple[int, int], t0: float) -> SolverResult:
    """The :class:`SolverResult` of a mode's outcome: the status, bound and gap made consistent,
    and the run's figures added to the stats."""
    mode, engine = o.mode, o.engine
    m, n = shape
    fixed_set = set(fixed_t)
    selected, status, objective, bound, name, stats = (ctx.selected, ctx.status, ctx.objective, ctx.bound, ctx.engine,
                                                        ctx.stats)
    minimize = mode == "setcover"
    if status == "optimal":
        bound, gap = objective, 0.0
    elif selected is None:
        gap = math.inf
    elif minimize:
        bound = min(bound, objective)
        gap = max(0.0, (objective - bound) / max(abs(objective), 1e-12))
    else:
        bound = max(bound, objective)
        gap = relative_gap(bound, objective)
    scale = 1.0 if minimize else float(w.sum())
    if (selected is not None and status == "feasible" and math.isfinite(bound)
            and abs(bound - objective) <= _OPT_TOL * max(abs(bound), scale)):  # (no bound proves nothing)
        status, bound, gap = "optimal", objective, 0.0
    if selected is None and o.team is not None:  # no team meets the constraints (or none found in time)
        objective, gap = math.nan, math.inf
    sel = tuple(sorted(int(j) for j in (selected or ())))
    stats.update({"mode": mode, "engine_requested": engine, "fixed": list(fixed_t), "forbidden": list(forbidden_t),
                  "new": [j for j in sel if j not in fixed_set], "conflict_pairs": int(conflicts.shape[0]),
                  "rows_in": int(m), "cols_in": int(n)})
    elapsed = time.perf_counter() - t0
    log.info("%s engine=%s: %s objective %.9g bound %.9g gap %.3g in %.3f s", mode, name, status, objective, bound, gap, elapsed)
    return SolverResult(
        selected=sel, status=status, objective=float(objective), bound=float(bound), gap=float(gap),
        engine=name, time_s=elapsed, stats=jsonable(stats),
    )


def _spaced_fallback(
    q: sp.csr_matrix, w: np.ndarray, k: Any, mode: str, views: int, min_angle_deg: float | None, pos: np.ndarray,
    points: np.ndarray | None, fixed: Sequence[int], forbidden: Sequence[int], dmin: float, engine: str,
    msg: str, deadline: Deadline,
) -> SolverResult:
    """Too many conflicting pairs to list: the greedy answer (spacing checked with a k-d tree) and the
    cheap bound, which ignores the spacing and so stays valid."""
    m, n = q.shape
    if k is None or isinstance(k, bool) or not isinstance(k, numbers.Integral) or int(k) < 0:
        raise CamplaceError(f"k must be an integer number of cameras for mode {mode!r}, got {k!r}")
    k = int(k)
    fixed_t = index_set(fixed, n, "fixed")
    banned = set(index_set(forbidden, n, "forbidden"))
    near = NearCandidates(pos, dmin)
    for f in fixed_t:
        for b in near[f]:
            if b in fixed_t:
                raise CamplaceError(f"fixed cameras {f} and {b} are closer than min_distance_m={dmin}")
            banned.add(b)
    free = np.ones(n, dtype=bool)
    free[list(set(fixed_t) | banned)] = False
    free_cols = np.flatnonzero(free)
    if k > free_cols.size:
        raise CamplaceError(f"cannot choose k={k} new cameras from {free_cols.size} allowed candidates "
                            "(lower k, or forbid/fix fewer cameras)")
    pts = points
    qf = q[:, free_cols].tocsr()
    base, gw = fixed_base(q, w, fixed_t, mode)
    log.warning("%s", msg)  # memory_fallback's message
    local = greedy(qf.tocsc(), gw, mode, views, base, k, np.ones(free_cols.size, dtype=bool),
                    NearCandidates(pos[free_cols], dmin)) if k else ()
    sel = None if local is None else tuple(sorted(set(fixed_t) | {int(free_cols[j]) for j in local}))
    bound = cheap_bound(q, qf, w, base, k, mode, views)
    objective = mode_value(q, w, sel, mode=mode, views=views, min_angle_deg=min_angle_deg, positions=pos,
                           points=pts) if sel else 0.0
    status = "feasible" if sel is not None else "unknown"
    gap = relative_gap(max(bound, objective), objective) if sel is not None else math.inf
    stats = {"memory_fallback": msg, "mode": mode, "engine_requested": engine, "fixed": list(fixed_t),
             "forbidden": list(index_set(forbidden, n, "forbidden")), "new": [j for j in (sel or ()) if j not in fixed_t],
             "rows_in": int(m), "cols_in": int(n), "k": k}
    return SolverResult(selected=tuple(sel or ()), status=status, objective=float(objective),
                        bound=float(max(bound, objective)), gap=float(gap), engine="mip",
                        time_s=deadline.elapsed(), stats=jsonable(stats))


def solve_maxcover(
    matrix: Any,
    weights: Any,
    k: int,
    *,
    engine: str = "auto",
    time_limit_s: float | None = None,
) -> SolverResult:
    """Choose exactly ``k`` columns maximising the weight of the covered rows.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Visibility / observation quality; any value > 0 means "the candidate observes the point".
    weights : (m,) array_like of float64
        Non-negative point weights.
    k : int
        Number of cameras to choose, ``1 <= k <= n``.
    engine : {"auto", "exact", "mip", "cpsat"}
        ``auto`` is :func:`camplace.solver.choose.choose_engine`'s choice: ``exact`` for
        ``k <= 4``, the large-k engines for ``4 < k <= 8`` and ``mip`` otherwise (and wherever
        an exact engine would not fit in memory).
    time_limit_s : float, optional
        Wall-clock limit for the whole solve (presolve included). When it expires the best
        solution found is returned with status ``"feasible"`` and a valid bound.

    Returns
    -------
    SolverResult
        ``selected`` are sorted original column indices; ``objective`` is recomputed in float64 on
        the original matrix.

    Raises
    ------
    CamplaceError
        For ``k < 1``, ``k > n``, an unknown engine, a non-positive time limit, or malformed input.
    """
    return solve(matrix, weights, k, mode="maxcover", engine=engine, time_limit_s=time_limit_s)
