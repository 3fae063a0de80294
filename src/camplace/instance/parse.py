"""Read and validate instance files (format v1, TOML, metres); :mod:`camplace.instance.write` writes them.

Every problem is reported as one :class:`~camplace.errors.InstanceError` line naming the file, the
dotted field (``camera.focal_length_mm``, ``frames[2].weight``, ``occluders[0].file``) and the fix.
"""

from __future__ import annotations

import copy
import difflib
import logging
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from camplace.errors import CamplaceError, InstanceError, plural
from camplace.instance import procedural
from camplace.instance.lab import PhysicalCamera, TransformConfig, parse_physical, parse_transform
from camplace.instance.meshio import MissingPackageError, is_watertight, read_mesh_file
from camplace.names import ROBUST_OBJECTIVES, SAMPLERS
from camplace.instance.schema import (
    SCHEMA_VERSION,
    QUALITY_MODES,
    QUALITY_PRECISIONS,
    CameraModel,
    Emitters,
    Frame,
    Instance,
    Light,
    Mesh,
    Occluder,
    AgentsSpec,
    Pose,
    QualitySpec,
    RobustSpec,
    RunDefaults,
    KeepOut,
    Mount,
    Team,
    Volume,
    Zone,
)

__all__ = ["load_instance", "parse_instance"]

log = logging.getLogger(__name__)

MAX_CANDIDATES = 1_000_000
#: Largest mesh accepted (triangles). Embree would cope with more, but the per-pixel renderer and
#: the instance files would not; decimate bigger models first.
MAX_FACES = 2_000_000
MAX_POINTS = 10_000_000

_TOP_KEYS = (
    "schema_version", "name", "k", "run", "camera", "volume", "light", "quality", "target", "occluders", "frames",
    "physical", "transform", "agents", "robust", "cameras", "volumes", "mounts", "keepouts", "team", "zones",
)
_TEAM_TOP_KEYS = ("cameras", "volumes", "mounts", "keepouts", "team", "zones")
_MODEL_KEYS = ("name", "cost", "min_count", "max_count")
_REGION_KEYS = ("models", "share")
_MOUNT_KEYS = ("position_m", "rotation_deg", "models", "share", "offset_m")
_ZONE_KEYS = ("name", "min_m", "max_m", "min_cameras", "max_cameras")
_TEAM_KEYS = ("budget",)
_RUN_KEYS = ("candidates", "points", "sampler", "seed", "time_limit_s", "orientations")
_AGENTS_KEYS = ("phases", "phase_starts_s", "speed_m_s", "start_positions_m", "start_time_s")
_ROBUST_KEYS = ("position_sigma_m", "rotation_sigma_deg", "scenarios", "objective", "eval_scenarios")
MAX_SCENARIOS = 4096
_QUALITY_KEYS = ("mode", "required_px_per_m", "max_incidence_deg", "require_light", "min_target_px", "precision")
_EMITTER_KEYS = ("positions_m", "weights", "file")
MAX_EMITTERS = 10_000_000
_CAMERA_KEYS = ("sensor_width_mm", "sensor_height_mm", "focal_length_mm", "width_px", "height_px", "near_m", "far_m")
_VOLUME_KEYS = ("min_m", "max_m")
_LIGHT_KEYS = ("position_m",)
_POSE_KEYS = ("position_m", "rotation_deg")
_FRAME_KEYS = ("weight", "time_s", "position_m", "rotation_deg", "target_weight", "emitters", "occluders")
_MESH_COMMON_KEYS = ("name", "file", "shape")
_FILE_KEYS = ("scale",)
_SHAPE_PARAMS: dict[str, dict[str, Any]] = {name: params for name, (_, params) in procedural.SHAPES.items()}
_ALL_SHAPE_PARAMS = sorted({p for params in _SHAPE_PARAMS.values() for p in params})


# --------------------------------------------------------------------------------------------------
# small helpers


def _one_line(text: str) -> str:
    return re.sub(r"\s*[\r\n]+\s*", " ", str(text)).strip()


def _show(value: Any, limit: int = 60) -> str:
    """Short one-line rendering of a TOML value for messages."""
    if isinstance(value, bool):
        s = "true" if value else "false"
    elif isinstance(value, str):
        s = repr(value)
    elif isinstance(value, dict):
        s = "{" + ", ".join(f"{k} = {_show(v, 20)}" for k, v in value.items()) + "}"
    else:
        s = repr(value)
    s = _one_line(s)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _type_name(value: Any) -> str:
    if isinstance(value, bool):
        return "boolean"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, (list, tuple)):
        return "array"
    if isinstance(value, dict):
        return "table"
    return type(value).__name__


