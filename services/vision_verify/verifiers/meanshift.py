"""Mean-shift verifier (seed 003, Livingston): CamShift on a hue back-projection, per body half.

Model. The model rectangle is cut at its middle row. Every candidate's rectangle is centred on
the image's horizontal centre line and scaled with depth (core.py), so the cut falls at the
same height of the body at every depth (about the waist). Each half gets its own
hue x saturation histogram (``hue_bins`` = 16 as seed 003 V-B, ``sat_bins`` = 4;
``sat_bins`` = 1 is seed 003's hue-only histogram) of its perceivable pixels, masked as in
OpenCV's CamShift practice: S >= ``s_min``, ``v_min`` <= V <= ``v_max``.

Back-projection. The frame is back-projected once per cut row: rows above the cut through the
upper histogram, rows below it through the lower one, pixels outside the mask 0. A window on
a person dressed like the target sees the target's colours in both halves; on a person who
shares only the target's trousers, only below the cut.

Judging. From each candidate's rectangle CamShift climbs this back-projection to the nearest
mode (seed 003 V: a kernel tracker converges to a local optimum from its start). The columns
of the converged window, with the rectangle's rows and cut, give two half regions, and

    d_half = d_B(model half histogram, that half's histogram)               (eq. 4 of seed 003)
             or, when larger (``mass``), 1 - (back-projection mass per pixel there) / (the
             same for the model, measured by the same CamShift on the model's own frame)
    d = max(d_upper, d_lower) + drift_weight * drift          (``combine = "mean"``: the mean)
    drift = min(1, |u_window - u_candidate| / rectangle width)

so a person has to match the target in both halves; a window that collapses (none of the
target's colours near the candidate: d = 2) or runs off to another blob of the target's
colours is unlike the target.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import cv2
import msgspec
import numpy as np

from ..core import (
    ImageFeatures,
    Model,
    Rect,
    View,
    _bins,
    _scratch,
    bhattacharyya,
    check_histogram,
)

__all__ = ["MeanShiftSettings", "MeanShiftVerifier"]


class MeanShiftSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    hue_bins: int = 16  # seed 003 V-B: m = 16 hue bins
    sat_bins: int = 4  # 1: hue only, as seed 003
    s_min: int = 30  # OpenCV's camshift sample: smin 30, vmin 10 (seed 003 has no mask)
    v_min: int = 10
    """Pixels darker than this value (V, 0-255) are outside the mask (hue means little)."""
    v_max: int = 255
    """Pixels brighter than this value are outside the mask."""
    max_iterations: int = 10
    """CamShift stops after this many iterations if not converged (epsilon_px) sooner."""
    epsilon_px: float = 1.0  # seed 003 V-A: converged when the centre moves < 1 pixel
    drift_weight: float = 1.0
    """Weight of the window's drift (its shift over the rectangle's width) in the distance."""
    combine: Literal["max", "mean"] = "max"
    """How the halves' distances combine: both must match (max), or on average (mean)."""
    mass: bool = True
    """A half's distance is at least its shortfall of back-projection mass against the model."""
    default_threshold: float = 0.78
    """Calibrated on training scenes (``evaluate calibrate``: midway between the target's 99th
    percentile distance and the 1st percentile of bystanders seen apart from it). The
    whole-person hue version was at 0.71 and let a bystander in the target's trousers be chosen
    in 27 of 145 scans while the target was hidden (docs/vision_verify.md)."""


def _cut(rect: Rect) -> int:
    return (rect[1] + rect[3]) // 2


