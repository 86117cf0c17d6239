"""The transport a node talks through: Zenoh for real, an in-process fake for unit tests.

A bus moves opaque payloads (bytes) between key expressions. It knows nothing of message
types; :class:`~.node.Node` encodes, decodes and validates. Both implementations call
subscriber callbacks with ``bytes``; :class:`ZenohBus` does so from Zenoh's callback thread, so a
callback must only hand the payload over (the node's loop does the work).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from typing import Protocol

__all__ = ["Bus", "FakeBus", "FakeNetwork", "Publisher", "ZenohBus", "key_matches"]

PayloadCallback = Callable[[bytes], None]
AliveCallback = Callable[[str, bool], None]
QueryHandler = Callable[[], bytes | None]


class Closeable(Protocol):
    def undeclare(self) -> None: ...


class Publisher(Protocol):
    def put(self, payload: bytes) -> None: ...
    def matching(self) -> bool:
        """Whether any subscriber currently matches this publisher's key."""
        ...


class Bus(Protocol):
    """What a node needs from the network."""

    node_id: str

    def publisher(self, key: str, *, reliable: bool = False) -> Publisher: ...
    def subscribe(self, key: str, callback: PayloadCallback) -> Closeable: ...
    def liveliness_token(self, key: str) -> Closeable: ...
    def watch_liveliness(self, key_expr: str, callback: AliveCallback) -> Closeable: ...
    def queryable(self, key: str, handler: QueryHandler) -> Closeable: ...
    def query(self, key: str, timeout_s: float) -> list[bytes]: ...
    def peer_count(self) -> int | None:
        """Zenoh peers and routers this process is connected to (None: not known)."""
        ...

    def close(self) -> None: ...


# --------------------------------------------------------------------------- Zenoh


class _ZenohPublisher:
    __slots__ = ("_pub", "put")

    def __init__(self, pub) -> None:
        self._pub = pub
        self.put = pub.put  # bound method: no extra call layer on the hot path

    def matching(self) -> bool:
        return bool(self._pub.matching_status.matching)


class ZenohBus:
    """A :class:`Bus` over an open ``zenoh.Session`` (the caller owns and closes the session)."""

    def __init__(self, session) -> None:
        import zenoh

        self._zenoh = zenoh
        self.session = session
        self.node_id = str(session.info.zid())
        self._declared: list = []

    def publisher(self, key: str, *, reliable: bool = False):
        return _ZenohPublisher(self._declare_publisher(key, reliable))

    def subscribe(self, key: str, callback: PayloadCallback):
        return self._declare_subscriber(key, callback)

    def _declare_publisher(self, key: str, reliable: bool, destination=None):
        """``destination``: a ``zenoh.Locality`` (None: zenoh's default, everyone)."""
        z = self._zenoh
        extra = {} if destination is None else {"allowed_destination": destination}
        pub = self.session.declare_publisher(
            key,
            # Sensor streams drop under congestion (only the latest matters); streams where
            # every sample matters block the writer instead of losing data.
            congestion_control=z.CongestionControl.BLOCK if reliable else z.CongestionControl.DROP,
            express=True,  # no batching: lowest latency for small, frequent messages
            **extra,
        )
        self._declared.append(pub)
        return pub

    def _declare_subscriber(self, key: str, callback: PayloadCallback, origin=None):
        """``origin``: a ``zenoh.Locality`` (None: zenoh's default, everyone)."""

        def on_sample(sample) -> None:
            callback(sample.payload.to_bytes())

        # zenoh-python's default (indirect) callback: its network thread pushes into a Rust
        # channel and a Python thread of its own calls us, so the network thread never waits
        # for the GIL while a node computes.
        extra = {} if origin is None else {"allowed_origin": origin}
        sub = self.session.declare_subscriber(key, on_sample, **extra)
        self._declared.append(sub)
        return sub

    def liveliness_token(self, key: str):
        tok = self.session.liveliness().declare_token(key)
        self._declared.append(tok)
        return tok

    def watch_liveliness(self, key_expr: str, callback: AliveCallback):
        z = self._zenoh

        def on_sample(sample) -> None:
            callback(str(sample.key_expr), sample.kind == z.SampleKind.PUT)

        sub = self.session.liveliness().declare_subscriber(key_expr, on_sample, history=True)
        self._declared.append(sub)
        return sub

    def queryable(self, key: str, handler: QueryHandler):
        def on_query(query) -> None:
            payload = handler()
            if payload is not None:
                query.reply(key, payload)

        q = self.session.declare_queryable(key, on_query)
        self._declared.append(q)
        return q

    def query(self, key: str, timeout_s: float) -> list[bytes]:
        out = []
        for reply in self.session.get(key, timeout=timeout_s):
            if reply.ok is not None:
                out.append(reply.ok.payload.to_bytes())
        return out

    def peer_count(self) -> int | None:
        info = self.session.info
        return sum(1 for _ in info.peers_zid()) + sum(1 for _ in info.routers_zid())

    def close(self) -> None:
        for d in reversed(self._declared):
            with contextlib.suppress(Exception):  # already undeclared, or the session closing
                d.undeclare()
        self._declared.clear()


