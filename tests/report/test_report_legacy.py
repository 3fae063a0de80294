"""The thesis's Algorithm 2 ("legacy" score): literal formulas against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from camplace.instance import builtin
from camplace.report.legacy import (
    LegacyTarget,
    corrected_fov_rad,
    legacy_camera_scores,
    legacy_system_score,
    legacy_target,
    printed_fov,
)

# A tiny configuration computed by hand:
#   sensorsize = 2 mm, focallength = 0.5 mm -> sensorsize / 2 * focallength = 1 * 0.5 = 0.5
#   fov = 2 * arctan(0.5) + 0 = 0.9272952180016122 ; fov * 2 = 1.8545904360032244
#   target: x_t = 2, y_t = 0.5, W = 1, H = 3 (box [2, 3] x [0.5, 3.5])
#   camera A at (1, 1):
#     d = sqrt(1^2 + 0.5^2) = 1.118033988749895
#     x box [-0.85459, 2.85459] -> x_overlap = 2.85459 - 2 = 0.8545904360032246
#     y box [-0.85459, 2.85459] -> y_overlap = 2.85459 - 0.5 = 2.3545904360032246
#     a = 0.85459... * 2.35459... = 2.0122104673130186 ; delta = 3.1302444560629135
#   camera B at (10, 10): x box [8.145, 11.855] misses [2, 3] -> a = 0 ; delta = d = sqrt(8^2 + 9.5^2) = 12.419742348374221
#   system score = 3.1302444560629135 + 12.419742348374221 = 15.549986804437134
TINY = LegacyTarget(x_t_m=2.0, y_t_m=0.5, width_m=1.0, height_m=3.0, sensor_size_mm=2.0, focal_length_mm=0.5, omega=0.0)


def test_printed_fov_keeps_the_published_operator_precedence() -> None:
    assert printed_fov(2.0, 0.5) == pytest.approx(0.9272952180016122, rel=1e-15)
    # (7.18 / 2) * 8 = 28.72, not 7.18 / (2 * 8)
    assert printed_fov(7.18, 8.0) == pytest.approx(2 * math.atan(28.72), rel=1e-15)
    assert math.degrees(printed_fov(7.18, 8.0)) == pytest.approx(176.0, abs=0.1)
    # omega is added as given (no unit conversion)
    assert printed_fov(2.0, 0.5, omega=30.0) == pytest.approx(0.9272952180016122 + 30.0, rel=1e-15)


def test_corrected_fov_is_the_pinhole_field_of_view() -> None:
    cam = builtin("comet-67p-bunker").camera
    assert corrected_fov_rad(cam.sensor_width_mm, cam.focal_length_mm) == pytest.approx(math.radians(cam.fov_x_deg), rel=1e-14)
    assert math.degrees(corrected_fov_rad(7.18, 8.0)) == pytest.approx(48.3, abs=0.05)


def test_legacy_matches_hand_computed_values() -> None:
    s = legacy_camera_scores(np.array([[1.0, 1.0, 7.0], [10.0, 10.0, -3.0]]), TINY)
    np.testing.assert_allclose(s["distance"], [1.118033988749895, 12.419742348374221], rtol=1e-14)
    np.testing.assert_allclose(s["x_overlap"], [0.8545904360032246, 0.0], rtol=1e-14, atol=0)
    np.testing.assert_allclose(s["y_overlap"], [2.3545904360032246, 0.0], rtol=1e-14, atol=0)
    np.testing.assert_allclose(s["area"], [2.0122104673130186, 0.0], rtol=1e-14, atol=0)
    np.testing.assert_allclose(s["delta"], [3.1302444560629135, 12.419742348374221], rtol=1e-14)
    sys_score = legacy_system_score(np.array([[[1.0, 1.0, 0.0], [10.0, 10.0, 0.0]]]), TINY)
    assert sys_score.shape == (1,)
    assert sys_score[0] == pytest.approx(15.549986804437134, rel=1e-14)


def test_height_is_ignored_and_score_grows_with_distance() -> None:
    a = legacy_camera_scores(np.array([[1.0, 1.0, 0.0]]), TINY)["delta"]
    b = legacy_camera_scores(np.array([[1.0, 1.0, 100.0]]), TINY)["delta"]
    assert a[0] == b[0]
    # both boxes hold the whole target (a = W * H = 3): the farther camera scores higher
    near = legacy_camera_scores(np.array([[2.5, 2.0]]), TINY)
    far = legacy_camera_scores(np.array([[3.5, 2.0]]), TINY)
    assert near["area"][0] == pytest.approx(3.0, rel=1e-15) and far["area"][0] == pytest.approx(3.0, rel=1e-15)
    assert far["delta"][0] > near["delta"][0]


def test_legacy_target_of_an_instance_is_the_target_top_view_box() -> None:
    inst = builtin("comet-67p-bunker")
    t = legacy_target(inst, omega=0.25)
    v, _ = inst.target_world(0)
    assert t.x_t_m == pytest.approx(v[:, 0].min()) and t.y_t_m == pytest.approx(v[:, 1].min())
    assert t.width_m == pytest.approx(np.ptp(v[:, 0])) and t.height_m == pytest.approx(np.ptp(v[:, 1]))
    assert t.sensor_size_mm == inst.camera.sensor_width_mm and t.focal_length_mm == inst.camera.focal_length_mm
    assert t.omega == 0.25
    assert LegacyTarget.from_dict(t.to_dict()) == t
