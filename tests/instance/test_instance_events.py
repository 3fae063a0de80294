"""Instance fields for events and quality: parse, validate, and round-trip through save_instance."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from camplace.errors import InstanceError
from camplace.instance import load_instance, parse_instance, save_instance
from camplace.instance.lab import PhysicalCamera, TransformConfig


def rich(valid_data: dict, tmp_path: Path) -> dict:
    data = copy.deepcopy(valid_data)
    data["quality"] = {"mode": "graded", "required_px_per_m": 800.0, "max_incidence_deg": 70.0, "require_light": True}
    data["run"]["orientations"] = 3
    (tmp_path / "coma.csv").write_text("x,y,z,weight\n12.0,1.5,2.0,0.5\n12.1,1.4,2.1,0.25\n")
    data["frames"][0]["emitters"] = {"file": "coma.csv"}
    data["frames"][0]["target_weight"] = 2.0
    data["frames"][1]["emitters"] = {"positions_m": [[13.0, 1.5, 2.0]], "weights": [1.5]}
    data["frames"][2]["occluders"] = [{"name": "rock", "shape": "box", "size_m": [0.2, 0.2, 0.2], "position_m": [13.5, 1.5, 1.5]}]
    data["physical"] = {"sigma_position_m": 0.01, "sigma_rotation_deg": 0.5}
    data["transform"] = {
        "method": "similarity",
        "pairs": [
            {"sim_m": [0.0, 0.0, 0.0], "phys_m": [1.0, 0.0, 0.0]},
            {"sim_m": [1.0, 0.0, 0.0], "phys_m": [1.0, 2.0, 0.0]},
            {"sim_m": [0.0, 1.0, 0.0], "phys_m": [-1.0, 0.0, 0.0]},
        ],
    }
    return data


def test_new_fields_parse(valid_data: dict, tmp_path: Path) -> None:
    inst = parse_instance(rich(valid_data, tmp_path), "rich.toml", tmp_path)
    assert inst.quality.mode == "graded" and inst.quality.require_light and inst.defaults.orientations == 3
    f0, f1, f2 = inst.frames
    assert f0.target_weight == 2.0 and len(f0.emitters) == 2 and np.allclose(f0.emitters.weights, [0.5, 0.25])
    assert f1.emitters.positions_m.shape == (1, 3) and f2.occluders[0].mesh.name == "rock"
    assert inst.physical.sigma_position_m == 0.01 and inst.transform.method == "similarity"
    assert len(inst.occluders_world(2)) == len(inst.occluders_world()) + 1


@pytest.mark.parametrize("mesh_files", [True, False])
def test_new_fields_round_trip(valid_data: dict, tmp_path: Path, mesh_files: bool) -> None:
    inst = parse_instance(rich(valid_data, tmp_path), str(tmp_path / "rich.toml"), tmp_path)
    out = tmp_path / "copy" / "again.toml"
    save_instance(inst, out, mesh_files=mesh_files)
    back = load_instance(out)
    assert back.quality == inst.quality and back.defaults == inst.defaults
    assert back.physical == inst.physical and back.transform == inst.transform
    for a, b in zip(inst.frames, back.frames):
        assert a.target_weight == b.target_weight and a.emitters == b.emitters
        assert len(a.occluders) == len(b.occluders)
        for oa, ob in zip(a.occluders, b.occluders):
            assert np.array_equal(oa.mesh.vertices, ob.mesh.vertices) and oa.pose == ob.pose


@pytest.mark.parametrize(
    ("physical", "transform", "expect_physical", "expect_transform"),
    [
        ({}, {"method": "identity"}, PhysicalCamera(), TransformConfig()),
        ({"vignetting": 0.25, "k1": 0}, {"method": "scale", "sim_extent_m": [10, 5, 4], "phys_extent_m": [2, 1, 1],
                                         "sim_scale": 2},
         PhysicalCamera(vignetting=0.25),
         TransformConfig(method="scale", sim_extent_m=(10.0, 5.0, 4.0), phys_extent_m=(2.0, 1.0, 1.0),
                         sim_scale=(2.0, 2.0, 2.0))),
    ],
)
def test_lab_tables_parsed_once_and_round_trip(valid_data: dict, tmp_path: Path, physical, transform,
                                               expect_physical, expect_transform) -> None:
    data = copy.deepcopy(valid_data)
    data["physical"], data["transform"] = physical, transform
    inst = parse_instance(data, str(tmp_path / "lab.toml"), tmp_path)
    assert inst.physical == expect_physical and inst.transform == expect_transform
    out = tmp_path / "copy" / "lab.toml"
    save_instance(inst, out)
    back = load_instance(out)
    assert back.physical == expect_physical and back.transform == expect_transform
    assert parse_instance(copy.deepcopy(valid_data), str(tmp_path / "bare.toml"), tmp_path).physical is None


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda d: d.__setitem__("quality", {"mode": "fancy"}), "quality.mode"),
        (lambda d: d.__setitem__("quality", {"max_incidence_deg": 120.0}), "quality.max_incidence_deg"),
        (lambda d: d.__setitem__("quality", {"require_light": "yes"}), "quality.require_light"),
        (lambda d: d.__setitem__("quality", {"reqired_px_per_m": 3.0}), "quality.reqired_px_per_m"),
        (lambda d: d["run"].__setitem__("orientations", 0), "run.orientations"),
        (lambda d: d["frames"][0].__setitem__("emitters", {"positions_m": [[1, 2]], "weights": [1]}), "frames[0].emitters.positions_m"),
        (lambda d: d["frames"][0].__setitem__("emitters", {"positions_m": [[1, 2, 3]], "weights": [-1]}), "frames[0].emitters.weights[0]"),
        (lambda d: d["frames"][0].__setitem__("emitters", {"positions_m": [[1, 2, 3]], "weights": [1, 2]}), "frames[0].emitters.weights"),
        (lambda d: d["frames"][0].__setitem__("emitters", {"file": "missing.csv"}), "frames[0].emitters.file"),
        (lambda d: d["frames"][0].__setitem__("target_weight", 0.0), "frames[0].target_weight"),
        (lambda d: d["frames"][1].__setitem__("occluders", [{"shape": "cube"}]), "frames[1].occluders[0].shape"),
    ],
)
def test_new_field_errors(valid_data: dict, tmp_path: Path, edit, field: str) -> None:
    data = copy.deepcopy(valid_data)
    edit(data)
    with pytest.raises(InstanceError) as err:
        parse_instance(data, "bad.toml", tmp_path)
    assert err.value.field == field, str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("table, needle", [("physical", "physical.sigma_position_m"), ("transform", "transform.method")])
def test_validation_tables_are_checked(valid_data: dict, tmp_path: Path, table: str, needle: str) -> None:
    data = copy.deepcopy(valid_data)
    data[table] = {"sigma_position_m": -1.0} if table == "physical" else {"method": "magic"}
    with pytest.raises(InstanceError) as err:
        parse_instance(data, "bad.toml", tmp_path)
    assert str(err.value).startswith("bad.toml: ") and needle in str(err.value) and "\n" not in str(err.value)
