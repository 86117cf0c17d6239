"""The kalman_window (seed 004) and nearest (seed 003) estimators: tracking, ego-motion,
gating, expiry, settings, selection by name, and the presets that use them."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest

from followbot.research.closedloop import metrics, run, world_error_m
from followbot.schemas import Candidate, Odometry, PersonCandidates
from followbot.services.runtime.compose import PRESETS
from followbot.services.runtime.plugins import UnknownPlugin
from followbot.services.tracker.core import Tracker, TrackerSettings, se2_change
from followbot.services.tracker.estimators import (
    BUILTIN,
    Estimator,
    KalmanWindowEstimator,
    KalmanWindowSettings,
    NearestFeatureEstimator,
    NearestSettings,
    check_estimator,
    estimator_factory,
    registry,
)
from followbot.services.tracker.settings import IdentitySettings

from .test_tracker_closed_loop import STANDING

NEW = ["kalman_window", "nearest"]
ALL = ["particle", "ukf", *NEW]
DT = 0.12
SCAN_NS = 120_000_000


def scan_at(k, points):
    """Candidates at ``points`` (x, y) in scan k."""
    return PersonCandidates(
        stamp_ns=k * SCAN_NS,
        frame_id="base_laser",
        candidates=[
            Candidate(x_m=a, y_m=b, range_m=math.hypot(a, b), bearing_rad=math.atan2(b, a))
            for a, b in points
        ],
    )


def walk(est, steps, start, velocity, noise_m, seed=3):
    """Feed a constant-velocity walker to ``est``; the (estimate, truth) pairs after each update."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(1, steps + 1):
        truth = np.asarray(start) + np.asarray(velocity) * DT * k
        z = truth + rng.normal(0.0, noise_m, 2)
        est.predict(DT, 0)
        d = est.distance(z[None], 0)
        assert d[0] <= est.gate(0), f"step {k}: the walker left the gate"
        est.update(z)
        out.append((est.mean.copy(), truth))
    return out


# --------------------------------------------------------------------------- tracking


@pytest.mark.parametrize(
    ("name", "settings", "max_rmse_m", "max_speed_error"),
    [
        ("kalman_window", {}, 0.04, 0.05),
        ("nearest", {}, 0.06, 0.10),  # the raw feature: the noise, velocity a difference
        ("nearest", {"motion_model": "constant_velocity"}, 0.06, 0.10),
    ],
)
def test_a_constant_velocity_walker_is_tracked(name, settings, max_rmse_m, max_speed_error):
    # 1.2 m/s diagonally away, 3 cm of measurement noise, 10 s
    velocity = np.array([0.9, -0.8])
    est = estimator_factory(name, settings)(1.5, 0.5, np.random.default_rng(0))
    pairs = walk(est, 84, (1.5, 0.5), velocity, noise_m=0.03)[15:]
    err = [np.hypot(*(m[:2] - t)) for m, t in pairs]
    assert math.sqrt(np.mean(np.square(err))) < max_rmse_m
    v_est = np.mean([m[2:] for m, _ in pairs], axis=0)
    assert np.hypot(*(v_est - velocity)) < max_speed_error * np.hypot(*velocity)
    assert not est.expired()


def test_the_kalman_filter_smooths_what_nearest_copies():
    """Same noisy walker: the Kalman estimate is closer to the truth than the raw feature."""
    rmse = {}
    for name in NEW:
        est = estimator_factory(name)(2.0, 0.0, np.random.default_rng(0))
        pairs = walk(est, 80, (2.0, 0.0), (0.0, 0.7), noise_m=0.05, seed=11)[20:]
        rmse[name] = math.sqrt(np.mean([np.sum((m[:2] - t) ** 2) for m, t in pairs]))
    assert rmse["kalman_window"] < 0.8 * rmse["nearest"], rmse


