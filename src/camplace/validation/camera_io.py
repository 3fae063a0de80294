"""Importers of calibrated cameras: Middlebury, COLMAP and OpenCV files -> :class:`~camplace.validation.cameras.CameraSet`.

The conventions are those of :mod:`camplace.validation.cameras` (OpenCV axes, world-from-camera
rotations, pixel centres at integer coordinates).

* Middlebury ``*_par.txt``: a count line, then ``name k11..k33 r11..r33 t1 t2 t3`` per image with
  ``x = K [R | t] X`` (R, t world-to-camera): rotation = R^T, centre = -R^T t.
* COLMAP text model (``cameras.txt`` + ``images.txt``): ``QW QX QY QZ TX TY TZ`` world-to-camera;
  models SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV. COLMAP puts the centre of the
  top-left pixel at (0.5, 0.5); it is shifted by -0.5 to the OpenCV convention.
* OpenCV FileStorage (YAML/XML/JSON, see :func:`read_opencv_cameras` for the layout); also written
  by :func:`write_opencv_cameras`.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Sequence

import numpy as np

from camplace.errors import CamplaceError
from camplace.geometry import quaternion_to_rotation
from camplace.validation.cameras import CameraSet, CameraView, _check_unique, _orthonormal_error

__all__ = [
    "IMPORT_FORMATS",
    "import_cameras",
    "read_middlebury",
    "read_colmap",
    "read_opencv_cameras",
    "write_opencv_cameras",
    "image_size",
]

IMPORT_FORMATS = ("middlebury", "colmap", "opencv")


# --------------------------------------------------------------------------------------------------
# image sizes (without decoding the image when it is a PNG)


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image file: read from the PNG header, else decoded with OpenCV."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
    except OSError as exc:
        raise CamplaceError(f"{path}: cannot read image ({exc.strerror}; check the path)") from None
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        w, h = struct.unpack(">II", head[16:24])
        return int(w), int(h)
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CamplaceError(f"{path}: not an image OpenCV can read")
    return int(img.shape[1]), int(img.shape[0])


def _parse_size(size: str | tuple[int, int] | None) -> tuple[int, int] | None:
    if size is None or isinstance(size, tuple):
        return size
    try:
        w, h = (int(x) for x in str(size).lower().split("x"))
    except ValueError:
        raise CamplaceError(f"--size: expected WIDTHxHEIGHT such as 640x480, got {size!r}") from None
    if w < 1 or h < 1:
        raise CamplaceError(f"--size: width and height must be >= 1, got {size!r}")
    return w, h


# --------------------------------------------------------------------------------------------------
# Middlebury


def read_middlebury(path: str | Path, *, images_dir: str | Path | None = None, size: str | tuple[int, int] | None = None) -> CameraSet:
    """Read a Middlebury multi-view ``*_par.txt`` file.

    Parameters
    ----------
    path : path
        The ``_par.txt`` file: a count line, then per image ``name k11..k33 r11..r33 t1 t2 t3``
        with ``x = K [R | t] X``.
    images_dir : path or None
        Where the images are, to read their size (default: beside ``path``).
    size : "WxH" or (w, h) or None
        Image size to use when the images are not available.

    Returns
    -------
    CameraSet
        Names are the image names without extension; ``image`` keeps the file name.
    """
    path = Path(path)
    fixed = _parse_size(size)
    images = Path(images_dir) if images_dir is not None else path.parent
    try:
        lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]
    except OSError as exc:
        raise CamplaceError(f"{path}: cannot read ({exc.strerror}; check the path)") from None
    if not lines:
        raise CamplaceError(f"{path}: empty file (expected a count line, then one camera per line)")
    try:
        count = int(lines[0].split()[0])
    except ValueError:
        raise CamplaceError(f"{path}: line 1 must be the number of cameras, got {lines[0][:40]!r}") from None
    rows = lines[1:]
    if count != len(rows):
        raise CamplaceError(f"{path}: line 1 says {count} cameras but {len(rows)} camera lines follow (fix the count)")
    cams = []
    for i, ln in enumerate(rows, start=2):
        parts = ln.split()
        if len(parts) != 22:
            raise CamplaceError(f"{path}:{i}: expected 'name k11..k33 r11..r33 t1 t2 t3' (22 fields), got {len(parts)}")
        try:
            vals = np.array([float(x) for x in parts[1:]], dtype=np.float64)
        except ValueError as exc:
            raise CamplaceError(f"{path}:{i}: {exc}") from None
        K, R, t = vals[:9].reshape(3, 3), vals[9:18].reshape(3, 3), vals[18:21]
        R = _check_rotation(R, f"{path}:{i}")
        name = parts[0]
        if fixed is not None:
            w, h = fixed
        elif (images / name).exists():
            w, h = image_size(images / name)
        else:
            raise CamplaceError(f"{path}:{i}: image {name} not found in {images} to read its size (pass --size WIDTHxHEIGHT or --images DIR)")
        cams.append(CameraView(Path(name).stem, -R.T @ t, R.T, K, w, h, image=name))
    _check_unique(cams, str(path))
    return CameraSet(tuple(cams), "middlebury", str(path))


def _check_rotation(R: np.ndarray, where: str) -> np.ndarray:
    err = _orthonormal_error(R)
    if err > 1e-4:
        raise CamplaceError(f"{where}: the rotation is not orthonormal (max |R^T R - I| = {err:.2g})")
    if np.linalg.det(R) < 0:
        raise CamplaceError(f"{where}: the rotation has determinant -1 (a reflection); use a right-handed calibration")
    # snap to the nearest rotation (polar decomposition) so downstream checks pass at 1e-12
    u, _, vt = np.linalg.svd(R)
    return u @ vt


# --------------------------------------------------------------------------------------------------
# COLMAP


_COLMAP_MODELS = {
    # model: (number of params, function params -> (fx, fy, cx, cy, dist))
    "SIMPLE_PINHOLE": (3, lambda p: (p[0], p[0], p[1], p[2], [])),
    "PINHOLE": (4, lambda p: (p[0], p[1], p[2], p[3], [])),
    "SIMPLE_RADIAL": (4, lambda p: (p[0], p[0], p[1], p[2], [p[3]])),
    "RADIAL": (5, lambda p: (p[0], p[0], p[1], p[2], [p[3], p[4]])),
    "OPENCV": (8, lambda p: (p[0], p[1], p[2], p[3], [p[4], p[5], p[6], p[7]])),
}


def _colmap_lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text()
    except OSError as exc:
        raise CamplaceError(f"{path}: cannot read ({exc.strerror}; check the path)") from None
    return [(i, ln) for i, ln in enumerate(text.splitlines(), start=1) if not ln.lstrip().startswith("#")]


def read_colmap(path: str | Path) -> CameraSet:
    """Read a COLMAP text model.

    Parameters
    ----------
    path : path
        The model folder (holding ``cameras.txt`` and ``images.txt``) or its ``images.txt``.

    Returns
    -------
    CameraSet
        One camera per registered image, named by the image name without extension.
    """
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    cam_file, img_file = folder / "cameras.txt", folder / "images.txt"
    intr: dict[int, tuple[np.ndarray, int, int, list[float]]] = {}
    for i, ln in _colmap_lines(cam_file):
        parts = ln.split()
        if not parts:
            continue
        if len(parts) < 4:
            raise CamplaceError(f"{cam_file}:{i}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'")
        model = parts[1].upper()
        if model not in _COLMAP_MODELS:
            raise CamplaceError(f"{cam_file}:{i}: camera model {parts[1]} is not supported (use one of {', '.join(_COLMAP_MODELS)})")
        nparam, conv = _COLMAP_MODELS[model]
        try:
            cid, w, h = int(parts[0]), int(parts[2]), int(parts[3])
            params = [float(x) for x in parts[4:]]
        except ValueError as exc:
            raise CamplaceError(f"{cam_file}:{i}: {exc}") from None
        if len(params) != nparam:
            raise CamplaceError(f"{cam_file}:{i}: model {model} needs {nparam} parameters, got {len(params)}")
        fx, fy, cx, cy, dist = conv(params)
        # COLMAP: centre of the top-left pixel at (0.5, 0.5); OpenCV: at (0, 0)
        K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
        intr[cid] = (K, w, h, list(dist))
    if not intr:
        raise CamplaceError(f"{cam_file}: no cameras")
    cams = []
    lines = [(i, ln) for i, ln in _colmap_lines(img_file)]
    # images.txt: two lines per image; the second (2D points) may be empty, so walk pairs of raw lines
    k = 0
    while k < len(lines):
        i, ln = lines[k]
        parts = ln.split()
        if not parts:
            k += 1
            continue
        if len(parts) < 10:
            raise CamplaceError(f"{img_file}:{i}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        try:
            q = [float(x) for x in parts[1:5]]
            t = np.array([float(x) for x in parts[5:8]])
            cid = int(parts[8])
        except ValueError as exc:
            raise CamplaceError(f"{img_file}:{i}: {exc}") from None
        name = " ".join(parts[9:])
        if cid not in intr:
            raise CamplaceError(f"{img_file}:{i}: CAMERA_ID {cid} is not in {cam_file.name}")
        K, w, h, dist = intr[cid]
        R = quaternion_to_rotation(q)
        cams.append(CameraView(Path(name).stem, -R.T @ t, R.T, K, w, h, dist, image=name))
        k += 2  # skip the POINTS2D line
    if not cams:
        raise CamplaceError(f"{img_file}: no images")
    _check_unique(cams, str(img_file))
    return CameraSet(tuple(cams), "colmap", str(img_file))


# --------------------------------------------------------------------------------------------------
# OpenCV FileStorage


def read_opencv_cameras(path: str | Path) -> CameraSet:
    """Read cameras from an OpenCV FileStorage file (YAML, XML or JSON).

    Layout (``cameras`` is a sequence of maps; R, t, rvec, tvec are world-to-camera, as
    ``cv2.calibrateCamera`` / ``cv2.solvePnP`` give them, so ``x ~ K (R X + t)``)::

        %YAML:1.0
        ---
        cameras:
          - name: "cam0"
            image: "cam0.png"          # optional
            image_width: 640
            image_height: 480
            K: !!opencv-matrix {rows: 3, cols: 3, dt: d, data: [...]}
            dist: !!opencv-matrix ...  # optional, 1 x 4 or 1 x 5 (k1, k2, p1, p2[, k3])
            R: !!opencv-matrix ...     # 3 x 3, or rvec: 3 x 1 (Rodrigues)
            t: !!opencv-matrix ...     # 3 x 1 (or tvec)

    Returns
    -------
    CameraSet
    """
    import cv2

    path = Path(path)
    if not path.exists():
        raise CamplaceError(f"{path}: no such file (check the path)")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise CamplaceError(f"{path}: OpenCV cannot parse it ({str(exc).strip().splitlines()[-1]})") from None
    if not fs.isOpened():
        raise CamplaceError(f"{path}: OpenCV cannot open it as a FileStorage file (YAML/XML/JSON)")
    try:
        node = fs.getNode("cameras")
        if node.empty() or not node.isSeq() or node.size() == 0:
            raise CamplaceError(f"{path}: needs a non-empty 'cameras' sequence (see 'camplace import-cameras --help')")
        cams = []
        for i in range(node.size()):
            c = node.at(i)
            where = f"{path}: cameras[{i}]"

            def mat(key: str, shape: tuple[int, ...] | None = None, *, required: bool = True):
                n = c.getNode(key)
                if n.empty():
                    if required:
                        raise CamplaceError(f"{where}: missing {key!r}")
                    return None
                m = n.mat()
                if m is None:
                    raise CamplaceError(f"{where}: {key!r} must be an !!opencv-matrix")
                m = np.asarray(m, dtype=np.float64)
                if shape is not None and m.size != int(np.prod(shape)):
                    raise CamplaceError(f"{where}: {key!r} must have {int(np.prod(shape))} entries, got {m.size}")
                return m if shape is None else m.reshape(shape)

            name_node = c.getNode("name")
            name = name_node.string() if not name_node.empty() else f"camera_{i + 1}"
            image_node = c.getNode("image")
            image = image_node.string() if not image_node.empty() else ""
            wn, hn = c.getNode("image_width"), c.getNode("image_height")
            if wn.empty() or hn.empty():
                raise CamplaceError(f"{where}: missing image_width/image_height")
            K = mat("K", (3, 3))
            dist = mat("dist", None, required=False)
            if c.getNode("R").empty():
                rvec = mat("rvec", (3,), required=False)
                if rvec is None:
                    raise CamplaceError(f"{where}: give R (3x3) or rvec (3x1)")
                R = cv2.Rodrigues(rvec.reshape(3, 1))[0]
            else:
                R = _check_rotation(mat("R", (3, 3)), where)
            t = mat("t", (3,), required=False)
            if t is None:
                t = mat("tvec", (3,), required=False)
            if t is None:
                raise CamplaceError(f"{where}: give t (3x1) or tvec (3x1)")
            cams.append(
                CameraView(name, -R.T @ t, R.T, K, int(wn.real()), int(hn.real()), [] if dist is None else dist.ravel(), image=image)
            )
    finally:
        fs.release()
    _check_unique(cams, str(path))
    return CameraSet(tuple(cams), "opencv", str(path))


def write_opencv_cameras(cameras: CameraSet | Sequence[CameraView], path: str | Path, *, use_rvec: bool = False) -> None:
    """Write cameras in the layout :func:`read_opencv_cameras` reads (atomically).

    Parameters
    ----------
    cameras : CameraSet or sequence of CameraView
    path : path
        ``.yml``/``.yaml``, ``.xml`` or ``.json``.
    use_rvec : bool
        Write ``rvec``/``tvec`` instead of ``R``/``t``.
    """
    import cv2

    from camplace._io import atomic_path

    with atomic_path(path) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        fs.startWriteStruct("cameras", cv2.FileNode_SEQ)
        for cam in cameras:
            Rwc, t = cam.world_to_camera()
            fs.startWriteStruct("", cv2.FileNode_MAP)
            fs.write("name", cam.name)
            if cam.image:
                fs.write("image", cam.image)
            fs.write("image_width", int(cam.width))
            fs.write("image_height", int(cam.height))
            fs.write("K", cam.K)
            if cam.has_distortion:
                fs.write("dist", cam.dist.reshape(1, 5))
            if use_rvec:
                fs.write("rvec", cv2.Rodrigues(Rwc)[0])
                fs.write("tvec", t.reshape(3, 1))
            else:
                fs.write("R", Rwc)
                fs.write("t", t.reshape(3, 1))
            fs.endWriteStruct()
        fs.endWriteStruct()
        fs.release()


def import_cameras(path: str | Path, fmt: str = "auto", *, images_dir: str | Path | None = None, size: str | None = None) -> CameraSet:
    """Read cameras from a Middlebury, COLMAP or OpenCV calibration.

    Parameters
    ----------
    path : path
        The calibration file (COLMAP: the model folder or its images.txt).
    fmt : {"auto", "middlebury", "colmap", "opencv"}
        "auto" guesses from the name: a folder or ``images.txt``/``cameras.txt`` is COLMAP,
        ``.yml``/``.yaml``/``.xml``/``.json`` is OpenCV, other ``.txt`` is Middlebury.
    images_dir, size :
        Middlebury only: where the images are (to read their size) or an explicit "WxH".
    """
    path = Path(path)
    if fmt == "auto":
        if path.is_dir() or path.name in ("images.txt", "cameras.txt"):
            fmt = "colmap"
        elif path.suffix.lower() in (".yml", ".yaml", ".xml", ".json"):
            fmt = "opencv"
        elif path.suffix.lower() == ".txt":
            fmt = "middlebury"
        else:
            raise CamplaceError(f"{path}: cannot tell the format from the name (pass --format {'|'.join(IMPORT_FORMATS)})")
    if fmt == "middlebury":
        return read_middlebury(path, images_dir=images_dir, size=size)
    if fmt == "colmap":
        return read_colmap(path)
    if fmt == "opencv":
        return read_opencv_cameras(path)
    raise CamplaceError(f"--format: unknown format {fmt!r} (use one of {', '.join(IMPORT_FORMATS)})")
