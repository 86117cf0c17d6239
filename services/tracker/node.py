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

from followbot.services.runtime.lockstep import HeldInputs
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


def setup(node: Node, settings: TrackerNodeSettings) -> Tracker:
    try:
        tracker = Tracker(core_settings(settings))
    except UnknownPlugin as exc:
        raise ValueError(str(exc)) from None
    target_pub = node.publisher("tracking/target")
    people_pub = node.publisher("tracking/people")

    # Lock-step (docs/runtime.md rule 5): a step waits for the odometry and the verification
    # it must use, which reach this process by other links than the candidates. A new target
    # model takes effect at the step that applies the first verification judged with it (the
    # model is sent just before that verification, but on another topic: either may come
    # first), not whenever it happens to arrive.
    lag = max(settings.vision_lag_scans, 1)
    stepped: deque[int] = deque(maxlen=lag)  # stamps of the last `lag` scans stepped
    newest = {"odom": -1, "verification": -1, "model": 0}  # model_id 0: judged without one
    verified_with: deque[tuple[int, int]] = deque()  # (verification stamp, its model_id)
    held_models: list = []
    odom_wait, vision_wait = settings.lockstep_odometry_wait_s, settings.lockstep_vision_wait_s

    def due_stamp() -> int | None:
        """Stamp of the scan whose verification the next step applies (None: none yet)."""
        return stepped[0] if len(stepped) == lag else None

    def model_due(due: int | None) -> int:
        """The newest model_id named by a verification the next step applies."""
        while len(verified_with) > 1 and due is not None and verified_with[1][0] <= due:
            verified_with.popleft()  # ids only grow: the latest due one is all that counts
        if due is None or not verified_with or verified_with[0][0] > due:
            return -1
        return verified_with[0][1]

    def ready(msg) -> bool:
        if odom_wait > 0 and newest["odom"] < msg.stamp_ns:
            return False
        if vision_wait <= 0:
            return True
        due = due_stamp()
        if due is not None and newest["verification"] < due:
            return False
        return newest["model"] >= model_due(due)

    def step(msg) -> None:
        if held_models:
            wanted = model_due(due_stamp())
            while held_models and held_models[0].model_id <= wanted:
                tracker.set_target_model(held_models.pop(0))
        stepped.append(msg.stamp_ns)
        if msg.stamp_ns > clock["stamp"]:
            clock.update(stamp=msg.stamp_ns, at=time.monotonic(), frame=msg.frame_id)
        target = tracker.step_target(msg)
        if "out_of_order" in target.flags:
            clock["out_of_order"] += 1
            if clock["out_of_order"] >= OUT_OF_ORDER_STREAK:
                node.set_condition(
                    "order", "degraded", f"{clock['out_of_order']} scans in a row out of order"
                )
        elif clock["out_of_order"]:
            clock["out_of_order"] = 0
            node.clear_condition("order")
        target_pub.put(target)  # the controller's input first, then the bookkeeping
        people_pub.put(tracker.step_rest())
        notes = [f"status:{target.status}", *target.flags]
        if held is not None:
            notes += [f"lockstep_waits={held.waits}", f"lockstep_wait_timeouts={held.timeouts}"]
        node.notes = notes[:16]

    clock = {"stamp": -1, "at": time.monotonic(), "frame": "base_link", "out_of_order": 0}

    def check_stale() -> None:
        if time.monotonic() - clock["at"] <= settings.stale_after_s:
            return
        lost = tracker.lose_target_stale(clock["frame"])
        if lost is not None:
            node.log.warning(
                "no scan for %.1f s (wall clock): target declared lost", settings.stale_after_s
            )
            target_pub.put(lost)

    if settings.stale_after_s > 0:
        node.every(min(0.1, settings.stale_after_s / 2), check_stale, name="stale_target")

    def restart() -> None:
        tracker.restart_clock()
        stepped.clear()
        verified_with.clear()
        held_models.clear()
        newest.update(odom=-1, verification=-1, model=0)
        clock.update(stamp=-1, at=time.monotonic(), out_of_order=0)
        node.clear_condition("order")

    held = None
    on_candidates = step
    if odom_wait > 0 or vision_wait > 0:
        held = HeldInputs(node, step, ready, max(odom_wait, vision_wait), "candidates")
        on_candidates = held.offer

    def on_odometry(odom) -> None:
        tracker.add_odometry(odom)
        newest["odom"] = max(newest["odom"], odom.stamp_ns)
        if held is not None:
            held.release()

    def on_verification(verification) -> None:
        tracker.add_verification(verification)
        newest["verification"] = max(newest["verification"], verification.stamp_ns)
        if vision_wait > 0:
            verified_with.append((verification.stamp_ns, verification.model_id))
        if held is not None:
            held.release()

    node.subscribe("sensors/odom", on_odometry, policy="all", on_restart=tracker.restart_odometry)
    node.subscribe("perception/verification", on_verification, policy="all")
    # Keep the model and answer queries with it: the tracker lives on the robot, so a vision
    # worker that restarts (another machine, a crash) recovers the model instead of rebuilding.
    model_pub = node.publisher("perception/target_model", serve_last=True)

    def on_model(model) -> None:
        if vision_wait > 0:
            held_models.append(model)
            newest["model"] = max(newest["model"], model.model_id)
            if held is not None:
                held.release()
        else:
            tracker.set_target_model(model)
        model_pub.serve(model)

    # models (rare; loaded from files or other workers) carry stamps of their own making
    node.subscribe("perception/target_model", on_model, policy="all", judge_stamps=False)
    node.subscribe(
        "perception/candidates",
        on_candidates,
        policy="all",
        on_restart=restart,
        expect_within_s=1.0,
    )

    def on_vision_alive(alive: bool) -> None:
        if alive:
            node.clear_condition("vision")
        elif tracker.vision_alive:
            node.set_condition("vision", "degraded", f"{settings.vision_service} gone: laser alone")
        tracker.set_vision_alive(alive)

    node.watch_alive(settings.vision_service, on_vision_alive)
    node.log.info(
        "tracker: estimator=%s vision_lag_scans=%d acquire=%s",
        settings.estimator,
        settings.vision_lag_scans,
        settings.acquire,
    )
    return tracker


def main(argv: list[str] | None = None) -> int:
    return service_main("tracker", TrackerNodeSettings, setup, argv, __doc__)
