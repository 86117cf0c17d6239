"""Writing followbot topics to MCAP, and reading MCAP files up to where they break.

The layout is documented in docs/recording.md. :class:`McapTopicWriter` ends a chunk and hands
it to the operating system at least every ``flush_period_s``, so a writer killed outright
(SIGKILL, a crash, power kept) leaves a file readable up to its last flush.
:class:`McapStream` reads a file front to back, record by record, and stops at the first
record it cannot read, saying where and why (:class:`Damage`): what came before is kept.
"""

from __future__ import annotations

import json
import time
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Damage", "McapStream", "McapTopicWriter", "check_magic"]

MAGIC = b"\x89MCAP0\r\n"


class McapTopicWriter:
    """An MCAP file of followbot topics: one msgpack channel per topic, JSON Schema per type.

    Channels are registered on first use. Messages are gathered in chunks; a chunk is ended
    and written out when it reaches 1 MiB or when the last flush is ``flush_period_s`` old
    (checked on every :meth:`write` and on :meth:`flush_if_due`, which a caller with a timer
    calls so that a quiet topic's last messages do not wait for the next one). Not
    thread-safe: call from one thread (a node's handlers and timers, which never run
    concurrently, qualify).
    """

    def __init__(self, path: str | Path, robot: str, *, flush_period_s: float = 0.5) -> None:
        from mcap.writer import Writer

        import followbot
        from followbot.schemas import SCHEMA_VERSION
        from followbot.schemas.export import message_schemas

        if not flush_period_s > 0:
            raise ValueError(f"flush_period_s must be > 0, got {flush_period_s}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("wb")
        self._writer = Writer(self._file)
        self._writer.start(profile="", library=f"followbot {followbot.__version__}")
        self._writer.add_metadata(
            "followbot",
            {
                "robot": robot,
                "followbot_version": followbot.__version__,
                "schema_version": str(SCHEMA_VERSION),
            },
        )
        self._defs = message_schemas()["$defs"]
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self._robot = robot
        self._flush_period_ns = int(flush_period_s * 1e9)
        self._unflushed = 0
        self.closed = False
        self.flush()  # header and metadata on disk at once: even an empty recording opens

    def _channel(self, topic: str) -> int:
        from followbot.schemas import Keys, topic_type

        ch = self._channels.get(topic)
        if ch is None:
            name = topic_type(topic).__name__
            sid = self._schemas.get(name)
            if sid is None:
                schema = {"$defs": self._defs, "$ref": f"#/$defs/{name}"}
                sid = self._writer.register_schema(name, "jsonschema", json.dumps(schema).encode())
                self._schemas[name] = sid
            key = Keys(self._robot).topic(topic)
            ch = self._writer.register_channel(topic, "msgpack", sid, {"key": key})
            self._channels[topic] = ch
            self.counts[topic] = 0
        return ch

    def write(self, topic: str, payload: bytes, stamp_ns: int, log_time_ns: int) -> None:
        """Add one message (``payload``: the validated wire bytes)."""
        ch = self._channel(topic)
        self._writer.add_message(
            ch, log_time=log_time_ns, data=payload, publish_time=stamp_ns,
            sequence=self.counts[topic] & 0xFFFFFFFF,
        )  # fmt: skip
        self.counts[topic] += 1
        self._unflushed += 1
        self.flush_if_due()

    def flush_if_due(self) -> None:
        """:meth:`flush` if messages wait and the last flush is ``flush_period_s`` old."""
        if (
            self._unflushed
            and not self.closed
            and time.monotonic_ns() - self._flushed_ns >= self._flush_period_ns
        ):
            self.flush()

    def flush(self) -> None:
        """End the chunk in progress, write it with its index and flush the file to the
        operating system (no fsync: it survives the process, not a power cut)."""
        self._writer.flush()
        self._flushed_ns = time.monotonic_ns()
        self._unflushed = 0

    def size_bytes(self) -> int:
        return self._file.tell()

    def close(self) -> None:
        """Write the index and close (the file is only complete after this)."""
        if not self.closed:
            self.closed = True
            self._writer.finish()
            self._file.close()


# ----------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class Damage:
    """Where a file stops being readable, why, and what was read before that point."""

    reason: str
    messages: int
    """Messages read before the break (of the topics asked for)."""
    first_log_ns: int | None
    last_log_ns: int | None
    size_bytes: int
    readable_bytes: int | None = None
    """Bytes before the first unreadable record (None: not known, an indexed read)."""

    @property
    def span_s(self) -> float:
        if self.first_log_ns is None or self.last_log_ns is None:
            return 0.0
        return (self.last_log_ns - self.first_log_ns) / 1e9

    def describe(self) -> str:
        if self.readable_bytes is None:
            where = f"of {self.size_bytes} bytes"
        elif self.readable_bytes >= self.size_bytes:
            where = f"all {self.size_bytes} bytes"
        else:
            where = f"the first {self.readable_bytes} of {self.size_bytes} bytes"
        return (
            f"read {self.messages} messages spanning {self.span_s:.1f} s ({where}), then "
            f"stopped: {self.reason}"
        )


def check_magic(path: Path) -> str | None:
    """Why ``path`` is not an MCAP file at all (None: it starts like one)."""
    with path.open("rb") as f:
        head = f.read(len(MAGIC))
    if not head:
        return "empty file (0 bytes): nothing was ever written to it"
    if head != MAGIC[: len(head)] or len(head) < len(MAGIC):
        return "not an MCAP file (it does not start with the MCAP magic bytes)"
    return None


class McapStream:
    """An MCAP file read front to back, stopping at the first record it cannot read.

    Reads without the index, so it works on a file whose writer never finished (no summary
    section) and on one cut short or damaged part-way: :meth:`messages` yields every message
    before the break, in file order, and then sets :attr:`damage`. Chunk checksums are
    checked, so a damaged chunk stops the read instead of yielding garbage.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.damage: Damage | None = None
        #: the file reached its footer (every record read)
        self.complete = False
        #: topic -> (schema name, message encoding) of every channel met
        self.channels: dict[str, tuple[str, str]] = {}

    def messages(self, topics: Collection[str] | None = None) -> Iterator[tuple[str, str, object]]:
        """``(topic, schema name, mcap Message record)`` of ``topics`` (None: all)."""
        from mcap.records import Channel, DataEnd, Footer, Message, Schema
        from mcap.stream_reader import StreamReader

        size = self.path.stat().st_size
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, str]] = {}
        n, first, last = 0, None, None
        data_end = False
        good = 0  # end of the last record read whole
        with self.path.open("rb") as f:
            # a length beyond the file is damage; the default limit (4 GiB) would try to read it
            reader = StreamReader(f, validate_crcs=True, record_size_limit=max(size, 1))
            records = reader.records
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    break
                # Any error of the parser is the file's damage (the library raises its own
                # errors, struct.error, zstd errors, UnicodeDecodeError, ... on bad bytes).
                except Exception as exc:
                    reason = _why_it_stopped(exc, f.tell(), good, size, data_end)
                    self.damage = Damage(reason, n, first, last, size, good)
                    return
                good = f.tell()
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel):
                    schema = schemas.get(record.schema_id, "")
                    channels[record.id] = (record.topic, schema)
                    self.channels[record.topic] = (schema, record.message_encoding)
                elif isinstance(record, Message):
                    topic, schema = channels.get(record.channel_id, ("", ""))
                    if not topic:
                        reason = f"a message of channel {record.channel_id}, never declared"
                        self.damage = Damage(reason, n, first, last, size, good)
                        return
                    if topics is not None and topic not in topics:
                        continue
                    n += 1
                    first = record.log_time if first is None else min(first, record.log_time)
                    last = record.log_time if last is None else max(last, record.log_time)
                    yield topic, schema, record
                elif isinstance(record, DataEnd):
                    data_end = True
                elif isinstance(record, Footer):
                    self.complete = True


def _why_it_stopped(exc: Exception, at: int, good: int, size: int, data_end: bool) -> str:
    if data_end:
        return "the index at the end of the file is damaged or cut (every message was read)"
    if at >= size and good >= size:
        return (
            "the file ends without its index: the recorder did not finish it (killed, or "
            "still recording)"
        )
    if at >= size:
        return (
            f"the file ends inside a record at byte {good}: it was cut short (a recorder "
            "killed mid-write, a full disk or an interrupted copy); the messages of that last "
            "chunk are lost"
        )
    return f"unreadable data after byte {good} ({type(exc).__name__}: {exc})"
