"""vision_verify as a real process over Zenoh: recovers the model by query, judges, stops."""

from __future__ import annotations

import contextlib
import queue
import signal
import time

import pytest
from conftest import LivelinessWatch

from followbot.schemas import Health, Image, Keys, PersonCandidates, Verification, decode, encode
from followbot.services.vision_verify.model import build_model
from followbot.services.vision_verify.verifiers.histogram import HistogramVerifier

from .helpers import acquired_scene, owner
from .test_node import crossing_frame

pytestmark = pytest.mark.multiprocess


def test_vision_verify_process_recovers_model_and_judges(spawn, endpoint, robot, zenoh_session):
    keys = Keys(robot)
    camera, acq, _ = acquired_scene()
    model = build_model(HistogramVerifier(), camera, acq, 9).to_message()
    model_payload = encode(model)
    # a "previous worker" that still serves the model on the network
    qbl = zenoh_session.declare_queryable(
        keys.topic("perception/target_model"),
        lambda q: q.reply(keys.topic("perception/target_model"), model_payload),
    )
    live = LivelinessWatch(zenoh_session, keys.alive("vision_verify"))
    got: queue.SimpleQueue = queue.SimpleQueue()
    vsub = zenoh_session.declare_subscriber(
        keys.topic("perception/verification"),
        lambda s: got.put(decode(Verification, s.payload.to_bytes())),
    )
    healths: queue.SimpleQueue = queue.SimpleQueue()
    hsub = zenoh_session.declare_subscriber(
        keys.health("vision_verify"), lambda s: healths.put(decode(Health, s.payload.to_bytes()))
    )
    proc = spawn(
        "run",
        "vision_verify",
        "--robot",
        robot,
        "--connect",
        endpoint,
        "--set",
        "health_period_s=0.2",
    )
    try:
        live.expect("PUT", timeout=15)
        img_pub = zenoh_session.declare_publisher(keys.topic("sensors/image"))
        cand_pub = zenoh_session.declare_publisher(keys.topic("perception/candidates"))
        px, pan, cands, truth = crossing_frame()
        v = None
        deadline = time.monotonic() + 15
        k = 0
        while v is None and time.monotonic() < deadline:
            k += 1
            stamp = 10**9 * k
            img_pub.put(encode(Image.jpeg_from_array(px, stamp_ns=stamp, pan_rad=pan)))
            time.sleep(0.05)
            cand_pub.put(
                encode(
                    PersonCandidates(
                        stamp_ns=stamp, n_beams=cands.n_beams, candidates=cands.candidates
                    )
                )
            )
            with contextlib.suppress(queue.Empty):
                v = got.get(timeout=0.5)
        assert v is not None, proc.output
        assert v.model_id == 9  # the model recovered by query on start
        assert v.stamp_ns % 10**9 == 0 and v.image_stamp_ns == v.stamp_ns
        assert v.chosen >= 0 and owner(cands.candidates[v.chosen], truth) == 1
        img_pub.put(b"\x00not an image")  # bad input: rejected, counted, no crash
        h = None
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            h = healths.get(timeout=2)
            if h.rejected.get("sensors/image", 0) >= 1:
                break
        assert h is not None and h.rejected["sensors/image"] >= 1 and h.errors == 0
        proc.signal(signal.SIGTERM)
        assert proc.wait(10) == 0, proc.output
    finally:
        for d in (qbl, live, vsub, hsub):
            d.undeclare()
