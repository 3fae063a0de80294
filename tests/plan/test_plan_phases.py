"""Splitting frames into phases, travel reach, and the [agents] table of an instance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from camplace.errors import CamplaceError, InstanceError
from camplace.instance import builtin_toml, load_instance, parse_instance, save_instance
from camplace.plan.phases import event_end_s, phase_of_frame, reach_m, split_phases, start_reach_m
from camplace.plan.workflow import agent_settings


def test_equal_durations_on_regular_frames():
    ph = split_phases(np.arange(36.0), 6)
    assert [p.frames for p in ph] == [tuple(range(6 * i, 6 * i + 6)) for i in range(6)]
    assert [p.start_s for p in ph] == pytest.approx([0, 6, 12, 18, 24, 30])
    assert ph[-1].end_s == pytest.approx(36.0)
    assert reach_m(ph, 5.0) == pytest.approx([30.0] * 5)


def test_equal_durations_follow_time_not_frame_count():
    t = np.array([0.0, 1.0, 2.0, 3.0, 10.0, 11.0])  # frames crowd early; the event lasts 12 s
    ph = split_phases(t, 2)
    assert [p.frames for p in ph] == [(0, 1, 2, 3), (4, 5)]
    assert [p.start_s for p in ph] == pytest.approx([0.0, 6.0])


def test_phase_starts():
    ph = split_phases(np.arange(10.0) * 2.0, phase_starts_s=[-1.0, 5.0, 9.5])
    assert [p.frames for p in ph] == [(0, 1, 2), (3, 4), (5, 6, 7, 8, 9)]
    assert reach_m(ph, 2.0) == pytest.approx([12.0, 9.0])
    assert list(phase_of_frame(ph, 10)) == [0, 0, 0, 1, 1, 2, 2, 2, 2, 2]


@pytest.mark.parametrize("kwargs", [
    {"n_phases": 11},  # more phases than frames
    {"phase_starts_s": [1.0, 4.0]},  # starts after the first frame
    {"phase_starts_s": [0.0, 3.2, 3.5]},  # phase 1 holds no frame
    {"phase_starts_s": [0.0, 0.0]},
    {},
])
def test_bad_phases_are_one_line_errors(kwargs):
    with pytest.raises(CamplaceError):
        split_phases(np.arange(10.0), **kwargs)


def test_start_reach_defaults_to_one_phase_duration():
    ph = split_phases(np.arange(12.0), 3)
    t0, r = start_reach_m(ph, 2.0, None)
    assert t0 == pytest.approx(-4.0) and r == pytest.approx(8.0)
    assert start_reach_m(ph, 2.0, -1.0) == pytest.approx((-1.0, 2.0))
    with pytest.raises(CamplaceError):
        start_reach_m(ph, 2.0, 0.0)
    assert event_end_s(np.array([5.0])) == 6.0
    assert math.isinf(reach_m(ph, math.inf)[0])


def _flyby_with(agents: dict):
    d = builtin_toml("comet-flyby")
    d["agents"] = agents
    return parse_instance(d, "test.toml", ".")


def test_agents_table_round_trip(tmp_path):
    inst = _flyby_with({"phase_starts_s": [0.0, 10.0, 20.0], "speed_m_s": 4.5,
                        "start_positions_m": [[0, 5, 0], [1, 6, 0], [2, 7, 0]], "start_time_s": -3.0})
    save_instance(inst, tmp_path / "i.toml")
    back = load_instance(tmp_path / "i.toml").agents
    assert back == inst.agents
    s = agent_settings(load_instance(tmp_path / "i.toml"), 3)
    assert [p.frames[0] for p in s.phases] == [0, 10, 20]
    assert s.reach_m == pytest.approx([45.0, 45.0])
    assert s.start_reach_m == pytest.approx(4.5 * 3.0)


def test_command_line_overrides_the_agents_table():
    inst = _flyby_with({"phases": 4, "speed_m_s": 1.0})
    s = agent_settings(inst, 3, phases=6, speed_m_s=5.0)
    assert len(s.phases) == 6 and s.reach_m == pytest.approx([30.0] * 5)
    s = agent_settings(inst, 3)
    assert len(s.phases) == 4 and s.speed_m_s == 1.0
    with pytest.raises(CamplaceError, match="--speed"):
        agent_settings(parse_instance(builtin_toml("comet-flyby"), "x", "."), 3, phases=3)
    with pytest.raises(CamplaceError, match="--phases"):
        agent_settings(parse_instance(builtin_toml("comet-flyby"), "x", "."), 3, speed_m_s=3.0)


@pytest.mark.parametrize("agents, field", [
    ({"speed_m_s": 1.0}, "agents"),
    ({"phases": 2, "phase_starts_s": [0.0], "speed_m_s": 1.0}, "agents"),
    ({"phases": 2}, "agents.speed_m_s"),
    ({"phases": 2, "speed_m_s": -1.0}, "agents.speed_m_s"),
    ({"phases": 99, "speed_m_s": 1.0}, "agents.phases"),
    ({"phase_starts_s": [3.0, 1.0], "speed_m_s": 1.0}, "agents.phase_starts_s"),
    ({"phases": 2, "speed_m_s": 1.0, "start_positions_m": [[0, 0, 0]]}, "agents.start_positions_m"),
    ({"phases": 2, "speed_m_s": 1.0, "start_positions_m": [[0, 0], [0, 0, 0], [1, 1, 1]]}, "agents.start_positions_m[0]"),
    ({"phases": 2, "speed_m_s": 1.0, "sped": 2}, "agents.sped"),
])
def test_agents_table_errors_name_the_field(agents, field):
    with pytest.raises(InstanceError) as exc:
        _flyby_with(agents)
    assert f"{field}:" in str(exc.value)
    assert "\n" not in str(exc.value)
