"""The vision_verify node on an in-process network: pairing, lock-step, model life, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from followbot.schemas import (
    Array,
    Candidate,
    Image,
    Keys,
    PersonCandidates,
    TargetCommand,
    TargetModel,
    Verification,
    decode,
    encode,
)
from followbot.services.runtime.bus import FakeNetwork
from followbot.services.runtime.node import Node
from followbot.services.runtime.settings import load_settings
from followbot.services.vision_verify.model import build_model, save_model
from followbot.services.vision_verify.node import VisionVerifySettings, setup
from followbot.services.vision_verify.verifiers.histogram import HistogramVerifier

from .helpers import acquired_scene, owner

KEYS = Keys("robot")


@pytest.fixture(autouse=True)
def _models_home(tmp_path, monkeypatch):
    """The default models folder ($XDG_DATA_HOME/followbot/models) in the test's own folder."""
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))


class Rig:
    def __init__(self, net: FakeNetwork | None = None, **kw) -> None:
        self.net = net or FakeNetwork()
        # quick queries, and no model holder to wait for, unless a test names one
        kw["recovery"] = {"query_timeout_s": 0.05, "holder": "", **kw.get("recovery", {})}
        self.settings = load_settings(VisionVerifySettings, base=kw)
        self.node = Node("vision_verify", self.settings, self.net.bus())
        self.svc = setup(self.node, self.settings)
        self._bus = self.net.bus("test")

    def put(self, topic: str, message) -> None:
        self._bus.publisher(KEYS.topic(topic)).put(encode(message))
        self.node.spin_once()

    def put_raw(self, topic: str, payload: bytes) -> None:
        self._bus.publisher(KEYS.topic(topic)).put(payload)
        self.node.spin_once()

    def out(self, topic: str, message_type):
        key = KEYS.topic(topic)
        return [decode(message_type, p) for k, p in self.net.published if k == key]

    def verifications(self) -> list[Verification]:
        return self.out("perception/verification", Verification)


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    camera, acq, _ = acquired_scene()
    path = tmp_path_factory.mktemp("model") / "target.model"
    save_model(path, build_model(HistogramVerifier(), camera, acq, 3).to_message())
    return path


def crossing_frame():
    """A frame with both people judged (t > 4 s): image pixels, pan, candidates, truth."""
    _, _, frames = acquired_scene()
    image, px, cands, truth, _scan = next(
        f
        for f in frames
        if f[0].stamp_ns > 4.3e9 and {owner(c, f[3]) for c in f[2].candidates} >= {1, 2}
    )
    return px, image.pan_rad, cands, truth


def load_command(model_file) -> TargetCommand:
    return TargetCommand(stamp_ns=0, action="load", path=model_file.name)


def loaded(path, **kw) -> Rig:
    kw["files"] = {"folder": str(path.parent), **kw.get("files", {})}
    rig = Rig(**kw)
    rig.put("perception/target_command", load_command(path))
    assert rig.svc.model is not None
    return rig


def test_loads_a_model_publishes_it_and_judges_a_pair(model_file):
    rig = loaded(model_file)
    (model_msg,) = rig.out("perception/target_model", TargetModel)
    assert model_msg.model_id == 4  # loaded models get a new id
    px, pan, cands, truth = crossing_frame()
    stamp = cands.stamp_ns
    rig.put("sensors/image", Image.from_array(px, stamp_ns=stamp + 20_000_000, pan_rad=pan))
    assert rig.verifications() == []  # no candidates yet
    rig.put("perception/candidates", cands)
    (v,) = rig.verifications()
    assert v.stamp_ns == stamp and v.image_stamp_ns == stamp + 20_000_000
    assert v.model_id == 4 and v.verifier == "histogram"
    assert [c.index for c in v.candidates] == list(range(len(cands.candidates)))
    assert [(c.x_m, c.y_m) for c in v.candidates] == [(c.x_m, c.y_m) for c in cands.candidates]
    assert v.chosen >= 0 and owner(cands.candidates[v.chosen], truth) == 1  # the target
    assert v.threshold == pytest.approx(HistogramVerifier().default_threshold)


