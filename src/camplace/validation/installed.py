"""The installed system: what the emulated installations of a run's cameras actually observe.

``camplace validate RUN [RUN2 ...] --physical phys.toml --installations N`` installs every system N
times with the ``[physical]`` pose error and scores each installation twice:

the installed objective
    the run's own objective (``solution.json`` ``options``: mode, views, min angle, event mode; the
    rows and weights of its ``points.csv``) with every camera at the pose its emulated photograph
    was taken from, ray cast by the visibility engine on the run's points. It is what the robust
    run's out-of-sample check estimates, measured on the installations that were photographed.
the photo figure
    from the photographs, without the visibility engine: the share (by weight) of the run's target
    points of the photographed frame that are *seen in the photographs*, counted per the run's mode
    (maxcover, quality, setcover: by >= 1 camera; multiview: by >= ``views`` cameras). A point is seen
    by a camera when it projects (installed pose, the lens's distortion) into the target that
    Algorithm 3 detected in that camera's emulated photograph, in front of the camera, and its depth
    is within ``DEPTH_TOLERANCE_PX`` pixel footprints of the photo's depth at that pixel (the render's depth channel, as
    an RGB-D camera would record it): a point on the far side of the target projects inside its
    silhouette too, and without the depth test it would count as seen. Only what the instance
    counts as observable is counted (:class:`ObservableRows`): with ``[quality] require_light`` an
    unlit point is not seen, however dark-but-visible the photograph shows it (the renderer's
    ambient term), and the instance's incidence limit and depth range apply from the installed pose.

Installation draws (:func:`installation_draws`): camera ``c`` of a system, chosen as candidate ``j``
of its run, is installed in installation ``t`` from the standard normals of
:func:`camplace.sampling.perturb.pose_draws` ``(seed, j, stream OUT_OF_SAMPLE_STREAM, iid)[t]``, the
robust run's own perturbation model and stream: with ``--seed`` equal to the run's seed, the N
installations are the first N of the run's out-of-sample check, and a camera two systems share is
installed identically in both (common random numbers; the systems are paired installation by
installation).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace.errors import CamplaceError
from camplace.sampling.perturb import OUT_OF_SAMPLE_STREAM, pose_draws

log = logging.getLogger(__name__)

__all__ = [
    "INSTALLATION_STREAM", "RunObjective", "load_run_objective", "installation_draws", "camera_keys", "photo_rows", "installed_objective",
    "seen_in_photo", "ObservableRows", "photo_value", "summarise_values", "compare_systems", "InstalledSystems",
]

#: Seed stream of the installations photographed (the robust run's out-of-sample stream).
INSTALLATION_STREAM = OUT_OF_SAMPLE_STREAM
#: Depth slack of the photo figure, in pixel footprints (:func:`seen_in_photo`).
DEPTH_TOLERANCE_PX = 6.0
#: Key offset of cameras with no candidate index (``2**31 + 1000 * system + slot``).
_NO_CANDIDATE_KEY = 2**31


@dataclass(frozen=True, eq=False)
class RunObjective:
    """A run's objective, as ``solution.json`` ``options`` and ``points.csv`` define it.

    Attributes
    ----------
    mode : str
        maxcover, quality, multiview or setcover.
    views : int
        Multiview: cameras a point needs.
    min_angle_deg : float or None
        Multiview: minimum angle between two views.
    event_mode : str
        ``all`` or ``peak`` (the weights).
    points : camplace.visibility.TargetPoints
        The run's rows.
    weights : (m,) float64
        The row weights the run maximised.
    source : str
        The run folder.
    """

    mode: str
    views: int
    min_angle_deg: float | None
    event_mode: str
    points: Any
    weights: np.ndarray
    source: str

    def record(self) -> dict[str, Any]:
        """JSON-ready description (no arrays)."""
        return {"run": self.source, "mode": self.mode, "views": self.views, "min_angle_deg": self.min_angle_deg,
                "event_mode": self.event_mode, "rows": int(len(self.weights))}


def load_run_objective(outdir: str | Path, instance) -> RunObjective:
    """The objective of the run in ``outdir`` (``solution.json`` options, ``points.csv``).

    Raises
    ------
    CamplaceError
        No ``points.csv`` (e.g. a folder not written by ``camplace run``).
    """
    import json

    from camplace.visibility import TargetPoints

    outdir = Path(outdir)
    if not (outdir / "points.csv").is_file():
        raise CamplaceError(f"{outdir / 'points.csv'}: missing (the installed objective is scored on the run's points; re-run 'camplace run -o {outdir}')")
    data = json.loads((outdir / "solution.json").read_text())
    opts = data.get("options") or {}
    mode = str(opts.get("mode") or data.get("mode") or "maxcover")
    views = int(opts.get("views") or 2)
    min_angle = opts.get("min_angle_deg")
    event_mode = str(opts.get("event_mode") or data.get("event_mode") or "all")
    pts = TargetPoints.load(outdir / "points.csv")
    weights = np.asarray(pts.weight, dtype=np.float64)
    if event_mode == "peak":  # as camplace.event.event_weights
        peak = int(np.argmax([f.weight for f in instance.frames]))
        weights = np.where(pts.frame == peak, weights, 0.0)
        total = weights.sum()
        weights = weights / total if total > 0 else weights
    return RunObjective(mode, views, None if min_angle is None else float(min_angle), event_mode, pts, weights, str(outdir))


def camera_keys(cameras: Sequence[dict], system: int) -> list[int]:
    """The draw key of each camera of a system: its candidate index (see the module docstring).

    Parameters
    ----------
    cameras : sequence of dict
        ``solution.json`` camera records (``candidate`` when known).
    system : int
        1-based system number (keys of cameras without a candidate index).
    """
    keys = []
    for slot, rec in enumerate(cameras):
        j = rec.get("candidate") if isinstance(rec, dict) else None
        keys.append(int(j) if j is not None and int(j) >= 0 else _NO_CANDIDATE_KEY + 1000 * int(system) + slot)
    return keys


def installation_draws(seed: int, keys: Sequence[int], installations: int) -> np.ndarray:
    """Standard normal pose-error draws of some cameras in N installations.

    Parameters
    ----------
    seed : int
        The validation seed (>= 0).
    keys : sequence of int
        Per camera, its draw key (:func:`camera_keys`).
    installations : int
        N.

    Returns
    -------
    (c, N, 6) float64
        :func:`camplace.sampling.perturb.pose_draws` on :data:`INSTALLATION_STREAM` (independent draws).
    """
    if int(seed) < 0:
        raise CamplaceError(f"--seed: must be >= 0 to draw installations, got {seed}")
    return pose_draws(int(seed), list(keys), int(installations), INSTALLATION_STREAM, design="iid")


def photo_rows(objective: RunObjective, frame: int) -> np.ndarray:
    """(r,) int64: the rows the photo figure counts: the frame's target surface points (emitter rows,
    volumetric glow without a surface, left out)."""
    pts = objective.points
    return np.flatnonzero((pts.frame == frame) & ~pts.is_emitter)


def installed_objective(instance, objective: RunObjective, installed: Sequence[Sequence[Any]], *,
                        rows: np.ndarray | None = None, memory_budget_bytes: int | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The run's objective of one system in each of its installations (ray cast on the run's points).

    Parameters
    ----------
    instance : camplace.instance.Instance
        The run's instance (its camera model and scene).
    objective : RunObjective
    installed : sequence of N sequences of k CameraView
        The system's cameras as installed in each installation (only their poses are used: the
        visibility engine models the instance's pinhole camera).
    rows : (r,) int64 or None
        Also score these rows alone, with their weights renormalised to sum to 1 (the rows the photo
        figure counts, :func:`photo_rows`).
    memory_budget_bytes : int or None
        For the visibility engine.

    Returns
    -------
    values : (N,) float64
        The objective per installation.
    row_values : (N,) float64 or None
        The same on ``rows`` (None without ``rows``).
    """
    from camplace.sampling import CandidateSet
    from camplace.solver.problem.objectives import mode_value
    from camplace.visibility import compute_visibility

    n_inst = len(installed)
    k = len(installed[0]) if n_inst else 0
    if n_inst == 0 or k == 0:
        return np.zeros(n_inst), (np.zeros(n_inst) if rows is not None else None)
    pos = np.array([[c.position for c in cams] for cams in installed], dtype=np.float64).reshape(n_inst * k, 3)
    rot = np.array([[c.rotation for c in cams] for cams in installed], dtype=np.float64).reshape(n_inst * k, 3, 3)
    model = None
    if getattr(instance, "team", None) is not None:  # each camera with its model's intrinsics
        index = {m.name: j for j, m in enumerate(instance.cameras)}
        model = np.array([[index.get(c.model, 0) for c in cams] for cams in installed], dtype=np.int16).reshape(n_inst * k)
    poses = CandidateSet(positions=pos, aims=pos + rot[:, :, 2], rotations=rot, model=model)
    matrix = compute_visibility(instance, poses, objective.points, memory_budget_bytes=memory_budget_bytes).matrix.tocsc()
    if rows is not None:
        rows = np.asarray(rows, dtype=np.int64)
        w_rows = objective.weights[rows]
        w_rows = w_rows / w_rows.sum() if w_rows.sum() > 0 else w_rows
    values = np.empty(n_inst)
    row_values = np.empty(n_inst) if rows is not None else None
    angle = objective.min_angle_deg if objective.mode == "multiview" else None
    for t in range(n_inst):
        sub = matrix[:, t * k:(t + 1) * k].tocsr()
        kw = dict(mode=objective.mode, views=objective.views, min_angle_deg=angle,
                  positions=pos[t * k:(t + 1) * k] if angle is not None else None,
                  points=objective.points.positions if angle is not None else None)
        values[t] = mode_value(sub, objective.weights, range(k), **kw)
        if rows is not None:
            if angle is not None:
                kw["points"] = objective.points.positions[rows]
            row_values[t] = mode_value(sub[rows], w_rows, range(k), **kw)
    return values, row_values


