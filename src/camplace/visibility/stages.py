"""The inputs of a run below the solver: its seed streams, candidate poses, matrix rows and matrix.

Shared by ``camplace run`` (:mod:`camplace.pipeline`), the sampler campaigns
(:mod:`camplace.report.campaign`) and the ladder study (:mod:`camplace.report.study`), so that a
campaign with a run's seed reproduces the run's candidates and points exactly. Embree is loaded
only when a function needs it (ground tests, the matrix).
"""

from __future__ import annotations

import os

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

    if getattr(instance, "team", None) is not None:
        return make_team_candidates(instance, sampler, n, orientations, seed)
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


def _region_seed(seed, r: int) -> np.random.SeedSequence:
    """The seed stream of region ``r`` of a run's candidate stream ``seed`` (int or SeedSequence)."""
    if isinstance(seed, np.random.SeedSequence):
        return np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, r))
    return np.random.SeedSequence(0 if seed is None else int(seed), spawn_key=(r,))


def split_count(n: int, shares) -> np.ndarray:
    """(r,) int64: ``n`` split over regions in proportion to ``shares`` (largest remainder; ties to the first)."""
    w = np.asarray(shares, dtype=np.float64)
    exact = n * w / w.sum()
    out = np.floor(exact).astype(np.int64)
    rest = n - int(out.sum())
    order = np.lexsort((np.arange(len(w)), -(exact - out)))
    out[order[:rest]] += 1
    return out


def sample_on_mesh(kind: str, n: int, vertices: np.ndarray, faces: np.ndarray, offset_m: float, *, seed=0) -> np.ndarray:
    """``n`` positions on a triangle mesh, each ``offset_m`` off it along its triangle's unit normal.

    The sampler's unit cube point (u0, u1, u2) picks a triangle by area (u0, inverse CDF) and a
    point in it uniformly (barycentric ``(1 - s, s (1 - u2), s u2)`` with ``s = sqrt(u1)``).

    Parameters
    ----------
    kind : {"chaotic", "uniform", "sobol"}
    n : int
    vertices : (v, 3) float64
        World metres.
    faces : (m, 3) int64
        Counter-clockwise seen from outside (the normal points away from the surface).
    offset_m : float
    seed : int, SeedSequence or None

    Returns
    -------
    (n, 3) float64
    """
    from camplace.sampling import sample_unit

    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(cross, axis=1)
    normal = cross / np.where(area > 0, area, 1.0)[:, None]
    cdf = np.cumsum(area)
    u = np.clip(sample_unit(kind, n, 3, seed=seed), 1e-9, 1.0 - 1e-9)
    t = np.minimum(np.searchsorted(cdf, u[:, 0] * cdf[-1], side="right"), len(tri) - 1)
    s = np.sqrt(u[:, 1])
    b = np.column_stack([1.0 - s, s * (1.0 - u[:, 2]), s * u[:, 2]])
    return np.einsum("ni,nij->nj", b, tri[t]) + float(offset_m) * normal[t]


def team_positions(instance, sampler: str, n: int, seed) -> tuple[np.ndarray, np.ndarray]:
    """``n`` sampled positions where some camera model of the team may stand.

    The count is split over the team's regions (volumes, then mounts) by their ``share``; each
    region draws its positions from its own seed stream with the run's sampler, rejecting those in
    a keep-out or under the ground (oversampling as :func:`make_run_candidates`, so a region's
    positions for a larger count start with those for a smaller one).

    Returns
    -------
    positions : (n, 3) float64
    mount : (n,) int64
        The mount a position was sampled on (index into ``team.mounts``), -1 for volume samples.
    """
    from camplace.sampling import sample_positions

    team = instance.team
    regions = [*team.volumes, *team.mounts]
    counts = split_count(n, [r.share for r in regions])
    out_pos, out_mount = [], []
    for r, (region, cnt) in enumerate(zip(regions, counts)):
        if cnt == 0:
            continue
        is_mount = r >= len(team.volumes)
        field = f"mounts[{r - len(team.volumes)}]" if is_mount else f"volumes[{r}]"
        factor = 1
        while True:
            if is_mount:
                v, f = region.world()
                pos = sample_on_mesh(sampler, int(cnt) * factor, v, f, region.offset_m, seed=_region_seed(seed, r))
            else:
                pos = sample_positions(sampler, int(cnt) * factor, region.min_m, region.max_m, seed=_region_seed(seed, r))
            ok = ~team.in_keepout(pos) & ~under_ground(instance, pos)
            if ok.sum() >= cnt or factor >= 256:
                break
            factor *= 4
        pos = pos[ok][:cnt]
        if len(pos) < cnt:
            raise CamplaceError(
                f"{instance.source}: {field}: only {len(pos)} of {int(cnt) * factor} sampled positions are outside the "
                "keep-outs and above the ground (shrink the [[keepouts]] or move the region)"
            )
        out_pos.append(pos)
        out_mount.append(np.full(len(pos), r - len(team.volumes) if is_mount else -1, dtype=np.int64))
    if not out_pos:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    return np.concatenate(out_pos), np.concatenate(out_mount)