def test_jpeg_images_give_the_same_choice(model_file):
    rig = loaded(model_file)
    px, pan, cands, _ = crossing_frame()
    rig.put("sensors/image", Image.jpeg_from_array(px, stamp_ns=cands.stamp_ns, pan_rad=pan))
    rig.put("perception/candidates", cands)
    (v,) = rig.verifications()
    raw = loaded(model_file)
    raw.put("sensors/image", Image.from_array(px, stamp_ns=cands.stamp_ns, pan_rad=pan))
    raw.put("perception/candidates", cands)
    assert v.chosen == raw.verifications()[0].chosen


def test_waits_for_the_nearest_image_then_pairs(model_file):
    rig = loaded(model_file)
    px, pan, cands, _ = crossing_frame()
    t = cands.stamp_ns
    rig.put("sensors/image", Image.from_array(px, stamp_ns=t - 160_000_000, pan_rad=pan))
    rig.put("sensors/image", Image.from_array(px, stamp_ns=t - 60_000_000, pan_rad=pan))
    # camera period 100 ms; the scan is 60 ms after the last image: the next one (due at
    # t + 40 ms) will be nearer, so it waits
    rig.put("perception/candidates", cands)
    assert rig.verifications() == []
    rig.put("sensors/image", Image.from_array(px, stamp_ns=t + 10_000_000, pan_rad=pan))
    (v,) = rig.verifications()
    assert v.image_stamp_ns == t + 10_000_000


def test_lock_step_pairs_the_scan_with_its_own_image_whatever_comes_first(model_file):
    """Candidates of scan k may arrive before image k (they come through laser_legs): in
    lock-step the scan waits for the image that is due, so reruns pair the same frames."""
    rig = loaded(model_file, answer_every_scan=True, image_wait_s=5.0)
    px, pan, cands, _ = crossing_frame()
    t = cands.stamp_ns
    rig.put("sensors/image", Image.from_array(px, stamp_ns=t - 200_000_000, pan_rad=pan))
    rig.put("sensors/image", Image.from_array(px, stamp_ns=t - 100_000_000, pan_rad=pan))
    rig.put("perception/candidates", cands)  # image t is due but not here yet
    assert rig.verifications() == []
    rig.put("sensors/image", Image.from_array(px, stamp_ns=t, pan_rad=pan))
    (v,) = rig.verifications()
    assert v.stamp_ns == t and v.image_stamp_ns == t


def test_stale_scans_are_dropped_not_queued(model_file):
    rig = loaded(model_file, max_lag_s=0.3)
    px, pan, cands, _ = crossing_frame()
    for k in range(10):  # 10 scans, 120 ms apart, no image yet
        msg = PersonCandidates(
            stamp_ns=10**9 + k * 120_000_000, n_beams=cands.n_beams, candidates=cands.candidates
        )
        rig.put("perception/candidates", msg)
    assert len(rig.svc.pending) <= 3
    last = 10**9 + 9 * 120_000_000
    rig.put("sensors/image", Image.from_array(px, stamp_ns=last, pan_rad=pan))
    assert [v.stamp_ns for v in rig.verifications()] == [last]
    assert rig.svc.counts["scan_stale"] + rig.svc.counts.get("scan_no_image", 0) == 9


def test_lock_step_answers_every_scan_even_without_model_or_image(model_file):
    rig = Rig(answer_every_scan=True, image_wait_s=0.01, files={"folder": str(model_file.parent)})
    for k in range(3):
        rig.put("perception/candidates", PersonCandidates(stamp_ns=k + 1))
    assert [(v.stamp_ns, v.chosen, v.candidates) for v in rig.verifications()] == [
        (1, -1, []),
        (2, -1, []),
        (3, -1, []),
    ]
    rig.put("perception/target_command", load_command(model_file))
    rig.put("perception/candidates", PersonCandidates(stamp_ns=10**9))  # no image ever comes
    import time

    time.sleep(0.03)
    rig.node.spin_once()
    rig.svc.on_timer()
    assert [v.stamp_ns for v in rig.verifications()] == [1, 2, 3, 10**9]


def test_a_restarted_worker_recovers_the_model_by_query(model_file):
    first = loaded(model_file)
    second = Rig(net=first.net)
    assert second.svc.model is not None and second.svc.model.model_id == 4
    np.testing.assert_array_equal(
        second.svc.model.features["colour_hs"], first.svc.model.features["colour_hs"]
    )
    first.put("perception/target_command", TargetCommand(stamp_ns=0, action="reset"))
    assert first.svc.model is None and first.svc.pub_model.last_payload is None
    # the second worker still serves the model it adopted
    third = Rig(net=first.net)
    assert third.svc.model is not None and third.svc.model.model_id == 4


