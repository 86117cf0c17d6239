"""Wire messages: round trips, zero-copy arrays, validation on decode, evolution, keys."""

from __future__ import annotations

import math

import msgspec
import numpy as np
import pytest
from examples import STAMP, example_messages, image, scan

from followbot.schemas import (
    Array,
    Candidate,
    Image,
    Keys,
    LaserScan,
    Leg,
    Odometry,
    People,
    PersonCandidates,
    PersonTrack,
    RejectedMessage,
    TargetModel,
    TrackState,
    VelocityCommand,
    Verification,
    VerifiedCandidate,
    decode,
    decode_any,
    encode,
    topic_type,
)
from followbot.schemas.messages import MAX_BEAMS, MESSAGE_TYPES

EXAMPLES = example_messages()


@pytest.mark.parametrize("message_type", MESSAGE_TYPES, ids=lambda t: t.__name__)
def test_every_message_round_trips(message_type):
    msg = EXAMPLES[message_type]
    payload = encode(msg)
    back = decode(message_type, payload)
    assert back == msg
    assert decode_any(payload) == msg
    assert back.schema_version == 1 and back.stamp_ns == STAMP


def test_scan_ranges_are_a_view_into_the_payload():
    payload = encode(scan())
    msg = decode(LaserScan, payload)
    ranges = msg.ranges_m()
    assert np.shares_memory(ranges, np.frombuffer(payload, np.uint8))
    assert not ranges.flags.writeable
    assert ranges.dtype == np.float32 and ranges.shape == (720,)
    np.testing.assert_array_equal(ranges, scan().ranges_m())
    angles = msg.angles_rad()
    assert angles[0] == pytest.approx(-2.356) and angles[-1] == pytest.approx(-2.356 + 4.712)


def test_raw_image_pixels_are_a_view_and_jpeg_round_trips():
    img = image()
    payload = encode(img)
    px = decode(Image, payload).pixels()
    assert px.shape == (48, 64, 3)
    assert np.shares_memory(px, np.frombuffer(payload, np.uint8))
    np.testing.assert_array_equal(px, img.pixels())

    smooth = np.zeros((48, 64, 3), np.uint8)
    smooth[:, 32:] = (10, 200, 30)
    jpg = Image.jpeg_from_array(smooth, stamp_ns=5, quality=95)
    back = decode(Image, encode(jpg))
    assert back.encoding == "jpeg"
    assert np.abs(back.pixels().astype(int) - smooth).mean() < 3


def test_corrupt_jpeg_fails_loudly_when_decoded():
    bad = Image(stamp_ns=1, width=8, height=8, encoding="jpeg", data=memoryview(b"\xff\xd8junk"))
    msg = decode(Image, encode(bad))  # the envelope is valid
    with pytest.raises(ValueError, match="corrupt JPEG"):
        msg.pixels()


def test_array_from_numpy_converts_byte_order_and_rejects_odd_dtypes():
    big_endian = np.arange(4, dtype=">f4")
    arr = Array.from_numpy(big_endian)
    assert arr.dtype == "<f4"
    np.testing.assert_array_equal(arr.numpy(), [0, 1, 2, 3])
    with pytest.raises(TypeError, match="cannot travel"):
        Array.from_numpy(np.zeros(3, np.complex64))


def _reencoded(message, **changes):
    """The payload of ``message`` with fields replaced at the msgpack level (bypassing checks)."""
    data = msgspec.msgpack.decode(encode(message))  # plain dicts, bytes kept as bytes
    for path, value in changes.items():
        node = data
        *parents, last = path.split("__")
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        node[last] = value
    return msgspec.msgpack.encode(data)


@pytest.mark.parametrize(
    ("message", "changes", "reason"),
    [
        (scan(), {"ranges__data": b"\x00" * 7}, "bytes"),
        (scan(), {"intensities__data": b"\x00" * 8, "intensities__shape": [2]}, "intensities"),
        (scan(), {"ranges__dtype": "|u1", "ranges__data": b"\x00" * 720}, "float32"),
        (scan(), {"angle_increment_rad": 0.0}, "angle_increment"),
        (scan(), {"angle_increment_rad": 1.0}, "full turn"),
        (scan(), {"range_min_m": 40.0}, "range_min_m"),
        (scan(), {"range_max_m": math.inf}, "range_max_m"),
        (scan(), {"angle_min_rad": math.nan}, "angle_min_rad"),
        (scan(), {"stamp_ns": -1}, "stamp_ns"),
        (image(), {"width": 65}, "needs"),
        (image(), {"width": 5000}, "width"),
        (image(), {"height": -3}, "height"),
        (image(), {"encoding": "rgb16"}, "encoding"),
        (image(), {"encoding": "jpeg"}, "SOI"),
        (EXAMPLES[Odometry], {"x_m": math.nan}, "x_m"),
        (EXAMPLES[Odometry], {"yaw_rad": math.inf}, "yaw_rad"),
        (EXAMPLES[PersonCandidates], {"n_beams": 20}, "outside"),
        (EXAMPLES[PersonCandidates], {"candidates__0__x_m": math.nan}, "x_m"),
        (EXAMPLES[Verification], {"chosen": 5}, "chosen"),
        (EXAMPLES[TargetModel], {"features__colour_hs__dtype": "<i4"}, "float or uint8"),
        (EXAMPLES[Verification], {"chosen": 1}, "not in view"),
        (EXAMPLES[TrackState], {"covariance": [0.0] * 15}, "covariance"),
        (EXAMPLES[TrackState], {"status": "confused"}, "status"),
        (
            EXAMPLES[People],
            {"tracks": [msgspec.to_builtins(PersonTrack(id=1, x_m=0, y_m=0))] * 2},
            "duplicate",
        ),
    ],
)
def test_invalid_payloads_are_rejected_with_a_reason(message, changes, reason):
    payload = _reencoded(message, **changes)
    with pytest.raises(RejectedMessage, match=reason):
        decode(type(message), payload)