def make_team_candidates(instance, sampler: str, n: int, orientations: int, seed) -> CandidateSet:
    """The candidate columns of a team: each sampled pose offered with each model that may stand there.

    Columns are model-major: model 0's poses (position ``i`` aimed ``orientations`` ways, in
    sampling order, as :func:`make_run_candidates`), then model 1's, ...; ``CandidateSet.model``
    holds the model of every column and ``CandidateSet.zones`` its zone membership.

    Raises
    ------
    CamplaceError
        When a model may stand at none of the sampled positions.
    """
    from camplace.sampling import candidates_from_positions

    team = instance.team
    pos, mount = team_positions(instance, sampler, n, seed)
    allowed = team.allowed_models(pos, mount)
    aims = event_aims(instance, orientations)
    parts, models = [], []
    for j, m in enumerate(team.models):
        idx = np.flatnonzero(allowed[:, j])
        if len(idx) == 0:
            raise CamplaceError(
                f"{instance.source}: cameras[{j}]: model {m.name!r} may stand at none of the {len(pos)} sampled positions "
                "(raise --candidates, or give it a larger [[volumes]] / [[mounts]] region outside the keep-outs)"
            )
        c = candidates_from_positions(pos[idx], aims, sampler=sampler)
        parts.append(c)
        models.append(np.full(len(c), j, dtype=np.int16))
    positions = np.concatenate([c.positions for c in parts])
    return CandidateSet(
        positions=positions, aims=np.concatenate([c.aims for c in parts]), rotations=np.concatenate([c.rotations for c in parts]),
        sampler=sampler, model=np.concatenate(models), zones=team.zone_membership(positions),
    )


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
    scratch=None,
    solve_mode: str | None = None,
    idle=None,
    solve_bytes=None,
) -> VisibilityMatrix:
    """Compute (or fetch from the cache) the visibility matrix, with a progress bar (``scratch``: a
    :class:`~camplace.visibility.scratch.Scratch` for column bitsets or bytes over the budget; ``solve_mode``:
    the mode the run solves next, for the memory estimate of quantised columns: None or
    ``quality`` counts the quality tree; ``solve_bytes``: the working bytes of the solve on column
    bitsets besides them, for their estimate, a number or a function of the observed share of cells
    (the pipeline's :func:`camplace.solver.api.bits_solve_bytes`); ``idle``: work
    for this thread while the chunks are cast,
    see :func:`~camplace.visibility.engine.compute_visibility`)."""
    from camplace.visibility.cache import default_cache_dir
    from camplace.visibility import compute_visibility

    reporter = reporter or Reporter()
    if memory_budget_gb is not None and not memory_budget_gb > 0:
        raise CamplaceError(f"--memory-budget-gb: must be > 0, got {memory_budget_gb}")
    budget = None if memory_budget_gb is None else int(memory_budget_gb * 2**30)
    # CAMPLACE_VISIBILITY_LAYOUT=csr keeps a binary matrix as float32 CSR (the layout before column
    # bitsets: benchmarks/scale.py measures it as the baseline)
    layout = os.environ.get("CAMPLACE_VISIBILITY_LAYOUT", "auto")
    with reporter.stage("visibility", total=len(cands)) as advance:
        return compute_visibility(
            instance, cands, pts, progress=advance, memory_budget_bytes=budget, dask_address=dask_address,
            cache_dir=default_cache_dir() if cache else None, layout=layout, scratch=scratch,
            quality_tree=solve_mode in (None, "quality"), idle=idle, solve_bytes=solve_bytes,
        )

