"""Reading recordings: followbot MCAP files, ROS 1 and ROS 2 bags, CARMEN logs, as one stream.

:func:`open_recording` returns a :class:`Recording` whose :meth:`~Recording.messages` yields
``(log_time_ns, topic, message)`` in log-time order (an MCAP without its index: in the order
the recorder wrote them), ``topic`` being a followbot topic (after remapping) and ``message`` a
validated followbot message. ROS messages are converted:

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

CARMEN logs (followbot.carmen) have no topics: their sources are record names (``FLASER``,
``ODOM``, ``ROBOTLASER1``, ``FLASER/odom`` for a laser record's odometry fields); by default the
front laser feeds ``sensors/scan`` and its odometry fields ``sensors/odom``.

A damaged MCAP (cut short, a recorder killed, a bad chunk) is read up to the damage, and so
is a ROS 1 bag whose index is missing or cut (:class:`Ros1Stream`) and a gzipped CARMEN log
cut short: :attr:`Recording.damage` then says how much was read and why it stopped.
:attr:`Recording.warnings` says what else the user must know (a CARMEN log's unreadable
lines, its restamped scans).
:meth:`Recording.select` narrows what is replayed (by default to the sensor topics).
"""

from __future__ import annotations

import itertools
import math
import struct
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path

import numpy as np

from followbot.carmen import CarmenLog
from followbot.mcapio import Damage
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

__all__ = [
    "SENSOR_PATTERNS",
    "Recording",
    "RecordingError",
    "Ros1Stream",
    "open_recording",
    "parse_remaps",
]

