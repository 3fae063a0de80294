"""Exact bound-pruned engine for multi-view coverage with a triangulation angle.

A point counts when at least ``views`` chosen cameras (new and fixed) observe it and two of them
see it under an angle of at least ``min_angle_deg`` (the angle at the point between the rays
point -> camera; :func:`camplace.solver.problem.objectives.mode_value` is the definition).

The search is that of :mod:`camplace.solver.engines.bitset.search` (tuples of nodes of a bisection tree
over the columns, in parallel batches, here best-first), with the angle added to the bound:

* **Blocks.** The countable rows are ordered spatially (recursive bisection of the points along
  their widest axis), so every 64-row word is a block of nearby points with a small bounding
  sphere.
* **Cones.** For every tree node and block, a cone (8 bytes) holds the directions from any point
  of the block to any camera of the node (:mod:`camplace.solver.engines.angle._kernels`). Two nodes whose cones
  are closer than the angle can form no valid pair on that block, so the rows only they observe
  twice cannot count there. A tuple's bound is the weight of the rows where some pair of its
  nodes (or a node and a fixed camera, or two fixed cameras) observes the row and may make the
  angle; a node repeated in the tuple provides pairs only if its own cone is at least the angle
  wide. Leaves (single cameras) decide doubtful blocks row by row, so a tuple of leaves gets its
  exact value.
* **Balls.** Where blocks are wide (comet-flyby: blocks 5-55 m across seen from 20-50 m, so even
  a single camera's cone is about 20 degrees wide), the cone refinement tests the doubtful rows
  one by one against a ball around each node's camera positions: from a point, a node's cameras
  lie within ``asin(radius / distance)`` of the direction to the ball's centre (the distance
  from that point: each row its own arcs), so two nodes whose centres are closer than the angle
  less both arcs make no pair there (the poses of one position: radius 0, never a pair among
  themselves).
* **Splits.** A tuple of a level where the cone refinement is on is split at its node with the
  widest ball (:func:`split_score`; ties the node of more columns), not its largest node: the
  balls' width is the refinement's slack; elsewhere (the angle hardly binds, the count bound
  decides) at its largest node.
* **Bound steps.** A child tuple gets the count bound first (rows ``views`` of its cameras may
  observe, angles ignored: :func:`~camplace.solver.engines.angle._kernels.count_shortfall`), which prunes
  most losers without reading a cone; a survivor whose nodes all hold camera pairs making the
  angle at every point (directions from the centre of a sphere around the points, apart by the
  angle plus both parallaxes: :func:`~camplace.solver.engines.angle._kernels.angle_free`) keeps that bound,
  exact for single cameras (a tuple of single cameras is always decided exactly at once). The cone
  refinement is lazy: a tuple of clusters gets it when it is taken from the open set to be split
  (most tuples never reach the top of the best-first order and never pay for it); one it prunes is
  not split, one it pushes below the best open bound goes back to the open set refined, and the
  others' children are capped by the refined bound. It runs only on the levels (log2 of the
  largest node) where it has been removing a good share of the tuples' margins over the
  incumbent (:meth:`_Tree._learn`): about a third where the angle binds, a few per cent where
  it hardly does, which is when its cost (about five count bounds) is not worth it.
* **Caps.** A counted row is observed by ``views`` chosen cameras, so the value is at most the
  chosen columns' weights over ``views``. With fewer cameras than ``2 * views`` the
  opposite-pairs layout of :mod:`camplace.solver.engines.bitset.pair_cap` applies unchanged (the angle only
  removes credit): at most one point of a matched pair counts.
* **Fixed cameras** are part of every tuple (their pairs among themselves are precomputed exactly,
  and rows they already make count are a constant); forbidden cameras are left out.
* **Incumbent.** Greedy from the heaviest columns plus 1-swap local search, with exact angles,
  then a large-neighbourhood search (:meth:`_Incumbent.climb`: one or two cameras moved to
  columns near them, every set evaluated exactly) from the best of those sets and from the warm
  start.
* **Time limit.** On expiry the incumbent comes back with the largest bound still open.
* **Memory.** :func:`angle_bytes` (column bitsets, the tree's level bitsets, 8 bytes of cone per
  node and block, the open tuples) is checked against the budget before anything is allocated;
  :class:`~camplace.solver._support.memory.OverBudget` is raised when it does not fit.
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any, Sequence

import numba
import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace._blocks import cuts, run_blocks, threads_for
from camplace.solver._support import bitkernels as K
from camplace.solver._support import parkernels as PK
from camplace.solver._support.deadline import Deadline, as_deadline, stopwatch
from camplace.solver._support.frontier import Frontier, best_first
from camplace.solver._support.memory import OverBudget, note_memory
from camplace.solver.engines.angle import _kernels as AK
from camplace.solver.engines.bitset.pair_cap import match_opposite, opposite_pair_bytes
from camplace.solver.problem.checks import kernel_data
from camplace.solver.problem.presolve_bits import layout_bits, row_counts_of
from camplace.visibility.bits import column_sums
from camplace.solver.result import EngineOutcome

__all__ = ["angle_bytes", "greedy_angle", "solve_angle"]

log = logging.getLogger(__name__)

_FLOAT_MARGIN = 1e-9
_PAIRS_MIN_SHARE = 0.05  # opposite-pairs layout when it matches at least this share of the weight
_PAIRS_TIME_SHARE = 0.1  # ... and the matching stops after this share of the time limit
_INCUMBENT_SHARE = 0.1
#: greedy + swaps of a warm start's rung (``rung=True``: a solve whose answer is the first incumbent of
#: a larger one) stop after this share of its time instead, its climbs at its end, and a rung with a
#: warm start of its own does not search: its incumbent is what it is for
_RUNG_INCUMBENT_SHARE = 0.7
#: the layout and the tree cost about this many times the first pass over the rows: with less time
#: left than that the engine returns its incumbent at once (the set-up is not interruptible)
_SETUP_COST = 4.0  # greedy + swaps stop after this share of the time limit
_STARTS = 3  # greedy starts (the heaviest columns)
_SWAP_ROUNDS = 20
#: the incumbent's large-neighbourhood search (:meth:`_Incumbent.climb`): the moves of a camera are
#: the _LNS_NEAR free columns nearest its position and every _LNS_FAR-th of the next
#: _LNS_NEAR * _LNS_FAR (fewer when k is large: about _LNS_COLS columns in all the lists, whose rows a
#: round holds); pairs of moves take the _LNS_TOP best single moves of each list (fewer when k is
#: large: about _LNS_SETS pairs a round), within _LNS_SHARE of the time left
_LNS_NEAR = 96
_LNS_FAR = 8
_LNS_COLS = 600
_LNS_TOP = 32
_LNS_SETS = 20_000
_LNS_SHARE = 0.1
_CHUNK = 4096  # tuples per stack entry
_BATCH = 1 << 14  # tuples expanded per parallel call, at most ...
_BATCH_MIN = 256  # ... and at least
_BATCH_S = 0.5  # seconds a batch should take (the deadline is checked between batches)
_PAR_CHUNK = 16  # tuples a thread takes at a time
_FRONTIER_MAX = 12_000_000  # open tuples at most (fewer when the memory budget is tight) ...
_FRONTIER_MIN = 100_000  # ... but at least this many, or the engine does not run
_REFINE_MIN_CUT = 0.3  # cone refinement of a tuple level stays on while it removes this share of the margins ...
_REFINE_TRIALS = 2000  # ... judged after this many tries ...
_REFINE_SAMPLE = 32  # ... and tried on 1 in this many tuples of a level where it is off
#: the bisection order also parts cameras by position (the L1 distance of their positions on a
#: grid of this many steps over the widest span is added to the bitsets' Hamming distance, as
#: thermometer codes of this many bits would add it; 0: bitsets only)
_POSITION_BITS = 4096
_DEPTH_FIRST_SHARE = 0.5  # depth-first (newest chunks) while more than this share of the cap is open


def angle_bytes(rows: int, n_cols: int, n_fixed: int, k: int, views: int, open_tuples: int = _FRONTIER_MIN,
                layout_rows: int | None = None) -> int:
    """Working memory of :func:`solve_angle` for ``rows`` countable rows and ``n_cols`` columns.

    ``layout_rows``: the bit rows of the layout searched: ``rows`` for the plain layout (one a
    countable row), the opposite-pairs layout's once the points are matched (a pair is a row on
    each side, a residual one more: up to twice as many bit rows as countable rows, the bound
    counted when None). Counted
    here: the column bitsets and their ordered copy (and, while the order is made, the positions'
    grid levels), ``min(views, k)`` level bitsets and an 8-byte
    cone per tree node and 64-row block (and a float64 working copy per thread), the points of the
    layout, the pair matching's row bitsets, ``open_tuples`` open tuples of the search (which
    stops there, with a valid bound) and the incumbent's climb (:meth:`_Incumbent.climb`).
    """
    bit_rows = 2 * int(rows) + 127 if layout_rows is None else int(layout_rows)  # r + pairs (<= r) + padding
    words = (bit_rows + 63) // 64 + 2
    nodes = 2 * max(int(n_cols), 1) - 1 + int(n_fixed)
    levels = max(1, min(int(views), int(k)))
    bits = words * 8 * (2 * int(n_cols) + levels * nodes) + int(n_cols) * 3 * 8 * 2
    cones = nodes * words * 8 + nodes * 32 * (1 + max(1, numba.config.NUMBA_NUM_THREADS)) + 32 * (int(n_cols) + int(n_fixed))
    points = words * 64 * 24 * 2
    match = opposite_pair_bytes(int(rows), int(n_cols) + int(n_fixed))
    frontier = (int(open_tuples) + (k + 1) * _BATCH) * _tuple_bytes(k)
    # the incumbent's climb: the rows of its columns (int32), 4 chunks of scratch, the search rows' copies
    lns = 4 * int(rows) * (lns_columns(k, n_cols) + int(n_fixed)) + 16 * int(rows) * (k + int(n_fixed) + 2) + 32 * int(rows)
    return int(bits + cones + points + match + frontier + lns + 64 * rows)


def _tuple_bytes(k: int) -> int:
    """Bytes per open tuple of ``k`` nodes (nodes, the refined flag and bound, and a copy while
    chunks are formed)."""
    return 2 * (8 * (k + 1) + 8)


def _spatial_order(xyz: np.ndarray) -> np.ndarray:
    """Order of points whose consecutive 64-point chunks are compact: recursive bisection along
    the widest axis, splitting at a multiple of 64."""
    out: list[np.ndarray] = []
    stack = [np.arange(xyz.shape[0], dtype=np.int64)]
    while stack:
        idx = stack.pop()
        if idx.size <= 64:
            out.append(idx)
            continue
        p = xyz[idx]
        axis = int(np.argmax(p.max(axis=0) - p.min(axis=0)))
        s = 64 * ((idx.size + 127) // 128)
        o = np.argsort(p[:, axis], kind="stable")
        stack.append(idx[o[s:]])
        stack.append(idx[o[:s]])
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


def _chunk_order(key: np.ndarray) -> np.ndarray:
    """Permutation of positions that reorders 64-position chunks by increasing mean ``key``."""
    n = key.size
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    n_chunks = (n + 63) // 64
    pad = np.full(n_chunks * 64, np.nan)
    pad[:n] = key
    mean = np.nanmean(pad.reshape(n_chunks, 64), axis=1)
    pos = np.arange(n_chunks * 64).reshape(n_chunks, 64)[np.argsort(mean, kind="stable")].ravel()
    return pos[pos < n]


class _Layout:
    """Bit rows of the search: matrix row of each bit (-1: padding), weights, pair words ``pw``."""

    def __init__(self, rows: np.ndarray, weights: np.ndarray, pw: int) -> None:
        self.rows, self.weights, self.pw = rows, weights, pw


def _plain_layout(search: np.ndarray, wu: np.ndarray, pts: np.ndarray, seen: np.ndarray) -> _Layout:
    rows = search[_spatial_order(pts[search])]
    rows = rows[_chunk_order(seen[rows].astype(np.float64))]  # rarely observed blocks first: early stops
    return _Layout(rows, wu[rows].astype(np.float64), 0)


def _pairs_layout(match, wu_unit: float | None, seen: np.ndarray, pts: np.ndarray) -> _Layout:
    """The opposite-pairs layout with spatially coherent words, rarely observed words first."""
    n_pairs = match.pairs.shape[0]
    first, second, amount = match.pairs[:, 0], match.pairs[:, 1], match.amount
    o = _spatial_order(pts[first])  # compact first rows (the partners follow loosely)
    first, second, amount = first[o], second[o], amount[o]
    o = _chunk_order((seen[first] + seen[second]).astype(np.float64))
    first, second, amount = first[o], second[o], amount[o]
    left = match.rows[match.residual > 0]
    lw = match.residual[match.residual > 0]
    o = _spatial_order(pts[left])
    left, lw = left[o], lw[o]
    o = _chunk_order(seen[left].astype(np.float64))
    left, lw = left[o], lw[o]
    pw = (n_pairs + 63) // 64
    rows = np.full(128 * pw + left.size, -1, dtype=np.int64)
    w = np.zeros(rows.size)
    rows[:n_pairs] = first
    rows[64 * pw : 64 * pw + n_pairs] = second
    w[:n_pairs] = amount
    rows[128 * pw :] = left
    w[128 * pw :] = lw
    if wu_unit is not None:
        w = np.round(w)
    return _Layout(rows, w, pw)


def _position_levels(xyz: np.ndarray) -> np.ndarray:
    """(n, 3) int64: the columns' positions ``xyz`` (n, 3) on a grid of :data:`_POSITION_BITS`
    steps over the widest span (0 .. _POSITION_BITS). The bisection order adds their L1 distance
    to the Hamming distance of the bitsets (:func:`~camplace.solver._support.bitkernels.bisection_order_with`:
    the bitsets with thermometer codes of these levels appended, without making them), so that it
    also parts cameras standing far apart: the tree's nodes then hold cameras close together,
    whose balls are narrow (only the order changes; every bound stays valid for any tree)."""
    lo = xyz.min(axis=0) if xyz.shape[0] else np.zeros(3)
    span = float((xyz.max(axis=0) - lo).max()) if xyz.shape[0] else 0.0
    if span <= 0:
        return np.zeros((xyz.shape[0], 3), dtype=np.int64)
    return np.ascontiguousarray(np.floor((xyz - lo) * (_POSITION_BITS / span)).astype(np.int64))


def split_score(balls: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N,) float64: the score by which a tuple picks the node it splits
    (:func:`~camplace.solver._support.bitkernels.split_tuple_by`, the largest score among its nodes of
    two or more columns): the radius of the node's ball around its camera positions (``balls``
    (N, 4), metres; :func:`~camplace.solver.engines.angle._kernels.node_balls`), ties the node of
    more columns (``hi - lo``). The balls' width is what the angle refinement loses (two nodes
    whose balls are wide lose the angle's rows), so the widest is split first; any choice keeps
    every column set in exactly one child. Used on the levels where the refinement is on
    (:func:`~camplace.solver.engines.angle._kernels.expand`; elsewhere the largest node is split):
    comet-flyby at 2,000 / 8,000 / 32,000 positions, bound after 200 / 200 / 150 fixed batches
    0.0027-0.0038 lower than splitting the largest node; comet-67p-bunker, every surface point,
    2,000 x 10,000: proven with 4.31 M bounds instead of 4.17 M (5.19 M with the ball on every
    level); 10,000 x 50,000 at 120 s: bound 0.4739-0.4741 instead of 0.4736 (docs/solver.md,
    seventh round)."""
    return np.ascontiguousarray(balls[:, 3] + 1e-9 * (hi - lo).astype(np.float64))


