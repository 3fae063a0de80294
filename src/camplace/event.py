"""Where the event is and how much of it a camera system sees: event centres and aim points
(from the instance), row weights by event mode, covered rows and per-camera light curves.

Functions of plain data (an Instance, TargetPoints, a sparse matrix); numpy only.
"""

from __future__ import annotations

import numpy as np


def event_centres(instance) -> np.ndarray:
    """(n_frames, 3) float64 centre of what is observed in each frame.

    The weighted mean of the target's bounding-box centre (weight ``target_weight``) and the
    frame's emitter points (their weights).
    """
    out = []
    for f, frame in enumerate(instance.frames):
        c, w = [instance.target_centre(f) * frame.target_weight], frame.target_weight
        if frame.emitters is not None and len(frame.emitters):
            c.append(frame.emitters.weights @ frame.emitters.positions_m)
            w += float(frame.emitters.weights.sum())
        out.append(np.sum(c, axis=0) / w if w > 0 else instance.target_centre(f))
    return np.array(out)


def event_aims(instance, orientations: int = 1) -> np.ndarray:
    """Aim points of the candidate poses at each position.

    One orientation aims at the likelihood-weighted mean event centre. ``n > 1`` orientations aim
    at the event centres of ``n`` key frames, taken at the likelihood quantiles (i + 0.5) / n of
    the frame sequence (duplicates removed), so a moving target is followed.

    Returns
    -------
    (a, 3) float64
        ``a <= orientations`` distinct aim points.
    """
    centres = event_centres(instance)
    w = instance.frame_weights()
    if orientations <= 1 or len(centres) == 1:
        return (w @ centres)[None, :]
    cdf = np.cumsum(w)
    keys = np.searchsorted(cdf, (np.arange(orientations) + 0.5) / orientations, side="left")
    keys = np.unique(np.minimum(keys, len(centres) - 1))
    return centres[keys]


def peak_frame(instance) -> int:
    """Index of the maximum-likelihood frame (the first one on ties)."""
    return int(np.argmax([f.weight for f in instance.frames]))


def event_weights(pts, instance, event_mode: str) -> np.ndarray:
    """Row weights the solver maximises: all frames (P-weighted), or the peak frame alone (summing to 1)."""
    if event_mode == "all":
        return pts.weight
    in_peak = pts.frame == peak_frame(instance)
    w = np.where(in_peak, pts.weight, 0.0)
    s = w.sum()
    return w / s if s > 0 else w


def covered_rows(matrix, selected) -> np.ndarray:
    """(m,) bool: rows observed by at least one of the ``selected`` columns (one pass over the CSR
    arrays, :func:`camplace.visibility.summary.summarise`)."""
    from camplace.visibility.summary import summarise

    return summarise(matrix.tocsr(), np.ones(matrix.shape[0]), list(selected)).covered


def light_curves_csv(instance, vis, selected, seen: np.ndarray | None = None) -> str:
    """``light_curves.csv``: per chosen camera and frame, the event weight it observes.

    Columns: camera (0-based position in ``solution.json`` cameras), frame, observed_weight (sum of
    the row weights it observes in that frame; a frame's rows sum to its normalised likelihood),
    observed_fraction (observed_weight / the frame's weight), candidate (column index), time_s.
    ``seen`` (k, n_frames): the observed weights when already read (:class:`camplace.solution.Solution`'s
    ``light_curves``); else one pass over the matrix reads them.
    """
    from camplace.visibility.summary import summarise

    pts = vis.points
    n_frames = len(instance.frames)
    frame_total = np.bincount(pts.frame, weights=pts.weight, minlength=n_frames)
    lines = ["camera,frame,observed_weight,observed_fraction,candidate,time_s"]
    if seen is None:
        seen = summarise(vis.matrix, pts.weight, selected, pts.frame, n_frames=n_frames).seen
    for cam, j in enumerate(selected):
        for f in range(n_frames):
            frac = seen[cam, f] / frame_total[f] if frame_total[f] > 0 else 0.0
            lines.append(f"{cam},{f},{float(seen[cam, f])!r},{float(frac)!r},{int(j)},{float(instance.frames[f].time_s)!r}")
    return "\n".join(lines) + "\n"
