"""The ``scene.ply`` file: the float32 triangle soup exactly as ray-cast (encoded by :func:`camplace.geometry.ply_bytes`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camplace._io import write_bytes_atomic
from camplace.geometry import triangle_soup_ply_bytes


def write_ply(path: str | Path, triangles: np.ndarray) -> None:
    """Write a triangle soup ``triangles`` (m, 3, 3) float32 as binary PLY atomically."""
    write_bytes_atomic(path, triangle_soup_ply_bytes(triangles, "camplace scene (world frame, metres)"))
