"""The report's "Moving agents" section: the plan of ``OUTDIR/plan.json`` against the static system.

A timeline (each frame's share of the objective that the plan and the static system observe) and a
top view of the agents' paths over the event's track. Empty when the run folder has no plan.
"""

from __future__ import annotations

import csv
import logging
from pathlib import Path

import numpy as np

from camplace.errors import CamplaceError, plural

__all__ = ["plan_section", "timeline_png", "paths_png"]

log = logging.getLogger(__name__)

_AGENT_COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")


def timeline_png(times_s: np.ndarray, frame_weight: np.ndarray, plan_value: np.ndarray, static_value: np.ndarray,
                 phase_starts_s: np.ndarray, end_s: float, title: str) -> bytes:
    """Per frame: share of the frame's weight the plan and the static system score.

    Parameters
    ----------
    times_s, frame_weight, plan_value, static_value : (n_frames,) float64
    phase_starts_s : (P,) float64
    end_s : float
    """
    from camplace.report.figures import _figure, _png, plain

    fig = _figure(6.8, 3.4)
    ax = fig.add_subplot()
    fw = np.where(frame_weight > 0, frame_weight, np.nan)
    for p, s in enumerate(phase_starts_s):
        e = phase_starts_s[p + 1] if p + 1 < len(phase_starts_s) else end_s
        if p % 2 == 0:
            ax.axvspan(s, e, color="#eef1f5", zorder=0)
        ax.text((s + e) / 2, 1.0, f"phase {p}", ha="center", va="top", fontsize=7, color="#4a5263",
                transform=ax.get_xaxis_transform())
    ax.plot(times_s, 100 * plan_value / fw, "o-", ms=3, color="#d62728", label=f"plan ({plan_value.sum():.4f})")
    ax.plot(times_s, 100 * static_value / fw, "s--", ms=3, color="#4a5263", label=f"static ({static_value.sum():.4f})")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("share of the frame's weight (%)")
    ax2 = ax.twinx()
    ax2.bar(times_s, frame_weight, width=0.6 * (np.median(np.diff(times_s)) if len(times_s) > 1 else 1.0),
            color="#9aa3b5", alpha=0.25, zorder=0)
    ax2.set_ylabel("frame weight", color="#6b7385")
    ax2.tick_params(axis="y", colors="#6b7385")
    ax.set_zorder(ax2.get_zorder() + 1)
    ax.patch.set_visible(False)
    ax.set_title(plain(title), fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower center")
    return _png(fig)


def paths_png(paths_m: np.ndarray, static_m: np.ndarray, track_m: np.ndarray, volume: tuple, title: str,
              start_m: np.ndarray | None = None) -> bytes:
    """Top view (x, y) of the agents' paths, the static system and the event's track.

    Parameters
    ----------
    paths_m : (k, P, 3) float64
        Each agent's position in each phase.
    static_m : (k, 3) float64
    track_m : (n_frames, 3) float64
        The event's centre per frame.
    volume : ((3,), (3,))
        Camera volume min and max.
    start_m : (k, 3) float64, optional
    """
    from matplotlib.patches import Rectangle

    from camplace.report.figures import _figure, _png, plain

    fig = _figure(6.8, 5.0)
    ax = fig.add_subplot()
    lo, hi = np.asarray(volume[0], dtype=float), np.asarray(volume[1], dtype=float)
    ax.add_patch(Rectangle((lo[0], lo[1]), hi[0] - lo[0], hi[1] - lo[1], fill=False, ls=":", ec="#6b7385", lw=1))
    ax.plot(track_m[:, 0], track_m[:, 1], "-", color="#9aa3b5", lw=2, label="event track")
    ax.plot(track_m[:1, 0], track_m[:1, 1], ">", color="#9aa3b5", ms=7)
    for a in range(paths_m.shape[0]):
        c = _AGENT_COLOURS[a % len(_AGENT_COLOURS)]
        xy = paths_m[a, :, :2]
        if start_m is not None:
            ax.plot([start_m[a, 0], xy[0, 0]], [start_m[a, 1], xy[0, 1]], ":", color=c, lw=1)
            ax.plot(start_m[a, 0], start_m[a, 1], "s", color=c, mfc="none", ms=6)
        ax.plot(xy[:, 0], xy[:, 1], "o-", color=c, ms=4, lw=1.5, label=f"agent {a}")
        p = 0
        while p < xy.shape[0]:  # one label per stay: "2" or "2-4"
            q = p
            while q + 1 < xy.shape[0] and np.allclose(paths_m[a, q + 1], paths_m[a, p]):
                q += 1
            ax.annotate(str(p) if q == p else f"{p}-{q}", xy[p], textcoords="offset points", xytext=(4, 4 + 7 * (a % 3)),
                        fontsize=7, color=c)
            p = q + 1
    ax.plot(static_m[:, 0], static_m[:, 1], "kx", ms=8, mew=2, label="static system")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(plain(title), fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    return _png(fig)


def _read_timeline(path: Path) -> dict[str, np.ndarray]:
    cols = ("frame", "time_s", "phase", "frame_weight", "plan_value", "static_value")
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
        return {c: np.array([float(r[c]) for r in rows]) for c in cols}
    except (OSError, KeyError, ValueError) as exc:
        raise CamplaceError(f"{path}: cannot read the plan timeline ({exc}); re-run 'camplace plan'") from None


def plan_section(run) -> str:
    """HTML of the "Moving agents" section for a run (:class:`~camplace.report.compare.RunData`); "" without plan.json."""
    from camplace.plan.io import load_plan
    from camplace.report.markup import _img, _num, _table, esc

    path = Path(run.outdir) / "plan.json"
    if not path.is_file():
        return ""
    doc = load_plan(path)
    if not doc["agents"]:
        return (f"<h2 id='plan'>Moving agents</h2><p class='bad'>The planner found no feasible plan "
                f"(status {esc(doc['status'])}).</p>")
    plan = np.array([ag["candidates"] for ag in doc["agents"]], dtype=np.int64)
    n = len(run.candidates)
    if plan.min() < 0 or plan.max() >= n:
        raise CamplaceError(f"{path}: candidates out of range of the run's {n} (re-run 'camplace plan')")
    phases = doc["phases"]
    starts = np.array([ph["start_s"] for ph in phases], dtype=np.float64)
    static = list(doc.get("static_candidates") or [])
    obj, st = doc.get("objective"), doc.get("static_objective")
    gain = (obj - st) if obj is not None and st is not None else None
    rel = f" ({100 * gain / st:+.2f} %)" if gain is not None and st else ""
    summary = _table(None, [
        ("status", doc["status"]),
        ("agents, phases, speed", f"{plural(doc.get('k'), 'agent')}, {plural(len(phases), 'phase')}, {doc['speed_m_s']:g} m/s"),
        (f"objective ({doc.get('mode', 'maxcover')}, all phases)", _num(obj, 6)),
        ("proven bound", _num(doc.get("bound"), 6)),
        ("gap", f"{_num(100 * doc['gap'] if doc.get('gap') is not None else None, 4)} %"),
        ("best static system (a feasible plan)", f"{_num(st, 6)} ({doc.get('static_status', '')})"),
        ("plan minus static", f"{_num(gain, 6)}{rel}"),
        ("sum of per-phase optima (infinite speed)", _num(doc.get("unconstrained_bound"), 6)),
        ("engine", f"{doc.get('engine', '')}, {doc.get('time_s', 0.0):.1f} s"),
    ])
    reach = doc.get("reach_m") or []
    po, pb = doc.get("phase_objectives") or [], doc.get("phase_bounds") or []
    rows = []
    tl_path = Path(run.outdir) / "plan_timeline.csv"
    tl = _read_timeline(tl_path) if tl_path.is_file() else None
    static_by_phase = (np.bincount(tl["phase"].astype(np.int64), weights=tl["static_value"], minlength=len(phases))
                       if tl is not None else [None] * len(phases))
    for i, ph in enumerate(phases):
        fr = ph["frames"]
        rows.append((i, f"{fr[0]}–{fr[-1]}", f"{ph['start_s']:g}–{ph['end_s']:g}",
                     _num(po[i] if i < len(po) else None, 5), _num(static_by_phase[i], 5), _num(pb[i] if i < len(pb) else None, 5),
                     "–" if i == 0 or i - 1 >= len(reach) or reach[i - 1] is None else f"{reach[i - 1]:.1f}"))
    per_phase = _table(["phase", "frames", "time (s)", "plan", "static", "phase optimum", "reach from previous (m)"], rows)
    figs = []
    if tl is not None:
        try:
            figs.append(_img(timeline_png(tl["time_s"], tl["frame_weight"], tl["plan_value"], tl["static_value"], starts,
                                          float(phases[-1]["end_s"]), "share of each frame observed: plan vs static"),
                             "timeline", "Each frame's share of the objective: the moving agents (plan) against the best static system."))
        except (ValueError, TypeError) as exc:  # a malformed timeline must not stop the report
            log.warning("report: plan timeline figure skipped (%s)", exc)
    pos = run.candidates.positions
    from camplace.event import event_centres  # the target and its emitters, weighted, per frame

    track = event_centres(run.instance)
    start = np.asarray(doc["start_positions_m"], dtype=np.float64) if doc.get("start_positions_m") else None
    figs.append(_img(paths_png(pos[plan], pos[static] if static else np.zeros((0, 3)), track,
                               (run.instance.volume.min_m, run.instance.volume.max_m), "agents' paths, top view (labels: phase)",
                               start),
                     "paths", "Top view: each agent's position per phase (numbers), the static system (x) and the event's track."))
    return ("<h2 id='plan'>Moving agents</h2>"
            "<p class='note'>k agents reposition between phases of the event, each moving at most speed × (time between "
            "phase starts); re-aiming is free. The objective uses the run's point weights, so it compares directly with "
            "the static system's.</p>"
            + summary + per_phase + "<div class='grid'>" + "".join(figs) + "</div>")
