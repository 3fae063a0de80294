"""Max coverage and multiview straight from column bitsets: the binary run's matrix as the
visibility stage made it (:class:`camplace.visibility.bits.BitMatrix`, one bit a cell), without a
CSR copy.

:func:`bits_outcome` takes the cases without fixed, forbidden, minimum-distance or team
constraints, on the routes of :func:`~camplace.solver.choose.choose_engine` that read bits
(forbidden cameras, and fixed ones in max coverage, come here as the allowed columns' bitsets
with the fixed-covered rows weighted 0; fixed ones in multiview with a minimum angle as
``o.fixed`` among the columns, for the angle engine, its warm start and its cap:
``camplace.solver.api._sides_bits``):

``maxcover`` (and ``quality``, the same objective on a binary matrix)
    plain max coverage (``exact`` for k <= 4 under ``auto``): the presolve of
    :func:`~camplace.solver.problem.presolve_bits.presolve_bits` (the same reduced instance as the
    CSR presolve), then the same max-coverage engines.
``large-k`` (4 < k <= 8: maxcover, quality, multiview without fixed cameras or angle)
    :func:`_large_k`: the bit presolve (column dominance for max coverage only), then the large-k
    engines (:func:`~camplace.solver.engines.large_k.search.run_large_k`) on the reduced instance:
    its column lists (:func:`~camplace.solver.problem.presolve_bits.reduced_pattern`, checked
    against the budget) for the local searches, its bitsets for the bitset engine
    (``stats["matrix"]``: ``column bitsets, presolved to m' x n' (their column lists)``); a CSR
    only of the reduced instance, and only for a SCIP model that fits, never the whole matrix's.
    Every k-set of the kept columns has the same value there, so the optimum and the bounds are
    the matrix's; a search stopped by the time limit may stop at another set than the CSR route's.
``multiview``
    the ``multiview`` route (the bitset engine, ``exact`` for k <= 4): the bit presolve without
    column dominance (dropping dead rows and merging identical ones keeps every column's view
    counts; dominance keeps only coverage), :func:`~camplace.solver.engines.bitset.search.solve_bitset`
    with ``views`` (its opposite-pairs layout transposed from the bits,
    :func:`~camplace.solver.problem.presolve_bits.layout_bits`), and, for fewer cameras than
    ``2 * views``, an unproven bound capped by the opposite pairs matched on the bits
    (:func:`~camplace.solver.engines.bitset.pair_cap.cap_bound`), as the CSR route does.
``multiview`` with ``min_angle_deg``
    the ``angle`` route (``exact`` for k <= 4):
    :func:`~camplace.solver.engines.angle.search.solve_angle` on the BitMatrix (its row passes read
    the bits, its gains summed in the CSR kernel's order), and the same cap. No float32 copy is
    made either (the CSR route makes one: 4 bytes a pair more).

The objective is summed as :func:`~camplace.solver.problem.objectives.mode_value` sums it
(:func:`~camplace.solver.problem.presolve_bits.covered_weight`,
:func:`~camplace.solver.problem.objectives.bits_views_value`), so without a time limit the answer
is the CSR route's (quality of a binary matrix: :func:`binary_value`, summed as ``mode_value``
sums quality). With a time limit, multiview (with or without the angle) is warm-started as
the CSR route warm-starts it (:func:`_warm_started`: the same subset of the columns solved first,
its bitsets copied); plain max coverage on bits is not (the engines' own greedy gives its first
incumbent, as before). Any other case
(another engine choice, an engine over the memory budget) returns None. Then, for maxcover,
quality and multiview without a minimum angle or a team (a minimum distance, the general model
asked for or chosen, multiview with fixed cameras and no angle, whose rows' thresholds are
``views`` less their fixed views, which the bitset engine does not model),
:func:`camplace.solver.api._rows_presolved` makes the CSR of the bit presolve's rows only (dead
rows dropped, identical rows merged, every column kept: no dominance) and solves that on the CSR
route, the objective recomputed on the bits (``stats["matrix"]``: ``column bitsets, rows
presolved to m' x n (that as CSR)``). Only what is left (a minimum angle on the general model, a
team off its bits route, that presolve or its CSR over the budget) has
:func:`camplace.solver.api.solve` convert the whole bits to a bool CSR pattern (5 bytes an
observed pair) as before. Set cover on bits is
:func:`camplace.solver.engines.setcover.mode.setcover`'s own (``api._setcover_bits``). The planner
(``camplace plan`` on a binary run) hands its per-phase and static solves the phase row blocks as
bitsets (:func:`camplace.visibility.bits.take_rows`), so they come here too.
"""

