"""learned on sparse and awkward scans (issue 35): legs with dropouts, far legs at fine
resolution, segments cut by the edge of the view, a full circle's seam, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from followbot.schemas import LaserScan
from followbot.services.laser_legs import make_detector
from followbot.services.laser_legs.detectors.learned import full_circle, segments
from followbot.services.laser_legs.scene import make_scan, person_legs

#: A wall behind the walkers (x = 9.5 m, 9 m wide): a background as in a room.
WALL = [(9.5, -4.5, 9.5, 4.5)]


def _walk(
    legs_at, *, steps: int = 12, fov_deg: float = 180.0, inc_deg: float = 0.5, edit=None, **kw
):
    """The default learned detector on a stream of ``steps`` scans 0.1 s apart; the person's
    legs at scan k are ``legs_at(k)``; ``edit(ranges, k)`` may change the ranges. Returns the
    results and the legs of each scan."""
    det = make_detector("learned")
    rng = np.random.default_rng(0)
    out = []
    for k in range(steps):
        legs = legs_at(k)
        scan = make_scan(
            legs,
            WALL,
            fov_rad=math.radians(fov_deg),
            increment_rad=math.radians(inc_deg),
            noise_m=0.005,
            rng=rng,
            stamp_ns=(k + 1) * 100_000_000,
            **kw,
        )
        if edit is not None:
            r = scan.ranges_m().copy()
            edit(r, k, scan)
            scan = LaserScan.from_ranges(
                r,
                stamp_ns=scan.stamp_ns,
                angle_min_rad=scan.angle_min_rad,
                angle_increment_rad=scan.angle_increment_rad,
                range_min_m=scan.range_min_m,
                range_max_m=scan.range_max_m,
            )
        out.append((det.detect(scan), legs))
    return out


def _found(result, x: float, y: float, radius: float = 0.15) -> bool:
    return any(
        math.hypot(leg.x_m - x, leg.y_m - y) <= radius for c in result.candidates for leg in c.legs
    )


def _walker(x0: float, y0: float, vx: float = 0.0, vy: float = 0.05):
    return lambda k: person_legs(x0 + vx * k, y0 + vy * k)


def test_a_leg_at_5_m_is_found_at_a_quarter_degree():
    results = _walk(_walker(5.0, -0.3), inc_deg=0.25)
    last, legs = results[-1]
    assert all(_found(last, x, y) for x, y, _ in legs)


def test_legs_out_to_max_range_m_are_segments_and_beyond_it_are_not():
    # at 7 m and 0.25 deg a leg is a segment of 4-5 points the forest is given; the shipped
    # forest scores legs beyond ~6 m low (few such legs in its training bags:
    # docs/laser_legs.md, "Issue 35"), so this checks the segmentation's reach only
    scan = make_scan(person_legs(7.0, -0.3), WALL, increment_rad=math.radians(0.25))
    assert len(segments(scan, max_range_m=8.0).starts) == 2
    assert len(segments(scan, max_range_m=6.5).starts) == 0


def test_a_sparse_leg_with_dropouts_and_its_hidden_partner_is_a_person():
    # one leg gives a few returns with no-return beams between them; the other only NaN/inf
    # (a real outdoor log at 2 m: 5 returns on one leg, none on the other)
    def edit(r, k, scan):
        ang = scan.angles_rad()
        (ax, ay, _), (bx, by, _) = person_legs(2.0, -0.3 + 0.05 * k)
        far = np.abs(ang - math.atan2(by, bx)) < math.radians(2.0)
        r[far & (r < 3.0)] = np.inf  # the second leg returns nothing
        near = np.flatnonzero((np.abs(ang - math.atan2(ay, ax)) < math.radians(2.0)) & (r < 3.0))
        keep = near[::3]
        r[np.setdiff1d(near, keep)] = np.nan  # two beams of every three of the first leg drop out
        assert 4 <= np.isfinite(r[near]).sum() <= 6

    results = _walk(_walker(2.0, -0.3), edit=edit, inc_deg=0.25)
    for result, legs in results[-3:]:
        (ax, ay, _), _b = legs
        assert _found(result, ax, ay)
    # the same scan without bridging: the leg falls into pieces too small to classify
    det = make_detector("learned", {"dropout_beams": 0})
    scan = make_scan(person_legs(2.0, 0.25), WALL, noise_m=0.0)
    r = scan.ranges_m().copy()
    r[(r < 3.0).nonzero()[0][1::2]] = np.nan
    geometry = {"angle_min_rad": scan.angle_min_rad}
    geometry["angle_increment_rad"] = scan.angle_increment_rad
    sparse = LaserScan.from_ranges(r, stamp_ns=1, **geometry)
    assert len(segments(sparse, dropout_beams=0).starts) == 0
    assert len(segments(sparse, dropout_beams=3).starts) == 2
    assert det.detect(sparse).candidates == []


def test_a_segment_cut_by_the_edge_of_the_view_is_not_a_leg():
    # a person walking out of a 180 deg view on its right edge (bearing -90 deg): legs found
    # while inside; a leg whose beams reach the first beam is never reported
    def legs_at(k):
        return person_legs(0.5 - 0.05 * k, -2.0, separation_m=0.3)

    results = _walk(legs_at, steps=16)
    n = results[0][0].n_beams
    seen_inside = 0
    for result, legs in results:
        for c in result.candidates:
            for leg in c.legs:
                assert leg.first_beam > 0 and leg.last_beam < n - 1
        seen_inside += all(_found(result, x, y) for x, y, _ in legs)
    assert seen_inside >= 3  # the walker is found while wholly in view
    # directly: a post cut by the edge is no segment; moved into the view it is
    cut = make_scan([(0.0, -2.0, 0.06)], WALL)
    inside = make_scan([(0.3, -2.0, 0.06)], WALL)
    assert len(segments(cut).starts) == 0
    assert len(segments(inside).starts) == 1


def test_a_full_circle_joins_its_last_beam_to_its_first():
    inc = 2 * math.pi / 720
    assert full_circle(720, inc) and not full_circle(719, inc) and not full_circle(360, inc)
    # a post on the seam (bearing 180 deg, beams 0 and 719 of a scan from -180 deg)
    scan = make_scan(
        [(-2.0, 0.0, 0.06)], fov_rad=inc * 719, increment_rad=inc, angle_min_rad=-math.pi
    )
    seg = segments(scan)
    assert len(seg.starts) == 1
    beams = seg.beam[seg.starts[0] : seg.ends[0] + 1]
    assert 719 in beams and 0 in beams
    # and the detector reports it with a valid span (the larger side of the seam)
    result = make_detector("learned", {"threshold": 0.0, "pair_threshold": 0.0}).detect(scan)
    for c in result.candidates:
        for leg in c.legs:
            assert 0 <= leg.first_beam <= leg.last_beam < 720


@pytest.mark.parametrize(
    "ranges", [np.array([1.5]), np.full(720, np.nan), np.full(720, np.inf), np.zeros(720)]
)
def test_bad_input_gives_no_candidates(ranges):
    # (a scan of no beams at all is refused by the LaserScan schema; one beam is the least)
    det = make_detector("learned")
    for k in range(3):
        scan = LaserScan.from_ranges(
            np.asarray(ranges, np.float32),
            stamp_ns=(k + 1) * 100_000_000,
            angle_min_rad=-math.pi / 2,
            angle_increment_rad=math.radians(0.25),
        )
        result = det.detect(scan)
        assert result.candidates == [] and result.n_beams == ranges.shape[0]
