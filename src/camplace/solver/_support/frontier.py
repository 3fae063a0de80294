"""The open tuples of the best-first searches (bitset, angle and quality-tree engines), and the one
best-first loop over them (:func:`best_first`)."""

from __future__ import annotations

import heapq
import math
import time
from typing import Any, Callable

import numpy as np

from camplace.solver._support.deadline import Deadline

__all__ = ["best_leaf", "push_chunks", "Frontier", "best_first"]

def best_leaf(children: np.ndarray, value: np.ndarray, leaf: np.ndarray) -> tuple[float, np.ndarray] | None:
    """The best tuple of leaves among expanded children (value -inf: not made or pruned).

    Parameters
    ----------
    children : (F, c, k) int64
    value : (F, c) float64
    leaf : (F, c) bool

    Returns
    -------
    (value, (k,) tree nodes) or None if no child is a tuple of leaves.
    """
    lv = np.where(leaf & np.isfinite(value), value, -np.inf)
    if lv.size == 0 or not np.isfinite(lv.max()):
        return None
    f, q = np.unravel_index(int(np.argmax(lv)), lv.shape)
    return float(lv[f, q]), children[f, q]


def push_chunks(stack_t: list[np.ndarray], stack_b: list[np.ndarray], children: np.ndarray, value: np.ndarray,
                leaf: np.ndarray, threshold: float, chunk: int) -> int:
    """Push the children that are not tuples of leaves and whose bound beats ``threshold`` onto a
    depth-first stack of chunks, in increasing bound order (the most promising is popped first).

    Returns the number of tuples pushed.
    """
    keep = np.isfinite(value) & ~leaf & (value > threshold)
    ch, cv = children[keep], value[keep]
    idx = np.argsort(cv, kind="stable")
    ch, cv = ch[idx], cv[idx]
    for c0 in range(0, cv.shape[0], chunk):
        stack_t.append(ch[c0 : c0 + chunk])
        stack_b.append(cv[c0 : c0 + chunk])
    return int(cv.shape[0])


class Frontier:
    """Open node tuples in chunks: best-first (a heap on each chunk's largest bound, so the
    reported bound falls as the search goes), depth-first from the newest chunks while more than
    ``depth_first_open`` tuples are open (memory). Children are kept in chunks of ``chunk`` tuples
    of similar bounds."""

    def __init__(self, tuples: np.ndarray, bounds: np.ndarray, depth_first_open: int, chunk: int) -> None:
        self.depth_first_open = depth_first_open
        self.chunk = chunk
        self.heap: list[tuple[float, int, np.ndarray, np.ndarray]] = []
        self.lifo: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.seq = 0
        self.n_open = 0
        self.peak = 0
        self.lifo_batches = 0
        self._add(tuples, bounds, lifo=False)

    def _add(self, tuples: np.ndarray, bounds: np.ndarray, lifo: bool) -> None:
        key = float(bounds.max())
        if lifo:
            self.lifo.append((key, tuples, bounds))
        else:
            self.seq += 1
            heapq.heappush(self.heap, (-key, self.seq, tuples, bounds))
        self.n_open += bounds.shape[0]
        self.peak = max(self.peak, self.n_open)

    def top(self) -> float:
        """Largest bound still open (-inf if none)."""
        out = -self.heap[0][0] if self.heap else -math.inf
        return max([out, *(key for key, _, _ in self.lifo)])

    def pop_batch(self, size: int, threshold: float) -> tuple[np.ndarray, np.ndarray]:
        """Up to about ``size`` open tuples whose bound beats ``threshold`` (newest depth-first
        chunks first, else the best chunks), and their bounds."""
        parts: list[np.ndarray] = []
        bparts: list[np.ndarray] = []
        got = 0
        from_lifo = bool(self.lifo)
        while got < size and (self.lifo if from_lifo else self.heap):
            if from_lifo:
                _, tup, tb = self.lifo.pop()
            else:
                if -self.heap[0][0] <= threshold:  # nothing left in the heap can win
                    self.n_open -= sum(e[3].shape[0] for e in self.heap)
                    self.heap.clear()
                    break
                _, _, tup, tb = heapq.heappop(self.heap)
            self.n_open -= tb.shape[0]
            keep = tb > threshold
            parts.append(tup[keep])
            bparts.append(tb[keep])
            got += int(keep.sum())
        self.lifo_batches += int(from_lifo)
        if not parts:
            return np.zeros((0, 0), dtype=np.int64), np.zeros(0)
        if len(parts) == 1:
            return parts[0], bparts[0]
        return np.concatenate(parts), np.concatenate(bparts)

    def push(self, children: np.ndarray, value: np.ndarray, leaf: np.ndarray, threshold: float) -> None:
        """The children that are not tuples of leaves and beat ``threshold``, in chunks of similar
        bounds (pushed so that the most promising chunk is popped first)."""
        keep = np.isfinite(value) & ~leaf & (value > threshold)
        ch, cv = children[keep], value[keep]
        idx = np.argsort(cv, kind="stable")
        ch, cv = ch[idx], cv[idx]
        lifo = self.n_open + cv.shape[0] > self.depth_first_open
        for c0 in range(0, cv.shape[0], self.chunk):
            self._add(ch[c0 : c0 + self.chunk], cv[c0 : c0 + self.chunk], lifo)


