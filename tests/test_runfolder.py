"""RunFolder: what a run writes reads back identical, each file only when asked for, and reading a
folder (the verbs solve, report, export-cameras) never loads Embree."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import camplace
from camplace.errors import CamplaceError
from camplace.runfolder import RunFolder


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("rf") / "run"
    sol = camplace.run("comet-67p-bunker", candidates=40, points=400, time_limit_s=30, outdir=out)
    return out, sol


def _same_csr(a, b) -> None:
    assert a.shape == b.shape
    assert np.array_equal(a.indptr, b.indptr) and np.array_equal(a.indices, b.indices)
    assert a.data.dtype == b.data.dtype and np.array_equal(a.data, b.data)


def test_a_run_folder_reads_back_what_the_run_held(run_dir) -> None:
    out, sol = run_dir
    folder = camplace.RunFolder(out)
    _same_csr(folder.matrix, sol.visibility.matrix.tocsr())
    for name in ("positions", "normals", "frame", "weight"):
        assert np.array_equal(getattr(folder.points, name), getattr(sol.visibility.points, name)), name
    assert np.array_equal(folder.candidates.positions, sol.candidates.positions)
    assert np.allclose(folder.candidates.rotations, sol.candidates.rotations, rtol=0, atol=1e-12)
    assert folder.solution_record == json.loads(json.dumps(sol.to_dict()))
    assert folder.solution.selected == sol.selected and folder.solution.objective == sol.objective
    assert folder.instance.name == "comet-67p-bunker"
    folder.check_sizes()
    assert np.array_equal(folder.weights(), sol.visibility.points.weight)


def test_each_file_is_read_only_when_asked_for(run_dir, tmp_path) -> None:
    out, sol = run_dir
    part = tmp_path / "part"
    part.mkdir()
    for name in ("solution.json", "visibility.cpm"):
        shutil.copy(out / name, part / name)
    folder = RunFolder(part)
    assert folder.matrix.shape == (sol.n_points, sol.n_candidates)
    assert folder.solution.cameras == sol.cameras
    assert folder.candidate_positions() is None
    with pytest.raises(CamplaceError, match="points.csv"):
        folder.points  # noqa: B018
    with pytest.raises(CamplaceError, match="no instance.toml here"):
        folder.instance  # noqa: B018
    # the matrix file itself names its folder (as 'camplace solve' accepts it)
    assert RunFolder(part / "visibility.cpm").path == part


def test_points_that_do_not_match_the_matrix_stop_with_one_line(run_dir, tmp_path) -> None:
    out, sol = run_dir
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    pts = sol.visibility.points
    short = type(pts)(pts.positions[:-1], pts.normals[:-1], pts.frame[:-1], pts.weight[:-1])
    RunFolder(bad).save_points(short)
    folder = RunFolder(bad)
    with pytest.raises(CamplaceError, match=rf"has {sol.n_points} rows but points.csv has {sol.n_points - 1}") as exc:
        folder.check_sizes()
    assert "\n" not in str(exc.value)


def test_saved_files_read_back_in_a_fresh_folder(run_dir, tmp_path) -> None:
    out, sol = run_dir
    dst = RunFolder(tmp_path / "copy")
    dst.save_instance(RunFolder(out).instance)
    dst.save_candidates(sol.candidates)
    dst.save_points(sol.visibility.points)
    dst.save_matrix(sol.visibility.matrix, fmt="npz")
    dst.save_solution(sol)
    back = RunFolder(tmp_path / "copy")
    assert back.matrix_path.name == "visibility.npz"
    _same_csr(back.matrix, RunFolder(out).matrix)
    assert back.solution_record == RunFolder(out).solution_record
    back.check_sizes()
    assert not list((tmp_path / "copy").glob(".*.tmp*"))  # atomic writes leave no temporaries


def test_reading_a_folder_loads_no_embree(run_dir, tmp_path) -> None:
    """solve, report (its sampler study on the run's own sampler: the run's matrix) and export-cameras."""
    out, _ = run_dir
    heavy = ("embreex", "cv2", "ortools")
    code = (
        "import sys; import camplace.runfolder; "
        f"print(sorted(m for m in {heavy!r} + ('numba', 'trimesh') if m in sys.modules)); "
        "from camplace.cli import main; "
        f"rc = [main(['solve', {str(out)!r}, '-o', {str(tmp_path / 's.json')!r}]), "
        f"main(['report', {str(out)!r}, '--samplers', 'chaotic', '-o', {str(tmp_path / 'rep')!r}]), "
        f"main(['export-cameras', {str(out)!r}, '--format', 'colmap', '-o', {str(tmp_path / 'exp')!r}])]; "
        f"print(rc, sorted(m for m in {heavy!r} if m in sys.modules))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    assert lines[0] == "[]"  # importing RunFolder loads nothing heavy
    assert lines[-1] == "[0, 0, 0] []"