from __future__ import annotations

import logging
import math
import numbers
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from camplace.errors import CamplaceError
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget, holding, memory_budget_bytes, note_memory
from camplace.solver.choose import choose_engine, problem_sizes
from camplace.solver.engines.angle.search import angle_bytes, solve_angle
from camplace.solver.engines.bitset.pair_cap import cap_applies, cap_bound, cap_deadline
from camplace.solver.engines.bitset.search import bitset_bytes, solve_bitset
from camplace.solver.engines.large_k.search import run_large_k
from camplace.solver.engines.maxcover import run_maxcover_engine
from camplace.solver.options import SolveOptions
from camplace.solver.problem.checks import coords
from camplace.solver.problem.objectives import bits_views_value
from camplace.solver.problem.presolve import check_weights
from camplace.solver.problem.presolve_bits import covered_weight, presolve_bits, reduced_pattern
from camplace.solver.result import EngineOutcome
from camplace.solver.routes import WARM_MAX_K, WARM_MIN_COLS, WARM_SHRINK, keep_warm, spread_subset, warm_share
from camplace.visibility.bits import BitMatrix, column_sums

__all__ = ["bits_applies", "bits_outcome", "binary_value", "large_k_reduced_bytes", "load_kernels",
           "multiview_engine_bytes", "outcome_bytes"]

log = logging.getLogger(__name__)


def outcome_bytes(m: int, n: int, o: SolveOptions, nnz: int = 0) -> int | None:
    """Working bytes of :func:`bits_outcome` for the options ``o`` on an (m, n) matrix of ``nnz``
    observed pairs held as column bitsets (``B = n x ceil(m / 64) x 8`` bytes), besides the bitsets,
    as far as they can be known before the matrix exists: the estimate the visibility stage's guard
    adds for the solve (through :func:`camplace.solver.api.bits_solve_bytes`).

    The guard is checked in stages, each allocation against an estimate made with what is known
    just before it. This is the first: what runs on the whole matrix. The engines that run on the
    presolved instance are not counted here: its size (rows merged, dominated columns dropped; at
    10,000 x 50,000 on comet-67p-bunker about a quarter of the pairs) is known only after the
    presolve, and the visibility pilot's sample does not predict it (the merges and the dominance
    are between whole rows and columns). They estimate their bytes on the reduced sizes before
    allocating, check them against the budget (falling back or stopping with a one-line message)
    and note them (:func:`~camplace.solver._support.memory.note_memory`; the solve's
    ``stats["memory_estimates"]``): :func:`large_k_reduced_bytes`, :func:`multiview_engine_bytes`,
    the exact max-coverage engine's bitsets, a max-coverage model.

    * max coverage (and quality of a binary matrix), any k and engine; multiview without a minimum
      angle: the bit presolve
      (:func:`~camplace.solver.problem.presolve_bits.presolve_bits_bytes`, about ``2.25 R`` with
      ``R = m x ceil(n / 64) x 8``). Multiview with ``k < 2 views`` (k <= 4) also matches opposite
      points and builds the opposite-pairs layout on the original rows, whose size the matching
      decides (one layout row a point on comet-67p-bunker, up to two in general): both are
      optional (the engine skips them when they would not fit and searches the plain layout, a
      valid and looser bound) and check and note their bytes once known
      (:func:`~camplace.solver.engines.bitset.pair_cap.match_opposite`, the engine's layout);
    * multiview with a minimum angle: the angle engine runs on every row and column (no presolve):
      :func:`~camplace.solver.engines.angle.search.angle_bytes` of them (fixed ones: ``o.fixed``),
      with the engine's least number of open tuples (it opens more only as far as its memory budget
      allows) on the plain layout, one bit row a row: the engine's first check, with every row for
      its countable ones. Its opposite-pairs layout (up to two bit rows a row) is checked and
      noted by the engine once the points are matched (the plain layout when it does not fit).

    Returns
    -------
    int or None
        Bytes; None where :func:`bits_outcome` leaves the solve to another route (the engine choice
        is the general model): the caller counts that route.
    """
    from camplace.solver.choose import ProblemSizes
    from camplace.solver.problem.presolve_bits import presolve_bits_bytes

    k, views, fixed = int(o.k), int(o.views), len(o.fixed)
    presolve = presolve_bits_bytes(m, n)
    views_mode = o.mode == "multiview"
    sizes = ProblemSizes(k=k, points=int(m), free=int(n) - fixed, nnz=int(nnz), fixed=fixed, conflicts=0)
    choice = choose_engine(sizes, o if views_mode else replace(o, mode="maxcover"), 1 << 62)
    if choice.route == "large-k" and not fixed:
        return presolve
    if choice.route == "angle" and o.min_angle_deg is not None:
        return angle_bytes(m, n - fixed, fixed, k, views, layout_rows=m)  # the plain layout: one bit row a row
    if choice.route == ("multiview" if views_mode else "maxcover"):
        return presolve
    return None


