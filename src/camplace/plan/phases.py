"""Splitting the event's frames into consecutive phases, and how far an agent travels between them.

A phase is a run of consecutive frames during which every agent holds one pose. Frame ``f`` lasts
from its ``time_s`` to the next frame's (the last frame as long as the one before it, 1 s when the
event has a single frame), so the event spans ``[t_0, t_end)``. Agents travel in a straight line
between the starts of consecutive phases: between phase ``p`` and ``p + 1`` an agent moves at most
``speed_m_s * (start_s[p + 1] - start_s[p])`` metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from camplace.errors import CamplaceError, plural

__all__ = ["Phase", "event_end_s", "split_phases", "reach_m", "start_reach_m", "phase_of_frame"]


@dataclass(frozen=True)
class Phase:
    """One phase of the event.

    Attributes
    ----------
    index : int
        0-based, in time order.
    frames : tuple of int
        The frame indices it holds (consecutive, at least one).
    start_s, end_s : float
        When it starts and ends, seconds (``end_s`` is the next phase's ``start_s``).
    """

    index: int
    frames: tuple[int, ...]
    start_s: float
    end_s: float

    def to_dict(self) -> dict:
        """The ``phases`` entry of ``plan.json``."""
        return {"index": int(self.index), "frames": [int(f) for f in self.frames], "start_s": float(self.start_s),
                "end_s": float(self.end_s)}


def event_end_s(frame_times_s: np.ndarray) -> float:
    """End of the event: the last frame's time plus the duration of the frame before it (1 s for one frame)."""
    t = np.asarray(frame_times_s, dtype=np.float64)
    last = float(t[-1] - t[-2]) if t.size > 1 else 1.0
    return float(t[-1] + (last if last > 0 else 1.0))


def split_phases(
    frame_times_s: Sequence[float] | np.ndarray,
    n_phases: int | None = None,
    phase_starts_s: Sequence[float] | None = None,
    *,
    field: str = "phases",
) -> tuple[Phase, ...]:
    """Split the frames into consecutive phases.

    Parameters
    ----------
    frame_times_s : (n_frames,) float64
        Each frame's ``time_s``, non-decreasing.
    n_phases : int, optional
        Phases of equal duration: the event's span ``[t_0, t_end)`` (see :func:`event_end_s`) is cut
        into ``n_phases`` equal intervals and each frame goes to the interval holding its time.
    phase_starts_s : sequence of float, optional
        Instead of ``n_phases``: strictly increasing phase start times; the first must not come after
        the first frame. Frame ``f`` belongs to the last phase starting at or before its time.
    field : str
        Name of the setting in error messages.

    Returns
    -------
    tuple of Phase
        Every phase holds at least one frame.

    Raises
    ------
    CamplaceError
        When a phase would hold no frame, or the settings are malformed.
    """
    t = np.asarray(frame_times_s, dtype=np.float64)
    if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)):
        raise CamplaceError("the event has no frames with finite time_s")
    if np.any(np.diff(t) < 0):
        raise CamplaceError("frame times (time_s) must not decrease to split the event into phases")
    end = event_end_s(t)
    if (n_phases is None) == (phase_starts_s is None):
        raise CamplaceError(f"{field}: give a number of phases or the phase start times (one of them)")
    if n_phases is not None:
        if isinstance(n_phases, bool) or int(n_phases) != n_phases or n_phases < 1:
            raise CamplaceError(f"{field}: the number of phases must be an integer >= 1, got {n_phases!r}")
        n = int(n_phases)
        if n > t.size:
            raise CamplaceError(f"{field}: {n} phases but the event has only {plural(t.size, 'frame')} (use at most {t.size})")
        starts = t[0] + (end - t[0]) * np.arange(n) / n
    else:
        starts = np.asarray([float(s) for s in phase_starts_s], dtype=np.float64)  # type: ignore[union-attr]
        if starts.size == 0 or not np.all(np.isfinite(starts)) or np.any(np.diff(starts) <= 0):
            raise CamplaceError(f"{field}: phase start times must be finite and strictly increasing, got {list(starts)}")
        if starts[0] > t[0]:
            raise CamplaceError(f"{field}: the first phase starts at {starts[0]:g} s, after the first frame ({t[0]:g} s); "
                                f"start it at {t[0]:g} s or earlier")
    # frame f -> last phase starting at or before time_s (a tiny tolerance for the equal splits)
    tol = 1e-9 * max(1.0, abs(end - t[0]))
    owner = np.searchsorted(starts, t + tol, side="right") - 1
    phases = []
    for p in range(starts.size):
        frames = tuple(int(f) for f in np.flatnonzero(owner == p))
        if not frames:
            raise CamplaceError(f"{field}: phase {p} (from {starts[p]:g} s) holds no frame; use fewer phases or other start times")
        stop = float(starts[p + 1]) if p + 1 < starts.size else max(end, float(starts[p]))
        phases.append(Phase(index=p, frames=frames, start_s=float(starts[p]), end_s=stop))
    return tuple(phases)


def reach_m(phases: Sequence[Phase], speed_m_s: float) -> np.ndarray:
    """(n_phases - 1,) float64: how far an agent may travel between consecutive phases, metres.

    ``speed_m_s * (start_s[p + 1] - start_s[p])``; ``inf`` speed gives ``inf``.
    """
    if not (speed_m_s >= 0):
        raise CamplaceError(f"speed: must be >= 0 m/s, got {speed_m_s!r}")
    starts = np.array([ph.start_s for ph in phases], dtype=np.float64)
    dt = np.diff(starts)
    if math.isinf(speed_m_s):
        return np.full(dt.shape, math.inf)
    return float(speed_m_s) * dt


def start_reach_m(phases: Sequence[Phase], speed_m_s: float, start_time_s: float | None) -> tuple[float, float]:
    """When the agents stand at their start positions, and how far they may go from there to their first pose.

    Parameters
    ----------
    phases : sequence of Phase
    speed_m_s : float
    start_time_s : float or None
        Default: one phase duration (the first phase's) before the first phase starts.

    Returns
    -------
    start_time_s : float
    reach_m : float
    """
    first = phases[0]
    t0 = first.start_s - (first.end_s - first.start_s) if start_time_s is None else float(start_time_s)
    if not t0 < first.start_s:
        raise CamplaceError(f"start time: {t0:g} s must be before the first phase starts ({first.start_s:g} s)")
    dist = math.inf if math.isinf(speed_m_s) else float(speed_m_s) * (first.start_s - t0)
    return t0, dist


def phase_of_frame(phases: Sequence[Phase], n_frames: int) -> np.ndarray:
    """(n_frames,) int64: the phase of each frame."""
    out = np.full(int(n_frames), -1, dtype=np.int64)
    for ph in phases:
        out[list(ph.frames)] = ph.index
    if np.any(out < 0):
        raise CamplaceError("the phases do not cover every frame")
    return out
