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
   target's bounding-box diagonal and keeps the point's own face from occluding it;
6. with ``[quality] min_target_px``, for a surface point: the frame's target covers at least that
   many pixels in the camera (its convex hull's projected area,
   :mod:`camplace.visibility.footprint`), so a view that cannot resolve the target observes none
   of it (applied to the assembled matrix, :func:`drop_small_views`).

Its value, the observation quality, is 1 in ``binary`` mode; in ``graded`` mode it is
``min(1, f_px / (distance * required_px_per_m)) * cos(theta)`` for surface points (resolution
times foreshortening) and the resolution factor alone for emitters.

Pairs failing 1-4 are culled before any ray is cast, in compiled GIL-free kernels
(:mod:`camplace.visibility._kernels`; the per-pair frustum test is skipped for cameras that hold
the whole target); segments to points on a
supporting plane of the target are cast against the occluders alone (they provably miss the
target); the rest are cast with Embree, chunk by chunk over candidates, on a pool of threads
(Embree and numpy release the GIL) or on a Dask cluster (:mod:`camplace.visibility.distributed`).
The chunk kernel is :mod:`camplace.visibility.chunk`; this module plans the chunks, checks the
memory budget on a pilot chunk, consults the cache and assembles the matrix.
"""

from __future__ import annotations

import logging
import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.spatial import ConvexHull, QhullError

from camplace._blocks import cuts, run_blocks, threads_for
from camplace._cores import thread_count
from camplace._signals import ctrl_c_deferred
from camplace.errors import CamplaceError
from camplace.visibility.points import TargetPoints
from camplace.visibility.raycast import RayScene
from camplace.visibility import cache
from camplace.visibility.chunk import (COUNT_KEYS, ChunkResult, FrameScenes, VisibilityTask, chunk_fx, compute_chunk,
                                       drop_scratch, scatter_part_bytes)
from camplace.visibility.distributed import compute_chunks_dask
from camplace.visibility.store import first_touch_empty, populate

log = logging.getLogger(__name__)

EPS_REL = 1e-4


class VisibilityMatrix:
    """Observation quality of every (point, candidate) pair.

    Attributes
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix of float32
        Value > 0 means observed; the value is the observation quality in (0, 1]. For a binary
        matrix held as :attr:`bits`, made on first use (8 bytes an observed pair).
    bits : camplace.visibility.bits.BitMatrix or None
        A binary matrix as column bitsets (one bit a cell; see :mod:`camplace.visibility.bits`),
        what the solver reads for the binary modes; None for a graded matrix.
    qbytes : camplace.visibility.qbytes.ByteMatrix or None
        A graded matrix quantised to a byte a cell, column by column (``[quality] precision =
        "byte"``; :mod:`camplace.visibility.qbytes`), what the solver reads; ``matrix`` is then
        its CSR float32 values ``q / 255``, made on first use.
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

    def __init__(self, matrix: sp.csr_matrix | None = None, points: TargetPoints | None = None, stats: dict | None = None,
                 store_path: Path | None = None, timings_s: dict | None = None, bits=None, qbytes=None):
        if matrix is None and bits is None and qbytes is None:
            raise ValueError("VisibilityMatrix needs a matrix, bits or bytes")
        self._matrix = matrix
        self.bits = bits
        self.qbytes = qbytes
        self.points = points
        self.stats = {} if stats is None else stats
        self.store_path = store_path
        self.timings_s = {} if timings_s is None else timings_s

    @property
    def matrix(self) -> sp.csr_matrix:
        if self._matrix is None:
            self._matrix = (self.bits if self.bits is not None else self.qbytes).tocsr()
        return self._matrix

    @property
    def pattern(self):
        """What the solver reads: :attr:`bits` or :attr:`qbytes` when held, else :attr:`matrix`."""
        for held in (self.bits, self.qbytes):
            if held is not None:
                return held
        return self._matrix

    @property
    def shape(self) -> tuple[int, int]:
        return self.pattern.shape

    def save(self, outdir: str | Path, matrix_format: str = "cpm") -> Path:
        """Write the matrix (:meth:`save_matrix`) and ``points.csv`` atomically. Returns the matrix file."""
        path = self.save_matrix(outdir, matrix_format)
        self.points.save(Path(outdir) / "points.csv")
        return path

    def save_matrix(self, outdir: str | Path, matrix_format: str = "cpm") -> Path:
        """Write ``visibility.cpm`` (or ``visibility.npz`` for ``scipy.sparse.load_npz`` with
        ``matrix_format="npz"``; see :mod:`camplace.visibility.store`) atomically: a hard link to
        the cache entry when there is one. Returns the file. A binary matrix held as bits is
        written as bits (the ``colbits`` structure) without a CSR copy."""
        from camplace.visibility.store import save_matrix

        # the same meta as the cache entry (the pair counts), so a written file equals a linked one
        counts = {k: self.stats[k] for k in COUNT_KEYS if k in self.stats}
        held = self.bits if self.bits is not None else self.qbytes
        source = held if (held is not None and matrix_format == "cpm") else self.matrix
        return save_matrix(Path(outdir), source, fmt=matrix_format, link_from=self.store_path,
                           meta={"stats": counts} if counts else None)


def frame_scene(instance, frame: int) -> RayScene:
    """Embree scene of everything that occludes in ``frame``: occluders and the posed target."""
    meshes = [(v, f) for _, v, f in instance.occluders_world(frame)]
    meshes.append(instance.target_world(frame))
    return RayScene(meshes)


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


def frame_eps(instance, frame: int) -> float:
    """Offset along the normal of a frame's segment ends, metres: :data:`EPS_REL` of the target's bounding-box diagonal."""
    tv = instance.target_world(frame)[0]
    return EPS_REL * float(np.linalg.norm(np.ptp(tv, axis=0)))


