"""Observation quality, incidence and light against analytic answers."""

import dataclasses

import numpy as np
import pytest
import trimesh

from camplace.errors import CamplaceError
from camplace.instance.schema import (
    CameraModel, Emitters, Frame, Instance, Light, Mesh, Occluder, Pose, QualitySpec, Volume,
)
from camplace.sampling import CandidateSet, look_at
from camplace.visibility import compute_visibility, make_target_points


def sphere_instance(light=(1e4, 0.0, 0.0), quality=QualitySpec(), focal_length_mm=5.0, frames=None) -> Instance:
    ico = trimesh.creation.icosphere(subdivisions=6)
    mesh = Mesh("sphere", np.asarray(ico.vertices, dtype=np.float64), np.asarray(ico.faces, dtype=np.int64))
    cam = CameraModel(36.0, 36.0, focal_length_mm, 800, 800, 0.01, 1e5)
    frames = frames or (Frame(Pose()),)
    return Instance("sphere", 1, cam, Volume((-2e3,) * 3, (2e3,) * 3), Light(tuple(light)), mesh, (), frames, quality=quality)


def cameras_at(*positions, aim=(0.0, 0.0, 0.0)) -> CandidateSet:
    pos = np.array(positions, dtype=np.float64)
    aims = np.broadcast_to(np.asarray(aim, dtype=np.float64), pos.shape).copy()
    return CandidateSet(pos, aims, look_at(pos, aims))


def test_light_from_the_side_lights_half_of_what_the_camera_sees() -> None:
    """Light far along +x. A camera far along +y sees the y>0 half; the lit half is x>0: half of it."""
    far_lens = 10000.0  # fov 0.21 deg: the unit sphere at 1000 m fits in the image (half-width 1.8 m)
    dark = sphere_instance(quality=QualitySpec(require_light=False), focal_length_mm=far_lens)
    lit = dataclasses.replace(dark, quality=QualitySpec(require_light=True))
    pts = make_target_points(dark, 40000, seed=4)
    cams = cameras_at((0.0, 1000.0, 0.0), (-1000.0, 0.0, 0.0), (1000.0, 0.0, 0.0))
    seen = compute_visibility(dark, cams, pts).matrix.toarray() > 0
    seen_lit = compute_visibility(lit, cams, pts).matrix.toarray() > 0
    # camera perpendicular to the light: half of its facing points are lit
    assert seen_lit[:, 0].sum() / seen[:, 0].sum() == pytest.approx(0.5, abs=0.02 * 0.5)
    # camera opposite the light: none
    assert seen[:, 1].sum() > 0.45 * len(pts) and seen_lit[:, 1].sum() == 0
    # camera at the light: everything it sees is lit
    assert seen_lit[:, 2].sum() / seen[:, 2].sum() > 0.99


def test_shadow_of_an_occluder() -> None:
    """A plate between the light and the sphere puts the sphere's light-facing side in shadow."""
    plate = trimesh.creation.box(extents=(0.01, 5.0, 5.0))
    occ = Occluder(Mesh("plate", np.asarray(plate.vertices), np.asarray(plate.faces, dtype=np.int64)), Pose((3.0, 0.0, 0.0)))
    inst = dataclasses.replace(
        sphere_instance(light=(10.0, 0.0, 0.0), quality=QualitySpec(require_light=True)), occluders=(occ,)
    )
    pts = make_target_points(inst, 5000, seed=1)
    cams = cameras_at((0.0, 5.0, 0.0))
    assert compute_visibility(inst, cams, pts).matrix.nnz == 0
    no_plate = dataclasses.replace(inst, occluders=())
    assert compute_visibility(no_plate, cams, pts).matrix.nnz > 0.1 * len(pts)


def test_resolution_quality_halves_when_distance_doubles() -> None:
    q = QualitySpec(mode="graded", required_px_per_m=1e6)  # never saturates
    inst = sphere_instance(quality=q, focal_length_mm=30.0)
    pts = make_target_points(inst, 20000, seed=2)
    d = 5.0
    cams = cameras_at((d, 0, 0), (2 * d, 0, 0))
    A = compute_visibility(inst, cams, pts, layout="csr").matrix.toarray()  # the float32 values
    fx = inst.camera.fx_px
    both = (A[:, 0] > 0) & (A[:, 1] > 0)
    assert both.sum() > 1000
    # oracle: quality = f_px / (distance * required) * cos(theta), computed independently
    for j, c in enumerate(cams.positions):
        view = c - pts.positions
        dist = np.linalg.norm(view, axis=1)
        cos_t = np.einsum("ij,ij->i", view, pts.normals) / dist
        expected = fx / (dist * q.required_px_per_m) * cos_t
        seen = A[:, j] > 0
        assert np.allclose(A[seen, j], expected[seen], rtol=1e-5)
    # two cameras on one ray through a point: same incidence, distance doubled -> quality halved
    p_idx = int(np.argmax(pts.normals[:, 0]))
    p, n = pts.positions[p_idx], pts.normals[p_idx]
    B = compute_visibility(inst, cameras_at(tuple(p + 4.0 * n), tuple(p + 8.0 * n)), pts, layout="csr").matrix.toarray()
    assert B[p_idx, 0] > 0 and B[p_idx, 1] / B[p_idx, 0] == pytest.approx(0.5, rel=1e-5)


