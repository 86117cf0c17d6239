"""Deployment files: which services run where, with which settings (docs/compose.md).

A compose file is YAML, validated strictly (an unknown key is an error naming it)::

    name: sim
    robot: robot
    laser_mount: {x_m: 0.3, y_m: 0, yaw_deg: 0}   # where the laser sits (every service)
    preset: thesis                 # thesis | bellotto | livingston | ristic | zhuang
    zenoh: {mode: peer}            # defaults for every service
    hosts:                         # optional: per-machine zenoh settings
      robot:    {zenoh: {listen: [tcp/192.168.1.10:7447]}}
      offboard: {zenoh: {connect: [tcp/192.168.1.10:7447]}}
    services:
      sim:        {settings: {scenario: thesis_5_2_1_arc}, stop_all_on_exit: true}
      laser_legs: {}
      vision_verify: {host: offboard}
      tracker:    {restart: always}
    security: {certs: certs}       # optional: TLS, passwords, access rules (security.py)

Settings of a service are merged, lowest first: the file's ``robot`` and ``laser_mount``, the
preset's choices for it, the file's ``zenoh``, its host's ``zenoh``, what the ``security``
section gives it (security.py), then the service's own ``settings``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
import yaml

from .security import SecuritySpec, compose_identities, compose_security
from .session import is_embedded_default
from .settings import ZenohSettings, _merge

__all__ = [
    "PRESETS",
    "Compose",
    "ComposeError",
    "RouterSpec",
    "ServiceSpec",
    "check_services",
    "client_of",
    "group_settings",
    "is_router",
    "load_compose",
    "on_embedded_default",
    "preset_settings",
    "process_groups",
    "reachable",
    "service_settings",
]

#: The seed systems as swappable parts (DESIGN.md "Presets"): service -> settings.
PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    # the defaults: the combination that does best on the real recordings (docs/benchmark.md),
    # what runs when no preset is named. The seed's parameters stay the settings' own defaults
    # (each with its seed section); this preset picks other implementations of some roles:
    # the learned leg detector (held-out recall 0.985 at 0.47 false candidates per scan,
    # against the thesis detector's 0.606 at 1.89), people confirmed on evidence of walking
    # (no person in the office logs), and a wider association gate for real legs' jitter;
    # the verifier that learns who it follows (PETS 2009 following rank-1 90.0 % against the
    # histogram's 63.1 %, someone else accepted 11.6 % against 78.4 %), whose probabilities
    # the tracker sums (docs/tracker_log.md "Issue 36": no time on a wrong person where votes
    # followed one for 12 s).
    "followbot": {
        "laser_legs": {"detector": "learned"},
        "vision_verify": {"verifier": "online"},
        "tracker": {
            "initiator": "evidence",
            "estimator_settings": {"gate_m": 0.5},
            "identity": {"vision_evidence": "probability"},
        },
    },
    "thesis": {  # seed 000, as published
        "laser_legs": {"detector": "thesis"},
        "vision_verify": {"verifier": "histogram"},
        "tracker": {"estimator": "particle"},
    },
    "bellotto": {  # seed 002
        "laser_legs": {"detector": "bellotto"},
        "vision_verify": {"verifier": "face"},
        "tracker": {"estimator": "ukf"},
    },
    "livingston": {  # seed 003
        "laser_legs": {"detector": "iav"},
        "vision_verify": {"verifier": "meanshift"},
        "tracker": {"estimator": "nearest"},
    },
    "ristic": {  # seed 004
        "laser_legs": {"detector": "derivative"},
        "vision_verify": {"verifier": "histogram"},
        "tracker": {"estimator": "kalman_window"},
    },
    # seed 001: the camera alone -- colour regions (camera_blobs, which needs the target's
    # colour: learn_rect or colour), the hybrid filter, the seed's rule. The first target is
    # the nearest region of the colour within 8 m ahead (the seed's user marks the target in
    # view); the seed backs off from a near person; the obstacle guard needs a laser, so it
    # is off (a laser that is present is ignored).
    "zhuang": {
        "camera_blobs": {},
        "tracker": {
            "estimator": "hybrid",
            "acquire": "nearest",
            "identity": {"acquire_range_m": 8.0},
        },
        "controller": {"rule": "zhuang", "limits": {"reverse": True}, "guard": {"enabled": False}},
    },
}

_NAME = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_\-]{1,64}$")]


class ComposeError(ValueError):
    """A compose file that cannot be used; the message names the file and the field."""


class HostSpec(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    zenoh: dict[str, Any] = {}


class ServiceSpec(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    service: str | None = None
    """The service to run (`followbot services`); defaults to the entry's name, so one service
    can run twice under two names."""
    host: _NAME = "local"
    settings: dict[str, Any] = {}
    restart: Literal["on-failure", "always", "never"] = "on-failure"
    stop_all_on_exit: bool = False
    """When this service exits 0 (e.g. the simulator at the scenario's end), stop everything."""
    process: _NAME | None = None
    """Services of one host with the same ``process`` run in one process (``followbot run
    a+b+c``, docs/runtime.md): messages between them skip the network. They must share their
    Zenoh settings, ``restart`` and ``stop_all_on_exit``."""


class RouterSpec(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    listen: str | None = None
    """Where the router ``followbot up`` starts listens (default: a free loopback port)."""


class Compose(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    name: str = "followbot"
    robot: _NAME = "robot"
    laser_mount: dict[str, Any] = {}
    """The laser's pose on the robot ({x_m, y_m, yaw_deg}), given to every service (each
    checks it: services/runtime/mount.py); empty: the laser frame is the base frame."""
    preset: Literal["followbot", "thesis", "bellotto", "livingston", "ristic", "zhuang"] | None = (
        None
    )
    """A system preset (PRESETS): the seed systems by name; none (or ``followbot``): the
    defaults."""
    zenoh: dict[str, Any] = {}
    hosts: dict[_NAME, HostSpec] = {}
    router: RouterSpec = msgspec.field(default_factory=RouterSpec)
    """The router ``up`` starts for the services whose settings name no Zenoh endpoints."""
    services: Annotated[dict[_NAME, ServiceSpec], msgspec.Meta(min_length=1)]
    security: SecuritySpec | None = None
    """Mutual TLS, passwords and access rules for every service (docs/compose.md, "Secure
    deployment"); none: plain TCP, anyone who reaches an endpoint may publish anything."""
    path: str = ""
    """Where the file was read from (set by load_compose)."""

    def hosts_named(self) -> list[str]:
        return sorted({s.host for s in self.services.values()})


def load_compose(path: str | Path) -> Compose:
    path = Path(path)
    try:
        text = expand_env(path.read_text(), path)
        data = yaml.safe_load(text)
    except OSError as exc:
        raise ComposeError(f"cannot read compose file {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ComposeError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ComposeError(f"{path}: expected a mapping with a 'services' section")
    # Entries of the services and hosts maps first, one by one, so an error names the entry.
    for section, spec_type in (("services", ServiceSpec), ("hosts", HostSpec)):
        entries = data.get(section)
        if isinstance(entries, dict):
            for key, entry in entries.items():
                if entry is None:
                    entries[key] = entry = {}
                _convert(path, entry, spec_type, f"{section}.{key}")
    compose = _convert(path, data, Compose, "")
    compose.path = str(path)
    _check_processes(path, compose)
    if compose.security is not None:
        try:
            compose_identities(compose)
        except ValueError as exc:
            raise ComposeError(str(exc)) from None
    for name, spec in compose.services.items():
        if spec.host != "local" and compose.hosts and spec.host not in compose.hosts:
            raise ComposeError(
                f"{path}: services.{name}.host: unknown host {spec.host!r}; "
                f"hosts: {', '.join(sorted(compose.hosts))}"
            )
    return compose


_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


def expand_env(text: str, path: Path | str = "compose file") -> str:
    """``${VAR}`` and ``${VAR:-default}`` from the environment (e.g. the robot's address in a
    split deployment); an unset variable without a default is an error naming it."""

    def sub(m: re.Match) -> str:
        value = os.environ.get(m.group(1))
        if value is None or value == "":
            if m.group(2) is None:
                raise ComposeError(
                    f"{path}: ${{{m.group(1)}}} is not set (set it, or write "
                    f"${{{m.group(1)}:-default}})"
                )
            return m.group(2)
        return value

    return _VAR.sub(sub, text)


def _convert(path: Path, data: Any, type_: type, where: str):
    try:
        return msgspec.convert(data, type_)
    except msgspec.ValidationError as exc:
        text = str(exc)
        head, sep, at = text.rpartition(" - at `$")
        field = ".".join(p for p in (where, at.rstrip("`").lstrip(".") if sep else "") if p)
        raise ComposeError(
            f"{path}: {field + ': ' if field else ''}{head if sep else text}"
        ) from None


def preset_settings(preset: str, service: str) -> dict[str, Any]:
    """The settings ``preset`` gives ``service`` (a copy; empty when the preset names none of
    them: the service keeps its own defaults). An unknown preset is a ValueError naming the
    presets there are."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; presets: {', '.join(PRESETS)}")
    return _deep_copy(PRESETS[preset].get(service, {}))


def service_settings(compose: Compose, name: str) -> dict[str, Any]:
    """The settings mapping one service is started with."""
    spec = compose.services[name]
    service = spec.service or name
    out: dict[str, Any] = {"robot": compose.robot}
    if compose.laser_mount:
        out["laser_mount"] = dict(compose.laser_mount)
    # no preset: the defaults, the followbot preset
    _merge(out, _deep_copy(PRESETS[compose.preset or "followbot"].get(service, {})))
    _merge(out, {"zenoh": dict(compose.zenoh)} if compose.zenoh else {})
    host = compose.hosts.get(spec.host)
    if host is not None and host.zenoh:
        _merge(out, {"zenoh": dict(host.zenoh)})
    try:
        _merge(out, compose_security(compose, name))  # this entry's certificate, password
    except ValueError as exc:
        raise ComposeError(str(exc)) from None
    _merge(out, _deep_copy(spec.settings))
    return out


def _check_processes(path: Path, compose: Compose) -> None:
    groups: dict[str, list[str]] = {}
    for name, spec in compose.services.items():
        if spec.process is not None:
            groups.setdefault(spec.process, []).append(name)
    for process, names in groups.items():
        specs = [compose.services[n] for n in names]
        where = f"{path}: services.{names[-1]}.process ({process!r})"
        if process in compose.services and process not in names:
            raise ComposeError(f"{where}: a process may not share the name of another service")
        for attr in ("host", "restart", "stop_all_on_exit"):
            if len({getattr(sp, attr) for sp in specs}) > 1:
                raise ComposeError(f"{where}: the services of one process need one {attr}")
        run = [sp.service or n for n, sp in zip(names, specs, strict=True)]
        if len(set(run)) != len(run):
            raise ComposeError(f"{where}: a process runs each service once")


def process_groups(compose: Compose, names: list[str]) -> list[tuple[str, list[str]]]:
    """(process name, the entries it runs) in file order; a service without ``process`` is a
    process of its own, named after it."""
    out: dict[str, list[str]] = {}
    for name in names:
        out.setdefault(compose.services[name].process or name, []).append(name)
    return list(out.items())


def group_settings(compose: Compose, names: list[str]) -> dict[str, Any]:
    """The settings file of a process that runs several entries (container.py's format): what
    they share at the top, each service's own keys in its section. Zenoh settings must agree."""
    each = {n: service_settings(compose, n) for n in names}
    first = each[names[0]]
    if any(e.get("zenoh", {}) != first.get("zenoh", {}) for e in each.values()):
        raise ComposeError(
            f"{compose.path}: services {', '.join(names)} share a process, so they need the "
            "same zenoh settings (preset, file, host and their own)"
        )
    shared = {k: v for k, v in first.items() if all(e.get(k) == v for e in each.values())}
    out: dict[str, Any] = dict(shared)
    for n in names:
        own = {k: v for k, v in each[n].items() if k not in shared}
        out[compose.services[n].service or n] = own
    return out


def check_services(compose: Compose, available: list[str]) -> None:
    """Every service named must be installed."""
    for name, spec in compose.services.items():
        service = spec.service or name
        if service not in available:
            raise ComposeError(
                f"{compose.path}: services.{name}: unknown service {service!r}; "
                f"installed: {', '.join(available)}"
            )


def _deep_copy(d: dict[str, Any]) -> dict[str, Any]:
    return msgspec.convert(msgspec.to_builtins(d), dict[str, Any])


# --------------------------------------------------------------------------- topology


def _zenoh_of(settings: dict[str, Any]) -> ZenohSettings | None:
    try:
        return msgspec.convert(settings.get("zenoh") or {}, ZenohSettings, strict=False)
    except msgspec.ValidationError:
        return None  # the service's own check reports it


def on_embedded_default(settings: dict[str, Any]) -> bool:
    """Whether a process started with ``settings`` (one service's, or a group's) would leave
    its topology to Zenoh's embedded default (no endpoints, no config file, not a client)."""
    z = _zenoh_of(settings)
    # with TLS, endpoints must be named (tls/...): a plain router would not admit it
    return z is not None and is_embedded_default(z) and not z.tls.enabled


def is_router(settings: dict[str, Any]) -> bool:
    z = _zenoh_of(settings)
    return z is not None and z.mode == "router"


def client_of(settings: dict[str, Any], endpoint: str) -> dict[str, Any]:
    """``settings`` with the process made a Zenoh client of the router at ``endpoint``."""
    out = _deep_copy(settings)
    out.setdefault("zenoh", {}).update(mode="client", connect=[endpoint])
    return out


def reachable(endpoint: str) -> str:
    """Where a process of this machine reaches a listen ``endpoint`` (a wildcard address is
    reached on loopback)."""
    proto, _, rest = endpoint.partition("/")
    host, sep, port = rest.rpartition(":")
    if sep and host in ("0.0.0.0", ""):
        host = "127.0.0.1"
    elif sep and host == "[::]":
        host = "[::1]"
    return f"{proto}/{host}{sep}{port}" if sep else endpoint