#: What a replay sends by default: sensor input only. A live pipeline makes its own
#: perception, tracking and commands; replaying recorded ones would double them.
SENSOR_PATTERNS = ("sensors/*",)

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
    kind: str  # "mcap" | "ros" | "carmen"
    #: source topic -> followbot topic, for the topics that will be replayed
    mapping: dict[str, str]
    #: source topic -> (type name, message count) for everything in the file (of a damaged
    #: file: what can be read)
    contents: dict[str, tuple[str, int]]
    skipped: Counter = field(default_factory=Counter)
    """Messages not replayed, by reason."""
    left_out: dict[str, str] = field(default_factory=dict)
    """Source topics not replayed: why, one line each."""
    damage: Damage | None = None
    """Where the file stops being readable: known on opening a file read without its index,
    else found (and set) by :meth:`messages` when it reaches the damage."""
    indexed: bool = True
    """The file's index is intact and read through (MCAP: in log-time order); else the file
    is read front to back."""
    index_problem: str = ""
    """Why the index of a ROS 1 bag read front to back could not be used."""
    warnings: list[str] = field(default_factory=list)
    """What the user must know about the file besides damage, one line each."""
    carmen: CarmenLog | None = field(default=None, repr=False)
    """The reader of a CARMEN log (read once on opening)."""

    def select(self, include: list[str] | None = None, exclude: list[str] | None = None) -> None:
        """Replay only the topics matching a pattern of ``include`` (default
        :data:`SENSOR_PATTERNS`) and none of ``exclude``.

        A pattern (``fnmatch``: ``*``, ``?``, ``[...]``) matches a topic when it matches its
        source name or the followbot topic it feeds. A pattern of ``include`` that matches no
        topic of the file is an error (a typo would otherwise replay nothing of it).
        """
        patterns = list(include) if include is not None else list(SENSOR_PATTERNS)

        def matches(pattern: str, src: str) -> bool:
            return fnmatchcase(src, pattern) or fnmatchcase(self.mapping[src], pattern)

        if include is not None:
            for pattern in patterns:
                if not any(matches(pattern, src) for src in self.mapping):
                    raise RecordingError(
                        f"{self.path}: --topics {pattern!r} matches no topic the file can "
                        f"replay; it has: {', '.join(sorted(self.mapping)) or 'none'}"
                    )
        for src in list(self.mapping):
            if not any(matches(p, src) for p in patterns):
                self.left_out[src] = (
                    "not sensor input (a live pipeline makes its own; --topics or "
                    "--all-topics replays it)"
                    if include is None
                    else "not chosen by --topics"
                )
            elif any(matches(p, src) for p in exclude or []):
                self.left_out[src] = "--exclude"
            else:
                continue
            del self.mapping[src]
        if not self.mapping:
            raise RecordingError(
                f"{self.path}: nothing left to replay: "
                + "; ".join(f"{src}: {why}" for src, why in sorted(self.left_out.items()))
            )

    def messages(self) -> Iterator[tuple[int, str, Message]]:
        if self.kind == "mcap":
            yield from self._mcap_messages()
        elif self.kind == "carmen":
            yield from self._carmen_messages()
        else:
            yield from self._ros_messages()

    # ------------------------------------------------------------------ followbot MCAP

    def _mcap_messages(self) -> Iterator[tuple[int, str, Message]]:
        from followbot.mcapio import McapStream

        if not self.indexed:
            stream = McapStream(self.path)
            for topic, _schema, msg in stream.messages(self.mapping):
                message = self._decoded(topic, msg.data)
                if message is not None:
                    yield msg.log_time, self.mapping[topic], message
            self.damage = stream.damage
            return
        from mcap.reader import SeekingReader

        n, first, last = 0, None, None
        with self.path.open("rb") as f:
            items = SeekingReader(f, validate_crcs=True).iter_messages(topics=list(self.mapping))
            while True:
                try:
                    _schema, channel, msg = next(items)
                except StopIteration:
                    return
                except Exception as exc:  # the parser's own errors, struct, zstd, ... on bad bytes
                    size = self.path.stat().st_size
                    why = f"a damaged chunk ({type(exc).__name__}: {exc})"
                    self.damage = Damage(why, n, first, last, size)
                    return
                n += 1
                first = msg.log_time if first is None else min(first, msg.log_time)
                last = msg.log_time if last is None else max(last, msg.log_time)
                message = self._decoded(channel.topic, msg.data)
                if message is not None:
                    yield msg.log_time, self.mapping[channel.topic], message

    def _decoded(self, src: str, data: bytes) -> Message | None:
        try:
            return decode(topic_type(self.mapping[src]), data)
        except RejectedMessage:
            self.skipped["invalid payload"] += 1
            return None

    # ------------------------------------------------------------------ CARMEN logs

    def _carmen_messages(self) -> Iterator[tuple[int, str, Message]]:
        def late(record: str) -> None:
            what = "line" if record == "ODOM" else "scan"
            for src in self.mapping:
                if src.removesuffix("/odom") == record:
                    why = f"{src}: stamped 0 or no later than an earlier {record} {what}"
                    self.skipped[why] += 1

        for stamp, src, message in self.carmen.messages(list(self.mapping), late):
            yield stamp, self.mapping[src], message

    # ------------------------------------------------------------------ ROS bags

    def _ros_messages(self) -> Iterator[tuple[int, str, Message]]:
        if not self.indexed:
            yield from self._ros1_stream_messages()
            return
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

    def _ros1_stream_messages(self) -> Iterator[tuple[int, str, Message]]:
        from rosbags.typesys import Stores, get_typestore

        # the standard message definitions (the bag's own are in the index, which is gone)
        store = get_typestore(Stores.ROS1_NOETIC)
        stream = Ros1Stream(self.path, why_not_indexed=self.index_problem)
        for topic, msgtype, t_ns, raw in stream.messages(self.mapping):
            try:
                message = convert(msgtype, store.deserialize_ros1(raw, msgtype), t_ns)
            except Exception as exc:  # a definition that differs, bytes that do not parse
                self.skipped[f"{topic}: {type(exc).__name__}: {exc}"[:120]] += 1
                continue
            if message is None:
                self.skipped[f"{topic}: unsupported {msgtype}"] += 1
                continue
            yield t_ns, self.mapping[topic], message
        self.damage = stream.damage


