"""Mesh files as users bring them (issue 33): an OBJ with texture coordinates whose seams split
vertices must read on the base install, without a false "not watertight" warning, with its
winding consistent across the seams; a package missing while reading says which to install; the
instance's warnings reach solution.json.
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

import camplace.instance.meshio as meshio
from camplace.errors import InstanceError
from camplace.instance import load_instance
from camplace.instance.meshio import MissingPackageError, is_watertight, read_mesh_file, welded_faces
from tests._meshes import asteroid_instance_toml, asteroid_km, write_textured_obj

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def textured(tmp_path: Path) -> Path:
    """A textured asteroid OBJ (km, seams duplicating vertices) and its instance file."""
    assert write_textured_obj(tmp_path / "asteroid.obj", asteroid_km()) > 0  # the file really has seams
    (tmp_path / "asteroid.toml").write_text(asteroid_instance_toml("asteroid.obj"))
    return tmp_path / "asteroid.toml"


def test_pillow_is_a_base_dependency() -> None:
    """trimesh needs Pillow for an OBJ with vt lines: the base install must have it, not an extra."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    names = [d.split(">")[0].split("=")[0].split("<")[0].split(";")[0].strip().lower() for d in deps]
    assert "pillow" in names


def test_seams_split_vertices_yet_the_mesh_is_watertight(textured: Path) -> None:
    vertices, faces = read_mesh_file(textured.parent / "asteroid.obj")
    assert len(vertices) > len(asteroid_km().vertices)  # trimesh keeps the seam's duplicates
    assert not meshio._is_closed(faces)  # so, on the file's own indices, the seam edges are open
    welded = welded_faces(vertices, faces)
    assert welded.shape == faces.shape and welded.max() + 1 == len(asteroid_km().vertices)
    assert is_watertight(vertices, faces)
    closed = trimesh.Trimesh(vertices, faces, process=True)  # trimesh's own opinion, merged
    assert closed.is_watertight and closed.is_winding_consistent and closed.volume > 0


def test_no_false_watertight_warning(textured: Path, caplog) -> None:
    with caplog.at_level(logging.WARNING, logger="camplace.instance.parse"):
        inst = load_instance(textured)
    assert "watertight" not in caplog.text
    assert inst.warnings == ()
    # metres: the km model times scale = 1000
    np.testing.assert_allclose(np.ptp(inst.target.vertices, axis=0), [2400.0, 1600.0, 1200.0], rtol=0.02)


def test_an_open_seamed_mesh_still_warns_and_keeps_the_warning(tmp_path: Path, caplog) -> None:
    """Welding must not hide a real hole: drop one face of the seamed asteroid."""
    mesh = asteroid_km()
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[1:], process=False)
    write_textured_obj(tmp_path / "asteroid.obj", mesh)
    (tmp_path / "asteroid.toml").write_text(asteroid_instance_toml("asteroid.obj"))
    with caplog.at_level(logging.WARNING, logger="camplace.instance.parse"):
        inst = load_instance(tmp_path / "asteroid.toml")
    assert "not watertight" in caplog.text
    assert len(inst.warnings) == 1 and inst.warnings[0].startswith("target: the mesh is not watertight")


def test_winding_is_made_consistent_across_split_vertices(tmp_path: Path) -> None:
    """An STL splits every vertex (three per triangle): half the faces flipped are turned back, as
    the winding is judged on the welded faces (on the file's own indices no edge is shared)."""
    mesh = asteroid_km()
    east = mesh.triangles_center[:, 1] > 0
    flipped = mesh.faces.copy()
    flipped[east] = flipped[east][:, ::-1]
    path = tmp_path / "asteroid.stl"
    trimesh.Trimesh(mesh.vertices, flipped, process=False).export(path)
    vertices, faces = read_mesh_file(path)
    assert len(vertices) == 3 * len(faces)
    welded = trimesh.Trimesh(vertices, faces, process=True)
    assert welded.is_winding_consistent and welded.is_watertight
    assert abs(welded.volume) == pytest.approx(mesh.volume, rel=1e-6)


def test_a_missing_package_names_itself(textured: Path, monkeypatch) -> None:
    """An ImportError inside trimesh is a missing package to install, not a bad mesh."""

    def load(*args, **kwargs):
        raise ModuleNotFoundError("No module named 'PIL'", name="PIL")

    monkeypatch.setattr(trimesh, "load", load)
    with pytest.raises(InstanceError) as err:
        load_instance(textured)
    assert err.value.field == "target.file"
    assert err.value.fix == "install it: pip install pillow"
    assert "valid triangle mesh" not in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(MissingPackageError) as raw:
        read_mesh_file(textured.parent / "asteroid.obj")
    assert raw.value.package == "pillow"


def test_without_pillow_the_command_line_says_install_pillow(textured: Path) -> None:
    """The real failure: Pillow absent before trimesh is imported (a fresh process), one line, exit 2."""
    code = ("import sys; sys.modules['PIL'] = None; from camplace.cli import main; "
            f"sys.exit(main(['run', {str(textured)!r}, '-o', {str(textured.parent / 'out')!r}]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("error: ") and "target.file" in err and "pip install pillow" in err
    assert "valid triangle mesh" not in err


def test_instance_warnings_reach_solution_json(tmp_path: Path) -> None:
    """A warning about the instance (here an open target) is in solution.json's warnings."""
    from camplace.pipeline import run

    mesh = asteroid_km()
    write_textured_obj(tmp_path / "asteroid.obj", trimesh.Trimesh(mesh.vertices, mesh.faces[1:], process=False))
    (tmp_path / "asteroid.toml").write_text(asteroid_instance_toml("asteroid.obj"))
    out = tmp_path / "out"
    run(load_instance(tmp_path / "asteroid.toml"), candidates=20, points=200, outdir=out)
    warnings = json.loads((out / "solution.json").read_text())["warnings"]
    assert any(w.startswith("target: the mesh is not watertight") for w in warnings), warnings


@pytest.mark.parametrize("exc,package", [
    (ModuleNotFoundError("No module named 'PIL'", name="PIL"), "pillow"),
    (ModuleNotFoundError("import of PIL halted; None in sys.modules"), "pillow"),  # trimesh's deferred re-raise
    (ImportError("cannot import name 'Image' from 'PIL' (unknown location)"), "pillow"),
    (ModuleNotFoundError("No module named 'networkx.algorithms'"), "networkx"),
    (ImportError("something else went wrong"), None),
])
def test_the_missing_package_is_read_from_the_error(exc: ImportError, package: str | None) -> None:
    err = MissingPackageError("model.obj", exc)
    assert err.package == package
    assert (f"pip install {package}" in str(err)) if package else ("pip install" not in str(err))
    assert str(err).startswith("reading model.obj needs ") and "\n" not in str(err)
