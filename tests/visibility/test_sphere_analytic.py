"""Analytic oracle: a unit sphere seen from distance d shows a cap of (1 - 1/d) / 2 of its surface."""

import numpy as np
import pytest
import trimesh

from camplace.instance.schema import CameraModel, Frame, Instance, Light, Mesh, Pose, Volume
from camplace.sampling import CandidateSet, look_at
from camplace.visibility import compute_visibility, make_target_points


def sphere_instance(focal_length_mm: float = 5.0) -> Instance:
    ico = trimesh.creation.icosphere(subdivisions=6)
    mesh = Mesh("sphere", np.asarray(ico.vertices, dtype=np.float64), np.asarray(ico.faces, dtype=np.int64))
    cam = CameraModel(36.0, 36.0, focal_length_mm, 800, 800, 0.01, 1000.0)
    return Instance("sphere", 1, cam, Volume((-20, -20, -20), (20, 20, 20)), Light((0, 0, 30)), mesh, (), (Frame(Pose()),))


@pytest.mark.parametrize("d", [1.5, 2.0, 4.0, 10.0])
def test_cap_fraction(d: float) -> None:
    inst = sphere_instance()
    pts = make_target_points(inst, 60000, seed=1)
    rng = np.random.default_rng(int(d * 10))
    dirs = rng.normal(size=(3, 3))
    pos = d * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    cands = CandidateSet(pos, np.zeros_like(pos), look_at(pos, np.zeros_like(pos)))
    vm = compute_visibility(inst, cands, pts)
    expected = (1 - 1 / d) / 2
    for j in range(3):
        frac = vm.matrix[:, j].nnz / len(pts)
        assert frac == pytest.approx(expected, rel=0.02), (d, j, frac, expected)


def test_narrow_lens_sees_less() -> None:
    """With a lens whose half field of view is below the sphere's angular radius, the cap is clipped."""
    inst = sphere_instance(focal_length_mm=200.0)  # fov ~ 10 deg, sphere at d=2 spans 60 deg
    pts = make_target_points(inst, 20000, seed=2)
    pos = np.array([[2.0, 0.0, 0.0]])
    cands = CandidateSet(pos, np.zeros_like(pos), look_at(pos, np.zeros_like(pos)))
    frac = compute_visibility(inst, cands, pts).matrix.nnz / len(pts)
    assert frac < 0.25 * 0.5
