"""The instance's lab tables: ``[physical]`` (the emulated physical camera) and ``[transform]``
(simulation -> lab coordinates), as frozen dataclasses with their parsers.

The instance parser checks both tables with these parsers; validation
(:mod:`camplace.validation.physical`, :mod:`camplace.validation.transform`) consumes the
dataclasses: how a :class:`PhysicalCamera` takes photographs and how a :class:`TransformConfig`
maps placements are described there.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from camplace.errors import CamplaceError

__all__ = ["PhysicalCamera", "parse_physical", "TRANSFORM_METHODS", "TransformConfig", "parse_transform"]


@dataclass(frozen=True)
class PhysicalCamera:
    """Imperfections of the physical cameras (all zero: a perfect camera, photo == render).

    Attributes
    ----------
    sigma_position_m : float
        Standard deviation of the placement error per axis, metres.
    sigma_rotation_deg : float
        Standard deviation of each component of the orientation error's rotation vector, degrees.
    exposure_ev : float
        Exposure change in stops (x 2 ** exposure_ev).
    gain_db : float
        Sensor gain in decibels (x 10 ** (gain_db / 20)).
    noise_poisson_a : float
        Poisson (shot) noise scale a of the Poisson-Gaussian model, image units (1.0 = white).
    noise_sigma : float
        Gaussian (read) noise standard deviation, image units.
    defocus_radius_px : float
        Radius of the defocus disc (circle of confusion), pixels.
    k1, k2 : float
        Radial distortion coefficients (OpenCV).
    vignetting : float
        Relative brightness loss in the image corners (0..1).
    ambient_light : float
        Extra ambient light in the room, added to the renderer's ambient term on every surface.
    """

    sigma_position_m: float = 0.0
    sigma_rotation_deg: float = 0.0
    exposure_ev: float = 0.0
    gain_db: float = 0.0
    noise_poisson_a: float = 0.0
    noise_sigma: float = 0.0
    defocus_radius_px: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    vignetting: float = 0.0
    ambient_light: float = 0.0

    @property
    def exposure_factor(self) -> float:
        """Total brightness factor of exposure and gain."""
        return 2.0**self.exposure_ev * 10.0 ** (self.gain_db / 20.0)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


_NONNEG = ("sigma_position_m", "sigma_rotation_deg", "noise_poisson_a", "noise_sigma", "defocus_radius_px", "ambient_light")


def parse_physical(table: dict[str, Any] | None, where: str = "[physical]") -> PhysicalCamera:
    """Build a :class:`PhysicalCamera` from a TOML/JSON table (e.g. an instance's ``[physical]``).

    Parameters
    ----------
    table : dict or None
        Keys are the field names; missing keys keep their default (0).
    where : str
        Prefix for error messages, e.g. ``"run.toml: [physical]"``.

    Raises
    ------
    CamplaceError
        Unknown key, non-number, negative standard deviation or vignetting outside [0, 1].
    """
    if table is None:
        return PhysicalCamera()
    if not isinstance(table, dict):
        raise CamplaceError(f"{where}: must be a table of numbers")
    names = [f.name for f in fields(PhysicalCamera)]
    vals: dict[str, float] = {}
    for key, value in table.items():
        if key not in names:
            close = difflib.get_close_matches(key, names, n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"known keys: {', '.join(names)}"
            raise CamplaceError(f"{where}.{key}: unknown key ({hint})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise CamplaceError(f"{where}.{key}: must be a finite number, got {value!r}")
        if key in _NONNEG and value < 0:
            raise CamplaceError(f"{where}.{key}: must be >= 0, got {value}")
        if key == "vignetting" and not 0.0 <= value <= 1.0:
            raise CamplaceError(f"{where}.vignetting: must be between 0 and 1, got {value}")
        vals[key] = float(value)
    return PhysicalCamera(**vals)


TRANSFORM_METHODS = ("scale", "similarity", "identity")
_KEYS = ("method", "sim_extent_m", "phys_extent_m", "sim_scale", "reference_m", "sim_reference_m", "pairs", "with_scale")

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class TransformConfig:
    """How simulation coordinates map to the lab (see the module docstring).

    Attributes
    ----------
    method : {"scale", "similarity", "identity"}
    sim_extent_m : (3,) float or None
        Simulation environment constraints V_sim per axis (scale method).
    phys_extent_m : (3,) float or None
        Physical environment constraints V_phys per axis (scale method).
    sim_scale : (3,) float
        Scale used when modelling the simulation, s (scale method; default 1).
    reference_m : (3,) float
        Physical coordinates x_r of the reference point (scale method).
    sim_reference_m : (3,) float
        Simulation coordinates of the same reference point (default: the origin, as in the thesis).
    pairs_sim_m, pairs_phys_m : tuple of (3,) float
        Matching reference points (similarity method; at least 3, not collinear).
    with_scale : bool
        Estimate a scale in the similarity (False: a rigid motion).
    """

    method: str = "identity"
    sim_extent_m: Vec3 | None = None
    phys_extent_m: Vec3 | None = None
    sim_scale: Vec3 = (1.0, 1.0, 1.0)
    reference_m: Vec3 = (0.0, 0.0, 0.0)
    sim_reference_m: Vec3 = (0.0, 0.0, 0.0)
    pairs_sim_m: tuple[Vec3, ...] = ()
    pairs_phys_m: tuple[Vec3, ...] = ()
    with_scale: bool = True

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"method": self.method}
        if self.method == "scale":
            out.update(
                sim_extent_m=list(self.sim_extent_m or ()),
                phys_extent_m=list(self.phys_extent_m or ()),
                sim_scale=list(self.sim_scale),
                reference_m=list(self.reference_m),
                sim_reference_m=list(self.sim_reference_m),
            )
        elif self.method == "similarity":
            out["pairs"] = [{"sim_m": list(a), "phys_m": list(b)} for a, b in zip(self.pairs_sim_m, self.pairs_phys_m)]
            out["with_scale"] = self.with_scale
        return out


def _vec3(value: Any, field: str, *, positive: bool = False, allow_scalar: bool = False) -> Vec3:
    if allow_scalar and isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * 3
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise CamplaceError(f"{field}: must be an array of 3 numbers [x, y, z], got {value!r}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise CamplaceError(f"{field}[{i}]: must be a finite number, got {v!r}")
        if positive and v <= 0:
            raise CamplaceError(f"{field}[{i}]: must be > 0, got {v} (mirroring axes cannot be placed in a lab)")
        out.append(float(v))
    return (out[0], out[1], out[2])


def parse_transform(table: dict[str, Any] | None, where: str = "[transform]") -> TransformConfig:
    """Build a :class:`TransformConfig` from a TOML/JSON table.

    Parameters
    ----------
    table : dict or None
        None gives the identity.
    where : str
        Prefix of error messages (e.g. ``"lab.toml: [transform]"``).
    """
    if table is None:
        return TransformConfig()
    if not isinstance(table, dict):
        raise CamplaceError(f"{where}: must be a table")
    for key in table:
        if key not in _KEYS:
            raise CamplaceError(f"{where}.{key}: unknown key (known: {', '.join(_KEYS)})")
    method = table.get("method")
    if method not in TRANSFORM_METHODS:
        raise CamplaceError(f"{where}.method: must be one of {', '.join(TRANSFORM_METHODS)}, got {method!r}")
    if method == "identity":
        return TransformConfig()
    if method == "scale":
        for key in ("sim_extent_m", "phys_extent_m"):
            if key not in table:
                raise CamplaceError(f"{where}.{key}: required for method = \"scale\" (the environment's size per axis [x, y, z])")
        return TransformConfig(
            method="scale",
            sim_extent_m=_vec3(table["sim_extent_m"], f"{where}.sim_extent_m", positive=True),
            phys_extent_m=_vec3(table["phys_extent_m"], f"{where}.phys_extent_m", positive=True),
            sim_scale=_vec3(table.get("sim_scale", 1.0), f"{where}.sim_scale", positive=True, allow_scalar=True),
            reference_m=_vec3(table.get("reference_m", [0.0, 0.0, 0.0]), f"{where}.reference_m"),
            sim_reference_m=_vec3(table.get("sim_reference_m", [0.0, 0.0, 0.0]), f"{where}.sim_reference_m"),
        )
    pairs = table.get("pairs")
    if not isinstance(pairs, list) or len(pairs) < 3:
        raise CamplaceError(f"{where}.pairs: method = \"similarity\" needs at least 3 pairs {{sim_m = [x, y, z], phys_m = [x, y, z]}}")
    sim, phys = [], []
    for i, p in enumerate(pairs):
        if not isinstance(p, dict) or set(p) != {"sim_m", "phys_m"}:
            raise CamplaceError(f"{where}.pairs[{i}]: must be a table with exactly sim_m and phys_m")
        sim.append(_vec3(p["sim_m"], f"{where}.pairs[{i}].sim_m"))
        phys.append(_vec3(p["phys_m"], f"{where}.pairs[{i}].phys_m"))
    s = np.array(sim)
    if np.linalg.matrix_rank(s - s.mean(axis=0), tol=1e-9 * max(1.0, float(np.abs(s).max()))) < 2:
        raise CamplaceError(f"{where}.pairs: the simulation points are collinear (add a point off their line)")
    with_scale = table.get("with_scale", True)
    if not isinstance(with_scale, bool):
        raise CamplaceError(f"{where}.with_scale: must be true or false")
    return TransformConfig(method="similarity", pairs_sim_m=tuple(sim), pairs_phys_m=tuple(phys), with_scale=with_scale)
