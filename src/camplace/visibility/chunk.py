"""The chunk kernel of the visibility matrix: one chunk of candidates against every point.

The bottom of :mod:`camplace.visibility`'s engine: :func:`compute_chunk` takes a picklable
:class:`VisibilityTask` and a range of candidates and returns a :class:`ChunkResult`. The engine
(:mod:`camplace.visibility.engine`: planning, memory checks, assembly), the cache
(:mod:`camplace.visibility.cache`, keyed with :data:`ENGINE_VERSION`) and the Dask workers
(:mod:`camplace.visibility.distributed`) all import it; it imports none of them. The observation
rules are in the engine's module docstring.
"""

from __future__ import annotations

import functools
import math
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from camplace._cores import thread_count
from camplace._signals import ctrl_c_deferred
from camplace.visibility.store import populated_empty

if TYPE_CHECKING:
    from camplace.visibility.raycast import RayScene

#: Bumped whenever the meaning of the matrix changes, so cached matrices are not reused.
ENGINE_VERSION = "4"
COUNT_KEYS = ("pairs", "in_range", "in_frustum", "facing", "cast", "observed")
#: occluder triangles of a frame up to which :attr:`VisibilityTask.enclosing_rest` checks it (a
#: room's walls, floor and ceiling; larger occluders are cast against as they are)
ENCLOSING_MAX_TRIANGLES = 256
#: the margin of :attr:`VisibilityTask.enclosing_rest`, relative to the scene's size
ENCLOSING_TOL = 1e-5


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
    min_target_px : float
        ``[quality] min_target_px`` (0: none); applied by the engine after assembly
        (:func:`camplace.visibility.engine.drop_small_views`), here for the cache key.
    quantised : bool
        A graded matrix kept as bytes (``[quality] precision = "byte"``,
        :mod:`camplace.visibility.qbytes`); for the cache key.
    cam_model : (n,) int16 or None
        A team's camera model of each candidate, non-decreasing (columns grouped by model); None:
        every candidate has the intrinsics ``K``, ``width_px``, ... above.
    models : tuple of (K (3, 3) float64, width_px, height_px, near_m, far_m)
        The intrinsics of each model of ``cam_model`` (model 0's are also ``K``, ``width_px``, ...).
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
    min_target_px: float = 0.0
    quantised: bool = False
    cam_model: np.ndarray | None = None
    models: tuple = ()

    @property
    def n_candidates(self) -> int:
        return int(self.cam_positions.shape[0])

    def model_ranges(self) -> list[tuple[int, int, int]]:
        """``(model, start, stop)`` of each run of columns with one camera model, in column order."""
        n = self.n_candidates
        if self.cam_model is None or n == 0:
            return [(0, 0, n)]
        cuts = np.flatnonzero(np.diff(self.cam_model)) + 1
        bounds = [0, *cuts.tolist(), n]
        return [(int(self.cam_model[a]), int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]

    def intrinsics(self, start: int, stop: int) -> tuple[np.ndarray, int, int, float, float]:
        """``(K, width_px, height_px, near_m, far_m)`` of candidates ``start:stop`` (one model).

        Raises
        ------
        ValueError
            When the range holds candidates of two models.
        """
        if self.cam_model is None or stop <= start:
            return self.K, self.width_px, self.height_px, self.near_m, self.far_m
        m = int(self.cam_model[start])
        if int(self.cam_model[stop - 1]) != m or np.any(self.cam_model[start:stop] != m):
            raise ValueError(f"candidates {start}:{stop} hold more than one camera model")
        return self.models[m]

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
    def emitters(self) -> np.ndarray:
        """(m,) bool: rows without a normal (emitters: a plume's particles), graded with cos = 1."""
        return ~np.any(self.normals != 0.0, axis=1)

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

    @functools.cached_property
    def enclosing_rest(self) -> dict[int, tuple[np.ndarray, np.ndarray, float]]:
        """Frames whose occluders cannot block any segment to a supporting row from a camera on
        the rows' side of every occluder triangle (``f -> (planes, side, scale)``).

        For each frame with at most :data:`ENCLOSING_MAX_TRIANGLES` occluder triangles, every
        supporting row's segment end (``ends32``) lies strictly on one side of each triangle's
        plane (``planes`` (t, 4) float64: unit normal and offset; ``side`` (t,) bool: the rows'
        side, at least ``ENCLOSING_TOL * scale`` from the plane), as inside a room. A segment whose
        camera is on the same side of every plane, by the same margin, lies in that open
        half-space intersection and meets no occluder triangle (the margin, 1e-5 of the scene's
        size, is far above Embree's float32 rounding), so it needs no cast:
        :func:`_compute_chunk` skips the frame's occluder casts for a chunk whose cameras all
        pass. Frames that do not qualify are absent.
        """
        out: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}
        live = self.live_rows
        for f, tri in self.rest_triangles.items():
            tri = np.asarray(tri, dtype=np.float64)
            if len(tri) == 0 or len(tri) > ENCLOSING_MAX_TRIANGLES:
                continue
            rows = live[(self.frame[live] == f) & self.support[live]]
            if len(rows) == 0:
                continue
            ends = self.ends32[rows].astype(np.float64)
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            length = np.linalg.norm(nrm, axis=1)
            if np.any(length <= 0.0):
                continue  # a degenerate triangle: no plane to be beyond
            nrm /= length[:, None]
            planes = np.column_stack([nrm, np.einsum("ij,ij->i", nrm, tri[:, 0])])
            scale = max(1.0, float(np.abs(tri).max()), float(np.abs(ends).max()))
            dist = ends @ planes[:, :3].T - planes[:, 3]  # (rows, t)
            side = dist[0] > 0.0
            if np.all(np.abs(dist) > ENCLOSING_TOL * scale) and np.all((dist > 0.0) == side):
                out[int(f)] = (planes, side, scale)
        return out

    def build_scenes(self) -> dict[int, "FrameScenes"]:
        """The Embree scenes of every frame (build once per process)."""
        from camplace.visibility.raycast import RayScene  # Embree: only where scenes are built

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


#: what :func:`camplace.visibility._kernels.cast_chunk` gets for the matrix it does not write
_NO_WORDS = np.zeros((0, 1), dtype=np.uint64)
_NO_VALUES = np.zeros((0, 1), dtype=np.uint8)
_NO_EMITTERS = np.zeros(0, dtype=np.bool_)

_SCRATCH_POOL: list[dict] = []  # idle per-chunk work-array sets, kept between calls
_SCRATCH_LOCK = threading.Lock()


def _take_scratch() -> dict:
    """A set of reusable work arrays for one chunk (return it with :func:`_give_scratch`).

    Chunk buffers of tens of MB would otherwise be fresh allocations, page-faulted in for every
    chunk (and on a VM with free-page reporting, for every call).
    """
    with _SCRATCH_LOCK:
        return _SCRATCH_POOL.pop() if _SCRATCH_POOL else {}


def _give_scratch(bufs: dict) -> None:
    with _SCRATCH_LOCK:
        if len(_SCRATCH_POOL) < thread_count():  # one set per worker thread
            _SCRATCH_POOL.append(bufs)


def drop_scratch() -> None:
    """Free the idle work-array sets (the visibility stage calls it when its chunks are done, so that
    the solve does not share memory with them)."""
    with _SCRATCH_LOCK:
        _SCRATCH_POOL.clear()


def _scratch(bufs: dict, name: str, shape: int | tuple[int, ...], dtype) -> np.ndarray:
    """A work array of this shape from ``bufs`` (contents undefined), grown when too small."""
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    size = math.prod(shape)
    buf = bufs.get(name)
    if buf is None or buf.dtype != np.dtype(dtype) or buf.size < size:
        buf = populated_empty(max(size, int(1.25 * (0 if buf is None else buf.size))), dtype)
        bufs[name] = buf
    return buf[:size].reshape(shape)


def compute_chunk(task: VisibilityTask, scenes: dict[int, "FrameScenes"], start: int, stop: int,
                  words: np.ndarray | None = None, values: np.ndarray | None = None) -> "ChunkResult":
    """Observed pairs of candidates ``start:stop``; with ``words`` (column bitsets, (n, W) uint64)
    their bits set there, with ``values`` (quantised columns, (n, m) uint8) their quantised quality
    written there (only columns ``start:stop``), the result then holding the counts alone.

    Culling and segment building run in compiled, GIL-free kernels
    (:mod:`camplace.visibility._kernels`); cameras that hold a frame's whole live point set
    inside their frustum and range skip the per-pair frustum test; segments to points on a
    supporting plane of the target (see :class:`VisibilityTask`) are cast against the occluders
    alone. Written into ``words`` or ``values`` through Embree's packets, the chunk runs camera by
    camera in one compiled call (:func:`camplace.visibility._kernels.cast_chunk`: work arrays of
    one camera's pairs); otherwise each scene gets one contiguous batch of the chunk's segments.
    """
    bufs = _take_scratch()
    try:
        with ctrl_c_deferred():  # (in the main thread only: the Dask pilot, direct calls)
            return _compute_chunk(task, scenes, start, stop, bufs, words, values)
    finally:
        _give_scratch(bufs)


def _cameras_inside(cam: np.ndarray, planes: np.ndarray, side: np.ndarray, scale: float) -> np.ndarray:
    """(c,) bool: camera c (``cam`` (c, 3) float64) is on the rows' ``side`` of every plane, beyond
    the margin of :attr:`VisibilityTask.enclosing_rest` (``scale`` grown to the camera's size)."""
    tol = ENCLOSING_TOL * np.maximum(scale, np.abs(cam).max(axis=1, initial=0.0))
    dist = cam @ planes[:, :3].T - planes[:, 3]  # (c, t)
    return np.all(np.abs(dist) > tol[:, None], axis=1) & np.all((dist > 0.0) == side, axis=1)


def _cameras_enclosed(cam: np.ndarray, planes: np.ndarray, side: np.ndarray, scale: float) -> bool:
    """Whether every camera ``cam`` (c, 3) float64 is inside the room (:func:`_cameras_inside`)."""
    return bool(np.all(_cameras_inside(cam, planes, side, scale)))


def _packet_scenes(task: VisibilityTask, scenes: dict[int, "FrameScenes"]) -> tuple[int, int, np.ndarray] | None:
    """What :func:`camplace.visibility._kernels.cast_chunk` casts through: the address of Embree's
    ``rtcOccluded{width}``, the width, and each scene group's scene handle ((2 * n_frames,)
    uint64, 0 where the scene has no triangles); None where a scene has no packet path (embreex)."""
    handles = np.zeros(2 * len(task.eps_m), dtype=np.uint64)
    api = None
    for f in task.scene_triangles:
        for g, scene in ((2 * f, scenes[f].full), (2 * f + 1, scenes[f].rest)):
            if len(scene) == 0:
                continue
            packets = scene.packet_scene()
            if packets is None:
                return None
            api = packets.api
            handles[g] = packets.handle
    return (0, 1, handles) if api is None else (int(api.occluded), int(api.width), handles)


def _enclosed_cameras(task: VisibilityTask, cam32: np.ndarray) -> np.ndarray:
    """(c, n_frames) bool: camera c (its float32 position, ``cam32`` (c, 3) float64) is inside frame
    f's occluder room (:attr:`VisibilityTask.enclosing_rest`, :func:`_cameras_inside`)."""
    out = np.zeros((len(cam32), len(task.eps_m)), dtype=bool)
    for f, room in task.enclosing_rest.items():
        out[:, f] = _cameras_inside(cam32, *room)
    return out


def _compute_chunk(task: VisibilityTask, scenes: dict[int, "FrameScenes"], start: int, stop: int, bufs: dict,
                   words: np.ndarray | None = None, values: np.ndarray | None = None) -> "ChunkResult":
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
    K, width_px, height_px, near_m, far_m = task.intrinsics(start, stop)
    whole = np.zeros((nc, n_frames), dtype=bool)
    for f, (centre, radius) in task.frame_spheres.items():
        whole[:, f] = sphere_inside_view(centre, radius, pos, rot, K, width_px, height_px, near_m, far_m)
    packets = _packet_scenes(task, scenes) if words is not None or values is not None else None
    if packets is None and values is not None:  # (embreex) the pair list, then its cells
        return scatter_part_bytes(task, values, _compute_chunk(task, scenes, start, stop, bufs))
    if packets is not None:  # through Embree's packets: camera by camera, in one call
        nl = len(live)
        cam32 = pos.astype(np.float32).astype(np.float64)  # the segments' origins, exactly
        if words is None:
            words = _NO_WORDS
            emitter = task.emitters
        else:
            values, emitter = _NO_VALUES, _NO_EMITTERS
        steps = _kernels.cast_chunk(
            np.ascontiguousarray(pos), np.ascontiguousarray(rot), whole, _enclosed_cameras(task, cam32),
            lv["frame_start"], lv["pos"], lv["nrm"], lv["ndotp"], lv["emit"], lv["support"], task.support_tol,
            lv["frame_blocks"], lv["block_start"], lv["block_centre"], lv["block_axis"], lv["block_spread"],
            lv["block_h_lo"], lv["block_h_hi"], lv["block_emit"], lv["block_reach"], float(K[0, 0]), float(K[1, 1]),
            float(K[0, 2]), float(K[1, 2]), width_px, height_px, near_m, far_m, task.cos_max_incidence,
            lv["ends32"], np.uint64(packets[0]), packets[1], packets[2], live, start, words, values,
            task.positions, task.normals, emitter, task.cam_positions, task.required_px_per_m,
            _scratch(bufs, "kept", nl, np.int32), _scratch(bufs, "group", nl, np.int8),
            _scratch(bufs, "origins", (nl, 3), np.float32), _scratch(bufs, "directions", (nl, 3), np.float32),
            _scratch(bufs, "slot", nl, np.int32), _scratch(bufs, "blocked", nl, np.bool_),
        )
        for key, v in zip(("in_range", "in_frustum", "facing", "cast", "observed"), steps, strict=True):
            counts[key] = int(v)
        return ChunkResult(start, np.empty(0, np.int32), np.zeros(1, np.int64), np.empty(0, np.uint8), counts)
    kept = _scratch(bufs, "kept", nc * len(live), np.int32)
    group = _scratch(bufs, "group", nc * len(live), np.int8)
    sizes = np.zeros(2 * n_frames, dtype=np.int64)
    q, per_cam, steps = _kernels.cull(
        np.ascontiguousarray(pos), np.ascontiguousarray(rot), whole, lv["frame_start"], lv["pos"], lv["nrm"],
        lv["ndotp"], lv["emit"], lv["support"], task.support_tol, lv["frame_blocks"], lv["block_start"],
        lv["block_centre"], lv["block_axis"], lv["block_spread"], lv["block_h_lo"], lv["block_h_hi"], lv["block_emit"],
        lv["block_reach"], float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
        width_px, height_px, near_m, far_m, task.cos_max_incidence, kept, group, sizes,
    )
    kept, group = kept[:q], group[:q]
    counts["in_range"], counts["in_frustum"], counts["facing"] = (int(x) for x in steps)
    origins, directions = _scratch(bufs, "origins", (q, 3), np.float32), _scratch(bufs, "directions", (q, 3), np.float32)
    slot = _scratch(bufs, "slot", q, np.int32)
    offsets = _kernels.build_segments(
        kept, group, sizes, per_cam, pos.astype(np.float32), lv["ends32"], origins, directions, slot
    )
    blocked = _scratch(bufs, "blocked", q, np.bool_)
    enclosing = task.enclosing_rest
    cam32 = pos.astype(np.float32).astype(np.float64)  # the segments' origins, exactly
    for f in task.scene_triangles:
        for g, scene in ((2 * f, scenes[f].full), (2 * f + 1, scenes[f].rest)):
            a, b = int(offsets[g]), int(offsets[g + 1])
            if b > a:
                if g % 2 and f in enclosing and _cameras_enclosed(cam32, *enclosing[f]):
                    blocked[a:b] = False  # inside the occluders' room with the rows: nothing to hit
                    continue
                scene.occluded_dir(origins[a:b], directions[a:b], out=blocked[a:b])
                counts["cast"] += b - a
    if words is not None:  # column bitsets: the bits set straight from the pairs, no pair list
        counts["observed"] = int(_kernels.set_bits(kept, per_cam, slot, blocked, live, start, words))
        return ChunkResult(start, np.empty(0, np.int32), np.zeros(1, np.int64), np.empty(0, np.uint8), counts)
    n_obs = q - int(np.count_nonzero(blocked))
    lcols = _arena_empty(n_obs, np.uint8 if nc <= 256 else np.uint16)
    rowids, row_offsets = _scratch(bufs, "rowids", len(live), np.int32), _scratch(bufs, "row_offsets", len(live) + 1, np.int64)
    r = _kernels.compact(kept, per_cam, slot, blocked, live, _scratch(bufs, "cursor", len(live), np.int64), rowids, row_offsets, lcols)
    counts["observed"] = n_obs
    kept_rows, kept_offsets = _arena_empty(r, np.int32), _arena_empty(r + 1, np.int64)
    kept_rows[:] = rowids[:r]
    kept_offsets[:] = row_offsets[:r + 1]
    return ChunkResult(start, kept_rows, kept_offsets, lcols, counts)


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


def chunk_fx(task: VisibilityTask, col0: int) -> float:
    """The focal length (pixels) that grades the pairs of the chunk starting at column ``col0``
    (every chunk holds one camera model)."""
    return float(task.intrinsics(col0, col0 + 1)[0][0, 0]) if task.cam_model is not None else float(task.K[0, 0])


def scatter_part_bytes(task: VisibilityTask, values: np.ndarray, part: ChunkResult, origin: int = 0) -> ChunkResult:
    """Write a chunk's observed pairs, quantised (:func:`camplace.visibility._kernels.scatter_chunk_quality`),
    into the columns ``values`` and return the chunk's counts with empty pair arrays.

    Parameters
    ----------
    task : VisibilityTask
    values : (c, m) uint8
        Quantised columns; row ``j`` is candidate ``origin + j`` (the whole matrix with
        ``origin = 0``, a Dask worker's block of the chunk's own columns with ``origin = part.col0``).
    part : ChunkResult
    origin : int
    """
    from camplace.visibility._kernels import scatter_chunk_quality

    if len(part.rowids):
        scatter_chunk_quality(part.rowids, part.offsets, part.lcols, int(part.col0) - origin, values, task.positions,
                              task.normals, task.emitters, task.cam_positions[origin:], chunk_fx(task, int(part.col0)),
                              task.required_px_per_m)
    return ChunkResult(part.col0, np.empty(0, np.int32), np.zeros(1, np.int64), np.empty(0, np.uint8),
                       {**part.counts})
