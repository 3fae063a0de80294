"""The points x candidates visibility matrix, by culling then Embree segment casting.

A (row, candidate) pair is observed when, in the candidate's camera (OpenCV axes, pinhole):

1. the point lies between ``near_m`` and ``far_m`` in depth (camera z);
2. it projects inside the image: ``-0.5 <= u < width - 0.5`` and ``-0.5 <= v < height - 0.5``
   (pixel centres at integer coordinates, principal point at the image centre);
3. for a surface point: it faces the camera, ``cos(theta) = n . (c - p) / |c - p| > 0``, and
   ``theta <= max_incidence_deg``; (volumetric emitter points, with zero normal, skip this test);
4. with ``require_light``, a surface point must be lit: ``n . (L - p) > 0`` and the segment from
   ``p + eps * n`` to the light ``L`` is unblocked (emitters glow and skip this test);
5. the segment from the camera centre to ``p + eps * n`` crosses no triangle of the scene
   (every occluder of the point's frame, the target itself included). ``eps`` is 1e-4 of the
   target's bounding-box diagonal and keeps the point's own face from occluding it.

Its value, the observation quality, is 1 in ``binary`` mode; in ``graded`` mode it is
``min(1, f_px / (distance * required_px_per_m)) * cos(theta)`` for surface points (resolution
times foreshortening) and the resolution factor alone for emitters.

Pairs failing 1-4 are culled in numpy before any ray is cast (facing by one matrix product per
chunk, the frustum per camera when the whole target fits in it); segments to points on a
supporting plane of the target are cast against the occluders alone (they provably miss the
target); the rest are cast with Embree, chunk by chunk over candidates, on a pool of threads
(Embree and numpy release the GIL) or on a Dask cluster (:mod:`camplace.visibility.distributed`).
"""

from __future__ import annotations

import functools
import logging
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import scipy.sparse as sp

from camplace._io import write_with_atomic
from camplace.errors import CamplaceError
from camplace.visibility.points import TargetPoints
from camplace.visibility.raycast import RayScene

log = logging.getLogger(__name__)

EPS_REL = 1e-4
#: Bumped whenever the meaning of the matrix changes, so cached matrices are not reused.
ENGINE_VERSION = "3"
COUNT_KEYS = ("pairs", "in_range", "in_frustum", "facing", "cast", "observed")


@dataclass(frozen=True, eq=False)
class VisibilityMatrix:
    """Observation quality of every (point, candidate) pair.

    Attributes
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix of float32
        Value > 0 means observed; the value is the observation quality in (0, 1].
    points : TargetPoints
        The m rows.
    stats : dict
        Pair counts after each culling step.
    """

    matrix: sp.csr_matrix
    points: TargetPoints
    stats: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return self.matrix.shape

    def save(self, outdir: str | Path) -> None:
        """Write ``visibility.npz`` (for ``scipy.sparse.load_npz``) and ``points.csv`` atomically."""
        outdir = Path(outdir)
        write_with_atomic(outdir / "visibility.npz", lambda p: sp.save_npz(p, self.matrix, compressed=True))
        self.points.save(outdir / "points.csv")

    @classmethod
    def load(cls, outdir: str | Path) -> "VisibilityMatrix":
        """Read ``visibility.npz`` and ``points.csv`` from a run's output folder."""
        outdir = Path(outdir)
        try:
            matrix = sp.load_npz(outdir / "visibility.npz").tocsr()
        except (OSError, ValueError) as exc:
            raise CamplaceError(f"{outdir / 'visibility.npz'}: cannot read the visibility matrix ({exc})") from None
        points = TargetPoints.load(outdir / "points.csv")
        if matrix.shape[0] != len(points):
            raise CamplaceError(
                f"{outdir}: visibility.npz has {matrix.shape[0]} rows but points.csv has {len(points)} (re-run)"
            )
        return cls(matrix=matrix.astype(np.float32), points=points)


def frame_scene(instance, frame: int) -> RayScene:
    """Embree scene of everything that occludes in ``frame``: occluders and the posed target."""
    meshes = [(v, f) for _, v, f in instance.occluders_world(frame)]
    meshes.append(instance.target_world(frame))
    return RayScene(meshes)


