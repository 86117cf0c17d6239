"""Issue 35: the target held through gaps without a camera, and taken back right.

``deleter: target_seconds`` keeps the target's track through a gap measured in seconds (at a
40 Hz laser the thesis's 8 misses are 0.2 s); ``identity.laser_retake: reach`` takes the
person back where they could have walked since last seen, walking or standing, but not a
passer-by who was tracked before the loss.
"""

from __future__ import annotations

import math

import pytest

from followbot.schemas import Candidate, Odometry, PersonCandidates
from followbot.services.tracker.core import Tracker
from followbot.services.tracker.settings import IdentitySettings, TrackerSettings

SCAN = 25_000_000  # a 40 Hz laser
HZ = 40


def cands(k: int, *xy) -> PersonCandidates:
    return PersonCandidates(
        stamp_ns=k * SCAN,
        frame_id="base_laser",
        candidates=[
            Candidate(x_m=x, y_m=y, range_m=math.hypot(x, y), bearing_rad=math.atan2(y, x))
            for x, y in xy
        ],
    )


def tracker(deleter="misses", retake="reach", vision=False, **identity) -> Tracker:
    trk = Tracker(
        TrackerSettings(
            acquire="nearest",
            deleter=deleter,
            identity=IdentitySettings(laser_retake=retake, **identity),
        )
    )
    trk.set_vision_alive(vision)
    return trk


def step(trk: Tracker, k: int, *xy):
    trk.add_odometry(Odometry(stamp_ns=k * SCAN, x_m=0.0, y_m=0.0, yaw_rad=0.0))
    return trk.step(cands(k, *xy))


def walker(k: int) -> tuple[float, float]:
    """The target: along x = 2 m at 0.6 m/s (y from -1.5 m)."""
    return 2.0, -1.5 + 0.6 * k / HZ


@pytest.mark.parametrize(("deleter", "held"), [("misses", False), ("target_seconds", True)])
def test_the_target_is_held_through_a_gap_measured_in_seconds(deleter, held):
    """At 40 Hz the thesis's 8 misses are 0.2 s; ``target_seconds`` keeps the target 2 s (and
    deletes the other people's tracks as before); the person coming back is the target again
    within a few scans, never lost on the way."""
    trk = tracker(deleter=deleter, retake="reach")
    for k in range(40):  # 1 s: the target walking, a bystander standing at (1, 1.5)
        step(trk, k, walker(k), (1.0, 1.5))
    statuses = [step(trk, k)[0].status for k in range(40, 40 + 60)]  # 1.5 s without anyone
    assert (statuses[-1] == "coasting") is held
    assert ("lost" in statuses) is not held
    assert len(trk.tracks) == (1 if held else 0)  # the bystander's track went after 0.2 s
    for k in range(100, 104):  # back where it walked on to
        target, _ = step(trk, k, walker(k))
        statuses.append(target.status)
    assert statuses[-1] == "tracking" and abs(target.y_m - walker(103)[1]) < 0.15
    assert ("lost" in statuses) is not held


@pytest.mark.parametrize(
    ("deleter", "retake", "retaken"),
    [("misses", "near_loss", False), ("misses", "reach", True), ("target_seconds", "reach", True)],
)
def test_a_walker_hidden_2_s_is_taken_back_1_2_m_on(deleter, retake, retaken):
    trk = tracker(deleter=deleter, retake=retake)
    for k in range(80):  # 2 s walking at 0.6 m/s
        step(trk, k, walker(k))
    for k in range(80, 160):  # hidden 2 s
        step(trk, k)
    target = None
    for k in range(160, 170):  # reappears 1.2 m on, walking on
        target, _ = step(trk, k, walker(k))
    assert (target.status == "tracking") is retaken
    if retaken:
        assert abs(target.y_m - walker(169)[1]) < 0.2


@pytest.mark.parametrize(("retake", "retaken"), [("near_loss", False), ("reach", True)])
def test_a_standing_target_that_reappears_is_taken_back(retake, retaken):
    """``near_loss`` takes only a walker (laser_reacquire_min_speed_mps); ``reach`` takes a
    person standing where the target stood."""
    trk = tracker(retake=retake)
    for k in range(80):
        step(trk, k, (2.0, 0.0))
    for k in range(80, 140):  # 1.5 s unseen
        step(trk, k)
    for k in range(140, 150):
        target, _ = step(trk, k, (2.1, 0.1))
    assert (target.status == "tracking") is retaken


@pytest.mark.parametrize("deleter", ["misses", "target_seconds"])
def test_a_passer_by_tracked_before_the_loss_crossing_the_gap_is_not_taken(deleter):
    """The target stands at (2, 0) and vanishes; a passer-by tracked since 2 s before walks
    right through where it stood at 0.8 m/s. The target is taken back only when it reappears,
    by the track started on it."""
    trk = tracker(deleter=deleter)

    def passer(k):
        return 1.9, 2.5 - 0.8 * k / HZ  # at y = 0.9 m when the target vanishes (k = 80)

    for k in range(80):
        step(trk, k, (2.0, 0.0), passer(k))
    target_id = trk.target_id
    passer_id = next(tid for tid in trk.tracks if tid != target_id)
    ids = set()
    for k in range(80, 180):  # the passer-by crosses the gap and walks on to y = -1.6 m
        step(trk, k, passer(k))
        ids.add(trk.target_id)
    assert passer_id in trk.tracks  # still tracked: it crossed under its own track
    assert passer_id not in ids
    for k in range(180, 190):  # the target comes back where it stood
        target, _ = step(trk, k, (2.05, 0.05), passer(k))
    assert target.status == "tracking" and trk.target_id != passer_id
    assert abs(target.x_m - 2.05) < 0.15 and abs(target.y_m - 0.05) < 0.15


@pytest.mark.parametrize(("seconds_after", "retaken"), [(0.5, False), (2.0, True), (4.5, False)])
def test_the_gate_grows_with_the_time_since_the_target_was_seen(seconds_after, retaken):
    """A standing target is lost; someone appears 1.2 m from where it stood, for 0.25 s. The
    gate, 0.5 m + 0.5 m/s x t, reaches them after 1.4 s; past retake_max_s (4 s) nobody."""
    trk = tracker()
    for k in range(40):
        step(trk, k, (2.0, 0.0))
    k0 = 40 + round(seconds_after * HZ)
    for k in range(40, k0):
        step(trk, k)
    states = [step(trk, k, (2.0, 1.2))[0].status for k in range(k0, k0 + 10)]
    assert ("tracking" in states) is retaken


def test_with_vision_alive_the_laser_still_takes_the_target_back():
    """Vision confirms or vetoes a re-take; it is not needed for it (``reach``)."""
    trk = tracker(vision=True)
    for k in range(40):
        step(trk, k, (2.0, 0.0))
    for k in range(40, 80):
        step(trk, k)
    for k in range(80, 90):
        target, _ = step(trk, k, (2.3, 0.2))
    assert target.status == "tracking"
