"""save_instance -> load_instance gives the same instance; file meshes with scale; the real 67P model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomli_w
import trimesh

from camplace.instance import Instance, builtin, load_instance, parse_instance, save_instance
from camplace.geometry import ply_bytes as mesh_ply_bytes

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[2]
SHARED_MESHES = (REPO / ".." / "shared" / "data" / "meshes").resolve()
COMET_67P = SHARED_MESHES / "comet_67p_5k.obj"


def assert_same_instance(a: Instance, b: Instance, exact: bool = True) -> None:
    """Every field and every mesh array equal (exactly, or to 1e-9)."""

    def same(x, y):
        x, y = np.asarray(x), np.asarray(y)
        assert x.shape == y.shape and x.dtype == y.dtype
        if exact:
            np.testing.assert_array_equal(x, y)
        else:
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-9)

    assert (a.name, a.k, a.camera, a.volume, a.light, a.defaults) == (b.name, b.k, b.camera, b.volume, b.light, b.defaults)
    assert a.frames == b.frames
    assert a.target.name == b.target.name
    same(a.target.vertices, b.target.vertices)
    same(a.target.faces, b.target.faces)
    assert len(a.occluders) == len(b.occluders)
    for oa, ob in zip(a.occluders, b.occluders):
        assert oa.mesh.name == ob.mesh.name and oa.pose == ob.pose
        same(oa.mesh.vertices, ob.mesh.vertices)
        same(oa.mesh.faces, ob.mesh.faces)


def test_builtin_save_load_identical(tmp_path):
    inst = builtin("comet-67p-bunker")
    out = tmp_path / "exp03.toml"
    save_instance(inst, out)
    assert sorted(p.name for p in (tmp_path / "exp03_meshes").iterdir()) == ["occluder0_corridor.ply", "target.ply"]
    data = tomllib.loads(out.read_text())
    assert data["target"]["file"] == "exp03_meshes/target.ply"
    assert "# generated from: shape = \"bilobed-comet\"" in out.read_text()
    back = load_instance(out)
    assert back.source == str(out)
    assert_same_instance(inst, back)
    assert back.target.vertices.dtype == np.float64 and back.target.faces.dtype == np.int64
    # saving the loaded copy again (now file-based) still round-trips exactly, from another folder
    out2 = tmp_path / "copy" / "again.toml"
    save_instance(back, out2)
    assert_same_instance(inst, load_instance(out2))


def test_save_procedural_specs(tmp_path):
    inst = builtin("comet-67p-bunker")
    out = tmp_path / "spec.toml"
    save_instance(inst, out, mesh_files=False)
    assert not (tmp_path / "spec_meshes").exists()
    data = tomllib.loads(out.read_text())
    assert data["target"] == {"name": "comet-67p", "shape": "bilobed-comet", "length_m": 0.6, "seed": 7}
    assert data["occluders"][0]["shape"] == "corridor"
    assert_same_instance(inst, load_instance(out))


def test_save_file_specs_relocated(tmp_path, valid_data):
    """mesh_files=False keeps file = ... specs, rewritten relative to the new location."""
    v, f = _tetra()
    (tmp_path / "src" / "m").mkdir(parents=True)
    (tmp_path / "src" / "m" / "tet.ply").write_bytes(mesh_ply_bytes(v, f))
    valid_data["target"] = {"file": "m/tet.ply", "scale": 0.5}
    (tmp_path / "src" / "inst.toml").write_text(tomli_w.dumps(valid_data))
    inst = load_instance(tmp_path / "src" / "inst.toml")
    out = tmp_path / "elsewhere" / "deep" / "inst.toml"
    save_instance(inst, out, mesh_files=False)
    data = tomllib.loads(out.read_text())
    assert data["target"]["file"] == "../../src/m/tet.ply" and data["target"]["scale"] == 0.5
    assert_same_instance(inst, load_instance(out))


def test_multi_frame_rotated_occluders_round_trip(tmp_path, valid_data):
    valid_data["occluders"].append(
        {"name": "rock / 1", "shape": "sphere", "radius_m": 0.25, "subdivisions": 2, "position_m": [5.0, 1.0, 0.25], "rotation_deg": [10.0, 20.0, 30.0]}
    )
    valid_data["occluders"].append({"shape": "box", "size_m": [0.5, 0.4, 1.0], "position_m": [20.0, 2.0, 0.5]})
    inst = parse_instance(valid_data, "multi", tmp_path)
    assert inst.occluders[2].mesh.name == "occluder2"
    for mesh_files in (True, False):
        out = tmp_path / f"multi_{mesh_files}.toml"
        save_instance(inst, out, mesh_files=mesh_files)
        assert_same_instance(inst, load_instance(out))
    assert (tmp_path / "multi_True_meshes" / "occluder1_rock-1.ply").exists()


def test_save_is_atomic_and_leaves_no_temp_files(tmp_path):
    save_instance(builtin("comet-67p-bunker"), tmp_path / "a.toml")
    leftovers = [p.name for p in tmp_path.rglob("*") if ".tmp" in p.name]
    assert leftovers == []


def _tetra():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64) + 0.1234567890123
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int64)
    return v, f


def test_ply_writer_is_exact_float64(tmp_path):
    rng = np.random.default_rng(1)
    v = rng.standard_normal((50, 3)) * 1e3
    f = rng.integers(0, 50, size=(80, 3))
    (tmp_path / "x.ply").write_bytes(mesh_ply_bytes(v, f, "hello\nworld"))
    m = trimesh.load(tmp_path / "x.ply", process=False)
    np.testing.assert_array_equal(m.vertices, v)
    np.testing.assert_array_equal(m.faces, f)


@pytest.mark.parametrize("fmt", ["ply", "stl", "obj", "off"])
def test_file_and_scale(tmp_path, valid_data, fmt):
    box = trimesh.creation.box(extents=[2.0, 4.0, 6.0])
    box.export(tmp_path / f"box.{fmt}")
    valid_data["target"] = {"file": f"box.{fmt}", "scale": 0.1, "name": "small box"}
    valid_data["occluders"].append({"file": str(tmp_path / f"box.{fmt}"), "position_m": [3.0, 1.0, 0.3]})  # absolute path, scale 1
    p = tmp_path / "inst.toml"
    p.write_text(tomli_w.dumps(valid_data))
    inst = load_instance(p)
    t = inst.target
    assert t.name == "small box" and t.source.startswith("file:") and t.spec["scale"] == 0.1
    np.testing.assert_allclose(t.vertices.max(axis=0) - t.vertices.min(axis=0), [0.2, 0.4, 0.6], rtol=1e-6)
    m = trimesh.Trimesh(t.vertices, t.faces, process=False)
    assert m.volume == pytest.approx(0.2 * 0.4 * 0.6, rel=1e-5)  # outward kept
    occ = inst.occluders[1].mesh
    np.testing.assert_allclose(occ.vertices.max(axis=0) - occ.vertices.min(axis=0), [2.0, 4.0, 6.0], rtol=1e-6)
    # and it round-trips through save/load
    save_instance(inst, tmp_path / "out" / "saved.toml")
    assert_same_instance(inst, load_instance(tmp_path / "out" / "saved.toml"))


def test_inconsistent_winding_is_made_consistent(tmp_path, valid_data):
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    faces = box.faces.copy()
    faces[3] = faces[3][::-1]
    (tmp_path / "bad.ply").write_bytes(mesh_ply_bytes(box.vertices, faces))
    valid_data["target"] = {"file": "bad.ply"}
    (tmp_path / "inst.toml").write_text(tomli_w.dumps(valid_data))
    t = load_instance(tmp_path / "inst.toml").target
    m = trimesh.Trimesh(t.vertices, t.faces, process=False)
    assert m.is_winding_consistent and m.is_watertight


def test_inward_file_mesh_kept_inward(tmp_path, valid_data):
    """A room mesh with inward normals (like the corridor written to PLY) is not flipped on load."""
    inst = builtin("comet-67p-bunker")
    save_instance(inst, tmp_path / "b.toml")
    occ = load_instance(tmp_path / "b.toml").occluders[0].mesh
    assert trimesh.Trimesh(occ.vertices, occ.faces, process=False).volume == pytest.approx(-270.0)


@pytest.mark.skipif(not COMET_67P.exists(), reason=f"shared comet 67P shape model not present at {COMET_67P}")
def test_real_comet_67p_shape_model(tmp_path, valid_data):
    """The real 67P shape model (coordinates in km, about 5.05 x 3.72 x 3.28): scale is a plain factor."""
    valid_data["target"] = {"name": "67P", "file": str(COMET_67P), "scale": 0.0001}
    inst = parse_instance(valid_data, "real67p", tmp_path)
    t = inst.target
    assert t.vertices.shape == (2502, 3) and t.faces.shape == (5000, 3)
    assert t.vertices.dtype == np.float64 and t.faces.dtype == np.int64
    ext = t.vertices.max(axis=0) - t.vertices.min(axis=0)
    np.testing.assert_allclose(ext, np.array([5.054641, 3.720007, 3.280283]) * 1e-4, rtol=1e-6)
    m = trimesh.Trimesh(t.vertices, t.faces, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    # a ~0.5 m lab model of the ~5 km nucleus needs scale 0.1 (km numbers -> metres / 10000)
    valid_data["target"]["scale"] = 0.1
    lab = parse_instance(valid_data, "real67p", tmp_path).target
    assert 0.45 < (lab.vertices.max(axis=0) - lab.vertices.min(axis=0)).max() < 0.55
    np.testing.assert_allclose(lab.vertices, t.vertices * 1000.0, rtol=1e-12)
    # relative path from an instance file in a repo-like layout works too
    inst_dir = tmp_path / "work" / "main" / "instances"
    inst_dir.mkdir(parents=True)
    (tmp_path / "mesh.obj").write_bytes(COMET_67P.read_bytes())
    valid_data["target"] = {"file": "../../../mesh.obj", "scale": 0.0001}
    (inst_dir / "i.toml").write_text(tomli_w.dumps(valid_data))
    np.testing.assert_array_equal(load_instance(inst_dir / "i.toml").target.vertices, t.vertices)
    # and it survives save/load
    save_instance(inst, tmp_path / "saved.toml")
    np.testing.assert_array_equal(load_instance(tmp_path / "saved.toml").target.vertices, t.vertices)


def test_make_winding_consistent():
    from camplace.instance.meshio import make_winding_consistent
    from camplace.instance.procedural import icosphere

    v, f = icosphere(6)  # > 46341 faces: face-pair keys overflow int32
    assert make_winding_consistent(f) is f  # consistent input untouched
    rng = np.random.default_rng(0)
    g = f.copy()
    flip = rng.random(len(f)) < 0.3
    flip[0] = False
    g[flip] = g[flip][:, ::-1]
    np.testing.assert_array_equal(make_winding_consistent(g), f)
    # two components: each keeps the orientation of its lowest-index face
    v2, f2 = icosphere(2)
    both = np.vstack([f2, f2[:, ::-1] + len(v2)])
    both[5] = both[5][::-1]
    both[len(f2) + 7] = both[len(f2) + 7][::-1]
    fixed = make_winding_consistent(both)
    np.testing.assert_array_equal(fixed[: len(f2)], f2)
    np.testing.assert_array_equal(fixed[len(f2) :], f2[:, ::-1] + len(v2))
