"""Simulation -> physical (lab) coordinates for placing the cameras (the thesis's Algorithm 1).

Two methods, configured by a :class:`TransformConfig` (an instance's ``[transform]`` table or a
TOML/JSON file):

``method = "scale"`` (Algorithm 1)
    Per-axis scale about a reference point::

        S = (phys_extent_m / sim_extent_m) * sim_scale          (per axis)
        x = reference_m + (X - sim_reference_m) * S

    Quirks of the thesis's version, and what is done here:

    * it writes ``S_x = (V_X / V_x) x s_X`` with ``V_XYZ`` the *simulation* and ``V_xyz`` the
      *physical* constraints, i.e. simulation / physical. Multiplying simulation coordinates by that
      shrinks a large simulated room onto a small lab the wrong way round; the ratio that maps the
      simulated extent onto the physical one is physical / simulation, used here;
    * it is 2-D (x, y only); here z is scaled the same way;
    * ``x = x_r + X S`` silently assumes the reference point is the simulation's origin; here its
      simulation coordinates ``sim_reference_m`` are explicit (default the origin: the thesis's formula);
    * it transforms positions only. A non-uniform scale also changes directions: a camera keeps
      looking at the image of its aim point when its forward axis is mapped by diag(S) (forward' =
      S * forward, normalised) and its "down" axis is re-orthogonalised against it (no roll added).

``method = "similarity"``
    ``x = s R X + t`` estimated from at least three non-collinear reference point pairs
    (``pairs = [{sim_m = [...], phys_m = [...]}, ...]``) by Umeyama's least-squares method
    (with scale unless ``with_scale = false``); rotations map as ``R_phys = R @ R_cam``.

``method = "identity"``
    No change (``camplace export --frame simulation``).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace._io import write_json_atomic, write_text_atomic
from camplace.errors import CamplaceError
from camplace.geometry import euler_xyz_deg
from camplace.instance.lab import TRANSFORM_METHODS, TransformConfig, parse_transform

__all__ = [
    "TRANSFORM_METHODS",
    "TransformConfig",
    "PlacementTransform",
    "parse_transform",
    "umeyama",
    "build_transform",
    "euler_xyz_deg",
    "placement_rows",
    "write_placement",
]

def umeyama(src: np.ndarray, dst: np.ndarray, *, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama 1991).

    Parameters
    ----------
    src, dst : (n, 3) float64
        Corresponding points, n >= 3, not collinear.
    with_scale : bool
        False forces s = 1.

    Returns
    -------
    s : float
    R : (3, 3) float64
        A proper rotation (det +1).
    t : (3,) float64
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise CamplaceError("umeyama: need two (n, 3) arrays of the same shape with n >= 3")
    n = len(src)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float((xs**2).sum() / n)
    cov = xd.T @ xs / n
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


@dataclass(frozen=True, eq=False)
class PlacementTransform:
    """An affine map ``x = A X + b`` from simulation to physical coordinates.

    Attributes
    ----------
    A : (3, 3) float64
    b : (3,) float64
    config : TransformConfig
    scale : float or None
        Similarity scale s (None for the per-axis method).
    rotation : (3, 3) float64 or None
        Similarity rotation R.
    rms_residual_m : float or None
        RMS distance between mapped simulation reference points and their physical partners.
    """

    A: np.ndarray
    b: np.ndarray
    config: TransformConfig
    scale: float | None = None
    rotation: np.ndarray | None = None
    rms_residual_m: float | None = None

    def apply_points(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) simulation points -> (n, 3) physical points."""
        return np.atleast_2d(np.asarray(points, dtype=np.float64)) @ self.A.T + self.b

    def apply_rotations(self, rotations: np.ndarray) -> np.ndarray:
        """World-from-camera rotations (n, 3, 3) mapped so each camera keeps looking along the image of its axis."""
        R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
        fwd = R[:, :, 2] @ self.A.T
        fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
        down = R[:, :, 1] @ self.A.T
        down -= np.einsum("ij,ij->i", down, fwd)[:, None] * fwd
        down /= np.linalg.norm(down, axis=1, keepdims=True)
        right = np.cross(down, fwd)
        return np.stack([right, down, fwd], axis=2)

    def to_dict(self) -> dict[str, Any]:
        return {
            "config": self.config.to_dict(),
            "A": self.A.tolist(),
            "b": self.b.tolist(),
            "scale": self.scale,
            "rotation": None if self.rotation is None else self.rotation.tolist(),
            "rms_residual_m": self.rms_residual_m,
        }


