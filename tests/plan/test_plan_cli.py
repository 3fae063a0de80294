"""``camplace run --phases --speed``, ``camplace plan``, the plan files, and the --phase hooks, end to end.

Every number is re-derived here from the folder alone: feasibility from ``candidates.csv`` positions
and the phases' start times, the objective from ``visibility.cpm`` and ``points.csv``.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

import camplace
import pytest
import scipy.sparse as sp

from camplace.cli import main
from tests.plan._oracle import plan_violations, set_value

SMALL = ["--candidates", "20", "--orientations", "2", "--points", "200", "--time-limit", "20"]
KEYS = ("status", "objective", "bound", "gap", "static_objective", "unconstrained_bound", "speed_m_s", "phases", "agents")


def _csv(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _folder(outdir: Path):
    cands = _csv(outdir / "candidates.csv")
    pos = np.array([[float(r["x"]), float(r["y"]), float(r["z"])] for r in cands])
    pts = _csv(outdir / "points.csv")
    frame = np.array([int(r["frame"]) for r in pts])
    weight = np.array([float(r["weight"]) for r in pts])
    q = camplace.load_visibility(outdir).tocsr()
    return pos, frame, weight, q


def _recompute(outdir: Path, doc: dict, mode: str = "maxcover") -> float:
    pos, frame, weight, q = _folder(outdir)
    plan = np.array([ag["candidates"] for ag in doc["agents"]])
    total = 0.0
    for ph in doc["phases"]:
        rows = np.isin(frame, ph["frames"])
        sub = q[np.flatnonzero(rows)]
        cols = sorted(set(plan[:, ph["index"]].tolist()))
        total += set_value(sub[:, cols].toarray(), weight[rows], range(len(cols)), mode)
    return total


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("plan") / "flyby"
    assert main(["run", "comet-flyby", "-o", str(out), *SMALL, "--phases", "4", "--speed", "5"]) == 0
    return out


def test_run_writes_a_feasible_plan_with_a_recomputable_objective(run_dir):
    doc = json.loads((run_dir / "plan.json").read_text())
    for key in KEYS:
        assert key in doc
    assert [ph["start_s"] for ph in doc["phases"]] == pytest.approx([0.0, 9.0, 18.0, 27.0])  # 36 frames of 1 s
    assert sorted(f for ph in doc["phases"] for f in ph["frames"]) == list(range(36))
    pos, *_ = _folder(run_dir)
    plan = np.array([ag["candidates"] for ag in doc["agents"]])
    assert plan.shape == (3, 4)
    assert plan_violations(plan, pos, [ph["start_s"] for ph in doc["phases"]], 5.0) == []
    assert doc["objective"] == pytest.approx(_recompute(run_dir, doc), rel=1e-9)
    sol = json.loads((run_dir / "solution.json").read_text())
    assert doc["static_objective"] == pytest.approx(sol["objective"], rel=1e-9)  # the same weights: one scale
    assert doc["static_objective"] <= doc["objective"] * (1 + 1e-12) <= doc["bound"] * (1 + 1e-9)
    assert doc["bound"] <= doc["unconstrained_bound"] * (1 + 1e-12)
    assert doc["status"] in ("optimal", "feasible") and 0 <= doc["gap"] <= 0.01


def test_plan_csv_and_light_curves_agree_with_plan_json(run_dir):
    doc = json.loads((run_dir / "plan.json").read_text())
    pos, frame, weight, q = _folder(run_dir)
    rows = _csv(run_dir / "plan.csv")
    assert len(rows) == 3 * 4
    for r in rows:
        a, p, j = int(r["agent"]), int(r["phase"]), int(r["candidate"])
        assert doc["agents"][a]["candidates"][p] == j
        assert [float(r["x"]), float(r["y"]), float(r["z"])] == pytest.approx(pos[j].tolist())
        prev = pos[doc["agents"][a]["candidates"][p - 1]] if p else pos[j]
        assert float(r["travel_m"]) == pytest.approx(float(np.linalg.norm(pos[j] - prev)), abs=1e-9)
        assert float(r["start_s"]) == doc["phases"][p]["start_s"]
    curves = _csv(run_dir / "plan_light_curves.csv")
    assert len(curves) == 3 * 36
    csc = q.tocsc()
    for r in curves[::17]:
        j, f = int(r["candidate"]), int(r["frame"])
        seen = csc.indices[csc.indptr[j]:csc.indptr[j + 1]]
        expect = float(weight[seen][frame[seen] == f].sum())
        assert float(r["observed_weight"]) == pytest.approx(expect, rel=1e-9, abs=1e-15)
    timeline = _csv(run_dir / "plan_timeline.csv")
    assert sum(float(r["plan_value"]) for r in timeline) == pytest.approx(doc["objective"], rel=1e-9)
    assert sum(float(r["static_value"]) for r in timeline) == pytest.approx(doc["static_objective"], rel=1e-9)


def test_plan_verb_speed_limits(run_dir, tmp_path):
    assert main(["plan", str(run_dir), "--phases", "4", "--speed", "1000", "-o", str(tmp_path / "fast")]) == 0
    fast = json.loads((tmp_path / "fast" / "plan.json").read_text())
    assert fast["status"] == "optimal"
    assert fast["objective"] == pytest.approx(fast["unconstrained_bound"], rel=1e-9)
    assert main(["plan", str(run_dir), "--phases", "4", "--speed", "0", "-o", str(tmp_path / "still")]) == 0
    still = json.loads((tmp_path / "still" / "plan.json").read_text())
    pos, *_ = _folder(run_dir)
    for ag in still["agents"]:  # only re-aiming: every pose of an agent at one position
        assert np.ptp(pos[ag["candidates"]], axis=0) == pytest.approx([0, 0, 0])
    assert still["objective"] >= still["static_objective"] * (1 - 1e-12)
    assert still["objective"] <= fast["objective"] * (1 + 1e-12)


def test_phase_starts_and_start_positions(run_dir, tmp_path):
    pos, *_ = _folder(run_dir)
    starts = ";".join(",".join(str(v) for v in pos[j]) for j in (0, 2, 4))
    assert main(["plan", str(run_dir), "--phase-starts", "0,10,25", "--speed", "3", "--start-positions", starts,
                 "--start-time", "-2", "-o", str(tmp_path / "p")]) == 0
    doc = json.loads((tmp_path / "p" / "plan.json").read_text())
    assert [ph["start_s"] for ph in doc["phases"]] == [0.0, 10.0, 25.0]
    plan = np.array([ag["candidates"] for ag in doc["agents"]])
    start = np.array([pos[j] for j in (0, 2, 4)])
    assert plan_violations(plan, pos, [0.0, 10.0, 25.0], 3.0, start, -2.0) == []
    assert doc["objective"] == pytest.approx(_recompute(run_dir, doc), rel=1e-9)


def test_export_cameras_of_a_phase(run_dir, tmp_path):
    doc = json.loads((run_dir / "plan.json").read_text())
    assert main(["export", str(run_dir), "--phase", "2", "--format", "json", "-o", str(tmp_path / "e")]) == 0
    cams = json.loads((tmp_path / "e" / "cameras.json").read_text())["cameras"]
    assert [c["candidate"] for c in cams] == [ag["candidates"][2] for ag in doc["agents"]]


@pytest.mark.parametrize("argv", [
    ["plan", "{d}", "--speed", "5"],  # no phases (and no [agents] table)
    ["plan", "{d}", "--phases", "4"],  # no speed
    ["plan", "{d}", "--phases", "99", "--speed", "1"],
    ["plan", "{d}", "--phases", "4", "--speed", "-1"],
    ["plan", "{d}", "--phases", "4", "--speed", "1", "--start-positions", "1,2"],
    ["plan", "{d}", "--phases", "4", "--speed", "1", "--mode", "setcover"],
    ["plan", "{d}", "--phases", "4", "--speed", "1", "--start-time", "-1"],  # no start positions
    ["export", "{d}", "--format", "all", "--phase", "7"],
])
def test_bad_plan_input_is_a_one_line_error(run_dir, argv, capsys):
    code = main([a.format(d=run_dir) for a in argv])
    err = capsys.readouterr().err
    assert code == 2
    assert err.strip().splitlines()[-1].startswith("error:") and "Traceback" not in err


@pytest.mark.slow
def test_report_has_the_plan_section(run_dir):
    from camplace.report.build import write_report

    path = write_report(run_dir, sampler_study=False)
    page = path.read_text()
    assert "id='plan'" in page and "Moving agents" in page
    section = page[page.index("id='plan'"):]
    assert section.count("<img src=\"data:image/png;base64,") >= 2


@pytest.mark.slow
def test_render_a_phase(run_dir, tmp_path):
    doc = json.loads((run_dir / "plan.json").read_text())
    frame = doc["phases"][1]["frames"][0]
    assert main(["render", str(run_dir), "--phase", "1", "--frames", str(frame), "-o", str(tmp_path / "r"), "--workers", "1"]) == 0
    rec = json.loads((tmp_path / "r" / "render.json").read_text())
    assert [im["candidate"] for im in rec["images"]] == [ag["candidates"][1] for ag in doc["agents"]]
    assert {im["frame"] for im in rec["images"]} == {frame}


@pytest.mark.slow
def test_run_plans_from_the_agents_table(tmp_path):
    toml = tmp_path / "flyby.toml"
    assert main(["init", "comet-flyby", "-o", str(toml)]) == 0
    toml.write_text(toml.read_text() + "\n[agents]\nphase_starts_s = [0.0, 12.0, 24.0]\nspeed_m_s = 2.0\n")
    out = tmp_path / "out"
    assert main(["run", str(toml), "-o", str(out), *SMALL]) == 0
    doc = json.loads((out / "plan.json").read_text())
    assert [ph["start_s"] for ph in doc["phases"]] == [0.0, 12.0, 24.0] and doc["speed_m_s"] == 2.0
    pos, *_ = _folder(out)
    plan = np.array([ag["candidates"] for ag in doc["agents"]])
    assert plan_violations(plan, pos, [0.0, 12.0, 24.0], 2.0) == []
    assert doc["objective"] == pytest.approx(_recompute(out, doc), rel=1e-9)


def test_run_rejects_bad_agent_options_before_the_run(tmp_path, capsys):
    out = tmp_path / "never"
    assert main(["run", "comet-flyby", "-o", str(out), *SMALL, "--phases", "99", "--speed", "1"]) == 2
    assert "--phases" in capsys.readouterr().err
    assert not (out / "solution.json").exists()
