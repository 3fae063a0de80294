"""Detection (thesis Algorithm 3) on synthetic images with known blobs."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from camplace.errors import CamplaceError
from camplace.validation.detect import Detection, DetectionSettings, detect_target, parse_threshold


def test_rectangle_on_black_threshold_alone() -> None:
    img = np.zeros((120, 160), np.uint8)
    img[30:60, 50:90] = 200  # rows 30..59, columns 50..89
    det = detect_target(img, None, DetectionSettings(morph_kernel_px=0))
    assert det.bbox_xywh == (50, 30, 40, 30)
    assert det.area_px == 40 * 30
    assert det.mean_intensity == pytest.approx(200 / 255)
    assert det.n_contours == 1


def test_disc_with_speckle_and_textured_background() -> None:
    rng = np.random.default_rng(3)
    bg = rng.uniform(0.2, 0.6, (240, 320, 3)).astype(np.float32)  # textured colour background
    img = bg.copy()
    disc = np.zeros((240, 320), np.uint8)
    cv2.circle(disc, (170, 110), 40, 1, thickness=-1)
    img[disc.astype(bool)] = (0.95, 0.9, 0.85)
    # salt noise the opening must remove
    ys, xs = rng.integers(0, 240, 40), rng.integers(0, 320, 40)
    img[ys, xs] = 1.0
    det = detect_target(img, bg)
    known_area = int(disc.sum())
    x, y, w, h = cv2.boundingRect(disc)
    assert det.n_contours == 1
    assert det.bbox_xywh is not None
    # the opening may shave the one-pixel nubs a rasterised circle has at its extremes: at most
    # the kernel radius (2 px) per side
    assert np.abs(np.array(det.bbox_xywh) - np.array([x, y, w, h])).max() <= 2
    assert det.area_px == pytest.approx(known_area, rel=0.01)
    gray_disc = 0.114 * 0.95 + 0.587 * 0.9 + 0.299 * 0.85  # OpenCV BGR -> gray weights
    assert det.mean_intensity == pytest.approx(gray_disc, abs=0.01)


def test_sixteen_bit_and_fixed_threshold() -> None:
    img = np.full((100, 100), 1000, np.uint16)
    img[10:20, 10:40] = 60000
    img[70:80, 70:75] = 20000  # dimmer blob: normalised level ~ 73
    both = detect_target(img, None, DetectionSettings(threshold=50.0, morph_kernel_px=0))
    bright = detect_target(img, None, DetectionSettings(threshold=100.0, morph_kernel_px=0))
    assert both.area_px == 300 + 50 and both.n_contours == 2 and both.bbox_xywh == (10, 10, 65, 70)
    assert bright.area_px == 300 and bright.bbox_xywh == (10, 10, 30, 10)
    largest = detect_target(img, None, DetectionSettings(threshold=50.0, morph_kernel_px=0, largest_component=True))
    assert largest.area_px == 300


def test_empty_and_flat_images_detect_nothing() -> None:
    det = detect_target(np.zeros((10, 10), np.uint8))
    assert det.area_px == 0 and det.bbox_xywh is None and det.mean_intensity == 0.0


def test_detection_save_load(tmp_path) -> None:
    img = np.zeros((50, 60), np.uint8)
    img[5:15, 20:30] = 255
    det = detect_target(img, None, DetectionSettings(morph_kernel_px=0))
    det.save(tmp_path / "d.npz")
    back = Detection.load(tmp_path / "d.npz")
    np.testing.assert_array_equal(back.mask, det.mask)
    assert back.to_dict() == det.to_dict()


def test_threshold_parsing() -> None:
    assert parse_threshold("OTSU") == "otsu" and parse_threshold("40") == 40.0
    with pytest.raises(CamplaceError, match="--threshold"):
        parse_threshold("300")
    with pytest.raises(CamplaceError, match="--threshold"):
        parse_threshold("mean")
    with pytest.raises(CamplaceError, match="background image"):
        detect_target(np.zeros((10, 10)), np.zeros((10, 12)))
