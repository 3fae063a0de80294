"""How many pixels the target covers in a camera: the projected area of its convex hull.

A run counts sample points, not pixels: a target a thousand times too small (a mesh in kilometres
read as metres, a body seen from 10 km) still has every sample point "observed" while the cameras
see it as a fraction of a pixel. :func:`target_footprint_px` measures, for every camera and frame,
the area in pixels of the target's convex hull projected by the pinhole camera (OpenCV axes,
world-from-camera rotations): the sum of the projected areas of the hull faces that face the
camera, which tile the hull's silhouette exactly. It bounds the target's own silhouette from
above (the silhouette lies inside the hull's), is not clipped to the image (it measures the
target's size in the view, not how much of it is framed) and costs one projection of the hull's
vertices per camera and frame.

Two users:

* ``camplace run`` warns (:func:`small_target_warnings`) when the target covers fewer than
  :data:`SMALL_TARGET_PX` pixels in every chosen camera;
* ``[quality] min_target_px`` (:attr:`camplace.instance.QualitySpec.min_target_px`): the visibility
  engine drops the target's points of a frame from a camera whose footprint in that frame is
  smaller (:func:`small_views`).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["SMALL_TARGET_PX", "convex_hull", "hull_footprint_px", "target_footprint_px", "small_views", "small_target_warnings"]

#: Pixels below which the target is too small to see: 25 px, a 5 x 5 px patch. Algorithm 3
#: (:mod:`camplace.validation.detect`) opens the detected mask with a 5 px elliptical kernel
#: (``DetectionSettings.morph_kernel_px``, 21 px), which erases any blob that cannot hold it, so
#: a target covering fewer pixels cannot be detected in a photograph, and the run's sample points
#: on it fall many to a pixel.
SMALL_TARGET_PX = 25.0

_CAMERAS_PER_BLOCK = 256  # cameras projected at once (bounds the (c, v, 3) work array)


def convex_hull(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The convex hull of some points (qhull through scipy), its faces wound outwards.

    Parameters
    ----------
    vertices : (n, 3) float64

    Returns
    -------
    (vertices (h, 3) float64, faces (f, 3) int64 wound outwards), or None when the points are flat
    or too few to enclose a volume.
    """
    from scipy.spatial import ConvexHull, QhullError

    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if len(v) < 4 or not np.all(np.isfinite(v)):
        return None
    try:
        hull = ConvexHull(v)
    except (QhullError, ValueError):  # qhull refuses flat or degenerate input
        return None
    if len(hull.simplices) < 4 or not hull.volume > 0.0:
        return None
    faces = np.asarray(hull.simplices, dtype=np.int64).copy()
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), hull.equations[:, :3]) < 0.0  # qhull: outward normals
    faces[inward] = faces[inward][:, ::-1]
    used = np.unique(faces)  # the hull's own vertices, renumbered in input order
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(used.size, dtype=np.int64)
    return v[used].copy(), remap[faces]


