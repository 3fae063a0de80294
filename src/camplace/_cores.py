"""How many threads camplace's stages use: the cores this process may run on, unless told fewer.

The default is the process's CPU affinity mask (``os.sched_getaffinity``), not the machine's count:
``taskset``, containers and batch schedulers give a process fewer cores than the machine has, and
threads beyond them only contend. :func:`set_threads` (``--threads N`` on the command line,
``threads=`` in the API) lowers it for every stage: Embree casting, the matrix merge and store
workers, numba's parallel kernels, the set-cover searches and OR-Tools' workers.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import Iterator

__all__ = ["allowed_cores", "set_threads", "thread_count", "using_threads"]

_requested: int | None = None


def allowed_cores() -> int:
    """Cores this process may run on (its affinity mask; the machine's count where there is none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def check_threads(n: int | None) -> int | None:
    """``n`` if it is a usable thread count, else a :class:`ValueError` saying what is allowed."""
    if n is None:
        return None
    cores = allowed_cores()
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= cores:
        raise ValueError(f"threads must be a whole number from 1 to {cores} (the cores this process may use), "
                         f"got {n!r}")
    return n


def set_threads(n: int | None) -> None:
    """Use at most ``n`` threads in every stage of this process (None: all allowed cores).

    Sets numba's thread count (``NUMBA_NUM_THREADS`` before numba loads; ``numba.set_num_threads``
    after, for the calling thread).

    Raises
    ------
    ValueError
        When ``n`` is not a whole number from 1 to :func:`allowed_cores`.
    """
    global _requested
    _requested = check_threads(n)
    count = thread_count()
    if "numba" in sys.modules:
        import numba

        numba.set_num_threads(min(count, numba.config.NUMBA_NUM_THREADS))
    else:
        os.environ["NUMBA_NUM_THREADS"] = str(count)


def thread_count(requested: int | None = None) -> int:
    """Threads a stage should use: ``requested``, else :func:`set_threads`'s value, else all allowed cores."""
    return max(1, requested or _requested or allowed_cores())


@contextmanager
def using_threads(n: int | None) -> Iterator[int]:
    """Within the block, :func:`set_threads` ``(n)`` (``n`` None: leave the setting as it is); the
    previous setting comes back afterwards. Yields :func:`thread_count`. (``threads=`` of
    :func:`camplace.run` and ``SolveOptions.threads``.)"""
    if n is None:
        yield thread_count()
        return
    before = _requested
    set_threads(n)
    try:
        yield thread_count()
    finally:
        set_threads(before)