def _sphere_directions(p: np.ndarray, cams: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (c, 3) from the centre of a sphere around the points ``p`` (q, 3) to the
    cameras ``cams`` (c, 3), and each camera's parallax over it, ``asin(radius / distance)``
    radians (``pi / 2`` inside it): a camera's direction from any point of the sphere is within
    its parallax of its direction from the centre."""
    c = 0.5 * (p.min(axis=0) + p.max(axis=0)) if p.shape[0] else np.zeros(3)
    rad = (float(np.linalg.norm(p - c, axis=1).max()) if p.shape[0] else 0.0) * (1.0 + 1e-9) + 1e-12
    d = cams - c
    dist = np.linalg.norm(d, axis=1)
    inside = dist <= rad * (1.0 + 1e-9)
    dirs = np.where(inside[:, None], 0.0, d / np.where(inside, 1.0, dist)[:, None])
    par = np.where(inside, 0.5 * math.pi, np.arcsin(np.minimum(1.0, rad / np.where(inside, 1.0, dist))) + 1e-9)
    return np.ascontiguousarray(dirs), np.ascontiguousarray(par)


def _blocks(rows: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of the bit rows (64 W, 3) and each block's bounding sphere: centres (W, 3), radii (W,)
    (-1 for a block without points)."""
    n_words = (rows.size + 63) // 64
    lp = np.zeros((n_words * 64, 3))
    valid = np.zeros(n_words * 64, dtype=bool)
    valid[: rows.size] = rows >= 0
    lp[: rows.size][rows >= 0] = pts[rows[rows >= 0]]
    v = valid.reshape(n_words, 64)
    p = lp.reshape(n_words, 64, 3)
    cnt = v.sum(axis=1)
    lo = np.where(v[:, :, None], p, np.inf).min(axis=1)
    hi = np.where(v[:, :, None], p, -np.inf).max(axis=1)
    centers = np.where(cnt[:, None] > 0, 0.5 * (lo + hi), 0.0)
    d = np.linalg.norm(p - centers[:, None, :], axis=2)
    radius = np.where(cnt > 0, np.where(v, d, 0.0).max(axis=1) * (1.0 + 1e-9) + 1e-12, -1.0)
    return lp, centers, radius


class _Rows:
    """The per-row passes the engine makes over the matrix, on a canonical CSR matrix (its row
    lists) or on a binary matrix held as column bitsets (:class:`camplace.visibility.bits.BitMatrix`,
    no CSR made): the same numbers either way (the bit kernels list each row's observers in the
    CSR order and sum in its order)."""

    def __init__(self, q: Any) -> None:
        self.q = q
        self.bits = getattr(q, "format", None) == "bits"
        self.shape = q.shape
        self.data = None if self.bits else kernel_data(q)  # a bool pattern as uint8, as the other kernels read it

    def row_status(self, sel: np.ndarray, pos: np.ndarray, pts: np.ndarray, views: int,
                   theta_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """:func:`~camplace.solver.engines.angle._kernels.row_status` of the cameras ``sel``."""
        q = self.q
        sel = np.unique(np.asarray(sel, dtype=np.int64))
        m = q.shape[0]
        count = np.zeros(m, dtype=np.int64)
        ok = np.zeros(m, dtype=np.bool_)
        with ctrl_c_deferred():  # row blocks on the pool: each writes its own rows
            if self.bits:
                run_blocks(lambda lo, hi: AK.row_status_bits_block(lo, hi, q.words, sel, pos, pts, views, theta_deg,
                                                                   count, ok), cuts(m), threads_for(m * len(sel)))
            else:
                where = AK.selection_index(sel, pos.shape[0])
                run_blocks(lambda lo, hi: AK.row_status_block(lo, hi, q.indptr, q.indices, self.data, where, len(sel),
                                                              pos, pts, views, theta_deg, count, ok), cuts(m),
                           threads_for(q.indices.shape[0]))
        return count, ok

    def gains(self, wu: np.ndarray, sel: np.ndarray, pos: np.ndarray, pts: np.ndarray, views: int, theta_deg: float,
              count: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """:func:`~camplace.solver.engines.angle._kernels.gains` of the cameras ``sel``."""
        q = self.q
        sel = np.unique(np.asarray(sel, dtype=np.int64))
        with ctrl_c_deferred():
            if self.bits:
                return AK.gains_bits(q.words, q.shape[0], wu, sel, pos, pts, views, theta_deg, count, ok, 4)
            return AK.gains(q.indptr, q.indices, self.data, wu, sel, pos, pts, views, theta_deg, count, ok, 4)

    def column_weights(self, rows: np.ndarray, w_rows: np.ndarray) -> np.ndarray:
        """(n,) float64: per column, the summed ``w_rows`` of the ``rows`` (ascending) it observes."""
        q = self.q
        if self.bits:
            wz = np.zeros(q.shape[0])
            wz[rows] = w_rows
            return column_sums(q, wz)  # the other rows add 0.0: the same sums
        with ctrl_c_deferred():
            return AK.column_weights(q.indptr, q.indices, self.data, rows, w_rows, q.shape[1])

    def seen(self, allowed: np.ndarray) -> np.ndarray:
        """(m,) int64: the ``allowed`` ((n,) bool) columns observing each row."""
        q = self.q
        if self.bits:
            return row_counts_of(q, np.flatnonzero(allowed))
        with ctrl_c_deferred():
            return PK.selected_row_stats(q.indptr, q.indices, self.data, allowed)[0]

    def build_bits(self, rows: np.ndarray, col_map: np.ndarray, n_cols: int) -> np.ndarray:
        """Column bitsets over ``rows`` (-1: padding) of the mapped columns: ``(n_cols, ceil(len(rows) / 64))``."""
        q = self.q
        if self.bits:
            return layout_bits(q, rows, col_map, n_cols)
        with ctrl_c_deferred():
            return PK.build_bits(q.indptr, q.indices, self.data, rows, col_map, n_cols)


    def column_lists(self, row_id: np.ndarray, local: np.ndarray, n_local: int) -> tuple[np.ndarray, np.ndarray]:
        """:func:`~camplace.solver.engines.angle._kernels.column_lists`: the rows (numbered by
        ``row_id``, -1 left out) of each wanted column (``local`` (n,) its output index, -1 not
        wanted), in matrix order: ``(ptr (n_local + 1,) int64, rows int32)``."""
        q = self.q
        if not self.bits:
            with ctrl_c_deferred():
                return AK.column_lists(q.indptr, q.indices, self.data, row_id, local, n_local)
        cols = np.empty(n_local, dtype=np.int64)
        want = np.flatnonzero(local >= 0)
        cols[local[want]] = want
        keep = row_id >= 0
        ptr = np.zeros(n_local + 1, dtype=np.int64)
        parts = []
        for c in range(n_local):  # one column's bits at a time: m bytes of scratch
            r = np.flatnonzero(q.column(int(cols[c])) & keep)
            parts.append(row_id[r].astype(np.int32))
            ptr[c + 1] = ptr[c] + r.size
        return ptr, (np.concatenate(parts) if parts else np.empty(0, dtype=np.int32))


class _Incumbent:
    """Greedy + 1-swap with exact angles on the original matrix (weights zero off the search rows)."""

    def __init__(self, q: _Rows, wu: np.ndarray, pos: np.ndarray, pts: np.ndarray, views: int,
                 theta_deg: float, fixed: np.ndarray, free: np.ndarray, margin: float, stop: Deadline) -> None:
        self.q, self.wu, self.pos, self.pts = q, wu, pos, pts
        self.views, self.theta_deg, self.fixed, self.margin = views, theta_deg, fixed, margin
        self.allowed = np.zeros(q.shape[1], dtype=bool)
        self.allowed[free] = True
        self.stop = stop  # when the swaps stop
        self.best = -math.inf
        self.best_set: tuple[int, ...] = ()
        self.calls = 0
        self.lns_rounds = 0

    def expired(self) -> bool:
        return self.stop.expired()

    def _state(self, sel: list[int]) -> tuple[np.ndarray, np.ndarray]:
        s = np.asarray(sorted(set(sel) | set(self.fixed.tolist())), dtype=np.int64)
        return self.q.row_status(s, self.pos, self.pts, self.views, self.theta_deg)

    def value(self, sel: list[int]) -> float:
        _, ok = self._state(sel)
        return float(self.wu[ok].sum())

    def gain(self, sel: list[int]) -> np.ndarray:
        count, ok = self._state(sel)
        s = np.asarray(sorted(set(sel) | set(self.fixed.tolist())), dtype=np.int64)
        self.calls += 1
        g = self.q.gains(self.wu, s, self.pos, self.pts, self.views, self.theta_deg, count, ok)
        g[~self.allowed] = -np.inf
        return g

    def offer(self, sel: list[int]) -> float:
        """Keep ``sel`` if it beats the incumbent; returns its value (:meth:`value`)."""
        v = self.value(sel)
        if v > self.best:
            self.best, self.best_set = v, tuple(sorted(sel))
        return v

    def run(self, k: int, colw: np.ndarray) -> tuple[tuple[int, ...], float]:
        """Greedy from each of the :data:`_STARTS` heaviest columns, then :meth:`swaps`; each set
        offered. Returns the best of them (original columns, sorted; empty if none was made) and
        its value (-inf if none)."""
        order = np.argsort(-np.where(self.allowed, colw, -np.inf), kind="stable")[: int(self.allowed.sum())]
        best, best_set = -math.inf, ()
        for s0 in order[:_STARTS]:
            if self.expired() and self.best_set:
                break
            sel = [int(s0)]
            while len(sel) < k:
                g = self.gain(sel)
                g[sel] = -np.inf
                # no gain yet (a first camera alone makes no pair): the heaviest remaining column
                j = int(np.argmax(g)) if np.max(g) > 0 else next(int(c) for c in order if int(c) not in sel)
                sel.append(j)
            sel = self.swaps(sel)
            v = self.offer(sel)
            if v > best:
                best, best_set = v, tuple(sorted(sel))
        return best_set, best

    def swaps(self, sel: Sequence[int]) -> list[int]:
        """1-swaps from ``sel``: each camera in turn replaced by the free column of the largest gain
        (one pass over the matrix, :meth:`gain`) while that gains more than the margin, at most
        :data:`_SWAP_ROUNDS` rounds, until the incumbent's stop. Returns the cameras."""
        sel = list(sel)
        for _ in range(_SWAP_ROUNDS):
            if self.expired():
                break
            improved = False
            for p in range(len(sel)):
                others = sel[:p] + sel[p + 1 :]
                g = self.gain(others)
                cur = g[sel[p]]
                g[sel] = -np.inf
                j = int(np.argmax(g))
                if g[j] > cur + self.margin:
                    sel[p] = j
                    improved = True
            if not improved:
                break
        return sel

    def climb(self, sel: Sequence[int], stop: Deadline, round_s: float = 0.0) -> None:
        """Large-neighbourhood search from the cameras ``sel`` (original columns, free), offered
        when it ends: each round evaluates exactly (:func:`~camplace.solver.engines.angle._kernels.set_values`,
        the rule of :meth:`value`) every set that replaces one camera by a column of its move
        list (:meth:`_near`), then every set that replaces one or two cameras by columns among the
        :func:`_top_size` best single moves of their lists (:func:`_best_moves`, :func:`_moves`),
        and moves to the best while it gains more than the margin. Candidates sampled more
        finely hold better sets close to a coarse answer: the moves climb there. A round (not
        interruptible) starts only while more than ``round_s`` seconds (an estimate: the
        caller's, then the longest round so far) are left before ``stop``. Memory: the search
        rows of the columns in the move lists (4 bytes a row, at most :func:`lns_columns`
        columns) and 4 chunks of (rows, k + fixed + 1) int32 scratch."""
        free = np.flatnonzero(self.allowed)
        sel = sorted(int(c) for c in sel)
        k = len(sel)
        if not sel or free.size <= k:
            return
        fpos = self.pos[free]
        search = np.flatnonzero(self.wu > 0)  # the lists and the scratch hold these rows only
        row_id = np.full(self.q.shape[0], -1, dtype=np.int64)
        row_id[search] = np.arange(search.size)
        w_s, pts_s = self.wu[search], np.ascontiguousarray(self.pts[search])
        size, top = _move_list_size(k), _top_size(k)
        cur = -math.inf
        while not stop.expired() and (stop.remaining() is None or stop.remaining() > round_s):
            t0 = time.perf_counter()
            near = [self._near(c, free, fpos, size) for c in sel]
            cols = np.unique(np.concatenate(near + [self.fixed]))
            local = np.full(self.q.shape[1], -1, dtype=np.int64)
            local[cols] = np.arange(cols.size)
            lsel, lnear = local[np.asarray(sel)], [local[c] for c in near]
            fixed_l = local[self.fixed]
            cpos = np.ascontiguousarray(self.pos[cols])

            def values(sets: np.ndarray) -> np.ndarray:
                full = np.concatenate([sets, np.broadcast_to(fixed_l, (sets.shape[0], fixed_l.size))], axis=1)
                return AK.set_values(ptr, rows, np.ascontiguousarray(full), w_s, cpos, pts_s, self.views,
                                     self.theta_deg, 4)

            with ctrl_c_deferred():
                ptr, rows = self.q.column_lists(row_id, local, cols.size)
                singles, owner = _singles(lsel, lnear)
                one = values(singles)
                pairs = _moves(lsel, _best_moves(lsel, lnear, singles, owner, one, top))
                sets, vals = np.concatenate([singles, pairs]), np.concatenate([one, values(pairs)])
            self.lns_rounds += 1
            round_s = max(round_s, time.perf_counter() - t0)
            cur = max(cur, float(vals[0]))  # the first set is the current one
            i = int(np.argmax(vals))
            if vals[i] <= cur + self.margin:
                break
            sel, cur = sorted(int(c) for c in cols[sets[i]]), float(vals[i])
        self.offer(sel)

    def _near(self, c: int, free: np.ndarray, fpos: np.ndarray, size: int) -> np.ndarray:
        """The moves of camera ``c`` in :meth:`climb`, nearest first: itself, the
        :data:`_LNS_NEAR` free columns nearest its position (its other poses first) and every
        :data:`_LNS_FAR`-th of the next ``_LNS_NEAR * _LNS_FAR`` (farther steps); ties by index;
        the first ``size`` of them (original columns)."""
        d = np.linalg.norm(fpos - self.pos[c], axis=1)
        n_near = min(d.size, _LNS_NEAR * (_LNS_FAR + 1))
        o = np.argpartition(d, n_near - 1)[:n_near]
        o = o[np.lexsort((free[o], d[o]))]
        got = free[np.concatenate([o[:_LNS_NEAR], o[_LNS_NEAR::_LNS_FAR]])]
        return np.concatenate([[c], got[got != c]])[:size].astype(np.int64)


def _move_list_size(k: int) -> int:
    """Entries of each camera's move list in :meth:`_Incumbent.climb`: all of them (``1 + 2
    _LNS_NEAR``), or fewer so that the lists hold about :data:`_LNS_COLS` columns in all."""
    return int(min(1 + 2 * _LNS_NEAR, max(2, _LNS_COLS // max(1, k))))


def _top_size(k: int) -> int:
    """Entries of each camera's list of best single moves that :meth:`_Incumbent.climb` pairs:
    :data:`_LNS_TOP`, or fewer so that the pairs of lists make about :data:`_LNS_SETS` sets."""
    pairs = max(1, k * (k - 1) // 2)
    return int(min(_LNS_TOP, max(2, math.isqrt(_LNS_SETS // pairs))))


def lns_columns(k: int, n_cols: int) -> int:
    """Columns (besides the fixed ones) whose rows :meth:`_Incumbent.climb` holds at most."""
    return int(min(n_cols, k * _move_list_size(k)))


def _singles(sel: np.ndarray, near: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The single moves of :meth:`_Incumbent.climb`: for each entry ``p`` of ``sel`` (k,), every
    set replacing it by one of ``near[p]``, with no column twice (``near[p]`` starts with
    ``sel[p]``: the first set is ``sel`` itself). Returns the sets (S, k) int64 and the entry
    each replaces (S,) int64."""
    out, owner = [], []
    for p in range(sel.size):
        grid = np.repeat(sel[None, :], near[p].size, axis=0)
        grid[:, p] = near[p]
        out.append(grid)
        owner.append(np.full(near[p].size, p, dtype=np.int64))
    sets, who = np.concatenate(out), np.concatenate(owner)
    ok = (np.diff(np.sort(sets, axis=1), axis=1) > 0).all(axis=1)
    return np.ascontiguousarray(sets[ok]), who[ok]


def _best_moves(sel: np.ndarray, near: list[np.ndarray], singles: np.ndarray, owner: np.ndarray,
                values: np.ndarray, top: int) -> list[np.ndarray]:
    """Each entry's list of moves for the pairs of :meth:`_Incumbent.climb`: itself first, then
    the columns of ``near[p]`` whose single moves (``singles`` (S, k), replacing entry
    ``owner``, of value ``values``) are worth the most (ties: nearer first), ``top`` in all."""
    out = []
    for p in range(sel.size):
        mine = np.flatnonzero(owner == p)  # in list order: nearer first
        order = mine[np.argsort(-values[mine], kind="stable")]
        got = singles[order, p]
        out.append(np.concatenate([[sel[p]], got[got != sel[p]]])[:top].astype(np.int64))
    return out


def _moves(sel: np.ndarray, near: list[np.ndarray]) -> np.ndarray:
    """The sets of :meth:`_Incumbent.climb`: ``sel`` (k,) itself first, then every set replacing
    one or two of its entries ``p`` (and ``q``) by one of ``near[p]`` (and ``near[q]``), with no
    column twice. Returns (T, k) int64."""
    k = sel.size
    pairs = [(p, q) for p in range(k) for q in range(p + 1, k)] or [(0, 0)]
    out = [sel[None, :]]
    for p, q in pairs:
        a, b = near[p], near[q]
        grid = np.repeat(sel[None, :], a.size * (b.size if q != p else 1), axis=0)
        grid[:, p] = np.repeat(a, b.size if q != p else 1)
        if q != p:
            grid[:, q] = np.tile(b, a.size)
        out.append(grid)
    sets = np.concatenate(out)
    srt = np.sort(sets, axis=1)
    return np.ascontiguousarray(sets[(np.diff(srt, axis=1) > 0).all(axis=1)])


class _Tree:
    """Everything the compiled search reads: the bisection tree over the useful free columns with
    its level bitsets and cones, the fixed cameras, the layout's weights and points.

    Parameters
    ----------
    q : (m, n) csr_matrix
    pos : (n, 3), pts : (m, 3) float64
    layout : _Layout
    free, fixed : int64 arrays of column indices
    colw : (n,) float64
        Each column's weight on the search rows (layout units).
    k, views : int
    theta_deg : float
    integer : bool
        Integer layout weights (popcount sums).
    lap : callable
        Records the time of each setup step.
    """

    def __init__(self, q: _Rows, pos: np.ndarray, pts: np.ndarray, layout: _Layout, free: np.ndarray,
                 fixed: np.ndarray, colw: np.ndarray, k: int, views: int, theta_deg: float, integer: bool,
                 lap: Any) -> None:
        n = q.shape[1]
        rows, lw = layout.rows, layout.weights
        self.k, self.views, self.pw, self.lw, self.theta_deg = k, views, layout.pw, lw, theta_deg
        self.total = float(lw.sum())
        useful = free[colw[free] > 0]  # columns observing a search row, padded to k
        if useful.size < k:
            useful = np.concatenate([useful, free[colw[free] <= 0][: k - useful.size]])
        cols = np.sort(useful)
        col_map = np.full(n, -1, dtype=np.int64)
        col_map[cols] = np.arange(cols.size)
        bits = q.build_bits(rows, col_map, cols.size)
        lap("bits")
        with ctrl_c_deferred():
            perm = K.bisection_order_with(bits, _position_levels(pos[cols]))
            lap("order")
            self.lo, self.hi, self.left, self.right, self.levels = K.build_tree(np.ascontiguousarray(bits[perm]),
                                                                                min(views, k))
        del bits
        lap("tree")
        n_words = self.levels.shape[2]
        self.cols_ord = cols[perm]
        self.pts, centers, radius = _blocks(rows, pts)
        self.blocks = (centers, radius)
        self.cones = np.empty((self.lo.shape[0], n_words, 4), dtype=np.int16)
        slot = np.empty(cols.size, dtype=np.int64)
        leaves = np.flatnonzero(self.left < 0)
        slot[self.lo[leaves]] = leaves
        fmap = np.full(n, -1, dtype=np.int64)
        fmap[fixed] = np.arange(fixed.size)
        self.campos = np.ascontiguousarray(pos[self.cols_ord])
        self.fpos = np.ascontiguousarray(pos[fixed]).reshape(-1, 3)
        with ctrl_c_deferred():
            AK.node_cones(self.campos, slot, self.left, self.right, centers, radius, self.cones)
            self.balls = AK.node_balls(self.campos, self.lo, self.hi)
            # the node a tuple splits: the widest ball (the angle's slack), ties the larger node
            self.split_score = split_score(self.balls, self.lo, self.hi)
            lap("cones")
            self.fbits = q.build_bits(rows, fmap, fixed.size)
            self.fcones = np.empty((fixed.size, n_words, 4), dtype=np.int16)
            none = np.full(fixed.size, -1, dtype=np.int64)
            AK.node_cones(self.fpos, np.arange(fixed.size, dtype=np.int64), none, none, centers, radius, self.fcones)
            self.fpair = AK.fixed_pairs(self.fbits, self.fpos, self.pts, theta_deg)
            # one sphere around every point: node pairs the angle cannot split (AK.angle_free)
            self.dirs, self.par = _sphere_directions(self.pts[: rows.size][rows >= 0],
                                                     np.concatenate([self.campos, self.fpos]))
        self.planes = K.weight_planes(lw) if integer else np.zeros((0, n_words), np.uint64)
        self.mask = _last_mask(rows.size)
        f = colw[self.cols_ord]
        self.colmax = np.empty(self.lo.shape[0])
        for v in range(self.lo.shape[0] - 1, -1, -1):
            self.colmax[v] = f[self.lo[v]] if self.left[v] < 0 else max(self.colmax[self.left[v]],
                                                                         self.colmax[self.right[v]])
        self.fixed_colsum = float(colw[fixed].sum())
        self.root = min(self.total, (float(np.sort(f)[-k:].sum()) + self.fixed_colsum) / views)
        self.tables = AK.angle_tables(math.radians(theta_deg))
        self.refine = np.ones(64, dtype=np.bool_)
        self.tries = np.zeros(64, dtype=np.int64)
        self.wins = np.zeros(64, dtype=np.int64)
        self.cuts = np.zeros(64)
        self.cos_t = math.cos(math.radians(theta_deg))

    def expand(self, tup: np.ndarray, tup_bound: np.ndarray, best: float, margin: float, rest: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int, int, int, int, int]:
        """Children of the tuples ``tup`` (F, k + 1: nodes, then 1 if the bound holds the angle)
        whose bounds are ``tup_bound`` (F,) and the children's bounds (at most their parent's,
        refined first where due; :func:`_anglekernels.expand`):
        children, values, leaf flags, and the numbers of bounds, exact evaluations, prunes by the
        count bound, angle-free tuples, prunes after the cone refinement and tuples sent back
        unsplit (refined below the best open bound)."""
        possible, always, self_ok = self.tables
        with ctrl_c_deferred(), numba.parallel_chunksize(_PAR_CHUNK):  # dynamic: evaluations vary in cost
            children, value, leaf, n_made, n_exact, n_cheap, n_free, n_angle, n_back, refined, cut = AK.expand(
                tup, tup_bound, self.lo, self.hi, self.left, self.right, self.levels, self.cones, self.views, self.campos,
                self.fbits, self.fcones, self.fpos, self.fpair, self.lw, self.planes, self.mask, self.total, best,
                margin, self.colmax, self.fixed_colsum, self.pw, self.pts, possible, always, self_ok, self.theta_deg,
                self.cos_t, self.dirs, self.par, self.refine, _REFINE_SAMPLE, rest, self.balls, self.blocks[0],
                self.blocks[1], self.split_score)
        self._learn(refined, cut)
        return children, value, leaf, int(n_made), int(n_exact), int(n_cheap), int(n_free), int(n_angle), int(n_back)

    def _learn(self, refined: np.ndarray, cut: np.ndarray) -> None:
        """Cone refinement per level of the tuples' largest node (log2 of its columns): kept on
        while, over the tuples it tried there, it removed on average at least _REFINE_MIN_CUT of
        their margin over the incumbent (a prune removes all of it), judged after _REFINE_TRIALS
        tries; 1 in _REFINE_SAMPLE tuples of a level where it is off goes on being tried. It
        costs about five count bounds: where the angle hardly binds (cameras seeing one side,
        far apart) it trims a few per cent of the margin and is switched off; where it binds it
        removes a third or more."""
        r = refined.ravel().astype(np.int64)
        on = r != 0
        lvl = np.abs(r[on]) - 1
        self.tries += np.bincount(lvl, minlength=64)[:64]
        self.cuts += np.bincount(lvl, weights=cut.ravel()[on], minlength=64)[:64]
        self.wins += np.bincount(-r[r < 0] - 1, minlength=64)[:64]
        self.refine = (self.tries < _REFINE_TRIALS) | (self.cuts >= _REFINE_MIN_CUT * self.tries)

    def columns(self, nodes: np.ndarray) -> tuple[int, ...]:
        """Original columns of a tuple of leaves, sorted."""
        return tuple(sorted(int(self.cols_ord[self.lo[x]]) for x in nodes))


def greedy_angle(q: sp.csr_matrix, w: np.ndarray, k: int, views: int, min_angle_deg: float, pos: np.ndarray,
                 pts: np.ndarray, fixed: np.ndarray, free: np.ndarray, *,
                 deadline: Deadline | None = None) -> tuple[int, ...]:
    """Greedy plus 1-swap choice of ``k`` new cameras with exact angles, then the
    large-neighbourhood search (:meth:`_Incumbent.climb`; the angle engine's incumbent alone), in
    O(m + n) memory besides the matrix and the rows of the columns near the chosen ones: the
    fallback when nothing else fits.

    Parameters are those of :func:`solve_angle`; the swaps and the climb stop at ``deadline``.

    Returns
    -------
    tuple of int
        The new cameras (original column indices, sorted).
    """
    deadline = as_deadline(deadline)
    fixed = np.asarray(fixed, dtype=np.int64)
    free = np.asarray(free, dtype=np.int64)
    wu = np.where(w > 0, w, 0.0)
    q = _Rows(q)
    colw = q.column_weights(np.arange(q.shape[0], dtype=np.int64), wu)
    inc = _Incumbent(q, wu, pos, pts, views, float(min_angle_deg), fixed, free, 0.0, deadline)
    t0 = time.perf_counter()
    inc.run(k, colw)
    # a climb's round reads the matrix once, like a gain: no round with less than one gain's time left
    inc.climb(inc.best_set, deadline, (time.perf_counter() - t0) / max(1, inc.calls))
    return inc.best_set


def solve_angle(
    q: sp.csr_matrix,
    w: np.ndarray,
    k: int,
    views: int,
    min_angle_deg: float,
    pos: np.ndarray,
    pts: np.ndarray,
    fixed: np.ndarray,
    free: np.ndarray,
    *,
    deadline: Deadline | None = None,
    budget_bytes: int,
    start: Sequence[int] | None = None,
    rung: bool = False,
) -> EngineOutcome:
    """Best ``k`` new cameras for multi-view coverage with a minimum triangulation angle.

    Parameters
    ----------
    q : (m, n) scipy.sparse.csr_matrix or BitMatrix
        Canonical visibility (> 0 observes), or a binary matrix as column bitsets
        (:class:`camplace.visibility.bits.BitMatrix`): its passes then read the bits (row states
        of the chosen cameras from their bits, gains and column weights column by column, the
        layout's bitsets and the opposite pairs transposed), no CSR is made, and the answer is
        the same.
    w : (m,) float64
        Point weights.
    k : int
        New cameras (>= 1).
    views : int
        Cameras a point needs (>= 2).
    min_angle_deg : float
        Minimum angle at the point between two of its views, degrees.
    pos : (n, 3) float64
        Camera positions.
    pts : (m, 3) float64
        Point positions.
    fixed : (r,) int64
        Cameras always used.
    free : (f,) int64
        Cameras that may be chosen (neither fixed nor forbidden), ``f >= k``.
    deadline : Deadline, optional
        The solve's deadline (default: none). On expiry the best set found comes back with status
        ``"feasible"`` and a valid bound.
    budget_bytes : int
        Memory the engine may use.
    start : sequence of int, optional
        ``k`` new cameras (original column indices, free) found elsewhere, e.g. by a solve on a
        subset of the candidates: offered as the first incumbent (the answer is never worse).
    rung : bool
        This solve is a warm start's rung (its answer the first incumbent of a solve on more
        candidates): with a time limit, greedy + swaps may use :data:`_RUNG_INCUMBENT_SHARE` of
        its time and the climbs the rest; with a ``start`` too (a middle rung) it returns the
        incumbent without a search (status ``"feasible"``, every countable row as the bound).

    Returns
    -------
    EngineOutcome
        ``selected``: the new cameras (original column indices, sorted; empty if none was found);
        ``bound``: an upper bound on the objective, fixed cameras included, in weight units.

    Raises
    ------
    OverBudget
        When :func:`angle_bytes` exceeds ``budget_bytes`` (raised before any large allocation).
    """
    deadline = as_deadline(deadline)
    since = stopwatch(deadline)
    total = None if deadline.limit is None else deadline.remaining()  # the steps' shares are of this
    inc_stop = deadline.share(_RUNG_INCUMBENT_SHARE if rung else _INCUMBENT_SHARE)
    matrix = q
    q = _Rows(q)
    m, n = q.shape
    fixed = np.asarray(fixed, dtype=np.int64)
    free = np.asarray(free, dtype=np.int64)
    theta_deg = float(min_angle_deg)
    stats: dict[str, Any] = {"views": views, "min_angle_deg": theta_deg, "times_s": {}}
    last = [0.0]

    def lap(what: str) -> None:
        now = since()
        stats["times_s"][what] = now - last[0]
        last[0] = now
    # rows the fixed cameras already make count: a constant
    _, ok_fixed = q.row_status(fixed, pos, pts, views, theta_deg)
    allowed = np.zeros(n, dtype=bool)
    allowed[fixed] = True
    allowed[free] = True
    seen = q.seen(allowed)
    only_free = np.zeros(n, dtype=bool)
    only_free[free] = True
    seen_free = seen if fixed.size == 0 else q.seen(only_free)  # no fixed camera: the same columns
    const = float(w[ok_fixed].sum())
    lap("rows")
    search = np.flatnonzero((w > 0) & ~ok_fixed & (seen >= views) & (seen_free > 0))
    # checked in two steps: here on the plain layout (one bit row a countable row: the least the
    # search needs), then on the opposite-pairs layout once the points are matched (its rows known)
    need = angle_bytes(search.size, free.size, fixed.size, k, views, _FRONTIER_MIN, search.size)
    if need > budget_bytes:
        raise OverBudget(need, budget_bytes, "the angle engine")
    note_memory("angle", need)
    stats["rows"] = int(search.size)
    pos_w = w[w > 0]
    unit = float(pos_w[0]) if pos_w.size and np.all(pos_w == pos_w[0]) else None
    wu = np.zeros(m)
    wu[search] = w[search] / unit if unit is not None else w[search]
    scale = unit if unit is not None else 1.0
    margin = 0.0 if unit is not None else _FLOAT_MARGIN * float(wu.sum())
    if search.size == 0 or k + fixed.size < views:
        return EngineOutcome(tuple(int(j) for j in free[:k]), "optimal", const, dict(stats, trivial=True))

    colw = q.column_weights(search, wu[search])
    inc = _Incumbent(q, wu, pos, pts, views, theta_deg, fixed, free, margin, inc_stop)
    lap("column_weights")
    start_ok = start is not None and len({int(j) for j in start}) == k and np.isin(np.asarray(start), free).all()
    rows_s = stats["times_s"]["rows"]
    first_v = greedy_v = -math.inf  # the warm start's and the greedy sets' values (none yet)

    def climb_stop() -> Deadline:
        return Deadline(None) if total is None else deadline if rung else deadline.share(_LNS_SHARE)

    if start_ok:
        # a warm start: the search starts at least there. Climbed, then 1-swaps from the climbed set
        # (a few passes over the matrix, where a greedy start of its own takes k and its swaps many
        # more), climbed again when they moved (comet-flyby, 8,000 positions: the 2,000-position
        # optimum 0.52776 climbs to 0.53620, swaps to 0.53746)
        assert start is not None
        first = sorted(int(j) for j in start)
        first_v = inc.offer(first)
        stats["start"] = const + first_v * scale
        inc.climb(first, climb_stop(), rows_s)
        swapped = sorted(inc.swaps(list(inc.best_set)))
        if tuple(swapped) != inc.best_set:
            inc.offer(swapped)
            inc.climb(swapped, climb_stop(), rows_s)
        stats["start_climbed"] = const + inc.best * scale
    left = deadline.remaining()
    # a greedy start costs about k passes over the matrix (like the first): with a warm start and not
    # the time for one (or none left of the incumbent's share), the warm start alone is the incumbent
    greedy: tuple[int, ...] = ()
    if not (start_ok and (inc.expired() or left is not None and left <= (k + _SETUP_COST) * rows_s)):
        greedy, greedy_v = inc.run(k, colw)  # at least one greedy start of its own without a warm start
    stats["incumbent_before_climb"] = const + max(greedy_v, first_v) * scale
    # the large-neighbourhood search from the greedy sets' best too: another basin (comet-flyby,
    # 8,000 positions: the warm start 0.53089 climbed to 0.53746, the greedy 0.53387 not at all)
    if greedy:
        inc.climb(list(greedy), climb_stop(), rows_s)
    stats["initial_incumbent"] = const + inc.best * scale
    stats["lns_rounds"] = inc.lns_rounds
    lap("incumbent")
    if rung and start_ok and total is not None:
        # a warm start's middle rung (itself warm-started): the larger solve takes its answer, not its
        # bound (every countable row); the bottom rung, small, searches what is left of its time
        stats.update({"stopped": "rung", "skipped": "search", "bound_evaluations": 0})
        return EngineOutcome(inc.best_set, "feasible", const + float(wu.sum()) * scale, stats)
    left = deadline.remaining()
    if left is not None and left <= _SETUP_COST * stats["times_s"]["rows"]:
        # no time for the layout and the tree (compiled, not interruptible): the incumbent, and every
        # countable row as the bound (the angle only removes weight)
        stats.update({"stopped": "time limit", "skipped": "set-up", "bound_evaluations": 0})
        return EngineOutcome(inc.best_set, "feasible", const + float(wu.sum()) * scale, stats)

    # bit rows: spatial blocks, with the opposite-pairs layout when it pays
    layout = None
    if k + fixed.size < 2 * views:
        wm = np.zeros(m)
        wm[search] = wu[search]
        match = match_opposite(matrix, wm, views, columns=np.flatnonzero(allowed),
                               deadline=Deadline(None) if total is None else deadline.within(_PAIRS_TIME_SHARE * total))
        share = match.matched / match.countable if match.countable > 0 else 0.0
        stats["opposite_pairs"] = dict(match.stats, matched_share=share)
        if share >= _PAIRS_MIN_SHARE:
            layout = _pairs_layout(match, unit, seen, pts)
        del match
        if layout is not None and angle_bytes(search.size, free.size, fixed.size, k, views, _FRONTIER_MIN,
                                              layout.rows.size) > budget_bytes:
            stats["opposite_pairs"]["skipped"] = f"{layout.rows.size} layout rows over the memory budget"
            layout = None  # the plain layout: a valid bound, less tight
    if layout is None:
        layout = _plain_layout(search, wu, pts, seen)
    # as many open tuples as the budget allows (the search stops there with a valid bound)
    need = angle_bytes(search.size, free.size, fixed.size, k, views, _FRONTIER_MIN, layout.rows.size)
    note_memory("angle", need)  # the layout's rows known (the open tuples at their least, as above)
    cap = int(max(_FRONTIER_MIN, min(_FRONTIER_MAX, _FRONTIER_MIN + (budget_bytes - need) // _tuple_bytes(k))))
    need = angle_bytes(search.size, free.size, fixed.size, k, views, cap, layout.rows.size)
    stats.update({"memory_estimate_bytes": need, "open_tuples_max": cap})
    lap("layout")
    tree = _Tree(q, pos, pts, layout, free, fixed, colw, k, views, theta_deg, unit is not None, lap)
    stats.update({"bit_rows": int(layout.rows.size), "words": int(tree.levels.shape[2]), "pair_words": int(layout.pw),
                  "cols": int(tree.cols_ord.size), "time_setup_s": since()})

    # the incumbent (in layout units: its value on the search rows), then best-first search
    best = inc.best
    best_set = inc.best_set
    front = Frontier(np.zeros((1, k + 1), dtype=np.int64), np.array([tree.root]), int(_DEPTH_FIRST_SHARE * cap), _CHUNK)
    cpu_search = time.process_time()
    evaluated = exact_evals = cheap_prunes = angle_free = angle_prunes = requeued = 0

    def expand(tup: np.ndarray, tup_bound: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nonlocal evaluated, exact_evals, cheap_prunes, angle_free, angle_prunes, requeued
        children, value, leaf, n_made, n_exact, n_cheap, n_free, n_angle, n_back = tree.expand(
            tup, tup_bound, best, margin, front.top())
        evaluated += n_made
        exact_evals += n_exact
        cheap_prunes += n_cheap
        angle_free += n_free
        angle_prunes += n_angle
        requeued += n_back
        return children, value, leaf

    def offer(value: float, nodes: np.ndarray) -> None:
        nonlocal best, best_set
        if value > best:
            best, best_set = value, tree.columns(nodes[:k])
            log.debug("angle: incumbent %.9g %s", const + best * scale, best_set)

    status, open_bound, batches, t_expand = best_first(
        front, expand, offer, lambda: best + margin, deadline, stats, max_open=cap, batch=min(_BATCH, _BATCH_MIN),
        batch_min=_BATCH_MIN, batch_max=_BATCH, batch_s=_BATCH_S)
    log.debug("angle: %d bounds (%d pruned without the angle, %d angle-free), open %d, %.1f s",
              evaluated, cheap_prunes, angle_free, front.n_open, since())
    bound = max(best, open_bound)
    if bound <= best + margin:
        status, bound = "optimal", best
    stats.update({"search": "opposite pairs" if layout.pw > 0 else "blocks", "bound_evaluations": int(evaluated),
                  "exact_evaluations": int(exact_evals), "pruned_without_angle": int(cheap_prunes),
                  "angle_free": int(angle_free), "refined": int(tree.tries.sum()),
                  "pruned_by_angle": int(angle_prunes), "requeued": int(requeued), "batches": batches,
                  "refine_levels": {int(v): [int(tree.tries[v]), int(tree.wins[v]), round(float(tree.cuts[v]), 1), bool(tree.refine[v])]
                                    for v in np.flatnonzero(tree.tries)},
                  "peak_open": int(front.peak),
                  "depth_first_batches": front.lifo_batches, "incumbent_calls": inc.calls,
                  "time_search_s": since() - stats["time_setup_s"],
                  "cpu_search_s": time.process_time() - cpu_search, "time_expand_s": t_expand})
    log.info("angle: k=%d views=%d angle %.3g deg on %d rows x %d columns, %s value %.9g bound %.9g, %d bound "
             "evaluations, %.3f s", k, views, theta_deg, layout.rows.size, tree.cols_ord.size, status, const + best * scale,
             const + bound * scale, evaluated, since())
    return EngineOutcome(best_set, status, const + bound * scale, stats)


def _last_mask(m: int) -> np.uint64:
    rem = m % 64
    return np.uint64((1 << rem) - 1) if rem else np.uint64(0xFFFFFFFFFFFFFFFF)
