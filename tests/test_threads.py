"""``--threads N``: checked against the cores the process may use, and the same outputs at every count."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from camplace._cores import allowed_cores, check_threads, thread_count

SIZE = ["--candidates", "120", "--points", "1500", "--no-cache"]


def camplace(*args: str, cwd: Path, prefix: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    return subprocess.run([*prefix, sys.executable, "-m", "camplace", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


@pytest.mark.parametrize("value", ["0", "-1", "abc", "1.5", str(allowed_cores() + 1)])
def test_a_bad_thread_count_is_one_line_and_exit_2_before_any_work(tmp_path, value):
    proc = camplace("run", "comet-67p-bunker", "-o", "out", "--threads", value, *SIZE, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("error: argument --threads:"), proc.stderr
    assert not (tmp_path / "out").exists()


def test_every_computing_verb_takes_threads():
    from camplace.cli import COMPUTE_VERBS, build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "verb")
    for verb in COMPUTE_VERBS:
        opts = {o for a in sub.choices[verb]._actions for o in a.option_strings}
        assert "--threads" in opts, verb


@pytest.mark.skipif(not shutil.which("taskset") or allowed_cores() < 2, reason="needs taskset and two cores")
def test_the_affinity_mask_not_the_machine_decides_the_limit(tmp_path):
    proc = camplace("run", "comet-67p-bunker", "-o", "out", "--threads", "2", *SIZE, cwd=tmp_path,
                    prefix=("taskset", "-c", "0"))
    assert proc.returncode == 2 and "from 1 to 1" in proc.stderr, proc.stderr


def test_check_threads_and_default():
    assert check_threads(None) is None and check_threads(1) == 1
    for bad in (0, -3, True, 2.0, allowed_cores() + 1):
        with pytest.raises(ValueError):
            check_threads(bad)
    assert thread_count() >= 1 and thread_count(1) == 1


@pytest.mark.skipif(allowed_cores() < 2, reason="needs two cores")
@pytest.mark.parametrize("mode", ["maxcover", "multiview"])
def test_one_and_two_threads_give_the_same_matrix_bits_and_the_same_answer(tmp_path, mode):
    out = {}
    for n in (1, 2):
        proc = camplace("run", "comet-67p-bunker", "-o", f"t{n}", "--threads", str(n), "--mode", mode, *SIZE,
                        cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        sol = json.loads((tmp_path / f"t{n}" / "solution.json").read_text())
        out[n] = sol
    a, b = (tmp_path / "t1" / "visibility.cpm").read_bytes(), (tmp_path / "t2" / "visibility.cpm").read_bytes()
    assert a == b
    for key in ("status", "objective", "bound"):
        assert out[1][key] == out[2][key], key
    assert [c["candidate"] for c in out[1]["cameras"]] == [c["candidate"] for c in out[2]["cameras"]]
