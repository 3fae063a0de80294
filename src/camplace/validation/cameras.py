"""Calibrated cameras for validation: one :class:`CameraView` per photograph, a :class:`CameraSet` per file.

One convention everywhere (the project's): OpenCV axes (x right, y down, z forward), rotations are
world-from-camera (``world = R @ cam + C``), so a world point X projects as ``x ~ K R^T (X - C)``.
Pixel centres are at integer coordinates (OpenCV), so the top-left pixel covers [-0.5, 0.5)^2.

``cameras.json`` (written by ``camplace import-cameras`` and read by ``camplace validate --cameras``)::

    {"format": "middlebury", "source": "templeSR_par.txt",
     "cameras": [{"name": "templeSR0001", "image": "templeSR0001.png",
                  "position": [x, y, z], "rotation": [[...], [...], [...]],
                  "K": [[fx, s, cx], [0, fy, cy], [0, 0, 1]], "width": 640, "height": 480,
                  "dist": [k1, k2, p1, p2, k3]}, ...]}

``image``, ``dist`` and ``model`` are optional (``dist`` defaults to no distortion, OpenCV coefficient
order; ``model`` names a team's camera model, ``[[cameras]]`` of the instance).
The importers of calibration files (Middlebury, COLMAP, OpenCV) are in :mod:`camplace.validation.camera_io`.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from camplace._io import write_json_atomic
from camplace.errors import CamplaceError

log = logging.getLogger(__name__)

__all__ = ["CameraView", "CameraSet", "camera_stem", "distort_normalized", "undistort_normalized"]


def _orthonormal_error(R: np.ndarray) -> float:
    return float(np.abs(R.T @ R - np.eye(3)).max())


@dataclass(frozen=True, eq=False)
class CameraView:
    """One calibrated pinhole camera (optionally with OpenCV lens distortion).

    Attributes
    ----------
    name : str
        Unique name; photographs are matched to cameras by it.
    position : (3,) float64
        Camera centre C, world metres.
    rotation : (3, 3) float64
        World-from-camera rotation (columns: camera x right, y down, z forward in world axes).
    K : (3, 3) float64
        Intrinsic matrix (OpenCV pixel convention).
    width, height : int
        Image size, pixels.
    dist : (5,) float64
        OpenCV distortion coefficients k1, k2, p1, p2, k3 (zeros: ideal pinhole).
    image : str
        File name of the photograph this camera took, when known (else "").
    model : str
        The camera model of a team's camera (``[[cameras]]`` name; "" when there is no team).
    """

    name: str
    position: np.ndarray
    rotation: np.ndarray
    K: np.ndarray
    width: int
    height: int
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    image: str = ""
    model: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", np.asarray(self.position, dtype=np.float64).reshape(3))
        object.__setattr__(self, "rotation", np.asarray(self.rotation, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))
        d = np.zeros(5)
        raw = np.asarray(self.dist, dtype=np.float64).ravel()
        if raw.size > 5:
            raise CamplaceError(f"camera {self.name!r}: dist has {raw.size} coefficients, at most 5 (k1, k2, p1, p2, k3)")
        d[: raw.size] = raw
        object.__setattr__(self, "dist", d)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def has_distortion(self) -> bool:
        """True when any distortion coefficient is non-zero."""
        return bool(np.any(self.dist != 0.0))

    def world_to_camera(self) -> tuple[np.ndarray, np.ndarray]:
        """OpenCV extrinsics: ``R_wc = rotation^T`` (3, 3) and ``t = -R_wc @ position`` (3,)."""
        Rwc = self.rotation.T
        return Rwc, -Rwc @ self.position

    def projection_matrix(self) -> np.ndarray:
        """(3, 4) float64 ``P = K [R_wc | t]``."""
        Rwc, t = self.world_to_camera()
        return self.K @ np.column_stack([Rwc, t])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points to pixels (with distortion when set).

        Parameters
        ----------
        points : (n, 3) float64

        Returns
        -------
        uv : (n, 2) float64
            Pixel coordinates (NaN for points not in front of the camera).
        depth : (n,) float64
            Camera-frame z of each point, metres.
        """
        pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
        cam = (pts - self.position) @ self.rotation
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = cam[:, :2] / z[:, None]
        if self.has_distortion:
            xn = distort_normalized(xn, self.dist)
        uv = xn @ self.K[:2, :2].T + self.K[:2, 2]
        uv[z <= 0] = np.nan
        return uv, z

    def with_pose(self, position: np.ndarray, rotation: np.ndarray, name: str | None = None) -> "CameraView":
        """A copy at another pose (same intrinsics)."""
        return CameraView(name or self.name, position, rotation, self.K, self.width, self.height, self.dist, self.image, self.model)

    def with_dist(self, dist: Sequence[float]) -> "CameraView":
        """A copy with other distortion coefficients."""
        return CameraView(self.name, self.position, self.rotation, self.K, self.width, self.height, dist, self.image, self.model)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (see the module docstring)."""
        out: dict[str, Any] = {
            "name": self.name,
            "position": [float(x) for x in self.position],
            "rotation": [[float(x) for x in row] for row in self.rotation],
            "K": [[float(x) for x in row] for row in self.K],
            "width": self.width,
            "height": self.height,
        }
        if self.has_distortion:
            out["dist"] = [float(x) for x in self.dist]
        if self.image:
            out["image"] = self.image
        if self.model:
            out["model"] = self.model
        return out

    @classmethod
    def from_dict(cls, rec: Any, where: str = "cameras.json") -> "CameraView":
        """Parse one record; errors name ``where`` and the field."""
        if not isinstance(rec, dict):
            raise CamplaceError(f"{where}: each camera must be an object with name, position, rotation, K, width, height")
        for key in ("name", "position", "rotation", "K", "width", "height"):
            if key not in rec:
                raise CamplaceError(f"{where}: camera {rec.get('name', '?')!r} has no {key!r} (add it)")
        name = str(rec["name"])
        try:
            pos = np.asarray(rec["position"], dtype=np.float64).reshape(3)
            R = np.asarray(rec["rotation"], dtype=np.float64).reshape(3, 3)
            K = np.asarray(rec["K"], dtype=np.float64).reshape(3, 3)
            dist = np.asarray(rec.get("dist", []), dtype=np.float64).ravel()
            width, height = int(rec["width"]), int(rec["height"])
        except (TypeError, ValueError) as exc:
            raise CamplaceError(f"{where}: camera {name!r}: position (3), rotation (3x3), K (3x3), width, height must be numbers ({exc})") from None
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(R)) and np.all(np.isfinite(K))):
            raise CamplaceError(f"{where}: camera {name!r} has NaN or infinite values")
        if _orthonormal_error(R) > 1e-5 or np.linalg.det(R) < 0:
            raise CamplaceError(f"{where}: camera {name!r}: rotation is not a proper rotation matrix (world-from-camera, det +1)")
        if width < 1 or height < 1:
            raise CamplaceError(f"{where}: camera {name!r}: width and height must be >= 1")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CamplaceError(f"{where}: camera {name!r}: K must have positive focal lengths K[0][0], K[1][1]")
        return cls(name, pos, R, K, width, height, dist, str(rec.get("image", "")), str(rec.get("model", "")))

    def rays(self, rows: slice | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per-pixel viewing rays (pixel (u, v) -> direction ``R K^-1 [u, v, 1]``, undistorted when set).

        Parameters
        ----------
        rows : slice or None
            Image rows to make rays for (default: all).

        Returns
        -------
        origin : (3,) float64
            The camera centre (shared by every ray).
        directions : (h, width, 3) float64
            World directions scaled so that their camera-frame z is 1: a hit at ray parameter t
            lies at depth t.
        """
        r = rows if rows is not None else slice(0, self.height)
        v = np.arange(self.height, dtype=np.float64)[r]
        u = np.arange(self.width, dtype=np.float64)
        uu, vv = np.meshgrid(u, v)
        Kinv = np.linalg.inv(self.K)
        xn = uu * Kinv[0, 0] + vv * Kinv[0, 1] + Kinv[0, 2]
        yn = vv * Kinv[1, 1] + Kinv[1, 2]
        if self.has_distortion:
            und = undistort_normalized(np.stack([xn.ravel(), yn.ravel()], axis=1), self.dist)
            xn = und[:, 0].reshape(xn.shape)
            yn = und[:, 1].reshape(yn.shape)
        d_cam = np.stack([xn, yn, np.ones_like(xn)], axis=-1)
        return self.position.copy(), d_cam @ self.rotation.T