def test_graded_quality_saturates_at_one() -> None:
    inst = sphere_instance(quality=QualitySpec(mode="graded", required_px_per_m=1.0))
    pts = make_target_points(inst, 5000, seed=2)
    A = compute_visibility(inst, cameras_at((3.0, 0, 0)), pts).matrix
    assert A.data.max() <= 1.0 and A.data.min() > 0


def test_max_incidence() -> None:
    inst = sphere_instance(quality=QualitySpec(max_incidence_deg=45.0))
    pts = make_target_points(inst, 20000, seed=3)
    c = np.array([50.0, 0, 0])
    A = compute_visibility(inst, cameras_at(tuple(c)), pts, chunk_size=1).matrix.toarray()[:, 0] > 0
    view = c - pts.positions
    ang = np.degrees(np.arccos(np.einsum("ij,ij->i", view, pts.normals) / np.linalg.norm(view, axis=1)))
    assert not np.any(A & (ang > 45.0 + 1e-6))
    assert np.all(A[ang < 44.0])  # convex, unoccluded: everything within the angle is seen
    # smooth-sphere answer: the polar angle phi where the incidence reaches 45 deg (theta = phi + parallax)
    phi = np.linspace(0, np.pi / 2, 200001)
    theta = np.arccos((50.0 * np.cos(phi) - 1) / np.sqrt(50.0**2 - 100.0 * np.cos(phi) + 1))
    phi_max = phi[np.argmax(theta > np.radians(45.0))]
    assert A.mean() == pytest.approx(0.5 * (1 - np.cos(phi_max)), abs=0.005)


def test_emitters_need_no_normal_but_are_occluded() -> None:
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    occ = Occluder(Mesh("box", np.asarray(box.vertices), np.asarray(box.faces, dtype=np.int64)), Pose((0.0, 3.0, 0.0)))
    em = Emitters(positions_m=np.array([[0.8, 2.0, 0.0], [0.0, 3.0, 0.0], [0.0, -2.0, 0.0]]), weights=np.array([1.0, 2.0, 1.0]))
    frames = (Frame(Pose(), weight=1.0, target_weight=4.0, emitters=em),)
    inst = dataclasses.replace(sphere_instance(quality=QualitySpec(require_light=True)), frames=frames, occluders=(occ,))
    pts = make_target_points(inst, 1000, seed=0)
    assert len(pts) == 1003 and pts.is_emitter.sum() == 3
    assert pts.weight.sum() == pytest.approx(1.0)
    assert pts.weight[pts.is_emitter] == pytest.approx([1 / 8, 2 / 8, 1 / 8])
    A = compute_visibility(inst, cameras_at((0.0, 5.0, 0.0), (0.0, -5.0, 0.0)), pts).matrix.toarray() > 0
    em_rows = np.nonzero(pts.is_emitter)[0]
    # camera at +y: the emitter at (0.8, 2, 0) is seen (even in the dark: it glows), the one inside the box is hidden,
    # the one behind the sphere is hidden
    assert list(A[em_rows, 0]) == [True, False, False]
    assert list(A[em_rows, 1]) == [False, False, True]


def test_frame_occluders_act_only_in_their_frame() -> None:
    wall = trimesh.creation.box(extents=(0.05, 4.0, 4.0))
    occ = Occluder(Mesh("wall", np.asarray(wall.vertices), np.asarray(wall.faces, dtype=np.int64)), Pose((2.0, 0.0, 0.0)))
    frames = (Frame(Pose()), Frame(Pose(), occluders=(occ,)))
    inst = sphere_instance(frames=frames)
    pts = make_target_points(inst, 4000, seed=0)
    A = compute_visibility(inst, cameras_at((5.0, 0.0, 0.0)), pts).matrix.toarray()[:, 0] > 0
    assert A[pts.frame == 0].mean() > 0.35 and A[pts.frame == 1].sum() == 0


def test_memory_budget_stops_early() -> None:
    inst = sphere_instance()
    pts = make_target_points(inst, 2000, seed=0)
    cams = cameras_at(*[(3.0, 0.0, float(z)) for z in np.linspace(-1, 1, 50)])
    with pytest.raises(CamplaceError, match="memory budget"):
        compute_visibility(inst, cams, pts, memory_budget_bytes=10_000, chunk_size=8)
