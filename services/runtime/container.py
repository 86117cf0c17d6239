"""Several services in one process: ``followbot run laser_legs+tracker+controller``.

Every service still is its own :class:`~.node.Node` (its own loop thread, lock, inputs, health
and liveliness token, so monitors, recorders, watchdogs and other machines see exactly what
they see of separate processes), but they share one Zenoh session, and a message one of them
publishes reaches the others in the process by a plain function call in the publishing thread:
no serialisation to a socket, no thread hand-over, no wake-up of another process. Zenoh still
carries every message to the rest of the network (the publishers' ``allowed_destination`` is
REMOTE, the subscribers' ``allowed_origin`` REMOTE, so nothing arrives twice).

Why: on a 2-core machine each hop between processes costs 0.1-0.4 ms (docs/runtime.md, "What the
runtime costs"); laser_legs -> tracker -> controller is three of the four hops between a scan
and the velocity command it causes. Run together, the chain is one call stack: a scan's
``cmd_vel`` leaves the process as soon as the controller has it.

When not: a heavy or crash-prone stage (vision) belongs in its own process, or on another
machine; a stage that blocks holds up every stage after it in the chain. The services'
handlers run inline in the thread that delivered the scan, so this suits short handlers (the
laser, tracker and controller stages) — exactly the ones that run inline anyway (node.py).

Settings: one file for the group, a section per service plus keys every service shares::

    robot: robot                       # shared: robot, zenoh, log_level, health_period_s ...
    zenoh: {connect: [tcp/192.168.1.10:7447]}
    tracker: {estimator: ukf}          # one service's own settings
    laser_legs: {detector: learned}

``--set tracker.estimator=ukf`` sets one service's key, ``--set log_level=debug`` a shared one.
The Zenoh settings belong to the process, so a service section may not have its own.
"""

from __future__ import annotations

import argparse
import copy
import json
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from .bus import ZenohBus
from .session import SessionError, open_session, overrides_from_args
from .settings import SettingsError, ZenohSettings, _merge, _parse_file, apply_overrides

__all__ = ["LocalHub", "current_hub", "main", "split_settings"]

log = logging.getLogger("followbot.container")

_hub: LocalHub | None = None


def current_hub() -> LocalHub | None:
    """The hub of this process when it runs several services (node.zenoh_node uses it)."""
    return _hub


class LocalHub:
    """One Zenoh session shared by the services of a process, and their in-process delivery."""

    def __init__(self, session) -> None:
        self.session = session
        self._lock = threading.Lock()
        self._subs: list[tuple[Any, PayloadCallback]] = []  # (zenoh KeyExpr, callback)
        self._routes: dict[str, tuple[PayloadCallback, ...]] = {}
        self.nodes: list = []
        self.stopping = threading.Event()

    def bus(self) -> HubBus:
        return HubBus(self)

    def add(self, key: str, callback: PayloadCallback) -> Callable[[], None]:
        import zenoh

        entry = (zenoh.KeyExpr(key), callback)
        with self._lock:
            self._subs.append(entry)
            self._routes.clear()

        def remove() -> None:
            with self._lock:
                if entry in self._subs:
                    self._subs.remove(entry)
                    self._routes.clear()

        return remove

    def local(self, key: str) -> tuple[PayloadCallback, ...]:
        """The in-process subscribers of a concrete key (cached until subscriptions change)."""
        route = self._routes.get(key)
        if route is None:
            import zenoh

            ke = zenoh.KeyExpr(key)
            with self._lock:
                route = tuple(cb for expr, cb in self._subs if expr.intersects(ke))
                self._routes[key] = route
        return route

    def register(self, node) -> None:
        with self._lock:
            self.nodes.append(node)
        if self.stopping.is_set():
            node.stop()

    def unregister(self, node) -> None:
        with self._lock:
            if node in self.nodes:
                self.nodes.remove(node)

    def stop_all(self) -> None:
        self.stopping.set()
        with self._lock:
            nodes = list(self.nodes)
        for node in nodes:
            node.stop()


PayloadCallback = Callable[[bytes], None]


class _HubPublisher:
    __slots__ = ("_hub", "_key", "_pub", "_zput")

    def __init__(self, pub, hub: LocalHub, key: str) -> None:
        self._pub, self._hub, self._key = pub, hub, key
        self._zput = pub.put

    def put(self, payload: bytes) -> None:
        self._zput(payload)  # the rest of the network first: it does not wait for our handlers
        for callback in self._hub.local(self._key):
            try:
                callback(payload)
            except Exception:  # a node's on_payload counts its own errors; this is a bug
                log.exception("in-process delivery on %s failed", self._key)

    def matching(self) -> bool:
        return bool(self._hub.local(self._key)) or bool(self._pub.matching_status.matching)


class HubBus(ZenohBus):
    """A :class:`~.bus.ZenohBus` on the hub's session that also delivers in-process."""

    def __init__(self, hub: LocalHub) -> None:
        super().__init__(hub.session)
        self._hub = hub

    def publisher(self, key: str, *, reliable: bool = False) -> _HubPublisher:
        pub = self._declare_publisher(key, reliable, self._zenoh.Locality.REMOTE)
        return _HubPublisher(pub, self._hub, key)

    def subscribe(self, key: str, callback: PayloadCallback):
        remove = self._hub.add(key, callback)
        sub = self._declare_subscriber(key, callback, self._zenoh.Locality.REMOTE)
        handle = _Both(sub, remove)
        self._declared.append(handle)
        return handle


