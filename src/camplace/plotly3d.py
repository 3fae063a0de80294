"""An interactive 3D view of a camera plan: occluders, the target coloured by coverage, camera frusta.

Built from plain arrays (no instance, run folder or solver object), so that the report
(:mod:`camplace.report.run_scene`) and validation (:mod:`camplace.validation.camera_scene`) share it
without importing one another. plotly draws it (``Mesh3d`` and ``Scatter3d`` traces); the page
fragment inlines plotly.js, so it works offline and makes no network request. The scene's data
also goes into the page, readable, as ``<script type="application/json" id="{div_id}-data">``
(the number of cameras, the coverage histogram and the coverage count of every drawn point).

Coverage colours: the number of chosen cameras that observe a point, in four classes 0, 1, 2 and
3+ (:data:`COVERAGE_CLASSES`). The target mesh is coloured face by face with the class of the
nearest sample point; the points themselves are drawn too.

Large meshes are decimated by vertex clustering (:func:`decimate_mesh`) and large point sets
subsampled (seeded) so that a page stays a few megabytes (plotly.js alone is about 4.8 MB).
"""

from __future__ import annotations

import html
import json
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from camplace.errors import CamplaceError

__all__ = [
    "SceneCamera",
    "SceneMesh",
    "Scene3D",
    "COVERAGE_CLASSES",
    "COVERAGE_COLOURS",
    "PAGE_CSP",
    "require_plotly",
    "frustum_corners",
    "reach_depth",
    "decimate_mesh",
    "coverage_class",
    "nearest_point_classes",
    "scene_data",
    "scene_figure",
    "scene_fragment",
    "scene_page",
]

COVERAGE_CLASSES = ("0", "1", "2", "3+")
COVERAGE_COLOURS = ("#c62828", "#f39c12", "#9ccc65", "#1b7f3b")
CAMERA_COLOURS = ("#1f5fbf", "#8e44ad", "#0097a7", "#d81b60", "#5d4037", "#3949ab", "#00897b", "#6d4c41",
                  "#7b1fa2", "#0277bd", "#ad1457", "#283593")
MUTED_COLOURS = ("#8a8f98", "#b0967a", "#7d9aa8", "#a08bb0")
OCCLUDER_COLOUR = "#9aa4b2"
TRAJECTORY_COLOUR = "#455a64"
UNSEEN_TARGET_COLOUR = "#b0b7c3"
MAX_TARGET_FACES = 20_000
MAX_OCCLUDER_FACES = 30_000  # all occluders together, shared in proportion to their faces
MAX_POINTS = 20_000
#: Content-Security-Policy of a page holding a scene: inline scripts and styles, data: images, nothing else.
PAGE_CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'"


@dataclass(frozen=True, eq=False)
class SceneCamera:
    """A pinhole camera drawn as a frustum.

    Attributes
    ----------
    label : str
    position : (3,) float64
        Camera centre, metres.
    rotation : (3, 3) float64
        World-from-camera rotation, OpenCV axes (columns: x right, y down, z forward).
    K : (3, 3) float64
        Intrinsic matrix, pixels.
    width_px, height_px : int
    near_m : float
        Depth of the frustum's near face (0: the apex at the centre).
    depth_m : float
        Depth of its far face (see :func:`reach_depth`).
    note : str
        Extra hover text.
    """

    label: str
    position: np.ndarray
    rotation: np.ndarray
    K: np.ndarray
    width_px: int
    height_px: int
    near_m: float = 0.0
    depth_m: float = 1.0
    note: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", np.asarray(self.position, dtype=np.float64).reshape(3))
        object.__setattr__(self, "rotation", np.asarray(self.rotation, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))


