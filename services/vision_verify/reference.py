"""The histograms of core.py computed the plain way, to check the fast path against.

This is the computation as first written (and as DESIGN.md states it): colour conversion,
colour mask, Sobel gradients and ``cv2.cartToPolar`` over the whole frame, then per rectangle
four masked ``calcHist`` calls for the colour halves and one masked float ``calcHist`` of the
orientations. :class:`~followbot.services.vision_verify.core.ImageFeatures` must give the same
histograms (tests/vision_verify/test_fast.py); ``bench.py`` times both in the same run.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from .core import (
    COLOUR_BINS,
    EDGE_BINS,
    EDGE_FRACTION,
    HALF_BINS,
    N_HUE,
    N_SAT,
    N_VAL,
    SV_MIN,
    Model,
    Rect,
    View,
    bhattacharyya,
)
from .verifiers.histogram import HistogramVerifier, model_window

__all__ = ["ReferenceFeatures", "ReferenceHistogramVerifier"]


class ReferenceFeatures:
    """Whole-frame HSV, colour mask and gradients; per-rectangle ``calcHist`` on them."""

    def __init__(self, bgr: np.ndarray) -> None:
        self.cache: dict[str, object] = {}
        self.hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
        # thesis 4.2.1.2: S >= 51 and V >= 51 -> colour bins; otherwise brightness bins
        self.colour_mask = cv2.inRange(self.hsv, (0, SV_MIN, SV_MIN), (255, 255, 255))
        self.dark_mask = cv2.bitwise_not(self.colour_mask)
        grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
        self.mag, self.ang = cv2.cartToPolar(gx, gy, angleInDegrees=True)

    def colour(self, rect: Rect) -> np.ndarray:
        x0, y0, x1, y1 = rect
        mid = (y0 + y1) // 2
        out = np.zeros(COLOUR_BINS, dtype=np.float32)
        for k, (a, b) in enumerate(((y0, mid), (mid, y1))):
            if b <= a:
                continue
            part = self.hsv[a:b, x0:x1]
            seg = out[k * HALF_BINS : (k + 1) * HALF_BINS]
            hs = cv2.calcHist(
                [part], [0, 1], self.colour_mask[a:b, x0:x1], [N_HUE, N_SAT], [0, 180, 0, 256]
            )
            val = cv2.calcHist([part], [2], self.dark_mask[a:b, x0:x1], [N_VAL], [0, 256])
            seg[: N_HUE * N_SAT] = hs.ravel()
            seg[N_HUE * N_SAT :] = val.ravel()
            total = float(seg.sum())
            if total > 0:
                seg *= 0.5 / total
        return out

    def edges(self, rect: Rect) -> np.ndarray:
        x0, y0, x1, y1 = rect
        m = self.mag[y0:y1, x0:x1]
        peak = float(m.max()) if m.size else 0.0
        if peak <= 0.0:
            return np.zeros(EDGE_BINS, dtype=np.float32)
        mask = (m > EDGE_FRACTION * peak).view(np.uint8)
        hist = cv2.calcHist([self.ang[y0:y1, x0:x1]], [0], mask, [EDGE_BINS], [0, 360]).ravel()
        total = float(hist.sum())
        return hist / total if total > 0 else hist

    def histograms(self, rect: Rect) -> dict[str, np.ndarray]:
        return {"colour_hs": self.colour(rect), "edge_orientation": self.edges(rect)}


class ReferenceHistogramVerifier:
    """The histogram verifier as first written: per candidate, both histograms in a dict, then
    two :func:`bhattacharyya` calls (d_colour + d_edge, thesis eq. 3-23). A candidate showing
    part of its body is compared with the same part of the model's pixels, recomputed here
    each time, the plain way (the window itself is :meth:`HistogramVerifier.window`)."""

    name = "histogram"
    default_threshold = 0.8

    def __init__(self) -> None:
        self._window = HistogramVerifier().window

    def distances(self, frame, views: Sequence[View], model: Model) -> list[float | None]:
        out: list[float | None] = []
        for v in views:
            if not v.ok:
                out.append(None)
                continue
            h = frame.histograms(v.rect)
            m = self._model(v, model)
            out.append(
                bhattacharyya(h["colour_hs"], m["colour_hs"])
                + bhattacharyya(h["edge_orientation"], m["edge_orientation"])
            )
        return out

    def _model(self, v: View, model: Model) -> dict[str, np.ndarray]:
        win = self._window(v)
        sub = None if win is None else model_window(model.features, win)
        if sub is None:
            return model.features
        return ReferenceFeatures(model.features["patch_bgr"]).histograms(sub)