def open_recording(path: str | Path, remaps: dict[str, str] | None = None) -> Recording:
    """Open ``path`` (followbot .mcap, ROS 1 .bag, a ROS 2 bag folder, or a CARMEN log) and
    plan the mapping."""
    from followbot.carmen import CARMEN_SUFFIXES, looks_like_carmen

    path = Path(path)
    remaps = dict(remaps or {})
    if not path.exists():
        raise RecordingError(f"{path}: no such file or folder")
    if path.is_file() and path.suffix == ".mcap":
        return _open_mcap(path, remaps)
    if (path.is_file() and path.name.endswith((".bag", ".bag.active"))) or path.is_dir():
        return _open_ros(path, remaps)
    if path.name.endswith(CARMEN_SUFFIXES) or looks_like_carmen(path):
        return _open_carmen(path, remaps)
    raise RecordingError(
        f"{path}: not a recording followbot reads (a followbot .mcap, a ROS 1 .bag, "
        "a ROS 2 bag folder, or a CARMEN .log/.clf, gzipped or not)"
    )


def _open_mcap(path: Path, remaps: dict[str, str]) -> Recording:
    from mcap.reader import SeekingReader

    from followbot.mcapio import McapStream, check_magic

    problem = check_magic(path)
    if problem:
        raise RecordingError(f"{path}: not a readable MCAP file ({problem})")
    try:
        with path.open("rb") as f:
            summary = SeekingReader(f).get_summary()
    except Exception:  # cut short or damaged at the end: no index to trust, read front to back
        summary = None
    damage = None
    indexed = summary is not None and bool(summary.chunk_indexes)
    if indexed:
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        contents = {
            ch.topic: (summary.schemas[ch.schema_id].name if ch.schema_id else "",
                       counts.get(ch.id, 0))
            for ch in summary.channels.values()
        }  # fmt: skip
        encodings = {ch.topic: ch.message_encoding for ch in summary.channels.values()}
    else:
        # No index (the writer did not finish, or the file was cut): count by streaming,
        # which also finds where the file breaks.
        stream = McapStream(path)
        counts = Counter(topic for topic, _, _ in stream.messages())
        contents = {t: (schema, counts[t]) for t, (schema, _) in stream.channels.items()}
        encodings = {t: enc for t, (_, enc) in stream.channels.items()}
        damage = stream.damage
        if damage is not None and not damage.messages:
            raise RecordingError(f"{path}: no message could be read: {damage.reason}")
    foreign = sorted(t for t, enc in encodings.items() if enc != "msgpack")
    if foreign:
        raise RecordingError(
            f"{path}: channels {foreign} are not followbot messages (encoding "
            "is not msgpack); for a ROS 2 MCAP bag pass its bag folder"
        )
    mapping, left_out = {}, {}
    for src in contents:
        dst = remaps.pop(src, src)
        if dst in TOPICS or dst.startswith("health/"):
            mapping[src] = dst
        else:
            left_out[src] = "not a followbot topic"
    if remaps:
        raise RecordingError(
            f"{path}: no topic {sorted(remaps)} in the file; it has {sorted(contents)}"
        )
    if not mapping:
        raise RecordingError(f"{path}: no followbot topics in the file ({sorted(contents)})")
    return Recording(path, "mcap", mapping, contents, left_out=left_out, damage=damage,
                     indexed=indexed)  # fmt: skip


def _open_ros(path: Path, remaps: dict[str, str]) -> Recording:
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:  # pragma: no cover - rosbags is a dependency
        raise RecordingError("reading ROS bags needs the rosbags package") from None
    damage, index_problem = None, ""
    try:
        with AnyReader([path]) as reader:
            contents = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
    except Exception as exc:
        if not path.is_file():
            raise RecordingError(f"{path}: cannot read the bag: {exc}") from None
        # A ROS 1 bag whose index is missing (a recorder killed: .bag.active) or cut off:
        # read it front to back instead, up to where it breaks.
        index_problem = str(exc)
        stream = Ros1Stream(path, why_not_indexed=index_problem)
        counts = Counter(topic for topic, _, _, _ in stream.messages())
        contents = {t: (msgtype, counts[t]) for t, msgtype in stream.connections.items()}
        damage = stream.damage
        if damage is not None and not damage.messages:
            raise RecordingError(f"{path}: no message could be read: {damage.reason}") from None
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
    left_out = {
        src: f"no conversion of {msgtype} to a followbot message"
        if msgtype not in ROS_DEFAULT_TOPIC
        else f"another {msgtype} topic feeds {ROS_DEFAULT_TOPIC[msgtype]}"
        for src, (msgtype, _) in contents.items()
        if src not in mapping
    }
    return Recording(path, "ros", mapping, contents, left_out=left_out, damage=damage,
                     indexed=damage is None, index_problem=index_problem)  # fmt: skip