def seen_in_photo(camera, detected: np.ndarray, depth: np.ndarray, points: np.ndarray, *,
                  depth_tolerance_px: float = DEPTH_TOLERANCE_PX) -> np.ndarray:
    """Which points one photograph sees: inside the detected target and not behind the surface shown.

    Parameters
    ----------
    camera : CameraView
        The camera as installed (pose and distortion of the photo).
    detected : (h, w) bool
        The target detected in the photograph (Algorithm 3).
    depth : (h, w) float
        The photo's depth per pixel: camera-frame z of the first surface hit, metres (inf: nothing).
    points : (m, 3) float64
        World points, metres.
    depth_tolerance_px : float
        In pixel footprints: a point counts when its depth is at most the depth shown at its pixel
        ``d`` plus ``depth_tolerance_px * d / fx`` metres (the photo samples the surface at pixel
        centres; on an inclined surface that differs from the point's own depth by a pixel's footprint
        times the tangent of the incidence angle).

    Returns
    -------
    (m,) bool
    """
    uv, z = camera.project(points)
    ok = np.isfinite(uv).all(axis=1) & (z > 0)
    px = np.zeros((len(points), 2), dtype=np.int64)
    px[ok] = np.rint(uv[ok]).astype(np.int64)
    ok &= (px[:, 0] >= 0) & (px[:, 0] < camera.width) & (px[:, 1] >= 0) & (px[:, 1] < camera.height)
    seen = np.zeros(len(points), dtype=bool)
    idx = np.flatnonzero(ok)
    u, v = px[idx, 0], px[idx, 1]
    d = depth[v, u].astype(np.float64)
    seen[idx] = detected[v, u] & (z[idx] <= d * (1.0 + float(depth_tolerance_px) / camera.K[0, 0]))
    return seen


