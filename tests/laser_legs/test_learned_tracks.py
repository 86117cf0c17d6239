"""The learned detector's temporal confirmation (LegTracks) and its cross-validation in train.py."""

from __future__ import annotations

import itertools
import math

import msgspec
import numpy as np
import pytest

from followbot.schemas import LaserScan
from followbot.services.laser_legs import make_detector
from followbot.services.laser_legs.detectors.learned import LearnedSettings, LegTracks
from followbot.services.laser_legs.scene import make_scan, person_legs

PERIOD_NS = 133_000_000  # the leg_tracker bags' 7.5 Hz
# a room: walls in both directions keep the scan matching (ICP) well posed
WALL = [(-4.0, -3.0, 6.0, -3.0), (6.0, -3.0, 6.0, 3.0), (6.0, 3.0, -4.0, 3.0)]


def _scan(k: int, circles=(), frame_id: str | None = None, **kw) -> LaserScan:
    kw.setdefault("fov_rad", math.radians(270))
    kw.setdefault("noise_m", 0.003)
    kw.setdefault("rng", np.random.default_rng(k))
    scan = make_scan(list(circles), WALL, stamp_ns=k * PERIOD_NS, **kw)
    return scan if frame_id is None else msgspec.structs.replace(scan, frame_id=frame_id)


def _with_ranges(like: LaserScan, ranges: np.ndarray, stamp_ns: int) -> LaserScan:
    return LaserScan.from_ranges(
        np.asarray(ranges, np.float32),
        stamp_ns=stamp_ns,
        angle_min_rad=like.angle_min_rad,
        angle_increment_rad=like.angle_increment_rad,
        range_min_m=like.range_min_m,
        range_max_m=like.range_max_m,
        frame_id=like.frame_id,
    )


def _feed(tracks: LegTracks, k: int, pts, score, **kw) -> np.ndarray:
    x = np.array([p[0] for p in pts], float)
    y = np.array([p[1] for p in pts], float)
    return tracks.update(_scan(k, **kw), x, y, np.asarray(score, float))


def test_a_persistent_leg_keeps_its_score_a_flicker_keeps_only_the_weight():
    tracks = LegTracks(0.8, weight=0.2, gate_m=0.3)
    steady, flicker = [], []
    for k in range(15):
        leg = (1.5, -0.5 + 0.05 * k)  # walking, 5 cm per scan
        blob = (3.5, -3.5 + 0.5 * k)  # somewhere new each scan, beyond the gate
        out = _feed(tracks, k, [leg, blob], [0.6, 0.6])
        steady.append(out[0])
        flicker.append(out[1])
    # no history: only the weight (the first scan of a stream has no Δt, its tracks start at 0)
    assert steady[0] == steady[1] == pytest.approx(0.2 * 0.6)
    assert all(b >= a for a, b in itertools.pairwise(steady))
    assert steady[-1] > 0.5
    assert flicker == pytest.approx([0.2 * 0.6] * 15)


def test_velocity_follows_a_leg_speeding_up_beyond_the_gate():
    # 0.1 m per scan, then 0.25 m per scan: beyond a 0.2 m gate without prediction
    steps = [0.1] * 5 + [0.25] * 6
    for velocity in (False, True):
        tracks = LegTracks(0.8, weight=0.2, gate_m=0.2, velocity=velocity)
        x = 1.0
        for k, step in enumerate(steps):
            x += step
            out = _feed(tracks, k, [(x, 0.0)], [0.8])
        if velocity:
            assert out[0] > 0.5
        else:
            assert out[0] == pytest.approx(0.2 * 0.8)


def test_new_stream_backwards_stamp_or_pause_drops_the_tracks():
    tracks = LegTracks(0.8, weight=0.2, max_gap_s=0.5)
    k = 0

    def feed(n, **kw):
        nonlocal k
        out = None
        for _ in range(n):
            out = _feed(tracks, k, [(1.5, 0.0)], [0.6], **kw)
            k += 1
        return out[0]

    assert feed(5) > 0.2 and tracks.resets == 0
    assert feed(1, frame_id="other") == pytest.approx(0.2 * 0.6)  # another frame
    assert tracks.resets == 1
    feed(3, frame_id="other")
    assert feed(1, frame_id="other", increment_rad=math.radians(1.0)) == pytest.approx(0.12)
    assert tracks.resets == 2
    feed(3, increment_rad=math.radians(1.0))  # back to the default frame: a third reset
    k -= 3  # a stamp going back
    assert feed(1, increment_rad=math.radians(1.0)) == pytest.approx(0.12)
    assert tracks.resets == 4
    k += 5  # a pause of ~0.8 s
    assert feed(1, increment_rad=math.radians(1.0)) == pytest.approx(0.12)
    assert tracks.resets == 5
    tracks.reset()
    assert tracks.count == 0


def test_bad_inputs_never_raise_and_pass_through():
    tracks = LegTracks(0.8)
    empty = np.zeros(0)
    assert tracks.update(_scan(0), empty, empty, empty).shape == (0,)
    x = np.array([1.0, np.nan, np.inf, 2.0, 1.5])
    y = np.array([0.0, 0.0, 1.0, -np.inf, 0.5])
    s = np.array([0.5, 0.5, 0.5, 0.5, np.nan])
    for k in range(1, 4):
        out = tracks.update(_scan(k), x, y, s, np.array([0.1 * k, 0.0, 0.01 * k]))
        assert out.shape == (5,)
        assert np.isnan(out[4]) and np.isfinite(out[:4]).all()
        assert tracks.count == 1  # only the finite segment starts or continues a track
    out = tracks.update(_scan(5), x, y, s, np.array([np.nan, 0.0, 0.0]))  # a bad pose
    assert out.shape == (5,)
    for bad in (
        {"memory_s": 0.0},
        {"memory_s": math.inf},
        {"memory_s": 1.0, "weight": 1.5},
        {"memory_s": 1.0, "gate_m": 0.0},
        {"memory_s": 1.0, "max_gap_s": -1.0},
    ):
        with pytest.raises(ValueError):
            LegTracks(**bad)


