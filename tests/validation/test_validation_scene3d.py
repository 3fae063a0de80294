"""scene3d.html of ``camplace validate``: coverage counts against analytic cases, and the Middlebury
templeSparseRing calibration drawn in a real headless Chromium (16 frusta around the box)."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import camplace.cli
from camplace.validation.cameras import CameraView
from camplace.validation.camera_scene import cameras_scene, seen_counts
from camplace.validation.workflow import box_mesh
from tests._chromium import distinct_colours, external_requests, open_in_chromium, pixels_near, png_colours, without_legend

TEMPLE = Path("/work/shared/data/photos/templeSparseRing")
if not TEMPLE.exists():
    TEMPLE = Path(__file__).resolve().parents[3] / "shared" / "data" / "photos" / "templeSparseRing"
BOX = "box:-0.073568,0.021728,-0.012445,0.028855,0.181892,0.062736"


def look_at(name: str, position, target=(0.0, 0.0, 0.0), f_px: float = 200.0, size: int = 400) -> CameraView:
    """A camera at ``position`` whose optical axis passes through ``target`` (OpenCV axes, world z up)."""
    c = np.asarray(position, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - c
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    K = np.array([[f_px, 0.0, size / 2], [0.0, f_px, size / 2], [0.0, 0.0, 1.0]])
    return CameraView(name, c, np.column_stack([x, y, z]), K, size, size)


def cube_faces_points(n_per_face: int = 30, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points inside each face of the cube [-0.5, 0.5]^3 (away from its edges) and their outward normals."""
    rng = np.random.default_rng(seed)
    pts, nrm = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            p = rng.uniform(-0.45, 0.45, size=(n_per_face, 3))
            p[:, axis] = 0.5 * sign
            n = np.zeros((n_per_face, 3))
            n[:, axis] = sign
            pts.append(p)
            nrm.append(n)
    return np.vstack(pts), np.vstack(nrm)


def test_seen_counts_of_a_cube_analytic() -> None:
    """Six cameras on the axes see one face each; a diagonal camera sees two; a wall hides a face; a narrow one sees little."""
    cube = box_mesh([-0.5] * 3, [0.5] * 3)
    pts, nrm = cube_faces_points()
    axes = [look_at(f"a{i}", 6.0 * s * np.eye(3)[i]) for i in range(3) for s in (-1.0, 1.0)]
    assert np.array_equal(seen_counts(axes, pts, nrm, [cube]), np.ones(len(pts), dtype=np.int64))
    diag = look_at("d", (6.0, 6.0, 0.0))
    got = seen_counts([*axes, diag], pts, nrm, [cube])
    faces_seen_twice = (nrm[:, 0] > 0) | (nrm[:, 1] > 0)
    assert np.array_equal(got, np.where(faces_seen_twice, 2, 1))
    # a wall between the +x camera and the cube hides the +x face from it
    wall = box_mesh([2.0, -3.0, -3.0], [2.1, 3.0, 3.0])
    got = seen_counts(axes, pts, nrm, [cube, wall])
    assert np.array_equal(got, np.where(nrm[:, 0] > 0, 0, 1))
    # a camera with a long focal length on +x sees only the middle of the +x face: its image x is
    # world y and its image y is world -z, pixels u = 200 + f y / 5.5 in [-0.5, 399.5)
    f = 4000.0
    tele = look_at("t", (6.0, 0.0, 0.0), f_px=f)
    u, v = 200.0 + f * pts[:, 1] / 5.5, 200.0 - f * pts[:, 2] / 5.5
    inside = (nrm[:, 0] > 0) & (u >= -0.5) & (u < 399.5) & (v >= -0.5) & (v < 399.5)
    assert 0 < inside.sum() < np.sum(nrm[:, 0] > 0)
    assert np.array_equal(seen_counts([tele], pts, nrm, [cube]), inside.astype(np.int64))
    # emitter points (zero normal) skip the facing test but not the occlusion test
    em = np.array([[1.5, 0.0, 0.0], [-1.5, 0.0, 0.0]])
    assert seen_counts([axes[1]], em, np.zeros((2, 3)), [cube]).tolist() == [1, 0]  # axes[1] stands on +x


