"""Rigid-body geometry shared by every stage: look-at, rotations, a box mesh, PLY bytes.

One convention everywhere: OpenCV camera axes (x right, y down, z forward) and world-from-camera
rotations (``world = R @ cam + C``). Rotations go through :class:`scipy.spatial.transform.Rotation`;
Euler angles are the instance format's extrinsic X, then Y, then Z (``R = Rz @ Ry @ Rx``, scipy's
``"xyz"``); quaternions are Hamilton ``(qw, qx, qy, qz)`` as COLMAP writes them.

At the bottom of the import order: imports numpy, scipy and :mod:`camplace.errors` only.
"""

from __future__ import annotations

import re
import warnings
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from camplace.errors import CamplaceError

__all__ = [
    "WORLD_UP",
    "look_at",
    "rotation_from_euler_deg",
    "euler_xyz_deg",
    "rotation_from_vector",
    "quaternion_to_rotation",
    "rotation_to_quaternion",
    "box_mesh",
    "ply_bytes",
    "triangle_soup_ply_bytes",
]

WORLD_UP = np.array([0.0, 0.0, 1.0])


def look_at(positions: np.ndarray, aims: np.ndarray, up: np.ndarray = WORLD_UP) -> np.ndarray:
    """World-from-camera rotations of cameras at ``positions`` looking at ``aims``.

    OpenCV convention: camera x right, y down, z forward. The columns of each matrix are the
    camera axes expressed in world coordinates, so ``world = R @ cam + position``. The image's
    "up" is the projection of ``up`` (world +z by default); a camera looking straight along
    ``up`` uses world +y instead.

    Parameters
    ----------
    positions : (n, 3) float64
    aims : (n, 3) float64
    up : (3,) float64

    Returns
    -------
    (n, 3, 3) float64
    """
    positions = np.atleast_2d(np.asarray(positions, dtype=np.float64))
    aims = np.atleast_2d(np.asarray(aims, dtype=np.float64))
    fwd = aims - positions
    norm = np.linalg.norm(fwd, axis=1, keepdims=True)
    if np.any(norm[:, 0] <= 0):
        raise CamplaceError("candidates: a camera position coincides with its aim point (move the volume or the target)")
    fwd = fwd / norm
    ups = np.broadcast_to(np.asarray(up, dtype=np.float64), fwd.shape).copy()
    parallel = np.abs(fwd @ np.asarray(up, dtype=np.float64)) > 1.0 - 1e-9
    ups[parallel] = np.array([0.0, 1.0, 0.0])
    right = np.cross(fwd, ups)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    down = np.cross(fwd, right)
    return np.stack([right, down, fwd], axis=2)


def rotation_from_euler_deg(angles_deg: Sequence[float] | np.ndarray) -> np.ndarray:
    """Rotation matrix from extrinsic X, then Y, then Z rotations (degrees): R = Rz @ Ry @ Rx.

    Parameters
    ----------
    angles_deg : (3,) float
        Rotation about the world x, y and z axes, degrees, applied in that order.

    Returns
    -------
    (3, 3) float64
    """
    return Rotation.from_euler("xyz", np.asarray(angles_deg, dtype=np.float64).reshape(3), degrees=True).as_matrix()


def euler_xyz_deg(R: np.ndarray) -> np.ndarray:
    """Extrinsic X-then-Y-then-Z Euler angles (degrees) of ``R = Rz @ Ry @ Rx`` (the instance format's convention).

    Parameters
    ----------
    R : (3, 3) float64

    Returns
    -------
    (3,) float64
        Angles about world x, y, z; at gimbal lock (|y| = 90 deg) x is set to 0.
    """
    R = np.asarray(R, dtype=np.float64)
    with warnings.catch_warnings():  # gimbal lock: scipy warns and sets the z angle to 0
        warnings.simplefilter("ignore", UserWarning)
        ax, ay, az = Rotation.from_matrix(R).as_euler("xyz", degrees=True)
    if abs(R[2, 0]) >= 1.0 - 1e-12:  # gimbal lock: only az - ax (y = +90) or az + ax (y = -90) is defined
        if ax != 0.0:
            az = ((az - ax if R[2, 0] < 0 else az + ax) + 180.0) % 360.0 - 180.0
        ax = 0.0
    return np.array([ax, ay, az])


