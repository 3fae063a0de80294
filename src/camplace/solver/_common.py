"""Types and helpers shared by the solver engines."""

from __future__ import annotations

import contextlib
import contextvars
import heapq
import math
import os
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import scipy.sparse as sp

from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.solver import _bitkernels as _bk
from camplace.solver.presolve import as_pattern, check_weights

__all__ = ["EngineOutcome", "coverage_weight", "selected_row_stats", "Deadline", "memory_budget_bytes", "memory_budget",
           "OverBudget", "greedy_swap", "best_leaf", "push_chunks", "Frontier"]

MEMORY_FRACTION = 0.6  # an engine's working memory may use this share of the memory available at its start
_FALLBACK_AVAILABLE = 4 << 30  # assumed when the platform does not say


@dataclass(frozen=True)
class EngineOutcome:
    """What an engine returns on a presolved instance (indices are REDUCED column indices).

    Attributes
    ----------
    selected : tuple of int
        Reduced column indices (empty if no solution was found).
    status : str
        ``"optimal"``, ``"feasible"``, ``"infeasible"`` or ``"unknown"``.
    bound : float
        Proven upper bound on the optimum, in original weight units.
    stats : dict
        JSON-serialisable engine details.
    """

    selected: tuple[int, ...]
    status: str
    bound: float
    stats: dict[str, Any] = field(default_factory=dict)


class Deadline:
    """Wall-clock deadline helper.

    Parameters
    ----------
    time_limit_s : float or None
        Seconds from now; None means no limit.
    """

    def __init__(self, time_limit_s: float | None) -> None:
        self.start = time.perf_counter()
        self.limit = None if time_limit_s is None else max(0.0, float(time_limit_s))

    def elapsed(self) -> float:
        """Seconds since creation."""
        return time.perf_counter() - self.start

    def remaining(self) -> float | None:
        """Seconds left (>= 0), or None without a limit."""
        if self.limit is None:
            return None
        return max(0.0, self.limit - self.elapsed())

    def expired(self) -> bool:
        """True once the limit has passed."""
        return self.limit is not None and self.elapsed() >= self.limit


def greedy_swap(scores: Callable[[list[int]], np.ndarray], start: Sequence[int], k: int, margin: float,
                rounds: int, expired: Callable[[], bool] | None = None) -> list[int]:
    """Greedy completion of ``start`` to ``k`` columns, then 1-swap local search.

    Parameters
    ----------
    scores : callable
        ``scores(sel)`` is an (n,) array ranking every column x by the value of ``sel + [x]``
        (values or gains over ``sel``; entries of ``sel`` itself are ignored).
    start : sequence of int
        Columns to start from.
    k : int
        Columns wanted.
    margin : float
        A swap must improve by more than this.
    rounds : int
        Swap rounds at most (a round tries every position once).
    expired : callable, optional
        Stops the swaps when it returns True.

    Returns
    -------
    list of int
    """
    sel = list(start)
    while len(sel) < k:
        v = scores(sel)
        v[sel] = -np.inf
        sel.append(int(np.argmax(v)))
    for _ in range(rounds):
        if expired is not None and expired():
            break
        improved = False
        for p in range(k):
            others = sel[:p] + sel[p + 1 :]
            v = scores(others)
            cur = v[sel[p]]
            v[sel] = -np.inf
            j = int(np.argmax(v))
            if v[j] > cur + margin:
                sel[p] = j
                improved = True
        if not improved:
            break
    return sel


class OverBudget(Exception):
    """An engine or model would need more memory than the budget (raised before allocating).

    Attributes
    ----------
    need, budget : int
        Estimated and allowed bytes.
    what : str
        The engine or model, e.g. ``"the angle engine"``.
    """

    def __init__(self, need: int, budget: int, what: str) -> None:
        self.need, self.budget, self.what = int(need), int(budget), what
        super().__init__(self.message)

    @property
    def message(self) -> str:
        """One line: what needs how much, and how much may be used."""
        return (f"{self.what} needs about {self.need / 2**30:.1f} GiB for this instance but only "
                f"{self.budget / 2**30:.1f} GiB may be used")


_BUDGET_CAP: contextvars.ContextVar[int | None] = contextvars.ContextVar("camplace_memory_budget", default=None)


@contextlib.contextmanager
def memory_budget(cap_bytes: int | None) -> Iterator[None]:
    """Within this context :func:`memory_budget_bytes` is at most ``cap_bytes`` (None: the
    enclosing cap, if any, stays).

    Parameters
    ----------
    cap_bytes : int or None
        The user's budget (``--memory-budget-gb``), in bytes.
    """
    if cap_bytes is not None and not cap_bytes > 0:
        raise CamplaceError(f"the memory budget must be > 0 bytes, got {cap_bytes!r}")
    outer = _BUDGET_CAP.get()
    cap = outer if cap_bytes is None else int(cap_bytes) if outer is None else min(outer, int(cap_bytes))
    token = _BUDGET_CAP.set(cap)
    try:
        yield
    finally:
        _BUDGET_CAP.reset(token)


def memory_budget_bytes() -> int:
    """Bytes an engine may allocate: :data:`MEMORY_FRACTION` of the memory available now, and at
    most the cap of an enclosing :func:`memory_budget` (the user's ``--memory-budget-gb``).

    Read from ``MemAvailable`` in ``/proc/meminfo`` (Linux), else from ``os.sysconf``; 4 GiB
    is assumed when neither says.
    """
    free = _available_fraction()
    cap = _BUDGET_CAP.get()
    return free if cap is None else min(cap, free)


