"""Synthetic scans with legs at known places: every detector finds them, at any resolution/FOV."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from followbot.schemas import PersonCandidates, decode, encode
from followbot.services.laser_legs import DETECTORS, make_detector
from followbot.services.laser_legs.detectors import ClusterLegDetector, ThesisSettings
from followbot.services.laser_legs.node import LaserLegsSettings
from followbot.services.laser_legs.pairing import Anchor, pair_legs
from followbot.services.laser_legs.scene import make_scan, person_legs
from followbot.services.runtime.settings import SettingsError, load_settings

WALL = [
    (3.0, -3.0, 3.0, 3.0),
    (3.0, 3.0, -3.0, 3.0),
    (-3.0, 3.0, -3.0, -3.0),
    (-3.0, -3.0, 3.0, -3.0),
]

# A leg is found at the middle of its visible arc, about 2/3 of a radius in front of its centre.
LEG_TOL_M = 0.06


def _nearest(points, x, y):
    return min(math.hypot(px - x, py - y) for px, py in points)


def _legs(result: PersonCandidates):
    return [(leg.x_m, leg.y_m) for c in result.candidates for leg in c.legs]


@pytest.mark.parametrize("increment_deg", [0.25, 0.36, 0.5, 1.0])
@pytest.mark.parametrize("fov_deg", [100, 180, 270, 360])
def test_thesis_two_legs_in_a_room(increment_deg, fov_deg):
    px, py = 1.5, 0.2
    legs = person_legs(px, py, separation_m=0.3, leg_radius_m=0.06)
    scan = make_scan(
        legs,
        WALL,
        fov_rad=math.radians(fov_deg) - math.radians(increment_deg),
        increment_rad=math.radians(increment_deg),
    )
    result = ClusterLegDetector().detect(scan)
    two = [c for c in result.candidates if c.pattern == "two_legs"]
    assert len(two) == 1, result
    c = two[0]
    assert math.hypot(c.x_m - px, c.y_m - py) < LEG_TOL_M
    assert c.range_m == pytest.approx(math.hypot(c.x_m, c.y_m))
    assert c.bearing_rad == pytest.approx(math.atan2(c.y_m, c.x_m))
    for lx, ly, _ in legs:
        assert _nearest([(leg.x_m, leg.y_m) for leg in c.legs], lx, ly) < LEG_TOL_M
    # the walls of the room are no legs
    assert all(math.hypot(k.x_m - px, k.y_m - py) < 0.5 for k in result.candidates)


@pytest.mark.parametrize("name", sorted(DETECTORS))
def test_every_detector_finds_clean_legs(name):
    """Noise-free half circles in front of a wall: every detector sees both legs."""
    legs = person_legs(1.2, -0.3, separation_m=0.35, leg_radius_m=0.06)
    scan = make_scan(legs, WALL, increment_rad=math.radians(0.5), fov_rad=math.radians(270))
    result = make_detector(name).detect(scan)
    found = _legs(result)
    for lx, ly, _ in legs:
        assert found and _nearest(found, lx, ly) < LEG_TOL_M, (name, result)
    assert result.detector == name
    assert result.n_beams == scan.ranges.shape[0]
    assert decode(PersonCandidates, encode(result)) == result


def test_lone_leg_and_far_legs():
    # one leg alone; a second person 2 m away -> separate candidates
    scan = make_scan(
        [(1.0, 0.5, 0.06), *person_legs(1.5, -1.0)], WALL, increment_rad=math.radians(0.5)
    )
    result = ClusterLegDetector().detect(scan)
    patterns = sorted(c.pattern for c in result.candidates)
    assert patterns == ["one_leg", "two_legs"]
    one = next(c for c in result.candidates if c.pattern == "one_leg")
    assert math.hypot(one.x_m - 1.0, one.y_m - 0.5) < LEG_TOL_M
    assert len(one.legs) == 1
    assert one.confidence < next(c for c in result.candidates if c.pattern == "two_legs").confidence


def test_thesis_clips_beyond_3_5_m():
    scan = make_scan(
        person_legs(4.0, 0.0), [(6.0, -6.0, 6.0, 6.0)], increment_rad=math.radians(0.25)
    )
    assert ClusterLegDetector().detect(scan).candidates == []
    noclip = ClusterLegDetector(ThesisSettings(clip_range_m=None)).detect(scan)
    # (the strip of wall seen between the legs, square to the robot, passes criteria 1-2 too)
    assert any(
        c.pattern == "two_legs" and math.hypot(c.x_m - 4.0, c.y_m) < LEG_TOL_M
        for c in noclip.candidates
    )


def test_criterion_3_gates_on_prediction():
    scan = make_scan(
        person_legs(1.5, 0.8) + person_legs(1.5, -0.8), WALL, increment_rad=math.radians(0.5)
    )
    det = ClusterLegDetector()
    assert len(det.detect(scan).candidates) == 2
    gated = det.detect(scan, prediction=(1.45, 0.8))
    assert len(gated.candidates) == 1
    assert gated.candidates[0].y_m > 0
    assert det.detect(scan, prediction=(0.0, 0.0)).candidates == []
    # a non-finite prediction is ignored rather than trusted
    assert len(det.detect(scan, prediction=(math.nan, 0.0)).candidates) == 2


def test_criterion_1_rejects_concave_and_flat_clusters():
    # a flat plank 0.2 m wide facing the robot: its closest point is the middle -> it passes
    # criterion 1 (the thesis would take it); a plank seen obliquely has its closest point at
    # an end and is rejected.
    oblique = [(1.0, 0.3, 1.15, 0.45)]
    scan = make_scan([], oblique, increment_rad=math.radians(0.5))
    assert ClusterLegDetector().detect(scan).candidates == []


def test_width_bounds():
    post = make_scan([(1.5, 0.0, 0.02)], WALL, increment_rad=math.radians(0.25))  # 4 cm post
    barrel = make_scan([(1.5, 0.0, 0.30)], WALL, increment_rad=math.radians(0.25))  # 60 cm
    assert ClusterLegDetector().detect(post).candidates == []
    assert ClusterLegDetector().detect(barrel).candidates == []


def test_pair_legs_closest_first():
    x = [0.0, 0.45, 0.55, 3.0]
    y = [0.0, 0.0, 0.0, 0.0]
    assert pair_legs(x, y, 0.5) == [(0,), (1, 2), (3,)]
    assert pair_legs([], [], 0.5) == []


def test_pair_legs_matching_keeps_two_people_side_by_side_apart():
    # two people 0.36 m apart, legs 0.2 m apart: the inner legs are the closest pair
    y = [-0.10, 0.10, 0.26, 0.46]
    x = [2.0] * 4
    assert pair_legs(x, y, 0.5) == [(0,), (1, 2), (3,)]  # thesis: a phantom in between
    assert pair_legs(x, y, 0.5, "matching") == [(0, 1), (2, 3)]
    # where only one pair is possible both rules agree; far legs stay alone
    assert pair_legs([0.0, 0.45, 0.55, 3.0], [0.0] * 4, 0.5, "matching") == [(0,), (1, 2), (3,)]
    assert pair_legs([], [], 0.5, "matching") == []
    with pytest.raises(ValueError, match="pairing"):
        pair_legs(x, y, 0.5, "nearest")


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 2), st.floats(0, 2)), max_size=16))
def test_pair_legs_matching_is_a_best_pairing(points):
    from itertools import combinations

    x = [p[0] for p in points]
    y = [p[1] for p in points]
    groups = pair_legs(x, y, 0.5, "matching")
    assert sorted(i for g in groups for i in g) == list(range(len(points)))  # each leg once
    pairs = [g for g in groups if len(g) == 2]
    assert all(math.dist(points[i], points[j]) < 0.5 for i, j in pairs)

    def value(ps):
        return sum(0.5 - math.dist(points[i], points[j]) for i, j in ps)

    greedy = [g for g in pair_legs(x, y, 0.5) if len(g) == 2]
    assert value(pairs) >= value(greedy) - 1e-9  # never worse than closest first
    if len(points) <= 7:  # brute force: no pairing is better
        edges = [
            (i, j) for i, j in combinations(range(len(points)), 2)
            if math.dist(points[i], points[j]) < 0.5
        ]  # fmt: skip
        for n in range(1, len(points) // 2 + 1):
            for ps in combinations(edges, n):
                if len({i for p in ps for i in p}) == 2 * n:
                    assert value(ps) <= value(pairs) + 1e-9


def test_anchor_keeps_a_passer_by_s_legs_together_in_front_of_the_target():
    # thesis_5_2_4_side_by_side seed 3, 12.00 s: the target's near leg, the passer-by's near
    # leg (the target's far leg hidden behind it) and the passer-by's far leg; the target is
    # at (1.59, 0.15)
    x, y = [1.54, 1.29, 1.00], [0.05, 0.22, 0.32]
    assert pair_legs(x, y, 0.5, "matching") == [(0, 1), (2,)]  # a cross pair
    anchor = Anchor(1.58, 0.15, weight=1.0, gate_m=0.4, lone_leg_m=0.15)
    assert pair_legs(x, y, 0.5, "matching", anchor) == [(0,), (1, 2)]
    # far from every leg the anchor changes nothing; closest first ignores it
    far = Anchor(3.0, -2.0, weight=1.0, gate_m=0.4, lone_leg_m=0.15)
    assert pair_legs(x, y, 0.5, "matching", far) == [(0, 1), (2,)]
    assert pair_legs(x, y, 0.5, "closest_first", anchor) == [(0, 1), (2,)]
    # a person alone keeps its two legs paired, even when the prediction lags onto one leg
    for at in (Anchor(2.1, 0.0, 1.0, 0.4, 0.15), Anchor(2.0, 0.2, 5.0, 0.4, 0.15)):
        assert pair_legs([2.0, 2.0], [-0.2, 0.2], 0.5, "matching", at) == [(0, 1)]


def test_thesis_anchor_weight_gives_the_target_its_own_leg_not_a_cross_pair():
    # the scene above as a scan: the target's far leg is hidden behind the passer-by's near one
    circles = [(1.58, 0.05, 0.06), (1.72, 0.25, 0.06), (1.33, 0.22, 0.06), (1.04, 0.32, 0.06)]
    scan = make_scan(circles, [(4, -4, 4, 4)])
    prediction = (1.64, 0.15)

    def target(settings):
        found = ClusterLegDetector(settings).detect(scan, prediction).candidates
        return [[(round(g.x_m, 2), round(g.y_m, 2)) for g in c.legs] for c in found]

    assert target(ThesisSettings(anchor_weight=0.0)) == [[(1.57, 0.05), (1.32, 0.22)]]  # cross
    assert target(ThesisSettings()) == [[(1.57, 0.05)]]  # the default anchors the pairing
    with pytest.raises(ValueError, match="anchor"):
        ThesisSettings(anchor_weight=-1.0)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0.35, 1.15), st.floats(0.35, 1.15)), max_size=7),
    st.tuples(st.floats(0.7, 0.8), st.floats(0.7, 0.8)),
    st.floats(0.0, 3.0),
)
@example([(1.02, 0.67), (1.13, 0.47), (0.59, 0.9), (0.86, 1.11), (0.78, 0.36)], (0.75, 0.75), 2.45)
@example([(0.88, 0.79), (0.53, 0.38), (0.48, 0.89), (0.79, 0.54), (0.68, 0.57)], (0.75, 0.75), 1.98)
def test_anchored_pairing_is_the_best_grouping_for_its_objective(points, at, weight):
    """Every leg lies within reach of the anchor (< 0.65 m: the gate plus half the pairing
    distance), so every grouping of them is a candidate: brute force finds none better."""
    from itertools import combinations

    x = [p[0] for p in points]
    y = [p[1] for p in points]
    a = Anchor(at[0], at[1], weight=weight, gate_m=0.4, lone_leg_m=0.15)
    groups = pair_legs(x, y, 0.5, "matching", a)
    assert sorted(i for g in groups for i in g) == list(range(len(points)))  # each leg once
    assert all(math.dist(points[g[0]], points[g[1]]) < 0.5 for g in groups if len(g) == 2)

    def objective(pairs):
        paired = {i for p in pairs for i in p}
        persons = [*pairs, *((i,) for i in range(len(points)) if i not in paired)]
        costs = []
        for g in persons:
            cx = sum(x[i] for i in g) / len(g)
            cy = sum(y[i] for i in g) / len(g)
            d = math.dist((cx, cy), at) - (a.lone_leg_m if len(g) == 1 else 0.0)
            costs.append(min(max(d, 0.0), a.gate_m))
        nearest = min(costs, default=a.gate_m)
        return sum(0.5 - math.dist(points[i], points[j]) for i, j in pairs) - weight * nearest

    mine = objective([g for g in groups if len(g) == 2])
    fewest = sum(len(g) == 2 for g in pair_legs(x, y, 0.5, "matching"))
    assert sum(len(g) == 2 for g in groups) >= fewest  # never fewer pairs than the matching
    edges = [
        (i, j) for i, j in combinations(range(len(points)), 2)
        if math.dist(points[i], points[j]) < 0.5
    ]  # fmt: skip
    for n in range(fewest, len(points) // 2 + 1):
        for ps in combinations(edges, n):
            if len({i for p in ps for i in p}) == 2 * n:
                assert objective(list(ps)) <= mine + 1e-9


def test_make_detector_by_name_and_settings():
    det = make_detector("thesis", {"pair_distance_m": 0.4})
    assert det.settings.pair_distance_m == 0.4
    with pytest.raises(ValueError, match="valid names: " + ", ".join(sorted(DETECTORS))):
        make_detector("nope")
    with pytest.raises(ValueError):
        ThesisSettings(min_width_m=0.5, max_width_m=0.1)


def test_stamp_frame_and_empty_scan():
    scan = make_scan([], [], stamp_ns=123)  # nothing hit: every beam is inf
    for name in DETECTORS:
        result = make_detector(name).detect(scan)
        assert result.candidates == []
        assert result.stamp_ns == 123
        assert result.frame_id == scan.frame_id


def test_float64_and_reversed_scans():
    legs = person_legs(1.5, 0.0)
    scan = make_scan(legs, WALL, dtype=np.float64)
    assert len(ClusterLegDetector().detect(scan).candidates) == 1
    # negative increment: beams run clockwise
    inc = -math.radians(0.5)
    rev = make_scan(legs, WALL, increment_rad=inc, angle_min_rad=math.radians(90))
    r = ClusterLegDetector().detect(rev)
    assert len(r.candidates) == 1
    assert math.hypot(r.candidates[0].x_m - 1.5, r.candidates[0].y_m) < LEG_TOL_M


@pytest.mark.parametrize("rng_m", [1.0, 1.5, 2.5])
def test_legs_are_placed_at_their_centres_not_their_surfaces(rng_m):
    """Beyond the thesis: its cluster 'middle' lies on the leg's surface, about pi R / 4 short
    of the centre; the default corrects that, leg_centre_factor=0 keeps the thesis's position."""
    legs = person_legs(rng_m, 0.0, separation_m=0.3, leg_radius_m=0.06)
    scan = make_scan(legs, fov_rad=math.radians(180), increment_rad=math.radians(0.25))
    centres = np.array([(x, y) for x, y, _ in legs])

    def errors(detector):
        found = detector.legs(scan)
        assert len(found) == 2
        got = np.stack([found.x, found.y], axis=1)
        return [float(np.min(np.hypot(*(centres - g).T))) for g in got]

    assert max(errors(ClusterLegDetector())) < 0.01
    literal = errors(ClusterLegDetector(ThesisSettings(leg_centre_factor=0.0)))
    assert min(literal) > 0.04  # the surface: ~pi R / 4 = 4.7 cm in front of the centre