def build_transform(config: TransformConfig) -> PlacementTransform:
    """The affine map of a :class:`TransformConfig`."""
    if config.method == "identity":
        return PlacementTransform(np.eye(3), np.zeros(3), config)
    if config.method == "scale":
        S = np.asarray(config.phys_extent_m) / np.asarray(config.sim_extent_m) * np.asarray(config.sim_scale)
        b = np.asarray(config.reference_m) - S * np.asarray(config.sim_reference_m)
        return PlacementTransform(np.diag(S), b, config)
    if config.method == "similarity":
        src, dst = np.array(config.pairs_sim_m), np.array(config.pairs_phys_m)
        s, R, t = umeyama(src, dst, with_scale=config.with_scale)
        res = dst - (s * src @ R.T + t)
        rms = float(np.sqrt((res**2).sum(axis=1).mean()))
        return PlacementTransform(s * R, t, config, scale=s, rotation=R, rms_residual_m=rms)
    raise CamplaceError(f"[transform].method: unknown method {config.method!r}")


PLACEMENT_COLUMNS = (
    "name", "x_m", "y_m", "z_m", "aim_x_m", "aim_y_m", "aim_z_m", "forward_x", "forward_y", "forward_z",
    "azimuth_deg", "elevation_deg", "euler_x_deg", "euler_y_deg", "euler_z_deg",
)


def placement_rows(cameras: Sequence[dict[str, Any]], transform: PlacementTransform) -> list[dict[str, Any]]:
    """Camera placements in the transform's frame.

    Parameters
    ----------
    cameras : list of dict
        ``name``, ``position`` (3,), ``rotation`` (3, 3) world-from-camera, optionally ``aim`` (3,).
    transform : PlacementTransform

    Returns
    -------
    list of dict
        Per camera: name, position, aim (or None), forward (unit), rotation (world-from-camera),
        azimuth_deg / elevation_deg of the forward axis (world z up), euler_xyz_deg of the rotation.
    """
    rows = []
    for cam in cameras:
        pos = transform.apply_points(np.asarray(cam["position"], dtype=np.float64))[0]
        R = transform.apply_rotations(np.asarray(cam["rotation"], dtype=np.float64))[0]
        aim = None if cam.get("aim") is None else transform.apply_points(np.asarray(cam["aim"], dtype=np.float64))[0]
        f = R[:, 2]
        rows.append(
            {
                "name": cam["name"],
                "position_m": pos.tolist(),
                "aim_m": None if aim is None else aim.tolist(),
                "forward": f.tolist(),
                "rotation": R.tolist(),
                "azimuth_deg": math.degrees(math.atan2(f[1], f[0])),
                "elevation_deg": math.degrees(math.asin(max(-1.0, min(1.0, f[2])))),
                "euler_xyz_deg": euler_xyz_deg(R).tolist(),
            }
        )
    return rows


def write_placement(outdir: str | Path, rows: Sequence[dict[str, Any]], transform: PlacementTransform, frame: str) -> tuple[Path, Path]:
    """Write ``placement.{frame}.csv`` and ``placement.{frame}.json`` atomically; returns their paths."""
    outdir = Path(outdir)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(PLACEMENT_COLUMNS)
    for r in rows:
        aim = r["aim_m"] if r["aim_m"] is not None else ["", "", ""]
        w.writerow(
            [r["name"], *(repr(float(v)) for v in r["position_m"]), *(v if v == "" else repr(float(v)) for v in aim),
             *(repr(float(v)) for v in r["forward"]), repr(float(r["azimuth_deg"])), repr(float(r["elevation_deg"])),
             *(repr(float(v)) for v in r["euler_xyz_deg"])]
        )
    csv_path, json_path = outdir / f"placement.{frame}.csv", outdir / f"placement.{frame}.json"
    write_text_atomic(csv_path, buf.getvalue())
    write_json_atomic(json_path, {"frame": frame, "transform": transform.to_dict(), "cameras": list(rows)})
    return csv_path, json_path
