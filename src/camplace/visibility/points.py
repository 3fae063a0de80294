"""Observation points: area-weighted samples of the target surface, with normals, per frame."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camplace._io import csv_text, read_numeric_csv, write_text_atomic
from camplace.errors import CamplaceError

POINTS_HEADER = "index,x,y,z,nx,ny,nz,frame,weight"


def face_normals_areas(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit face normals (right-hand rule on the winding) and face areas.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64

    Returns
    -------
    normals : (m, 3) float64
        Zero rows for degenerate faces.
    areas : (m,) float64
    """
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, norm[:, None], out=np.zeros_like(cross), where=norm[:, None] > 0)
    return normals, 0.5 * norm


def sample_surface(
    vertices: np.ndarray, faces: np.ndarray, n: int, *, seed: int | np.random.SeedSequence | None = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample ``n`` points uniformly by area on a triangle mesh.

    Parameters
    ----------
    vertices : (v, 3) float64
    faces : (f, 3) int64
    n : int
    seed : int, SeedSequence or None

    Returns
    -------
    face_index : (n,) int64
        The face each point lies on.
    barycentric : (n, 3) float64
        Barycentric coordinates of each point in its face.
    points : (n, 3) float64
    """
    rng = np.random.default_rng(seed)
    _, areas = face_normals_areas(vertices, faces)
    total = areas.sum()
    if not np.isfinite(total) or total <= 0:
        raise CamplaceError("target: mesh has zero surface area (check the target mesh)")
    cdf = np.cumsum(areas) / total
    face_index = np.minimum(np.searchsorted(cdf, rng.random(n), side="right"), len(faces) - 1)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.column_stack([1.0 - s, s * (1.0 - r2), s * r2])
    tri = vertices[faces[face_index]]
    points = np.einsum("ni,nij->nj", bary, tri)
    return face_index.astype(np.int64), bary, points


@dataclass(frozen=True, eq=False)
class TargetPoints:
    """The rows of the visibility matrix: (frame, point) pairs.

    Attributes
    ----------
    positions : (m, 3) float64
        World positions, metres.
    normals : (m, 3) float64
        Outward unit normals (the normal of the face the point lies on); all zero for a
        volumetric emitter point (a coma or plume particle), which has no surface.
    frame : (m,) int32
        Event frame of each row.
    weight : (m,) float64
        Row weight: frame likelihood / points per frame (sums to 1 over all rows).
    """

    positions: np.ndarray
    normals: np.ndarray
    frame: np.ndarray
    weight: np.ndarray

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    @property
    def is_emitter(self) -> np.ndarray:
        """(m,) bool: rows that are volumetric emitter points (zero normal)."""
        return ~np.any(self.normals != 0.0, axis=1)

    def to_csv(self) -> str:
        """The ``points.csv`` text: ``index,x,y,z,nx,ny,nz,frame,weight``.

        Formatted once per set and kept (the points are frozen): ``camplace run`` formats it while
        the rays are cast (:func:`camplace.pipeline.run_settings`), and the run folder writes it."""
        text = self.__dict__.get("_csv")
        if text is None:
            m = len(self)
            text = self.__dict__["_csv"] = csv_text(POINTS_HEADER, [np.arange(m), *self.positions.T, *self.normals.T,
                                                                     self.frame, self.weight])
        return text

    def save(self, path: str | Path) -> None:
        """Write ``points.csv`` atomically."""
        write_text_atomic(path, self.to_csv())

    @classmethod
    def load(cls, path: str | Path) -> "TargetPoints":
        """Read a ``points.csv`` written by :meth:`save`."""
        data = read_numeric_csv(path, POINTS_HEADER, "points file")
        return cls(
            positions=data[:, 1:4].copy(),
            normals=data[:, 4:7].copy(),
            frame=data[:, 7].astype(np.int32),
            weight=data[:, 8].copy(),
        )


def make_target_points(instance, n_points: int, *, seed: int | np.random.SeedSequence | None = 0) -> TargetPoints:
    """The matrix rows: target surface points in every frame, then that frame's emitter points.

    The same material points (sampled once on the target's local mesh, by area) are carried into
    each frame by the frame's target pose; each frame gets ``ceil(n_points / n_frames)`` of them.
    A frame's rows sum to its normalised likelihood P: the surface points share
    ``P * target_weight / T`` equally and each emitter gets ``P * w / T``, where ``T`` is
    ``target_weight`` plus the frame's emitter weights.

    Parameters
    ----------
    instance : camplace.instance.Instance
    n_points : int
        Surface points in all (split over frames).
    seed : int, SeedSequence or None

    Returns
    -------
    TargetPoints
    """
    if n_points < 1:
        raise CamplaceError(f"points: need at least 1 point, got {n_points} (raise --points)")
    n_frames = len(instance.frames)
    per_frame = -(-n_points // n_frames)
    local_v = instance.target.vertices
    faces = instance.target.faces
    face_index, bary, local_p = sample_surface(local_v, faces, per_frame, seed=seed)
    local_n, _ = face_normals_areas(local_v, faces)
    local_n = local_n[face_index]
    fw = instance.frame_weights()
    pos, nrm, frm, wts = [], [], [], []
    for f, frame in enumerate(instance.frames):
        em = frame.emitters
        em_w = em.weights if em is not None else np.empty(0)
        total = frame.target_weight + float(em_w.sum())
        if total <= 0:
            total = 1.0
        if frame.target_weight > 0:
            rot = frame.target_pose.rotation()
            pos.append(frame.target_pose.apply(local_p))
            nrm.append(local_n @ rot.T)
            frm.append(np.full(per_frame, f, dtype=np.int32))
            wts.append(np.full(per_frame, fw[f] * frame.target_weight / (total * per_frame)))
        if em is not None:
            pos.append(np.asarray(em.positions_m, dtype=np.float64))
            nrm.append(np.zeros((len(em), 3)))
            frm.append(np.full(len(em), f, dtype=np.int32))
            wts.append(fw[f] * em_w / total)
    return TargetPoints(
        positions=np.concatenate(pos), normals=np.concatenate(nrm), frame=np.concatenate(frm), weight=np.concatenate(wts)
    )
