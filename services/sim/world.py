"""The static world as flat numpy arrays, ready for vectorised ray casting and rendering.

Everything is an upright extrusion of 2-D geometry on the floor (world frame, REP-103):

* segments ``(M, 4)`` rows ``[x0, y0, x1, y1]``: walls and the four faces of each box;
* circles ``(K, 3)`` rows ``[x, y, r]``: table and chair legs, pillars, bins;

each with a height (m; the laser at 0.4 m sees anything taller) and a colour (BGR, for the
camera). A "door corner" is not a special type: a door jamb is a small box, and a jamb turned
45 deg shows the laser a convex corner of leg-like width (thesis 5.2.4.2, Figure 5.6 b-3).
People are not part of the static world; see ``people.py``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from .scenario import WorldSpec

__all__ = ["StaticWorld", "rgb_to_bgr"]


def rgb_to_bgr(rgb: tuple[int, int, int]) -> tuple[int, int, int]:
    return (int(rgb[2]), int(rgb[1]), int(rgb[0]))


@dataclass(frozen=True, slots=True)
class StaticWorld:
    segments: np.ndarray
    """(M, 4) float64 [x0, y0, x1, y1]."""
    segment_height_m: np.ndarray
    """(M,)"""
    segment_colour: np.ndarray
    """(M, 3) uint8 BGR."""
    segment_is_wall: np.ndarray
    """(M,) bool: True for walls, False for box faces (walls get the panel texture)."""
    circles: np.ndarray
    """(K, 3) float64 [x, y, r]."""
    circle_height_m: np.ndarray
    circle_colour: np.ndarray
    floor_bgr: tuple[int, int, int]
    ceiling_bgr: tuple[int, int, int]
    light_zones: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    """(Z, 6) float64 [cx, cy, half_x, half_y, gain, edge_m]: people's light (LightZoneSpec)."""

    @classmethod
    def from_spec(cls, spec: WorldSpec) -> StaticWorld:
        segs: list[list[float]] = []
        heights: list[float] = []
        colours: list[tuple[int, int, int]] = []
        is_wall: list[bool] = []
        for wall in spec.walls:
            pts = list(wall.points)
            if wall.closed:
                pts.append(pts[0])
            for a, b in itertools.pairwise(pts):
                if a == b:
                    continue
                segs.append([a[0], a[1], b[0], b[1]])
                heights.append(wall.height_m)
                colours.append(rgb_to_bgr(wall.colour_rgb))
                is_wall.append(True)
        for box in spec.boxes:
            c, s = math.cos(math.radians(box.yaw_deg)), math.sin(math.radians(box.yaw_deg))
            hl, hw = box.size_m[0] / 2, box.size_m[1] / 2
            corners = [
                (box.centre[0] + c * dx - s * dy, box.centre[1] + s * dx + c * dy)
                for dx, dy in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))
            ]
            for i in range(4):
                a, b = corners[i], corners[(i + 1) % 4]
                segs.append([a[0], a[1], b[0], b[1]])
                heights.append(box.height_m)
                colours.append(rgb_to_bgr(box.colour_rgb))
                is_wall.append(False)
        circles = [[c.centre[0], c.centre[1], c.radius_m] for c in spec.circles]
        return cls(
            segments=np.asarray(segs, dtype=np.float64).reshape(-1, 4),
            segment_height_m=np.asarray(heights, dtype=np.float64),
            segment_colour=np.asarray(colours, dtype=np.uint8).reshape(-1, 3),
            segment_is_wall=np.asarray(is_wall, dtype=bool),
            circles=np.asarray(circles, dtype=np.float64).reshape(-1, 3),
            circle_height_m=np.asarray([c.height_m for c in spec.circles], dtype=np.float64),
            circle_colour=np.asarray(
                [rgb_to_bgr(c.colour_rgb) for c in spec.circles], dtype=np.uint8
            ).reshape(-1, 3),
            floor_bgr=rgb_to_bgr(spec.floor_rgb),
            ceiling_bgr=rgb_to_bgr(spec.ceiling_rgb),
            light_zones=np.asarray(
                [
                    [z.centre[0], z.centre[1], z.size_m[0] / 2, z.size_m[1] / 2, z.gain, z.edge_m]
                    for z in spec.light_zones
                ],
                dtype=np.float64,
            ).reshape(-1, 6),
        )

    def light_at(self, x_m: float, y_m: float) -> float:
        """The light zones' gain at a floor point: each zone's gain inside it, blending
        linearly to 1 over its edge outside; overlapping zones multiply. 1 with no zones."""
        k = 1.0
        for cx, cy, hx, hy, gain, edge in self.light_zones.tolist():
            d = math.hypot(max(abs(x_m - cx) - hx, 0.0), max(abs(y_m - cy) - hy, 0.0))
            if d <= 0.0:
                k *= gain
            elif d < edge:
                k *= gain + (1.0 - gain) * d / edge
        return k

    def segments_taller_than(self, height_m: float) -> np.ndarray:
        """Segments a sensor at ``height_m`` sees (rows of :attr:`segments`)."""
        return self.segments[self.segment_height_m > height_m]

    def circles_taller_than(self, height_m: float) -> np.ndarray:
        return self.circles[self.circle_height_m > height_m]

    def clearance_m(self, x_m: float, y_m: float) -> float:
        """Distance from the floor point (x, y) to the nearest wall, box face or circle's edge
        (negative inside a circle; inf in an empty world). The robot's bumper
        (``DiffDriveRobot``) keeps it at least the body's radius."""
        best = math.inf
        if len(self.segments):
            a = self.segments[:, :2]
            ab = self.segments[:, 2:] - a
            ap = np.array([x_m, y_m]) - a
            t = np.clip((ap * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-18), 0.0, 1.0)
            d = ap - t[:, None] * ab
            best = float(np.sqrt((d * d).sum(1).min()))
        if len(self.circles):
            c = self.circles
            best = min(best, float((np.hypot(c[:, 0] - x_m, c[:, 1] - y_m) - c[:, 2]).min()))
        return best
