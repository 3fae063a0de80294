"""The emulated physical camera: identity when perfect, IoU falling with placement error, noise model."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from camplace.errors import CamplaceError
from camplace.sampling import look_at
from camplace.validation.cameras import CameraView
from camplace.validation.compare import mask_metrics
from camplace.validation.detect import DetectionSettings, detect_target, expected_detection
from camplace.validation.physical import PhysicalCamera, apply_optics_and_sensor, emulate_shots, parse_physical, rotation_from_vector
from camplace.validation.render import RenderScene, encode_png, quantise, render_view


def small_scene(ground: bool = True):
    """A sphere on (or, without ground, floating above) a ground plane, lit from above."""
    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    target = (np.asarray(ico.vertices) + [0.0, 0.0, 0.3], np.asarray(ico.faces, dtype=np.int64))
    occ = [(np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))] if ground else []
    light = [1.0, -2.0, 4.0]
    return RenderScene.build(target, occ, light), RenderScene.build(None, occ, light)


def cameras(n: int = 4, width: int = 160, height: int = 120) -> list[CameraView]:
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.3
    pos = np.stack([2.5 * np.cos(ang), 2.5 * np.sin(ang), np.full(n, 1.2)], axis=1)
    R = look_at(pos, np.tile([0.0, 0.0, 0.3], (n, 1)))
    K = np.array([[200.0, 0, (width - 1) / 2], [0, 200.0, (height - 1) / 2], [0, 0, 1]])
    return [CameraView(f"c{i}", pos[i], R[i], K, width, height) for i in range(n)]


def test_perfect_camera_reproduces_the_render_exactly() -> None:
    fg, bg = small_scene()
    cams = cameras()
    shots = emulate_shots(cams, fg, bg, PhysicalCamera(), seed=123)
    for cam, shot in zip(cams, shots):
        ref = render_view(cam, fg)
        ref_bg = render_view(cam, bg)
        np.testing.assert_array_equal(shot.photo, np.clip(ref.image, 0.0, 1.0))
        np.testing.assert_array_equal(shot.background, np.clip(ref_bg.image, 0.0, 1.0))
        assert encode_png(quantise(shot.photo)) == encode_png(quantise(ref.image))
        np.testing.assert_array_equal(shot.actual.position, cam.position)
        np.testing.assert_array_equal(shot.actual.rotation, cam.rotation)
        np.testing.assert_array_equal(shot.target_mask, ref.target_mask)


def _analytic_shadow(cam: CameraView, target_mask: np.ndarray, centre=(0.0, 0.0, 0.3), radius: float = 0.3, light=(1.0, -2.0, 4.0)) -> np.ndarray:
    """(h, w) bool: pixels whose ray meets the ground z = 0 at a point whose segment to the light crosses the sphere."""
    origin, dirs = cam.rays(slice(0, cam.height))
    d = dirs.reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / d[:, 2]
    g = origin + d * t[:, None]
    seg = np.asarray(light) - g
    s = np.clip(np.einsum("ij,ij->i", np.asarray(centre) - g, seg) / np.einsum("ij,ij->i", seg, seg), 0.0, 1.0)
    dist = np.linalg.norm(g + seg * s[:, None] - np.asarray(centre), axis=1)
    return ((t > 0) & (dist < radius)).reshape(cam.height, cam.width) & ~target_mask


def test_expected_detection_is_the_target_and_its_cast_shadow() -> None:
    """Oracle: the sphere's shadow on the ground by ray-sphere geometry. Algorithm 3 on the render against
    the background render finds the target and that shadow (the prediction validation compares with)."""
    import cv2

    fg, bg = small_scene()
    for cam in cameras(4):
        render, background = render_view(cam, fg), render_view(cam, bg)
        target = render.target_mask
        shadow = _analytic_shadow(cam, target)
        assert shadow.sum() > 200
        exp = expected_detection(render.image, background.image, DetectionSettings(threshold="triangle", morph_kernel_px=0)).mask
        union = target | shadow
        assert np.count_nonzero(exp & union) / np.count_nonzero(exp | union) > 0.97, cam.name
        # the default (Otsu, 5 px morphology) keeps the whole shadow and adds nothing beyond target and shadow
        # (2 px of slack: the icosphere's facets against the analytic sphere, the kernel's rounding)
        exp = expected_detection(render.image, background.image).mask
        near = cv2.dilate(union.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        assert not np.any(exp & ~near), cam.name
        assert np.count_nonzero(exp & shadow) > 0.95 * shadow.sum(), cam.name
        # and a perfect camera's emulated photograph detects exactly that
        shot = emulate_shots([cam], fg, bg, PhysicalCamera(), seed=0)[0]
        np.testing.assert_array_equal(detect_target(quantise(shot.photo), quantise(shot.background)).mask, exp)


def test_iou_falls_as_placement_error_grows() -> None:
    # no ground: background subtraction would also detect the sphere's cast shadow (see the shadow test)
    fg, bg = small_scene(ground=False)
    cams = cameras(4)
    predicted = [render_view(c, fg).target_mask for c in cams]
    levels = [(0.0, 0.0), (0.03, 0.5), (0.08, 1.5), (0.15, 3.0), (0.3, 6.0)]
    means = []
    for sp, sr in levels:
        ious = []
        for seed in range(4):
            shots = emulate_shots(cams, fg, bg, PhysicalCamera(sigma_position_m=sp, sigma_rotation_deg=sr), seed=seed)
            for pred, shot in zip(predicted, shots):
                # triangle threshold: Otsu would split the sphere's lit and shaded halves (three-mode histogram)
                det = detect_target(quantise(shot.photo), quantise(shot.background), DetectionSettings(threshold="triangle"))
                ious.append(mask_metrics(pred, det.mask)["iou"] or 0.0)
        means.append(float(np.mean(ious)))
    assert all(a > b for a, b in zip(means, means[1:])), means
    assert means[0] > 0.95 and means[-1] < 0.5 * means[0], means


def test_same_seed_same_poses_whatever_the_noise() -> None:
    fg, bg = small_scene()
    cams = cameras(3, 32, 24)
    place = PhysicalCamera(sigma_position_m=0.05, sigma_rotation_deg=1.0)
    noisy = PhysicalCamera(sigma_position_m=0.05, sigma_rotation_deg=1.0, noise_sigma=0.01, noise_poisson_a=0.001)
    a = emulate_shots(cams, fg, bg, place, seed=7)
    b = emulate_shots(cams, fg, bg, noisy, seed=7)
    c = emulate_shots(cams, fg, bg, noisy, seed=8)
    for x, y, z in zip(a, b, c, strict=True):
        np.testing.assert_array_equal(x.actual.position, y.actual.position)
        np.testing.assert_array_equal(x.actual.rotation, y.actual.rotation)
        assert not np.array_equal(x.actual.position, z.actual.position)
        assert not np.array_equal(x.photo, y.photo)  # the noise is there


def test_placement_error_statistics() -> None:
    fg, bg = small_scene()
    cam = cameras(1, 16, 12)[0]
    phys = PhysicalCamera(sigma_position_m=0.05, sigma_rotation_deg=2.0)
    shots = emulate_shots([cam] * 300, fg, bg, phys, seed=7)
    dp = np.array([s.actual.position - cam.position for s in shots])
    assert dp.std(axis=0) == pytest.approx([0.05] * 3, rel=0.15)
    ang = np.array([math.degrees(math.acos(np.clip((np.trace(cam.rotation.T @ s.actual.rotation) - 1) / 2, -1, 1))) for s in shots])
    # the angle of a rotation vector with N(0, s^2) components is Maxwell distributed: mean 2 s sqrt(2 / pi)
    assert ang.mean() == pytest.approx(2 * 2.0 * math.sqrt(2 / math.pi), rel=0.1)
    same = emulate_shots([cam] * 3, fg, bg, phys, seed=7)
    for a, b in zip(shots[:3], same):
        np.testing.assert_array_equal(a.photo, b.photo)


def test_poisson_gaussian_noise_and_exposure() -> None:
    cam = cameras(1, 400, 300)[0]
    flat = np.full((300, 400), 0.25, np.float32)
    rng = np.random.default_rng(0)
    phys = PhysicalCamera(exposure_ev=1.0, noise_poisson_a=0.01, noise_sigma=0.02)
    out = apply_optics_and_sensor(flat, cam, phys, rng)
    y = 0.5  # 0.25 x 2^1
    assert out.mean() == pytest.approx(y, abs=2e-3)
    assert out.var() == pytest.approx(0.01 * y + 0.02**2, rel=0.03)  # Foi's model: a y + sigma^2
    halved = apply_optics_and_sensor(flat, cam, PhysicalCamera(exposure_ev=-1.0), rng)
    np.testing.assert_array_equal(halved, np.full_like(flat, 0.125))
    gain = apply_optics_and_sensor(flat, cam, PhysicalCamera(gain_db=20.0), rng)
    np.testing.assert_allclose(gain, 1.0)  # x10, clipped


def test_defocus_conserves_flux_and_vignetting_darkens_corners() -> None:
    cam = cameras(1, 81, 61)[0]
    img = np.zeros((61, 81), np.float32)
    img[30, 40] = 1.0
    blurred = apply_optics_and_sensor(img, cam, PhysicalCamera(defocus_radius_px=4.0), np.random.default_rng(0))
    assert blurred.sum() == pytest.approx(1.0, rel=1e-5)
    ys, xs = np.nonzero(blurred > 0)
    assert np.max(np.hypot(ys - 30, xs - 40)) <= 4.0 + math.sqrt(2) / 2 + 1e-9
    # a disc's second moment: r^2 / 4 per axis
    w = blurred / blurred.sum()
    yy, xx = np.mgrid[0:61, 0:81]
    assert float((w * (xx - 40) ** 2).sum()) == pytest.approx(4.0**2 / 4, rel=0.05)
    vig = apply_optics_and_sensor(np.ones((61, 81), np.float32), cam, PhysicalCamera(vignetting=0.4), np.random.default_rng(0))
    assert vig[30, 40] == 1.0
    assert 0.6 <= vig[0, 0] < vig[0, 40] < 1.0 and vig[0, 0] == pytest.approx(vig[60, 80])


def test_distortion_and_ambient_are_applied() -> None:
    fg, bg = small_scene()
    cam = cameras(1)[0]
    shot = emulate_shots([cam], fg, bg, PhysicalCamera(k1=-0.2, k2=0.05), seed=0)[0]
    np.testing.assert_array_equal(shot.actual.dist, [-0.2, 0.05, 0, 0, 0])
    np.testing.assert_array_equal(shot.photo, np.clip(render_view(shot.actual, fg).image, 0, 1))
    lit = emulate_shots([cam], fg, bg, PhysicalCamera(ambient_light=0.1), seed=0)[0]
    base = emulate_shots([cam], fg, bg, PhysicalCamera(), seed=0)[0]
    surf = shot.target_mask | (base.photo > 0)
    np.testing.assert_allclose(lit.photo[surf], np.clip(base.photo[surf] + 0.1, 0, 1), atol=1e-6)


def test_rotation_from_vector_matches_scipy() -> None:
    from scipy.spatial.transform import Rotation

    w = np.array([0.3, -0.2, 0.5])
    np.testing.assert_allclose(rotation_from_vector(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-12)


def test_parse_physical() -> None:
    p = parse_physical({"sigma_position_m": 0.01, "k1": -0.1, "gain_db": 3})
    assert p.sigma_position_m == 0.01 and p.k1 == -0.1 and p.gain_db == 3.0 and p.noise_sigma == 0.0
    assert parse_physical(None) == PhysicalCamera()
    with pytest.raises(CamplaceError, match="sigma_position: unknown key .*sigma_position_m"):
        parse_physical({"sigma_position": 0.01})
    with pytest.raises(CamplaceError, match="noise_sigma: must be >= 0"):
        parse_physical({"noise_sigma": -1})
    with pytest.raises(CamplaceError, match="vignetting"):
        parse_physical({"vignetting": 2})
    with pytest.raises(CamplaceError, match="finite number"):
        parse_physical({"k2": "big"})