@dataclass(frozen=True, eq=False)
class ObservableRows:
    """The instance's rules of observation that a photograph cannot judge, on the photo figure's rows.

    A photograph shows whether a point is inside the detected target and in front of the surface
    shown (:func:`seen_in_photo`); the instance also asks that a surface point be lit
    (``require_light``), face the camera within ``max_incidence_deg`` and lie between ``near_m``
    and ``far_m`` in depth, the tests of the visibility matrix (:mod:`camplace.visibility.engine`).

    Attributes
    ----------
    positions : (r, 3) float64
        The rows' world positions, metres.
    normals : (r, 3) float64
        Their unit normals (zero for emitters, which skip the facing and light tests).
    lit : (r,) bool
        Lit rows (every row when the instance does not require light).
    cos_max : float
        Cosine of ``max_incidence_deg`` (0 when it is 90: facing alone).
    near_m, far_m : float
    model_ranges : dict of str to (near_m, far_m)
        A team's depth range per camera model (a camera whose ``model`` is not listed uses
        ``near_m``, ``far_m``).
    """

    positions: np.ndarray
    normals: np.ndarray
    lit: np.ndarray
    cos_max: float
    near_m: float
    far_m: float
    model_ranges: dict = field(default_factory=dict)

    @classmethod
    def of(cls, instance, points, rows: np.ndarray) -> "ObservableRows":
        """The rules of ``instance`` on ``points[rows]`` (``points``: the run's TargetPoints)."""
        from camplace.visibility.engine import lit_points

        q = instance.quality
        rows = np.asarray(rows, dtype=np.int64)
        lit = lit_points(instance, points)[rows] if q.require_light else np.ones(len(rows), dtype=bool)
        cos_max = math.cos(math.radians(q.max_incidence_deg)) if q.max_incidence_deg < 90.0 else 0.0
        ranges = {m.name: (float(m.near_m), float(m.far_m)) for m in instance.cameras} if getattr(instance, "team", None) is not None else {}
        return cls(points.positions[rows], points.normals[rows], lit, cos_max, float(instance.camera.near_m), float(instance.camera.far_m),
                   ranges)

    def from_camera(self, camera) -> np.ndarray:
        """(r,) bool: rows the instance counts as observable from ``camera`` (CameraView) but for
        frustum and occlusion, which the photograph judges."""
        view = np.asarray(camera.position, dtype=np.float64) - self.positions
        dist = np.linalg.norm(view, axis=1)
        cos = np.einsum("ij,ij->i", self.normals, view) / np.where(dist > 0, dist, 1.0)
        emitter = ~np.any(self.normals != 0.0, axis=1)
        facing = (cos > 0) & (cos >= self.cos_max)
        z = -view @ np.asarray(camera.rotation, dtype=np.float64)[:, 2]
        near, far = self.model_ranges.get(getattr(camera, "model", ""), (self.near_m, self.far_m))
        return (emitter | (facing & self.lit)) & (z >= near) & (z <= far)


