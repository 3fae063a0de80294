"""Hypothesis fuzzer over instance files: every input loads or fails with one clean InstanceError line."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camplace.errors import CamplaceError, InstanceError
from camplace.instance import load_instance, parse_instance

from .counts import COUNTS

BASE = {
    "schema_version": 1,
    "name": "fuzz",
    "k": 2,
    "run": {"candidates": 50, "points": 100, "sampler": "uniform", "seed": 1, "time_limit_s": 5.0, "orientations": 1},
    "camera": {"sensor_width_mm": 7.0, "sensor_height_mm": 5.0, "focal_length_mm": 8.0, "width_px": 64,
               "height_px": 48, "near_m": 0.1, "far_m": 50.0},
    "volume": {"min_m": [-5.0, -5.0, -5.0], "max_m": [5.0, 5.0, 5.0]},
    "light": {"position_m": [0.0, 0.0, 10.0]},
    "quality": {"mode": "graded", "required_px_per_m": 100.0, "max_incidence_deg": 80.0, "require_light": True},
    "target": {"name": "ball", "shape": "sphere", "radius_m": 0.5, "subdivisions": 1},
    "occluders": [{"name": "wall", "shape": "box", "size_m": [0.1, 2.0, 2.0], "position_m": [2.0, 0.0, 0.0]}],
    "frames": [
        {"weight": 1.0, "time_s": 0.0, "position_m": [0.0, 0.0, 0.0], "rotation_deg": [0.0, 0.0, 0.0]},
        {"weight": 0.5, "position_m": [0.5, 0.0, 0.0], "target_weight": 1.0,
         "emitters": {"positions_m": [[0.0, 0.0, 1.0]], "weights": [0.3]}},
    ],
}

junk = st.one_of(
    st.none(),  # None means: delete the key
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1, 2, 10**9, 0.0, -0.0, 1e-300, 1e300, math.nan, math.inf, -math.inf]),
    st.text(max_size=20),
    st.sampled_from(["sphere", "box", "corridor", "volcano", "bilobed-comet", "chaotic", "sobol", "peak", "graded"]),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
    st.lists(st.integers(-3, 3), max_size=4),
    st.lists(st.lists(st.floats(-10, 10), min_size=3, max_size=3), max_size=3),
    st.dictionaries(st.text(max_size=8), st.integers(), max_size=3),
)


def paths(obj, prefix=()):
    """Every (container path, key) in a nested dict/list."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield prefix, k
            yield from paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield prefix, i
            yield from paths(v, prefix + (i,))


ALL_PATHS = list(paths(BASE))


def mutate(data: dict, edits) -> dict:
    data = copy.deepcopy(data)
    for (where, key), value, extra_key in edits:
        try:
            parent = data
            for p in where:
                parent = parent[p]
        except (KeyError, IndexError, TypeError):
            continue
        if extra_key is not None and isinstance(parent, dict):
            parent[extra_key] = value  # an unknown key
        elif value is None:
            if isinstance(parent, dict):
                parent.pop(key, None)
            elif isinstance(parent, list) and isinstance(key, int) and key < len(parent):
                parent.pop(key)
        else:
            try:
                parent[key] = value
            except (IndexError, TypeError):
                pass
    return data


def check(data, source: str, base_dir: Path) -> None:
    COUNTS["inputs tried"] += 1
    try:
        parse_instance(data, source, base_dir)
    except InstanceError as exc:
        msg = str(exc)
        assert "\n" not in msg and msg.startswith(source), msg
    except CamplaceError as exc:  # pragma: no cover - would be a wrongly classified error
        pytest.fail(f"CamplaceError instead of InstanceError: {exc}")


edit = st.tuples(st.sampled_from(ALL_PATHS), junk, st.one_of(st.none(), st.sampled_from(["focal_lenght_mm", "extra", "zz"])))


