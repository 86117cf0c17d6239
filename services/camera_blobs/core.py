"""Colour learning, pixel classification and regions: seed 001 (Zhuang et al.) 3.1-3.2.

The seed assumes the followed person wears one plain colour. From a rectangle on that colour
(the seed's user drags it with the mouse) the hue and saturation ranges of the clothing are
learnt, intensity ignored (3.1); every pixel of later frames is then target or not by those two
thresholds, and the target pixels are grouped into connected regions, each reported as its
bounding rectangle ``[x, y, w, h]`` with (x, y) the centre (3.2, ``Z_k``).

HSV on OpenCV's scale: H in [0, 180) (hue is circular: red straddles 0), S and V in [0, 255].

- Learning (:func:`learn_colour`): the hue range is the shortest circular interval holding
  the central ``coverage`` share of the rectangle's hues, the saturation range the same share
  of its saturations, each widened by a margin. Pixels darker than ``min_value`` are left out
  of learning and of classification: their hue and saturation are sensor noise (on a real
  camera and in the simulator's shadows), so "intensity ignored" stops short of black.
- Regions (:func:`regions`): OpenCV's connected components (8-connected) stand in for the
  seed's run-length union-find (Bruce et al. 2000): same regions, one call. Regions smaller
  than ``min_area_px`` are dropped (speckle); the rest are sorted by area, largest first.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np

__all__ = ["BlobSettings", "ColourError", "ColourModel", "classify", "learn_colour", "regions"]

_HUE = 180  # OpenCV's 8-bit hue scale


class ColourError(ValueError):
    """A rectangle a colour cannot be learnt from; the message says why."""


class BlobSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    coverage: Annotated[float, msgspec.Meta(gt=0.5, le=1.0)] = 0.9
    """Share of the learning rectangle's hues (and saturations) the thresholds keep."""
    hue_margin: Annotated[float, msgspec.Meta(ge=0, le=45)] = 4.0
    """Widening of the learnt hue range on each side, OpenCV hue units (2 deg)."""
    sat_margin: Annotated[float, msgspec.Meta(ge=0, le=128)] = 25.0
    """Widening of the learnt saturation range on each side (0-255 scale)."""
    min_saturation: Annotated[int, msgspec.Meta(ge=0, le=255)] = 40
    """A learnt colour must be at least this saturated: a grey shirt has no hue to follow."""
    min_value: Annotated[int, msgspec.Meta(ge=0, le=255)] = 30
    """Pixels darker than this are never target (their hue is noise)."""
    min_area_px: Annotated[int, msgspec.Meta(ge=1)] = 40
    """Smallest region reported, at 320x240 (scaled with the image's area)."""
    max_regions: Annotated[int, msgspec.Meta(ge=1, le=256)] = 32
    """At most this many regions per frame are reported, the largest."""


class ColourModel(msgspec.Struct, frozen=True):
    """Learnt thresholds: hue from ``hue_lo`` counter-clockwise to ``hue_hi`` (may wrap past
    180), saturation in [``sat_lo``, ``sat_hi``]."""

    hue_lo: float
    """Lower end of the hue range (OpenCV hue, 0-180; above hue_hi when it wraps past red)."""
    hue_hi: float
    """Upper end of the hue range (OpenCV hue, 0-180)."""
    sat_lo: float
    """Lowest saturation of the colour (0-255)."""
    sat_hi: float
    """Highest saturation of the colour (0-255)."""
    min_value: int = 30
    """Pixels darker than this (V, 0-255) are never the colour: their hue is noise."""


