"""The report's 3D view of a run: occluders, the target coloured by coverage, the chosen cameras.

:func:`run_scene` turns a run folder's data (instance.toml, solution.json, candidates.csv,
points.csv, visibility.cpm, as read by :func:`camplace.report.compare.load_run_data`) into a
:class:`camplace.plotly3d.Scene3D`; :func:`scene3d_section` is the report's HTML section.

Coverage of a point = how many of the optimised system's cameras observe it, read from the
visibility matrix (``> 0``). For an event with several frames the view shows the peak frame (the
target there and that frame's rows) and the target's trajectory (its centre in every frame).
"""

from __future__ import annotations

import html
import logging
from typing import Any, Sequence

import numpy as np

from camplace.errors import CamplaceError
from camplace.plotly3d import Scene3D, SceneCamera, SceneMesh, reach_depth

log = logging.getLogger(__name__)

__all__ = ["system_columns", "multiview_counted", "run_scene", "scene3d_section", "SECTION_ID", "PLOT_ID"]

#: The report's ids: the section heading (the navigation's target) and the plot element (its data
#: tag is ``PLOT_ID + "-data"``). Every id in a page must be unique: plotly draws into the first
#: element with its id, so a heading sharing it received the plot.
SECTION_ID = "view3d"
PLOT_ID = "scene3d"

#: Positions and rotations equal within this are the same camera.
SAME_POSE = 1e-9


def _find_pose(positions: np.ndarray, rotations: np.ndarray, pos: np.ndarray, rot: np.ndarray) -> int | None:
    """Index of the pose equal to (pos, rot) in flat arrays, or None."""
    hit = np.flatnonzero(np.all(np.abs(positions - pos) <= SAME_POSE, axis=1)
                         & np.all(np.abs(rotations - rot) <= SAME_POSE, axis=(1, 2)))
    return int(hit[0]) if len(hit) else None


def system_columns(run, comp=None, campaigns: Sequence = ()) -> tuple[list[dict], Any, str]:
    """The optimised system's cameras and their visibility columns on the run's rows.

    The run's own system unless the comparison re-solved over the union with campaign cameras
    (``comp.method == "union"``); then each camera is found by its pose among the run's candidates
    or the campaigns' cameras.

    Returns
    -------
    cameras : list of dict
        ``label``, ``position`` (3,), ``rotation`` (3, 3).
    columns : (n_points, k) scipy.sparse.csc_matrix
    note : str
        Which system this is.
    """
    import scipy.sparse as sp

    sol = run.solution
    own = ([{"label": f"camera {n} (candidate {int(c['candidate'])})", "position": np.asarray(c["position"], dtype=np.float64),
             "rotation": np.asarray(c["rotation"], dtype=np.float64), **_intrinsics(run.instance, c.get("model_index"))}
            for n, c in enumerate(sol.cameras, start=1)],
           run.matrix[:, [int(c["candidate"]) for c in sol.cameras]].tocsc(), "the run's system")
    if comp is None or comp.method != "union":
        return own
    cams, cols = [], []
    cand = run.candidates
    for n, c in enumerate(comp.cameras, start=1):
        pos, rot = np.asarray(c["position"], dtype=np.float64), np.asarray(c["rotation"], dtype=np.float64)
        j = _find_pose(cand.positions, cand.rotations, pos, rot)
        col = run.matrix[:, j] if j is not None else None
        for camp in campaigns if col is None else ():
            hit = _find_pose(camp.positions.reshape(-1, 3), camp.rotations.reshape(-1, 3, 3), pos, rot)
            if hit is not None and camp.matrix is not None:
                col = sp.csr_matrix(camp.matrix)[:, hit]
                break
        if col is None:
            log.warning("report: 3D view: camera %s of the re-solved system is neither a run candidate nor a campaign camera; "
                        "showing the run's system", c.get("source"))
            return own[0], own[1], "the run's system (the re-solved system's columns were not found)"
        cams.append({"label": f"camera {n} ({c.get('source', '?')})", "position": pos, "rotation": rot,
                     **_intrinsics(run.instance, c.get("model_index"))})
        cols.append(col)
    return cams, sp.hstack(cols, format="csc"), "the system re-solved over the union with the campaign cameras"


