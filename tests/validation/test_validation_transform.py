"""Simulation -> lab transforms: Umeyama against known similarities, the per-axis formula, rotations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camplace.errors import CamplaceError
from camplace.instance.schema import rotation_from_euler_deg
from camplace.sampling import look_at
from camplace.validation.transform import (
    build_transform,
    euler_xyz_deg,
    parse_transform,
    placement_rows,
    umeyama,
)


def test_umeyama_exact_without_noise() -> None:
    rng = np.random.default_rng(0)
    R = Rotation.random(random_state=1).as_matrix()
    s, t = 0.37, np.array([1.0, -2.0, 0.5])
    src = rng.uniform(-5, 5, (6, 3))
    dst = s * src @ R.T + t
    s2, R2, t2 = umeyama(src, dst)
    assert s2 == pytest.approx(s, rel=1e-12)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_umeyama_recovers_known_similarity_from_noisy_pairs(seed: int) -> None:
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed + 10).as_matrix()
    s, t = rng.uniform(0.2, 3.0), rng.uniform(-10, 10, 3)
    n, sigma = 40, 0.01
    src = rng.uniform(-5, 5, (n, 3))
    dst = s * src @ R.T + t + rng.normal(0, sigma, (n, 3))
    s2, R2, t2 = umeyama(src, dst)
    # least-squares errors scale as sigma / (spread sqrt(n)); spread ~ 2.9 m, so 5-sigma bounds:
    spread = float(np.sqrt(((src - src.mean(0)) ** 2).sum(1).mean()))
    assert abs(s2 - s) < 5 * sigma / (spread * np.sqrt(n))
    angle = np.degrees(Rotation.from_matrix(R2 @ R.T).magnitude())
    assert angle < np.degrees(5 * sigma / (s * spread * np.sqrt(n)))
    # the fitted map predicts held-out points to within the noise level
    test = rng.uniform(-5, 5, (10, 3))
    np.testing.assert_allclose(s2 * test @ R2.T + t2, s * test @ R.T + t, atol=5 * sigma)
    # and the config route gives the same transform with an RMS residual near sigma * sqrt(3)
    cfg = parse_transform({"method": "similarity", "pairs": [{"sim_m": a.tolist(), "phys_m": b.tolist()} for a, b in zip(src, dst)]})
    tr = build_transform(cfg)
    assert tr.scale == pytest.approx(s2) and tr.rms_residual_m == pytest.approx(sigma * np.sqrt(3), rel=0.3)


def test_umeyama_rigid_and_reflection_guard() -> None:
    src = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    mirrored = src * [1, 1, -1]
    s, R, _ = umeyama(src, mirrored, with_scale=False)
    assert s == 1.0 and np.linalg.det(R) == pytest.approx(1.0)


def test_scale_method_is_the_thesis_formula_with_phys_over_sim() -> None:
    cfg = parse_transform(
        {"method": "scale", "sim_extent_m": [30, 3, 3], "phys_extent_m": [15, 6, 3], "sim_scale": [1, 1, 2],
         "reference_m": [10, 20, 0], "sim_reference_m": [0, 0, 0]}
    )
    tr = build_transform(cfg)
    X = np.array([[4.0, 1.0, 0.5], [0.0, 0.0, 0.0]])
    S = np.array([15 / 30 * 1, 6 / 3 * 1, 3 / 3 * 2])
    np.testing.assert_allclose(tr.apply_points(X), np.array([10, 20, 0]) + X * S)
    # with a reference point that is not the simulation origin
    tr2 = build_transform(parse_transform({"method": "scale", "sim_extent_m": 2 * [1.0] + [1.0], "phys_extent_m": [2, 2, 2],
                                           "reference_m": [1, 1, 1], "sim_reference_m": [5, 5, 5]}))
    np.testing.assert_allclose(tr2.apply_points([[5, 5, 5], [6, 5, 5]]), [[1, 1, 1], [3, 1, 1]])


def test_rotations_keep_cameras_aimed_at_the_mapped_aim_point() -> None:
    tr = build_transform(parse_transform({"method": "scale", "sim_extent_m": [10, 10, 10], "phys_extent_m": [5, 2, 8]}))
    rng = np.random.default_rng(3)
    pos, aims = rng.uniform(-5, 5, (20, 3)), rng.uniform(-1, 1, (20, 3))
    R = look_at(pos, aims)
    R2 = tr.apply_rotations(R)
    p2, a2 = tr.apply_points(pos), tr.apply_points(aims)
    fwd = (a2 - p2) / np.linalg.norm(a2 - p2, axis=1, keepdims=True)
    np.testing.assert_allclose(R2[:, :, 2], fwd, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R2, R2), np.broadcast_to(np.eye(3), R2.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R2), 1.0)
    # a similarity maps rotations by left multiplication
    Rs = Rotation.random(random_state=4).as_matrix()
    pairs = [{"sim_m": p.tolist(), "phys_m": (2.0 * Rs @ p + 1.0).tolist()} for p in rng.uniform(-3, 3, (5, 3))]
    sim = build_transform(parse_transform({"method": "similarity", "pairs": pairs}))
    np.testing.assert_allclose(sim.apply_rotations(R), Rs @ R, atol=1e-9)


def test_euler_round_trip_and_placement_rows() -> None:
    for ang in ([10.0, -20.0, 30.0], [0.0, 0.0, 0.0], [170.0, 45.0, -100.0]):
        np.testing.assert_allclose(rotation_from_euler_deg(euler_xyz_deg(rotation_from_euler_deg(ang))), rotation_from_euler_deg(ang), atol=1e-12)
    pos = np.array([[1.0, 0.0, 0.0]])
    R = look_at(pos, np.zeros((1, 3)))
    rows = placement_rows([{"name": "c", "position": pos[0], "rotation": R[0], "aim": [0, 0, 0]}], build_transform(parse_transform(None)))
    assert rows[0]["azimuth_deg"] == pytest.approx(180.0) and rows[0]["elevation_deg"] == pytest.approx(0.0)
    np.testing.assert_allclose(rotation_from_euler_deg(rows[0]["euler_xyz_deg"]), R[0], atol=1e-12)


def test_transform_config_errors() -> None:
    with pytest.raises(CamplaceError, match=r"\[transform\]\.method"):
        parse_transform({"method": "affine"})
    with pytest.raises(CamplaceError, match="phys_extent_m: required"):
        parse_transform({"method": "scale", "sim_extent_m": [1, 1, 1]})
    with pytest.raises(CamplaceError, match=r"sim_extent_m\[1\]: must be > 0"):
        parse_transform({"method": "scale", "sim_extent_m": [1, -1, 1], "phys_extent_m": [1, 1, 1]})
    with pytest.raises(CamplaceError, match="at least 3 pairs"):
        parse_transform({"method": "similarity", "pairs": [{"sim_m": [0, 0, 0], "phys_m": [0, 0, 0]}]})
    with pytest.raises(CamplaceError, match="collinear"):
        parse_transform({"method": "similarity", "pairs": [{"sim_m": [i, i, i], "phys_m": [0, 0, i]} for i in range(4)]})
    with pytest.raises(CamplaceError, match="unknown key"):
        parse_transform({"method": "scale", "scale": 2})
