"""A mixed camera team walked through the CLI (issue 31): init, run --report, render, export --format all, validate.

Whole commands in subprocesses (``python -m camplace``) at tiny sizes on the built-in
``comet-67p-team``; one camera column of the narrow science model is fixed so that the system
holds both models, and every output must carry each camera's model consistently: solution.json
(and its team record, ``enforced: true``, every constraint checked here on the cameras), candidates.csv, the report, the
renders (image size per model), cameras.json / cameras.csv, COLMAP (one camera entry per model)
and the GLB (frusta per model).
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from camplace.instance import builtin
from camplace.visibility.stages import make_run_candidates, stage_seeds

SIZES = ["--candidates", "60", "--points", "600"]


def _cli(*args: str, env: dict, cwd: Path) -> subprocess.CompletedProcess:
    r = subprocess.run([sys.executable, "-m", "camplace", *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=600)
    assert r.returncode == 0, f"camplace {' '.join(args)} exited {r.returncode}:\n{r.stderr[-3000:]}"
    assert "Traceback" not in r.stderr, r.stderr
    return r


@pytest.fixture(scope="module")
def team_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("team")
    env = {**os.environ, "CAMPLACE_CACHE_DIR": str(tmp / "cache"), "MPLBACKEND": "Agg"}
    # the first column of the science model among the run's candidates (same seed stream as the run)
    inst = builtin("comet-67p-team")
    cands = make_run_candidates(inst, "chaotic", 60, 1, stage_seeds(0)[0])
    science = int(np.flatnonzero(cands.model == 1)[0])
    out = tmp / "run"
    r = _cli("run", "comet-67p-team", "-o", str(out), *SIZES, "--fixed", str(science), "--report", "--report-systems", "10",
             env=env, cwd=tmp)
    return {"out": out, "env": env, "tmp": tmp, "science": science, "stderr": r.stderr, "inst": inst}


def _check_team_holds(sol: dict, inst) -> None:
    """Every constraint of the team holds on solution.json's cameras (checked here from the instance)."""
    team = inst.team
    cams = sol["cameras"]
    for m in team.models:
        c = sum(1 for cam in cams if cam["model"] == m.name)
        assert c >= m.min_count and (m.max_count is None or c <= m.max_count), (m.name, c)
    cost = sum(inst.cameras[cam["model_index"]].cost for cam in cams)
    assert team.budget is None or cost <= team.budget + 1e-9, cost
    for z in team.zones:
        inside = int(sum(bool(z.contains(np.array([cam["position"]]))[0]) for cam in cams))
        assert inside >= z.min_cameras and (z.max_cameras is None or inside <= z.max_cameras), (z.name, inside)
    poses = {(tuple(cam["position"]), tuple(map(tuple, cam["rotation"]))) for cam in cams}
    assert len(poses) == len(cams), "two cameras share a pose"
    rec = sol["team"]
    assert rec["enforced"] is True and rec["broken"] == [] and rec["cardinality"] == "budget"
    assert rec["uses"]["cost"] == pytest.approx(cost)
    assert sol["solver_stats"]["engine_choice"]["route"] == "team"


def test_run_records_models_and_enforces_the_team(team_run) -> None:
    out = team_run["out"]
    sol = json.loads((out / "solution.json").read_text())
    models = [c["model"] for c in sol["cameras"]]
    assert "science" in models and "wide" in models
    assert sol["cameras"][models.index("science")]["candidate"] == team_run["science"]
    inst = team_run["inst"]
    for c in sol["cameras"]:
        m = inst.cameras[c["model_index"]]
        assert m.name == c["model"] and c["width"] == m.width_px and c["K"] == m.K().tolist() and c["far_m"] == m.far_m
        assert c["cost"] == m.cost
    team = sol["team"]
    assert team["enforced"] is True and team["budget"] == 8000.0
    assert team["uses"]["models"] == {"wide": models.count("wide"), "science": models.count("science")}
    assert team["uses"]["cost"] == sum(c["cost"] for c in sol["cameras"])
    _check_team_holds(sol, inst)
    assert sol["status"] == "optimal"
    assert not any("not yet enforced" in w for w in sol["warnings"])
    assert "not yet enforced" not in team_run["stderr"]
    # candidates.csv: the model column, model-major
    with open(out / "candidates.csv") as fh:
        rows = list(csv.DictReader(fh))
    model_col = np.array([int(r["model"]) for r in rows])
    assert np.all(np.diff(model_col) >= 0) and set(model_col) == {0, 1}
    assert model_col[team_run["science"]] == 1
    # the run folder gives the solver round each column's model and zone membership
    from camplace.runfolder import RunFolder

    folder = RunFolder(out).candidates
    np.testing.assert_array_equal(folder.model, model_col)
    for c in sol["cameras"]:
        zones = [z.name for z, inside in zip(inst.team.zones, folder.zones[c["candidate"]]) if inside]
        assert zones == c["zones"] and len(zones) == 1
    # the instance copy keeps the team
    from camplace.instance import load_instance

    again = load_instance(out / "instance.toml")
    assert again.team.model_names == ("wide", "science") and again.team.budget == 8000.0


