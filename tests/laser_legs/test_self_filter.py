"""The robot-body filter: beams steady while the world moves past are the robot; candidates on
them are dropped, nothing else is (services/laser_legs/self_filter.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.schemas import Candidate, LaserScan, Leg, PersonCandidates
from followbot.services.laser_legs.node import LaserLegsSettings, build_detector
from followbot.services.laser_legs.self_filter import (
    RobotBodyFilter,
    SelfFilteredDetector,
    SelfFilterSettings,
)
from followbot.services.runtime.settings import load_settings

N = 541  # 270 deg at 0.5 deg
INC = math.radians(0.5)
BODY = slice(0, 10)  # the robot's body at the start of the field of view, 0.3 m away
MS = 1_000_000


def _room(k: int, turning: bool) -> np.ndarray:
    """A room 2-4 m away; a turning robot sees it slide by 4 beams (2 deg) per scan."""
    a = np.arange(N) + (4 * k if turning else 0)
    return 3.0 + np.sin(a * 0.05)


def _scan(k: int, *, turning: bool = True, body_m: float = 0.3, frame_id: str = "laser"):
    r = _room(k, turning)
    r[BODY] = body_m
    return LaserScan.from_ranges(
        r.astype(np.float32),
        stamp_ns=(k + 1) * 100 * MS,
        angle_min_rad=-INC * (N - 1) / 2,
        angle_increment_rad=INC,
        frame_id=frame_id,
    )


def _candidate(first: int, last: int, r: float) -> Candidate:
    leg = Leg(x_m=r, y_m=0.0, first_beam=first, last_beam=last, width_m=0.1)
    return Candidate(x_m=r, y_m=0.0, range_m=r, bearing_rad=0.0, legs=[leg])


class _Fixed:
    """Stands in for a detector (unit test): one candidate on the body, one out in the room."""

    name = "fixed"

    def detect(self, scan: LaserScan, prediction=None, pose=None) -> PersonCandidates:
        return PersonCandidates(
            stamp_ns=scan.stamp_ns,
            frame_id=scan.frame_id,
            detector=self.name,
            n_beams=scan.ranges.shape[0],
            candidates=[_candidate(3, 6, 0.3), _candidate(200, 210, 3.0)],
        )


def _kept(det: SelfFilteredDetector, scan: LaserScan) -> list[int]:
    return [c.legs[0].first_beam for c in det.detect(scan).candidates]


def test_body_learned_while_turning_then_its_candidates_dropped():
    det = SelfFilteredDetector(_Fixed())
    need = SelfFilterSettings().min_moving_scans
    # the first scan has nothing to compare with; then `need` scans of motion
    seen = [_kept(det, _scan(k)) for k in range(need + 1)]
    assert all(s == [3, 200] for s in seen[:need])
    assert seen[need] == [200]
    assert [_kept(det, _scan(k)) for k in range(need + 1, need + 30)] == [[200]] * 29
    assert det.dropped == 30
    assert det.body_beams == BODY.stop


def test_a_still_robot_learns_nothing():
    # a person standing beside a still robot looks like its body: never dropped
    det = SelfFilteredDetector(_Fixed())
    assert all(_kept(det, _scan(k, turning=False)) == [3, 200] for k in range(100))
    assert det.dropped == 0


def test_a_beam_reading_elsewhere_starts_over():
    det = SelfFilteredDetector(_Fixed())
    for k in range(20):
        det.detect(_scan(k))
    assert _kept(det, _scan(20)) == [200]
    # what stood there is gone (say, a person who walked beside the robot): the beams read
    # 0.6 m now, and must be steady through 10 scans of motion again
    need = SelfFilterSettings().min_moving_scans
    seen = [_kept(det, _scan(k, body_m=0.6)) for k in range(21, 21 + need + 1)]
    assert all(s == [3, 200] for s in seen[:need])
    assert seen[need] == [200]


def test_a_dropout_keeps_the_memory():
    f = RobotBodyFilter()
    for k in range(20):
        f.update(_scan(k))
    assert f.update(_scan(20, body_m=float("nan")))[BODY].sum() == 0
    assert f.update(_scan(21))[BODY].all()


def test_another_stream_or_a_replay_starts_afresh():
    f = RobotBodyFilter()
    for k in range(20):
        f.update(_scan(k))
    assert f.update(_scan(20))[BODY].all()
    assert not f.update(_scan(21, frame_id="rear_laser")).any()
    f = RobotBodyFilter()
    for k in range(20):
        f.update(_scan(k))
    assert not f.update(_scan(0)).any()  # stamp went back


def test_far_returns_are_never_the_body():
    # beams steady at 1.5 m while turning (a pole carried on the robot, beyond max_range_m)
    f = RobotBodyFilter()
    for k in range(40):
        mask = f.update(_scan(k, body_m=1.5))
    assert not mask.any()
    f = RobotBodyFilter(SelfFilterSettings(max_range_m=2.0))
    for k in range(40):
        mask = f.update(_scan(k, body_m=1.5))
    assert mask[BODY].all() and mask.sum() == BODY.stop


@pytest.mark.parametrize(
    "ranges",
    [
        np.full(N, np.nan),
        np.full(N, np.inf),
        np.full(N, -np.inf),
        np.zeros(N),
        np.full(1, 0.3),
        np.where(np.arange(N) % 2 == 0, np.nan, 0.3),
        np.full(N, 1e30),
    ],
)
def test_bad_ranges_never_raise_and_mark_nothing_at_once(ranges):
    f = RobotBodyFilter()
    scan = LaserScan.from_ranges(
        ranges.astype(np.float32), stamp_ns=MS, angle_min_rad=0.0, angle_increment_rad=INC
    )
    for _ in range(3):
        mask = f.update(scan)
        assert mask.shape == ranges.shape and not mask.any()


def test_node_filters_by_default_and_null_switches_it_off():
    assert isinstance(build_detector(LaserLegsSettings()), SelfFilteredDetector)
    plain = build_detector(load_settings(LaserLegsSettings, overrides=["self_filter=null"]))
    assert not isinstance(plain, SelfFilteredDetector) and plain.name == "thesis"
    tuned = load_settings(LaserLegsSettings, overrides=["self_filter={max_range_m: 0.5}"])
    assert tuned.self_filter == SelfFilterSettings(max_range_m=0.5)


def test_evaluate_scores_as_the_node_runs_unless_told_not_to():
    from followbot.research.legs_evaluate import build

    assert isinstance(build("thesis"), SelfFilteredDetector)
    assert isinstance(build("learned_notrack"), SelfFilteredDetector)
    for plain in (build("learned_noself"), build("thesis", self_filter=False)):
        assert not isinstance(plain, SelfFilteredDetector)