def photo_value(seen: np.ndarray, weights: np.ndarray, mode: str, views: int) -> float:
    """The photo figure of one installed system.

    Parameters
    ----------
    seen : (k, m) bool
        Per camera, the points its photograph sees (:func:`seen_in_photo`).
    weights : (m,) float64
        The points' weights (normalised by the caller).
    mode : str
        multiview counts a point seen by >= ``views`` cameras, every other mode by >= 1.
    views : int

    Returns
    -------
    float
        The weight of the points seen enough.
    """
    need = int(views) if mode == "multiview" else 1
    count = np.asarray(seen, dtype=np.int64).sum(axis=0)
    return float(np.sum(np.asarray(weights, dtype=np.float64)[count >= need], dtype=np.float64))


def summarise_values(values: Sequence[float]) -> dict[str, Any]:
    """Mean, 10th percentile (:func:`camplace.robust.p10.order_p10`), min, max and the values."""
    from camplace.robust.p10 import order_p10

    v = np.asarray(values, dtype=np.float64)
    return {"mean": float(v.mean()), "p10": order_p10(v), "min": float(v.min()), "max": float(v.max()), "values": [float(x) for x in v]}


def _paired(a: Sequence[float], b: Sequence[float]) -> dict[str, float]:
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    se = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else None
    return {"mean": float(d.mean()), "standard_error": se, "wins": int(np.sum(d > 0)), "losses": int(np.sum(d < 0))}


def compare_systems(systems: list[dict[str, Any]], run_systems: int) -> dict[str, Any]:
    """Which system keeps more once installed, and the paired differences to system 1.

    Parameters
    ----------
    systems : list of dict
        Per system: ``system``, ``objective`` and ``photo`` summaries (:func:`summarise_values`;
        ``photo`` may be None).
    run_systems : int
        How many of them are run folders (the first ones; the rest are random systems).

    Returns
    -------
    dict
        ``best_objective_mean``, ``best_objective_p10``, ``best_photo_mean`` (system numbers, among
        the run systems), ``paired`` (per run system after the first: its values minus system 1's,
        mean, standard error, installations won and lost, for the objective and the photo figure)
        and ``verdict`` (one sentence).
    """
    runs = systems[:run_systems]
    out: dict[str, Any] = {}

    def best(key: str, stat: str) -> int | None:
        cands = [s for s in runs if s.get(key) is not None]
        return None if not cands else int(max(cands, key=lambda s: (s[key][stat], -s["system"]))["system"])

    out["best_objective_mean"] = best("objective", "mean")
    out["best_objective_p10"] = best("objective", "p10")
    out["best_photo_mean"] = best("photo", "mean")
    paired = []
    for s in runs[1:]:
        rec: dict[str, Any] = {"system": s["system"], "minus_system": runs[0]["system"]}
        rec["objective"] = _paired(s["objective"]["values"], runs[0]["objective"]["values"])
        if s.get("photo") is not None and runs[0].get("photo") is not None:
            rec["photo"] = _paired(s["photo"]["values"], runs[0]["photo"]["values"])
        paired.append(rec)
    out["paired"] = paired
    if len(runs) >= 2:
        by_number = {s["system"]: s for s in runs}
        b, p = out["best_objective_mean"], out["best_photo_mean"]
        text = (f"system {b} ({Path(by_number[b]['run']).name}) keeps the most once installed "
                f"(objective mean {by_number[b]['objective']['mean']:.4f})")
        if p is not None:
            text += (f"; in the photographs system {p} ({Path(by_number[p]['run']).name}) keeps the most "
                     f"(photo figure mean {by_number[p]['photo']['mean']:.4f})")
        out["verdict"] = text
    else:
        out["verdict"] = None
    return out


