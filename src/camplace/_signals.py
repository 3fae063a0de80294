"""Ctrl-C around compiled (numba) code, and for a whole command."""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import threading
from typing import Iterator


_log = logging.getLogger(__name__)
_NOTED = threading.Event()  # a Ctrl-C arrived during the current command (ctrl_c_noted)


def _note_and_raise(signum, frame) -> None:
    _NOTED.set()
    raise KeyboardInterrupt


@contextlib.contextmanager
def ctrl_c_noted() -> Iterator[None]:
    """For a whole command: every Ctrl-C (SIGINT) is noted before KeyboardInterrupt is raised.

    A KeyboardInterrupt raised while numba loads cached machine code outside
    :func:`ctrl_c_deferred` (a ctypes callback) is dropped by ctypes, which hands it to
    ``sys.unraisablehook``; here that hook drops it without a traceback, the note stays, and
    :func:`check_ctrl_c` (at every progress stage's start and step) raises it again, so Ctrl-C is
    never lost, at worst a little late. Once a Ctrl-C is noted the command is ending, and an
    object whose construction the interrupt cut short may fail in its ``__del__`` (llvmlite's
    wrappers raise AttributeError there): every unraisable error after the note goes to the
    log at debug level instead of printing a traceback (before the note, to the previous hook).
    Outside the main thread it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _NOTED.clear()
    previous = signal.signal(signal.SIGINT, _note_and_raise)
    previous_hook = sys.unraisablehook

    def hook(unraisable) -> None:
        if not _NOTED.is_set():
            previous_hook(unraisable)
        elif not isinstance(unraisable.exc_value, KeyboardInterrupt):  # noted: check_ctrl_c raises it again
            _log.debug("after Ctrl-C, ignored in %r: %r", unraisable.object, unraisable.exc_value)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        sys.unraisablehook = previous_hook
        _NOTED.clear()


def check_ctrl_c() -> None:
    """Raise KeyboardInterrupt if a Ctrl-C of this command was noted (it may have been dropped)."""
    if _NOTED.is_set():
        raise KeyboardInterrupt


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