def large_k_reduced_bytes(m: int, n: int, nnz: int, k: int, levels: int = 0) -> int:
    """Bytes :func:`_large_k` allocates after the bit presolve, on its reduced (m, n) instance of
    ``nnz`` pairs (the sizes the presolve left, known then): the column lists
    (:func:`~camplace.solver.problem.presolve_bits.reduced_pattern_bytes`), the large-k engines'
    working memory on them (:func:`~camplace.solver.engines.large_k.search.large_k_bytes` with the
    pattern) and, for multiview (``levels`` > 0), the bitset engine's ``levels`` level bitsets
    (:func:`~camplace.solver.engines.bitset.search.bitset_bytes` without its open tuples). The
    reduced bitsets themselves are held by then (not counted here)."""
    from camplace.solver.engines.large_k.search import large_k_bytes
    from camplace.solver.problem.presolve_bits import reduced_pattern_bytes

    engine = large_k_bytes(m, n, nnz, pattern=True)
    if levels:
        engine += bitset_bytes(m, n, levels, k, tuples=False)
    return int(reduced_pattern_bytes(n, nnz) + engine)


def multiview_engine_bytes(m: int, n: int, views: int, k: int) -> int:
    """Bytes the multiview bitset engine allocates up front on a presolved (m, n) instance: its
    bitsets (:func:`~camplace.solver.engines.bitset.search.bitset_bytes` with ``min(views, k)``
    levels); not the open tuples, which grow with the search up to a fixed cap that the engine's
    own budget check counts. For ``1 < views`` and ``k < 2 views`` the engine may search the
    opposite-pairs layout instead, on the original rows: its size is known once the points are
    matched, and the engine checks and notes it then
    (:func:`~camplace.solver.engines.bitset.search.pairs_layout_bytes` is its bound before)."""
    return bitset_bytes(m, n, min(int(views), int(k)), k, tuples=False)


def _presolved_bytes(pre) -> int:
    """Bytes of a bit presolve's reduced instance held while the engines run: its column bitsets
    and weights."""
    return int(pre.bits.nbytes + pre.weights.nbytes)


def bits_applies(o: SolveOptions) -> bool:
    """True for plain max coverage or multiview (with or without a minimum angle), without fixed,
    forbidden, distance or team constraints (a minimum angle in multiview only).

    ``quality`` on a binary matrix is plain max coverage too: every value is 1, so
    ``max_{j in S} Q_ij`` is 1 exactly when some chosen camera observes row i, and the two
    objectives are the same number."""
    return (o.mode in ("maxcover", "quality", "multiview") and not o.fixed and not o.forbidden
            and o.min_distance_m is None and (o.min_angle_deg is None or o.mode == "multiview")
            and getattr(o, "team", None) is None)


