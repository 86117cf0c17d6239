"""The thesis's verifier (default): HS colour + edge-orientation histograms, Bhattacharyya.

d = d_colour + d_edge (thesis eq. 3-23); the weights are settings (1, 1 in the thesis).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import msgspec
import numpy as np

from ..core import COLOUR_BINS, EDGE_BINS, ImageFeatures, Model, Rect, View, bhattacharyya

__all__ = ["HistogramSettings", "HistogramVerifier"]


class HistogramSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    colour_weight: float = 1.0  # thesis eq. 3-23: d_colour + d_edge
    edge_weight: float = 1.0
    default_threshold: float = 0.8
    """Rejection threshold on d_colour + d_edge when the node's ``threshold`` is unset."""


class HistogramVerifier:
    """HS colour histogram (216 bins) + edge orientation histogram (72 bins)."""

    name = "histogram"
    settings_type = HistogramSettings

    def __init__(self, settings: HistogramSettings | None = None) -> None:
        self.settings = settings or HistogramSettings()
        self.default_threshold = self.settings.default_threshold

    def learn(self, frame: ImageFeatures, rect: Rect, view: View) -> dict[str, np.ndarray]:
        return frame.histograms(rect)

    def describe(self, frame: ImageFeatures, rect: Rect) -> dict[str, np.ndarray]:
        return frame.histograms(rect)

    def distance(self, feats: dict[str, np.ndarray], model: dict[str, np.ndarray]) -> float:
        s = self.settings
        return s.colour_weight * bhattacharyya(
            feats["colour_hs"], model["colour_hs"]
        ) + s.edge_weight * bhattacharyya(feats["edge_orientation"], model["edge_orientation"])

    def distances(
        self, frame: ImageFeatures, views: Sequence[View], model: Model
    ) -> list[float | None]:
        if "colour_hs" not in model.features or "edge_orientation" not in model.features:
            raise ValueError("the model has no colour_hs/edge_orientation features")
        # the model's side of bhattacharyya() once, then one compareHist per histogram
        colour = _model_side(model.features["colour_hs"], COLOUR_BINS)
        edges = _model_side(model.features["edge_orientation"], EDGE_BINS)
        wc, we = self.settings.colour_weight, self.settings.edge_weight
        frame.share_gradients([v.rect for v in views if v.ok])
        return [
            wc * _to_model(frame.colour(v.rect), colour)
            + we * _to_model(frame.edges(v.rect), edges)
            if v.ok
            else None
            for v in views
        ]


def _model_side(q: np.ndarray, bins: int) -> np.ndarray | None:
    """The model histogram as compareHist wants it (float32, contiguous); None when empty."""
    if q.shape != (bins,):
        raise ValueError(f"model histogram has shape {q.shape}, expected ({bins},)")
    q = np.ascontiguousarray(q, dtype=np.float32)
    return q if q.sum() > 0 else None


def _to_model(p: np.ndarray, q: np.ndarray | None) -> float:
    """:func:`bhattacharyya` (p, q) for a float32 histogram ``p`` of ImageFeatures."""
    if q is None or not p.any():
        return 1.0  # an empty histogram is at distance 1
    return min(1.0, max(0.0, cv2.compareHist(p, q, cv2.HISTCMP_BHATTACHARYYA)))
