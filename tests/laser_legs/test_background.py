"""The static-background model (background.py) and the learned detector's background option."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.schemas import LaserScan
from followbot.services.laser_legs import make_detector
from followbot.services.laser_legs.background import StaticBackground
from followbot.services.laser_legs.detectors.learned import LearnedSettings, segments
from followbot.services.laser_legs.scene import make_scan, person_legs

PERIOD_NS = 100_000_000  # 10 Hz
ROOM = [(-4.0, -3.0, 6.0, -3.0), (6.0, -3.0, 6.0, 3.0), (6.0, 3.0, -4.0, 3.0)]
POST = (3.0, -1.0, 0.05)  # (x, y, radius) in the world


def _to_laser(pose, x, y):
    """World point -> laser frame of ``pose`` (x, y, theta)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = x - pose[0], y - pose[1]
    return c * dx + s * dy, -s * dx + c * dy


def world_scan(pose, circles, walls, k, **kw) -> LaserScan:
    """A 270° scan of world geometry from a laser at ``pose``; stamp k * 100 ms."""
    cl = [(*_to_laser(pose, cx, cy), r) for cx, cy, r in circles]
    wl = [(*_to_laser(pose, a, b), *_to_laser(pose, c, d)) for a, b, c, d in walls]
    kw.setdefault("fov_rad", math.radians(270))
    kw.setdefault("noise_m", 0.005)
    kw.setdefault("rng", np.random.default_rng(k))
    return make_scan(cl, wl, stamp_ns=k * PERIOD_NS, **kw)


def walker(k):
    """A person crossing the room at 1 m/s, 2 m in front of the post's line."""
    return person_legs(1.8, -2.0 + 0.1 * k, separation_m=0.3)


def _query(bg, scan, pts):
    x = np.array([p[0] for p in pts], float)
    y = np.array([p[1] for p in pts], float)
    return bg.update(scan, x, y)


@pytest.mark.parametrize("moving", [False, True], ids=["still", "moving"])
def test_post_becomes_static_walking_legs_do_not(moving):
    bg = StaticBackground(3.0, ego_motion=True)
    statics = []
    for k in range(40):
        # a moving robot drives forward at 0.3 m/s and turns at 10°/s
        pose = (0.03 * k, 0.0, math.radians(1.0) * k) if moving else (0.0, 0.0, 0.0)
        legs = walker(k)
        scan = world_scan(pose, [POST, *legs], ROOM, k)
        pts = [_to_laser(pose, POST[0], POST[1])] + [_to_laser(pose, lx, ly) for lx, ly, _ in legs]
        hits, views = _query(bg, scan, pts)
        statics.append(StaticBackground.static_mask(hits, views, 0.9, 5))
    statics = np.array(statics)
    assert bg.resets == 0
    assert not statics[:5].any()  # before min_views views nothing is static
    assert statics[10:, 0].all()  # the post, once the memory has views of it
    assert not statics[:, 1:].any()  # the walking legs never


def test_person_standing_still_for_the_whole_memory_is_static():
    # the documented price: a person who has not moved for the whole memory is background
    bg = StaticBackground(2.0)
    legs = person_legs(2.0, 0.5)
    for k in range(30):
        hits, views = _query(bg, world_scan((0, 0, 0), legs, ROOM, k), [leg[:2] for leg in legs])
    assert StaticBackground.static_mask(hits, views, 0.9, 5).all()


def test_scan_matching_follows_the_laser():
    bg = StaticBackground(5.0)
    truth = []
    for k in range(30):
        pose = (0.05 * k, 0.01 * k, math.radians(2.0) * k)
        bg.update(world_scan(pose, [POST], ROOM, k), np.zeros(0), np.zeros(0))
        truth.append(pose)
    # the odometry frame starts at the first scan (truth[0] is the origin)
    est = bg._pose
    assert est[0] == pytest.approx(truth[-1][0], abs=0.03)
    assert est[1] == pytest.approx(truth[-1][1], abs=0.03)
    assert est[2] == pytest.approx(truth[-1][2], abs=math.radians(0.5))


def test_without_ego_motion_a_moving_laser_sees_no_static_post():
    # with the laser taken as still, a post seen from a moving robot is not background
    bg = StaticBackground(3.0, ego_motion=False)
    for k in range(30):
        pose = (0.05 * k, 0.0, math.radians(2.0) * k)
        hits, views = _query(
            bg, world_scan(pose, [POST], ROOM, k), [_to_laser(pose, POST[0], POST[1])]
        )
    assert not StaticBackground.static_mask(hits, views, 0.9, 5).any()


def _scan(ranges, stamp_ns, inc=0.5 * math.pi / 180, frame_id="laser"):
    r = np.asarray(ranges, np.float32)
    return LaserScan.from_ranges(
        r,
        stamp_ns=stamp_ns,
        angle_min_rad=-inc * (r.shape[0] - 1) / 2,
        angle_increment_rad=inc,
        frame_id=frame_id,
    )