def test_settings_switch_and_validate():
    assert make_detector("learned", {"track_memory_s": None}).tracks is None
    assert make_detector("learned", {"track_memory_s": 0}).tracks is None
    det = make_detector("learned")
    assert det.tracks is not None and det.tracks.weight == LearnedSettings().track_weight
    for bad in (
        {"track_memory_s": -1.0},
        {"track_memory_s": math.inf},
        {"track_weight": -0.1},
        {"track_gate_m": 0.0},
        {"track_max_gap_s": 0.0},
    ):
        with pytest.raises(ValueError):
            LearnedSettings(**bad)


def _walker(k):
    return person_legs(2.0, -1.0 + 0.1 * k, separation_m=0.3)


@pytest.mark.parametrize("background", [2.0, None], ids=["registered", "laser-frame"])
def test_detector_confirms_a_walking_pair_and_drops_a_flickering_lone_blob(background):
    """Forest scores stubbed (every segment 0.4; a blob shows up somewhere new in every other
    scan): with tracks the walking pair is a candidate from the second scan on and the
    flickering blob never; without tracks both are. (The room's wall pieces stay put: with
    tracks they are confirmed too — only the walker and the blob are checked.)"""
    # a blob in every other scan, 0.4 m from the last one: never behind the walker, near enough
    # for three beams
    blobs = [(2.5, 0.5 + 0.2 * k, 0.06) for k in range(10)]

    def stub(det):
        det.leg_scores = lambda feats: np.full(feats.shape[0], 0.4)
        return det

    settings = {"background_memory_s": background, "threshold": 0.10, "pair_threshold": 0.05}
    with_tracks = stub(make_detector("learned", settings))
    plain = stub(make_detector("learned", {**settings, "track_memory_s": None}))
    for det, confirm in ((with_tracks, True), (plain, False)):
        for k in range(10):
            circles = [*_walker(k)] + ([blobs[k]] if k % 2 else [])
            got = det.detect(_scan(k, circles)).candidates
            bx, by, _ = blobs[k]
            near_blob = [c for c in got if math.hypot(c.x_m - bx, c.y_m - by) < 0.3]
            near_walker = [c for c in got if math.hypot(c.x_m - 2.0, c.y_m + 1.0 - 0.1 * k) < 0.3]
            if k % 2:
                assert bool(near_blob) != confirm
            if k >= 1:
                assert len(near_walker) == 1 and len(near_walker[0].legs) == 2


def test_detector_resets_its_tracks_with_the_stream_and_the_registered_frame():
    det = make_detector("learned")
    for k in range(5):
        det.detect(_scan(k, _walker(k)))
    assert det.tracks.count > 0
    det.reset()
    assert det.tracks.count == 0
    calls = []
    real_reset = det.tracks.reset
    det.tracks.reset = lambda: (calls.append(1), real_reset())
    for k in range(5):
        det.detect(_scan(k, _walker(k)))
    # a scan the ICP cannot match (nothing in common): the background restarts, so do the tracks
    rng = np.random.default_rng(0)
    like = _scan(0)
    junk = _with_ranges(like, rng.uniform(0.5, 8.0, like.ranges_m().shape[0]), 5 * PERIOD_NS)
    resets = det.background.resets
    det.detect(junk)
    assert det.background.resets == resets + 1 and calls


@pytest.mark.parametrize(
    "ranges",
    [np.full(540, np.nan), np.full(540, np.inf), np.zeros(540), np.full(1, 2.0), np.full(540, 1e6)],
    ids=["nan", "inf", "zero", "one-beam", "far"],
)
def test_a_stream_of_bad_scans_never_raises(ranges):
    det = make_detector("learned")
    good = _scan(0, _walker(0))
    for k, r in enumerate([good.ranges_m(), ranges, ranges, good.ranges_m(), ranges]):
        scan = _with_ranges(good, r, k * PERIOD_NS)
        assert det.detect(scan).stamp_ns == k * PERIOD_NS


def test_training_replays_the_detector_exactly():
    """train.py's cross-validation (background counts, with_background, with_tracks) gives the
    scores the detector computes on the same stream, so the settings are judged as they run."""
    from followbot.research import train

    s = LearnedSettings()
    det = make_detector("learned")
    stream = []
    got = []
    for k in range(25):
        scan = _scan(k, [*_walker(k), (3.0, 1.0, 0.05)])
        d = train.ScanData(scan, np.zeros((0, 2)), s)
        d.oof = det.leg_scores(d.features)
        stream.append(d)
        captured = {}
        real = det.tracks.update

        def spy(*a, _real=real, _c=captured, **kw):
            _c["out"] = _real(*a, **kw)
            return _c["out"]

        det.tracks.update = spy
        det.detect(scan)
        det.tracks.update = real
        got.append(captured["out"])
    m = s.background_memory_s
    train.background_counts([stream], [m], s)
    train.with_background(
        stream, m, s.background_static_fraction, s.background_min_views, s.background_penalty
    )
    train.with_tracks([stream], m, s.track_memory_s, s.track_weight, s.track_velocity, s)
    for d, g in zip(stream, got, strict=True):
        np.testing.assert_allclose(d.score, g, rtol=0, atol=1e-12)
