"""Camera exports: COLMAP round trip (pose and pixel convention), GLB frustums, JSON and CSV."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

import camplace.cli
from camplace.instance import builtin
from camplace.pipeline import run
from camplace.solution import Solution
from camplace.report.export import Z_UP_TO_Y_UP, export_cameras, frustum_mesh, parse_formats, rotation_to_quaternion
from camplace.geometry import quaternion_to_rotation
from camplace.validation.camera_io import read_colmap
from camplace.validation.cameras import CameraSet


@pytest.fixture
def cli(monkeypatch):
    monkeypatch.setattr(camplace.cli, "VERB_MODULES", ("camplace.validation.cli", "camplace.report.cli"))
    return camplace.cli.main


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "out"
    run(builtin("comet-67p-bunker"), seed=3, candidates=60, points=600, outdir=out)
    return out


@pytest.fixture(scope="module")
def exported(run_dir, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export")
    export_cameras(run_dir, formats="all", out=out)
    return out


def solution_cameras(run_dir: Path):
    return CameraSet.from_solution(Solution.load(run_dir)).cameras


def random_rotations(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    return np.array([quaternion_to_rotation(v) for v in q])


def test_quaternion_inverts_colmap_reader_convention() -> None:
    Rs = list(random_rotations(200, 1))
    # rotations by ~180 degrees (trace near -1) and the identity
    Rs += [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]), np.eye(3)]
    for R in Rs:
        q = rotation_to_quaternion(R)
        assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
        np.testing.assert_allclose(quaternion_to_rotation(q), R, atol=1e-12)


def test_colmap_round_trip_gives_the_same_poses(run_dir, exported) -> None:
    cams = solution_cameras(run_dir)
    back = read_colmap(exported / "colmap").by_name()
    assert len(back) == len(cams)
    for cam in cams:
        b = back[cam.name]
        np.testing.assert_allclose(b.position, cam.position, atol=1e-9)
        np.testing.assert_allclose(b.rotation, cam.rotation, atol=1e-12)
        np.testing.assert_allclose(b.K, cam.K, atol=1e-9)
        assert (b.width, b.height) == (cam.width, cam.height)
        assert b.image == f"{cam.name}.png"


def test_colmap_pixel_convention(run_dir, exported) -> None:
    """COLMAP's own projection (x = R(q) X + t; u = fx x/z + cx, top-left pixel centre at 0.5) is ours + 0.5."""
    cams = solution_cameras(run_dir)
    cam_lines = [ln.split() for ln in (exported / "colmap" / "cameras.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    img_lines = [ln for ln in (exported / "colmap" / "images.txt").read_text().splitlines() if not ln.startswith("#")]
    assert img_lines[1::2] == [""] * len(cams)  # empty POINTS2D lines
    rng = np.random.default_rng(0)
    sol = Solution.load(run_dir)
    for cam, cl, il, rec in zip(cams, cam_lines, img_lines[0::2], sol.cameras):
        assert cl[1] == "PINHOLE" and (int(cl[2]), int(cl[3])) == (cam.width, cam.height)
        fx, fy, cx, cy = map(float, cl[4:8])
        parts = il.split()
        R = quaternion_to_rotation([float(x) for x in parts[1:5]])
        t = np.array([float(x) for x in parts[5:8]])
        # the aim point is at the image centre: ours ((w-1)/2, (h-1)/2), COLMAP's (w/2, h/2)
        x = R @ np.asarray(rec["aim"]) + t
        assert x[2] > 0
        np.testing.assert_allclose([fx * x[0] / x[2] + cx, fy * x[1] / x[2] + cy], [cam.width / 2, cam.height / 2], atol=1e-6)
        pts = rec["aim"] + rng.normal(scale=0.3, size=(20, 3))
        ours, _ = cam.project(pts)
        xc = pts @ R.T + t
        theirs = np.column_stack([fx * xc[:, 0] / xc[:, 2] + cx, fy * xc[:, 1] / xc[:, 2] + cy])
        np.testing.assert_allclose(theirs, ours + 0.5, atol=1e-6)


def test_glb_has_the_scene_and_one_frustum_per_camera(run_dir, exported) -> None:
    cams = solution_cameras(run_dir)
    sol = Solution.load(run_dir)
    scene = trimesh.load(exported / "cameras.glb", force="scene")
    frustums = sorted(n for n in scene.graph.nodes_geometry if n.startswith("frustum."))
    assert frustums == sorted(f"frustum.{c.name}" for c in cams)
    assert any(n.startswith("scene.") and "target" in n for n in scene.graph.nodes_geometry)
    back = np.linalg.inv(Z_UP_TO_Y_UP)
    for cam, rec in zip(cams, sol.cameras):
        T, gname = scene.graph[f"frustum.{cam.name}"]
        mesh = scene.geometry[gname]
        assert len(mesh.vertices) == 5 and len(mesh.faces) == 6
        v = trimesh.transformations.transform_points(mesh.vertices, back @ T)
        # apex at the camera centre
        apex = [i for i in range(5) if np.allclose(v[i], cam.position, atol=1e-5)]
        assert len(apex) == 1
        base = np.delete(v, apex[0], axis=0)
        # base corners: the image's outer pixel corners at the aim distance
        uv, z = cam.project(base)
        depth = float((np.asarray(rec["aim"]) - cam.position) @ cam.rotation[:, 2])
        np.testing.assert_allclose(z, depth, rtol=1e-5)
        corners = {(-0.5, -0.5), (cam.width - 0.5, -0.5), (cam.width - 0.5, cam.height - 0.5), (-0.5, cam.height - 0.5)}
        got = {tuple(np.round(p, 2)) for p in uv}
        assert got == corners
        # glTF y-up: the camera's world z became y
        np.testing.assert_allclose(trimesh.transformations.transform_points(cam.position[None], Z_UP_TO_Y_UP)[0][1], cam.position[2])


def test_frustum_is_closed_and_outward(run_dir) -> None:
    cam = solution_cameras(run_dir)[0]
    m = frustum_mesh(cam, 2.0)
    assert m.is_watertight and m.volume > 0
    # volume of the pyramid: base area x height / 3
    w = (cam.width / cam.K[0, 0]) * 2.0
    h = (cam.height / cam.K[1, 1]) * 2.0
    assert m.volume == pytest.approx(w * h * 2.0 / 3.0, rel=1e-9)


def test_json_reads_back_as_a_camera_set(run_dir, exported) -> None:
    cams = solution_cameras(run_dir)
    back = CameraSet.load(exported / "cameras.json").by_name()
    doc = json.loads((exported / "cameras.json").read_text())
    for cam, item in zip(cams, doc["cameras"]):
        b = back[cam.name]
        np.testing.assert_allclose(b.position, cam.position, atol=0)
        np.testing.assert_allclose(b.rotation, cam.rotation, atol=0)
        np.testing.assert_allclose(b.K, cam.K, atol=0)
        np.testing.assert_allclose(quaternion_to_rotation(item["qvec"]), cam.rotation.T, atol=1e-12)
        np.testing.assert_allclose(item["tvec"], -cam.rotation.T @ cam.position, atol=1e-12)


def test_csv_columns_and_values(run_dir, exported) -> None:
    cams = solution_cameras(run_dir)
    rows = list(csv.DictReader((exported / "cameras.csv").read_text().splitlines()))
    assert len(rows) == len(cams)
    for cam, r in zip(cams, rows):
        assert r["name"] == cam.name
        np.testing.assert_allclose([float(r[c]) for c in ("x_m", "y_m", "z_m")], cam.position, atol=0)
        np.testing.assert_allclose([[float(r[f"r{i}{j}"]) for j in (1, 2, 3)] for i in (1, 2, 3)], cam.rotation, atol=0)
        R = quaternion_to_rotation([float(r[c]) for c in ("qw", "qx", "qy", "qz")])
        np.testing.assert_allclose(R, cam.rotation.T, atol=1e-12)
        assert float(r["cx_px"]) == cam.K[0, 2] and int(r["width_px"]) == cam.width


def files_in(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*") if p.is_file())


def test_export_verb_camera_formats(cli, run_dir, tmp_path, capsys) -> None:
    out = tmp_path / "x"
    assert cli(["export", str(run_dir), "--format", "colmap,csv", "-o", str(out)]) == 0
    assert files_in(out) == ["cameras.csv", "cameras.txt", "images.txt", "points3D.txt"]
    captured = capsys.readouterr()
    assert "wrote" in captured.out and captured.err == ""
    assert cli(["export", str(run_dir), "--format", "ply", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --format") and "ply" in err
    assert cli(["export", str(tmp_path / "nope"), "--format", "all"]) == 2
    assert "solution.json" in capsys.readouterr().err


def test_export_verb_placement_and_camera_files_in_one_call(cli, run_dir, tmp_path, capsys) -> None:
    out = tmp_path / "both"
    assert cli(["export", str(run_dir), "--format", "json,placement", "--frame", "simulation", "-o", str(out)]) == 0
    assert files_in(out) == ["cameras.json", "placement.simulation.csv", "placement.simulation.json"]
    placed = json.loads((out / "placement.simulation.json").read_text())
    cams = json.loads((out / "cameras.json").read_text())["cameras"]
    assert len(placed["cameras"]) == len(cams) > 0
    for p, c in zip(placed["cameras"], cams, strict=True):  # the same poses in the simulation frame
        np.testing.assert_allclose(p["position_m"], c["position"], atol=1e-12)


@pytest.mark.parametrize("argv, option", [
    (["--format", "json", "--frame", "physical"], "--frame"),
    (["--format", "csv", "--transform", "lab.toml"], "--transform"),
    (["--format", "placement,json", "--phase", "1"], "--phase"),
    (["--frustum-depth", "2"], "--frustum-depth"),  # default format: placement
    (["--format", "glb", "--frustum-depth", "0"], "--frustum-depth"),
])
def test_export_verb_options_that_do_not_apply_are_one_line_errors(cli, run_dir, tmp_path, capsys, argv, option) -> None:
    out = tmp_path / "none"
    assert cli(["export", str(run_dir), *argv, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {option}") and err.count("\n") == 1
    assert not out.exists()  # nothing written


def test_export_cameras_is_a_deprecated_alias(cli, run_dir, tmp_path, capsys) -> None:
    out = tmp_path / "alias"
    assert cli(["export-cameras", str(run_dir), "--format", "colmap,csv", "-o", str(out)]) == 0
    assert files_in(out) == ["cameras.csv", "cameras.txt", "images.txt", "points3D.txt"]
    captured = capsys.readouterr()
    assert "wrote" in captured.out
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning:") and "deprecated" in lines[0] and "camplace export" in lines[0]


def test_parse_formats() -> None:
    assert parse_formats("all") == ("json", "csv", "colmap", "glb")
    assert parse_formats("glb, json") == ("json", "glb")
    assert parse_formats(["csv", "colmap"]) == ("csv", "colmap")