def _open_carmen(path: Path, remaps: dict[str, str]) -> Recording:
    from followbot.carmen import DEFAULT_SCAN_SOURCES, NOT_CONVERTED, CarmenLog

    try:
        log = CarmenLog(path)
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read the file: {exc}") from None
    if not log.contents:
        found = [f"{n} {name}" for name, n in (log.not_converted + log.unknown).most_common(8)]
        what = f"it has {', '.join(found)}" if found else "no records at all"
        bad = f"; {log.bad.describe()}" if log.bad.total else ""
        why = f"; {log.damage.describe()}" if log.damage else ""
        raise RecordingError(f"{path}: no CARMEN laser or odometry records ({what}){bad}{why}")

    def clock(src: str) -> str:
        """Sources replayed together must share a clock: the file's, or a restamped laser's."""
        record = src.removesuffix("/odom")
        return record if record in log.restamped else "the log's clock"

    missing = sorted(set(remaps) - set(log.contents))
    if missing:
        raise RecordingError(
            f"{path}: no source {missing} in the CARMEN log; it has: "
            + ", ".join(f"{s} ({ty})" for s, (ty, _) in sorted(log.contents.items()))
        )
    mapping: dict[str, str] = {}
    for src, dst in remaps.items():
        want, have = topic_type(dst).__name__, log.source_type(src)
        if want != have:
            raise RecordingError(f"{path}: {src} gives {have}; {dst} takes {want}")
        mapping[src] = dst
    taken = set(mapping.values())
    if "sensors/scan" not in taken:
        lasers = [s for s, (ty, _) in log.contents.items() if ty == "LaserScan"]
        scan = next((s for s in DEFAULT_SCAN_SOURCES if s in log.contents), None)
        if scan is None and len(lasers) == 1:  # a log of one other laser (RLASER, say)
            scan = lasers[0]
        if scan is not None:
            mapping[scan] = "sensors/scan"
    clocks = {clock(s) for s in mapping}
    if len(clocks) > 1:
        raise RecordingError(
            f"{path}: {', '.join(sorted(mapping))} cannot be replayed together: "
            + "; ".join(f"{name}: {why}" for name, why in log.restamped.items())
            + ", so the other records' stamps are on another clock"
        )
    if "sensors/odom" not in taken:
        scans = [s for s, d in mapping.items() if d == "sensors/scan"]
        odom = [f"{s}/odom" for s in scans if f"{s}/odom" in log.contents] + ["ODOM"]
        odom = [s for s in odom if s in log.contents and (not clocks or clock(s) in clocks)]
        if odom:
            mapping[odom[0]] = "sensors/odom"
    if not mapping:
        raise RecordingError(
            f"{path}: no default source for sensors/scan or sensors/odom; say which with "
            f"--remap SRC=DST; it has: "
            + ", ".join(f"{s} ({ty})" for s, (ty, _) in sorted(log.contents.items()))
        )
    contents = dict(log.contents)
    left_out = {}
    for src, (type_name, _) in log.contents.items():
        if src in mapping:
            continue
        dst = "sensors/scan" if type_name == "LaserScan" else "sensors/odom"
        if clock(src) not in {clock(s) for s in mapping}:
            left_out[src] = (
                "its stamps are on another clock than the replayed sources' (restamped "
                "scans: see the warning)"
            )
        elif dst in mapping.values():
            feeds = next(s for s, d in mapping.items() if d == dst)
            left_out[src] = f"{feeds} feeds {dst} (--remap {src}={dst} chooses this one)"
        else:
            left_out[src] = f"not replayed (--remap {src}={dst} replays it)"
    for name, n in log.not_converted.items():
        contents[name] = ("-", n)
        left_out[name] = f"{NOT_CONVERTED[name]}: no followbot message carries them"
    for name, n in log.unknown.items():
        contents[name] = ("-", n)
        left_out[name] = "not a CARMEN record followbot knows; ignored"
    warnings = [f"{name}: {why}" for name, why in log.restamped.items()]
    if log.bad.total:
        warnings.append(log.bad.describe())
    return Recording(path, "carmen", mapping, contents, left_out=left_out, damage=log.damage,
                     warnings=warnings, carmen=log)  # fmt: skip


