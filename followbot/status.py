"""``followbot status``: every live service of a robot, its health, where it runs.

Listens on the bus for a moment (``--wait``, default 2.5 s: every service publishes Health on
``followbot/<robot>/health/<service>`` once a second) and prints one table: each service whose
liveliness token (``followbot/<robot>/alive/<service>``) is up or whose Health arrived, with
its status and why, its rates, its last error, the host and pid it runs as, its uptime and
how long ago its last Health came. ``--watch`` refreshes the table every second until Ctrl-C.

Connection options are those of ``followbot run``: with none, the embedded default (this
machine); from another machine, e.g. ``--connect tcp/<robot-ip>:7447``.

Exit codes: 0 every service is ok; 1 some service is not (degraded, error, alive but silent,
or publishing Health without a liveliness token); 2 bad options, or no Zenoh session; 3 no
service of the robot is on the bus. With ``--watch``, the code of the last table.
"""

from __future__ import annotations

import argparse
import contextlib
import queue
import signal
import sys
import threading
import time
from dataclasses import dataclass

from followbot.schemas import Health, Keys, RejectedMessage, decode

__all__ = ["BusWatch", "Row", "main", "render", "rows"]

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

#: Exit codes (see the module docstring).
OK, NOT_OK, USAGE, NOTHING = 0, 1, 2, 3


