"""The points x candidates visibility matrix, by culling then Embree segment casting.

A (point, candidate) pair is observed when, in the candidate's camera (OpenCV axes, pinhole):

1. the point lies between ``near_m`` and ``far_m`` in depth (camera z);
2. it projects inside the image: ``-0.5 <= u < width - 0.5`` and ``-0.5 <= v < height - 0.5``
   (pixel centres at integer coordinates, principal point at the image centre);
3. it faces the camera: ``n . (c - p) > 0``;
4. the segment from the camera centre to ``p + eps * n`` crosses no triangle of the scene
   (every occluder of the point's frame, the target itself included). ``eps`` is 1e-4 of the
   target's bounding-box diagonal and keeps the point's own face from occluding it.

Pairs failing 1-3 are culled in numpy before any ray is cast; the remaining segments are cast
with Embree, chunk by chunk over candidates, on a pool of threads (Embree and numpy release the GIL).
"""

from __future__ import annotations

import logging
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


@dataclass(frozen=True, eq=False)
class VisibilityMatrix:
    """Observation quality of every (point, candidate) pair.

    Attributes
    ----------
    matrix : (m, n) scipy.sparse.csr_matrix of float32
        Value > 0 means observed; the value is the observation quality (1.0 for a binary test).
    points : TargetPoints
        The m rows.
    stats : dict
        Pair counts after each culling step and timings.
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
    """Embree scene of everything that occludes in ``frame``: static occluders and the posed target."""
    meshes = [(v, f) for _, v, f in instance.occluders_world()]
    meshes.append(instance.target_world(frame))
    return RayScene(meshes)


def cull_chunk(
    points: np.ndarray,
    normals: np.ndarray,
    cam_pos: np.ndarray,
    cam_rot: np.ndarray,
    K: np.ndarray,
    width_px: int,
    height_px: int,
    near_m: float,
    far_m: float,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Frustum, range and facing tests for a chunk of cameras against all points.

    Parameters
    ----------
    points : (m, 3) float64
    normals : (m, 3) float64
    cam_pos : (c, 3) float64
    cam_rot : (c, 3, 3) float64
        World-from-camera rotations (OpenCV axes).
    K : (3, 3) float64
    width_px, height_px : int
    near_m, far_m : float

    Returns
    -------
    cam_idx : (q,) int64
        Chunk-local camera index of each surviving pair.
    point_idx : (q,) int64
        Point index of each surviving pair.
    counts : dict
        Pairs surviving each test.
    """
    diff = points[None, :, :] - cam_pos[:, None, :]  # (c, m, 3) camera -> point
    cam = np.einsum("cmk,ckl->cml", diff, cam_rot)  # camera coordinates
    z = cam[:, :, 2]
    ok = (z >= near_m) & (z <= far_m)
    n_range = int(ok.sum())
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * cam[:, :, 0] / z + K[0, 2]
        v = K[1, 1] * cam[:, :, 1] / z + K[1, 2]
    ok &= (u >= -0.5) & (u < width_px - 0.5) & (v >= -0.5) & (v < height_px - 0.5)
    n_frustum = int(ok.sum())
    ok &= np.einsum("cmk,mk->cm", diff, normals) < 0.0  # n . (c - p) > 0
    cam_idx, point_idx = np.nonzero(ok)
    return cam_idx, point_idx, {"in_range": n_range, "in_frustum": n_frustum, "facing": int(len(cam_idx))}


def compute_visibility(
    instance,
    candidates,
    points: TargetPoints,
    *,
    chunk_size: int = 32,
    workers: int | None = None,
    progress: Callable[[int], None] | None = None,
) -> VisibilityMatrix:
    """Build the points x candidates visibility matrix.

    Parameters
    ----------
    instance : camplace.instance.Instance
    candidates : camplace.sampling.CandidateSet
    points : TargetPoints
    chunk_size : int
        Candidates per work item.
    workers : int or None
        Threads (default: number of CPUs, at most 8).
    progress : callable or None
        Called with the number of candidates finished after each chunk.

    Returns
    -------
    VisibilityMatrix
    """
    cam = instance.camera
    K = cam.K()
    n_cand = len(candidates)
    m = len(points)
    frames = np.unique(points.frame)
    scenes = {int(f): frame_scene(instance, int(f)) for f in frames}
    rows_by_frame = {int(f): np.nonzero(points.frame == f)[0] for f in frames}
    diag = {
        int(f): float(np.linalg.norm(np.ptp(instance.target_world(int(f))[0], axis=0))) for f in frames
    }
    workers = workers or min(8, os.cpu_count() or 1)
    starts = list(range(0, n_cand, chunk_size))

    def work(start: int) -> tuple[np.ndarray, np.ndarray, dict]:
        stop = min(start + chunk_size, n_cand)
        pos = candidates.positions[start:stop]
        rot = candidates.rotations[start:stop]
        out_r, out_c = [], []
        counts = {"pairs": 0, "in_range": 0, "in_frustum": 0, "facing": 0, "cast": 0, "observed": 0}
        for f, rows in rows_by_frame.items():
            p = points.positions[rows]
            nrm = points.normals[rows]
            ci, pi, cnt = cull_chunk(p, nrm, pos, rot, K, cam.width_px, cam.height_px, cam.near_m, cam.far_m)
            for key in ("in_range", "in_frustum", "facing"):
                counts[key] += cnt[key]
            counts["pairs"] += len(rows) * (stop - start)
            ends = p[pi] + (EPS_REL * diag[f]) * nrm[pi]
            blocked = scenes[f].occluded(pos[ci], ends)
            counts["cast"] += len(ci)
            keep = ~blocked
            counts["observed"] += int(keep.sum())
            out_r.append(rows[pi[keep]])
            out_c.append(ci[keep] + start)
        return np.concatenate(out_r), np.concatenate(out_c), counts

    total = {"pairs": 0, "in_range": 0, "in_frustum": 0, "facing": 0, "cast": 0, "observed": 0}
    rows_all, cols_all = [], []
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for start, (r, c, cnt) in zip(starts, pool.map(work, starts)):
            rows_all.append(r)
            cols_all.append(c)
            for key in total:
                total[key] += cnt[key]
            if progress is not None:
                progress(min(chunk_size, n_cand - start))
    rows = np.concatenate(rows_all) if rows_all else np.empty(0, dtype=np.int64)
    cols = np.concatenate(cols_all) if cols_all else np.empty(0, dtype=np.int64)
    matrix = sp.csr_matrix((np.ones(len(rows), dtype=np.float32), (rows, cols)), shape=(m, n_cand), dtype=np.float32)
    matrix.sum_duplicates()
    matrix.sort_indices()
    log.info(
        "visibility: %d pairs, %d in range, %d in frustum, %d facing, %d observed",
        total["pairs"], total["in_range"], total["in_frustum"], total["facing"], total["observed"],
    )
    return VisibilityMatrix(matrix=matrix, points=points, stats=total)
