"""Multiview with a minimum angle and a minimum distance between the cameras, where the general
model (a row for every point and pair of cameras that may make the angle) does not fit.

The exact angle engine (:func:`~camplace.solver.engines.angle.search.solve_angle`) runs on the
same problem without the minimum distance. Dropping a constraint only widens the choice, so the
engine's bound (valid wherever it stops) bounds the spaced problem too, and its answer, when its
cameras are spaced and proven optimal, is the spaced optimum. Otherwise the answer is the best of
the caller's ``hints``, the engine's answer repaired (its cameras kept in turn while spaced, the
rest filled by :func:`spaced_greedy`) and :func:`spaced_greedy` from scratch, each valued exactly.

The matrix is what the angle engine reads: a canonical CSR matrix or column bitsets
(:class:`camplace.visibility.bits.BitMatrix`), so the same search serves the CSR route
(:func:`camplace.solver.routes._angle_spaced`) and the bits route (:func:`camplace.solver.api._solve`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from camplace.solver._support.deadline import Deadline
from camplace.solver._support.memory import OverBudget
from camplace.solver.engines.angle.search import greedy_angle, solve_angle

__all__ = ["SpacedAngle", "Neighbours", "neighbours", "spaced_greedy", "spaced_swaps", "solve_spaced_angle", "RELAXED_SHARE"]

log = logging.getLogger(__name__)

#: The share of the time left that the angle engine gets on the problem without the spacing; the
#: spaced answers (needed only when its answer is not spaced) take the rest. At half, a spaced
#: answer at comet-67p-bunker 10,000 x 50,000 (60 s) ended the solve after 31 s with a 3.6 % gap.
RELAXED_SHARE = 0.85


@dataclass
class SpacedAngle:
    """What :func:`solve_spaced_angle` found.

    Attributes
    ----------
    selected : tuple of int
        Fixed and new cameras (original indices, sorted), pairwise spaced.
    status : {"optimal", "feasible"}
    bound : float
        Valid upper bound on the spaced problem's objective.
    objective : float
        ``value(selected)``.
    stats : dict
        ``status``, ``bound``, ``objective`` and ``spaced`` of the engine on the relaxed problem,
        ``answers`` (the values of the spaced answers compared, when its answer was not spaced)
        and ``engine_stats`` (the engine's own).
    """

    selected: tuple[int, ...]
    status: str
    bound: float
    objective: float
    stats: dict[str, Any] = field(default_factory=dict)


class Neighbours:
    """The candidates closer than the minimum distance to each one: adjacency lists over the
    candidate index (CSR, built with two numpy passes; a Python set is made only for the few
    candidates asked for, as ``get`` of a dict of sets would return it).

    Parameters
    ----------
    conflicts : (p, 2) int64
        Pairs of candidates closer than the minimum distance (original indices).
    """

    def __init__(self, conflicts: np.ndarray) -> None:
        pairs = np.asarray(conflicts, dtype=np.int64).reshape(-1, 2)
        ends = np.concatenate([pairs[:, 0], pairs[:, 1]])
        others = np.concatenate([pairs[:, 1], pairs[:, 0]])
        n = int(ends.max()) + 1 if len(ends) else 0
        self._indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(ends, minlength=n), out=self._indptr[1:])
        self._others = others[np.argsort(ends, kind="stable")]

    def get(self, j: int, default: Any = None) -> Any:
        """The set of candidates closer than the minimum distance to ``j``, ``default`` when none."""
        j = int(j)
        if not 0 <= j < len(self._indptr) - 1 or self._indptr[j] == self._indptr[j + 1]:
            return default
        return set(self._others[self._indptr[j]:self._indptr[j + 1]].tolist())


def neighbours(conflicts: np.ndarray) -> Neighbours:
    """The candidates closer than the minimum distance to each one (:class:`Neighbours`).

    Parameters
    ----------
    conflicts : (p, 2) int64
        Pairs of candidates closer than the minimum distance (original indices).
    """
    return Neighbours(conflicts)


def spaced_greedy(q: Any, w: np.ndarray, k: int, views: int, min_angle_deg: float, pos: np.ndarray,
                  pts: np.ndarray, fixed: Sequence[int], free: np.ndarray, nbr: Neighbours,
                  keep: Sequence[int], deadline: Deadline) -> tuple[int, ...] | None:
    """``k`` new cameras in O(m + n) memory: ``keep`` (free, pairwise spaced columns), then one
    camera at a time the best addition with exact angles (:func:`greedy_angle` with k = 1, the
    cameras chosen so far fixed) among the free columns not closer than the minimum distance to a
    chosen one.

    Parameters
    ----------
    q : (m, n) scipy.sparse.csr_matrix or BitMatrix
    w : (m,) float64
    k, views : int
    min_angle_deg : float
    pos : (n, 3) float64
        Camera positions, metres.
    pts : (m, 3) float64
        Point positions, metres.
    fixed : sequence of int
        Fixed cameras (the free columns are already spaced from them).
    free : (f,) int64
        Columns the new cameras may be chosen from.
    nbr : Neighbours
        :func:`neighbours` of the conflicting pairs among the free columns.
    keep : sequence of int
        New cameras to start from.
    deadline : Deadline
        Each addition takes at most a third of the time left.

    Returns
    -------
    tuple of int or None
        The new cameras (original indices, sorted); None when the spacing leaves too few candidates.
    """
    free = np.asarray(free, dtype=np.int64)
    chosen = [int(j) for j in keep]
    banned = set(chosen).union(*(nbr.get(j, set()) for j in chosen))
    while len(chosen) < k:
        allowed = free[~np.isin(free, np.fromiter(banned, dtype=np.int64, count=len(banned)))]
        if allowed.size == 0:
            return None
        base = np.asarray(sorted({int(j) for j in fixed} | set(chosen)), dtype=np.int64)
        new = greedy_angle(q, w, 1, views, float(min_angle_deg), pos, pts, base, allowed, deadline=deadline.share(1 / 3))
        if len(new) != 1:
            return None
        chosen.append(int(new[0]))
        banned |= {int(new[0])} | nbr.get(int(new[0]), set())
    return tuple(sorted(chosen))


def solve_spaced_angle(q: Any, w: np.ndarray, k: int, views: int, min_angle_deg: float, pos: np.ndarray,
                       pts: np.ndarray, fixed: Sequence[int], free: np.ndarray, conflicts: np.ndarray,
                       value: Callable[[tuple[int, ...]], float], deadline: Deadline, budget_bytes: int, *,
                       start: Sequence[int] | None = None,
                       hints: Sequence[tuple[int, ...]] = ()) -> SpacedAngle | None:
    """The spaced problem's answer and a valid bound (see the module docstring); None when no
    spaced answer was found (the spacing leaves fewer than ``k`` cameras and no hint is given).

    Parameters
    ----------
    q, w, k, views, min_angle_deg, pos, pts, fixed, free
        As :func:`spaced_greedy`.
    conflicts : (p, 2) int64
        Pairs of free columns closer than the minimum distance.
    value : callable
        The objective of a set of cameras (fixed ones included, original indices).
    deadline : Deadline
    budget_bytes : int
        The angle engine's memory budget.
    start : sequence of int, optional
        New cameras for the engine's first incumbent (any set: the relaxed problem takes it).
    hints : sequence of tuple of int
        Spaced answers (fixed cameras included) found otherwise, compared with the others.

    Raises
    ------
    OverBudget
        The angle engine does not fit in ``budget_bytes`` (the caller falls back).
    """
    fixed_set = {int(j) for j in fixed}
    out = solve_angle(q, w, k, views, float(min_angle_deg), pos, pts, np.asarray(sorted(fixed_set), dtype=np.int64),
                      free, deadline=deadline.share(RELAXED_SHARE), budget_bytes=budget_bytes, start=start)
    new = [int(j) for j in out.selected if int(j) not in fixed_set]
    nbr = neighbours(conflicts)
    spaced = not any(nbr.get(a, set()) & set(new) for a in new)
    relaxed_sel = tuple(sorted(fixed_set | set(new)))
    stats: dict[str, Any] = {"status": out.status, "bound": float(out.bound), "spaced": spaced,
                             "objective": value(relaxed_sel), "engine_stats": dict(out.stats)}
    if spaced:
        return SpacedAngle(relaxed_sel, out.status, float(out.bound), stats["objective"], stats)
    keep: list[int] = []
    for j in new:  # the relaxed answer's cameras, kept while spaced
        if not nbr.get(j, set()) & set(keep):
            keep.append(j)
    cands = [tuple(h) for h in hints]
    for first in (keep, ()):
        got = spaced_greedy(q, w, k, views, min_angle_deg, pos, pts, sorted(fixed_set), free, nbr, first, deadline)
        if got is not None:
            cands.append(tuple(sorted(fixed_set | set(got))))
    if not cands:
        return None
    values = [value(c) for c in cands]
    best = int(np.argmax(values))
    stats["answers"] = [float(v) for v in values]
    sel, val, rounds = spaced_swaps(q, w, views, min_angle_deg, pos, pts, sorted(fixed_set), free, nbr,
                                    [j for j in cands[best] if j not in fixed_set], value, values[best], deadline)
    stats["swap_rounds"] = rounds
    return SpacedAngle(sel, "feasible", max(float(out.bound), val), val, stats)


def spaced_swaps(q: Any, w: np.ndarray, views: int, min_angle_deg: float, pos: np.ndarray, pts: np.ndarray,
                 fixed: Sequence[int], free: np.ndarray, nbr: Neighbours, new: Sequence[int],
                 value: Callable[[tuple[int, ...]], float], current: float,
                 deadline: Deadline) -> tuple[tuple[int, ...], float, int]:
    """Spaced 1-swaps: each new camera in turn is replaced by the best spaced addition to the others
    (:func:`spaced_greedy` from them), moving to the first exchange that gains, until none does or
    the deadline passes.

    Parameters
    ----------
    q, w, views, min_angle_deg, pos, pts, fixed, free, nbr
        As :func:`spaced_greedy`.
    new : sequence of int
        Pairwise spaced new cameras to start from.
    value : callable
        The objective of a set of cameras (fixed ones included).
    current : float
        ``value`` of ``new`` with the fixed cameras.
    deadline : Deadline

    Returns
    -------
    (selected, objective, rounds)
        The fixed and new cameras (sorted), their value and the rounds made.
    """
    fixed_set = {int(j) for j in fixed}
    new = [int(j) for j in new]
    rounds, moved = 0, True
    while moved and not deadline.expired():
        moved = False
        rounds += 1
        for i in range(len(new)):
            others = new[:i] + new[i + 1:]
            got = spaced_greedy(q, w, len(new), views, min_angle_deg, pos, pts, sorted(fixed_set), free, nbr, others,
                                deadline)
            if got is None or set(got) == set(new):
                continue
            v = value(tuple(sorted(fixed_set | set(got))))
            if v > current:
                new, current, moved = list(got), v, True
                break
    return tuple(sorted(fixed_set | set(new))), current, rounds
