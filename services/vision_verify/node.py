"""vision_verify: say which laser candidate is the target, by appearance (thesis 3.5, 4.4).

Inputs: sensors/image (latest only), perception/candidates, perception/target_command,
perception/target_model (models of other workers), sensors/scan (used only while acquiring),
tracking/target (a verifier that learns online: which candidate the tracker followed).
Outputs: perception/verification (one per judged scan, naming the scan stamp and the candidate
positions judged), perception/target_model (also answers queries, so a restarted stage or a
second worker recovers the model).

The model's life (docs/vision_verify.md "The target model"): on start the service asks the
network for the model, and keeps asking every ``recovery.query_period_s`` while it has none, so a
restarted worker recovers the model the tracker keeps. Every model -- from the network, a
query reply or a file -- is checked (core.checked_model) before it replaces the one in use;
one that fails is refused, counted in Health.rejected and logged. With ``acquire.auto`` a
model is learnt only when nobody on the network holds one. Save and load commands name files
of one folder (``files.folder``; model.ModelFiles); a refused command is counted in
Health.rejected[perception/target_command], logged, and reported in Health.notes
(``command <action> <stamp_ns> refused: <why>``), where ``followbot target`` reads it.

Pairing: each candidates message waits (in a bounded buffer) for the image nearest its scan
stamp within ``pair_tolerance_s``; the two newest decoded images are kept. Work that can no
longer be paired, or that lags the newest scan by more than ``max_lag_s``, is dropped and
counted rather than queued, so latency stays bounded however slow the verifier is. With
``answer_every_scan`` (lock-step runs, docs/runtime.md rule 2) every scan gets exactly one
verification: an empty one (``chosen = -1``) when there is no model or no image for it.

Bad input (image of the wrong size for its camera, unknown camera, corrupt JPEG, candidates
behind the camera or with empty or huge rectangles) is skipped and counted (Health.rejected
for images, Health.notes for the rest), never fatal.

    followbot run vision_verify --set verifier=meanshift --set threshold=0.7
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Iterable

import cv2
import numpy as np

from followbot.schemas import (
    Image,
    LaserScan,
    People,
    PersonCandidates,
    TargetCommand,
    TargetModel,
    TrackState,
    Verification,
    VerifiedCandidate,
)
from followbot.services.runtime.mount import candidates_in_base
from followbot.services.runtime.node import Node
from followbot.services.runtime.plugins import PluginSettingsError
from followbot.services.runtime.service import service_main
from followbot.services.runtime.stats import RateLimitedLog

from .core import (
    Camera,
    ImageFeatures,
    InvalidModel,
    Judgement,
    Model,
    View,
    checked_model,
    confident,
    judge,
)
from .model import (
    ModelBuilder,
    ModelFileError,
    ModelFiles,
    build_model,
    default_models_dir,
)
from .settings import VisionVerifySettings
from .verifiers import make_verifier

__all__ = ["VisionVerify", "VisionVerifySettings", "main", "setup"]

_NS = 1_000_000_000


class CommandRefused(ValueError):
    """A target command that cannot be carried out; ``kind`` names why (for counting)."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


class _Frame:
    __slots__ = ("camera", "features", "pan_rad", "stamp_ns")

    def __init__(self, stamp_ns: int, features: ImageFeatures, pan_rad: float, camera: Camera):
        self.stamp_ns, self.features, self.pan_rad, self.camera = (
            stamp_ns,
            features,
            pan_rad,
            camera,
        )