def rotation_from_vector(w: np.ndarray) -> np.ndarray:
    """(3, 3) rotation ``Exp(w)`` of a rotation vector ``w`` (3,) (axis * angle, radians)."""
    return Rotation.from_rotvec(np.asarray(w, dtype=np.float64).reshape(3)).as_matrix()


def quaternion_to_rotation(q: Sequence[float]) -> np.ndarray:
    """(3, 3) rotation of the quaternion ``(qw, qx, qy, qz)`` (Hamilton, as COLMAP writes it; normalised first)."""
    w, x, y, z = (float(v) for v in q)
    if w == 0 and x == 0 and y == 0 and z == 0:
        raise CamplaceError("quaternion (0, 0, 0, 0) is not a rotation")
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (qw, qx, qy, qz) of a rotation matrix (Hamilton convention, as COLMAP), with qw >= 0.

    Parameters
    ----------
    R : (3, 3) float64

    Returns
    -------
    (4,) float64
        Inverse of :func:`quaternion_to_rotation`.
    """
    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat(canonical=True)
    return np.array([w, x, y, z])


# corner index 4 i + 2 j + k takes lo or hi on x, y, z by the bits i, j, k; two triangles a side, outward
_BOX_CORNER_BITS = np.array([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)], dtype=bool)
_BOX_FACES = np.array(
    [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
    dtype=np.int64,
)  # fmt: skip


def box_mesh(lo: Sequence[float], hi: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh of the axis-aligned box ``[lo, hi]`` (8 vertices, 12 outward-facing triangles).

    Parameters
    ----------
    lo, hi : (3,) float
        Opposite corners, metres (``lo < hi`` on every axis for outward normals).

    Returns
    -------
    vertices : (8, 3) float64
        Corner ``4 i + 2 j + k`` is ``hi`` on x when i = 1, on y when j = 1, on z when k = 1 (else ``lo``).
    faces : (12, 3) int64
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return np.where(_BOX_CORNER_BITS, hi, lo), _BOX_FACES.copy()


def _one_line(text: str) -> str:
    return re.sub(r"\s*[\r\n]+\s*", " ", str(text)).strip()


def ply_bytes(vertices: np.ndarray, faces: np.ndarray, comment: str = "", *, vertex_dtype: str = "<f8") -> bytes:
    """Binary little-endian PLY of a triangle mesh.

    trimesh's exporter writes float32 vertices; this one keeps float64 (``double``) by default, so
    coordinates round-trip exactly.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int
    comment : str
        One header comment line (newlines become spaces); none when empty.
    vertex_dtype : {"<f8", "<f4"}
        Vertex precision: ``double`` or ``float`` properties.

    Returns
    -------
    bytes
    """
    prop = {"<f8": "double", "<f4": "float"}[vertex_dtype]
    v = np.ascontiguousarray(vertices, dtype=vertex_dtype).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= min(len(v), 2**31 - 1)):
        raise ValueError("face index out of range")
    comment_line = f"comment {_one_line(comment)}\n" if comment else ""
    header = (
        f"ply\nformat binary_little_endian 1.0\n{comment_line}"
        f"element vertex {len(v)}\nproperty {prop} x\nproperty {prop} y\nproperty {prop} z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode("ascii")
    packed = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    packed["n"] = 3
    packed["i"] = f
    return header + v.tobytes() + packed.tobytes()


def triangle_soup_ply_bytes(triangles: np.ndarray, comment: str = "") -> bytes:
    """Binary PLY of a triangle soup with float32 vertices (each triangle its own 3 vertices).

    Parameters
    ----------
    triangles : (m, 3, 3) float32
        Vertex coordinates per triangle, written exactly (e.g. as ray-cast).
    comment : str

    Returns
    -------
    bytes
    """
    tri = np.asarray(triangles, dtype="<f4").reshape(-1, 3)
    return ply_bytes(tri, np.arange(len(tri) - len(tri) % 3, dtype=np.int64).reshape(-1, 3), comment, vertex_dtype="<f4")
