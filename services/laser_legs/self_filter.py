"""The robot's own body in its laser scans, found from the scans alone, and the candidates on it.

Every laser of the leg_tracker recordings sees part of the robot at the ends of its field of
view: beams that return 0.12–0.7 m every scan, whatever the robot does (negative_2: 18, 45 and
16 such beams on the left, rear and right lasers). A detector trained on one laser learns that
laser's body as clutter, but another laser's body has another shape: on the rear and right
lasers of negative_2, 59 % of ``learned``'s false person candidates were pieces of the robot
(docs/laser_legs.md, "Robot body": 2.12 -> 0.87 per scan with this filter).

ROS setups remove the body with a footprint filter someone has to measure and configure per
laser. This one needs no configuration: a beam belongs to the robot when it keeps returning the
same short range (within ``tolerance_m``, under ``max_range_m``) while the world moves past the
laser — over ``min_moving_scans`` scans in which at least ``moving_fraction`` of the beams
changed by more than ``change_m`` (the robot drove or turned). Nothing in the world stays put
in the laser's frame while the laser moves, except what the laser is mounted on. While the
robot stands still nothing new is learned (a person standing beside it would look the same),
and a beam that reads another range loses its evidence at once.

A candidate any of whose legs lies on a body beam is dropped. The beams themselves are not
blanked out before detection: a gap where the body was cuts the scan into new short segments
beside it, which look like legs (tried: on the training laser the false persons doubled).
"""

from __future__ import annotations

from typing import Annotated

import msgspec
import numpy as np

from followbot.schemas import LaserScan, PersonCandidates
from followbot.services.common.scan import valid_mask

from .core import LaserPose, LegDetector, Prediction

__all__ = ["RobotBodyFilter", "SelfFilterSettings", "SelfFilteredDetector", "on_mask"]


class SelfFilterSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """How a beam is recognised as the robot's body (defaults: physical choices, not tuned)."""

    max_range_m: Annotated[float, msgspec.Meta(gt=0, le=5)] = 1.0
    """Only returns nearer than this can be the robot (the recordings' bodies: 0.12–0.71 m)."""
    tolerance_m: Annotated[float, msgspec.Meta(gt=0, le=0.5)] = 0.03
    """A body beam reads within this of the range it first read (noise: ~1 cm)."""
    min_moving_scans: Annotated[int, msgspec.Meta(ge=1, le=10_000)] = 10
    """Scans with the world moving past the laser before a steady beam counts as the robot."""
    moving_fraction: Annotated[float, msgspec.Meta(gt=0, le=1)] = 0.3
    """A scan shows the laser moving when at least this share of the beams valid in it and in
    the scan before changed by more than ``change_m`` (negative_2, robot driving: 60–70 %;
    people walking past a still robot: a few %)."""
    change_m: Annotated[float, msgspec.Meta(gt=0, le=1)] = 0.05


