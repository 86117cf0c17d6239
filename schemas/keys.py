"""Zenoh key expressions: the only place that spells them.

Every key lives under ``followbot/<robot>/`` so several robots share one Zenoh network::

    followbot/<robot>/<topic>             data, e.g. followbot/r1/sensors/scan
    followbot/<robot>/health/<service>    Health of one service
    followbot/<robot>/alive/<service>     liveliness token of one service

``TOPICS`` maps each data topic to its message type; code asks :class:`Keys` for a key and
never writes one by hand.
"""

from __future__ import annotations

import re

from .base import Message
from .messages import (
    GroundTruth,
    Health,
    Image,
    LaserScan,
    Odometry,
    PanCommand,
    People,
    PersonCandidates,
    TargetCommand,
    TargetModel,
    TrackState,
    VelocityCommand,
    Verification,
)

__all__ = ["PREFIX", "TOPICS", "Keys", "topic_type"]

PREFIX = "followbot"

#: Data topics and the one message type each carries.
TOPICS: dict[str, type[Message]] = {
    "sensors/scan": LaserScan,
    "sensors/image": Image,
    "sensors/odom": Odometry,
    "perception/candidates": PersonCandidates,
    "perception/verification": Verification,
    "perception/target_model": TargetModel,
    "perception/target_command": TargetCommand,
    "tracking/target": TrackState,
    "tracking/people": People,
    "control/cmd_vel": VelocityCommand,
    "control/pan": PanCommand,
    "sim/truth": GroundTruth,
}

_NAME = re.compile(r"^[A-Za-z0-9_\-]{1,64}$")


def _check_name(kind: str, name: str) -> str:
    if not _NAME.match(name):
        raise ValueError(
            f"{kind} name {name!r} must be 1-64 characters of letters, digits, '_' or '-' "
            "(it becomes one chunk of a Zenoh key expression)"
        )
    return name


def topic_type(topic: str) -> type[Message]:
    """The message type of a data topic or of ``health/<service>``."""
    if topic.startswith("health/"):
        return Health
    try:
        return TOPICS[topic]
    except KeyError:
        raise ValueError(
            f"unknown topic {topic!r}; topics are: {', '.join(sorted(TOPICS))}, health/<service>"
        ) from None


class Keys:
    """Key expressions of one robot."""

    def __init__(self, robot: str = "robot") -> None:
        self.robot = _check_name("robot", robot)
        self.root = f"{PREFIX}/{robot}"

    def topic(self, topic: str) -> str:
        """Key of a data topic (``sensors/scan``...) or ``health/<service>``."""
        topic_type(topic)
        if topic.startswith("health/"):
            _check_name("service", topic.removeprefix("health/"))
        return f"{self.root}/{topic}"

    def health(self, service: str) -> str:
        return f"{self.root}/health/{_check_name('service', service)}"

    def alive(self, service: str) -> str:
        """Liveliness token key of a service."""
        return f"{self.root}/alive/{_check_name('service', service)}"

    @property
    def all_health(self) -> str:
        return f"{self.root}/health/*"

    @property
    def all_alive(self) -> str:
        return f"{self.root}/alive/*"

    def topic_of(self, key: str) -> str:
        """Inverse of :meth:`topic`: the topic name of a key of this robot."""
        prefix = self.root + "/"
        if not key.startswith(prefix):
            raise ValueError(f"key {key!r} is not under {prefix!r}")
        topic = key[len(prefix) :]
        topic_type(topic)
        return topic

    def __repr__(self) -> str:
        return f"Keys(robot={self.robot!r})"
