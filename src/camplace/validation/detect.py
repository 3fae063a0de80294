"""Target detection in a photograph (the thesis's Algorithm 3, with OpenCV).

1. ``diff = |I_t - I_b|`` with the background photograph I_b, or ``I_t`` alone when there is none
   (a dark background: the threshold alone separates the target);
2. grayscale (OpenCV BGR weights); with a floor ``min_level`` > 0, pixels whose photograph (I_t,
   gray) is no brighter than it are set to 0 in the difference: they are never target. Validation
   sets the floor to the level of an unlit surface when the instance requires light
   (``[quality] require_light``, :func:`camplace.validation.physical.unlit_level`): the night
   side, lit by the renderer's ambient term alone, is not detected. A photograph with no pixel
   above the floor (a view of the night side against dark space) detects nothing, where the
   min-max normalisation of step 3 would stretch the ambient glow to full contrast, Otsu's
   threshold would fall to 0 and the whole dark outline would count as detected;
3. min-max normalisation to 0..255 (uint8);
4. binary threshold: Otsu's (default), the triangle method, or a fixed value on that 0..255 scale;
5. morphological opening then closing with an elliptical kernel (removes speckle, fills pin holes);
6. optionally only the largest connected component is kept;
7. external contours, their joint bounding box, the coverage area (mask pixels) and the mean
   target intensity (mean gray level of I_t over the mask, in [0, 1] whatever the bit depth).

:func:`expected_detection` runs the same algorithm on a render (and its background render) saved as
an 8-bit photograph: what a perfect camera would detect. Validation compares the photograph's
detection with it (like for like: the target's cast shadow, unlit faces that match the background,
the two-class split of Otsu's threshold and the morphology affect both alike), and reports the
ray-cast target mask as a second figure.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from camplace._io import write_bytes_atomic
from camplace.errors import CamplaceError

__all__ = ["Detection", "DetectionSettings", "detect_target", "expected_detection", "to_gray01", "parse_threshold"]


@dataclass(frozen=True)
class DetectionSettings:
    """Parameters of :func:`detect_target`.

    Attributes
    ----------
    threshold : "otsu" | "triangle" | float
        Thresholding of the 0..255 normalised difference; a number is a fixed level (pixels above it are target).
    morph_kernel_px : int
        Diameter of the elliptical kernel of the opening and closing (0 or 1: none).
    largest_component : bool
        Keep only the largest 8-connected component of the mask.
    min_level : float
        Floor on the photograph's gray level, [0, 1]: pixels no brighter are never target (0: none).
    """

    threshold: str | float = "otsu"
    morph_kernel_px: int = 5
    largest_component: bool = False
    min_level: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"threshold": self.threshold, "morph_kernel_px": self.morph_kernel_px, "largest_component": self.largest_component,
                "min_level": self.min_level}

    def with_floor(self, level: float) -> "DetectionSettings":
        """A copy whose ``min_level`` is at least ``level``."""
        from dataclasses import replace

        return replace(self, min_level=max(float(self.min_level), float(level)))


def parse_threshold(text: str | float) -> str | float:
    """``"otsu"``, ``"triangle"`` or a number in [0, 255] (from the CLI's ``--threshold``)."""
    if isinstance(text, (int, float)):
        value = float(text)
    elif str(text).lower() in ("otsu", "triangle"):
        return str(text).lower()
    else:
        try:
            value = float(text)
        except ValueError:
            raise CamplaceError(f"--threshold: use otsu, triangle or a number 0..255, got {text!r}") from None
    if not 0.0 <= value <= 255.0:
        raise CamplaceError(f"--threshold: a fixed threshold must be in 0..255, got {value}")
    return value


@dataclass(frozen=True, eq=False)
class Detection:
    """The target found in one photograph.

    Attributes
    ----------
    mask : (h, w) bool
        Target pixels.
    bbox_xywh : (x, y, w, h) ints or None
        Bounding box of all external contours (None when nothing is detected).
    area_px : int
        Coverage area: number of mask pixels.
    mean_intensity : float
        Mean gray level of the photograph over the mask, [0, 1] (0 when nothing is detected).
    threshold : float
        The level used on the 0..255 normalised difference.
    n_contours : int
        Number of external contours (separate blobs).
    """

    mask: np.ndarray
    bbox_xywh: tuple[int, int, int, int] | None
    area_px: int
    mean_intensity: float
    threshold: float
    n_contours: int

    def to_dict(self) -> dict[str, Any]:
        """Everything but the mask, JSON-ready."""
        return {
            "bbox_xywh": None if self.bbox_xywh is None else [int(v) for v in self.bbox_xywh],
            "area_px": int(self.area_px),
            "mean_intensity": float(self.mean_intensity),
            "threshold": float(self.threshold),
            "n_contours": int(self.n_contours),
        }

    def save(self, path: str | Path) -> None:
        """Write mask and fields to one ``.npz`` (atomically)."""
        buf = io.BytesIO()
        np.savez_compressed(buf, mask=self.mask, meta=np.array(json.dumps(self.to_dict())))
        write_bytes_atomic(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> "Detection":
        with np.load(Path(path)) as z:
            meta = json.loads(str(z["meta"]))
            mask = z["mask"].astype(bool)
        bbox = None if meta["bbox_xywh"] is None else tuple(int(v) for v in meta["bbox_xywh"])
        return cls(mask, bbox, meta["area_px"], meta["mean_intensity"], meta["threshold"], meta["n_contours"])


def to_gray01(image: np.ndarray) -> np.ndarray:
    """Any image (uint8, uint16 or float in [0, 1]; gray, BGR or BGRA) as float32 gray in [0, 1]."""
    import cv2

    img = np.asarray(image)
    if img.dtype == np.uint8:
        img = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        img = img.astype(np.float32) / 65535.0
    else:
        img = img.astype(np.float32)
    if img.ndim == 3:
        if img.shape[2] == 4:
            img = img[:, :, :3]
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.shape[2] == 3 else img[:, :, 0]
    return img


def _as_float(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    if img.dtype == np.uint16:
        return img.astype(np.float32) / 65535.0
    return img.astype(np.float32)


def detect_target(image: np.ndarray, background: np.ndarray | None = None, settings: DetectionSettings = DetectionSettings()) -> Detection:
    """Find the target in a photograph (see the module docstring).

    Parameters
    ----------
    image : (h, w) or (h, w, 3) uint8, uint16 or float32 in [0, 1]
        The photograph with the target (I_t).
    background : same shape as ``image`` or None
        The photograph without the target (I_b); None thresholds the image itself.
    settings : DetectionSettings

    Returns
    -------
    Detection
    """
    import cv2

    img = _as_float(image)
    if background is not None:
        bg = _as_float(background)
        if bg.shape != img.shape:
            raise CamplaceError(f"background image is {bg.shape[1]}x{bg.shape[0]} but the photo is {img.shape[1]}x{img.shape[0]} (use a background from the same camera)")
        diff = np.abs(img - bg)
    else:
        diff = img
    gray = to_gray01(diff)
    if settings.min_level > 0:
        gray = np.where(to_gray01(img) > settings.min_level, gray, np.float32(0.0))
    lo, hi = float(gray.min()), float(gray.max())
    h, w = gray.shape
    if hi <= lo:
        return Detection(np.zeros((h, w), bool), None, 0, 0.0, 0.0, 0)
    norm = np.rint((gray - lo) * (255.0 / (hi - lo))).astype(np.uint8)
    th = settings.threshold
    if th == "otsu":
        level, mask = cv2.threshold(norm, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    elif th == "triangle":
        level, mask = cv2.threshold(norm, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_TRIANGLE)
    else:
        level, mask = cv2.threshold(norm, float(th), 255, cv2.THRESH_BINARY)
    k = int(settings.morph_kernel_px)
    if k > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    if settings.largest_component:
        n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        if n > 1:
            big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
            mask = np.where(lab == big, 255, 0).astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    m = mask > 0
    area = int(m.sum())
    if area == 0 or not contours:
        return Detection(m, None, 0, 0.0, float(level), 0)
    pts = np.concatenate([c.reshape(-1, 2) for c in contours])
    x0, y0 = pts.min(axis=0)
    x1, y1 = pts.max(axis=0)
    bbox = (int(x0), int(y0), int(x1 - x0 + 1), int(y1 - y0 + 1))
    mean_i = float(to_gray01(img)[m].mean())
    return Detection(m, bbox, area, mean_i, float(level), len(contours))


def expected_detection(
    render: np.ndarray, background_render: np.ndarray | None = None, settings: DetectionSettings = DetectionSettings(), bit_depth: int = 8
) -> Detection:
    """What :func:`detect_target` finds in a perfect camera's photograph: the render itself.

    The render (and background render) are quantised as the photographs are written (clipped to
    [0, 1], ``bit_depth`` bits), so an emulated perfect camera's photo gives exactly this detection.

    Parameters
    ----------
    render : (h, w) float32
        Linear radiance of the view with the target (glow included).
    background_render : (h, w) float32 or None
        The same view without the target; None when the photograph has no background photograph
        (then the render is thresholded alone, as the photo is).
    settings : DetectionSettings
        The settings used on the photographs.
    bit_depth : {8, 16}

    Returns
    -------
    Detection
    """
    from camplace.validation.render import quantise

    bg = None if background_render is None else quantise(background_render, bit_depth)
    return detect_target(quantise(render, bit_depth), bg, settings)