# --------------------------------------------------------------------------- ROS 1, no index

ROS1_MAGIC = b"#ROSBAG V2.0\n"
_OP_MESSAGE, _OP_BAG_HEADER, _OP_CHUNK, _OP_CONNECTION = 0x02, 0x03, 0x05, 0x07


class _Cut(EOFError):
    """The bytes end inside a record."""


class Ros1Stream:
    """A ROS 1 bag (format 2.0) read front to back without its index, up to the first record
    it cannot read.

    For bags ``rosbags`` refuses because the index at the end is missing (``rosbag record``
    killed leaves a ``.bag.active`` never indexed) or cut off. A bag is a sequence of
    records, each a header of ``name=value`` fields (``op`` says which record) and a data
    block; chunks (compressed ``none``, ``bz2`` or ``lz4``) hold connection records (topic,
    type) and message records (connection, time, serialized message). :meth:`messages` yields
    the messages in file order and then sets :attr:`damage` (always, as the index is unusable).
    """

    def __init__(self, path: Path, why_not_indexed: str = "") -> None:
        self.path = path
        self.why_not_indexed = why_not_indexed
        self.damage: Damage | None = None
        #: topic -> ROS message type (``sensor_msgs/msg/LaserScan``) of every connection met
        self.connections: dict[str, str] = {}

    def messages(self, topics=None) -> Iterator[tuple[str, str, int, bytes]]:
        """``(topic, ROS message type, receive time ns, serialized message)`` of ``topics``."""
        size = self.path.stat().st_size
        conns: dict[int, tuple[str, str]] = {}
        n, first, last = 0, None, None
        index_pos = 0
        cut = ""
        with self.path.open("rb") as f:
            if f.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
                raise RecordingError(f"{self.path}: not a ROS 1 bag of format 2.0 (bad magic)")
            good = f.tell()
            while f.tell() < size and not cut:
                try:
                    header, data, cut = _ros1_record(f)
                    op = _ros1_op(header)
                    if op == _OP_BAG_HEADER:
                        index_pos = struct.unpack("<Q", header["index_pos"])[0]
                    if op == _OP_CHUNK:
                        # an uncompressed chunk cut short still holds whole records up to the cut
                        if cut and header["compression"] != b"none":
                            raise _Cut(cut)
                        records = list(_ros1_records(_ros1_chunk_data(header, data), bool(cut)))
                    elif cut:
                        raise _Cut(cut)
                    else:
                        records = [(header, data)]
                    out = []
                    for h, d in records:
                        op = _ros1_op(h)
                        if op == _OP_CONNECTION:
                            topic = h["topic"].decode()
                            msgtype = _ros2_name(_ros1_fields(d)["type"].decode())
                            conns[struct.unpack("<I", h["conn"])[0]] = (topic, msgtype)
                            self.connections[topic] = msgtype
                        elif op == _OP_MESSAGE:
                            topic, msgtype = conns.get(struct.unpack("<I", h["conn"])[0], ("", ""))
                            if topic and (topics is None or topic in topics):
                                sec, nsec = struct.unpack("<II", h["time"])
                                out.append((topic, msgtype, sec * 1_000_000_000 + nsec, d))
                except Exception as exc:  # struct, bz2, lz4, KeyError, ... on bad bytes
                    why = _ros1_why_it_stopped(exc, f.tell(), good, size, index_pos)
                    self.damage = Damage(why, n, first, last, size, good)
                    return
                if not cut:
                    good = f.tell()
                for item in out:
                    n += 1
                    first = item[2] if first is None else min(first, item[2])
                    last = item[2] if last is None else max(last, item[2])
                    yield item
        if cut:
            why = (
                f"the file ends inside an uncompressed chunk (at byte {size}): it was cut short "
                "(a recorder killed mid-write, a full disk or an interrupted copy); the messages "
                "before the cut were read"
            )
        elif index_pos == 0:
            why = (
                "the bag was never indexed: its recorder did not finish it (a killed "
                "`rosbag record` leaves such a .bag.active); every message was read"
            )
        elif index_pos >= size:
            why = "the file ends before the bag's index: it was cut short at a record boundary"
        else:
            why = f"the bag's index is unusable ({self.why_not_indexed}); every message was read"
        self.damage = Damage(why, n, first, last, size, size if cut else good)


