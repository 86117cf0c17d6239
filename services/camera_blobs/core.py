"""Pixel classes and regions: seed 001 (Zhuang et al.) 3.1-3.2.

The colour model (learnt in hue and saturation from a rectangle on the target's clothing, seed
3.1) and the pixel classification live in ``services/common/colour.py``: the appearance
verifier ``colour`` (vision_verify) uses them too. This module groups the target pixels into
connected regions, each reported as its bounding rectangle ``[x, y, w, h]`` with (x, y) the
centre (3.2, ``Z_k``).

- Regions (:func:`regions`): OpenCV's connected components (8-connected) stand in for the
  seed's run-length union-find (Bruce et al. 2000): same regions, one call. Regions smaller
  than ``min_area_px`` are dropped (speckle); the rest are sorted by area, largest first.
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np

from followbot.services.common.colour import (
    ColourError,
    ColourLearning,
    ColourModel,
    classify,
    learn_colour,
)

__all__ = ["BlobSettings", "ColourError", "ColourModel", "classify", "learn_colour", "regions"]


class BlobSettings(ColourLearning, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Colour learning (``ColourLearning``: coverage, margins, min_saturation, min_value) and
    regions."""

    min_area_px: Annotated[int, msgspec.Meta(ge=1)] = 40
    """Smallest region reported, at 320x240 (scaled with the image's area)."""
    max_regions: Annotated[int, msgspec.Meta(ge=1, le=256)] = 32
    """At most this many regions per frame are reported, the largest."""


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
