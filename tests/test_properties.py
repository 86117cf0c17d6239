"""Property tests: no payload, however broken, escapes a decoder or stops a node."""

from __future__ import annotations

import math

import msgspec
import pytest
from examples import example_messages, scan
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from followbot.schemas import Message, RejectedMessage, decode, encode
from followbot.schemas.messages import MESSAGE_TYPES
from followbot.services.runtime.bus import FakeNetwork
from followbot.services.runtime.node import Node
from followbot.services.runtime.settings import NodeSettings

EXAMPLES = example_messages()

# Values that break types, bounds and cross-field rules.
nasty_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, -1, 0, 2**40, 1e300]),
    st.text(max_size=20),
    st.binary(max_size=64),
)
nasty_values = st.recursive(
    nasty_scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=10,
)


def _paths(node, prefix=()):
    """Every path to a value inside a decoded msgpack document."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, (*prefix, i))


def _mutated(message: Message, data: st.DataObject) -> bytes:
    doc = msgspec.msgpack.decode(encode(message))
    paths = [p for p in _paths(doc) if p]
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(paths))
        parent = doc
        try:
            for p in path[:-1]:
                parent = parent[p]
            action = data.draw(st.sampled_from(["replace", "delete", "truncate"]))
            if action == "delete" and isinstance(parent, dict):
                parent.pop(path[-1], None)
            elif action == "truncate" and isinstance(parent[path[-1]], bytes | list):
                parent[path[-1]] = parent[path[-1]][: data.draw(st.integers(0, 5))]
            else:
                parent[path[-1]] = data.draw(nasty_values)
        except (KeyError, IndexError, TypeError):
            continue  # an earlier mutation removed this path
    return msgspec.msgpack.encode(doc)


def _decode_or_reject(message_type, payload):
    try:
        msg = decode(message_type, payload)
    except RejectedMessage:
        return None
    # Whatever was accepted must be a valid message: it re-encodes and decodes to itself.
    assert decode(message_type, encode(msg)) == msg
    return msg


@pytest.mark.parametrize("message_type", MESSAGE_TYPES, ids=lambda t: t.__name__)
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(payload=st.binary(max_size=512))
def test_random_bytes_never_escape_a_decoder(message_type, payload):
    _decode_or_reject(message_type, payload)


@pytest.mark.parametrize("message_type", MESSAGE_TYPES, ids=lambda t: t.__name__)
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_malformed_but_decodable_messages_are_rejected_or_valid(message_type, data):
    payload = _mutated(EXAMPLES[message_type], data)
    _decode_or_reject(message_type, payload)


@pytest.mark.parametrize("message_type", MESSAGE_TYPES, ids=lambda t: t.__name__)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_truncated_payloads_are_rejected(message_type, data):
    payload = encode(EXAMPLES[message_type])
    cut = data.draw(st.integers(0, len(payload) - 1))
    with pytest.raises(RejectedMessage):
        decode(message_type, payload[:cut])


def test_accepted_floats_are_finite():
    """Spot check of the invariant the property tests rely on: NaN never gets through."""
    doc = msgspec.msgpack.decode(encode(EXAMPLES[MESSAGE_TYPES[2]]))  # Odometry
    for field in ("x_m", "y_m", "yaw_rad", "v_mps", "w_radps"):
        bad = dict(doc, **{field: math.nan})
        with pytest.raises(RejectedMessage, match=field):
            decode(MESSAGE_TYPES[2], msgspec.msgpack.encode(bad))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    stream=st.lists(
        st.one_of(
            st.integers(0, 10_000).map(lambda i: ("good", i)),
            st.binary(max_size=64).map(lambda b: ("bad", b)),
            st.just(("mutant", None)),
        ),
        max_size=25,
    ),
    data=st.data(),
)
def test_a_running_node_counts_bad_input_and_keeps_processing_good(stream, data):
    net = FakeNetwork()
    node = Node("prop", NodeSettings(), net.bus("prop"))
    got: list[int] = []
    inp = node.subscribe("sensors/scan", lambda m: got.append(m.stamp_ns))
    key = node.keys.topic("sensors/scan")
    expected_good, expected_rejected = [], 0
    for kind, value in stream:
        if kind == "good":
            net.put(key, encode(scan(n=16, stamp_ns=value)))
            expected_good.append(value)
            continue
        payload = value if kind == "bad" else _mutated(scan(n=16, stamp_ns=10**9), data)
        try:
            ok = decode(type(EXAMPLES[MESSAGE_TYPES[0]]), payload)
            expected_good.append(ok.stamp_ns)  # a mutation that leaves a valid message
        except RejectedMessage:
            expected_rejected += 1
        net.put(key, payload)
    node.spin_once()
    assert got == expected_good
    assert inp.rejected == expected_rejected
    assert node.health().rejected == {"sensors/scan": expected_rejected}
    assert node.errors == 0