class Holder:
    """A stand-in for the tracker on the fake network: alive, and answering model queries
    with ``model`` (None: it holds none), as the tracker's serve_last publisher does."""

    def __init__(self, net: FakeNetwork, model: TargetModel | None) -> None:
        self.bus = net.bus("tracker")
        self.bus.liveliness_token(KEYS.alive("tracker"))
        self.payload = None if model is None else encode(model)
        self.bus.queryable(KEYS.topic("perception/target_model"), lambda: self.payload)


def _the_model(model_file) -> TargetModel:
    from followbot.services.vision_verify.model import load_model

    return load_model(model_file)


def _acquisition():
    _, acq, _ = acquired_scene()
    return acq


def test_a_worker_without_a_model_keeps_asking_until_it_recovers_one(model_file):
    """Nobody answers at start; the model appears later where only a query finds it (the
    tracker serves it, nobody publishes it): the next periodic query recovers it."""
    net = FakeNetwork()
    rig = Rig(net=net)
    assert rig.svc.model is None and rig.svc.asking
    h = rig.node.health()
    assert h.status == "degraded" and "no target model" in h.reasons
    holder = Holder(net, None)
    rig.node.run_timer("ask_model")
    rig.svc._query_thread.join(5)
    rig.node.spin_once()
    assert rig.svc.model is None and rig.svc.asking  # asked: nobody has one yet
    holder.payload = encode(_the_model(model_file))
    rig.node.run_timer("ask_model")
    rig.svc._query_thread.join(5)
    rig.node.spin_once()
    assert rig.svc.model is not None and rig.svc.model.model_id == 3
    assert not rig.svc.asking
    assert rig.node.health().status == "ok" and rig.node.health().reasons == []


def test_a_reset_stops_the_asking(model_file):
    net = FakeNetwork()
    rig = Rig(net=net)
    rig.put("perception/target_command", TargetCommand(stamp_ns=5, action="reset"))
    assert rig.node.notes[-1] == "command reset 5 done: target model dropped"
    Holder(net, _the_model(model_file))
    rig.node.run_timer("ask_model")
    assert rig.svc._query_thread is None  # the operator dropped the model: not recovered
    assert rig.svc.model is None


def test_acquire_auto_gives_way_to_the_model_a_holder_keeps(model_file):
    """A restarted worker with acquire.auto: the tracker holds model 3; the worker recovers it
    before it says it is alive, and does not learn another."""
    net = FakeNetwork()
    Holder(net, _the_model(model_file))
    rig = Rig(
        net=net, acquire={"auto": True}, recovery={"holder": "tracker", "holder_wait_s": 30.0}
    )
    assert rig.svc.model.model_id == 3 and rig.svc.model_id == 3
    assert rig.svc.builder is None  # auto-acquisition stopped: there is a model
    assert rig.node.health().status == "ok"


def test_acquire_auto_learns_when_the_holder_is_alive_and_holds_nothing():
    net = FakeNetwork()
    Holder(net, None)
    rig = Rig(
        net=net, acquire={"auto": True}, recovery={"holder": "tracker", "holder_wait_s": 30.0}
    )
    assert rig.svc.nobody_holds and rig.svc.builder is not None  # at once, not after 30 s
    rig.svc._acquired(_acquisition())
    assert rig.svc.model is not None and rig.svc.model.model_id == 1
    (published,) = rig.out("perception/target_model", TargetModel)
    assert published.model_id == 1


