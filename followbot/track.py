"""``followbot track FILE``: what would followbot have done on this recording?

    followbot track demo.bag --scan-topic /scan --output out/track
    followbot track run.mcap --scan-topic sensors/scan --odom-topic sensors/odom \\
                    --image-topic sensors/image --output out/track
    followbot track aces-corrected.log.gz --output out/aces     # CARMEN: FLASER, FLASER/odom

Runs the real pipeline (laser_legs and tracker, plus vision_verify when images are given) as
processes over Zenoh, in lock-step with the recording: each scan is published only once the
stages have answered the previous one, so the run is deterministic and as fast as the stages
allow. Writes ``DIR/tracks.mcap`` (tracking/target and tracking/people as published) and
``DIR/people.csv`` / ``DIR/target.csv`` with columns ``stamp_ns,id,x_m,y_m,vx_mps,vy_mps,frame``
in the base frame of each scan (``frame`` names it; target.csv: scans where the target is
tracked or coasting). Without a camera the target is the nearest person ahead (tracker
``acquire: nearest``).

Without odometry in the recording (and no --odom-topic), the laser_odometry stage runs first
and estimates it from the scans (``--laser-odometry auto``, said on stderr); ``on`` runs it
instead of the recording's odometry, ``off`` never.

Where the laser sits on the robot (the stages' ``laser_mount``), first found wins:
``--laser-pose x,y,yaw_deg``; a ROS bag's /tf_static (then /tf), the chain from
``--base-frame`` to ``--laser-frame`` (default: the scans' frame_id) in 2-D; a CARMEN log's
ROBOTLASER records (the laser's pose against the robot's); else the laser is taken to sit at
the base's origin, facing ahead. The mount used and where it came from are printed.
"""

from __future__ import annotations

import argparse
import csv
import heapq
import math
import os
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from followbot import progress
from followbot.presetargs import add_preset_arguments
from followbot.services.runtime.argtypes import positive_float, positive_int