@pytest.mark.parametrize("name", NEW)
def test_selected_by_the_tracker_estimator_setting(name):
    trk = Tracker(TrackerSettings(estimator=name, acquire="nearest"))
    for k in range(25):
        trk.add_odometry(Odometry(stamp_ns=k * SCAN_NS, x_m=0.0, y_m=0.0, yaw_rad=0.0))
        x, y = 2.0, -0.5 + 0.05 * k
        target, people = trk.step(scan_at(k, [(x, y)]))
    assert target.estimator == people.estimator == name
    assert target.status == "tracking" and target.track_id == 1
    assert abs(target.y_m - y) < 0.05 and abs(target.vy_mps - 0.05 / DT) < 0.1
    assert isinstance(trk.tracks[1].estimator, BUILTIN[name])


# --------------------------------------------------------------------------- ego-motion


@pytest.mark.parametrize("name", ALL)
def test_ego_motion_moves_the_estimate_as_the_particle_filter_does(name):
    """p <- R p + t and v <- R v for every estimator, the rule the particle filter follows."""
    est = estimator_factory(name)(1.0, 1.0, np.random.default_rng(4))
    walk(est, 12, (1.0, 1.0), (0.5, 0.3), noise_m=0.0)
    before = est.mean.copy()
    assert np.hypot(*before[2:]) > 0.2  # a velocity to rotate
    rot, trans = se2_change((0.0, 0.0, 0.0), (0.4, -0.2, 0.7))  # the robot moves and turns
    est.ego_motion(rot, trans)
    after = est.mean
    assert np.allclose(after[:2], rot @ before[:2] + trans, atol=1e-9)
    assert np.allclose(after[2:], rot @ before[2:], atol=1e-9)


def test_kalman_window_ego_motion_rotates_the_covariance():
    est = KalmanWindowEstimator(1.0, 0.0)
    # the filter's own P stays isotropic per block (position measurements, isotropic R), so
    # rotating it changes nothing; give it a correlated one to see the transform
    a = np.random.default_rng(5).normal(size=(4, 4))
    est._kf.P = a @ a.T + 0.1 * np.eye(4)
    P = est.covariance
    rot, trans = se2_change((0.0, 0.0, 0.0), (0.3, 0.1, 0.8))
    est.ego_motion(rot, trans)
    big = np.zeros((4, 4))
    big[:2, :2] = big[2:, 2:] = rot
    assert np.allclose(est.covariance, big @ P @ big.T, atol=1e-12)
    assert not np.allclose(est.covariance, P)  # the rotation mattered


@pytest.mark.parametrize("name", NEW)
def test_a_person_standing_still_stays_put_in_the_world_while_the_robot_drives(name):
    # the closed-loop check of test_tracker_closed_loop, with these estimators
    records = run(
        STANDING,
        estimator=name,
        drive=(0.2, 0.5),
        candidates="truth",
        truth_noise_m=0.01,
        vision="none",
    )
    errs = [world_error_m(r) for r in records if r.target.status == "tracking"]
    assert len(errs) == len(records) == 26
    assert max(errs) < 0.05, errs
    assert records[-1].truth.robot_yaw_rad > 1.2


# --------------------------------------------------------------------------- kalman_window


def window(settings=None, at=(2.0, 0.0)):
    est = KalmanWindowEstimator(*at, settings or KalmanWindowSettings())
    est.predict(DT, 0)
    return est


def test_the_search_window_starts_at_1_m_square():
    est = window()
    assert est.gate() == pytest.approx(0.5)  # seed 004: 1 m x 1 m
    # a square, not a disc: a corner point 0.45 m off in x and y is inside (0.64 m away)
    d = est.distance(np.array([[2.45, 0.45], [2.0, 0.55]]))
    assert d == pytest.approx([0.45, 0.55])
    assert d[0] <= est.gate() < d[1]