def test_pair_first_keeps_a_passer_by_s_leg_from_pairing_with_the_target_s():
    """outside_gate: pair_first (default) -- a passer-by crossing close in front of the target
    (thesis_5_2_4_two_people, as simulated): one of their legs lies in the target's gate,
    0.20 m from a target leg, closer than the target's own legs are to each other (0.28 m).
    The thesis drops the passer-by's other leg first (criterion 3), and the closest legs left
    pair across the two people; paired over the whole scan (matching), each keeps its own,
    and only the target's pair lies within the gate."""
    t1, t2, b1, b2 = (1.60, -0.06), (1.79, -0.27), (1.54, 0.13), (1.38, 0.34)
    scan = make_scan([(x, y, 0.055) for x, y in (t1, t2, b1, b2)])
    prediction = (1.69, -0.18)

    def pairs(msg):
        return [
            sorted((round(leg.x_m, 1), round(leg.y_m, 1)) for leg in c.legs)
            for c in msg.candidates
            if len(c.legs) == 2
        ]

    literal = {"outside_gate": "drop", "pairing": "closest_first"}  # the thesis, as printed
    thesis = make_detector("thesis", literal).detect(scan, prediction)
    assert pairs(thesis) == [[(1.5, 0.1), (1.6, -0.1)]]  # across the two people
    got = make_detector("thesis").detect(scan, prediction)  # pair_first + matching: default
    assert pairs(got) == [[(1.6, -0.1), (1.8, -0.3)]] and len(got.candidates) == 1
    (c,) = got.candidates
    assert math.hypot(c.x_m - 1.70, c.y_m - -0.17) < 0.06