def main(argv: list[str] | None = None) -> int:
    from followbot.bags import RecordingError, open_recording

    p = argparse.ArgumentParser(
        prog="followbot track", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    p.add_argument(
        "file",
        help="a followbot .mcap, a ROS 1 .bag, a ROS 2 bag folder or a CARMEN .log/.clf "
        "(gzipped or not)",
    )
    p.add_argument(
        "--scan-topic",
        help="the laser scans (LaserScan); default: the recording's own (a followbot MCAP's "
        "sensors/scan, a bag's only LaserScan topic, a CARMEN log's front laser) and with it "
        "its odometry, if it has one",
    )
    p.add_argument(
        "--odom-topic",
        help="odometry (ego-motion compensation); with --scan-topic, none unless given",
    )
    p.add_argument("--image-topic", help="camera images (vision verification)")
    p.add_argument(
        "--laser-pose", metavar="X,Y,YAW_DEG",
        help="where the laser sits on the robot: metres ahead of and left of the base's "
        "origin, and degrees turned counter-clockwise, e.g. 0.88,0,42 (overrides the "
        "recording's tf)",
    )  # fmt: skip
    p.add_argument(
        "--base-frame", default="base_link",
        help="the robot's base frame in the recording's tf (base_link)",
    )  # fmt: skip
    p.add_argument(
        "--laser-frame", help="the laser's frame in the recording's tf (default: the scans' "
        "frame_id)",
    )  # fmt: skip
    p.add_argument(
        "--laser-odometry", choices=("auto", "on", "off"), default="auto",
        help="estimate the odometry from the scans (the laser_odometry stage): auto (default) "
        "when the recording has none, on (instead of the recording's), off",
    )  # fmt: skip
    p.add_argument("--output", required=True, metavar="DIR", help="output folder")
    add_preset_arguments(p)
    p.add_argument(
        "--max-scans", type=positive_int, metavar="N", help="stop after N scans (default: all)"
    )
    p.add_argument(
        "--timeout", type=positive_float, default=5.0, metavar="S",
        help="seconds to wait for the stages' answers to one scan (5)",
    )  # fmt: skip
    args = p.parse_args(argv)
    remaps = {args.scan_topic: "sensors/scan"} if args.scan_topic else {}
    if args.odom_topic:
        remaps[args.odom_topic] = "sensors/odom"
    if args.image_topic:
        remaps[args.image_topic] = "sensors/image"
    rec = None
    if args.scan_topic is None:
        # The recording says which of its topics are the scans (and odometry): open it first.
        try:
            rec = open_with_defaults(args.file, remaps)
        except (RecordingError, ValueError) as exc:
            print(f"followbot track: {exc}", file=sys.stderr)
            print("followbot track: say which topic holds the scans with --scan-topic",
                  file=sys.stderr)  # fmt: skip
            return 2
    odometry = bool(args.odom_topic) if rec is None else "sensors/odom" in rec.mapping.values()
    laser_odometry = use_laser_odometry(args.laser_odometry, odometry)
    if laser_odometry:
        remaps = {src: dst for src, dst in remaps.items() if dst != "sensors/odom"}
        if rec is not None:
            rec.mapping = {s: d for s, d in rec.mapping.items() if d != "sensors/odom"}
        print(laser_odometry_note(odometry), file=sys.stderr)
    stages = ["laser_legs", "tracker"] + (["vision_verify"] if args.image_topic else [])
    settings = tracking_settings(
        args.preset, stages, bool(args.image_topic), args.set, odometry=odometry,
        laser_odometry=laser_odometry,
    )  # fmt: skip
    stages = (["laser_odometry"] if laser_odometry else []) + stages
    if isinstance(settings, str):
        print(f"followbot track: {settings}", file=sys.stderr)
        return 2
    pose = None
    if args.laser_pose is not None:
        from followbot.services.runtime.mount import parse_laser_pose

        try:
            pose = parse_laser_pose(args.laser_pose)
        except ValueError as exc:
            print(f"followbot track: --laser-pose: {exc}", file=sys.stderr)
            return 2
    # Each stage checks its settings the way it will when started, all at once, before the
    # recording is read: a wrong key or value is an error in about a second.
    from followbot.runner import invalid_stage_settings

    bad = invalid_stage_settings(settings)
    if bad:
        for stage, why in bad.items():
            print(f"followbot track: {stage}: {why}", file=sys.stderr)
        return 2
    if rec is None:
        try:
            rec = open_recording(args.file, remaps)
        except (RecordingError, ValueError) as exc:
            print(f"followbot track: {exc}", file=sys.stderr)
            return 2
        rec.mapping = {src: dst for src, dst in rec.mapping.items() if src in remaps}
    print(f"tracking {rec.path}: " + ", ".join(f"{src} -> {dst}" for src, dst in
          sorted(rec.mapping.items(), key=lambda item: item[1])), file=sys.stderr)  # fmt: skip
    if rec.damage is not None:
        print(f"warning: {rec.path} is damaged: {rec.damage.describe()}; tracking what was "
              "read", file=sys.stderr)  # fmt: skip
    for warning in rec.warnings:
        print(f"warning: {rec.path}: {warning}", file=sys.stderr)
    try:
        mount, source = laser_mount_of(rec, pose, args.base_frame, args.laser_frame)
    except RecordingError as exc:
        print(f"followbot track: {exc}", file=sys.stderr)
        return 2
    print(f"laser mount: {mount.describe()} ({source})", file=sys.stderr)
    if not mount.is_identity:
        import msgspec

        for stage in settings.values():
            stage["laser_mount"] = msgspec.to_builtins(mount)
    try:
        return _track(rec, stages, settings, Path(args.output), args.max_scans, args.timeout)
    except RecordingError as exc:
        print(f"followbot track: {exc}", file=sys.stderr)
        return 1


def laser_mount_of(rec, given, base_frame: str, laser_frame: str | None):
    """(LaserMount, where it came from): ``given`` (--laser-pose), else the recording's tf or
    CARMEN ROBOTLASER records, else the base's origin (module doc)."""
    from followbot.bags import mount_from_tf
    from followbot.services.runtime.mount import LaserMount

    if given is not None:
        return given, "--laser-pose"
    scan_src = next((s for s, d in rec.mapping.items() if d == "sensors/scan"), None)
    if rec.kind == "ros" and rec.indexed:
        frame = laser_frame or _scan_frame(rec)
        found = mount_from_tf(rec.path, base_frame, frame) if frame else None
        if found is not None:
            for warning in found.warnings:
                print(f"warning: {rec.path}: {warning}", file=sys.stderr)
            return found.mount, f"tf {found.source}"
        why = f"no tf joins {base_frame} and {frame or 'the scans frame'}"
        return LaserMount(), f"{why}: taken at the base's origin; give --laser-pose"
    if rec.kind == "carmen" and scan_src is not None:
        pose = rec.carmen.laser_mount(scan_src)
        if pose is not None:
            x, y, yaw = pose
            mount = LaserMount(x_m=x, y_m=y, yaw_deg=math.degrees(yaw))
            return mount, f"{scan_src} records: the laser's pose against the robot's"
    return LaserMount(), "none in the recording: taken at the base's origin; give --laser-pose"


def _scan_frame(rec) -> str | None:
    """The frame_id of the recording's first scan."""
    for _t, topic, message in rec.messages():
        if topic == "sensors/scan":
            return message.frame_id.lstrip("/") or None
    return None


def open_with_defaults(path: str, remaps: dict[str, str]):
    """Open ``path`` for tracking: the recording with its default scan source (and
    odometry, if it has one), plus what ``remaps`` names."""
    from followbot.bags import RecordingError, open_recording

    rec = open_recording(path, remaps)
    rec.mapping = {
        src: dst
        for src, dst in rec.mapping.items()
        if src in remaps or dst in ("sensors/scan", "sensors/odom")
    }
    if "sensors/scan" not in rec.mapping.values():
        raise RecordingError(
            f"{rec.path}: no topic of it feeds sensors/scan by default; it has: "
            + ", ".join(f"{t} ({ty})" for t, (ty, _) in sorted(rec.contents.items()))
        )
    return rec


def use_laser_odometry(mode: str, recorded: bool) -> bool:
    """Whether laser_odometry runs (``--laser-odometry`` ``mode``), the recording having
    odometry of its own (``recorded``) or not."""
    if mode not in ("auto", "on", "off"):
        raise ValueError(f"laser odometry {mode!r}: expected auto, on or off")
    return mode == "on" or (mode == "auto" and not recorded)


def laser_odometry_note(recorded: bool) -> str:
    """What a run with laser_odometry says it does."""
    if recorded:
        return "odometry: laser_odometry, from the scans, instead of the recording's"
    return (
        "odometry: none in the recording; laser_odometry estimates it from the scans "
        "(--laser-odometry off: run without)"
    )


def tracking_settings(
    preset: str,
    stages: list[str],
    vision: bool,
    overrides: list[str],
    *,
    odometry: bool,
    laser_odometry: bool = False,
) -> dict | str:
    """Each of ``stages``' settings for a lock-step run of ``preset`` with ``overrides``
    (``SERVICE.KEY=VALUE``); without vision the target is the nearest person ahead. With
    ``laser_odometry`` the laser_odometry stage comes first (its odometry then counts as the
    recording's). A bad override gives the reason (str) instead. An unknown preset raises
    RunError."""
    from followbot.runner import stage_settings
    from followbot.services.runtime.settings import SettingsError, apply_overrides

    odometry = odometry or laser_odometry
    all_settings = stage_settings(preset, lockstep=True, odometry=odometry, vision=vision)
    settings = {s: v for s, v in all_settings.items() if s in stages}
    if laser_odometry:
        stages = ["laser_odometry", *stages]
        # the recording sets the pace: a gap between its scans is no stamp from the future
        settings = {"laser_odometry": {"clock": {"max_ahead_s": None}}, **settings}
    if not vision:
        settings["tracker"]["acquire"] = "nearest"
    for item in overrides:
        service, dot, rest = item.partition(".")
        if not dot or service not in settings:
            return f"--set {item!r}: expected SERVICE.KEY=VALUE with SERVICE in {stages}"
        try:
            apply_overrides(settings[service], [rest])
        except SettingsError as exc:
            return str(exc)
    return settings


class PipelineError(RuntimeError):
    """The stages could not run the recording (one failed to start, exited, or stopped
    answering); says why, with the last lines of its log."""


@dataclass
class PipelineRun:
    """What :func:`run_pipeline` did."""

    scans: int
    """Scans sent (each answered by the stages or timed out)."""
    scan_stamps: list[int]
    """Their stamps, in the order sent."""
    seconds: float
    """From the first scan sent to the last one answered (start-up not included)."""
    timeouts: dict[str, int]
    """Stage -> scans it did not answer within the timeout."""

    @property
    def scans_per_s(self) -> float:
        return self.scans / self.seconds if self.seconds > 0 else float("nan")


def run_pipeline(
    rec,
    stages: list[str],
    settings: dict,
    out: Path,
    *,
    max_scans: int | None = None,
    timeout_s: float = 5.0,
    on_people: Callable | None = None,
    on_target: Callable | None = None,
    label: str = "tracking",
    robot: str | None = None,
    give_up_after: int | None = None,
) -> PipelineRun:
    """Run ``rec`` (a :class:`followbot.bags.Recording`) through ``stages`` started as
    processes with ``settings`` ({stage: settings}), in lock-step, their settings files and
    logs in ``out``. ``on_people(msg, payload)`` / ``on_target(msg, payload)`` get each
    tracking/people and tracking/target message (People, TrackState) as published, from
    Zenoh's threads. Raises :class:`PipelineError` when a stage fails: it exits, or leaves
    ``give_up_after`` (default :data:`GIVE_UP_SCANS`) scans in a row unanswered."""
    from followbot.runner import StageProcesses
    from followbot.services.runtime.bus import ZenohBus
    from followbot.services.runtime.clock import ClockSettings
    from followbot.services.runtime.lockstep import LockstepBarrier
    from followbot.services.runtime.node import Node
    from followbot.services.runtime.session import free_loopback_endpoint, open_session
    from followbot.services.runtime.settings import NodeSettings, ZenohSettings

    give_up_after = give_up_after or GIVE_UP_SCANS
    out.mkdir(parents=True, exist_ok=True)
    endpoint = free_loopback_endpoint()
    robot = robot or f"track{os.getpid()}x{time.monotonic_ns() % 1_000_000}"
    total = sum(n for src, (_, n) in rec.contents.items() if rec.mapping.get(src) == "sensors/scan")
    if max_scans:
        total = min(total, max_scans)
    session = open_session(ZenohSettings(listen=[endpoint]))
    # the recording sets the pace: a gap between its scans is no stamp from the future
    node_settings = NodeSettings(
        robot=robot, health_period_s=3600, clock=ClockSettings(max_ahead_s=None)
    )
    node = Node("track", node_settings, ZenohBus(session))
    if on_people is not None:
        node.subscribe("tracking/people", on_people, with_payload=True)
    if on_target is not None:
        node.subscribe("tracking/target", on_target, with_payload=True)
    barrier = LockstepBarrier(node, stages)
    pubs = {t: node.publisher(t, reliable=True) for t in set(rec.mapping.values())}
    common = {"robot": robot, "zenoh": {"connect": [endpoint]}, "log_level": "warning"}
    procs = StageProcesses(out)
    stamps: list[int] = []
    t0 = None
    t1 = time.monotonic()
    try:
        for s in stages:
            procs.start(s, {**common, **settings[s]})
        deadline = time.monotonic() + 60.0
        while missing := barrier.wait_alive(0.1):
            if (s := procs.exited(stages)) is not None:
                code = procs.procs[s].returncode
                raise PipelineError(_why(f"{s} exited {code} on start-up", procs, [s]))
            if time.monotonic() > deadline:
                raise PipelineError(_why(f"stages did not start: {missing}", procs, missing))
        time.sleep(0.3)  # alive means subscribed; let the stages' links to each other settle
        last_shown = 0.0
        silent = 0  # scans in a row a stage left unanswered
        messages = sensor_order(rec.messages())
        if "sensors/odom" in pubs:
            messages = odometry_ahead(messages)
        for topic, message in messages:
            if t0 is None:
                t0 = time.monotonic()
            pubs[topic].put(message)
            if topic != "sensors/scan":
                continue
            stamps.append(message.stamp_ns)
            late = barrier.wait(message.stamp_ns, timeout_s)
            silent = silent + 1 if late else 0
            if silent >= give_up_after:
                log = ", ".join(str(out / f"{s}.log") for s in late)
                why = f"{', '.join(late)} answered none of the last {silent} scans (see {log})"
                raise PipelineError(_why(why, procs, late))
            t1 = time.monotonic()
            if t1 - last_shown > 0.5 or len(stamps) == total:
                last_shown = t1
                n = len(stamps)
                progress.show(f"  {label} {n}/{total} scans {progress.count_bar(n, total)}")
            if max_scans and len(stamps) >= max_scans:
                break
            if (s := procs.exited(stages)) is not None:
                code = procs.procs[s].returncode
                raise PipelineError(_why(f"{s} exited {code}", procs, [s]))
        time.sleep(0.2)  # the last tracking/people
        node.spin_once()  # with what came while a handler ran (queued for the loop)
    finally:
        procs.stop()
        node.close()
        session.close()
        progress.finish()
    return PipelineRun(
        scans=len(stamps),
        scan_stamps=stamps,
        seconds=t1 - t0 if t0 is not None else 0.0,
        timeouts={s: n for s, n in barrier.timeouts.items() if n},
    )


def _track(rec, stages, settings, out: Path, max_scans, timeout_s: float) -> int:
    from followbot.mcapio import McapTopicWriter

    out.mkdir(parents=True, exist_ok=True)
    robot = f"track{os.getpid()}"
    writer = McapTopicWriter(out / "tracks.mcap", robot)
    people_rows: list[list] = []
    target_rows: list[list] = []
    most_at_once = [0]

    def on_people(m, payload: bytes) -> None:
        writer.write("tracking/people", payload, m.stamp_ns, time.time_ns())
        most_at_once[0] = max(most_at_once[0], len(m.tracks))
        for t in m.tracks:
            people_rows.append([m.stamp_ns, t.id, t.x_m, t.y_m, t.vx_mps, t.vy_mps, m.frame_id])

    def on_target(m, payload: bytes) -> None:
        writer.write("tracking/target", payload, m.stamp_ns, time.time_ns())
        if m.status in ("tracking", "coasting"):
            target_rows.append(
                [m.stamp_ns, m.track_id, m.x_m, m.y_m, m.vx_mps, m.vy_mps, m.frame_id]
            )

    t0 = time.monotonic()
    try:
        run = run_pipeline(
            rec, stages, settings, out, max_scans=max_scans, timeout_s=timeout_s,
            on_people=on_people, on_target=on_target, robot=robot,
        )  # fmt: skip
    except PipelineError as exc:
        print(f"followbot track: {exc}", file=sys.stderr)
        return 1
    finally:
        writer.close()
    write_csv(out / "people.csv", people_rows)
    write_csv(out / "target.csv", target_rows)
    ids = {r[1] for r in people_rows}
    wall = time.monotonic() - t0
    scans = run.scans
    # A track id is not a person: one person lost and found again gets a new id, so the ids
    # over-count people; the most tracks in one scan is what a scan shows at once.
    plural = "" if len(ids) == 1 else "s"
    print(f"tracked {scans} scans in {wall:.1f} s ({scans / max(wall, 1e-9):.0f} scans/s): "
          f"{len(ids)} person track{plural} (distinct track ids), at most {most_at_once[0]} "
          f"in one scan; target tracked in {len(target_rows)} scans")  # fmt: skip
    if run.timeouts:
        print(f"  stages that did not answer in time: {run.timeouts}")
    for reason, n in rec.skipped.most_common():
        print(f"  skipped {n}: {reason}")
    for warning in rec.warnings:
        print(f"warning: {rec.path}: {warning}", file=sys.stderr)
    if rec.damage is not None:
        print(f"warning: {rec.path} is damaged: {rec.damage.describe()}", file=sys.stderr)
    print(f"wrote {out / 'tracks.mcap'}, {out / 'people.csv'}, {out / 'target.csv'}")
    return 0


def write_csv(path: Path, rows: list[list]) -> None:
    """``stamp_ns,id,x_m,y_m,vx_mps,vy_mps,frame`` rows (people.csv, target.csv)."""
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["stamp_ns", "id", "x_m", "y_m", "vx_mps", "vy_mps", "frame"])
        w.writerows([r[:2] + [f"{v:.4f}" for v in r[2:6]] + r[6:] for r in rows])


