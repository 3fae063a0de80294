"""An emulated physical camera: photographs of the chosen placement as a real camera would take them.

With no real photographs, ``camplace validate`` takes "photographs" with :class:`PhysicalCamera`:

1. placement error: the camera stands at ``C + N(0, sigma_position_m^2 I)`` and is turned by a
   small rotation whose rotation vector (in the camera frame) has independent
   ``N(0, sigma_rotation_deg^2)`` components: ``R_actual = R @ Exp(w)``;
2. lens: radial distortion ``k1``, ``k2`` (OpenCV model; the rays of the render follow it exactly);
3. the scene: rendered from the actual pose with ``ambient_light`` added to the ambient term;
4. optics: defocus blur (a uniform disc of radius ``defocus_radius_px``), then vignetting
   ``gain(r) = max(0, 1 - vignetting * (r / r_corner)^2)`` with r the distance to the principal point;
5. exposure: times ``2 ** exposure_ev * 10 ** (gain_db / 20)``;
6. sensor noise, Poisson-Gaussian (Foi et al. 2008): ``z = a * Poisson(y / a) + N(0, noise_sigma^2)``
   with ``a = noise_poisson_a`` (variance ``a * y + noise_sigma^2``; ``a = 0`` disables the Poisson part);
7. clipping to [0, 1] (and quantisation when written to PNG).

Every field zero (the default) is the identity: the photograph equals the render bit for bit.
The same actual pose is used for a camera's photo and its background photo (the camera does not
move between the two shots); their noise is drawn independently.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from camplace.geometry import rotation_from_vector
from camplace.instance.lab import PhysicalCamera, parse_physical
from camplace.validation.cameras import CameraView

log = logging.getLogger(__name__)

__all__ = ["PhysicalCamera", "parse_physical", "perturb_camera", "install_camera", "apply_optics_and_sensor", "EmulatedShot",
           "emulate_shots", "rotation_from_vector", "unlit_level"]

#: Noise standard deviations above an unlit surface's mean level that :func:`unlit_level` allows.
UNLIT_NOISE_SIGMAS = 4.0


def perturb_camera(camera: CameraView, physical: PhysicalCamera, rng: np.random.Generator) -> CameraView:
    """The camera as actually placed: placement error and the lens's radial distortion.

    Draws 6 normal numbers from ``rng`` (always, so streams stay aligned whatever the sigmas).
    """
    z = np.concatenate([rng.normal(0.0, 1.0, 3), rng.normal(0.0, 1.0, 3)])
    return install_camera(camera, physical, z)


def install_camera(camera: CameraView, physical: PhysicalCamera, normals: np.ndarray) -> CameraView:
    """The camera as actually placed, from given standard normal draws (:func:`perturb_camera`'s model).

    Parameters
    ----------
    camera : CameraView
        The planned camera.
    physical : PhysicalCamera
        Its sigmas and lens distortion.
    normals : (6,) float64
        Standard normals: 3 of the position error (world axes), then 3 of the rotation vector (camera
        frame), as one scenario of :func:`camplace.sampling.perturb.pose_draws`.

    Returns
    -------
    CameraView
        At ``C + sigma_p * normals[:3]``, turned to ``R @ Exp(sigma_r * normals[3:])``, with the lens's
        radial distortion.
    """
    z = np.asarray(normals, dtype=np.float64).reshape(6)
    dp = z[:3] * physical.sigma_position_m
    w = z[3:] * math.radians(physical.sigma_rotation_deg)
    pos = camera.position + dp
    rot = camera.rotation @ rotation_from_vector(w) if np.any(w != 0) else camera.rotation
    out = camera.with_pose(pos, rot)
    if physical.k1 != 0.0 or physical.k2 != 0.0:
        out = out.with_dist([physical.k1, physical.k2, 0.0, 0.0, 0.0])
    return out


def unlit_level(physical: PhysicalCamera | None = None, settings=None, bit_depth: int = 8) -> float:
    """Gray level ([0, 1]) at or below which a pixel of an emulated photograph shows no lit surface.

    An unlit surface (night side, cast shadow) is rendered with the ambient term alone
    (:mod:`camplace.validation.render`), plus the room's ``ambient_light``, times the exposure
    factor; the level returned adds :data:`UNLIT_NOISE_SIGMAS` standard deviations of the sensor
    noise at that level (Poisson-Gaussian, step 6 of the module docstring) and half a quantisation
    step of ``bit_depth`` (an 8-bit photograph rounds 0.05 up to 13/255). Vignetting and defocus only
    lower it. Used as Algorithm 3's ``min_level`` when the instance requires light.

    Parameters
    ----------
    physical : PhysicalCamera or None
        The emulated camera (None: a perfect camera, the render itself).
    settings : camplace.validation.render.RenderSettings or None
        The renderer's constants (default ones when None).
    bit_depth : {8, 16}

    Returns
    -------
    float
    """
    from camplace.validation.render import RenderSettings

    physical = physical or PhysicalCamera()
    settings = settings or RenderSettings()
    mean = max(0.0, (settings.ambient + physical.ambient_light) * physical.exposure_factor)
    noise = math.sqrt(physical.noise_poisson_a * mean + physical.noise_sigma**2)
    return float(mean + UNLIT_NOISE_SIGMAS * noise + 0.5 / (2**int(bit_depth) - 1))


def _disc_kernel(radius_px: float) -> np.ndarray:
    r = int(math.ceil(radius_px))
    y, x = np.mgrid[-r : r + 1, -r : r + 1]
    # area-weighted disc by 4x4 supersampling of each kernel pixel
    s = (np.arange(4) + 0.5) / 4 - 0.5
    acc = np.zeros(x.shape)
    for sy in s:
        for sx in s:
            acc += ((x + sx) ** 2 + (y + sy) ** 2) <= radius_px**2
    k = acc / acc.sum()
    return k.astype(np.float32)


def apply_optics_and_sensor(
    image: np.ndarray, camera: CameraView, physical: PhysicalCamera, rng: np.random.Generator
) -> np.ndarray:
    """Steps 4-7 of the module docstring on a linear float image.

    Parameters
    ----------
    image : (h, w) float32
        Rendered radiance.
    camera : CameraView
        For the principal point (vignetting).
    physical : PhysicalCamera
    rng : numpy.random.Generator

    Returns
    -------
    (h, w) float32 in [0, 1]
    """
    out = np.asarray(image, dtype=np.float32).copy()
    if physical.defocus_radius_px > 0:
        import cv2

        out = cv2.filter2D(out, cv2.CV_32F, _disc_kernel(physical.defocus_radius_px), borderType=cv2.BORDER_REFLECT)
    if physical.vignetting > 0:
        h, w = out.shape
        cx, cy = camera.K[0, 2], camera.K[1, 2]
        yy, xx = np.mgrid[0:h, 0:w]
        r2 = (xx - cx) ** 2 + (yy - cy) ** 2
        corner2 = max((cx - x) ** 2 + (cy - y) ** 2 for x in (-0.5, w - 0.5) for y in (-0.5, h - 0.5))
        out *= np.maximum(0.0, 1.0 - physical.vignetting * r2 / corner2).astype(np.float32)
    if physical.exposure_factor != 1.0:
        out *= np.float32(physical.exposure_factor)
    if physical.noise_poisson_a > 0:
        a = physical.noise_poisson_a
        out = (a * rng.poisson(np.maximum(out, 0.0) / a)).astype(np.float32)
    if physical.noise_sigma > 0:
        out += rng.normal(0.0, physical.noise_sigma, out.shape).astype(np.float32)
    return np.clip(out, 0.0, 1.0)


@dataclass(frozen=True, eq=False)
class EmulatedShot:
    """An emulated photograph and background photograph of one camera.

    Attributes
    ----------
    photo : (h, w) float32
        With the target, in [0, 1].
    background : (h, w) float32
        Without the target, in [0, 1].
    camera : CameraView
        The nominal camera.
    actual : CameraView
        Where the physical camera actually stood (and its distortion).
    target_mask : (h, w) bool
        The target's pixels in the actual photo (ground truth of the emulation).
    depth : (h, w) float32 or None
        Ray length to the first surface hit per pixel in the actual photo (the render's depth, metres;
        inf where nothing is hit).
    """

    photo: np.ndarray
    background: np.ndarray
    camera: CameraView
    actual: CameraView
    target_mask: np.ndarray
    depth: np.ndarray | None = None


def emulate_shots(
    cameras,
    scene,
    background_scene,
    physical: PhysicalCamera,
    *,
    settings=None,
    emitters: Any = None,
    seed: int | np.random.Generator | None = 0,
    workers: int | None = None,
    installed: Any = None,
) -> list[EmulatedShot]:
    """Photograph the scene with every camera as a :class:`PhysicalCamera` would.

    Parameters
    ----------
    cameras : sequence of CameraView
        The nominal (planned) cameras.
    scene, background_scene : camplace.validation.render.RenderScene
        The frame with and without the target.
    physical : PhysicalCamera
    settings : camplace.validation.render.RenderSettings or None
    emitters : optional
        Emitters of the frame (glow in the photo, not in the background).
    seed : int, Generator or None
        ``numpy.random.default_rng`` is called once with it; placement errors and sensor noise draw
        from two streams spawned from it, so one seed gives the same poses whatever the noise settings
        (the placement error's share of a validation's drop can be measured alone).
    workers : int or None
        Render threads.
    installed : sequence of CameraView or None
        Where each camera actually stands (e.g. :func:`install_camera` from given draws); None: drawn
        here with :func:`perturb_camera`. The sensor noise stream is the same either way.

    Returns
    -------
    list of EmulatedShot
    """
    from camplace.validation.render import RenderSettings, render_view

    pose_rng, sensor_rng = np.random.default_rng(seed).spawn(2)
    settings = settings or RenderSettings()
    if physical.ambient_light:
        settings = settings.with_ambient(settings.ambient + physical.ambient_light)
    shots = []
    cameras = list(cameras)
    if installed is not None and len(installed) != len(cameras):
        raise ValueError(f"installed: {len(installed)} poses for {len(cameras)} cameras")
    for t, cam in enumerate(cameras):
        actual = perturb_camera(cam, physical, pose_rng) if installed is None else installed[t]
        fg = render_view(actual, scene, settings=settings, emitters=emitters, workers=workers)
        bg = render_view(actual, background_scene, settings=settings, workers=workers)
        photo = apply_optics_and_sensor(fg.image, actual, physical, sensor_rng)
        background = apply_optics_and_sensor(bg.image, actual, physical, sensor_rng)
        shots.append(EmulatedShot(photo=photo, background=background, camera=cam, actual=actual, target_mask=fg.target_mask,
                                  depth=fg.depth))
        log.debug("emulated %s: moved %.4f m", cam.name, float(np.linalg.norm(actual.position - cam.position)))
    return shots