@dataclass(frozen=True, eq=False)
class VisibilityTask:
    """Everything a worker needs to compute columns of the matrix: plain, picklable arrays.

    Attributes
    ----------
    positions : (m, 3) float64
        Row points.
    normals : (m, 3) float64
        Row normals (zero for emitters).
    frame : (m,) int32
    active : (m,) bool
        Rows that can be observed at all (False for unlit surface points when light is required).
    eps_m : (n_frames,) float64
        Per-frame offset along the normal for the segment end.
    cam_positions : (n, 3) float64
    cam_rotations : (n, 3, 3) float64
    K : (3, 3) float64
    width_px, height_px : int
    near_m, far_m : float
    graded : bool
    required_px_per_m : float
    cos_max_incidence : float
    scene_triangles : dict of int to (t, 3, 3) float32
        The triangles of each frame's scene, exactly as cast.
    rest_triangles : dict of int to (t, 3, 3) float32
        The same without the target (the occluders alone).
    support : (m,) bool
        Surface rows whose tangent plane supports the target: every target vertex v of the row's
        frame has ``n . (v - p) <= support_tol``. A segment from a camera with
        ``n . (c - p) > support_tol`` to ``p + eps n`` then lies in the open half-space beyond that
        plane and cannot meet the target, so it is cast against the occluders alone.
    support_tol : (n_frames,) float64
    """

    positions: np.ndarray
    normals: np.ndarray
    frame: np.ndarray
    active: np.ndarray
    eps_m: np.ndarray
    cam_positions: np.ndarray
    cam_rotations: np.ndarray
    K: np.ndarray
    width_px: int
    height_px: int
    near_m: float
    far_m: float
    graded: bool
    required_px_per_m: float
    cos_max_incidence: float
    scene_triangles: dict
    rest_triangles: dict
    support: np.ndarray
    support_tol: np.ndarray

    @property
    def n_candidates(self) -> int:
        return int(self.cam_positions.shape[0])

    @functools.cached_property
    def live_rows(self) -> np.ndarray:
        """(l,) int64: the rows that can be observed at all (``active``), ascending."""
        return np.nonzero(self.active)[0]

    @functools.cached_property
    def ends32(self) -> np.ndarray:
        """(m, 3) float32: segment end of every row, ``p + eps n`` (the point itself for emitters)."""
        return (self.positions + self.eps_m[self.frame][:, None] * self.normals).astype(np.float32)

    def build_scenes(self) -> dict[int, "FrameScenes"]:
        """The Embree scenes of every frame (build once per process)."""
        return {
            f: FrameScenes(RayScene.from_triangles(t), RayScene.from_triangles(self.rest_triangles[f]))
            for f, t in self.scene_triangles.items()
        }


@dataclass(frozen=True, eq=False)
class FrameScenes:
    """A frame's scene with the target (``full``) and without it (``rest``)."""

    full: RayScene
    rest: RayScene


def sphere_inside_view(
    centre: np.ndarray, radius: float, cam_pos: np.ndarray, cam_rot: np.ndarray, K: np.ndarray,
    width_px: int, height_px: int, near_m: float, far_m: float,
) -> np.ndarray:
    """Which cameras hold a whole sphere inside their frustum and depth range.

    Parameters
    ----------
    centre : (3,) float64
    radius : float
    cam_pos : (c, 3) float64
    cam_rot : (c, 3, 3) float64
    K : (3, 3) float64
    width_px, height_px : int
    near_m, far_m : float

    Returns
    -------
    (c,) bool
        True when every point of the sphere passes the range and frustum tests (conservative:
        False may still hold it).
    """
    cam = np.einsum("ck,ckl->cl", centre[None, :] - cam_pos, cam_rot)
    x, y, z = cam[:, 0], cam[:, 1], cam[:, 2]
    ok = (z - radius >= near_m) & (z + radius <= far_m)
    # image bounds -0.5 .. W-0.5 as tangent slopes of the four side planes, shrunk a hair
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    bounds = ((-0.5 - cx) / fx, (width_px - 0.5 - cx) / fx, (-0.5 - cy) / fy, (height_px - 0.5 - cy) / fy)
    for coord, slope, sign in ((x, bounds[0], -1), (x, bounds[1], 1), (y, bounds[2], -1), (y, bounds[3], 1)):
        # plane through the origin containing the axis direction (slope, 1); outward normal ~ sign*(1, -slope)
        nrm = np.array([1.0, -slope]) / np.hypot(1.0, slope)
        signed = sign * (coord * nrm[0] + z * nrm[1])  # > 0 outside
        ok &= signed <= -radius * (1 + 1e-9) - 1e-12
    return ok


