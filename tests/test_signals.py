"""Ctrl-C is held back, not lost, while compiled kernels run in the main thread."""

import os
import signal
import threading
import time

import pytest

from camplace._signals import ctrl_c_deferred


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