def best_first(
    front: Frontier,
    expand: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]],
    offer: Callable[[float, np.ndarray], None],
    threshold: Callable[[], float],
    deadline: Deadline,
    stats: dict[str, Any],
    *,
    max_open: int,
    batch: int,
    batch_min: int,
    batch_max: int,
    batch_s: float,
) -> tuple[str, float, int, float]:
    """The best-first loop of the tuple searches: pop a batch of open tuples that can still beat
    ``threshold()``, expand it, offer its best tuple of leaves, push the children that stay open.

    A batch takes about ``batch_s`` seconds at the rate of the previous one (at most a quarter of
    the time left, between ``batch_min`` and ``batch_max`` tuples). The search stops when the
    frontier is empty (``"optimal"``), at the deadline or with more than ``max_open`` open tuples
    (``"feasible"``; ``stats["stopped"]`` says which).

    Parameters
    ----------
    front : Frontier
        The open tuples (the root(s) already pushed).
    expand : callable
        ``expand(tuples, bounds) -> (children (F, c, k), value (F, c), leaf (F, c))``.
    offer : callable
        ``offer(value, leaves)`` with the best tuple of leaves of a batch (the engine keeps it if it
        beats its incumbent).
    threshold : callable
        The value an open tuple must beat (incumbent plus margin), read before every pop and push.
    deadline : Deadline
    stats : dict
        Gets ``stopped`` when the search does not finish.
    max_open : int
    batch, batch_min, batch_max : int
        The first batch size and the bounds of the later ones.
    batch_s : float

    Returns
    -------
    status : {"optimal", "feasible"}
    open_bound : float
        The largest bound still open (-inf when the search finished).
    batches : int
        Batches expanded.
    time_expand_s : float
        Seconds spent in ``expand``.
    """
    status, open_bound = "optimal", -math.inf
    batches = 0
    t_expand = 0.0
    while front.n_open:
        if deadline.expired() or front.n_open > max_open:
            status = "feasible"
            open_bound = front.top()
            stats["stopped"] = "time limit" if deadline.expired() else "open tuples"
            break
        tup, tup_bound = front.pop_batch(batch, threshold())
        if tup.shape[0] == 0:
            continue
        batches += 1
        t_batch = time.perf_counter()
        children, value, leaf = expand(tup, tup_bound)
        spent = time.perf_counter() - t_batch
        t_expand += spent
        # next batch: about batch_s seconds, and at most a quarter of the time left
        per = spent / tup.shape[0]
        left_s = deadline.remaining()
        want = batch_s if left_s is None else min(batch_s, 0.25 * left_s)
        batch = int(min(batch_max, max(batch_min, want / max(per, 1e-9))))
        top = best_leaf(children, value, leaf)
        if top is not None:
            offer(*top)
        front.push(children, value, leaf, threshold())
    return status, open_bound, batches, t_expand
