"""Minimal binary PLY writer for triangle soups (exactly the float32 triangles that were ray-cast)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camplace._io import write_bytes_atomic


def ply_bytes(triangles: np.ndarray) -> bytes:
    """Binary little-endian PLY of a triangle soup.

    Parameters
    ----------
    triangles : (m, 3, 3) float32
        Vertex coordinates per triangle (each triangle gets its own 3 vertices).

    Returns
    -------
    bytes
    """
    tri = np.ascontiguousarray(triangles, dtype="<f4").reshape(-1, 3)
    m = len(tri) // 3
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment camplace scene (world frame, metres)\n"
        f"element vertex {len(tri)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {m}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode("ascii")
    faces = np.empty(m, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = np.arange(3 * m, dtype=np.int32).reshape(m, 3)
    return header + tri.tobytes() + faces.tobytes()


def write_ply(path: str | Path, triangles: np.ndarray) -> None:
    """Write a triangle soup as binary PLY atomically."""
    write_bytes_atomic(path, ply_bytes(triangles))
