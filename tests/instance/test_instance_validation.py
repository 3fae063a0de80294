"""Every malformed instance gives one InstanceError line naming the source and the dotted field."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from camplace.errors import CamplaceError, InstanceError
from camplace.instance import load_instance, parse_instance

SRC = "broken.toml"


def _set(path: str, value):
    """Mutation that sets data[a][b]... = value (ints index lists)."""

    def mutate(d):
        keys = [int(k) if k.isdigit() else k for k in path.split("/")]
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value

    return mutate


def _del(path: str):
    def mutate(d):
        keys = [int(k) if k.isdigit() else k for k in path.split("/")]
        for k in keys[:-1]:
            d = d[k]
        del d[keys[-1]]

    return mutate


def _rename(path: str, new: str):
    def mutate(d):
        keys = path.split("/")
        for k in keys[:-1]:
            d = d[int(k) if k.isdigit() else k]
        d[new] = d.pop(keys[-1])

    return mutate


def _zero_weights(d):
    for f in d["frames"]:
        f["weight"] = 0.0


NAN, INF = math.nan, math.inf

# (id, mutation, expected field, text the message must contain)
CASES = [
    ("no-schema", _del("schema_version"), "schema_version", "missing"),
    ("schema-2", _set("schema_version", 2), "schema_version", "unknown schema version 2"),
    ("schema-str", _set("schema_version", "1"), "schema_version", "integer"),
    ("schema-bool", _set("schema_version", True), "schema_version", "boolean"),
    ("no-name", _del("name"), "name", "missing"),
    ("name-int", _set("name", 3), "name", "string"),
    ("name-empty", _set("name", "  "), "name", "empty"),
    ("no-k", _del("k"), "k", "missing"),
    ("k-0", _set("k", 0), "k", ">= 1"),
    ("k-bool", _set("k", True), "k", "boolean"),
    ("k-float", _set("k", 2.0), "k", "integer"),
    ("k-gt-default-candidates", _set("k", 3000), "k", "run.candidates"),
    ("k-gt-candidates", _set("run/candidates", 2), "k", "run.candidates"),
    ("run-not-table", _set("run", 5), "run", "table"),
    ("candidates-0", _set("run/candidates", 0), "run.candidates", ">= 1"),
    ("candidates-huge", _set("run/candidates", 2_000_000), "run.candidates", "<="),
    ("points-0", _set("run/points", 0), "run.points", ">= 1"),
    ("points-huge", _set("run/points", 10**8), "run.points", "<="),
    ("points-float", _set("run/points", 1e4), "run.points", "integer"),
    ("sampler-typo", _set("run/sampler", "chaotc"), "run.sampler", "did you mean 'chaotic'?"),
    ("sampler-int", _set("run/sampler", 1), "run.sampler", "string"),
    ("seed-neg", _set("run/seed", -1), "run.seed", ">= 0"),
    ("time-0", _set("run/time_limit_s", 0), "run.time_limit_s", "> 0"),
    ("time-nan", _set("run/time_limit_s", NAN), "run.time_limit_s", "finite"),
    ("run-unknown", _set("run/threads", 4), "run.threads", "unknown key"),
    ("run-typo", _rename("run/candidates", "candidate"), "run.candidate", "did you mean 'candidates'?"),
    ("top-typo", _rename("camera", "cameras"), "cameras", "did you mean 'camera'?"),
    ("top-unknown", _set("colour", "red"), "colour", "unknown key"),
    ("no-camera", _del("camera"), "camera", "missing"),
    ("camera-int", _set("camera", 5), "camera", "table"),
    ("no-focal", _del("camera/focal_length_mm"), "camera.focal_length_mm", "missing"),
    ("focal-bool", _set("camera/focal_length_mm", True), "camera.focal_length_mm", "boolean"),
    ("focal-str", _set("camera/focal_length_mm", "8"), "camera.focal_length_mm", "number"),
    ("focal-nan", _set("camera/focal_length_mm", NAN), "camera.focal_length_mm", "finite"),
    ("focal-inf", _set("camera/focal_length_mm", INF), "camera.focal_length_mm", "finite"),
    ("focal-neg", _set("camera/focal_length_mm", -8.0), "camera.focal_length_mm", "> 0"),
    ("focal-0", _set("camera/focal_length_mm", 0), "camera.focal_length_mm", "> 0"),
    ("focal-typo", _rename("camera/focal_length_mm", "focal_lenght_mm"), "camera.focal_lenght_mm", "did you mean 'focal_length_mm'?"),
    ("sensor-0", _set("camera/sensor_width_mm", 0.0), "camera.sensor_width_mm", "> 0"),
    ("sensor-h-neg", _set("camera/sensor_height_mm", -1), "camera.sensor_height_mm", "> 0"),
    ("width-float", _set("camera/width_px", 1280.0), "camera.width_px", "integer"),
    ("width-0", _set("camera/width_px", 0), "camera.width_px", ">= 1"),
    ("height-str", _set("camera/height_px", "960"), "camera.height_px", "integer"),
    ("near-0", _set("camera/near_m", 0.0), "camera.near_m", "> 0"),
    ("far-lt-near", _set("camera/far_m", 0.05), "camera.far_m", "near_m"),
    ("far-eq-near", _set("camera/far_m", 0.1), "camera.far_m", "near_m"),
    ("no-volume", _del("volume"), "volume", "missing"),
    ("volume-no-max", _del("volume/max_m"), "volume.max_m", "missing"),
    ("volume-short", _set("volume/min_m", [0.3, 0.3]), "volume.min_m", "3 numbers"),
    ("volume-scalar", _set("volume/min_m", 0.3), "volume.min_m", "3 numbers"),
    ("volume-str-item", _set("volume/min_m/1", "a"), "volume.min_m[1]", "number"),
    ("volume-bool-item", _set("volume/max_m/2", False), "volume.max_m[2]", "boolean"),
    ("volume-nan-item", _set("volume/max_m/0", NAN), "volume.max_m[0]", "finite"),
    ("volume-inverted", _set("volume/min_m/0", 30.0), "volume.max_m", "x: 30 >= 29.7"),
    ("volume-empty", _set("volume/max_m/2", 0.3), "volume.max_m", "z: 0.3 >= 0.3"),
    ("volume-typo", _rename("volume/min_m", "min"), "volume.min", "did you mean 'min_m'?"),
    ("no-light", _del("light"), "light", "missing"),
    ("light-no-pos", _del("light/position_m"), "light.position_m", "missing"),
    ("light-inf", _set("light/position_m/2", INF), "light.position_m[2]", "finite"),
    ("no-target", _del("target"), "target", "missing"),
    ("target-both", _set("target/file", "comet.ply"), "target.file", "both file and shape"),
    ("target-neither", _del("target/shape"), "target.shape", "neither file nor shape"),
    ("target-shape-typo", _set("target/shape", "bilobed-commet"), "target.shape", "did you mean 'bilobed-comet'?"),
    ("target-shape-int", _set("target/shape", 3), "target.shape", "string"),
    ("target-length-neg", _set("target/length_m", -0.6), "target.length_m", "> 0"),
    ("target-length-bool", _set("target/length_m", True), "target.length_m", "boolean"),
    ("target-noise", _set("target/noise", 0.5), "target.noise", "<= 0.3"),
    ("target-subdiv-lo", _set("target/subdivisions", 1), "target.subdivisions", ">= 2"),
    ("target-subdiv-hi", _set("target/subdivisions", 8), "target.subdivisions", "<= 7"),
    ("target-seed-float", _set("target/seed", 7.5), "target.seed", "integer"),
    ("target-other-shape-param", _set("target/radius_m", 0.3), "target.radius_m", "sphere"),
    ("target-scale-on-shape", _set("target/scale", 2.0), "target.scale", "only to file meshes"),
    ("target-param-typo", _rename("target/length_m", "lenght_m"), "target.lenght_m", "did you mean 'length_m'?"),
    ("target-name-int", _set("target/name", 1), "target.name", "string"),
    ("occluders-table", _set("occluders", {"shape": "box"}), "occluders", "array of tables"),
    ("occluder-not-table", _set("occluders/0", 3), "occluders[0]", "table"),
    ("occluder-shape-typo", _set("occluders/0/shape", "corridoor"), "occluders[0].shape", "did you mean 'corridor'?"),
    ("occluder-shape-unknown", _set("occluders/0/shape", "teapot"), "occluders[0].shape", "unknown shape"),
    ("occluder-size-0", _set("occluders/0/size_m/1", 0.0), "occluders[0].size_m[1]", "> 0"),
    ("occluder-no-size", _del("occluders/0/size_m"), "occluders[0].size_m", "missing"),
    ("occluder-pos-short", _set("occluders/0/position_m", [0.0, 0.0]), "occluders[0].position_m", "3 numbers"),
    ("occluder-rot-nan", _set("occluders/0/rotation_deg/0", NAN), "occluders[0].rotation_deg[0]", "finite"),
    ("occluder-unknown", _set("occluders/0/colour", "red"), "occluders[0].colour", "unknown key"),
    ("occluder-missing-file", _set("occluders/0", {"file": "nowhere/walls.ply"}), "occluders[0].file", "not found"),
    ("occluder-file-int", _set("occluders/0", {"file": 5}), "occluders[0].file", "path string"),
    ("occluder-file-shape-param", _set("occluders/0", {"file": "x.ply", "size_m": [1, 1, 1]}), "occluders[0].size_m", "need shape"),
    ("occluder-scale-0", _set("occluders/0", {"file": "x.ply", "scale": 0}), "occluders[0].scale", "> 0"),
    ("no-frames", _del("frames"), "frames", "missing"),
    ("frames-empty", _set("frames", []), "frames", "non-empty"),
    ("frames-table", _set("frames", {"weight": 1.0}), "frames", "non-empty array"),
    ("frame-weight-neg", _set("frames/0/weight", -1.0), "frames[0].weight", ">= 0"),
    ("frame-weight-bool", _set("frames/1/weight", True), "frames[1].weight", "boolean"),
    ("frame-weight-nan", _set("frames/2/weight", NAN), "frames[2].weight", "finite"),
    ("frame-weights-zero", _zero_weights, "frames", "weight 0"),
    ("frame-time-inf", _set("frames/1/time_s", INF), "frames[1].time_s", "finite"),
    ("frame-pos-typo", _rename("frames/2/position_m", "positon_m"), "frames[2].positon_m", "did you mean 'position_m'?"),
    ("frame-not-table", _set("frames/1", 1.0), "frames[1]", "table"),
    ("quality-precision", _set("quality", {"mode": "graded", "precision": "float16"}), "quality.precision",
     "unknown precision"),
]


@pytest.mark.parametrize("mutate,field,text", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_broken_variant(valid_data, tmp_path, mutate, field, text):
    parse_instance(valid_data, SRC, tmp_path)  # the unbroken dict is valid
    mutate(valid_data)
    with pytest.raises(InstanceError) as info:
        parse_instance(valid_data, SRC, tmp_path)
    err = info.value
    msg = str(err)
    assert err.field == field
    assert msg.startswith(f"{SRC}: {field}: ")
    assert text in msg
    assert "\n" not in msg and "\r" not in msg
    assert err.fix  # every error says what to do
    assert isinstance(err, CamplaceError)


def test_valid_dict_parses(valid_data, tmp_path):
    inst = parse_instance(valid_data, SRC, tmp_path)
    assert inst.k == 3 and inst.source == SRC
    assert [f.time_s for f in inst.frames] == [0.0, 1.0, 2.0]  # default time = index
    assert [f.weight for f in inst.frames] == [1.0, 0.5, 1.0]
    assert inst.frames[1].target_pose.rotation_deg == (0.0, 0.0, 30.0)
    assert inst.frames[2].target_pose.rotation_deg == (0.0, 0.0, 0.0)
    assert inst.defaults.sampler == "chaotic"


@pytest.mark.parametrize("precision", [None, "byte", "float32"])
def test_quality_precision_parses_and_round_trips(valid_data, tmp_path, precision):
    from camplace.instance import save_instance

    valid_data["quality"] = {"mode": "graded", **({"precision": precision} if precision else {})}
    inst = parse_instance(valid_data, SRC, tmp_path)
    assert inst.quality.precision == (precision or "byte")
    save_instance(inst, tmp_path / "again.toml")
    assert load_instance(tmp_path / "again.toml").quality == inst.quality


def test_defaults_when_run_absent(valid_data, tmp_path):
    del valid_data["run"]
    del valid_data["occluders"]
    inst = parse_instance(valid_data, SRC, tmp_path)
    assert inst.defaults.candidates == 2000 and inst.occluders == ()


def test_not_a_dict(tmp_path):
    with pytest.raises(InstanceError, match="table of keys"):
        parse_instance([1, 2], SRC, tmp_path)


# ------------------------------------------------------------------------------------------------
# file-level errors


def _write(tmp_path: Path, text: str, name: str = "inst.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _one_line_error(call, *fragments):
    with pytest.raises(InstanceError) as info:
        call()
    msg = str(info.value)
    assert "\n" not in msg
    for frag in fragments:
        assert frag in msg, msg
    return info.value


def test_toml_syntax_error_names_line(tmp_path):
    p = _write(tmp_path, 'schema_version = 1\nname = "x"\nk = = 3\n')
    _one_line_error(lambda: load_instance(p), str(p), "TOML syntax error", "line 3")


def test_missing_instance_file(tmp_path):
    p = tmp_path / "nope.toml"
    _one_line_error(lambda: load_instance(p), str(p), "not found")


def test_instance_path_is_folder(tmp_path):
    _one_line_error(lambda: load_instance(tmp_path), "folder")


def test_instance_not_utf8(tmp_path):
    p = tmp_path / "bin.toml"
    p.write_bytes(b"name = \"\xff\xfe\"\n")
    _one_line_error(lambda: load_instance(p), "UTF-8")


def _instance_with_target(tmp_path, valid_data, target: dict) -> Path:
    import tomli_w

    valid_data["target"] = target
    p = tmp_path / "inst.toml"
    p.write_text(tomli_w.dumps(valid_data))
    return p


def test_unreadable_mesh_content(tmp_path, valid_data):
    (tmp_path / "junk.ply").write_bytes(b"this is not a mesh \x00\x01\x02" * 10)
    p = _instance_with_target(tmp_path, valid_data, {"file": "junk.ply"})
    err = _one_line_error(lambda: load_instance(p), "target.file", "cannot read mesh junk.ply")
    assert err.field == "target.file"


def test_unknown_mesh_format(tmp_path, valid_data):
    (tmp_path / "model.xyzq").write_text("1 2 3\n")
    p = _instance_with_target(tmp_path, valid_data, {"file": "model.xyzq"})
    _one_line_error(lambda: load_instance(p), "target.file")


def test_mesh_file_is_folder(tmp_path, valid_data):
    (tmp_path / "meshdir.ply").mkdir()
    p = _instance_with_target(tmp_path, valid_data, {"file": "meshdir.ply"})
    _one_line_error(lambda: load_instance(p), "target.file", "not a file")


def _ascii_ply(vertices, faces) -> str:
    lines = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(vertices)}",
        "property float x",
        "property float y",
        "property float z",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    lines += [" ".join(str(x) for x in v) for v in vertices]
    lines += ["3 " + " ".join(str(i) for i in f) for f in faces]
    return "\n".join(lines) + "\n"


TET_V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
TET_F = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]


@pytest.mark.parametrize(
    "vertices,faces,text",
    [
        ([], [], "no vertices"),
        (TET_V, [], "no triangles"),
        ([[0, 0, 0], [1, 0, "nan"], [0, 1, 0], [0, 0, 1]], TET_F, "NaN"),
        (TET_V, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 9]], "target.file"),
    ],
    ids=["empty", "no-faces", "nan-vertex", "bad-index"],
)
def test_bad_mesh_arrays(tmp_path, valid_data, vertices, faces, text):
    (tmp_path / "bad.ply").write_text(_ascii_ply(vertices, faces))
    p = _instance_with_target(tmp_path, valid_data, {"file": "bad.ply"})
    err = _one_line_error(lambda: load_instance(p), "target.file", text)
    assert err.field == "target.file"


def test_relative_file_resolved_from_instance_folder(tmp_path, valid_data, monkeypatch):
    sub = tmp_path / "sub"
    (sub / "meshes").mkdir(parents=True)
    (sub / "meshes" / "tet.ply").write_text(_ascii_ply(TET_V, TET_F))
    import tomli_w

    valid_data["target"] = {"file": "meshes/tet.ply"}
    (sub / "inst.toml").write_text(tomli_w.dumps(valid_data))
    monkeypatch.chdir(tmp_path)  # cwd is not the instance folder
    inst = load_instance("sub/inst.toml")
    np.testing.assert_array_equal(inst.target.vertices, np.array(TET_V, dtype=float))
    assert inst.target.source == f"file:{(sub / 'meshes' / 'tet.ply').resolve()}"
