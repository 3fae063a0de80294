"""The thesis's camera score (section 5.4.2, Algorithm 2 "Score Calculation"), implemented literally.

The published algorithm, for each camera ``c`` at ``(x_c, y_c)`` of a system, with the target's
coordinates ``(x_t, y_t)``, dimensions ``W, H`` and a camera angle ``omega``::

    d     = sqrt((x_t - x_c)^2 + (y_t - y_c)^2)
    fov   = 2 * arctan(sensorsize / 2 * focallength) + omega
    Max(fov(x)) = x_c + fov * 2          Min(fov(x)) = x_c - fov * 2
    Max(fov(y)) = y_c + fov * 2          Min(fov(y)) = y_c - fov * 2
    x_overlap = Max(0, Min(Max(fov(x)), x_t + W) - Max(Min(fov(x)), x_t))
    y_overlap = Max(0, Min(Max(fov(y)), y_t + H) - Max(Min(fov(y)), y_t))
    a     = x_overlap * y_overlap
    delta = d + a

:func:`legacy_camera_scores` computes exactly that; :func:`legacy_system_score` sums ``delta``
over the cameras of a system ("the combined scores of the cameras were analyzed", section 7.3).
It is kept only to compare with the thesis: it is **not** a measure of observation quality.

Quirks of the published formulas, kept on purpose (``legacy`` is the literal score):

1. **2D only.** Heights (z), the camera's orientation, occlusion and the image itself play no
   part: a camera looking away from the target scores like one looking at it.
2. **The FoV formula is garbled.** ``sensorsize / 2 * focallength`` is, with the usual operator
   precedence, ``(sensorsize / 2) * focallength`` (units mm^2), not the pinhole field of view
   ``2 * arctan(sensorsize / (2 * focallength))`` that was meant; :func:`corrected_fov_rad` gives
   the intended formula. With a 7.18 mm sensor and an 8 mm lens the printed formula gives
   2 * arctan(28.72) = 3.07 rad (176 deg) instead of 0.84 rad (48.3 deg).
3. **Degrees or radians?** ``arctan`` returns radians (numpy, Python) while the camera angle
   ``omega`` is "the camera angle", which Blender's interface shows in degrees. The literal sum
   adds ``omega`` as given, whatever its unit; the default ``omega = 0`` sidesteps the question.
   What "camera angle" means is not defined either (it is a single constant in the algorithm's
   "Define" block, not a per-camera heading).
4. **An angle used as a length.** ``fov * 2`` (radians, or degrees) is added to metre coordinates
   to make a square "coverage" box centred on the camera, of half-width ``2 * fov``. The text says
   "half of FoV was added", the formula adds twice the FoV. The box does not depend on where the
   camera looks or how far it can see.
5. **Misplaced parentheses.** ``Max(Min(fov(x), x_t))`` is printed with one argument to ``Max``;
   it is read as ``Max(Min(fov(x)), x_t)`` (the lower end of the intersection of the intervals
   ``[Min(fov(x)), Max(fov(x))]`` and ``[x_t, x_t + W]``), the only reading that is an overlap.
6. **Target corner, not centre.** The overlap uses the interval ``[x_t, x_t + W]``, so ``(x_t, y_t)``
   is the target's minimum corner, and ``d`` is measured to that corner. (If Blender's object
   origin, the centre, was meant, the box is off by half its size.) ``H`` is the target's extent
   along y (a top view), not its height.
7. **Units added together.** ``delta = d + a`` adds metres to square metres (units of the
   product of two angle-lengths, in fact), so the score depends on the unit of length.
8. **The score grows with distance.** Once the (huge) coverage box contains the target, ``a`` is
   the constant ``W * H`` and ``delta`` increases with ``d``: moving a camera away from the
   target raises its score. Normalising by the maximum score (as the thesis does) keeps the order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "LegacyTarget",
    "legacy_target",
    "printed_fov",
    "corrected_fov_rad",
    "legacy_camera_scores",
    "legacy_system_score",
]


@dataclass(frozen=True)
class LegacyTarget:
    """The inputs of Algorithm 2 that are the same for every camera.

    Attributes
    ----------
    x_t_m, y_t_m : float
        Target "coordinates": the minimum corner of its top-view bounding box, metres.
    width_m, height_m : float
        Target dimensions ``W`` (along x) and ``H`` (along y), metres.
    sensor_size_mm : float
        ``sensorsize`` (the sensor width).
    focal_length_mm : float
        ``focallength``.
    omega : float
        Camera angle ``omega``, added to the FoV as given (unit ambiguous, see quirk 3).
    """

    x_t_m: float
    y_t_m: float
    width_m: float
    height_m: float
    sensor_size_mm: float
    focal_length_mm: float
    omega: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {k: float(v) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "LegacyTarget":
        return cls(**{k: float(data[k]) for k in cls.__dataclass_fields__ if k in data})


def legacy_target(instance, omega: float = 0.0) -> LegacyTarget:
    """Algorithm 2's constants for an instance.

    ``(x_t, y_t, W, H)`` is the top-view (x-y) bounding box of the target over every frame with a
    positive likelihood (for a single frame: the target's box); ``sensorsize`` is the sensor width.

    Parameters
    ----------
    instance : camplace.instance.Instance
    omega : float
        The camera angle, added as given.

    Returns
    -------
    LegacyTarget
    """
    w = instance.frame_weights()
    lo = np.full(2, np.inf)
    hi = np.full(2, -np.inf)
    for f in range(len(instance.frames)):
        if w[f] <= 0 and len(instance.frames) > 1:
            continue
        v, _ = instance.target_world(f)
        lo = np.minimum(lo, v[:, :2].min(axis=0))
        hi = np.maximum(hi, v[:, :2].max(axis=0))
    cam = instance.camera
    return LegacyTarget(
        x_t_m=float(lo[0]), y_t_m=float(lo[1]), width_m=float(hi[0] - lo[0]), height_m=float(hi[1] - lo[1]),
        sensor_size_mm=float(cam.sensor_width_mm), focal_length_mm=float(cam.focal_length_mm), omega=float(omega),
    )


def printed_fov(sensor_size_mm: float, focal_length_mm: float, omega: float = 0.0) -> float:
    """The FoV exactly as printed: ``2 * arctan(sensorsize / 2 * focallength) + omega``.

    Operator precedence as written: ``sensorsize / 2 * focallength = (sensorsize / 2) * focallength``.
    ``arctan`` is in radians; ``omega`` is added as given (quirks 2 and 3 of the module docstring).
    """
    return 2.0 * math.atan(sensor_size_mm / 2 * focal_length_mm) + omega


def corrected_fov_rad(sensor_size_mm: float, focal_length_mm: float) -> float:
    """The pinhole field of view the thesis meant: ``2 * arctan(sensorsize / (2 * focallength))``, radians.

    Equals :attr:`camplace.instance.CameraModel.fov_x_deg` (in radians) for the sensor width.
    """
    return 2.0 * math.atan(sensor_size_mm / (2.0 * focal_length_mm))


def legacy_camera_scores(positions_m: np.ndarray, target: LegacyTarget) -> dict[str, np.ndarray]:
    """Algorithm 2 for each camera (literal; see the module docstring for its quirks).

    Parameters
    ----------
    positions_m : (..., 2) or (..., 3) float64
        Camera positions; only x and y are used (quirk 1).
    target : LegacyTarget

    Returns
    -------
    dict of str to (...,) float64
        ``distance`` (d), ``fov`` (as printed), ``x_overlap``, ``y_overlap``, ``area`` (a) and
        ``delta`` (d + a) per camera.
    """
    p = np.asarray(positions_m, dtype=np.float64)
    x_c, y_c = p[..., 0], p[..., 1]
    x_t, y_t, W, H = target.x_t_m, target.y_t_m, target.width_m, target.height_m
    d = np.sqrt((x_t - x_c) ** 2 + (y_t - y_c) ** 2)
    fov = printed_fov(target.sensor_size_mm, target.focal_length_mm, target.omega)
    max_x, max_y = x_c + fov * 2, y_c + fov * 2
    min_x, min_y = x_c - fov * 2, y_c - fov * 2
    x_overlap = np.maximum(0.0, np.minimum(max_x, x_t + W) - np.maximum(min_x, x_t))
    y_overlap = np.maximum(0.0, np.minimum(max_y, y_t + H) - np.maximum(min_y, y_t))
    a = x_overlap * y_overlap
    return {
        "distance": d,
        "fov": np.full(d.shape, fov),
        "x_overlap": x_overlap,
        "y_overlap": y_overlap,
        "area": a,
        "delta": d + a,
    }


def legacy_system_score(positions_m: np.ndarray, target: LegacyTarget) -> np.ndarray:
    """The legacy score of camera systems: the sum of Algorithm 2's ``delta`` over their cameras.

    Parameters
    ----------
    positions_m : (n_systems, k, 2 or 3) float64

    Returns
    -------
    (n_systems,) float64
    """
    return legacy_camera_scores(positions_m, target)["delta"].sum(axis=-1)
