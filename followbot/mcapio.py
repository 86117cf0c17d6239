"""Writing followbot topics to MCAP (the layout is documented in docs/recording.md)."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["McapTopicWriter"]


class McapTopicWriter:
    """An MCAP file of followbot topics: one msgpack channel per topic, JSON Schema per type.

    Channels are registered on first use. Not thread-safe: call from one thread (a node's
    handlers, which never run concurrently, qualify).
    """

    def __init__(self, path: str | Path, robot: str) -> None:
        from mcap.writer import Writer

        import followbot
        from followbot.schemas import SCHEMA_VERSION
        from followbot.schemas.export import message_schemas

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
        self.closed = False

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

    def size_bytes(self) -> int:
        return self._file.tell()

    def close(self) -> None:
        """Write the index and close (the file is only complete after this)."""
        if not self.closed:
            self.closed = True
            self._writer.finish()
            self._file.close()
