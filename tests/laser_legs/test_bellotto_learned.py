"""seed 002's edge patterns (LA / FS / SL) and the learned detector's model and features."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.schemas import LaserScan
from followbot.services.laser_legs import make_detector
from followbot.services.laser_legs.detectors.bellotto import EdgePatternDetector
from followbot.services.laser_legs.detectors.learned import (
    FEATURES,
    LearnedSettings,
    default_model_path,
    features_and_centroids,
    load_model,
    segment_features,
    segments,
    select_legs,
    vote_share,
)
from followbot.services.laser_legs.scene import make_scan, person_legs

WALL = [(3.0, -3.0, 3.0, 3.0)]
R = 0.06


def _patterns(scan):
    return sorted(c.pattern for c in EdgePatternDetector().detect(scan).candidates)


def test_legs_apart_is_LA_with_two_legs():
    scan = make_scan(person_legs(1.5, 0.0, separation_m=0.3, leg_radius_m=R), WALL)
    (c,) = EdgePatternDetector().detect(scan).candidates
    assert c.pattern == "LA" and len(c.legs) == 2
    assert math.hypot(c.x_m - 1.5, c.y_m) < 0.06
    assert all(0.10 < leg.width_m < 0.20 for leg in c.legs)


def test_single_leg_and_legs_together_are_SL():
    assert _patterns(make_scan([(1.5, 0.4, R)], WALL)) == ["SL"]
    together = person_legs(1.5, -0.4, separation_m=2 * R, leg_radius_m=R)  # touching
    assert _patterns(make_scan(together, WALL)) == ["SL"]


def test_forward_straddle_is_FS():
    # one leg 0.25 m behind the other along the line of sight, half hidden
    legs = [(1.5, 0.0, R), (1.75, 0.07, R)]
    (c,) = EdgePatternDetector().detect(make_scan(legs, WALL)).candidates
    assert c.pattern == "FS" and len(c.legs) == 2
    assert c.legs[0].last_beam < c.legs[1].first_beam or c.legs[1].last_beam < c.legs[0].first_beam


def test_thin_objects_and_walls_are_no_legs():
    table_leg = make_scan([(1.5, 0.0, 0.012)], WALL)  # 2.4 cm: removed by the max operator
    assert _patterns(table_leg) == []
    barrel = make_scan([(1.5, 0.0, 0.35)], WALL)  # 70 cm: too wide for any pattern
    assert _patterns(barrel) == []


def test_bellotto_settings_are_checked():
    with pytest.raises(ValueError):
        make_detector("bellotto", {"min_window_beams": 4})
    with pytest.raises(ValueError):
        make_detector("bellotto", {"leg_min_m": 0.3})


def test_learned_model_is_shipped_and_finds_clean_legs():
    assert default_model_path().is_file()
    legs = person_legs(1.5, 0.3, separation_m=0.3, leg_radius_m=R)
    scan = make_scan(legs, WALL, fov_rad=math.radians(180))
    result = make_detector("learned").detect(scan)
    found = [(leg.x_m, leg.y_m) for c in result.candidates for leg in c.legs]
    for lx, ly, _ in legs:
        assert min(math.hypot(x - lx, y - ly) for x, y in found) < 0.06
    assert all(0.0 <= c.confidence <= 1.0 for c in result.candidates)


def test_segment_features_are_finite_and_describe_shape():
    plank = [(2.5, 1.0, 2.5, 1.3)]  # 30 cm, flat (segments wider than 0.6 m are dropped)
    scan = make_scan([(1.5, 0.0, R), (2.0, -1.0, 0.02)], plank)
    seg = segments(scan)
    st = seg.starts
    f = segment_features(seg)
    assert f.shape == (len(st), len(FEATURES)) and np.isfinite(f).all()
    col = {name: i for i, name in enumerate(FEATURES)}
    wall = int(np.argmax(f[:, col["width_m"]]))
    assert f[wall, col["width_m"]] == pytest.approx(0.3, abs=0.05)
    leg = int(np.argmin(np.abs(f[:, col["range_m"]] - 1.46)))
    assert f[leg, col["circle_radius_m"]] == pytest.approx(R, abs=0.015)
    assert f[wall, col["line_residual_m"]] < 1e-3 < f[leg, col["line_residual_m"]]
    assert f[leg, col["step_min_m"]] > 0.5
    # a leg bulges towards the laser (positive chord depth), a flat plank does not
    assert f[leg, col["chord_depth_m"]] > 0.01 and abs(f[wall, col["chord_depth_m"]]) < 1e-3
    assert f[wall, col["circle_radius_m"]] == pytest.approx(1.0)  # capped: straight


def _reference(scan):
    """Some features computed segment by segment, the obvious way."""
    st, en, x, y = segments(scan)[:4]
    rows = []
    for a, b in zip(st.tolist(), en.tolist(), strict=True):
        px, py = x[a : b + 1], y[a : b + 1]
        cx, cy = px.mean(), py.mean()
        dx, dy = px - cx, py - cy
        lam = np.linalg.eigvalsh(np.cov(np.vstack([dx, dy]), bias=True))
        A = np.column_stack([px, py, np.ones_like(px)])
        sol = np.linalg.lstsq(A, -(px * px + py * py), rcond=None)[0]
        ccx, ccy = -sol[0] / 2, -sol[1] / 2
        rad = math.sqrt(ccx * ccx + ccy * ccy - sol[2])
        steps = np.hypot(np.diff(px), np.diff(py))
        ia = [
            abs(
                math.atan2(
                    (px[0] - px[i]) * (py[-1] - py[i]) - (py[0] - py[i]) * (px[-1] - px[i]),
                    (px[0] - px[i]) * (px[-1] - px[i]) + (py[0] - py[i]) * (py[-1] - py[i]),
                )
            )
            for i in range(1, b - a)
        ]
        rows.append(
            {
                "n_points": b - a + 1,
                "width_m": math.hypot(px[-1] - px[0], py[-1] - py[0]),
                "range_m": math.hypot(cx, cy),
                "line_residual_m": math.sqrt(max(lam[0], 0.0)),
                "circle_radius_m": min(rad, 1.0),
                "boundary_length_m": steps.sum(),
                "boundary_regularity_m": steps.std(),
                "inscribed_mean_rad": np.mean(ia),
                "inscribed_std_rad": np.std(ia),
            }
        )
    return rows


@pytest.mark.parametrize("seed", range(5))
def test_vectorised_features_equal_a_segment_by_segment_reference(seed):
    rng = np.random.default_rng(seed)
    people = [
        leg
        for _ in range(3)
        for leg in person_legs(rng.uniform(0.8, 5.0), rng.uniform(-2, 2), leg_radius_m=R)
    ]
    posts = [(rng.uniform(1, 5), rng.uniform(-3, 3), rng.uniform(0.01, 0.2)) for _ in range(4)]
    room = [(6, -4, 6, 4), (6, 4, -1, 4), (-1, -4, 6, -4)]
    scan = make_scan([*people, *posts], room, fov_rad=math.radians(270), noise_m=0.005, rng=rng)
    f = segment_features(segments(scan))
    ref = _reference(scan)
    assert len(ref) == f.shape[0] > 5
    col = {name: i for i, name in enumerate(FEATURES)}
    for i, row in enumerate(ref):
        for name, want in row.items():
            assert f[i, col[name]] == pytest.approx(want, rel=1e-3, abs=1e-5), (i, name)


def _scan(ranges, **kw):
    kw.setdefault("angle_min_rad", -math.pi)
    kw.setdefault("angle_increment_rad", math.radians(0.5))
    kw.setdefault("range_min_m", 0.02)
    kw.setdefault("range_max_m", 30.0)
    return LaserScan.from_ranges(np.asarray(ranges, np.float32), stamp_ns=0, **kw)


@pytest.mark.parametrize(
    "ranges",
    [
        np.zeros(720),
        np.full(720, np.nan),
        np.full(720, np.inf),
        np.full(720, 2.0),  # a circle round the laser: one segment per 0.6 m
        np.full(720, 0.021),  # just above range_min: points a fraction of a mm apart
        np.tile([1.0, 1.0, 1.0, np.nan], 180),  # three-point slivers
        np.tile([1.0, 5.0], 360),
        np.r_[np.full(3, 3.0), np.full(717, np.inf)],  # one segment, no neighbours
        np.random.default_rng(0).uniform(-1.0, 40.0, 720),
        np.random.default_rng(1).normal(1.5, 0.001, 720),
    ],
    ids=["zeros", "nan", "inf", "ring", "tiny", "slivers", "alternate", "lonely", "junk", "flat"],
)
def test_features_are_finite_and_detection_survives_adversarial_scans(ranges):
    scan = _scan(ranges)
    st = segments(scan)[0]
    f, cx, cy = features_and_centroids(segments(scan))
    assert f.shape == (st.shape[0], len(FEATURES)) and np.isfinite(f).all()
    assert np.isfinite(cx).all() and np.isfinite(cy).all()
    result = make_detector("learned").detect(scan)
    for c in result.candidates:
        assert 0.0 <= c.confidence <= 1.0 and 1 <= len(c.legs) <= 2


def test_infinite_range_max_and_reversed_beams_stay_finite():
    r = np.random.default_rng(2).uniform(0.5, 4.0, 400)
    r[::7] = np.inf
    scan = _scan(r, range_max_m=math.inf, angle_min_rad=math.pi, angle_increment_rad=-0.01)
    f = segment_features(segments(scan))
    assert np.isfinite(f).all()


def test_select_legs_accepts_a_weaker_leg_beside_a_second_one():
    x = np.array([1.0, 1.0, 3.0, 5.0, 5.0])
    y = np.array([0.0, 0.3, 0.0, 0.0, 0.3])
    score = np.array([0.3, 0.2, 0.5, 0.1, 0.6])
    groups = select_legs(x, y, score, threshold=0.4, pair_threshold=0.2, pair_distance_m=0.5)
    # the pair (0, 1) passes on the pair threshold; 2 is a strong lone leg; 3 is too weak to
    # pair, so 4 stands alone on its own score
    assert sorted(groups) == [(0, 1), (2,), (4,)]
    assert select_legs(x, y, score, 0.7, 0.7, 0.5) == []


def test_learned_settings_are_checked():
    with pytest.raises(ValueError):
        LearnedSettings(pair_threshold=1.5)
    with pytest.raises(ValueError):
        LearnedSettings(min_points=2)


def test_vote_share_counts_the_trees_voting_leg():
    model = load_model(default_model_path())
    scan = make_scan(person_legs(2.0, 0.0, leg_radius_m=R), WALL, fov_rad=math.radians(180))
    f = segment_features(segments(scan))
    votes = model.getVotes(f, 0)
    labels, counts = votes[0], votes[1:].astype(float)
    want = counts[:, labels == 1].sum(axis=1) / counts.sum(axis=1)
    assert vote_share(model, f) == pytest.approx(want)


def _labelled_pair_and_post():
    """Training data of one scan: a person at (2, 0) whose leg at (2, 0.15) is labelled, and a
    post at (2, 1.5). Returns the ScanData and masks of its labelled leg, partner and post."""
    from followbot.research.train import ScanData

    legs = person_legs(2.0, 0.0, separation_m=0.3, leg_radius_m=R)
    pos = ScanData(
        make_scan([*legs, (2.0, 1.5, R)], WALL), np.array([[2.0, 0.15]]), LearnedSettings()
    )
    near = np.hypot(pos.cx - 2.0, pos.cy - 0.15) < 0.1
    partner = np.hypot(pos.cx - 2.0, pos.cy + 0.15) < 0.1
    post = np.hypot(pos.cx - 2.0, pos.cy - 1.5) < 0.1
    assert near.sum() == partner.sum() == post.sum() == 1
    return pos, near, partner, post


def test_training_figures_and_threshold_choice_follow_the_detector_rule():
    from followbot.research.train import ScanData, choose_thresholds, figures

    s = LearnedSettings()
    # the labelled leg, its partner and a lone object: the label is found only via the pair
    pos, near, partner, _post = _labelled_pair_and_post()
    pos.score = np.where(near, 0.3, np.where(partner, 0.25, 0.0))
    neg = ScanData(make_scan([(1.0, 0.5, R), (2.0, -1.0, R)], WALL), None, s)
    posts = np.hypot(neg.cx - 1.0, neg.cy - 0.5) < 0.1
    posts |= np.hypot(neg.cx - 2.0, neg.cy + 1.0) < 0.1
    assert posts.sum() == 2
    neg.score = np.where(posts, 0.35, 0.0)  # two lone false legs per scan
    assert figures([pos], [neg], 0.4, 0.2, 0.5) == (1.0, 0.0)  # pair rule: both >= 0.2
    assert figures([pos], [neg], 0.4, 0.3, 0.5) == (0.0, 0.0)  # partner too weak
    assert figures([pos], [neg], 0.3, 0.3, 0.5) == (1.0, 2.0)  # lone legs >= 0.3 count
    t, tp, rc, fp = choose_thresholds([pos], [neg], 0.5, 0.5)
    assert rc == 1.0 and fp == 0.0 and t > 0.35 and tp <= 0.25


def test_threshold_choice_can_bound_the_labelled_scans_background():
    from followbot.research.train import ScanData, background_false, choose_thresholds

    s = LearnedSettings()
    pos, near, partner, post = _labelled_pair_and_post()  # the post: 1.35 m from the label
    pos.score = np.select([near, partner, post], [0.3, 0.25, 0.45], 0.0)
    neg = ScanData(make_scan([(1.0, 0.5, R)], WALL), None, s)
    neg.score = np.zeros_like(neg.score)
    # the pair is near the label (not background); the lone post is
    assert background_false([pos], 0.4, 0.2, 0.5, far_m=1.0) == 1.0
    assert background_false([pos], 0.5, 0.2, 0.5, far_m=1.0) == 0.0
    assert background_false([pos], 0.4, 0.2, 0.5, far_m=2.0) == 0.0
    t, tp, rc, fp = choose_thresholds([pos], [neg], 0.5, 0.5)
    assert t < 0.45 and (rc, fp) == (1.0, 0.0)  # the negatives alone let the post through
    t, tp, rc, fp = choose_thresholds([pos], [neg], 0.5, 0.5, background_far_m=1.0)
    assert t == 0.5 and tp <= 0.25 and rc == 1.0


def test_the_recall_rule_buys_the_fewest_false_persons_at_the_recall_asked():
    """--min-recall: the fewest validation false persons among the thresholds reaching the
    recall; the earlier rule (min_recall None) takes the highest recall its false-person bound
    allows. A strong leg (0.6), a weak one (0.3), and two posts per negative scan (0.35)."""
    from types import SimpleNamespace

    from followbot.research.train import choose_thresholds

    pos = SimpleNamespace(
        cx=np.array([2.0, 3.0]),
        cy=np.array([0.0, 2.0]),
        score=np.array([0.6, 0.3]),
        legs=np.array([[2.0, 0.0], [3.0, 2.0]]),
    )
    neg = SimpleNamespace(
        cx=np.array([1.0, 4.0]), cy=np.array([1.0, -2.0]), score=np.array([0.35, 0.35]), legs=None
    )
    t, _tp, rc, fp = choose_thresholds([pos], [neg], 2.0, 0.5)
    assert (rc, fp) == (1.0, 2.0) and t <= 0.3  # the weak leg, at the posts' price
    t, _tp, rc, fp = choose_thresholds([pos], [neg], 2.0, 0.5, min_recall=0.5)
    assert (rc, fp) == (0.5, 0.0) and 0.35 < t <= 0.6
    t, _tp, rc, fp = choose_thresholds([pos], [neg], 2.0, 0.5, min_recall=0.9)
    assert (rc, fp) == (1.0, 2.0)
    _t, _tp, rc, _fp = choose_thresholds([pos], [neg], 0.0, 0.5, min_recall=1.5)
    assert rc == 1.0  # out of reach: the highest recall
