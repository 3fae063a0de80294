"""The wall-clock deadline of a solve: made once per solve, passed to every engine.

The engines take this object (``deadline=``), never a number of seconds: they check it
(:meth:`Deadline.expired`, :meth:`Deadline.remaining`), cut their steps' slices from it
(:meth:`Deadline.share`, :meth:`Deadline.within`, :meth:`Deadline.shortened`), and time their
own stats from ``deadline.elapsed()`` at their start. A test injects one stand-in (an object with
the same methods) instead of patching a module's ``Deadline``.
"""

from __future__ import annotations

import time
from typing import Any, Callable

__all__ = ["Deadline", "as_deadline", "stopwatch"]


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

    def within(self, seconds: float) -> "Deadline":
        """A deadline (same start) ending ``seconds`` from now, or at this one's end if that is
        earlier: a step that may take at most ``seconds`` of what is left."""
        end = self.elapsed() + max(0.0, float(seconds))
        return Deadline(end if self.limit is None else min(end, self.limit), start=self.start)

    def share(self, fraction: float) -> "Deadline":
        """A deadline (same start) ending after ``fraction`` of the time left now: a step's slice of
        what is left (without a limit when this one has none)."""
        if self.limit is None:
            return Deadline(None, start=self.start)
        left = max(0.0, self.limit - self.elapsed())
        return Deadline(self.elapsed() + max(0.0, float(fraction)) * left, start=self.start)


def as_deadline(deadline: Any) -> Any:
    """``deadline`` itself, or a :class:`Deadline` without a limit when it is None (an engine
    called on its own, outside :func:`camplace.solver.solve`)."""
    return Deadline(None) if deadline is None else deadline


def stopwatch(deadline: Any) -> Callable[[], float]:
    """Seconds since now, read from ``deadline``'s clock: an engine's own timings (its stats)
    while it checks the solve's one deadline."""
    t0 = deadline.elapsed()
    return lambda: deadline.elapsed() - t0
