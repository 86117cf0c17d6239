"""Pixel <-> floor point through a pinhole camera at height H, pitched by an elevation angle.

Seed 001 (Zhuang et al.), section 4, equations 15-16: a pixel (x_p, y_p) of a camera at height
``H`` above the floor with elevation ``alpha`` (positive: the optical axis tilted *up*; a camera
looking down at the floor has a negative alpha) and intrinsics f_cx, f_cy, c_x, c_y sees the
floor point, in the camera's floor frame (x forward, y left, REP-103),

    x_r = (f_cx H cos a + H sin a (y_p - c_y)) / ((y_p - c_y) cos a - f_cy sin a)      (15)
    y_r = (x_p - c_x) (H sin a - x_r cos a) / f_cx                                      (16)

Equation 15 as printed uses f_cx in the numerator; derived from the pinhole it is f_cy (the
two are equal for square pixels, as in the simulator and on the seed's camera). Equation 16
is right as printed with y to the left. The inverse (floor -> pixel), from the same model:

    z_c = x_r cos a - H sin a                (depth along the optical axis)
    y_p = c_y + f_cy (H cos a + x_r sin a) / z_c
    x_p = c_x - f_cx y_r / z_c

Only pixels below the horizon (``y_p - c_y > f_cy tan a``) see the floor; the others have no
floor point (:func:`pixel_to_floor` returns NaN for them). ``mount_x_m`` puts the camera ahead
of the robot's base origin and ``pan_rad`` turns it about the vertical axis; both are applied
after equations 15-16 so the base-frame point is what the tracker and controller reason on.

Shared by the camera candidate source (services/camera_blobs) and the hybrid filter
(services/tracker/estimators/hybrid.py), so both read the image the same way.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

__all__ = ["GroundCamera"]


class GroundCamera(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A pinhole camera over a flat floor. Defaults: the simulator's camera (320x240, 47.5 deg
    horizontal field of view, 1.0 m high, level)."""

    width: int = 320
    """Image width, pixels."""
    height: int = 240
    """Image height, pixels."""
    hfov_deg: float = 47.5
    """Horizontal field of view; square pixels, so f_cx = f_cy = (width / 2) / tan(hfov / 2)."""
    height_m: float = 1.0
    """H: the optical centre above the floor."""
    elevation_deg: float = 0.0
    """alpha: tilt of the optical axis above the horizontal (negative: looking down)."""
    mount_x_m: float = 0.0
    """The camera ahead of the base origin."""

    def __post_init__(self) -> None:
        if not (self.width >= 2 and self.height >= 2):
            raise ValueError(f"camera image {self.width}x{self.height}: need at least 2x2")
        if not 1.0 < self.hfov_deg < 170.0:
            raise ValueError(f"camera hfov_deg {self.hfov_deg}: expected 1 < hfov < 170")
        if not self.height_m > 0.0:
            raise ValueError(f"camera height_m {self.height_m}: must be above the floor (> 0)")
        if not -80.0 < self.elevation_deg < 80.0:
            raise ValueError(f"camera elevation_deg {self.elevation_deg}: expected -80..80")

    @property
    def focal_px(self) -> float:
        return (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def centre(self) -> tuple[float, float]:
        return self.width / 2.0, self.height / 2.0

    def above_floor(self, z_m: float) -> GroundCamera:
        """The same camera reading pixels as points of the plane ``z_m`` above the floor (the
        bottom edge of a coloured region that stops short of the floor: trousers over shoes)."""
        if not 0.0 <= z_m < self.height_m:
            raise ValueError(f"a plane {z_m} m above the floor: expected 0 <= z < {self.height_m}")
        return msgspec.structs.replace(self, height_m=self.height_m - z_m)

    def scaled(self, width: int, height: int) -> GroundCamera:
        """The same camera delivering ``width`` x ``height`` images (same field of view)."""
        return msgspec.structs.replace(self, width=width, height=height)

    def pixel_to_floor(
        self, x_px: np.ndarray, y_px: np.ndarray, pan_rad: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Equations 15-16, then mount and pan: base-frame floor points (m) of pixels; NaN for
        pixels at or above the horizon."""
        f = self.focal_px
        cx, cy = self.centre
        a = math.radians(self.elevation_deg)
        ca, sa, h = math.cos(a), math.sin(a), self.height_m
        dy = np.asarray(y_px, dtype=float) - cy
        den = dy * ca - f * sa
        with np.errstate(divide="ignore", invalid="ignore"):
            xr = (f * h * ca + h * sa * dy) / den  # (15)
            xr = np.where(den > 1e-9, xr, np.nan)
        yr = (np.asarray(x_px, dtype=float) - cx) * (h * sa - xr * ca) / f  # (16)
        return self._to_base(xr, yr, pan_rad)

    def floor_to_pixel(
        self, x_m: np.ndarray, y_m: np.ndarray, pan_rad: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Base-frame floor points to pixels (the inverse of :meth:`pixel_to_floor`); NaN for
        points at or behind the camera's image plane."""
        xr, yr = self._from_base(x_m, y_m, pan_rad)
        f = self.focal_px
        cx, cy = self.centre
        a = math.radians(self.elevation_deg)
        ca, sa, h = math.cos(a), math.sin(a), self.height_m
        zc = xr * ca - h * sa
        with np.errstate(divide="ignore", invalid="ignore"):
            zc = np.where(zc > 1e-9, zc, np.nan)
            return cx - f * yr / zc, cy + f * (h * ca + xr * sa) / zc

    def _to_base(self, xr, yr, pan_rad: float):
        c, s = math.cos(pan_rad), math.sin(pan_rad)
        return c * xr - s * yr + self.mount_x_m, s * xr + c * yr

    def _from_base(self, x_m, y_m, pan_rad: float):
        x = np.asarray(x_m, dtype=float) - self.mount_x_m
        y = np.asarray(y_m, dtype=float)
        c, s = math.cos(pan_rad), math.sin(pan_rad)
        return c * x + s * y, -s * x + c * y