def _to_hsv(bgr: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(np.ascontiguousarray(bgr), cv2.COLOR_BGR2HSV)


def learn_colour(
    bgr: np.ndarray, rect: tuple[int, int, int, int], settings: BlobSettings | None = None
) -> ColourModel:
    """Thresholds from the pixels of ``rect`` = (x0, y0, width, height) of a BGR frame."""
    s = settings or BlobSettings()
    x0, y0, w, h = (round(float(v)) for v in rect)
    x0, y0 = max(0, x0), max(0, y0)
    patch = bgr[y0 : y0 + max(0, h), x0 : x0 + max(0, w)]
    if patch.size == 0:
        raise ColourError(f"learning rectangle {rect} holds no pixel of the {bgr.shape} image")
    hsv = _to_hsv(patch).reshape(-1, 3).astype(float)
    hsv = hsv[hsv[:, 2] >= s.min_value]
    if len(hsv) < 10:
        raise ColourError(f"learning rectangle {rect}: fewer than 10 pixels bright enough")
    sat = hsv[:, 1]
    tail = (1.0 - s.coverage) / 2.0
    sat_lo, sat_hi = np.quantile(sat, [tail, 1.0 - tail])
    if sat_lo < s.min_saturation:
        raise ColourError(
            f"learning rectangle {rect}: the colour is too grey to follow (saturation "
            f"{sat_lo:.0f} < min_saturation {s.min_saturation}); the seed assumes one plain colour"
        )
    lo, hi = _hue_interval(hsv[:, 0], s.coverage)
    return ColourModel(
        hue_lo=(lo - s.hue_margin) % _HUE,
        hue_hi=(hi + s.hue_margin) % _HUE,
        sat_lo=max(float(s.min_saturation), sat_lo - s.sat_margin),
        sat_hi=min(255.0, sat_hi + s.sat_margin),
        min_value=s.min_value,
    )


def _hue_interval(hue: np.ndarray, coverage: float) -> tuple[float, float]:
    """The shortest circular arc [lo, hi] (degrees of 0..180, hi may be < lo: wraps) holding
    ``coverage`` of the hues."""
    h = np.sort(hue % _HUE)
    n = len(h)
    k = max(1, min(n, int(np.ceil(coverage * n))))
    ext = np.concatenate([h, h + _HUE])
    starts = np.arange(n)
    widths = ext[starts + k - 1] - ext[starts]
    i = int(np.argmin(widths))
    return float(ext[i]) % _HUE, float(ext[i + k - 1]) % _HUE


def classify(bgr: np.ndarray, model: ColourModel) -> np.ndarray:
    """uint8 mask (255 target, 0 not) of a BGR frame by the learnt H and S thresholds."""
    import cv2

    hsv = _to_hsv(bgr)
    lo_s, hi_s, v = int(np.ceil(model.sat_lo)), int(np.floor(model.sat_hi)), model.min_value
    lo_h, hi_h = int(np.ceil(model.hue_lo)), int(np.floor(model.hue_hi))
    if lo_h <= hi_h:
        return cv2.inRange(hsv, (lo_h, lo_s, v), (hi_h, hi_s, 255))
    # the range wraps past 180 (reds): two bands
    a = cv2.inRange(hsv, (lo_h, lo_s, v), (_HUE - 1, hi_s, 255))
    b = cv2.inRange(hsv, (0, lo_s, v), (hi_h, hi_s, 255))
    return cv2.bitwise_or(a, b)


def regions(mask: np.ndarray, settings: BlobSettings | None = None) -> np.ndarray:
    """(n, 4) float rectangles [x_centre, y_centre, w, h] in pixels of the mask's connected
    target regions, largest first (seed 3.2)."""
    import cv2

    s = settings or BlobSettings()
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    stats = stats[1:n]  # label 0 is the background
    min_area = s.min_area_px * mask.shape[0] * mask.shape[1] / (320 * 240)
    stats = stats[stats[:, cv2.CC_STAT_AREA] >= min_area]
    stats = stats[np.argsort(-stats[:, cv2.CC_STAT_AREA], kind="stable")][: s.max_regions]
    x, y = stats[:, cv2.CC_STAT_LEFT], stats[:, cv2.CC_STAT_TOP]
    w, h = stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]
    return np.stack([x + w / 2.0, y + h / 2.0, w, h], axis=1).astype(float).reshape(-1, 4)
