"""The wall-clock deadline of a solve, and the check of a time limit."""

from __future__ import annotations

import time

from camplace.errors import CamplaceError

__all__ = ["Deadline", "remaining", "check_engine_and_limit"]

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


def remaining(t0: float, time_limit_s: float | None) -> float | None:
    """Seconds left of ``time_limit_s`` since ``t0`` (``time.perf_counter``), at least 1 ms; None without a limit."""
    return None if time_limit_s is None else max(1e-3, float(time_limit_s) - (time.perf_counter() - t0))


def check_engine_and_limit(engine: str, engines, time_limit_s) -> None:
    """One-line errors for an unknown engine name or a non-positive time limit."""
    if engine not in engines:
        raise CamplaceError(f"unknown solver engine {engine!r} (choose one of {', '.join(engines)})")
    if time_limit_s is not None and not (float(time_limit_s) > 0.0):
        raise CamplaceError(f"time_limit_s must be > 0 seconds, got {time_limit_s!r}")
