"""The node loop every service runs: inputs, decoding with rejection counting, health, shutdown.

Threading model
---------------
Handlers of one node never run concurrently: every handler and timer runs under the node's
lock. Zenoh delivers samples on its own threads; a subscription's callback appends the payload
bytes to that input's buffer, then dispatches in one of two ways:

``inline`` (default for ``all`` inputs)
    If the node is idle, the delivery thread takes the lock and runs decode + handler at once:
    no thread hand-over, the lowest latency (a hand-over costs ~80 us here). If the node is
    busy, the sample waits in the buffer for the loop thread, so order is kept. Handlers on
    inline inputs should be short (the laser, tracker and controller stages are).
``loop``
    The loop thread is woken and does the work. Required for ``latest`` inputs and right for
    heavy handlers (vision), so Zenoh's delivery thread is never held up.

Two buffering policies:

``all``
    A FIFO drained in order, bounded by ``capacity``; overflow drops the oldest and is counted
    and logged as ``dropped``. For streams where every sample matters (scans, candidates).
``latest``
    A one-slot buffer: a newer sample replaces an unprocessed older one (counted as
    ``superseded``, not lost). For sensors where only the newest matters (images).

Bad input never stops a node: a payload that fails to decode or validate is counted in
``rejected`` and logged (rate-limited); an exception in a handler is counted in ``errors`` and
logged with its traceback (rate-limited); the next sample is processed as usual.

Every node declares a liveliness token ``followbot/<robot>/alive/<service>`` and publishes
:class:`~followbot.schemas.Health` on ``followbot/<robot>/health/<service>`` every
``health_period_s``. SIGINT and SIGTERM stop the loop; the node then undeclares everything and
the process exits 0.
"""

from __future__ import annotations

import hashlib
import logging
import os
import queue
import signal
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Generic, Literal, TypeVar

import msgspec

from followbot.schemas import Health, Keys, Message, RejectedMessage, decode, encode, topic_type

from .bus import Bus
from .clock import StampGuard
from .settings import NodeSettings
from .stats import RateLimitedLog, Window, rss_mb

__all__ = ["Node", "Policy", "TypedPublisher", "configure_logging", "zenoh_node"]

M = TypeVar("M", bound=Message)
Policy = Literal["latest", "all"]
Dispatch = Literal["inline", "loop"]

#: Environment variable naming a folder: every node started with it writes there, one line per
#: message its handlers get, in the order they get them (docs/runtime.md, "Tracing inputs").
TRACE_ENV = "FOLLOWBOT_TRACE_INPUTS"

_HOST = socket.gethostname()[:256]

#: A process this long up with nobody else on the network says so in its health.
_LONELY_AFTER_NS = 3_000_000_000

#: Longest the loop sleeps without looking at its stop flag and timers.
_MAX_WAIT_S = 0.1


def configure_logging(level: str = "info") -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper()),
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
    )


class _Input(Generic[M]):
    """One subscription: its buffer and its counters."""

    def __init__(
        self,
        node: Node,
        topic: str,
        key: str,
        message_type: type[M],
        handler: Callable[[M], None],
        policy: Policy,
        capacity: int,
        dispatch: Dispatch,
        with_payload: bool = False,
        guard: StampGuard | None = None,
        on_restart: Callable[[], None] | None = None,
    ) -> None:
        if policy not in ("latest", "all"):
            raise ValueError(f"policy must be 'latest' or 'all', got {policy!r}")
        if dispatch not in ("inline", "loop"):
            raise ValueError(f"dispatch must be 'inline' or 'loop', got {dispatch!r}")
        if policy == "latest" and dispatch == "inline":
            raise ValueError("a 'latest' input must use dispatch='loop'")
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.topic, self.key = topic, key
        self.message_type, self.handler, self.policy = message_type, handler, policy
        self.buffer: deque[bytes] = deque(maxlen=1 if policy == "latest" else capacity)
        self.inline = dispatch == "inline"
        self.with_payload = with_payload
        self.guard = guard
        self.on_restart = on_restart
        self._node = node
        self._wake = node._wake
        self.received = 0
        self.superseded = 0
        self.dropped = 0
        self.rejected = 0
        self.processed = 0
        self.last_processed_ns = 0
        """``time.monotonic_ns()`` of the last good message handled (0: none yet)."""
        self.last_reject = ""
        """Why the last rejected message was rejected."""
        self.expect_within_ns = 0
        """Health says so when no good message has come for this long (0: never)."""

    def on_payload(self, payload: bytes) -> None:
        """Zenoh's delivery thread: buffer, then run inline if the node is idle, else ring."""
        self.received += 1
        if len(self.buffer) == self.buffer.maxlen:
            if self.policy == "all":
                self.dropped += 1
            else:
                self.superseded += 1
        self.buffer.append(payload)
        node = self._node
        if self.inline and node._lock.acquire(blocking=False):
            try:
                if not node._stop.is_set():
                    while self.buffer:
                        node._service(self)
            finally:
                node._lock.release()
        else:
            self._wake.put(self)