def test_a_model_learnt_before_anyone_answered_waits_and_loses_to_a_recovered_one(model_file):
    """With no holder seen, nobody-holds-one is not concluded before recovery.holder_wait_s: a model
    learnt meanwhile is held back; a model the network then gives is used instead."""
    import time

    net = FakeNetwork()
    t0 = time.monotonic()
    rig = Rig(net=net, acquire={"auto": True}, recovery={"holder": "tracker", "holder_wait_s": 0.3})
    assert time.monotonic() - t0 >= 0.3  # setup asked until the wait was over
    assert rig.svc.nobody_holds  # no holder appeared: nobody holds one
    # the same, with the conclusion still open when the model is learnt
    rig.svc.nobody_holds = False
    rig.svc.start_acquire(auto=True)
    rig.svc._acquired(_acquisition())
    assert rig.svc.model is None and rig.svc.held_build is not None
    assert rig.out("perception/target_model", TargetModel) == []
    rig.svc._answered([_the_model(model_file)], conclusive=False)
    assert rig.svc.model.model_id == 3 and rig.svc.held_build is None
    assert rig.svc.counts["acquired_dropped"] == 1
    # ... and had nobody answered, the held model would have gone in
    other = Rig(net=FakeNetwork(), acquire={"auto": True}, recovery={"holder_wait_s": 0.01})
    other.svc.nobody_holds = False
    other.svc._acquired(_acquisition())
    assert other.svc.model is None
    other.svc._answered([], conclusive=True)
    assert other.svc.model is not None and other.svc.model.model_id == 1


def test_a_rogue_model_is_refused_and_the_model_in_use_stays(model_file):
    import msgspec

    rig = loaded(model_file)
    good = rig.out("perception/target_model", TargetModel)[0]
    colour = np.array(good.features["colour_hs"].numpy())
    rogue = [
        msgspec.structs.replace(  # NaN features
            good,
            model_id=20,
            features={**good.features, "colour_hs": Array.from_numpy(colour * np.nan)},
        ),
        msgspec.structs.replace(good, model_id=10**9),  # an absurd id
        msgspec.structs.replace(  # histogram of the wrong size
            good,
            model_id=50,
            features={**good.features, "colour_hs": Array.from_numpy(colour[:100])},
        ),
        msgspec.structs.replace(good, model_id=51, verifier="meanshift"),
    ]
    for m in rogue:
        rig.put("perception/target_model", m)
    assert rig.svc.model.model_id == 4 and rig.svc.model_id == 4
    h = rig.node.health()
    assert h.rejected["perception/target_model"] == 4
    assert h.reasons == ["rejected 4 perception/target_model (model wrong_verifier)"]
    assert rig.node.health().status == "ok"  # the next period: nothing wrong, a model in use
    c = rig.svc.counts
    assert c["model_non_finite"] == 1 and c["model_bad_model_id"] == 1
    assert c["model_bad_features"] == 1 and c["model_wrong_verifier"] == 1
    px, pan, cands, _ = crossing_frame()
    rig.put("sensors/image", Image.from_array(px, stamp_ns=cands.stamp_ns, pan_rad=pan))
    rig.put("perception/candidates", cands)
    (v,) = rig.verifications()
    assert v.model_id == 4 and v.chosen >= 0
    # a good newer model from another worker still replaces it
    rig.put("perception/target_model", msgspec.structs.replace(good, model_id=6))
    assert rig.svc.model.model_id == 6


def test_save_command_writes_a_loadable_file_in_the_models_folder(model_file, tmp_path):
    rig = loaded(model_file)
    rig.svc.files.folder = tmp_path / "models"  # saved elsewhere than the fixture's folder
    rig.put("perception/target_command", TargetCommand(stamp_ns=7, action="save", path="saved"))
    assert (tmp_path / "models" / "saved").is_file()
    assert rig.node.notes[-1].startswith("command save 7 done: model 4 saved to ")
    other = Rig(files={"folder": str(tmp_path / "models")})
    other.put("perception/target_command", TargetCommand(stamp_ns=0, action="load", path="saved"))
    assert other.svc.model.model_id == 5
    # no name: the files.default_name setting's, in the same folder
    rig.put("perception/target_command", TargetCommand(stamp_ns=0, action="save"))
    assert (tmp_path / "models" / "target.model").is_file()


def test_a_save_or_load_that_cannot_be_done_is_refused_counted_and_reported(model_file, tmp_path):
    rig = loaded(model_file, files={"default_name": ""})
    # no name and no files.default_name setting; a file that is not there: refused, not a failure
    rig.put("perception/target_command", TargetCommand(stamp_ns=1, action="save"))
    assert rig.node.notes[-1] == (
        "command save 1 refused: save: no path in the command and no files.default_name setting"
    )
    rig.put("perception/target_command", TargetCommand(stamp_ns=2, action="load", path="gone"))
    assert rig.node.notes[-1].startswith("command load 2 refused: no model file 'gone' in ")
    assert rig.node.errors == 0 and rig.svc.model.model_id == 4
    assert rig.node.health().rejected["perception/target_command"] == 2
    empty = Rig(files={"folder": str(tmp_path)})
    empty.put("perception/target_command", TargetCommand(stamp_ns=3, action="save", path="x"))
    assert empty.node.notes[-1] == "command save 3 refused: save: there is no target model"
    assert not (tmp_path / "x").exists()


