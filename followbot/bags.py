"""Reading recordings: followbot MCAP files, ROS 1 bags and ROS 2 bags, as one message stream.

:func:`open_recording` returns a :class:`Recording` whose :meth:`~Recording.messages` yields
``(log_time_ns, topic, message)`` in log-time order, ``topic`` being a followbot topic (after
remapping) and ``message`` a validated followbot message. ROS messages are converted:

=============================  ================================================
ROS type                       followbot message
=============================  ================================================
sensor_msgs/LaserScan          LaserScan
nav_msgs/Odometry              Odometry (yaw from the quaternion)
sensor_msgs/Image              Image (bgr8, rgb8 → bgr8, mono8)
sensor_msgs/CompressedImage    Image (jpeg kept as JPEG; png decoded to bgr8)
=============================  ================================================

A ROS header stamp of 0 (some recorders leave it unset) is replaced by the bag's receive time.
By default a ROS topic is mapped by its message type when that type has exactly one topic in
the file (``/scan`` → ``sensors/scan``); otherwise ``--remap SRC=DST`` says which. Messages
that fail conversion or validation are skipped and counted, never fatal.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from followbot.schemas import (
    TOPICS,
    Image,
    LaserScan,
    Message,
    Odometry,
    RejectedMessage,
    decode,
    topic_type,
)

__all__ = ["Recording", "RecordingError", "open_recording", "parse_remaps"]

#: ROS message type -> the followbot topic it feeds by default.
ROS_DEFAULT_TOPIC = {
    "sensor_msgs/msg/LaserScan": "sensors/scan",
    "nav_msgs/msg/Odometry": "sensors/odom",
    "sensor_msgs/msg/Image": "sensors/image",
    "sensor_msgs/msg/CompressedImage": "sensors/image",
}


class RecordingError(ValueError):
    """A file that cannot be replayed (unreadable, truncated, nothing to replay)."""


def parse_remaps(items: list[str]) -> dict[str, str]:
    """``["/scan=sensors/scan", ...]`` -> {source: followbot topic} (the target is checked)."""
    out = {}
    for item in items:
        src, sep, dst = item.partition("=")
        if not sep or not src or not dst:
            raise RecordingError(f"--remap expects SRC=DST, got {item!r}")
        topic_type(dst)  # ValueError listing the valid topics
        out[src] = dst
    return out


@dataclass
class Recording:
    """A readable recording and what it holds."""

    path: Path
    kind: str  # "mcap" | "ros"
    #: source topic -> followbot topic, for the topics that will be replayed
    mapping: dict[str, str]
    #: source topic -> (type name, message count) for everything in the file
    contents: dict[str, tuple[str, int]]
    skipped: Counter = field(default_factory=Counter)
    """Messages not replayed, by reason."""

    def messages(self) -> Iterator[tuple[int, str, Message]]:
        if self.kind == "mcap":
            yield from self._mcap_messages()
        else:
            yield from self._ros_messages()

    # ------------------------------------------------------------------ followbot MCAP

    def _mcap_messages(self) -> Iterator[tuple[int, str, Message]]:
        from mcap.exceptions import McapError
        from mcap.reader import make_reader

        n = 0
        with self.path.open("rb") as f:
            try:
                for _schema, channel, msg in make_reader(f).iter_messages(
                    topics=list(self.mapping)
                ):
                    dst = self.mapping[channel.topic]
                    try:
                        message = decode(topic_type(dst), msg.data)
                    except RejectedMessage:
                        self.skipped["invalid payload"] += 1
                        continue
                    n += 1
                    yield msg.log_time, dst, message
            except (McapError, EOFError, OSError, ValueError) as exc:
                raise RecordingError(
                    f"{self.path}: truncated or corrupt after {n} messages ({exc})"
                ) from None

    # ------------------------------------------------------------------ ROS bags

    def _ros_messages(self) -> Iterator[tuple[int, str, Message]]:
        from rosbags.highlevel import AnyReader

        try:
            with AnyReader([self.path]) as reader:
                conns = [c for c in reader.connections if c.topic in self.mapping]
                for conn, t_ns, raw in reader.messages(connections=conns):
                    try:
                        ros = reader.deserialize(raw, conn.msgtype)
                        message = convert(conn.msgtype, ros, t_ns)
                    except (ValueError, TypeError, KeyError, AttributeError) as exc:
                        self.skipped[f"{conn.topic}: {exc}"[:120]] += 1
                        continue
                    if message is None:
                        self.skipped[f"{conn.topic}: unsupported {conn.msgtype}"] += 1
                        continue
                    yield t_ns, self.mapping[conn.topic], message
        except RecordingError:
            raise
        except Exception as exc:  # rosbags raises its own error types per format
            raise RecordingError(f"{self.path}: cannot read the bag: {exc}") from None


def open_recording(path: str | Path, remaps: dict[str, str] | None = None) -> Recording:
    """Open ``path`` (followbot .mcap, ROS 1 .bag, or a ROS 2 bag folder) and plan the mapping."""
    path = Path(path)
    remaps = dict(remaps or {})
    if not path.exists():
        raise RecordingError(f"{path}: no such file or folder")
    if path.is_file() and path.suffix == ".mcap":
        return _open_mcap(path, remaps)
    if (path.is_file() and path.suffix == ".bag") or path.is_dir():
        return _open_ros(path, remaps)
    raise RecordingError(
        f"{path}: not a recording followbot reads (a followbot .mcap, a ROS 1 .bag, "
        "or a ROS 2 bag folder)"
    )


def _open_mcap(path: Path, remaps: dict[str, str]) -> Recording:
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with path.open("rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                # No index (the writer did not finish): count by streaming, which also finds
                # where the file breaks.
                contents, truncated = _scan_unindexed(path)
            else:
                counts = summary.statistics.channel_message_counts if summary.statistics else {}
                contents = {
                    ch.topic: (summary.schemas[ch.schema_id].name if ch.schema_id else "",
                               counts.get(ch.id, 0))
                    for ch in summary.channels.values()
                }  # fmt: skip
                foreign = [
                    ch.topic for ch in summary.channels.values() if ch.message_encoding != "msgpack"
                ]
                if foreign:
                    raise RecordingError(
                        f"{path}: channels {foreign} are not followbot messages (encoding "
                        "is not msgpack); for a ROS 2 MCAP bag pass its bag folder"
                    )
                truncated = False
    except (McapError, EOFError, OSError) as exc:
        raise RecordingError(f"{path}: not a readable MCAP file ({exc})") from None
    mapping = {}
    for src in contents:
        dst = remaps.pop(src, src)
        if dst in TOPICS or dst.startswith("health/"):
            mapping[src] = dst
    if remaps:
        raise RecordingError(
            f"{path}: no topic {sorted(remaps)} in the file; it has {sorted(contents)}"
        )
    if not mapping:
        raise RecordingError(f"{path}: no followbot topics in the file ({sorted(contents)})")
    rec = Recording(path, "mcap", mapping, contents)
    if truncated:
        rec.skipped["file truncated: messages after the break"] += 1
    return rec


def _scan_unindexed(path: Path) -> tuple[dict[str, tuple[str, int]], bool]:
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader

    counts: Counter = Counter()
    names: dict[str, str] = {}
    with path.open("rb") as f:
        try:
            for schema, channel, _msg in NonSeekingReader(f).iter_messages():
                counts[channel.topic] += 1
                names[channel.topic] = schema.name if schema else ""
        except (McapError, EOFError, ValueError):
            return {t: (names[t], n) for t, n in counts.items()}, True
    return {t: (names[t], n) for t, n in counts.items()}, False


def _open_ros(path: Path, remaps: dict[str, str]) -> Recording:
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:  # pragma: no cover - rosbags is a dependency
        raise RecordingError("reading ROS bags needs the rosbags package") from None
    try:
        with AnyReader([path]) as reader:
            contents = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
    except Exception as exc:
        raise RecordingError(f"{path}: cannot read the bag: {exc}") from None
    missing = sorted(set(remaps) - set(contents))
    if missing:
        raise RecordingError(
            f"{path}: no topic {missing} in the bag; it has: "
            + ", ".join(f"{t} ({ty})" for t, (ty, _) in sorted(contents.items()))
        )
    mapping = {}
    for src, (msgtype, _) in contents.items():
        if src in remaps:
            if msgtype not in ROS_DEFAULT_TOPIC:
                raise RecordingError(f"{src} is {msgtype}, which followbot cannot convert")
            mapping[src] = remaps[src]
    taken = set(mapping.values())
    by_type: dict[str, list[str]] = {}
    for src, (msgtype, _) in contents.items():
        if src not in mapping and msgtype in ROS_DEFAULT_TOPIC:
            by_type.setdefault(msgtype, []).append(src)
    for msgtype, srcs in by_type.items():
        dst = ROS_DEFAULT_TOPIC[msgtype]
        if dst in taken:
            continue
        if len(srcs) > 1:
            raise RecordingError(
                f"{path}: several {msgtype} topics ({', '.join(sorted(srcs))}); "
                f"say which feeds {dst} with --remap SRC={dst}"
            )
        mapping[srcs[0]] = dst
        taken.add(dst)
    if not mapping:
        raise RecordingError(
            f"{path}: nothing followbot can replay (it reads "
            f"{', '.join(sorted(ROS_DEFAULT_TOPIC))}); the bag has: "
            + ", ".join(f"{t} ({ty})" for t, (ty, _) in sorted(contents.items()))
        )
    return Recording(path, "ros", mapping, contents)


# --------------------------------------------------------------------------- conversions


def _stamp(header, fallback_ns: int) -> int:
    ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    return ns if ns > 0 else fallback_ns


def convert(msgtype: str, ros, t_ns: int) -> Message | None:
    """A deserialised ROS message as a followbot message (None for types it does not read)."""
    if msgtype == "sensor_msgs/msg/LaserScan":
        ranges = np.asarray(ros.ranges, dtype=np.float32)
        intens = np.asarray(ros.intensities, dtype=np.float32)
        return LaserScan.from_ranges(
            ranges,
            stamp_ns=_stamp(ros.header, t_ns),
            frame_id=ros.header.frame_id,
            angle_min_rad=float(ros.angle_min),
            angle_increment_rad=float(ros.angle_increment),
            range_min_m=float(ros.range_min),
            range_max_m=float(ros.range_max),
            intensities=intens if intens.shape == ranges.shape else None,
            scan_time_s=max(float(ros.scan_time), 0.0),
        )
    if msgtype == "nav_msgs/msg/Odometry":
        p, q = ros.pose.pose.position, ros.pose.pose.orientation
        yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        return Odometry(
            stamp_ns=_stamp(ros.header, t_ns),
            frame_id=ros.header.frame_id or "odom",
            child_frame_id=ros.child_frame_id or "base_link",
            x_m=float(p.x),
            y_m=float(p.y),
            yaw_rad=yaw,
            v_mps=float(ros.twist.twist.linear.x),
            w_radps=float(ros.twist.twist.angular.z),
        )
    if msgtype == "sensor_msgs/msg/Image":
        return _raw_image(ros, t_ns)
    if msgtype == "sensor_msgs/msg/CompressedImage":
        return _compressed_image(ros, t_ns)
    return None


def _raw_image(ros, t_ns: int) -> Image:
    h, w, step = int(ros.height), int(ros.width), int(ros.step)
    channels = {"bgr8": 3, "rgb8": 3, "mono8": 1}.get(ros.encoding)
    if channels is None:
        raise ValueError(f"image encoding {ros.encoding!r} (reads bgr8, rgb8, mono8)")
    rows = np.asarray(ros.data, dtype=np.uint8).reshape(h, step)[:, : w * channels]
    pixels = rows.reshape(h, w, channels) if channels == 3 else rows.reshape(h, w)
    if ros.encoding == "rgb8":
        pixels = pixels[:, :, ::-1]
    return Image.from_array(pixels, stamp_ns=_stamp(ros.header, t_ns), frame_id=ros.header.frame_id)


def _compressed_image(ros, t_ns: int) -> Image:
    import cv2

    data = np.asarray(ros.data, dtype=np.uint8)
    pixels = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if pixels is None:
        raise ValueError("corrupt compressed image")
    stamp = _stamp(ros.header, t_ns)
    img = Image.from_array(pixels, stamp_ns=stamp, frame_id=ros.header.frame_id)
    if "jpeg" in ros.format.lower() or "jpg" in ros.format.lower():
        img.encoding = "jpeg"
        img.data = memoryview(data.tobytes())
    return img
