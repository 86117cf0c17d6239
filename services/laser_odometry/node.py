"""laser_odometry: the robot's odometry from its laser scans, for a robot or recording without.

Subscribes ``sensors/scan`` and publishes ``sensors/odom`` (:class:`Odometry
<followbot.schemas.Odometry>`), one message per scan stamped with the scan's stamp (lock-step
rule 2 of docs/runtime.md: the stages that wait for odometry at or after a scan's stamp get
it), also for a scan it refuses or cannot match. The laser's motion comes from matching each
scan against a keyframe (core.py); the published pose is the *base's* (``base_link``), placed
by the robot-wide ``laser_mount`` (services/runtime/mount.py)::

    B = M ∘ L ∘ M⁻¹          L: the laser's pose in its first scan's frame, M: the mount

so the odometry frame is the base frame at the first scan. ``v_mps`` and ``w_radps`` are the
base's forward speed and turn rate over the last step. Run it only where nothing else
publishes ``sensors/odom`` (the robot's driver, the simulator): two sources would fight.

A failed match or a refused scan (too few finite returns: NaN, ±inf, empty) is counted in the
Health notes and logged (at most every 5 s); the pose is carried on by the last twist for
``carry_twist_s``, then held. A stream whose clock restarts starts again at zero.

    followbot run laser_odometry --set 'laser_mount={x_m: 0.2, y_m: 0, yaw_deg: 0}'
"""

from __future__ import annotations

import logging
import math

import numpy as np

from followbot.schemas import LaserScan, Odometry
from followbot.services.common.scanmatch import compose, invert
from followbot.services.runtime.node import Node
from followbot.services.runtime.service import service_main
from followbot.services.runtime.stats import RateLimitedLog

from .core import ScanOdometry, Update
from .settings import LaserOdometrySettings

__all__ = ["LaserOdometrySettings", "main", "setup"]


class _Stage:
    """The node's state and handler (the node runs them one at a time)."""

    def __init__(self, node: Node, settings: LaserOdometrySettings) -> None:
        self.node, self.s = node, settings
        self.odometry = ScanOdometry(settings)
        self.out = node.publisher("sensors/odom")
        self.mount = np.array(settings.laser_mount.pose())
        self.unmount = invert(self.mount)
        self.last: tuple[int, np.ndarray] | None = None  # stamp, base pose of the last message
        self.log = RateLimitedLog(node.log, 5.0)

    def on_scan(self, scan: LaserScan) -> None:
        up = self.odometry.update(scan)
        if up.status in ("failed", "refused"):
            c = self.odometry.counts
            self.log.log(
                logging.WARNING, up.status, "scan %d %s (inliers %.2f); pose carried on or "
                "held; %d failed, %d refused so far", scan.stamp_ns, up.status, up.inliers,
                c["failed"], c["refused"],
            )  # fmt: skip
        self.publish(scan, up)

    def publish(self, scan: LaserScan, up: Update) -> None:
        base = compose(compose(self.mount, np.array(up.pose)), self.unmount)
        v = w = 0.0
        if self.last is not None and scan.stamp_ns > self.last[0]:
            dt = (scan.stamp_ns - self.last[0]) / 1e9
            step = compose(invert(self.last[1]), base)
            v, w = float(step[0] / dt), float(math.remainder(step[2], math.tau) / dt)
        self.last = (scan.stamp_ns, base)
        self.out.put(
            Odometry(
                stamp_ns=scan.stamp_ns,
                frame_id=self.s.odom_frame_id,
                seq=scan.seq,
                child_frame_id=self.s.base_frame_id,
                x_m=float(base[0]),
                y_m=float(base[1]),
                yaw_rad=math.remainder(float(base[2]), math.tau),
                v_mps=v,
                w_radps=w,
            )
        )

    def restart(self) -> None:
        """The source restarted with a new clock: a new stream, a new odometry frame."""
        self.odometry.reset()
        self.last = None

    def notes(self) -> None:
        c = self.odometry.counts
        x, y, th = self.odometry.pose
        self.node.notes = [f"{k}={c[k]}" for k in c] + [
            f"laser_pose=({x:.2f}, {y:.2f}, {math.degrees(th):.1f} deg)"
        ]


def setup(node: Node, settings: LaserOdometrySettings) -> ScanOdometry:
    st = _Stage(node, settings)
    node.subscribe(
        "sensors/scan", st.on_scan, policy="all", on_restart=st.restart, expect_within_s=1.0
    )
    st.notes()
    node.every(settings.health_period_s, st.notes, name="notes")
    node.log.info("laser mount %s", settings.laser_mount.describe())
    return st.odometry


def main(argv: list[str] | None = None) -> int:
    return service_main("laser_odometry", LaserOdometrySettings, setup, argv, __doc__)
