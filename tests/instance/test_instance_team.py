"""Camera teams in the instance (issue 31): [[cameras]], [[volumes]], [[mounts]], [[keepouts]], [team], [[zones]].

Parsing, the values stored in the frozen dataclasses, the round trip through ``save_instance`` and
every bad team as one InstanceError line naming the field and the fix (exit 2 from the CLI).
"""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from camplace.errors import InstanceError
from camplace.instance import builtin, builtin_toml, load_instance, parse_instance, save_instance
from camplace.instance.schema import KeepOut, Mount, Team, Volume, Zone

SRC = "team.toml"


@pytest.fixture
def team_data() -> dict:
    """The built-in mixed team with a cheap comet."""
    data = copy.deepcopy(builtin_toml("comet-67p-team"))
    data["target"]["subdivisions"] = 2
    return data


def _parse(data: dict, tmp_path: Path):
    return parse_instance(data, SRC, tmp_path)


def test_builtin_team_values(team_data, tmp_path) -> None:
    inst = _parse(team_data, tmp_path)
    team = inst.team
    assert isinstance(team, Team)
    assert team.model_names == ("wide", "science")
    wide, science = team.models
    assert (wide.cost, wide.min_count, wide.max_count, wide.focal_length_mm) == (900.0, 1, 2, 4.0)
    assert (science.cost, science.min_count, science.max_count, science.width_px) == (6000.0, 0, 1, 2048)
    assert inst.camera is wide and inst.cameras == (wide, science)
    assert [v.models for v in team.volumes] == [("wide",), ("science",)]
    assert isinstance(team.mounts[0], Mount) and team.mounts[0].models == ("science",) and team.mounts[0].offset_m == 0.05
    assert isinstance(team.keepouts[0], KeepOut) and team.keepouts[0].box == Volume((11.0, 0.0, 0.0), (13.0, 3.0, 3.0))
    assert team.budget == 8000.0
    assert team.zones == (Zone("upstream", (0.0, 0.0, 0.0), (12.0, 3.0, 3.0), 1, None),
                          Zone("downstream", (12.0, 0.0, 0.0), (30.0, 3.0, 3.0), 1, None))
    # Instance.volume of a team: the box around every region (the mast reaches below the volumes)
    lo, hi = np.asarray(inst.volume.min_m), np.asarray(inst.volume.max_m)
    mast = team.mounts[0].world()[0]
    assert np.all(lo <= mast.min(axis=0) - 0.05 + 1e-12) and np.all(hi >= np.asarray([29.7, 2.7, 2.7]))
    assert np.isclose(lo[2], 0.25)


def test_single_camera_file_has_no_team(tmp_path) -> None:
    inst = builtin("comet-67p-bunker")
    assert inst.team is None and inst.cameras == (inst.camera,) and inst.camera.name == "camera"


def test_old_camera_with_new_regions_is_a_one_model_team(tmp_path) -> None:
    data = copy.deepcopy(builtin_toml("comet-67p-bunker"))
    data["keepouts"] = [{"min_m": [11.0, 0.0, 0.0], "max_m": [13.0, 3.0, 3.0]}]
    inst = _parse(data, tmp_path)
    assert inst.team is not None and inst.team.model_names == ("camera",)
    assert inst.team.volumes == (Volume((0.3, 0.3, 0.3), (29.7, 2.7, 2.7)),)  # [volume] is a region for every model
    assert inst.volume == Volume((0.3, 0.3, 0.3), (29.7, 2.7, 2.7))


@pytest.mark.parametrize("mesh_files", [True, False])
def test_round_trip(team_data, tmp_path, mesh_files) -> None:
    team_data["keepouts"].append({"name": "pillar", "shape": "sphere", "radius_m": 0.4, "subdivisions": 1,
                                  "position_m": [20.0, 1.5, 1.5]})
    team_data["volumes"][1]["share"] = 2.5
    team_data["zones"][0]["max_cameras"] = 2
    a = _parse(team_data, tmp_path)
    save_instance(a, tmp_path / "out" / "team.toml", mesh_files=mesh_files)
    b = load_instance(tmp_path / "out" / "team.toml")
    assert b.team.models == a.team.models
    assert b.team.volumes == a.team.volumes and b.team.zones == a.team.zones and b.team.budget == a.team.budget
    for x, y in zip(a.team.mounts, b.team.mounts):
        assert (x.pose, x.models, x.offset_m, x.share) == (y.pose, y.models, y.offset_m, y.share)
        np.testing.assert_array_equal(x.world()[0], y.world()[0])
    assert b.team.keepouts[0].box == a.team.keepouts[0].box
    np.testing.assert_array_equal(a.team.keepouts[1].bounds()[0], b.team.keepouts[1].bounds()[0])
    assert b.volume == a.volume and b.camera == a.camera


def _cams(d):
    return d["cameras"]