def test_a_model_the_verifier_cannot_use_is_refused_at_the_door(model_file):
    """A histogram model relabelled for a meanshift worker: its features are not meanshift's,
    so it is refused on arrival (counted in Health.rejected), never installed."""
    import msgspec

    from followbot.services.vision_verify.model import load_model

    rig = Rig(verifier="meanshift", answer_every_scan=True)
    wrong = msgspec.structs.replace(load_model(model_file), verifier="meanshift")
    rig.put("perception/target_model", wrong)
    assert rig.svc.model is None and rig.svc.counts["model_bad_features"] == 1
    assert rig.node.health().rejected["perception/target_model"] == 1
    assert "no target model" in rig.node.health().reasons


def test_a_model_found_unusable_while_judging_is_dropped_once_not_failed_on_every_scan(
    model_file,
):
    """A verifier plugin without check_model cannot refuse a model at the door: the first
    judgement finds it unusable; the model is dropped, counted, and Health says so."""
    import msgspec

    from followbot.services.vision_verify.core import Camera, Model
    from followbot.services.vision_verify.model import load_model

    rig = Rig(verifier="meanshift", answer_every_scan=True)
    wrong = msgspec.structs.replace(load_model(model_file), verifier="meanshift")
    rig.svc._use(Model.from_message(wrong, Camera()), publish=False, source="test")
    assert rig.svc.model is not None and rig.node.health().status == "ok"
    px, pan, cands, _ = crossing_frame()
    rig.put("sensors/image", Image.from_array(px, stamp_ns=cands.stamp_ns, pan_rad=pan))
    rig.put("perception/candidates", cands)
    assert rig.svc.model is None and rig.svc.counts["model_incompatible"] == 1
    (v,) = rig.verifications()  # lock-step: still answered
    assert v.stamp_ns == cands.stamp_ns and v.chosen == -1
    assert rig.node.health().status == "degraded"


def test_bad_images_and_candidates_are_counted_and_skipped(model_file):
    rig = loaded(model_file, max_rect_width_factor=2.0)
    px, pan, cands, _ = crossing_frame()
    t = cands.stamp_ns
    small = np.zeros((48, 64, 3), np.uint8)
    rig.put("sensors/image", Image.from_array(small, stamp_ns=t, pan_rad=pan))  # wrong size
    rig.put("sensors/image", Image.from_array(px, stamp_ns=t, intrinsics_id="nope"))
    corrupt = Image.from_array(px, stamp_ns=t)
    corrupt.encoding, corrupt.data = "jpeg", memoryview(b"\xff\xd8" + b"\x13" * 500)
    rig.put("sensors/image", corrupt)
    rig.put_raw("sensors/image", b"\x00garbage")  # does not even decode
    assert rig.svc.in_image.rejected == 4
    assert rig.svc.frames == []
    rig.put("sensors/image", Image.from_array(px, stamp_ns=t, pan_rad=pan))
    odd = [
        Candidate(x_m=-1.0, y_m=0.0, range_m=1.0, bearing_rad=3.1),  # behind
        Candidate(x_m=0.0, y_m=0.0, range_m=0.0, bearing_rad=0.0),  # at the laser
        Candidate(x_m=0.31, y_m=0.0, range_m=0.31, bearing_rad=0.0),  # > 2 image widths
        Candidate(x_m=1e6, y_m=0.0, range_m=1e6, bearing_rad=0.0),  # empty rectangle
    ]
    rig.put(
        "perception/candidates",
        PersonCandidates(stamp_ns=t, n_beams=cands.n_beams, candidates=[*odd, *cands.candidates]),
    )
    (v,) = rig.verifications()
    assert [c.in_view for c in v.candidates[:4]] == [False] * 4
    assert all(c.distance is None for c in v.candidates[:4])
    assert v.chosen >= 4
    c = rig.svc.counts
    assert c["candidate_behind"] == 2 and c["candidate_too_large"] == 1
    assert c["candidate_too_small"] == 1
    assert c["image_wrong_size"] == 1 and c["image_unknown_camera"] == 1
    assert c["image_corrupt_jpeg"] == 1
    assert rig.node.errors == 0
    health = rig.node.health()
    assert health.rejected["sensors/image"] == 4
    rig.svc.update_notes()
    assert any("candidate_behind=2" in n for n in rig.node.notes)