class _InputTrace:
    """``<folder>/<service>.<pid>.inputs``: ``topic stamp_ns digest`` per message handled.

    The digest covers the message with ``seq`` set to 0 (a replay numbers messages afresh), so
    two runs' files can be compared with ``diff`` to find the first input that differed.
    """

    def __init__(self, folder: str, service: str) -> None:
        path = Path(folder) / f"{service}.{os.getpid()}.inputs"
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file = path.open("w", buffering=1)  # line-buffered: whole lines, even if killed

    def write(self, topic: str, message: Message) -> None:
        body = encode(msgspec.structs.replace(message, seq=0))
        digest = hashlib.blake2b(body, digest_size=8).hexdigest()
        self._file.write(f"{topic} {message.stamp_ns} {digest}\n")


class TypedPublisher(Generic[M]):
    """Publishes messages of one topic; numbers them and can answer queries with the last."""

    def __init__(self, node: Node, topic: str, key: str, raw, serve_last: bool) -> None:
        self.topic, self.key = topic, key
        self.message_type = topic_type(topic)
        self._raw = raw
        self._node = node
        self.sent = 0
        self.last_payload: bytes | None = None
        if serve_last:
            node.bus.queryable(key, lambda: self.last_payload)

    def matching(self) -> bool:
        """Whether any subscriber currently listens to this topic."""
        return self._raw.matching()

    def serve(self, message: M | None) -> None:
        """Answer queries with ``message`` from now on without publishing it (None: stop
        answering), e.g. a model adopted from another worker, or one that was dropped."""
        self.last_payload = None if message is None else encode(message)

    def put(self, message: M) -> bytes:
        """Encode and publish; sets ``message.seq`` to this publisher's count. Returns payload."""
        if not isinstance(message, self.message_type):
            raise TypeError(
                f"{self.topic} carries {self.message_type.__name__}, not {type(message).__name__}"
            )
        message.seq = self.sent
        payload = encode(message)
        self._raw.put(payload)
        self.sent += 1
        self.last_payload = payload
        return payload


