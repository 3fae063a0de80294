"""Ctrl-C around compiled (numba) code."""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator


@contextlib.contextmanager
def ctrl_c_deferred() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) back while kernels run in the main thread; raise it afterwards.

    numba loads and finalises machine code through ctypes callbacks into Python. A
    KeyboardInterrupt raised inside such a callback cannot cross the C frames: ctypes prints it
    and drops it, and the run would go on as if Ctrl-C had never been pressed. Inside this
    context, SIGINT only records itself, and KeyboardInterrupt is raised on exit. Outside the
    main thread (where Python never runs signal handlers) it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt
