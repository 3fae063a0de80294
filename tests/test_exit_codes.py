"""Every verb's failure paths end with the exit code of :mod:`camplace.errors`, the same on every verb.

0 ok, 1 no feasible system, 2 bad input, 3 I/O, 130 interrupted. Bad input and no-solution cases
run as whole commands in subprocesses; the I/O and interrupt cases run ``camplace.cli.main`` in
process with a full disk (``fsync`` raising ENOSPC) or a Ctrl-C injected, as
tests/reliability/test_faults.py does.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from camplace import errors
from camplace.cli import build_parser, main

SMALL = ["--candidates", "60", "--points", "600", "--no-cache"]


def camplace(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "camplace", *args], cwd=cwd, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("exit")
    proc = camplace("run", "comet-67p-bunker", "-o", "run", *SMALL, cwd=tmp)
    assert proc.returncode == 0, proc.stderr
    return tmp / "run"


def verbs() -> list[str]:
    sub = next(a for a in build_parser()._actions if a.dest == "verb")
    return list(sub.choices)


# a bad input per verb: a missing folder or file, an unknown name
BAD_INPUT = {
    "run": ["run", "no-such-instance", "-o", "out"],
    "visibility": ["visibility", "comet-67p-bunker", "--candidates", "missing.csv", "-o", "out"],
    "convert-matrix": ["convert-matrix", "nowhere", "--format", "npz"],
    "init": ["init", "no-such-instance", "-o", "x.toml"],
    "render": ["render", "nowhere"],
    "validate": ["validate", "nowhere"],
    "import-cameras": ["import-cameras", "missing.json", "-o", "out"],
    "campaign": ["campaign", "nowhere"],
    "report": ["report", "nowhere"],
    "export": ["export", "nowhere"],
    "export-cameras": ["export-cameras", "nowhere"],
    "solve": ["solve", "nowhere"],
    "setcover": ["setcover", "missing.txt", "--format", "orlib"],
    "plan": ["plan", "nowhere"],
    "instances": ["instances", "--no-such-option"],
}


def test_the_codes_have_one_home_with_the_documented_values():
    assert (errors.EXIT_OK, errors.EXIT_NO_SOLUTION, errors.EXIT_BAD_INPUT, errors.EXIT_IO,
            errors.EXIT_INTERRUPTED) == (0, 1, 2, 3, 130)
    src = Path(errors.__file__).parent
    for path in src.rglob("*.py"):
        if path.name == "errors.py":
            continue
        for line in path.read_text(encoding="utf-8").splitlines():
            assert not line.startswith("EXIT_"), f"{path}: exit codes are defined in camplace.errors only: {line}"


def test_every_verb_has_a_bad_input_case():
    assert set(verbs()) <= set(BAD_INPUT), set(verbs()) - set(BAD_INPUT)


@pytest.mark.parametrize("verb", sorted(BAD_INPUT))
def test_bad_input_is_one_line_and_exit_2(verb, tmp_path):
    assert verb in verbs(), f"BAD_INPUT names {verb!r}, which is no verb (a stale entry)"
    proc = camplace(*BAD_INPUT[verb], cwd=tmp_path)
    assert proc.returncode == errors.EXIT_BAD_INPUT, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("error:"), proc.stderr


@pytest.mark.parametrize("argv", [
    ["solve", "{run}", "--min-distance", "1000", "-o", "{tmp}/inf.json"],
    ["run", "comet-67p-bunker", "-o", "{tmp}/inf", "--min-distance", "1000", *SMALL],
], ids=["solve", "run"])
def test_no_feasible_system_is_exit_1_on_every_solving_verb(argv, run_folder, tmp_path):
    proc = camplace(*[a.format(run=run_folder, tmp=tmp_path) for a in argv], cwd=tmp_path)
    assert proc.returncode == errors.EXIT_NO_SOLUTION, (proc.returncode, proc.stdout, proc.stderr)
    assert "infeasible" in proc.stdout


def _full_disk(monkeypatch) -> None:
    import camplace._io as cio

    def full_fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(cio.os, "fsync", full_fsync)


@pytest.mark.parametrize("argv", [
    ["run", "comet-67p-bunker", "-o", "{tmp}/out", *SMALL],
    ["solve", "{run}", "-o", "{tmp}/s.json"],
    ["export", "{run}", "--format", "json,csv", "-o", "{tmp}/exp"],
    ["init", "comet-67p-bunker", "-o", "{tmp}/x.toml"],
    ["render", "{run}", "-o", "{tmp}/render"],
], ids=["run", "solve", "export", "init", "render"])
def test_a_full_disk_is_exit_3_with_one_line(argv, run_folder, tmp_path, monkeypatch, capsys):
    _full_disk(monkeypatch)
    code = main([a.format(run=run_folder, tmp=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert code == errors.EXIT_IO, err
    assert err.strip().splitlines()[-1].startswith("error:") and "No space left" in err, err


@pytest.mark.parametrize("argv", [
    ["solve", "{run}", "-o", "{tmp}/s.json"],
    ["run", "comet-67p-bunker", "-o", "{tmp}/out", *SMALL],
], ids=["solve", "run"])
def test_ctrl_c_is_exit_130_and_writes_nothing(argv, run_folder, tmp_path, monkeypatch, capsys):
    import camplace.solver.api as api

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(api, "solve", interrupted)
    code = main([a.format(run=run_folder, tmp=tmp_path) for a in argv])
    assert code == errors.EXIT_INTERRUPTED, capsys.readouterr().err
    assert not (tmp_path / "s.json").exists() and not (tmp_path / "out" / "solution.json").exists()
