"""Top-view vision-cone density (the thesis's Figure 7.18).

Each camera's horizontal field of view is drawn as a 2D wedge in the x-y plane: apex at the camera,
axis along the horizontal heading of its optical axis (the x-y part of the rotation's third column),
half-angle ``fov_x / 2`` (the instance camera's horizontal field of view) and radius ``range_m``
(default: the camera's far limit). The density of a grid cell is the number of wedges that contain
its centre. The wedge ignores the camera's pitch (a tilted camera's footprint on a horizontal
plane is wider and shorter than its wedge), as the thesis's figure does; a camera looking straight
up or down has no heading and adds nothing.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ConeGrid", "cone_grid", "cone_density"]


class ConeGrid:
    """Cell centres of an x-y grid over a box.

    Parameters
    ----------
    min_xy, max_xy : (2,) float64
        Box corners, metres.
    cells : int
        Cells along the longer side (the other side gets the same cell size).

    Attributes
    ----------
    x, y : (nx,), (ny,) float64
        Cell-centre coordinates.
    extent : tuple of float
        (xmin, xmax, ymin, ymax) for plotting.
    """

    def __init__(self, min_xy, max_xy, cells: int = 400) -> None:
        lo = np.asarray(min_xy, dtype=np.float64)[:2]
        hi = np.asarray(max_xy, dtype=np.float64)[:2]
        size = hi - lo
        cell = float(size.max()) / max(1, int(cells))
        nx, ny = (max(1, int(math.ceil(s / cell - 1e-9))) for s in size)
        self.x = lo[0] + (np.arange(nx) + 0.5) * size[0] / nx
        self.y = lo[1] + (np.arange(ny) + 0.5) * size[1] / ny
        self.extent = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))


def cone_grid(instance, cells: int = 400) -> ConeGrid:
    """The grid over the instance's camera volume (top view)."""
    return ConeGrid(instance.volume.min_m, instance.volume.max_m, cells)


def cone_density(positions_m: np.ndarray, rotations: np.ndarray, fov_x_rad: float, range_m: float, grid: ConeGrid) -> np.ndarray:
    """Number of cameras whose horizontal FoV wedge covers each grid cell.

    Parameters
    ----------
    positions_m : (k, 3) float64
    rotations : (k, 3, 3) float64
        World-from-camera (OpenCV axes: the third column is the optical axis).
    fov_x_rad : float
        Full horizontal field of view.
    range_m : float
        Wedge radius.
    grid : ConeGrid

    Returns
    -------
    (ny, nx) int32
    """
    X, Y = np.meshgrid(grid.x, grid.y)
    out = np.zeros(X.shape, dtype=np.int32)
    cos_half = math.cos(fov_x_rad / 2.0)
    for p, R in zip(np.asarray(positions_m, dtype=np.float64), np.asarray(rotations, dtype=np.float64)):
        fwd = R[:2, 2]
        n = float(np.hypot(*fwd))
        if n < 1e-9:
            continue
        fwd = fwd / n
        dx, dy = X - p[0], Y - p[1]
        dist = np.hypot(dx, dy)
        with np.errstate(invalid="ignore", divide="ignore"):
            cosang = (dx * fwd[0] + dy * fwd[1]) / dist
        inside = (dist <= range_m) & ((cosang >= cos_half) | (dist == 0))
        out += inside.astype(np.int32)
    return out