@pytest.mark.parametrize(
    "ranges",
    [
        np.full(360, np.nan),
        np.full(360, np.inf),
        np.full(360, -np.inf),
        np.zeros(360),
        np.full(1, 2.0),
        np.full(2, 2.0),
        np.where(np.arange(360) % 3 == 0, np.nan, 2.0),
        np.where(np.arange(360) % 2 == 0, np.inf, 2.0),
        np.full(360, 1e6),
    ],
    ids=["nan", "inf", "-inf", "zero", "one-beam", "two-beams", "nan-holes", "inf-holes", "far"],
)
def test_bad_beams_never_raise(ranges):
    bg = StaticBackground(1.0)
    det = make_detector("learned", {"background_memory_s": 1.0})
    good = np.full(ranges.shape, 2.0)
    for k, r in enumerate([good, ranges, ranges, good, ranges]):
        scan = _scan(r, k * PERIOD_NS)
        hits, views = bg.update(scan, np.array([1.0, np.nan]), np.array([0.0, np.inf]))
        assert hits.shape == views.shape == (2,)
        assert (hits <= views).all()
        det.detect(scan)


def test_other_size_frame_backwards_stamp_or_gap_resets():
    bg = StaticBackground(1.0)
    wall = [(2.0, -5.0, 2.0, 5.0)]
    k = 0

    def feed(n_scans, **kw):
        nonlocal k
        out = None
        for _ in range(n_scans):
            out = _query(bg, world_scan((0, 0, 0), [], wall, k, **kw), [(2.0, 0.0)])
            k += 1
        return out

    _, views = feed(8)
    assert views[0] >= 5 and bg.resets == 0
    _, views = feed(1, increment_rad=math.radians(1.0))  # another resolution
    assert bg.resets == 1 and views[0] == 0
    feed(8, increment_rad=math.radians(1.0))
    assert bg.resets == 1
    _, views = feed(1, fov_rad=math.radians(180), increment_rad=math.radians(1.0))  # FOV
    assert bg.resets == 2 and views[0] == 0
    k -= 5  # a stamp going backwards
    _, views = feed(1, fov_rad=math.radians(180), increment_rad=math.radians(1.0))
    assert bg.resets == 3 and views[0] == 0
    k += 30  # a gap longer than the memory
    _, views = feed(1, fov_rad=math.radians(180), increment_rad=math.radians(1.0))
    assert bg.resets == 4 and views[0] == 0


def test_learned_settings_switch_and_validate():
    assert make_detector("learned", {"background_memory_s": None}).background is None
    assert make_detector("learned", {"background_memory_s": 0}).background is None
    assert make_detector("learned", {"background_memory_s": 2.0}).background is not None
    for bad in (
        {"background_memory_s": -1.0},
        {"background_static_fraction": 1.5},
        {"background_penalty": -0.1},
        {"background_min_views": 0},
        {"background_hit_m": 0.0},
    ):
        with pytest.raises(ValueError):
            LearnedSettings(**bad)


def test_detector_marks_the_post_segment_static_not_the_walker():
    det = make_detector("learned", {"background_memory_s": 3.0})
    seen_post = 0
    for k in range(40):
        scan = world_scan((0, 0, 0), [POST, *walker(k)], ROOM, k, increment_rad=math.radians(0.25))
        st, en, x, y = segments(scan)[:4]
        cx = np.array([x[a : b + 1].mean() for a, b in zip(st, en, strict=True)])
        cy = np.array([y[a : b + 1].mean() for a, b in zip(st, en, strict=True)])
        static = det.static_segments(scan, cx, cy)
        post = np.hypot(cx - POST[0], cy - POST[1]) < 0.15
        legs = np.zeros_like(post)
        for lx, ly, _ in walker(k):
            legs |= np.hypot(cx - lx, cy - ly) < 0.15
        assert not static[legs].any()
        seen_post += bool(post.any())
        if k >= 10:
            assert static[post].all()
    assert seen_post >= 35  # hidden by the walker a few times


def test_background_penalty_removes_static_candidates_only():
    """Before the memory has views, the option changes nothing; after, no candidate lies on a
    static segment, and every candidate of the plain detector away from static structure
    stays."""
    plain = make_detector("learned", {"background_memory_s": None})
    det = make_detector("learned", {"background_memory_s": 3.0, "background_penalty": 1.0})
    posts = [POST, (4.0, 1.0, 0.06), (4.2, 1.3, 0.06)]  # a post and a pair of furniture legs
    on_posts = 0
    for k in range(40):
        scan = world_scan((0, 0, 0), [*posts, *walker(k)], ROOM, k)
        a = plain.detect(scan).candidates
        b = det.detect(scan).candidates
        if k < 4:
            assert a == b
        elif k >= 12:
            on_posts += sum(
                min(math.hypot(leg.x_m - p[0], leg.y_m - p[1]) for p in posts) < 0.3
                for c in a
                for leg in c.legs
            )
            for c in b:
                for leg in c.legs:
                    assert min(math.hypot(leg.x_m - p[0], leg.y_m - p[1]) for p in posts) > 0.3
            moving = [c for c in a if all(abs(leg.x_m - 1.8) < 0.3 for leg in c.legs)]
            for c in moving:
                assert any(math.hypot(c.x_m - d.x_m, c.y_m - d.y_m) < 1e-9 for d in b)
    assert on_posts > 10  # the plain detector does take the posts for legs


