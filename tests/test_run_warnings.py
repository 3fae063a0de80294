"""Warnings a run records in solution.json (issue 33): ``--mode quality`` on an instance whose
``[quality]`` is binary is maxcover under another name, and says so without changing the numbers.
"""

from __future__ import annotations

import copy
import json
import logging
from pathlib import Path

import pytest

from camplace.cli import main
from camplace.instance import builtin_toml, parse_instance
from camplace.pipeline import mode_warnings

TINY = ["--candidates", "30", "--points", "300", "--k", "2", "--seed", "2"]


def instance_file(tmp_path: Path, quality_mode: str) -> Path:
    """The built-in comet bunker with a cheap comet and ``[quality] mode = quality_mode``."""
    from camplace.instance.write import save_instance

    data = copy.deepcopy(builtin_toml("comet-67p-bunker"))
    data["target"]["subdivisions"] = 2
    data["quality"] = {"mode": quality_mode}
    path = tmp_path / f"{quality_mode}.toml"
    save_instance(parse_instance(data, "test", tmp_path), path)
    return path


def run_json(tmp_path: Path, instance: Path, mode: str, capsys) -> tuple[dict, str]:
    out = tmp_path / f"{instance.stem}-{mode}"
    assert main(["run", str(instance), "-o", str(out), *TINY, "--mode", mode]) == 0
    return json.loads((out / "solution.json").read_text()), capsys.readouterr().err


def test_quality_mode_on_binary_quality_says_it_is_maxcover(tmp_path: Path, capsys, caplog) -> None:
    binary = instance_file(tmp_path, "binary")
    with caplog.at_level(logging.WARNING, logger="camplace.pipeline"):
        quality, err = run_json(tmp_path, binary, "quality", capsys)
    notes = [w for w in quality["warnings"] if w.startswith("--mode quality")]
    assert len(notes) == 1 and "binary" in notes[0] and "--mode maxcover" in notes[0] and 'mode = "graded"' in notes[0]
    assert notes[0] in caplog.text  # logged when the run starts
    assert f"warning: {notes[0]}" in err.splitlines()  # and repeated under the result
    # the numbers are the solver's, untouched: the same optimum as maxcover on the same matrix
    caplog.clear()
    maxcover, err = run_json(tmp_path, binary, "maxcover", capsys)
    assert quality["status"] == maxcover["status"] == "optimal"
    assert quality["objective"] == pytest.approx(maxcover["objective"], rel=1e-9)
    assert not any("--mode quality" in w for w in maxcover["warnings"]) and "--mode quality" not in caplog.text + err


def test_quality_mode_on_graded_quality_is_quiet(tmp_path: Path) -> None:
    data = copy.deepcopy(builtin_toml("comet-67p-bunker"))
    data["target"]["subdivisions"] = 2
    graded = parse_instance({**data, "quality": {"mode": "graded"}}, "test", tmp_path)
    binary = parse_instance({**data, "quality": {"mode": "binary"}}, "test", tmp_path)
    assert mode_warnings(graded, "quality") == []
    assert [len(mode_warnings(binary, m)) for m in ("quality", "maxcover", "multiview", "setcover")] == [1, 0, 0, 0]


def test_solve_mode_quality_on_a_binary_run_says_it_equals_maxcover(tmp_path):
    """Found: ``camplace solve --mode quality`` on a binary run silently gave the maxcover answer."""
    import json
    import subprocess
    import sys

    def cp(*args):
        return subprocess.run([sys.executable, "-m", "camplace", *args], cwd=tmp_path, capture_output=True, text=True,
                              timeout=300)

    assert cp("run", "comet-67p-bunker", "-o", "run", "--candidates", "60", "--points", "600").returncode == 0
    q = cp("solve", "run", "--mode", "quality", "-o", "q.json")
    m = cp("solve", "run", "--mode", "maxcover", "-o", "m.json")
    assert q.returncode == 0 and m.returncode == 0, q.stderr + m.stderr
    assert "warning: --mode quality on a matrix whose every observed pair has quality 1" in q.stderr
    assert "warning" not in m.stderr
    qj, mj = json.loads((tmp_path / "q.json").read_text()), json.loads((tmp_path / "m.json").read_text())
    assert len(qj["warnings"]) == 1 and mj["warnings"] == []
    assert qj["objective"] == pytest.approx(mj["objective"], rel=1e-12)
