"""camplace.geometry against oracles: the axes of a look-at, elementary rotations, scipy, trimesh."""

import math

import numpy as np
import pytest
import trimesh

from camplace import geometry as g
from camplace.errors import CamplaceError


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_look_at_maps_the_view_direction_to_plus_z_orthonormal_det_one() -> None:
    rng = np.random.default_rng(7)
    pos = rng.uniform(-5, 5, (300, 3))
    aim = rng.uniform(-1, 1, (300, 3))
    pos[:2] = [[0, 0, 5.0], [1, 2, -4.0]]  # straight down and straight up: the +y fallback
    aim[:2] = [[0, 0, 0.0], [1, 2, 0.0]]
    R = g.look_at(pos, aim)
    assert R.shape == (300, 3, 3)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, rtol=1e-12)
    view = (aim - pos) / np.linalg.norm(aim - pos, axis=1, keepdims=True)
    # world-from-camera: R^T maps the world view direction to camera +z
    np.testing.assert_allclose(np.einsum("nk,nkl->nl", view, R), np.tile([0.0, 0.0, 1.0], (300, 1)), atol=1e-12)
    # image "up" (-y) is the projection of world +z, except where the camera looks along it
    up_cam = np.einsum("k,nkl->nl", np.array([0, 0, 1.0]), R)
    assert np.all(up_cam[2:, 1] < 0)
    np.testing.assert_allclose(R[0][:, 0] @ np.array([0, 1.0, 0]), 0.0, atol=1e-12)  # x right is perpendicular to +y


def test_look_at_rejects_a_camera_on_its_aim() -> None:
    with pytest.raises(CamplaceError, match="coincides"):
        g.look_at(np.ones((1, 3)), np.ones((1, 3)))


def test_euler_is_extrinsic_xyz_and_round_trips() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        a = rng.uniform([-180, -89, -180], [180, 89, 180])
        R = g.rotation_from_euler_deg(a)
        ax, ay, az = np.radians(a)
        np.testing.assert_allclose(R, _rz(az) @ _ry(ay) @ _rx(ax), atol=1e-14)
        np.testing.assert_allclose(g.euler_xyz_deg(R), a, atol=1e-9)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_euler_at_gimbal_lock_sets_x_to_zero_and_keeps_the_rotation(sign: float) -> None:
    a = np.array([25.0, 90.0 * sign, -40.0])
    R = g.rotation_from_euler_deg(a)
    e = g.euler_xyz_deg(R)
    assert e[0] == 0.0
    assert e[1] == pytest.approx(90.0 * sign)
    np.testing.assert_allclose(g.rotation_from_euler_deg(e), R, atol=1e-12)


def test_rotation_vector_is_rodrigues() -> None:
    rng = np.random.default_rng(5)
    for _ in range(50):
        w = rng.normal(size=3)
        theta = np.linalg.norm(w)
        k = w / theta
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        np.testing.assert_allclose(g.rotation_from_vector(w), np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * K @ K, atol=1e-14)
    np.testing.assert_array_equal(g.rotation_from_vector(np.zeros(3)), np.eye(3))


def test_quaternions_hamilton_wxyz_round_trip() -> None:
    # 90 degrees about z: (cos 45, 0, 0, sin 45)
    np.testing.assert_allclose(g.quaternion_to_rotation([math.sqrt(0.5), 0, 0, math.sqrt(0.5)]), _rz(math.pi / 2), atol=1e-15)
    np.testing.assert_allclose(g.quaternion_to_rotation([2.0, 0, 0, 0]), np.eye(3))  # normalised
    rng = np.random.default_rng(11)
    for _ in range(100):
        R = g.rotation_from_euler_deg(rng.uniform(-180, 180, 3))
        q = g.rotation_to_quaternion(R)
        assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(g.quaternion_to_rotation(q), R, atol=1e-14)
    with pytest.raises(CamplaceError, match="not a rotation"):
        g.quaternion_to_rotation([0, 0, 0, 0])


def test_box_mesh_is_a_closed_outward_box() -> None:
    lo, hi = np.array([-1.0, 0.5, 2.0]), np.array([3.0, 1.5, 2.25])
    v, f = g.box_mesh(lo, hi)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume == pytest.approx(np.prod(hi - lo))  # positive: outward normals
    np.testing.assert_array_equal(m.bounds, [lo, hi])
    assert sorted(map(tuple, v)) == sorted((x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2]))


def test_ply_bytes_reads_back_exactly_with_trimesh(tmp_path) -> None:
    rng = np.random.default_rng(2)
    v = rng.normal(size=(7, 3))
    f = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]])
    data = g.ply_bytes(v, f, "two\nlines")
    assert b"comment two lines\n" in data and b"property double x" in data
    m = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="ply", process=False)
    np.testing.assert_array_equal(m.vertices, v)
    np.testing.assert_array_equal(m.faces, f)
    with pytest.raises(ValueError, match="out of range"):
        g.ply_bytes(v, [[0, 1, 7]])


def test_triangle_soup_ply_is_float32_and_exact() -> None:
    tri = np.random.default_rng(4).normal(size=(5, 3, 3)).astype(np.float32)
    data = g.triangle_soup_ply_bytes(tri, "scene")
    assert b"property float x" in data
    m = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="ply", process=False)
    np.testing.assert_array_equal(m.vertices.astype(np.float32).reshape(-1, 3, 3), tri)
    np.testing.assert_array_equal(m.faces, np.arange(15).reshape(5, 3))
