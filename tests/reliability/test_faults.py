"""Fault injection: kills, Ctrl-C, corrupt cache entries and a full disk never cost data or a traceback."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import camplace._io as cio
from camplace.cli import main
from camplace.instance import builtin
from camplace.pipeline import run
from camplace.visibility.store import load_visibility

from .counts import COUNTS
from .verify import verify_outputs
from tests._package import subprocess_env

ARGS = ["--candidates", "120", "--points", "1500", "--seed", "2"]


def cli_proc(args: list[str], cache: Path) -> subprocess.Popen:
    env = subprocess_env(CAMPLACE_CACHE_DIR=str(cache))
    return subprocess.Popen([sys.executable, "-m", "camplace", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)


def wait_for_stage(proc: subprocess.Popen, line_start: str, timeout_s: float = 120.0) -> None:
    """Read stderr until a stage's 'done' line (the next stage is then running)."""
    t0 = time.time()
    while time.time() - t0 < timeout_s:
        line = proc.stderr.readline()
        if line.startswith(line_start):
            return
        if not line and proc.poll() is not None:
            raise AssertionError(f"process ended early: {proc.returncode}")
    raise AssertionError("timed out waiting for the stage")


def outputs_equal(a: Path, b: Path) -> None:
    for name in ("candidates.csv", "points.csv", "visibility.cpm", "light_curves.csv", "scene.ply"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    sa, sb = (json.loads((d / "solution.json").read_text()) for d in (a, b))
    sa.pop("timings_s"), sb.pop("timings_s")
    assert sa == sb


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "out"
    assert main(["run", "comet-67p-bunker", "-o", str(out), *ARGS, "--no-cache"]) == 0
    verify_outputs(out)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_kill_during_visibility_then_resume(sig, reference: Path, tmp_path: Path) -> None:
    out, cache = tmp_path / "out", tmp_path / "cache"
    big = ["--candidates", "3000", "--points", "20000", "--seed", "2"]
    proc = cli_proc(["run", "comet-67p-bunker", "-o", str(out), *big], cache)
    wait_for_stage(proc, "sampling")  # the visibility stage is now running
    time.sleep(0.3)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    COUNTS["faults injected"] += 1
    if sig == signal.SIGINT:
        assert proc.returncode == 130 and "Traceback" not in err and "interrupted" in err
    else:
        assert proc.returncode == -signal.SIGKILL
    assert not (out / "solution.json").exists()
    verify_outputs(out) if out.exists() else None
    # no cache entry, or a complete one
    for entry in cache.rglob("*.cpm"):
        load_visibility(entry)
    # the small run resumes cleanly into the same folder and equals an uninterrupted run
    assert main(["run", "comet-67p-bunker", "-o", str(out), *ARGS]) == 0
    verify_outputs(out)
    outputs_equal(out, reference)


@pytest.mark.parametrize("nth", [1, 2, 3, 4, 5, 6, 7])
def test_interrupt_at_each_write_leaves_complete_files(nth: int, reference: Path, tmp_path: Path, monkeypatch) -> None:
    """Ctrl-C at the n-th file rename of the write stage: what exists is complete, nothing is half-written."""
    calls = {"n": 0}
    real_replace = os.replace

    def replace(src, dst):
        calls["n"] += 1
        if calls["n"] == nth:
            raise KeyboardInterrupt
        return real_replace(src, dst)

    out = tmp_path / "out"
    monkeypatch.setattr(cio.os, "replace", replace)
    with pytest.raises(KeyboardInterrupt):
        run(builtin("comet-67p-bunker"), candidates=120, points=1500, seed=2, outdir=out)
    monkeypatch.undo()
    COUNTS["faults injected"] += 1
    assert not (out / "solution.json").exists()
    verify_outputs(out)
    assert main(["run", "comet-67p-bunker", "-o", str(out), *ARGS]) == 0
    verify_outputs(out)
    outputs_equal(out, reference)


def test_disk_full_is_one_line_exit_3(tmp_path: Path, monkeypatch, capsys) -> None:
    def full_fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    out = tmp_path / "out"
    monkeypatch.setattr(cio.os, "fsync", full_fsync)
    code = main(["run", "comet-67p-bunker", "-o", str(out), *ARGS, "--no-cache"])
    monkeypatch.undo()
    COUNTS["faults injected"] += 1
    err = capsys.readouterr().err
    assert code == 3, err
    lines = [ln for ln in err.splitlines() if ln.startswith("error")]
    assert len(lines) == 1 and "No space left on device" in lines[0] and "Traceback" not in err
    assert not (out / "solution.json").exists()
    verify_outputs(out)


def test_unwritable_output_folder(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    code = main(["run", "comet-67p-bunker", "-o", str(blocker / "out"), *ARGS])
    COUNTS["faults injected"] += 1
    err = capsys.readouterr().err
    # a file where the folder should be is bad input, found before the run (issue 33): exit 2, not 3 after it
    errors = [ln for ln in err.splitlines() if ln.startswith("error")]
    assert code == 2 and len(errors) == 1 and str(blocker) in errors[0]
    assert "sampling" not in err and blocker.read_text() == "not a folder"


def test_corrupt_cache_entry_is_recomputed(reference: Path, tmp_path: Path, monkeypatch) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setenv("CAMPLACE_CACHE_DIR", str(cache))
    assert main(["run", "comet-67p-bunker", "-o", str(tmp_path / "a"), *ARGS]) == 0
    entries = list(cache.rglob("*.cpm"))
    assert len(entries) == 1
    for garbage in (b"", b"PK\x03\x04 not a zip", entries[0].read_bytes()[:100]):
        entries[0].write_bytes(garbage)
        COUNTS["faults injected"] += 1
        out = tmp_path / f"b{len(garbage)}"
        assert main(["run", "comet-67p-bunker", "-o", str(out), *ARGS]) == 0
        verify_outputs(out)
        outputs_equal(out, reference)


@pytest.mark.slow
def test_byte_identical_in_process_and_on_dask(reference: Path, tmp_path: Path) -> None:
    pytest.importorskip("distributed", reason="the test extra installs dask[distributed]")
    out = tmp_path / "dask"
    assert main(["run", "comet-67p-bunker", "-o", str(out), *ARGS, "--no-cache", "--dask", "local:2"]) == 0
    verify_outputs(out)
    outputs_equal(out, reference)


def _out_of_core_budget_gb() -> float:
    """A memory budget between the in-memory and the out-of-core estimates of ARGS' matrix: the
    run must keep its column bitsets in the scratch folder."""
    from camplace.visibility.engine import estimate_matrix_bytes

    m, n = 1500, 120
    lo, hi = estimate_matrix_bytes(m, n, 1.0, "bits-disk"), estimate_matrix_bytes(m, n, 1.0, "bits")
    return (lo + hi) / 2 / 2**30


def test_out_of_core_run_equals_in_memory_and_removes_its_scratch(reference: Path, tmp_path: Path) -> None:
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    out = tmp_path / "ooc"
    proc = cli_proc(["-v", "run", "comet-67p-bunker", "-o", str(out), *ARGS, "--no-cache", "--memory-budget-gb",
                     repr(_out_of_core_budget_gb()), "--scratch", str(scratch)], tmp_path / "cache")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-2000:]
    assert "out of core" in err
    verify_outputs(out)
    outputs_equal(out, reference)
    assert list(scratch.iterdir()) == []  # the temporary folder is gone


def test_full_scratch_folder_is_one_line_exit_2(tmp_path: Path, monkeypatch, capsys) -> None:
    import camplace.visibility.scratch as scr

    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    scratch = tmp_path / "scratch"
    out = tmp_path / "out"
    monkeypatch.setattr(scr.os, "posix_fallocate", full)
    code = main(["run", "comet-67p-bunker", "-o", str(out), *ARGS, "--no-cache", "--memory-budget-gb",
                 repr(_out_of_core_budget_gb()), "--scratch", str(scratch)])
    monkeypatch.undo()
    COUNTS["faults injected"] += 1
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if ln.startswith("error")]
    assert code == 2 and len(errors) == 1 and "scratch" in errors[0] and "No space left" in errors[0], err
    assert "Traceback" not in err and not (out / "solution.json").exists()
    assert list(scratch.iterdir()) == []