def test_cameras_scene_draws_every_camera_and_its_coverage() -> None:
    cube = box_mesh([-0.5] * 3, [0.5] * 3)
    cams = [look_at(f"cam{i}", (5 * np.cos(a), 5 * np.sin(a), 1.0)) for i, a in enumerate(np.linspace(0, 2 * np.pi, 5)[:4])]
    sc = cameras_scene(cams, cube, title="ring", n_points=600, seed=2)
    assert [c.label for c in sc.cameras] == ["cam0", "cam1", "cam2", "cam3"]
    assert len(sc.points) == 600 and sc.counts.max() <= 4
    # the bottom face (z = -0.5, normal -z) is seen by no camera above it
    bottom = np.isclose(sc.points[:, 2], -0.5)
    assert bottom.any() and np.all(sc.counts[bottom] == 0)
    for c in sc.cameras:  # frusta reach the far side of the cube
        far = (cube[0] - c.position) @ c.rotation[:, 2]
        assert c.depth_m >= far.max()


def scene_json(page: Path) -> dict:
    m = re.search(r"<script type='application/json' id='scene3d-data'>(.*?)</script>", page.read_text(), re.S)
    assert m is not None
    return json.loads(m.group(1))


@pytest.mark.skipif(not TEMPLE.exists(), reason=f"Middlebury templeSparseRing photos not found at {TEMPLE} (shared data not present)")
def test_temple_calibration_in_3d(monkeypatch, tmp_path, capsys) -> None:
    monkeypatch.setattr(camplace.cli, "VERB_MODULES", ("camplace.validation.cli",))
    cams = tmp_path / "cameras.json"
    assert camplace.cli.main(["import-cameras", str(TEMPLE / "templeSR_par.txt"), "--format", "middlebury", "-o", str(cams)]) == 0
    out = tmp_path / "val"
    assert camplace.cli.main(["validate", "--cameras", str(cams), "--target", BOX, "--photos", str(TEMPLE), "-o", str(out)]) == 0
    page = out / "scene3d.html"
    assert f"wrote {out / 'validation.json'}, {page} (3D view)" in capsys.readouterr().out
    d = scene_json(page)
    assert d["n_cameras"] == 16 and d["kind"] == "validation" and d["mode"] == "cameras"
    assert len(d["photographed"]) == 16
    # oracle: each camera's centre is where its Middlebury line puts it, C = -R^T t
    rows = [ln.split() for ln in (TEMPLE / "templeSR_par.txt").read_text().splitlines()[1:] if ln.strip()]
    assert len(rows) == 16
    by_name = {c["label"]: c for c in d["cameras"]}
    for r in rows:
        R = np.array(r[10:19], dtype=float).reshape(3, 3)
        t = np.array(r[19:22], dtype=float)
        assert by_name[Path(r[0]).stem]["position"] == pytest.approx(-R.T @ t, abs=1e-5)
    # the ring sees the box's sides: most of its surface by 3 or more cameras
    assert d["coverage"]["n_points"] == 4000 and d["coverage"]["weight_share"][3] > 0.5
    shot = tmp_path / "scene.png"
    res = open_in_chromium(page, tmp_path / "page.png", scene_id="scene3d", scene_screenshot=shot)
    assert res["errors"] == [] and external_requests(page, res["requests"]) == []
    sc = res["scene"]
    assert sc["ready"] and any(c["webgl"] for c in sc["canvases"]) and sc["data"] == d
    frusta = [t for t in sc["traces"] if t["mode"] == "lines" and (t["group"] or "").startswith("camera")]
    assert len(frusta) == 16
    _, rgb = png_colours(shot.read_bytes())
    assert distinct_colours(rgb) > 300 and pixels_near(without_legend(rgb, sc), d["coverage"]["colours"][3]) > 20
    keep = os.environ.get("CAMPLACE_VALIDATE_SCREENSHOT")
    if keep:
        shutil.copy(shot, keep)