# (id, mutation of the team data, expected field, text the message must contain)
BAD = [
    ("unknown-model-in-volume", lambda d: d["volumes"][1].update(models=["sciense"]), "volumes[1].models",
     "unknown camera model 'sciense'; did you mean 'science'?"),
    ("unknown-model-in-mount", lambda d: d["mounts"][0].update(models=["tele"]), "mounts[0].models", "unknown camera model 'tele'"),
    ("model-without-pose", lambda d: (d["mounts"].clear(), d["volumes"].pop(1)), "cameras[1]", "has no allowed pose"),
    ("budget-below-cheapest", lambda d: d["team"].update(budget=500.0), "team.budget", "below the cheapest camera (900)"),
    ("budget-below-minimum", lambda d: (d["team"].update(budget=1000.0), _cams(d)[0].update(min_count=2)), "team.budget",
     "min_count cameras (1800)"),
    ("min-counts-over-k", lambda d: (_cams(d)[0].update(min_count=2), _cams(d)[1].update(min_count=2, max_count=2)), "cameras",
     "add up to 4, more than k = 3"),
    ("max-counts-under-k", lambda d: (_cams(d)[0].update(max_count=1), _cams(d)[1].update(max_count=1)), "cameras",
     "add up to 2, fewer than k = 3"),
    ("max-below-min", lambda d: _cams(d)[0].update(min_count=2, max_count=1), "cameras[0].max_count", "must be >= min_count = 2"),
    ("min-count-over-k", lambda d: _cams(d)[1].update(min_count=4, max_count=4), "cameras[1].min_count", "exceed k = 3"),
    ("negative-cost", lambda d: _cams(d)[0].update(cost=-1.0), "cameras[0].cost", "must be >= 0"),
    ("duplicate-model", lambda d: _cams(d)[1].update(name="wide"), "cameras[1].name", "used twice"),
    ("model-without-name", lambda d: _cams(d)[1].pop("name"), "cameras[1].name", "missing required key"),
    ("camera-and-cameras", lambda d: d.update(camera=dict(_cams(d)[0])), "camera", "both [camera] and [[cameras]]"),
    ("cameras-as-table", lambda d: d.update(cameras=_cams(d)[0]), "cameras", "did you mean 'camera'?"),
    ("no-cameras", lambda d: d.update(cameras=[]), "cameras", "has no camera model"),
    ("no-region", lambda d: (d["volumes"].clear(), d["mounts"].clear()), "volumes", "no region where cameras may stand"),
    ("zone-unreachable", lambda d: d["zones"][0].update(min_m=[40.0, 0.0, 0.0], max_m=[50.0, 3.0, 3.0]), "zones[0].min_cameras",
     "no [[volumes]] or [[mounts]] region reaches into it"),
    ("zone-quota-over-k", lambda d: d["zones"][0].update(min_cameras=4), "zones[0].min_cameras", "must be <= 3"),
    ("zone-max-below-min", lambda d: d["zones"][0].update(max_cameras=0), "zones[0].max_cameras", "must be >= 1"),
    ("zone-empty-box", lambda d: d["zones"][1].update(max_m=[12.0, 3.0, 3.0]), "zones[1].max_m", "must exceed zones[1].min_m"),
    ("zone-twice", lambda d: d["zones"][1].update(name="upstream"), "zones[1].name", "used twice"),
    ("zone-typo", lambda d: d["zones"][0].update(min_camera=1), "zones[0].min_camera", "did you mean 'min_cameras'?"),
    ("team-typo", lambda d: d["team"].update(budjet=1.0), "team.budjet", "did you mean 'budget'?"),
    ("budget-zero", lambda d: d["team"].update(budget=0.0), "team.budget", "must be > 0"),
    ("share-zero", lambda d: d["volumes"][0].update(share=0), "volumes[0].share", "must be > 0"),
    ("offset-negative", lambda d: d["mounts"][0].update(offset_m=-0.1), "mounts[0].offset_m", "must be >= 0"),
    ("mount-without-mesh", lambda d: d["mounts"][0].pop("shape"), "mounts[0].shape", "missing mesh"),
    ("keepout-half-box", lambda d: d["keepouts"][0].pop("max_m"), "keepouts[0].max_m", "missing required key"),
    ("volume-inverted", lambda d: d["volumes"][0].update(min_m=[29.7, 0.3, 0.3], max_m=[0.3, 2.7, 2.7]), "volumes[0].max_m",
     "must exceed volumes[0].min_m"),
    ("models-not-list", lambda d: d["volumes"][0].update(models="wide"), "volumes[0].models", "non-empty array of model names"),
]


@pytest.mark.parametrize("case", BAD, ids=[c[0] for c in BAD])
def test_bad_team_is_one_line(team_data, tmp_path, case) -> None:
    _, mutate, field, text = case
    mutate(team_data)
    with pytest.raises(InstanceError) as info:
        _parse(team_data, tmp_path)
    msg = str(info.value)
    assert "\n" not in msg
    assert info.value.field == field, msg
    assert msg.startswith(f"{SRC}: {field}: "), msg
    assert text in msg, msg
    assert "(" in msg and msg.endswith(")"), msg  # the fix, in parentheses


def test_a_volume_inside_a_keepout_warns(team_data, tmp_path) -> None:
    team_data["keepouts"].append({"min_m": [13.0, 0.0, 0.0], "max_m": [23.0, 3.0, 3.0]})
    inst = _parse(team_data, tmp_path)
    assert any(w.startswith("volumes[1]: lies wholly inside a keep-out box") for w in inst.warnings)


def test_cli_bad_team_exits_2_without_traceback(team_data, tmp_path) -> None:
    import tomli_w

    team_data["volumes"][1]["models"] = ["sciense"]
    team_data["mounts"][0]["models"] = ["science"]
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(team_data))
    env = {**os.environ, "CAMPLACE_CACHE_DIR": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, "-m", "camplace", "run", str(path), "-o", str(tmp_path / "out")],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "volumes[1].models" in lines[0] and "did you mean 'science'?" in lines[0], r.stderr