class Node:
    """One service's presence on the bus and its single-threaded loop.

    Declare inputs with :meth:`subscribe`, outputs with :meth:`publisher`, periodic work with
    :meth:`every`, then call :meth:`run`.
    """

    def __init__(self, service: str, settings: NodeSettings, bus: Bus) -> None:
        self.service = service
        self.settings = settings
        self.bus = bus
        self.keys = Keys(settings.robot)
        self.log = logging.getLogger(f"followbot.{service}")
        self._ratelog = RateLimitedLog(self.log)
        self._wake: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._inputs: list[_Input] = []
        self._publishers: list[TypedPublisher] = []
        self._timers: list[list] = []  # [next_due_ns, period_ns, fn, name]
        self._on_stop: list[Callable[[], None]] = []
        self._proc = Window(4096)
        self._started_ns = time.monotonic_ns()
        self.errors = 0
        self.last_error = ""
        self.status: Literal["ok", "degraded", "error"] = "ok"
        """A floor for the published status (a service that cannot work at all sets "error")."""
        self.notes: list[str] = []
        self._conditions: dict[str, tuple[str, str]] = {}
        self._health_pub = bus.publisher(self.keys.health(service))
        self._last_health: tuple[int, dict, dict[str, int], int] | None = None
        self._announced = False
        folder = os.environ.get(TRACE_ENV)
        self._trace = _InputTrace(folder, service) if folder else None
        self.every(settings.health_period_s, self.publish_health, name="health")

    # ------------------------------------------------------------------ declaration

    def subscribe(
        self,
        topic: str,
        handler: Callable[[M], None],
        *,
        policy: Policy = "all",
        capacity: int = 10_000,
        dispatch: Dispatch | None = None,
        with_payload: bool = False,
        judge_stamps: bool = True,
        on_restart: Callable[[], None] | None = None,
        expect_within_s: float | None = None,
    ) -> _Input[M]:
        """Call ``handler(message)`` for each message on ``topic`` (see the module docstring
        for ``policy`` and ``dispatch``; dispatch defaults to inline for ``all``).
        ``with_payload``: call ``handler(message, payload)`` with the validated wire bytes too
        (recorders keep them as they came). ``judge_stamps``: reject stamps far ahead of or
        behind the stream (settings ``clock``, :mod:`.clock`); off for inputs that mix several
        sources' clocks. ``on_restart()`` runs, before the message is handled, when the
        stream's source is judged to have restarted with a new clock. ``expect_within_s``:
        Health says so when no good message has come for that long (an input the service
        cannot work without)."""
        key = self.keys.topic(topic)
        if dispatch is None:
            dispatch = "inline" if policy == "all" else "loop"
        guard = StampGuard.from_settings(self.settings.clock) if judge_stamps else None
        inp = _Input(
            self, topic, key, topic_type(topic), handler, policy, capacity, dispatch,
            with_payload, guard, on_restart,
        )  # fmt: skip
        if expect_within_s is not None:
            inp.expect_within_ns = int(expect_within_s * 1e9)
        self._inputs.append(inp)
        self.bus.subscribe(key, inp.on_payload)
        return inp

    def publisher(
        self, topic: str, *, reliable: bool = False, serve_last: bool = False
    ) -> TypedPublisher:
        """A publisher for ``topic``. ``reliable``: block rather than drop under congestion.
        ``serve_last``: answer Zenoh queries on the key with the last message sent."""
        key = self.keys.topic(topic)
        pub = TypedPublisher(
            self, topic, key, self.bus.publisher(key, reliable=reliable), serve_last
        )
        self._publishers.append(pub)
        return pub

    def every(self, period_s: float, fn: Callable[[], None], *, name: str = "") -> None:
        """Run ``fn()`` in the loop every ``period_s`` (no drift; late ticks are not bunched)."""
        if period_s <= 0:
            raise ValueError("period_s must be > 0")
        period_ns = int(period_s * 1e9)
        self._timers.append([time.monotonic_ns() + period_ns, period_ns, fn, name or fn.__name__])

    def run_timer(self, name: str) -> None:
        """Run the timer ``name`` (see :meth:`every`) once now, as the loop would (errors
        counted in Health), without moving its schedule: for tests, and for a service that
        wants a tick at once. KeyError if there is no such timer."""
        for t in self._timers:
            if t[3] == name:
                with self._lock:
                    self._call("timer", t[2])
                return
        raise KeyError(f"no timer named {name!r} (have {[t[3] for t in self._timers]})")

    def reject(self, inp: _Input, reason: str) -> None:
        """Count a message the service itself refuses (valid on the wire, unusable for it, e.g.
        an image of the wrong size) in ``Health.rejected[topic]``, with a rate-limited log."""
        inp.rejected += 1
        inp.last_reject = reason
        self._ratelog.log(
            logging.WARNING, f"reject:{inp.topic}:{reason}", "rejected %s: %s", inp.topic, reason
        )

    def wait_for_subscribers(self, publisher: TypedPublisher, timeout_s: float) -> bool:
        """Block until ``publisher`` has a subscriber, ``timeout_s`` passes or the node stops."""
        deadline = time.monotonic() + timeout_s
        while not publisher.matching():
            if self._stop.is_set() or time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    def announce(self) -> None:
        """Declare the liveliness token (once). :meth:`run` does it before serving, so that
        'alive' means every subscription of the service's setup is in place."""
        if not self._announced:
            self._announced = True
            self.bus.liveliness_token(self.keys.alive(self.service))

    def call_soon(self, fn: Callable[[], None]) -> None:
        """Run ``fn()`` in the loop thread, soon (thread-safe)."""
        self._wake.put(fn)

    def on_stop(self, fn: Callable[[], None]) -> None:
        """Run ``fn()`` once when the loop ends (final summaries, flushing files)."""
        self._on_stop.append(fn)

    def watch_alive(self, service: str, callback: Callable[[bool], None]) -> None:
        """Call ``callback(alive)`` in the loop when ``service``'s liveliness changes."""

        def on_change(_key: str, alive: bool) -> None:
            self.call_soon(lambda: callback(alive))

        self.bus.watch_liveliness(self.keys.alive(service), on_change)

    def query(self, topic: str, timeout_s: float = 1.0) -> list[Message]:
        """Ask the network for ``topic``'s current value (e.g. the target model)."""
        out = []
        for payload in self.bus.query(self.keys.topic(topic), timeout_s):
            try:
                out.append(decode(topic_type(topic), payload))
            except RejectedMessage as exc:
                self._ratelog.log(logging.WARNING, f"query:{topic}", "rejected reply: %s", exc)
        return out

    # ------------------------------------------------------------------ loop

    def stop(self) -> None:
        """Ask the loop to return (thread- and signal-safe)."""
        self._stop.set()
        self._wake.put(None)

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def run(self, duration_s: float | None = None) -> int:
        """Serve until :meth:`stop`, SIGINT/SIGTERM or ``duration_s``; returns the exit code 0."""
        deadline = None if duration_s is None else time.monotonic_ns() + int(duration_s * 1e9)
        self.announce()
        with _stop_on_signals(self):
            while not self._stop.is_set():
                now = time.monotonic_ns()
                if deadline is not None and now >= deadline:
                    break
                wait_ns = _MAX_WAIT_S * 1e9
                for t in self._timers:
                    wait_ns = min(wait_ns, t[0] - now)
                if deadline is not None:
                    wait_ns = min(wait_ns, deadline - now)
                try:
                    item = self._wake.get(timeout=max(wait_ns, 0) / 1e9) if wait_ns > 0 else None
                except queue.Empty:
                    item = None
                with self._lock:
                    if item is not None:
                        self._service(item)
                    self._run_timers()
        with self._lock:
            for fn in self._on_stop:
                self._call("stop", fn)
        return 0

    def spin_once(self) -> int:
        """Process everything already delivered and due timers, without waiting (for tests)."""
        n = 0
        with self._lock:
            while True:
                try:
                    item = self._wake.get_nowait()
                except queue.Empty:
                    break
                if item is not None:
                    self._service(item)
                    n += 1
            self._run_timers()
        return n

    def _service(self, item) -> None:
        if isinstance(item, _Input):
            try:
                payload = item.buffer.popleft()
            except IndexError:  # a 'latest' slot already taken by an earlier ring
                return
            try:
                message = decode(item.message_type, payload)
            except RejectedMessage as exc:
                item.rejected += 1
                item.last_reject = "malformed"
                self._ratelog.log(
                    logging.WARNING,
                    f"reject:{item.topic}",
                    "rejected %s payload: %s",
                    item.topic,
                    exc,
                )
                return
            if item.guard is not None and not self._judge(item, message):
                return
            if self._trace is not None:
                self._trace.write(item.topic, message)
            if item.with_payload:
                self._call(item.topic, item.handler, message, payload)
            else:
                self._call(item.topic, item.handler, message)
            item.processed += 1
            item.last_processed_ns = time.monotonic_ns()
        else:
            self._call("event", item)

    def _judge(self, item: _Input, message: Message) -> bool:
        """Whether ``message``'s stamp may be handled (see :mod:`.clock`); a source restart
        runs the input's ``on_restart`` first."""
        guard = item.guard
        newest = guard.newest_ns
        verdict = guard.judge(message.stamp_ns, time.monotonic_ns())
        if verdict == "ok":
            return True
        if verdict == "restart":
            self.log.warning(
                "%s: the source's clock restarted (stamps now near %d, were near %s); "
                "starting afresh",
                item.topic,
                message.stamp_ns,
                newest,
            )
            if item.on_restart is not None:
                self._call(f"{item.topic}:restart", item.on_restart)
            return True
        item.rejected += 1
        item.last_reject = f"stamp {verdict}"
        self._ratelog.log(
            logging.WARNING,
            f"stamp:{item.topic}:{verdict}",
            "rejected %s: stamp %d is %s of the stream (newest accepted %s)",
            item.topic,
            message.stamp_ns,
            "ahead" if verdict == "ahead" else "behind",
            newest,
        )
        return False

    def _call(self, where: str, fn: Callable, *args) -> None:
        t0 = time.perf_counter_ns()
        try:
            fn(*args)
        except Exception as exc:
            self.errors += 1
            self.last_error = f"{where}: {type(exc).__name__}: {exc}"
            self._ratelog.log(
                logging.ERROR,
                f"error:{where}",
                "handler for %s failed: %s",
                where,
                exc,
                exc_info=True,
            )
        finally:
            if where != "timer":
                self._proc.add((time.perf_counter_ns() - t0) / 1e6)

    def _run_timers(self) -> None:
        now = time.monotonic_ns()
        for t in self._timers:
            if now >= t[0]:
                # Next tick on the original grid; if we fell more than a period behind,
                # skip the missed ticks rather than firing them in a burst.
                t[0] += t[1]
                if t[0] <= now:
                    t[0] = now + t[1] - (now - t[0]) % t[1]
                self._call("timer", t[2])
                if self._stop.is_set():
                    return

    # ------------------------------------------------------------------ health

    def set_condition(self, key: str, level: Literal["degraded", "error"], reason: str) -> None:
        """Report a lasting problem (e.g. ``no target model``) until :meth:`clear_condition`:
        ``level`` lowers the published status and ``reason`` is listed in ``Health.reasons``."""
        if level not in ("degraded", "error"):
            raise ValueError(f"level must be 'degraded' or 'error', got {level!r}")
        self._conditions[key] = (level, reason)

    def clear_condition(self, key: str) -> None:
        """End a problem reported with :meth:`set_condition` (no-op if there is none)."""
        self._conditions.pop(key, None)

    def health(self) -> Health:
        """The current vital signs (also published every ``health_period_s``). ``status`` and
        ``reasons`` judge what happened since the previous call (rejections, drops, errors),
        what has not happened for too long (an expected input), and lasting conditions."""
        now = time.monotonic_ns()
        counts = {i.topic: (i.received, i.rejected, i.processed, i.dropped) for i in self._inputs}
        sent = {p.topic: p.sent for p in self._publishers}
        rates: dict[str, float] = {}
        before: dict[str, tuple[int, int, int, int]] = {}
        errors0 = 0
        if self._last_health is not None:
            t0, before, tx0, errors0 = self._last_health
            dt = max((now - t0) / 1e9, 1e-9)
            rates.update(
                {f"in:{k}": (c[0] - before.get(k, (0,))[0]) / dt for k, c in counts.items()}
            )
            rates.update({f"out:{k}": (v - tx0.get(k, 0)) / dt for k, v in sent.items()})
        self._last_health = (now, counts, sent, self.errors)
        reasons = self._reasons(now, counts, before, self.errors - errors0)
        status = self.status
        for level, reason in self._conditions.values():
            reasons.append(reason)
            if level == "error":
                status = "error"
        if status == "ok" and reasons:
            status = "degraded"
        p50, p99 = self._proc.percentiles()
        return Health(
            stamp_ns=time.time_ns(),
            service=self.service,
            node_id=self.bus.node_id,
            status=status,
            uptime_s=(now - self._started_ns) / 1e9,
            rates_hz=rates,
            received={k: c[0] for k, c in counts.items()},
            rejected={k: c[1] for k, c in counts.items()},
            dropped={k: c[3] for k, c in counts.items() if c[3]},
            errors=self.errors,
            proc_p50_ms=0.0 if p50 != p50 else p50,
            proc_p99_ms=0.0 if p99 != p99 else p99,
            last_error=self.last_error[:1024],
            rss_mb=rss_mb(),
            notes=list(self.notes)[:16],
            reasons=[r[:256] for r in reasons[:16]],
            host=_HOST,
            pid=os.getpid(),
        )

    def _reasons(self, now: int, counts: dict, before: dict, new_errors: int) -> list[str]:
        reasons: list[str] = []
        for i in self._inputs:
            _, rej0, proc0, drop0 = before.get(i.topic, (0, 0, 0, 0))
            _, rej, proc, drop = counts[i.topic]
            if rej > rej0:
                what = "rejecting every" if proc == proc0 else f"rejected {rej - rej0}"
                reasons.append(f"{what} {i.topic} ({i.last_reject})")
            if drop > drop0:
                reasons.append(f"dropped {drop - drop0} {i.topic} (input queue full)")
            if i.expect_within_ns:
                since = now - (i.last_processed_ns or self._started_ns)
                if since > i.expect_within_ns:
                    reasons.append(
                        f"no {i.topic} for {since / 1e9:.0f} s"
                        if i.last_processed_ns
                        else f"no {i.topic} yet"
                    )
        if new_errors:
            reasons.append(f"{new_errors} handler errors (last: {self.last_error[:120]})")
        peers = self.bus.peer_count()
        if peers == 0 and now - self._started_ns > _LONELY_AFTER_NS:
            reasons.append("no peers")
        return reasons

    def publish_health(self) -> None:
        h = self.health()
        for i in self._inputs:
            if i.dropped:
                self._ratelog.log(
                    logging.WARNING,
                    f"drop:{i.topic}",
                    "%s: %d samples dropped so far (input queue of %d full)",
                    i.topic,
                    i.dropped,
                    i.buffer.maxlen,
                )
        self._health_pub.put(encode(h))

    def close(self) -> None:
        """Undeclare everything this node declared (the liveliness token goes with it)."""
        self.bus.close()


@contextmanager
def _stop_on_signals(node: Node) -> Iterator[None]:
    """SIGINT/SIGTERM stop the node (main thread only; elsewhere signals are left alone)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, _frame) -> None:
        node.log.info("%s received, stopping", signal.Signals(signum).name)
        node.stop()

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def zenoh_node(service: str, settings: NodeSettings) -> Iterator[Node]:
    """A :class:`Node` on a real Zenoh session, closed cleanly on exit. In a process that runs
    several services (container.py) the node joins the process's shared session instead."""
    from .bus import ZenohBus
    from .container import current_hub
    from .session import open_session

    hub = current_hub()
    if hub is not None:
        node = Node(service, settings, hub.bus())
        node.log.info("%s up (with others): robot=%s pid=%d", service, settings.robot, os.getpid())
        hub.register(node)
        try:
            yield node
        finally:
            hub.unregister(node)
            node.close()
        return
    session = open_session(settings.zenoh)
    try:
        bus = ZenohBus(session)
        node = Node(service, settings, bus)
        node.log.info(
            "%s up: robot=%s zid=%s pid=%d", service, settings.robot, bus.node_id, os.getpid()
        )
        try:
            yield node
        finally:
            node.close()
    finally:
        session.close()
