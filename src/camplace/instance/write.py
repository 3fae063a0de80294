"""Write an :class:`~camplace.instance.schema.Instance` back to an instance file (format v1, TOML).

Meshes go out as binary float64 PLY files (:func:`camplace.geometry.ply_bytes`) next to the file, so
``load_instance(save_instance(x))`` gives the same geometry bit for bit.
"""

from __future__ import annotations

import copy
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from camplace._io import write_bytes_atomic, write_text_atomic
from camplace.geometry import ply_bytes
from camplace.instance.lab import PhysicalCamera
from camplace.instance.parse import _one_line
from camplace.instance.schema import SCHEMA_VERSION, CameraModel, Instance, Mesh, QualitySpec, Team

__all__ = ["mesh_folder", "save_instance"]


def _slug(name: str) -> str:
    s = re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-.")
    return s or "mesh"


def _rel(target: Path, start: Path) -> str:
    try:
        return Path(os.path.relpath(target, start)).as_posix()
    except ValueError:  # different drives on Windows
        return target.as_posix()


def _vec(v) -> list[float]:
    return [float(x) for x in v]


def mesh_folder(path: str | os.PathLike[str]) -> Path:
    """The folder of the mesh files that :func:`save_instance` writes beside ``path``: ``<stem>_meshes/``."""
    out = Path(path)
    return out.parent / f"{out.stem}_meshes"


