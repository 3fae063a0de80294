"""The process's own clock: how long since the ``camplace`` process started.

A command's ``timings_s`` accounts for the whole process, not only its stages: ``startup`` (the
interpreter and the imports up to the command line's entry), ``setup`` (from there to the first
stage: the verb's imports, reading the instance and checking options) and ``process.untimed`` (the
wall time so far that no stage holds). :func:`mark_main` is called by the command line; a library
caller (a notebook that started hours ago) has no process start worth reporting, so nothing is
added there.
"""

from __future__ import annotations

import os
import time

__all__ = ["mark_main", "process_age_s", "main_marked_s", "account"]

_main_at: float | None = None  # perf_counter at the command line's entry
_startup_s: float | None = None  # process age then


def process_age_s() -> float | None:
    """Seconds since this process started (Linux ``/proc``; None elsewhere), 10 ms resolution."""
    try:
        with open("/proc/self/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        with open("/proc/uptime", encoding="ascii") as fh:
            uptime = float(fh.read().split()[0])
        return max(0.0, uptime - int(fields[19]) / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):  # pragma: no cover - not Linux
        return None


def mark_main() -> None:
    """Note the command line's entry (called first thing by :func:`camplace.cli.main`)."""
    global _main_at, _startup_s
    _main_at = time.perf_counter()
    _startup_s = process_age_s()


def main_marked_s() -> float | None:
    """Seconds since :func:`mark_main` (None when the command line did not start this process)."""
    return None if _main_at is None else time.perf_counter() - _main_at


def account(timings: dict[str, float], first_stage_at: float) -> None:
    """Add ``startup``, ``setup``, ``process.wall`` and ``process.untimed`` to a command's timings.

    Parameters
    ----------
    timings : dict of str to float
        The command's stage timings so far (seconds; keys without a dot are stages, dotted keys are
        parts of one). Changed in place; unchanged when the command line did not start the process.
    first_stage_at : float
        ``time.perf_counter()`` when the first stage began.
    """
    if _main_at is None or _startup_s is None:
        return
    timings["startup"] = _startup_s
    timings["setup"] = max(0.0, first_stage_at - _main_at)
    wall = _startup_s + (time.perf_counter() - _main_at)
    timings["process.wall"] = wall
    stages = sum(v for k, v in timings.items() if "." not in k)
    timings["process.untimed"] = max(0.0, wall - stages)