class BusWatch:
    """What the bus says about one robot's services: liveliness tokens and their Health.

    Zenoh calls back on its own threads; the state is guarded by a lock, and every change is
    also queued as an event ``(kind, service, detail)`` for a caller that reports changes
    (``followbot up``): ``alive``, ``gone``, and ``status`` when a service's status or reasons
    change (``detail`` is then its Health).
    """

    def __init__(self, session, robot: str) -> None:
        import zenoh

        self.keys = Keys(robot)
        self._lock = threading.Lock()
        self.alive: dict[str, float] = {}
        """Service -> ``time.monotonic()`` its token appeared."""
        self.health: dict[str, tuple[Health, float]] = {}
        """Service -> its last Health and the ``time.monotonic()`` it arrived."""
        self.rejected = 0
        self.events: queue.SimpleQueue = queue.SimpleQueue()
        put = zenoh.SampleKind.PUT
        self._subs = [
            session.liveliness().declare_subscriber(
                self.keys.all_alive,
                lambda s: self._on_alive(str(s.key_expr), s.kind == put),
                history=True,
            ),
            session.declare_subscriber(
                self.keys.all_health, lambda s: self._on_health(s.payload.to_bytes())
            ),
        ]

    def _on_alive(self, key: str, alive: bool) -> None:
        service = key.rsplit("/", 1)[-1]
        with self._lock:
            if alive:
                if service in self.alive:
                    return
                self.alive[service] = time.monotonic()
            else:
                if self.alive.pop(service, None) is None:
                    return
                self.health.pop(service, None)  # a later one has a new pid, uptime...
        self.events.put(("alive" if alive else "gone", service, None))

    def _on_health(self, payload: bytes) -> None:
        try:
            h = decode(Health, payload)
        except RejectedMessage:
            with self._lock:
                self.rejected += 1
            return
        with self._lock:
            old = self.health.get(h.service)
            self.health[h.service] = (h, time.monotonic())
        if old is None or (old[0].status, old[0].reasons) != (h.status, h.reasons):
            self.events.put(("status", h.service, h))

    def snapshot(self) -> tuple[dict[str, float], dict[str, tuple[Health, float]]]:
        with self._lock:
            return dict(self.alive), dict(self.health)

    def wait_for_health(
        self, services: set[str] | None, timeout_s: float, at_least_s: float = 0.0
    ) -> None:
        """Wait until each of ``services`` (None: each service alive by then) has sent Health,
        at least ``at_least_s`` (tokens arrive over a moment) and at most ``timeout_s``."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            alive, health = self.snapshot()
            want = set(alive) if services is None else services
            if want and want <= set(health) and time.monotonic() - t0 >= at_least_s:
                return
            time.sleep(0.05)

    def close(self) -> None:
        for sub in self._subs:
            with contextlib.suppress(Exception):  # the session is closing
                sub.undeclare()


@dataclass
class Row:
    service: str
    state: str
    """ok | degraded | error | silent (alive, no Health) | no-token (Health, no liveliness)"""
    reasons: str
    rates: str
    last_error: str
    where: str
    uptime: str
    age: str

    @property
    def ok(self) -> bool:
        return self.state == "ok"


def _rates(h: Health) -> str:
    parts = []
    for key, hz in sorted(h.rates_hz.items()):
        direction, _, topic = key.partition(":")
        arrow = "<" if direction == "in" else ">"
        parts.append(f"{arrow}{topic.rsplit('/', 1)[-1]} {hz:.3g}")
    return " ".join(parts)


def _duration(s: float) -> str:
    if s < 60:
        return f"{s:.0f}s"
    if s < 3600:
        return f"{s // 60:.0f}m{s % 60:02.0f}s"
    return f"{s // 3600:.0f}h{s % 3600 // 60:02.0f}m"


def rows(alive: dict[str, float], health: dict[str, tuple[Health, float]], now: float) -> list:
    out = []
    for name in sorted(set(alive) | set(health)):
        if name not in health:
            out.append(Row(name, "silent", "alive, but no Health received", "", "", "", "", ""))
            continue
        h, at = health[name]
        state = h.status if name in alive else "no-token"
        reasons = "; ".join(h.reasons)
        if name not in alive:
            reasons = "; ".join(r for r in ("Health without a liveliness token", reasons) if r)
        out.append(
            Row(
                service=name,
                state=state,
                reasons=reasons,
                rates=_rates(h),
                last_error=h.last_error,
                where=f"{h.host or '?'}:{h.pid or '?'}",
                uptime=_duration(h.uptime_s),
                age=f"{now - at:.1f}s",
            )
        )
    return out


_COLUMNS = (
    ("SERVICE", "service", 24),
    ("STATUS", "state", 8),
    ("HOST:PID", "where", 28),
    ("UPTIME", "uptime", 8),
    ("HEALTH AGE", "age", 10),
    ("RATES HZ", "rates", 48),
    ("REASONS", "reasons", 60),
    ("LAST ERROR", "last_error", 60),
)


def render(table: list[Row]) -> str:
    """The rows as a fixed-width table (long cells cut with '...')."""

    def cell(text: str, limit: int) -> str:
        text = " ".join(text.split())
        return text if len(text) <= limit else text[: limit - 3] + "..."

    cells = [[cell(getattr(r, attr), limit) for _, attr, limit in _COLUMNS] for r in table]
    widths = [
        max([len(title)] + [len(c[i]) for c in cells]) for i, (title, _, _) in enumerate(_COLUMNS)
    ]
    lines = ["  ".join(t.ljust(w) for (t, _, _), w in zip(_COLUMNS, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in cells]
    return "\n".join(line.rstrip() for line in lines)


def exit_code(table: list[Row]) -> int:
    if not table:
        return NOTHING
    return OK if all(r.ok for r in table) else NOT_OK


def main(argv: list[str] | None = None) -> int:
    from followbot.services.runtime.session import (
        SessionError,
        add_zenoh_arguments,
        open_session,
        overrides_from_args,
    )
    from followbot.services.runtime.settings import NodeSettings, SettingsError, load_settings

    p = argparse.ArgumentParser(
        prog="followbot status",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--watch", action="store_true", help="refresh every second until Ctrl-C")
    p.add_argument(
        "--wait",
        type=float,
        default=2.5,
        metavar="S",
        help="listen this long before the first table (default 2.5 s: Health comes every 1 s)",
    )
    add_zenoh_arguments(p)
    args = p.parse_args(argv)
    if args.wait < 0:
        p.error("--wait must be >= 0")
    try:
        settings = load_settings(NodeSettings, None, overrides_from_args(args))
    except SettingsError as exc:
        print(f"followbot status: {exc}", file=sys.stderr)
        return USAGE
    try:
        session = open_session(settings.zenoh)
    except SessionError as exc:
        print(f"followbot status: {exc}", file=sys.stderr)
        return USAGE
    stop = threading.Event()
    previous = {}
    if args.watch:
        previous = {
            s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)
        }
    try:
        watch = BusWatch(session, settings.robot)
        try:
            watch.wait_for_health(None, args.wait, at_least_s=min(args.wait, 0.5))
            while True:
                alive, health = watch.snapshot()
                table = rows(alive, health, time.monotonic())
                text = render(table) if table else f"no service of robot {settings.robot!r} found"
                if args.watch and sys.stdout.isatty():
                    sys.stdout.write("\x1b[H\x1b[2J")
                header = f"robot {settings.robot}, {time.strftime('%H:%M:%S')}"
                print(f"{header}\n{text}\n" if args.watch else text, flush=True)
                code = exit_code(table)
                if not args.watch or stop.wait(1.0):
                    return code
        finally:
            watch.close()
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        session.close()


if __name__ == "__main__":
    raise SystemExit(main())
