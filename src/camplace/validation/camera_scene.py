"""``scene3d.html`` of ``camplace validate``: the photographed cameras around the target, in 3D.

It shows at once whether imported calibrated cameras (``--cameras``) stand where they should
around the target (``--target``): each camera is a frustum from its centre to a depth that reaches
the target, and the target's surface is coloured by how many cameras see each sample point.

A sample point counts as seen by a camera when it projects inside the image (with the camera's
distortion), lies in front of it, faces it (surface points: normal towards the camera) and the
segment to the camera centre crosses no triangle of the scene (target and occluders, Embree).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import numpy as np

from camplace._io import write_text_atomic
from camplace.errors import CamplaceError
from camplace.plotly3d import Scene3D, SceneCamera, SceneMesh, reach_depth

log = logging.getLogger(__name__)

__all__ = ["seen_counts", "cameras_scene", "write_scene3d", "SCENE3D_FILE", "SAMPLE_POINTS"]

SCENE3D_FILE = "scene3d.html"
SAMPLE_POINTS = 4000


def seen_counts(cameras: Sequence, points: np.ndarray, normals: np.ndarray, blockers: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """How many cameras see each point (image, front, facing, unoccluded).

    Parameters
    ----------
    cameras : sequence of CameraView
    points : (n, 3) float64
        World points, metres.
    normals : (n, 3) float64
        Unit outward normals; all-zero rows (emitter points) skip the facing test.
    blockers : sequence of (vertices (v, 3) float64, faces (f, 3) int64)
        Meshes that occlude (the target included).

    Returns
    -------
    (n,) int64
    """
    from camplace.visibility import RayScene

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    counts = np.zeros(len(p), dtype=np.int64)
    if len(p) == 0:
        return counts
    scale = max(float(np.max(p.max(axis=0) - p.min(axis=0))), 1e-3)
    start = p + nrm * (1e-5 * scale)  # off the surface, so that its own triangle does not block
    scene = RayScene([(v, f) for v, f in blockers])
    for cam in cameras:
        uv, z = cam.project(p)
        with np.errstate(invalid="ignore"):
            inside = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < cam.width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < cam.height - 0.5)
        facing = np.einsum("ij,ij->i", nrm, cam.position - p) > 0
        facing |= ~np.any(nrm != 0.0, axis=1)
        cand = np.flatnonzero(inside & facing)
        if len(cand):
            blocked = scene.occluded(start[cand], np.repeat(cam.position[None], len(cand), axis=0))
            counts[cand[~blocked]] += 1
    return counts


def _scene_cameras(cameras: Sequence, depth_points: np.ndarray) -> tuple[SceneCamera, ...]:
    return tuple(SceneCamera(c.name, c.position, c.rotation, c.K, c.width, c.height, near_m=0.0,
                             depth_m=reach_depth(c.position, c.rotation, depth_points),
                             note=f"photo {c.image}" if getattr(c, "image", "") else "") for c in cameras)


def cameras_scene(
    cameras: Sequence,
    target: tuple[np.ndarray, np.ndarray],
    *,
    title: str,
    target_name: str = "target",
    occluders: Sequence[tuple[str, np.ndarray, np.ndarray]] = (),
    emitters: np.ndarray | None = None,
    other_systems: Sequence[tuple[str, Sequence]] = (),
    n_points: int = SAMPLE_POINTS,
    seed: int = 0,
    meta: dict | None = None,
) -> Scene3D:
    """The 3D scene of calibrated cameras around a target.

    Parameters
    ----------
    cameras : sequence of CameraView
        Drawn in strong colours; the coverage counts are theirs.
    target : (vertices (v, 3) float64, faces (f, 3) int64)
        World space, metres.
    title, target_name : str
    occluders : sequence of (name, vertices, faces)
        Drawn translucent; they block views.
    emitters : (e, 3) float64 or None
        Volumetric emitter points (coma, plume), coloured by coverage too.
    other_systems : sequence of (name, sequence of CameraView)
        Drawn muted, hidden until clicked in the legend.
    n_points : int
        Surface points sampled on the target (by area).
    seed : int
        Seed of that sample.
    meta : dict or None
        Extra fields of the page's data tag.

    Returns
    -------
    Scene3D
    """
    from camplace.visibility import sample_surface
    from camplace.visibility.points import face_normals_areas

    v, f = (np.asarray(target[0], dtype=np.float64), np.asarray(target[1], dtype=np.int64))
    if len(f) == 0:
        raise CamplaceError("scene3d: the target has no triangles")
    face, _, pts = sample_surface(v, f, int(n_points), seed=seed)
    nrm = face_normals_areas(v, f)[0][face]
    em = np.zeros((0, 3)) if emitters is None else np.asarray(emitters, dtype=np.float64).reshape(-1, 3)
    all_p = np.vstack([pts, em])
    all_n = np.vstack([nrm, np.zeros_like(em)])
    blockers = [(v, f)] + [(ov, of) for _, ov, of in occluders]
    counts = seen_counts(cameras, all_p, all_n, blockers)
    depth_points = np.vstack([v, em])
    return Scene3D(
        title=title,
        cameras=_scene_cameras(cameras, depth_points),
        target=SceneMesh(target_name, v, f),
        occluders=tuple(SceneMesh(name, ov, of) for name, ov, of in occluders),
        points=all_p,
        counts=counts,
        surface=np.concatenate([np.ones(len(pts), dtype=bool), np.zeros(len(em), dtype=bool)]),
        other_systems=tuple((name, _scene_cameras(cams, depth_points)) for name, cams in other_systems),
        notes=(f"Coverage: {len(pts):,} points sampled on the target by area (seed {seed}); a point is seen by a camera when it "
               "projects inside the image, faces the camera and nothing blocks the segment to its centre. Frusta from the "
               "centre to the depth that reaches the target (lens distortion ignored in the drawing).",),
        meta={"kind": "validation", **(meta or {})},
    )


def write_scene3d(out: str | Path, scene: Scene3D, *, intro_html: str = "") -> Path | None:
    """Write ``out/scene3d.html`` (self-contained, offline).

    Returns None, with a warning, when plotly is missing (and removes a stale ``scene3d.html``
    of an earlier validation there).
    """
    from camplace.plotly3d import require_plotly, scene_page

    path = Path(out) / SCENE3D_FILE
    try:
        require_plotly()
    except CamplaceError as exc:
        log.warning("validate: no %s (%s)", SCENE3D_FILE, exc)
        path.unlink(missing_ok=True)
        return None
    write_text_atomic(path, scene_page(scene, heading=f"camplace validate: {scene.title}", intro_html=intro_html))
    log.info("validate: wrote %s", path)
    return path