class RobotBodyFilter:
    """Per-stream memory of which beams are the robot's body (see the module docstring)."""

    def __init__(self, settings: SelfFilterSettings | None = None) -> None:
        self.settings = settings or SelfFilterSettings()
        self.reset()

    def reset(self) -> None:
        self._key: tuple | None = None
        self._stamp_ns = -1
        self._prev: LaserScan | None = None
        self._ref = np.empty(0)
        self._evidence = np.empty(0, dtype=np.int64)

    def update(self, scan: LaserScan) -> np.ndarray:
        """Feed ``scan`` (streams in stamp order); the (n,) bool mask of its body beams."""
        s = self.settings
        r = scan.ranges.numpy()
        n = r.shape[0]
        key = (n, scan.frame_id, scan.angle_min_rad, scan.angle_increment_rad)
        if key != self._key or scan.stamp_ns < self._stamp_ns:
            # another laser, geometry or a replay from the start: learn afresh
            self._key = key
            self._prev = None
            self._ref = np.full(n, np.nan)
            self._evidence = np.zeros(n, dtype=np.int64)
        self._stamp_ns = scan.stamp_ns
        prev, self._prev = self._prev, scan
        with np.errstate(invalid="ignore"):
            # only beams near now, or near when last read, can be or have been the body
            idx = np.flatnonzero((r < s.max_range_m) | (self._ref == self._ref))
        mask = np.zeros(n, dtype=bool)
        if idx.size == 0:
            return mask
        now, ref = r[idx].astype(np.float64), self._ref[idx]
        valid_now = valid_mask(now, scan.range_min_m, scan.range_max_m)
        near = valid_now & (now < s.max_range_m)
        with np.errstate(invalid="ignore"):
            steady = near & (np.abs(now - ref) <= s.tolerance_m)
        # a beam reading anything else starts over from what it reads now (no return: it keeps
        # its memory, as bodies drop the odd return)
        restart = valid_now & ~steady
        other = idx[restart]
        self._ref[other] = np.where(near[restart], now[restart], np.nan)
        self._evidence[other] = 0
        kept = idx[steady]
        known = self._evidence[kept] >= s.min_moving_scans
        # the motion test only where it can still make a difference
        if not known.all() and prev is not None and self._moving(scan, prev):
            self._evidence[kept[~known]] += 1
            known = self._evidence[kept] >= s.min_moving_scans
        mask[kept[known]] = True
        return mask

    def _moving(self, scan: LaserScan, prev: LaserScan) -> bool:
        """Did the world move past the laser between ``prev`` and ``scan``?"""
        s = self.settings
        # every k-th beam (about 96 of them) tells as well as all, at a fraction of the cost
        k = max(1, scan.ranges.shape[0] // 96)
        a = scan.ranges.numpy()[::k]
        b = prev.ranges.numpy()[::k]
        both = valid_mask(a, scan.range_min_m, scan.range_max_m) & valid_mask(
            b, prev.range_min_m, prev.range_max_m
        )
        compared = np.count_nonzero(both)
        if compared == 0:
            return False
        with np.errstate(invalid="ignore"):
            changed = np.count_nonzero((np.abs(a - b) > s.change_m) & both)
        return changed >= s.moving_fraction * compared


def on_mask(result: PersonCandidates, mask: np.ndarray) -> PersonCandidates:
    """``result`` without the candidates one of whose legs spans a beam set in ``mask``."""
    if not mask.any() or not result.candidates:
        return result
    before = np.concatenate(([0], np.cumsum(mask)))
    n = mask.shape[0]

    def touches(c) -> bool:
        for leg in c.legs:
            first, last = min(leg.first_beam, n - 1), min(leg.last_beam, n - 1)
            if before[last + 1] - before[first] > 0:
                return True
        return False

    keep = [c for c in result.candidates if not touches(c)]
    if len(keep) == len(result.candidates):
        return result
    return msgspec.structs.replace(result, candidates=keep)


class SelfFilteredDetector:
    """``inner`` whose candidates on the robot's body are dropped; counts what it dropped."""

    def __init__(self, inner: LegDetector, settings: SelfFilterSettings | None = None) -> None:
        self.inner = inner
        self.name = inner.name
        self.body = RobotBodyFilter(settings)
        self.dropped = 0
        """Candidates dropped since the last reset."""
        self.body_beams = 0
        """Beams recognised as the body in the last scan."""

    def reset(self) -> None:
        reset = getattr(self.inner, "reset", None)
        if callable(reset):
            reset()
        self.body.reset()
        self.dropped = 0

    def detect(
        self, scan: LaserScan, prediction: Prediction = None, pose: LaserPose = None
    ) -> PersonCandidates:
        mask = self.body.update(scan)
        self.body_beams = int(mask.sum())
        result = self.inner.detect(scan, prediction, pose)
        kept = on_mask(result, mask)
        self.dropped += len(result.candidates) - len(kept.candidates)
        return kept