def lit_points(instance, points: TargetPoints) -> np.ndarray:
    """(m,) bool: rows lit by the instance's light, exactly as the matrix's ``require_light`` test
    (:func:`lit_mask` on every frame's scene; emitters count as lit)."""
    frames = [int(f) for f in np.unique(points.frame)]
    eps = np.zeros(len(instance.frames))
    for f in frames:
        eps[f] = frame_eps(instance, f)
    return lit_mask(instance, points, {f: frame_scene(instance, f) for f in frames}, eps)


def supporting_rows(points: TargetPoints, frame: int, target_vertices: np.ndarray, tol: float,
                    topology: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(m,) bool: surface rows of ``frame`` whose tangent plane has every target vertex behind it.

    A row p with normal n qualifies when ``max_v n . (v - p) <= tol`` over the frame's target
    vertices ``v``: the whole (closed, piecewise planar) target lies in the half-space
    ``n . (x - p) <= tol``. A linear function's maximum over the vertices is reached on their
    convex hull, and found there by ascent along the hull's edges (:func:`hull_graph`); where the
    hull is degenerate (a flat target) it is the largest over every vertex. Rows are cut into
    fixed blocks on every allowed core (the same flags at every count).

    Parameters
    ----------
    points : TargetPoints
    frame : int
    target_vertices : (t, 3) float64
        The target's vertices in ``frame``, metres.
    tol : float
        Metres.
    topology : tuple, optional
        :func:`hull_topology` of the same vertices in any rigid placement (the target's own
        frame: one hull for every event frame); default: computed from ``target_vertices``.
    """
    from camplace.visibility import _kernels

    out = np.zeros(len(points), dtype=bool)
    rows = np.nonzero((points.frame == frame) & ~points.is_emitter)[0]
    if len(rows) == 0:
        return out
    verts = np.ascontiguousarray(target_vertices, dtype=np.float64)
    pos = np.ascontiguousarray(points.positions[rows], dtype=np.float64)
    nrm = np.ascontiguousarray(points.normals[rows], dtype=np.float64)
    ok = np.zeros(len(rows), dtype=bool)
    graph = hull_graph(verts, topology)
    if graph is None:  # every vertex a seed, no edges: the plain maximum
        graph = (verts, np.zeros(len(verts) + 1, dtype=np.int64), np.zeros(0, dtype=np.int64),
                 np.arange(len(verts), dtype=np.int64))
    hverts, indptr, neighbours, seeds = graph
    work = len(rows) * (len(seeds) + 64)

    def block(lo: int, hi: int) -> None:
        _kernels.supporting_hull(lo, hi, hverts, indptr, neighbours, seeds, pos, nrm, float(tol), ok)

    with ctrl_c_deferred():
        run_blocks(block, cuts(len(rows)), threads_for(work))
    out[rows] = ok
    return out


#: directions whose extreme hull vertices seed the ascent: the 26 of a cube's faces, edges, corners
_SEED_DIRECTIONS = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                             if (x, y, z) != (0, 0, 0)], dtype=np.float64)


def hull_topology(verts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The convex hull of ``verts`` as a graph: which vertices, and their neighbours along its edges.

    The same for the vertices in any rigid placement, so one hull serves every event frame.

    Parameters
    ----------
    verts : (t, 3) float64
        Vertices, metres.

    Returns
    -------
    tuple or None
        ``(ids (h,) int64, indptr (h + 1,) int64, neighbours (e,) int64)``: the hull's vertices
        (indices into ``verts``) and hull vertex ``i``'s neighbours along the edges of Qhull's
        triangulated facets, ``neighbours[indptr[i]:indptr[i + 1]]`` (hull vertex numbers); None
        when the hull is degenerate (fewer than four vertices, or all of them on a plane).
    """
    try:
        hull = ConvexHull(np.asarray(verts, dtype=np.float64))
    except (QhullError, ValueError):
        return None
    ids = np.asarray(hull.vertices, dtype=np.int64)
    index = np.full(len(verts), -1, dtype=np.int64)
    index[ids] = np.arange(len(ids))
    tri = index[hull.simplices]
    h = len(ids)
    a, b = tri.ravel(), np.roll(tri, -1, axis=1).ravel()  # each facet's three edges
    keys = np.unique(np.concatenate([a * h + b, b * h + a]))  # both ways, sorted by first vertex
    indptr = np.zeros(h + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys // h, minlength=h), out=indptr[1:])
    return ids, indptr, np.ascontiguousarray(keys % h)


def hull_graph(verts: np.ndarray, topology: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The convex hull of ``verts`` for :func:`_kernels.supporting_hull`, or None.

    Parameters
    ----------
    verts : (t, 3) float64
        Vertices, metres.
    topology : tuple, optional
        :func:`hull_topology` of these vertices in any rigid placement; default: computed here.

    Returns
    -------
    tuple or None
        ``(hull_verts (h, 3) float64, indptr (h + 1,) int64, neighbours (e,) int64, seeds (s,)
        int64)``: the hull's vertices, their neighbours along its edges (:func:`hull_topology`)
        and the vertices extreme in 26 directions; None when the hull is degenerate.
    """
    topo = hull_topology(verts) if topology is None else topology
    if topo is None:
        return None
    ids, indptr, neighbours = topo
    hverts = np.ascontiguousarray(np.asarray(verts, dtype=np.float64)[ids])
    seeds = np.unique(np.argmax(hverts @ _SEED_DIRECTIONS.T, axis=0)).astype(np.int64)
    return hverts, indptr, neighbours, seeds


def make_task(instance, candidates, points: TargetPoints,
              quantised: bool | None = None) -> tuple[VisibilityTask, dict[int, FrameScenes]]:
    """The picklable task for (instance, candidates, points) and the frame scenes built for it
    (``quantised``: a graded matrix kept as bytes; default: as the instance's ``[quality]
    precision`` says)."""
    cam = instance.camera
    q = instance.quality
    frames = [int(f) for f in np.unique(points.frame)]
    full = {f: frame_scene(instance, f) for f in frames}
    rest = {f: RayScene([(v, fc) for _, v, fc in instance.occluders_world(f)]) for f in frames}
    scenes = {f: FrameScenes(full[f], rest[f]) for f in frames}
    eps = np.zeros(len(instance.frames))
    tol = np.zeros(len(instance.frames))
    support = np.zeros(len(points), dtype=bool)
    topology = hull_topology(instance.target.vertices)  # a rigid pose per frame: one hull for all
    for f in frames:
        tv = instance.target_world(f)[0]
        eps[f] = frame_eps(instance, f)
        tol[f] = 1e-9 * float(np.linalg.norm(np.ptp(tv, axis=0)))
        support |= supporting_rows(points, f, tv, tol[f], topology)
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
        min_target_px=float(getattr(q, "min_target_px", 0.0)),
        quantised=bool(quantised if quantised is not None else byte_precision(instance)),
        **team_intrinsics(instance, candidates),
    )
    return task, scenes


def byte_precision(instance) -> bool:
    """True when the instance's matrix is graded and kept as bytes (``[quality] precision = "byte"``)."""
    q = instance.quality
    return q.mode == "graded" and getattr(q, "precision", "byte") == "byte"


def team_intrinsics(instance, candidates) -> dict:
    """The task's ``cam_model`` and ``models`` of a team (nothing for a single-model instance)."""
    model = getattr(candidates, "model", None)
    if getattr(instance, "team", None) is None:
        if model is not None and len(model) and np.any(np.asarray(model) != 0):
            raise CamplaceError("candidates: the columns name camera models but the instance has a single [camera] "
                                "(use the team instance the candidates were sampled for)")
        return {}
    if model is None:
        if len(instance.cameras) > 1:
            log.warning("visibility: the candidates name no camera model: every column is the first model, %r", instance.camera.name)
        return {}
    models = tuple((c.K(), int(c.width_px), int(c.height_px), float(c.near_m), float(c.far_m)) for c in instance.cameras)
    model = np.asarray(model, dtype=np.int16)
    if len(model) and (model.min() < 0 or model.max() >= len(models)):
        raise CamplaceError(f"candidates: camera model index {int(model.max())} is not one of the instance's {len(models)} models")
    return {"cam_model": model, "models": models}


def assemble(task: VisibilityTask, parts: list[ChunkResult], workers: int | None = None) -> tuple[sp.csr_matrix, dict]:
    """CSR float32 matrix (rows x candidates) and summed counts from chunk results in column order.

    Each chunk's row runs are copied straight into the CSR arrays by a compiled kernel, which
    computes each pair's observation quality on the way (see the module docstring), on
    ``workers`` threads (default: the cores this process may use, :func:`camplace._cores.thread_count`),
    each thread filling a contiguous range of rows with about the same number of entries; chunks
    are taken in column order, so the column indices of each row come out ascending.
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
    # the big arrays' pages are faulted in by the merge threads, each for the rows it fills
    indices, data = first_touch_empty(nnz, index_dtype), first_touch_empty(nnz, np.float32)
    workers = max(1, min(thread_count(workers), m))
    emitter = ~np.any(task.normals != 0.0, axis=1)
    # every chunk holds one camera model: its fx grades its pairs
    fxs = [chunk_fx(task, int(p.col0)) for p in parts]
    bounds = [0, *np.searchsorted(indptr, [nnz * (t + 1) / workers for t in range(workers - 1)]), m]

    def merge(t: int) -> None:
        lo, hi = int(bounds[t]), int(bounds[t + 1])
        if hi <= lo:
            return
        populate(indices, indptr[lo], indptr[hi])
        populate(data, indptr[lo], indptr[hi])
        nxt = indptr[:-1].copy()
        for p, fx in zip(parts, fxs):
            _kernels.merge_rows(
                p.rowids, p.offsets, p.lcols, p.col0, lo, hi, nxt, indices, data, task.graded, task.positions,
                task.normals, emitter, task.cam_positions, fx, task.required_px_per_m,
            )

    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(merge, range(workers)))
    matrix = sp.csr_matrix((data, indices, indptr.astype(index_dtype)), shape=(m, n), copy=False)
    matrix.has_sorted_indices = True
    return matrix, total


def scatter_part(words: np.ndarray, part: ChunkResult) -> ChunkResult:
    """Set a chunk's observed pairs in the column bitsets ``words`` ((n, ceil(m / 64)) uint64) and
    return the chunk's counts with empty pair arrays (the chunk's own arrays can then be freed)."""
    from camplace.visibility.bits import scatter_chunk

    if len(part.rowids):
        scatter_chunk(part.rowids, part.offsets, part.lcols, int(part.col0), words)
    return ChunkResult(part.col0, np.empty(0, np.int32), np.zeros(1, np.int64), np.empty(0, np.uint8),
                       {**part.counts})


def compute_chunk_bytes(task: VisibilityTask, scenes, start: int, stop: int, values: np.ndarray) -> ChunkResult:
    """:func:`compute_chunk` of candidates ``start:stop`` written, quantised, straight into
    ``values`` (only these columns). Returns the counts. When ``values`` is a scratch file's
    mapping, the chunk's pages are then dropped from memory."""
    out = compute_chunk(task, scenes, start, stop, values=values)
    release_columns(values, start, stop)
    return out


def compute_chunk_bits(task: VisibilityTask, scenes, start: int, stop: int, words: np.ndarray) -> ChunkResult:
    """:func:`compute_chunk` of candidates ``start:stop`` set straight in ``words`` (only
    these columns are written: chunks run on threads side by side). Returns the counts. When
    ``words`` is a scratch file's mapping, the chunk's pages are then dropped from memory."""
    out = compute_chunk(task, scenes, start, stop, words)
    release_columns(words, start, stop)
    return out


def release_columns(words: np.ndarray, start: int, stop: int) -> None:
    """Drop columns ``start:stop`` of file-backed column bitsets or bytes ((n, w) uint64 or (n, m)
    uint8) from this process's memory (a no-op in memory)."""
    from camplace.visibility.scratch import release_pages

    row = words.shape[1] * words.itemsize
    release_pages(words, start * row, stop * row)


def _small_views(instance, candidates, points: TargetPoints) -> tuple[list[int], np.ndarray | None]:
    """The frames of ``points`` and which candidates see each frame's target smaller than
    ``[quality] min_target_px`` ((n, n_frames) bool), or None when none does (rule 6)."""
    from camplace.visibility.footprint import small_views

    frames = [int(f) for f in np.unique(points.frame)]
    small = small_views(instance, candidates.positions, candidates.rotations, frames,
                        models=getattr(candidates, "model", None))
    return frames, (small if small is not None and small.any() else None)


def _dropped(instance, counts: dict, n_drop: int, small: np.ndarray, frames: list[int]) -> dict:
    """``counts`` with ``observed`` lowered by the ``n_drop`` pairs rule 6 dropped (logged)."""
    if n_drop:
        log.info("visibility: %d pairs dropped by [quality] min_target_px = %g (%d of %d camera-frame views too small)",
                 n_drop, instance.quality.min_target_px, int(small[:, frames].sum()), small[:, frames].size)
    return {**counts, "observed": int(counts["observed"]) - n_drop}


def drop_small_views_bits(instance, candidates, points: TargetPoints, bits, counts: dict) -> dict:
    """:func:`drop_small_views` on a :class:`~camplace.visibility.bits.BitMatrix`, in place.

    Returns
    -------
    dict
        ``counts`` with ``observed`` lowered by the pairs dropped.
    """
    from camplace.visibility.bits import pack_rows

    frames, small = _small_views(instance, candidates, points)
    if small is None:
        return counts
    before = bits.column_counts.copy()
    surface = ~points.is_emitter
    for f in frames:
        cols = np.flatnonzero(small[:, f])
        if not len(cols):
            continue
        keep = ~pack_rows(surface & (points.frame == f))
        for c0 in range(0, len(cols), 1024):  # blocks of columns: a bounded copy
            sel = cols[c0:c0 + 1024]
            bits.words[sel] &= keep[None, :]
            for j in sel:
                release_columns(bits.words, int(j), int(j) + 1)
    bits.__dict__.pop("column_counts", None)
    n_drop = int(before.sum() - bits.column_counts.sum())
    return _dropped(instance, counts, n_drop, small, frames)


def drop_small_views_bytes(instance, candidates, points: TargetPoints, qbytes, counts: dict) -> dict:
    """:func:`drop_small_views` on a :class:`~camplace.visibility.qbytes.ByteMatrix`, in place.

    Returns
    -------
    dict
        ``counts`` with ``observed`` lowered by the pairs dropped.
    """
    frames, small = _small_views(instance, candidates, points)
    if small is None:
        return counts
    before = qbytes.column_counts.copy()
    surface = ~points.is_emitter
    for f in frames:
        rows = np.flatnonzero(surface & (points.frame == f))
        for j in np.flatnonzero(small[:, f]):
            qbytes.values[j, rows] = 0
    qbytes.__dict__.pop("column_counts", None)
    n_drop = int(before.sum() - qbytes.column_counts.sum())
    return _dropped(instance, counts, n_drop, small, frames)


_DROP_BLOCK_PAIRS = 1 << 22  # pairs examined at once by drop_small_views


def drop_small_views(instance, candidates, points: TargetPoints, matrix: sp.csr_matrix, counts: dict) -> tuple[sp.csr_matrix, dict]:
    """Rule 6 of the module docstring: drop the target's points of a frame from the cameras that see
    that frame's target smaller than ``[quality] min_target_px`` (emitter rows are kept).

    Parameters
    ----------
    instance : camplace.instance.Instance
    candidates : CandidateSet
        The matrix's columns (positions, world-from-camera rotations).
    points : TargetPoints
        Its rows.
    matrix : (m, n) scipy.sparse.csr_matrix
    counts : dict
        The engine's pair counts; ``observed`` is lowered by the pairs dropped.

    Returns
    -------
    (m, n) scipy.sparse.csr_matrix, dict
    """
    frames, small = _small_views(instance, candidates, points)
    if small is None:
        return matrix, counts
    m = matrix.shape[0]
    surface = ~points.is_emitter
    keep = np.ones(matrix.nnz, dtype=bool)  # 1 byte a pair; the rest is made a block of rows at a time
    row_counts = np.zeros(m, dtype=np.int64)
    bounds = np.unique(np.append(np.searchsorted(matrix.indptr, np.arange(0, matrix.nnz, _DROP_BLOCK_PAIRS), side="right") - 1, m))
    for r0, r1 in zip(bounds[:-1], bounds[1:]):
        a, b = int(matrix.indptr[r0]), int(matrix.indptr[r1])
        rows = np.repeat(np.arange(r0, r1), np.diff(matrix.indptr[r0:r1 + 1]))
        keep[a:b] = ~(small[matrix.indices[a:b], points.frame[rows]] & surface[rows])
        row_counts[r0:r1] = np.bincount(rows[keep[a:b]] - r0, minlength=r1 - r0)
    n_drop = int(matrix.nnz - np.count_nonzero(keep))
    if n_drop == 0:
        return matrix, counts
    indptr = np.zeros(m + 1, dtype=matrix.indptr.dtype)
    np.cumsum(row_counts, out=indptr[1:])
    out = sp.csr_matrix((matrix.data[keep], matrix.indices[keep], indptr), shape=matrix.shape, copy=False)
    out.has_sorted_indices = True
    return out, _dropped(instance, counts, n_drop, small, frames)


def default_chunk_size(task: VisibilityTask) -> int:
    """Candidates per work item: about 2 million (row, candidate) pairs, 8 to 256 candidates."""
    return int(np.clip(2_000_000 // max(1, len(task.live_rows)), 8, 256))


def team_chunk_plan(task: VisibilityTask, chunk_size: int, workers: int) -> list[tuple[int, int]]:
    """:func:`chunk_plan` within each run of columns of one camera model (a chunk never holds two)."""
    plan = []
    for _, a, b in task.model_ranges():
        plan += [(a + s, a + e) for s, e in chunk_plan(b - a, chunk_size, workers)]
    return plan


def _while_waiting(idle: Callable[[], object]) -> None:
    """Run :func:`compute_visibility`'s ``idle`` work; an error there is logged, not raised."""
    t0 = time.perf_counter()
    try:
        idle()
    except Exception as exc:  # noqa: BLE001 - optional work: the matrix does not depend on it
        log.debug("visibility: the idle work failed (%s: %s); going on", type(exc).__name__, exc)
    log.debug("visibility: idle work took %.3f s while the chunks were cast", time.perf_counter() - t0)


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


def available_memory_bytes() -> int:
    """Physical memory of this machine (bytes), or 8 GiB when unknown."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        return 8 << 30


#: resident bytes of the process besides the matrix and the threads' work arrays: interpreter,
#: numpy / scipy / numba / Embree, the compiled kernels, the scenes, the points and candidates
#: (calibrated with benchmarks/scale.py on comet-67p-bunker, 2 threads: 380-410 MiB in all at
#: 2,000 x 10,000 and 10,000 x 50,000 besides the bitsets)
BASE_BYTES = 280 * 2**20
#: per-thread chunk work arrays and result slabs of a chunk cast as a whole (a float32 CSR, or no
#: Embree 4 packet path): culling, segments, Embree batches for the chunk's pairs (comet-67p-bunker,
#: 2 threads, the run's resident bytes fell by 63 MiB at 2,000 x 10,000 and 120-125 MiB at
#: 10,000 x 50,000 from the cast's peak to the solve's start, /proc sampled every 20 ms)
THREAD_BYTES = 60 * 2**20
#: a thread's work arrays when chunks are cast camera by camera into bits or bytes
#: (:func:`camplace.visibility._kernels.cast_chunk`): kept, group, origins, directions, slot and
#: blocked for one camera's pairs, 34 bytes a live row ...
CAMERA_PAIR_BYTES = 34
#: ... besides the thread's own (its stack, Embree's per-thread state): comet-67p-bunker
#: 10,000 x 50,000, bits, peak 364 MiB at 1 thread and 367 MiB at 2 (1.7 MiB of work arrays a thread)
CAMERA_THREAD_BYTES = 4 * 2**20


def thread_bytes(layout: str, n_rows: int) -> int:
    """Resident bytes of one casting thread's work arrays for a matrix of ``n_rows`` rows in
    ``layout`` (see :func:`estimate_matrix_bytes`): :data:`CAMERA_THREAD_BYTES` plus
    :data:`CAMERA_PAIR_BYTES` a row when the chunks are cast camera by camera (bits and bytes,
    with Embree 4's packets), else :data:`THREAD_BYTES`."""
    from camplace.visibility._embree import packet_api

    if layout == "csr" or packet_api() is None:
        return THREAD_BYTES
    return CAMERA_THREAD_BYTES + CAMERA_PAIR_BYTES * int(n_rows)


#: the quality tree's table when the full one is over the budget, as a share of the matrix bytes
#: (rows for the clusters of more than 64 cameras only: about n / 40 rows; :mod:`camplace.solver.bytes_route`)
LEAN_TREE = 1 / 32


def estimate_matrix_bytes(n_rows: int, n_cols: int, density: float, layout: str = "csr", tree: float = 1.0,
                          solve_bytes: int | Callable[[float], int] | None = None) -> int:
    """Peak bytes of a run with a matrix of this size and density in ``layout``.

    ``csr`` (graded values): the chunk results (1 byte a pair, plus 12 bytes a nonempty row of a
    chunk) and the float32 CSR (8 bytes a pair plus row pointers) coexist at the peak: about 10
    bytes a pair. ``bits`` (binary): each chunk is scattered into the column bitsets as it
    finishes and dropped, so the matrix is ``B = n_cols * ceil(n_rows / 64) * 8`` bytes whatever
    the density; the presolve's working bitsets (the live rows over the kept columns, then the
    reduced columns, :func:`camplace.solver.problem.presolve_bits.presolve_bits`) are at most one
    more ``B``: ``2 B``. ``bits-disk`` (out of core, :mod:`camplace.visibility.scratch`): the
    bitsets are in a scratch file and only the pages of the chunks in flight are resident; the
    presolve's reduced instance must still fit in memory, and the presolve checks it against the
    budget itself once it knows its size. ``bytes`` (graded, quantised: :mod:`camplace.visibility.qbytes`):
    the matrix is ``C = n_cols * n_rows`` bytes whatever the density, and the solver's quality tree
    adds its inner nodes' table (``(n_cols - 1) x n_rows`` bytes, :func:`camplace.solver.engines.quality.tree.quality_tree_bytes_dense`)
    and the pattern's column bitsets (``B``, its ordering and the run's summary): ``2 C + B``
    (``(1 + tree) C + B``: ``tree = 0`` for a run whose solve reads the pattern, e.g. max coverage,
    :data:`LEAN_TREE` when the solver keeps rows for large clusters only). ``bytes-disk`` (out of
    core): the bytes are in a scratch file (only the chunks in flight resident while they are cast;
    afterwards the solver's reads keep pages in the page cache, which the kernel reclaims under
    memory pressure): ``tree C + B``. All add the per-thread work arrays
    (:func:`thread_bytes` a thread; ``bits``: or the solve's bytes, the larger) and the process's
    base (:data:`BASE_BYTES`).

    ``solve_bytes`` (``bits`` only): the working bytes of the solve the run makes next, besides the
    bitsets, as far as they are known before the cast, from the stage that knows the solver (the
    pipeline: :func:`camplace.solver.api.bits_solve_bytes`: e.g. the bit presolve, set cover's row
    bitsets and their transposition, about ``2 B``, the angle engine; the engines on the presolved
    instance estimate and check their own bytes once it is known), a number or a function of the
    density (the share of observed cells: 0 before the work, the pilot's at the pilot's check).
    The threads' work arrays are freed when the cast ends, before the solve allocates: the bits
    layout counts the larger of the two, ``B + max(threads' arrays, solve_bytes)`` besides the
    base. None: ``B`` for the solve (max coverage's presolve, as counted before the solve was known).
    """
    threads = thread_bytes(layout, n_rows) * thread_count()
    fixed = BASE_BYTES + threads
    words = 8 * n_cols * ((n_rows + 63) // 64)
    if layout == "bytes":
        cells = n_rows * n_cols
        return int((1 + float(tree)) * cells + words + 16 * n_rows + fixed)
    if layout == "bits-disk":
        return int(16 * n_rows + 64 * n_cols + fixed)
    if layout == "bytes-disk":
        return int(float(tree) * n_rows * n_cols + words + 16 * n_rows + 64 * n_cols + fixed)
    if layout == "bits":  # the cast's threads' arrays, then (freed) the solve's working bytes
        solve = words if solve_bytes is None else solve_bytes(density) if callable(solve_bytes) else solve_bytes
        return int(words + 16 * n_rows + BASE_BYTES + max(threads, int(solve)))
    nnz = density * n_rows * n_cols
    return int(10 * nnz + 16 * (n_rows + 1) + fixed)


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
    layout: str = "auto",
    scratch=None,
    quality_tree: bool = True,
    idle: Callable[[], object] | None = None,
    solve_bytes: int | Callable[[float], int] | None = None,
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
        Threads (default: the cores this process may use, :func:`camplace._cores.thread_count`).
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
    layout : {"auto", "bits", "bytes", "csr"}
        ``auto``: a binary instance's matrix as column bitsets (:attr:`VisibilityMatrix.bits`,
        one bit a cell, each chunk scattered into them as it finishes: no float CSR is made), a
        graded one as quantised columns (:attr:`VisibilityMatrix.qbytes`, one byte a cell, filled
        the same way) when its ``[quality] precision`` is ``byte`` (the default), else as float32
        CSR; ``csr``: float32 CSR always (``bits`` is refused for a graded instance, ``bytes``
        for a binary one).
    scratch : camplace.visibility.scratch.Scratch or None
        Where column bitsets that do not fit ``memory_budget_bytes`` go (out of core: a file, read
        and written block by block); None: such a matrix is an error before the work.
    quality_tree : bool
        Quantised columns only: the run's solve builds the quality tree over them (``--mode
        quality``), so the memory estimate counts its inner nodes' table too (False: a solve that
        reads the pattern).
    solve_bytes : int, callable or None
        Column bitsets only: the working bytes of the solve the run makes next, besides the bitsets,
        for the memory estimate (:func:`estimate_matrix_bytes`'s ``solve_bytes``: a number or a
        function of the observed share of cells; the pipeline gives
        :func:`camplace.solver.api.bits_solve_bytes`); None: max coverage's presolve.
    idle : callable or None
        Called once by this thread while the worker threads cast the chunks (after the first one),
        for work that would otherwise wait for the matrix (the pipeline loads the solver's
        kernels there); not called on a cache hit or a Dask cluster. Its errors are logged and
        ignored: it must not change the matrix.

    Returns
    -------
    VisibilityMatrix
    """
    if layout not in ("auto", "bits", "bytes", "csr"):
        raise CamplaceError(f"visibility layout: unknown {layout!r} (use auto, bits, bytes or csr)")
    graded = instance.quality.mode == "graded"
    if layout == "bits" and graded:
        raise CamplaceError("visibility layout bits: the instance's [quality] mode is graded (its values need csr)")
    if layout == "bytes" and not graded:
        raise CamplaceError("visibility layout bytes: the instance's [quality] mode is binary (use bits)")
    use_bits = layout == "bits" or (layout == "auto" and not graded)
    use_bytes = layout == "bytes" or (layout == "auto" and byte_precision(instance))
    n_cand = len(candidates)
    model = getattr(candidates, "model", None)
    if getattr(instance, "team", None) is not None and model is not None and len(model) and np.any(np.diff(model) < 0):
        # a team's columns in any order: compute them grouped by model, then put them back
        order = np.argsort(model, kind="stable")
        grouped = type(candidates)(candidates.positions[order], candidates.aims[order], candidates.rotations[order],
                                   sampler=candidates.sampler, seed=candidates.seed, model=np.asarray(model)[order])
        vis = compute_visibility(instance, grouped, points, chunk_size=chunk_size, workers=workers, progress=progress,
                                 memory_budget_bytes=memory_budget_bytes, dask_address=dask_address, cache_dir=cache_dir,
                                 layout=layout)
        back = np.empty_like(order)
        back[order] = np.arange(len(order))
        if vis.bits is not None:
            from camplace.visibility.bits import BitMatrix

            return VisibilityMatrix(bits=BitMatrix(vis.bits.words[back], len(points)), points=points, stats=vis.stats,
                                    timings_s=vis.timings_s)
        if vis.qbytes is not None:
            from camplace.visibility.qbytes import ByteMatrix

            return VisibilityMatrix(qbytes=ByteMatrix(vis.qbytes.values[back]), points=points, stats=vis.stats,
                                    timings_s=vis.timings_s)
        matrix = vis.matrix[:, back].tocsr()
        matrix.sort_indices()
        return VisibilityMatrix(matrix=matrix, points=points, stats=vis.stats, timings_s=vis.timings_s)
    t_prepare = time.perf_counter()
    task, scenes = make_task(instance, candidates, points, quantised=use_bytes)
    if chunk_size is None:
        chunk_size = default_chunk_size(task)
    key = None
    timings: dict[str, float] = {}
    if cache_dir is not None:
        key = cache.task_key(task)
        t0 = time.perf_counter()
        hit = cache.load(Path(cache_dir), key, (len(points), n_cand), bits=use_bits, quantised=use_bytes)
        timings["cache.load"] = time.perf_counter() - t0
        if hit is not None:
            if progress is not None:
                progress(n_cand)
            held = {"bits": hit[0]} if use_bits else {"qbytes": hit[0]} if use_bytes else {"matrix": hit[0]}
            return VisibilityMatrix(**held, points=points, stats={**hit[1], "cache": "hit"},
                                    store_path=cache.entry_path(Path(cache_dir), key), timings_s=timings)
    budget = memory_budget_bytes if memory_budget_bytes is not None else available_memory_bytes() // 2
    starts = list(range(0, n_cand, chunk_size))
    solve_kw = {} if solve_bytes is None else {"solve_bytes": solve_bytes if callable(solve_bytes) else int(solve_bytes)}

    # The first chunk is a pilot: its density is checked against the memory budget before the bulk
    # of the work (in process, the other chunks start beside it and are cancelled on a failed check).

    def check_pilot(first: ChunkResult, pilot_cols: int) -> None:
        if pilot_layout in ("bytes", "bytes-disk"):  # one byte a cell: checked before the work
            return
        density = first.counts["observed"] / max(1, len(points) * pilot_cols)
        need = estimate_matrix_bytes(len(points), n_cand, density, pilot_layout, **solve_kw)
        if need > budget:
            raise CamplaceError(
                f"visibility: the matrix and the solve would need about {need / 2**30:.1f} GiB ({len(points):_} rows x "
                f"{n_cand:_} candidates, {100 * density:.1f}% observed in a pilot of {pilot_cols} candidates), over the memory "
                f"budget of {budget / 2**30:.1f} GiB (lower --points or --candidates, or raise --memory-budget-gb)"
            )

    parts: list[ChunkResult] = []
    pilot_layout = "bits" if use_bits else "bytes" if use_bytes else "csr"
    words = values = None
    if use_bytes:
        need = estimate_matrix_bytes(len(points), n_cand, 1.0, "bytes", tree=1.0 if quality_tree else 0.0)
        lean = estimate_matrix_bytes(len(points), n_cand, 1.0, "bytes", tree=LEAN_TREE)
        if need > budget and quality_tree and lean <= budget:  # the tree will keep rows for large clusters only
            log.info("visibility: estimated peak %.2f GiB with the quality tree's full table, over the memory budget "
                     "(%.2f GiB); %.2f GiB with rows for large clusters only (the solver sizes the table to its budget)",
                     need / 2**30, budget / 2**30, lean / 2**30)
            need = lean
        disk = estimate_matrix_bytes(len(points), n_cand, 1.0, "bytes-disk", tree=LEAN_TREE if quality_tree else 0.0)
        if need > budget and scratch is not None and disk <= budget:
            values = scratch.array("colbytes.u8", (n_cand, len(points)), np.uint8)
            pilot_layout = "bytes-disk"
            log.info("visibility: quantised columns %.1f MiB out of core in %s (estimated peak %.2f GiB, budget %.2f GiB)",
                     len(points) * n_cand / 2**20, scratch.path, disk / 2**30, budget / 2**30)
        elif need > budget:
            raise CamplaceError(
                f"visibility: the run would need about {min(need, disk) / 2**30:.1f} GiB ({len(points):_} rows x "
                f"{n_cand:_} candidates, one byte a cell for the matrix and as much for the quality tree"
                f"{', out of core' if scratch is not None else ''}), over the memory budget of {budget / 2**30:.1f} GiB "
                f"(lower --points or --candidates, raise --memory-budget-gb, or set [quality] precision = \"float32\" "
                f"for a sparse matrix)")
        else:
            log.info("visibility: quantised columns %.1f MiB, estimated peak %.2f GiB", len(points) * n_cand / 2**20,
                     need / 2**30)
            values = np.zeros((n_cand, len(points)), dtype=np.uint8)
    if use_bits:
        from camplace.visibility.bits import bit_words

        # one bit a cell: known before the work; the solve's part that grows with the observed pairs
        # (density 0 here) is checked with the pilot's density
        need = estimate_matrix_bytes(len(points), n_cand, 0.0, "bits", **solve_kw)
        shape = (n_cand, bit_words(len(points)))
        if need > budget and scratch is not None:
            disk = estimate_matrix_bytes(len(points), n_cand, 1.0, "bits-disk")
            if disk > budget:
                raise CamplaceError(
                    f"visibility: even out of core the run needs about {disk / 2**30:.1f} GiB ({len(points):_} rows), over "
                    f"the memory budget of {budget / 2**30:.1f} GiB (lower --points or raise --memory-budget-gb)")
            words = scratch.array("colbits.u64", shape)
            pilot_layout = "bits-disk"
            log.info("visibility: column bitsets %.1f MiB out of core in %s (estimated peak %.2f GiB, budget %.2f GiB)",
                     8 * shape[0] * shape[1] / 2**20, scratch.path, disk / 2**30, budget / 2**30)
        elif need > budget:
            raise CamplaceError(
                f"visibility: the matrix would need about {need / 2**30:.1f} GiB ({len(points):_} rows x {n_cand:_} "
                f"candidates, one bit a cell), over the memory budget of {budget / 2**30:.1f} GiB (lower --points or "
                f"--candidates, or raise --memory-budget-gb)"
            )
        else:
            log.info("visibility: column bitsets %.1f MiB, estimated peak %.2f GiB", 8 * shape[0] * shape[1] / 2**20,
                     need / 2**30)
            words = np.zeros(shape, dtype=np.uint64)
    t_cast = time.perf_counter()
    timings["visibility.prepare"] = t_cast - t_prepare
    if dask_address is not None:
        if task.cam_model is not None:  # chunks end at the model boundaries
            ranges = [(a + s, a + e) for _, a, b in task.model_ranges() for s, e in chunk_plan(b - a, chunk_size, 1)]
        else:
            ranges = [(s, min(s + chunk_size, n_cand)) for s in starts]
        if ranges:
            a0, b0 = ranges[0]
            parts.append(compute_chunk(task, scenes, a0, b0))
            check_pilot(parts[0], b0 - a0)
            if words is not None:
                parts[0] = scatter_part(words, parts[0])
                release_columns(words, a0, b0)
            if values is not None:
                parts[0] = scatter_part_bytes(task, values, parts[0])
                release_columns(values, a0, b0)
            if progress is not None:
                progress(b0 - a0)
        rest = ranges[1:]
        parts += compute_chunks_dask(task, [a for a, _ in rest], chunk_size, dask_address, progress=progress,
                                     stops=[b for _, b in rest] if task.cam_model is not None else None,
                                     words=words, values=values)
    else:
        workers = thread_count(workers)

        plan = chunk_plan(n_cand, chunk_size, workers) if task.cam_model is None else team_chunk_plan(task, chunk_size, workers)
        pool = ThreadPoolExecutor(max_workers=workers)
        try:
            if values is not None:  # every chunk writes its cells on its thread (checked before the work)
                futures = [pool.submit(compute_chunk_bytes, task, scenes, a, b, values) for a, b in plan]
            elif words is None:
                futures = [pool.submit(compute_chunk, task, scenes, a, b) for a, b in plan]
            else:  # every chunk sets its bits on its thread; the pilot's count is checked
                futures = [pool.submit(compute_chunk_bits, task, scenes, a, b, words) for a, b in plan]
            for i, ((a, b), fut) in enumerate(zip(plan, futures, strict=True)):
                parts.append(fut.result())
                if i == 0:
                    check_pilot(parts[0], b - a)
                if progress is not None:
                    progress(b - a)
                if i == 0 and idle is not None and len(plan) > 1:
                    _while_waiting(idle)
        finally:  # on an error or Ctrl-C, chunks not started are dropped
            pool.shutdown(wait=True, cancel_futures=True)
            drop_scratch()
    t_finish = time.perf_counter()
    timings["visibility.cast"] = t_finish - t_cast
    bits = qbytes = None
    if words is not None or values is not None:
        from camplace.visibility.bits import BitMatrix
        from camplace.visibility.qbytes import ByteMatrix

        total = dict.fromkeys(COUNT_KEYS, 0)
        for part in parts:
            for k in COUNT_KEYS:
                total[k] += part.counts[k]
        parts.clear()
        matrix = None
        if words is not None:
            bits = BitMatrix(words, len(points))
            if task.min_target_px > 0:
                total = drop_small_views_bits(instance, candidates, points, bits, total)
        else:
            qbytes = ByteMatrix(values)
            if task.min_target_px > 0:
                total = drop_small_views_bytes(instance, candidates, points, qbytes, total)
    else:
        matrix, total = assemble(task, parts)
        parts.clear()
        if task.min_target_px > 0:
            matrix, total = drop_small_views(instance, candidates, points, matrix, total)
    timings["visibility.finish"] = time.perf_counter() - t_finish
    store_path = None
    if key is not None:
        t0 = time.perf_counter()
        store_path = cache.store(Path(cache_dir), key, bits if bits is not None else qbytes if qbytes is not None
                                 else matrix, total)
        timings["cache.store"] = time.perf_counter() - t0
        total = {**total, "cache": "miss"}
    log.info(
        "visibility: %d pairs, %d in range, %d in frustum, %d facing, %d observed",
        total["pairs"], total["in_range"], total["in_frustum"], total["facing"], total["observed"],
    )
    return VisibilityMatrix(matrix=matrix, bits=bits, qbytes=qbytes, points=points, stats=total, store_path=store_path,
                            timings_s=timings)
