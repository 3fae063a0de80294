"""The visibility cache and the `camplace visibility` verb."""

from pathlib import Path

import numpy as np
import pytest

from camplace.cli import main
from camplace.instance import builtin
from camplace.event import event_aims
from camplace.sampling import make_candidates
from camplace.visibility import compute_visibility, make_target_points
from camplace.visibility import store
from camplace.visibility.cache import entry_path, task_key
from camplace.visibility.engine import make_task
from camplace.visibility.store import load_visibility


@pytest.fixture()
def problem():
    inst = builtin("comet-67p-bunker")
    pts = make_target_points(inst, 1500, seed=1)
    cands = make_candidates("uniform", 64, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=2)
    return inst, pts, cands


def test_rerun_hits_cache_and_is_identical(problem, tmp_path: Path) -> None:
    inst, pts, cands = problem
    a = compute_visibility(inst, cands, pts, cache_dir=tmp_path)
    b = compute_visibility(inst, cands, pts, cache_dir=tmp_path)
    assert a.stats["cache"] == "miss" and b.stats["cache"] == "hit"
    assert (a.matrix != b.matrix).nnz == 0
    # any change of input gives another key
    other = make_candidates("uniform", 64, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=3)
    assert task_key(make_task(inst, cands, pts)[0]) != task_key(make_task(inst, other, pts)[0])
    assert compute_visibility(inst, other, pts, cache_dir=tmp_path).stats["cache"] == "miss"


def test_corrupt_cache_entry_is_recomputed(problem, tmp_path: Path) -> None:
    inst, pts, cands = problem
    a = compute_visibility(inst, cands, pts, cache_dir=tmp_path)
    path = entry_path(tmp_path, task_key(make_task(inst, cands, pts)[0]))
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # truncated, as by a crash mid-write
    b = compute_visibility(inst, cands, pts, cache_dir=tmp_path)
    assert b.stats["cache"] == "miss" and (a.matrix != b.matrix).nnz == 0
    assert compute_visibility(inst, cands, pts, cache_dir=tmp_path).stats["cache"] == "hit"


def test_interrupted_store_leaves_no_entry(problem, tmp_path: Path, monkeypatch) -> None:
    inst, pts, cands = problem

    def boom(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(store, "_write_file", boom)
    with pytest.raises(KeyboardInterrupt):
        compute_visibility(inst, cands, pts, cache_dir=tmp_path)
    monkeypatch.undo()
    assert not any(p.is_file() for p in tmp_path.rglob("*"))


def test_visibility_verb_matches_run(tmp_path: Path) -> None:
    run_dir, vis_dir = tmp_path / "run", tmp_path / "vis"
    assert main(["run", "comet-67p-bunker", "-o", str(run_dir), "--candidates", "60", "--points", "800", "--seed", "4"]) == 0
    assert main(["visibility", "comet-67p-bunker", "--candidates", str(run_dir / "candidates.csv"),
                 "--points", "800", "--seed", "4", "--no-cache", "-o", str(vis_dir)]) == 0
    a = load_visibility(run_dir)
    b = load_visibility(vis_dir)
    assert a.shape == b.shape and (a != b).nnz == 0
    assert (run_dir / "points.csv").read_bytes() == (vis_dir / "points.csv").read_bytes()
    assert (run_dir / "scene.ply").read_bytes() == (vis_dir / "scene.ply").read_bytes()