def bits_outcome(bits, weights: Any, o: SolveOptions, deadline: Deadline, positions: Any = None, points: Any = None):
    """Solve plain max coverage or multiview on column bitsets.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n) observed pairs.
    weights : (m,) array_like of float64
    o : SolveOptions
        Checked options with :func:`bits_applies`.
    deadline : Deadline
    positions : (n, 3) array_like, optional
        Camera positions (metres; multiview with a minimum angle needs them).
    points : (m, 3) array_like, optional
        Point positions (metres; the same).

    Returns
    -------
    (EngineOutcome, (m,) float64 weights) or None
        None when the engine choice is not one this route runs (the general model) or the engine
        (or the large-k engines' column lists) would not fit in the memory budget.
    """
    m, n = bits.shape
    if n == 0:
        raise CamplaceError("the visibility matrix has no candidate columns")
    w = check_weights(weights, m)
    k = o.k
    if k is None or isinstance(k, bool) or not isinstance(k, numbers.Integral):
        raise CamplaceError(f"k must be an integer number of cameras for mode {o.mode!r}, got {k!r}")
    k = int(k)
    if k < 1:
        raise CamplaceError(f"k must be at least 1, got {k}")
    fixed = tuple(int(j) for j in o.fixed)
    if fixed and not (o.mode == "multiview" and o.min_angle_deg is not None):
        raise CamplaceError("bits route: fixed cameras only with a minimum angle (the caller weights the rest)")
    if k > n - len(fixed):
        raise CamplaceError(f"cannot choose k={k} new cameras from {n - len(fixed)} allowed candidates "
                            "(lower k, or forbid/fix fewer cameras)")
    if o.mode == "multiview":
        pos = pts = None
        if o.min_angle_deg is not None:
            if positions is None or points is None:
                raise CamplaceError("min_angle_deg needs camera positions (positions (n, 3)) and point positions "
                                    "(points (m, 3))")
            pos = coords(positions, n, "positions", "camera positions")
            pts = coords(points, m, "points", "point positions")
        got = _multiview(_Views(bits, w, k, o, pos, pts, fixed), deadline)
    else:
        got = _maxcover(bits, w, k, o, deadline)
    return None if got is None else (got, w)


def _maxcover(bits, w: np.ndarray, k: int, o: SolveOptions, deadline: Deadline) -> EngineOutcome | None:
    """Plain max coverage of ``k`` columns (quality solved as maxcover); None off the maxcover route."""
    n = bits.shape[1]
    budget = memory_budget_bytes()
    asked = o.mode
    o = replace(o, mode="maxcover")  # quality of a binary matrix: the same objective (see bits_applies)
    choice = choose_engine(problem_sizes(bits, k, n, 0, 0, "maxcover"), o, budget)
    if choice.route not in ("maxcover", "large-k"):
        return None
    stats = _choice_stats(k, choice)
    if asked != "maxcover":
        stats["binary_matrix"] = f"{asked} of a binary matrix (every value 1) is max coverage: solved as maxcover"
    if choice.route == "large-k":
        got = _large_k(bits, w, k, o, stats, deadline)
        return None if got is None else replace(got, objective=binary_value(bits, w, got.selected, asked))
    pre = presolve_bits(bits, w, k, deadline=deadline.share(0.5))  # at least half the time left to the search
    with holding(_presolved_bytes(pre)):  # the engine checks (and notes) its bytes on the kept columns
        name, out = run_maxcover_engine(choice.engine, o.engine, pre, deadline, stats, budget)
    sel = tuple(sorted(int(j) for j in pre.original_columns(out.selected))) if out.selected else None
    objective = binary_value(bits, w, sel, asked) if sel else 0.0
    stats.update({"rows_after": pre.shape[0], "cols_after": pre.shape[1], "presolve": dict(pre.stats),
                  "engine_stats": dict(out.stats)})
    return EngineOutcome(sel, out.status if sel else "unknown", float(out.bound), stats, engine=name,
                         objective=objective)


def binary_value(bits, w: np.ndarray, sel: tuple[int, ...], mode: str) -> float:
    """The ``maxcover`` or ``quality`` objective of the columns ``sel`` of a binary matrix, the same
    float64 number as :func:`~camplace.solver.problem.objectives.mode_value` on its CSR: the covered
    weight summed (maxcover), or ``w`` dotted with the rows' best value, 1 or 0 (quality).

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n).
    w : (m,) float64
        Checked weights.
    sel : tuple of int
        Columns.
    mode : {"maxcover", "quality"}
    """
    if mode != "quality":
        return covered_weight(bits, w, sel)
    best = bits.union(list(sel)).astype(np.float64) if len(sel) else np.zeros(bits.shape[0])
    return float(w @ best)


