"""One valid, non-trivial instance of every wire message (for round-trip and property tests)."""

from __future__ import annotations

import numpy as np

from followbot.schemas import (
    Array,
    Candidate,
    GroundTruth,
    Health,
    Image,
    LaserScan,
    Leg,
    Message,
    Odometry,
    PanCommand,
    People,
    PersonCandidates,
    PersonTrack,
    PersonTruth,
    TargetCommand,
    TargetModel,
    TrackState,
    VelocityCommand,
    Verification,
    VerifiedCandidate,
)
from followbot.schemas.messages import MESSAGE_TYPES

STAMP = 1_700_000_000_123_456_789


def scan(n: int = 720, stamp_ns: int = STAMP, seq: int = 0) -> LaserScan:
    ranges = np.linspace(0.5, 7.5, n, dtype=np.float32)
    ranges[::50] = np.nan  # "no return" beams are legal
    return LaserScan.from_ranges(
        ranges,
        stamp_ns=stamp_ns,
        seq=seq,
        angle_min_rad=-2.356,
        angle_increment_rad=4.712 / (n - 1),
        range_min_m=0.02,
        range_max_m=30.0,
        intensities=np.ones(n, np.float32),
        scan_time_s=0.025,
    )


def image(w: int = 64, h: int = 48) -> Image:
    pixels = np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8)
    return Image.from_array(pixels, stamp_ns=STAMP, pan_rad=0.3, intrinsics_id="cam0")


def example_messages() -> dict[type[Message], Message]:
    leg = Leg(x_m=1.0, y_m=0.1, first_beam=10, last_beam=14, width_m=0.12)
    cand = Candidate(
        x_m=1.0,
        y_m=0.0,
        range_m=1.0,
        bearing_rad=0.0,
        width_m=0.3,
        legs=[leg, Leg(x_m=1.0, y_m=-0.1, first_beam=20, last_beam=25)],
        pattern="two_legs",
        confidence=0.9,
    )
    track = PersonTrack(id=3, x_m=1.5, y_m=0.2, vx_mps=0.6, covariance=[0.01] * 16)
    out: list[Message] = [
        scan(),
        image(),
        Odometry(stamp_ns=STAMP, frame_id="odom", x_m=1.0, y_m=-2.0, yaw_rad=0.5, v_mps=0.3),
        PersonCandidates(
            stamp_ns=STAMP, frame_id="base_laser", detector="thesis", n_beams=720, candidates=[cand]
        ),
        TargetModel(
            stamp_ns=STAMP,
            model_id=1,
            verifier="histogram",
            x_m=1.2,
            y_m=0.0,
            rect_width_px=60,
            rect_height_px=180,
            image_width=320,
            image_height=240,
            features={
                "colour_hs": Array.from_numpy(np.full(216, 1 / 216, np.float32)),
                "edge_orientation": Array.from_numpy(np.full(72, 1 / 72, np.float32)),
                "patch_bgr": Array.from_numpy(np.arange(36, dtype=np.uint8).reshape(4, 3, 3)),
            },
        ),
        TargetCommand(stamp_ns=STAMP, action="acquire"),
        Verification(
            stamp_ns=STAMP,
            image_stamp_ns=STAMP - 10,
            model_id=1,
            verifier="histogram",
            candidates=[
                VerifiedCandidate(index=0, x_m=1.0, y_m=0.0, in_view=True, distance=0.2),
                VerifiedCandidate(index=1, x_m=-1.0, y_m=0.0, in_view=False),
            ],
            chosen=0,
            threshold=0.6,
        ),
        TrackState(
            stamp_ns=STAMP,
            frame_id="base_link",
            status="tracking",
            track_id=3,
            x_m=1.5,
            y_m=0.2,
            vx_mps=0.6,
            misses=0,
            sources=["laser", "vision"],
            estimator="particle",
        ),
        People(stamp_ns=STAMP, frame_id="base_link", tracks=[track], target_id=3),
        VelocityCommand(stamp_ns=STAMP, linear_mps=0.5, angular_radps=-0.2, reason="tracking"),
        PanCommand(stamp_ns=STAMP, pan_rad=0.4, reason="tracking"),
        Health(
            stamp_ns=STAMP,
            service="laser_legs",
            rates_hz={"in:sensors/scan": 40.0},
            received={"sensors/scan": 100},
            rejected={"sensors/scan": 2},
        ),
        GroundTruth(
            stamp_ns=STAMP,
            frame_id="world",
            robot_x_m=0.0,
            robot_y_m=0.0,
            robot_yaw_rad=0.0,
            target_id=1,
            people=[
                PersonTruth(
                    id=1,
                    x_m=2.0,
                    y_m=0.0,
                    robot_x_m=2.0,
                    is_target=True,
                    legs_robot_m=[2.0, 0.1, 2.0, -0.1],
                    visible_laser=True,
                )
            ],
        ),
    ]
    by_type = {type(m): m for m in out}
    assert set(by_type) == set(MESSAGE_TYPES), "an example is missing for a message type"
    return by_type