def save_instance(instance: Instance, path: str | os.PathLike[str], *, mesh_files: bool = True) -> None:
    """Write ``instance`` as a v1 TOML file (atomically) that :func:`load_instance` reads back.

    Parameters
    ----------
    instance : Instance
    path : path
        The ``.toml`` file to write.
    mesh_files : bool
        True: write every mesh (target and occluders) as a binary float64 PLY into ``<stem>_meshes/``
        beside ``path`` and reference it with a relative ``file = ...`` (exact geometry round trip; the
        procedural spec that made a mesh, if any, is kept as a comment). False: write each mesh's
        original spec (``Mesh.spec``): procedural specs as they are, ``file`` specs with the path
        rewritten relative to the new location; a mesh without a spec is written as a PLY anyway.
    """
    out = Path(path)
    out_dir = Path(os.path.abspath(out.parent))
    mesh_dir_name = mesh_folder(out).name
    comments: dict[str, str] = {}

    def mesh_table(mesh: Mesh, key: str, file_stem: str) -> dict:
        spec = dict(mesh.spec) if mesh.spec else {}
        is_file_spec = "file" in spec and mesh.source.startswith("file:")
        if not mesh_files and spec and ("shape" in spec or is_file_spec):
            table = copy.deepcopy(spec)
            if is_file_spec:
                table["file"] = _rel(Path(mesh.source[len("file:") :]), out_dir)
            table["name"] = mesh.name
            return {"name": table.pop("name"), **table}
        rel = f"{mesh_dir_name}/{file_stem}.ply"
        write_bytes_atomic(out_dir / rel, ply_bytes(mesh.vertices, mesh.faces, f"camplace mesh {mesh.name} (metres)"))
        if "shape" in spec:
            comments[key] = "generated from: " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in spec.items() if k != "name")
        elif is_file_spec:
            comments[key] = f"read from: {mesh.source[len('file:'):]}" + (f" (scale {spec['scale']})" if "scale" in spec else "")
        return {"name": mesh.name, "file": rel}

    def occluder_table(occ, key: str, file_stem: str) -> dict:
        """An occluder's mesh table with its pose (and ``ground``, which only static occluders have)."""
        t = mesh_table(occ.mesh, key, f"{file_stem}_{_slug(occ.mesh.name)}")
        t["position_m"] = _vec(occ.pose.position_m)
        t["rotation_deg"] = _vec(occ.pose.rotation_deg)
        if occ.ground:
            t["ground"] = True
        return t

    d = instance.defaults
    data: dict[str, Any] = {
        "schema_version": SCHEMA_VERSION,
        "name": instance.name,
        "k": int(instance.k),
        "run": {
            "candidates": int(d.candidates),
            "points": int(d.points),
            "sampler": d.sampler,
            "seed": int(d.seed),
            "time_limit_s": float(d.time_limit_s),
            "orientations": int(d.orientations),
        },
    }
    team = instance.team
    if team is None:
        data["camera"] = camera_table(instance.camera)
        data["volume"] = {"min_m": _vec(instance.volume.min_m), "max_m": _vec(instance.volume.max_m)}
    data.update({
        "light": {"position_m": _vec(instance.light.position_m)},
        "target": mesh_table(instance.target, "target", "target"),
    })
    if team is not None:
        data.update(team_tables(team, lambda mesh, key, stem: mesh_table(mesh, key, stem)))
    if instance.occluders:
        data["occluders"] = [occluder_table(occ, f"occluders[{i}]", f"occluder{i}")
                             for i, occ in enumerate(instance.occluders)]
    q = instance.quality
    if q != QualitySpec():
        data["quality"] = {
            "mode": q.mode,
            "required_px_per_m": float(q.required_px_per_m),
            "max_incidence_deg": float(q.max_incidence_deg),
            "require_light": bool(q.require_light),
        }
        if q.min_target_px:
            data["quality"]["min_target_px"] = float(q.min_target_px)
        if q.precision != QualitySpec().precision:
            data["quality"]["precision"] = q.precision
    if instance.robust is not None:
        r = instance.robust
        data["robust"] = {
            "position_sigma_m": float(r.position_sigma_m), "rotation_sigma_deg": float(r.rotation_sigma_deg),
            "scenarios": int(r.scenarios), "objective": r.objective, "eval_scenarios": int(r.eval_scenarios),
        }
    if instance.physical is not None:  # the fields that differ from a perfect camera
        perfect = PhysicalCamera().to_dict()
        data["physical"] = {k: v for k, v in instance.physical.to_dict().items() if v != perfect[k]}
    if instance.transform is not None:
        data["transform"] = instance.transform.to_dict()
    agents = getattr(instance, "agents", None)
    if agents is not None:
        at: dict[str, Any] = {}
        if agents.phases is not None:
            at["phases"] = int(agents.phases)
        else:
            at["phase_starts_s"] = [float(t) for t in agents.phase_starts_s or ()]
        at["speed_m_s"] = float(agents.speed_m_s)
        if agents.start_positions_m is not None:
            at["start_positions_m"] = [_vec(v) for v in agents.start_positions_m]
        if agents.start_time_s is not None:
            at["start_time_s"] = float(agents.start_time_s)
        data["agents"] = at
    frames = []
    for i, f in enumerate(instance.frames):
        ft: dict[str, Any] = {
            "weight": float(f.weight),
            "time_s": float(f.time_s),
            "position_m": _vec(f.target_pose.position_m),
            "rotation_deg": _vec(f.target_pose.rotation_deg),
        }
        if f.target_weight != 1.0:
            ft["target_weight"] = float(f.target_weight)
        if f.emitters is not None:
            src = f.emitters.source
            if not mesh_files and src.startswith("file:"):
                ft["emitters"] = {"file": _rel(Path(src[len("file:"):]), out_dir)}
            else:
                rel = f"{mesh_dir_name}/frame{i}_emitters.csv"
                table = np.column_stack([f.emitters.positions_m, f.emitters.weights])
                text = "x,y,z,weight\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in table)
                write_text_atomic(out_dir / rel, text)
                ft["emitters"] = {"file": rel}
        if f.occluders:
            ft["occluders"] = [occluder_table(occ, f"frames[{i}].occluders[{j}]", f"frame{i}_occluder{j}")
                               for j, occ in enumerate(f.occluders)]
        frames.append(ft)
    data["frames"] = frames

    head = f"# camplace instance, schema v{SCHEMA_VERSION} (metres, degrees). Written by camplace.instance.save_instance."
    write_text_atomic(out, _dumps_toml(data, comments, head))


def camera_table(cam: CameraModel, team: bool = False) -> dict[str, Any]:
    """A ``[camera]`` table, or with ``team`` a ``[[cameras]]`` one (name, cost and counts first)."""
    out: dict[str, Any] = {}
    if team:
        out["name"] = cam.name
        out["cost"] = float(cam.cost)
        out["min_count"] = int(cam.min_count)
        if cam.max_count is not None:
            out["max_count"] = int(cam.max_count)
    out.update({
        "sensor_width_mm": float(cam.sensor_width_mm),
        "sensor_height_mm": float(cam.sensor_height_mm),
        "focal_length_mm": float(cam.focal_length_mm),
        "width_px": int(cam.width_px),
        "height_px": int(cam.height_px),
        "near_m": float(cam.near_m),
        "far_m": float(cam.far_m),
    })
    return out


