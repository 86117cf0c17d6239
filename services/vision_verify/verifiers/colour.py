"""Colour verifier (seed 001, Zhuang et al.): one plain colour, and how much of a box wears it.

Seed 001 follows a person by one colour learnt in hue and saturation from a rectangle the user
drags on the person's clothing (3.1); every pixel is the colour or not, and the connected
regions of the colour are the candidates (3.2). The colour model and the pixel classes are
``services/common/colour.py`` (the camera stage camera_blobs uses the same ones).

As a verifier. Model: the colour learnt from a window of the model rectangle
(``learn_window``, fractions of its width and height: by default the middle half of the
columns, rows 0.2-0.5 of a standing person's box, the shirt), the seed's user's rectangle on
the clothing. A model rectangle too grey or too dark to learn a colour from (the seed's
assumption of one plain colour fails) gives a model that judges no box (the verifier has no
opinion: every distance None).

Judging. The frame's pixels are classified once per model; a candidate's rectangle (the part
of it the camera sees) gets

    d = 1 - (area of the largest connected region of the colour inside it) / (its area)

in [0, 1]: the seed's cue (a region of the colour) scaled by how much of the box it fills. The
seed has no threshold: any region of the colour above its minimum area is a candidate. The
default threshold 0.925 accepts a box whose largest region covers at least 7.5 % of it, half
of the 15 % the default learning window covers: a box wearing the learnt colour where it was learnt
covers about that window, and half of it allows for shade and pose. It was set from that
reasoning, not tuned on any footage.

The seed never updates its colour (``describe`` gives None: following keeps the first view).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated

import cv2
import msgspec
import numpy as np

from followbot.services.common.colour import (
    ColourError,
    ColourLearning,
    ColourModel,
    classify_hsv,
    learn_colour,
)

from ..core import ImageFeatures, Model, Rect, View

__all__ = ["ColourVerifier", "ColourVerifierSettings"]

_FIELDS = 5  # hue_lo, hue_hi, sat_lo, sat_hi, min_value


class ColourVerifierSettings(ColourLearning, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Colour learning (seed 001 3.1: coverage, margins, min_saturation, min_value), where in
    the model rectangle it is learnt, and the threshold."""

    learn_window: Annotated[list[float], msgspec.Meta(min_length=4, max_length=4)] = msgspec.field(
        default_factory=lambda: [0.25, 0.2, 0.75, 0.5]
    )
    """[left, top, right, bottom] fractions of the model rectangle the colour is learnt from
    (the seed's user's rectangle on the clothing): by default the middle half of the columns,
    rows 0.2-0.5 of a standing person, the shirt."""
    default_threshold: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.925
    """Rejection threshold on 1 - (the largest region of the colour's share of the box), when
    the node's threshold is unset: 0.925 accepts a box 7.5 % of which one region of the colour
    fills, half of what the default learn_window covers (module docstring)."""


class ColourVerifier:
    """Seed 001's colour model judging boxes (module docstring)."""

    name = "colour"
    settings_type = ColourVerifierSettings

    def __init__(self, settings: ColourVerifierSettings | None = None) -> None:
        self.settings = settings or ColourVerifierSettings()
        self.default_threshold = self.settings.default_threshold
        left, top, right, bottom = self.settings.learn_window
        if not (0 <= left < right <= 1 and 0 <= top < bottom <= 1):
            raise ValueError(
                f"colour: learn_window {self.settings.learn_window} is not inside [0, 1]"
            )

    def learn(self, frame: ImageFeatures, rect: Rect, view: View) -> dict[str, np.ndarray]:
        """The colour of the learning window of ``rect``; an empty range when there is none to
        learn (too grey, too dark)."""
        x0, y0, x1, y1 = rect
        left, top, right, bottom = self.settings.learn_window
        w, h = x1 - x0, y1 - y0
        window = (x0 + left * w, y0 + top * h, (right - left) * w, (bottom - top) * h)
        try:
            m = learn_colour(frame.bgr, window, self.settings)
        except ColourError:
            return {"colour_range": np.zeros(0, np.float32)}
        values = [m.hue_lo, m.hue_hi, m.sat_lo, m.sat_hi, m.min_value]
        return {"colour_range": np.array(values, np.float32)}

    def describe(self, frame: ImageFeatures, rect: Rect):
        return None  # the seed never updates its colour

    def check_model(self, model: Model) -> None:
        """ValueError unless ``colour_range`` is 5 finite values in range (hue 0-180,
        saturation and value 0-255, sat_lo <= sat_hi), or empty (no colour learnt)."""
        r = model.features.get("colour_range")
        if r is None:
            raise ValueError("no 'colour_range' feature")
        if r.dtype.kind != "f" or r.shape not in ((0,), (_FIELDS,)):
            raise ValueError(f"'colour_range' is {r.dtype} {r.shape}, expected 0 or 5 floats")
        if r.size and not (
            np.isfinite(r).all()
            and 0 <= r[0] < 180
            and 0 <= r[1] < 180
            and 0 <= r[2] <= r[3] <= 255
            and 0 <= r[4] <= 255
        ):
            raise ValueError(f"'colour_range' {r.tolist()} is outside the HSV scale")

    def distances(
        self, frame: ImageFeatures, views: Sequence[View], model: Model
    ) -> list[float | None]:
        r = model.features.get("colour_range")
        if r is None:
            raise ValueError("the model has no colour_range feature")
        if r.size == 0:
            return [None] * len(views)
        mask = self._mask(frame, r)
        return [None if not v.ok or v.rect is None else self._distance(mask, v.rect) for v in views]

    def _mask(self, frame: ImageFeatures, r: np.ndarray) -> np.ndarray:
        """The frame's pixels of the colour, once per frame and colour."""
        key = "colour_mask " + ",".join(f"{float(x):g}" for x in r)
        mask = frame.cache.get(key)
        if mask is None:
            colour = ColourModel(float(r[0]), float(r[1]), float(r[2]), float(r[3]), int(r[4]))
            mask = classify_hsv(frame.hsv(), colour)
            frame.cache[key] = mask
        return mask  # type: ignore[return-value]

    def _distance(self, mask: np.ndarray, rect: Rect) -> float | None:
        x0, y0, x1, y1 = rect
        crop = mask[max(0, y0) : y1, max(0, x0) : x1]
        if crop.size == 0:
            return None
        n, _, stats, _ = cv2.connectedComponentsWithStats(crop, connectivity=8)
        covered = int(stats[1:n, cv2.CC_STAT_AREA].max()) if n > 1 else 0
        return 1.0 - covered / crop.size
