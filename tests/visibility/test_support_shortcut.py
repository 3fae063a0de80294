"""The supporting-plane shortcut changes no entry of the matrix, only the work."""

import dataclasses

import numpy as np
import pytest

from camplace.instance import builtin
from camplace.event import event_aims
from camplace.sampling import make_candidates
from camplace.visibility import make_target_points
from camplace.visibility.engine import assemble, compute_chunk, make_task


@pytest.mark.parametrize("name", ["comet-67p-bunker", "comet-flyby"])
def test_shortcut_gives_the_identical_matrix(name: str) -> None:
    inst = builtin(name)
    pts = make_target_points(inst, 2000 if len(inst.frames) == 1 else 3600, seed=5)
    cands = make_candidates("uniform", 96, inst.volume.min_m, inst.volume.max_m, event_aims(inst, 3), seed=6)
    task, scenes = make_task(inst, cands, pts)
    assert task.support[~pts.is_emitter].mean() > 0.2  # the shortcut really applies to many surface rows
    plain = dataclasses.replace(task, support=np.zeros_like(task.support))
    starts = range(0, len(cands), 32)
    a, ca = assemble(task, [compute_chunk(task, scenes, s, min(s + 32, len(cands))) for s in starts])
    b, cb = assemble(plain, [compute_chunk(plain, scenes, s, min(s + 32, len(cands))) for s in starts])
    assert a.shape == b.shape and (a != b).nnz == 0 and np.array_equal(a.indices, b.indices)
    assert {k: v for k, v in ca.items() if k != "cast"} == {k: v for k, v in cb.items() if k != "cast"}
    assert ca["cast"] <= cb["cast"]  # supporting rows inside a room of occluders need no cast at all


@pytest.mark.parametrize("name", ["comet-67p-bunker", "comet-67p-team", "volcanic-eruption"])
def test_enclosing_room_shortcut_gives_the_identical_matrix(name: str, monkeypatch) -> None:
    """Segments from cameras inside the room of occluders (the bunker's corridor) to supporting rows
    are not cast: the same matrix as casting them, and fewer casts where the room encloses."""
    from camplace.visibility import chunk

    inst = builtin(name)
    pts = make_target_points(inst, 2000 if len(inst.frames) == 1 else 3600, seed=5)
    cands = make_candidates("uniform", 96, inst.volume.min_m, inst.volume.max_m, event_aims(inst, 3), seed=6)
    task, scenes = make_task(inst, cands, pts)
    starts = range(0, len(cands), 32)
    a, ca = assemble(task, [compute_chunk(task, scenes, s, min(s + 32, len(cands))) for s in starts])
    monkeypatch.setattr(chunk, "ENCLOSING_MAX_TRIANGLES", 0)
    task2, scenes2 = make_task(inst, cands, pts)
    assert not task2.enclosing_rest
    b, cb = assemble(task2, [compute_chunk(task2, scenes2, s, min(s + 32, len(cands))) for s in starts])
    assert a.shape == b.shape and (a != b).nnz == 0 and np.array_equal(a.indices, b.indices)
    assert np.array_equal(a.data, b.data)
    if name.startswith("comet-67p"):  # the corridor encloses the cameras and the comet
        assert task.enclosing_rest and ca["cast"] < cb["cast"]


def test_enclosing_room_needs_the_camera_inside() -> None:
    """A camera outside a room (or on a wall's plane) is not enclosed; inside by the margin it is."""
    from camplace.visibility.chunk import _cameras_enclosed

    # the unit cube's six faces as planes with outward normals; rows inside: side False (negative)
    planes = np.array([[1, 0, 0, 1], [-1, 0, 0, 0], [0, 1, 0, 1], [0, -1, 0, 0], [0, 0, 1, 1], [0, 0, -1, 0]], float)
    side = np.zeros(6, dtype=bool)
    assert _cameras_enclosed(np.array([[0.5, 0.5, 0.5], [0.1, 0.9, 0.2]]), planes, side, 1.0)
    assert not _cameras_enclosed(np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5]]), planes, side, 1.0)
    assert not _cameras_enclosed(np.array([[1.0, 0.5, 0.5]]), planes, side, 1.0)  # on a wall
    assert not _cameras_enclosed(np.array([[1.0 - 1e-7, 0.5, 0.5]]), planes, side, 1.0)  # within the margin


def test_supporting_rows_oracle() -> None:
    """Rows flagged as supporting really have every target vertex behind their tangent plane."""
    inst = builtin("comet-67p-bunker")
    pts = make_target_points(inst, 3000, seed=1)
    cands = make_candidates("uniform", 4, inst.volume.min_m, inst.volume.max_m, event_aims(inst), seed=2)
    task, _ = make_task(inst, cands, pts)
    v, _ = inst.target_world(0)
    reach = np.array([np.max((v - p) @ n) for p, n in zip(pts.positions, pts.normals)])
    assert np.all(reach[task.support] <= task.support_tol[0])
    assert np.all(reach[~task.support] > task.support_tol[0])
