"""Fixed blocks of work on one kept thread pool: how camplace's compiled kernels use every allowed core.

A kernel that treats rows (or columns) one by one gets a block version ``kernel(lo, hi, ...)``
(GIL-free, ``nogil=True``) writing into arrays made beforehand; :func:`run_blocks` calls it on
:func:`cuts` (a number of blocks that does not depend on the thread count) from a thread pool of
:func:`camplace._cores.thread_count` threads. Each block writes only its own part of the outputs,
and anything summed across blocks is summed in block order by the caller, so the result is the
same bits at every thread count. The visibility stage's passes over the finished matrix
(:mod:`camplace.visibility.bits`, :mod:`camplace.visibility.qbytes`,
:mod:`camplace.visibility.summary`) and the solver's share the pool (one home: a stage below the
solver may not import it, so it lives beside :mod:`camplace._cores`); ray casting keeps its own
pool of chunk futures (:func:`camplace.visibility.engine.compute_visibility`).

A thread pool rather than numba's ``prange`` (OpenMP here): measured on the shared 2-core
machine, an OpenMP region around a 15 ms pass waited 0.6-0.9 s at its barrier when the other core
was busy, while the pool's threads simply take the next block.
"""

from __future__ import annotations

import itertools
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

from camplace._cores import thread_count

__all__ = ["BLOCKS", "cuts", "work_cuts", "run_blocks", "threads_for", "PoolProfile"]

#: blocks per pass (fixed: results must not depend on the thread count)
BLOCKS = 64
#: below this much work (entries or words touched) one thread does it all (a pool costs ~0.1 ms)
PARALLEL_MIN_WORK = 200_000


def cuts(n: int, blocks: int = BLOCKS, align: int = 1) -> list[int]:
    """Boundaries ``[0, ..., n]`` of at most ``blocks`` blocks of ``range(n)``, each inner boundary
    a multiple of ``align`` (e.g. 512 rows: 8 bitset words, one cache line)."""
    if n <= 0:
        return [0, 0]
    units = -(-n // align)
    b = max(1, min(blocks, units))
    out = sorted({min(n, (units * i // b) * align) for i in range(b)} | {n})
    return out if out[0] == 0 else [0, *out]


def work_cuts(work, blocks: int = BLOCKS) -> list[int]:
    """Boundaries ``[0, ..., len(work)]`` of at most ``blocks`` contiguous blocks of about equal
    total ``work`` ((n,) array_like of non-negative numbers; an item heavier than a block's share is
    a block of its own): fixed by ``work``, not by the thread count."""
    import numpy as np

    w = np.asarray(work, dtype=np.float64)
    n = int(w.size)
    if n == 0:
        return [0, 0]
    cum = np.cumsum(w)
    targets = cum[-1] * np.arange(1, blocks, dtype=np.float64) / blocks
    return [int(c) for c in np.unique(np.concatenate([[0], np.searchsorted(cum, targets, side="right"), [n]]))]


def threads_for(work: int) -> int:
    """Threads for a pass of ``work`` units: :func:`thread_count`, or 1 below ``PARALLEL_MIN_WORK``."""
    return thread_count() if work >= PARALLEL_MIN_WORK else 1


class PoolProfile:
    """CPU seconds of the pool's workers, for benchmarks (``with PoolProfile() as p: ...``).

    Per :func:`run_blocks` call on a pool it adds ``p.cpu`` (every worker's CPU seconds) and
    ``p.critical`` (the busiest worker's): on idle cores a pass takes about its critical CPU
    time, whatever else the machine runs, so ``main thread CPU + critical`` estimates a stage's
    time at that thread count on a quiet machine."""

    active: "PoolProfile | None" = None

    def __init__(self) -> None:
        self.cpu = 0.0
        self.critical = 0.0
        self.calls = 0

    def __enter__(self) -> "PoolProfile":
        PoolProfile.active = self
        return self

    def __exit__(self, *exc) -> None:
        PoolProfile.active = None


_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()
_PREFIX = "camplace-block"


def _pool(threads: int) -> ThreadPoolExecutor:
    """The process's pool of ``threads`` workers, made on first use and kept: a solve makes some
    50 parallel passes, and starting 16 threads for each cost more than a short pass itself."""
    with _pools_lock:
        pool = _pools.get(threads)
        if pool is None:
            pool = _pools[threads] = ThreadPoolExecutor(max_workers=threads, thread_name_prefix=f"{_PREFIX}{threads}")
        return pool


def run_blocks(fn: Callable[[int, int], object], bounds: list[int], threads: int | None = None) -> list:
    """``fn(lo, hi)`` for every block of ``bounds`` (from :func:`cuts`), on ``threads`` threads
    (default :func:`thread_count`); returns the results in block order. Called from one of the
    pool's own workers, it runs the blocks there, one by one (no pool waits on itself)."""
    spans = list(zip(bounds[:-1], bounds[1:]))
    t = min(len(spans), thread_count() if threads is None else threads)
    if t <= 1 or threading.current_thread().name.startswith(_PREFIX):
        return [fn(lo, hi) for lo, hi in spans]
    prof = PoolProfile.active
    if prof is None:
        call = lambda s: fn(*s)  # noqa: E731
    else:
        per: dict[int, float] = {}

        def call(s):
            c0 = time.thread_time()
            out = fn(*s)
            ident = threading.get_ident()
            per[ident] = per.get(ident, 0.0) + time.thread_time() - c0
            return out
    # t tasks that take the next block in turn, not one pool task per block: a solve makes some 50
    # passes of 64 blocks, and each task's hand-out costs the main thread about 0.1 ms of GIL
    out: list = [None] * len(spans)
    turn = itertools.count()

    def take_turns() -> None:
        for i in iter(turn.__next__, None):
            if i >= len(spans):
                return
            out[i] = call(spans[i])

    for task in [_pool(t).submit(take_turns) for _ in range(t)]:
        task.result()  # waits; re-raises a block's error
    if prof is not None:
        prof.cpu += sum(per.values())
        prof.critical += max(per.values(), default=0.0)
        prof.calls += 1
    return out
