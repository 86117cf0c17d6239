"""Seed 001's following rule (Zhuang et al. 4, 5.1): turn toward the person's image column,
keep a distance band measured through the floor.

- Turn: by k_p (x_p - x_0), x_p the person's column, x_0 the image centre; here as a turn rate
  (rad/s) toward the person: w = -k_p (x_p - x_0) (a column right of centre is a bearing to the
  right, a negative, clockwise turn in REP-103).
- Dead band: still while x_p is within 76-116 px of a 192x144 image (seed 5.1), i.e. within
  +-20/192 of the width about the centre, scaled to the image's actual width. The seed says
  "on the y-axis" of the 192x144 image; 76-116 is centred on 96 = 192 / 2, the *horizontal*
  centre, and the rule turns the robot, so it is the column (x), as implemented and tested.
- Distance (from the floor point under the person, equations 15-16): beyond ``max_distance_m``
  move forward, inside ``safe_distance_m`` back off, between them stand. The seed gives no
  distances or speeds; the defaults keep the feet in view of a low level camera (below) and
  use the thesis's 0.75 m/s top speed.

The rule returns a wish; followbot's controller (``rule: zhuang``, core.py) applies its limits
and watchdog to it and holds the camera's pan at 0, as the seed's camera is fixed.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec

__all__ = ["ZhuangRule", "ZhuangSettings"]

_SEED_WIDTH_PX = 192.0  # seed 5.1: 192x144 images
_SEED_BAND_PX = (76.0, 116.0)  # seed 5.1: still while the person is within 76-116 px


class ZhuangSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    k_p: Annotated[float, msgspec.Meta(gt=0, le=1)] = 0.01
    """Turn rate per pixel off centre at 192 px wide, rad/s/px (scaled by 192 / width)."""
    dead_band_px: tuple[float, float] = _SEED_BAND_PX
    """Columns of a 192 px wide image inside which the robot does not turn (seed 5.1)."""
    # the seed gives no distances: a band a level camera 0.4 m high (a Pioneer 3's top plate)
    # can measure, its floor visible from 1.2 m on
    safe_distance_m: Annotated[float, msgspec.Meta(gt=0)] = 1.5
    """Nearer than this (m, from the camera) the robot backs off (limits.reverse permitting)."""
    max_distance_m: Annotated[float, msgspec.Meta(gt=0)] = 2.5
    """Farther than this (m, from the camera) the robot moves forward."""
    forward_mps: Annotated[float, msgspec.Meta(gt=0, le=2)] = 0.75
    """Forward speed beyond max_distance_m (m/s)."""
    back_mps: Annotated[float, msgspec.Meta(gt=0, le=2)] = 0.2
    """Backing-off speed inside safe_distance_m (m/s)."""
    hfov_deg: Annotated[float, msgspec.Meta(gt=1, lt=170)] = 47.5
    """The camera's horizontal field of view (the simulator's): the target's bearing gives its
    column in the image through it."""
    camera_x_m: Annotated[float, msgspec.Meta(ge=-10, le=10)] = 0.0
    """The camera ahead of the base's origin (m): bearing and distance are taken from it."""

    def __post_init__(self) -> None:
        lo, hi = self.dead_band_px
        if not 0.0 <= lo <= hi <= _SEED_WIDTH_PX:
            raise ValueError(f"dead_band_px {self.dead_band_px}: expected 0 <= lo <= hi <= 192")
        if not self.safe_distance_m < self.max_distance_m:
            raise ValueError(
                f"safe_distance_m {self.safe_distance_m} must be below max_distance_m "
                f"{self.max_distance_m}"
            )


class ZhuangRule:
    """(linear m/s, angular rad/s) from the person's column and floor distance."""

    def __init__(self, settings: ZhuangSettings | None = None) -> None:
        self.settings = settings or ZhuangSettings()

    def follow(self, x_m: float, y_m: float) -> tuple[float, float]:
        """(v, w) for a target at (x, y) in the base frame: its column in the seed's 192 px
        image (a pinhole with ``hfov_deg``) and its distance, both from the camera."""
        s = self.settings
        dx = x_m - s.camera_x_m
        if dx <= 0.0:  # beside or behind the camera: not in the image, turn toward it
            x_px = 0.0 if y_m < 0 else _SEED_WIDTH_PX
        else:
            f = (_SEED_WIDTH_PX / 2.0) / math.tan(math.radians(s.hfov_deg) / 2.0)
            x_px = _SEED_WIDTH_PX / 2.0 - f * y_m / dx
        return self.command(x_px, int(_SEED_WIDTH_PX), math.hypot(dx, y_m))

    def command(self, x_px: float, image_width: int, distance_m: float) -> tuple[float, float]:
        s = self.settings
        scale = image_width / _SEED_WIDTH_PX
        lo, hi = s.dead_band_px[0] * scale, s.dead_band_px[1] * scale
        x0 = image_width / 2.0
        w = 0.0 if lo <= x_px <= hi else -s.k_p / scale * (x_px - x0)
        if not math.isfinite(distance_m):
            v = 0.0  # no floor point (feet out of the image): turn only
        elif distance_m > s.max_distance_m:
            v = s.forward_mps
        elif distance_m < s.safe_distance_m:
            v = -s.back_mps
        else:
            v = 0.0
        return v, w
