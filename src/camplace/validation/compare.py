"""Prediction against photographs: per camera, per system and across systems (``validation.json``).

Per camera, the detected mask D is :func:`detect_target` on the photo and two masks are predicted:

* the **prediction** P (like for like): the same detection run on the render, against the
  background render when the photo has a background photograph (:func:`expected_detection`) - what
  a perfect camera would detect, cast shadow, unlit faces and threshold splits included. A perfect
  camera scores ``iou = inside_fraction = 1``;
* the **target mask** T: the render's target pixels (the target alone, no shadow), a second figure.

``iou`` = |P & D| / |P | D|; ``inside_fraction`` = |P & D| / |D| (share of detected pixels the
prediction explains); ``area_ratio`` = |D| / |P|; the same against T are ``iou_target``,
``inside_fraction_target``, ``area_ratio_target``, and ``perfect_iou_target`` /
``perfect_inside_fraction_target`` are what a perfect camera scores against T (P in place of D).
``intensity_difference`` = mean photo gray level over D - mean render level over P ([0, 1] units).
:func:`agreement` gathers their medians and minima over the views where the target covers at least
``min_target_px`` pixels, with the drop from a perfect camera's values.

Per system (the cameras of one solution), a score from the prediction and one from the photos:
``score = sum over its cameras of predicted (detected) pixels / image pixels`` (the coverage the
system gets of the target, in images; ``score_target`` from the target masks). Across systems
(thesis section 7.3) the scores are normalised by their
maximum, then compared by the overlap of their Gaussian KDEs (``integral of min(f, g)``, percent),
the mean difference (photo - predicted) and Spearman's rank correlation. The camera x camera
heatmaps hold ``|value_predicted[i] - value_photo[j]|`` for the mean intensity and the coverage
fraction (rows: predicted, columns: photographed), as the thesis's figures 7.16/7.17 do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace._io import read_json, write_json_atomic
from camplace.errors import CamplaceError

__all__ = [
    "mask_metrics",
    "target_metrics",
    "agreement",
    "MIN_TARGET_PX",
    "kde_overlap",
    "rank_correlation",
    "system_scores",
    "across_systems",
    "difference_matrix",
    "ValidationReport",
    "heatmap_image",
    "kde_image",
    "overlay_image",
]


def mask_metrics(predicted: np.ndarray, detected: np.ndarray) -> dict[str, Any]:
    """Agreement of a predicted and a detected mask.

    Parameters
    ----------
    predicted, detected : (h, w) bool

    Returns
    -------
    dict
        predicted_px, detected_px, intersection_px, iou, inside_fraction, area_ratio
        (ratios are None when their denominator is 0).
    """
    p = np.asarray(predicted, dtype=bool)
    d = np.asarray(detected, dtype=bool)
    if p.shape != d.shape:
        raise CamplaceError(f"predicted mask is {p.shape[1]}x{p.shape[0]} but the photo is {d.shape[1]}x{d.shape[0]} (the camera's width/height must match its photo)")
    inter = int(np.count_nonzero(p & d))
    union = int(np.count_nonzero(p | d))
    np_, nd = int(np.count_nonzero(p)), int(np.count_nonzero(d))
    return {
        "predicted_px": np_,
        "detected_px": nd,
        "intersection_px": inter,
        "iou": inter / union if union else None,
        "inside_fraction": inter / nd if nd else None,
        "area_ratio": nd / np_ if np_ else None,
    }


def target_metrics(target: np.ndarray, detected: np.ndarray, expected: np.ndarray) -> dict[str, Any]:
    """The second figure: the detected mask, and a perfect camera's (``expected``), against the target mask.

    Parameters
    ----------
    target : (h, w) bool
        The ray-cast target mask (the target alone).
    detected : (h, w) bool
        Detection in the photograph.
    expected : (h, w) bool
        Detection in the render (:func:`camplace.validation.detect.expected_detection`).

    Returns
    -------
    dict
        target_px, target_intersection_px, iou_target, inside_fraction_target, area_ratio_target,
        perfect_iou_target, perfect_inside_fraction_target (None when a denominator is 0).
    """
    m = mask_metrics(target, detected)
    e = mask_metrics(target, expected)
    return {
        "target_px": m["predicted_px"],
        "target_intersection_px": m["intersection_px"],
        "iou_target": m["iou"],
        "inside_fraction_target": m["inside_fraction"],
        "area_ratio_target": m["area_ratio"],
        "perfect_iou_target": e["iou"],
        "perfect_inside_fraction_target": e["inside_fraction"],
    }


MIN_TARGET_PX = 500


def _median_min(values: Sequence[float | None]) -> tuple[float | None, float | None, int]:
    v = [float(x) for x in values if x is not None]
    if not v:
        return None, None, len(values)
    return float(np.median(v)), float(min(v)), len(values) - len(v)


def agreement(cameras: Sequence[dict[str, Any]], min_target_px: int = MIN_TARGET_PX) -> dict[str, Any]:
    """Medians and minima of both figures over the views where the target covers >= ``min_target_px`` pixels.

    Parameters
    ----------
    cameras : list of dict
        Per-camera records (``iou``, ``inside_fraction``, ``predicted_px``, ``target_px``,
        ``iou_target``, ``inside_fraction_target``, ``perfect_iou_target``, ``perfect_inside_fraction_target``).
    min_target_px : int

    Returns
    -------
    dict
        ``min_target_px``, ``n_views``, and per figure (``like_for_like``: against the prediction;
        ``target_mask``: against the target mask) ``{iou,inside_fraction}_{median,min}``, a perfect
        camera's medians ``perfect_{iou,inside_fraction}_median`` (1 like for like, by construction,
        where the prediction is not empty), the drops ``{iou,inside_fraction}_drop`` (perfect median
        - median) and ``n_undefined`` (views where IoU is undefined: nothing predicted nor detected).
    """
    views = [c for c in cameras if (c.get("target_px") if c.get("target_px") is not None else c.get("predicted_px", 0)) >= min_target_px]
    out: dict[str, Any] = {"min_target_px": int(min_target_px), "n_views": len(views)}
    figures = {
        "like_for_like": ("iou", "inside_fraction", lambda c: 1.0 if c.get("predicted_px") else None, lambda c: 1.0 if c.get("predicted_px") else None),
        "target_mask": ("iou_target", "inside_fraction_target", lambda c: c.get("perfect_iou_target"), lambda c: c.get("perfect_inside_fraction_target")),
    }
    for fig, (k_iou, k_in, perfect_iou, perfect_in) in figures.items():
        iou_med, iou_min, undefined = _median_min([c.get(k_iou) for c in views])
        in_med, in_min, _ = _median_min([c.get(k_in) for c in views])
        p_iou, _, _ = _median_min([perfect_iou(c) for c in views])
        p_in, _, _ = _median_min([perfect_in(c) for c in views])
        out[fig] = {
            "iou_median": iou_med,
            "iou_min": iou_min,
            "inside_fraction_median": in_med,
            "inside_fraction_min": in_min,
            "perfect_iou_median": p_iou,
            "perfect_inside_fraction_median": p_in,
            "iou_drop": None if iou_med is None or p_iou is None else p_iou - iou_med,
            "inside_fraction_drop": None if in_med is None or p_in is None else p_in - in_med,
            "n_undefined": undefined,
        }
    return out


_trapezoid = getattr(np, "trapezoid", None) or np.trapz  # numpy < 2 has only trapz


def kde_overlap(a: Sequence[float], b: Sequence[float], grid_points: int = 4096) -> float | None:
    """Overlap of the Gaussian KDEs of two samples: the integral of min(f_a, f_b), in [0, 1].

    Parameters
    ----------
    a, b : (n,) float
        At least two values each, not all equal (else None: a KDE needs a spread).

    Returns
    -------
    float or None
    """
    from scipy.stats import gaussian_kde

    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if len(a) < 2 or len(b) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    fa, fb = gaussian_kde(a), gaussian_kde(b)
    bw = max(math.sqrt(float(fa.covariance[0, 0])), math.sqrt(float(fb.covariance[0, 0])))
    lo = min(a.min(), b.min()) - 6 * bw
    hi = max(a.max(), b.max()) + 6 * bw
    x = np.linspace(lo, hi, grid_points)
    return float(min(1.0, _trapezoid(np.minimum(fa(x), fb(x)), x)))


def rank_correlation(a: Sequence[float], b: Sequence[float]) -> tuple[float | None, float | None]:
    """Spearman's rho and its p-value (None when undefined: fewer than 2 values or a constant sample)."""
    from scipy.stats import spearmanr

    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if len(a) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None, None
    res = spearmanr(a, b)
    rho, p = float(res.statistic), float(res.pvalue)
    return (rho if math.isfinite(rho) else None), (p if math.isfinite(p) else None)