def team_tables(team: Team, mesh_table) -> dict[str, Any]:
    """The team's tables: ``cameras``, ``volumes``, ``mounts``, ``keepouts``, ``team``, ``zones``.

    ``mesh_table(mesh, key, file_stem)`` writes a mesh spec (as for the occluders).
    """
    out: dict[str, Any] = {"cameras": [camera_table(m, team=True) for m in team.models]}
    vols = []
    for v in team.volumes:
        t: dict[str, Any] = {"min_m": _vec(v.min_m), "max_m": _vec(v.max_m)}
        if v.models:
            t["models"] = list(v.models)
        if v.share != 1.0:
            t["share"] = float(v.share)
        vols.append(t)
    if vols:
        out["volumes"] = vols
    mounts = []
    for i, mt in enumerate(team.mounts):
        t = mesh_table(mt.mesh, f"mounts[{i}]", f"mount{i}_{_slug(mt.mesh.name)}")
        t["position_m"] = _vec(mt.pose.position_m)
        t["rotation_deg"] = _vec(mt.pose.rotation_deg)
        if mt.models:
            t["models"] = list(mt.models)
        t["offset_m"] = float(mt.offset_m)
        if mt.share != 1.0:
            t["share"] = float(mt.share)
        mounts.append(t)
    if mounts:
        out["mounts"] = mounts
    kos = []
    for i, ko in enumerate(team.keepouts):
        if ko.box is not None:
            kos.append({"min_m": _vec(ko.box.min_m), "max_m": _vec(ko.box.max_m)})
        else:
            t = mesh_table(ko.mesh, f"keepouts[{i}]", f"keepout{i}_{_slug(ko.mesh.name)}")
            t["position_m"] = _vec(ko.pose.position_m)
            t["rotation_deg"] = _vec(ko.pose.rotation_deg)
            kos.append(t)
    if kos:
        out["keepouts"] = kos
    if team.budget is not None:
        out["team"] = {"budget": float(team.budget)}
    zones = []
    for z in team.zones:
        t = {"name": z.name, "min_m": _vec(z.min_m), "max_m": _vec(z.max_m), "min_cameras": int(z.min_cameras)}
        if z.max_cameras is not None:
            t["max_cameras"] = int(z.max_cameras)
        zones.append(t)
    if zones:
        out["zones"] = zones
    return out


def _toml_value(value: Any) -> str:
    """Inline TOML for a scalar or an array of scalars (tomli_w does the escaping)."""
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):  # inline table (frame emitters and occluders)
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()) + " }"
    return tomli_w.dumps({"v": value})[len("v = ") :].strip()


def _dumps_toml(data: dict[str, Any], comments: dict[str, str], head: str) -> str:
    """TOML text of an instance dict: scalars, inline arrays, [tables], [[arrays of tables]]; with comments.

    ``comments`` maps ``"target"`` / ``"occluders[0]"`` to a line written just above that table.
    """

    def body(table: dict[str, Any]) -> list[str]:
        return [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in table.items()]

    lines = [head, ""]
    lines += body({k: v for k, v in data.items() if not isinstance(v, dict) and not _is_table_array(v)})
    for key, value in data.items():
        if isinstance(value, dict):
            lines.append("")
            if key in comments:
                lines.append(f"# {_one_line(comments[key])}")
            lines.append(f"[{_toml_key(key)}]")
            lines += body(value)
        elif _is_table_array(value):
            for i, item in enumerate(value):
                lines.append("")
                if f"{key}[{i}]" in comments:
                    lines.append(f"# {_one_line(comments[f'{key}[{i}]'])}")
                lines.append(f"[[{_toml_key(key)}]]")
                lines += body(item)
    text = "\n".join(lines) + "\n"
    tomllib.loads(text)  # never write a file we could not read back
    return text


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_value(key)
