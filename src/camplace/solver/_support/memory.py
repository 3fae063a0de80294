"""The memory budget of the engines and the one policy for an engine that does not fit.

How many bytes an engine may allocate (:func:`memory_budget_bytes`, capped by
:func:`memory_budget`), the error an engine raises before allocating more (:class:`OverBudget`),
and what happens then, decided in one place (:func:`memory_fallback`): an engine asked for by name,
or a step with nothing to fall back to, is a one-line error; otherwise a logged warning,
``stats["memory_fallback"]`` and the next engine.

The estimates a solve makes on its way are recorded too (:func:`note_memory`, collected by
:func:`memory_notes`; :func:`camplace.solver.solve` puts them in ``stats["memory_estimates"]``):
each step's estimate of what it is about to allocate, made with what is known just before it (the
presolved sizes for an engine that runs after the presolve), beside the bytes the solve holds
then (:func:`holding`: the input matrix, a presolved copy, the merged rows' CSR). The largest
``held + bytes`` over the steps is the solve's estimated peak besides the process's base."""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
from typing import Any, Iterator

from camplace.errors import CamplaceError

__all__ = ["MEMORY_FRACTION", "OverBudget", "holding", "matrix_bytes", "memory_budget", "memory_budget_bytes",
           "memory_fallback", "memory_notes", "note_memory"]

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


def memory_fallback(exc: OverBudget, stats: dict[str, Any] | None, *, asked: bool, then: str | None,
                    fix: str = "use fewer candidates / points", warn: bool = True) -> str:
    """The one memory policy: what happens when an engine, model or step needs more memory than
    the budget (``exc``, raised or made before anything large is allocated).

    It stops with a one-line :class:`~camplace.errors.CamplaceError` (``"<exc.message>; <fix>"``)
    when the thing that does not fit was asked for by name (``asked``: ``engine="exact"`` and the
    exact engine does not fit) or there is nothing to fall back to (``then`` is None). Otherwise
    the run goes on with ``then``: the message ``"<exc.message>; <then>"`` is logged as a warning
    and recorded in ``stats["memory_fallback"]``.

    Parameters
    ----------
    exc : OverBudget
        What does not fit: its estimated and allowed bytes.
    stats : dict or None
        The result's stats (None: nothing to record, e.g. when ``then`` is None).
    asked : bool
        The engine that does not fit is the one the caller asked for by name.
    then : str or None
        What happens instead (``"falling back to the general model"``); None: nothing.
    fix : str
        What the user can do (the end of the error).
    warn : bool
        Log the warning here (False: a pure caller, :func:`~camplace.solver.choose.choose_engine`,
        whose caller logs the recorded message).

    Returns
    -------
    str
        The message recorded.

    Raises
    ------
    CamplaceError
        When ``asked`` or ``then`` is None.
    """
    if asked or then is None:
        raise CamplaceError(f"{exc.message}; {fix}")
    msg = f"{exc.message}; {then}"
    if warn:
        log.warning("%s", msg)
    if stats is not None:
        stats["memory_fallback"] = msg
    return msg


_NOTES: contextvars.ContextVar[dict[str, dict[str, int]] | None] = contextvars.ContextVar("camplace_memory_notes",
                                                                                          default=None)
_HELD: contextvars.ContextVar[int] = contextvars.ContextVar("camplace_memory_held", default=0)


@contextlib.contextmanager
def memory_notes() -> Iterator[dict[str, dict[str, int]]]:
    """Collect the :func:`note_memory` calls made within this context into the dict yielded
    (``stage -> {"bytes": estimate, "held": bytes held then}``); nested contexts share the
    outermost one's dict (a solve within a solve: the warm start, the merged rows)."""
    outer = _NOTES.get()
    if outer is not None:
        yield outer
        return
    notes: dict[str, dict[str, int]] = {}
    token = _NOTES.set(notes)
    try:
        yield notes
    finally:
        _NOTES.reset(token)


@contextlib.contextmanager
def holding(nbytes: int) -> Iterator[None]:
    """Within this context the solve holds ``nbytes`` more (an array made and kept while the steps
    inside run: the input matrix, a presolved copy); :func:`note_memory` records the sum."""
    token = _HELD.set(_HELD.get() + max(0, int(nbytes)))
    try:
        yield
    finally:
        _HELD.reset(token)


def matrix_bytes(matrix: Any) -> int:
    """Bytes of the arrays of a matrix (column bitsets or bytes, a sparse matrix's data, indices
    and pointers, a dense array): what its holder keeps while a step runs, or a copy of it costs."""
    words = getattr(matrix, "words", None)
    if words is not None:
        return int(words.nbytes)
    parts = [getattr(matrix, name, None) for name in ("data", "indices", "indptr")]
    if any(p is not None for p in parts):
        return int(sum(getattr(p, "nbytes", 0) for p in parts if p is not None))
    return int(getattr(matrix, "nbytes", 0))


def held_bytes() -> int:
    """Bytes the enclosing :func:`holding` contexts hold (0 outside them)."""
    return _HELD.get()


def note_memory(stage: str, nbytes: int, extra_held: int = 0, refused: bool = False) -> None:
    """Record a step's estimate of the bytes it is about to allocate (``nbytes``, the figure it
    checks against the budget or counts for the run), beside the bytes held then
    (:func:`held_bytes` plus ``extra_held``, e.g. the conflicting pairs the step's caller keeps).
    A stage noted twice (a warm start and the full search) keeps its larger ``held + bytes``.
    A step that does not allocate because its estimate is over the budget (``refused``: it falls
    back or stops) is recorded as ``"<stage> (refused)"``: not a peak the run reached (an estimate
    noted for the same stage before the step found it was over, e.g. by an engine that checks
    inside, is dropped). Nothing is recorded outside :func:`memory_notes`.

    Parameters
    ----------
    stage : str
        The step, e.g. ``"presolve"``, ``"large-k"``, ``"model"``.
    nbytes : int
        Its estimate, bytes.
    extra_held : int
        Bytes held besides :func:`held_bytes`.
    refused : bool
        The estimate is over the budget: the step is not taken.
    """
    notes = _NOTES.get()
    if notes is None:
        return
    if refused:
        notes.pop(stage, None)
        stage = f"{stage} (refused)"
    got = {"bytes": int(nbytes), "held": held_bytes() + int(extra_held)}
    old = notes.get(stage)
    if old is None or got["bytes"] + got["held"] > old["bytes"] + old["held"]:
        notes[stage] = got
