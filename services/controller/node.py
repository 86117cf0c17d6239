"""controller: follow the target -- control/cmd_vel and control/pan from tracking/target.

One VelocityCommand and one PanCommand per TrackState, naming its scan stamp (lock-step
rule 2). A watchdog timer brakes to zero velocity (reason ``stale``) when no target arrived for
``stale_after_s`` of wall time, or at once (reason ``tracker_gone``) when the tracker's
liveliness token disappears; its commands carry the stamp of the last target. Limits hold for
every command (core.py).

    followbot run controller --set max_speed_mps=0.5
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
    tracker_service: str = "tracker"
    nominal_dt_s: Annotated[float, msgspec.Meta(gt=0)] = 0.12
    """dt for the first target and after gaps longer than max_dt_s."""
    max_dt_s: Annotated[float, msgspec.Meta(gt=0)] = 0.5
    scan_wait_s: Annotated[float, msgspec.Meta(ge=0)] = 0.1
    """avoid_obstacles: a target whose scan has not arrived yet (the tracker's answer can
    overtake the laser's own message) waits this long (wall clock) for it; then it is
    answered with the newest older scan, and Health's notes count it."""
    scan_max_age_s: Annotated[float, msgspec.Meta(gt=0)] = 0.5
    """avoid_obstacles: a scan stamped more than this before the target's scan is no scan
    (the base stops)."""


def core_settings(settings: msgspec.Struct) -> ControllerSettings:
    names = ControllerSettings.__struct_fields__
    return ControllerSettings(**{n: getattr(settings, n) for n in names})


def setup(node: Node, settings: ControllerNodeSettings) -> FollowController:
    ctl = FollowController(core_settings(settings))
    cmd_pub = node.publisher("control/cmd_vel")
    pan_pub = node.publisher("control/pan")
    st = {
        "last_target": None,  # monotonic s of the last target
        "last_stamp": None,  # its stamp_ns
        "last_out": None,  # monotonic s of the last command
        "watchdog_out": False,  # was the last command the watchdog's?
        "tracker_alive": None,  # None: not known yet
        "scans": {},  # avoid_obstacles: stamp_ns -> base-frame points, the last few
        "pending": None,  # (target, monotonic s): waiting for the scan of its stamp
        "scans_missed": 0,  # targets answered without the scan of their stamp
    }

    def publish(c: Command, stamp_ns: int) -> None:
        cmd_pub.put(
            VelocityCommand(
                stamp_ns=stamp_ns,
                frame_id="base_link",
                linear_mps=c.linear_mps,
                angular_radps=c.angular_radps,
                reason=c.reason,
            )
        )
        pan_pub.put(
            PanCommand(stamp_ns=stamp_ns, frame_id="base_link", pan_rad=c.pan_rad, reason=c.reason)
        )
        st["last_out"] = time.monotonic()

    def on_target(t: TrackState) -> None:
        if ctl.guard is not None:
            if st["pending"] is not None:  # an older one still waiting: answer it now
                answer(st["pending"][0])
            if t.stamp_ns not in st["scans"]:
                # its scan (straight from the laser) is not here yet: wait for it a little, so
                # the answer does not depend on which message won the race (lock-step runs
                # stay reproducible); watchdog() answers with the last scan after scan_wait_s
                st["pending"] = (t, time.monotonic())
                return
        answer(t)

    def answer(t: TrackState) -> None:
        st["pending"] = None
        now = time.monotonic()
        last_stamp = st["last_stamp"]
        if st["watchdog_out"] and last_stamp is not None and t.stamp_ns <= last_stamp:
            # the watchdog is braking and this target is no newer than the last: it says
            # nothing new (a tracker whose input is stuck), so braking goes on
            publish(ctl.stop(now - st["last_out"], "stale"), last_stamp)
            return
        if st["watchdog_out"] and st["last_out"] is not None:
            dt = now - st["last_out"]
        elif last_stamp is not None and 0 < t.stamp_ns - last_stamp <= settings.max_dt_s * 1e9:
            dt = (t.stamp_ns - last_stamp) / 1e9
        elif last_stamp is not None and t.stamp_ns <= last_stamp:
            dt = 0.0  # repeated or older stamp: answer it, change nothing
        else:
            dt = settings.nominal_dt_s
        scan = obstacles_for(t.stamp_ns) if ctl.guard is not None else None
        pts, view = (None, None) if scan is None else scan
        c = ctl.on_target(t, dt, pts, view)
        if last_stamp is None or t.stamp_ns > last_stamp:
            # only a target newer than the last one is fresh: a tracker repeating a stamp
            # (its input stuck) must not keep the watchdog quiet
            st["last_target"] = now
        st["last_stamp"] = t.stamp_ns if last_stamp is None else max(last_stamp, t.stamp_ns)
        st["watchdog_out"] = False
        publish(c, t.stamp_ns)

    def on_scan(scan: LaserScan) -> None:
        pts = scan_points(scan, settings.laser_mount)  # base frame
        scans = st["scans"]
        scans[scan.stamp_ns] = (pts, scan_view(scan, settings.laser_mount))
        while len(scans) > 8:
            del scans[min(scans)]
        pending = st["pending"]
        if pending is not None and pending[0].stamp_ns == scan.stamp_ns:
            answer(pending[0])

    def obstacles_for(stamp_ns: int):
        """The scan of the target's stamp, else the newest older one not too old."""
        scans = st["scans"]
        if stamp_ns in scans:
            return scans[stamp_ns]
        older = [s for s in scans if s < stamp_ns]
        if not older or stamp_ns - max(older) > settings.scan_max_age_s * 1e9:
            return None
        return scans[max(older)]

    def watchdog() -> None:
        now = time.monotonic()
        pending = st["pending"]
        if pending is not None and now - pending[1] >= settings.scan_wait_s:
            st["scans_missed"] += 1  # answered with the last scan before it (or none: stop)
            node.notes = [f"targets_without_their_scan={st['scans_missed']}"]
            answer(pending[0])
        gone = st["tracker_alive"] is False
        stale = settings.stale_after_s > 0 and (
            st["last_target"] is None or now - st["last_target"] > settings.stale_after_s
        )
        if not (gone or stale):
            return
        if st["last_target"] is None and ctl.at_rest and st["last_out"] is not None:
            return  # never followed anyone and already said zero
        if ctl.at_rest and st["watchdog_out"]:
            return  # already braked to rest and said so
        dt = settings.watchdog_period_s if st["last_out"] is None else now - st["last_out"]
        c = ctl.stop(dt, "tracker_gone" if gone else "stale")
        publish(c, st["last_stamp"] or 0)
        st["watchdog_out"] = True

    def on_tracker_alive(alive: bool) -> None:
        st["tracker_alive"] = alive
        if alive:
            node.clear_condition("tracker")
        else:
            node.set_condition("tracker", "degraded", "tracker gone: braking to a stop")
        if not alive:
            node.log.warning("tracker liveliness gone: braking to zero velocity")
            watchdog()

    def restart_targets() -> None:
        st.update(last_stamp=None, pending=None)

    def restart_scans() -> None:
        st["scans"].clear()

    node.subscribe(
        "tracking/target",
        on_target,
        policy="all",
        on_restart=restart_targets,
        expect_within_s=settings.stale_after_s or None,
    )
    if ctl.guard is not None:
        node.subscribe("sensors/scan", on_scan, policy="all", on_restart=restart_scans)
    node.watch_alive(settings.tracker_service, on_tracker_alive)
    node.every(settings.watchdog_period_s, watchdog, name="watchdog")
    return ctl


def main(argv: list[str] | None = None) -> int:
    return service_main("controller", ControllerNodeSettings, setup, argv, __doc__)
