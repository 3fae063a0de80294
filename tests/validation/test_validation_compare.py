"""Comparison statistics against closed forms: mask metrics, KDE overlap, rank correlation, report I/O."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from camplace.validation.compare import (
    ValidationReport,
    across_systems,
    agreement,
    difference_matrix,
    heatmap_image,
    kde_image,
    kde_overlap,
    mask_metrics,
    rank_correlation,
    system_scores,
    target_metrics,
)


def test_mask_metrics_by_hand() -> None:
    p = np.zeros((10, 10), bool)
    d = np.zeros((10, 10), bool)
    p[0:4, 0:5] = True  # 20 px
    d[2:6, 0:5] = True  # 20 px, 10 shared
    m = mask_metrics(p, d)
    assert m == {"predicted_px": 20, "detected_px": 20, "intersection_px": 10, "iou": 10 / 30, "inside_fraction": 0.5, "area_ratio": 1.0}
    empty = mask_metrics(np.zeros((3, 3), bool), np.zeros((3, 3), bool))
    assert empty["iou"] is None and empty["inside_fraction"] is None and empty["area_ratio"] is None


def test_target_metrics_by_hand() -> None:
    t = np.zeros((10, 10), bool)
    d = np.zeros((10, 10), bool)
    e = np.zeros((10, 10), bool)
    t[0:4, 0:5] = True  # 20 px target
    d[0:4, 0:10] = True  # 40 px detected (target and its shadow), 20 shared
    e[0:4, 0:8] = True  # 32 px expected, 20 shared
    m = target_metrics(t, d, e)
    assert m == {
        "target_px": 20, "target_intersection_px": 20, "iou_target": 0.5, "inside_fraction_target": 0.5, "area_ratio_target": 2.0,
        "perfect_iou_target": 20 / 32, "perfect_inside_fraction_target": 20 / 32,
    }


def test_agreement_by_hand() -> None:
    def rec(target_px, iou, inside, predicted_px=100, iou_t=0.5, inside_t=0.6, p_iou_t=0.7, p_inside_t=0.8):
        return {"target_px": target_px, "predicted_px": predicted_px, "iou": iou, "inside_fraction": inside, "iou_target": iou_t,
                "inside_fraction_target": inside_t, "perfect_iou_target": p_iou_t, "perfect_inside_fraction_target": p_inside_t}

    recs = [rec(600, 0.9, 0.95), rec(500, 0.7, 0.85, iou_t=0.3), rec(2000, 0.8, 1.0, iou_t=0.4, p_iou_t=0.9), rec(499, 0.0, 0.0), rec(800, None, None, 0, 0.0, None, 0.0, None)]
    g = agreement(recs)
    assert g["n_views"] == 4 and g["min_target_px"] == 500  # the 499 px view is left out
    lfl, tm = g["like_for_like"], g["target_mask"]
    assert lfl["iou_median"] == pytest.approx(0.8) and lfl["iou_min"] == pytest.approx(0.7) and lfl["n_undefined"] == 1
    assert lfl["inside_fraction_median"] == pytest.approx(0.95) and lfl["inside_fraction_min"] == pytest.approx(0.85)
    assert lfl["perfect_iou_median"] == 1.0 and lfl["iou_drop"] == pytest.approx(0.2) and lfl["inside_fraction_drop"] == pytest.approx(0.05)
    # nothing predicted nor detected on the 800 px view: IoU against the target 0, inside undefined
    assert tm["iou_median"] == pytest.approx(0.35) and tm["iou_min"] == 0.0 and tm["n_undefined"] == 0
    assert tm["perfect_iou_median"] == pytest.approx(0.7) and tm["iou_drop"] == pytest.approx(0.35)
    assert tm["inside_fraction_median"] == pytest.approx(0.6) and tm["inside_fraction_drop"] == pytest.approx(0.2)
    none = agreement(recs[3:4])
    assert none["n_views"] == 0 and none["like_for_like"]["iou_median"] is None and none["like_for_like"]["iou_drop"] is None


def test_kde_overlap_of_two_normals() -> None:
    rng = np.random.default_rng(0)
    n = 4000
    a, b = rng.normal(0, 1, n), rng.normal(1, 1, n)
    # Scott's bandwidth widens each density to variance 1 + n^(-2/5); overlap of N(0, v) and N(1, v) = 2 Phi(-1 / (2 sqrt v))
    v = 1 + n ** (-0.4)
    assert kde_overlap(a, b) == pytest.approx(2 * norm.cdf(-0.5 / math.sqrt(v)), abs=0.02)
    assert kde_overlap(a, a) == pytest.approx(1.0, abs=1e-6)
    assert kde_overlap(a, a + 50) < 1e-6
    assert kde_overlap([1.0], [1.0, 2.0]) is None and kde_overlap([1.0, 1.0], [1.0, 2.0]) is None


def test_rank_correlation() -> None:
    assert rank_correlation([1, 2, 3, 4], [10, 20, 30, 40])[0] == pytest.approx(1.0)
    assert rank_correlation([1, 2, 3, 4], [4, 3, 2, 1])[0] == pytest.approx(-1.0)
    # one swapped pair among 4: rho = 1 - 6 * 2 / (4 * 15) = 0.8
    assert rank_correlation([1, 2, 3, 4], [1, 3, 2, 4])[0] == pytest.approx(0.8)
    assert rank_correlation([1, 1, 1], [1, 2, 3]) == (None, None)


def test_system_scores_and_across() -> None:
    recs = []
    for s, (pp, dd) in enumerate([((100, 200), (90, 210)), ((400, 0), (380, 10)), ((50, 50), (60, 40))], start=1):
        for j, (a, b) in enumerate(zip(pp, dd)):
            recs.append({"system": s, "name": f"{s}.{j}", "width": 100, "height": 10, "predicted_px": a, "detected_px": b})
    systems = system_scores(recs)
    assert [s["score_predicted"] for s in systems] == pytest.approx([0.3, 0.4, 0.1])
    assert [s["score_photo"] for s in systems] == pytest.approx([0.3, 0.39, 0.1])
    across = across_systems(systems)
    assert across["spearman_rho"] == pytest.approx(1.0)
    assert across["best_system_predicted"] == 2 and across["best_system_photo"] == 2
    assert [s["normalised_predicted"] for s in systems] == pytest.approx([0.75, 1.0, 0.25])
    assert across["mean_difference"] == pytest.approx(np.mean([0.3 / 0.39 - 0.75, 0.0, 0.1 / 0.39 - 0.25]))
    assert 0 < across["kde_overlap_pct"] <= 100
    single = across_systems(system_scores(recs[:2]))
    assert single["kde_overlap_pct"] is None and single["spearman_rho"] is None and single["notes"]


def test_difference_matrix_and_figures() -> None:
    m = difference_matrix([0.1, 0.5], [0.2, 0.2, 0.9])
    np.testing.assert_allclose(m, [[0.1, 0.1, 0.8], [0.3, 0.3, 0.4]])
    img = heatmap_image(m, "test")
    assert img.dtype == np.uint8 and img.ndim == 3
    assert kde_image([0.1, 0.5, 0.9], [0.2, 0.4, 1.0]).shape == (360, 640, 3)


def test_report_save_load(tmp_path) -> None:
    r = ValidationReport(cameras=[{"name": "a", "iou": float("nan"), "x": np.float32(0.5)}], across={"kde_overlap_pct": 12.5}, figures=["f.png"],
                         agreement={"n_views": 1})
    r.save(tmp_path)
    back = ValidationReport.load(tmp_path)
    assert back.cameras == [{"name": "a", "iou": None, "x": 0.5}] and back.agreement == {"n_views": 1}
    assert back.across == {"kde_overlap_pct": 12.5} and back.figures == ["f.png"] and back.systems == []