def _join(prefix: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{prefix}[{key}]"
    return f"{prefix}.{key}" if prefix else key


def _section(prefix: str) -> str:
    """How the user would spell the table holding ``prefix``'s keys."""
    if not prefix:
        return "the top level"
    m = re.fullmatch(r"(\w+)\[(\d+)\]", prefix)
    if m:
        return f"[[{m.group(1)}]] number {int(m.group(2)) + 1}"
    return f"[{prefix}]"


class _Parser:
    """Validating reader of one instance's data; ``source`` names it in every error."""

    def __init__(self, source: str, base_dir: Path) -> None:
        self.source = _one_line(source)
        self.base_dir = Path(base_dir)
        self.warnings: list[str] = []  # ``Instance.warnings``: "field: what" lines

    # -- errors and warnings -----------------------------------------------------------------------

    def error(self, field: str, problem: str, fix: str | None = None) -> InstanceError:
        return InstanceError(self.source, _one_line(field), _one_line(problem), _one_line(fix) if fix else None)

    def warn(self, field: str, message: str) -> None:
        """Log a warning about ``field`` and keep it for ``Instance.warnings`` (and so ``solution.json``)."""
        line = f"{_one_line(field)}: {_one_line(message)}"
        log.warning("%s: %s", self.source, line)
        self.warnings.append(line)

    # -- structure ---------------------------------------------------------------------------------

    def table(self, parent: dict, key: str, prefix: str, *, required: bool = True) -> dict | None:
        field = _join(prefix, key)
        if key not in parent:
            if required:
                raise self.error(field, "missing required table", f"add a [{field}] table")
            return None
        value = parent[key]
        if not isinstance(value, dict):
            raise self.error(
                field, f"must be a table, got {_type_name(value)} {_show(value)}", f"write it as a [{field}] section"
            )
        return value

    def check_keys(self, table: dict, allowed: tuple[str, ...] | list[str], prefix: str, hint: dict | None = None) -> None:
        """Reject keys not in ``allowed``, suggesting the closest allowed key."""
        for key in table:
            if key in allowed:
                continue
            field = _join(prefix, str(key))
            extra = (hint or {}).get(key)
            close = difflib.get_close_matches(str(key), list(allowed), n=1, cutoff=0.6)
            problem = "unknown key"
            if extra:
                problem += f"; {extra}"
            if close:
                problem += f"; did you mean '{close[0]}'?"
            raise self.error(field, problem, f"allowed keys in {_section(prefix)}: {', '.join(allowed)}")

    def require(self, table: dict, key: str, prefix: str, what: str) -> Any:
        if key not in table:
            raise self.error(_join(prefix, key), "missing required key", f"add {key} = <{what}> to {_section(prefix)}")
        return table[key]

    # -- scalars -----------------------------------------------------------------------------------

    def number(
        self,
        table: dict,
        key: str,
        prefix: str,
        *,
        default: float | None = None,
        required: bool = False,
        gt: float | None = None,
        ge: float | None = None,
        le: float | None = None,
        unit: str = "",
    ) -> float:
        field = _join(prefix, key)
        if key not in table:
            if required or default is None:
                self.require(table, key, prefix, f"number{unit and ' in ' + unit}")
            return float(default)  # type: ignore[arg-type]
        return self._check_number(table[key], field, gt=gt, ge=ge, le=le)

    def _check_number(self, value: Any, field: str, *, gt=None, ge=None, le=None) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(field, f"must be a number, got {_type_name(value)} {_show(value)}", "write a plain number")
        x = float(value)
        if not math.isfinite(x):
            raise self.error(field, f"must be a finite number, got {_show(value)}", "replace nan/inf by a real value")
        if gt is not None and not x > gt:
            raise self.error(field, f"must be > {gt:g}, got {_show(value)}", f"use a value greater than {gt:g}")
        if ge is not None and not x >= ge:
            raise self.error(field, f"must be >= {ge:g}, got {_show(value)}", f"use a value of at least {ge:g}")
        if le is not None and not x <= le:
            raise self.error(field, f"must be <= {le:g}, got {_show(value)}", f"use a value of at most {le:g}")
        return x

    def integer(
        self,
        table: dict,
        key: str,
        prefix: str,
        *,
        default: int | None = None,
        required: bool = False,
        ge: int | None = None,
        le: int | None = None,
    ) -> int:
        field = _join(prefix, key)
        if key not in table:
            if required or default is None:
                self.require(table, key, prefix, "integer")
            return int(default)  # type: ignore[arg-type]
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            fix = "write a whole number without a decimal point" if isinstance(value, float) else "write a whole number"
            raise self.error(field, f"must be an integer, got {_type_name(value)} {_show(value)}", fix)
        n = int(value)
        if ge is not None and n < ge:
            raise self.error(field, f"must be >= {ge}, got {n}", f"use an integer of at least {ge}")
        if le is not None and n > le:
            raise self.error(field, f"must be <= {le:_}, got {n:_}", f"use an integer of at most {le:_}")
        return n

    def string(self, table: dict, key: str, prefix: str, *, default: str | None = None) -> str:
        field = _join(prefix, key)
        if key not in table:
            if default is None:
                self.require(table, key, prefix, '"text"')
            return default  # type: ignore[return-value]
        value = table[key]
        if not isinstance(value, str):
            raise self.error(field, f"must be a string, got {_type_name(value)} {_show(value)}", 'put the text in quotes, e.g. "name"')
        if not value.strip():
            raise self.error(field, "must not be empty", "write a non-empty string")
        if "\n" in value or "\r" in value:
            raise self.error(field, "must be a single line", "remove the line breaks")
        return value

    def vec3(self, table: dict, key: str, prefix: str, *, default: tuple | None = None, positive: bool = False) -> tuple[float, float, float]:
        field = _join(prefix, key)
        if key not in table:
            if default is None:
                self.require(table, key, prefix, "[x, y, z]")
            return tuple(float(x) for x in default)  # type: ignore[return-value,union-attr]
        value = table[key]
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            got = f"{_type_name(value)} of length {len(value)}" if isinstance(value, (list, tuple)) else f"{_type_name(value)} {_show(value)}"
            raise self.error(field, f"must be an array of 3 numbers [x, y, z], got {got}", f"write {key} = [x, y, z]")
        out = []
        for i, item in enumerate(value):
            out.append(self._check_number(item, f"{field}[{i}]", gt=0.0 if positive else None))
        return tuple(out)  # type: ignore[return-value]

    def vec2(self, table: dict, key: str, prefix: str, *, default: tuple) -> tuple[float, float]:
        field = _join(prefix, key)
        if key not in table:
            return (float(default[0]), float(default[1]))
        value = table[key]
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise self.error(field, f"must be an array of 2 numbers [x, y], got {_type_name(value)} {_show(value)}", f"write {key} = [x, y]")
        return tuple(self._check_number(v, f"{field}[{i}]", gt=0.0) for i, v in enumerate(value))  # type: ignore[return-value]

    # -- sections ----------------------------------------------------------------------------------

    def pose(self, table: dict, prefix: str) -> Pose:
        return Pose(
            position_m=self.vec3(table, "position_m", prefix, default=(0.0, 0.0, 0.0)),
            rotation_deg=self.vec3(table, "rotation_deg", prefix, default=(0.0, 0.0, 0.0)),
        )

    def mesh(self, table: dict, prefix: str, default_name: str, extra_keys: tuple[str, ...] = ()) -> Mesh:
        """A mesh spec: ``file`` (+ ``scale``) or ``shape`` (+ its parameters); plus ``extra_keys`` (pose)."""
        has_file, has_shape = "file" in table, "shape" in table
        if has_file and has_shape:
            raise self.error(
                _join(prefix, "file"), "both file and shape are given", f"keep only one of file = ... or shape = ... in {_section(prefix)}"
            )
        if not has_file and not has_shape:
            raise self.error(
                _join(prefix, "shape"),
                "missing mesh: neither file nor shape is given",
                f"add file = \"path/to/mesh.ply\" or shape = one of {', '.join(_SHAPE_PARAMS)} to {_section(prefix)}",
            )
        name = self.string(table, "name", prefix, default=default_name)
        spec = {k: copy.deepcopy(v) for k, v in table.items() if k not in extra_keys}

        if has_file:
            allowed = _MESH_COMMON_KEYS[:2] + _FILE_KEYS + extra_keys
            hint = {p: "shape parameters need shape = ..., not file = ..." for p in _ALL_SHAPE_PARAMS}
            self.check_keys(table, allowed, prefix, hint)
            scale = self.number(table, "scale", prefix, default=1.0, gt=0.0)
            vertices, faces, path = self.read_file(table, prefix, scale)
            faces = self.drop_degenerate(vertices, faces, _join(prefix, "file"))
            return Mesh(name=name, vertices=vertices, faces=faces, source=f"file:{path}", spec=spec)

        shape = table["shape"]
        field = _join(prefix, "shape")
        if not isinstance(shape, str):
            raise self.error(field, f"must be a string, got {_type_name(shape)} {_show(shape)}", f"use one of {', '.join(_SHAPE_PARAMS)}")
        if shape not in _SHAPE_PARAMS:
            close = difflib.get_close_matches(shape, list(_SHAPE_PARAMS), n=1, cutoff=0.5)
            problem = f"unknown shape {_show(shape)}" + (f"; did you mean '{close[0]}'?" if close else "")
            raise self.error(field, problem, f"use one of {', '.join(_SHAPE_PARAMS)}, or file = \"mesh.ply\"")
        params = _SHAPE_PARAMS[shape]
        allowed = ("name", "shape", *params, *extra_keys)
        hint: dict[str, str] = {"scale": "scale applies only to file meshes; set the shape's size parameters instead"}
        for p in _ALL_SHAPE_PARAMS:
            if p not in params:
                owners = [s for s, ps in _SHAPE_PARAMS.items() if p in ps]
                hint[p] = f"not a parameter of shape '{shape}', only of {', '.join(owners)}"
        self.check_keys(table, allowed, prefix, hint)
        vertices, faces = self.shape(shape, table, prefix)
        return Mesh(name=name, vertices=vertices, faces=faces, source=f"procedural:{shape}", spec=spec)

    def shape(self, shape: str, table: dict, prefix: str) -> tuple[np.ndarray, np.ndarray]:
        if shape == "sphere":
            args = {
                "radius_m": self.number(table, "radius_m", prefix, default=0.5, gt=0.0),
                "subdivisions": self.integer(table, "subdivisions", prefix, default=4, ge=1, le=7),
            }
        elif shape in ("box", "corridor"):
            args = {"size_m": self.vec3(table, "size_m", prefix, positive=True)}
        elif shape == "bilobed-comet":
            args = {
                "length_m": self.number(table, "length_m", prefix, default=0.6, gt=0.0),
                "seed": self.integer(table, "seed", prefix, default=0, ge=0),
                "subdivisions": self.integer(table, "subdivisions", prefix, default=5, ge=2, le=7),
                "noise": self.number(table, "noise", prefix, default=0.06, ge=0.0, le=0.3),
            }
        elif shape == "volcano":
            size = self.vec2(table, "size_m", prefix, default=(400.0, 400.0))
            args = {
                "size_m": size,
                "height_m": self.number(table, "height_m", prefix, default=80.0, gt=0.0),
                "base_radius_m": self.number(table, "base_radius_m", prefix, default=150.0, gt=0.0),
                "crater_radius_m": self.number(table, "crater_radius_m", prefix, default=25.0, gt=0.0),
                "crater_depth_m": self.number(table, "crater_depth_m", prefix, default=20.0, ge=0.0),
                "cells": self.integer(table, "cells", prefix, default=100, ge=2, le=2000),
            }
            if not args["crater_radius_m"] < args["base_radius_m"]:
                raise self.error(_join(prefix, "crater_radius_m"), "must be smaller than base_radius_m", "shrink the crater or widen the base")
        else:  # pragma: no cover - guarded by the caller
            raise AssertionError(shape)
        func = procedural.SHAPES[shape][0]
        try:
            vertices, faces = func(**args)
        except ValueError as exc:  # pragma: no cover - arguments were validated above
            raise self.error(_join(prefix, "shape"), str(exc), "check the shape parameters") from None
        self.check_arrays(vertices, faces, _join(prefix, "shape"))
        return vertices, faces

    def read_file(self, table: dict, prefix: str, scale: float) -> tuple[np.ndarray, np.ndarray, Path]:
        field = _join(prefix, "file")
        raw = table["file"]
        if not isinstance(raw, str) or not raw.strip():
            raise self.error(field, f"must be a non-empty path string, got {_type_name(raw)} {_show(raw)}", 'write file = "meshes/model.ply"')
        path = Path(raw).expanduser()
        if not path.is_absolute():
            path = self.base_dir / path
        path = Path(os.path.abspath(path))
        if not path.exists():
            raise self.error(field, f"mesh file not found: {path}", "check the path; relative paths are relative to the instance file's folder")
        if not path.is_file():
            raise self.error(field, f"not a file: {path}", "point file at a mesh file (.ply, .obj, .stl, ...)")
        if not os.access(path, os.R_OK):
            raise self.error(field, f"mesh file is not readable: {path}", "check the file's permissions")
        try:
            vertices, faces = read_mesh_file(path)
        except InstanceError:
            raise
        except MissingPackageError as exc:
            raise self.error(field, f"cannot read mesh {path.name}: {exc.reason}", exc.fix) from None
        except Exception as exc:  # trimesh raises many kinds of errors on bad content
            raise self.error(
                field, f"cannot read mesh {path.name}: {type(exc).__name__}: {_show(str(exc), 120)}", "use a valid triangle mesh file that trimesh can read (.ply, .obj, .stl, .off, .glb)"
            ) from None
        self.check_arrays(vertices, faces, field, path.name)
        return vertices * scale if scale != 1.0 else vertices, faces, path

    def check_arrays(self, vertices: np.ndarray, faces: np.ndarray, field: str, what: str = "mesh") -> None:
        fix = "use a non-empty triangle mesh with valid indices and finite coordinates"
        if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
            raise self.error(field, f"{what} has no vertices", fix)
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
            raise self.error(field, f"{what} has no triangles", fix)
        if not np.all(np.isfinite(vertices)):
            raise self.error(field, f"{what} has NaN or infinite vertex coordinates", fix)
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise self.error(field, f"{what} has face indices outside 0..{len(vertices) - 1}", fix)
        if len(faces) > MAX_FACES:
            raise self.error(
                field, f"{what} has {len(faces):_} triangles, over the budget of {MAX_FACES:_}",
                "decimate it first (e.g. trimesh's simplify_quadric_decimation or MeshLab's quadric edge collapse)",
            )

    def drop_degenerate(self, vertices: np.ndarray, faces: np.ndarray, field: str) -> np.ndarray:
        """Faces without the degenerate ones (a repeated vertex or zero area), with a warning."""
        tri = vertices[faces]
        area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
        bad = repeated | ~(area2 > 0)
        if bad.all():
            raise self.error(field, "every triangle of the mesh is degenerate (zero area)", "check the mesh file and its scale")
        if bad.any():
            self.warn(field, f"dropped {int(bad.sum())} degenerate (zero-area) triangles of {len(faces)}")
        return faces[~bad]

    # -- the whole instance ------------------------------------------------------------------------

    def instance(self, data: Any) -> Instance:
        if not isinstance(data, dict):
            raise self.error("", f"an instance must be a table of keys, got {_type_name(data)}", "see instances/comet-67p-bunker.toml")
        if "schema_version" not in data:
            raise self.error("schema_version", "missing required key", f"add schema_version = {SCHEMA_VERSION} at the top of the file")
        version = data["schema_version"]
        if isinstance(version, bool) or not isinstance(version, int):
            raise self.error("schema_version", f"must be an integer, got {_type_name(version)} {_show(version)}", f"write schema_version = {SCHEMA_VERSION}")
        if version != SCHEMA_VERSION:
            fix = "upgrade camplace" if version > SCHEMA_VERSION else f"convert the file to schema_version = {SCHEMA_VERSION}"
            raise self.error("schema_version", f"unknown schema version {version}; this camplace reads version {SCHEMA_VERSION}", fix)
        self.check_keys(data, _TOP_KEYS, "")
        name = self.string(data, "name", "")
        k = self.integer(data, "k", "", required=True, ge=1)

        run_t = self.table(data, "run", "", required=False) or {}
        self.check_keys(run_t, _RUN_KEYS, "run")
        d = RunDefaults()
        sampler = self.string(run_t, "sampler", "run", default=d.sampler)
        if sampler not in SAMPLERS:
            close = difflib.get_close_matches(sampler, SAMPLERS, n=1, cutoff=0.5)
            raise self.error(
                "run.sampler", f"unknown sampler {_show(sampler)}" + (f"; did you mean '{close[0]}'?" if close else ""), f"use one of {', '.join(SAMPLERS)}"
            )
        run = RunDefaults(
            candidates=self.integer(run_t, "candidates", "run", default=d.candidates, ge=1, le=MAX_CANDIDATES),
            points=self.integer(run_t, "points", "run", default=d.points, ge=1, le=MAX_POINTS),
            sampler=sampler,
            seed=self.integer(run_t, "seed", "run", default=d.seed, ge=0),
            time_limit_s=self.number(run_t, "time_limit_s", "run", default=d.time_limit_s, gt=0.0),
            orientations=self.integer(run_t, "orientations", "run", default=d.orientations, ge=1, le=64),
        )
        if k > run.candidates:
            raise self.error("k", f"{k} cameras cannot be chosen from run.candidates = {run.candidates} candidate positions", "lower k or raise run.candidates")

        team = None
        if any(key in data for key in _TEAM_TOP_KEYS):
            team = self.team(data, k)
            camera = team.models[0]
            volume = self.bounding_volume(team)
        else:
            camera = self.camera(self.table(data, "camera", ""), "camera")
            volume = self.box(self.table(data, "volume", ""), "volume", _VOLUME_KEYS)

        light_t = self.table(data, "light", "")
        self.check_keys(light_t, _LIGHT_KEYS, "light")
        light = Light(position_m=self.vec3(light_t, "position_m", "light"))

        quality = self.quality(self.table(data, "quality", "", required=False) or {})

        target_t = self.table(data, "target", "")
        target = self.mesh(target_t, "target", "target")
        if not is_watertight(target.vertices, target.faces):
            self.warn("target", "the mesh is not watertight (open edges, even with the vertices at one position merged): "
                      "surface points are still sampled, but its inside is visible through the holes")
        extent = float(np.linalg.norm(np.ptp(target.vertices, axis=0)))
        if extent > float(np.linalg.norm(volume.size_m)):
            self.warn("target", f"the target ({extent:.3g} m across) is larger than the camera volume "
                      f"({float(np.linalg.norm(volume.size_m)):.3g} m across): check the units (metres) and target.scale")

        occluders = self.occluders(data, "")

        if "frames" not in data:
            raise self.error("frames", "missing: at least one frame is required", "add a [[frames]] section with position_m = [x, y, z]")
        frame_list = data["frames"]
        if not isinstance(frame_list, list) or not frame_list:
            raise self.error("frames", "must be a non-empty array of tables", "add at least one [[frames]] section")
        frames = []
        for i, fr_t in enumerate(frame_list):
            prefix = f"frames[{i}]"
            if not isinstance(fr_t, dict):
                raise self.error(prefix, f"must be a table, got {_type_name(fr_t)}", "write each frame as a [[frames]] section")
            self.check_keys(fr_t, _FRAME_KEYS, prefix)
            emitters = None
            if "emitters" in fr_t:
                emitters = self.emitters(self.table(fr_t, "emitters", prefix), _join(prefix, "emitters"))
            target_weight = self.number(fr_t, "target_weight", prefix, default=1.0, ge=0.0)
            if target_weight == 0 and emitters is None:
                raise self.error(
                    _join(prefix, "target_weight"), "is 0 and the frame has no emitters, so nothing in it can be observed",
                    "give the target a weight > 0 or add [frames.emitters]",
                )
            frames.append(
                Frame(
                    target_pose=self.pose(fr_t, prefix),
                    weight=self.number(fr_t, "weight", prefix, default=1.0, ge=0.0),
                    time_s=self.number(fr_t, "time_s", prefix, default=float(i)),
                    target_weight=target_weight,
                    emitters=emitters,
                    occluders=tuple(self.occluders(fr_t, prefix)),
                )
            )
        if not any(f.weight > 0 for f in frames):
            raise self.error("frames", "every frame has weight 0", "give at least one frame a weight > 0")

        return Instance(
            name=name,
            k=k,
            camera=camera,
            volume=volume,
            light=light,
            target=target,
            occluders=tuple(occluders),
            frames=tuple(frames),
            defaults=run,
            source=self.source,
            quality=quality,
            physical=self.lab_table(data, "physical"),
            transform=self.lab_table(data, "transform"),
            agents=self.agents(self.table(data, "agents", "", required=False), k, len(frames)),
            robust=self.robust(data),
            warnings=tuple(self.warnings),
            team=team,
        )

    # -- cameras and where they stand -----------------------------------------------------------------

    def camera(self, cam_t: dict, prefix: str, extra: tuple[str, ...] = ()) -> CameraModel:
        """A camera model table: ``[camera]`` or one ``[[cameras]]`` (``extra``: name, cost, counts)."""
        self.check_keys(cam_t, _CAMERA_KEYS + extra, prefix)
        near = self.number(cam_t, "near_m", prefix, required=True, gt=0.0, unit="metres")
        far = self.number(cam_t, "far_m", prefix, required=True, gt=0.0, unit="metres")
        team_fields: dict[str, Any] = {}
        if extra:
            team_fields["name"] = self.string(cam_t, "name", prefix)
            team_fields["cost"] = self.number(cam_t, "cost", prefix, default=1.0, ge=0.0)
            team_fields["min_count"] = self.integer(cam_t, "min_count", prefix, default=0, ge=0)
            if "max_count" in cam_t:
                team_fields["max_count"] = self.integer(cam_t, "max_count", prefix, ge=0)
                if team_fields["max_count"] < team_fields["min_count"]:
                    raise self.error(_join(prefix, "max_count"), f"must be >= min_count = {team_fields['min_count']}, got {team_fields['max_count']}",
                                     "raise max_count or lower min_count")
        camera = CameraModel(
            sensor_width_mm=self.number(cam_t, "sensor_width_mm", prefix, required=True, gt=0.0, unit="mm"),
            sensor_height_mm=self.number(cam_t, "sensor_height_mm", prefix, required=True, gt=0.0, unit="mm"),
            focal_length_mm=self.number(cam_t, "focal_length_mm", prefix, required=True, gt=0.0, unit="mm"),
            width_px=self.integer(cam_t, "width_px", prefix, required=True, ge=1),
            height_px=self.integer(cam_t, "height_px", prefix, required=True, ge=1),
            near_m=near,
            far_m=far,
            **team_fields,
        )
        if not far > near:
            raise self.error(_join(prefix, "far_m"), f"must be > {_join(prefix, 'near_m')} = {near:g}, got {far:g}", "set far_m beyond near_m")
        return camera

    def box(self, table: dict, prefix: str, keys: tuple[str, ...], **extra: Any) -> Volume:
        """A box table with ``min_m`` < ``max_m`` on every axis (``[volume]``, a ``[[volumes]]`` or a keep-out)."""
        self.check_keys(table, keys, prefix)
        vmin = self.vec3(table, "min_m", prefix)
        vmax = self.vec3(table, "max_m", prefix)
        bad = [f"{ax}: {lo:g} >= {hi:g}" for ax, lo, hi in zip("xyz", vmin, vmax) if not hi > lo]
        if bad:
            raise self.error(
                _join(prefix, "max_m"), f"must exceed {_join(prefix, 'min_m')} on every axis ({'; '.join(bad)})",
                "make the box non-empty: min_m < max_m on x, y and z",
            )
        return Volume(min_m=vmin, max_m=vmax, **extra)

    def table_list(self, data: dict, key: str) -> list[dict]:
        """The ``[[key]]`` array of tables (empty when absent)."""
        value = data.get(key, [])
        if isinstance(value, dict):
            singular = {"cameras": "camera", "volumes": "volume"}.get(key)
            raise self.error(key, f"is a single [{key}] table, not an array of tables" + (f"; did you mean '{singular}'?" if singular else ""),
                             f"write [[{key}]] (double brackets), one section per entry" + (f", or [{singular}] for one" if singular else ""))
        if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
            raise self.error(key, f"must be an array of tables, got {_type_name(value)} {_show(value)}", f"write each entry as a [[{key}]] section")
        return value

    def model_list(self, table: dict, prefix: str, names: tuple[str, ...]) -> tuple[str, ...]:
        """A region's ``models = ["name", ...]`` (empty: every model); each must name a ``[[cameras]]`` model."""
        if "models" not in table:
            return ()
        value = table["models"]
        field = _join(prefix, "models")
        if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
            raise self.error(field, f"must be a non-empty array of model names, got {_show(value)}", f"write models = [{', '.join(repr(n) for n in names[:2])}] or leave it out for every model")
        for v in value:
            if v not in names:
                close = difflib.get_close_matches(v, list(names), n=1, cutoff=0.5)
                raise self.error(field, f"unknown camera model {_show(v)}" + (f"; did you mean '{close[0]}'?" if close else ""),
                                 f"use a name of a [[cameras]] section: {', '.join(names)}")
        return tuple(dict.fromkeys(value))

    def team(self, data: dict, k: int) -> Team:
        """The camera models (``[[cameras]]`` or the single ``[camera]``) and where they may stand."""
        if "cameras" in data and "camera" in data:
            raise self.error("camera", "both [camera] and [[cameras]] are given", "move the [camera] table into a [[cameras]] section with a name")
        if "cameras" in data:
            cam_list = self.table_list(data, "cameras")
            if not cam_list:
                raise self.error("cameras", "has no camera model", "add at least one [[cameras]] section")
            models = [self.camera(t, f"cameras[{i}]", _MODEL_KEYS) for i, t in enumerate(cam_list)]
        else:
            models = [self.camera(self.table(data, "camera", ""), "camera")]
        names = tuple(m.name for m in models)
        for i, n in enumerate(names):
            if n in names[:i]:
                raise self.error(f"cameras[{i}].name", f"model name {_show(n)} is used twice", "give every [[cameras]] model its own name")

        volumes = []
        if "volume" in data:
            volumes.append(self.box(self.table(data, "volume", ""), "volume", _VOLUME_KEYS))
        for i, t in enumerate(self.table_list(data, "volumes")):
            p = f"volumes[{i}]"
            volumes.append(self.box(t, p, _VOLUME_KEYS + _REGION_KEYS, models=self.model_list(t, p, names),
                                    share=self.number(t, "share", p, default=1.0, gt=0.0)))
        mounts = []
        for i, t in enumerate(self.table_list(data, "mounts")):
            p = f"mounts[{i}]"
            mesh = self.mesh(t, p, f"mount{i}", _MOUNT_KEYS)
            mounts.append(Mount(mesh=mesh, pose=self.pose(t, p), models=self.model_list(t, p, names),
                                offset_m=self.number(t, "offset_m", p, default=0.05, ge=0.0, unit="metres"),
                                share=self.number(t, "share", p, default=1.0, gt=0.0)))
        if not volumes and not mounts:
            raise self.error("volumes", "no region where cameras may stand", "add a [volume], [[volumes]] or [[mounts]] section")
        keepouts = []
        for i, t in enumerate(self.table_list(data, "keepouts")):
            p = f"keepouts[{i}]"
            if "min_m" in t or "max_m" in t:
                keepouts.append(KeepOut(box=self.box(t, p, _VOLUME_KEYS)))
            else:
                mesh = self.mesh(t, p, f"keepout{i}", _POSE_KEYS)
                if not is_watertight(mesh.vertices, mesh.faces):
                    self.warn(p, "the keep-out mesh is not watertight: its inside is only approximate")
                keepouts.append(KeepOut(mesh=mesh, pose=self.pose(t, p)))

        team_t = self.table(data, "team", "", required=False) or {}
        self.check_keys(team_t, _TEAM_KEYS, "team")
        budget = self.number(team_t, "budget", "team", gt=0.0) if "budget" in team_t else None

        zones = []
        for i, t in enumerate(self.table_list(data, "zones")):
            p = f"zones[{i}]"
            self.check_keys(t, _ZONE_KEYS, p)
            zname = self.string(t, "name", p)
            if zname in [z.name for z in zones]:
                raise self.error(_join(p, "name"), f"zone name {_show(zname)} is used twice", "give every [[zones]] section its own name")
            box = self.box({kk: v for kk, v in t.items() if kk in _VOLUME_KEYS}, p, _VOLUME_KEYS)
            zmin = self.integer(t, "min_cameras", p, default=0, ge=0, le=k)
            zmax = self.integer(t, "max_cameras", p, ge=zmin) if "max_cameras" in t else None
            zones.append(Zone(name=zname, min_m=box.min_m, max_m=box.max_m, min_cameras=zmin, max_cameras=zmax))

        team = Team(models=tuple(models), volumes=tuple(volumes), mounts=tuple(mounts), keepouts=tuple(keepouts),
                    zones=tuple(zones), budget=budget)
        self.check_team(team, k, "cameras" in data)
        return team

    def check_team(self, team: Team, k: int, listed: bool = True) -> None:
        """Quotas, counts and the budget that no choice of k cameras can meet are one-line errors.

        ``listed``: the models come from ``[[cameras]]`` (else from the single ``[camera]``).
        """
        for i, m in enumerate(team.models):
            field = f"cameras[{i}]" if listed else "camera"
            if not any(v.allows(m.name) for v in team.volumes) and not any(mt.allows(m.name) for mt in team.mounts):
                raise self.error(field, f"model {_show(m.name)} has no allowed pose: no [[volumes]] or [[mounts]] section lists it",
                                 f'add "{m.name}" to the models of a [[volumes]] or [[mounts]] section (or leave models out there for every model)')
            if m.min_count > k:
                raise self.error(_join(field, "min_count"), f"{m.min_count} cameras of {_show(m.name)} exceed k = {k}", f"lower min_count to at most {k} or raise k")
        mins = sum(m.min_count for m in team.models)
        if mins > k:
            raise self.error("cameras", f"the models' min_count add up to {mins}, more than k = {k}", "lower some min_count or raise k")
        if all(m.max_count is not None for m in team.models):
            maxs = sum(int(m.max_count) for m in team.models)  # type: ignore[arg-type]
            if maxs < k:
                raise self.error("cameras", f"the models' max_count add up to {maxs}, fewer than k = {k}", "raise some max_count, drop one, or lower k")
        if team.budget is not None:
            cheapest = min(m.cost for m in team.models)
            if team.budget < cheapest:
                raise self.error("team.budget", f"{team.budget:g} is below the cheapest camera ({cheapest:g})",
                                 f"raise the budget to at least {cheapest:g} or lower the models' cost")
            need = sum(m.cost * m.min_count for m in team.models)
            if need > team.budget:
                raise self.error("team.budget", f"{team.budget:g} is below the cost of the models' min_count cameras ({need:g})",
                                 f"raise the budget to at least {need:g} or lower min_count")
        regions = [(np.asarray(v.min_m), np.asarray(v.max_m)) for v in team.volumes]
        regions += [(v.min(axis=0) - mt.offset_m, v.max(axis=0) + mt.offset_m) for mt in team.mounts for v in [mt.world()[0]]]
        for i, z in enumerate(team.zones):
            if z.min_cameras == 0:
                continue
            zlo, zhi = np.asarray(z.min_m), np.asarray(z.max_m)
            if not any(np.all(lo < zhi) and np.all(hi > zlo) for lo, hi in regions):
                raise self.error(f"zones[{i}].min_cameras", f"zone {_show(z.name)} asks for {z.min_cameras} camera(s) but no [[volumes]] or [[mounts]] region reaches into it",
                                 "move the zone over a region where cameras may stand, or set min_cameras = 0")
        for i, v in enumerate(team.volumes):
            for ko in team.keepouts:
                if ko.box is not None and np.all(np.asarray(ko.box.min_m) <= v.min_m) and np.all(np.asarray(ko.box.max_m) >= v.max_m):
                    self.warn(f"volumes[{i}]", "lies wholly inside a keep-out box: no camera can stand in it")

    def bounding_volume(self, team: Team) -> Volume:
        """The box around every region cameras may stand in (``Instance.volume`` of a team)."""
        los = [np.asarray(v.min_m) for v in team.volumes] + [mt.world()[0].min(axis=0) - mt.offset_m for mt in team.mounts]
        his = [np.asarray(v.max_m) for v in team.volumes] + [mt.world()[0].max(axis=0) + mt.offset_m for mt in team.mounts]
        lo, hi = np.min(los, axis=0), np.max(his, axis=0)
        hi = np.maximum(hi, lo + 1e-6)  # a flat mount still spans a (thin) box
        return Volume(min_m=tuple(float(x) for x in lo), max_m=tuple(float(x) for x in hi))

    def lab_table(self, data: dict, key: str) -> PhysicalCamera | TransformConfig | None:
        """The ``[physical]`` or ``[transform]`` table, parsed by :mod:`camplace.instance.lab` (None when absent)."""
        table = self.table(data, key, "", required=False)
        if table is None:
            return None
        parse = parse_physical if key == "physical" else parse_transform
        try:
            return parse(table, key)
        except CamplaceError as exc:
            raise InstanceError(self.source, "", _one_line(str(exc))) from None

    def agents(self, table: dict | None, k: int, n_frames: int) -> AgentsSpec | None:
        """The ``[agents]`` table: phases (a count or start times), speed, optional start positions."""
        if table is None:
            return None
        self.check_keys(table, _AGENTS_KEYS, "agents")
        if ("phases" in table) == ("phase_starts_s" in table):
            raise self.error("agents", "give exactly one of phases and phase_starts_s",
                             "write phases = N (equal durations) or phase_starts_s = [t0, t1, ...]")
        phases = starts = None
        if "phases" in table:
            phases = self.integer(table, "phases", "agents", ge=1, le=n_frames)
        else:
            value = table["phase_starts_s"]
            if not isinstance(value, list) or not value:
                raise self.error("agents.phase_starts_s", f"must be a non-empty array of times, got {_type_name(value)} {_show(value)}",
                                 "write phase_starts_s = [0.0, 6.0, 12.0]")
            starts = tuple(self._check_number(v, f"agents.phase_starts_s[{i}]") for i, v in enumerate(value))
            if any(b <= a for a, b in zip(starts, starts[1:])):
                raise self.error("agents.phase_starts_s", f"must be strictly increasing, got {_show(value)}", "sort the start times and drop repeats")
            if len(starts) > n_frames:
                raise self.error("agents.phase_starts_s", f"{len(starts)} phases but only {plural(n_frames, 'frame')}", "give at most one phase per frame")
        speed = self.number(table, "speed_m_s", "agents", required=True, ge=0.0, unit="m/s")
        start_pos = None
        if "start_positions_m" in table:
            value = table["start_positions_m"]
            if not isinstance(value, list) or len(value) != k:
                raise self.error("agents.start_positions_m", f"must be an array of k = {k} positions [x, y, z], got {_type_name(value)} {_show(value)}",
                                 f"write one [x, y, z] per agent ({k} in all)")
            rows = []
            for i, v in enumerate(value):
                field = f"agents.start_positions_m[{i}]"
                if not isinstance(v, list) or len(v) != 3:
                    raise self.error(field, f"must be an array of 3 numbers [x, y, z], got {_type_name(v)} {_show(v)}", "write [x, y, z]")
                rows.append(tuple(self._check_number(c, f"{field}[{j}]") for j, c in enumerate(v)))
            start_pos = tuple(rows)
        start_time = None
        if "start_time_s" in table:
            start_time = self.number(table, "start_time_s", "agents")
            if starts is not None and not start_time < starts[0]:
                raise self.error("agents.start_time_s", f"must be before the first phase start {starts[0]:g} s, got {start_time:g}",
                                 "give an earlier start time")
        return AgentsSpec(phases=phases, phase_starts_s=starts, speed_m_s=speed, start_positions_m=start_pos, start_time_s=start_time)

    def robust(self, data: dict) -> RobustSpec | None:
        """The ``[robust]`` table (None when absent)."""
        table = self.table(data, "robust", "", required=False)
        if table is None:
            return None
        self.check_keys(table, _ROBUST_KEYS, "robust")
        d = RobustSpec()
        objective = self.string(table, "objective", "robust", default=d.objective)
        if objective not in ROBUST_OBJECTIVES:
            raise self.error("robust.objective", f"unknown objective {_show(objective)}", f"use one of {', '.join(ROBUST_OBJECTIVES)}")
        return RobustSpec(
            position_sigma_m=self.number(table, "position_sigma_m", "robust", default=d.position_sigma_m, ge=0.0, unit="metres"),
            rotation_sigma_deg=self.number(table, "rotation_sigma_deg", "robust", default=d.rotation_sigma_deg, ge=0.0, le=90.0, unit="degrees"),
            scenarios=self.integer(table, "scenarios", "robust", default=d.scenarios, ge=1, le=MAX_SCENARIOS),
            objective=objective,
            eval_scenarios=self.integer(table, "eval_scenarios", "robust", default=d.eval_scenarios, ge=1, le=MAX_SCENARIOS),
        )

    def quality(self, table: dict) -> QualitySpec:
        self.check_keys(table, _QUALITY_KEYS, "quality")
        d = QualitySpec()
        mode = self.string(table, "mode", "quality", default=d.mode)
        if mode not in QUALITY_MODES:
            close = difflib.get_close_matches(mode, QUALITY_MODES, n=1, cutoff=0.5)
            raise self.error(
                "quality.mode", f"unknown mode {_show(mode)}" + (f"; did you mean '{close[0]}'?" if close else ""),
                f"use one of {', '.join(QUALITY_MODES)}",
            )
        precision = self.string(table, "precision", "quality", default=d.precision)
        if precision not in QUALITY_PRECISIONS:
            raise self.error("quality.precision", f"unknown precision {_show(precision)}",
                             f"use one of {', '.join(QUALITY_PRECISIONS)}")
        light = table.get("require_light", d.require_light)
        if not isinstance(light, bool):
            raise self.error("quality.require_light", f"must be true or false, got {_type_name(light)} {_show(light)}", "write true or false")
        return QualitySpec(
            mode=mode,
            required_px_per_m=self.number(table, "required_px_per_m", "quality", default=d.required_px_per_m, gt=0.0),
            max_incidence_deg=self.number(table, "max_incidence_deg", "quality", default=d.max_incidence_deg, gt=0.0, le=90.0),
            require_light=light,
            min_target_px=self.number(table, "min_target_px", "quality", default=d.min_target_px, ge=0.0),
            precision=precision,
        )

    def occluders(self, parent: dict, prefix: str) -> list[Occluder]:
        """The ``occluders`` array of tables of ``parent`` (top level or a frame)."""
        field = _join(prefix, "occluders")
        occ_list = parent.get("occluders", [])
        section = f"[[{field.split('[')[0] if not prefix else 'frames.occluders'}]]"
        if not isinstance(occ_list, list):
            raise self.error(field, f"must be an array of tables, got {_type_name(occ_list)}", f"write each occluder as an {section} section")
        out = []
        for i, occ_t in enumerate(occ_list):
            p = f"{field}[{i}]"
            if not isinstance(occ_t, dict):
                raise self.error(p, f"must be a table, got {_type_name(occ_t)}", f"write each occluder as an {section} section")
            keys = _POSE_KEYS + ("ground",) if not prefix else _POSE_KEYS
            mesh = self.mesh(occ_t, p, f"occluder{i}", keys)
            ground = occ_t.get("ground", False)
            if not isinstance(ground, bool):
                raise self.error(_join(p, "ground"), f"must be true or false, got {_type_name(ground)} {_show(ground)}", "write ground = true for terrain cameras must stay above")
            out.append(Occluder(mesh=mesh, pose=self.pose(occ_t, p), ground=ground))
        return out

    def emitters(self, table: dict, prefix: str) -> Emitters:
        """Volumetric emitters: inline ``positions_m`` + ``weights``, or a CSV ``file`` with x,y,z,weight columns."""
        self.check_keys(table, _EMITTER_KEYS, prefix)
        if "file" in table:
            if "positions_m" in table or "weights" in table:
                raise self.error(_join(prefix, "file"), "both file and positions_m/weights are given", "keep only one")
            rel = self.string(table, "file", prefix)
            path = Path(rel) if Path(rel).is_absolute() else self.base_dir / rel
            try:
                data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
            except OSError as exc:
                raise self.error(_join(prefix, "file"), f"cannot read {rel!r} ({getattr(exc, 'strerror', None) or exc})", "check the path (relative to the instance file)") from None
            except ValueError as exc:
                raise self.error(_join(prefix, "file"), f"{rel!r} is not a CSV of x,y,z,weight rows ({_one_line(str(exc))})", "write a header line, then x,y,z,weight per row") from None
            if data.shape[1] != 4:
                raise self.error(_join(prefix, "file"), f"{rel!r} has {data.shape[1]} columns, expected 4 (x,y,z,weight)", "write x,y,z,weight per row")
            pos, w, source = data[:, :3].copy(), data[:, 3].copy(), f"file:{path}"
            field_pos = field_w = _join(prefix, "file")
        else:
            field_pos, field_w = _join(prefix, "positions_m"), _join(prefix, "weights")
            raw_p = self.require(table, "positions_m", prefix, "[[x, y, z], ...]")
            raw_w = self.require(table, "weights", prefix, "[w, ...]")
            if not isinstance(raw_p, list) or not all(isinstance(r, list) and len(r) == 3 for r in raw_p):
                raise self.error(field_pos, "must be an array of [x, y, z] arrays", "write positions_m = [[x, y, z], ...]")
            if not isinstance(raw_w, list):
                raise self.error(field_w, f"must be an array of numbers, got {_type_name(raw_w)}", "write weights = [w, ...]")
            for i, row in enumerate(raw_p):
                for j, x in enumerate(row):
                    self._check_number(x, f"{field_pos}[{i}][{j}]")
            for i, x in enumerate(raw_w):
                self._check_number(x, f"{field_w}[{i}]", ge=0.0)
            pos = np.array(raw_p, dtype=np.float64).reshape(-1, 3)
            w = np.array(raw_w, dtype=np.float64)
            source = "inline"
        if len(pos) == 0:
            raise self.error(field_pos, "has no emitter points", "give at least one point or remove the emitters table")
        if len(pos) > MAX_EMITTERS:
            raise self.error(field_pos, f"has {len(pos):_} points, more than {MAX_EMITTERS:_}", "subsample the emitters")
        if len(w) != len(pos):
            raise self.error(field_w, f"has {len(w)} weights for {len(pos)} positions", "give one weight per position")
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(w))):
            raise self.error(field_pos, "contains NaN or infinite values", "replace them by real numbers")
        if np.any(w < 0):
            raise self.error(field_w, "contains negative weights", "weights must be >= 0")
        return Emitters(positions_m=pos, weights=w, source=source)