def _ros1_fields(buf: bytes) -> dict[str, bytes]:
    """A record header (or connection header): fields of ``<uint32 length>name=value``."""
    out, i = {}, 0
    while i < len(buf):
        (length,) = struct.unpack_from("<I", buf, i)
        i += 4
        if i + length > len(buf):
            raise ValueError("a header field runs past the end of its header")
        name, eq, value = buf[i : i + length].partition(b"=")
        if not eq:
            raise ValueError("a header field without '='")
        out[name.decode()] = value
        i += length
    return out


def _ros1_read(f, length: int) -> bytes:
    data = f.read(length)
    if len(data) < length:
        raise _Cut(f"{length - len(data)} bytes missing")
    return data


def _ros1_record(f) -> tuple[dict[str, bytes], bytes, str]:
    """One record: header fields, data, and why the data is short ("" when whole). A cut in
    the header or the lengths raises :class:`_Cut`; a cut in the data returns what is there."""
    (header_len,) = struct.unpack("<I", _ros1_read(f, 4))
    header = _ros1_fields(_ros1_read(f, header_len))
    (data_len,) = struct.unpack("<I", _ros1_read(f, 4))
    data = f.read(data_len)
    return header, data, f"{data_len - len(data)} bytes missing" if len(data) < data_len else ""


def _ros1_records(data: bytes, partial: bool) -> Iterator[tuple[dict[str, bytes], bytes]]:
    """The records of a chunk's data; ``partial``: the data was cut, stop at the cut."""
    import io

    buf = io.BytesIO(data)
    while buf.tell() < len(data):
        try:
            header, body, cut = _ros1_record(buf)
            if cut:
                raise _Cut(cut)
        except _Cut:
            if partial:
                return
            raise ValueError("a record runs past the end of its chunk") from None
        yield header, body


def _ros1_op(header: dict[str, bytes]) -> int:
    op = header.get("op", b"")
    if len(op) != 1:
        raise ValueError("a record without its op field")
    return op[0]


def _ros1_chunk_data(header: dict[str, bytes], data: bytes) -> bytes:
    compression = header["compression"].decode()
    if compression == "none":
        return data
    if compression == "bz2":
        import bz2

        return bz2.decompress(data)
    if compression == "lz4":
        from lz4.frame import decompress

        return decompress(data)
    raise ValueError(f"chunk compression {compression!r} (reads none, bz2, lz4)")


def _ros2_name(ros1_type: str) -> str:
    """``sensor_msgs/LaserScan`` -> ``sensor_msgs/msg/LaserScan`` (the names rosbags uses)."""
    package, _, name = ros1_type.rpartition("/")
    return f"{package}/msg/{name}" if package and "/msg/" not in ros1_type else ros1_type


def _ros1_why_it_stopped(exc: Exception, at: int, good: int, size: int, index_pos: int) -> str:
    if 0 < index_pos <= good:
        return "the index at the end of the bag is damaged or cut (every message was read)"
    if isinstance(exc, _Cut) and at >= size:
        return (
            f"the file ends inside a record at byte {good}: it was cut short (a recorder killed "
            "mid-write, a full disk or an interrupted copy)"
        )
    return f"unreadable data after byte {good} ({type(exc).__name__}: {exc})"


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


# --------------------------------------------------------------------------- the laser's mount

TF_TYPE = "tf2_msgs/msg/TFMessage"
#: Roll or pitch beyond this (radians, ~2 deg) is not a level 2-D laser: warned about.
TILT_WARN_RAD = math.radians(2.0)
#: /tf messages read at most, looking for a transform /tf_static lacks.
TF_SCAN_LIMIT = 5000


@dataclass
class MountFound:
    """The laser's pose in the base frame as a recording gives it, and where it came from."""

    mount: object  # LaserMount
    source: str
    warnings: list[str] = field(default_factory=list)


