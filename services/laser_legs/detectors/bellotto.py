"""Leg patterns from vertical edges (seed 002, Bellotto & Hu 2009, II-A and Table I).

1. Preprocessing: a local minimisation operator (removes spikes from reflections on sloped
   surfaces), then a local maximisation operator (discards thin objects such as table legs).
   On the range signal a minimum over ``w_min`` beams widens near objects by ``(w_min-1)/2``
   beams a side and removes far spikes narrower than ``w_min``; the maximum over
   ``w_max > w_min`` beams then removes near objects (dips) of at most ``w_max - w_min`` beams
   and leaves the others ``(w_max - w_min)/2`` beams narrower a side. Windows are given at
   0.5 deg and scaled to the scanner's resolution. Beams without return count as far.
2. Vertical edges: a doublet ``(r_i, r_i+1)`` with ``|r_i+1 - r_i| > edge_jump_m``;
   ``L`` when the range drops (``r_i > r_i+1``: an object begins, in beam order), ``R`` when it
   rises. Adjacent edges of the same type (consecutive doublets) are joined into one.
3. Patterns, extracted in this order, each edge used once (Table I):
   ``LA`` (legs apart) ``{L, R, L, R}``: two legs each of width ``a``, centres less than the
   step length ``b`` apart; ``FS`` (forward straddle) ``{L, L, R}`` or ``{L, R, R}``: one
   object of width ``a..c`` in two parts whose depth step is below ``b``; ``SL`` (single leg
   or legs together) ``{L, R}`` of width ``a_min..c_max``.
   Constraints (IV-A): leg width ``10 < a < 20 cm``, step ``b < 40 cm``, two legs together
   ``10 < c < 40 cm``.

The person is at the midpoint of its pattern (mean of its legs). Legs carry the raw beams of
their span (a span that holds a beam without return is dropped); their position is the
centroid of those raw points. The preprocessing narrows objects, so widths are measured as the
chord between a span's end points plus the beams lost a side and one beam spacing (the end
beams lie inside the outline). ``edge_jump_m`` and the windows are not given in seed 002; the
defaults are choices (documented in docs/laser_legs.md).
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from followbot.schemas import Candidate, LaserScan, Leg, PersonCandidates
from followbot.services.common.scan import valid_mask

from ..core import LaserPose, Prediction
from ..message import candidates_message, person

__all__ = ["BellottoSettings", "EdgePatternDetector"]

_HALF_DEG = math.radians(0.5)


class BellottoSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of :class:`EdgePatternDetector`; a, b, c are seed 002's (IV-A)."""

    min_window_beams: int = 3  # seed 002 II-A "local minimization": window not given
    max_window_beams: int = 5  # seed 002 II-A "local maximization": window not given
    edge_jump_m: float = 0.10  # seed 002 II-A edge threshold: value not given
    far_m: float = 100.0  # range given to beams without return (far background)
    leg_min_m: float = 0.10  # seed 002 IV-A: 10 < a
    leg_max_m: float = 0.20  # seed 002 IV-A: a < 20 cm
    step_max_m: float = 0.40  # seed 002 IV-A: b < 40 cm
    together_min_m: float = 0.10  # seed 002 IV-A: 10 < c
    together_max_m: float = 0.40  # seed 002 IV-A: c < 40 cm
    gate_m: float = 0.40  # thesis 4.3.2 criterion 3, when a prediction is given
    la_confidence: float = 1.0  # seed 002: LA patterns are the most reliable
    fs_confidence: float = 0.8
    """PersonCandidate.confidence of an FS pattern (two legs, one hiding part of the other);
    seed 002 ranks FS between LA and SL."""
    sl_confidence: float = 0.4  # seed 002: SL patterns are the easiest to misinterpret

    def __post_init__(self) -> None:
        if self.min_window_beams < 1 or self.min_window_beams % 2 == 0:
            raise ValueError("min_window_beams must be odd and >= 1")
        if self.max_window_beams < self.min_window_beams or self.max_window_beams % 2 == 0:
            raise ValueError("max_window_beams must be odd and >= min_window_beams")
        if not 0 < self.leg_min_m < self.leg_max_m:
            raise ValueError("need 0 < leg_min_m < leg_max_m")
        if not 0 < self.together_min_m < self.together_max_m:
            raise ValueError("need 0 < together_min_m < together_max_m")
        for name in ("edge_jump_m", "far_m", "step_max_m", "gate_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")


def _window(beams_at_half_deg: int, increment_rad: float) -> int:
    """An odd window covering the same angle as ``beams_at_half_deg`` beams of 0.5 deg."""
    w = round(beams_at_half_deg * _HALF_DEG / increment_rad)
    return max(1, w | 1)


def _running(a: np.ndarray, w: int, op) -> np.ndarray:
    """Running min/max over ``w`` (odd) beams, edges padded with the end values."""
    if w <= 1 or a.shape[0] < 2:
        return a
    h = w // 2
    p = np.concatenate([np.full(h, a[0]), a, np.full(h, a[-1])])
    out = p[: a.shape[0]].copy()
    for k in range(1, w):
        op(out, p[k : k + a.shape[0]], out=out)
    return out


