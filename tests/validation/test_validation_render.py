"""Renderer against analytic oracles: sphere silhouettes, Lambertian shading, hard shadows, glow, distortion."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import trimesh

from camplace.sampling import look_at
from camplace.validation.cameras import CameraView
from camplace.validation.render import (
    LABEL_TARGET,
    GlowEmitters,
    RenderScene,
    RenderSettings,
    read_image,
    render_view,
    write_png,
)


def sphere(radius: float = 1.0, subdivisions: int = 6) -> tuple[np.ndarray, np.ndarray]:
    ico = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(ico.vertices, dtype=np.float64), np.asarray(ico.faces, dtype=np.int64)


def camera_at(position, aim, f_px: float, width: int, height: int, name: str = "cam") -> CameraView:
    pos = np.asarray(position, dtype=np.float64)
    R = look_at(pos[None], np.asarray(aim, dtype=np.float64)[None])[0]
    K = np.array([[f_px, 0.0, (width - 1) / 2], [0.0, f_px, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return CameraView(name, pos, R, K, width, height)


def quad(z: float, half: float, centre=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    cx, cy = centre
    v = np.array([[cx - half, cy - half, z], [cx + half, cy - half, z], [cx + half, cy + half, z], [cx - half, cy + half, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("d", [2.5, 4.0, 8.0])
def test_sphere_mask_area_matches_projected_disc(d: float) -> None:
    f = 300.0
    cam = camera_at([0.0, -d, 0.0], [0.0, 0.0, 0.0], f, 401, 401)
    res = render_view(cam, RenderScene.build(sphere(), (), [0.0, -d, 0.0]))
    # a sphere of radius r at distance d seen on the optical axis projects to a disc of radius f r / sqrt(d^2 - r^2)
    rho = f / math.sqrt(d * d - 1.0)
    expected = math.pi * rho * rho
    assert res.target_px == pytest.approx(expected, rel=0.015)
    # the disc is centred on the principal point
    ys, xs = np.nonzero(res.target_mask)
    assert xs.mean() == pytest.approx(200.0, abs=0.3) and ys.mean() == pytest.approx(200.0, abs=0.3)


def _analytic_sphere(cam: CameraView, radius: float = 1.0):
    """Per pixel: does the ray hit the exact sphere at the origin, and the hit point and normal."""
    o, dirs = cam.rays()
    d = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    b = d @ o
    c = o @ o - radius * radius
    disc = b * b - c
    hit = disc > 0
    t = -b - np.sqrt(np.maximum(disc, 0))
    p = o + d * t[..., None]
    return hit, p, p / radius


@pytest.mark.parametrize("light", [[0.0, -6.0, 0.0], [5.0, -5.0, 3.0]], ids=["head-on", "oblique"])
def test_lambertian_shading_matches_analytic_sphere(light) -> None:
    settings = RenderSettings(albedo_target=0.7, ambient=0.1, light_intensity=1.0)
    cam = camera_at([0.0, -6.0, 0.0], [0.0, 0.0, 0.0], 500.0, 201, 201)
    res = render_view(cam, RenderScene.build(sphere(), (), light, settings), settings=settings)
    hit, p, n = _analytic_sphere(cam)
    L = np.asarray(light) - p
    cos = np.einsum("...k,...k->...", n, L) / np.linalg.norm(L, axis=-1)
    expected = 0.7 * np.maximum(cos, 0.0) + 0.1
    # centre pixel: the sphere point facing the camera
    c = res.image[100, 100]
    if light[0] == 0.0:
        assert c == pytest.approx(0.7 * 1.0 + 0.1, abs=1e-3)  # cos(0) = 1
    else:
        # a flat facet's normal is within delta of the sphere's normals at its corners: |d cos| <= delta
        v, f = sphere()
        tri = v[f]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        fn /= np.linalg.norm(fn, axis=1, keepdims=True)
        delta = float(np.arccos(np.clip(np.einsum("fk,fck->fc", fn, tri / np.linalg.norm(tri, axis=2, keepdims=True)), -1, 1)).max())
        assert c == pytest.approx(expected[100, 100], abs=0.7 * delta + 1e-4)
    both = hit & res.target_mask
    # ignore the silhouette rim, where facets and the true sphere disagree on the pixel
    inner = cv2.erode(both.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    err = np.abs(res.image[inner] - expected[inner])
    assert np.median(err) < 3e-3
    assert np.quantile(err, 0.99) < 0.03  # flat facets of a 40k-triangle sphere, terminator included
    assert np.all(res.image[~res.target_mask] == settings.background)


def test_hard_shadow_of_a_plate_on_the_ground() -> None:
    settings = RenderSettings(albedo_target=0.6, albedo_occluder=0.6, ambient=0.05)
    light = np.array([0.0, 0.0, 10.0])
    ground = quad(0.0, 20.0)
    plate = quad(5.0, 0.5, centre=(2.0, 0.0))  # 1 x 1 m plate halfway to the light
    scene = RenderScene.build(ground, [plate], light, settings)
    cam = camera_at([4.0, -8.0, 6.0], [4.0, 0.0, 0.0], 300.0, 320, 240)
    res = render_view(cam, scene, settings=settings)
    # central projection of the plate from the light onto z = 0: x in [3, 5], y in [-1, 1]
    o, dirs = cam.rays()
    t = -o[2] / dirs[..., 2]
    g = o + dirs * t[..., None]
    on_ground = res.label == LABEL_TARGET
    assert on_ground.sum() > 0.5 * res.image.size
    inside = on_ground & (np.abs(g[..., 0] - 4.0) < 0.95) & (np.abs(g[..., 1]) < 0.95)
    outside = on_ground & ((np.abs(g[..., 0] - 4.0) > 1.05) | (np.abs(g[..., 1]) > 1.05))
    assert inside.sum() > 500
    np.testing.assert_allclose(res.image[inside], 0.05, atol=1e-6)
    L = light - g
    lit = 0.6 * L[..., 2] / np.linalg.norm(L, axis=-1) + 0.05
    np.testing.assert_allclose(res.image[outside], lit[outside], atol=2e-5)
    # without shadow rays the same pixels are lit
    flat = render_view(cam, scene, settings=RenderSettings(albedo_target=0.6, albedo_occluder=0.6, ambient=0.05, shadows=False))
    np.testing.assert_allclose(flat.image[inside], lit[inside], atol=2e-5)


def test_background_render_has_no_target_and_label_mask_agree() -> None:
    cam = camera_at([0.0, -5.0, 1.0], [0.0, 0.0, 0.0], 200.0, 160, 120)
    ground = quad(-1.0, 10.0)
    with_t = render_view(cam, RenderScene.build(sphere(0.5, 4), [ground], [2.0, -3.0, 5.0]))
    without = render_view(cam, RenderScene.build(None, [ground], [2.0, -3.0, 5.0]))
    assert with_t.target_px > 0 and without.target_px == 0
    np.testing.assert_array_equal(with_t.target_mask, with_t.label == LABEL_TARGET)


def test_glow_emitter_peak_flux_and_occlusion() -> None:
    cam = camera_at([0.0, 0.0, 0.0], [0.0, 5.0, 0.0], 400.0, 201, 201)
    glow = GlowEmitters.from_pairs([((0.0, 5.0, 0.0), 0.7)], radius_m=0.05)
    settings = RenderSettings(ambient=0.0)
    empty = RenderScene.build(None, (), None)
    res = render_view(cam, empty, settings=settings, emitters=glow)
    sigma = 400.0 * 0.05 / 5.0  # 4 px
    assert res.image[100, 100] == pytest.approx(0.7, rel=1e-6)
    assert float(res.image.sum()) == pytest.approx(0.7 * 2 * math.pi * sigma**2, rel=0.01)
    assert res.target_px == 0
    # a wall in front of the emitter hides it; a wall behind it does not
    front = RenderScene.build(None, [(np.array([[-5, 3, -5], [5, 3, -5], [5, 3, 5], [-5, 3, 5]], float), np.array([[0, 1, 2], [0, 2, 3]]))], None)
    behind = RenderScene.build(None, [(np.array([[-5, 8, -5], [5, 8, -5], [5, 8, 5], [-5, 8, 5]], float), np.array([[0, 1, 2], [0, 2, 3]]))], None)
    assert render_view(cam, front, settings=settings, emitters=glow).image.max() == 0.0
    assert render_view(cam, behind, settings=settings, emitters=glow).image[100, 100] == pytest.approx(0.7, rel=1e-6)
    # the instance's Emitters (positions_m, weights) are accepted too
    from camplace.instance.schema import Emitters

    inst_em = Emitters(positions_m=np.array([[0.0, 5.0, 0.0]]), weights=np.array([0.35]))
    r2 = render_view(cam, empty, settings=RenderSettings(ambient=0.0, emitter_radius_m=0.05, emitter_gain=2.0), emitters=inst_em)
    np.testing.assert_allclose(r2.image, res.image, rtol=1e-6)


def test_distorted_rays_project_back_to_their_pixels() -> None:
    """Each pixel's ray, projected with OpenCV's distortion model, lands on that pixel."""
    cam = camera_at([0.0, -3.0, 0.5], [0.0, 0.0, 0.0], 250.0, 64, 48).with_dist([-0.25, 0.08, 0.0, 0.0, 0.0])
    o, dirs = cam.rays()
    pts = (o + dirs * 2.0).reshape(-1, 3)
    Rwc, t = cam.world_to_camera()
    uv, _ = cv2.projectPoints(pts, cv2.Rodrigues(Rwc)[0], t, cam.K, cam.dist)
    vv, uu = np.mgrid[0:48, 0:64]
    np.testing.assert_allclose(uv.reshape(48, 64, 2), np.stack([uu, vv], axis=-1), atol=1e-6)


def test_projection_matches_opencv() -> None:
    cam = camera_at([1.0, -3.0, 0.5], [0.0, 0.0, 0.0], 250.0, 64, 48).with_dist([-0.1, 0.02, 0.001, -0.002, 0.0])
    pts = np.random.default_rng(0).uniform(-0.5, 0.5, (50, 3))
    Rwc, t = cam.world_to_camera()
    ref, _ = cv2.projectPoints(pts, cv2.Rodrigues(Rwc)[0], t, cam.K, cam.dist)
    uv, _ = cam.project(pts)
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-9)


def test_png_round_trip_8_and_16_bit(tmp_path) -> None:
    img = np.linspace(0.0, 1.2, 64 * 48, dtype=np.float32).reshape(48, 64)
    write_png(tmp_path / "a.png", img, 8)
    write_png(tmp_path / "b.png", img, 16)
    a, b = read_image(tmp_path / "a.png"), read_image(tmp_path / "b.png")
    np.testing.assert_allclose(a, np.clip(img, 0, 1), atol=0.5 / 255 + 1e-7)
    np.testing.assert_allclose(b, np.clip(img, 0, 1), atol=0.5 / 65535 + 1e-7)
    assert cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16