class VisionVerify:
    """The service's state and handlers (all run in the node's loop, never concurrently)."""

    def __init__(self, node: Node, settings: VisionVerifySettings) -> None:
        self.node, self.s = node, settings
        self.verifier = build_verifier(settings)
        if not settings.cameras:
            raise ValueError("cameras: at least one camera is needed")
        self.threshold = None
        if settings.reject:
            self.threshold = (
                settings.threshold
                if settings.threshold is not None
                else getattr(self.verifier, "default_threshold", None)
            )
        self.files = ModelFiles(
            settings.files.folder or default_models_dir(), settings.files.max_bytes
        )
        if settings.files.default_name:
            try:
                self.files.check_name(settings.files.default_name)
            except ModelFileError as exc:  # a settings error: exit 2
                raise ValueError(f"files.default_name: {exc}") from None
        self._log = RateLimitedLog(node.log)
        self._init_state()
        self._connect()
        node.set_condition("model", "degraded", "no target model")
        if settings.acquire.auto:
            self.start_acquire(auto=True)

    def _init_state(self) -> None:
        """The model, what waits to be judged, and what the acquisition has seen."""
        self.model: Model | None = None
        self.model_id = 0  # the largest id installed or built here
        # Recovery (see the module docstring): ask while there is no model; an auto-learnt
        # model waits (held_build) until a conclusive query found nobody holding one.
        self.asking = self.s.recovery.query_on_start
        self.nobody_holds = not self.s.recovery.query_on_start
        self.held_build: Model | None = None
        self._holder_seen = threading.Event()
        self._recover_deadline = time.monotonic() + self.s.recovery.holder_wait_s
        self._query_thread: threading.Thread | None = None
        self.last_command = ""
        self.frames: list[_Frame] = []  # the two newest decoded images, oldest first
        self.period_ns = 0  # camera period estimate
        self.min_period_ns = 0  # shortest gap between two images (lock-step: when one is due)
        self.pending: OrderedDict[int, tuple[PersonCandidates, float]] = OrderedDict()
        self.last_judged_ns = -1
        self.counts: dict[str, int] = {}
        self.builder: ModelBuilder | None = None
        self.builder_auto = False  # the builder runs for acquire.auto, not for a command
        self.acquire_deadline = 0.0
        self.scans: OrderedDict[int, np.ndarray] = OrderedDict()  # acquisition only
        # lock-step acquisition: images wait here so the builder sees every input in stamp order
        self.acq_images: list[tuple[int, np.ndarray, float]] = []
        self.acq_cands: OrderedDict[int, PersonCandidates] = OrderedDict()
        # learn.source tracker: judged scans (stamp -> frame, views, model id) awaiting the
        # tracker's state of the same stamp
        self.judged: OrderedDict[int, tuple[ImageFeatures, list[View], list[float | None], int]] = (
            OrderedDict()
        )
        self.learns = getattr(self.verifier, "update", None) is not None
        # learn.bystanders people: the tracker's people by stamp, and target states waiting
        # for the people of their stamp (the tracker publishes both per scan, in either order)
        self.people: OrderedDict[int, People] = OrderedDict()
        self.waiting: OrderedDict[int, TrackState] = OrderedDict()
        # lock-step: the tracker's states of scans not judged yet
        self.early: OrderedDict[int, TrackState] = OrderedDict()
        self._learnt_frame: ImageFeatures | None = None  # the image last learnt from
        # lock-step: (scan stamp, model id, frame, views, target) waiting to be learnt
        self._learn_due: list[tuple[int, int, ImageFeatures, list[View], int]] = []

    def _connect(self) -> None:
        """Publishers, subscriptions, timers and the model holder's liveliness."""
        node, settings = self.node, self.s
        self.pub_verification = node.publisher("perception/verification")
        self.pub_model = node.publisher("perception/target_model", reliable=True, serve_last=True)
        # lock-step: every image (none dropped by a busy loop), so reruns see the same frames
        self.in_image = node.subscribe(
            "sensors/image",
            self.on_image,
            policy="all" if settings.answer_every_scan else "latest",
            capacity=8,
            on_restart=self.restart_images,
        )
        self.in_candidates = node.subscribe(
            "perception/candidates",
            self.on_candidates,
            capacity=256,
            dispatch="loop",
            on_restart=self.restart_candidates,
        )
        # commands and models carry stamps of their makers' clocks (an operator's wall clock,
        # a file's): they are not judged against the sensors' stream
        self.in_command = node.subscribe(
            "perception/target_command",
            self.on_command,
            capacity=16,
            dispatch="loop",
            judge_stamps=False,
        )
        self.in_model = node.subscribe(
            "perception/target_model",
            self.on_model,
            capacity=8,
            dispatch="loop",
            judge_stamps=False,
        )
        node.subscribe(
            "sensors/scan", self.on_scan, capacity=16, dispatch="loop", on_restart=self.scans.clear
        )
        if self.learns and settings.learn.source == "tracker":
            node.subscribe(
                "tracking/target",
                self.on_target,
                capacity=16,
                dispatch="loop",
                on_restart=self._forget_judged,
            )
            if settings.learn.bystanders == "people":
                node.subscribe(
                    "tracking/people",
                    self.on_people,
                    capacity=16,
                    dispatch="loop",
                    on_restart=self.people.clear,
                )
        node.every(0.02, self.on_timer, name="vision_timer")
        node.every(settings.health_period_s, self.update_notes, name="notes")
        node.every(settings.recovery.query_period_s, self.ask, name="ask_model")
        if settings.recovery.holder:
            node.bus.watch_liveliness(node.keys.alive(settings.recovery.holder), self._on_holder)

    def _forget_judged(self) -> None:
        """The tracker restarted: the judged scans and early states wait for nothing more."""
        self.judged.clear()
        self.early.clear()

    # ------------------------------------------------------------------ helpers

    def count(self, what: str, n: int = 1) -> None:
        self.counts[what] = self.counts.get(what, 0) + n

    def update_notes(self) -> None:
        model = f"model {self.model.model_id} ({self.model.verifier})" if self.model else "no model"
        acquiring = " acquiring" if self.builder is not None else ""
        asking = " asking the network" if self.asking and self.model is None else ""
        counts = " ".join(f"{k}={v}" for k, v in sorted(self.counts.items()))
        notes = [f"{model}{acquiring}{asking}", f"counts: {counts}"[:200]]
        if self.last_command:
            notes.append(self.last_command)
        self.node.notes = notes

    def camera_for(self, image_width: int, image_height: int) -> Camera:
        for cam in self.s.cameras.values():
            if (cam.width, cam.height) == (image_width, image_height):
                return cam
        return next(iter(self.s.cameras.values()))

    def restart_images(self) -> None:
        """The camera's source restarted with a new clock: its old frames go."""
        self.frames = []
        self.period_ns = self.min_period_ns = 0
        self.acq_images = []

    def restart_candidates(self) -> None:
        """The scans' source restarted with a new clock: what waited on the old clock goes."""
        self.pending.clear()
        self.last_judged_ns = -1
        self.scans.clear()
        self.acq_cands.clear()

    # ------------------------------------------------------------------ images

    def on_image(self, img: Image) -> None:
        cam = self.s.cameras.get(img.intrinsics_id)
        if cam is None:
            return self._bad_image("unknown_camera")
        if (img.width, img.height) != (cam.width, cam.height):
            return self._bad_image("wrong_size")
        try:
            px = img.pixels()
        except ValueError:
            return self._bad_image("corrupt_jpeg")
        if px.ndim == 2:
            px = cv2.cvtColor(px, cv2.COLOR_GRAY2BGR)
        if self.frames:
            dt = img.stamp_ns - self.frames[-1].stamp_ns
            if dt <= 0:
                return self._bad_image("out_of_order")
            self.period_ns = dt if self.period_ns == 0 else round(0.8 * self.period_ns + 0.2 * dt)
            self.min_period_ns = dt if self.min_period_ns == 0 else min(self.min_period_ns, dt)
        self.frames = [*self.frames[-1:], _Frame(img.stamp_ns, ImageFeatures(px), img.pan_rad, cam)]
        if self.builder is not None:
            if self.s.answer_every_scan:
                self.acq_images = [
                    *self.acq_images[-15:],
                    (img.stamp_ns, np.array(px), img.pan_rad),
                ]
                self._feed_builder()
            else:
                self._acquired(self.builder.add_image(img.stamp_ns, np.array(px), img.pan_rad))
        self.work()

    def _bad_image(self, why: str) -> None:
        self.node.reject(self.in_image, why)  # shows in Health.rejected[sensors/image]
        self.count(f"image_{why}")

    # ------------------------------------------------------------------ candidates, pairing

    def on_candidates(self, msg: PersonCandidates) -> None:
        # the laser frame of the scan -> the base frame, where the cameras' mounts are given
        # and where the tracker reads the verification's positions
        msg = candidates_in_base(msg, self.s.laser_mount)
        had_model = self.model is not None
        if self.builder is not None:
            self.acq_cands[msg.stamp_ns] = msg
            self._feed_builder()
        if self.s.answer_every_scan and not had_model:
            # lock-step: a model built while this scan was fed to the builder judges from the
            # next scan on, whether image or candidates came last (reruns must agree)
            self.count("scan_no_model")
            self.publish_empty(msg, model_id=0)  # not the model this scan may have built
            return
        if msg.stamp_ns <= self.last_judged_ns or msg.stamp_ns in self.pending:
            self.count("scan_duplicate_or_old")
            if self.s.answer_every_scan and msg.stamp_ns not in self.pending:
                self.publish_empty(msg)
            return
        if self.model is None:
            self.count("scan_no_model")
            if self.s.answer_every_scan:
                self.publish_empty(msg)
            return
        self.pending[msg.stamp_ns] = (msg, time.monotonic())
        self.work()

    def _nearest_frame(self, stamp_ns: int) -> _Frame | None:
        best = min(self.frames, key=lambda f: abs(f.stamp_ns - stamp_ns), default=None)
        if best is None or abs(best.stamp_ns - stamp_ns) > self.s.pair_tolerance_s * _NS:
            return None
        return best

    def work(self) -> None:
        """Judge the pending scans that have their image; drop those that never will."""
        if not self.pending:
            return
        newest = next(reversed(self.pending))
        latest_img = self.frames[-1].stamp_ns if self.frames else None
        for stamp in list(self.pending):
            msg, _ = self.pending[stamp]
            if newest - stamp > self.s.max_lag_s * _NS or len(self.pending) > self.s.scan_buffer:
                self._drop(stamp, "scan_stale")
                continue
            if latest_img is None:
                continue
            if (
                self.s.answer_every_scan
                and self.min_period_ns
                and latest_img + self.min_period_ns <= stamp
            ):
                # Lock-step: an image due at or before this scan may still be on its way (it
                # comes straight from the source, the candidates through laser_legs, and the
                # two arrive in either order); judging now would pair another image than a
                # rerun might. Wait for it (bounded by image_wait_s, then dropped).
                continue
            if (
                stamp > latest_img
                and not (0 < stamp - latest_img <= self.period_ns / 2)
                and not self.s.answer_every_scan
            ):
                # Live: the next image may be nearer, wait for it. In lock-step the source has
                # sent every image due at or before the scan (docs/runtime.md, rule 1): no
                # nearer one can come before we answer, so judge with what we have.
                continue
            frame = self._nearest_frame(stamp)
            if frame is None:
                self._drop(stamp, "scan_no_image")
                continue
            del self.pending[stamp]
            self.judge(msg, frame)

    def _drop(self, stamp: int, why: str) -> None:
        msg, _ = self.pending.pop(stamp)
        self.count(why)
        if self.s.answer_every_scan:
            self.publish_empty(msg)

    def on_timer(self) -> None:
        now = time.monotonic()
        if self.pending and self.s.answer_every_scan:
            for stamp in list(self.pending):
                if now - self.pending[stamp][1] > self.s.image_wait_s:
                    self._drop(stamp, "scan_no_image")
        if self.builder is not None and now > self.acquire_deadline:
            self.node.log.warning(
                "no target model after %.0f s of trying", self.s.acquire.timeout_s
            )
            self.count("acquire_timeout")
            self.builder = None

    # ------------------------------------------------------------------ judging

    def judge(self, msg: PersonCandidates, frame: _Frame) -> None:
        self._learn_due_now()
        model = self.model
        xy = np.array([[c.x_m, c.y_m] for c in msg.candidates], dtype=np.float64).reshape(-1, 2)
        try:
            j = judge(
                self.verifier,
                frame.features,
                frame.camera,
                model,
                xy,
                frame.pan_rad,
                self.threshold,
                min_visible_fraction=self.s.occlusion.min_visible_fraction,
                horizon=msg.horizon,
                horizon_margin_m=self.s.occlusion.laser_margin_m,
                horizon_half_width_m=self.s.occlusion.laser_half_width_m,
                abstain_fraction=self.s.occlusion.laser_abstain_fraction,
                min_side_px=self.s.min_rect_side_px,
                max_width_factor=self.s.max_rect_width_factor,
            )
        except ValueError as exc:
            # a model this verifier cannot use (e.g. saved by an older version): drop it once,
            # loudly, rather than fail on every scan
            self.node.log.warning("dropping target model %d: %s", model.model_id, exc)
            self.count("model_incompatible")
            self._set_model(None)
            if self.s.answer_every_scan:
                self.publish_empty(msg)
            return
        out = []
        calibrated = getattr(self.verifier, "calibrated", False)  # distance = 1 - probability
        for v, d in zip(j.views, j.distances, strict=True):
            if v.status not in ("ok", "out_of_view"):
                self.count(f"candidate_{v.status}")
            out.append(
                VerifiedCandidate(
                    index=v.index,
                    x_m=v.x_m,
                    y_m=v.y_m,
                    in_view=d is not None,
                    distance=d,
                    probability=None if d is None or not calibrated else max(0.0, 1.0 - d),
                )
            )
        self.last_judged_ns = max(self.last_judged_ns, msg.stamp_ns)
        self.count("verified")
        self.pub_verification.put(
            Verification(
                stamp_ns=msg.stamp_ns,
                frame_id=msg.frame_id,
                image_stamp_ns=frame.stamp_ns,
                model_id=model.model_id,
                verifier=self.verifier.name,
                candidates=out,
                chosen=j.chosen,
                threshold=self.threshold,
            )
        )
        if self.learns:
            self._learn_from_judged(msg.stamp_ns, frame.features, j, model.model_id)

    def _learn_from_judged(
        self, stamp_ns: int, frame: ImageFeatures, j: Judgement, model_id: int
    ) -> None:
        """An online verifier after a judged scan: keep the scan until the tracker's state of
        its stamp names the target (``learn.source: tracker``), or learn the verifier's own
        choice now when it is confident (``confident``)."""
        learn = self.s.learn
        if learn.source == "tracker":
            self.judged[stamp_ns] = (frame, j.views, j.distances, model_id)
            while len(self.judged) > learn.scans:
                self.judged.popitem(last=False)
            early = self.early.pop(stamp_ns, None)
            if early is not None:  # lock-step: the tracker's state came before this judgement
                self.on_target(early)
        elif learn.source == "confident" and confident(
            j.distances, j.chosen, learn.confident_max_distance, learn.confident_margin
        ):
            self.learn(frame, j.views, j.chosen)

    def learn(
        self, frame: ImageFeatures, views: list[View], target: int, stamp_ns: int | None = None
    ) -> None:
        """Let an online verifier learn ``views[target]`` as the target, the others as
        bystanders; once per image (a laser faster than the camera has several scans judged
        on one image: the same views again would crowd the reservoirs with copies).

        Lock-step (``answer_every_scan``), what the tracker's state of scan ``stamp_ns`` taught
        is learnt just before judging the second scan after it, never the next one: that
        state and the next scan's candidates come from two processes in either order, and a
        model learnt before or after judging that scan would make reruns differ."""
        if self.s.answer_every_scan and stamp_ns is not None:
            model_id = self.model.model_id if self.model is not None else 0
            self._learn_due.append((stamp_ns, model_id, frame, views, target))
            del self._learn_due[: -self.s.learn.scans]  # bounded: no scans judged, no learning
            return
        self._learn_now(frame, views, target)

    def _learn_due_now(self) -> None:
        """Lock-step: the learning of scans before the last one judged (see :meth:`learn`)."""
        due = [d for d in self._learn_due if d[0] < self.last_judged_ns]
        if not due:
            return
        self._learn_due = [d for d in self._learn_due if d[0] >= self.last_judged_ns]
        for _, model_id, frame, views, target in sorted(due, key=lambda d: d[0]):
            if self.model is not None and self.model.model_id == model_id:
                self._learn_now(frame, views, target)

    def _learn_now(self, frame: ImageFeatures, views: list[View], target: int) -> None:
        if frame is self._learnt_frame:
            self.count("learn_same_image")
            return
        self._learnt_frame = frame
        learnt = self.verifier.update(frame, views, target, self.model)
        if learnt is None:
            self.count("learn_no_view")
            return
        # Not republished: a target model on the network makes the tracker take the target
        # where the model was learnt. A restarted worker starts again from the model as
        # first learnt; a save command saves what was learnt since.
        self.model.features = learnt
        self.count("learnt")

    def on_people(self, people: People) -> None:
        """The tracker's people at a scan (``learn.bystanders: people``)."""
        self.people[people.stamp_ns] = people
        while len(self.people) > self.s.learn.scans:
            self.people.popitem(last=False)
        state = self.waiting.pop(people.stamp_ns, None)
        if state is not None:
            self.on_target(state)

    def on_target(self, state: TrackState) -> None:
        """The tracker's target at a judged scan: learn which candidate it was. Lock-step, a
        state that comes before its scan is judged (the tracker applies vision a scan late,
        so it does not wait for this scan's judgement) waits for it: learnt or not depending
        on which came first, reruns would differ."""
        if (
            self.s.answer_every_scan
            and state.stamp_ns > self.last_judged_ns
            and state.stamp_ns not in self.judged
        ):
            self.early[state.stamp_ns] = state
            while len(self.early) > self.s.learn.scans:
                self.early.popitem(last=False)
            return
        people = None
        if self.s.learn.bystanders == "people":
            people = self.people.get(state.stamp_ns)
            if people is None:  # its people come next
                if state.stamp_ns in self.judged:
                    self.waiting[state.stamp_ns] = state
                    while len(self.waiting) > self.s.learn.scans:
                        self.waiting.popitem(last=False)
                return
        judged = self.judged.pop(state.stamp_ns, None)
        if judged is None or self.model is None or state.status != "tracking":
            return
        frame, views, distances, model_id = judged
        if model_id != self.model.model_id:
            return  # judged with a model since replaced
        # both in the base frame: candidates are turned into it as they arrive
        x, y = state.x_m - state.shift_x_m, state.y_m - state.shift_y_m
        near = [
            i
            for i, v in enumerate(views)
            if math.hypot(v.x_m - x, v.y_m - y) <= self.s.learn.gate_m
        ]
        if len(near) != 1:
            self.count("learn_ambiguous" if near else "learn_target_not_candidate")
            return
        if not views[near[0]].ok:
            self.count("learn_target_not_in_view")
            return
        most = self.s.learn.agree_max_distance
        d = distances[near[0]]
        if most is not None and not (d is not None and d <= most):
            self.count("learn_not_agreed")  # the tracker may follow someone else: not learnt
            return
        if people is None:
            self.learn(frame, views, near[0], state.stamp_ns)
            return
        # bystanders: only candidates on the tracker's other people (not clutter)
        others = [
            (t.x_m, t.y_m) for t in people.tracks if t.id != people.target_id and t.misses == 0
        ]
        gate = self.s.learn.gate_m
        keep = [
            i
            for i, v in enumerate(views)
            if i == near[0] or any(math.hypot(v.x_m - x, v.y_m - y) <= gate for x, y in others)
        ]
        self.learn(frame, [views[i] for i in keep], keep.index(near[0]), state.stamp_ns)

    def publish_empty(self, msg: PersonCandidates, model_id: int | None = None) -> None:
        """An answer that judged nothing; ``model_id`` defaults to the current model's."""
        if model_id is None:
            model_id = self.model.model_id if self.model else 0
        self.last_judged_ns = max(self.last_judged_ns, msg.stamp_ns)
        self.pub_verification.put(
            Verification(
                stamp_ns=msg.stamp_ns,
                frame_id=msg.frame_id,
                image_stamp_ns=0,
                model_id=model_id,
                verifier=self.verifier.name,
                chosen=-1,
                threshold=self.threshold,
            )
        )

    # ------------------------------------------------------------------ model

    def _set_model(self, model: Model | None) -> None:
        """The one place the model in use changes (Health says when there is none)."""
        self.model = model
        if model is None:
            self.node.set_condition("model", "degraded", "no target model")
            return
        self.model_id = max(self.model_id, model.model_id)
        self.node.clear_condition("model")
        self.asking = False
        if self.held_build is not None and self.held_build is not model:
            self.node.log.info(
                "dropping the model learnt meanwhile: model %d is in use", model.model_id
            )
            self.count("acquired_dropped")
        self.held_build = None
        if self.builder is not None and self.builder_auto:
            self.node.log.info("auto-acquisition stopped: model %d is in use", model.model_id)
            self.builder = None

    def check(self, message: TargetModel) -> Model:
        """``message`` as a model this service can use; InvalidModel otherwise."""
        return checked_model(
            message, self.verifier, self.s.cameras.values(), max_bytes=self.s.files.max_bytes
        )

    def install(self, message: TargetModel, *, publish: bool, source: str) -> bool:
        """Use the model of ``message`` from the network (``source``) if it passes the
        checks; a refused one is counted in Health.rejected[perception/target_model]."""
        try:
            model = self.check(message)
        except InvalidModel as exc:
            self.count(f"model_{exc.kind}")
            self.node.reject(self.in_model, f"model {exc.kind}")
            self._log.log(
                logging.WARNING,
                f"model:{exc.kind}",
                "refused a target model from %s (%s): %s",
                source,
                f"model {self.model.model_id} stays in use" if self.model else "still none",
                exc,
            )
            return False
        self._use(model, publish=publish, source=source, message=message)
        return True

    def _use(
        self, model: Model, *, publish: bool, source: str, message: TargetModel | None = None
    ) -> None:
        self._set_model(model)
        self.node.log.info("target model %d from %s", model.model_id, source)
        if publish:
            self.pub_model.put(model.to_message())
        else:  # serve it too, so it survives the worker that built it
            self.pub_model.serve(message if message is not None else model.to_message())

    def on_model(self, message: TargetModel) -> None:
        if self.model is None or message.model_id > self.model_id:
            self.install(message, publish=False, source="network")

    # ------------------------------------------------------------------ recovery

    def _on_holder(self, _key: str, alive: bool) -> None:
        """Zenoh's thread: the model holder's liveliness changed."""
        if alive:
            self._holder_seen.set()
            self.node.call_soon(self.ask)  # it may hold the model: ask now, not next period

    def _conclusive(self) -> bool:
        """Whether a query sent now and answered by nobody means nobody holds a model."""
        return (
            not self.s.recovery.holder
            or self._holder_seen.is_set()
            or time.monotonic() >= self._recover_deadline
        )

    def recover(self) -> None:
        """Setup, before the service says it is alive: ask once; with acquire.auto, go on
        asking until a model is recovered or nobody holds one (at most recovery.holder_wait_s plus a
        query), so a lock-step source, which waits for every stage, starts only then."""
        while self.asking and not self.nobody_holds:
            conclusive = self._conclusive()
            self._answered(
                self.node.query("perception/target_model", self.s.recovery.query_timeout_s),
                conclusive,
            )
            if not self.s.acquire.auto or self.node.stopping:
                return
            if not self.nobody_holds and self.model is None:
                left = self._recover_deadline - time.monotonic()
                self._holder_seen.wait(min(self.s.recovery.query_period_s, max(left, 0.0)))

    def ask(self) -> None:
        """Ask the network for the model, in a thread of its own (a query may wait up to
        recovery.query_timeout_s); the answers come back to the loop."""
        if not self.asking or self.model is not None:
            return
        if self._query_thread is not None and self._query_thread.is_alive():
            return
        conclusive = self._conclusive()
        node, timeout = self.node, self.s.recovery.query_timeout_s

        def run() -> None:
            try:
                replies = node.query("perception/target_model", timeout)
            except Exception as exc:  # the session closing under it: ask again next period
                node.log.debug("model query failed: %s", exc)
                return
            node.call_soon(lambda: self._answered(replies, conclusive))

        self._query_thread = threading.Thread(target=run, name="vision_model_query", daemon=True)
        self._query_thread.start()

    def _answered(self, replies: Iterable[TargetModel], conclusive: bool) -> None:
        """A query's answers: the newest model that passes the checks is used; none, from a
        conclusive query, lets an auto-learnt model in."""
        if not self.asking or self.model is not None:
            return
        for message in sorted(replies, key=lambda m: m.model_id, reverse=True):
            if self.install(message, publish=False, source="query"):
                return
        if conclusive and not self.nobody_holds:
            self.nobody_holds = True
            if self.s.acquire.auto:
                self.node.log.info("nobody on the network holds a target model: learning one")
            if self.held_build is not None:
                self._use_built(self.held_build)

    # ------------------------------------------------------------------ commands

    def on_command(self, cmd: TargetCommand) -> None:
        name = cmd.path or self.s.files.default_name
        try:
            done = self._command(cmd, name)
        except (ModelFileError, InvalidModel, CommandRefused) as exc:
            self.count(f"command_{exc.kind}")
            self.node.reject(self.in_command, f"{cmd.action} refused: {exc.kind}")
            self._log.log(
                logging.WARNING,
                f"command:{cmd.action}:{exc.kind}",
                "command %s %r refused: %s",
                cmd.action,
                name,
                exc,
            )
            self._report(cmd, f"refused: {exc}")
        else:
            self._report(cmd, f"done: {done}")

    def _report(self, cmd: TargetCommand, outcome: str) -> None:
        """The last command's outcome, in Health.notes for the operator (followbot target)."""
        self.last_command = f"command {cmd.action} {cmd.stamp_ns} {outcome}"[:256]
        self.update_notes()

    def _command(self, cmd: TargetCommand, name: str) -> str:
        if cmd.action == "acquire":
            self.start_acquire()
            return "acquiring: the target should move alone in front of the still robot"
        if cmd.action == "reset":
            self._set_model(None)
            self.builder, self.held_build, self.asking = None, None, False
            self.pub_model.serve(None)  # stop serving the dropped model
            self.pending.clear()
            self.node.log.info("target model dropped")
            return "target model dropped"
        if not name:
            raise CommandRefused(
                "no_name", f"{cmd.action}: no path in the command and no files.default_name setting"
            )
        self.files.check_name(name)  # a bad name is named as such, whatever else is wrong
        if cmd.action == "save":
            if self.model is None:
                raise CommandRefused("no_model", "save: there is no target model")
            path = self.files.save(name, self.model.to_message())
            self.node.log.info("target model %d saved to %s", self.model.model_id, path)
            return f"model {self.model.model_id} saved to {path}"
        message = self.files.load(name)  # load
        message.model_id = max(self.model_id, message.model_id) + 1
        model = self.check(message)
        self._use(model, publish=True, source=f"file {self.files.folder / name}")
        return f"model {model.model_id} loaded from {self.files.folder / name}"

    # ------------------------------------------------------------------ acquisition

    def start_acquire(self, *, auto: bool = False) -> None:
        self.builder = ModelBuilder(self.camera_for(*self._image_size()), self.s.acquire)
        self.builder_auto = auto
        self.acquire_deadline = time.monotonic() + self.s.acquire.timeout_s
        self.scans.clear()
        self.acq_cands.clear()
        self.acq_images.clear()
        self.node.log.info("acquiring a target model: the target should move alone")

    def _image_size(self) -> tuple[int, int]:
        if self.frames:
            f = self.frames[-1].features
            return f.width, f.height
        cam = next(iter(self.s.cameras.values()))
        return cam.width, cam.height

    def on_scan(self, scan: LaserScan) -> None:
        if self.builder is None:
            return
        self.scans[scan.stamp_ns] = np.array(scan.ranges_m(), dtype=np.float64)
        while len(self.scans) > 16:
            self.scans.popitem(last=False)
        self._feed_builder()

    def _feed_builder(self) -> None:
        while len(self.acq_cands) > 16:
            self.acq_cands.popitem(last=False)
        for stamp in sorted(set(self.scans) & set(self.acq_cands)):
            if self.s.answer_every_scan:
                # lock-step: the images up to this scan first, in order; if one that is due
                # has not come yet, wait for it (on_image calls back here)
                latest = self.frames[-1].stamp_ns if self.frames else None
                if latest is None or (self.min_period_ns and latest + self.min_period_ns <= stamp):
                    return
                while self.acq_images and self.acq_images[0][0] <= stamp:
                    t, px, pan = self.acq_images.pop(0)
                    if self.builder is not None:
                        self._acquired(self.builder.add_image(t, px, pan))
            ranges = self.scans.pop(stamp)
            cands = self.acq_cands.pop(stamp)
            if self.builder is not None:
                self._acquired(self.builder.add_scan(stamp, ranges, cands))

    def _acquired(self, acq) -> None:
        if acq is None or self.builder is None:
            return
        auto, self.builder = self.builder_auto, None
        model = build_model(self.verifier, self.builder_camera(acq), acq, self.model_id + 1)
        if auto and not self.nobody_holds:
            # someone may still hold the model: this one waits for a query to say nobody does
            self.held_build = model
            self.node.log.info("target model learnt; used once the network says nobody holds one")
            return
        self._use_built(model)

    def _use_built(self, model: Model) -> None:
        self._set_model(model)
        self.pending.clear()
        self.pub_model.put(model.to_message())
        self.node.log.info(
            "target model %d built: %.2f, %.2f m, rectangle %dx%d px",
            model.model_id,
            model.x_m,
            model.y_m,
            model.rect_w_px,
            model.rect_h_px,
        )

    def builder_camera(self, acq) -> Camera:
        return self.camera_for(acq.bgr.shape[1], acq.bgr.shape[0])


def setup(node: Node, settings: VisionVerifySettings) -> VisionVerify:
    svc = VisionVerify(node, settings)
    svc.recover()
    return svc


def check(settings: VisionVerifySettings) -> None:
    """The verifier is built as the service will build it (a face verifier loads its cascade
    file), so `followbot up --check` reports a missing or bad file before anything starts."""
    build_verifier(settings)


def build_verifier(settings: VisionVerifySettings):
    """The configured verifier; a bad setting is a ValueError naming ``verifier_settings``."""
    try:
        return make_verifier(settings.verifier, settings.verifier_settings)
    except PluginSettingsError as exc:
        raise ValueError(f"verifier_settings: {exc}") from None


def main(argv: list[str] | None = None) -> int:
    return service_main("vision_verify", VisionVerifySettings, setup, argv, __doc__, check)