def multiview_counted(points: np.ndarray, seen: np.ndarray, positions: np.ndarray, views: int,
                      min_angle_deg: float | None = None) -> np.ndarray:
    """The rows the multiview objective credits (as :func:`camplace.solver.mode_value`).

    Parameters
    ----------
    points : (m, 3) float64
        Row positions, metres.
    seen : (m, k) bool
        Which of the system's cameras observe each row.
    positions : (k, 3) float64
        The cameras' centres.
    views : int
        Cameras a row needs.
    min_angle_deg : float or None
        Two of them must see the row from directions at least this far apart (at the row).

    Returns
    -------
    (m,) bool
    """
    seen = np.asarray(seen, dtype=bool)
    ok = seen.sum(axis=1) >= int(views)
    if min_angle_deg is None:
        return ok
    rows = np.flatnonzero(ok)
    rays = np.asarray(positions, dtype=np.float64)[None, :, :] - np.asarray(points, dtype=np.float64)[rows, None, :]
    rays /= np.maximum(np.linalg.norm(rays, axis=2, keepdims=True), 1e-300)
    good = np.zeros(len(rows), dtype=bool)
    k = seen.shape[1]
    for a in range(k):
        for b in range(a + 1, k):
            both = seen[rows, a] & seen[rows, b]
            ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", rays[:, a], rays[:, b]), -1.0, 1.0)))
            good |= both & (ang >= float(min_angle_deg))
    ok[rows] = good
    return ok


def _intrinsics(instance, model: int | None) -> dict:
    """A team camera's record fields K, width, height, near_m, far_m (its model's); nothing without a team."""
    if model is None or getattr(instance, "team", None) is None:
        return {}
    m = instance.cameras[int(model)]
    return {"K": m.K().tolist(), "width": m.width_px, "height": m.height_px, "near_m": m.near_m, "far_m": m.far_m}


def _scene_cameras(records: Sequence[dict], sol, depth_points: np.ndarray) -> tuple[SceneCamera, ...]:
    """The records' cameras, with their own intrinsics when they carry them (a team's), else the first chosen camera's."""
    ref = sol.cameras[0]
    out = []
    for r in records:
        src = r if "K" in r else ref
        near, far = float(src.get("near_m", 0.0)), float(src.get("far_m", np.inf))
        d = reach_depth(r["position"], r["rotation"], depth_points, near, far)
        out.append(SceneCamera(r["label"], r["position"], r["rotation"], np.asarray(src["K"], dtype=np.float64), int(src["width"]),
                               int(src["height"]), near_m=near, depth_m=d, note=r.get("note", "")))
    return tuple(out)


def _campaign_systems(campaigns: Sequence, sol, depth_points: np.ndarray, instance=None) -> tuple[tuple[str, tuple[SceneCamera, ...]], ...]:
    """The best and the median system of each campaign."""
    out = []
    for c in campaigns:
        order = np.argsort(c.objective, kind="stable")
        n = len(order)
        if n == 0:
            continue
        for s, label in ((int(order[-1]), "best"), (int(order[int(round(0.5 * (n - 1)))]), "median")):
            recs = [{"label": f"{c.name} {label} s{s + 1} c{j + 1}", "position": c.positions[s, j], "rotation": c.rotations[s, j],
                     "note": f"{c.name} system {s + 1} ({label}, objective {c.objective[s]:.4f}) camera {j + 1}",
                     **_intrinsics(instance, None if getattr(c, "model", None) is None else int(c.model[s, j]))} for j in range(c.k)]
            out.append((f"{c.name} {label} (objective {c.objective[s]:.4f})", _scene_cameras(recs, sol, depth_points)))
    return tuple(out)


