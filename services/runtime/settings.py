"""Settings: typed, strictly validated, loaded from a file and ``--set key=value`` overrides.

Every service declares its settings as a msgspec Struct deriving from :class:`NodeSettings`
(``forbid_unknown_fields=True``: a mistyped key is an error that names it, never silently
ignored). Values come, in increasing priority, from the Struct's defaults, a YAML or JSON file
(``--config FILE``) and ``--set dotted.key=value`` pairs (the value is parsed as YAML, so
``--set zenoh.listen=[tcp/127.0.0.1:7000]`` and ``--set rate_hz=40`` work).

A setting that was removed or renamed stays known: a settings type lists it in its class
attribute ``retired_settings`` (dotted key -> what to do instead, see :func:`removed` and
:func:`renamed`), and a file or ``--set`` naming it fails with that message rather than
msgspec's bare "unknown field".
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import msgspec
import yaml

from .clock import ClockSettings
from .mount import LaserMount
from .security import AccessSettings, AuthSettings, TlsSettings

__all__ = [
    "DEFAULT_ENDPOINT",
    "NodeSettings",
    "SettingsError",
    "ZenohSettings",
    "apply_overrides",
    "load_settings",
    "removed",
    "renamed",
    "with_node_settings",
]

#: Loopback rendezvous of the embedded default: the first process binds it, the others connect.
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

S = TypeVar("S", bound=msgspec.Struct)


class SettingsError(ValueError):
    """A settings file or override that is not valid; the message names the key."""


class ZenohSettings(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """How a process joins the Zenoh network (same options as zenoh's own tools).

    With no endpoints at all, the embedded default applies: peer mode, multicast scouting off,
    listen on and connect to ``DEFAULT_ENDPOINT`` on loopback, so processes on one machine find
    each other with no router and no flags. Across machines name ``connect``/``listen``
    endpoints (or a router) explicitly.
    """

    mode: Literal["peer", "client", "router"] = "peer"
    """Zenoh session mode: ``peer`` talks to other peers directly, ``client`` only through
    the routers it connects to, ``router`` routes for others (the ``router`` service)."""
    connect: list[str] = []
    """Endpoints to connect to, e.g. ``tcp/192.168.1.10:7447``; empty with ``listen`` empty
    means the embedded loopback default (docs/runtime.md)."""
    listen: list[str] = []
    """Endpoints to listen on, e.g. ``tcp/192.168.1.10:7447``; empty: loopback only."""
    config: str | None = None
    """A zenoh JSON5 configuration file, applied first; the fields here override it."""
    multicast_scouting: bool = False
    """Discover peers by UDP multicast on the local network; off by default (the embedded
    default finds peers on loopback, and across machines endpoints are named)."""
    shared_memory: bool = False
    """Zenoh shared memory between processes of one host. Faster for images, but each
    publishing process leaves ~18 MiB of *.zenoh files in /dev/shm, so it is off by default."""
    connect_timeout_s: Annotated[float, msgspec.Meta(ge=0, le=3600)] = 10.0
    """How long opening a session keeps trying its connect endpoints (a router still starting)
    before it fails."""
    lease_ms: Annotated[int, msgspec.Meta(ge=100, le=600_000)] = 1000
    """Link lease: a hung peer's liveliness token expires after about this long."""
    drop_wait_ms: Annotated[float, msgspec.Meta(ge=0, le=10_000)] = 50.0
    """How long a drop-under-congestion publication waits for room in a link's queue before
    it is dropped (zenoh's wait_before_drop; its default is 1 ms). At 1 ms the stages lost
    about 1 output in 12 000 at 200 scans/s whenever another process took the CPU for a
    moment (make soak); a congested link, not a busy scheduler, should be what drops."""
    # Security (security.py; docs/compose.md "Secure deployment"): all off by default.
    tls: TlsSettings = msgspec.field(default_factory=TlsSettings)
    """Mutual TLS: ca, cert, key (PEM files); endpoints must then be tls/host:port."""
    auth: AuthSettings = msgspec.field(default_factory=AuthSettings)
    """Zenoh user/password: user + password_file, or (router) dictionary_file."""
    access: AccessSettings = msgspec.field(default_factory=AccessSettings)
    """Router: access rules, robot + identities (identity -> roles); default deny."""


class NodeSettings(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """Settings every service has."""

    robot: str = "robot"
    """Robot name: every key lives under followbot/<robot>/ (letters, digits, '_', '-')."""
    zenoh: ZenohSettings = msgspec.field(default_factory=ZenohSettings)
    health_period_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 1.0
    """Seconds between two health messages of this process (followbot/<robot>/health/...)."""
    clock: ClockSettings = msgspec.field(default_factory=ClockSettings)
    """How the stamps of received messages are judged (docs/runtime.md, "Clocks")."""
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    """Lowest level of log line written to stderr."""
    laser_mount: LaserMount = LaserMount()
    """Where the laser sits on the robot: {x_m, y_m, yaw_deg} in the base frame (REP-103; one
    value for the whole robot, written once at the top of a compose or group settings file:
    docs/robot.md). Candidates are turned from the laser frame into the base frame with it."""

    def __post_init__(self) -> None:
        from followbot.schemas import Keys

        Keys(self.robot)  # a name that cannot be a key chunk is refused here, with the rule


def removed(why: str) -> str:
    """The ``retired_settings`` entry of a setting that is gone without a replacement."""
    return f"was removed ({why}); delete it from your settings"


def renamed(new_key: str) -> str:
    """The ``retired_settings`` entry of a setting that now lives at ``new_key`` (dotted)."""
    return f"was renamed: set {new_key} instead"


def _check_retired(settings_type: type, layer: Mapping[str, Any], source: str) -> None:
    """Refuse a settings layer that names a key ``settings_type`` lists as retired."""
    table: Mapping[str, str] = getattr(settings_type, "retired_settings", None) or {}
    for key, note in table.items():
        node: Any = layer
        *sections, last = key.split(".")
        for part in sections:
            node = node.get(part) if isinstance(node, Mapping) else None
        if isinstance(node, Mapping) and last in node:
            raise SettingsError(f"{source}: {key} {note}")


def with_node_settings(core: type[msgspec.Struct], name: str, module: str) -> type[NodeSettings]:
    """NodeSettings plus every field of ``core``, flat (``--set estimator=ukf``): the settings
    type of a service whose logic lives in ``core`` (tracker, controller); ``core``'s
    ``retired_settings`` carry over."""
    spec = []
    for f in msgspec.structs.fields(core):
        if f.default is msgspec.NODEFAULT:
            spec.append((f.name, f.type, msgspec.field(default_factory=f.default_factory)))
        else:
            spec.append((f.name, f.type, f.default))
    retired = {
        "retired_settings": dict(getattr(core, "retired_settings", None) or {}),
        # where the fields are declared (and documented): followbot settings reads it
        "core_settings": core,
    }
    return msgspec.defstruct(
        name,
        spec,
        bases=(NodeSettings,),
        kw_only=True,
        forbid_unknown_fields=True,
        module=module,
        namespace=retired,
    )


class _Loader(yaml.SafeLoader):
    """YAML with only ``true``/``false`` (any case) as booleans, as YAML 1.2 has it: PyYAML
    follows YAML 1.1, where ``off``, ``on``, ``yes``, ``no`` are booleans too, so a setting
    whose value is the word ``off`` (``learn.source: off``) arrived as ``False``."""


_Loader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF")
)


def load_yaml(text: str) -> Any:
    """``text`` as YAML with YAML 1.2's booleans (:class:`_Loader`)."""
    return yaml.load(text, Loader=_Loader)  # a SafeLoader: no arbitrary objects


def _parse_file(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text()
    except OSError as exc:
        raise SettingsError(f"cannot read settings file {path}: {exc.strerror}") from None
    try:
        data = json.loads(text) if path.suffix == ".json" else load_yaml(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        kind = "JSON" if path.suffix == ".json" else "YAML"
        raise SettingsError(f"{path}: not valid {kind}: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise SettingsError(f"{path}: expected a mapping of settings, got {type(data).__name__}")
    return data


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``dotted.key=value`` overrides (values parsed as YAML) to a nested dict."""
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise SettingsError(f"--set expects key=value, got {item!r}")
        try:
            value = load_yaml(raw) if raw.strip() else ""
        except yaml.YAMLError as exc:
            raise SettingsError(f"--set {key}: value {raw!r} is not valid YAML: {exc}") from None
        node = data
        parts = key.strip().split(".")
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise SettingsError(f"--set {key}: {part!r} is not a section")
            node = child
        node[parts[-1]] = value
    return data


def load_settings(
    settings_type: type[S],
    config_file: str | Path | None = None,
    overrides: list[str] | None = None,
    base: dict[str, Any] | None = None,
) -> S:
    """Build ``settings_type`` from defaults, ``base``, a file and overrides; validate strictly.

    Each layer is merged key by key into the one below, so a partial section (``zenoh:
    {connect: [...]}``) keeps the service's other defaults in that section.
    """
    try:
        data: dict[str, Any] = msgspec.to_builtins(settings_type())
    except TypeError:  # a settings type with required fields: start from nothing
        data = {}
    _check_retired(settings_type, dict(base or {}), "settings")
    _merge(data, dict(base or {}))
    source = "settings"
    if config_file is not None:
        layer = _parse_file(Path(config_file))
        _check_retired(settings_type, layer, str(config_file))
        _merge(data, layer)
        source = str(config_file)
    _check_retired(settings_type, apply_overrides({}, list(overrides or [])), "--set")
    apply_overrides(data, list(overrides or []))
    try:
        return msgspec.convert(data, settings_type, strict=False)
    except msgspec.ValidationError as exc:
        raise SettingsError(f"{source}: {_explain(exc)}") from None


def _merge(into: dict[str, Any], layer: dict[str, Any]) -> None:
    for key, value in layer.items():
        if isinstance(value, dict) and isinstance(into.get(key), dict):
            _merge(into[key], value)
        else:
            into[key] = value


def _explain(exc: msgspec.ValidationError) -> str:
    """msgspec says ``... - at `$.zenoh.mode```; make the path read like the dotted key."""
    text = str(exc)
    head, sep, path = text.rpartition(" - at `$")
    if sep:
        dotted = path.rstrip("`").lstrip(".") or "(top level)"
        return f"{dotted}: {head}"
    return text
