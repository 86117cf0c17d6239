"""tracker: people and the target at laser rate, from candidates, odometry and (late) vision.

Subscribes perception/candidates (every message, inline: one step each), sensors/odom (every
message), perception/verification and perception/target_model; watches vision_verify's
liveliness. Publishes, once per candidates message and naming its scan stamp,
tracking/target (TrackState) and tracking/people (People) -- also when nobody is tracked, so a
lock-step source always gets its answer (docs/runtime.md, rules 2 and 4).

    followbot run tracker --set estimator=ukf --set vision_lag_scans=3
"""

from __future__ import annotations

import msgspec

from followbot.services.runtime.node import Node
from followbot.services.runtime.plugins import UnknownPlugin
from followbot.services.runtime.service import service_main
from followbot.services.runtime.settings import NodeSettings

from .core import Tracker, TrackerSettings

__all__ = ["TrackerNodeSettings", "main", "setup"]


def _with_node_settings(core: type[msgspec.Struct], name: str) -> type[NodeSettings]:
    """NodeSettings plus every field of ``core``, flat (``--set estimator=ukf``)."""
    spec = []
    for f in msgspec.structs.fields(core):
        if f.default is msgspec.NODEFAULT:
            spec.append((f.name, f.type, msgspec.field(default_factory=f.default_factory)))
        else:
            spec.append((f.name, f.type, f.default))
    return msgspec.defstruct(
        name,
        spec,
        bases=(NodeSettings,),
        kw_only=True,
        forbid_unknown_fields=True,
        module=__name__,
    )


_TrackerNodeBase = _with_node_settings(TrackerSettings, "_TrackerNodeBase")


class TrackerNodeSettings(_TrackerNodeBase, kw_only=True, forbid_unknown_fields=True):
    vision_service: str = "vision_verify"
    """Whose liveliness says vision is there (else the status carries no_vision)."""


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

    def on_candidates(msg) -> None:
        target, people = tracker.step(msg)
        target_pub.put(target)
        people_pub.put(people)
        node.notes = [f"status:{target.status}", *target.flags][:16]

    node.subscribe("sensors/odom", tracker.add_odometry, policy="all")
    node.subscribe("perception/verification", tracker.add_verification, policy="all")
    # Keep the model and answer queries with it: the tracker lives on the robot, so a vision
    # worker that restarts (another machine, a crash) recovers the model instead of rebuilding.
    model_pub = node.publisher("perception/target_model", serve_last=True)

    def on_model(model) -> None:
        tracker.set_target_model(model)
        model_pub.serve(model)

    node.subscribe("perception/target_model", on_model, policy="all")
    node.subscribe("perception/candidates", on_candidates, policy="all")
    node.watch_alive(settings.vision_service, tracker.set_vision_alive)
    node.log.info(
        "tracker: estimator=%s vision_lag_scans=%d acquire=%s",
        settings.estimator,
        settings.vision_lag_scans,
        settings.acquire,
    )
    return tracker


def main(argv: list[str] | None = None) -> int:
    return service_main("tracker", TrackerNodeSettings, setup, argv, __doc__)
