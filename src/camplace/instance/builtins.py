"""Built-in instances, each defined as TOML data and parsed like a file (source ``builtin:<name>``)."""

from __future__ import annotations

import copy
import os
from pathlib import Path
from typing import Any

from camplace.errors import CamplaceError
from camplace.instance.events import comet_flyby_toml, volcanic_eruption_toml
from camplace.instance.parse import parse_instance
from camplace.instance.write import save_instance
from camplace.instance.schema import Instance

__all__ = ["BUILTINS", "builtin", "builtin_toml", "write_builtin"]

_DATA: dict[str, dict[str, Any]] = {
    # The thesis's Experiment 03: a ~0.6 m model of comet 67P in a 30 x 3 x 3 m lab corridor
    # (x along the corridor, z up); cameras stand at least 0.3 m from every wall.
    "comet-67p-bunker": {
        "schema_version": 1,
        "name": "comet-67p-bunker",
        "k": 3,
        "run": {"candidates": 2000, "points": 10000, "sampler": "chaotic", "seed": 0, "time_limit_s": 60.0},
        "camera": {
            "sensor_width_mm": 7.18,
            "sensor_height_mm": 5.32,
            "focal_length_mm": 8.0,
            "width_px": 1280,
            "height_px": 960,
            "near_m": 0.1,
            "far_m": 40.0,
        },
        "volume": {"min_m": [0.3, 0.3, 0.3], "max_m": [29.7, 2.7, 2.7]},
        "light": {"position_m": [10.5, 0.6, 2.8]},
        "target": {"name": "comet-67p", "shape": "bilobed-comet", "length_m": 0.6, "seed": 7},
        "occluders": [
            {
                "name": "corridor",
                "shape": "corridor",
                "size_m": [30.0, 3.0, 3.0],
                "position_m": [0.0, 0.0, 0.0],
                "rotation_deg": [0.0, 0.0, 0.0],
            }
        ],
        "frames": [
            {"weight": 1.0, "time_s": 0.0, "position_m": [12.0, 1.5, 1.5], "rotation_deg": [0.0, 0.0, 0.0]}
        ],
    },
    # A mixed team in the same corridor: two wide machine-vision cameras stand anywhere in the
    # corridor, one narrow science camera only downstream of the comet or on a mast; nobody within
    # 1 m of the model, a budget and a camera on each side of it (enforced by the solver).
    "comet-67p-team": {
        "schema_version": 1,
        "name": "comet-67p-team",
        "k": 3,
        "run": {"candidates": 2000, "points": 10000, "sampler": "chaotic", "seed": 0, "time_limit_s": 60.0},
        "cameras": [
            {"name": "wide", "cost": 900.0, "min_count": 1, "max_count": 2,
             "sensor_width_mm": 7.18, "sensor_height_mm": 5.32, "focal_length_mm": 4.0,
             "width_px": 1280, "height_px": 960, "near_m": 0.1, "far_m": 20.0},
            {"name": "science", "cost": 6000.0, "min_count": 0, "max_count": 1,
             "sensor_width_mm": 13.3, "sensor_height_mm": 13.3, "focal_length_mm": 50.0,
             "width_px": 2048, "height_px": 2048, "near_m": 0.5, "far_m": 40.0},
        ],
        "volumes": [
            {"min_m": [0.3, 0.3, 0.3], "max_m": [29.7, 2.7, 2.7], "models": ["wide"]},
            {"min_m": [14.0, 0.3, 1.0], "max_m": [22.0, 2.7, 2.7], "models": ["science"]},
        ],
        "mounts": [
            {"name": "mast", "shape": "box", "size_m": [0.1, 0.1, 2.0], "position_m": [9.0, 2.5, 1.3],
             "models": ["science"], "offset_m": 0.05},
        ],
        "keepouts": [{"min_m": [11.0, 0.0, 0.0], "max_m": [13.0, 3.0, 3.0]}],
        "team": {"budget": 8000.0},
        "zones": [
            {"name": "upstream", "min_m": [0.0, 0.0, 0.0], "max_m": [12.0, 3.0, 3.0], "min_cameras": 1},
            {"name": "downstream", "min_m": [12.0, 0.0, 0.0], "max_m": [30.0, 3.0, 3.0], "min_cameras": 1},
        ],
        "light": {"position_m": [10.5, 0.6, 2.8]},
        "target": {"name": "comet-67p", "shape": "bilobed-comet", "length_m": 0.6, "seed": 7},
        "occluders": [
            {"name": "corridor", "shape": "corridor", "size_m": [30.0, 3.0, 3.0],
             "position_m": [0.0, 0.0, 0.0], "rotation_deg": [0.0, 0.0, 0.0]},
        ],
        "frames": [
            {"weight": 1.0, "time_s": 0.0, "position_m": [12.0, 1.5, 1.5], "rotation_deg": [0.0, 0.0, 0.0]}
        ],
    },
}

# Built-ins whose event is generated from a seed (the run seed, unless given).
_FACTORIES = {"comet-flyby": comet_flyby_toml, "volcanic-eruption": volcanic_eruption_toml}

BUILTINS: dict[str, str] = {
    "comet-67p-bunker": "Experiment 03: 3 cameras around a 0.6 m comet 67P model in a 30 x 3 x 3 m lab corridor",
    "comet-67p-team": "a mixed team in the same corridor: two wide machine-vision cameras, one narrow science camera (volume or mast), a budget, two zones",
    "comet-flyby": "Experiment 01: a comet nucleus with coma and tail crossing the field on a hyperbola, 36 frames",
    "volcanic-eruption": "Experiment 02: a plume rising and drifting over a procedural volcano, peak drawn from the seed",
}


def _check(name: str) -> None:
    if name not in _DATA and name not in _FACTORIES:
        raise CamplaceError(f"no built-in instance named {name!r}; built-ins: {', '.join(sorted(BUILTINS))}")


def builtin_toml(name: str, seed: int | None = None) -> dict[str, Any]:
    """A fresh copy of the TOML data that defines built-in ``name``.

    Parameters
    ----------
    name : str
    seed : int or None
        For built-ins with a generated event (``comet-flyby``, ``volcanic-eruption``): the seed that
        draws it, also written as the instance's ``run.seed`` (default 0). Ignored by the others.
    """
    _check(name)
    if name in _FACTORIES:
        return _FACTORIES[name](0 if seed is None else int(seed))
    return copy.deepcopy(_DATA[name])


def builtin(name: str, seed: int | None = None) -> Instance:
    """Built-in instance ``name`` (meshes generated; source ``builtin:<name>``).

    Raises
    ------
    CamplaceError
        If there is no such built-in; the message lists the names.
    """
    return parse_instance(builtin_toml(name, seed), f"builtin:{name}", Path.cwd())


def write_builtin(name: str, path: str | os.PathLike[str], seed: int | None = None) -> None:
    """Write built-in ``name`` to ``path`` with its meshes as PLY files in ``<stem>_meshes/`` (``camplace init``)."""
    save_instance(builtin(name, seed), path, mesh_files=True)
