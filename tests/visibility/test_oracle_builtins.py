"""Every built-in instance, every frame: the engine agrees with the numpy oracle (incl. incidence and shadow)."""

import dataclasses

import numpy as np
import pytest

from camplace.instance import BUILTINS, builtin
from camplace.instance.schema import QualitySpec
from camplace.event import event_aims
from camplace.sampling import make_candidates
from camplace.visibility import compute_visibility, frame_scene, make_target_points
from camplace.visibility.engine import EPS_REL

from .oracle import observed


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_builtin_agrees_with_oracle(name: str) -> None:
    inst = builtin(name)
    inst = dataclasses.replace(inst, quality=QualitySpec(mode="graded", max_incidence_deg=75.0, require_light=True))
    n_frames = len(inst.frames)
    pts = make_target_points(inst, 300 * n_frames, seed=1)
    cands = make_candidates("uniform", 40, inst.volume.min_m, inst.volume.max_m, event_aims(inst, 3), seed=2)
    dense = compute_visibility(inst, cands, pts, chunk_size=16).matrix.toarray() > 0
    rng = np.random.default_rng(3)
    K = inst.camera.K()
    light = np.asarray(inst.light.position_m)
    agree = total = positives = 0
    for f in range(n_frames):
        rows = np.nonzero(pts.frame == f)[0]
        tris = frame_scene(inst, f).triangles.astype(np.float64)
        eps = EPS_REL * float(np.linalg.norm(np.ptp(inst.target_world(f)[0], axis=0)))
        n_pairs = max(40, 2000 // n_frames)
        for r, c in zip(rng.choice(rows, n_pairs), rng.integers(0, len(cands), n_pairs)):
            want = observed(
                pts.positions[r], pts.normals[r], cands.positions[c], cands.rotations[c], K,
                inst.camera.width_px, inst.camera.height_px, inst.camera.near_m, inst.camera.far_m, tris, eps,
                max_incidence_deg=75.0, light=light,
            )
            agree += want == dense[r, c]
            positives += want
            total += 1
    assert agree / total >= 0.999, (name, agree, total)
    assert positives > 0.02 * total, (name, positives, total)