def _planar(tr) -> tuple[tuple[float, float, float], float, float]:
    """((x, y, yaw), roll, pitch) of a ROS geometry_msgs/Transform."""
    t, q = tr.translation, tr.rotation
    yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
    roll = math.atan2(2 * (q.w * q.x + q.y * q.z), 1 - 2 * (q.x * q.x + q.y * q.y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (q.w * q.y - q.z * q.x))))
    return (float(t.x), float(t.y), yaw), roll, pitch


def _compose(a, b):
    """SE(2) ``a`` then ``b`` (b expressed in a's frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def _inverse(a):
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-(c * a[0] + s * a[1]), s * a[0] - c * a[1], -a[2])


def chain_transforms(edges: dict, base: str, laser: str):
    """The pose of frame ``laser`` in frame ``base`` through ``edges`` ({(parent, child):
    (x, y, yaw) of the child in the parent}), walking each edge either way; (pose, the frames
    passed) or None when no chain joins them."""
    links: dict[str, list] = {}
    for (parent, child), pose in edges.items():
        links.setdefault(parent, []).append((child, pose))
        links.setdefault(child, []).append((parent, _inverse(pose)))
    seen = {base: ((0.0, 0.0, 0.0), [base])}
    todo = [base]
    while todo:
        frame = todo.pop(0)
        pose, path = seen[frame]
        if frame == laser:
            return pose, path
        for nxt, step in links.get(frame, []):
            if nxt not in seen:
                seen[nxt] = (_compose(pose, step), [*path, nxt])
                todo.append(nxt)
    return None


def mount_from_tf(path: Path, base_frame: str, laser_frame: str) -> MountFound | None:
    """The laser's mount from a ROS bag's /tf_static (and /tf, when the static transforms do
    not join the two frames): the chain ``base_frame`` -> ... -> ``laser_frame`` in 2-D (x, y,
    yaw; z ignored, roll and pitch warned about when not ~0). None when the bag has no tf or
    no chain joins the frames."""
    from followbot.services.runtime.mount import LaserMount

    try:
        from rosbags.highlevel import AnyReader

        with AnyReader([path]) as reader:
            conns = [c for c in reader.connections if c.msgtype == TF_TYPE]
            if not conns:
                return None
            static = [c for c in conns if c.topic.endswith("tf_static")]
            dynamic = [c for c in conns if c not in static]
            edges: dict = {}
            tilt: dict = {}
            used: list[str] = []
            for group in (static, dynamic):
                if not group:
                    continue
                for n, (conn, _t, raw) in enumerate(reader.messages(connections=group)):
                    if n >= TF_SCAN_LIMIT:
                        break
                    msg = reader.deserialize(raw, conn.msgtype)
                    for ts in msg.transforms:
                        key = (ts.header.frame_id.lstrip("/"), ts.child_frame_id.lstrip("/"))
                        if key not in edges:  # the first: a mount does not move
                            edges[key], roll, pitch = _planar(ts.transform)
                            tilt[key] = (roll, pitch)
                used.append(group[0].topic)
                found = chain_transforms(edges, base_frame, laser_frame)
                if found is not None:
                    break
    except Exception as exc:  # rosbags raises its own error types per format
        raise RecordingError(f"{path}: cannot read its tf: {exc}") from None
    if found is None:
        return None
    (x, y, yaw), frames = found
    warnings = []
    for a, b in itertools.pairwise(frames):
        roll, pitch = tilt.get((a, b)) or tilt.get((b, a)) or (0.0, 0.0)
        if abs(math.remainder(roll, math.tau)) > TILT_WARN_RAD or abs(pitch) > TILT_WARN_RAD:
            warnings.append(
                f"tf {a} -> {b} is tilted (roll {math.degrees(roll):.1f} deg, pitch "
                f"{math.degrees(pitch):.1f} deg): followbot reads the laser in 2-D and ignores "
                "the tilt (an upside-down laser mirrors its scans)"
            )
    mount = LaserMount(x_m=x, y_m=y, yaw_deg=math.degrees(math.remainder(yaw, math.tau)))
    return MountFound(mount, f"{' + '.join(used)}: {' -> '.join(frames)}", warnings)
