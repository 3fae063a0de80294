"""A global upper bound for ``multiview`` from pairs of points no camera observes together.

Call two points *opposite* when no allowed candidate observes both (on a convex target seen from
outside, a point and its antipode). A camera system of ``N`` cameras gives at most ``N`` sightings
to an opposite pair, since each camera sees at most one of the two; counting both needs
``2 * views`` sightings. So when ``N < 2 * views`` (the stereo default: 3 cameras, 2 views) at most
one point of every opposite pair counts, whichever cameras are chosen.

With a fractional matching ``f`` of opposite pairs (``f_pq >= 0``, ``sum_q f_pq <= w_p``) this
gives, for every system ``S`` of ``N`` cameras with counted points ``c_p`` in {0, 1}::

    sum_p w_p c_p = sum_p (w_p - sum_q f_pq) c_p + sum_{pairs} f_pq (c_p + c_q)
                 <= total - sum_{pairs} f_pq

which is the bound returned (:func:`opposite_pair_bound`). It needs no search and ignores which
cameras are chosen, so it is never below half of the countable weight: on comet-67p-bunker with
every surface point counted (10,000 candidates x 50,000 points) it lowers the multiview m = 2
bound from 0.706 to 0.502 in about 1 s, where the optimum is 0.4719. The bitset engine uses the
same matching inside its cluster bounds (:meth:`OppositePairs.layout`), which is what proves that
optimum. A matching stopped early is still a valid certificate (a smaller ``sum f``), so the work
is cut at the deadline without losing validity.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from camplace._signals import ctrl_c_deferred
from camplace.solver._support import bitkernels as _bk
from camplace.solver._support import parkernels as _pk
from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import memory_budget_bytes, note_memory
from camplace.solver.problem.checks import kernel_data
from camplace.solver.problem.presolve import canonical_csr, check_weights
from camplace.solver.problem.presolve_bits import row_bitsets, row_counts_of

__all__ = ["OppositePairs", "match_opposite", "opposite_pair_bound", "opposite_pair_bytes", "cap_applies", "cap_deadline",
           "cap_bound"]

log = logging.getLogger(__name__)

_BATCH = 2048  # rows matched between two deadline checks
_CAP_SHARE = 0.05  # multiview: share of the time limit kept for the opposite-pairs bound ...
_CAP_MAX_S = 2.0  # ... at most this many seconds (a matching stopped early is still a valid bound)


def opposite_pair_bytes(m: int, n: int) -> int:
    """Working memory of :func:`opposite_pair_bound` on ``m`` countable rows and ``n`` columns."""
    return int(m) * (((int(n) + 63) // 64) * 8 + 8 * 4 + 1)


@dataclass(frozen=True)
class OppositePairs:
    """A fractional matching of opposite points (rows no allowed column observes together).

    Attributes
    ----------
    pairs : (P, 2) int64
        Matched rows (row indices of the matrix).
    amount : (P,) float64
        Weight moved by each match.
    rows : (r,) int64
        The countable rows (observed by at least ``views`` allowed columns, positive weight).
    residual : (r,) float64
        Weight of each countable row left unmatched.
    countable : float
        Weight of the countable rows.
    stats : dict
        ``rows``, ``checks``, ``complete``, ``time_s`` (and ``skipped`` when it did not run).
    """

    pairs: np.ndarray
    amount: np.ndarray
    rows: np.ndarray
    residual: np.ndarray
    countable: float
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def matched(self) -> float:
        """Matched weight (each pair once)."""
        return float(self.amount.sum())

    @property
    def bound(self) -> float:
        """``countable - matched``: at least the value of every allowed camera system."""
        return self.countable - self.matched

    def layout(self, unit: float | None = None) -> tuple[np.ndarray, np.ndarray, int]:
        """Rows and weights of the paired bitset layout of :func:`camplace.solver._support.bitkernels.shortfall`.

        Parameters
        ----------
        unit : float, optional
            Divide the weights by this (presolve's ``weight_unit``: integer weights).

        Returns
        -------
        rows : (128 pw + u,) int64
            Matrix row of each bit (-1: padding): first rows of the pairs, their partners at the
            same offset ``64 pw`` further on, then the rows with weight left unmatched.
        weights : float64, same shape
            A pair's weight on its first row, 0 on its partner, the leftover weight on the rest.
        pw : int
            Words of first rows.
        """
        n_pairs = self.pairs.shape[0]
        pw = (n_pairs + 63) // 64
        left = self.residual > 0
        out_rows = np.full(128 * pw + int(left.sum()), -1, dtype=np.int64)
        out_w = np.zeros(out_rows.size)
        out_rows[:n_pairs] = self.pairs[:, 0]
        out_rows[64 * pw : 64 * pw + n_pairs] = self.pairs[:, 1]
        out_w[:n_pairs] = self.amount
        out_rows[128 * pw :] = self.rows[left]
        out_w[128 * pw :] = self.residual[left]
        if unit is not None:
            out_w = np.round(out_w / unit)
        return out_rows, out_w, pw


def match_opposite(
    matrix: Any,
    weights: Any,
    views: int,
    columns: Sequence[int] | None = None,
    order_seed: int | None = None,
    deadline: Deadline | None = None,
) -> OppositePairs:
    """Match opposite points greedily (see the module docstring).

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Visibility (> 0 means observes), or a binary matrix as column bitsets
        (:class:`camplace.visibility.bits.BitMatrix`: its row bitsets are transposed from the
        columns, no CSR is made).
    weights : (m,) array_like of float64
        Non-negative point weights.
    views : int
        Sightings a point needs to count (rows with fewer allowed observers are left out).
    columns : sequence of int, optional
        The allowed cameras (default: every column).
    order_seed : int, optional
        Process the rows in a random order from this seed instead of heaviest first (better when
        many rows have different weights, e.g. merged rows).
    deadline : Deadline, optional
        Matching stops when it expires (a partial matching is still valid).

    Returns
    -------
    OppositePairs
        With ``stats["skipped"]`` and no pairs if the row bitsets would not fit in memory.
    """
    t0 = time.perf_counter()
    bits = getattr(matrix, "format", None) == "bits"
    a = matrix if bits else canonical_csr(matrix)
    m, n = a.shape
    w = check_weights(weights, m)
    col_map = np.full(n, -1, dtype=np.int64)
    cols = np.arange(n, dtype=np.int64) if columns is None else np.unique(np.asarray(columns, dtype=np.int64))
    col_map[cols] = np.arange(cols.size)
    # Observers per row among the allowed columns; rows seen fewer than `views` times never count.
    if bits:
        seen = row_counts_of(a, cols)
    else:
        allowed = np.zeros(n, dtype=bool)
        allowed[cols] = True
        seen, _ = _pk.selected_row_stats(a.indptr, a.indices, kernel_data(a), allowed)
    rows = np.flatnonzero((seen >= views) & (w > 0))
    countable = float(w[rows].sum())
    stats: dict[str, Any] = {"rows": int(rows.size), "checks": 0, "complete": False}
    none = np.zeros((0, 2), dtype=np.int64)
    need = opposite_pair_bytes(rows.size, cols.size)
    if need > memory_budget_bytes():
        stats["skipped"] = f"row bitsets need {need / 2**30:.1f} GiB"
        note_memory("opposite pairs", need, refused=True)
        stats["time_s"] = time.perf_counter() - t0
        return OppositePairs(none, np.zeros(0), rows, w[rows].astype(np.float64), countable, stats)
    note_memory("opposite pairs", need)  # the countable rows known: their row bitsets and the matching
    if order_seed is None:
        rows = rows[np.argsort(-w[rows], kind="stable")]  # heaviest first: they gain most from a partner
    else:
        rows = rows[np.random.default_rng(order_seed).permutation(rows.size)]
    if bits:  # the transposition of the column bitsets, no CSR
        bits = row_bitsets(a, rows, cols)
    else:
        with ctrl_c_deferred():
            bits = _bk.row_bits(a.indptr, a.indices, kernel_data(a), rows, col_map, cols.size)
    r = rows.size
    rem = w[rows].astype(np.float64)
    nxt = np.arange(1, r + 1, dtype=np.int64)
    prv = np.arange(-1, r - 1, dtype=np.int64)
    alive = np.ones(r, dtype=bool)
    head = np.zeros(1, dtype=np.int64)
    pairs = np.zeros((max(r, 1), 2), dtype=np.int64)
    amount = np.zeros(max(r, 1))
    n_pairs = np.zeros(1, dtype=np.int64)
    checks, start = 0, 0
    while start < r:
        if deadline is not None and deadline.expired():
            break
        stop = min(r, start + _BATCH)
        with ctrl_c_deferred():
            _, c = _bk.opposite_matching(bits, rem, nxt, prv, alive, head, start, stop, pairs, amount, n_pairs)
        checks += int(c)
        start = stop
    p = int(n_pairs[0])
    stats.update({"checks": checks, "complete": start >= r, "time_s": time.perf_counter() - t0})
    out = OppositePairs(rows[pairs[:p]], amount[:p].copy(), rows, rem, countable, stats)
    log.info("opposite pairs: %d rows, %.6g of %.6g weight matched (%d pair tests, %s) in %.2f s", r, out.matched,
             countable, checks, "complete" if start >= r else "stopped at the time limit", stats["time_s"])
    return out


def opposite_pair_bound(
    matrix: Any,
    weights: Any,
    views: int,
    cameras: int,
    columns: Sequence[int] | None = None,
    deadline: Deadline | None = None,
) -> tuple[float, dict[str, Any]]:
    """Upper bound on the weight seen by ``>= views`` of any ``cameras`` allowed cameras.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Visibility (> 0 means observes), or column bitsets (see :func:`match_opposite`).
    weights : (m,) array_like of float64
        Non-negative point weights.
    views : int
        Sightings a point needs to count.
    cameras : int
        Size of the camera system (new and fixed cameras together); must be below ``2 * views``.
    columns : sequence of int, optional
        The allowed cameras (default: every column). Fixed cameras must be among them.
    deadline : Deadline, optional
        The solve's deadline: matching stops there (the bound stays valid, only looser).

    Returns
    -------
    bound : float
        ``countable - matched``: the weight of the rows observed by at least ``views`` allowed
        cameras, minus the matched weight. ``inf`` if the row bitsets would not fit in memory.
    stats : dict
        ``countable``, ``matched``, ``rows``, ``checks``, ``complete`` and ``time_s``.

    Raises
    ------
    ValueError
        If ``cameras >= 2 * views`` (two points of a pair could then both count).
    """
    if cameras >= 2 * views:
        raise ValueError(f"opposite pairs bound nothing with {cameras} cameras and {views} views")
    res = match_opposite(matrix, weights, views, columns=columns, deadline=deadline)
    stats = dict(res.stats, countable=res.countable, matched=res.matched)
    return (math.inf if "skipped" in res.stats else res.bound), stats


def cap_applies(cameras: int, views: int) -> bool:
    """Multiview with fewer cameras (new and fixed) than ``2 * views``: an unproven answer's bound
    is tightened by :func:`opposite_pair_bound` (:func:`cap_bound`)."""
    return int(cameras) < 2 * int(views)


def cap_deadline(deadline: Deadline) -> Deadline:
    """The engines' deadline when the cap may run after them: all but :data:`_CAP_SHARE` of the
    time limit (at most :data:`_CAP_MAX_S` seconds) kept for it; unchanged without a limit."""
    if deadline.limit is None:
        return deadline
    return deadline.shortened(min(_CAP_SHARE * deadline.limit, _CAP_MAX_S))


def cap_bound(outcome: Any, matrix: Any, weights: np.ndarray, views: int, cameras: int, allowed: np.ndarray | None,
              deadline: Deadline) -> Any:
    """Tighten an unproven multiview bound with :func:`opposite_pair_bound`.

    Parameters
    ----------
    outcome : camplace.solver.result.EngineOutcome
        The engines' answer.
    matrix : (m, n) scipy.sparse matrix or BitMatrix
    weights : (m,) float64
    views, cameras : int
        As in :func:`opposite_pair_bound` (``cameras < 2 * views``).
    allowed : (a,) int64 or None
        The allowed columns (fixed and free; None: all).
    deadline : Deadline

    Returns
    -------
    EngineOutcome
        ``outcome`` with the lower of the two bounds; ``stats["opposite_pairs"]`` records the cap.
    """
    from dataclasses import replace

    cap, cap_stats = opposite_pair_bound(matrix, weights, views, cameras, columns=allowed, deadline=deadline)
    cap_stats["bound_before"] = float(outcome.bound)
    outcome.stats["opposite_pairs"] = cap_stats
    return replace(outcome, bound=cap) if cap < outcome.bound else outcome
