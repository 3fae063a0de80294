"""Export a run's chosen cameras: JSON, CSV, COLMAP text model and a GLB scene with camera frustums.

All in the run's (simulation) world frame, metres; for lab coordinates use ``camplace export --format placement``.
Cameras are named ``e{experiment}.1.camera_{n}`` like the renders (``OUTDIR/render``).

``cameras.json``
    The ``cameras.json`` format of :mod:`camplace.validation.cameras` (so ``camplace validate
    --cameras`` reads it), each camera with extra fields: candidate, aim, near_m, far_m, fov_x_deg,
    fov_y_deg and the COLMAP world-to-camera ``qvec`` (qw, qx, qy, qz) and ``tvec``.
``cameras.csv``
    ``name, candidate, x_m, y_m, z_m, aim_x_m, aim_y_m, aim_z_m, qw, qx, qy, qz, tx, ty, tz,
    r11..r33, fx_px, fy_px, cx_px, cy_px, width_px, height_px, near_m, far_m`` — q and t are COLMAP's
    world-to-camera pose; r11..r33 the world-from-camera rotation (OpenCV axes); cx, cy with pixel
    centres at integer coordinates (OpenCV).
``colmap/cameras.txt``, ``colmap/images.txt``, ``colmap/points3D.txt``
    COLMAP's text model: one PINHOLE camera per image (``fx fy cx cy`` with COLMAP's pixel
    convention, where the centre of the top-left pixel is (0.5, 0.5): cx, cy = ours + 0.5), and per
    image ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` (world-to-camera: x_cam = R(q) x_world + t)
    followed by an empty 2D-points line; points3D.txt is empty. For a team (cameras with a
    ``model``), one camera entry per camera model instead, shared by that model's images.
``cameras.glb``
    A glTF 2.0 binary scene: the instance's occluders and target (frame 0) and one frustum mesh per
    camera (apex at the camera centre, base = the image corners at the distance to its aim point).
    For a team, frustums are coloured by camera model and named ``frustum.{model}.{camera name}``.

For a team, ``cameras.json`` and ``cameras.csv`` also give each camera's ``model`` (the csv as a
last column) and ``cameras.json`` its ``cost``.
    glTF is y-up, so every node carries the rotation (x, y, z) -> (x, z, -y) from the run's z-up world.
"""

from __future__ import annotations

import csv
import io
import logging
from pathlib import Path
from typing import Sequence

import numpy as np

from camplace._io import write_bytes_atomic, write_json_atomic, write_text_atomic
from camplace.errors import CamplaceError
from camplace.geometry import rotation_to_quaternion
from camplace.names import CAMERA_FORMATS

log = logging.getLogger(__name__)

__all__ = [
    "EXPORT_FORMATS",
    "Z_UP_TO_Y_UP",
    "parse_formats",
    "rotation_to_quaternion",
    "colmap_pose",
    "write_colmap",
    "frustum_mesh",
    "glb_bytes",
    "default_export_folder",
    "export_cameras",
]

EXPORT_FORMATS = CAMERA_FORMATS  # the camera files (``camplace export`` adds ``placement``: camplace.names.EXPORT_FORMATS)

#: 4x4 transform from the run's z-up world to glTF's y-up frame: (x, y, z) -> (x, z, -y).
Z_UP_TO_Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, -1.0, 0, 0], [0, 0, 0, 1.0]])

CSV_COLUMNS = (
    ["name", "candidate", "x_m", "y_m", "z_m", "aim_x_m", "aim_y_m", "aim_z_m", "qw", "qx", "qy", "qz", "tx", "ty", "tz"]
    + [f"r{i}{j}" for i in range(1, 4) for j in range(1, 4)]
    + ["fx_px", "fy_px", "cx_px", "cy_px", "width_px", "height_px", "near_m", "far_m"]
)


def parse_formats(spec: str | Sequence[str]) -> tuple[str, ...]:
    """``"all"``, one format or a comma list (``"json,colmap"``) -> formats in canonical order."""
    items = [spec] if isinstance(spec, str) else list(spec)
    names = {s.strip().lower() for item in items for s in str(item).split(",") if s.strip()}
    if not names:
        raise CamplaceError(f"--format: give one of {', '.join(EXPORT_FORMATS)} or all")
    if "all" in names:
        return EXPORT_FORMATS
    bad = sorted(names - set(EXPORT_FORMATS))
    if bad:
        raise CamplaceError(f"--format: unknown format {bad[0]!r} (use {', '.join(EXPORT_FORMATS)} or all, comma-separated)")
    return tuple(f for f in EXPORT_FORMATS if f in names)