_Edge = tuple[str, int, int]
"""A joined vertical edge: type ("L" or "R"), first and last doublet."""
_Span = tuple[int, int]
"""First and last beam of an object, inclusive."""
_LegFit = tuple[float, float, float]
"""(x, y, width) of a leg, m."""
_Part = tuple[_Span, _LegFit]
_Pattern = tuple[str, list[_Part]]
"""A pattern's name ("LA", "FS", "SL") and its legs."""


class _Spans:
    """Objects of one scan as beam spans, and the legs they make (raw points, bearings)."""

    def __init__(
        self, raw: np.ndarray, valid: np.ndarray, angles: np.ndarray, inc: float, lost: int
    ) -> None:
        self.raw, self.valid, self.angles = raw, valid, angles
        self.inc = inc
        """Beam spacing, rad."""
        self.lost = lost
        """Beams the preprocessing takes off each side of an object."""

    def span(self, first: int, last: int) -> _Span | None:
        """Beams ``first..last``; None when outside the scan or one of them has no return."""
        if not 0 <= first <= last < self.raw.shape[0] or not self.valid[first : last + 1].all():
            return None
        return first, last

    def between(self, left: _Edge, right: _Edge) -> _Span | None:
        """The object between an L edge and the next R edge: beams (L.last + 1) .. R.first."""
        return self.span(left[2] + 1, right[1])

    def leg(self, span: _Span) -> _LegFit:
        """(x, y, width) of the raw points of ``span``: their centroid, and the chord between
        the end points widened by the beams the preprocessing took off and one beam spacing."""
        raw, angles = self.raw, self.angles
        a, b = span
        rr, aa = raw[a : b + 1], angles[a : b + 1]
        x = float(np.mean(rr * np.cos(aa)))
        y = float(np.mean(rr * np.sin(aa)))
        xa, ya = raw[a] * math.cos(angles[a]), raw[a] * math.sin(angles[a])
        xb, yb = raw[b] * math.cos(angles[b]), raw[b] * math.sin(angles[b])
        r_mid = 0.5 * (raw[a] + raw[b])
        width = math.hypot(xb - xa, yb - ya) + (1 + 2 * self.lost) * r_mid * self.inc
        return x, y, float(width)


