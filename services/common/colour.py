"""One plain colour learnt in hue and saturation, and pixels classified by it: seed 001
(Zhuang et al.) 3.1. Shared by the camera stage (camera_blobs: the seed's regions) and the
appearance verifier ``colour`` (vision_verify: the same model judging a person's box).

The seed assumes the followed person wears one plain colour. From a rectangle on that colour
(the seed's user drags it with the mouse) the hue and saturation ranges of the clothing are
learnt, intensity ignored; every pixel of later frames is then target or not by those two
thresholds.

HSV on OpenCV's scale: H in [0, 180) (hue is circular: red straddles 0), S and V in [0, 255].

Learning (:func:`learn_colour`): the hue range is the shortest circular interval holding the
central ``coverage`` share of the rectangle's hues, the saturation range the same share of its
saturations, each widened by a margin. Pixels darker than ``min_value`` are left out of
learning and of classification: their hue and saturation are sensor noise (on a real camera
and in the simulator's shadows), so "intensity ignored" stops short of black.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np

__all__ = [
    "ColourError",
    "ColourLearning",
    "ColourModel",
    "classify",
    "classify_hsv",
    "learn_colour",
]

_HUE = 180  # OpenCV's 8-bit hue scale


class ColourError(ValueError):
    """A rectangle a colour cannot be learnt from; the message says why."""


class ColourLearning(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """How a colour is learnt from a rectangle (seed 001 3.1)."""

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


def to_hsv(bgr: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.cvtColor(np.ascontiguousarray(bgr), cv2.COLOR_BGR2HSV)


def learn_colour(
    bgr: np.ndarray, rect: tuple[float, float, float, float], settings: ColourLearning | None = None
) -> ColourModel:
    """Thresholds from the pixels of ``rect`` = (x0, y0, width, height) of a BGR frame;
    :class:`ColourError` when the rectangle is outside the frame, too dark or too grey."""
    s = settings or ColourLearning()
    x0, y0, w, h = (round(float(v)) for v in rect)
    x0, y0 = max(0, x0), max(0, y0)
    patch = bgr[y0 : y0 + max(0, h), x0 : x0 + max(0, w)]
    if patch.size == 0:
        raise ColourError(f"learning rectangle {rect} holds no pixel of the {bgr.shape} image")
    hsv = to_hsv(patch).reshape(-1, 3).astype(float)
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
    return classify_hsv(to_hsv(bgr), model)


def classify_hsv(hsv: np.ndarray, model: ColourModel) -> np.ndarray:
    """:func:`classify` of a frame already in OpenCV's HSV."""
    import cv2

    lo_s, hi_s, v = int(np.ceil(model.sat_lo)), int(np.floor(model.sat_hi)), model.min_value
    lo_h, hi_h = int(np.ceil(model.hue_lo)), int(np.floor(model.hue_hi))
    if lo_h <= hi_h:
        return cv2.inRange(hsv, (lo_h, lo_s, v), (hi_h, hi_s, 255))
    # the range wraps past 180 (reds): two bands
    a = cv2.inRange(hsv, (lo_h, lo_s, v), (_HUE - 1, hi_s, 255))
    b = cv2.inRange(hsv, (0, lo_s, v), (hi_h, hi_s, 255))
    return cv2.bitwise_or(a, b)
