"""A minimum distance by branching on the relaxed optimum's conflicting pairs.

When the problem without the spacing between new cameras (:func:`camplace.solver.api._relaxed_first`)
has an optimum with two cameras closer than the distance, every spaced answer leaves out at least
one of the two. So the spaced problem splits into two: the same relaxed problem with the first of
them forbidden, and with the second forbidden. Each is solved on the same exact route (the bits,
no general model), and its optimum or bound bounds the spaced answers it holds. The nodes are
taken best bound first; a node whose relaxed optimum is spaced gives a spaced answer; a node whose
bound cannot beat the best spaced answer is dropped. When no node is left the best spaced answer is
the spaced optimum; when the time share or the solve budget ends first, or a part's solve stops
before its proof (the parts are then too hard for the time left), the largest bound of the
nodes left (and of the best answer) is a valid bound, which the spaced route's answer keeps.

The route reads the same bits for every node, so a solve takes the relaxed route's time and
memory; no candidates x candidates matrix is formed (the pairs are read from the selected cameras'
positions).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from camplace.errors import CamplaceError

FOUND = ("optimal", "feasible")


@dataclass
class BranchOutcome:
    """What the branching found.

    Attributes
    ----------
    best : SolverResult or None
        The best spaced answer (a node's relaxed optimum whose cameras are spaced), or None.
    bound : float
        A valid upper bound on the spaced optimum (-inf when no spaced answer exists).
    closed : bool
        True when every node was solved or dropped: ``best`` is then the spaced optimum.
    stats : dict
        ``solves`` (relaxed solves, the first included), ``open`` (nodes left), ``stopped`` (why
        it stopped early, if it did).
    """

    best: Any
    bound: float
    closed: bool
    stats: dict = field(default_factory=dict)


def conflict(selected: Any, positions: np.ndarray, min_distance_m: float) -> tuple[int, int] | None:
    """The first pair of ``selected`` (in order) closer than ``min_distance_m``, or None.

    Parameters
    ----------
    selected : sequence of int
        Column indices.
    positions : (n, 3) float64
        Every candidate's position, metres.
    min_distance_m : float
    """
    sel = np.asarray(selected, dtype=np.int64)
    for i in range(sel.size - 1):
        gaps = np.linalg.norm(positions[sel[i + 1:]] - positions[sel[i]], axis=1)
        j = np.flatnonzero(gaps < min_distance_m)
        if j.size:
            return int(sel[i]), int(sel[i + 1 + j[0]])
    return None


def branch_on_conflicts(first: Any, solve_forbidding: Callable[[tuple[int, ...]], Any], positions: np.ndarray,
                        min_distance_m: float, forbidden: tuple[int, ...], free_columns: int, k: int,
                        expired: Callable[[], bool], tolerance: float, max_solves: int,
                        stall_solves: int) -> BranchOutcome:
    """Best-first branching on conflicting pairs from the relaxed answer ``first`` (maximisation).

    Parameters
    ----------
    first : SolverResult
        The relaxed problem's answer (status, objective, bound, selected), ``forbidden`` excluded.
    solve_forbidding : callable
        ``solve_forbidding(forbidden)``: the relaxed problem with those columns forbidden (a
        sorted tuple), solved on its route within the time left; may raise CamplaceError.
    positions : (n, 3) float64
        Candidate positions, metres.
    min_distance_m : float
    forbidden : tuple of int
        The relaxed problem's forbidden columns.
    free_columns : int
        Columns the relaxed problem may choose (not fixed, not forbidden).
    k : int
        New cameras to choose.
    expired : callable
        True once the branching's time is up.
    tolerance : float
        A node is dropped when its bound is at most the best spaced value plus this.
    max_solves : int
        Relaxed solves at most (the first included).
    stall_solves : int
        Stop when this many solves in a row have not lowered the bound (a problem where many
        parts keep the relaxed optimum's value, which branching would only multiply).

    Returns
    -------
    BranchOutcome
    """
    best, best_value = None, -math.inf
    heap: list = []
    unresolved: list[float] = []  # bounds of nodes that stopped on time with a spaced answer
    seen = {frozenset(forbidden)}
    solves, order, stopped = 1, 0, None

    def consider(res: Any, forb: frozenset, parent_bound: float = math.inf) -> None:
        nonlocal best, best_value, order
        if res.status not in FOUND:
            return  # no answer in this part (e.g. too few columns): nothing spaced there either
        if res.bound > parent_bound:  # a part holds fewer answers than its parent: its bound is no larger
            res = replace(res, bound=parent_bound)
        pair = conflict(res.selected, positions, min_distance_m)
        if pair is None:
            if res.objective > best_value:
                best, best_value = res, float(res.objective)
            if res.status != "optimal":
                unresolved.append(float(res.bound))
            return
        order += 1
        heapq.heappush(heap, (-float(res.bound), order, forb, pair))

    consider(first, frozenset(forbidden))
    low, since_low = math.inf, 0  # the lowest bound so far, and the solves since it fell
    while heap:
        if -heap[0][0] <= best_value + tolerance:
            heap.clear()  # no node left can beat the best spaced answer
            break
        top = max(-heap[0][0], best_value, *unresolved)
        if top < low - tolerance:
            low, since_low = top, 0
        if expired() or solves >= max_solves or since_low >= stall_solves:
            stopped = "time limit" if expired() else "solve budget" if solves >= max_solves else "no progress"
            break
        neg_bound, _, forb, pair = heapq.heappop(heap)
        for col in pair:
            child = forb | {col}
            if child in seen:
                continue  # the same part, reached by forbidding the pair's columns in another order
            seen.add(child)
            if free_columns - (len(child) - len(forbidden)) < k:
                continue  # fewer than k columns left: no answer there
            if expired():  # no solve is started after the time: the part stays open at its bound
                seen.discard(child)
                heapq.heappush(heap, (neg_bound, 0, forb, pair))
                stopped = "time limit"
                break
            try:
                res = solve_forbidding(tuple(sorted(child)))
            except CamplaceError:
                seen.discard(child)
                heapq.heappush(heap, (neg_bound, 0, forb, pair))  # this part stays open at its bound
                stopped = "a relaxed solve failed"
                break
            solves += 1
            since_low += 1
            consider(res, child, -neg_bound)
            if res.status != "optimal":  # a part not proven in the time left: the rest would not be either
                if col != pair[-1]:
                    heapq.heappush(heap, (neg_bound, 0, forb, pair))  # the pair's other part stays open
                stopped = "a part not proven"
                break
        if stopped:
            break
    bound = max([best_value, *unresolved, *(-b for b, *_ in heap)])
    closed = not heap and not unresolved
    return BranchOutcome(best, bound, closed, {"solves": solves, "open": len(heap) + len(unresolved),
                                               "stopped": stopped})
