"""Campaigns of random systems for a camera team (issue 31): each random camera has a model that may stand there."""

from __future__ import annotations

import numpy as np

from camplace.instance import builtin
from camplace.report.campaign import Campaign, run_campaign
from camplace.sampling import CandidateSet
from camplace.visibility import compute_visibility


def test_team_campaign_draws_allowed_models_and_round_trips(tmp_path) -> None:
    inst = builtin("comet-67p-team")
    camp = run_campaign(inst, systems=12, sampler="uniform", seed=3, points=400, k=3, outdir=tmp_path / "c", cache=False)
    assert camp.model.shape == (12, 3)
    model = camp.model.reshape(-1)
    pos = camp.positions.reshape(-1, 3)
    assert set(model.tolist()) == {0, 1}  # both models drawn
    team = inst.team
    v, f = team.mounts[0].world()
    lo, hi = v.min(axis=0) - 0.051, v.max(axis=0) + 0.051
    on_mast = np.all((pos > lo) & (pos < hi), axis=1)
    allowed = team.allowed_models(pos, np.where(on_mast, 0, -1))
    assert allowed[np.arange(len(pos)), model].all()
    # scored with each camera's own intrinsics: the stored matrix is the team matrix of those columns
    cands = CandidateSet(pos, camp.aims.reshape(-1, 3), camp.rotations.reshape(-1, 3, 3), model=model)
    from camplace.visibility.stages import compute_points

    ref = compute_visibility(inst, cands, compute_points(inst, 400, 3)).matrix
    assert (ref != camp.matrix).nnz == 0
    back = Campaign.load(tmp_path / "c", matrix=True)
    np.testing.assert_array_equal(back.model, camp.model)
