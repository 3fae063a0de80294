"""Built-ins, resolve_instance and the committed instances/ files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from camplace.errors import CamplaceError, InstanceError
from camplace.instance import (
    BUILTINS,
    Instance,
    builtin,
    builtin_toml,
    load_instance,
    resolve_instance,
    write_builtin,
)

REPO = Path(__file__).resolve().parents[2]


def test_registry():
    assert "comet-67p-bunker" in BUILTINS
    for name, desc in BUILTINS.items():
        assert isinstance(desc, str) and desc and "\n" not in desc
        assert builtin_toml(name)["name"] == name


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_every_builtin_parses(name):
    inst = builtin(name)
    assert isinstance(inst, Instance) and inst.source == f"builtin:{name}"


def test_comet_bunker_contents():
    inst = builtin("comet-67p-bunker")
    assert inst.k == 3
    cam = inst.camera
    assert (cam.sensor_width_mm, cam.sensor_height_mm, cam.focal_length_mm) == (7.18, 5.32, 8.0)
    assert (cam.width_px, cam.height_px, cam.near_m, cam.far_m) == (1280, 960, 0.1, 40.0)
    assert inst.volume.min_m == (0.3, 0.3, 0.3) and inst.volume.max_m == (29.7, 2.7, 2.7)
    d = inst.defaults
    assert (d.candidates, d.points, d.sampler, d.seed, d.time_limit_s) == (2000, 10000, "chaotic", 0, 60.0)
    assert len(inst.frames) == 1 and inst.frames[0].weight == 1.0
    # the comet sits in the corridor, inside the camera volume, about 0.6 m long
    v, f = inst.target_world(0)
    assert np.all(v.min(axis=0) > np.array(inst.volume.min_m)) and np.all(v.max(axis=0) < np.array(inst.volume.max_m))
    assert (v.max(axis=0) - v.min(axis=0)).max() == pytest.approx(0.6)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.volume > 0
    (name, cv, cf), = inst.occluders_world()
    assert name == "corridor"
    np.testing.assert_allclose([cv.min(axis=0), cv.max(axis=0)], [[0, 0, 0], [30, 3, 3]])
    assert trimesh.Trimesh(cv, cf, process=False).volume == pytest.approx(-270.0)
    # the light is inside the corridor too
    assert np.all(np.array(inst.light.position_m) > 0) and np.all(np.array(inst.light.position_m) < [30, 3, 3])


def test_builtin_toml_is_a_copy():
    a = builtin_toml("comet-67p-bunker")
    a["k"] = 99
    a["camera"]["focal_length_mm"] = 1.0
    assert builtin_toml("comet-67p-bunker")["k"] == 3
    assert builtin("comet-67p-bunker").camera.focal_length_mm == 8.0


def test_unknown_builtin_lists_names():
    with pytest.raises(CamplaceError, match="comet-67p-bunker") as info:
        builtin("comet-67p")
    assert not isinstance(info.value, InstanceError)
    with pytest.raises(CamplaceError, match="comet-67p-bunker"):
        builtin_toml("nope")


def test_write_builtin(tmp_path):
    out = tmp_path / "init" / "exp.toml"
    write_builtin("comet-67p-bunker", out)
    assert (tmp_path / "init" / "exp_meshes" / "target.ply").exists()
    inst = load_instance(out)
    ref = builtin("comet-67p-bunker")
    np.testing.assert_array_equal(inst.target.vertices, ref.target.vertices)


def test_resolve_instance(tmp_path, monkeypatch):
    assert resolve_instance("comet-67p-bunker").source == "builtin:comet-67p-bunker"
    write_builtin("comet-67p-bunker", tmp_path / "x.toml")
    assert resolve_instance(tmp_path / "x.toml").source == str(tmp_path / "x.toml")
    assert resolve_instance(str(tmp_path / "x.toml")).name == "comet-67p-bunker"
    with pytest.raises(CamplaceError, match="no built-in or file named 'nope.toml'; built-ins: comet-67p-bunker"):
        resolve_instance("nope.toml")
    # a file in the working folder that happens to be named like a built-in: the built-in wins
    monkeypatch.chdir(tmp_path)
    (tmp_path / "comet-67p-bunker").write_text("garbage")
    assert resolve_instance("comet-67p-bunker").source == "builtin:comet-67p-bunker"
    (tmp_path / "bad.toml").write_text("k = [")
    with pytest.raises(InstanceError, match="TOML syntax error"):
        resolve_instance("bad.toml")


def test_committed_instance_file_matches_builtin():
    """instances/comet-67p-bunker.toml is write_builtin's output; regenerate it if this fails."""
    path = REPO / "instances" / "comet-67p-bunker.toml"
    assert path.exists(), f"{path} is part of the repository (regenerate it with camplace init)"
    inst = load_instance(path)
    ref = builtin("comet-67p-bunker")
    assert inst.name == ref.name and inst.k == ref.k and inst.camera == ref.camera and inst.frames == ref.frames
    np.testing.assert_array_equal(inst.target.vertices, ref.target.vertices)
    np.testing.assert_array_equal(inst.target.faces, ref.target.faces)
    np.testing.assert_array_equal(inst.occluders[0].mesh.vertices, ref.occluders[0].mesh.vertices)
    np.testing.assert_array_equal(inst.occluders[0].mesh.faces, ref.occluders[0].mesh.faces)