class _Both:
    """Undeclares a Zenoh subscriber and its in-process registration together."""

    def __init__(self, sub, remove: Callable[[], None]) -> None:
        self._sub, self._remove = sub, remove

    def undeclare(self) -> None:
        self._remove()
        self._sub.undeclare()


# --------------------------------------------------------------------------- the command


def split_settings(
    services: list[str],
    data: dict[str, Any],
    overrides: list[str],
    presets: dict[str, dict[str, Any]] | None = None,
) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """(shared keys, each service's merged settings) from a group file's mapping and
    ``--set`` overrides (``service.key=value`` for one service, ``key=value`` for all), on top
    of ``presets`` (service -> a preset's settings for it, ``--preset``)."""
    shared = {k: v for k, v in data.items() if k not in services}
    own: dict[str, dict[str, Any]] = {}
    for s in services:
        section = data.get(s) or {}
        if not isinstance(section, dict):
            raise SettingsError(f"{s}: expected a mapping of {s}'s settings")
        own[s] = dict(section)
    for item in overrides:
        head = item.partition("=")[0].strip().split(".", 1)
        if len(head) == 2 and head[0] in services:
            apply_overrides(own[head[0]], [item.split(".", 1)[1]])
        else:
            apply_overrides(shared, [item])
    merged = {}
    for s in services:
        if "zenoh" in own[s]:
            raise SettingsError(
                f"{s}.zenoh: services run together share one Zenoh session; "
                "set zenoh at the top level (or with --connect/--listen/--mode)"
            )
        m: dict[str, Any] = copy.deepcopy((presets or {}).get(s, {}))
        _merge(m, copy.deepcopy(shared))
        _merge(m, own[s])
        merged[s] = m
    return shared, merged


def main(services: list[str], argv: list[str] | None = None) -> int:
    """``followbot run A+B+C [options]``: run services A, B and C in this process."""
    from .plugins import Registry, UnknownPlugin
    from .service import add_run_arguments, preset_layer

    name = "+".join(services)
    parser = argparse.ArgumentParser(
        prog=f"followbot run {name}",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_run_arguments(
        parser,
        config_help="group settings (YAML or JSON)",
        set_help="SERVICE.key=value for one service, key=value for all (repeatable)",
        print_help="print each service's effective settings and exit",
    )
    args = parser.parse_args(argv)
    if len(set(services)) != len(services):
        print(f"followbot run {name}: a service is named twice", file=sys.stderr)
        return 2
    registry = Registry("services")
    try:
        mains = {s: registry.load(s) for s in services}
    except UnknownPlugin as exc:
        print(f"followbot run {name}: {exc}", file=sys.stderr)
        return 2
    try:
        data = _parse_file(Path(args.config)) if args.config else {}
        presets = {s: preset_layer(args.preset, s) or {} for s in services}
        overrides = [*args.set, *overrides_from_args(args)]
        shared, merged = split_settings(services, data, overrides, presets)
        zenoh_settings = _zenoh_settings(shared)
    except SettingsError as exc:
        print(f"followbot run {name}: {exc}", file=sys.stderr)
        return 2
    argvs = {s: _argv(merged[s], args.duration) for s in services}
    if args.print_settings:
        for s in services:
            print(f"# {s}", flush=True)
            code = mains[s]([*argvs[s], "--print-settings"])
            if code:
                return code
        return 0
    logging.basicConfig(
        level=getattr(logging, str(shared.get("log_level", "info")).upper(), logging.INFO),
        format="%(asctime)s %(name)s %(levelname)s: %(message)s",
    )
    return _serve(name, services, mains, argvs, zenoh_settings)


def exit_now(code: int) -> NoReturn:
    """End a process that ran a group: flush the logs and streams, then exit without the
    interpreter's finalisation. Zenoh's own threads of the shared session may still be inside
    a Python callback then (a liveliness watcher), and a thread torn down there aborts the
    process (SIGABRT, "FATAL: exception not rethrown") instead of exiting with its code: seen
    once in three runs of a group whose service failed at start."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _zenoh_settings(shared: dict[str, Any]) -> ZenohSettings:
    import msgspec

    try:
        return msgspec.convert(shared.get("zenoh") or {}, ZenohSettings, strict=False)
    except msgspec.ValidationError as exc:
        raise SettingsError(f"zenoh: {exc}") from None


def _argv(settings: dict[str, Any], duration: float | None) -> list[str]:
    out = []
    for key, value in settings.items():
        out += ["--set", f"{key}={json.dumps(value)}"]  # JSON is YAML: the value as given
    if duration is not None:
        out += ["--duration", str(duration)]
    return out


def _serve(name, services, mains, argvs, zenoh_settings: ZenohSettings) -> int:
    global _hub
    if _hub is not None:
        raise RuntimeError("one group of services per process")
    try:
        session = open_session(zenoh_settings)
    except SessionError as exc:
        log.error("%s", exc)
        return 1
    codes: dict[str, int] = {}
    hub = _hub = LocalHub(session)

    def run(s: str) -> None:
        try:
            codes[s] = int(mains[s](argvs[s]) or 0)
        except BaseException:
            log.exception("service %s crashed", s)
            codes[s] = 1
        finally:
            hub.stop_all()  # one service ending ends the group (a supervisor restarts it)

    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, _f: hub.stop_all())
    threads = [threading.Thread(target=run, args=(s,), name=s, daemon=True) for s in services]
    try:
        log.info("%s: %d services in one process, pid and zid shared", name, len(services))
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            for t in threads:
                t.join(0.1)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        _hub = None
        session.close()
    return max(codes.values(), default=0)
