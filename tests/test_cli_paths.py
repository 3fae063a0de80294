"""Output paths and defaults of the verbs that write (issue 33: items 1, 7, 8 and the CLI parts of 9).

Each test walks a user's command in a fresh interpreter (``python -m camplace``). Path errors exit
before any work: a file where a folder is needed (or the reverse) is one ``error:`` line naming the
path, exit code 2, and nothing is written anywhere (the whole work folder is compared before and
after).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from camplace.cli import main
from tests._package import subprocess_env

TINY = ["--candidates", "40", "--points", "300"]


def camplace(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``python -m camplace ARGS`` in ``cwd`` (the camplace these tests imported first on the path)."""
    env = subprocess_env(env)
    return subprocess.run([sys.executable, "-m", "camplace", *args], cwd=cwd, capture_output=True, text=True, env=env,
                          timeout=600)


def tree(root: Path) -> dict[str, bytes | None]:
    """Every file (with its bytes) and folder under ``root``, hidden ones included."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def one_error_line(proc: subprocess.CompletedProcess) -> str:
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A tiny run folder of the one-frame bunker (read only: tests that write copy it or write elsewhere)."""
    out = tmp_path_factory.mktemp("paths") / "run"
    assert main(["run", "comet-67p-bunker", "-o", str(out), *TINY, "--seed", "1"]) == 0
    return out


# ------------------------------------------------------------------------------------------------
# item 1: a file where a folder is needed, or the reverse, before any work


WRONG_KIND = [
    # (command with RUN = the run folder, FILE = an existing file, DIR = an existing folder), the path named
    (["run", "comet-67p-bunker", "-o", "FILE", *TINY], "FILE"),
    (["run", "comet-67p-bunker", "-o", "FILE/sub", *TINY], "FILE"),
    (["visibility", "comet-67p-bunker", "--candidates", "RUN/candidates.csv", "-o", "FILE", "--points", "300"], "FILE"),
    (["solve", "RUN", "-o", "DIR"], "DIR"),
    (["solve", "RUN", "-o", "FILE/solve.json"], "FILE"),
    (["render", "RUN", "-o", "FILE"], "FILE"),
    (["validate", "RUN", "-o", "FILE"], "FILE"),
    (["campaign", "RUN", "--systems", "2", "-o", "FILE"], "FILE"),
    (["report", "RUN", "-o", "DIR"], "DIR"),
    (["export", "RUN", "--frame", "simulation", "-o", "FILE"], "FILE"),
    (["export", "RUN", "--format", "json", "-o", "FILE"], "FILE"),
    (["export-cameras", "RUN", "-o", "FILE"], "FILE"),
    (["plan", "RUN", "--phases", "1", "--speed", "1", "-o", "FILE"], "FILE"),
    (["import-cameras", "cameras.txt", "-o", "DIR"], "DIR"),
    (["init", "comet-67p-bunker", "-o", "DIR.toml"], "DIR.toml"),
]


@pytest.mark.parametrize("argv, named", WRONG_KIND, ids=[f"{a[0]} -o {a[a.index('-o') + 1]}" for a, _ in WRONG_KIND])
def test_output_of_the_wrong_kind_is_one_line_before_any_work(argv, named, run_dir, tmp_path) -> None:
    """Found: ``run -o notes.txt`` wrote into the current folder and exited 0 ("wrote notes.txt/solution.json");
    ``visibility`` did the same; ``solve``, ``render``, ``validate``, ... failed after the work with exit 3
    ("File exists" / "Is a directory", "free disk space")."""
    work = tmp_path / "work"
    work.mkdir()
    (work / "FILE").write_text("notes\n")
    (work / "DIR").mkdir()
    (work / "DIR.toml").mkdir()
    (work / "solution.json").write_text("an unrelated file that a run into '.' would overwrite\n")
    names = {"RUN": str(run_dir)}
    argv = [names.get(a, a.replace("RUN/", f"{run_dir}/")) for a in argv]
    before_work, before_run = tree(work), tree(run_dir)
    t0 = time.perf_counter()
    proc = camplace(*argv, cwd=work)
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    line = one_error_line(proc)
    assert named in line and "-o" in line, line
    assert tree(work) == before_work  # nothing written, here or ...
    assert tree(run_dir) == before_run  # ... in the run folder
    assert time.perf_counter() - t0 < 60  # before the work (a tiny run takes longer on a loaded machine)


def test_convert_matrix_onto_a_folder_is_one_line_before_reading(run_dir, tmp_path) -> None:
    """Found: the matrix was read and converted, then the rename failed with exit 3 ("Is a directory")."""
    run = tmp_path / "run"
    subprocess.run(["cp", "-r", str(run_dir), str(run)], check=True)
    (run / "visibility.npz").mkdir()
    before = tree(run)
    proc = camplace("convert-matrix", str(run), "--format", "npz", cwd=tmp_path)
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    line = one_error_line(proc)
    assert str(run / "visibility.npz") in line and "is a folder" in line
    assert tree(run) == before


