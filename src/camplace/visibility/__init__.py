"""Visibility: which target points each candidate camera observes (Embree ray casting)."""

from camplace.visibility.engine import VisibilityMatrix, compute_visibility, frame_scene
from camplace.visibility.points import TargetPoints, make_target_points, sample_surface
from camplace.visibility.ply import write_ply
from camplace.visibility.raycast import RayScene

__all__ = [
    "RayScene",
    "TargetPoints",
    "VisibilityMatrix",
    "compute_visibility",
    "frame_scene",
    "make_target_points",
    "sample_surface",
    "write_ply",
]