def system_scores(cameras: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per system: its cameras, the predicted and photographed scores (sum of coverage fractions).

    Parameters
    ----------
    cameras : list of dict
        Per-camera records with ``system``, ``name``, ``width``, ``height``, ``predicted_px``, ``detected_px``
        (and ``target_px``: then ``score_target`` too).
    """
    systems: dict[int, list[dict]] = {}
    for rec in cameras:
        systems.setdefault(int(rec["system"]), []).append(rec)
    out = []
    for s in sorted(systems):
        recs = systems[s]
        pred = sum(r["predicted_px"] / (r["width"] * r["height"]) for r in recs)
        phot = sum(r["detected_px"] / (r["width"] * r["height"]) for r in recs if r.get("detected_px") is not None)
        entry = {"system": s, "cameras": [r["name"] for r in recs], "score_predicted": pred, "score_photo": phot}
        if all(r.get("target_px") is not None for r in recs):
            entry["score_target"] = sum(r["target_px"] / (r["width"] * r["height"]) for r in recs)
        out.append(entry)
    return out


def across_systems(systems: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """KDE overlap (%), mean difference and Spearman correlation of normalised system scores.

    Normalised scores (score / max over systems) are also written back into each system's dict.
    """
    pred = np.array([s["score_predicted"] for s in systems], dtype=np.float64)
    phot = np.array([s["score_photo"] for s in systems], dtype=np.float64)
    npred = pred / pred.max() if len(pred) and pred.max() > 0 else np.zeros_like(pred)
    nphot = phot / phot.max() if len(phot) and phot.max() > 0 else np.zeros_like(phot)
    for s, a, b in zip(systems, npred, nphot):
        s["normalised_predicted"] = float(a)
        s["normalised_photo"] = float(b)
    overlap = kde_overlap(npred, nphot)
    rho, p = rank_correlation(pred, phot)
    notes = []
    if overlap is None:
        notes.append("KDE overlap needs >= 2 systems whose scores differ (run validate with more OUTDIRs or --random-systems)")
    if rho is None:
        notes.append("Spearman correlation needs >= 2 systems with non-constant scores")
    return {
        "n_systems": len(systems),
        "kde_overlap_pct": None if overlap is None else 100.0 * overlap,
        "mean_difference": float(np.mean(nphot - npred)) if len(systems) else None,
        "spearman_rho": rho,
        "spearman_p": p,
        "best_system_predicted": int(systems[int(np.argmax(pred))]["system"]) if len(systems) else None,
        "best_system_photo": int(systems[int(np.argmax(phot))]["system"]) if len(systems) else None,
        "notes": notes,
    }


def difference_matrix(predicted: Sequence[float], photo: Sequence[float]) -> np.ndarray:
    """(n, m) float64 ``|predicted[i] - photo[j]|`` (rows: predicted cameras, columns: photographed)."""
    a = np.asarray(predicted, dtype=np.float64)
    b = np.asarray(photo, dtype=np.float64)
    return np.abs(a[:, None] - b[None, :])


def _clean(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars to Python, NaN/inf to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


@dataclass(frozen=True, eq=False)
class ValidationReport:
    """The content of ``validation.json``.

    Attributes
    ----------
    cameras : list of dict
        Per camera: name, system, photo, background, width, height; against the prediction (Algorithm 3
        on the render): predicted_px, detected_px, intersection_px, iou, inside_fraction, area_ratio;
        against the target mask: target_px, target_intersection_px, iou_target, inside_fraction_target,
        area_ratio_target, perfect_iou_target, perfect_inside_fraction_target; predicted_intensity,
        target_intensity, detected_intensity, intensity_difference, bbox_xywh, threshold, and (emulated
        photos) pose_error_m, pose_error_deg.
    systems : list of dict
        Per system: cameras, score_predicted, score_photo, score_target, normalised_predicted, normalised_photo.
    across : dict
        n_systems, kde_overlap_pct, mean_difference, spearman_rho, spearman_p, best systems, notes.
    heatmaps : dict
        ``intensity_difference`` and ``coverage_difference`` matrices (rows predicted, columns photo)
        and ``labels`` (camera names, same order for both axes).
    settings : dict
        How it was made: mode, photos source, detection settings, physical camera, seed, frame.
    figures : list of str
        PNG files written beside ``validation.json``.
    agreement : dict
        Both figures' medians, minima and drops from a perfect camera (see :func:`agreement`).
    installed : dict
        Emulated photographs: every system's run objective at its installed poses and its photo
        figure over the installations, and which system keeps more
        (:meth:`camplace.validation.installed.InstalledSystems.finish`).
    """

    cameras: list = field(default_factory=list)
    systems: list = field(default_factory=list)
    across: dict = field(default_factory=dict)
    heatmaps: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    figures: list = field(default_factory=list)
    agreement: dict = field(default_factory=dict)
    installed: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return _clean(
            {
                "cameras": self.cameras,
                "systems": self.systems,
                "across": self.across,
                "heatmaps": self.heatmaps,
                "settings": self.settings,
                "figures": self.figures,
                "agreement": self.agreement,
                "installed": self.installed,
            }
        )

    def save(self, outdir: str | Path) -> Path:
        """Write ``validation.json`` into ``outdir`` atomically; returns its path."""
        path = Path(outdir) / "validation.json"
        write_json_atomic(path, self.to_dict())
        return path

    @classmethod
    def load(cls, path: str | Path) -> "ValidationReport":
        """Read a ``validation.json`` (or the folder holding one)."""
        data = read_json(path, "validation.json", "validation report")
        return cls(**{k: data.get(k, [] if k in ("cameras", "systems", "figures") else {}) for k in cls.__dataclass_fields__})

    def summary(self) -> str:
        """A few human-readable lines."""

        def f3(v: Any) -> str:
            return "-" if v is None else f"{v:.3f}"

        lines = ["  predicted = Algorithm 3 on the render (like for like); target = the ray-cast target mask alone"]
        for c in self.cameras:
            line = f"  {c['name']}: detected {c.get('detected_px')} px, predicted {c['predicted_px']} px, inside {f3(c.get('inside_fraction'))}, IoU {f3(c.get('iou'))}"
            if "target_px" in c:
                line += f" | target {c['target_px']} px, inside {f3(c.get('inside_fraction_target'))}, IoU {f3(c.get('iou_target'))}"
            lines.append(line)
        a = self.across
        if a:
            ov = a.get("kde_overlap_pct")
            rho = a.get("spearman_rho")
            lines.append(
                f"  {a.get('n_systems')} system(s): KDE overlap {'-' if ov is None else f'{ov:.1f}%'}, "
                f"Spearman {'-' if rho is None else f'{rho:.3f}'}, mean difference {a.get('mean_difference')}"
            )
        g = self.agreement
        if g:
            lines.append(f"  {g['n_views']} view(s) where the target covers >= {g['min_target_px']} px:")
            for fig, what in (("like_for_like", "against the prediction "), ("target_mask", "against the target mask")):
                d = g.get(fig) or {}
                lines.append(
                    f"    {what}: median IoU {f3(d.get('iou_median'))} (min {f3(d.get('iou_min'))}), "
                    f"median inside {f3(d.get('inside_fraction_median'))} (min {f3(d.get('inside_fraction_min'))}); "
                    f"a perfect camera {f3(d.get('perfect_iou_median'))} / {f3(d.get('perfect_inside_fraction_median'))}, "
                    f"drop {f3(d.get('iou_drop'))} / {f3(d.get('inside_fraction_drop'))}"
                )
        lines += installed_summary(self.installed)
        return "\n".join(lines)


def installed_summary(installed: dict[str, Any]) -> list[str]:
    """Summary lines of ``validation.json`` ``installed`` (empty when there is none)."""
    if not installed:
        return []
    if not installed.get("available"):
        return [f"  installed systems: {installed.get('note') or 'not scored'}"] + [f"    note: {n}" for n in installed.get("notes", [])]
    n = installed["installations"]
    ph = installed.get("physical") or {}
    lines = [f"  installed systems ({n} installation(s), seed {installed['seed']}, pose error {ph.get('sigma_position_m', 0):g} m, "
             f"{ph.get('sigma_rotation_deg', 0):g} deg): the run's objective at the installed poses; photo = share of the "
             f"frame's points seen in the photographs"]
    for r in installed["systems"]:
        o, p, of = r.get("objective"), r.get("photo"), r.get("objective_frame")
        if o is None:
            lines.append(f"    system {r['system']} ({r['run']}): not scored")
            continue
        line = f"    system {r['system']} ({Path(r['run']).name}): objective mean {o['mean']:.4f}, p10 {o['p10']:.4f}, min {o['min']:.4f}"
        if p is not None:
            line += f" | photo mean {p['mean']:.4f}, p10 {p['p10']:.4f}"
            if of is not None:
                line += f" (ray cast on the same points {of['mean']:.4f})"
        lines.append(line)
    c = installed.get("comparison") or {}
    for d in c.get("paired", []):
        o = d["objective"]
        se = "-" if o["standard_error"] is None else f"{o['standard_error']:.4f}"
        line = (f"    system {d['system']} minus system {d['minus_system']}: objective {o['mean']:+.4f} (standard error {se}, "
                f"better in {o['wins']}, worse in {o['losses']} of {n})")
        if d.get("photo") is not None:
            ph_ = d["photo"]
            se = "-" if ph_["standard_error"] is None else f"{ph_['standard_error']:.4f}"
            line += f"; photo {ph_['mean']:+.4f} (standard error {se})"
        lines.append(line)
    if c.get("verdict"):
        lines.append(f"    {c['verdict']}")
    lines += [f"    note: {n_}" for n_ in installed.get("notes", [])]
    return lines


# --------------------------------------------------------------------------------------------------
# figures (OpenCV drawing; no matplotlib)


def _text(img: np.ndarray, s: str, org: tuple[int, int], scale: float = 0.45, color=(255, 255, 255), thickness: int = 1, outline: bool = False) -> None:
    import cv2

    if outline:
        cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thickness + 2, cv2.LINE_AA)
    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, color, thickness, cv2.LINE_AA)


def heatmap_image(matrix: np.ndarray, title: str, row_label: str = "predicted camera", col_label: str = "photographed camera") -> np.ndarray:
    """A labelled heatmap (viridis, with a colour bar) of a matrix, as a BGR uint8 image.

    Parameters
    ----------
    matrix : (n, m) float64
    """
    import cv2

    m = np.asarray(matrix, dtype=np.float64)
    n_r, n_c = m.shape
    cell = int(np.clip(480 // max(n_r, n_c, 1), 14, 60))
    left, top, right, bottom = 70, 50, 110, 50
    H, W = top + n_r * cell + bottom, left + n_c * cell + right
    img = np.full((H, W, 3), 32, dtype=np.uint8)
    finite = m[np.isfinite(m)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    span = hi - lo if hi > lo else 1.0
    norm = np.where(np.isfinite(m), (m - lo) / span, 0.0)
    colours = cv2.applyColorMap(np.rint(norm * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    for i in range(n_r):
        for j in range(n_c):
            y0, x0 = top + i * cell, left + j * cell
            img[y0 : y0 + cell, x0 : x0 + cell] = colours[i, j] if np.isfinite(m[i, j]) else (60, 60, 60)
    step = max(1, int(math.ceil(16 / cell)))
    for i in range(0, n_r, step):
        _text(img, str(i + 1), (left - 26, top + i * cell + cell // 2 + 5), 0.4)
    for j in range(0, n_c, step):
        _text(img, str(j + 1), (left + j * cell + cell // 2 - 6, top + n_r * cell + 16), 0.4)
    _text(img, title, (8, 22), 0.55)
    _text(img, col_label, (left, H - 12), 0.45)
    _text(img, row_label, (4, top - 8), 0.4)
    # colour bar
    bx, by, bh = W - right + 20, top, max(n_r * cell, 60)
    ramp = cv2.applyColorMap(np.linspace(255, 0, bh).astype(np.uint8)[:, None].repeat(16, axis=1), cv2.COLORMAP_VIRIDIS)
    img[by : by + bh, bx : bx + 16] = ramp[: min(bh, H - by)]
    _text(img, f"{hi:.3g}", (bx + 20, by + 10), 0.4)
    _text(img, f"{lo:.3g}", (bx + 20, by + bh), 0.4)
    return img


def kde_image(a: Sequence[float], b: Sequence[float], labels: tuple[str, str] = ("predicted", "photo"), title: str = "KDE of normalised system scores") -> np.ndarray:
    """Two KDE curves (green: ``a``, orange: ``b``) with their overlap shaded, as a BGR uint8 image."""
    import cv2
    from scipy.stats import gaussian_kde

    W, H, pad = 640, 360, 40
    img = np.full((H, W, 3), 255, dtype=np.uint8)
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    _text(img, title, (pad, 24), 0.55, (0, 0, 0), 1)
    if len(a) < 2 or len(b) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        _text(img, "not enough distinct systems for a KDE", (pad, H // 2), 0.5, (0, 0, 200))
        return img
    fa, fb = gaussian_kde(a), gaussian_kde(b)
    lo, hi = min(a.min(), b.min()) - 0.25, max(a.max(), b.max()) + 0.25
    x = np.linspace(lo, hi, 400)
    ya, yb = fa(x), fb(x)
    top = max(ya.max(), yb.max())
    px = pad + (x - lo) / (hi - lo) * (W - 2 * pad)

    def py(y):
        return H - pad - y / top * (H - 2 * pad - 20)

    over = np.minimum(ya, yb)
    poly = np.concatenate([np.stack([px, py(over)], 1), np.stack([px[::-1], np.full(len(px), H - pad)], 1)]).astype(np.int32)
    cv2.fillPoly(img, [poly], (220, 200, 200))
    cv2.polylines(img, [np.stack([px, py(ya)], 1).astype(np.int32)], False, (60, 160, 0), 2, cv2.LINE_AA)
    cv2.polylines(img, [np.stack([px, py(yb)], 1).astype(np.int32)], False, (0, 120, 255), 2, cv2.LINE_AA)
    cv2.line(img, (pad, H - pad), (W - pad, H - pad), (0, 0, 0), 1)
    for v in np.linspace(lo, hi, 6):
        xx = int(pad + (v - lo) / (hi - lo) * (W - 2 * pad))
        cv2.line(img, (xx, H - pad), (xx, H - pad + 4), (0, 0, 0), 1)
        cv2.putText(img, f"{v:.2f}", (xx - 14, H - pad + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, labels[0], (W - 170, 50), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (60, 160, 0), 1, cv2.LINE_AA)
    cv2.putText(img, labels[1], (W - 170, 70), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 120, 255), 1, cv2.LINE_AA)
    ov = kde_overlap(a, b)
    cv2.putText(img, f"overlap {100 * ov:.1f}%", (W - 170, 90), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (120, 80, 80), 1, cv2.LINE_AA)
    return img


def overlay_image(photo: np.ndarray, predicted: np.ndarray, detected: np.ndarray, bbox_xywh: tuple[int, int, int, int] | None,
                  label: str = "", target: np.ndarray | None = None) -> np.ndarray:
    """The photo with outlines: target mask (yellow, when given), prediction (green), detection (blue) and its box (red)."""
    import cv2

    from camplace.validation.render import quantise

    p = np.asarray(photo)
    if p.dtype != np.uint8:
        p = quantise(p if p.dtype != np.uint16 else p.astype(np.float32) / 65535.0, 8)
    img = cv2.cvtColor(p, cv2.COLOR_GRAY2BGR) if p.ndim == 2 else p[:, :, :3].copy()
    outlines = [(target, (0, 220, 255), "target mask")] if target is not None else []
    outlines += [(predicted, (0, 220, 0), "predicted (render)"), (detected, (255, 120, 0), "detected (photo)")]
    for mask, colour, _ in outlines:
        cs, _ = cv2.findContours(np.asarray(mask, dtype=np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(img, cs, -1, colour, 1, cv2.LINE_AA)
    if bbox_xywh is not None:
        x, y, w, h = bbox_xywh
        cv2.rectangle(img, (x, y), (x + w - 1, y + h - 1), (0, 0, 255), 1)
    if label:
        _text(img, label, (6, 18), 0.45, outline=True)
    if img.shape[1] >= 320 and img.shape[0] >= 120:
        for i, (_, colour, name) in enumerate(reversed(outlines)):
            _text(img, name, (6, img.shape[0] - 8 - 16 * i), 0.4, colour, outline=True)
    return img
