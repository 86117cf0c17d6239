"""controller: follow the target -- control/cmd_vel and control/pan from tracking/target.

One VelocityCommand and one PanCommand per TrackState, naming its scan stamp (lock-step
rule 2). A watchdog timer brakes to zero velocity (reason ``stale``) when no target arrived for
``stale_after_s`` of wall time, or at once (reason ``tracker_gone``) when the tracker's
liveliness token disappears; its commands carry the stamp of the last target. Limits hold for
every command (core.py).

    followbot run controller --set limits.max_speed_mps=0.5
"""

from __future__ import annotations

import time
from typing import Annotated

import msgspec

from followbot.schemas import LaserScan, PanCommand, TrackState, VelocityCommand
from followbot.services.runtime.node import Node
from followbot.services.runtime.service import service_main
from followbot.services.runtime.settings import with_node_settings

from .avoid import scan_points, scan_view
from .core import Command, ControllerSettings, FollowController

__all__ = ["ControllerNodeSettings", "main", "setup"]

_ControllerNodeBase = with_node_settings(ControllerSettings, "_ControllerNodeBase", __name__)


class ControllerNodeSettings(_ControllerNodeBase, kw_only=True, forbid_unknown_fields=True):
    def __post_init__(self) -> None:
        super().__post_init__()
        core_settings(self)  # ControllerSettings' checks (the hardware caps) while loading

    stale_after_s: Annotated[float, msgspec.Meta(ge=0)] = 0.5
    """No target for this long (wall clock) -> brake to zero. 0 disables (lock-step on a slow
    machine, where wall time between scans means nothing)."""
    watchdog_period_s: Annotated[float, msgspec.Meta(gt=0)] = 0.05
    """Seconds between two checks of the watchdog (stale target, tracker gone); also the dt
    of its first braking command."""
    tracker_service: str = "tracker"
    """The service name whose liveliness token the watchdog watches: when it disappears, the
    base brakes (reason tracker_gone)."""
    nominal_dt_s: Annotated[float, msgspec.Meta(gt=0)] = 0.12
    """dt for the first target and after gaps longer than max_dt_s."""
    max_dt_s: Annotated[float, msgspec.Meta(gt=0)] = 0.5
    """The limits use the time between two targets' stamps as dt, up to this (s); a longer
    gap counts as nominal_dt_s."""
    scan_wait_s: Annotated[float, msgspec.Meta(ge=0)] = 0.1
    """guard.enabled: a target whose scan has not arrived yet (the tracker's answer can
    overtake the laser's own message) waits this long (wall clock) for it; then it is
    answered with the newest older scan, and Health's notes count it."""
    scan_max_age_s: Annotated[float, msgspec.Meta(gt=0)] = 0.5
    """guard.enabled: a scan stamped more than this before the target's scan is no scan
    (the base stops)."""


def core_settings(settings: msgspec.Struct) -> ControllerSettings:
    names = ControllerSettings.__struct_fields__
    return ControllerSettings(**{n: getattr(settings, n) for n in names})


