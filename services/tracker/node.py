"""tracker: people and the target at laser rate, from candidates, odometry and (late) vision.

Subscribes perception/candidates (every message, inline: one step each), sensors/odom (every
message), perception/verification and perception/target_model; watches vision_verify's
liveliness. Publishes, once per candidates message and naming its scan stamp,
tracking/target (TrackState) and tracking/people (People) -- also when nobody is tracked, so a
lock-step source always gets its answer (docs/runtime.md, rules 2 and 4).

    followbot run tracker --set estimator=ukf --set vision_lag_scans=3
"""

from __future__ import annotations

import time
from collections import deque
from typing import Annotated

import msgspec

from followbot.schemas import Odometry, PersonCandidates, TargetModel, TrackState, Verification
from followbot.services.runtime.lockstep import HeldInputs
from followbot.services.runtime.mount import BASE_FRAME
from followbot.services.runtime.node import Node
from followbot.services.runtime.plugins import UnknownPlugin
from followbot.services.runtime.service import service_main
from followbot.services.runtime.settings import with_node_settings

from .core import Tracker, TrackerSettings

__all__ = ["TrackerNodeSettings", "main", "setup"]

#: Scans in a row answered ``out_of_order`` before Health says so.
OUT_OF_ORDER_STREAK = 10


_TrackerNodeBase = with_node_settings(TrackerSettings, "_TrackerNodeBase", __name__)


class TrackerNodeSettings(_TrackerNodeBase, kw_only=True, forbid_unknown_fields=True):
    def __post_init__(self) -> None:
        super().__post_init__()
        core_settings(self)  # TrackerSettings' checks (the estimator) while the settings load

    vision_service: str = "vision_verify"
    """Whose liveliness says vision is there (else the status carries no_vision)."""
    lockstep_odometry_wait_s: Annotated[float, msgspec.Meta(ge=0, le=60)] = 0.0
    """Lock-step runs: hold the candidates of scan k until odometry stamped at or after k has
    arrived (it comes from the source, the candidates through laser_legs: either may come
    first), at most this long. 0 (live, or no odometry): never wait."""
    stale_after_s: Annotated[float, msgspec.Meta(ge=0, le=60)] = 1.0
    """A target that no scan has moved the tracker's clock past for this long (wall clock:
    scans stopped, or their stamps stand still) is declared lost and published so, and the
    controller stops. 0: never (lock-step runs, whose source sets the pace)."""
    lockstep_vision_wait_s: Annotated[float, msgspec.Meta(ge=0, le=60)] = 0.0
    """Lock-step runs with vision: hold the candidates of scan k until the verification due at
    k (of the scan max(vision_lag_scans, 1) steps earlier) has arrived, at most this long.
    0 (live, or no vision): never wait."""


def core_settings(settings: msgspec.Struct) -> TrackerSettings:
    names = TrackerSettings.__struct_fields__
    return TrackerSettings(**{n: getattr(settings, n) for n in names})


class _Lockstep:
    """Lock-step (docs/runtime.md rule 5): a step waits for the odometry and the verification
    it must use, which reach this process by other links than the candidates. A new target
    model takes effect at the step that applies the first verification judged with it (the
    model is sent just before that verification, but on another topic: either may come
    first), not whenever it happens to arrive."""

    def __init__(self, settings: TrackerNodeSettings) -> None:
        self.lag = max(settings.vision_lag_scans, 1)
        self.odom_wait = settings.lockstep_odometry_wait_s
        self.vision_wait = settings.lockstep_vision_wait_s
        self.stepped: deque[int] = deque(maxlen=self.lag)  # stamps of the last `lag` scans
        self.newest = {"odom": -1, "verification": -1, "model": 0}  # model 0: judged without
        self.verified_with: deque[tuple[int, int]] = deque()  # (verification stamp, model_id)
        self.held_models: list[TargetModel] = []

    def clear(self) -> None:
        self.stepped.clear()
        self.verified_with.clear()
        self.held_models.clear()
        self.newest.update(odom=-1, verification=-1, model=0)

    def due_stamp(self) -> int | None:
        """Stamp of the scan whose verification the next step applies (None: none yet)."""
        return self.stepped[0] if len(self.stepped) == self.lag else None

    def model_due(self, due: int | None) -> int:
        """The newest model_id named by a verification the next step applies."""
        verified_with = self.verified_with
        while len(verified_with) > 1 and due is not None and verified_with[1][0] <= due:
            verified_with.popleft()  # ids only grow: the latest due one is all that counts
        if due is None or not verified_with or verified_with[0][0] > due:
            return -1
        return verified_with[0][1]

    def ready(self, msg: PersonCandidates) -> bool:
        if self.odom_wait > 0 and self.newest["odom"] < msg.stamp_ns:
            return False
        if self.vision_wait <= 0:
            return True
        due = self.due_stamp()
        if due is not None and self.newest["verification"] < due:
            return False
        return self.newest["model"] >= self.model_due(due)

    def models_due(self) -> list[TargetModel]:
        """The held target models that the next step applies, oldest first."""
        out: list[TargetModel] = []
        if self.held_models:
            wanted = self.model_due(self.due_stamp())
            while self.held_models and self.held_models[0].model_id <= wanted:
                out.append(self.held_models.pop(0))
        return out


