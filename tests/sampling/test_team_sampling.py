"""Where a team's cameras may stand (issue 31): the samplers honour volumes, keep-outs and mount surfaces.

Oracles: every sampled position lies inside a region allowed for its column's model and outside
every keep-out (box: coordinates; mesh: the distance to a sphere's centre); a mount sample lies
``offset_m`` off a triangle of the mount along its normal, inside the triangle; every allowed
(position, model) pair is a column and no other; zone membership is the box test.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from camplace.instance import builtin_toml, parse_instance
from camplace.instance.procedural import icosphere
from camplace.instance.schema import KeepOut, Mesh, Pose
from camplace.visibility.stages import make_run_candidates, sample_on_mesh, split_count, stage_seeds, team_positions

SAMPLERS = ("chaotic", "uniform", "sobol")


def _team(tmp_path, **changes):
    data = copy.deepcopy(builtin_toml("comet-67p-team"))
    data["target"]["subdivisions"] = 2
    # a spherical (mesh) keep-out around a pillar inside the wide volume, besides the box of the built-in
    data["keepouts"].append({"name": "pillar", "shape": "sphere", "radius_m": 0.6, "subdivisions": 3,
                             "position_m": [5.0, 1.5, 1.5]})
    data.update(changes)
    return parse_instance(data, "team.toml", tmp_path)


def _on_triangle(p: np.ndarray, tri: np.ndarray, offset: float, tol: float = 1e-9) -> np.ndarray:
    """(n_tri,) bool: p lies ``offset`` off triangle t along its unit normal, over the triangle."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1)[:, None]
    q = p - offset * n  # the foot on the triangle's plane
    plane = np.abs(np.einsum("ij,ij->i", q - a, n)) < tol
    # barycentric coordinates of q
    v0, v1, v2 = b - a, c - a, q - a
    d00, d01, d11 = (np.einsum("ij,ij->i", x, y) for x, y in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("ij,ij->i", v2, v0), np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return plane & (v >= -tol) & (w >= -tol) & (v + w <= 1 + tol)


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_positions_honour_regions_keepouts_and_mounts(tmp_path, sampler) -> None:
    inst = _team(tmp_path)
    team = inst.team
    pos, mount = team_positions(inst, sampler, 300, stage_seeds(3)[0])
    assert pos.shape == (300, 3) and mount.shape == (300,)
    # keep-outs: the box, and the sphere (distance to its centre; the icosphere lies inside radius 0.6)
    box = team.keepouts[0].box
    assert not np.any(np.all((pos > box.min_m) & (pos < box.max_m), axis=1))
    pillar_v = team.keepouts[1].mesh.transformed(team.keepouts[1].pose)[0]
    inner = np.min(np.linalg.norm(pillar_v - [5.0, 1.5, 1.5], axis=1)) * np.cos(np.radians(12))  # inside the faces
    assert np.all(np.linalg.norm(pos - [5.0, 1.5, 1.5], axis=1) > inner - 1e-9)
    # every volume sample inside its volume, every mount sample on the mast (offset along a face normal)
    counts = split_count(300, [1.0, 1.0, 1.0])
    starts = np.concatenate([[0], np.cumsum(counts)])
    for r, v in enumerate(team.volumes):
        part = pos[starts[r]:starts[r + 1]]
        assert np.all(mount[starts[r]:starts[r + 1]] == -1)
        assert np.all((part > v.min_m) & (part < v.max_m))
    on = pos[mount == 0]
    assert len(on) == counts[2]
    vtx, faces = team.mounts[0].world()
    tri = vtx[faces]
    assert all(_on_triangle(p, tri, 0.05).any() for p in on)
    # the mast's samples spread over its faces (not all on one)
    which = np.array([int(np.flatnonzero(_on_triangle(p, tri, 0.05))[0]) // 2 for p in on])
    assert len(np.unique(which)) >= 4


def test_a_point_off_the_mast_is_not_on_it() -> None:
    # the oracle itself can fail: a point 1 cm further out is not `offset` off any triangle
    v, f = icosphere(1)
    p = sample_on_mesh("uniform", 20, v, f, 0.05, seed=1)
    tri = v[f]
    assert all(_on_triangle(x, tri, 0.05).any() for x in p)
    assert not any(_on_triangle(x * 1.01, tri, 0.05).any() for x in p)


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_columns_are_exactly_the_allowed_pose_model_pairs(tmp_path, sampler) -> None:
    inst = _team(tmp_path)
    team = inst.team
    seed = stage_seeds(0)[0]
    pos, mount = team_positions(inst, sampler, 120, seed)
    from camplace.event import event_aims

    # two frames, so that two orientations give two aims per position
    inst = dataclasses.replace(inst, frames=(*inst.frames, dataclasses.replace(inst.frames[0], target_pose=Pose((16.0, 1.5, 1.5)))))
    cands = make_run_candidates(inst, sampler, 120, 2, seed)
    a = len(event_aims(inst, 2))
    assert a == 2
    model = np.asarray(cands.model)
    assert np.all(np.diff(model) >= 0)  # model-major columns
    # oracle of "may stand there": inside one of the model's volumes, or sampled on one of its mounts
    allowed = np.zeros((len(pos), 2), dtype=bool)
    for j, name in enumerate(("wide", "science")):
        for v in team.volumes:
            if not v.models or name in v.models:
                allowed[:, j] |= np.all((pos > v.min_m) & (pos < v.max_m), axis=1)
        for r, mt in enumerate(team.mounts):
            if not mt.models or name in mt.models:
                allowed[:, j] |= mount == r
    want = [(tuple(pos[i]), j) for j in range(2) for i in np.flatnonzero(allowed[:, j]) for _ in range(a)]
    got = [(tuple(cands.positions[c]), int(model[c])) for c in range(len(cands))]
    assert got == want
    assert allowed[:, 1].sum() > counts_science_only(pos, mount, team)  # some wide-volume positions lie in science's volume too
    # zones: the box test, per column
    for z, zone in enumerate(team.zones):
        np.testing.assert_array_equal(cands.zones[:, z], np.all((cands.positions > zone.min_m) & (cands.positions < zone.max_m), axis=1))
    # every column looks at the event (OpenCV z axis towards the aim)
    fwd = cands.rotations[:, :, 2]
    to_aim = cands.aims - cands.positions
    np.testing.assert_allclose(np.einsum("ij,ij->i", fwd, to_aim / np.linalg.norm(to_aim, axis=1)[:, None]), 1.0, atol=1e-9)


def counts_science_only(pos, mount, team) -> int:
    """Positions sampled in science's own regions (its volume and the mast)."""
    v = team.volumes[1]
    return int(np.sum((mount == 0) | np.all((pos > v.min_m) & (pos < v.max_m), axis=1) & (mount == -1)
                      & ~np.all((pos > team.volumes[0].min_m) & (pos < team.volumes[0].max_m), axis=1)))


def test_share_splits_the_count() -> None:
    np.testing.assert_array_equal(split_count(10, [1, 1, 1]), [4, 3, 3])
    np.testing.assert_array_equal(split_count(10, [1, 3]), [3, 7])
    np.testing.assert_array_equal(split_count(7, [2.5, 1, 0.5]), [4, 2, 1])
    assert split_count(1000, [0.3, 2, 7]).sum() == 1000


def test_shares_set_how_many_positions_each_region_draws(tmp_path) -> None:
    data = copy.deepcopy(builtin_toml("comet-67p-team"))
    data["target"]["subdivisions"] = 2
    data["volumes"][1]["share"] = 3.0
    inst = parse_instance(data, "team.toml", tmp_path)
    pos, mount = team_positions(inst, "uniform", 100, 5)
    science = inst.team.volumes[1]
    in_science_only = np.all((pos > science.min_m) & (pos < science.max_m), axis=1)
    assert in_science_only[20:80].all()  # 20 in the wide volume, then 60 in science's, then 20 on the mast
    assert np.all(mount[80:] == 0) and np.all(mount[:80] == -1)


def test_sampling_is_reproducible_and_seeded(tmp_path) -> None:
    inst = _team(tmp_path)
    a = make_run_candidates(inst, "chaotic", 80, 1, stage_seeds(7)[0])
    b = make_run_candidates(inst, "chaotic", 80, 1, stage_seeds(7)[0])
    c = make_run_candidates(inst, "chaotic", 80, 1, stage_seeds(8)[0])
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.model, b.model)
    assert not np.array_equal(a.positions[:10], c.positions[:10])


def test_mesh_keepout_contains_matches_a_sphere() -> None:
    v, f = icosphere(4)
    ko = KeepOut(mesh=Mesh("ball", v * 2.0, f), pose=Pose((1.0, 2.0, 3.0)))
    rng = np.random.default_rng(0)
    p = rng.uniform(-2.5, 2.5, (2000, 3)) + [1.0, 2.0, 3.0]
    r = np.linalg.norm(p - [1.0, 2.0, 3.0], axis=1)
    sure = (r < 1.97) | (r > 2.0)  # away from the faceted surface
    inside = ko.contains(p)
    np.testing.assert_array_equal(inside[sure], r[sure] < 1.97)
    assert 0.1 < inside.mean() < 0.9


def test_a_model_that_can_stand_nowhere_is_one_line(tmp_path) -> None:
    from camplace.errors import CamplaceError

    data = copy.deepcopy(builtin_toml("comet-67p-team"))
    data["target"]["subdivisions"] = 2
    data["mounts"] = []
    data["keepouts"].append({"min_m": [13.9, 0.0, 0.0], "max_m": [22.1, 3.0, 3.0]})  # swallows science's volume
    inst = parse_instance(data, "team.toml", tmp_path)
    assert any("lies wholly inside a keep-out box" in w for w in inst.warnings)
    with pytest.raises(CamplaceError, match=r"volumes\[1\]: only 0 of .* sampled positions are outside the keep-outs"):
        make_run_candidates(inst, "uniform", 40, 1, 0)
