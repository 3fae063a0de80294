"""Procedural meshes: topology, orientation, determinism, size."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from camplace.instance import procedural


def _tm(vf):
    v, f = vf
    assert v.dtype == np.float64 and f.dtype == np.int64
    assert v.ndim == 2 and v.shape[1] == 3 and f.ndim == 2 and f.shape[1] == 3
    assert np.all(np.isfinite(v))
    assert f.min() >= 0 and f.max() < len(v)
    return trimesh.Trimesh(v, f, process=False)


@pytest.mark.parametrize("s", range(5))
def test_icosphere_counts_and_unit(s):
    v, f = procedural.icosphere(s)
    assert len(f) == 20 * 4**s and len(v) == 10 * 4**s + 2
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-12)
    m = _tm((v, f))
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0


def test_sphere_outward_radius():
    m = _tm(procedural.sphere(0.7, 3))
    assert m.is_watertight and m.is_winding_consistent
    np.testing.assert_allclose(np.linalg.norm(m.vertices, axis=1), 0.7)
    assert 0.95 * (4 / 3 * np.pi * 0.7**3) < m.volume < 4 / 3 * np.pi * 0.7**3


def test_box_centred_outward():
    m = _tm(procedural.box([1.0, 2.0, 3.0]))
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume == pytest.approx(6.0)
    np.testing.assert_allclose(m.bounds, [[-0.5, -1.0, -1.5], [0.5, 1.0, 1.5]])
    # every face normal points away from the centre
    assert np.all(np.einsum("ij,ij->i", m.face_normals, m.triangles_center) > 0)


def test_corridor_inward():
    size = np.array([30.0, 3.0, 3.0])
    m = _tm(procedural.corridor(size))
    assert m.is_watertight and m.is_winding_consistent
    np.testing.assert_allclose(m.bounds, [[0, 0, 0], size])
    assert m.volume == pytest.approx(-270.0)  # signed volume < 0: inward normals
    centre = size / 2
    assert np.all(np.einsum("ij,ij->i", m.face_normals, centre - m.triangles_center) > 0)
    # ray test: from a point inside, each ray's first hit is a face seen from its front (normal against the ray)
    origin = np.array([12.0, 1.0, 2.0])
    dirs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [0.6, 0.48, 0.64]])
    for d in dirs:
        face = _first_hit(m.triangles, origin, d)
        assert face >= 0
        assert np.dot(m.face_normals[face], d) < 0


def _first_hit(triangles: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> int:
    """Index of the first triangle hit by the ray (Moller-Trumbore), -1 if none."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = b - a, c - a
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    if not hit.any():
        return -1
    return int(np.argmin(np.where(hit, t, np.inf)))


def test_comet_watertight_outward_and_sized():
    v, f = procedural.bilobed_comet(length_m=0.6, seed=7)
    m = _tm((v, f))
    assert len(f) == 20 * 4**5
    assert m.is_watertight and m.is_winding_consistent and m.is_volume
    assert m.volume > 0
    ext = v.max(axis=0) - v.min(axis=0)
    assert ext.max() == pytest.approx(0.6, abs=1e-12)
    np.testing.assert_allclose((v.max(axis=0) + v.min(axis=0)) / 2, 0.0, atol=1e-12)
    assert np.argmax(ext) == 0  # lobes along x
    assert ext[1] < 0.8 * ext[0] and ext[2] < ext[1]  # elongated, flattened like 67P
    # bilobed: a neck, i.e. the cross-section near the middle is thinner than through the lobes
    assert m.volume < 0.9 * m.convex_hull.volume


def test_comet_deterministic_and_seeded():
    a = procedural.bilobed_comet(seed=3)
    b = procedural.bilobed_comet(seed=3)
    c = procedural.bilobed_comet(seed=4)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_array_equal(a[1], c[1])  # same topology
    assert np.abs(a[0] - c[0]).max() > 1e-3


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32),
    noise=st.floats(0.0, 0.3),
    length=st.floats(1e-3, 1e3),
    subdivisions=st.integers(2, 4),
)
def test_comet_property(seed, noise, length, subdivisions):
    v, f = procedural.bilobed_comet(length_m=length, seed=seed, subdivisions=subdivisions, noise=noise)
    m = _tm((v, f))
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    assert (v.max(axis=0) - v.min(axis=0)).max() == pytest.approx(length, rel=1e-12)


@pytest.mark.parametrize(
    "call",
    [
        lambda: procedural.sphere(0.0),
        lambda: procedural.sphere(1.0, 8),
        lambda: procedural.sphere(1.0, True),
        lambda: procedural.box([1, 0, 1]),
        lambda: procedural.box([1, 1]),
        lambda: procedural.corridor([1, 1, float("nan")]),
        lambda: procedural.bilobed_comet(length_m=-1),
        lambda: procedural.bilobed_comet(seed=-1),
        lambda: procedural.bilobed_comet(subdivisions=1),
        lambda: procedural.bilobed_comet(noise=0.31),
    ],
)
def test_bad_arguments_raise_valueerror(call):
    with pytest.raises(ValueError):
        call()
