"""Best-effort, temporary limit on OpenBLAS threads (numpy's and scipy's bundled copies).

Why: the exact engine issues many small/medium BLAS calls. Multi-threaded OpenBLAS spins on
synchronisation between threads, and when the cores are oversubscribed (other processes busy) a
descheduled BLAS thread stalls every call: measured slowdowns of 5-15x on a 2-core machine, against
a gain of only ~1.3x from the second thread when the machine is idle. Limiting BLAS to one thread
for the duration of a solve makes run times predictable.

How: OpenBLAS exports ``*_set_num_threads``/``*_get_num_threads`` (with build-specific prefixes
and suffixes, e.g. ``scipy_openblas_set_num_threads64_``). The libraries already mapped into the
process are found in ``/proc/self/maps`` (Linux); elsewhere, or if nothing is found, this is a
no-op. If the user set ``OPENBLAS_NUM_THREADS`` explicitly, it is respected (no-op).
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
from typing import Iterator

__all__ = ["limit_blas_threads"]

log = logging.getLogger(__name__)

_SET = (
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)
_GET = (
    "scipy_openblas_get_num_threads64_",
    "scipy_openblas_get_num_threads",
    "openblas_get_num_threads64_",
    "openblas_get_num_threads",
)

_handles: list[tuple[ctypes.CDLL, str, str]] | None = None


def _openblas_handles() -> list[tuple[ctypes.CDLL, str, str]]:
    """(library, setter name, getter name) for every OpenBLAS mapped into this process."""
    global _handles
    if _handles is not None:
        return _handles
    found: list[tuple[ctypes.CDLL, str, str]] = []
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and ".so" in line})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=os.RTLD_NOLOAD if hasattr(os, "RTLD_NOLOAD") else 0)
        except OSError:
            continue
        setter = next((s for s in _SET if hasattr(lib, s)), None)
        getter = next((g for g in _GET if hasattr(lib, g)), None)
        if setter and getter:
            found.append((lib, setter, getter))
    _handles = found
    log.debug("OpenBLAS libraries found: %s", [(p, s) for p, (_, s, _) in zip(paths, found)])
    return found


@contextlib.contextmanager
def limit_blas_threads(n_threads: int | None) -> Iterator[None]:
    """Temporarily limit the OpenBLAS thread count; restore it on exit.

    Parameters
    ----------
    n_threads : int or None
        Threads to use inside the block; None leaves BLAS untouched.
    """
    if n_threads is None or "OPENBLAS_NUM_THREADS" in os.environ:
        yield
        return
    saved: list[tuple[ctypes.CDLL, str, int]] = []
    for lib, setter, getter in _openblas_handles():
        try:
            before = int(getattr(lib, getter)())
            getattr(lib, setter)(ctypes.c_int(int(n_threads)))
            saved.append((lib, setter, before))
        except Exception:  # pragma: no cover - exotic builds
            continue
    try:
        yield
    finally:
        for lib, setter, before in saved:
            getattr(lib, setter)(ctypes.c_int(before))
