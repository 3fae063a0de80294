"""Validation: render what the chosen cameras should see, photograph it (real or emulated), detect the
target, compare, import calibrated cameras, and export placements in lab coordinates.

Everything is imported lazily (``import camplace.validation`` loads neither OpenCV nor Embree)::

    from camplace.validation import render_view, detect_target, PhysicalCamera, umeyama
"""

from __future__ import annotations

from camplace._lazy import lazy_getattr

_LAZY = {
    # cameras
    "CameraView": "camplace.validation.cameras",
    "CameraSet": "camplace.validation.cameras",
    "import_cameras": "camplace.validation.camera_io",
    "read_middlebury": "camplace.validation.camera_io",
    "read_colmap": "camplace.validation.camera_io",
    "read_opencv_cameras": "camplace.validation.camera_io",
    "write_opencv_cameras": "camplace.validation.camera_io",
    # render
    "RenderSettings": "camplace.validation.render",
    "RenderScene": "camplace.validation.render",
    "RenderResult": "camplace.validation.render",
    "GlowEmitters": "camplace.validation.render",
    "render_view": "camplace.validation.render",
    "scene_for_frame": "camplace.validation.render",
    "target_scene": "camplace.validation.render",
    "write_png": "camplace.validation.render",
    "read_image": "camplace.validation.render",
    # physical camera
    "PhysicalCamera": "camplace.validation.physical",
    "parse_physical": "camplace.validation.physical",
    "emulate_shots": "camplace.validation.physical",
    "EmulatedShot": "camplace.validation.physical",
    # detection
    "Detection": "camplace.validation.detect",
    "DetectionSettings": "camplace.validation.detect",
    "detect_target": "camplace.validation.detect",
    "expected_detection": "camplace.validation.detect",
    # comparison
    "ValidationReport": "camplace.validation.compare",
    "mask_metrics": "camplace.validation.compare",
    "kde_overlap": "camplace.validation.compare",
    "rank_correlation": "camplace.validation.compare",
    # transform
    "TransformConfig": "camplace.validation.transform",
    "PlacementTransform": "camplace.validation.transform",
    "parse_transform": "camplace.validation.transform",
    "build_transform": "camplace.validation.transform",
    "umeyama": "camplace.validation.transform",
    # workflow
    "render_run": "camplace.validation.workflow",
    "validate_runs": "camplace.validation.workflow",
    "validate_cameras": "camplace.validation.workflow",
    "export_run": "camplace.validation.workflow",
    "parse_target": "camplace.validation.workflow",
    "read_manifest": "camplace.validation.workflow",
}

__all__ = sorted(_LAZY)


__getattr__ = lazy_getattr(__name__, _LAZY)
