"""The inputs of a run below the solver: its seed streams, candidate poses, matrix rows and matrix.

Shared by ``camplace run`` (:mod:`camplace.pipeline`), the sampler campaigns
(:mod:`camplace.report.campaign`) and the ladder study (:mod:`camplace.report.study`), so that a
campaign with a run's seed reproduces the run's candidates and points exactly. Embree is loaded
only when a function needs it (ground tests, the matrix).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from camplace._progress import Reporter
from camplace.errors import CamplaceError
from camplace.event import event_aims
from camplace.sampling import CandidateSet

if TYPE_CHECKING:  # pragma: no cover
    from camplace.visibility.engine import VisibilityMatrix

__all__ = ["under_ground", "make_run_candidates", "stage_seeds", "check_input_memory", "compute_points",
           "visibility_stage"]


def under_ground(instance, positions: np.ndarray) -> np.ndarray:
    """(n,) bool: positions under (or inside) a ``ground = true`` occluder: a ray straight up hits it."""
    ground = [o.mesh.transformed(o.pose) for o in instance.occluders if o.ground]
    if not ground or len(positions) == 0:
        return np.zeros(len(positions), dtype=bool)
    from camplace.visibility import RayScene  # Embree: only when there is ground to test against

    scene = RayScene(ground)
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), positions.shape)
    tri, _ = scene.first_hit(positions, up)
    return tri >= 0


def make_run_candidates(instance, sampler: str, n: int, orientations: int, seed) -> CandidateSet:
    """The candidate poses of a run: ``n`` sampled positions above any ground, each aimed ``orientations`` ways.

    Positions under the terrain are rejected; since every sampler's sequence for a larger count
    starts with the sequence for a smaller one, oversampling keeps the result independent of how
    many draws were needed.
    """
    from camplace.sampling import candidates_from_positions, sample_positions

    lo, hi = instance.volume.min_m, instance.volume.max_m
    factor = 1
    while True:
        pos = sample_positions(sampler, n * factor, lo, hi, seed=seed)
        ok = ~under_ground(instance, pos)
        if ok.sum() >= n or factor >= 256:
            break
        factor *= 4
    pos = pos[ok][:n]
    if len(pos) < n:
        raise CamplaceError(
            f"{instance.source}: volume: only {len(pos)} of {n * factor} sampled positions are above the ground "
            "(raise volume.max_m above the terrain)"
        )
    return candidates_from_positions(pos, event_aims(instance, orientations), sampler=sampler)


def stage_seeds(seed: int) -> tuple[np.random.SeedSequence, np.random.SeedSequence]:
    """Independent seed streams of a run: (candidates, points)."""
    cand_seed, point_seed = np.random.SeedSequence(seed).spawn(2)
    return cand_seed, point_seed


# Bytes a matrix row (target point) and a candidate pose cost before the matrix exists: the arrays
# kept (positions, normals, frame, weight; position, aim, rotation) and the sampling temporaries.
_ROW_BYTES = 200
_POSE_BYTES = 400


def check_input_memory(n_points: int, n_frames: int, n_poses: int = 0, memory_budget_gb: float | None = None) -> None:
    """Stop with a one-line error when the rows and candidate poses alone would not fit the budget.

    Parameters
    ----------
    n_points : int
        Surface points requested (``--points``; split over ``n_frames`` frames, rounded up).
    n_frames : int
    n_poses : int
        Candidate poses (positions x orientations).
    memory_budget_gb : float or None
        Budget in GiB (default: half the machine's memory, as the visibility stage).

    Raises
    ------
    CamplaceError
        Naming the option to lower, before anything is allocated.
    """
    from camplace.visibility.engine import available_memory_bytes

    budget = available_memory_bytes() // 2 if memory_budget_gb is None else int(memory_budget_gb * 2**30)
    rows = -(-int(n_points) // max(1, n_frames)) * max(1, n_frames)
    need = rows * _ROW_BYTES + int(n_poses) * _POSE_BYTES
    if need > budget:
        what = "--points" if rows * _ROW_BYTES >= n_poses * _POSE_BYTES else "--candidates"
        raise CamplaceError(
            f"{what}: {rows:,} points and {n_poses:,} candidate poses need about {need / 2**30:.1f} GiB before the "
            f"visibility matrix, over the {budget / 2**30:.1f} GiB budget (lower {what} or raise --memory-budget-gb)"
        )


def compute_points(instance, n_points: int | None = None, seed: int | None = None):
    """The matrix rows of a run with this seed (the same points ``run`` makes).

    Parameters
    ----------
    instance : Instance
    n_points : int or None
        Surface points (default: the instance's ``run.points``).
    seed : int or None
        Run seed (default: the instance's ``run.seed``).

    Returns
    -------
    TargetPoints
    """
    n_points = instance.defaults.points if n_points is None else int(n_points)
    seed = instance.defaults.seed if seed is None else int(seed)
    if seed < 0:
        raise CamplaceError(f"--seed: must be >= 0, got {seed}")
    if n_points < 1:
        raise CamplaceError(f"--points: must be >= 1, got {n_points}")
    from camplace.visibility import make_target_points

    check_input_memory(n_points, len(instance.frames))
    return make_target_points(instance, n_points, seed=stage_seeds(seed)[1])


def visibility_stage(
    instance,
    cands: CandidateSet,
    pts,
    *,
    reporter: Reporter | None = None,
    cache: bool = True,
    dask_address: str | None = None,
    memory_budget_gb: float | None = None,
) -> VisibilityMatrix:
    """Compute (or fetch from the cache) the visibility matrix, with a progress bar."""
    from camplace.visibility.cache import default_cache_dir
    from camplace.visibility import compute_visibility

    reporter = reporter or Reporter()
    if memory_budget_gb is not None and not memory_budget_gb > 0:
        raise CamplaceError(f"--memory-budget-gb: must be > 0, got {memory_budget_gb}")
    budget = None if memory_budget_gb is None else int(memory_budget_gb * 2**30)
    with reporter.stage("visibility", total=len(cands)) as advance:
        return compute_visibility(
            instance, cands, pts, progress=advance, memory_budget_bytes=budget, dask_address=dask_address,
            cache_dir=default_cache_dir() if cache else None,
        )