def test_the_window_shrinks_until_one_candidate_is_left_and_keeps_that_size():
    s = KalmanWindowSettings()
    est = window(s)
    d = est.distance(np.array([[2.1, 0.0], [2.0, 0.32], [1.7, -0.4]]))  # 0.1, 0.32, 0.3 away
    gate = est.gate()
    assert int(np.count_nonzero(d <= gate)) == 1 and d[0] <= gate
    assert gate >= s.min_window_m / 2
    assert gate + s.window_step_m / 2 > 0.3  # it stopped as soon as one was left
    est.update(np.array([2.1, 0.0]))
    est.predict(DT, 0)
    assert est.gate() == pytest.approx(gate)  # the size carries over to the next scan


def test_the_window_never_shrinks_below_its_minimum_nor_to_empty():
    s = KalmanWindowSettings(min_window_m=0.6)
    est = window(s)
    d = est.distance(np.array([[2.05, 0.0], [2.0, -0.06]]))  # two people within 6 cm
    assert est.gate() == pytest.approx(0.3)  # stopped at min_window_m
    assert np.all(d <= est.gate())
    est = window()
    d = est.distance(np.array([[2.22, 0.0], [2.0, 0.24]]))  # one step would empty it
    assert 0.24 <= est.gate() < 0.5


def test_the_window_grows_until_a_candidate_is_inside_up_to_its_maximum():
    s = KalmanWindowSettings()
    est = window(s)
    d = est.distance(np.array([[2.0, 0.8]]))
    assert d[0] <= est.gate() < d[0] + s.window_step_m / 2
    est = window(s)
    d = est.distance(np.array([[3.5, 0.0]]))
    assert est.gate() == pytest.approx(s.max_window_m / 2) and d[0] > est.gate()


def test_kalman_window_expires_when_the_prediction_outgrows_the_largest_window():
    for max_window_m, expected_range in ((2.0, (3, 20)), (1.0, (1, 10))):
        est = KalmanWindowEstimator(2.0, 0.0, KalmanWindowSettings(max_window_m=max_window_m))
        misses = 0
        while not est.expired():
            est.predict(DT, misses)
            misses += 1
            assert misses < 100
        P = est.covariance
        assert math.sqrt(P[0, 0] + P[1, 1]) > max_window_m / 2
        assert expected_range[0] <= misses <= expected_range[1], misses
        est.update(np.array([2.0, 0.0]))
        assert not est.expired()  # a measurement brings it back


def test_two_people_side_by_side_keep_their_own_kalman_tracks():
    """0.4 m apart, walking together: each window shrinks onto its own person."""
    trk = Tracker(TrackerSettings(estimator="kalman_window", acquire="nearest"))
    for k in range(40):
        trk.add_odometry(Odometry(stamp_ns=k * SCAN_NS, x_m=0.0, y_m=0.0, yaw_rad=0.0))
        x = 1.5 + 0.06 * k
        pts = [(x, -0.2), (x, 0.2)]
        _, people = trk.step(scan_at(k, pts))
    assert sorted(t.id for t in people.tracks) == [1, 2]
    for t in people.tracks:
        assert abs(abs(t.y_m) - 0.2) < 0.02 and abs(t.vx_mps - 0.5) < 0.1
    assert all(trk.tracks[i].estimator.gate() < 0.4 for i in (1, 2))  # both shrank


# --------------------------------------------------------------------------- nearest


def test_nearest_gate_is_max_speed_times_time_since_the_last_feature_plus_a_diameter():
    s = NearestSettings(max_speed_mps=2.0, person_diameter_m=0.4)
    est = NearestFeatureEstimator(2.0, 0.0, s)
    gates = []
    for misses in range(4):
        est.predict(DT, misses)
        gates.append(est.gate(misses))
    assert gates == pytest.approx([0.4 + 2.0 * DT * k for k in range(1, 5)])
    assert est.mean[:2] == pytest.approx([2.0, 0.0])  # hold: the last feature's position
    g = est.gate()
    d = est.distance(np.array([[2.0 + g - 0.01, 0.0], [2.0, g + 0.01]]))
    assert d[0] <= g < d[1]
    est.update(np.array([2.5, 0.0]))
    est.predict(DT, 0)
    assert est.gate() == pytest.approx(0.4 + 2.0 * DT)  # back to one scan's reach