@dataclass(frozen=True)
class _Views:
    """One multiview problem on bits: the matrix, the checked weights, k (new cameras), the
    options, with a minimum angle the checked camera (n, 3) and point (m, 3) positions, and the
    fixed cameras (columns of ``bits``; a minimum angle only: the angle engine takes them, the
    bitset engine does not)."""

    bits: Any
    w: np.ndarray
    k: int
    o: SolveOptions
    pos: np.ndarray | None
    pts: np.ndarray | None
    fixed: tuple[int, ...] = ()

    @property
    def angle(self) -> bool:
        return self.o.min_angle_deg is not None

    @property
    def free(self) -> np.ndarray:
        """(f,) int64: the columns the new cameras are chosen from (all but the fixed ones)."""
        return np.setdiff1d(np.arange(self.bits.shape[1], dtype=np.int64), np.asarray(self.fixed, dtype=np.int64))

    def columns(self, cols: np.ndarray) -> "_Views":
        """The same problem on the columns ``cols`` (sorted, the fixed ones among them; their
        bitsets copied)."""
        return replace(self, bits=BitMatrix(self.bits.words[cols], self.bits.shape[0]),
                       pos=None if self.pos is None else self.pos[cols],
                       fixed=tuple(int(j) for j in np.searchsorted(cols, np.asarray(self.fixed, dtype=np.int64))))

    def value(self, sel: tuple[int, ...] | None) -> float:
        """The objective of ``sel`` (:func:`~camplace.solver.problem.objectives.mode_value`'s number)."""
        if not sel:
            return 0.0
        return bits_views_value(self.bits, self.w, sel, int(self.o.views), self.o.min_angle_deg, self.pos, self.pts)


def _multiview(p: _Views, deadline: Deadline) -> EngineOutcome | None:
    """``k`` columns maximising the weight of rows observed by at least ``o.views`` of them (and,
    with a minimum angle, by two making it): the CSR route's :func:`camplace.solver.routes.run_cover`
    (the multiview or angle route, warm start included) and the opposite-pairs cap of
    :func:`camplace.solver.api.solve`, on the bits. None off those routes, or when the engine's
    working memory is over the budget (the CSR route then falls back as before)."""
    views = int(p.o.views)
    cameras = p.k + len(p.fixed)  # new and fixed, as the CSR route counts them
    cap = cap_applies(cameras, views)
    inner = cap_deadline(deadline) if cap else deadline  # leaves the cap its share of the limit
    got = _search(p, inner)
    if got is None:
        return None
    searched = got.stats.get("engine_stats", {}).get("search") == "opposite pairs"  # already bounded by them
    if cap and got.selected is not None and got.status != "optimal" and not searched and not deadline.expired():
        got = cap_bound(got, p.bits, p.w, views, cameras, None, deadline)  # every column: the free and the fixed
    return got


def _search(p: _Views, deadline: Deadline, warm: bool = True,
            start: tuple[int, ...] | None = None, rung: bool = False) -> EngineOutcome | None:
    """The route on ``p.bits``: with ``warm``, warm-started as :func:`camplace.solver.routes.run_cover`
    warm-starts it (more than ``WARM_MIN_COLS`` columns, k <= ``WARM_MAX_K``, a time limit); then
    the engine (:func:`_bitset` or :func:`_angle`), from ``start`` (k original columns) when given;
    ``rung``: a warm start's rung (the angle engine's ``rung``)."""
    n_free = p.bits.shape[1] - len(p.fixed)
    if warm and p.k <= WARM_MAX_K and n_free > WARM_MIN_COLS and deadline.limit is not None:
        return _warm_started(p, deadline, rung)
    choice = choose_engine(problem_sizes(p.bits, p.k, n_free, len(p.fixed), 0, "multiview"), p.o,
                           memory_budget_bytes())
    if choice.route == "large-k" and not p.fixed:  # (choose_engine: never with fixed cameras or the angle)
        got = _large_k(p.bits, p.w, p.k, p.o, _choice_stats(p.k, choice), deadline)
        return None if got is None else replace(got, objective=p.value(got.selected))
    if choice.route != ("angle" if p.angle else "multiview"):
        return None
    if p.angle:
        return _angle(p, choice, deadline, start, rung)
    return _bitset(p, choice, deadline, start)


