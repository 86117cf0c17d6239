"""followbot.evaluation: metrics on hand-built runs whose values are known, plus a smoke run."""

from __future__ import annotations

import json
import math

import msgspec
import pytest

from followbot.evaluation import (
    EvaluationSettings,
    ScanRecord,
    ScenarioRun,
    _to_world,
    compute_metrics,
    plot_run,
    summary,
    write_report,
)
from followbot.schemas import (
    Candidate,
    GroundTruth,
    Leg,
    People,
    PersonCandidates,
    PersonTrack,
    PersonTruth,
    TrackState,
    Verification,
    VerifiedCandidate,
)

PERIOD_NS = 100_000_000  # 10 Hz scans: every scan lasts 0.1 s
TARGET = 1
OTHER = 2


# --------------------------------------------------------------------------- builders


def person(
    pid: int,
    x: float,
    y: float,
    *,
    laser: bool = True,
    camera: bool = True,
    robot: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> PersonTruth:
    """A person at world (x, y), with robot-frame coordinates for the given robot pose."""
    rx, ry, yaw = robot
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = x - rx, y - ry
    return PersonTruth(
        id=pid,
        x_m=x,
        y_m=y,
        robot_x_m=c * dx + s * dy,
        robot_y_m=-s * dx + c * dy,
        is_target=pid == TARGET,
        visible_laser=laser,
        visible_camera=camera,
    )


def truth(k: int, people: list[PersonTruth], robot=(0.0, 0.0, 0.0)) -> GroundTruth:
    return GroundTruth(
        stamp_ns=k * PERIOD_NS,
        robot_x_m=robot[0],
        robot_y_m=robot[1],
        robot_yaw_rad=robot[2],
        target_id=TARGET,
        people=people,
    )


def track(k: int, x: float, y: float, status: str = "tracking") -> TrackState:
    return TrackState(stamp_ns=k * PERIOD_NS, status=status, x_m=x, y_m=y)


def people_msg(k: int, tracks: dict[int, tuple[float, float]]) -> People:
    return People(
        stamp_ns=k * PERIOD_NS,
        tracks=[PersonTrack(id=i, x_m=x, y_m=y) for i, (x, y) in tracks.items()],
    )


def record(k: int, truth_people: list[PersonTruth], **fields) -> ScanRecord:
    return ScanRecord(stamp_ns=k * PERIOD_NS, truth=truth(k, truth_people), **fields)


def run_of(records: list[ScanRecord], **fields) -> ScenarioRun:
    return ScenarioRun(
        scenario=fields.pop("scenario", "hand"), preset="p", records=records, **fields
    )


def leg(x: float, y: float) -> Leg:
    return Leg(x_m=x, y_m=y, first_beam=0, last_beam=5)


def candidate(x: float, y: float, n_legs: int) -> Candidate:
    legs = [leg(x, y - 0.1), leg(x, y + 0.1)][:n_legs] if n_legs == 2 else [leg(x, y)][:n_legs]
    return Candidate(
        x_m=x, y_m=y, range_m=math.hypot(x, y), bearing_rad=math.atan2(y, x), legs=legs
    )


def candidates(k: int, cands: list[Candidate]) -> PersonCandidates:
    return PersonCandidates(stamp_ns=k * PERIOD_NS, n_beams=361, candidates=cands)


def verification(k: int, positions: list[tuple[float, float]], chosen: int) -> Verification:
    return Verification(
        stamp_ns=k * PERIOD_NS,
        image_stamp_ns=k * PERIOD_NS,
        model_id=0,
        verifier="test",
        candidates=[
            VerifiedCandidate(index=i, x_m=x, y_m=y, in_view=True, distance=0.1)
            for i, (x, y) in enumerate(positions)
        ],
        chosen=chosen,
    )


# --------------------------------------------------------------------------- tracking


def test_perfect_tracking_gives_zero_error_and_mota_one():
    """Robot driving and turning; estimates equal truth in the robot frame of each scan."""
    records = []
    for k in range(20):
        robot = (0.1 * k, 0.05 * k, 0.03 * k)
        tgt = person(TARGET, 0.1 * k + 1.5, 0.2, robot=robot)
        other = person(OTHER, 3.0, -1.0 + 0.05 * k, robot=robot)
        records.append(
            ScanRecord(
                stamp_ns=k * PERIOD_NS,
                truth=truth(k, [tgt, other], robot=robot),
                target=track(k, tgt.robot_x_m, tgt.robot_y_m),
                people=people_msg(
                    k,
                    {7: (tgt.robot_x_m, tgt.robot_y_m), 9: (other.robot_x_m, other.robot_y_m)},
                ),
            )
        )
    m = compute_metrics(run_of(records))
    assert m["rmse_m"] == pytest.approx(0.0, abs=1e-12)
    assert m["tracked_visible_share"] == 1.0
    assert m["identity_switches"] == 0
    assert m["wrong_target_s"] == 0.0
    assert m["mota"] == 1.0
    assert m["motp_m"] == pytest.approx(0.0, abs=1e-12)
    assert (m["misses"], m["false_positives"], m["id_switches"]) == (0, 0, 0)
    assert m["mot_objects"] == 40
    assert m["occlusions"] == 0
    assert m["reacquire_s"] is None
    # the target is ~1.51 m from the robot throughout
    assert m["follow_distance_share"] == 1.0


def test_rmse_counts_only_visible_tracked_scans():
    people = lambda laser: [person(TARGET, 2.0, 0.0, laser=laser)]  # noqa: E731
    records = [
        record(0, people(True), target=track(0, 2.3, 0.0)),  # error 0.3
        record(1, people(True), target=track(1, 2.0, 0.4, "coasting")),  # error 0.4
        record(2, people(True), target=track(2, 9.0, 9.0, "lost")),  # not tracked
        record(3, people(False), target=track(3, 5.0, 0.0)),  # not visible
        record(4, people(True)),  # no tracker output
    ]
    m = compute_metrics(run_of(records))
    assert m["rmse_m"] == pytest.approx(math.sqrt((0.09 + 0.16) / 2))
    assert m["scans_target_visible"] == 4
    assert m["tracked_visible_share"] == pytest.approx(2 / 4)


def test_identity_switch_and_wrong_target_time():
    """T x4, bystander x3, T x2, nobody x1, bystander x2: two switches, 0.5 s on the wrong one."""
    at = {"T": (2.0, 0.0), "B": (2.0, 1.0), "-": (5.0, 5.0)}
    sequence = "TTTTBBBTT-BB"
    records = [
        record(
            k,
            [person(TARGET, 2.0, 0.0), person(OTHER, 2.0, 1.0)],
            target=track(k, *at[c]),
        )
        for k, c in enumerate(sequence)
    ]
    m = compute_metrics(run_of(records))
    assert m["identity_switches"] == 2
    assert m["wrong_target_s"] == pytest.approx(0.5)
    assert m["tracked_visible_share"] == pytest.approx(6 / 12)


def test_moving_between_bystanders_is_not_a_new_switch():
    at = {"T": (2.0, 0.0), "B": (2.0, 1.0), "C": (2.0, -1.0)}
    people = [person(TARGET, 2.0, 0.0), person(OTHER, 2.0, 1.0), person(3, 2.0, -1.0)]
    records = [record(k, people, target=track(k, *at[c])) for k, c in enumerate("TTBCBC")]
    m = compute_metrics(run_of(records))
    assert m["identity_switches"] == 1
    assert m["wrong_target_s"] == pytest.approx(0.4)


def test_starting_on_a_bystander_is_wrong_time_but_no_switch():
    people = [person(TARGET, 2.0, 0.0), person(OTHER, 2.0, 1.0)]
    records = [record(k, people, target=track(k, 2.0, 0.9)) for k in range(3)]
    m = compute_metrics(run_of(records))
    assert m["identity_switches"] == 0
    assert m["wrong_target_s"] == pytest.approx(0.3)


def test_estimate_between_people_goes_to_the_nearer_one():
    """0.4 m from the target but 0.3 m from the bystander: on the bystander (a switch)."""
    people = [person(TARGET, 2.0, 0.0), person(OTHER, 2.0, 0.7)]
    records = [
        record(0, people, target=track(0, 2.0, 0.0)),
        record(1, people, target=track(1, 2.0, 0.4)),
    ]
    assert compute_metrics(run_of(records))["identity_switches"] == 1


def test_follow_distance_share_is_time_weighted_over_tracked_time():
    # scans 0..3 at 0.1 s, then scan 4 after 0.3 s; last scan gets the median period (0.1 s)
    stamps = [0, 1, 2, 3, 6]
    dists = [0.8, 1.5, 1.0, 2.5, 1.9]
    statuses = ["tracking", "tracking", "lost", "coasting", "tracking"]
    records = [
        ScanRecord(
            stamp_ns=s * PERIOD_NS,
            truth=truth(s, [person(TARGET, d, 0.0)]),
            target=track(s, d, 0.0, st),
        )
        for s, d, st in zip(stamps, dists, statuses, strict=True)
    ]
    m = compute_metrics(run_of(records))
    # tracked time: 0.1 + 0.1 + 0.3 + 0.1 = 0.6 s; in band: scan 1 (0.1) + scan 4 (0.1)
    assert m["tracked_s"] == pytest.approx(0.6)
    assert m["follow_distance_share"] == pytest.approx(0.2 / 0.6)


# --------------------------------------------------------------------------- re-acquisition


def _occlusion_run(visible: str, tracked_ok: str) -> ScenarioRun:
    """One char per scan: visible 'v'/'.', tracker 'y' on target, 'c' coasting off, '.' lost."""
    records = []
    for k, (v, t) in enumerate(zip(visible, tracked_ok, strict=True)):
        tgt = person(TARGET, 2.0, 0.0, laser=v == "v")
        target = {
            "y": track(k, 2.0, 0.0),
            "c": track(k, 3.5, 0.0, "coasting"),
            ".": track(k, 0.0, 0.0, "lost"),
        }[t]
        records.append(record(k, [tgt], target=target))
    return run_of(records)


def test_occlusion_then_reacquisition():
    vis = "v" * 10 + "." * 10 + "v" * 10
    trk = "y" * 10 + "ccc" + "." * 10 + "y" * 7
    m = compute_metrics(_occlusion_run(vis, trk))
    assert m["occlusions"] == 1
    assert m["reacquire_s_episodes"] == [pytest.approx(0.3)]
    assert m["reacquire_s"] == pytest.approx(0.3)
    assert m["reacquire_failures"] == 0
    assert m["tracked_visible_share"] == pytest.approx(17 / 20)
    assert m["tracked_visible_share_acquired"] == pytest.approx(17 / 20)  # tracked at once


def test_tracked_share_from_the_first_acquisition_leaves_out_the_learning_time():
    vis = "v" * 20
    trk = "." * 5 + "y" * 10 + "." * 5
    m = compute_metrics(_occlusion_run(vis, trk))
    assert m["tracked_visible_share"] == pytest.approx(10 / 20)
    assert m["tracked_visible_share_acquired"] == pytest.approx(10 / 15)


def test_a_target_lost_for_good_out_of_view_shows_in_the_followed_share_only():
    """The robot loses the target and the person stays out of its view to the end: no visible
    scan is missed, so the visible shares say 1.0; followed_share_acquired says 10 of 30."""
    vis = "v" * 10 + "." * 20
    trk = "y" * 10 + "." * 20
    m = compute_metrics(_occlusion_run(vis, trk))
    assert m["tracked_visible_share_acquired"] == pytest.approx(1.0)
    assert m["followed_share_acquired"] == pytest.approx(10 / 30)
    # tracked through a hidden stretch (coasting on target) counts as followed
    m = compute_metrics(_occlusion_run("vv" + "." * 6 + "vv", "." + "y" * 9))
    assert m["followed_share_acquired"] == pytest.approx(1.0)
    # coasting off the target does not
    m = compute_metrics(_occlusion_run("v" * 10, "y" * 5 + "c" * 5))
    assert m["followed_share_acquired"] == pytest.approx(0.5)


def test_immediate_reacquisition_is_zero_and_mean_over_episodes():
    vis = "vvv" + "...." + "vvv" + "....." + "vvvv"
    trk = "yyy" + "...." + "yyy" + "....." + ".yyy"
    m = compute_metrics(_occlusion_run(vis, trk))
    assert m["occlusions"] == 2
    assert m["reacquire_s_episodes"] == [pytest.approx(0.0), pytest.approx(0.1)]
    assert m["reacquire_s"] == pytest.approx(0.05)


def test_an_occlusion_before_the_first_acquisition_is_no_reacquisition():
    vis = "vvv" + "....." + "vvvvvv" + "....." + "vvvv"
    trk = "..." + "....." + "..yyyy" + "....." + ".yyy"  # first tracked after the 1st
    m = compute_metrics(_occlusion_run(vis, trk))
    assert m["occlusions"] == 1
    assert m["reacquire_s_episodes"] == [pytest.approx(0.1)]


def test_never_reacquired_and_dropouts_and_edges():
    # hidden at the start (never seen yet) and at the end (never seen again): no episodes;
    # a one-scan dropout (0.1 s) is shorter than min_occlusion_s (0.2 s): no episode;
    # the 3-scan occlusion is never followed by tracking: a failure.
    vis = "..vvv.vvv...vvv.."
    trk = "..yyy.yyy........"
    m = compute_metrics(_occlusion_run(vis, trk))
    assert m["occlusions"] == 1
    assert m["reacquire_s_episodes"] == [None]
    assert m["reacquire_failures"] == 1
    assert m["reacquire_s"] is None
    # with no minimum the dropout counts too, re-acquired at once
    m0 = compute_metrics(_occlusion_run(vis, trk), EvaluationSettings(min_occlusion_s=0.0))
    assert m0["reacquire_s_episodes"] == [pytest.approx(0.0), None]


def test_a_glimpse_shorter_than_min_occlusion_is_part_of_the_occlusion():
    # hidden 0.4 s, seen for one scan (0.1 s), hidden 0.3 s, then seen: one occlusion whose
    # re-acquisition counts from the end of the second gap (the glimpse was too short to take)
    vis = "vvv" + "...." + "v" + "..." + "vvvv"
    trk = "yyy" + "...." + "." + "..." + ".yyy"
    m = compute_metrics(_occlusion_run(vis, trk))
    assert m["occlusions"] == 1
    assert m["reacquire_s_episodes"] == [pytest.approx(0.1)]
    # a glimpse at the very end of the run is no reappearance: no episode, no failure
    m_end = compute_metrics(_occlusion_run("vvv" + "...." + "v", "yyy" + "....."))
    assert m_end["occlusions"] == 0
    assert m_end["reacquire_failures"] == 0
    # a glimpse of two scans (0.2 s) is a reappearance: never re-acquired is a failure
    m_two = compute_metrics(_occlusion_run("vvv" + "...." + "vv" + "...", "yyy" + "." * 9))
    assert m_two["reacquire_s_episodes"] == [None]


def test_where_a_reacquisition_goes_the_laser_and_the_camera_parts():
    """Per episode, from the first visible-again scan: the first scan with a laser candidate
    on the target (a candidate 0.5 m off is not on it) and the first with the target in the
    camera's view; None when that never comes."""
    vis = "vvv" + "...." + "vvvvvvvv"
    trk = "yyy" + "...." + ".....yyy"
    las = "yyy" + "...." + "x.yyyyyy"  # y: candidate on the target, x: 0.5 m off
    cam = "yyy" + "...." + "....yyyy"
    records = []
    for k, (v, t, c, e) in enumerate(zip(vis, trk, las, cam, strict=True)):
        tgt = person(TARGET, 2.0, 0.0, laser=v == "v", camera=e == "y")
        where = {"y": [candidate(2.05, 0.0, 2)], "x": [candidate(2.5, 0.0, 2)], ".": []}[c]
        target = track(k, 2.0, 0.0) if t == "y" else track(k, 0.0, 0.0, "lost")
        records.append(record(k, [tgt], target=target, candidates=candidates(k, where)))
    m = compute_metrics(run_of(records))
    assert m["reacquire_s_episodes"] == [pytest.approx(0.5)]
    assert m["reacquire_laser_s_episodes"] == [pytest.approx(0.2)]
    assert m["reacquire_camera_s_episodes"] == [pytest.approx(0.4)]
    assert m["reacquire_turn_s_episodes"] == [0.0]  # straight ahead of the camera
    # no candidate ever (the camera sees the target at once): None for the laser
    m = compute_metrics(_occlusion_run(vis, trk))
    assert m["reacquire_laser_s_episodes"] == [None]
    assert m["reacquire_camera_s_episodes"] == [pytest.approx(0.0)]  # person(): in view


def test_the_least_camera_turn_to_a_reappearing_target():
    """reacquire_turn_s_episodes: the target comes back at bearing 90 deg, the camera looks
    ahead (pan 0): 90 - 47.5 / 2 deg to turn at 90 deg/s; at 180 deg/s half that; from the
    other side (pan -170 deg) the short way round, 100 deg."""
    vis, trk = "vvv" + "...." + "vvv", "yyy" + "...." + "..y"

    def run(pan_deg: float) -> ScenarioRun:
        records = []
        for k, (v, t) in enumerate(zip(vis, trk, strict=True)):
            tgt = person(TARGET, 0.0, 2.0, laser=v == "v")
            gt = msgspec.structs.replace(truth(k, [tgt]), camera_pan_rad=math.radians(pan_deg))
            target = track(k, 0.0, 2.0) if t == "y" else track(k, 0.0, 0.0, "lost")
            records.append(ScanRecord(stamp_ns=k * PERIOD_NS, truth=gt, target=target))
        return run_of(records)

    m = compute_metrics(run(0.0))
    assert m["reacquire_turn_s_episodes"] == [pytest.approx((90 - 23.75) / 90)]
    fast = EvaluationSettings(camera_pan_rate_deg_s=180.0)
    assert compute_metrics(run(0.0), fast)["reacquire_turn_s_episodes"] == [
        pytest.approx((90 - 23.75) / 180)
    ]
    m = compute_metrics(run(-170.0))
    assert m["reacquire_turn_s_episodes"] == [pytest.approx((100 - 23.75) / 90)]
    assert compute_metrics(run(80.0))["reacquire_turn_s_episodes"] == [0.0]
    with pytest.raises(ValueError, match="camera_hfov_deg"):
        EvaluationSettings(camera_hfov_deg=0.0)


# --------------------------------------------------------------------------- CLEAR-MOT


def test_clear_mot_counts_misses_false_positives_and_switches():
    a, b = (2.0, 0.0), (2.0, 2.0)

    def gt(b_visible: bool = True) -> list[PersonTruth]:
        return [person(TARGET, *a), person(OTHER, *b, laser=b_visible)]

    records = [
        record(0, gt(), people=people_msg(0, {10: a, 20: b})),
        record(1, gt(), people=people_msg(1, {10: a, 20: b, 30: (5.0, 5.0)})),  # 1 FP
        record(2, gt(), people=people_msg(2, {10: a})),  # 1 miss (b)
        # the hypotheses swap: both objects change hypothesis -> 2 id switches
        record(3, gt(), people=people_msg(3, {10: (2.0, 2.1), 20: (2.0, 0.1)})),
        # b hidden from the laser is not an object: the track on it is a false positive
        record(4, gt(b_visible=False), people=people_msg(4, {20: a, 10: b})),
    ]
    m = compute_metrics(run_of(records))
    assert m["mot_objects"] == 9
    assert m["mot_matches"] == 8
    assert m["misses"] == 1
    assert m["false_positives"] == 2
    assert m["id_switches"] == 2
    assert m["mota"] == pytest.approx(1 - 5 / 9)
    assert m["motp_m"] == pytest.approx(0.2 / 8)


def test_clear_mot_keeps_previous_matches_within_threshold():
    """Crossing hypotheses still within 0.75 m of their objects keep their ids (no switch),
    although the Hungarian method alone would swap them."""
    a, b = (2.0, 0.0), (2.0, 0.6)
    gt = [person(TARGET, *a), person(OTHER, *b)]
    records = [
        record(0, gt, people=people_msg(0, {1: a, 2: b})),
        record(1, gt, people=people_msg(1, {1: (2.0, 0.5), 2: (2.0, 0.1)})),
    ]
    m = compute_metrics(run_of(records))
    assert m["id_switches"] == 0
    assert m["motp_m"] == pytest.approx(0.25)
    assert m["mota"] == 1.0


def test_clear_mot_beyond_threshold_is_miss_plus_false_positive():
    records = [record(0, [person(TARGET, 2.0, 0.0)], people=people_msg(0, {1: (2.0, 0.8)}))]
    m = compute_metrics(run_of(records))
    assert (m["misses"], m["false_positives"], m["mot_matches"]) == (1, 1, 0)
    assert m["mota"] == pytest.approx(-1.0)
    assert m["motp_m"] is None


def test_clear_mot_switch_is_remembered_across_a_gap():
    a = (2.0, 0.0)
    gt = [person(TARGET, *a)]
    records = [
        record(0, gt, people=people_msg(0, {1: a})),
        record(1, gt, people=people_msg(1, {})),  # miss
        record(2, gt, people=people_msg(2, {2: a})),  # new id for the same person
    ]
    m = compute_metrics(run_of(records))
    assert (m["misses"], m["id_switches"]) == (1, 1)


# --------------------------------------------------------------------------- Table 5.1


def test_candidate_detection_table_5_1():
    tgt = person(TARGET, 2.0, 0.0)
    hidden = person(TARGET, 2.0, 0.0, laser=False)
    records = [
        record(0, [tgt], candidates=candidates(0, [candidate(2.1, 0.0, 2)])),  # two legs
        # nearest within 0.3 m decides: the one-leg at 0.2 m beats the two-leg at 0.28 m
        record(
            1,
            [tgt],
            candidates=candidates(1, [candidate(2.0, 0.28, 2), candidate(2.0, -0.2, 1)]),
        ),
        record(2, [tgt], candidates=candidates(2, [candidate(2.5, 0.0, 2)])),  # 0.5 m: none
        record(3, [tgt], candidates=candidates(3, [])),  # none
        record(4, [hidden], candidates=candidates(4, [candidate(2.0, 0.0, 2)])),  # not counted
        record(5, [tgt]),  # no candidates message: not counted
        record(6, [tgt], candidates=candidates(6, [candidate(2.0, 0.0, 0)])),  # no legs
    ]
    m = compute_metrics(run_of(records))
    assert m["candidates_scans"] == 5
    assert m["candidates_two_leg_share"] == pytest.approx(0.2)
    assert m["candidates_one_leg_share"] == pytest.approx(0.2)
    assert m["candidates_undetected_share"] == pytest.approx(0.4)
    assert m["candidates_no_legs_share"] == pytest.approx(0.2)


# --------------------------------------------------------------------------- verification


def test_robot_bumps_is_the_simulator_s_count_at_the_end_of_the_run():
    recs = [record(k, [person(TARGET, 2.0, 0.0)]) for k in range(5)]
    assert compute_metrics(run_of(recs))["robot_bumps"] == 0
    for k, n in enumerate([0, 0, 1, 1, 2]):
        recs[k].truth = msgspec.structs.replace(recs[k].truth, robot_bumps=n)
    assert compute_metrics(run_of(recs))["robot_bumps"] == 2


def test_verification_counting():
    t_pos, b_pos, far = (2.0, 0.0), (2.0, 1.0), (2.5, 0.0)

    def people(camera: bool) -> list[PersonTruth]:
        return [person(TARGET, *t_pos, camera=camera), person(OTHER, *b_pos)]

    records = [
        record(0, people(True), verification=verification(0, [b_pos, t_pos], 1)),  # right
        record(1, people(True), verification=verification(1, [t_pos, b_pos], 1)),  # bystander
        record(2, people(True), verification=verification(2, [t_pos, b_pos], -1)),  # rejected
        record(3, people(False), verification=verification(3, [b_pos], 0)),  # bystander, hidden
        record(4, people(False), verification=verification(4, [b_pos], -1)),  # hidden, none
        record(5, people(True)),  # no verification
        record(6, people(True), verification=verification(6, [far, b_pos], 0)),  # 0.5 m: wrong
    ]
    m = compute_metrics(run_of(records))
    assert m["verification_scans"] == 3
    assert m["verification_accuracy"] == pytest.approx(1 / 3)
    assert m["verification_rejected"] == 1
    assert m["verification_bystander_choices"] == 1
    assert m["verification_bystander_share"] == pytest.approx(1 / 2)


# --------------------------------------------------------------------------- latency, rtf


def test_latency_percentiles_real_time_factor_and_timeouts():
    tgt = [person(TARGET, 2.0, 0.0)]
    records = [
        record(k, tgt, latency_ms={"controller": float(k + 1), "tracker": 0.5}) for k in range(100)
    ]
    records[0].latency_ms["laser_legs"] = 0.2
    run = run_of(records, timeouts={"vision_verify": 2, "tracker": 1}, wall_s=5.0, sim_s=10.0)
    m = compute_metrics(run)
    assert list(m["latency_ms"]) == ["laser_legs", "tracker", "controller"]  # pipeline order
    ctrl = m["latency_ms"]["controller"]
    assert ctrl["p50_ms"] == pytest.approx(50.5)
    assert ctrl["p99_ms"] == pytest.approx(99.01)
    assert ctrl["max_ms"] == 100.0
    assert ctrl["n"] == 100
    assert m["latency_ms"]["laser_legs"]["n"] == 1
    assert m["real_time_factor"] == pytest.approx(2.0)
    assert m["timeouts_total"] == 3
    assert compute_metrics(run_of(records))["real_time_factor"] is None


def test_to_world_uses_the_robot_pose():
    t = truth(0, [], robot=(1.0, 2.0, math.pi / 2))
    x, y = _to_world(t, 1.0, 0.5)
    assert (x, y) == (pytest.approx(0.5), pytest.approx(3.0))


def test_settings_are_validated():
    with pytest.raises(ValueError, match="mot_match_m"):
        EvaluationSettings(mot_match_m=0.0)
    with pytest.raises(ValueError, match="follow_band_m"):
        EvaluationSettings(follow_band_m=(2.0, 1.0))


# --------------------------------------------------------------------------- report, JSON


def _strict_json(path):
    def no_constants(name):
        raise AssertionError(f"{name} in JSON")

    return json.loads(path.read_text(), parse_constant=no_constants)


def test_empty_run_metrics_are_null_not_nan(tmp_path):
    run = run_of([record(k, [person(TARGET, 2.0, 0.0, laser=False)]) for k in range(3)])
    m = compute_metrics(run)
    for key in ("rmse_m", "tracked_visible_share", "mota", "motp_m", "follow_distance_share"):
        assert m[key] is None, key
    write_report([(run, m)], tmp_path, plots=False)
    doc = _strict_json(tmp_path / "summary.json")
    assert doc["scenarios"]["hand"]["rmse_m"] is None
    assert "presets" not in doc


def test_summary_shape_with_several_presets(tmp_path):
    def run(scenario: str, preset: str, err: float) -> ScenarioRun:
        recs = [
            record(k, [person(TARGET, 2.0, 0.0)], target=track(k, 2.0 + err, 0.0)) for k in range(4)
        ]
        return ScenarioRun(scenario=scenario, preset=preset, records=recs)

    pairs = [
        (run("s1", "thesis", 0.1), None),
        (run("s1", "bellotto", 0.2), None),
        (run("s2", "bellotto", 0.3), None),
    ]
    report = write_report(pairs, tmp_path, plots=False)
    doc = _strict_json(tmp_path / "summary.json")
    assert doc == summary(pairs)
    # documented keys under "scenarios", for the first preset given for each scenario
    s1 = doc["scenarios"]["s1"]
    for key in ("identity_switches", "rmse_m", "tracked_visible_share", "mota", "motp_m"):
        assert key in s1
    assert s1["preset"] == "thesis"
    assert s1["rmse_m"] == pytest.approx(0.1)
    assert doc["scenarios"]["s2"]["rmse_m"] == pytest.approx(0.3)
    assert set(doc["presets"]) == {"thesis", "bellotto"}
    assert set(doc["presets"]["thesis"]["scenarios"]) == {"s1"}
    assert doc["presets"]["bellotto"]["scenarios"]["s1"]["rmse_m"] == pytest.approx(0.2)
    text = report.read_text()
    assert "| scenario | thesis | bellotto |" in text
    # s1 RMSE: thesis better (bold), s2 has no thesis run
    assert "| s1 | **0.1** | 0.2 |" in text
    assert "| s2 | – | 0.3 |" in text
    with pytest.raises(ValueError, match="given twice"):
        write_report([pairs[0], pairs[0]], tmp_path / "dup", plots=False)


def test_single_preset_report_has_one_results_table(tmp_path):
    recs = [record(k, [person(TARGET, 2.0, 0.0)], target=track(k, 2.1, 0.0)) for k in range(4)]
    runs = [(ScenarioRun(scenario=n, preset="thesis", records=recs), None) for n in ("a", "b")]
    text = write_report(runs, tmp_path, plots=False).read_text()
    assert "## Results" in text
    assert "## Presets side by side" not in text
    assert "| scenario | acq. s | tracked | tr. acq. | followed | RMSE m | ID sw. |" in text
    assert "| a | 0 | 1 | 1 | 1 | 0.1 | 0 |" in text  # tracked from the first scan
    assert "| b | 0 | 1 | 1 | 1 | 0.1 | 0 |" in text


def test_plot_run_with_gaps_switches_and_no_latency(tmp_path):
    """Untracked scans, a wrong-person episode, no People and no latency still plot."""
    people = [person(TARGET, 2.0, 0.0), person(OTHER, 2.0, 1.0)]
    at = {"T": track(0, 2.0, 0.0), "B": track(0, 2.0, 1.0), ".": None}
    records = [record(k, people, target=at[c]) for k, c in enumerate("TT..BBTT")]
    paths = plot_run(run_of(records), None, tmp_path)
    assert len(paths) == 3
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- smoke run


def _simulated_run(n_scans: int) -> ScenarioRun:
    """The simulator core with a truth-fed fake pipeline: the tracker reports the target 5 cm
    ahead of truth, every visible person as a track, each as a two-leg candidate."""
    from followbot.research.render_docs import truth_follower
    from followbot.schemas import GroundTruth as GT
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation

    sim = Simulation(load_builtin("thesis_5_2_4_two_people"))
    records: list[ScanRecord] = []
    while len(records) < n_scans and not sim.finished:
        for msg in sim.tick():
            if not isinstance(msg, GT):
                continue
            k = len(records)
            stamp = msg.stamp_ns
            tgt = next(p for p in msg.people if p.id == msg.target_id)
            seen = [p for p in msg.people if p.visible_laser]
            records.append(
                ScanRecord(
                    stamp_ns=stamp,
                    truth=msg,
                    candidates=PersonCandidates(
                        stamp_ns=stamp,
                        n_beams=361,
                        candidates=[candidate(p.robot_x_m, p.robot_y_m, 2) for p in seen],
                    ),
                    target=TrackState(
                        stamp_ns=stamp,
                        status="tracking",
                        x_m=tgt.robot_x_m + 0.05,
                        y_m=tgt.robot_y_m,
                    ),
                    people=People(
                        stamp_ns=stamp,
                        tracks=[
                            PersonTrack(id=p.id, x_m=p.robot_x_m, y_m=p.robot_y_m) for p in seen
                        ],
                    ),
                    latency_ms={
                        "laser_legs": 0.2 + 0.01 * (k % 7),
                        "tracker": 0.5 + 0.02 * (k % 5),
                        "controller": 0.9 + 0.05 * (k % 11),
                    },
                )
            )
            truth_follower(sim, msg)
    return ScenarioRun(
        scenario="thesis_5_2_4_two_people",
        preset="truth",
        records=records,
        wall_s=1.0,
        sim_s=sim.t_s,
    )


def test_smoke_simulated_run_writes_plots_and_report(tmp_path):
    run = _simulated_run(100)
    assert len(run.records) == 100
    m = compute_metrics(run)
    assert m["scans_target_visible"] > 50
    assert m["rmse_m"] == pytest.approx(0.05)
    assert m["tracked_visible_share"] == 1.0
    assert m["identity_switches"] == 0
    assert m["mota"] == 1.0
    assert m["candidates_two_leg_share"] == 1.0

    paths = plot_run(run, m, tmp_path / "plots")
    assert [p.name.rsplit("_", 1)[-1] for p in paths] == [
        "topdown.png",
        "distance.png",
        "latency.png",
    ]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert p.stat().st_size > 10_000

    report = write_report([(run, m)], tmp_path / "report")
    assert report.name == "report.md"
    text = report.read_text()
    assert "thesis_5_2_4_two_people" in text
    for p in paths:
        assert f"(plots/{p.name})" in text
        assert (tmp_path / "report" / "plots" / p.name).exists()
    doc = _strict_json(tmp_path / "report" / "summary.json")
    entry = doc["scenarios"]["thesis_5_2_4_two_people"]
    assert entry["rmse_m"] == pytest.approx(0.05)
    assert entry["identity_switches"] == 0
    assert entry["latency_ms"]["controller"]["n"] == 100


def test_acquired_s_is_the_first_tracked_time_or_none():
    def run(first_tracked):
        return run_of([
            record(k, [person(TARGET, 2.0, 0.0)],
                   target=track(k, 2.0, 0.0, "tracking" if first_tracked is not None
                                and k >= first_tracked else "initialising"))
            for k in range(8)
        ])  # fmt: skip

    assert compute_metrics(run(3))["acquired_s"] == pytest.approx(0.3)
    assert compute_metrics(run(None))["acquired_s"] is None


def test_stage_overrides_apply_and_bad_ones_are_refused():
    from followbot.eval_cli import main as eval_main
    from followbot.runner import RunError, apply_stage_overrides, stage_settings

    settings = {**stage_settings("thesis", True), "sim": {}}
    apply_stage_overrides(
        settings,
        ["laser_legs.detector_settings.pairing=matching", "tracker.max_misses=4", "sim.seed=3"],
    )
    assert settings["laser_legs"]["detector_settings"] == {"pairing": "matching"}
    assert settings["laser_legs"]["detector"] == "thesis"  # the preset's keys stay
    assert settings["tracker"]["max_misses"] == 4 and settings["sim"]["seed"] == 3
    for bad in ("max_misses=4", "nobody.key=1", "tracker.max_misses"):
        with pytest.raises(RunError, match=r"STAGE\.key=value"):
            apply_stage_overrides(settings, [bad])
    # the command refuses a bad --set before running anything (exit 2, no report)
    assert eval_main(["--output", "/nonexistent/never", "--set", "oops=1"]) == 2


def test_eval_runs_a_scenario_at_another_laser_rate(tmp_path):
    """--laser-rate-hz: the scenario's laser at that rate (a 40 Hz scanner): four times the
    scans of the same duration, the run named NAME_40hz; a rate out of range is refused."""
    import json

    from conftest import shortened_scenario

    from followbot.eval_cli import main as eval_main

    path = shortened_scenario("thesis_5_2_4_two_people", 3.0, tmp_path)
    args = ["--scenario", str(path), "--no-record", "--preset", "thesis"]
    assert eval_main([*args, "--laser-rate-hz", "40", "--output", str(tmp_path / "a")]) == 0
    assert eval_main([*args, "--output", str(tmp_path / "b")]) == 0
    fast = json.loads((tmp_path / "a" / "summary.json").read_text())["scenarios"]
    own = json.loads((tmp_path / "b" / "summary.json").read_text())["scenarios"]
    ((name, run),) = fast.items()
    ((_, run_own),) = own.items()
    assert "thesis_5_2_4_two_people_3s_40hz" in name
    assert run["scans"] == pytest.approx(3.0 * 40, abs=2)
    assert run_own["scans"] == pytest.approx(3.0 / 0.12, abs=2)
    assert eval_main([*args, "--laser-rate-hz", "0", "--output", str(tmp_path / "c")]) == 2


def test_eval_records_the_camera_images_when_asked(tmp_path):
    """--record-images: the run's recording holds sensors/image (what vision judged), beside
    the topics it always holds; without it, no image."""
    from collections import Counter

    from conftest import shortened_scenario

    from followbot.eval_cli import main as eval_main
    from followbot.mcapio import McapStream

    path = shortened_scenario("thesis_5_2_4_two_people", 2.0, tmp_path)
    counts = {}
    for images in (True, False):
        out = tmp_path / str(images)
        args = ["--scenario", str(path), "--preset", "thesis", "--output", str(out)]
        assert eval_main([*args, *(["--record-images"] if images else [])]) == 0
        (mcap,) = out.glob("runs/*/run.mcap")
        counts[images] = Counter(topic for topic, _, _ in McapStream(str(mcap)).messages())
    assert counts[True]["sensors/image"] >= 15  # 10 Hz for 2 s
    assert counts[False]["sensors/image"] == 0
    assert counts[True]["sensors/scan"] == counts[False]["sensors/scan"] > 0
