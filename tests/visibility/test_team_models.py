"""Two camera models in one matrix (issue 31): each column is observed with its own K, size, near and far.

Against the independent numpy oracle (per-column intrinsics), against a single-model matrix of the
same poses (the model-0 columns are those bits exactly), in any column order, and with graded
quality each column's value uses its model's focal length.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from camplace.instance.schema import CameraModel, QualitySpec, Team, Volume
from camplace.sampling import CandidateSet, make_candidates
from camplace.visibility import compute_visibility, frame_scene, make_target_points
from camplace.visibility.engine import EPS_REL, make_task

from .oracle import observed
from .test_oracle import occluded_scene

WIDE = CameraModel(7.18, 5.32, 4.0, 160, 120, 0.2, 3.5, name="wide")
TELE = CameraModel(7.18, 7.18, 25.0, 96, 96, 1.0, 6.0, name="tele")


def _team_scene(quality: QualitySpec | None = None):
    inst = occluded_scene()
    vol = inst.volume
    team = Team(models=(WIDE, TELE), volumes=(Volume(vol.min_m, vol.max_m),))
    inst = dataclasses.replace(inst, camera=WIDE, team=team)
    return dataclasses.replace(inst, quality=quality) if quality is not None else inst


def _columns(inst, order: str) -> CandidateSet:
    """Every sampled pose with both models: model-major, or interleaved (pose, model) pairs."""
    base = make_candidates("uniform", 40, inst.volume.min_m, inst.volume.max_m, np.zeros(3), seed=4)
    n = len(base)
    if order == "model-major":
        idx, model = np.tile(np.arange(n), 2), np.repeat([0, 1], n)
    else:
        idx, model = np.repeat(np.arange(n), 2), np.tile([1, 0], n)  # tele first: not grouped
    return CandidateSet(base.positions[idx], base.aims[idx], base.rotations[idx], sampler="uniform", model=model.astype(np.int16))


@pytest.mark.parametrize("order", ["model-major", "interleaved"])
def test_two_models_agree_with_numpy_oracle(order) -> None:
    inst = _team_scene()
    pts = make_target_points(inst, 3000, seed=3)
    cands = _columns(inst, order)
    dense = compute_visibility(inst, cands, pts, chunk_size=7).matrix.toarray() > 0
    rng = np.random.default_rng(5)
    rows = rng.integers(0, len(pts), 5000)
    cols = rng.integers(0, len(cands), 5000)
    scenes = {f: frame_scene(inst, f).triangles.astype(np.float64) for f in range(len(inst.frames))}
    # each frame's ray offset, once (the same number for every pair of the frame)
    epss = {f: EPS_REL * float(np.linalg.norm(np.ptp(inst.target_world(f)[0], axis=0))) for f in range(len(inst.frames))}
    agree = 0
    seen = {0: 0, 1: 0}
    wrong_model_agree = 0
    for r, c in zip(rows, cols, strict=True):
        f = int(pts.frame[r])
        eps = epss[f]
        m = inst.cameras[int(cands.model[c])]
        other = inst.cameras[1 - int(cands.model[c])]
        want = observed(pts.positions[r], pts.normals[r], cands.positions[c], cands.rotations[c], m.K(),
                        m.width_px, m.height_px, m.near_m, m.far_m, scenes[f], eps)
        alt = observed(pts.positions[r], pts.normals[r], cands.positions[c], cands.rotations[c], other.K(),
                       other.width_px, other.height_px, other.near_m, other.far_m, scenes[f], eps)
        agree += want == dense[r, c]
        wrong_model_agree += alt == dense[r, c]
        seen[int(cands.model[c])] += want
    assert agree / len(rows) >= 0.999, agree / len(rows)
    # meaningful: both models observe often, and the other model's intrinsics would disagree often
    assert seen[0] > 200 and seen[1] > 50, seen
    assert wrong_model_agree / len(rows) < 0.95


@pytest.mark.parametrize("min_target_px", [0.0, 6000.0])
def test_model_columns_equal_the_single_model_matrices(min_target_px) -> None:
    inst = _team_scene(QualitySpec(min_target_px=min_target_px))
    pts = make_target_points(inst, 2000, seed=1)
    cands = _columns(inst, "interleaved")
    team_m = compute_visibility(inst, cands, pts, chunk_size=9).matrix
    for j, model in enumerate((WIDE, TELE)):
        single = dataclasses.replace(inst, camera=model, team=None)
        sel = np.flatnonzero(cands.model == j)
        plain = CandidateSet(cands.positions[sel], cands.aims[sel], cands.rotations[sel])
        ref = compute_visibility(single, plain, pts, chunk_size=9).matrix
        got = team_m[:, sel].tocsr()
        got.sort_indices()
        assert (got != ref).nnz == 0
        assert ref.nnz > 0
        if min_target_px and j == 0:  # the minimum projected size bites (on the wide model's small views)
            unlimited = compute_visibility(dataclasses.replace(single, quality=QualitySpec()), plain, pts, chunk_size=9).matrix
            assert unlimited.nnz > ref.nnz
    # and the two models' matrices differ (so the test above could fail)
    a, b = team_m[:, np.flatnonzero(cands.model == 0)], team_m[:, np.flatnonzero(cands.model == 1)]
    order0 = np.argsort(np.flatnonzero(cands.model == 0) // 2)
    order1 = np.argsort(np.flatnonzero(cands.model == 1) // 2)
    assert (a[:, order0] != b[:, order1]).nnz > 0


@pytest.mark.parametrize("layout", ["csr", "auto"])
def test_graded_quality_uses_each_models_focal_length(layout) -> None:
    inst = _team_scene(QualitySpec(mode="graded", required_px_per_m=2000.0))
    pts = make_target_points(inst, 1500, seed=2)
    cands = _columns(inst, "model-major")
    vis = compute_visibility(inst, cands, pts, chunk_size=11, layout=layout)  # auto: quantised to bytes
    assert (vis.qbytes is not None) == (layout == "auto")
    mat = vis.matrix.tocoo()
    assert mat.nnz > 0
    fx = np.array([WIDE.fx_px, TELE.fx_px])[cands.model[mat.col]]
    d = np.linalg.norm(cands.positions[mat.col] - pts.positions[mat.row], axis=1)
    view = (cands.positions[mat.col] - pts.positions[mat.row]) / d[:, None]
    cos = np.einsum("ij,ij->i", pts.normals[mat.row], view)
    want = np.minimum(1.0, fx / (d * 2000.0)) * cos
    if layout == "csr":
        np.testing.assert_allclose(mat.data, want, rtol=1e-5, atol=1e-6)
    else:  # within half a step of 1/255 (a value below that is one step), plus float32 rounding
        np.testing.assert_array_less(np.abs(mat.data - want), np.where(want >= 0.5 / 255, 0.5 / 255, 1 / 255) + 1e-6)
    assert len(np.unique(cands.model[mat.col])) == 2


def test_task_and_cache_key() -> None:
    from camplace.visibility.cache import task_key

    inst = _team_scene()
    pts = make_target_points(inst, 300, seed=1)
    cands = _columns(inst, "model-major")
    task, _ = make_task(inst, cands, pts)
    assert task.model_ranges() == [(0, 0, 40), (1, 40, 80)]
    assert task.intrinsics(40, 80)[1:] == (96, 96, 1.0, 6.0)
    with pytest.raises(ValueError, match="more than one camera model"):
        task.intrinsics(30, 50)
    # the single-model task has no model columns and its key ignores them; the team's key differs
    single, _ = make_task(dataclasses.replace(inst, team=None), CandidateSet(cands.positions, cands.aims, cands.rotations), pts)
    assert single.cam_model is None
    assert task_key(single) != task_key(task)


def test_perturbed_poses_keep_their_model() -> None:
    from camplace.sampling.perturb import perturb_poses

    inst = _team_scene()
    cands = _columns(inst, "model-major")
    cols = [3, 45, 7, 60]
    pert = perturb_poses(cands, cols, 3, 0.0, 0.0, seed=1)
    np.testing.assert_array_equal(pert.model, np.tile(cands.model[cols], 3))
    pts = make_target_points(inst, 800, seed=1)
    # zero pose error: the installed columns are the nominal ones (scenario-major, models interleaved)
    a = compute_visibility(inst, pert, pts).matrix
    b = compute_visibility(inst, cands, pts).matrix[:, np.tile(cols, 3)]
    assert (a != b).nnz == 0 and b.nnz > 0


def test_model_columns_need_a_team_instance() -> None:
    from camplace.errors import CamplaceError

    inst = _team_scene()
    pts = make_target_points(inst, 200, seed=1)
    cands = _columns(inst, "model-major")
    with pytest.raises(CamplaceError, match="the columns name camera models but the instance has a single"):
        compute_visibility(dataclasses.replace(inst, team=None), cands, pts)