# --------------------------------------------------------------------------- in-process fake


def key_matches(expr: str, key: str) -> bool:
    """Zenoh key-expression matching for the fake: ``*`` is one chunk, ``**`` any chunks."""
    e, k = expr.split("/"), key.split("/")

    def match(i: int, j: int) -> bool:
        if i == len(e):
            return j == len(k)
        if e[i] == "**":
            return any(match(i + 1, jj) for jj in range(j, len(k) + 1))
        if j == len(k):
            return False
        return (e[i] == "*" or e[i] == k[j]) and match(i + 1, j + 1)

    return match(0, 0)


class _Handle:
    def __init__(self, undeclare: Callable[[], None]) -> None:
        self._undeclare = undeclare
        self._done = False

    def undeclare(self) -> None:
        if not self._done:
            self._done = True
            self._undeclare()


class FakeNetwork:
    """An in-memory 'Zenoh network' joining several :class:`FakeBus` instances.

    Delivery is synchronous: ``put`` calls every matching subscriber before returning, in the
    publishing thread. Good for deterministic unit tests of nodes; not a stand-in for timing.
    """

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._subs: list[tuple[str, PayloadCallback]] = []
        self._tokens: dict[str, int] = {}
        self._watchers: list[tuple[str, AliveCallback]] = []
        self._queryables: list[tuple[str, QueryHandler]] = []
        self.published: list[tuple[str, bytes]] = []

    def bus(self, node_id: str = "fake") -> FakeBus:
        return FakeBus(self, node_id)

    def put(self, key: str, payload: bytes) -> None:
        with self._lock:
            self.published.append((key, payload))
            targets = [cb for expr, cb in self._subs if key_matches(expr, key)]
        for cb in targets:
            cb(payload)

    def _set_alive(self, key: str, alive: bool) -> None:
        with self._lock:
            watchers = [cb for expr, cb in self._watchers if key_matches(expr, key)]
        for cb in watchers:
            cb(key, alive)


class _FakePublisher:
    def __init__(self, net: FakeNetwork, key: str) -> None:
        self._net, self.key = net, key

    def put(self, payload: bytes) -> None:
        if not isinstance(payload, bytes | bytearray):
            raise TypeError("put takes bytes or bytearray (as zenoh does)")
        self._net.put(self.key, bytes(payload))

    def matching(self) -> bool:
        with self._net._lock:
            return any(key_matches(expr, self.key) for expr, _ in self._net._subs)


class FakeBus:
    """One node's view of a :class:`FakeNetwork`."""

    def __init__(self, net: FakeNetwork, node_id: str = "fake") -> None:
        self.net, self.node_id = net, node_id
        self._handles: list[_Handle] = []

    def _track(self, handle: _Handle) -> _Handle:
        self._handles.append(handle)
        return handle

    def publisher(self, key: str, *, reliable: bool = False) -> _FakePublisher:
        return _FakePublisher(self.net, key)

    def subscribe(self, key: str, callback: PayloadCallback) -> _Handle:
        entry = (key, callback)
        with self.net._lock:
            self.net._subs.append(entry)
        return self._track(_Handle(lambda: self.net._subs.remove(entry)))

    def liveliness_token(self, key: str) -> _Handle:
        with self.net._lock:
            self.net._tokens[key] = self.net._tokens.get(key, 0) + 1
        self.net._set_alive(key, True)

        def drop() -> None:
            with self.net._lock:
                self.net._tokens[key] -= 1
                gone = self.net._tokens[key] == 0
            if gone:
                self.net._set_alive(key, False)

        return self._track(_Handle(drop))

    def watch_liveliness(self, key_expr: str, callback: AliveCallback) -> _Handle:
        entry = (key_expr, callback)
        with self.net._lock:
            self.net._watchers.append(entry)
            present = [k for k, n in self.net._tokens.items() if n and key_matches(key_expr, k)]
        for k in present:  # history, as zenoh's liveliness subscriber with history=True
            callback(k, True)
        return self._track(_Handle(lambda: self.net._watchers.remove(entry)))

    def queryable(self, key: str, handler: QueryHandler) -> _Handle:
        entry = (key, handler)
        with self.net._lock:
            self.net._queryables.append(entry)
        return self._track(_Handle(lambda: self.net._queryables.remove(entry)))

    def query(self, key: str, timeout_s: float) -> list[bytes]:
        with self.net._lock:
            handlers = [h for k, h in self.net._queryables if key_matches(key, k)]
        return [p for p in (h() for h in handlers) if p is not None]

    def peer_count(self) -> int | None:
        return None

    def close(self) -> None:
        for h in reversed(self._handles):
            h.undeclare()
        self._handles.clear()