def _large_k(bits, w: np.ndarray, k: int, o: SolveOptions, stats: dict[str, Any],
             deadline: Deadline) -> EngineOutcome | None:
    """The engines for ``4 < k <= 8`` (:func:`~camplace.solver.engines.large_k.search.run_large_k`,
    as :func:`camplace.solver.routes._large_k` runs them) on the bit presolve's reduced instance:
    dead rows dropped, identical rows merged (their weights summed) and, for max coverage, dominated
    columns dropped (not for multiview: dominance keeps only coverage); the reduced instance made
    into the column lists the engines' local searches read
    (:func:`~camplace.solver.problem.presolve_bits.reduced_pattern`, checked against the memory
    budget); the bitset engine and SCIP take the presolved instance itself (its bitsets; SCIP's
    model makes its CSR when the model fits), never the whole matrix's CSR.

    Every k-set of the kept columns has the same value on the reduced instance as on the matrix,
    and the dropped columns leave an optimum among the kept ones, so the engines' optimum and
    bounds are the matrix's.

    Parameters
    ----------
    bits : camplace.visibility.bits.BitMatrix
        (m, n) observed pairs.
    w : (m,) float64
        Checked weights.
    k : int
        New cameras, ``4 < k <= 8``.
    o : SolveOptions
        ``mode`` maxcover (quality of a binary matrix comes as maxcover) or multiview, ``views``,
        ``engine``.
    stats : dict
        The result's stats (:func:`_choice_stats`), filled by the engines.
    deadline : Deadline

    Returns
    -------
    EngineOutcome or None
        ``selected`` original columns; ``objective`` the covered weight (multiview: the caller's
        :meth:`_Views.value`). None when the column lists or the engines do not fit in the memory
        budget under ``auto`` (the CSR route then falls back as before).
    """
    views = o.mode == "multiview"
    # max coverage: at most half of the time to the dominance, as on the k <= 4 route
    pre = presolve_bits(bits, w, k, dominance=not views, deadline=deadline if views else deadline.share(0.5))
    with holding(_presolved_bytes(pre)):
        return _large_k_presolved(bits, w, k, o, stats, deadline, pre)


def _large_k_presolved(bits, w: np.ndarray, k: int, o: SolveOptions, stats: dict[str, Any], deadline: Deadline,
                       pre) -> EngineOutcome | None:
    """:func:`_large_k` after the bit presolve ``pre``: the reduced instance's column lists and the
    engines on them, their bytes on the reduced sizes noted first (``"large-k"``:
    :func:`large_k_reduced_bytes`)."""
    views = o.mode == "multiview"
    note_memory("large-k", large_k_reduced_bytes(pre.shape[0], pre.shape[1], int(pre.nnz), k,
                                                 min(int(o.views), k) if views else 0))
    try:  # the column lists the local searches read (8 bytes a pair), instead of their CSR copies
        pattern = reduced_pattern(pre, what="the presolved instance's column lists (the large-k engines)")
    except OverBudget as exc:
        log.info("large k on bits: %s: the CSR route", exc.message)
        return None
    mode, n_views = ("multiview", int(o.views)) if views else ("maxcover", 1)
    stats["matrix"] = f"column bitsets, presolved to {pre.shape[0]} x {pre.shape[1]} (their column lists)"
    stats["presolve"] = dict(pre.stats)
    # the bitset engine and SCIP take the presolved instance itself (SCIP makes its CSR, when its model fits)
    got = run_large_k(BitMatrix(pre.bits, pre.shape[0]), pre.weights, k, mode, n_views, o.engine, deadline, stats,
                      pattern=pattern, presolved=pre)
    if got is None:
        return None
    sel = pre.original_columns(got.selected)
    stats.update({"rows_after": pre.shape[0], "cols_after": pre.shape[1]})  # the bit presolve's
    objective = 0.0 if views else covered_weight(bits, w, sel)
    return EngineOutcome(sel, got.status, float(got.bound), stats, engine=got.engine, objective=objective)


