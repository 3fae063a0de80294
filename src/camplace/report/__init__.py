"""Campaigns of random camera systems, the HTML report and camera exports.

Everything is imported lazily (``import camplace.report`` loads neither matplotlib nor Embree)::

    from camplace.report import run_campaign, write_report, run_report_bundle, export_cameras
"""

from __future__ import annotations

from camplace._lazy import lazy_getattr

_LAZY = {
    # campaigns
    "Campaign": "camplace.report.campaign",
    "run_campaign": "camplace.report.campaign",
    "score_systems": "camplace.report.campaign",
    "problem_fingerprint": "camplace.report.campaign",
    "find_campaigns": "camplace.report.campaign",
    "campaign_seed": "camplace.report.campaign",
    # legacy score
    "LegacyTarget": "camplace.report.legacy",
    "legacy_target": "camplace.report.legacy",
    "legacy_camera_scores": "camplace.report.legacy",
    "legacy_system_score": "camplace.report.legacy",
    "printed_fov": "camplace.report.legacy",
    "corrected_fov_rad": "camplace.report.legacy",
    # comparison
    "RunData": "camplace.report.compare",
    "load_run_data": "camplace.report.compare",
    "Comparison": "camplace.report.compare",
    "compare_with_campaigns": "camplace.report.compare",
    # sampler study
    "SamplerStudy": "camplace.report.study",
    "sampler_study": "camplace.report.study",
    "default_ladder": "camplace.report.study",
    # vision cones
    "ConeGrid": "camplace.report.cones",
    "cone_grid": "camplace.report.cones",
    "cone_density": "camplace.report.cones",
    # report
    "write_report": "camplace.report.build",
    "run_report_bundle": "camplace.report.build",
    # export
    "EXPORT_FORMATS": "camplace.report.export",
    "export_cameras": "camplace.report.export",
    "write_colmap": "camplace.report.export",
    "rotation_to_quaternion": "camplace.report.export",
    "colmap_pose": "camplace.report.export",
    "frustum_mesh": "camplace.report.export",
    "glb_bytes": "camplace.report.export",
}

__all__ = sorted(_LAZY)


__getattr__ = lazy_getattr(__name__, _LAZY)