def run_scene(run, comp=None, campaigns: Sequence = ()) -> Scene3D:
    """The 3D scene of a run (at its peak frame), coloured by the optimised system's coverage.

    Parameters
    ----------
    run : camplace.report.compare.RunData
    comp : camplace.report.compare.Comparison or None
        The optimised system (None: the run's own system).
    campaigns : sequence of Campaign
        Their best and median systems are added (hidden until clicked in the legend).

    Returns
    -------
    Scene3D
    """
    from camplace.report.campaign import scoring_of

    inst, sol = run.instance, run.solution
    pts = run.points
    n_frames = len(inst.frames)
    peak = int(getattr(sol, "peak_frame", 0) or 0)
    peak = peak if 0 <= peak < n_frames else 0
    records, cols, which = system_columns(run, comp, campaigns)
    seen = (cols > 0).toarray()
    counts_all = seen.sum(axis=1).astype(np.int64)
    rows = np.flatnonzero(pts.frame == peak)
    tv, tf = inst.target_world(peak)
    depth_points = np.vstack([tv, pts.positions[rows]]) if len(rows) else tv
    cams = _scene_cameras(records, sol, depth_points)
    notes = [f"Cameras: {which}; frusta from the near limit to the depth that reaches the target (lens distortion ignored)."]
    counted = None
    scoring = scoring_of(sol)
    if scoring["mode"] == "multiview":
        views, angle = scoring["views"], scoring["min_angle_deg"]
        counted_all = multiview_counted(pts.positions, seen, np.array([r["position"] for r in records]), views, angle)
        counted = counted_all[rows]
        cond = f" and two of them see it from directions at least {angle:g} deg apart" if angle is not None else ""
        notes.append(f"Multiview: a point counts when at least {views} of the chosen cameras observe it{cond}; the counted points "
                     f"weigh {float(run.weights[counted_all].sum()):.6f} (the objective); legend entry 'counted by the objective'.")
    trajectory = labels = None
    if n_frames > 1:
        observed = counts_all > 0
        fw = np.bincount(pts.frame, weights=pts.weight, minlength=n_frames)
        fo = np.bincount(pts.frame[observed], weights=pts.weight[observed], minlength=n_frames)
        trajectory = np.array([inst.target_centre(f) for f in range(n_frames)])
        labels = tuple(f"frame {f}{' (shown)' if f == peak else ''}: t = {fr.time_s:g} s, P = {p:.4f}, "
                       f"{100.0 * fo[f] / fw[f] if fw[f] > 0 else 0.0:.1f} % of the frame's weight observed"
                       for f, (fr, p) in enumerate(zip(inst.frames, inst.frame_weights(), strict=True)))
        notes.append(f"Event of {n_frames} frames: the target and the points of the peak frame {peak} are shown, with the "
                     "target's centre in every frame (hover for each frame's observed share).")
    emit = pts.is_emitter[rows]
    if emit.any():
        notes.append(f"{int(emit.sum()):,} of the frame's {len(rows):,} points are emitter points (coma, plume) with no surface; "
                     "the target mesh is coloured by the nearest surface point.")
    return Scene3D(
        title=sol.instance or inst.name,
        cameras=cams,
        target=SceneMesh(inst.target.name, tv, tf),
        occluders=tuple(SceneMesh(name, v, f) for name, v, f in inst.occluders_world(peak)),
        points=pts.positions[rows],
        counts=counts_all[rows],
        weights=pts.weight[rows],
        counted=counted,
        surface=~emit,
        other_systems=_campaign_systems(campaigns, sol, depth_points, run.instance),
        trajectory=trajectory,
        trajectory_labels=labels or (),
        peak_frame=peak if n_frames > 1 else None,
        notes=tuple(notes),
        meta={"kind": "run", "frame": peak, "n_frames": n_frames, "mode": getattr(sol, "mode", "maxcover"),
              "n_points_all_frames": int(len(pts)), "system": which},
    )


def scene3d_section(run, comp=None, campaigns: Sequence = ()) -> str:
    """The report's ``3D view`` section (plotly.js inlined), or a note when plotly is missing."""
    from camplace.plotly3d import require_plotly, scene_fragment

    head = f"<h2 id='{SECTION_ID}'>3D view: where the cameras stand and what they see</h2>"
    try:
        require_plotly()
    except CamplaceError as exc:
        log.warning("report: no 3D view (%s)", exc)
        return head + f"<p class='muted'>No 3D view: {html.escape(str(exc))}.</p>"
    scene = run_scene(run, comp, campaigns)
    n_frames = len(run.instance.frames)
    frame = f" at the peak frame {scene.meta['frame']} of {n_frames}" if n_frames > 1 else ""
    intro = (f"<p class='note'>The scene{frame}: occluders (light grey, translucent), the target and its sample points coloured "
             "by how many of the chosen cameras observe them (<b style='color:#c62828'>0</b>, <b style='color:#f39c12'>1</b>, "
             "<b style='color:#7cb342'>2</b>, <b style='color:#1b7f3b'>3+</b>), and each chosen camera's frustum. Drag to orbit, "
             "scroll to zoom, hover for labels; click a legend entry to show or hide it (the campaigns' best and median "
             "systems are hidden until clicked).</p>")
    return head + intro + scene_fragment(scene, div_id=PLOT_ID)