def test_report_names_the_models(team_run) -> None:
    html = (team_run["out"] / "report.html").read_text()
    assert "camera model wide" in html and "camera model science" in html
    assert "enforced by the solver" in html and "not yet enforced" not in html
    assert "<td class='l'>science</td>" in html or ">science<" in html
    # the 3D view draws each chosen camera's frustum with its model's intrinsics
    from camplace.report.compare import load_run_data
    from camplace.report.run_scene import run_scene

    sol = json.loads((team_run["out"] / "solution.json").read_text())
    scene = run_scene(load_run_data(team_run["out"]))
    assert [c.width_px for c in scene.cameras] == [c["width"] for c in sol["cameras"]]
    assert len({c.width_px for c in scene.cameras}) == 2


def test_render_sizes_follow_the_model(team_run) -> None:
    _cli("render", str(team_run["out"]), env=team_run["env"], cwd=team_run["tmp"])
    doc = json.loads((team_run["out"] / "render" / "render.json").read_text())
    from PIL import Image

    inst = team_run["inst"]
    sizes = {m.name: (m.width_px, m.height_px) for m in inst.cameras}
    assert {im["model"] for im in doc["images"]} == {"wide", "science"}
    for im in doc["images"]:
        with Image.open(team_run["out"] / "render" / im["image"]) as img:
            assert img.size == sizes[im["model"]]


