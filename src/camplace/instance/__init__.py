"""Camera-placement instances: the v1 TOML format, its validation, procedural meshes and built-ins."""

from __future__ import annotations

import os
from pathlib import Path

from camplace.errors import CamplaceError, InstanceError
from camplace.instance.builtins import BUILTINS, builtin, builtin_toml, write_builtin
from camplace.instance.parse import load_instance, parse_instance
from camplace.instance.write import mesh_folder, save_instance
from camplace.names import SAMPLERS
from camplace.instance.schema import (
    SCHEMA_VERSION,
    CameraModel,
    Frame,
    Instance,
    KeepOut,
    Light,
    Mesh,
    Mount,
    Occluder,
    Pose,
    RobustSpec,
    RunDefaults,
    Team,
    Volume,
    Zone,
    rotation_from_euler_deg,
)

__all__ = [
    "BUILTINS",
    "SAMPLERS",
    "SCHEMA_VERSION",
    "CameraModel",
    "Frame",
    "Instance",
    "InstanceError",
    "KeepOut",
    "Light",
    "Mesh",
    "Mount",
    "Occluder",
    "Pose",
    "RobustSpec",
    "RunDefaults",
    "Team",
    "Volume",
    "Zone",
    "builtin",
    "builtin_toml",
    "load_instance",
    "mesh_folder",
    "parse_instance",
    "resolve_instance",
    "rotation_from_euler_deg",
    "save_instance",
    "write_builtin",
]


def resolve_instance(name_or_path: str | os.PathLike[str], seed: int | None = None) -> Instance:
    """A built-in by name, else the instance file at that path.

    ``seed`` draws the event of a built-in with a generated event (ignored for files).

    Raises
    ------
    CamplaceError
        If it is neither a built-in name nor an existing path (the message lists the built-ins).
    InstanceError
        If the file exists but is not a valid instance.
    """
    text = os.fspath(name_or_path)
    if isinstance(name_or_path, str) and text in BUILTINS:
        return builtin(text, seed)
    if not Path(text).exists():
        raise CamplaceError(f"no built-in or file named {text!r}; built-ins: {', '.join(sorted(BUILTINS))}")
    return load_instance(text)