def test_scan_size_bound():
    with pytest.raises(ValueError, match="beams"):  # a producer cannot even build one
        LaserScan.from_ranges(
            np.ones(MAX_BEAMS + 1, np.float32),
            stamp_ns=1,
            angle_min_rad=0,
            angle_increment_rad=1e-4,
        )
    payload = _reencoded(
        scan(),
        ranges__data=b"\x00" * 4 * (MAX_BEAMS + 1),
        ranges__shape=[MAX_BEAMS + 1],
        intensities=None,
        angle_increment_rad=1e-4,
    )
    with pytest.raises(RejectedMessage, match="beams"):
        decode(LaserScan, payload)
    ok = LaserScan.from_ranges(
        np.ones(MAX_BEAMS, np.float32), stamp_ns=1, angle_min_rad=0, angle_increment_rad=1e-4
    )
    assert decode(LaserScan, encode(ok)).ranges.shape == [MAX_BEAMS]


def test_nan_ranges_are_no_return_not_an_error():
    ranges = np.array([np.nan, np.inf, 0.0, 1.0], np.float32)
    msg = LaserScan.from_ranges(ranges, stamp_ns=1, angle_min_rad=0, angle_increment_rad=0.01)
    assert np.isnan(decode(LaserScan, encode(msg)).ranges_m()[0])


def test_wrong_type_tag_is_rejected():
    with pytest.raises(RejectedMessage, match="laser_scan"):
        decode(Odometry, encode(scan()))


def test_evolution_unknown_fields_ignored_and_new_fields_defaulted():
    data = msgspec.to_builtins(EXAMPLES[Odometry])
    data["future_field"] = {"anything": [1, 2, 3]}
    assert decode(Odometry, msgspec.msgpack.encode(data)) == EXAMPLES[Odometry]
    for optional in ("v_mps", "w_radps", "seq", "frame_id", "schema_version"):
        del data[optional]
    old = decode(Odometry, msgspec.msgpack.encode(data))
    assert old.v_mps == 0.0 and old.seq == 0 and old.schema_version == 1


def test_leg_span_must_be_ordered():
    leg = msgspec.to_builtins(Leg(x_m=1, y_m=0, first_beam=3, last_beam=4))
    leg["first_beam"] = 9
    cand = msgspec.to_builtins(Candidate(x_m=1, y_m=0, range_m=1, bearing_rad=0))
    cand["legs"] = [leg]
    msg = msgspec.to_builtins(PersonCandidates(stamp_ns=1, n_beams=100))
    msg["candidates"] = [cand]
    with pytest.raises(RejectedMessage, match="first_beam"):
        decode(PersonCandidates, msgspec.msgpack.encode(msg))


def test_verification_with_no_choice_is_valid():
    v = Verification(
        stamp_ns=1,
        image_stamp_ns=1,
        model_id=0,
        verifier="histogram",
        candidates=[VerifiedCandidate(index=0, x_m=1, y_m=0, in_view=True, distance=0.9)],
        chosen=-1,
        threshold=0.5,
    )
    assert decode(Verification, encode(v)).chosen == -1


# ------------------------------------------------------------------------------------ keys


def test_keys_are_namespaced_by_robot():
    k = Keys("r1")
    assert k.topic("sensors/scan") == "followbot/r1/sensors/scan"
    assert k.health("laser_legs") == "followbot/r1/health/laser_legs"
    assert k.alive("tracker") == "followbot/r1/alive/tracker"
    assert k.topic_of("followbot/r1/control/cmd_vel") == "control/cmd_vel"
    assert Keys("r2").topic("sensors/scan") != k.topic("sensors/scan")


@pytest.mark.parametrize("bad", ["", "a/b", "a*", "x" * 65, "r 1", "**"])
def test_bad_robot_names_are_refused(bad):
    with pytest.raises(ValueError, match="robot name"):
        Keys(bad)


def test_unknown_topic_lists_the_valid_ones():
    with pytest.raises(ValueError, match="sensors/scan"):
        Keys().topic("sensors/scna")
    assert topic_type("health/anything") is not None


@pytest.mark.parametrize(("v", "w"), [(10.0**12, 0.0), (-3.5, 0.0), (0.5, 7.0), (0.0, -100.0)])
def test_velocity_commands_beyond_any_base_are_rejected_on_the_wire(v, w):
    # a command any receiver refuses: no followbot base goes faster than 3 m/s or 2 pi rad/s
    payload = msgspec.msgpack.encode(
        {"type": "velocity_command", "stamp_ns": 1, "linear_mps": v, "angular_radps": w}
    )
    with pytest.raises(RejectedMessage):
        decode(VelocityCommand, payload)
