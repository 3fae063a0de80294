"""End-to-end CLI tests: outputs, their consistency, determinism and one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from camplace.cli import main
from camplace.visibility.store import load_visibility
from tests._package import subprocess_env

SMALL = ["--candidates", "150", "--points", "1500"]


def run_cli(*args: str) -> tuple[int, str, str]:
    """Run the CLI in a fresh interpreter (as a user would), returning (code, stdout, stderr)."""
    p = subprocess.run([sys.executable, "-m", "camplace", *args], capture_output=True, text=True, env=subprocess_env(),
                       timeout=600)
    return p.returncode, p.stdout, p.stderr


@pytest.fixture(scope="module")
def small_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run") / "out"
    assert main(["run", "comet-67p-bunker", "-o", str(out), *SMALL, "--seed", "3"]) == 0
    return out


def test_instances_lists_builtin(capsys) -> None:
    assert main(["instances"]) == 0
    assert "comet-67p-bunker" in capsys.readouterr().out


def test_run_outputs_are_consistent(small_run: Path) -> None:
    sol = json.loads((small_run / "solution.json").read_text())
    for key in ("status", "objective", "bound", "gap", "k", "seed", "sampler", "n_candidates", "n_points",
                "coverage_fraction", "timings_s", "versions", "cameras"):
        assert key in sol, key
    assert sol["status"] == "optimal" and sol["k"] == 3 and len(sol["cameras"]) == 3
    assert sol["bound"] >= sol["objective"] - 1e-12 and sol["gap"] <= 1e-9
    A = load_visibility(small_run)
    pts = np.loadtxt(small_run / "points.csv", delimiter=",", skiprows=1)
    cands = np.loadtxt(small_run / "candidates.csv", delimiter=",", skiprows=1)
    assert A.shape == (len(pts), len(cands)) == (sol["n_points"], sol["n_candidates"])
    chosen = [c["candidate"] for c in sol["cameras"]]
    covered = np.asarray((A[:, chosen] > 0).sum(axis=1)).ravel() > 0
    assert sol["objective"] == pytest.approx(pts[covered, 8].sum(), rel=1e-6)
    assert sol["coverage_fraction"] == pytest.approx(sol["objective"] / pts[:, 8].sum(), rel=1e-9)
    for cam in sol["cameras"]:
        row = cands[cam["candidate"]]
        assert np.allclose(cam["position"], row[1:4])
        R = np.array(cam["rotation"])
        assert np.allclose(R, row[7:16].reshape(3, 3))
        # the camera looks at the target: the aim projects to the image centre
        K = np.array(cam["K"])
        pc = R.T @ (row[4:7] - row[1:4])
        uv = (K @ pc)[:2] / pc[2]
        assert np.allclose(uv, [(cam["width"] - 1) / 2, (cam["height"] - 1) / 2])
    scene = trimesh.load(small_run / "scene.ply", force="mesh", process=False)
    assert len(scene.faces) > 12  # corridor + comet


def test_same_seed_same_solution(small_run: Path, tmp_path: Path) -> None:
    out2 = tmp_path / "again"
    assert main(["run", "comet-67p-bunker", "-o", str(out2), *SMALL, "--seed", "3"]) == 0
    a = json.loads((small_run / "solution.json").read_text())
    b = json.loads((out2 / "solution.json").read_text())
    for d in (a, b):
        d.pop("timings_s")
        d.get("solver_stats", {}).pop("time_s", None)
    assert a == b
    for name in ("candidates.csv", "points.csv"):
        assert (small_run / name).read_bytes() == (out2 / name).read_bytes()
    assert (small_run / "visibility.cpm").read_bytes() == (out2 / "visibility.cpm").read_bytes()


def test_init_writes_a_runnable_file(tmp_path: Path) -> None:
    f = tmp_path / "bunker.toml"
    assert main(["init", "comet-67p-bunker", "-o", str(f)]) == 0
    assert f.exists()
    assert main(["run", str(f), "-o", str(tmp_path / "out"), "--candidates", "40", "--points", "300"]) == 0
    assert (tmp_path / "out" / "solution.json").exists()


@pytest.mark.parametrize(
    "args, needle",
    [
        (["run", "no-such-file.toml", "-o", "OUT"], "no-such-file.toml"),
        (["run", "comet-67p-bunker", "-o", "OUT", "--k", "0"], "--k"),
        (["run", "comet-67p-bunker", "-o", "OUT", "--candidates", "2", "--k", "3"], "--candidates"),
        (["run", "comet-67p-bunker", "-o", "OUT", "--points", "0"], "--points"),
        (["run", "comet-67p-bunker", "-o", "OUT", "--sampler", "halton"], "halton"),
        (["init", "nope", "-o", "x.toml"], "nope"),
    ],
)
def test_bad_input_is_one_line_exit_2(args: list[str], needle: str, tmp_path: Path) -> None:
    args = [a.replace("OUT", str(tmp_path / "out")) for a in args]
    code, out, err = run_cli(*args)
    assert code == 2, (code, out, err)
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("error")]
    assert len(lines) == 1 and needle in lines[0], err
    assert "Traceback" not in err
    assert not (tmp_path / "out" / "solution.json").exists()


def test_bad_instance_file_names_field(tmp_path: Path) -> None:
    f = tmp_path / "bad.toml"
    assert main(["init", "comet-67p-bunker", "-o", str(f)]) == 0
    text = f.read_text().replace("focal_length_mm = 8.0", "focal_length_mm = -8.0")
    assert "focal_length_mm = -8.0" in text
    f.write_text(text)
    code, _, err = run_cli("run", str(f), "-o", str(tmp_path / "out"))
    assert code == 2 and "Traceback" not in err
    assert "camera.focal_length_mm" in err and str(f.name) in err and len(err.strip().splitlines()) == 1


def test_console_entry_freezes_the_collector_after_the_command() -> None:
    """The console script (and python -m camplace) ends without the interpreter's last full
    collection (0.2 s of a quick start): the collector is frozen after the command, with its exit
    code returned; main() itself leaves the collector alone."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import gc, sys; sys.argv = ['camplace', '--version']; from camplace.cli import console, main\n"
            "assert main(['--version']) == 0 and gc.isenabled() and gc.get_freeze_count() == 0\n"
            "rc = console(); print(rc, gc.isenabled(), gc.get_freeze_count() > 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "0 False True"
    pyproject = (Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    assert 'camplace = "camplace.cli:console"' in pyproject
