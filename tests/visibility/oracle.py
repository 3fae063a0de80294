"""An independent pure-numpy visibility oracle (float64 Moller-Trumbore, explicit projection).

Written from the definition in camplace.visibility.engine's docstring, sharing no code with it.
"""

from __future__ import annotations

import numpy as np


def segment_hits_any(origin: np.ndarray, end: np.ndarray, triangles: np.ndarray, eps: float = 1e-12) -> bool:
    """True when the open segment origin -> end crosses any triangle (float64 Moller-Trumbore).

    triangles : (t, 3, 3) float64
    """
    d = end - origin
    v0, v1, v2 = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    pvec = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    ok = np.abs(det) > eps
    inv = np.zeros_like(det)
    inv[ok] = 1.0 / det[ok]
    tvec = origin - v0
    u = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    v = (qvec @ d) * inv
    t = np.einsum("ij,ij->i", e2, qvec) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < 1)
    return bool(hit.any())


def observed(
    point: np.ndarray,
    normal: np.ndarray,
    cam_pos: np.ndarray,
    cam_rot: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    near: float,
    far: float,
    triangles: np.ndarray,
    eps_m: float,
    max_incidence_deg: float = 90.0,
    light: np.ndarray | None = None,
) -> bool:
    """The full observation test for one pair, from first principles.

    ``light`` given: a surface point must also be lit (n . (L - p) > 0, unblocked shadow segment).
    A zero normal marks a volumetric emitter: no facing, incidence or light test.
    """
    emitter = not np.any(normal)
    if not emitter:
        view = cam_pos - point
        cos_t = float(np.dot(normal, view) / np.linalg.norm(view))
        if cos_t <= 0 or np.degrees(np.arccos(min(1.0, cos_t))) > max_incidence_deg + 1e-9:
            return False
        if light is not None:
            if np.dot(normal, light - point) <= 0:
                return False
            if segment_hits_any(point + eps_m * normal, light, triangles):
                return False
    # world -> camera: the camera axes are the columns of cam_rot
    x, y, z = (point - cam_pos) @ cam_rot[:, 0], (point - cam_pos) @ cam_rot[:, 1], (point - cam_pos) @ cam_rot[:, 2]
    if not (near <= z <= far):
        return False
    u = K[0, 0] * x / z + K[0, 2]
    v = K[1, 1] * y / z + K[1, 2]
    if not (-0.5 <= u < width - 0.5 and -0.5 <= v < height - 0.5):
        return False
    if not emitter and np.dot(normal, cam_pos - point) <= 0:
        return False
    return not segment_hits_any(cam_pos, point + eps_m * normal, triangles)
