"""Zenoh sessions from :class:`ZenohSettings`, and the shared CLI options that fill them.

The only module (with :mod:`.bus`) that imports zenoh.
"""

from __future__ import annotations

import argparse
import json
import os
import socket

import zenoh

from .security import zenoh_entries
from .settings import DEFAULT_ENDPOINT, ZenohSettings

__all__ = [
    "SessionError",
    "add_zenoh_arguments",
    "is_embedded_default",
    "open_session",
    "overrides_from_args",
    "zenoh_config",
]

_zenoh_logging_started = False


class SessionError(RuntimeError):
    """The Zenoh session could not be opened (bad endpoint, port taken, bad config file)."""


def zenoh_config(settings: ZenohSettings, *, hub: bool | None = None) -> zenoh.Config:
    """Translate settings into a ``zenoh.Config`` (an invalid key or value raises ValueError).

    ``hub`` matters only for the embedded default (no endpoints, no config file, not a client):
    True binds the rendezvous, False connects to it; None decides by whether the rendezvous
    port is free now (:func:`open_session` tries the hub and falls back, which has no race).
    """
    conf = zenoh.Config.from_file(settings.config) if settings.config else zenoh.Config()

    def put(key: str, value: object) -> None:
        try:
            conf.insert_json5(key, json.dumps(value))
        except Exception as exc:  # zenoh raises its own ZError
            raise ValueError(f"zenoh config {key}={value!r}: {exc}") from None

    put("mode", settings.mode)
    put("scouting/multicast/enabled", settings.multicast_scouting)
    put("transport/shared_memory/enabled", settings.shared_memory)
    put("transport/link/tx/lease", settings.lease_ms)
    put(
        "transport/link/tx/queue/congestion_control/drop/wait_before_drop",
        int(settings.drop_wait_ms * 1000),  # microseconds
    )
    connect, listen = list(settings.connect), list(settings.listen)
    if is_embedded_default(settings):
        # The embedded default: one rendezvous port on loopback. The hub binds it; the others
        # connect to it and listen on a port of their own, through which gossip meshes the
        # peers directly. A peer keeps retrying its connect endpoint, so when a hub dies, the
        # next process to start becomes the hub and everyone finds it again.
        if hub is None:
            hub = _rendezvous_free()
        if hub:
            listen = [DEFAULT_ENDPOINT]
            # fail to open rather than run alone when another process won the port
            put("listen/exit_on_failure", True)
        else:
            connect, listen = [DEFAULT_ENDPOINT], ["tcp/127.0.0.1:0"]
            put("listen/exit_on_failure", False)
    elif settings.mode == "client" and not connect:
        connect = [DEFAULT_ENDPOINT]
    if connect:
        put("connect/endpoints", connect)
        if settings.connect or settings.mode == "client":
            put("connect/timeout_ms", int(settings.connect_timeout_s * 1000))
    if listen:
        put("listen/endpoints", listen)
    elif settings.mode != "client" and isinstance(
        json.loads(conf.get_json("listen/endpoints")), dict
    ):
        # Nothing says where to listen (a mode-dependent dict is zenoh's own default: every
        # interface, tcp/[::]). Listen on loopback only; with TLS on, nowhere (a plain
        # listener would admit peers without a certificate).
        loopback = DEFAULT_ENDPOINT if settings.mode == "router" else "tcp/127.0.0.1:0"
        put("listen/endpoints", [] if settings.tls.enabled else [loopback])
    endpoints = [*settings.connect, *settings.listen]
    for key, value in zenoh_entries(settings.tls, settings.auth, settings.access, endpoints):
        put(key, value)
    return conf


def is_embedded_default(settings: ZenohSettings) -> bool:
    """Whether ``settings`` leave the topology to the embedded default (docs/runtime.md)."""
    return (
        not settings.connect
        and not settings.listen
        and not settings.config
        and settings.mode != "client"
    )


def free_loopback_endpoint() -> str:
    """A TCP endpoint on loopback whose port is free right now (tests, demo, bench)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _rendezvous_free() -> bool:
    """Whether nobody listens on DEFAULT_ENDPOINT yet."""
    host, port = DEFAULT_ENDPOINT.removeprefix("tcp/").rsplit(":", 1)
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, int(port)))
        except OSError:
            return False
    return True


def open_session(settings: ZenohSettings) -> zenoh.Session:
    """Open a session; the caller must close it (``with open_session(s) as session:``)."""
    global _zenoh_logging_started
    if not _zenoh_logging_started:
        # Zenoh's own (Rust) log goes to stdout only for errors unless RUST_LOG says otherwise.
        zenoh.init_log_from_env_or("error")
        _zenoh_logging_started = True
    try:
        if is_embedded_default(settings) and _rendezvous_free():
            # Try to be the hub. Two processes starting together may both have seen the port
            # free: the one whose bind fails connects to the winner instead of running alone.
            try:
                return zenoh.open(zenoh_config(settings, hub=True))
            except zenoh.ZError:
                pass
            return zenoh.open(zenoh_config(settings, hub=False))
        return zenoh.open(zenoh_config(settings))
    except Exception as exc:
        raise SessionError(
            f"cannot open a zenoh session (mode={settings.mode}, connect={settings.connect}, "
            f"listen={settings.listen}): {exc}"
        ) from None


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """The options zenoh's own tools take: --mode --connect --listen --config (+ ours)."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--mode", choices=["peer", "client", "router"], help="zenoh mode (peer)")
    g.add_argument(
        "-e",
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to connect to, e.g. tcp/192.168.1.10:7447 (repeatable)",
    )
    g.add_argument(
        "-l",
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="endpoint to listen on, e.g. tcp/192.168.1.10:7447 (repeatable; default: "
        "loopback only)",
    )
    g.add_argument("--zenoh-config", metavar="FILE", help="a zenoh JSON5 configuration file")
    g.add_argument(
        "--identity",
        metavar="DIR/NAME",
        help="secure deployment: connect as identity NAME with the files `followbot certs` "
        "wrote to DIR (NAME.pem, NAME.key, NAME.password, ca.pem), e.g. certs/operator",
    )
    g.add_argument("--robot", help="robot name; keys live under followbot/<robot>/")


def overrides_from_args(args: argparse.Namespace) -> list[str]:
    """Turn the zenoh CLI options into ``--set`` style overrides (applied last)."""
    out: list[str] = []
    if getattr(args, "mode", None):
        out.append(f"zenoh.mode={args.mode}")
    if getattr(args, "connect", None):
        out.append(f"zenoh.connect={json.dumps(args.connect)}")
    if getattr(args, "listen", None):
        out.append(f"zenoh.listen={json.dumps(args.listen)}")
    if getattr(args, "zenoh_config", None):
        out.append(f"zenoh.config={json.dumps(args.zenoh_config)}")
    if getattr(args, "robot", None):
        out.append(f"robot={json.dumps(args.robot)}")
    if getattr(args, "identity", None):
        folder, name = os.path.split(args.identity)
        files = {"tls.ca": "ca.pem", "tls.cert": f"{name}.pem", "tls.key": f"{name}.key",
                 "auth.password_file": f"{name}.password"}  # fmt: skip
        for key, file in files.items():
            out.append(f"zenoh.{key}={json.dumps(os.path.join(folder, file))}")
        out.append(f"zenoh.auth.user={json.dumps(name)}")
    return out