def hull_footprint_px(vertices: np.ndarray, positions: np.ndarray, rotations: np.ndarray, K: np.ndarray,
                      hull: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Projected area, in pixels, of the convex hull of some points in each camera.

    Parameters
    ----------
    vertices : (n, 3) float64
        World points, metres (a mesh's vertices).
    positions : (c, 3) float64
        Camera centres, metres.
    rotations : (c, 3, 3) float64
        World-from-camera rotations (columns: camera x right, y down, z forward).
    K : (3, 3) float64
        Pinhole intrinsics (pixels).
    hull : (vertices (h, 3), faces (f, 3)) or None
        The points' convex hull in world coordinates when already known (:func:`convex_hull`).

    Returns
    -------
    (c,) float64
        Area of the hull's silhouette in the image plane, pixels (not clipped to the image); 0
        when the hull lies wholly behind the camera, inf when it straddles the camera's plane
        (the projection is unbounded). A flat or degenerate point set is measured by its
        bounding sphere instead (the disc ``pi (f r)^2 / (d^2 - r^2)`` seen on the optical axis).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    rot = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    hull = convex_hull(v) if hull is None else hull
    if hull is None:
        return _sphere_footprint_px(v, pos, K)
    hv, hf = hull
    out = np.empty(len(pos))
    for a in range(0, len(pos), _CAMERAS_PER_BLOCK):
        b = min(a + _CAMERAS_PER_BLOCK, len(pos))
        out[a:b] = _convex_area_px(hv, hf, pos[a:b], rot[a:b], K)
    return out


def _convex_area_px(hv: np.ndarray, hf: np.ndarray, pos: np.ndarray, rot: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Silhouette area (c,) of a convex hull (vertices hv, outward faces hf): its front faces' projected areas."""
    cam = np.einsum("vk,ckl->cvl", hv, rot) - np.einsum("ck,ckl->cl", pos, rot)[:, None, :]  # (c, v, 3)
    z = cam[..., 2]
    straddles = ~(z > 0).all(axis=1) & (z > 0).any(axis=1)
    behind = ~(z > 0).any(axis=1)
    zs = np.where(z > 0, z, 1.0)
    uv = np.stack([K[0, 0] * cam[..., 0] / zs, K[1, 1] * cam[..., 1] / zs], axis=-1)  # (c, v, 2), offsets cancel
    tri = hv[hf]  # (f, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    front = np.einsum("fk,cfk->cf", normal, pos[:, None, :] - tri[None, :, 0]) > 0  # (c, f)
    a, b, c = uv[:, hf[:, 0]], uv[:, hf[:, 1]], uv[:, hf[:, 2]]
    cross = (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
    area = 0.5 * np.sum(np.where(front, np.abs(cross), 0.0), axis=1)
    return np.where(straddles, np.inf, np.where(behind, 0.0, area))


def _sphere_footprint_px(v: np.ndarray, pos: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(c,) on-axis projected area of the points' bounding sphere (inf when a camera is inside it)."""
    if len(v) == 0:
        return np.zeros(len(pos))
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre, r = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo)) / 2.0
    d2 = np.sum((pos - centre) ** 2, axis=1)
    f2 = float(K[0, 0] * K[1, 1])
    with np.errstate(divide="ignore"):
        return np.where(d2 > r * r, np.pi * f2 * r * r / np.maximum(d2 - r * r, 1e-300), np.inf)


def target_footprint_px(instance, positions: np.ndarray, rotations: np.ndarray, frames: Sequence[int] | None = None,
                        models: np.ndarray | None = None) -> np.ndarray:
    """The target's footprint (:func:`hull_footprint_px`) in each camera and frame.

    Parameters
    ----------
    instance : camplace.instance.Instance
        Its camera model and posed target.
    positions : (c, 3) float64
    rotations : (c, 3, 3) float64
        World-from-camera.
    frames : sequence of int or None
        Frames to measure (default: all); the other columns are NaN.
    models : (c,) int or None
        Each camera's model (index into ``instance.cameras``; default: all the first model).

    Returns
    -------
    (c, n_frames) float64
        Pixels.
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    rotations = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    if models is not None and len(getattr(instance, "cameras", ())) > 1:
        models = np.asarray(models)
        out = np.full((len(pos), len(instance.frames)), np.nan)
        for j in np.unique(models):
            sel = models == j
            out[sel] = _footprint_px(instance, pos[sel], rotations[sel], frames, instance.cameras[int(j)].K())
        return out
    return _footprint_px(instance, pos, rotations, frames, instance.camera.K())


def _footprint_px(instance, pos: np.ndarray, rotations: np.ndarray, frames, K: np.ndarray) -> np.ndarray:
    """:func:`target_footprint_px` of cameras with one intrinsic matrix ``K``."""
    out = np.full((len(pos), len(instance.frames)), np.nan)
    local = convex_hull(instance.target.vertices)  # once: each frame's pose is a rigid motion of it
    for f in range(len(instance.frames)) if frames is None else frames:
        pose = instance.frames[int(f)].target_pose
        hull = None if local is None else (pose.apply(local[0]), local[1])
        verts = instance.target_world(int(f))[0] if hull is None else hull[0]
        out[:, int(f)] = hull_footprint_px(verts, pos, rotations, K, hull=hull)
    return out


def small_views(instance, positions: np.ndarray, rotations: np.ndarray, frames: Sequence[int] | None = None,
                models: np.ndarray | None = None) -> np.ndarray | None:
    """Which (camera, frame) views see the target smaller than ``[quality] min_target_px``.

    Returns
    -------
    (c, n_frames) bool or None
        None when the instance sets no minimum (``min_target_px = 0``).
    """
    need = float(getattr(instance.quality, "min_target_px", 0.0))
    if need <= 0:
        return None
    fp = target_footprint_px(instance, positions, rotations, frames, models)
    return np.nan_to_num(fp, nan=np.inf) < need


def small_target_warnings(instance, positions: np.ndarray, rotations: np.ndarray, labels: Sequence[str] | None = None,
                          threshold: float = SMALL_TARGET_PX, models: np.ndarray | None = None) -> list[str]:
    """Warnings when the chosen cameras see the target smaller than ``threshold`` pixels.

    Parameters
    ----------
    instance : camplace.instance.Instance
    positions : (k, 3) float64
        The chosen cameras' centres.
    rotations : (k, 3, 3) float64
        Their world-from-camera rotations.
    labels : sequence of str or None
        How to name each camera in a warning (default: 1, 2, ...).
    threshold : float
        Pixels (default :data:`SMALL_TARGET_PX`; at least the instance's ``min_target_px``).
    models : (k,) int or None
        Each camera's model (index into ``instance.cameras``).

    Returns
    -------
    list of str
        One warning when the target covers fewer than ``threshold`` px in every chosen camera and
        frame (the largest footprint named), else one naming the cameras that see it that small in
        every frame, else nothing.
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(pos) == 0:
        return []
    labels = [str(j + 1) for j in range(len(pos))] if labels is None else [str(x) for x in labels]
    threshold = max(float(threshold), float(getattr(instance.quality, "min_target_px", 0.0)))
    largest = np.max(target_footprint_px(instance, pos, rotations, models=models), axis=1)  # (k,) over frames
    small = f"fewer than {threshold:g} px"
    why = "Algorithm 3's 5 px morphology erases a target that small, so photographs cannot confirm what the run counts as observed"
    if np.all(largest < threshold):
        return [
            f"the target is too small to see: its convex hull covers at most {float(largest.max()):.3g} px in every "
            f"chosen camera, {small} ({why}); check the mesh scale (the target file's units, `scale`) and "
            "camera.focal_length_mm, or set [quality] min_target_px so that only views resolving it count"
        ]
    few = np.flatnonzero(largest < threshold)
    if len(few) == 0:
        return []
    names = ", ".join(f"{labels[j]} ({largest[j]:.3g} px)" for j in few)
    return [f"the target covers {small} in every frame of chosen camera(s) {names} ({why}): what they add is not resolved"]
