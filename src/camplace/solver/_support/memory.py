"""The memory budget of the engines and the one policy for an engine that does not fit.

How many bytes an engine may allocate (:func:`memory_budget_bytes`, capped by
:func:`memory_budget`), the error an engine raises before allocating more (:class:`OverBudget`),
and what happens then: an engine asked for by name is a one-line error, under ``auto`` a logged
warning, ``stats["memory_fallback"]`` and the next engine (:func:`memory_fallback`,
:func:`exact_too_big`)."""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
from typing import Any, Iterator

from camplace.errors import CamplaceError

__all__ = ["MEMORY_FRACTION", "OverBudget", "memory_budget", "memory_budget_bytes", "memory_fallback", "exact_too_big",
           "too_big_message"]

log = logging.getLogger(__name__)

MEMORY_FRACTION = 0.6  # an engine's working memory may use this share of the memory available at its start
_FALLBACK_AVAILABLE = 4 << 30  # assumed when the platform does not say


class OverBudget(Exception):
    """An engine or model would need more memory than the budget (raised before allocating).

    Attributes
    ----------
    need, budget : int
        Estimated and allowed bytes.
    what : str
        The engine or model, e.g. ``"the angle engine"``.
    """

    def __init__(self, need: int, budget: int, what: str) -> None:
        self.need, self.budget, self.what = int(need), int(budget), what
        super().__init__(self.message)

    @property
    def message(self) -> str:
        """One line: what needs how much, and how much may be used."""
        return (f"{self.what} needs about {self.need / 2**30:.1f} GiB for this instance but only "
                f"{self.budget / 2**30:.1f} GiB may be used")


_BUDGET_CAP: contextvars.ContextVar[int | None] = contextvars.ContextVar("camplace_memory_budget", default=None)


@contextlib.contextmanager
def memory_budget(cap_bytes: int | None) -> Iterator[None]:
    """Within this context :func:`memory_budget_bytes` is at most ``cap_bytes`` (None: the
    enclosing cap, if any, stays).

    Parameters
    ----------
    cap_bytes : int or None
        The user's budget (``--memory-budget-gb``), in bytes.
    """
    if cap_bytes is not None and not cap_bytes > 0:
        raise CamplaceError(f"the memory budget must be > 0 bytes, got {cap_bytes!r}")
    outer = _BUDGET_CAP.get()
    cap = outer if cap_bytes is None else int(cap_bytes) if outer is None else min(outer, int(cap_bytes))
    token = _BUDGET_CAP.set(cap)
    try:
        yield
    finally:
        _BUDGET_CAP.reset(token)


def memory_budget_bytes() -> int:
    """Bytes an engine may allocate: :data:`MEMORY_FRACTION` of the memory available now, and at
    most the cap of an enclosing :func:`memory_budget` (the user's ``--memory-budget-gb``).

    Read from ``MemAvailable`` in ``/proc/meminfo`` (Linux), else from ``os.sysconf``; 4 GiB
    is assumed when neither says.
    """
    free = _available_fraction()
    cap = _BUDGET_CAP.get()
    return free if cap is None else min(cap, free)


def _available_fraction() -> int:
    """:data:`MEMORY_FRACTION` of the memory available now (bytes)."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if avail is None:
        try:
            avail = int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
        except (AttributeError, ValueError, OSError):
            avail = _FALLBACK_AVAILABLE
    return int(MEMORY_FRACTION * avail)


_FIX = {"exact": "use engine mip, or fewer candidates / points",
        "mip": "use engine exact, or fewer candidates / points",
        "cpsat": "use engine exact, or fewer candidates / points"}


def memory_fallback(exc: OverBudget, requested: str, name: str, stats: dict[str, Any], then: str) -> None:
    """Engine ``name`` does not fit: a one-line error when it was requested by name, otherwise a
    logged warning and ``stats["memory_fallback"]`` (``then`` says what happens instead)."""
    if requested == name:
        raise CamplaceError(f"{exc.message}; {_FIX.get(name, 'use fewer candidates / points')}")
    msg = f"{exc.message}; {then}"
    log.warning("%s", msg)
    stats["memory_fallback"] = msg


def too_big_message(need: int, budget: int) -> str:
    """The exact engine's one-line memory message."""
    return (f"the exact engine needs about {need / 2**30:.1f} GiB for this instance but only "
            f"{budget / 2**30:.1f} GiB may be used")


def exact_too_big(engine: str, stats: dict[str, Any], need: int, budget: int) -> None:
    """An exact engine of a k-camera mode would need more memory than is free: an error when
    ``exact`` was asked for, otherwise a logged fallback to the general model (recorded in ``stats``)."""
    msg = too_big_message(need, budget)
    if engine == "exact":
        raise CamplaceError(msg + "; use engine mip (or fewer candidates / points)")
    log.warning("%s; falling back to the general model", msg)
    stats["memory_fallback"] = msg