def distort_normalized(xn: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV distortion of normalised image coordinates.

    Parameters
    ----------
    xn : (n, 2) float64
        Ideal normalised coordinates (x/z, y/z).
    dist : (5,) float64
        k1, k2, p1, p2, k3.

    Returns
    -------
    (n, 2) float64
    """
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    x, y = xn[:, 0], xn[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def undistort_normalized(xd: np.ndarray, dist: np.ndarray, iterations: int = 30) -> np.ndarray:
    """Invert :func:`distort_normalized` by Newton iterations with the analytic Jacobian.

    Parameters
    ----------
    xd : (n, 2) float64
        Distorted normalised coordinates.
    dist : (5,) float64

    Returns
    -------
    (n, 2) float64
        Ideal normalised coordinates x with ``distort(x) = xd`` (to ~1e-12 where the model is invertible).
    """
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    x = xd.copy()
    for _ in range(iterations):
        xx, yy = x[:, 0], x[:, 1]
        r2 = xx * xx + yy * yy
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r2
        f = distort_normalized(x, dist) - xd
        # Jacobian of the distortion map
        j11 = radial + 2 * xx * xx * dradial + 2 * p1 * yy + 6 * p2 * xx
        j12 = 2 * xx * yy * dradial + 2 * p1 * xx + 2 * p2 * yy
        j21 = 2 * xx * yy * dradial + 2 * p1 * xx + 2 * p2 * yy
        j22 = radial + 2 * yy * yy * dradial + 6 * p1 * yy + 2 * p2 * xx
        det = j11 * j22 - j12 * j21
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        dx = (j22 * f[:, 0] - j12 * f[:, 1]) / det
        dy = (-j21 * f[:, 0] + j11 * f[:, 1]) / det
        x = x - np.stack([dx, dy], axis=1)
        if np.nanmax(np.abs(f), initial=0.0) < 1e-14:
            break
    return x


@dataclass(frozen=True, eq=False)
class CameraSet:
    """The cameras of one ``cameras.json``.

    Attributes
    ----------
    cameras : tuple of CameraView
    format : str
        Where they came from: "middlebury", "colmap", "opencv", "solution" or "json".
    source : str
        The file they were read from.
    """

    cameras: tuple[CameraView, ...]
    format: str = "json"
    source: str = ""

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self):
        return iter(self.cameras)

    def by_name(self) -> dict[str, CameraView]:
        """Cameras keyed by name."""
        return {c.name: c for c in self.cameras}

    def to_dict(self) -> dict[str, Any]:
        return {"format": self.format, "source": self.source, "cameras": [c.to_dict() for c in self.cameras]}

    def save(self, path: str | Path) -> None:
        """Write ``cameras.json`` atomically."""
        write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "CameraSet":
        """Read a ``cameras.json``."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except OSError as exc:
            raise CamplaceError(f"{path}: cannot read cameras file ({exc.strerror}; check the path)") from None
        except json.JSONDecodeError as exc:
            raise CamplaceError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}); write it with 'camplace import-cameras'") from None
        if not isinstance(data, dict) or not isinstance(data.get("cameras"), list) or not data["cameras"]:
            raise CamplaceError(f"{path}: needs a non-empty \"cameras\" list (write it with 'camplace import-cameras')")
        cams = tuple(CameraView.from_dict(rec, str(path)) for rec in data["cameras"])
        _check_unique(cams, str(path))
        return cls(cams, str(data.get("format", "json")), str(data.get("source", path)))

    @classmethod
    def from_solution(cls, solution, *, experiment: str = "", system: int = 1) -> "CameraSet":
        """The chosen cameras of a :class:`camplace.solution.Solution`, named ``e{experiment}.{system}.camera_{n}``.

        Parameters
        ----------
        solution : camplace.solution.Solution
        experiment : str
            Experiment name (default: the solution's instance name).
        system : int
            System number (1-based, as in the thesis).
        """
        exp = experiment or solution.instance or "camplace"
        cams = []
        for n, rec in enumerate(solution.cameras, start=1):
            cams.append(
                CameraView(
                    camera_stem(exp, system, n),
                    rec["position"],
                    rec["rotation"],
                    rec["K"],
                    int(rec["width"]),
                    int(rec["height"]),
                    model=str(rec.get("model", "")),
                )
            )
        return cls(tuple(cams), "solution", "solution.json")


def camera_stem(experiment: str, system: int, camera: int) -> str:
    """The thesis's image name convention ``e{experiment}.{system}.camera_{n}`` (no extension)."""
    return f"e{experiment}.{system}.camera_{camera}"


def _check_unique(cams: Iterable[CameraView], where: str) -> None:
    seen: set[str] = set()
    for c in cams:
        if c.name in seen:
            raise CamplaceError(f"{where}: camera name {c.name!r} appears twice (names must be unique)")
        seen.add(c.name)