def _bitset(p: _Views, choice, deadline: Deadline, start: tuple[int, ...] | None) -> EngineOutcome | None:
    """:func:`camplace.solver.routes._multiview` on bits: the bit presolve without dominance, then
    the bitset engine with ``views``; None when the engine's estimate is over the budget."""
    assert not p.fixed  # the bitset engine has one views for every row (choose_engine: the model)
    k, views, budget = p.k, int(p.o.views), memory_budget_bytes()
    stats = _choice_stats(k, choice)
    pre = presolve_bits(p.bits, p.w, k, dominance=False, deadline=deadline)  # dominance: one view only
    mp, np_ = pre.shape
    need = bitset_bytes(mp, np_, min(views, k), k)
    if need > budget:  # the CSR route makes the same estimate and falls back to the general model
        log.info("multiview on bits: the bitset engine needs %.3g GiB (budget %.3g GiB): the CSR route",
                 need / 2**30, budget / 2**30)
        return None
    with holding(_presolved_bytes(pre)):
        note_memory("bitset", multiview_engine_bytes(mp, np_, views, k))  # the pairs layout: noted by the engine
        out = solve_bitset(pre, views=views, deadline=deadline,
                           start=None if start is None else pre.reduced_columns(start))
    sel = tuple(int(j) for j in pre.original_columns(out.selected)) if out.selected else None
    stats.update({"rows_after": mp, "cols_after": np_, "presolve": dict(pre.stats), "engine_stats": dict(out.stats)})
    return EngineOutcome(sel, out.status if sel else "unknown", float(out.bound), stats, engine=choice.engine,
                         objective=p.value(sel))


def _angle(p: _Views, choice, deadline: Deadline, start: tuple[int, ...] | None,
           rung: bool = False) -> EngineOutcome | None:
    """:func:`camplace.solver.routes._angle` on bits: the angle engine reading the bitsets; None when
    it does not fit in the memory budget."""
    assert p.pos is not None and p.pts is not None and p.o.min_angle_deg is not None
    stats = _choice_stats(p.k, choice)
    # the engine notes its bytes itself: on its countable rows, then with its layout's rows
    try:
        out = solve_angle(p.bits, p.w, p.k, int(p.o.views), float(p.o.min_angle_deg), p.pos, p.pts,
                          np.asarray(p.fixed, dtype=np.int64), p.free, deadline=deadline,
                          budget_bytes=memory_budget_bytes(), start=start, rung=rung)
    except OverBudget as exc:
        note_memory("angle", exc.need, refused=True)
        log.info("multiview on bits: %s: the CSR route", exc.message)
        return None
    sel = tuple(sorted(set(p.fixed) | {int(j) for j in out.selected}))  # the engine's are the new cameras
    stats["engine_stats"] = dict(out.stats)
    return EngineOutcome(sel, out.status, float(out.bound), stats, engine="exact", objective=p.value(sel))