def test_unwritable_scratch_folder_is_one_line_exit_2(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    out = tmp_path / "out"
    code = main(["run", "comet-67p-bunker", "-o", str(out), *ARGS, "--no-cache", "--memory-budget-gb",
                 repr(_out_of_core_budget_gb()), "--scratch", str(blocker / "scratch")])
    COUNTS["faults injected"] += 1
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if ln.startswith("error")]
    assert code == 2 and len(errors) == 1 and "scratch" in errors[0], err
    assert not (out / "solution.json").exists() and blocker.read_text() == "not a folder"


def test_interrupted_out_of_core_run_removes_its_scratch(tmp_path: Path) -> None:
    from camplace.visibility.engine import BASE_BYTES, thread_bytes

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    words = 2000 * ((20000 + 63) // 64) * 8  # the bitsets: in memory they would pass this budget (1 thread)
    budget = (BASE_BYTES + thread_bytes("bits", 20000) + words // 2) / 2**30
    proc = cli_proc(["run", "comet-67p-bunker", "-o", str(tmp_path / "out"), "--candidates", "2000", "--points", "20000",
                     "--no-cache", "--memory-budget-gb", repr(budget), "--threads", "1", "--scratch", str(scratch)],
                    tmp_path / "cache")
    t0 = time.time()
    while not any(scratch.iterdir()) and time.time() - t0 < 60 and proc.poll() is None:
        time.sleep(0.05)
    assert any(scratch.iterdir()), proc.communicate()[1][-2000:]
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    COUNTS["faults injected"] += 1
    assert proc.returncode != 0 and "Traceback" not in err, err[-2000:]
    assert list(scratch.iterdir()) == []