def frustum_mask(
    points: np.ndarray, cam_pos: np.ndarray, cam_rot: np.ndarray, K: np.ndarray,
    width_px: int, height_px: int, near_m: float, far_m: float,
) -> tuple[np.ndarray, int]:
    """(c, m) bool: points in each camera's depth range and image; also the in-range count."""
    diff = points[None, :, :] - cam_pos[:, None, :]
    cam = np.einsum("cmk,ckl->cml", diff, cam_rot)
    z = cam[:, :, 2]
    ok = (z >= near_m) & (z <= far_m)
    n_range = int(ok.sum())
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * cam[:, :, 0] / z + K[0, 2]
        v = K[1, 1] * cam[:, :, 1] / z + K[1, 2]
    ok &= (u >= -0.5) & (u < width_px - 0.5) & (v >= -0.5) & (v < height_px - 0.5)
    return ok, n_range


def compute_chunk(
    task: VisibilityTask, scenes: dict[int, "FrameScenes"], start: int, stop: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Observed pairs of candidates ``start:stop``, column-major with rows ascending.

    Facing tests are one matrix product per frame (``C @ N^T`` against ``n . p``); cameras that
    hold the frame's whole active point set inside their frustum and range skip the per-pair
    frustum test; segments to points on a supporting plane of the target (see
    :class:`VisibilityTask`) are cast against the occluders alone.

    Returns
    -------
    rows : (q,) int32
    cols : (q,) int32
        Global candidate indices.
    values : (q,) float32
        Observation quality.
    counts : dict
    """
    pos = task.cam_positions[start:stop]
    rot = task.cam_rotations[start:stop]
    nc = stop - start
    counts = dict.fromkeys(COUNT_KEYS, 0)
    live = task.live_rows
    counts["pairs"] = len(task.frame) * nc
    if len(live) == 0 or nc == 0:
        return np.empty(0, np.int32), np.empty(0, np.int32), np.empty(0, np.float32), counts
    live_frame = task.frame[live]
    ok = np.zeros((nc, len(live)), dtype=bool)
    sup = np.zeros((nc, len(live)), dtype=bool)  # pairs whose segment cannot meet the target
    for f in sorted(task.scene_triangles):
        sl = np.nonzero(live_frame == f)[0]
        if len(sl) == 0:
            continue
        rows = live[sl]
        p = task.positions[rows]
        nrm = task.normals[rows]
        emitter = ~np.any(nrm != 0.0, axis=1)
        dot = pos @ nrm.T - np.einsum("ij,ij->i", nrm, p)[None, :]  # n . (c - p)
        fac = (dot > 0.0) | emitter[None, :]
        lo, hi = p.min(axis=0), p.max(axis=0)
        whole = sphere_inside_view(
            (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2), pos, rot, task.K,
            task.width_px, task.height_px, task.near_m, task.far_m,
        )
        n_whole = int(whole.sum()) * len(sl)
        counts["in_range"] += n_whole
        counts["in_frustum"] += n_whole
        part = np.nonzero(~whole)[0]
        if len(part):
            view, n_range = frustum_mask(p, pos[part], rot[part], task.K, task.width_px, task.height_px, task.near_m, task.far_m)
            counts["in_range"] += n_range
            counts["in_frustum"] += int(view.sum())
            fac[part] &= view
        block = slice(sl[0], sl[-1] + 1) if sl[-1] - sl[0] + 1 == len(sl) else sl  # frames: contiguous rows
        ok[:, block] = fac
        sup[:, block] = fac & (dot > task.support_tol[f]) & task.support[rows][None, :]
    ci, li = np.nonzero(ok)  # camera-major, rows ascending within a camera
    rows_g = live[li]
    supported = sup[ci, li]
    if task.graded or task.cos_max_incidence > 0.0:
        d = task.positions[rows_g] - pos[ci]
        dist = np.sqrt(np.einsum("qk,qk->q", d, d))
        emit = ~np.any(task.normals[rows_g] != 0.0, axis=1)
        cos_t = np.where(emit, 1.0, -np.einsum("qk,qk->q", d, task.normals[rows_g]) / np.maximum(dist, 1e-300))
        keep = emit | (cos_t >= task.cos_max_incidence)
        ci, rows_g, supported, dist, cos_t = ci[keep], rows_g[keep], supported[keep], dist[keep], cos_t[keep]
    counts["facing"] += len(ci)
    # segments camera -> p + eps * n, as float32 origin + unnormalised direction (tfar = 1);
    # rows on a supporting plane of the target, seen from its outer side, skip the target
    pos32 = pos.astype(np.float32)
    fr = task.frame[rows_g]
    single = len(task.scene_triangles) == 1
    blocked = np.zeros(len(ci), dtype=bool)
    for f in task.scene_triangles:
        in_f = None if single else fr == f
        for flag, scene in ((False, scenes[f].full), (True, scenes[f].rest)):
            mask = supported if flag else ~supported
            if in_f is not None:
                mask = mask & in_f
            idx = np.nonzero(mask)[0]
            if len(idx) == 0:
                continue
            origins = pos32[ci[idx]]
            blocked[idx] = scene.occluded_dir(origins, task.ends32[rows_g[idx]] - origins)
            counts["cast"] += len(idx)
    ok_q = ~blocked
    counts["observed"] += int(ok_q.sum())
    if task.graded:
        fx = float(task.K[0, 0])
        q = np.minimum(1.0, fx / (dist[ok_q] * task.required_px_per_m)) * cos_t[ok_q]
        q = np.maximum(q, np.finfo(np.float32).tiny).astype(np.float32)
    else:
        q = np.ones(int(ok_q.sum()), dtype=np.float32)
    return rows_g[ok_q].astype(np.int32), (ci[ok_q] + start).astype(np.int32), q, counts


def lit_mask(instance, points: TargetPoints, scenes: dict[int, RayScene], eps_m: np.ndarray) -> np.ndarray:
    """(m,) bool: surface points lit by the instance's light (emitters count as lit).

    A surface point is lit when ``n . (L - p) > 0`` and the segment from ``p + eps * n`` to the
    light is unblocked in its frame's scene.
    """
    light = np.asarray(instance.light.position_m, dtype=np.float64)
    lit = points.is_emitter.copy()
    for f, scene in scenes.items():
        rows = np.nonzero((points.frame == f) & ~points.is_emitter)[0]
        p, n = points.positions[rows], points.normals[rows]
        facing = np.einsum("qk,qk->q", light - p, n) > 0
        r = rows[facing]
        start = points.positions[r] + float(eps_m[f]) * points.normals[r]
        ok = ~scene.occluded(start, np.broadcast_to(light, start.shape))
        lit[r[ok]] = True
    return lit


def supporting_rows(points: TargetPoints, frame: int, target_vertices: np.ndarray, tol: float) -> np.ndarray:
    """(m,) bool: surface rows of ``frame`` whose tangent plane has every target vertex behind it.

    A row p with normal n qualifies when ``max_v n . (v - p) <= tol`` over the frame's target
    vertices ``v``: the whole (closed, piecewise planar) target lies in the half-space
    ``n . (x - p) <= tol``.
    """
    out = np.zeros(len(points), dtype=bool)
    rows = np.nonzero((points.frame == frame) & ~points.is_emitter)[0]
    for s in range(0, len(rows), 2048):
        r = rows[s:s + 2048]
        n, p = points.normals[r], points.positions[r]
        reach = (target_vertices @ n.T).max(axis=0) - np.einsum("ij,ij->i", n, p)
        out[r] = reach <= tol
    return out


def make_task(instance, candidates, points: TargetPoints) -> tuple[VisibilityTask, dict[int, FrameScenes]]:
    """The picklable task for (instance, candidates, points) and the frame scenes built for it."""
    cam = instance.camera
    q = instance.quality
    frames = [int(f) for f in np.unique(points.frame)]
    full = {f: frame_scene(instance, f) for f in frames}
    rest = {f: RayScene([(v, fc) for _, v, fc in instance.occluders_world(f)]) for f in frames}
    scenes = {f: FrameScenes(full[f], rest[f]) for f in frames}
    eps = np.zeros(len(instance.frames))
    tol = np.zeros(len(instance.frames))
    support = np.zeros(len(points), dtype=bool)
    for f in frames:
        tv = instance.target_world(f)[0]
        diag = float(np.linalg.norm(np.ptp(tv, axis=0)))
        eps[f] = EPS_REL * diag
        tol[f] = 1e-9 * diag
        support |= supporting_rows(points, f, tv, tol[f])
    active = lit_mask(instance, points, full, eps) if q.require_light else np.ones(len(points), dtype=bool)
    cos_max = math.cos(math.radians(q.max_incidence_deg)) if q.max_incidence_deg < 90.0 else 0.0
    task = VisibilityTask(
        positions=points.positions,
        normals=points.normals,
        frame=points.frame,
        active=active,
        eps_m=eps,
        cam_positions=np.asarray(candidates.positions, dtype=np.float64),
        cam_rotations=np.asarray(candidates.rotations, dtype=np.float64),
        K=cam.K(),
        width_px=int(cam.width_px),
        height_px=int(cam.height_px),
        near_m=float(cam.near_m),
        far_m=float(cam.far_m),
        graded=q.mode == "graded",
        required_px_per_m=float(q.required_px_per_m),
        cos_max_incidence=cos_max,
        scene_triangles={f: s.triangles for f, s in full.items()},
        rest_triangles={f: s.triangles for f, s in rest.items()},
        support=support,
        support_tol=tol,
    )
    return task, scenes


def assemble(task: VisibilityTask, parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, dict]]) -> tuple[sp.csr_matrix, dict]:
    """CSR float32 matrix (rows x candidates) and summed counts from chunk results in column order."""
    total = dict.fromkeys(COUNT_KEYS, 0)
    for _, _, _, cnt in parts:
        for key in COUNT_KEYS:
            total[key] += cnt[key]
    m, n = len(task.positions), task.n_candidates
    # parts are in column order and each is column-major with sorted rows: together they are a CSC
    # matrix as it is (filled in place, no concatenation copies), whose conversion to CSR is linear
    nnz = sum(len(p[0]) for p in parts)
    index_dtype = np.int32 if max(m, n, nnz) < 2**31 - 1 else np.int64
    indices = np.empty(nnz, dtype=index_dtype)
    data = np.empty(nnz, dtype=np.float32)
    counts = np.zeros(n, dtype=np.int64)
    at = 0
    for rows, cols, vals, _ in parts:
        q = len(rows)
        indices[at:at + q] = rows
        data[at:at + q] = vals
        counts += np.bincount(cols, minlength=n)
        at += q
    indptr = np.zeros(n + 1, dtype=index_dtype)
    np.cumsum(counts, out=indptr[1:])
    csc = sp.csc_matrix((data, indices, indptr), shape=(m, n), copy=False)
    matrix = csc.tocsr()
    matrix.has_sorted_indices = True
    return matrix, total


def available_memory_bytes() -> int:
    """Physical memory of this machine (bytes), or 8 GiB when unknown."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 8 << 30


def estimate_matrix_bytes(n_rows: int, n_cols: int, density: float) -> int:
    """Peak bytes to build a float32 CSR matrix of this density.

    Chunk results (int32 row, int32 column, float32 value = 12 bytes a pair), their concatenation
    and the CSR (8 bytes a pair plus row pointers) coexist at the peak: about 32 bytes per pair.
    """
    nnz = density * n_rows * n_cols
    return int(32 * nnz + 8 * (n_rows + 1))


def compute_visibility(
    instance,
    candidates,
    points: TargetPoints,
    *,
    chunk_size: int | None = None,
    workers: int | None = None,
    progress: Callable[[int], None] | None = None,
    memory_budget_bytes: int | None = None,
    dask_address: str | None = None,
    cache_dir: str | Path | None = None,
) -> VisibilityMatrix:
    """Build the points x candidates visibility matrix.

    Parameters
    ----------
    instance : camplace.instance.Instance
    candidates : camplace.sampling.CandidateSet
    points : TargetPoints
    chunk_size : int or None
        Candidates per work item (default: about 2 million pairs per chunk, 8 to 256 candidates).
    workers : int or None
        Threads (default: number of CPUs, at most 8).
    progress : callable or None
        Called with the number of candidates finished after each chunk.
    memory_budget_bytes : int or None
        Stop with a clear error, before the bulk of the work, when the matrix is estimated to
        need more (default: half the machine's memory).
    dask_address : str or None
        Compute the chunks on a Dask cluster: a scheduler address or ``local:N``.
    cache_dir : path or None
        Reuse / store the matrix in this cache folder (see :mod:`camplace.visibility.cache`);
        None disables the cache.

    Returns
    -------
    VisibilityMatrix
    """
    n_cand = len(candidates)
    task, scenes = make_task(instance, candidates, points)
    if chunk_size is None:
        chunk_size = int(np.clip(2_000_000 // max(1, len(task.live_rows)), 8, 256))
    key = None
    if cache_dir is not None:
        from camplace.visibility import cache

        key = cache.task_key(task)
        hit = cache.load(Path(cache_dir), key, (len(points), n_cand))
        if hit is not None:
            if progress is not None:
                progress(n_cand)
            return VisibilityMatrix(matrix=hit[0], points=points, stats={**hit[1], "cache": "hit"})
    budget = memory_budget_bytes if memory_budget_bytes is not None else available_memory_bytes() // 2
    starts = list(range(0, n_cand, chunk_size))

    # A pilot chunk measures the density before the bulk of the work, to check the memory budget.
    parts = []
    if starts:
        first = compute_chunk(task, scenes, 0, min(chunk_size, n_cand))
        parts.append(first)
        pilot_cols = min(chunk_size, n_cand)
        density = len(first[0]) / max(1, len(points) * pilot_cols)
        need = estimate_matrix_bytes(len(points), n_cand, density)
        if need > budget:
            raise CamplaceError(
                f"visibility: the matrix would need about {need / 2**30:.1f} GiB ({len(points):_} rows x {n_cand:_} "
                f"candidates, {100 * density:.1f}% observed in a pilot of {pilot_cols} candidates), over the memory "
                f"budget of {budget / 2**30:.1f} GiB (lower --points or --candidates, or raise --memory-budget-gb)"
            )
        if progress is not None:
            progress(pilot_cols)
    rest = starts[1:]
    if dask_address is not None:
        from camplace.visibility.distributed import compute_chunks_dask

        parts += compute_chunks_dask(task, rest, chunk_size, dask_address, progress=progress)
    else:
        workers = workers or min(8, os.cpu_count() or 1)

        def work(start: int):
            return compute_chunk(task, scenes, start, min(start + chunk_size, n_cand))

        with ThreadPoolExecutor(max_workers=workers) as pool:
            for start, part in zip(rest, pool.map(work, rest)):
                parts.append(part)
                if progress is not None:
                    progress(min(chunk_size, n_cand - start))
    matrix, total = assemble(task, parts)
    if key is not None:
        cache.store(Path(cache_dir), key, matrix, total)
        total = {**total, "cache": "miss"}
    log.info(
        "visibility: %d pairs, %d in range, %d in frustum, %d facing, %d observed",
        total["pairs"], total["in_range"], total["in_frustum"], total["facing"], total["observed"],
    )
    return VisibilityMatrix(matrix=matrix, points=points, stats=total)