@dataclass(frozen=True, eq=False)
class SceneMesh:
    """A world-space triangle mesh: ``vertices (v, 3) float64`` metres, ``faces (f, 3) int64``."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray


@dataclass(frozen=True, eq=False)
class Scene3D:
    """Everything the 3D view draws.

    Attributes
    ----------
    title : str
    cameras : tuple of SceneCamera
        The chosen (or photographed) cameras, drawn in strong colours.
    target : SceneMesh or None
        The target (at the peak frame of an event), coloured by the coverage of ``points``.
    occluders : tuple of SceneMesh
        Drawn light and translucent.
    points : (n, 3) float64
        Target sample points (surface and emitter points), metres.
    counts : (n,) int64
        How many of ``cameras`` observe each point.
    weights : (n,) float64 or None
        Point weights for the histogram's weight shares (None: equal weights).
    counted : (n,) bool or None
        Multiview: the points the objective credits.
    surface : (n,) bool or None
        The points on the target's surface, which colour its mesh (None: all; emitter points of a
        coma or plume have no surface).
    other_systems : tuple of (str, tuple of SceneCamera)
        Further camera systems (e.g. a campaign's best and median), drawn muted, one legend entry
        each, hidden until it is clicked (the view's box may cut far ones: :func:`view_bounds`).
    trajectory : (f, 3) float64 or None
        Target centre per frame of an event.
    trajectory_labels : tuple of str
        Hover text per frame.
    peak_frame : int or None
        Index into ``trajectory`` of the frame shown.
    notes : tuple of str
        Caveats shown under the view.
    meta : dict
        Extra JSON fields for the data tag.
    """

    title: str
    cameras: tuple[SceneCamera, ...]
    target: SceneMesh | None = None
    occluders: tuple[SceneMesh, ...] = ()
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    counts: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    weights: np.ndarray | None = None
    counted: np.ndarray | None = None
    surface: np.ndarray | None = None
    other_systems: tuple[tuple[str, tuple[SceneCamera, ...]], ...] = ()
    trajectory: np.ndarray | None = None
    trajectory_labels: tuple[str, ...] = ()
    peak_frame: int | None = None
    notes: tuple[str, ...] = ()
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        cnt = np.asarray(self.counts, dtype=np.int64).ravel()
        if len(cnt) != len(pts):
            raise CamplaceError(f"scene3d: {len(pts)} points but {len(cnt)} coverage counts")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "counts", cnt)
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=np.float64).ravel()
            if len(w) != len(pts):
                raise CamplaceError(f"scene3d: {len(pts)} points but {len(w)} weights")
            object.__setattr__(self, "weights", w)
        for name in ("counted", "surface"):
            if getattr(self, name) is not None:
                c = np.asarray(getattr(self, name), dtype=bool).ravel()
                if len(c) != len(pts):
                    raise CamplaceError(f"scene3d: {len(pts)} points but {len(c)} '{name}' flags")
                object.__setattr__(self, name, c)


def require_plotly():
    """The plotly package, or a one-line CamplaceError naming the extra that installs it."""
    try:
        import plotly.graph_objects as go  # noqa: F401
        import plotly.io  # noqa: F401
    except ImportError:
        raise CamplaceError("the 3D view needs plotly (part of the report extra): pip install 'camplace[report]'") from None
    import plotly

    return plotly


# --------------------------------------------------------------------------------------------------
# geometry


def frustum_corners(camera: SceneCamera, depth_m: float) -> np.ndarray:
    """World positions of the image corners at camera-frame depth ``depth_m`` (distortion ignored).

    Returns
    -------
    (4, 3) float64
        The outer corners of the image, pixels (-0.5, -0.5), (w-0.5, -0.5), (w-0.5, h-0.5),
        (-0.5, h-0.5) (OpenCV: pixel centres are integers, as in
        :func:`camplace.report.export.frustum_mesh`), back-projected to depth ``depth_m``, metres.
    """
    w, h = float(camera.width_px) - 0.5, float(camera.height_px) - 0.5
    uv1 = np.array([[-0.5, -0.5, 1.0], [w, -0.5, 1.0], [w, h, 1.0], [-0.5, h, 1.0]])
    rays = np.linalg.solve(camera.K, uv1.T).T  # camera-frame directions with z = 1
    return camera.position + (rays * float(depth_m)) @ camera.rotation.T


def reach_depth(position: np.ndarray, rotation: np.ndarray, points: np.ndarray, near_m: float = 0.0,
                far_m: float = math.inf, margin: float = 0.05) -> float:
    """Frustum depth that reaches ``points``: their largest camera-frame z (plus ``margin`` of it).

    Clipped to ``(near_m, far_m]``. When every point is behind the camera, the distance to their
    centroid (still clipped).

    Parameters
    ----------
    position : (3,) float64
    rotation : (3, 3) float64
        World-from-camera.
    points : (n, 3) float64
        E.g. the target's vertices.
    near_m, far_m : float
    margin : float
        Relative extra depth.

    Returns
    -------
    float
        Metres.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(position, dtype=np.float64)
    if len(p) == 0:
        d = 1.0
    else:
        z = (p - c) @ np.asarray(rotation, dtype=np.float64)[:, 2]
        d = float(z.max()) if z.max() > near_m else float(np.linalg.norm(p.mean(axis=0) - c))
    d *= 1.0 + margin
    lo = max(float(near_m), 0.0)
    d = min(d, float(far_m))
    return d if d > lo else lo + max(1e-3, 0.1 * max(lo, 1.0))


def decimate_mesh(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_faces`` triangles, by vertex clustering on a uniform grid.

    Vertices in one grid cell merge into their mean; triangles that collapse (two corners in one
    cell) and duplicates go. The finest grid (cells along the longest edge of the bounding box,
    found by bisection) that leaves at most ``max_faces`` triangles is used. Deterministic.

    Parameters
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int64
    max_faces : int

    Returns
    -------
    vertices : (v', 3) float64
    faces : (f', 3) int64
        ``f' <= max_faces`` (the input itself when it already fits).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) <= max_faces:
        return v, f
    if max_faces < 1:
        return v[:0], f[:0]
    lo = v.min(axis=0)
    span = float(np.max(v.max(axis=0) - lo)) or 1.0

    def cluster(cells: int) -> tuple[np.ndarray, np.ndarray]:
        key = np.floor((v - lo) / span * cells).astype(np.int64)
        key = np.minimum(key, cells - 1)
        flat = (key[:, 0] * (cells + 1) + key[:, 1]) * (cells + 1) + key[:, 2]
        uniq, inv = np.unique(flat, return_inverse=True)
        inv = inv.ravel()
        sums = np.zeros((len(uniq), 3))
        np.add.at(sums, inv, v)
        nv = sums / np.bincount(inv, minlength=len(uniq))[:, None]
        nf = inv[f]
        keep = (nf[:, 0] != nf[:, 1]) & (nf[:, 1] != nf[:, 2]) & (nf[:, 0] != nf[:, 2])
        nf = nf[keep]
        if len(nf):
            # a triangle and its rotations are one face; keep the first (orientation preserved)
            r = np.argmin(nf, axis=1)
            canon = np.stack([nf[np.arange(len(nf)), r], nf[np.arange(len(nf)), (r + 1) % 3], nf[np.arange(len(nf)), (r + 2) % 3]], axis=1)
            _, first = np.unique(canon, axis=0, return_index=True)
            nf = nf[np.sort(first)]
        used = np.unique(nf)
        remap = np.full(len(nv), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        return nv[used], remap[nf]

    lo_c, hi_c = 1, 2
    best = cluster(lo_c)
    while True:  # grow until too many faces (or the grid is finer than the vertices)
        cand = cluster(hi_c)
        if len(cand[1]) > max_faces:
            break
        best, lo_c = cand, hi_c
        if hi_c > 1 << 14:
            return best
        hi_c *= 2
    while hi_c - lo_c > 1:
        mid = (lo_c + hi_c) // 2
        cand = cluster(mid)
        if len(cand[1]) <= max_faces:
            best, lo_c = cand, mid
        else:
            hi_c = mid
    return best


def coverage_class(counts: np.ndarray) -> np.ndarray:
    """(n,) int64 class index into :data:`COVERAGE_CLASSES`: min(count, 3)."""
    return np.minimum(np.asarray(counts, dtype=np.int64), len(COVERAGE_CLASSES) - 1)


def nearest_point_classes(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """Class of each face: that of the sample point nearest to its centroid.

    Parameters
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int64
    points : (n, 3) float64
    classes : (n,) int64

    Returns
    -------
    (f,) int64
        -1 for every face when there is no point.
    """
    from scipy.spatial import cKDTree

    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(points) == 0:
        return np.full(len(f), -1, dtype=np.int64)
    centroids = np.asarray(vertices, dtype=np.float64)[f].mean(axis=1)
    _, idx = cKDTree(np.asarray(points, dtype=np.float64)).query(centroids)
    return np.asarray(classes, dtype=np.int64)[idx]


def _drawn_points(n: int, max_points: int, seed: int) -> np.ndarray:
    """(n',) int64 sorted indices of the points drawn: all, or ``max_points`` of them at random (seeded)."""
    if n <= max_points:
        return np.arange(n, dtype=np.int64)
    return np.sort(np.random.default_rng(seed).choice(n, size=max_points, replace=False)).astype(np.int64)


# --------------------------------------------------------------------------------------------------
# data and figure


def _round(a: np.ndarray, digits: int = 5) -> list:
    return np.round(np.asarray(a, dtype=np.float64), digits).tolist()


def _camera_json(c: SceneCamera) -> dict[str, Any]:
    return {"label": c.label, "position": _round(c.position), "forward": _round(c.rotation[:, 2]),
            "near_m": float(c.near_m), "depth_m": round(float(c.depth_m), 6), "width_px": c.width_px, "height_px": c.height_px}


def scene_data(scene: Scene3D, drawn: np.ndarray, meshes: dict[str, tuple[int, int]]) -> dict[str, Any]:
    """The readable JSON of a scene (what the page's data tag holds).

    Parameters
    ----------
    scene : Scene3D
    drawn : (n',) int64
        Indices of the points drawn.
    meshes : dict of str to (int, int)
        Faces in and faces drawn per mesh name (``"target"`` for the target).

    Returns
    -------
    dict
        ``n_cameras``, ``cameras``, ``coverage`` (per class: points and weight share of all points;
        ``count`` per drawn point with its ``index``), ``target``, ``occluders``,
        ``other_systems``, ``trajectory`` and the scene's ``meta``.
    """
    cls = coverage_class(scene.counts)
    w = scene.weights if scene.weights is not None else np.ones(len(cls))
    total = float(w.sum())
    n_cls = len(COVERAGE_CLASSES)
    cov: dict[str, Any] = {
        "classes": list(COVERAGE_CLASSES),
        "colours": list(COVERAGE_COLOURS),
        "n_points": int(len(cls)),
        "points": np.bincount(cls, minlength=n_cls).tolist(),
        "weight_share": (np.bincount(cls, weights=w, minlength=n_cls) / total).tolist() if total > 0 else [0.0] * n_cls,
        "n_drawn": int(len(drawn)),
        "index": drawn.tolist(),
        "count": scene.counts[drawn].tolist(),
    }
    if scene.counted is not None:
        cov["counted_points"] = int(scene.counted.sum())
        cov["counted_weight_share"] = float(w[scene.counted].sum() / total) if total > 0 else 0.0
    out: dict[str, Any] = {
        "schema": "camplace-scene3d/1",
        "title": scene.title,
        "n_cameras": len(scene.cameras),
        "cameras": [_camera_json(c) for c in scene.cameras],
        "coverage": cov,
        "target": None if scene.target is None else {"name": scene.target.name, "faces": meshes["target"][0], "faces_drawn": meshes["target"][1]},
        "occluders": [{"name": o.name, "faces": meshes[f"occluder {i}"][0], "faces_drawn": meshes[f"occluder {i}"][1]}
                      for i, o in enumerate(scene.occluders)],
        "other_systems": [{"name": name, "n_cameras": len(cams), "cameras": [_camera_json(c) for c in cams]} for name, cams in scene.other_systems],
        "trajectory": None if scene.trajectory is None else {
            "centres": _round(scene.trajectory), "labels": list(scene.trajectory_labels), "peak": scene.peak_frame},
        "notes": list(scene.notes),
    }
    out.update(scene.meta)
    return out


def view_bounds(scene: Scene3D, margin: float = 0.08, reach: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Axis ranges of the view: the plan (the chosen cameras, the target, its points and trajectory)
    widened towards the occluders and the other systems' cameras, plus ``margin``.

    A corridor or a terrain can be far larger than the plan, and random systems spread over the
    whole camera volume: the view reaches out to them by at most ``reach`` times the plan's largest
    extent on each side; plotly cuts what lies beyond.

    Returns
    -------
    lo, hi : (3,) float64
        Metres; ``hi > lo`` on every axis.
    """
    parts = [c.position[None] for c in scene.cameras]
    if scene.target is not None and len(scene.target.vertices):
        parts.append(np.asarray(scene.target.vertices, dtype=np.float64))
    if len(scene.points):
        parts.append(scene.points)
    if scene.trajectory is not None and len(scene.trajectory):
        parts.append(np.asarray(scene.trajectory, dtype=np.float64))
    around = [np.asarray(o.vertices, dtype=np.float64) for o in scene.occluders if len(o.vertices)]
    around += [c.position[None] for _, cams in scene.other_systems for c in cams]
    if not parts:
        parts, around = around or [np.zeros((1, 3))], []
    a = np.vstack(parts)
    lo, hi = a.min(axis=0), a.max(axis=0)
    span = max(float(np.max(hi - lo)), 1e-6)
    if around:
        o = np.vstack(around)
        lo = np.maximum(np.minimum(lo, o.min(axis=0)), lo - reach * span)
        hi = np.minimum(np.maximum(hi, o.max(axis=0)), hi + reach * span)
    pad = margin * max(float(np.max(hi - lo)), 1e-6)
    return lo - pad, hi + pad


def _frustum_lines(c: SceneCamera) -> np.ndarray:
    """(n, 3) polyline of a frustum's 12 edges (NaN rows break the line)."""
    far = frustum_corners(c, c.depth_m)
    near = frustum_corners(c, c.near_m) if c.near_m > 0 else np.repeat(c.position[None], 4, axis=0)
    gap = np.full((1, 3), np.nan)
    segs = [np.vstack([far, far[:1]]), gap, np.vstack([near, near[:1]]), gap]
    for i in range(4):
        segs += [np.vstack([near[i], far[i]]), gap]
    return np.vstack(segs)


def _lines_xyz(a: np.ndarray) -> dict[str, list]:
    """x, y, z lists with None where ``a`` has NaN rows (plotly breaks a line there)."""
    out: dict[str, list] = {"x": [], "y": [], "z": []}
    for row in np.asarray(a, dtype=np.float64):
        for k, v in zip("xyz", row, strict=True):
            out[k].append(None if not np.isfinite(v) else round(float(v), 5))
    return out


def _mesh3d(go, mesh: SceneMesh, max_faces: int, **style) -> tuple[Any, int]:
    v, f = decimate_mesh(mesh.vertices, mesh.faces, max_faces)
    v32 = v.astype(np.float32)
    return go.Mesh3d(x=v32[:, 0], y=v32[:, 1], z=v32[:, 2], i=f[:, 0].astype(np.int32), j=f[:, 1].astype(np.int32),
                     k=f[:, 2].astype(np.int32), **style), len(f)


def _camera_traces(go, cams: Sequence[SceneCamera], colours: Sequence[str], *, group: str | None = None, name: str = "",
                   width: float = 5, visible: Any = True) -> list:
    """Frustum lines and a labelled centre marker per camera.

    With ``group`` the cameras form one legend entry ``name`` (a system); else one entry each.
    """
    traces = []
    for n, c in enumerate(cams):
        col = colours[n % len(colours)]
        label = html.escape(c.label)
        hover = f"{label}<br>centre ({c.position[0]:.3f}, {c.position[1]:.3f}, {c.position[2]:.3f}) m<br>frustum depth {c.depth_m:.3g} m"
        if c.note:
            hover += "<br>" + html.escape(c.note)
        lg = group if group is not None else f"camera{n}"
        traces.append(go.Scatter3d(**_lines_xyz(_frustum_lines(c)), mode="lines", line={"color": col, "width": width},
                                   name=html.escape(name) if group is not None else label, legendgroup=lg,
                                   showlegend=group is None or n == 0, hovertext=hover, hoverinfo="text", visible=visible))
        traces.append(go.Scatter3d(x=[c.position[0]], y=[c.position[1]], z=[c.position[2]], mode="markers+text",
                                   marker={"size": 4, "color": col}, text=[label], textposition="top center",
                                   textfont={"color": col, "size": 11}, hovertext=[hover], hoverinfo="text",
                                   legendgroup=lg, showlegend=False, visible=visible))
    return traces


def _occluder_traces(go, occluders: Sequence[SceneMesh], meshes: dict[str, tuple[int, int]]) -> list:
    """Light translucent meshes, sharing :data:`MAX_OCCLUDER_FACES` in proportion to their faces."""
    traces = []
    total = sum(len(o.faces) for o in occluders)
    for i, occ in enumerate(occluders):
        limit = len(occ.faces) if total <= MAX_OCCLUDER_FACES else max(12, MAX_OCCLUDER_FACES * len(occ.faces) // total)
        tr, nf = _mesh3d(go, occ, limit, color=OCCLUDER_COLOUR, opacity=0.14, flatshading=True,
                         name=f"occluder: {html.escape(occ.name)}", showlegend=True, hoverinfo="name",
                         lighting={"ambient": 0.8, "diffuse": 0.3, "specular": 0.0})
        meshes[f"occluder {i}"] = (len(occ.faces), nf)
        traces.append(tr)
    return traces


def _target_trace(go, scene: Scene3D, cls: np.ndarray, meshes: dict[str, tuple[int, int]]):
    """The target mesh, each face in the coverage colour of the nearest surface point."""
    v, f = decimate_mesh(scene.target.vertices, scene.target.faces, MAX_TARGET_FACES)
    surf = np.flatnonzero(scene.surface) if scene.surface is not None else np.arange(len(cls))
    fcls = nearest_point_classes(v, f, scene.points[surf], cls[surf])
    style: dict[str, Any] = {"flatshading": True, "lighting": {"ambient": 0.55, "diffuse": 0.6, "specular": 0.05},
                             "name": f"target: {html.escape(scene.target.name)}", "showlegend": True, "hoverinfo": "name"}
    if np.all(fcls < 0):
        style["color"] = UNSEEN_TARGET_COLOUR
    else:
        n_cls = len(COVERAGE_CLASSES)
        steps = []
        for c, col in enumerate(COVERAGE_COLOURS):  # a step colour scale: class c -> its colour
            steps += [[c / n_cls, col], [(c + 1) / n_cls, col]]
        style.update(intensity=fcls.astype(np.float32), intensitymode="cell", colorscale=steps, cmin=-0.5, cmax=n_cls - 0.5, showscale=False)
    tr, nf = _mesh3d(go, SceneMesh(scene.target.name, v, f), MAX_TARGET_FACES, **style)
    meshes["target"] = (len(scene.target.faces), nf)
    return tr


def _point_traces(go, scene: Scene3D, cls: np.ndarray, drawn: np.ndarray) -> list:
    """One trace of drawn points per coverage class (legend: its share of all points), and the multiview rings."""
    w = scene.weights if scene.weights is not None else np.ones(len(cls))
    total = float(w.sum()) or 1.0
    traces = []
    for c, (name, col) in enumerate(zip(COVERAGE_CLASSES, COVERAGE_COLOURS, strict=True)):
        sel = drawn[cls[drawn] == c]
        p = scene.points[sel].astype(np.float32)
        share = 100.0 * float(w[cls == c].sum()) / total
        traces.append(go.Scatter3d(
            x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers", marker={"size": 2.5, "color": col},
            name=f"seen by {name} camera{'' if name == '1' else 's'}: {int(np.count_nonzero(cls == c)):,} points, {share:.1f} % of weight",
            customdata=scene.counts[sel].astype(np.int32), legendgroup=f"coverage{c}",
            hovertemplate="seen by %{customdata} camera(s)<br>(%{x:.3f}, %{y:.3f}, %{z:.3f}) m<extra></extra>"))
    if scene.counted is not None:
        p = scene.points[drawn[scene.counted[drawn]]].astype(np.float32)
        traces.append(go.Scatter3d(
            x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers", marker={"size": 5, "color": "rgba(0,0,0,0)", "line": {"color": "#111", "width": 1}},
            name=f"counted by the objective: {int(scene.counted.sum()):,} points", hoverinfo="skip", visible="legendonly"))
    return traces


def _trajectory_traces(go, scene: Scene3D) -> list:
    """The target's centre per frame, and the frame shown."""
    if scene.trajectory is None or len(scene.trajectory) == 0:
        return []
    t = np.asarray(scene.trajectory, dtype=np.float64)
    labels = [html.escape(s) for s in scene.trajectory_labels] if scene.trajectory_labels else [f"frame {i}" for i in range(len(t))]
    traces = [go.Scatter3d(x=t[:, 0], y=t[:, 1], z=t[:, 2], mode="lines+markers", line={"color": TRAJECTORY_COLOUR, "width": 3},
                           marker={"size": 2.5, "color": TRAJECTORY_COLOUR}, name="target trajectory (centre per frame)",
                           hovertext=labels, hoverinfo="text")]
    if scene.peak_frame is not None and 0 <= scene.peak_frame < len(t):
        pk = t[scene.peak_frame]
        traces.append(go.Scatter3d(x=[pk[0]], y=[pk[1]], z=[pk[2]], mode="markers", marker={"size": 7, "color": TRAJECTORY_COLOUR, "symbol": "diamond"},
                                   name=f"frame shown ({scene.peak_frame})", hovertext=[labels[scene.peak_frame]], hoverinfo="text"))
    return traces


def _focus(scene: Scene3D) -> np.ndarray | None:
    """(3,) float64 what the view orbits around: the target's bounding-box centre (else the points')."""
    for a in ((scene.target.vertices if scene.target is not None else None), scene.points):
        if a is not None and len(a):
            a = np.asarray(a, dtype=np.float64)
            return (a.min(axis=0) + a.max(axis=0)) / 2.0
    return None


def _layout(go, scene: Scene3D, height_px: int):
    """Axis ranges of :func:`view_bounds` at true proportions, legend on the right; the view orbits
    the target and frames the chosen cameras."""
    lo, hi = view_bounds(scene)
    span = hi - lo
    ratio = np.maximum(span, 0.05 * span.max()) / span.max()
    axis = {"showbackground": True, "backgroundcolor": "#f6f7f9", "gridcolor": "#dde1e7", "zerolinecolor": "#c4cad3"}
    ax = {c: {**axis, "title": {"text": f"{c} (m)"}, "range": [float(lo[i]), float(hi[i])]} for i, c in enumerate("xyz")}
    mid = (lo + hi) / 2.0

    def norm(p: np.ndarray) -> np.ndarray:  # plotly's camera units: the box spans aspectratio, centred on 0
        return (np.asarray(p, dtype=np.float64) - mid) / span * ratio

    focus = _focus(scene)
    centre = norm(focus) if focus is not None else np.zeros(3)
    reach = [np.linalg.norm(norm(c.position) - centre) for c in scene.cameras]
    dist = min(3.0 * max(reach, default=0.87), 2.6) or 2.17  # plotly frames its box (radius 0.87) from 2.17
    eye = centre + dist * np.array([1.0, 1.0, 0.8]) / np.linalg.norm([1.0, 1.0, 0.8])
    camera = {"center": dict(zip("xyz", centre.tolist(), strict=True)), "eye": dict(zip("xyz", eye.tolist(), strict=True))}
    return go.Layout(
        template="none", height=height_px, margin={"l": 0, "r": 0, "t": 10, "b": 0}, paper_bgcolor="#ffffff",
        font={"family": "system-ui, -apple-system, 'Segoe UI', Roboto, 'DejaVu Sans', sans-serif", "size": 12},
        legend={"itemsizing": "constant", "font": {"size": 11}, "y": 0.93, "yanchor": "top"},  # below the mode bar
        scene={"aspectmode": "manual", "aspectratio": {c: float(r) for c, r in zip("xyz", ratio, strict=True)},
               "xaxis": ax["x"], "yaxis": ax["y"], "zaxis": ax["z"], "camera": camera},
        hoverlabel={"namelength": -1},
    )


def scene_figure(scene: Scene3D, *, max_points: int = MAX_POINTS, seed: int = 0, height_px: int = 640):
    """The plotly figure of a scene and its readable data.

    Parameters
    ----------
    scene : Scene3D
    max_points : int
        Points drawn at most (a seeded random subset beyond).
    seed : int
        Seed of that subset.
    height_px : int

    Returns
    -------
    figure : plotly.graph_objects.Figure
    data : dict
        :func:`scene_data`.
    """
    require_plotly()
    import plotly.graph_objects as go

    meshes: dict[str, tuple[int, int]] = {}
    cls = coverage_class(scene.counts)
    drawn = _drawn_points(len(cls), max_points, seed)
    traces = _occluder_traces(go, scene.occluders, meshes)
    if scene.target is not None:
        traces.append(_target_trace(go, scene, cls, meshes))
    traces += _point_traces(go, scene, cls, drawn)
    traces += _trajectory_traces(go, scene)
    traces += _camera_traces(go, scene.cameras, CAMERA_COLOURS)
    for s, (name, cams) in enumerate(scene.other_systems):
        traces += _camera_traces(go, cams, [MUTED_COLOURS[s % len(MUTED_COLOURS)]], group=f"system{s}", name=name, width=2,
                                 visible="legendonly")
    return go.Figure(traces, _layout(go, scene, height_px)), scene_data(scene, drawn, meshes)


_SCRIPT_TAG_SAFE = {ord("<"): "\\u003c", ord(">"): "\\u003e", ord("&"): "\\u0026"}


def _json_for_script(data: dict) -> str:
    """JSON that cannot close its script element."""
    return json.dumps(data, separators=(",", ":"), allow_nan=False).translate(_SCRIPT_TAG_SAFE)


def plotly_js_tag() -> str:
    """The plotly.js bundle of the installed plotly package as an inline script element."""
    require_plotly()
    from plotly.offline.offline import get_plotlyjs

    js = get_plotlyjs()
    if "</script" in js.lower():  # pragma: no cover - plotly.js never holds it; checked because we inline it
        raise CamplaceError("plotly.js holds '</script' and cannot be inlined")
    return f"<script>{js}</script>"


def scene_fragment(scene: Scene3D, *, div_id: str = "scene3d", include_plotlyjs: bool = True, max_points: int = MAX_POINTS,
                   seed: int = 0, height_px: int = 640) -> str:
    """HTML of a scene: its data tag, plotly.js (when asked), the plot and the notes.

    The page holding it needs a Content-Security-Policy that allows inline scripts
    (:data:`PAGE_CSP`). Once plotly has drawn, the plot element gets ``data-ready="1"``.

    Parameters
    ----------
    scene : Scene3D
    div_id : str
        Id of the plot element; the data tag is ``{div_id}-data``.
    include_plotlyjs : bool
        Inline plotly.js (once per page).
    max_points, seed, height_px
        As in :func:`scene_figure`.

    Returns
    -------
    str
    """
    import plotly.io as pio

    fig, data = scene_figure(scene, max_points=max_points, seed=seed, height_px=height_px)
    config = {"displaylogo": False, "responsive": True, "showSendToCloud": False, "scrollZoom": True}
    plot = pio.to_html(fig, full_html=False, include_plotlyjs=False, div_id=div_id, config=config, default_height=f"{height_px}px",
                       post_script="document.getElementById('{plot_id}').dataset.ready = '1';")
    notes = "".join(f"<p class='muted'>{html.escape(n)}</p>" for n in scene.notes)
    return (f"<script type='application/json' id='{html.escape(div_id)}-data'>{_json_for_script(data)}</script>"
            + (plotly_js_tag() if include_plotlyjs else "")
            + f"<div class='scene3d' style='border:1px solid #e2e5ea'>{plot}</div>" + notes)


def scene_page(scene: Scene3D, *, heading: str = "", intro_html: str = "", **fragment_options: Any) -> str:
    """A standalone, self-contained HTML page of a scene (offline; :data:`PAGE_CSP`).

    Parameters
    ----------
    scene : Scene3D
    heading : str
        Page heading (default: the scene's title); escaped.
    intro_html : str
        Trusted HTML placed under the heading.
    **fragment_options
        Passed to :func:`scene_fragment`.

    Returns
    -------
    str
    """
    title = html.escape(heading or scene.title)
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        f"<meta http-equiv='Content-Security-Policy' content=\"{PAGE_CSP}\">"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{title}</title><style>body{{font-family:system-ui,-apple-system,'Segoe UI',Roboto,'DejaVu Sans',sans-serif;"
        "margin:0;background:#f4f5f7;color:#1d2330}main{max-width:1120px;margin:0 auto;padding:20px 28px 40px;background:#fff}"
        ".muted{color:#6b7385;font-size:.88em}code{background:#f1f3f6;padding:0 3px}</style></head><body><main>"
        f"<h1>{title}</h1>{intro_html}" + scene_fragment(scene, **fragment_options) + "</main></body></html>\n"
    )
