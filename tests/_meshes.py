"""Mesh files as users bring them: a km-sized asteroid shape model written as an OBJ with texture
coordinates whose seams duplicate vertices, and an instance file around it (docs/instance-format.md).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

#: semi-axes of the test asteroid, km (a 2.4 x 1.6 x 1.2 km ellipsoid)
ASTEROID_AXES_KM = (1.2, 0.8, 0.6)


def asteroid_km(subdivisions: int = 2) -> trimesh.Trimesh:
    """A closed ellipsoidal asteroid in km, centred on the origin (trimesh icosphere scaled per axis)."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    mesh.apply_scale(ASTEROID_AXES_KM)
    return mesh


def seamed_uv(mesh: trimesh.Trimesh) -> np.ndarray:
    """Spherical texture coordinates per face corner, with a seam where a face crosses u = 0.

    Returns
    -------
    (m, 3, 2) float64
        (u, v) of each corner; on a seam face the corners with small u get u + 1, so the seam's
        positions carry two texture coordinates.
    """
    unit = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    u = (np.arctan2(unit[:, 1], unit[:, 0]) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(unit[:, 2], -1.0, 1.0)) / np.pi
    fu, fv = u[mesh.faces], v[mesh.faces]
    seam = np.ptp(fu, axis=1) > 0.5
    fu[seam] = np.where(fu[seam] < 0.5, fu[seam] + 1.0, fu[seam])
    return np.stack([fu, fv], axis=2)


def write_textured_obj(path: Path, mesh: trimesh.Trimesh) -> int:
    """Write ``mesh`` as an OBJ with ``vt`` lines, one ``v`` line per distinct (position, texture
    coordinate), as texture-mapping exporters do: every seam position is written twice or more.

    Returns
    -------
    int
        How many ``v`` lines repeat an earlier position (> 0: the file has seams).
    """
    uv = seamed_uv(mesh).reshape(-1, 2)
    corner_vertex = mesh.faces.reshape(-1)
    keys = np.column_stack([corner_vertex, np.round(uv * 1e6)])
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    first = np.unique(inverse.reshape(-1), return_index=True)[1]
    positions = mesh.vertices[unique[:, 0].astype(np.int64)]
    texture = uv[first]
    faces = inverse.reshape(-1, 3) + 1
    # no material library: trimesh then gives the texture coordinates a default material, which needs Pillow
    lines = ["# textured asteroid shape model, km", "o asteroid"]
    lines += [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in positions]
    lines += [f"vt {s:.6f} {t:.6f}" for s, t in texture]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")
    return len(positions) - len(mesh.vertices)


def asteroid_instance_toml(mesh_file: str, *, k: int = 2, require_light: bool = True) -> str:
    """An instance file written as a user would from docs/instance-format.md: the OBJ in km scaled to
    metres (``scale = 1000``), cameras on a 10 km box around it, the Sun along +x."""
    return f"""\
schema_version = 1
name = "textured-asteroid"
k = {k}

[run]
candidates = 60
points = 600
seed = 1

[camera]
sensor_width_mm = 7.18
sensor_height_mm = 5.32
focal_length_mm = 8.0
width_px = 640
height_px = 480
near_m = 100.0
far_m = 20000.0

[volume]
min_m = [-5000.0, -5000.0, -5000.0]
max_m = [5000.0, 5000.0, 5000.0]

[light]
position_m = [1.0e6, 0.0, 0.0]

[quality]
mode = "binary"
require_light = {"true" if require_light else "false"}

[target]
name = "asteroid"
file = "{mesh_file}"
scale = 1000.0                # the shape model is in km

[[frames]]
weight = 1.0
position_m = [0.0, 0.0, 0.0]
"""
