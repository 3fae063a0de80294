"""The wall-clock deadline of a solve."""

from __future__ import annotations

import time

__all__ = ["Deadline"]


class Deadline:
    """The wall-clock deadline of a solve: made once, by :func:`camplace.solver.solve` from
    ``SolveOptions.time_limit_s``, and passed down to the mode's engines (which take their shares
    of what is left).

    Parameters
    ----------
    time_limit_s : float or None
        Seconds from ``start``; None means no limit.
    start : float, optional
        ``time.perf_counter()`` value the limit counts from (default: now).
    """

    def __init__(self, time_limit_s: float | None, start: float | None = None) -> None:
        self.start = time.perf_counter() if start is None else float(start)
        self.limit = None if time_limit_s is None else max(0.0, float(time_limit_s))

    def elapsed(self) -> float:
        """Seconds since ``start``."""
        return time.perf_counter() - self.start

    def remaining(self) -> float | None:
        """Seconds left (>= 0), or None without a limit."""
        if self.limit is None:
            return None
        return max(0.0, self.limit - self.elapsed())

    def left(self) -> float | None:
        """Seconds left, at least 1 ms (a time limit to hand to an engine), or None without a limit."""
        return None if self.limit is None else max(1e-3, self.limit - self.elapsed())

    def expired(self) -> bool:
        """True once the limit has passed."""
        return self.limit is not None and self.elapsed() >= self.limit

    def shortened(self, seconds: float) -> "Deadline":
        """The same deadline ``seconds`` earlier (for a step that must leave time to another)."""
        return Deadline(None if self.limit is None else self.limit - float(seconds), start=self.start)
