"""``followbot record`` and ``followbot replay``.

Record writes chosen topics to MCAP (the log format Foxglove and ROS 2 read): one channel per
followbot topic, message encoding ``msgpack`` (the exact validated wire bytes), the message's
JSON Schema as the channel schema (encoding ``jsonschema``), ``log_time`` = receive time (wall
clock, ns), ``publish_time`` = the message's ``stamp_ns``. File metadata ``followbot`` holds the
robot name, the followbot version and the schema version. Chunks are flushed to the file at
least every half second, so a recorder killed outright loses at most that. See
docs/recording.md.

Replay republishes a followbot MCAP, a ROS 1 bag, a ROS 2 bag folder or a CARMEN log with the
original timing (``--rate`` multiplier, ``--rate 0`` as fast as possible), remapping topics and
converting ROS and CARMEN messages (followbot.bags, followbot.carmen). It sends the sensor
topics only unless told otherwise, and reads a damaged file up to the damage.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from followbot import progress
from followbot.services.runtime.argtypes import non_negative_float, positive_float

__all__ = ["record_main", "replay_main"]

#: The recorder ends a chunk and writes it out at least this often (s): a recorder killed
#: outright loses the messages of at most the last FLUSH_PERIOD_S (+ a timer tick).
FLUSH_PERIOD_S = 0.5


def _node_settings(args: argparse.Namespace, *, paced_by_source: bool = False):
    """``paced_by_source``: the node's inputs answer a source that sets its own pace (a
    lock-step replay), so a gap between their stamps is no stamp from the future."""
    from followbot.services.runtime.session import overrides_from_args
    from followbot.services.runtime.settings import NodeSettings, load_settings

    overrides = [*overrides_from_args(args), "log_level=warning"]
    if paced_by_source:
        overrides.append("clock.max_ahead_s=null")
    return load_settings(NodeSettings, None, overrides)


# ----------------------------------------------------------------------------- record


def record_main(argv: list[str] | None = None) -> int:
    from followbot.schemas import TOPICS
    from followbot.services.runtime.session import SessionError, add_zenoh_arguments

    p = argparse.ArgumentParser(
        prog="followbot record",
        description="Record followbot topics to an MCAP file (Ctrl-C or --duration stops).",
    )
    p.add_argument(
        "topics",
        nargs="*",
        help="topics to record (default: every data topic; `followbot topics` lists them)",
    )
    p.add_argument("-o", "--output", default="recording.mcap", help="MCAP file to write")
    p.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds")
    add_zenoh_arguments(p)
    args = p.parse_args(argv)
    topics = args.topics or list(TOPICS)
    try:
        settings = _node_settings(args)
        from followbot.schemas import topic_type

        for t in topics:
            topic_type(t)
    except ValueError as exc:
        print(f"followbot record: {exc}", file=sys.stderr)
        return 2
    try:
        return _record(topics, Path(args.output), args.duration, settings)
    except SessionError as exc:
        print(f"followbot record: {exc}", file=sys.stderr)
        return 1


def _record(topics: list[str], output: Path, duration: float | None, settings) -> int:
    from followbot.mcapio import McapTopicWriter
    from followbot.services.runtime.node import zenoh_node

    with zenoh_node("record", settings) as node:
        out = McapTopicWriter(output, settings.robot, flush_period_s=FLUSH_PERIOD_S)
        try:
            for t in topics:
                node.subscribe(
                    t,
                    lambda m, payload, t=t: out.write(t, payload, m.stamp_ns, time.time_ns()),
                    with_payload=True,
                )
            t0 = time.monotonic()

            def show() -> None:
                total = sum(out.counts.values())
                size = out.size_bytes() / 2**20
                progress.show(f"  recording {time.monotonic() - t0:6.1f} s  {total} messages  "
                               f"{size:.1f} MiB")  # fmt: skip

            node.every(1.0, show, name="progress")
            # a quiet topic's last messages reach the file within a flush period too
            node.every(FLUSH_PERIOD_S / 2, out.flush_if_due, name="flush")
            print(f"recording {len(topics)} topics of robot '{settings.robot}' to {output}; "
                  "Ctrl-C stops", file=sys.stderr)  # fmt: skip
            node.run(duration)
            node.close()  # no more callbacks before the file is finished
        finally:
            out.close()
    progress.finish()
    elapsed = time.monotonic() - t0
    print(f"wrote {output} ({output.stat().st_size / 2**20:.2f} MiB, {elapsed:.1f} s)")
    for t in topics:
        n = out.counts.get(t, 0)
        if n:
            print(f"  {t:<28} {n:>8} messages  {n / max(elapsed, 1e-9):8.1f} Hz")
    silent = [t for t in topics if not out.counts.get(t)]
    if silent:
        print(f"  no messages on: {', '.join(silent)}")
    return 0


# ----------------------------------------------------------------------------- replay


def replay_main(argv: list[str] | None = None) -> int:
    from followbot.bags import RecordingError, open_recording, parse_remaps
    from followbot.services.runtime.session import SessionError, add_zenoh_arguments

    p = argparse.ArgumentParser(
        prog="followbot replay",
        description=(
            "Republish a recording: a followbot .mcap, a ROS 1 .bag, a ROS 2 bag folder or a "
            "CARMEN log (.log, .clf, gzipped or not). ROS LaserScan, Odometry, Image and "
            "CompressedImage are converted, and so are CARMEN laser and odometry records."
        ),
        epilog=REPLAY_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("file", help="the recording")
    p.add_argument(
        "--rate", type=non_negative_float, default=1.0,
        help="speed multiplier of the original timing; 0 = as fast as possible (1)",
    )  # fmt: skip
    p.add_argument(
        "--remap", action="append", default=[], metavar="SRC=DST",
        help="feed source topic SRC to followbot topic DST, e.g. /scan=sensors/scan",
    )  # fmt: skip
    which = p.add_mutually_exclusive_group()
    which.add_argument(
        "--topics", action="append", metavar="PATTERN[,PATTERN...]",
        help="replay only these topics (glob patterns, comma-separated or repeated, matched "
        "against the file's topic or the followbot topic it feeds; default: sensors/*)",
    )  # fmt: skip
    which.add_argument(
        "--all-topics", action="store_true",
        help="replay every topic of the file, recorded commands and tracks included",
    )  # fmt: skip
    p.add_argument(
        "--exclude", action="append", default=[], metavar="PATTERN[,PATTERN...]",
        help="leave these topics out (glob patterns, as --topics)",
    )  # fmt: skip
    p.add_argument(
        "--wait", type=non_negative_float, default=5.0, metavar="S",
        help="wait up to S seconds for a subscriber before starting (5)",
    )  # fmt: skip
    p.add_argument(
        "--lockstep", action="store_true",
        help="after each scan, wait for every running stage's answer to it (docs/runtime.md)",
    )  # fmt: skip
    p.add_argument(
        "--timeout", type=positive_float, default=5.0, metavar="S",
        help="lock-step: seconds to wait for the stages' answers to one scan (5)",
    )  # fmt: skip
    p.add_argument(
        "--info", action="store_true",
        help="print what the file holds and what would be replayed, then exit",
    )  # fmt: skip
    add_zenoh_arguments(p)
    args = p.parse_args(argv)
    try:
        rec = open_recording(args.file, parse_remaps(args.remap))
        include = None if not args.topics else _patterns(args.topics)
        rec.select(["*"] if args.all_topics else include, _patterns(args.exclude))
    except (RecordingError, ValueError) as exc:
        print(f"followbot replay: {exc}", file=sys.stderr)
        return 2
    print(f"{rec.path} ({rec.kind}):", file=sys.stderr)
    for src, (type_name, n) in sorted(rec.contents.items()):
        dst = rec.mapping.get(src)
        arrow = f"-> {dst}" if dst else f"skipped: {rec.left_out.get(src, 'not replayed')}"
        print(f"  {src:<28} {type_name:<32} {n:>7}  {arrow}", file=sys.stderr)
    print(f"replaying {', '.join(sorted(rec.mapping))}"
          + (f"; skipping {', '.join(sorted(rec.left_out))}" if rec.left_out else ""),
          file=sys.stderr)  # fmt: skip
    if rec.damage is not None:
        print(f"warning: {rec.path} is damaged: {rec.damage.describe()}; replaying what was "
              "read", file=sys.stderr)  # fmt: skip
    for warning in rec.warnings:
        print(f"warning: {rec.path}: {warning}", file=sys.stderr)
    if args.info:
        return 0
    try:
        return _replay(rec, args)
    except SessionError as exc:
        print(f"followbot replay: {exc}", file=sys.stderr)
        return 1


REPLAY_EPILOG = """\
which topics:
  By default only sensor input is replayed (sensors/scan, sensors/image, sensors/odom):
  replay usually feeds a live pipeline, which makes its own candidates, tracks and commands.
  Replaying the recorded tracking/target or control/cmd_vel as well would give its controller
  and the robot two command streams. --topics chooses others (e.g. --topics 'sensors/*,sim/*'),
  --all-topics replays everything (into a system where nothing else publishes), --exclude
  leaves topics out. The list printed at the start says what is replayed and what is skipped.

