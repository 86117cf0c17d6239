"""The leg detector role: what every detector offers (DESIGN.md "Leg candidates").

A detector turns one :class:`~followbot.schemas.LaserScan` into one
:class:`~followbot.schemas.PersonCandidates`. The steps most of them share live beside this
module, each a function on numpy arrays: :mod:`.beams` (validity, geometry, clip, horizon),
:mod:`.clusters` (clustering and per-cluster reductions, legs), :mod:`.pairing` (legs into
persons) and :mod:`.message` (the wire message).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from followbot.schemas import LaserScan, PersonCandidates

__all__ = ["LaserPose", "LegDetector", "Prediction"]

#: Optional tracked-target position (x_m, y_m) in the scan's frame (thesis criterion 3).
Prediction = tuple[float, float] | None

#: Optional pose (x_m, y_m, yaw_rad) of the laser in the odometry frame at the scan's stamp
#: (the robot's odometry pose composed with its ``laser_mount``), when the stage has odometry
#: covering the stamp. Detectors that keep a history of scans (``learned``'s static
#: background) register their scans with it; the others ignore it.
LaserPose = tuple[float, float, float] | None


@runtime_checkable
class LegDetector(Protocol):
    """What every detector offers: a ``name`` and ``detect``; settings are frozen Structs."""

    name: str

    def detect(
        self, scan: LaserScan, prediction: Prediction = None, pose: LaserPose = None
    ) -> PersonCandidates: ...
