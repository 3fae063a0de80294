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

Pairs failing 1-4 are culled before any ray is cast, in compiled GIL-free kernels
(:mod:`camplace.visibility._kernels`; the per-pair frustum test is skipped for cameras that hold
the whole target); segments to points on a
supporting plane of the target are cast against the occluders alone (they provably miss the
target); the rest are cast with Embree, chunk by chunk over candidates, on a pool of threads
(Embree and numpy release the GIL) or on a Dask cluster (:mod:`camplace.visibility.distributed`).
"""

from __future__ import annotations

import functools
import logging
import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.spatial import ConvexHull, QhullError

from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.visibility.points import TargetPoints
from camplace.visibility.raycast import RayScene
from camplace.visibility.store import populated_empty

log = logging.getLogger(__name__)

EPS_REL = 1e-4
#: Bumped whenever the meaning of the matrix changes, so cached matrices are not reused.
ENGINE_VERSION = "4"
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
    store_path : Path or None
        A ``.cpm`` file (the cache entry) that holds exactly this matrix: :meth:`save` hard-links
        it instead of writing the matrix again.
    timings_s : dict
        Seconds spent in the cache: ``cache.load`` and / or ``cache.store``.
    """

    matrix: sp.csr_matrix
    points: TargetPoints
    stats: dict = field(default_factory=dict)
    store_path: Path | None = None
    timings_s: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return self.matrix.shape

    def save(self, outdir: str | Path, matrix_format: str = "cpm") -> Path:
        """Write the matrix (:meth:`save_matrix`) and ``points.csv`` atomically. Returns the matrix file."""
        path = self.save_matrix(outdir, matrix_format)
        self.points.save(Path(outdir) / "points.csv")
        return path

    def save_matrix(self, outdir: str | Path, matrix_format: str = "cpm") -> Path:
        """Write ``visibility.cpm`` (or ``visibility.npz`` for ``scipy.sparse.load_npz`` with
        ``matrix_format="npz"``; see :mod:`camplace.visibility.store`) atomically: a hard link to
        the cache entry when there is one. Returns the file."""
        from camplace.visibility.store import save_matrix

        # the same meta as the cache entry (the pair counts), so a written file equals a linked one
        counts = {k: self.stats[k] for k in COUNT_KEYS if k in self.stats}
        return save_matrix(Path(outdir), self.matrix, fmt=matrix_format, link_from=self.store_path,
                           meta={"stats": counts} if counts else None)

    @classmethod
    def load(cls, outdir: str | Path) -> "VisibilityMatrix":
        """Read the matrix (``visibility.cpm`` or ``visibility.npz``) and ``points.csv`` from a run's output folder."""
        from camplace.visibility.store import load_visibility, matrix_path

        outdir = Path(outdir)
        mpath = matrix_path(outdir)
        matrix = load_visibility(mpath)
        points = TargetPoints.load(outdir / "points.csv")
        if matrix.shape[0] != len(points):
            raise CamplaceError(
                f"{outdir}: {mpath.name} has {matrix.shape[0]} rows but points.csv has {len(points)} (re-run)"
            )
        return cls(matrix=matrix, points=points)