def test_nearest_constant_velocity_carries_the_position_and_hold_does_not():
    hold = NearestFeatureEstimator(2.0, 0.0, NearestSettings())
    cv = NearestFeatureEstimator(2.0, 0.0, NearestSettings(motion_model="constant_velocity"))
    for est in (hold, cv):
        for k in range(1, 6):
            est.predict(DT, 0)
            est.update(np.array([2.0, 0.1 * k]))
        for m in range(3):
            est.predict(DT, m)
    assert hold.mean[:2] == pytest.approx([2.0, 0.5])
    assert cv.mean[:2] == pytest.approx([2.0, 0.5 + 3 * DT * cv.mean[3]])
    assert cv.mean[3] == pytest.approx(0.1 / DT)


def test_nearest_velocity_is_clipped_to_the_max_speed_on_a_jump():
    est = NearestFeatureEstimator(2.0, 0.0, NearestSettings(max_speed_mps=1.5))
    est.predict(DT, 0)
    est.update(np.array([2.0, 0.5]))  # 0.5 m in 0.12 s: a jump to the other leg
    assert np.hypot(*est.mean[2:]) == pytest.approx(1.5)
    assert est.mean[:2] == pytest.approx([2.0, 0.5])


def test_nearest_expiry_after_max_unseen_s_and_the_seeds_immediate_rule():
    est = NearestFeatureEstimator(2.0, 0.0, NearestSettings(max_unseen_s=1.0))
    steps = 0
    while not est.expired():
        est.predict(DT, steps)
        steps += 1
    assert steps == math.floor(1.0 / DT) + 1  # the first step past 1 s
    seed = NearestFeatureEstimator(2.0, 0.0, NearestSettings(max_unseen_s=0.0))
    seed.predict(DT, 0)
    seed.update(np.array([2.0, 0.05]))
    assert not seed.expired()  # a feature this scan
    seed.predict(DT, 0)
    assert seed.expired()  # seed 003 step 12: unknown at the first scan without a feature


def test_nearest_with_the_seeds_rule_loses_the_target_at_the_first_miss():
    trk = Tracker(
        TrackerSettings(
            estimator="nearest",
            estimator_settings={"max_unseen_s": 0.0},
            acquire="nearest",
            identity=IdentitySettings(laser_reacquire_min_speed_mps=0.0),
        )
    )
    statuses = []
    for k in range(6):
        trk.add_odometry(Odometry(stamp_ns=k * SCAN_NS, x_m=0.0, y_m=0.0, yaw_rad=0.0))
        pts = [] if k == 4 else [(2.0, 0.0)]
        target, _ = trk.step(scan_at(k, pts))
        statuses.append(target.status)
    assert statuses[1:4] == ["tracking"] * 3 and statuses[4] == "lost"
    # no vision: re-taken by the laser near where it was lost (the tracker's rule)
    assert statuses[5] == "tracking"


# --------------------------------------------------------------------------- settings, names


@pytest.mark.parametrize(
    ("name", "bad", "field"),
    [
        ("kalman_window", {"window_m": -1.0}, "window_m"),
        ("kalman_window", {"window_m": 3.0}, "window_m"),  # outside [min, max]
        ("kalman_window", {"measurement_std_m": 0}, "measurement_std_m"),
        ("kalman_window", {"windw_m": 1.0}, "windw_m"),
        ("nearest", {"max_speed_mps": 0.0}, "max_speed_mps"),
        ("nearest", {"velocity_smoothing": 1.0}, "velocity_smoothing"),
        ("nearest", {"motion_model": "teleport"}, "motion_model"),
        ("nearest", {"max_unseen_s": -0.1}, "max_unseen_s"),
    ],
)
def test_bad_settings_name_the_field(name, bad, field):
    with pytest.raises(ValueError, match=field) as exc:
        Tracker(TrackerSettings(estimator=name, estimator_settings=bad))
    assert name in str(exc.value)


