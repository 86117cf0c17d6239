"""Where the laser sits on the robot: its pose in the base frame, one setting for every stage.

The laser's scans, and the person candidates laser_legs finds in them, are in the *laser*
frame; odometry moves the *base* (``base_link``, REP-105), and the tracker, the controller and
everything they publish work in the base frame. :class:`LaserMount` is the laser's pose in the
base frame (REP-103: x forward, y left, yaw counter-clockwise), so that

    p_base = R(yaw) p_laser + (x, y)        p_laser = R(-yaw) (p_base - (x, y))

Every service has it as the ``laser_mount`` setting (:class:`NodeSettings
<followbot.services.runtime.settings.NodeSettings>`), written once for a robot: at the top of a
compose file or a group's settings file (docs/robot.md "Where the sensors sit").
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec
import numpy as np

from followbot.schemas import PersonCandidates

__all__ = ["BASE_FRAME", "LaserMount", "candidates_in_base", "parse_laser_pose"]

#: The name of the base frame (REP-105) in the frame_id of what the tracker publishes.
BASE_FRAME = "base_link"

_Offset = Annotated[float, msgspec.Meta(ge=-100.0, le=100.0)]


class LaserMount(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The laser's pose in the base frame: ``x_m`` forward, ``y_m`` left of the base's origin
    (metres), turned ``yaw_deg`` counter-clockwise from the base's +x (degrees)."""

    x_m: _Offset = 0.0
    """How far ahead of the base's origin the laser sits (m)."""
    y_m: _Offset = 0.0
    """How far left of the base's origin the laser sits (m)."""
    yaw_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    """How far the laser is turned counter-clockwise from the base's +x (degrees)."""

    @property
    def yaw_rad(self) -> float:
        return math.radians(self.yaw_deg)

    @property
    def is_identity(self) -> bool:
        """The laser frame is the base frame (nothing to transform)."""
        return self.x_m == 0.0 and self.y_m == 0.0 and self.yaw_deg % 360.0 == 0.0

    def pose(self) -> tuple[float, float, float]:
        """(x_m, y_m, yaw_rad)."""
        return self.x_m, self.y_m, self.yaw_rad

    def to_base(self, points) -> np.ndarray:
        """(k, 2) laser-frame points in the base frame: R(yaw) p + (x, y)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.column_stack(
            [c * p[:, 0] - s * p[:, 1] + self.x_m, s * p[:, 0] + c * p[:, 1] + self.y_m]
        )

    def to_laser(self, points) -> np.ndarray:
        """(k, 2) base-frame points in the laser frame: R(-yaw) (p - (x, y))."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        dx, dy = p[:, 0] - self.x_m, p[:, 1] - self.y_m
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.column_stack([c * dx + s * dy, -s * dx + c * dy])

    def describe(self) -> str:
        return f"x {self.x_m:.3f} m, y {self.y_m:.3f} m, yaw {self.yaw_deg:.1f} deg"


def candidates_in_base(msg: PersonCandidates, mount: LaserMount) -> PersonCandidates:
    """``msg`` (the laser frame of its scan) in the base frame: every candidate's and leg's
    position, and its range and bearing from the base's origin; ``frame_id`` becomes
    :data:`BASE_FRAME`. The ``horizon`` and ``reach_m`` stay what the laser saw, from where it
    sits (their users turn base-frame points into the laser frame to read them)."""
    if mount.is_identity:
        return msgspec.structs.replace(msg, frame_id=BASE_FRAME)
    cands = msg.candidates
    xy = mount.to_base([[c.x_m, c.y_m] for c in cands])
    legs = mount.to_base([[leg.x_m, leg.y_m] for c in cands for leg in c.legs]).tolist()
    out, k = [], 0
    for c, (x, y) in zip(cands, xy.tolist(), strict=True):
        moved = []
        for leg in c.legs:
            moved.append(msgspec.structs.replace(leg, x_m=legs[k][0], y_m=legs[k][1]))
            k += 1
        out.append(
            msgspec.structs.replace(
                c,
                x_m=x,
                y_m=y,
                range_m=math.hypot(x, y),
                bearing_rad=math.atan2(y, x),
                legs=moved,
            )
        )
    return msgspec.structs.replace(msg, frame_id=BASE_FRAME, candidates=out)


def parse_laser_pose(text: str) -> LaserMount:
    """``"x,y,yaw_deg"`` (metres, metres, degrees) as a :class:`LaserMount`; a ValueError that
    says the expected form otherwise."""
    parts = [p.strip() for p in text.split(",")]
    try:
        if len(parts) != 3:
            raise ValueError
        x, y, yaw = (float(p) for p in parts)
        if not all(math.isfinite(v) for v in (x, y, yaw)):
            raise ValueError
        return msgspec.convert({"x_m": x, "y_m": y, "yaw_deg": yaw}, LaserMount)
    except (ValueError, msgspec.ValidationError):
        raise ValueError(
            f"laser pose {text!r}: expected x,y,yaw_deg (metres forward and left of the base, "
            "degrees counter-clockwise), e.g. 0.88,0,42"
        ) from None