def _morton3(cell: np.ndarray) -> np.ndarray:
    """(n,) uint64 Z-curve key of (n, 3) integer cells in 0..1023 (10 bits an axis, interleaved)."""
    key = np.zeros(len(cell), dtype=np.uint64)
    for bit in range(10):
        for axis in range(3):
            key |= ((cell[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return key


ROW_BLOCK = 32  # live rows per culling block


def _row_blocks(pos: np.ndarray, nrm: np.ndarray, emit: np.ndarray, frame_start: np.ndarray) -> dict[str, np.ndarray]:
    """Blocks of up to :data:`ROW_BLOCK` consecutive live rows of one frame, with what bounds
    ``n_i . (c - p_i)`` over a block for any camera c.

    Returns
    -------
    dict
        ``frame_blocks`` (n_frames + 1,) int64: frame f's blocks are
        ``frame_blocks[f]:frame_blocks[f + 1]``; ``block_start`` (b + 1,) int64 row offsets;
        ``block_centre`` (b, 3) mean position; ``block_axis`` (b, 3) unit mean normal;
        ``block_spread`` (b,) ``max_i |n_i - axis|``; ``block_h_lo`` / ``block_h_hi`` (b,)
        min / max of ``n_i . (p_i - centre)``; ``block_emit`` (b,) bool (holds an emitter);
        ``block_reach`` float, the largest ``|p_i|`` (scales the rounding slack).
    """
    starts = [np.arange(frame_start[f], frame_start[f + 1], ROW_BLOCK) for f in range(len(frame_start) - 1)]
    first = np.concatenate(starts).astype(np.int64) if starts else np.zeros(0, dtype=np.int64)
    block_start = np.append(first, frame_start[-1]).astype(np.int64)
    frame_blocks = np.searchsorted(block_start, frame_start).astype(np.int64)
    nb = len(first)
    out = {
        "frame_blocks": frame_blocks,
        "block_start": block_start,
        "block_centre": np.zeros((nb, 3)),
        "block_axis": np.zeros((nb, 3)),
        "block_spread": np.full(nb, np.inf),
        "block_h_lo": np.zeros(nb),
        "block_h_hi": np.zeros(nb),
        "block_emit": np.zeros(nb, dtype=bool),
        "block_reach": float(np.linalg.norm(pos, axis=1).max()) if len(pos) else 0.0,
    }
    if nb == 0:
        return out
    size = np.diff(block_start).astype(np.float64)
    of = np.repeat(np.arange(nb), np.diff(block_start))
    centre = np.add.reduceat(pos, first, axis=0) / size[:, None]
    axis = np.add.reduceat(nrm, first, axis=0)
    norm = np.linalg.norm(axis, axis=1)
    axis = np.where(norm[:, None] > 0, axis / np.where(norm > 0, norm, 1.0)[:, None], 0.0)
    spread = np.maximum.reduceat(np.linalg.norm(nrm - axis[of], axis=1), first)
    h = np.einsum("ij,ij->i", nrm, pos - centre[of])
    out.update(
        block_centre=centre,
        block_axis=axis,
        block_spread=np.where(norm > 0, spread * (1 + 1e-12) + 1e-15, np.inf),
        block_h_lo=np.minimum.reduceat(h, first),
        block_h_hi=np.maximum.reduceat(h, first),
        block_emit=np.maximum.reduceat(emit.astype(np.int8), first).astype(bool),
    )
    return out


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
        """(l,) int64: the rows that can be observed at all (``active``), by frame, then in Morton
        (Z-curve) order of position.

        Neighbouring points then face the same way (predictable culling branches) and their
        segments from one camera traverse the same part of the Embree BVH (coherent casts).
        Within a chunk's columns rows are in this order; the assembled CSR is sorted anyway.
        """
        live = np.nonzero(self.active)[0]
        if len(live) == 0:
            return live
        p = self.positions[live]
        lo, span = p.min(axis=0), np.ptp(p, axis=0)
        cell = np.floor((p - lo) / np.where(span > 0, span, 1.0) * 1023.999).astype(np.uint64)
        return live[np.lexsort((_morton3(cell), self.frame[live]))]

    @functools.cached_property
    def ends32(self) -> np.ndarray:
        """(m, 3) float32: segment end of every row, ``p + eps n`` (the point itself for emitters)."""
        return (self.positions + self.eps_m[self.frame][:, None] * self.normals).astype(np.float32)

    @functools.cached_property
    def live_arrays(self) -> dict[str, np.ndarray]:
        """Contiguous per-live-row arrays for the kernels: ``pos``, ``nrm`` (l, 3) float64, ``ndotp``
        (l,) float64, ``emit`` and ``support`` (l,) bool, ``ends32`` (l, 3) float32,
        ``frame_start`` (n_frames + 1,) int64 (live rows come frame by frame), and the row blocks
        of :func:`_row_blocks`."""
        live = self.live_rows
        nrm = np.ascontiguousarray(self.normals[live], dtype=np.float64)
        pos = np.ascontiguousarray(self.positions[live], dtype=np.float64)
        emit = ~np.any(nrm != 0.0, axis=1)
        frame_start = np.searchsorted(self.frame[live], np.arange(len(self.eps_m) + 1)).astype(np.int64)
        out = {
            "pos": pos,
            "nrm": nrm,
            "ndotp": np.einsum("ij,ij->i", nrm, pos),
            "emit": emit,
            "support": np.ascontiguousarray(self.support[live]),
            "frame_start": frame_start,
            "ends32": np.ascontiguousarray(self.ends32[live]),
        }
        out.update(_row_blocks(pos, nrm, emit, frame_start))
        return out

    @functools.cached_property
    def frame_spheres(self) -> dict[int, tuple[np.ndarray, float]]:
        """Bounding sphere (centre (3,) float64, radius) of each frame's live rows."""
        out = {}
        live_frame = self.frame[self.live_rows]
        for f in np.unique(live_frame):
            p = self.positions[self.live_rows[live_frame == f]]
            lo, hi = p.min(axis=0), p.max(axis=0)
            out[int(f)] = ((lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2))
        return out

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


@dataclass(frozen=True, eq=False)
class ChunkResult:
    """The observed pairs of a chunk of candidates, as a list of its nonempty rows.

    Attributes
    ----------
    col0 : int
        Global index of the chunk's first candidate.
    rowids : (r,) int32
        Global rows with at least one observed pair (each once).
    offsets : (r + 1,) int64
        Row t's pairs are ``offsets[t]:offsets[t + 1]`` of ``lcols``.
    lcols : (o,) uint8 or uint16
        Chunk-local candidate of each pair (global: ``col0 + lcols``), ascending within a row.
        The observation quality is not stored: :func:`assemble` computes it from the row and
        the candidate.
    counts : dict
        Pair counts after each culling step (keys ``COUNT_KEYS``).
    """

    col0: int
    rowids: np.ndarray
    offsets: np.ndarray
    lcols: np.ndarray
    counts: dict


_SCRATCH_POOL: list[dict] = []  # idle per-chunk work-array sets, kept between calls
_SCRATCH_LOCK = threading.Lock()
_SCRATCH_KEEP = 8


def _take_scratch() -> dict:
    """A set of reusable work arrays for one chunk (return it with :func:`_give_scratch`).

    Chunk buffers of tens of MB would otherwise be fresh allocations, page-faulted in for every
    chunk (and on a VM with free-page reporting, for every call).
    """
    with _SCRATCH_LOCK:
        return _SCRATCH_POOL.pop() if _SCRATCH_POOL else {}


def _give_scratch(bufs: dict) -> None:
    with _SCRATCH_LOCK:
        if len(_SCRATCH_POOL) < _SCRATCH_KEEP:
            _SCRATCH_POOL.append(bufs)


def _scratch(bufs: dict, name: str, shape: int | tuple[int, ...], dtype) -> np.ndarray:
    """A work array of this shape from ``bufs`` (contents undefined), grown when too small."""
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    size = math.prod(shape)
    buf = bufs.get(name)
    if buf is None or buf.dtype != np.dtype(dtype) or buf.size < size:
        buf = populated_empty(max(size, int(1.25 * (0 if buf is None else buf.size))), dtype)
        bufs[name] = buf
    return buf[:size].reshape(shape)


def compute_chunk(task: VisibilityTask, scenes: dict[int, "FrameScenes"], start: int, stop: int) -> "ChunkResult":
    """Observed pairs of candidates ``start:stop``.

    Culling and segment building run in compiled, GIL-free kernels
    (:mod:`camplace.visibility._kernels`); cameras that hold a frame's whole live point set
    inside their frustum and range skip the per-pair frustum test; segments to points on a
    supporting plane of the target (see :class:`VisibilityTask`) are cast against the occluders
    alone. Each scene gets one contiguous batch of segments.
    """
    bufs = _take_scratch()
    try:
        with ctrl_c_deferred():  # (in the main thread only: the Dask pilot, direct calls)
            return _compute_chunk(task, scenes, start, stop, bufs)
    finally:
        _give_scratch(bufs)


def _compute_chunk(task: VisibilityTask, scenes: dict[int, "FrameScenes"], start: int, stop: int, bufs: dict) -> "ChunkResult":
    """:func:`compute_chunk` with the work arrays ``bufs``."""
    from camplace.visibility import _kernels

    pos = task.cam_positions[start:stop]
    rot = task.cam_rotations[start:stop]
    nc = stop - start
    counts = dict.fromkeys(COUNT_KEYS, 0)
    live = task.live_rows
    counts["pairs"] = len(task.frame) * nc
    if len(live) == 0 or nc == 0:
        return ChunkResult(start, np.empty(0, np.int32), np.zeros(1, np.int64), np.empty(0, np.uint8), counts)
    lv = task.live_arrays
    n_frames = len(task.eps_m)
    whole = np.zeros((nc, n_frames), dtype=bool)
    for f, (centre, radius) in task.frame_spheres.items():
        whole[:, f] = sphere_inside_view(
            centre, radius, pos, rot, task.K, task.width_px, task.height_px, task.near_m, task.far_m
        )
    K = task.K
    kept = _scratch(bufs, "kept", nc * len(live), np.int32)
    group = _scratch(bufs, "group", nc * len(live), np.int8)
    sizes = np.zeros(2 * n_frames, dtype=np.int64)
    q, per_cam, steps = _kernels.cull(
        np.ascontiguousarray(pos), np.ascontiguousarray(rot), whole, lv["frame_start"], lv["pos"], lv["nrm"],
        lv["ndotp"], lv["emit"], lv["support"], task.support_tol, lv["frame_blocks"], lv["block_start"],
        lv["block_centre"], lv["block_axis"], lv["block_spread"], lv["block_h_lo"], lv["block_h_hi"], lv["block_emit"],
        lv["block_reach"], float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
        task.width_px, task.height_px, task.near_m, task.far_m, task.cos_max_incidence, kept, group, sizes,
    )
    kept, group = kept[:q], group[:q]
    counts["in_range"], counts["in_frustum"], counts["facing"] = (int(x) for x in steps)
    origins, directions = _scratch(bufs, "origins", (q, 3), np.float32), _scratch(bufs, "directions", (q, 3), np.float32)
    slot = _scratch(bufs, "slot", q, np.int32)
    offsets = _kernels.build_segments(
        kept, group, sizes, per_cam, pos.astype(np.float32), lv["ends32"], origins, directions, slot
    )
    blocked = _scratch(bufs, "blocked", q, np.bool_)
    for f in task.scene_triangles:
        for g, scene in ((2 * f, scenes[f].full), (2 * f + 1, scenes[f].rest)):
            a, b = int(offsets[g]), int(offsets[g + 1])
            if b > a:
                scene.occluded_dir(origins[a:b], directions[a:b], out=blocked[a:b])
                counts["cast"] += b - a
    n_obs = q - int(np.count_nonzero(blocked))
    lcols = _arena_empty(n_obs, np.uint8 if nc <= 256 else np.uint16)
    rowids, row_offsets = _scratch(bufs, "rowids", len(live), np.int32), _scratch(bufs, "row_offsets", len(live) + 1, np.int64)
    r = _kernels.compact(kept, per_cam, slot, blocked, live, _scratch(bufs, "cursor", len(live), np.int64), rowids, row_offsets, lcols)
    counts["observed"] = n_obs
    kept_rows, kept_offsets = _arena_empty(r, np.int32), _arena_empty(r + 1, np.int64)
    kept_rows[:] = rowids[:r]
    kept_offsets[:] = row_offsets[:r + 1]
    return ChunkResult(start, kept_rows, kept_offsets, lcols, counts)


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
    ``n . (x - p) <= tol``. A linear function's maximum over the vertices is reached on their
    convex hull, so only the hull vertices are tried (all of them when the hull is degenerate),
    in a compiled loop that stops at the first vertex above the plane.
    """
    out = np.zeros(len(points), dtype=bool)
    rows = np.nonzero((points.frame == frame) & ~points.is_emitter)[0]
    verts = np.asarray(target_vertices, dtype=np.float64)
    try:
        verts = verts[ConvexHull(verts).vertices]
    except (QhullError, ValueError):  # flat or too few vertices: try them all
        pass
    from camplace.visibility import _kernels

    ok = np.zeros(len(rows), dtype=bool)
    with ctrl_c_deferred():
        _kernels.supporting(
            np.ascontiguousarray(verts), np.ascontiguousarray(points.positions[rows], dtype=np.float64),
            np.ascontiguousarray(points.normals[rows], dtype=np.float64), float(tol), ok,
        )
    out[rows] = ok
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


def assemble(task: VisibilityTask, parts: list[ChunkResult], workers: int | None = None) -> tuple[sp.csr_matrix, dict]:
    """CSR float32 matrix (rows x candidates) and summed counts from chunk results in column order.

    Each chunk's row runs are copied straight into the CSR arrays by a compiled kernel, which
    computes each pair's observation quality on the way (see the module docstring), on
    ``workers`` threads (default: number of CPUs, at most 8), each thread filling a contiguous
    range of rows with about the same number of entries; chunks are taken in column order, so
    the column indices of each row come out ascending.
    """
    from camplace.visibility import _kernels

    total = dict.fromkeys(COUNT_KEYS, 0)
    for part in parts:
        for key in COUNT_KEYS:
            total[key] += part.counts[key]
    m, n = len(task.positions), task.n_candidates
    nnz = sum(len(p.lcols) for p in parts)
    index_dtype = np.int32 if max(m, n, nnz) < 2**31 - 1 else np.int64
    row_counts = np.zeros(m, dtype=np.int64)
    for p in parts:
        row_counts[p.rowids] += np.diff(p.offsets)
    indptr = np.zeros(m + 1, dtype=np.int64)
    np.cumsum(row_counts, out=indptr[1:])
    with ThreadPoolExecutor(max_workers=2) as pool:  # the two big arrays are faulted in side by side
        indices, data = pool.map(lambda dt: populated_empty(nnz, dt), (index_dtype, np.float32))
    workers = max(1, min(workers or min(8, os.cpu_count() or 1), m))
    emitter = ~np.any(task.normals != 0.0, axis=1)
    fx = float(task.K[0, 0])
    bounds = [0, *np.searchsorted(indptr, [nnz * (t + 1) / workers for t in range(workers - 1)]), m]

    def merge(t: int) -> None:
        lo, hi = int(bounds[t]), int(bounds[t + 1])
        if hi <= lo:
            return
        nxt = indptr[:-1].copy()
        for p in parts:
            _kernels.merge_rows(
                p.rowids, p.offsets, p.lcols, p.col0, lo, hi, nxt, indices, data, task.graded, task.positions,
                task.normals, emitter, task.cam_positions, fx, task.required_px_per_m,
            )

    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(merge, range(workers)))
    matrix = sp.csr_matrix((data, indices, indptr.astype(index_dtype)), shape=(m, n), copy=False)
    matrix.has_sorted_indices = True
    return matrix, total


def default_chunk_size(task: VisibilityTask) -> int:
    """Candidates per work item: about 2 million (row, candidate) pairs, 8 to 256 candidates."""
    return int(np.clip(2_000_000 // max(1, len(task.live_rows)), 8, 256))


def chunk_plan(n_candidates: int, chunk_size: int, workers: int) -> list[tuple[int, int]]:
    """Candidate ranges ``(start, stop)`` for the thread pool, in column order.

    Chunks of ``chunk_size``, except that the last ``2 * workers`` are cut in four (at least 8
    candidates each), so that the threads run out of work at about the same time.
    """
    starts = list(range(0, n_candidates, chunk_size))
    tail = max(1, len(starts) - 2 * workers)  # the first chunk (the pilot) keeps its size
    plan = [(s, min(s + chunk_size, n_candidates)) for s in starts[:tail]]
    for s in starts[tail:]:
        e = min(s + chunk_size, n_candidates)
        step = max(8, -(-(e - s) // 4))
        plan += [(a, min(a + step, e)) for a in range(s, e, step)]
    return plan


class _Arena(threading.local):
    """Per-thread bump allocator over populated slabs, for the chunk results."""

    slab: np.ndarray | None = None
    used: int = 0


_ARENA = _Arena()
_SLAB_BYTES = 32 << 20


def _arena_empty(n: int, dtype) -> np.ndarray:
    """An uninitialised (n,) array carved from this thread's current populated slab.

    Chunk results are many arrays of about a MB, each of which would otherwise be page-faulted in
    4 KiB at a time (see :func:`populated_empty`). A slab lives as long as any array carved from
    it: the chunk results are dropped after assembly, and the slabs with them.
    """
    dtype = np.dtype(dtype)
    nbytes = int(n) * dtype.itemsize
    if nbytes > _SLAB_BYTES // 4:
        return populated_empty(n, dtype)
    arena = _ARENA
    start = (arena.used + 7) & ~7
    if arena.slab is None or start + nbytes > len(arena.slab):
        arena.slab = populated_empty(_SLAB_BYTES, np.uint8)
        start = 0
    arena.used = start + nbytes
    return arena.slab[start:start + nbytes].view(dtype)


def available_memory_bytes() -> int:
    """Physical memory of this machine (bytes), or 8 GiB when unknown."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 8 << 30


def estimate_matrix_bytes(n_rows: int, n_cols: int, density: float) -> int:
    """Peak bytes to build a float32 CSR matrix of this density.

    Chunk results (1 byte a pair, plus 12 bytes a nonempty row of a chunk) and the CSR (8 bytes
    a pair plus row pointers) coexist at the peak: about 10 bytes per pair, plus the per-thread
    work arrays and result slab (about 100 MB a thread).
    """
    nnz = density * n_rows * n_cols
    return int(10 * nnz + 16 * (n_rows + 1) + 100 * 2**20 * min(8, os.cpu_count() or 1))


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
        chunk_size = default_chunk_size(task)
    key = None
    timings: dict[str, float] = {}
    if cache_dir is not None:
        from camplace.visibility import cache

        key = cache.task_key(task)
        t0 = time.perf_counter()
        hit = cache.load(Path(cache_dir), key, (len(points), n_cand))
        timings["cache.load"] = time.perf_counter() - t0
        if hit is not None:
            if progress is not None:
                progress(n_cand)
            return VisibilityMatrix(matrix=hit[0], points=points, stats={**hit[1], "cache": "hit"},
                                    store_path=cache.entry_path(Path(cache_dir), key), timings_s=timings)
    budget = memory_budget_bytes if memory_budget_bytes is not None else available_memory_bytes() // 2
    starts = list(range(0, n_cand, chunk_size))

    # The first chunk is a pilot: its density is checked against the memory budget before the bulk
    # of the work (in process, the other chunks start beside it and are cancelled on a failed check).

    def check_pilot(first: ChunkResult) -> None:
        pilot_cols = min(chunk_size, n_cand)
        density = len(first.lcols) / max(1, len(points) * pilot_cols)
        need = estimate_matrix_bytes(len(points), n_cand, density)
        if need > budget:
            raise CamplaceError(
                f"visibility: the matrix would need about {need / 2**30:.1f} GiB ({len(points):_} rows x {n_cand:_} "
                f"candidates, {100 * density:.1f}% observed in a pilot of {pilot_cols} candidates), over the memory "
                f"budget of {budget / 2**30:.1f} GiB (lower --points or --candidates, or raise --memory-budget-gb)"
            )

    parts: list[ChunkResult] = []
    if dask_address is not None:
        from camplace.visibility.distributed import compute_chunks_dask

        if starts:
            parts.append(compute_chunk(task, scenes, 0, min(chunk_size, n_cand)))
            check_pilot(parts[0])
            if progress is not None:
                progress(min(chunk_size, n_cand))
        parts += compute_chunks_dask(task, starts[1:], chunk_size, dask_address, progress=progress)
    else:
        workers = workers or min(8, os.cpu_count() or 1)

        plan = chunk_plan(n_cand, chunk_size, workers)
        pool = ThreadPoolExecutor(max_workers=workers)
        try:
            futures = [pool.submit(compute_chunk, task, scenes, a, b) for a, b in plan]
            for i, ((a, b), fut) in enumerate(zip(plan, futures)):
                parts.append(fut.result())
                if i == 0:
                    check_pilot(parts[0])
                if progress is not None:
                    progress(b - a)
        finally:  # on an error or Ctrl-C, chunks not started are dropped
            pool.shutdown(wait=True, cancel_futures=True)
    matrix, total = assemble(task, parts)
    store_path = None
    if key is not None:
        t0 = time.perf_counter()
        store_path = cache.store(Path(cache_dir), key, matrix, total)
        timings["cache.store"] = time.perf_counter() - t0
        total = {**total, "cache": "miss"}
    log.info(
        "visibility: %d pairs, %d in range, %d in frustum, %d facing, %d observed",
        total["pairs"], total["in_range"], total["in_frustum"], total["facing"], total["observed"],
    )
    return VisibilityMatrix(matrix=matrix, points=points, stats=total, store_path=store_path,
                            timings_s=timings)