@pytest.mark.parametrize("cls", [KalmanWindowSettings, NearestSettings])
def test_settings_are_frozen_and_documented_defaults_round_trip(cls):
    s = cls()
    with pytest.raises(AttributeError):
        s.max_window_m = 1.0 if cls is KalmanWindowSettings else None  # type: ignore[misc]
    assert msgspec.convert(msgspec.to_builtins(s), cls) == s


def test_both_are_installed_plugins_and_unknown_names_list_them():
    for name in NEW:
        cls = registry.load(name)
        assert cls is BUILTIN[name] and cls.name == name
    with pytest.raises(UnknownPlugin, match=r"valid names: .*kalman_window.*nearest"):
        registry.load("kalman")
    with pytest.raises(ValueError, match=r"valid names: .*kalman_window.*nearest"):
        TrackerSettings(estimator="kalman")


def test_every_preset_names_an_installed_estimator():
    names = set(registry.names())
    assert PRESETS["ristic"]["tracker"]["estimator"] == "kalman_window"
    assert PRESETS["livingston"]["tracker"]["estimator"] == "nearest"
    for preset in PRESETS.values():  # followbot: the defaults
        assert preset.get("tracker", {}).get("estimator", TrackerSettings().estimator) in names


# --------------------------------------------------------------------------- closed loop


@pytest.mark.parametrize("name", NEW)
def test_closed_loop_follows_the_walker_of_thesis_5_2_2(name):
    m = metrics(run("thesis_5_2_2_straight", estimator=name, duration_s=30.0))
    assert m["rmse_m"] < 0.1 and m["tracked_visible_share"] > 0.9
    assert m["identity_switches"] == 0


@pytest.mark.parametrize("name", sorted(set(registry.names()) | set(ALL)))
def test_every_estimator_keeps_the_protocol_and_its_batch_steps_give_the_per_track_numbers(name):
    """Every installed estimator is an Estimator (base.py), batch steps included: three tracks
    stepped by motion_all / cost_all / update_all end where the per-track calls take them."""
    make = estimator_factory(name)
    starts = [(2.0, 0.0), (1.5, 1.0), (3.0, -0.5)]

    def tracks():
        return [make(x, y, np.random.default_rng([7, i])) for i, (x, y) in enumerate(starts)]

    assert all(isinstance(e, Estimator) for e in tracks())
    cls = make.estimator_class
    rot = np.array([[math.cos(0.1), -math.sin(0.1)], [math.sin(0.1), math.cos(0.1)]])
    shift, points = np.array([0.05, -0.02]), np.array([[2.05, 0.1], [1.6, 1.1], [2.9, -0.4]])
    batch, each = tracks(), tracks()
    for _ in range(3):
        cls.motion_all(batch, rot, shift, 0.12, [0, 0, 0])
        for e in each:
            e.ego_motion(rot, shift)
            e.predict(0.12, 0)
        cost = cls.cost_all(batch, points, [0, 0, 0])
        for r, e in enumerate(each):
            d = e.distance(points, 0)
            np.testing.assert_allclose(cost[r], np.where(d <= e.gate(0), d, np.inf), atol=1e-9)
        cls.update_all(batch, points, np.array([1.0, 2.0, 1.0]))
        for e, z, k in zip(each, points, (1.0, 2.0, 1.0), strict=True):
            e.update(z, k)
        cls.prepare_all(batch)
    for b, e in zip(batch, each, strict=True):
        np.testing.assert_allclose(b.mean, e.mean, atol=1e-9)
        snap = b.snapshot()
        assert snap is not b and np.array_equal(snap.mean, b.mean)


def test_an_estimator_class_missing_part_of_the_protocol_is_refused_naming_it():
    class Half:
        name = "half"
        settings_type = NearestSettings

        def predict(self, dt_s, misses): ...

    with pytest.raises(TypeError, match=r"Half lacks mean, covariance, .*motion_all"):
        check_estimator(Half)
    check_estimator(NearestFeatureEstimator)  # a built-in one derives from EstimatorBase
