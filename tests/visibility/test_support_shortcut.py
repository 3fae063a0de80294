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
    assert ca == cb


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