# ------------------------------------------------------------------------------------------------
# item 7: run --report without the report extra


def test_run_report_without_the_report_extra_fails_before_the_run(tmp_path) -> None:
    """Found: the whole run (and its files) first, then exit 2, which the docs call "nothing written"."""
    blocker = tmp_path / "no-extra"
    blocker.mkdir()
    (blocker / "matplotlib.py").write_text("raise ImportError('matplotlib is not installed (test)')\n")
    env = dict(os.environ, PYTHONPATH=str(blocker) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = camplace("run", "comet-67p-bunker", "-o", "out", *TINY, "--report", cwd=tmp_path, env=env)
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    line = one_error_line(proc)
    assert "camplace[report]" in line
    assert not (tmp_path / "out").exists()
    assert "sampling" not in proc.stderr  # no stage ran


# ------------------------------------------------------------------------------------------------
# item 8: init does not overwrite; an interrupted validate leaves no photographs


def test_init_refuses_to_overwrite_without_force(tmp_path) -> None:
    first = camplace("init", "comet-67p-bunker", "-o", "my.toml", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    edited = (tmp_path / "my.toml").read_text() + "# my edits\n"
    (tmp_path / "my.toml").write_text(edited)
    again = camplace("init", "comet-67p-bunker", "-o", "my.toml", cwd=tmp_path)
    assert again.returncode == 2
    line = one_error_line(again)
    assert "my.toml" in line and "--force" in line
    assert (tmp_path / "my.toml").read_text() == edited  # the user's edits are kept
    forced = camplace("init", "comet-67p-bunker", "-o", "my.toml", "--force", cwd=tmp_path)
    assert forced.returncode == 0, forced.stderr
    assert "# my edits" not in (tmp_path / "my.toml").read_text()


def _pngs(root: Path) -> list[Path]:
    return sorted(root.rglob("*.png"))


def test_interrupted_validate_leaves_no_photographs_then_defaults_into_the_run_folder(run_dir, tmp_path) -> None:
    """Found: Ctrl-C during ``validate`` said "no partial output was written" and left its photographs."""
    run = tmp_path / "run"
    subprocess.run(["cp", "-r", str(run_dir), str(run)], check=True)
    env = subprocess_env()
    argv = [sys.executable, "-m", "camplace", "validate", str(run), "--random-systems", "3", "--installations", "16"]
    with open(tmp_path / "stderr.txt", "w+") as err:
        proc = subprocess.Popen(argv, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=err, env=env)
        t0 = time.time()
        while not _pngs(run) and proc.poll() is None and time.time() - t0 < 300:
            time.sleep(0.02)
        assert _pngs(run), "validate wrote no photograph"  # the photographs are being written ...
        proc.send_signal(signal.SIGINT)  # ... when Ctrl-C comes
        proc.wait(timeout=120)
        err.seek(0)
        text = err.read()
    assert proc.returncode == 130 and "interrupted" in text and "Traceback" not in text, text
    assert _pngs(run) == []  # no photograph, no figure, no temporary folder left
    assert sorted(p.name for p in run.iterdir()) == sorted(p.name for p in run_dir.iterdir())
    # without -o the validation goes into the run folder
    done = camplace("validate", str(run), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    report = json.loads((run / "validation" / "validation.json").read_text())
    photos = [Path(c["photo"]) for c in report["cameras"]]
    assert photos and all(p.parent == run / "validation" / "photos" and p.is_file() for p in photos)
    assert sorted(p.name for p in run.iterdir() if p.name.startswith(".")) == []


# ------------------------------------------------------------------------------------------------
# item 9: defaults, plain export, campaign sizes, plural, grouped help


def test_solve_without_o_writes_solve_json_in_the_run_folder(run_dir, tmp_path) -> None:
    """Found: ``solve`` required -o while render, campaign and report default into the run folder."""
    run = tmp_path / "run"
    subprocess.run(["cp", "-r", str(run_dir), str(run)], check=True)
    proc = camplace("solve", str(run / "visibility.cpm"), cwd=tmp_path)  # the matrix file: its folder
    assert proc.returncode == 0, proc.stderr
    res = json.loads((run / "solve.json").read_text())
    sol = json.loads((run / "solution.json").read_text())
    assert res["options"]["k"] == sol["options"]["k"] and res["status"] == "optimal"
    assert f"wrote {run / 'solve.json'}" in proc.stdout


def test_plain_export_writes_the_placement_in_the_simulation_frame(run_dir, tmp_path) -> None:
    """Found: plain ``export OUTDIR`` failed on "no [transform] table" (its default format needs one)."""
    out = tmp_path / "exp"
    proc = camplace("export", str(run_dir), "-o", str(out), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["placement.simulation.csv", "placement.simulation.json"]
    warning = proc.stderr.strip().splitlines()
    assert len(warning) == 1 and warning[0].startswith("warning:") and "--transform" in warning[0]
    placed = json.loads((out / "placement.simulation.json").read_text())
    sol = json.loads((run_dir / "solution.json").read_text())
    np.testing.assert_allclose([c["position_m"] for c in placed["cameras"]], [c["position"] for c in sol["cameras"]],
                               atol=1e-12)
    # lab coordinates asked for explicitly: one line naming both ways out, nothing written
    phys = camplace("export", str(run_dir), "--frame", "physical", "-o", str(tmp_path / "phys"), cwd=tmp_path)
    assert phys.returncode == 2
    line = one_error_line(phys)
    assert "--transform" in line and "--frame simulation" in line
    assert not (tmp_path / "phys").exists()


def test_campaign_keeps_a_larger_campaign_unless_forced(run_dir, tmp_path) -> None:
    """Found: ``campaign OUTDIR --systems 50`` silently replaced the 200 systems of ``run --report``."""
    run = tmp_path / "run"
    subprocess.run(["cp", "-r", str(run_dir), str(run)], check=True)
    camp = run / "campaign-uniform" / "campaign.json"
    assert camplace("campaign", str(run), "--systems", "4", cwd=tmp_path).returncode == 0
    smaller = camplace("campaign", str(run), "--systems", "2", cwd=tmp_path)
    assert smaller.returncode == 2
    line = one_error_line(smaller)
    assert "4 uniform systems" in line and "--force" in line and "-o" in line
    assert json.loads(camp.read_text())["n_systems"] == 4  # kept
    same = camplace("campaign", str(run), "--systems", "4", cwd=tmp_path)  # re-running the same is fine, and said
    assert same.returncode == 0 and "replaced a campaign of 4 uniform systems" in same.stdout
    forced = camplace("campaign", str(run), "--systems", "2", "--force", cwd=tmp_path)
    assert forced.returncode == 0, forced.stderr
    assert json.loads(camp.read_text())["n_systems"] == 2


def test_more_phases_than_frames_says_1_frame(run_dir, tmp_path) -> None:
    proc = camplace("plan", str(run_dir), "--phases", "2", "--speed", "1", "-o", str(tmp_path / "plan"), cwd=tmp_path)
    assert proc.returncode == 2
    line = one_error_line(proc)
    assert "only 1 frame (" in line and "1 frames" not in line


def test_run_help_groups_the_options_by_stage(tmp_path) -> None:
    """Found: ``run --help`` listed 40 options in one flat list."""
    proc = camplace("run", "--help", cwd=tmp_path)
    assert proc.returncode == 0
    groups: dict[str, list[str]] = {}
    current = None
    for line in proc.stdout.splitlines():
        if line and not line.startswith(" ") and line.endswith(":"):
            current = line[:-1]
            groups[current] = []
        elif current and line.startswith("  -"):
            groups[current].append(line.split()[0].rstrip(","))
    expected = {
        "instance": ["--seed", "--event-mode"],
        "sampling": ["--candidates", "--points", "--sampler", "--orientations"],
        "visibility": ["--no-cache", "--dask", "--memory-budget-gb"],
        "solver": ["--mode", "--k", "--engine", "--time-limit"],
        "robust placement": ["--pose-error", "--scenarios"],
        "outputs": ["-o", "--matrix-format", "--report", "--report-systems"],
    }
    for group, options in expected.items():
        assert group in groups, list(groups)
        assert set(options) <= set(groups[group]), (group, groups[group])
    assert groups["options"] == ["-h"]  # nothing left in the flat list


def test_staged_folder_moves_everything_or_nothing(tmp_path) -> None:
    """The mechanism behind render's and validate's "no partial output" (camplace._io.staged_folder)."""
    from camplace._io import staged_folder

    out = tmp_path / "new" / "val"
    with pytest.raises(KeyboardInterrupt):
        with staged_folder(out) as work:
            (work / "photos").mkdir()
            (work / "photos" / "a.png").write_bytes(b"half")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []  # no output, no temporary folder, no folder created above it
    out.mkdir(parents=True)
    (out / "keep.txt").write_text("a user's file")
    (out / "photos").mkdir()
    (out / "photos" / "stale.png").write_bytes(b"old")
    (out / "validation.json").write_text("old")
    with staged_folder(out) as work:
        (work / "photos").mkdir()
        (work / "photos" / "a.png").write_bytes(b"new")
        (work / "validation.json").write_text("new")
    assert tree(out) == {"keep.txt": b"a user's file", "photos": None, "photos/a.png": b"new", "validation.json": b"new"}
    assert sorted(p.name for p in out.parent.iterdir()) == ["val"]
