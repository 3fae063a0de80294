"""Embree scenes (embreex) built from world-space triangle meshes, and segment occlusion queries."""

from __future__ import annotations

import logging
import threading

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh


log = logging.getLogger(__name__)

_ONES: list[np.ndarray] = [np.ones(0, dtype=np.float32)]
_ONES_LOCK = threading.Lock()


def _ones32(n: int) -> np.ndarray:
    """(n,) float32 ones: a view of one module-wide array, grown as needed and never written
    after it is made (a fresh array per batch of segments costs a page fault every 4 KiB).
    Embree only reads it (``tests/visibility/test_kernels.py`` checks that it stays all ones)."""
    buf = _ONES[0]
    if len(buf) < n:
        with _ONES_LOCK:
            buf = _ONES[0]
            if len(buf) < n:
                buf = np.ones(max(n, 2 * len(buf)), dtype=np.float32)
                _ONES[0] = buf
    return buf[:n]


_UNBUILT = object()


def _packet_scene(triangles: np.ndarray):
    """An Embree scene for packet casts (:mod:`camplace.visibility._embree`), or None (embreex)."""
    from camplace.visibility._embree import PacketScene, packet_api

    api = packet_api()
    if api is None:
        return None
    try:
        return PacketScene(api, triangles)
    except RuntimeError as exc:  # pragma: no cover - an Embree that refuses the scene
        log.debug("%s: casting through embreex", exc)
        return None


class RayScene:
    """An Embree scene of triangle meshes for occlusion and first-hit queries.

    Embree works in float32; the exact float32 triangles cast against are kept in
    ``triangles`` (so ``scene.ply`` can be written exactly as ray-cast). Queries on one scene
    are thread-safe and release the GIL.

    Parameters
    ----------
    meshes : list of (vertices (n, 3) float64, faces (m, 3) int64)
        World-space meshes.
    """

    def __init__(self, meshes: list[tuple[np.ndarray, np.ndarray]]) -> None:
        tris = [np.asarray(v, dtype=np.float64)[np.asarray(f, dtype=np.int64)] for v, f in meshes if len(f)]
        self.triangles: np.ndarray = (
            np.concatenate(tris).astype(np.float32) if tris else np.empty((0, 3, 3), dtype=np.float32)
        )
        self._empty = len(self.triangles) == 0
        self._embreex = None  # embreex's scene: first hits, normalised occlusion, and the fallback
        self._packet = _UNBUILT  # the packet casts' scene (occluded_dir), None where there is none
        self._lock = threading.Lock()

    def packet_scene(self):
        """The Embree 4 scene that :meth:`occluded_dir` casts packets against
        (:class:`camplace.visibility._embree.PacketScene`: its ``api`` and ``handle`` let compiled
        code cast on it), built on first use; None where there is none (embreex casts)."""
        return self._packets

    @property
    def _packets(self):
        """The scene :meth:`occluded_dir` casts packets against, built on first use; None: embreex."""
        if self._packet is _UNBUILT:
            with self._lock:
                if self._packet is _UNBUILT:
                    self._packet = _packet_scene(self.triangles)
        return self._packet

    @property
    def _scene(self) -> rtcore_scene.EmbreeScene:
        """embreex's scene of the same triangles, built on first use (thread-safe)."""
        if self._embreex is None:
            with self._lock:
                if self._embreex is None:
                    scene = rtcore_scene.EmbreeScene()
                    TriangleMesh(scene, self.triangles)
                    self._embreex = scene
        return self._embreex

    @classmethod
    def from_triangles(cls, triangles: np.ndarray) -> "RayScene":
        """Scene of a float32 triangle soup (t, 3, 3), e.g. ``RayScene.triangles`` of another scene."""
        tri = np.asarray(triangles, dtype=np.float32).reshape(-1, 3, 3)
        n = len(tri)
        return cls([(tri.reshape(-1, 3).astype(np.float64), np.arange(3 * n, dtype=np.int64).reshape(n, 3))])

    def __len__(self) -> int:
        return int(self.triangles.shape[0])

    def occluded(self, origins: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """Whether each segment ``origins[i] -> ends[i]`` is blocked by a triangle.

        Parameters
        ----------
        origins : (n, 3) float
        ends : (n, 3) float

        Returns
        -------
        (n,) bool
            True where some triangle intersects the open segment.
        """
        n = len(origins)
        if n == 0 or self._empty:
            return np.zeros(n, dtype=bool)
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.asarray(ends, dtype=np.float64) - np.asarray(origins, dtype=np.float64)
        length = np.linalg.norm(d, axis=1)
        d = np.ascontiguousarray(d / np.maximum(length, 1e-30)[:, None], dtype=np.float32)
        # embreex OCCLUDED: -1 = nothing hit within [0, tfar], otherwise the geometry id (0)
        res = self._scene.run(o, d, dists=np.ascontiguousarray(length, dtype=np.float32), query="OCCLUDED")
        return np.asarray(res) != -1

    def occluded_dir(self, origins: np.ndarray, directions: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Whether each segment ``origins[i] + t * directions[i]``, t in [0, 1], is blocked.

        The fast path: float32 inputs are passed to Embree as they are (unnormalised directions,
        tfar = 1), with no per-ray normalisation.

        Parameters
        ----------
        origins : (n, 3) float32
        directions : (n, 3) float32
            Segment end minus origin.
        out : (n,) bool or None
            Where to write the answer (saves an allocation).

        Returns
        -------
        (n,) bool
        """
        n = len(origins)
        if out is None:
            out = np.empty(n, dtype=bool)
        if n == 0 or self._empty:
            out[:] = False
            return out
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        if self._packets is not None:
            from camplace.visibility._castkernels import occluded_packets

            api = self._packets.api
            done = out if out.flags.c_contiguous and out.dtype == np.bool_ else np.empty(n, dtype=bool)
            occluded_packets(np.uint64(api.occluded), np.uint64(self._packets.handle), api.width, o, d, done)
            if done is not out:
                out[:] = done
            return out
        res = self._scene.run(o, d, dists=_ones32(n), query="OCCLUDED")
        return np.not_equal(res, -1, out=out)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest hit along rays.

        Parameters
        ----------
        origins : (n, 3) float
        directions : (n, 3) float
            Need not be normalised; distances are in units of their length.

        Returns
        -------
        triangle : (n,) int64
            Index into ``triangles`` (-1 for a miss).
        distance : (n,) float64
            Ray parameter of the hit (inf for a miss).
        """
        n = len(origins)
        if n == 0 or self._empty:
            return np.full(n, -1, dtype=np.int64), np.full(n, np.inf)
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        out = self._scene.run(o, d, output=1)
        prim = np.asarray(out["primID"]).astype(np.int64)
        tfar = np.asarray(out["tfar"]).astype(np.float64)
        hit = np.asarray(out["geomID"]) != -1
        prim[~hit] = -1
        tfar[~hit] = np.inf
        return prim, tfar
