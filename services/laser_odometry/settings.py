"""laser_odometry's settings (beyond the seeds: none of the four seed systems estimates its own
ego-motion; they all read the robot's wheel odometry)."""

from __future__ import annotations

from typing import Annotated

import msgspec

from followbot.services.runtime.settings import NodeSettings

__all__ = ["LaserOdometrySettings", "MatchSettings"]


class MatchSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """How one scan is matched to the keyframe (services/common/scanmatch.py)."""

    stride: Annotated[int, msgspec.Meta(ge=1, le=16)] = 2
    """Every k-th beam of the new scan is matched (cost against accuracy)."""
    iterations: Annotated[int, msgspec.Meta(ge=1, le=100)] = 15
    """Gauss-Newton iterations at most per match (it stops earlier once the step is tiny)."""
    max_distance_m: Annotated[
        tuple[Annotated[float, msgspec.Meta(gt=0, le=5)], ...], msgspec.Meta(min_length=1)
    ] = (0.4, 0.2, 0.1)
    """Inlier distance of the first iterations, one per iteration; the last holds after."""
    min_inliers: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.3
    """A match whose share of inlier points at the last distance is smaller failed."""
    recovery_turns_deg: tuple[Annotated[float, msgspec.Meta(gt=0, le=180)], ...] = (
        15.0,
        30.0,
        50.0,
        80.0,
    )
    """When the match from the constant-velocity guess fails, it is tried again from the guess
    turned this much either way, and from no motion and no motion turned, the best kept (a
    sudden turn or stop; a slow scanner's large steps). Empty: no second try."""
    normal_max_chord_m: Annotated[float, msgspec.Meta(gt=0, le=5)] = 0.5
    """A beam's surface normal comes from its two neighbours when their returns are at most
    this far apart (m): 0.5 keeps the walls of a 1° scanner out to ~14 m (laser_legs' static
    background uses 0.2: its scans are dense and near)."""
    min_points: Annotated[int, msgspec.Meta(ge=10, le=100000)] = 30
    """A scan with fewer valid returns (finite, within its range limits) is refused: counted,
    the pose carried on as after a failed match."""


class LaserOdometrySettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    match: MatchSettings = msgspec.field(default_factory=MatchSettings)
    """Scan matching (ICP) settings."""
    keyframe_distance_m: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.3
    """A scan matched farther than this from the keyframe becomes the next keyframe (m). Scans
    are matched against the keyframe, not the previous scan, so a still robot's pose does not
    wander with the matching noise."""
    keyframe_angle_deg: Annotated[float, msgspec.Meta(ge=0, le=180)] = 10.0
    """... or turned more than this from it (degrees)."""
    keyframe_min_inliers: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.4
    """... or matched with a smaller share of inliers (the view changed: people, doors)."""
    carry_twist_s: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.5
    """After a failed match or a refused scan the pose goes on along the last matched twist,
    for at most this long after the last good match; then it is held. 0: always held."""
    max_gap_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 1.0
    """A gap between scans longer than this: no constant-velocity guess (the match starts
    from no motion) and no twist carried."""
    odom_frame_id: str = "odom"
    """frame_id of the published Odometry (its pose starts at zero at the first scan)."""
    base_frame_id: str = "base_link"
    """child_frame_id of the published Odometry: the base, placed by laser_mount."""
