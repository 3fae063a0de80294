"""Hostile meshes: degenerate faces, NaN, empty, over budget, open surfaces, wrong units."""

from __future__ import annotations

import copy
import logging
from pathlib import Path

import pytest

import camplace.instance.parse as parse_module
from camplace.errors import InstanceError
from camplace.instance import parse_instance

from .counts import COUNTS
from .test_fuzz_instances import BASE


def write_obj(path: Path, vertices, faces) -> None:
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


TETRA_V = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
TETRA_F = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def with_target(tmp_path: Path, vertices, faces, scale: float = 0.3) -> dict:
    f = tmp_path / "target.obj"
    write_obj(f, vertices, faces)
    data = copy.deepcopy(BASE)
    data["target"] = {"file": "target.obj", "scale": scale}
    return data


def parse(data: dict, tmp_path: Path):
    COUNTS["inputs tried"] += 1
    return parse_instance(data, "mesh.toml", tmp_path)


def test_degenerate_faces_are_dropped_with_a_warning(tmp_path: Path, caplog) -> None:
    v = TETRA_V + [(2, 2, 2)]
    f = TETRA_F + [(0, 0, 1), (0, 1, 1), (1, 4, 4)]  # repeated vertices = zero area
    with caplog.at_level(logging.WARNING, logger="camplace.instance.parse"):
        inst = parse(with_target(tmp_path, v, f), tmp_path)
    assert inst.target.faces.shape == (4, 3)
    assert "dropped 3 degenerate" in caplog.text


def test_all_degenerate_is_an_error(tmp_path: Path) -> None:
    v = [(0, 0, 0), (1, 0, 0), (2, 0, 0)]  # collinear
    with pytest.raises(InstanceError) as err:
        parse(with_target(tmp_path, v, [(0, 1, 2)]), tmp_path)
    assert err.value.field == "target.file" and "degenerate" in str(err.value)


def test_nan_vertices_are_an_error(tmp_path: Path) -> None:
    v = TETRA_V[:3] + [(0, 0, float("nan"))]
    with pytest.raises(InstanceError) as err:
        parse(with_target(tmp_path, v, TETRA_F), tmp_path)
    assert "NaN" in str(err.value) and "\n" not in str(err.value)


def test_face_budget(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(parse_module, "MAX_FACES", 3)
    with pytest.raises(InstanceError) as err:
        parse(with_target(tmp_path, TETRA_V, TETRA_F), tmp_path)
    assert "over the budget" in str(err.value) and "decimate" in str(err.value)


def test_open_target_warns(tmp_path: Path, caplog) -> None:
    with caplog.at_level(logging.WARNING, logger="camplace.instance.parse"):
        parse(with_target(tmp_path, TETRA_V, TETRA_F[:3]), tmp_path)
    assert "not watertight" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="camplace.instance.parse"):
        parse(with_target(tmp_path, TETRA_V, TETRA_F), tmp_path)
    assert "not watertight" not in caplog.text


def test_wrong_units_warn(tmp_path: Path, caplog) -> None:
    with caplog.at_level(logging.WARNING, logger="camplace.instance.parse"):
        parse(with_target(tmp_path, TETRA_V, TETRA_F, scale=1000.0), tmp_path)  # a km model read as metres
    assert "larger than the camera volume" in caplog.text and "units" in caplog.text


def test_empty_and_garbage_mesh_files(tmp_path: Path) -> None:
    data = copy.deepcopy(BASE)
    data["target"] = {"file": "empty.obj"}
    (tmp_path / "empty.obj").write_text("")
    for content in ("", "v 1 2\nf 1 2 3\n", "\x00\x01binary junk", "f 1 2 3\n"):
        (tmp_path / "empty.obj").write_text(content)
        with pytest.raises(InstanceError) as err:
            parse(data, tmp_path)
        assert err.value.field.startswith("target") and "\n" not in str(err.value)
    (tmp_path / "empty.obj").unlink()
    with pytest.raises(InstanceError) as err:
        parse(data, tmp_path)
    assert "target.file" in str(err.value)