class _Loop:
    """The node's state and handlers (all run in the node's loop, never concurrently)."""

    def __init__(self, node: Node, settings: ControllerNodeSettings) -> None:
        self.node, self.s = node, settings
        self.ctl = FollowController(core_settings(settings))
        self.cmd_pub = node.publisher("control/cmd_vel")
        self.pan_pub = node.publisher("control/pan")
        self.last_target: float | None = None  # monotonic s of the last target
        self.last_stamp: int | None = None  # its stamp_ns
        self.last_out: float | None = None  # monotonic s of the last command
        self.watchdog_out = False  # was the last command the watchdog's?
        self.tracker_alive: bool | None = None  # None: not known yet
        # guard.enabled: stamp_ns -> (base-frame points, scan_view), the last few scans
        self.scans: dict[int, tuple] = {}
        self.pending: tuple[TrackState, float] | None = None  # waiting for its scan
        self.scans_missed = 0  # targets answered without the scan of their stamp

    def publish(self, c: Command, stamp_ns: int) -> None:
        self.cmd_pub.put(
            VelocityCommand(
                stamp_ns=stamp_ns,
                frame_id="base_link",
                linear_mps=c.linear_mps,
                angular_radps=c.angular_radps,
                reason=c.reason,
            )
        )
        self.pan_pub.put(
            PanCommand(stamp_ns=stamp_ns, frame_id="base_link", pan_rad=c.pan_rad, reason=c.reason)
        )
        self.last_out = time.monotonic()

    def on_target(self, t: TrackState) -> None:
        if self.ctl.guard is not None:
            if self.pending is not None:  # an older one still waiting: answer it now
                self.answer(self.pending[0])
            if t.stamp_ns not in self.scans:
                # its scan (straight from the laser) is not here yet: wait for it a little, so
                # the answer does not depend on which message won the race (lock-step runs
                # stay reproducible); watchdog() answers with the last scan after scan_wait_s
                self.pending = (t, time.monotonic())
                return
        self.answer(t)

    def answer(self, t: TrackState) -> None:
        self.pending = None
        now = time.monotonic()
        last_stamp = self.last_stamp
        if self.watchdog_out and last_stamp is not None and t.stamp_ns <= last_stamp:
            # the watchdog is braking and this target is no newer than the last: it says
            # nothing new (a tracker whose input is stuck), so braking goes on
            self.publish(self.ctl.stop(now - self.last_out, "stale"), last_stamp)
            return
        if self.watchdog_out and self.last_out is not None:
            dt = now - self.last_out
        elif last_stamp is not None and 0 < t.stamp_ns - last_stamp <= self.s.max_dt_s * 1e9:
            dt = (t.stamp_ns - last_stamp) / 1e9
        elif last_stamp is not None and t.stamp_ns <= last_stamp:
            dt = 0.0  # repeated or older stamp: answer it, change nothing
        else:
            dt = self.s.nominal_dt_s
        scan = self.obstacles_for(t.stamp_ns) if self.ctl.guard is not None else None
        pts, view = (None, None) if scan is None else scan
        c = self.ctl.on_target(t, dt, pts, view)
        if last_stamp is None or t.stamp_ns > last_stamp:
            # only a target newer than the last one is fresh: a tracker repeating a stamp
            # (its input stuck) must not keep the watchdog quiet
            self.last_target = now
        self.last_stamp = t.stamp_ns if last_stamp is None else max(last_stamp, t.stamp_ns)
        self.watchdog_out = False
        self.publish(c, t.stamp_ns)

    def on_scan(self, scan: LaserScan) -> None:
        pts = scan_points(scan, self.s.laser_mount)  # base frame
        self.scans[scan.stamp_ns] = (pts, scan_view(scan, self.s.laser_mount))
        while len(self.scans) > 8:
            del self.scans[min(self.scans)]
        if self.pending is not None and self.pending[0].stamp_ns == scan.stamp_ns:
            self.answer(self.pending[0])

    def obstacles_for(self, stamp_ns: int):
        """The scan of the target's stamp, else the newest older one not too old."""
        if stamp_ns in self.scans:
            return self.scans[stamp_ns]
        older = [s for s in self.scans if s < stamp_ns]
        if not older or stamp_ns - max(older) > self.s.scan_max_age_s * 1e9:
            return None
        return self.scans[max(older)]

    def watchdog(self) -> None:
        now = time.monotonic()
        if self.pending is not None and now - self.pending[1] >= self.s.scan_wait_s:
            self.scans_missed += 1  # answered with the last scan before it (or none: stop)
            self.node.notes = [f"targets_without_their_scan={self.scans_missed}"]
            self.answer(self.pending[0])
        gone = self.tracker_alive is False
        stale = self.s.stale_after_s > 0 and (
            self.last_target is None or now - self.last_target > self.s.stale_after_s
        )
        if not (gone or stale):
            return
        if self.last_target is None and self.ctl.at_rest and self.last_out is not None:
            return  # never followed anyone and already said zero
        if self.ctl.at_rest and self.watchdog_out:
            return  # already braked to rest and said so
        dt = self.s.watchdog_period_s if self.last_out is None else now - self.last_out
        c = self.ctl.stop(dt, "tracker_gone" if gone else "stale")
        self.publish(c, self.last_stamp or 0)
        self.watchdog_out = True

    def on_tracker_alive(self, alive: bool) -> None:
        self.tracker_alive = alive
        if alive:
            self.node.clear_condition("tracker")
        else:
            self.node.set_condition("tracker", "degraded", "tracker gone: braking to a stop")
            self.node.log.warning("tracker liveliness gone: braking to zero velocity")
            self.watchdog()

    def restart_targets(self) -> None:
        self.last_stamp, self.pending = None, None

    def restart_scans(self) -> None:
        self.scans.clear()


def setup(node: Node, settings: ControllerNodeSettings) -> FollowController:
    loop = _Loop(node, settings)
    node.subscribe(
        "tracking/target",
        loop.on_target,
        policy="all",
        on_restart=loop.restart_targets,
        expect_within_s=settings.stale_after_s or None,
    )
    if loop.ctl.guard is not None:
        node.subscribe("sensors/scan", loop.on_scan, policy="all", on_restart=loop.restart_scans)
    node.watch_alive(settings.tracker_service, loop.on_tracker_alive)
    node.every(settings.watchdog_period_s, loop.watchdog, name="watchdog")
    return loop.ctl


def main(argv: list[str] | None = None) -> int:
    return service_main("controller", ControllerNodeSettings, setup, argv, __doc__)