def sensor_order(messages, window: int = 64):
    """``(topic, message)`` in the order a lock-step source sends them: by stamp, the scan
    last among messages of the same stamp (docs/runtime.md, rule 1).

    A recording logs messages as they arrived, and two publishers' messages of one sensor
    instant (odometry and scan, say) can arrive either way round; replaying a scan before its
    odometry would make the tracker extrapolate. A window of ``window`` messages is re-sorted.
    """
    heap: list = []
    for n, (_log_ns, topic, message) in enumerate(messages):
        heapq.heappush(heap, (message.stamp_ns, topic == "sensors/scan", n, topic, message))
        if len(heap) > window:
            *_, t, m = heapq.heappop(heap)
            yield t, m
    while heap:
        *_, t, m = heapq.heappop(heap)
        yield t, m


def odometry_ahead(messages, horizon_ns: int = 1_000_000_000):
    """Hold each scan back until an odometry message stamped at or after it has gone out.

    The stages, in lock-step, wait for such odometry before they use a scan (docs/runtime.md,
    rule 5), so a scan is only sent after it: the odometry poses at the scan's instant are
    then interpolated, never extrapolated. A scan waits at most until the recording is
    ``horizon_ns`` past it (odometry that stopped); what came after it waits with it. In a
    followbot simulator recording the odometry already has the scan's stamp: nothing moves.
    """
    pending: deque = deque()
    newest = -1

    def due(now_ns: int) -> bool:
        topic, message = pending[0]
        return (
            topic != "sensors/scan"
            or message.stamp_ns <= newest
            or now_ns - message.stamp_ns > horizon_ns
        )

    for topic, message in messages:
        while pending and due(message.stamp_ns):  # held scans now past the horizon
            yield pending.popleft()
        if topic == "sensors/odom":
            newest = max(newest, message.stamp_ns)
            yield topic, message
        else:
            pending.append((topic, message))
        while pending and due(message.stamp_ns):
            yield pending.popleft()
    yield from pending


#: A stage that answers none of this many scans in a row is failing on each: stop the run.
GIVE_UP_SCANS = 3


def _why(why: str, procs, stages) -> str:
    tails = "; ".join(f"{s}: {procs.tail(s, 3)}" for s in stages)
    return f"{why}; {tails}"


if __name__ == "__main__":
    raise SystemExit(main())