def _available_fraction() -> int:
    """:data:`MEMORY_FRACTION` of the memory available now (bytes)."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if avail is None:
        try:
            avail = int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
        except (AttributeError, ValueError, OSError):
            avail = _FALLBACK_AVAILABLE
    return int(MEMORY_FRACTION * avail)


def coverage_weight(matrix: Any, weights: Any, selected: Sequence[int]) -> float:
    """Total weight of the rows observed by at least one selected column.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix or array_like
        Visibility; values > 0 mean "observes".
    weights : (m,) array_like of float64
        Point weights.
    selected : sequence of int
        0-based column indices (duplicates are ignored).

    Returns
    -------
    float
        ``sum(weights[i] for rows i covered by selected)`` in float64.
    """
    if sp.issparse(matrix) and matrix.format == "csr":
        count, _ = selected_row_stats(matrix, selected)
        w = check_weights(weights, matrix.shape[0])
        return float(np.sum(w[count > 0], dtype=np.float64))
    a = sp.csc_matrix(matrix) if sp.issparse(matrix) else sp.csc_matrix(np.asarray(matrix))
    m, n = a.shape
    w = check_weights(weights, m)
    cols = sorted({int(j) for j in selected})
    if any(j < 0 or j >= n for j in cols):
        raise CamplaceError(f"selected column index out of range 0..{n - 1}: {cols}")
    if not cols:
        return 0.0
    sub = as_pattern(a[:, cols])
    covered = np.diff(sub.indptr) > 0
    return float(np.sum(w[covered], dtype=np.float64))


def selected_row_stats(matrix: sp.csr_matrix, selected: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a CSR matrix: number of selected columns with a value > 0, and their largest value.

    One compiled pass over the matrix (no copy), so it suits large visibility matrices.

    Parameters
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix
        Values > 0 mean "observes" (canonical or not: duplicates count separately).
    selected : sequence of int
        0-based column indices (duplicates are ignored).

    Returns
    -------
    count : (m,) int64
    vmax : (m,) float64
    """
    m, n = matrix.shape
    cols = sorted({int(j) for j in selected})
    if any(j < 0 or j >= n for j in cols):
        raise CamplaceError(f"selected column index out of range 0..{n - 1}: {cols}")
    chosen = np.zeros(n, dtype=bool)
    chosen[cols] = True
    data = np.asarray(matrix.data)
    if data.dtype.kind == "b":
        data = data.view(np.uint8)
    with ctrl_c_deferred():
        return _bk.selected_row_stats(matrix.indptr, matrix.indices, data, chosen)


def greedy_incumbent(matrix: sp.spmatrix, weights: np.ndarray, k: int, rounds: int = 20) -> tuple[int, ...]:
    """Greedy max coverage followed by first-improvement 1-swap local search (sparse).

    Parameters
    ----------
    matrix : (m, n) scipy.sparse matrix
        0/1 pattern.
    weights : (m,) float64
        Row weights.
    k : int
        Number of columns (``<= n``).
    rounds : int
        Maximum swap passes.

    Returns
    -------
    tuple of int
        ``k`` distinct column indices, sorted.
    """
    a = sp.csc_matrix(matrix)
    at = a.T.tocsr()
    m, n = a.shape
    w = np.asarray(weights, dtype=np.float64)
    sel: list[int] = []
    resid = w.copy()
    for _ in range(k):
        g = at @ resid
        if sel:
            g[sel] = -1.0
        j = int(np.argmax(g))
        sel.append(j)
        resid[a.indices[a.indptr[j] : a.indptr[j + 1]]] = 0.0
    cnt = np.asarray(a[:, sel].sum(axis=1)).ravel()
    for _ in range(rounds):
        improved = False
        for p in range(k):
            s = sel[p]
            col = np.zeros(m)
            col[a.indices[a.indptr[s] : a.indptr[s + 1]]] = 1.0
            others = cnt - col
            g = at @ np.where(others > 0, 0.0, w)
            cur = g[s]
            g[sel] = -1.0
            j = int(np.argmax(g))
            if g[j] > cur * (1.0 + 1e-12) + 1e-300:
                newcol = np.zeros(m)
                newcol[a.indices[a.indptr[j] : a.indptr[j + 1]]] = 1.0
                cnt = others + newcol
                sel[p] = j
                improved = True
        if not improved:
            break
    return tuple(sorted(sel))


def check_engine_and_limit(engine: str, engines, time_limit_s) -> None:
    """One-line errors for an unknown engine name or a non-positive time limit."""
    if engine not in engines:
        raise CamplaceError(f"unknown solver engine {engine!r} (choose one of {', '.join(engines)})")
    if time_limit_s is not None and not (float(time_limit_s) > 0.0):
        raise CamplaceError(f"time_limit_s must be > 0 seconds, got {time_limit_s!r}")


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


def remaining(t0: float, time_limit_s: float | None) -> float | None:
    """Seconds left of ``time_limit_s`` since ``t0`` (``time.perf_counter``), at least 1 ms; None without a limit."""
    return None if time_limit_s is None else max(1e-3, float(time_limit_s) - (time.perf_counter() - t0))


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