class MeanShiftVerifier:
    name = "meanshift"
    settings_type = MeanShiftSettings

    def __init__(self, settings: MeanShiftSettings | None = None) -> None:
        self.settings = settings or MeanShiftSettings()
        self.default_threshold = self.settings.default_threshold
        s = self.settings
        self._criteria = (
            cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT,
            s.max_iterations,
            s.epsilon_px,
        )
        self._bins = s.hue_bins * s.sat_bins
        if min(s.hue_bins, s.sat_bins) < 1 or self._bins > 255:
            raise ValueError("meanshift: hue_bins * sat_bins must be 1..255")
        h, sat = _bins(s.hue_bins, 180), _bins(s.sat_bins, 256)
        lut_h = np.where(h >= 0, h * s.sat_bins, 255)  # H >= 180 does not occur
        lut_s = np.where(sat >= 0, sat, 255)
        lut_s[: s.s_min] = 255
        v = np.arange(256)
        lut_v = np.where((v >= s.v_min) & (v <= s.v_max), 0, 255)
        self._luts = tuple(t.astype(np.uint8) for t in (lut_h, lut_s, lut_v))

    # ---------------------------------------------------------------- histograms

    def _index(self, frame: ImageFeatures) -> np.ndarray:
        """Per pixel its bin ``hue_bin * sat_bins + sat_bin`` (uint8), or 255 where the mask
        is off; once per frame. The bins are OpenCV's own (``cv2.calcHist`` would count each
        pixel in the same one), looked up in three 256-entry tables and added (saturating)."""
        index = frame.cache.get("ms_index")
        if index is None:
            lut_h, lut_s, lut_v = self._luts
            hsv = frame.hsv()
            planes = _scratch("ms_planes", (3, *hsv.shape[:2]), np.uint8)  # reused: see core
            cv2.split(hsv, list(planes))
            h, s, v = planes
            index = cv2.LUT(h, lut_h)
            cv2.LUT(s, lut_s, dst=h)
            cv2.add(index, h, dst=index)
            cv2.LUT(v, lut_v, dst=s)
            cv2.add(index, s, dst=index)
            frame.cache["ms_index"] = index
        return index

    def histogram(self, frame: ImageFeatures, rect: Rect) -> np.ndarray:
        """Hue x saturation histogram (hue-major) of the masked pixels of ``rect`` (float32,
        sums to 1, or all zero when no pixel passes the mask)."""
        x0, y0, x1, y1 = rect
        if x1 <= x0 or y1 <= y0:
            return np.zeros(self._bins, dtype=np.float32)
        part = self._index(frame)[y0:y1, x0:x1]
        hist = cv2.calcHist([part], [0], None, [self._bins], [0, self._bins]).ravel()
        total = float(hist.sum())
        return hist / total if total > 0 else hist

    def halves(self, frame: ImageFeatures, rect: Rect) -> list[np.ndarray]:
        """The upper and lower half histograms of ``rect`` (cut at its middle row)."""
        x0, y0, x1, y1 = rect
        mid = _cut(rect)
        return [self.histogram(frame, (x0, y0, x1, mid)), self.histogram(frame, (x0, mid, x1, y1))]

    def back_projection(
        self, frame: ImageFeatures, hists: Sequence[np.ndarray], cut: int
    ) -> np.ndarray:
        """The frame's back-projection (uint8): rows above ``cut`` through the upper
        histogram, the rest through the lower one, each scaled to a peak of 255, 0 where the
        mask is off. Once per frame, model and cut row."""
        key = ("ms_back", cut, hists[0].tobytes(), hists[1].tobytes())
        back = frame.cache.get(key)
        if back is None:
            index = self._index(frame)
            back = np.empty_like(index)
            for rows, hist in ((slice(0, cut), hists[0]), (slice(cut, None), hists[1])):
                table = np.zeros(256, dtype=np.uint8)  # 255 (masked) stays 0
                peak = float(hist.max())
                if peak > 0:
                    table[: self._bins] = np.rint(hist * (255.0 / peak)).clip(0, 255)
                if index[rows].size:
                    back[rows] = cv2.LUT(index[rows], table)
            frame.cache[key] = back
        return back

    def _window(self, back: np.ndarray, rect: Rect) -> tuple[int, int] | None:
        """Columns [a, b) of the CamShift window converged from ``rect``; None if it
        collapsed."""
        x0, y0, x1, y1 = rect
        box, (wx, _wy, ww, wh) = cv2.CamShift(back, (x0, y0, x1 - x0, y1 - y0), self._criteria)
        if min(box[1]) < 1.0 or ww < 2 or wh < 2:  # no mass: OpenCV returns an empty box
            return None
        return wx, wx + ww

    def _densities(self, back: np.ndarray, cols: tuple[int, int], rect: Rect) -> list[float]:
        """Mean back-projection (0..1) of the upper and lower half of ``rect``'s rows in
        columns ``cols``."""
        a, b = cols
        y0, mid, y1 = rect[1], _cut(rect), rect[3]
        return [
            float(cv2.mean(back[r0:r1, a:b])[0]) / 255.0 if r1 > r0 else 0.0
            for r0, r1 in ((y0, mid), (mid, y1))
        ]

    # ---------------------------------------------------------------- plugin interface

    def learn(self, frame: ImageFeatures, rect: Rect, view: View) -> dict[str, np.ndarray]:
        hists = [h.astype(np.float32) for h in self.halves(frame, rect)]
        back = self.back_projection(frame, hists, _cut(rect))
        cols = self._window(back, rect) or (rect[0], rect[2])
        dens = self._densities(back, cols, rect)
        return {
            "hs_upper": hists[0],
            "hs_lower": hists[1],
            "mass": np.array(dens, dtype=np.float32),
        }

    def describe(self, frame: ImageFeatures, rect: Rect) -> dict[str, np.ndarray]:
        up, low = self.halves(frame, rect)
        return {"hs_upper": up, "hs_lower": low}

    def check_model(self, model: Model) -> None:
        """ValueError unless the features are what :meth:`learn` gives with these settings:
        ``hs_upper`` and ``hs_lower`` of hue_bins x sat_bins bins, each summing to 1 (0: no
        pixel passed the mask), and ``mass``, if there, two densities in [0, 1]."""
        f = model.features
        for name in ("hs_upper", "hs_lower"):
            try:
                check_histogram(f, name, self._bins, (1.0, 0.0))
            except ValueError as exc:
                raise ValueError(f"{exc} (meanshift with {self._bins} bins)") from None
        mass = f.get("mass")
        if mass is not None and (
            mass.shape != (2,) or mass.dtype.kind != "f" or not ((mass >= 0) & (mass <= 1)).all()
        ):
            raise ValueError(f"'mass' must be two densities in [0, 1], got {mass!r}")

    def _model(self, model: Model) -> tuple[list[np.ndarray], list[float]]:
        hists = []
        for name in ("hs_upper", "hs_lower"):
            h = model.features.get(name)
            if h is None or h.shape != (self._bins,):
                raise ValueError(
                    f"the model has no {self._bins}-bin {name} histogram (a meanshift model "
                    "from before the split into halves, or other bins: acquire the target again)"
                )
            hists.append(h)
        mass = model.features.get("mass")
        dens = [float(m) for m in mass] if mass is not None and mass.shape == (2,) else [0.0, 0.0]
        return hists, dens

    def distances(
        self, frame: ImageFeatures, views: Sequence[View], model: Model
    ) -> list[float | None]:
        hists, model_dens = self._model(model)
        if not any(v.ok for v in views):
            return [None] * len(views)
        s = self.settings
        out: list[float | None] = []
        for v in views:
            if not v.ok:
                out.append(None)
                continue
            x0, y0, x1, y1 = v.rect
            mid = _cut(v.rect)
            back = self.back_projection(frame, hists, mid)
            cols = self._window(back, v.rect)
            if cols is None:
                out.append(2.0)  # collapsed: none of the target's colours near the candidate
                continue
            a, b = cols
            ds = [
                bhattacharyya(self.histogram(frame, (a, r0, b, r1)), hist)
                for (r0, r1), hist in zip(((y0, mid), (mid, y1)), hists, strict=True)
            ]
            if s.mass:
                for k, (seen, want) in enumerate(
                    zip(self._densities(back, cols, v.rect), model_dens, strict=True)
                ):
                    if want > 0:
                        ds[k] = max(ds[k], 1.0 - min(1.0, seen / want))
            d = max(ds) if s.combine == "max" else 0.5 * (ds[0] + ds[1])
            drift = min(1.0, abs(0.5 * (a + b) - v.u_px) / max(1, x1 - x0))
            out.append(d + s.drift_weight * drift)
        return out
