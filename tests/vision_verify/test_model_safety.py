"""vision_verify as a real process against hostile commands and models, and restarted late.

Each test runs `followbot run vision_verify` (and, for the restart, `followbot run tracker`)
over Zenoh and plays a rogue peer from the test's own session.
"""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import subprocess
import sys
import time

import msgspec
import numpy as np
import pytest
import zenoh
from conftest import LivelinessWatch

from followbot.schemas import (
    Array,
    Health,
    Image,
    Keys,
    PersonCandidates,
    TargetCommand,
    TargetModel,
    Verification,
    decode,
    encode,
)
from followbot.services.vision_verify.model import MAX_MODEL_BYTES, build_model, save_model
from followbot.services.vision_verify.verifiers.histogram import HistogramVerifier

from .helpers import acquired_scene
from .test_node import crossing_frame

pytestmark = pytest.mark.multiprocess


def model_message(model_id: int) -> TargetModel:
    camera, acq, _ = acquired_scene()
    return build_model(HistogramVerifier(), camera, acq, model_id).to_message()


class Peer:
    """The test's side of the network: commands, images and candidates out; verifications and
    vision_verify's health in."""

    def __init__(self, session, robot: str) -> None:
        self.session, self.keys = session, Keys(robot)
        self.verifications: queue.SimpleQueue = queue.SimpleQueue()
        self.healths: queue.SimpleQueue = queue.SimpleQueue()
        self._decls = [
            session.declare_subscriber(
                self.keys.topic("perception/verification"),
                lambda s: self.verifications.put(decode(Verification, s.payload.to_bytes())),
            ),
            session.declare_subscriber(
                self.keys.health("vision_verify"),
                lambda s: self.healths.put(decode(Health, s.payload.to_bytes())),
            ),
        ]
        self._pubs: dict[str, object] = {}
        self._k = 0

    def put(self, topic: str, payload: bytes) -> None:
        if topic not in self._pubs:
            self._pubs[topic] = self.session.declare_publisher(self.keys.topic(topic))
            self._decls.append(self._pubs[topic])
        self._pubs[topic].put(payload)

    def command(self, action: str, path: str = "") -> None:
        self.put(
            "perception/target_command",
            encode(TargetCommand(stamp_ns=time.time_ns(), action=action, path=path)),
        )

    def verification(self, proc, timeout_s: float = 20.0) -> Verification:
        """Send image + candidates pairs until one verification comes back."""
        px, pan, cands, _ = crossing_frame()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self._k += 1
            stamp = 10**9 * self._k
            self.put(
                "sensors/image", encode(Image.jpeg_from_array(px, stamp_ns=stamp, pan_rad=pan))
            )
            time.sleep(0.05)
            msg = PersonCandidates(
                stamp_ns=stamp, n_beams=cands.n_beams, candidates=cands.candidates
            )
            self.put("perception/candidates", encode(msg))
            with contextlib.suppress(queue.Empty):
                return self.verifications.get(timeout=0.5)
        raise AssertionError(f"no verification within {timeout_s} s:\n{proc.output}")

    def health_until(self, proc, ok, timeout_s: float = 15.0) -> Health:
        """The first Health for which ``ok(health)`` holds."""
        deadline = time.monotonic() + timeout_s
        last = None
        while time.monotonic() < deadline:
            with contextlib.suppress(queue.Empty):
                last = self.healths.get(timeout=0.5)
                if ok(last):
                    return last
        raise AssertionError(f"last health {last}:\n{proc.output}")

    def close(self) -> None:
        for d in self._decls:
            d.undeclare()


def start_vision(spawn, robot: str, endpoint: str, *settings: str):
    sets = [x for s in ("health_period_s=0.2", *settings) for x in ("--set", s)]
    return spawn("run", "vision_verify", "--robot", robot, "--connect", endpoint, *sets)