def test_criterion_3_can_keep_the_others_apart_from_the_target():
    """outside_gate: the thesis drops every leg beyond gate_m of the target's prediction;
    keep_apart reports them too, paired only among themselves -- a bystander whose inner leg
    lies in the target's gate does not pair with the target's legs, nor vanishes."""
    target = person_legs(2.0, 0.0, separation_m=0.2)
    bystander = person_legs(2.0, 0.55, separation_m=0.3)  # legs at y = 0.40 and 0.70
    scan = make_scan([*target, *bystander])
    drop = make_detector("thesis").detect(scan, (2.0, 0.0))
    apart = make_detector("thesis", {"outside_gate": "keep_apart"}).detect(scan, (2.0, 0.0))
    every = make_detector("thesis").detect(scan, None)

    def people(msg):
        return sorted((round(c.y_m * 4) / 4, len(c.legs)) for c in msg.candidates)

    assert people(drop) == [(0.0, 2)]  # the thesis: only the target
    assert people(apart) == [(0.0, 2), (0.5, 2)]  # both, each with its own legs
    assert people(every) == people(apart)  # here as without criterion 3
    # a leg of the bystander inside the gate stays on the target's side of the partition
    close = make_scan([*target, *person_legs(2.0, 0.5, separation_m=0.3)])  # y 0.35, 0.65
    got = make_detector("thesis", {"outside_gate": "keep_apart"}).detect(close, (2.0, 0.0))
    assert people(got) == [(0.0, 2), (0.25, 1), (0.75, 1)]


@pytest.mark.parametrize(
    ("key", "value"),
    [("edge_slivers", True), ("occluded_partner", True), ("lone_leg_offset_m", 0.1)],
)
def test_a_removed_detector_experiment_is_refused_with_the_reason(key, value):
    """Experiments measured and left off are gone; naming one, directly or through
    laser_legs' detector_settings, says so and where it was measured."""
    with pytest.raises(ValueError, match=rf"^detector 'thesis': {key} was removed \(.*laser_legs"):
        make_detector("thesis", {key: value})
    with pytest.raises(
        SettingsError, match=rf"detector_settings: detector 'thesis': {key} was removed"
    ):
        load_settings(LaserLegsSettings, overrides=[f"detector_settings.{key}={value}"])
    assert make_detector("thesis", {"pair_distance_m": 0.4}).settings.pair_distance_m == 0.4