def _same_candidates(outdirs: Sequence[str | Path]) -> bool | None:
    """True when every run folder has the same ``candidates.csv`` (None when one is missing)."""
    texts = []
    for d in outdirs:
        path = Path(d) / "candidates.csv"
        if not path.is_file():
            return None
        texts.append(path.read_bytes())
    return all(t == texts[0] for t in texts)


class InstalledSystems:
    """The installations of the systems of one validation, and what each photograph sees.

    Built by :meth:`plan` before any photograph is taken; the photographs are then reported with
    :meth:`record_photo` and :meth:`finish` scores every installation.

    Attributes
    ----------
    installed : list (system) of list (installation) of list (camera) of CameraView
        Where each camera stands in each installation (its emulated photograph's pose).
    keys : list (system) of list of int
        Per camera, its draw key (:func:`camera_keys`).
    objectives : list (system) of RunObjective or None
        The run's objective (random systems: the first run's); None when the run has no points.csv.
    rules : list (system) of ObservableRows or None
        What the system's instance counts as observable on the photo figure's rows.
    notes : list of str
    """

    def __init__(self, installed, keys, objectives, rows, outdirs, seed: int, installations: int, frame: int,
                 physical, run_systems: int, notes: list[str], rules: list | None = None):
        self.installed = installed
        self.rules = rules if rules is not None else [None] * len(keys)
        self.keys = keys
        self.objectives = objectives
        self.rows = rows
        self.outdirs = [str(d) for d in outdirs]
        self.seed = int(seed)
        self.installations = int(installations)
        self.frame = int(frame)
        self.physical = physical
        self.run_systems = int(run_systems)
        self.notes = notes
        # seen[s][t][c]: (r,) bool, or None until photographed
        self.seen = [[[None] * len(keys[s]) for _ in range(self.installations)] for s in range(len(keys))]

    @classmethod
    def plan(cls, outdirs: Sequence[str | Path], runs: Sequence[tuple[Any, Any]], systems: Sequence[tuple[Any, Sequence[Any]]],
             physical, seed: int, installations: int, frame: int) -> "InstalledSystems":
        """Draw every installation of every system.

        Parameters
        ----------
        outdirs : sequence of path
            The run folders (systems 1..len(outdirs)).
        runs : sequence of (instance, solution)
        systems : sequence of (instance, list of CameraView)
            Every system photographed: the runs' then the random ones.
        physical : PhysicalCamera
        seed, installations, frame : int
        """
        from camplace.validation.physical import install_camera

        n_runs = len(outdirs)
        notes: list[str] = []
        objectives: list[RunObjective | None] = []
        for d, (inst, _) in zip(outdirs, runs, strict=True):
            try:
                objectives.append(load_run_objective(d, inst))
            except CamplaceError as exc:
                objectives.append(None)
                notes.append(f"no installed objective for {d}: {exc}")
        objectives += [objectives[0]] * (len(systems) - n_runs)
        keys = [camera_keys(runs[s][1].cameras, s + 1) if s < n_runs else camera_keys([{}] * len(cams), s + 1)
                for s, (_, cams) in enumerate(systems)]
        installed = []
        for s, (_, cams) in enumerate(systems):
            z = installation_draws(seed, keys[s], installations)  # (k, N, 6)
            installed.append([[install_camera(cam, physical, z[c, t]) for c, cam in enumerate(cams)] for t in range(int(installations))])
        rows = [None if o is None else photo_rows(o, frame) for o in objectives]
        rules, known = [], {}
        for (inst, _), o, r in zip(systems, objectives, rows, strict=True):
            key = (id(inst), id(o))  # random systems share the first run's instance and objective
            if o is not None and key not in known:
                known[key] = ObservableRows.of(inst, o.points, r)
            rules.append(None if o is None else known[key])
        same = _same_candidates(outdirs)
        if n_runs >= 2:
            if same:
                notes.append("the runs share candidates.csv: a camera chosen by several systems is installed identically in each "
                             "(common random numbers); the others draw their own errors; the systems are compared installation by installation")
            else:
                notes.append("the runs' candidates differ: each system's installations are independent draws of the same model "
                             "(cameras keyed by candidate index), so the comparison is of two samples, not a paired one")
        if len(systems) > n_runs:
            notes.append("random systems draw their own installations (keyed by system and slot)")
        return cls(installed, keys, objectives, rows, outdirs, seed, installations, frame, physical, n_runs, notes, rules)

    def record_photo(self, system: int, installation: int, camera: int, shot, detected: np.ndarray,
                     depth_tolerance_px: float = DEPTH_TOLERANCE_PX) -> None:
        """What one emulated photograph sees (:func:`seen_in_photo`) of what the system's instance counts
        as observable (:class:`ObservableRows`); ``system`` is 0-based."""
        obj, rows, rules = self.objectives[system], self.rows[system], self.rules[system]
        if obj is None or shot.depth is None:
            return
        seen = seen_in_photo(shot.actual, detected, shot.depth, obj.points.positions[rows], depth_tolerance_px=depth_tolerance_px)
        self.seen[system][installation][camera] = seen if rules is None else seen & rules.from_camera(shot.actual)

    def finish(self, systems: Sequence[tuple[Any, Sequence[Any]]], *, memory_budget_bytes: int | None = None) -> dict[str, Any]:
        """Score every installation: the ``installed`` record of ``validation.json``.

        Returns
        -------
        dict
            ``available``, ``installations``, ``seed``, ``seed_stream``, ``draws`` (how installations
            are drawn and paired), ``physical`` (the two sigmas), ``frame``, ``systems`` (per system:
            ``system``, ``run``, ``keys``, ``objective_settings``, ``objective`` (mean, p10, min, max,
            values), ``objective_frame`` (the objective on the photo figure's rows), ``photo``
            (the photo figure's summary), ``photo_rows``), ``comparison`` (:func:`compare_systems`),
            ``notes``.
        """
        recs = []
        for s, (inst, _) in enumerate(systems):
            obj = self.objectives[s]
            rec: dict[str, Any] = {"system": s + 1, "run": self.outdirs[s] if s < self.run_systems else "random",
                                   "keys": [int(k) for k in self.keys[s]]}
            if obj is None:
                rec.update(objective=None, objective_frame=None, photo=None)
                recs.append(rec)
                continue
            rows = self.rows[s]
            values, row_values = installed_objective(inst, obj, self.installed[s], rows=rows, memory_budget_bytes=memory_budget_bytes)
            rec["objective_settings"] = obj.record()
            rec["objective"] = summarise_values(values)
            rec["objective_frame"] = summarise_values(row_values) if len(rows) else None
            rec["photo_rows"] = int(len(rows))
            seen = self.seen[s]
            if len(rows) and all(x is not None for per in seen for x in per):
                w = obj.weights[rows]
                w = w / w.sum() if w.sum() > 0 else w
                rec["photo"] = summarise_values([photo_value(np.array(per), w, obj.mode, obj.views) for per in seen])
            else:
                rec["photo"] = None
            recs.append(rec)
        scored = [r for r in recs if r.get("objective") is not None]
        run_scored = [r for r in scored if r["system"] <= self.run_systems]
        comparison = compare_systems(run_scored, len(run_scored)) if run_scored else None
        return {
            "available": bool(scored),
            "installations": self.installations,
            "seed": self.seed,
            "seed_stream": INSTALLATION_STREAM,
            "draws": ("camera with candidate index j, installation t: pose_draws(seed, j, stream 3, iid)[t] "
                      "(sampling/perturb.py), the robust run's out-of-sample model and stream"),
            "physical": {"sigma_position_m": self.physical.sigma_position_m, "sigma_rotation_deg": self.physical.sigma_rotation_deg},
            "frame": self.frame,
            "depth_tolerance_px": DEPTH_TOLERANCE_PX,
            "systems": recs,
            "comparison": comparison,
            "notes": list(self.notes),
        }
