"""The Embree visibility matrix agrees with the independent pure-numpy oracle on random pairs."""

import numpy as np
import trimesh

from camplace.instance.schema import CameraModel, Frame, Instance, Light, Mesh, Occluder, Pose, Volume
from camplace.sampling import make_candidates
from camplace.visibility import compute_visibility, frame_scene, make_target_points
from camplace.visibility.engine import EPS_REL

from .oracle import observed


def occluded_scene() -> Instance:
    """A lumpy target, a wall that hides part of it, and a box room around everything."""
    ico = trimesh.creation.icosphere(subdivisions=3)
    v = np.asarray(ico.vertices) * np.array([0.5, 0.3, 0.25])
    target = Mesh("blob", v, np.asarray(ico.faces, dtype=np.int64))
    wall = trimesh.creation.box(extents=(0.05, 1.0, 0.6))
    room = trimesh.creation.box(extents=(8.0, 6.0, 4.0))
    room.invert()
    occ = (
        Occluder(Mesh("wall", np.asarray(wall.vertices), np.asarray(wall.faces, dtype=np.int64)), Pose((1.0, 0.3, 0.0))),
        Occluder(Mesh("room", np.asarray(room.vertices), np.asarray(room.faces, dtype=np.int64)), Pose((0.0, 0.0, 0.0))),
    )
    cam = CameraModel(7.18, 5.32, 8.0, 640, 480, 0.2, 3.5)
    frames = (Frame(Pose((0.0, 0.0, 0.0), (0.0, 0.0, 20.0))), Frame(Pose((0.3, -0.2, 0.1), (10.0, 0.0, 60.0))))
    return Instance("oracle", 3, cam, Volume((-3.8, -2.8, -1.8), (3.8, 2.8, 1.8)), Light((0, 0, 1.9)), target, occ, frames)


def test_agrees_with_numpy_oracle() -> None:
    inst = occluded_scene()
    pts = make_target_points(inst, 4000, seed=3)
    # aim at jittered points so some targets fall outside the frustum
    cands = make_candidates("uniform", 60, inst.volume.min_m, inst.volume.max_m, np.zeros(3), seed=4)
    vm = compute_visibility(inst, cands, pts, chunk_size=7)
    dense = vm.matrix.toarray() > 0
    rng = np.random.default_rng(5)
    rows = rng.integers(0, len(pts), 6000)
    cols = rng.integers(0, len(cands), 6000)
    K = inst.camera.K()
    # each frame's triangles and ray offset, once (the same arrays for every pair of the frame)
    frames = range(len(inst.frames))
    tris = {f: frame_scene(inst, f).triangles.astype(np.float64) for f in frames}
    eps = {f: EPS_REL * float(np.linalg.norm(np.ptp(inst.target_world(f)[0], axis=0))) for f in frames}
    agree = 0
    n_obs = 0
    for r, c in zip(rows, cols, strict=True):
        f = int(pts.frame[r])
        want = observed(
            pts.positions[r], pts.normals[r], cands.positions[c], cands.rotations[c], K,
            inst.camera.width_px, inst.camera.height_px, inst.camera.near_m, inst.camera.far_m, tris[f], eps[f],
        )
        agree += want == dense[r, c]
        n_obs += want
    assert agree / len(rows) >= 0.999, agree / len(rows)
    # the test is only meaningful when both outcomes occur often
    assert 0.05 < n_obs / len(rows) < 0.95
    # every culling stage removes something in this scene
    s = vm.stats
    assert s["pairs"] > s["in_range"] > s["in_frustum"] > s["facing"] > s["observed"] > 0