def test_export_all_carries_the_model(team_run) -> None:
    _cli("export", str(team_run["out"]), "--format", "all", env=team_run["env"], cwd=team_run["tmp"])
    ex = team_run["out"] / "export"
    sol = json.loads((team_run["out"] / "solution.json").read_text())
    want = [c["model"] for c in sol["cameras"]]
    cams = json.loads((ex / "cameras.json").read_text())["cameras"]
    assert [c["model"] for c in cams] == want
    inst = team_run["inst"]
    for c in cams:
        m = inst.cameras[inst.team.model_names.index(c["model"])]
        assert abs(c["fov_x_deg"] - m.fov_x_deg) < 1e-9 and c["width"] == m.width_px
    with open(ex / "cameras.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["model"] for r in rows] == want
    # COLMAP: one camera entry per model, each image pointing at its model's entry
    cam_lines = [ln.split() for ln in (ex / "colmap" / "cameras.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    assert len(cam_lines) == len(set(want)) == 2
    size_of = {int(ln[0]): (int(ln[2]), int(ln[3])) for ln in cam_lines}
    img_lines = [ln.split() for ln in (ex / "colmap" / "images.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    assert len(img_lines) == len(want)
    for ln, model in zip(img_lines, want):
        m = inst.cameras[inst.team.model_names.index(model)]
        assert size_of[int(ln[8])] == (m.width_px, m.height_px)
    # GLB: a frustum per camera, named by model
    import trimesh

    scene = trimesh.load(ex / "cameras.glb", force="scene")
    frusta = [n for n in scene.graph.nodes_geometry if n.startswith("frustum.")]
    assert sorted(n.split(".")[1] for n in frusta) == sorted(want)


def test_validate_scores_each_camera_with_its_model(team_run) -> None:
    _cli("validate", str(team_run["out"]), env=team_run["env"], cwd=team_run["tmp"])
    doc = json.loads((team_run["out"] / "validation" / "validation.json").read_text())
    sol = json.loads((team_run["out"] / "solution.json").read_text())
    # the installed system, ray cast again at its (unperturbed) poses with each camera's model, scores the run's objective
    assert abs(doc["installed"]["systems"][0]["objective"]["mean"] - sol["objective"]) < 1e-9
    assert [c["model"] for c in doc["cameras"]] == [c["model"] for c in sol["cameras"]]
    assert [c["width"] for c in doc["cameras"]] == [c["width"] for c in sol["cameras"]]
    # the science camera alone: its model's intrinsics give its own column of the run's matrix, the wide model's would not
    from camplace.instance import load_instance
    from camplace.solution import Solution
    from camplace.validation.cameras import CameraSet
    from camplace.validation.installed import installed_objective, load_run_objective
    from camplace.visibility.store import load_visibility

    out = team_run["out"]
    inst = load_instance(out / "instance.toml")
    objective = load_run_objective(out, inst)
    views = CameraSet.from_solution(Solution.load(out)).cameras
    science = [v for v in views if v.model == "science"]
    assert len(science) == 1
    column = load_visibility(out / "visibility.cpm")[:, team_run["science"]].toarray().ravel() > 0
    want = float(objective.weights[column].sum())
    got, _ = installed_objective(inst, objective, [science])
    assert abs(got[0] - want) < 1e-9
    # a close view (1.1 m) where the narrow science model sees only a patch of the comet and the wide one all of it
    from camplace.geometry import look_at

    pos = np.array([10.9, 1.5, 1.5])
    rot = look_at(pos[None], np.array([[12.0, 1.5, 1.5]]))[0]
    close = {m.name: type(science[0])(m.name, pos, rot, m.K(), m.width_px, m.height_px, model=m.name) for m in inst.cameras}
    v_sci, _ = installed_objective(inst, objective, [[close["science"]]])
    v_wide, _ = installed_objective(inst, objective, [[close["wide"]]])
    assert v_wide[0] > v_sci[0] + 0.05, (v_wide, v_sci)


def test_init_writes_the_mixed_team(tmp_path) -> None:
    env = {**os.environ}
    _cli("init", "comet-67p-team", "-o", str(tmp_path / "team.toml"), env=env, cwd=tmp_path)
    text = (tmp_path / "team.toml").read_text()
    assert text.count("[[cameras]]") == 2 and "[team]" in text and text.count("[[zones]]") == 2 and "[[mounts]]" in text
    from camplace.instance import load_instance

    inst = load_instance(tmp_path / "team.toml")
    assert inst.team.model_names == ("wide", "science")


_GAP_ZONE = """
[[zones]]
name = "gap"
min_m = [11.2, 0.0, 0.0]
max_m = [12.8, 3.0, 3.0]
min_cameras = 1
"""  # inside the keep-out: no camera of any model may stand there


def test_solve_enforces_the_team_and_an_impossible_quota_exits_1(team_run, tmp_path) -> None:
    """``camplace solve`` on the run folder builds the same constraints; a quota no pose can meet
    (a zone inside the keep-out) is infeasible: exit 1 from ``solve`` and from ``run``."""
    import shutil

    env, out = team_run["env"], team_run["out"]
    r = _cli("solve", str(out), "--fixed", str(team_run["science"]), "-o", str(tmp_path / "again.json"), env=env, cwd=tmp_path)
    again = json.loads((tmp_path / "again.json").read_text())
    sol = json.loads((out / "solution.json").read_text())
    assert again["status"] == "optimal" and abs(again["objective"] - sol["objective"]) < 1e-9
    assert team_run["science"] in again["selected"]
    assert again["options"]["team"]["cardinality"] == "budget" and again["stats"]["engine_choice"]["route"] == "team"
    # the same folder with the impossible zone added to its instance
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    (bad / "instance.toml").write_text((bad / "instance.toml").read_text() + _GAP_ZONE)
    r = subprocess.run([sys.executable, "-m", "camplace", "solve", str(bad), "-o", str(tmp_path / "bad.json")],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    assert r.returncode == 1, (r.stdout, r.stderr[-2000:])
    assert r.stdout.startswith("infeasible") and "Traceback" not in r.stderr
    assert json.loads((tmp_path / "bad.json").read_text())["status"] == "infeasible"
    # and a whole run of such an instance
    from camplace.instance import save_instance

    save_instance(team_run["inst"], tmp_path / "team.toml")
    (tmp_path / "team.toml").write_text((tmp_path / "team.toml").read_text() + _GAP_ZONE)
    r = subprocess.run([sys.executable, "-m", "camplace", "run", str(tmp_path / "team.toml"), "-o", str(tmp_path / "run"),
                        *SIZES], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    assert r.returncode == 1, (r.stdout, r.stderr[-2000:])
    assert r.stdout.startswith("infeasible") and "Traceback" not in r.stderr


@pytest.mark.parametrize("flags", [["--mode", "quality"], ["--mode", "multiview", "--views", "2"],
                                   ["--mode", "multiview", "--views", "2", "--min-angle", "20"]],
                         ids=["quality", "multiview", "multiview-angle"])
def test_solve_enforces_the_team_in_quality_and_multiview(team_run, tmp_path, flags) -> None:
    """``camplace solve`` in modes quality and multiview (with and without a minimum angle) on the
    team run's folder: the team route, every constraint met, optimal (budget cardinality: no k)."""
    from camplace.runfolder import RunFolder
    from camplace.solver.problem.team import TeamConstraints

    env, out = team_run["env"], team_run["out"]
    _cli("solve", str(out), *flags, "--fixed", str(team_run["science"]), "-o", str(tmp_path / "s.json"), env=env,
         cwd=tmp_path)
    got = json.loads((tmp_path / "s.json").read_text())
    assert got["status"] == "optimal" and got["gap"] == 0.0 and got["objective"] > 0, got["status"]
    assert got["stats"]["engine_choice"]["route"] == "team" and got["options"]["team"]["cardinality"] == "budget"
    assert team_run["science"] in got["selected"]
    team = TeamConstraints.from_team(team_run["inst"].team, RunFolder(out).candidates)
    assert team.violations(got["selected"], fixed=[team_run["science"]]) == []
