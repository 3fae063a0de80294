"""Visibility: which target points each candidate camera observes (Embree ray casting).

Everything is imported lazily (PEP 562): ``import camplace.visibility.store`` (the matrix files)
loads neither Embree nor the engine's compiled kernels.
"""

from __future__ import annotations

from camplace._lazy import lazy_getattr

_LAZY = {
    "RayScene": "camplace.visibility.raycast",
    "TargetPoints": "camplace.visibility.points",
    "VisibilityMatrix": "camplace.visibility.engine",
    "compute_visibility": "camplace.visibility.engine",
    "frame_scene": "camplace.visibility.engine",
    "make_target_points": "camplace.visibility.points",
    "sample_surface": "camplace.visibility.points",
    "write_ply": "camplace.visibility.ply",
    "load_visibility": "camplace.visibility.store",
    "save_visibility": "camplace.visibility.store",
    "convert_matrix": "camplace.visibility.store",
}

__all__ = sorted(_LAZY)

__getattr__ = lazy_getattr(__name__, _LAZY)