def test_settings_are_strict_and_plugins_checked():
    from followbot.services.runtime.settings import SettingsError

    with pytest.raises(SettingsError, match="thresold"):
        load_settings(VisionVerifySettings, base={"thresold": 1})
    with pytest.raises(ValueError, match="valid names"):
        Rig(verifier="nope")
    with pytest.raises(ValueError, match="verifier_settings"):
        Rig(verifier_settings={"edge_wieght": 1})


@settings(
    max_examples=30,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(
    st.lists(st.tuples(st.floats(-1e5, 1e5), st.floats(-1e5, 1e5)), max_size=20),
    st.floats(-6.2, 6.2),
)
def test_any_candidates_any_pan_never_fail(model_file, xy, pan):
    rig = loaded(model_file)
    px, _, _, _ = crossing_frame()
    rig.put("sensors/image", Image.from_array(px, stamp_ns=5, pan_rad=pan))
    cands = [Candidate(x_m=x, y_m=y, range_m=float(np.hypot(x, y)), bearing_rad=0.0) for x, y in xy]
    rig.put("perception/candidates", PersonCandidates(stamp_ns=5, candidates=cands))
    assert rig.node.errors == 0
    (v,) = rig.verifications()
    assert len(v.candidates) == len(xy)
    assert v.chosen == -1 or v.candidates[v.chosen].in_view


def online_judged(tmp_path, lockstep=False, **learn):
    """A vision_verify with an online model of person 1 (``learn`` settings; ``lockstep``:
    answer_every_scan) that judged the crossing frame: the rig, the candidates, the
    verification, person 1's and 2's judged candidates."""
    from followbot.services.vision_verify.verifiers.online import OnlineVerifier

    camera, acq, _ = acquired_scene()
    path = tmp_path / "online.model"
    save_model(path, build_model(OnlineVerifier(), camera, acq, 3).to_message())
    rig = loaded(path, verifier="online", learn=learn, answer_every_scan=lockstep)
    px, pan, cands, truth = crossing_frame()
    rig.put("sensors/image", Image.from_array(px, stamp_ns=cands.stamp_ns, pan_rad=pan))
    rig.put("perception/candidates", cands)
    (v,) = rig.verifications()
    people = [
        next(c for c in v.candidates if owner(cands.candidates[c.index], truth) == who)
        for who in (1, 2)
    ]
    return rig, cands, v, people


@pytest.mark.parametrize(("agree", "on_target", "learnt"), [
    (0.3, True, True),    # the tracker follows whom vision also takes for the target
    (0.3, False, False),  # the tracker follows the bystander: not learnt as the target
    (None, False, True),  # without the agreement rule, whatever the tracker follows
])  # fmt: skip
def test_an_online_verifier_learns_the_tracker_s_target_only_when_it_agrees(
    tmp_path, agree, on_target, learnt
):
    from followbot.schemas import TrackState

    rig, cands, _, (mine, other) = online_judged(tmp_path, agree_max_distance=agree)
    assert mine.probability > 0.7 > other.probability
    followed = mine if on_target else other
    before = rig.svc.model.features["state"][0]  # target views seen
    rig.put(
        "tracking/target",
        TrackState(stamp_ns=cands.stamp_ns, status="tracking", x_m=followed.x_m, y_m=followed.y_m),
    )
    assert rig.svc.model.features["state"][0] == before  # waits for the tracker's people
    rig.put(
        "tracking/people", people_at(cands.stamp_ns, followed, mine if followed is other else other)
    )
    assert (rig.svc.model.features["state"][0] == before + 1) == learnt
    assert (rig.svc.counts.get("learn_not_agreed", 0) == 1) == (not learnt)


def people_at(stamp_ns, target, *others):
    from followbot.schemas import People, PersonTrack

    tracks = [PersonTrack(id=1, x_m=target.x_m, y_m=target.y_m)]
    tracks += [PersonTrack(id=2 + i, x_m=o.x_m, y_m=o.y_m) for i, o in enumerate(others)]
    return People(stamp_ns=stamp_ns, tracks=tracks, target_id=1)


@pytest.mark.parametrize("bystanders", ["people", "candidates"])
def test_only_the_tracker_s_other_people_are_learnt_as_bystanders(tmp_path, bystanders):
    """learn.bystanders: people -- a candidate on none of the tracker's people (clutter) is
    not learnt as a bystander; candidates -- every other candidate is."""
    from followbot.schemas import TrackState

    rig, cands, v, (mine, _) = online_judged(tmp_path, bystanders=bystanders)
    rig.put("tracking/people", people_at(cands.stamp_ns, mine))  # nobody else is a person
    rig.put(
        "tracking/target",
        TrackState(stamp_ns=cands.stamp_ns, status="tracking", x_m=mine.x_m, y_m=mine.y_m),
    )
    state = rig.svc.model.features["state"]
    assert state[0] == 2  # the target learnt
    assert state[1] == (0 if bystanders == "people" else len(v.candidates) - 1)


def test_two_scans_judged_on_one_image_are_learnt_once(tmp_path):
    """A laser faster than the camera: the second scan is judged on the same image; learning
    it again would only copy the same views into the reservoirs. Lock-step: what scan k
    taught is learnt just before judging scan k + 2, whichever of the tracker's state of k
    and the candidates of k + 1 came first (reruns agree)."""
    import msgspec

    from followbot.schemas import TrackState

    rig, cands, _, (mine, other) = online_judged(tmp_path, lockstep=True)
    before = rig.svc.model.features["state"][0]

    def scan(k):
        later = msgspec.structs.replace(cands, stamp_ns=cands.stamp_ns + k * 15_000_000)
        rig.put("perception/candidates", later)
        return rig.verifications()[-1]

    def tracker_says(k):
        stamp = cands.stamp_ns + k * 15_000_000
        rig.put("tracking/people", people_at(stamp, mine, other))
        rig.put(
            "tracking/target",
            TrackState(stamp_ns=stamp, status="tracking", x_m=mine.x_m, y_m=mine.y_m),
        )

    tracker_says(0)  # before the next scan's candidates
    v = scan(1)
    assert v.image_stamp_ns == cands.stamp_ns  # the same image
    assert rig.svc.model.features["state"][0] == before  # not learnt before judging scan 1
    tracker_says(1)
    scan(2)  # scan 0's lesson is learnt first
    assert rig.svc.model.features["state"][0] == before + 1
    scan(3)  # scan 1's: the same image again, not learnt twice
    assert rig.svc.model.features["state"][0] == before + 1
    assert rig.svc.counts["learn_same_image"] == 1


def test_lockstep_learning_does_not_depend_on_which_message_comes_first(tmp_path):
    """Lock-step: the tracker's state of scan k may reach vision_verify before or after scan
    k is judged (the tracker applies vision a scan late, so it does not wait for it); either
    way the same is learnt, at the same point (reruns of a run agree)."""
    import msgspec

    from followbot.schemas import TrackState

    models = []
    for state_first in (False, True):
        rig, cands, _, (mine, other) = online_judged(tmp_path / str(state_first), lockstep=True)

        def at(k, cands=cands):
            return msgspec.structs.replace(cands, stamp_ns=cands.stamp_ns + k * 15_000_000)

        def tracker_says(k, rig=rig, cands=cands, mine=mine, other=other):
            stamp = cands.stamp_ns + k * 15_000_000
            rig.put("tracking/people", people_at(stamp, mine, other))
            rig.put(
                "tracking/target",
                TrackState(stamp_ns=stamp, status="tracking", x_m=mine.x_m, y_m=mine.y_m),
            )

        if state_first:
            tracker_says(1)
        rig.put("perception/candidates", at(1))
        if not state_first:
            tracker_says(1)
        for k in (2, 3):
            rig.put("perception/candidates", at(k))
        models.append({k: a.copy() for k, a in rig.svc.model.features.items()})
    assert models[0].keys() == models[1].keys()
    for k in models[0]:
        np.testing.assert_array_equal(models[0][k], models[1][k])
    assert models[0]["state"][0] == 2  # the acquisition's view and scan 1's