def _moving_pose(k):
    """A robot driving forward at 0.3 m/s and turning at 10°/s (world frame)."""
    return (0.03 * k, 0.0, math.radians(1.0) * k)


def _in_odometry_frame(pose, origin=(5.0, -2.0, 2.0)):
    """``pose`` in an odometry frame whose origin sits at ``origin`` of the world: the frame
    of the given poses is the odometry's own, not the first scan's."""
    c, s = math.cos(origin[2]), math.sin(origin[2])
    return (origin[0] + c * pose[0] - s * pose[1], origin[1] + s * pose[0] + c * pose[1],
            origin[2] + pose[2])  # fmt: skip


def _post_and_legs(bg, k, given):
    pose = _moving_pose(k)
    legs = walker(k)
    scan = world_scan(pose, [POST, *legs], ROOM, k)
    pts = [_to_laser(pose, POST[0], POST[1])] + [_to_laser(pose, lx, ly) for lx, ly, _ in legs]
    x = np.array([p[0] for p in pts], float)
    y = np.array([p[1] for p in pts], float)
    hits, views = bg.update(scan, x, y, _in_odometry_frame(pose) if given else None)
    return StaticBackground.static_mask(hits, views, 0.9, 5)


def test_given_poses_register_the_scans_without_matching(monkeypatch):
    # odometry (laser pose = odom pose * mount) places each scan: no ICP is run
    def no_match(*_a, **_k):
        raise AssertionError("matched a scan that came with its pose")

    monkeypatch.setattr("followbot.services.laser_legs.background.match_scans", no_match)
    bg = StaticBackground(3.0)
    statics = np.array([_post_and_legs(bg, k, True) for k in range(40)])
    assert bg.resets == 0 and bg.given_poses == 40
    assert statics[10:, 0].all()  # the post
    assert not statics[:, 1:].any()  # the walking legs never
    assert bg.pose == pytest.approx(np.array(_in_odometry_frame(_moving_pose(39))))


def test_scans_without_a_pose_are_matched_onto_the_given_ones():
    # odometry missing for some scans: those are matched by ICP and chained onto the last
    # given pose, in the same frame (no reset, the post stays static)
    bg = StaticBackground(3.0)
    statics = []
    for k in range(40):
        given = k % 3 != 2
        statics.append(_post_and_legs(bg, k, given))
        if not given:
            assert bg.pose[:2] == pytest.approx(_in_odometry_frame(_moving_pose(k))[:2], abs=0.03)
    statics = np.array(statics)
    assert bg.resets == 0 and bg.given_poses == 27
    assert statics[10:, 0].all()
    assert not statics[:, 1:].any()


def test_poses_arriving_after_matched_scans_start_the_history_afresh():
    # the chained frame (zero at the first scan) is not the odometry's: one reset, then on
    bg = StaticBackground(3.0)
    statics = np.array([_post_and_legs(bg, k, k >= 5) for k in range(30)])
    assert bg.resets == 1
    assert statics[15:, 0].all()
    assert not statics[:, 1:].any()


def test_detector_behind_the_body_filter_registers_by_the_given_pose(monkeypatch):
    """``detect(scan, prediction, pose)`` as the node calls it: on a moving robot the posts
    become background by the odometry pose alone (no matching), the walker stays."""
    from followbot.services.laser_legs.self_filter import SelfFilteredDetector

    def no_match(*_a, **_k):
        raise AssertionError("matched a scan that came with its pose")

    monkeypatch.setattr("followbot.services.laser_legs.background.match_scans", no_match)
    det = SelfFilteredDetector(
        make_detector("learned", {"background_memory_s": 3.0, "background_penalty": 1.0})
    )
    posts = [POST, (4.0, 1.0, 0.06), (4.2, 1.3, 0.06)]
    for k in range(40):
        pose = _moving_pose(k)
        scan = world_scan(pose, [*posts, *walker(k)], ROOM, k)
        out = det.detect(scan, None, _in_odometry_frame(pose))
        if k >= 12:
            for c in out.candidates:
                for leg in c.legs:
                    wx, wy = _in_odometry_frame((leg.x_m, leg.y_m, 0.0), pose)[:2]  # world
                    assert min(math.hypot(wx - p[0], wy - p[1]) for p in posts) > 0.3
    assert det.inner.background.given_poses == 40 and det.inner.background.resets == 0
