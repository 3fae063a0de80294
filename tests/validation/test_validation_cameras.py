"""Camera import (Middlebury, COLMAP, OpenCV) checked against the formats' own projection formulas."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camplace.errors import CamplaceError
from camplace.validation.camera_io import import_cameras, read_colmap, read_middlebury, read_opencv_cameras, write_opencv_cameras
from camplace.validation.cameras import CameraSet

TEMPLE = Path("/work/shared/data/photos/templeSparseRing")
if not TEMPLE.exists():  # the shared data sits beside the repository
    TEMPLE = Path(__file__).resolve().parents[3] / "shared" / "data" / "photos" / "templeSparseRing"
BOX_LO = np.array([-0.073568, 0.021728, -0.012445])
BOX_HI = np.array([0.028855, 0.181892, 0.062736])


def box_corners() -> np.ndarray:
    return np.array([[x, y, z] for x in (BOX_LO[0], BOX_HI[0]) for y in (BOX_LO[1], BOX_HI[1]) for z in (BOX_LO[2], BOX_HI[2])])


def random_cameras(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        R = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()  # world-to-camera
        t = np.array([0.1, -0.2, 4.0]) + rng.normal(0, 0.3, 3)
        K = np.array([[800 + 50 * i, 0, 319.7], [0, 810 + 50 * i, 241.2], [0, 0, 1]])
        out.append((f"img{i:02d}.png", K, R, t))
    return out


def write_par(path: Path, cams) -> None:
    lines = [str(len(cams))]
    for name, K, R, t in cams:
        lines.append(" ".join([name] + [repr(float(v)) for v in (*K.ravel(), *R.ravel(), *t)]))
    path.write_text("\n".join(lines) + "\n")


def test_middlebury_projection_matches_K_R_t(tmp_path) -> None:
    cams = random_cameras(4)
    write_par(tmp_path / "x_par.txt", cams)
    got = read_middlebury(tmp_path / "x_par.txt", size="640x480")
    X = np.random.default_rng(1).uniform(-0.5, 0.5, (20, 3))
    for (name, K, R, t), cam in zip(cams, got.cameras):
        x = (K @ (R @ X.T + t[:, None])).T
        uv_ref = x[:, :2] / x[:, 2:]
        uv, depth = cam.project(X)
        np.testing.assert_allclose(uv, uv_ref, atol=1e-7)
        assert cam.name == Path(name).stem and cam.image == name and (cam.width, cam.height) == (640, 480)
        np.testing.assert_allclose(cam.position, -R.T @ t, atol=1e-12)


@pytest.mark.skipif(not TEMPLE.exists(), reason=f"Middlebury templeSparseRing photos not found at {TEMPLE}")
def test_temple_import_projects_box_corners_like_the_raw_file(tmp_path) -> None:
    cams = import_cameras(TEMPLE / "templeSR_par.txt", "middlebury")
    assert len(cams) == 16
    rows = [ln.split() for ln in (TEMPLE / "templeSR_par.txt").read_text().splitlines()[1:] if ln.strip()]
    X = box_corners()
    for row, cam in zip(rows, cams.cameras):
        v = np.array([float(s) for s in row[1:]])
        K, R, t = v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:21]
        P = K @ np.column_stack([R, t])
        x = (P @ np.column_stack([X, np.ones(8)]).T).T
        uv_ref = x[:, :2] / x[:, 2:]
        uv, _ = cam.project(X)
        np.testing.assert_allclose(uv, uv_ref, atol=1e-6)
        assert (cam.width, cam.height) == (640, 480)
    cams.save(tmp_path / "cameras.json")
    back = CameraSet.load(tmp_path / "cameras.json")
    for a, b in zip(cams.cameras, back.cameras):
        np.testing.assert_allclose(a.projection_matrix(), b.projection_matrix(), atol=1e-12)


def _colmap_model(folder: Path, model: str) -> list:
    cams = random_cameras(3, seed=5)
    params = {
        "PINHOLE": lambda K: [K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
        "SIMPLE_PINHOLE": lambda K: [K[0, 0], K[0, 2], K[1, 2]],
        "OPENCV": lambda K: [K[0, 0], K[1, 1], K[0, 2], K[1, 2], -0.05, 0.01, 0.001, -0.0005],
    }[model]
    cam_lines = ["# Camera list", "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    img_lines = ["# Image list with two lines of data per image:"]
    for i, (name, K, R, t) in enumerate(cams, start=1):
        if model == "SIMPLE_PINHOLE":
            K = K.copy()
            K[1, 1] = K[0, 0]
        cam_lines.append(" ".join([str(i), model, "640", "480"] + [repr(float(p)) for p in params(K)]))
        qx, qy, qz, qw = Rotation.from_matrix(R).as_quat()
        img_lines.append(" ".join([str(i), *(repr(float(q)) for q in (qw, qx, qy, qz)), *(repr(float(v)) for v in t), str(i), name]))
        img_lines.append("" if i % 2 else "100.0 200.0 -1 150.5 250.5 7")
    (folder / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
    (folder / "images.txt").write_text("\n".join(img_lines) + "\n")
    return cams


@pytest.mark.parametrize("model", ["PINHOLE", "SIMPLE_PINHOLE", "OPENCV"])
def test_colmap_projection_matches_colmap_convention(tmp_path, model: str) -> None:
    cams = _colmap_model(tmp_path, model)
    got = read_colmap(tmp_path)
    X = np.random.default_rng(2).uniform(-0.5, 0.5, (20, 3))
    for (name, K, R, t), cam in zip(cams, got.cameras):
        if model == "SIMPLE_PINHOLE":
            K = K.copy()
            K[1, 1] = K[0, 0]
        dist = np.array([-0.05, 0.01, 0.001, -0.0005]) if model == "OPENCV" else np.zeros(4)
        ref, _ = cv2.projectPoints(X, cv2.Rodrigues(R)[0], t, K, dist)
        # COLMAP puts the centre of the top-left pixel at (0.5, 0.5), OpenCV at (0, 0)
        uv, _ = cam.project(X)
        np.testing.assert_allclose(uv, ref.reshape(-1, 2) - 0.5, atol=1e-7)
        assert cam.name == Path(name).stem
    assert import_cameras(tmp_path / "images.txt").format == "colmap"


def test_opencv_filestorage_rvec_tvec_and_R_t(tmp_path) -> None:
    cams = random_cameras(3, seed=9)
    path = tmp_path / "calib.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
    dist = np.array([[-0.1, 0.02, 0.0, 0.001, 0.0]])
    for i, (name, K, R, t) in enumerate(cams):
        fs.startWriteStruct("", cv2.FileNode_MAP)
        fs.write("name", Path(name).stem)
        fs.write("image_width", 640)
        fs.write("image_height", 480)
        fs.write("K", K)
        fs.write("dist", dist)
        if i % 2:
            fs.write("R", R)
            fs.write("t", t.reshape(3, 1))
        else:
            fs.write("rvec", cv2.Rodrigues(R)[0])
            fs.write("tvec", t.reshape(3, 1))
        fs.endWriteStruct()
    fs.endWriteStruct()
    fs.release()
    got = read_opencv_cameras(path)
    X = np.random.default_rng(4).uniform(-0.5, 0.5, (20, 3))
    for (name, K, R, t), cam in zip(cams, got.cameras):
        ref, _ = cv2.projectPoints(X, cv2.Rodrigues(R)[0], t, K, dist)
        np.testing.assert_allclose(cam.project(X)[0], ref.reshape(-1, 2), atol=1e-6)
    # our writer round-trips through our reader
    write_opencv_cameras(got, tmp_path / "again.yaml", use_rvec=True)
    again = read_opencv_cameras(tmp_path / "again.yaml")
    for a, b in zip(got.cameras, again.cameras):
        np.testing.assert_allclose(a.project(X)[0], b.project(X)[0], atol=1e-6)


def test_import_errors_are_one_line(tmp_path) -> None:
    (tmp_path / "bad_par.txt").write_text("2\nimg.png 1 2 3\n")
    with pytest.raises(CamplaceError, match="line 1 says 2 cameras"):
        read_middlebury(tmp_path / "bad_par.txt", size="10x10")
    write_par(tmp_path / "ok_par.txt", random_cameras(1))
    with pytest.raises(CamplaceError, match="--size"):
        read_middlebury(tmp_path / "ok_par.txt")
    (tmp_path / "cameras.json").write_text(json.dumps({"cameras": [{"name": "a"}]}))
    with pytest.raises(CamplaceError, match="has no 'position'"):
        CameraSet.load(tmp_path / "cameras.json")
    with pytest.raises(CamplaceError, match="--format"):
        import_cameras(tmp_path / "cameras.bin")
