"""Initiators: which tentative tracks the tracker publishes as people (initiators.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.schemas import Array, Candidate, Horizon, Leg, Odometry, PersonCandidates
from followbot.services.tracker.core import Tracker, TrackerSettings
from followbot.services.tracker.settings import EvidenceSettings

SCAN_NS = 100_000_000  # 10 Hz
EVIDENCE = TrackerSettings(initiator="evidence")


def odom(stamp_ns: int, x: float, y: float = 0.0, yaw: float = 0.0) -> Odometry:
    return Odometry(stamp_ns=stamp_ns, x_m=x, y_m=y, yaw_rad=yaw)


def to_base(p, pose):
    """A world point in the base frame of a robot at ``pose`` (x, y, yaw)."""
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    dx, dy = p[0] - x, p[1] - y
    return c * dx + s * dy, -s * dx + c * dy


def scan(stamp_ns: int, *xy, beams: list[tuple[int, int]] | None = None, n_beams: int = 0):
    """Candidates at the base-frame points ``xy``; ``beams``: each one's leg's beam span."""
    out = []
    for i, (x, y) in enumerate(xy):
        legs = []
        if beams is not None:
            legs = [Leg(x_m=x, y_m=y, first_beam=beams[i][0], last_beam=beams[i][1])]
        out.append(
            Candidate(
                x_m=x, y_m=y, range_m=math.hypot(x, y), bearing_rad=math.atan2(y, x), legs=legs
            )
        )
    horizon = None
    if n_beams:  # a 180 deg laser, one bin per degree
        horizon = Horizon(
            angle_min_rad=-math.pi / 2,
            increment_rad=math.radians(1.0),
            ranges=Array.from_numpy(np.full(180, 5.0)),
        )
    return PersonCandidates(
        stamp_ns=stamp_ns, frame_id="base_laser", candidates=out, n_beams=n_beams, horizon=horizon
    )


def published(trk: Tracker, candidates: PersonCandidates) -> list[int]:
    _, people = trk.step(candidates)
    return [p.id for p in people.tracks]


@pytest.mark.parametrize(("initiator", "ghost"), [("hits", True), ("evidence", False)])
def test_static_clutter_seen_by_a_moving_robot_is_never_a_person(initiator, ghost):
    """A chair at (3, 0.5) in the world, seen on 100 scans by a robot driving at 0.6 m/s and
    turning, with odometry: in the robot's frame it sweeps past, in the odometry frame it stays
    put. The thesis publishes it from its second scan; ``evidence`` never does."""
    trk = Tracker(TrackerSettings(initiator=initiator, acquire="nearest"))
    ever = set()
    for k in range(100):
        t = k * SCAN_NS
        pose = (0.06 * k * math.cos(0.002 * k), 0.06 * k * math.sin(0.002 * k), 0.004 * k)
        trk.add_odometry(odom(t, *pose))
        x, y = to_base((3.0 + 0.03 * (k % 3), 0.5), pose)  # (a little noise)
        if x > 0.2:
            ever.update(published(trk, scan(t, (x, y))))
        else:
            published(trk, scan(t))
    assert bool(ever) == ghost
    if not ghost:
        assert trk.target_id < 0  # nor is it chosen as the target (acquire: nearest)


def walk(trk: Tracker, stops_at_k: int, odometry: bool = True, scans: int = 60):
    """A walker crossing at 1 m/s in front of a still robot from (2, -1), standing still from
    scan ``stops_at_k``; returns the distance walked when first published, and whether it was
    published on every scan after that."""
    first, always = None, True
    for k in range(scans):
        t = k * SCAN_NS
        if odometry:
            trk.add_odometry(odom(t, 0.0))
        y = -1.0 + 0.1 * min(k, stops_at_k)
        people = published(trk, scan(t, (2.0, y)))
        if first is None and people:
            first = y + 1.0
        elif first is not None:
            always &= bool(people)
    return first, always


@pytest.mark.parametrize("odometry", [True, False])
def test_a_walker_is_a_person_after_walking_half_a_metre_and_stays_one_standing(odometry):
    """Published once it walked evidence.min_travel_m (0.5 m), then on every scan, also after
    it stopped (3 s standing). Without odometry (a still robot) alike."""
    trk = Tracker(EVIDENCE)
    walked, always = walk(trk, stops_at_k=15, odometry=odometry)
    assert walked is not None and 0.5 <= walked <= 0.9
    assert always
    assert trk.tracks[next(iter(trk.tracks))].person


def test_a_track_jittering_in_place_is_not_a_person():
    """A thing at (2, 0) whose candidate jumps about by up to 0.25 m every scan for 10 s: it
    never goes anywhere, so it is never published (the thesis publishes it at once)."""
    rng = np.random.default_rng(7)
    trk, thesis = Tracker(EVIDENCE), Tracker(TrackerSettings())
    ever, ever_thesis = set(), set()
    for k in range(100):
        t = k * SCAN_NS
        x, y = np.array([2.0, 0.0]) + rng.uniform(-0.25, 0.25, 2)
        for tr in (trk, thesis):
            tr.add_odometry(odom(t, 0.0))
        ever.update(published(trk, scan(t, (x, y))))
        ever_thesis.update(published(thesis, scan(t, (x, y))))
    assert not ever
    assert ever_thesis


def test_a_track_hopping_back_and_forth_is_not_a_person():
    """Taking candidates 0.6 m apart in turn (two pieces of clutter): far from where it began at
    times, but along a path many times longer (evidence.min_straightness)."""
    settings = TrackerSettings(initiator="evidence", evidence=EvidenceSettings(min_hits=3))
    trk = Tracker(settings)
    ever = set()
    for k in range(60):
        t = k * SCAN_NS
        trk.add_odometry(odom(t, 0.0))
        ever.update(published(trk, scan(t, (2.0, 0.3 * ((k // 2) % 2)))))
    assert not ever


def test_a_wall_end_at_the_edge_of_the_view_is_no_evidence():
    """A robot driving ahead at 1 m/s sees the end of a wall at the right edge of its 180 deg
    view, always 1 m to its side: in the odometry frame it walks with the robot, straight and
    at a walker's pace. At the view's edge (evidence.edge_margin_deg) it is no evidence."""
    runs = {}
    for margin in (0.0, 10.0):
        settings = TrackerSettings(
            initiator="evidence", evidence=EvidenceSettings(edge_margin_deg=margin)
        )
        trk, ever = Tracker(settings), set()
        for k in range(40):
            t = k * SCAN_NS
            trk.add_odometry(odom(t, 0.1 * k))
            ever.update(published(trk, scan(t, (0.05, -1.0), beams=[(0, 3)], n_beams=180)))
        runs[margin] = bool(ever)
    assert runs == {0.0: True, 10.0: False}


def test_the_first_target_without_vision_is_the_nearest_person_not_the_nearest_thing():
    """acquire: nearest: a chair 1 m ahead and a walker 2 m ahead crossing the robot's path:
    the target is the walker, once it is a person; the thesis takes the chair at once."""
    for initiator, want_walker in (("hits", False), ("evidence", True)):
        trk = Tracker(TrackerSettings(initiator=initiator, acquire="nearest"))
        for k in range(30):
            t = k * SCAN_NS
            trk.add_odometry(odom(t, 0.0))
            target, _ = trk.step(scan(t, (1.0, 0.0), (2.0, -0.8 + 0.05 * k)))
        assert target.status == "tracking"
        assert (abs(target.x_m - 2.0) < 0.3) == want_walker


def test_hits_is_the_thesis_a_person_at_confirm_hits():
    for confirm in (1, 2, 3):
        trk = Tracker(TrackerSettings(confirm_hits=confirm))
        counts = [len(trk.step(scan(k * SCAN_NS, (2.0, 0.0)))[1].tracks) for k in range(4)]
        assert counts == [0] * (confirm - 1) + [1] * (5 - confirm)