def test_save_and_load_outside_the_models_folder_are_refused_and_the_service_still_answers(
    spawn, endpoint, robot, zenoh_session, tmp_path
):
    folder = tmp_path / "models"
    save_model(folder / "target.model", model_message(3))
    os.mkfifo(folder / "pipe")
    (folder / "big.model").write_bytes(b"\0" * (MAX_MODEL_BYTES + 1))
    live = LivelinessWatch(zenoh_session, Keys(robot).alive("vision_verify"))
    peer = Peer(zenoh_session, robot)
    proc = start_vision(spawn, robot, endpoint, f"files.folder={folder}", "recovery.holder=")
    try:
        live.expect("PUT", timeout=20)
        peer.command("load", "target.model")
        assert peer.verification(proc).model_id == 4  # loaded models get a new id
        # the operator's command line says why
        out = subprocess.run(
            [sys.executable, "-m", "followbot", "target", "save", "--path", "../escape.model",
             "--robot", robot, "--connect", endpoint, "--wait", "10"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert out.returncode == 1, out.stdout + out.stderr
        assert "vision_verify refused: '../escape.model' is not a model name" in out.stderr
        # a rogue peer's commands
        peer.command("save", str(tmp_path / "absolute.model"))
        peer.command("save", "made/up/folders.model")
        peer.command("load", "pipe")  # would hang a plain open() for ever
        peer.command("load", "big.model")
        peer.command("load", "/dev/zero")
        h = peer.health_until(proc, lambda h: h.rejected.get("perception/target_command") == 6)
        assert h.errors == 0
        peer.health_until(proc, lambda h: h.status == "ok")  # refusals are no lasting harm
        assert peer.verification(proc).model_id == 4  # still answering, same model
        # one line per kind of refusal at least (a flood of one kind is rate-limited)
        for reason in (
            "command save '../escape.model' refused: '../escape.model' is not a model name",
            "command load 'pipe' refused: ",
            "pipe is a named pipe (FIFO), not a regular file",
            f"big.model has {MAX_MODEL_BYTES + 1} bytes, more than the {MAX_MODEL_BYTES}",
            "command load '/dev/zero' refused: '/dev/zero' is not a model name",
        ):
            assert reason in proc.output
        assert sorted(p.name for p in tmp_path.iterdir() if not p.name.endswith(".log")) == [
            "models"
        ]
        assert sorted(p.name for p in folder.iterdir()) == ["big.model", "pipe", "target.model"]
        assert live.events.empty()  # the liveliness token never went
        proc.signal(signal.SIGTERM)
        assert proc.wait(10) == 0, proc.output
    finally:
        live.undeclare()
        peer.close()


def test_rogue_models_are_refused_and_verification_goes_on_with_the_model_in_use(
    spawn, endpoint, robot, zenoh_session, tmp_path
):
    folder = tmp_path / "models"
    save_model(folder / "target.model", model_message(3))
    live = LivelinessWatch(zenoh_session, Keys(robot).alive("vision_verify"))
    peer = Peer(zenoh_session, robot)
    proc = start_vision(spawn, robot, endpoint, f"files.folder={folder}", "recovery.holder=")
    try:
        live.expect("PUT", timeout=20)
        peer.command("load", "target.model")
        assert peer.verification(proc).model_id == 4
        good = model_message(4)
        colour = np.array(good.features["colour_hs"].numpy())
        nan = np.where(np.arange(colour.size) == 7, np.nan, colour).astype(np.float32)
        for rogue in (
            msgspec.structs.replace(  # what the hostile tester sent: NaN features, id 10^9
                good, model_id=10**9, features={**good.features, "colour_hs": Array.from_numpy(nan)}
            ),
            msgspec.structs.replace(  # NaN features under a plausible id
                good, model_id=5, features={**good.features, "colour_hs": Array.from_numpy(nan)}
            ),
            msgspec.structs.replace(  # histograms of the wrong size
                good,
                model_id=6,
                features={**good.features, "edge_orientation": Array.from_numpy(colour[:36])},
            ),
        ):
            peer.put("perception/target_model", encode(rogue))
        h = peer.health_until(proc, lambda h: h.rejected.get("perception/target_model") == 3)
        assert h.errors == 0 and h.notes[0] == "model 4 (histogram)"
        peer.health_until(proc, lambda h: h.status == "ok")
        v = peer.verification(proc)
        assert v.model_id == 4 and v.chosen >= 0  # the model in use goes on judging
        assert "model_id 1000000000 is outside 1..1000000" in proc.output
        assert "model 5: feature 'colour_hs' holds NaN or infinite values" in proc.output
        assert "'edge_orientation' is float32 (36,), expected 72 float bins" in proc.output
        proc.signal(signal.SIGTERM)
        assert proc.wait(10) == 0, proc.output
    finally:
        live.undeclare()
        peer.close()


def test_a_late_restarted_worker_recovers_the_model_from_the_tracker_not_relearns_it(
    spawn, endpoint, robot, zenoh_session, tmp_path
):
    """vision_verify dies while the robot follows; it comes back well after the tracker
    (here 2 s after its old liveliness token went) with acquire.auto on. It must take the
    model the tracker keeps, under the same id, and must not learn another."""
    keys = Keys(robot)
    folder = tmp_path / "models"
    save_model(folder / "target.model", model_message(3))
    tracker_live = LivelinessWatch(zenoh_session, keys.alive("tracker"))
    live = LivelinessWatch(zenoh_session, keys.alive("vision_verify"))
    peer = Peer(zenoh_session, robot)
    tracker = spawn("run", "tracker", "--robot", robot, "--connect", endpoint)
    first = start_vision(spawn, robot, endpoint, f"files.folder={folder}")
    try:
        tracker_live.expect("PUT", timeout=20)
        live.expect("PUT", timeout=20)
        peer.command("load", "target.model")
        assert peer.verification(first).model_id == 4
        first.kill()  # SIGKILL: no goodbye
        live.expect("DELETE", timeout=10)

        def served() -> list[int]:
            replies = zenoh_session.get(
                keys.topic("perception/target_model"),
                target=zenoh.QueryTarget.ALL,
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=2.0,
            )
            return [decode(TargetModel, r.ok.payload.to_bytes()).model_id for r in replies if r.ok]

        assert served() == [4], tracker.output  # only the tracker is left, and it keeps it
        time.sleep(2.0)
        second = start_vision(
            spawn, robot, endpoint, f"files.folder={tmp_path / 'empty'}", "acquire.auto=true"
        )
        live.expect("PUT", timeout=20)
        v = peer.verification(second)
        assert v.model_id == 4, second.output
        h = peer.health_until(second, lambda h: h.notes and h.notes[0].startswith("model 4 "))
        assert h.notes[0] == "model 4 (histogram)"  # not "... acquiring": the learning stopped
        assert h.status == "ok" and "no target model" not in h.reasons
        assert "target model 4 from query" in second.output
        assert "auto-acquisition stopped: model 4 is in use" in second.output
        assert "built" not in second.output
        assert served() == [4, 4]  # the tracker and the restarted worker serve the same model
        for p in (second, tracker):
            p.signal(signal.SIGTERM)
            assert p.wait(10) == 0, p.output
    finally:
        for d in (tracker_live, live, peer):
            d.undeclare() if hasattr(d, "undeclare") else d.close()


def test_a_worker_without_a_model_keeps_asking_and_takes_a_good_answer_beside_a_rogue_one(
    spawn, endpoint, robot, zenoh_session, tmp_path
):
    """A rogue holder answers every query with a NaN model; the good holder (a tracker, here
    played by the test) turns up later. The worker refuses the rogue answer each time, keeps
    asking, and takes the good model when it is there."""
    keys = Keys(robot)
    key = keys.topic("perception/target_model")
    good = model_message(4)
    colour = np.array(good.features["colour_hs"].numpy())
    rogue = msgspec.structs.replace(
        good,
        model_id=9,  # newer-looking
        features={**good.features, "colour_hs": Array.from_numpy(colour * np.nan)},
    )
    holders = [zenoh_session.declare_queryable(key, lambda q: q.reply(key, encode(rogue)))]
    live = LivelinessWatch(zenoh_session, keys.alive("vision_verify"))
    peer = Peer(zenoh_session, robot)
    proc = start_vision(spawn, robot, endpoint, f"files.folder={tmp_path}", "recovery.holder=")
    try:
        live.expect("PUT", timeout=20)
        h = peer.health_until(proc, lambda h: h.rejected.get("perception/target_model", 0) >= 2)
        assert h.status == "degraded" and "no target model" in h.reasons
        assert h.notes[0] == "no model asking the network"
        assert "refused a target model from query (still none): model 9: feature 'colour_hs'" in (
            proc.output
        )
        holders.append(zenoh_session.declare_queryable(key, lambda q: q.reply(key, encode(good))))
        peer.health_until(proc, lambda h: h.notes[0] == "model 4 (histogram)")
        # the period it was recovered in also refused the rogue answer; then all is well
        h = peer.health_until(proc, lambda h: h.status == "ok")
        assert h.reasons == [] and h.notes[0] == "model 4 (histogram)"
        assert peer.verification(proc).model_id == 4
        proc.signal(signal.SIGTERM)
        assert proc.wait(10) == 0, proc.output
    finally:
        for d in (*holders, live, peer):
            d.undeclare() if hasattr(d, "undeclare") else d.close()
