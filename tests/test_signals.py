"""Ctrl-C is held back, not lost, while compiled kernels run in the main thread; and a Ctrl-C
that something swallowed during a command is raised again at the next progress stage or step."""

import os
import signal
import threading
import time

import pytest

from camplace._progress import ConsoleReporter, Reporter
from camplace._signals import check_ctrl_c, ctrl_c_deferred, ctrl_c_noted


def test_ctrl_c_is_raised_after_the_block_and_the_handler_restored() -> None:
    before = signal.getsignal(signal.SIGINT)
    ran_to_end = False
    with pytest.raises(KeyboardInterrupt):
        with ctrl_c_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # a KeyboardInterrupt here would skip the next line
            ran_to_end = True
    assert ran_to_end
    assert signal.getsignal(signal.SIGINT) is before


def test_no_ctrl_c_no_exception_and_worker_threads_untouched() -> None:
    with ctrl_c_deferred():
        pass
    seen = []

    def worker() -> None:
        with ctrl_c_deferred():  # outside the main thread: a no-op (signal.signal would raise)
            seen.append(signal.getsignal(signal.SIGINT))

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen == [signal.getsignal(signal.SIGINT)]


def _swallowed_ctrl_c() -> None:
    """A Ctrl-C whose KeyboardInterrupt is dropped (as ctypes does inside numba's callbacks)."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
    except KeyboardInterrupt:
        pass


@pytest.mark.parametrize("reporter", [Reporter(), ConsoleReporter()])
def test_a_swallowed_ctrl_c_is_raised_at_the_next_stage_and_step(reporter, capsys) -> None:
    before = signal.getsignal(signal.SIGINT)
    with ctrl_c_noted():
        with reporter.stage("first", total=3) as advance:
            advance(1)
            _swallowed_ctrl_c()
            with pytest.raises(KeyboardInterrupt):
                advance(1)
        with pytest.raises(KeyboardInterrupt):
            with reporter.stage("second"):
                pass
    assert signal.getsignal(signal.SIGINT) is before
    check_ctrl_c()  # the note ends with the command
    with reporter.stage("after the command") as advance:
        advance(1)


def test_a_ctrl_c_outside_a_command_leaves_no_note() -> None:
    """The API (no command around it): a deferred Ctrl-C is raised once, and later stages run."""
    with pytest.raises(KeyboardInterrupt):
        with ctrl_c_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
    check_ctrl_c()
    with Reporter().stage("next") as advance:
        advance(1)


def test_a_ctrl_c_dropped_in_a_ctypes_callback_prints_no_traceback(monkeypatch, caplog) -> None:
    """A Ctrl-C that lands inside a ctypes callback (numba loading machine code) is dropped by
    ctypes through ``sys.unraisablehook``: within a command it never reaches the hook that prints
    (no traceback), stays noted and is raised at the next check. An error in a callback before
    the Ctrl-C still reaches that hook; after it, an object whose construction the interrupt cut
    short and whose ``__del__`` then fails (as llvmlite's PipelineTuningOptions did in CI) goes
    to the debug log, not to the hook. The hook is restored afterwards."""
    import ctypes
    import gc
    import logging
    import sys

    seen: list[type] = []
    printer = lambda unraisable: seen.append(type(unraisable.exc_value))  # noqa: E731 - stands for the default hook
    monkeypatch.setattr(sys, "unraisablehook", printer)

    def interrupted() -> None:
        os.kill(os.getpid(), signal.SIGINT)  # the handler raises KeyboardInterrupt in the callback
        for _ in range(1000):
            pass

    def failing() -> None:
        raise ValueError("a real error in a callback")

    class HalfBuilt:
        """Like llvmlite's wrappers: ``__del__`` reads what ``__init__`` sets last."""

        def __init__(self) -> None:
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):
                pass
            self.handle = 1

        def __del__(self) -> None:
            del self.handle

    callback = ctypes.CFUNCTYPE(None)
    with caplog.at_level(logging.DEBUG, logger="camplace._signals"):
        with ctrl_c_noted():
            callback(failing)()  # before any Ctrl-C: a real error reaches the hook
            callback(interrupted)()  # ctypes drops the KeyboardInterrupt: the run goes on
            with pytest.raises(KeyboardInterrupt):
                check_ctrl_c()
            with pytest.raises(KeyboardInterrupt):
                HalfBuilt()
            gc.collect()
    assert seen == [ValueError]
    assert sys.unraisablehook is printer
    assert any("AttributeError" in r.getMessage() for r in caplog.records)