CARMEN logs:
  A CARMEN log has no topics: its sources are its record names (FLASER, RLASER, ROBOTLASER1,
  RAWLASER1..4, ODOM) and NAME/odom for the odometry fields of a laser record (FLASER/odom).
  By default the front laser (ROBOTLASER1, else FLASER, else RAWLASER1, else the only laser)
  feeds sensors/scan and its odometry fields sensors/odom; --remap ODOM=sensors/odom takes the
  ODOM lines instead. docs/recording.md, "CARMEN logs", says more.
  Lines that cannot be read are skipped and counted (a warning says how many, why, where).

damaged files:
  A recording cut short (a recorder killed, a full disk, an interrupted copy) or damaged
  part-way is replayed up to the damage, with a warning saying how much was read and why it
  stopped; the exit code is 0. A file with nothing readable is an error (exit 2).
"""


def _patterns(items: list[str]) -> list[str]:
    """``["a,b", "c"]`` -> ``["a", "b", "c"]`` (comma-separated or repeated options)."""
    return [p.strip() for item in items for p in item.split(",") if p.strip()]


def _replay(rec, args: argparse.Namespace) -> int:
    from followbot.bags import RecordingError
    from followbot.services.runtime.node import zenoh_node

    settings = _node_settings(args, paced_by_source=args.lockstep)
    total = sum(n for src, (_, n) in rec.contents.items() if src in rec.mapping)
    sent = 0
    with zenoh_node("replay", settings) as node:
        # every sample matters in a replay: block rather than drop under congestion
        pubs = {t: node.publisher(t, reliable=True) for t in set(rec.mapping.values())}
        barrier = None
        if args.lockstep:
            from followbot.services.runtime.lockstep import STAGE_OUTPUT, LockstepBarrier

            barrier = LockstepBarrier(node, list(STAGE_OUTPUT))
            time.sleep(1.0)  # liveliness of the running stages arrives
            running = barrier.alive()
            print(f"  lock-step with: {', '.join(running) or 'no stage (nothing to wait for)'}",
                  file=sys.stderr)  # fmt: skip
        if args.wait > 0:
            deadline = time.monotonic() + args.wait
            while not any(p.matching() for p in pubs.values()) and time.monotonic() < deadline:
                time.sleep(0.02)
        t_wall0 = time.monotonic()
        t_log0 = None
        last_shown = 0.0
        error = None
        stop: list[int] = []
        previous = {
            sig: signal.signal(sig, lambda signum, _f: stop.append(signum))
            for sig in (signal.SIGINT, signal.SIGTERM)
        }
        try:
            for log_ns, topic, message in rec.messages():
                if t_log0 is None:
                    t_log0 = log_ns
                if args.rate > 0:
                    due = t_wall0 + (log_ns - t_log0) / 1e9 / args.rate
                    while not stop and (delay := due - time.monotonic()) > 0:
                        time.sleep(min(delay, 0.1))
                if stop:
                    error = "stopped by signal"
                    break
                pubs[topic].put(message)  # numbered afresh by the replay's publisher
                sent += 1
                if barrier is not None and topic == "sensors/scan":
                    barrier.wait(message.stamp_ns, args.timeout)
                now = time.monotonic()
                if now - last_shown > 1.0:
                    last_shown = now
                    progress.show(f"  replayed {sent}/{total} messages")
        except RecordingError as exc:
            error = str(exc)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    progress.finish()
    elapsed = time.monotonic() - t_wall0
    print(f"replayed {sent} messages in {elapsed:.1f} s")
    for reason, n in rec.skipped.most_common():
        print(f"  skipped {n}: {reason}")
    for warning in rec.warnings:
        print(f"warning: {rec.path}: {warning}", file=sys.stderr)
    if rec.damage is not None and error is None:
        print(f"warning: {rec.path} is damaged: {rec.damage.describe()}", file=sys.stderr)
    if barrier is not None and any(barrier.timeouts.values()):
        late = {s: n for s, n in barrier.timeouts.items() if n}
        print(f"  lock-step: scans a stage did not answer within {args.timeout:.0f} s: {late}")
    if error:
        print(f"followbot replay: {error}", file=sys.stderr)
        return 1
    return 0