def colmap_pose(position: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's world-to-camera (qvec, tvec) of a camera at ``position`` with world-from-camera ``rotation``.

    Returns
    -------
    qvec : (4,) float64
        (qw, qx, qy, qz) of ``R_cw = rotation^T``.
    tvec : (3,) float64
        ``-R_cw @ position``.
    """
    Rcw = np.asarray(rotation, dtype=np.float64).T
    return rotation_to_quaternion(Rcw), -Rcw @ np.asarray(position, dtype=np.float64)


def write_colmap(cameras, folder: str | Path) -> list[Path]:
    """Write a COLMAP text model (cameras.txt, images.txt, empty points3D.txt) atomically.

    Parameters
    ----------
    cameras : sequence of camplace.validation.cameras.CameraView
        Ideal pinhole cameras (distortion is not exported; an error if any has some).
    folder : path

    Returns
    -------
    list of Path
    """
    folder = Path(folder)
    cam_lines = ["# Camera list with one line of data per camera:",
                 "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
                 "# PINHOLE params: fx, fy, cx, cy (COLMAP pixel convention: top-left pixel centre at (0.5, 0.5))",
                 f"# Number of cameras: {len(cameras)}"]
    img_lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
                 "#   POINTS2D[] as (X, Y, POINT3D_ID)",
                 f"# Number of images: {len(cameras)}, mean observations per image: 0"]
    by_model = any(getattr(cam, "model", "") for cam in cameras)
    camera_id: dict[str, int] = {}
    for i, cam in enumerate(cameras, start=1):
        if cam.has_distortion:
            raise CamplaceError(f"camera {cam.name!r}: has lens distortion; the COLMAP export writes PINHOLE cameras only")
        K = cam.K
        if abs(K[0, 1]) > 1e-12:
            raise CamplaceError(f"camera {cam.name!r}: K has a skew term, which COLMAP's PINHOLE model cannot hold")
        # ours: pixel centres at integer coordinates; COLMAP: at +0.5
        params = (K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5)
        line = f"PINHOLE {cam.width} {cam.height} " + " ".join(repr(float(v)) for v in params)
        if by_model:  # a team: one COLMAP camera per model, shared by its images
            key = f"{cam.model}\0{line}"
            if key not in camera_id:
                camera_id[key] = len(camera_id) + 1
                cam_lines.append(f"{camera_id[key]} {line}")
            cid = camera_id[key]
        else:
            cid = i
            cam_lines.append(f"{i} {line}")
        q, t = colmap_pose(cam.position, cam.rotation)
        name = cam.image or f"{cam.name}.png"
        img_lines.append(f"{i} " + " ".join(repr(float(v)) for v in (*q, *t)) + f" {cid} {name}")
        img_lines.append("")
    if by_model:
        cam_lines[3] = f"# Number of cameras: {len(camera_id)} (one per camera model: " + ", ".join(
            k.split("\0")[0] for k in camera_id) + ")"
    paths = [folder / "cameras.txt", folder / "images.txt", folder / "points3D.txt"]
    write_text_atomic(paths[0], "\n".join(cam_lines) + "\n")
    write_text_atomic(paths[1], "\n".join(img_lines) + "\n")
    write_text_atomic(paths[2], "# 3D point list with one line of data per point:\n"
                                "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
                                "# Number of points: 0, mean track length: 0\n")
    return paths


def frustum_mesh(camera, depth_m: float):
    """A closed pyramid mesh of a camera's view: apex at its centre, base = the image corners at ``depth_m``.

    Parameters
    ----------
    camera : camplace.validation.cameras.CameraView
    depth_m : float
        Depth (camera z) of the base.

    Returns
    -------
    trimesh.Trimesh
        5 vertices (apex first, then the corners of pixels (-0.5, -0.5), (w-0.5, -0.5),
        (w-0.5, h-0.5), (-0.5, h-0.5)) and 6 outward-facing triangles, in world coordinates.
    """
    import trimesh

    w, h = camera.width, camera.height
    corners_px = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    Kinv = np.linalg.inv(camera.K)
    rays = np.column_stack([corners_px, np.ones(4)]) @ Kinv.T  # camera frame, z = 1
    base = (rays * depth_m) @ camera.rotation.T + camera.position
    verts = np.vstack([camera.position[None], base])
    # camera frame: x right, y down, z forward; corners go clockwise seen from the camera, so the
    # sides (apex, b, a) and the base (1, 2, 3), (1, 3, 4) face outwards
    faces = np.array([[0, 2, 1], [0, 3, 2], [0, 4, 3], [0, 1, 4], [1, 2, 3], [1, 3, 4]])
    mesh = trimesh.Trimesh(verts, faces, process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


_FRUSTUM_COLOURS = [(230, 57, 70), (42, 157, 143), (69, 123, 157), (244, 162, 97), (131, 56, 236), (255, 190, 11)]


def glb_bytes(cameras, depths_m: Sequence[float], meshes: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> bytes:
    """A GLB scene: the given meshes and one frustum per camera (nodes ``frustum.{camera name}``).

    Parameters
    ----------
    cameras : sequence of CameraView
    depths_m : sequence of float
        Frustum depth per camera.
    meshes : sequence of (name, vertices (n, 3), faces (m, 3))
        Scene geometry in world coordinates.

    Returns
    -------
    bytes
    """
    import trimesh

    scene = trimesh.Scene()
    for name, v, f in meshes:
        m = trimesh.Trimesh(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64), process=False)
        target = name == "target"
        m.visual.face_colors = (235, 140, 52, 255) if target else (190, 195, 205, 90)
        scene.add_geometry(m, node_name=f"scene.{name}", geom_name=f"scene.{name}", transform=Z_UP_TO_Y_UP)
    models = list(dict.fromkeys(getattr(cam, "model", "") for cam in cameras))
    for i, (cam, d) in enumerate(zip(cameras, depths_m)):
        fr = frustum_mesh(cam, float(d))
        model = getattr(cam, "model", "")
        colour = models.index(model) if model else i  # a team: one colour per camera model
        fr.visual.face_colors = (*_FRUSTUM_COLOURS[colour % len(_FRUSTUM_COLOURS)], 160)
        node = f"frustum.{model}.{cam.name}" if model else f"frustum.{cam.name}"
        scene.add_geometry(fr, node_name=node, geom_name=node, transform=Z_UP_TO_Y_UP)
    data = scene.export(file_type="glb")
    return bytes(data)


def _solution_cameras(outdir: Path, experiment: str | None, phase: int | None = None):
    from camplace.validation.cameras import CameraSet
    from camplace.validation.workflow import load_run

    instance, solution = load_run(outdir)
    if phase is not None:  # the moving agents' poses of that phase (plan.json)
        from camplace.plan.io import phase_solution

        solution, _ = phase_solution(outdir, solution, phase)
    cams = CameraSet.from_solution(solution, experiment=experiment or instance.name, system=1).cameras
    return instance, solution, cams


def _model_of(instance, rec: dict):
    """The camera model (CameraModel) of a solution's camera record: by name, else the first."""
    for m in instance.cameras:
        if m.name == rec.get("model"):
            return m
    return instance.camera


def default_export_folder(outdir: str | Path, phase: int | None = None) -> Path:
    """The camera files' default folder: ``OUTDIR/export``, or ``OUTDIR/export-phaseP`` for a phase."""
    return Path(outdir) / ("export" if phase is None else f"export-phase{phase}")


def export_cameras(
    outdir: str | Path,
    *,
    formats: str | Sequence[str] = "all",
    out: str | Path | None = None,
    experiment: str | None = None,
    frustum_depth_m: float | None = None,
    phase: int | None = None,
) -> list[Path]:
    """Write the chosen cameras of a run in the requested formats (see the module docstring).

    Parameters
    ----------
    outdir : path
        A ``camplace run`` output folder.
    formats : str or sequence of str
        "json", "csv", "colmap", "glb", "all" or a comma list.
    out : path or None
        Output folder (default ``OUTDIR/export``).
    experiment : str or None
        Experiment name in camera names (default: the instance name).
    frustum_depth_m : float or None
        GLB frustum depth (default: each camera's distance to its aim point, within near..far).
    phase : int or None
        Export the moving agents' poses of this phase of ``OUTDIR/plan.json`` instead of the run's
        cameras (default out: ``OUTDIR/export-phaseP``).

    Returns
    -------
    list of Path
        The files written.
    """
    fmts = parse_formats(formats)
    outdir = Path(outdir)
    dest = Path(out) if out is not None else default_export_folder(outdir, phase)
    if frustum_depth_m is not None and not frustum_depth_m > 0:
        raise CamplaceError(f"--frustum-depth: must be > 0 metres, got {frustum_depth_m}")
    instance, solution, cams = _solution_cameras(outdir, experiment, phase)
    recs = solution.cameras
    written: list[Path] = []
    cm = instance.camera
    if "json" in fmts:
        items = []
        for cam, rec in zip(cams, recs):
            q, t = colmap_pose(cam.position, cam.rotation)
            d = cam.to_dict()
            d.update({"image": f"{cam.name}.png", "candidate": int(rec["candidate"]), "aim": [float(x) for x in rec.get("aim", [])],
                      "near_m": float(rec.get("near_m", cm.near_m)), "far_m": float(rec.get("far_m", cm.far_m)),
                      "fov_x_deg": cm.fov_x_deg, "fov_y_deg": cm.fov_y_deg,
                      "qvec": [float(x) for x in q], "tvec": [float(x) for x in t]})
            if "model" in rec:  # a team: the model's own field of view, and its cost
                m = _model_of(instance, rec)
                d.update({"model": rec["model"], "cost": float(rec.get("cost", m.cost)), "fov_x_deg": m.fov_x_deg, "fov_y_deg": m.fov_y_deg})
            items.append(d)
        src = str(outdir / "solution.json") if phase is None else f"{outdir / 'plan.json'} phase {phase}"
        doc = {"format": "json", "source": src, "instance": solution.instance,
               "frame": "simulation", "objective": solution.objective, "status": solution.status, "cameras": items}
        write_json_atomic(dest / "cameras.json", doc)
        written.append(dest / "cameras.json")
    if "csv" in fmts:
        buf = io.StringIO()
        wr = csv.writer(buf, lineterminator="\n")
        team = any("model" in rec for rec in recs)
        wr.writerow(CSV_COLUMNS + (["model"] if team else []))
        for cam, rec in zip(cams, recs):
            q, t = colmap_pose(cam.position, cam.rotation)
            aim = rec.get("aim") or [float("nan")] * 3
            K = cam.K
            wr.writerow([cam.name, int(rec["candidate"]), *map(repr, map(float, cam.position)), *map(repr, map(float, aim)),
                         *map(repr, map(float, q)), *map(repr, map(float, t)), *map(repr, map(float, cam.rotation.ravel())),
                         repr(float(K[0, 0])), repr(float(K[1, 1])), repr(float(K[0, 2])), repr(float(K[1, 2])),
                         cam.width, cam.height, repr(float(rec.get("near_m", cm.near_m))), repr(float(rec.get("far_m", cm.far_m))),
                         *([rec.get("model", "")] if team else [])])
        write_text_atomic(dest / "cameras.csv", buf.getvalue())
        written.append(dest / "cameras.csv")
    if "colmap" in fmts:
        written += write_colmap(cams, dest / "colmap")
    if "glb" in fmts:
        depths = []
        for cam, rec in zip(cams, recs):
            if frustum_depth_m is not None:
                depths.append(float(frustum_depth_m))
                continue
            aim = np.asarray(rec.get("aim") or (cam.position + cam.rotation[:, 2]), dtype=np.float64)
            z = float((aim - cam.position) @ cam.rotation[:, 2])
            near, far = float(rec.get("near_m", cm.near_m)), float(rec.get("far_m", cm.far_m))
            depths.append(min(max(z, near), far) if z > 0 else near)
        meshes = [(name, v, f) for name, v, f in instance.occluders_world(0)] + [("target", *instance.target_world(0))]
        write_bytes_atomic(dest / "cameras.glb", glb_bytes(cams, depths, meshes))
        written.append(dest / "cameras.glb")
    log.info("export-cameras: wrote %s", ", ".join(str(p) for p in written))
    return written