# --------------------------------------------------------------------------------------------------
# public API


def parse_instance(data: dict, source: str, base_dir: str | os.PathLike[str] | None = None) -> Instance:
    """Validate TOML data (already parsed) and build an :class:`Instance` with its meshes resolved.

    Parameters
    ----------
    data : dict
        The instance table, as :mod:`tomllib` returns it.
    source : str
        Name for error messages and ``Instance.source`` (a file path, or ``builtin:<name>``).
    base_dir : path, optional
        Folder that relative ``file = ...`` mesh paths are resolved against (default: the current folder).

    Raises
    ------
    InstanceError
        On the first problem found, naming ``source`` and the dotted field.
    """
    return _Parser(source, Path(base_dir) if base_dir is not None else Path.cwd()).instance(data)


def load_instance(path: str | os.PathLike[str]) -> Instance:
    """Read and validate an instance TOML file; mesh paths in it are relative to its folder.

    Raises
    ------
    InstanceError
        If the file is missing, is not valid TOML or fails validation.
    """
    p = Path(path)
    source = str(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise InstanceError(source, "", "instance file not found", "check the path") from None
    except IsADirectoryError:
        raise InstanceError(source, "", "is a folder, not an instance file", "give the path of a .toml file") from None
    except OSError as exc:
        raise InstanceError(source, "", f"cannot read: {_one_line(exc.strerror or str(exc))}", "check the file's permissions") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InstanceError(source, "", f"not UTF-8 text (byte {exc.start})", "save the instance file as UTF-8 TOML") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InstanceError(source, "", f"TOML syntax error: {_one_line(str(exc))}", "fix the TOML syntax at that line") from None
    return parse_instance(data, source, p.resolve().parent)