class EdgePatternDetector:
    """LA / FS / SL leg patterns from vertical edges (seed 002)."""

    name = "bellotto"
    settings_type = BellottoSettings

    def __init__(self, settings: BellottoSettings | None = None) -> None:
        self.settings = settings or BellottoSettings()

    def preprocess(self, scan: LaserScan) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """(raw ranges as float64, validity, preprocessed ranges, |increment|)."""
        s = self.settings
        raw = scan.ranges_m().astype(np.float64)
        valid = valid_mask(raw, scan.range_min_m, scan.range_max_m)
        inc = abs(float(scan.angle_increment_rad)) or _HALF_DEG
        r = np.where(valid, raw, s.far_m)
        wmin = _window(s.min_window_beams, inc)
        wmax = max(_window(s.max_window_beams, inc), wmin)
        pre = _running(_running(r, wmin, np.minimum), wmax, np.maximum)
        return raw, valid, pre, inc

    def edges(self, pre: np.ndarray) -> list[tuple[str, int, int]]:
        """Joined vertical edges in beam order: (type, first doublet, last doublet)."""
        d = pre[1:] - pre[:-1]
        idx = np.flatnonzero(np.abs(d) > self.settings.edge_jump_m)
        kinds = np.where(d[idx] < 0, "L", "R").tolist()
        out: list[tuple[str, int, int]] = []
        for kind, i in zip(kinds, idx.tolist(), strict=True):
            if out and out[-1][0] == kind and out[-1][2] == i - 1:
                out[-1] = (kind, out[-1][1], i)  # adjacent and aligned: one longer edge
            else:
                out.append((kind, i, i))
        return out

    def detect(
        self, scan: LaserScan, prediction: Prediction = None, pose: LaserPose = None
    ) -> PersonCandidates:
        s = self.settings
        if scan.ranges.shape[0] < 3:
            return candidates_message(scan, self.name, [])
        raw, valid, pre, inc = self.preprocess(scan)
        edges = self.edges(pre)
        if len(edges) < 2:
            return candidates_message(scan, self.name, [])
        lost = (max(_window(s.max_window_beams, inc), 1) - _window(s.min_window_beams, inc)) // 2
        spans = _Spans(raw, valid, scan.angles_rad(), inc, lost)
        # Table I's order: each edge goes to the first pattern that takes it
        used = [False] * len(edges)
        found = self._legs_apart(spans, edges, used)
        found += self._forward_straddles(spans, edges, used, pre)
        found += self._single_legs(spans, edges, used)
        out = [self._candidate(spans, pattern, parts) for pattern, parts in found]
        if prediction is not None:
            out = [c for c in out if _near(c, prediction, s.gate_m)]
        out.sort(key=lambda c: c.legs[0].first_beam)
        return candidates_message(scan, self.name, out)

    def _legs_apart(self, spans: _Spans, edges: list[_Edge], used: list[bool]) -> list[_Pattern]:
        """LA: {L, R, L, R}, both legs of width a, centres closer than b; marks their edges."""
        s = self.settings
        kinds = [e[0] for e in edges]
        m = len(edges)
        found: list[_Pattern] = []
        for i in range(m - 3):
            if used[i] or kinds[i] != "L" or used[i + 1] or kinds[i + 1] != "R":
                continue
            sp1 = spans.between(edges[i], edges[i + 1])
            g1 = self._leg_sized(spans, sp1)
            if g1 is None:
                continue
            for j in range(i + 2, m - 1):
                if used[j] or kinds[j] != "L" or used[j + 1] or kinds[j + 1] != "R":
                    continue
                sp2 = spans.between(edges[j], edges[j + 1])
                g2 = self._leg_sized(spans, sp2)
                if g2 is not None and math.hypot(g2[0] - g1[0], g2[1] - g1[1]) < s.step_max_m:
                    found.append(("LA", [(sp1, g1), (sp2, g2)]))
                    used[i] = used[i + 1] = used[j] = used[j + 1] = True
                    break
        return found

    def _forward_straddles(
        self, spans: _Spans, edges: list[_Edge], used: list[bool], pre: np.ndarray
    ) -> list[_Pattern]:
        """FS: {L, L, R} or {L, R, R} among the edges still free: one object of width
        a_min..c_max in two parts whose depth step (on the preprocessed ranges) is below b."""
        s = self.settings
        kinds = [e[0] for e in edges]
        free = [k for k in range(len(edges)) if not used[k]]
        found: list[_Pattern] = []
        for a_, b_, c_ in zip(free, free[1:], free[2:], strict=False):
            if used[a_] or used[b_] or used[c_] or kinds[a_] != "L":
                continue
            if kinds[b_] + kinds[c_] not in ("LR", "RR"):
                continue
            # LLR: the farther leg's visible part, then the nearer leg; LRR: the other way round
            p1 = spans.span(edges[a_][2] + 1, edges[b_][1])
            p2 = spans.span(edges[b_][2] + 1, edges[c_][1])
            whole = spans.span(edges[a_][2] + 1, edges[c_][1])
            if p1 is None or p2 is None or whole is None:
                continue
            step = abs(pre[edges[b_][2] + 1] - pre[edges[b_][1]])
            gw = spans.leg(whole)
            if step < s.step_max_m and s.leg_min_m < gw[2] < s.together_max_m:
                found.append(("FS", [(p1, spans.leg(p1)), (p2, spans.leg(p2))]))
                used[a_] = used[b_] = used[c_] = True
        return found

    def _single_legs(self, spans: _Spans, edges: list[_Edge], used: list[bool]) -> list[_Pattern]:
        """SL: {L, R} among the edges still free, a single leg or two legs together."""
        s = self.settings
        kinds = [e[0] for e in edges]
        found: list[_Pattern] = []
        for i in range(len(edges) - 1):
            if used[i] or used[i + 1] or kinds[i] != "L" or kinds[i + 1] != "R":
                continue
            sp = spans.between(edges[i], edges[i + 1])
            if sp is None:
                continue
            g = spans.leg(sp)
            if min(s.leg_min_m, s.together_min_m) < g[2] < s.together_max_m:
                found.append(("SL", [(sp, g)]))
                used[i] = used[i + 1] = True
        return found

    def _leg_sized(self, spans: _Spans, span: _Span | None) -> _LegFit | None:
        """The leg of ``span`` when its width is a single leg's (leg_min_m..leg_max_m)."""
        if span is None:
            return None
        g = spans.leg(span)
        return g if self.settings.leg_min_m < g[2] < self.settings.leg_max_m else None

    def _candidate(self, spans: _Spans, pattern: str, parts: list[_Part]) -> Candidate:
        """The person of one pattern, at the mean of its legs, with the pattern's confidence."""
        s = self.settings
        conf = {"LA": s.la_confidence, "FS": s.fs_confidence, "SL": s.sl_confidence}
        legs = [
            Leg(x_m=g[0], y_m=g[1], first_beam=sp[0], last_beam=sp[1], width_m=g[2])
            for sp, g in parts
        ]
        c = person(legs, pattern, conf[pattern])
        if pattern == "FS":  # one object: its width is the whole pattern's
            c.width_m = spans.leg((parts[0][0][0], parts[1][0][1]))[2]
        return c


def _near(c: Candidate, prediction: Prediction, radius_m: float) -> bool:
    px, py = float(prediction[0]), float(prediction[1])
    if not (math.isfinite(px) and math.isfinite(py)):
        return True
    return math.hypot(c.x_m - px, c.y_m - py) < radius_m