@settings(max_examples=2500, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(st.lists(edit, min_size=1, max_size=4))
def test_mutated_instances_fail_cleanly(tmp_path_factory, edits) -> None:
    check(mutate(BASE, edits), "fuzz.toml", tmp_path_factory.getbasetemp())


@settings(max_examples=600, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(st.data())
def test_corrupted_toml_text_fails_cleanly(tmp_path_factory, data) -> None:
    text = tomli_w.dumps(BASE)
    pos = data.draw(st.integers(0, len(text) - 1))
    cut = data.draw(st.integers(0, 40))
    insert = data.draw(st.text(max_size=12))
    bad = text[:pos] + insert + text[pos + cut:]
    f = tmp_path_factory.getbasetemp() / "fuzz-text.toml"
    f.write_bytes(bad.encode("utf-8", "surrogatepass") if "\ud800" not in bad else b"\xff\xfe")
    COUNTS["inputs tried"] += 1
    try:
        load_instance(f)
    except InstanceError as exc:
        assert "\n" not in str(exc) and str(exc).startswith(str(f)), str(exc)


def test_base_instance_is_valid(tmp_path: Path) -> None:
    inst = parse_instance(copy.deepcopy(BASE), "fuzz.toml", tmp_path)
    assert inst.k == 2 and len(inst.frames) == 2


# A mixed camera team (issue 31): the same mutations over the team tables.
TEAM_BASE = {k: copy.deepcopy(v) for k, v in BASE.items() if k not in ("camera", "volume")}
TEAM_BASE.update({
    "k": 3,
    "cameras": [
        {"name": "wide", "cost": 900.0, "min_count": 1, "max_count": 2, "sensor_width_mm": 7.0, "sensor_height_mm": 5.0,
         "focal_length_mm": 4.0, "width_px": 64, "height_px": 48, "near_m": 0.1, "far_m": 20.0},
        {"name": "tele", "cost": 5000.0, "max_count": 1, "sensor_width_mm": 13.0, "sensor_height_mm": 13.0,
         "focal_length_mm": 50.0, "width_px": 32, "height_px": 32, "near_m": 0.5, "far_m": 50.0},
    ],
    "volumes": [{"min_m": [-5.0, -5.0, -5.0], "max_m": [5.0, 5.0, 5.0], "models": ["wide"]},
                {"min_m": [2.0, -5.0, 0.0], "max_m": [5.0, 5.0, 5.0], "models": ["tele"], "share": 2.0}],
    "mounts": [{"name": "mast", "shape": "box", "size_m": [0.1, 0.1, 2.0], "position_m": [-3.0, 0.0, 0.0],
                "models": ["tele", "wide"], "offset_m": 0.05}],
    "keepouts": [{"min_m": [-1.0, -1.0, -1.0], "max_m": [1.0, 1.0, 1.0]},
                 {"shape": "sphere", "radius_m": 0.5, "subdivisions": 1, "position_m": [3.0, 3.0, 3.0]}],
    "team": {"budget": 8000.0},
    "zones": [{"name": "east", "min_m": [0.0, -5.0, -5.0], "max_m": [5.0, 5.0, 5.0], "min_cameras": 1, "max_cameras": 2}],
})
TEAM_PATHS = [p for p in paths(TEAM_BASE) if p[0][:1] in (("cameras",), ("volumes",), ("mounts",), ("keepouts",), ("team",), ("zones",))
              or p[1] in ("cameras", "volumes", "mounts", "keepouts", "team", "zones", "k")]
team_edit = st.tuples(st.sampled_from(TEAM_PATHS), junk, st.one_of(st.none(), st.sampled_from(["modells", "extra", "min_count"])))


def test_team_base_instance_is_valid(tmp_path: Path) -> None:
    inst = parse_instance(copy.deepcopy(TEAM_BASE), "fuzz.toml", tmp_path)
    assert inst.team is not None and inst.team.model_names == ("wide", "tele") and len(inst.team.keepouts) == 2


@settings(max_examples=1500, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(st.lists(team_edit, min_size=1, max_size=4))
def test_mutated_teams_fail_cleanly(tmp_path_factory, edits) -> None:
    check(mutate(TEAM_BASE, edits), "fuzz.toml", tmp_path_factory.getbasetemp())