def _warm_started(p: _Views, deadline: Deadline, rung: bool = False) -> EngineOutcome | None:
    """:func:`camplace.solver.routes._warm_started` on bits: solve the columns
    :func:`camplace.solver.routes.warm_subset` picks first (with a minimum angle every pose of the
    first ``1 / WARM_SHRINK`` of the positions, else the ``1 / WARM_SHRINK`` observing the most weight, their
    weights summed in the CSR route's order) within :func:`camplace.solver.routes.warm_share` of
    the time left, offer its
    answer to the full search as the first incumbent and keep the better.

    The subset's bitsets are a copy (``columns x ceil(m / 64) x 8`` bytes, checked against the
    memory budget: over it, no warm start)."""
    k = p.k
    free = p.free
    sub_free = spread_subset(free, p.pos, WARM_SHRINK) if p.angle else np.zeros(0, dtype=np.int64)
    if sub_free.size < k:
        colw = column_sums(p.bits, p.w)[free]  # weights >= 0 (checked): the CSR route's ranking
        size = max(k, -(-free.size // WARM_SHRINK))
        sub_free = np.sort(free[np.lexsort((np.arange(free.size), -colw))[:size]])
    cols = np.union1d(sub_free, np.asarray(p.fixed, dtype=np.int64))  # the subset and the fixed cameras
    need, budget = cols.size * p.bits.words.shape[1] * 8, memory_budget_bytes()
    if need > budget:
        log.info("multiview on bits: no warm start (the subset's bitsets need %.3g GiB)", need / 2**30)
        return _search(p, deadline, warm=False, rung=rung)
    got = _search(p.columns(cols), deadline.share(warm_share(p.angle, rung)), rung=True)
    got_sel = None if got is None or got.selected is None else tuple(sorted(int(cols[j]) for j in got.selected))
    warm: dict[str, Any] = {}
    if got is not None:
        warm = {"columns": int(sub_free.size), "status": got.status, "objective": float(got.objective),
                "engine": got.engine, "time_s": deadline.elapsed()}
        if "warm_start" in got.stats:
            warm["inner"] = got.stats["warm_start"]
    start = None if got_sel is None else tuple(sorted(set(got_sel) - set(p.fixed)))  # its new cameras
    out = _search(p, deadline, warm=False, start=start, rung=rung)
    if out is None:
        return None
    if warm:
        out.stats["warm_start"] = warm
    return keep_warm(out, got_sel, got.objective if got is not None else -math.inf, warm)


def _choice_stats(k: int, choice) -> dict[str, Any]:
    """The result's first stats: ``k``, the engine choice and its own figures, and the layout."""
    stats: dict[str, Any] = {"k": k, "engine_choice": {"engine": choice.engine, "route": choice.route,
                                                       "reason": choice.reason},
                             "matrix": "column bitsets (no CSR copy)"}
    stats.update(choice.stats)
    return stats


#: :func:`load_kernels` solves a random instance of this many rows and columns (density 0.3,
#: k = 3): small enough to take about a millisecond once loaded, large enough that the presolve
#: and the bitset engine call every kernel the k <= 4 route calls (measured against the
#: kernels a 50,000 x 10,000 solve loads).
_LOAD_SHAPE = (200, 100)


def load_kernels(o: SolveOptions) -> bool:
    """Load the compiled kernels of plain max coverage on column bitsets (the bit presolve and the
    bitset engine) before the solve needs them, by solving a small seeded random instance.

    numba loads a kernel's machine code from its cache on the kernel's first call (about 0.03 s
    for the presolve's and as much for the engine's, one thread at a time): the pipeline calls
    this from the thread that waits while the visibility chunks are cast, so that the solve
    stage does not. It never changes a result.

    Parameters
    ----------
    o : SolveOptions
        The run's options: nothing is done unless they are plain max coverage on
        :func:`bits_applies`'s route with the exact engine (``auto`` or ``exact``, 1 <= k <= 4).

    Returns
    -------
    bool
        True when the kernels were called.
    """
    from camplace.visibility.bits import BitMatrix, bit_words

    k = o.k
    if (not bits_applies(o) or o.mode not in ("maxcover", "quality") or o.engine not in ("auto", "exact")
            or isinstance(k, bool)
            or not isinstance(k, numbers.Integral) or not 1 <= int(k) <= 4):
        return False
    from camplace.solver.engines.bitset.search import bind_search_kernel

    bind_search_kernel()  # first: the search calls its own copies of the helpers
    rng = np.random.default_rng(0)
    m, n = _LOAD_SHAPE
    cells = np.zeros((n, bit_words(m) * 64), dtype=bool)  # column bitsets, rows past m empty
    cells[:, :m] = rng.random((n, m)) < 0.3
    words = np.packbits(cells, axis=1, bitorder="little").view(np.uint64)  # no kernel of its own to load
    quiet = logging.getLogger("camplace.solver")  # the user's log shows their solve, not this one
    level = quiet.level
    quiet.setLevel(logging.WARNING)
    try:
        solve_bitset(presolve_bits(BitMatrix(words, m), rng.random(m), int(k)))
    finally:
        quiet.setLevel(level)
    return True