class _TrackerNode:
    """The tracker's inputs and outputs on the bus around one :class:`Tracker`."""

    def __init__(self, node: Node, settings: TrackerNodeSettings, tracker: Tracker) -> None:
        self.node, self.settings, self.tracker = node, settings, tracker
        self.target_pub = node.publisher("tracking/target")
        self.people_pub = node.publisher("tracking/people")
        self.model_pub = None
        self.lockstep = _Lockstep(settings)
        self.held: HeldInputs | None = None
        # the newest scan stepped: its stamp, when (wall clock) and its frame
        self.clock = {"stamp": -1, "at": time.monotonic(), "frame": BASE_FRAME, "out_of_order": 0}

    def step(self, msg: PersonCandidates) -> None:
        tracker, clock = self.tracker, self.clock
        for model in self.lockstep.models_due():
            tracker.set_target_model(model)
        self.lockstep.stepped.append(msg.stamp_ns)
        if msg.stamp_ns > clock["stamp"]:
            clock.update(stamp=msg.stamp_ns, at=time.monotonic())
        target = tracker.step_target(msg)
        self._note_order(target)
        self.target_pub.put(target)  # the controller's input first, then the bookkeeping
        self.people_pub.put(tracker.step_rest())
        notes = [f"status:{target.status}", *target.flags]
        if self.held is not None:
            held = self.held
            notes += [f"lockstep_waits={held.waits}", f"lockstep_wait_timeouts={held.timeouts}"]
        self.node.notes = notes[:16]

    def _note_order(self, target: TrackState) -> None:
        clock = self.clock
        if "out_of_order" in target.flags:
            clock["out_of_order"] += 1
            if clock["out_of_order"] >= OUT_OF_ORDER_STREAK:
                self.node.set_condition(
                    "order", "degraded", f"{clock['out_of_order']} scans in a row out of order"
                )
        elif clock["out_of_order"]:
            clock["out_of_order"] = 0
            self.node.clear_condition("order")

    def check_stale(self) -> None:
        stale_after_s = self.settings.stale_after_s
        if time.monotonic() - self.clock["at"] <= stale_after_s:
            return
        lost = self.tracker.lose_target_stale(self.clock["frame"])
        if lost is not None:
            self.node.log.warning(
                "no scan for %.1f s (wall clock): target declared lost", stale_after_s
            )
            self.target_pub.put(lost)

    def restart(self) -> None:
        self.tracker.restart_clock()
        self.lockstep.clear()
        self.clock.update(stamp=-1, at=time.monotonic(), out_of_order=0)
        self.node.clear_condition("order")

    def on_odometry(self, odom: Odometry) -> None:
        self.tracker.add_odometry(odom)
        newest = self.lockstep.newest
        newest["odom"] = max(newest["odom"], odom.stamp_ns)
        if self.held is not None:
            self.held.release()

    def on_verification(self, verification: Verification) -> None:
        self.tracker.add_verification(verification)
        newest = self.lockstep.newest
        newest["verification"] = max(newest["verification"], verification.stamp_ns)
        if self.lockstep.vision_wait > 0:
            self.lockstep.verified_with.append((verification.stamp_ns, verification.model_id))
        if self.held is not None:
            self.held.release()

    def on_model(self, model: TargetModel) -> None:
        if self.lockstep.vision_wait > 0:
            self.lockstep.held_models.append(model)
            newest = self.lockstep.newest
            newest["model"] = max(newest["model"], model.model_id)
            if self.held is not None:
                self.held.release()
        else:
            self.tracker.set_target_model(model)
        self.model_pub.serve(model)

    def on_vision_alive(self, alive: bool) -> None:
        if alive:
            self.node.clear_condition("vision")
        elif self.tracker.vision_alive:
            service = self.settings.vision_service
            self.node.set_condition("vision", "degraded", f"{service} gone: laser alone")
        self.tracker.set_vision_alive(alive)


def setup(node: Node, settings: TrackerNodeSettings) -> Tracker:
    try:
        tracker = Tracker(core_settings(settings), settings.laser_mount)
    except UnknownPlugin as exc:
        raise ValueError(str(exc)) from None
    t = _TrackerNode(node, settings, tracker)
    if settings.stale_after_s > 0:
        node.every(min(0.1, settings.stale_after_s / 2), t.check_stale, name="stale_target")
    on_candidates = t.step
    wait = max(t.lockstep.odom_wait, t.lockstep.vision_wait)
    if wait > 0:
        t.held = HeldInputs(node, t.step, t.lockstep.ready, wait, "candidates")
        on_candidates = t.held.offer
    node.subscribe("sensors/odom", t.on_odometry, policy="all", on_restart=tracker.restart_odometry)
    node.subscribe("perception/verification", t.on_verification, policy="all")
    # Keep the model and answer queries with it: the tracker lives on the robot, so a vision
    # worker that restarts (another machine, a crash) recovers the model instead of rebuilding.
    t.model_pub = node.publisher("perception/target_model", serve_last=True)
    # models (rare; loaded from files or other workers) carry stamps of their own making
    node.subscribe("perception/target_model", t.on_model, policy="all", judge_stamps=False)
    node.subscribe(
        "perception/candidates",
        on_candidates,
        policy="all",
        on_restart=t.restart,
        expect_within_s=1.0,
    )
    node.watch_alive(settings.vision_service, t.on_vision_alive)
    node.log.info(
        "tracker: estimator=%s vision_lag_scans=%d acquire=%s laser mount %s",
        settings.estimator,
        settings.vision_lag_scans,
        settings.acquire,
        settings.laser_mount.describe(),
    )
    return tracker


def main(argv: list[str] | None = None) -> int:
    return service_main("tracker", TrackerNodeSettings, setup, argv, __doc__)
