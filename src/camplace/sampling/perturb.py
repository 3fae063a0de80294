"""Installation error: perturbed copies of candidate poses (the scenarios of a robust placement).

A camera planned at position ``p`` with world-from-camera rotation ``R`` is installed at

* ``p + dp`` with ``dp ~ N(0, position_sigma_m^2 I)`` (metres, per world axis), and
* ``R @ Exp(w)`` with ``w ~ N(0, rotation_sigma_rad^2 I)``, a rotation vector in the camera frame
  (:class:`scipy.spatial.transform.Rotation`), so the turn is about a random axis;

the same model as the emulated physical camera of ``[physical]``
(:func:`camplace.validation.physical.perturb_camera`), so ``camplace validate`` with the same sigmas
photographs installations drawn from the distribution the placement was optimised against. (The
angle of the turn, ``|w|``, then follows a Maxwell distribution with mean ``1.60 * sigma``.)

Draws: candidate ``j`` has its own stream ``SeedSequence(seed, spawn_key=(stream, j))`` from which
its ``S`` scenarios take ``(S, 6)`` standard normals (3 position, then 3 rotation numbers per
scenario). The in-sample scenarios of a robust run use a randomised quasi-Monte Carlo design
instead (``design="sobol"``): candidate j's S scenarios are the first S points of a scrambled Sobol
sequence in 6 dimensions (scipy.stats.qmc, scrambled from the same stream) in a random order of
its own, mapped to normals by the inverse normal CDF. (Without the shuffle the scrambles of one
base sequence agree on leading digits point by point, which would pair the cameras' errors.) Each scenario is still an exact draw of the model and the errors of
different cameras stay independent (each candidate has its own scramble), but a camera's average
over its S installations is far less noisy than with independent draws, and that noise is what the
optimiser would otherwise exploit among many near-equal candidates (the winner's curse).
The draws of one candidate therefore do not depend on the other candidates nor on how
many there are, every candidate is perturbed independently of the others in each scenario, and a
camera shared by two systems is perturbed identically in both (common random numbers). A different
``stream`` (the run's in-sample scenarios use 2, the out-of-sample check 3) gives fresh scenarios.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from camplace.sampling.candidates import CandidateSet

__all__ = ["DESIGNS", "IN_SAMPLE_STREAM", "OUT_OF_SAMPLE_STREAM", "pose_draws", "perturb_poses"]

#: ``spawn_key`` stream of the scenarios a robust run optimises over (0 and 1 are the candidate and
#: point streams of :func:`camplace.visibility.stages.stage_seeds`).
IN_SAMPLE_STREAM = 2
#: Stream of the fresh scenarios of the out-of-sample check.
OUT_OF_SAMPLE_STREAM = 3


DESIGNS = ("iid", "sobol")


def pose_draws(seed: int, candidates: Sequence[int], scenarios: int, stream: int = IN_SAMPLE_STREAM,
               design: str = "iid") -> np.ndarray:
    """Standard normal draws of the pose errors of some candidates.

    Parameters
    ----------
    seed : int
        The run seed (>= 0).
    candidates : sequence of int
        Candidate (column) indices; each has its own stream, so the result for ``j`` does not
        depend on the other indices.
    scenarios : int
        S, the installations drawn per candidate.
    stream : int
        Which family of scenarios (:data:`IN_SAMPLE_STREAM`, :data:`OUT_OF_SAMPLE_STREAM`).
    design : {"iid", "sobol"}
        Independent normals, or a scrambled Sobol design per candidate (see the module docstring).

    Returns
    -------
    (c, S, 6) float64
        Per candidate and scenario: 3 position then 3 rotation-vector standard normals.
    """
    idx = [int(j) for j in candidates]
    out = np.empty((len(idx), int(scenarios), 6), dtype=np.float64)
    for t, j in enumerate(idx):
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(stream), j)))
        if design == "sobol":
            m = max(0, math.ceil(math.log2(max(1, int(scenarios)))))
            from scipy.special import ndtri
            from scipy.stats import qmc  # here: 0.3 s of imports a plain run does not need

            u = qmc.Sobol(d=6, scramble=True, seed=rng).random_base2(m)[: int(scenarios)]
            # scrambles of one base sequence share its leading digits point by point: shuffled per
            # candidate, so that the cameras of one scenario are paired at random (independent)
            out[t] = ndtri(np.clip(u[rng.permutation(len(u))], 1e-12, 1.0 - 1e-12))
        elif design == "iid":
            out[t] = rng.standard_normal((int(scenarios), 6))
        else:
            raise ValueError(f"unknown design {design!r} (use one of {', '.join(DESIGNS)})")
    return out


def perturb_poses(
    cands: CandidateSet,
    candidates: Sequence[int] | None,
    scenarios: int,
    position_sigma_m: float,
    rotation_sigma_deg: float,
    *,
    seed: int,
    stream: int = IN_SAMPLE_STREAM,
    design: str = "iid",
) -> CandidateSet:
    """The installed poses of some candidates in S sampled installations.

    Parameters
    ----------
    cands : CandidateSet
        The nominal (planned) poses.
    candidates : sequence of int or None
        Which candidates (column indices of ``cands``); None for all.
    scenarios : int
        S.
    position_sigma_m, rotation_sigma_deg : float
        Standard deviations of the position error per axis (metres) and of each rotation-vector
        component (degrees).
    seed, stream : int
        See :func:`pose_draws`.
    design : {"iid", "sobol"}
        See :func:`pose_draws`.

    Returns
    -------
    CandidateSet
        ``S * c`` poses, scenario-major: pose ``s * c + t`` is candidate ``candidates[t]`` in
        scenario ``s``. Aims move with the camera (same distance along the new optical axis).
    """
    idx = np.arange(len(cands)) if candidates is None else np.asarray(list(candidates), dtype=np.int64)
    c, s_count = len(idx), int(scenarios)
    z = pose_draws(seed, idx, s_count, stream, design)  # (c, S, 6)
    z = np.swapaxes(z, 0, 1)  # (S, c, 6): scenario-major
    pos0 = cands.positions[idx]
    rot0 = cands.rotations[idx]
    dist = np.linalg.norm(cands.aims[idx] - pos0, axis=1)
    pos = (pos0[None, :, :] + float(position_sigma_m) * z[:, :, :3]).reshape(s_count * c, 3)
    turn = Rotation.from_rotvec((math.radians(float(rotation_sigma_deg)) * z[:, :, 3:]).reshape(-1, 3)).as_matrix()
    rot = np.einsum("cij,scjk->scik", rot0, turn.reshape(s_count, c, 3, 3)).reshape(s_count * c, 3, 3)
    aims = pos + rot[:, :, 2] * np.tile(dist, s_count)[:, None]
    model = None if cands.model is None else np.tile(np.asarray(cands.model)[idx], s_count)
    return CandidateSet(positions=pos, aims=aims, rotations=rot, sampler=cands.sampler, seed=cands.seed, model=model)
