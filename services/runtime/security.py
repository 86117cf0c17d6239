"""Zenoh security from followbot's settings: mutual TLS, user/password, access rules.

Three sections of :class:`~.settings.ZenohSettings` (docs/compose.md, "Secure deployment"):

    zenoh:
      tls:    {ca: certs/ca.pem, cert: certs/tracker.pem, key: certs/tracker.key}
      auth:   {user: tracker, password_file: certs/tracker.password}
      access: {robot: r1, identities: {tracker: [tracker], operator: [operator]}}   # router

``tls`` turns on mutual TLS: a process shows its certificate (whose common name is its
*identity*) and accepts only peers whose certificate the CA signed; endpoints are then
``tls/host:port``. ``auth`` adds Zenoh's user/password check (the router holds the
``dictionary_file`` of every user). ``access`` makes the router enforce, per identity, which
keys it may publish, answer queries on, ask, and declare presence on; everything not allowed is
dropped (Zenoh's access control, default deny). The rights come from :data:`ROLES`: an identity
plays one or more roles, the services it runs (a process running laser_legs+tracker+controller
plays all three) or ``operator`` (``followbot target``, ``record``, ``monitor``).

``followbot certs`` writes the files; ``followbot up`` fills these sections from a compose
file's ``security`` section (:func:`compose_security`). Nothing here imports zenoh: session.py
turns :func:`zenoh_entries` into the config.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

if TYPE_CHECKING:
    from .compose import Compose

__all__ = [
    "ROLES",
    "AccessSettings",
    "AuthSettings",
    "Role",
    "TlsSettings",
    "access_control",
    "check_identity",
    "compose_identities",
    "compose_security",
    "zenoh_entries",
]

_IDENTITY = re.compile(r"^[A-Za-z0-9_\-]{1,64}$")


@dataclass(frozen=True)
class Role:
    """What one role does on the network besides reading (every member may subscribe)."""

    publishes: tuple[str, ...] = ()
    """Topics it puts."""
    answers: tuple[str, ...] = ()
    """Topics whose last message it serves to queries (``serve_last``)."""
    asks: tuple[str, ...] = ()
    """Topics it queries."""
    nodes: tuple[str, ...] | None = None
    """Node names it publishes Health and a liveliness token as; None: the role's own name."""


_SENSORS = ("sensors/scan", "sensors/image", "sensors/odom")

#: Each role's rights. Every topic has one publishing role (sensors: whichever source runs:
#: sim, synthetic or the robot's own driver; odometry also laser_odometry; candidates
#: laser_legs, or camera_blobs in the camera-only preset); the tests check
#: this table against what each service declares.
ROLES: dict[str, Role] = {
    "sim": Role(publishes=(*_SENSORS, "sim/truth")),
    "synthetic": Role(publishes=_SENSORS),
    "driver": Role(publishes=_SENSORS, nodes=()),  # a real robot's driver: sensors only
    # odometry from the scans, on a robot whose driver has none (its driver then does not
    # publish sensors/odom)
    "laser_odometry": Role(publishes=("sensors/odom",)),
    "laser_legs": Role(publishes=("perception/candidates",)),
    # the camera-only preset's candidate source, in laser_legs' place (one of the two runs)
    "camera_blobs": Role(publishes=("perception/candidates",)),
    "vision_verify": Role(
        publishes=("perception/verification", "perception/target_model"),
        answers=("perception/target_model",),
        asks=("perception/target_model",),
    ),
    "tracker": Role(
        publishes=("tracking/target", "tracking/people"), answers=("perception/target_model",)
    ),
    "controller": Role(publishes=("control/cmd_vel", "control/pan")),
    "router": Role(),
    "monitor": Role(),
    # a person at a console: target acquire/reset/save/load, and watching (record, monitor)
    "operator": Role(
        publishes=("perception/target_command",), nodes=("target_cli", "record", "monitor")
    ),
}


class TlsSettings(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """Mutual TLS. All three files, or none (off)."""

    ca: str | None = None
    """The CA certificate (PEM) that signed every certificate of the deployment."""
    cert: str | None = None
    """This process's certificate (PEM); its common name is the process's identity."""
    key: str | None = None
    """The certificate's private key (PEM)."""
    verify_name: bool = True
    """When connecting, check that the router's certificate names the address dialled."""

    @property
    def enabled(self) -> bool:
        return any((self.ca, self.cert, self.key))


class AuthSettings(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """Zenoh's user/password authentication."""

    user: str | None = None
    """The user this process logs in as (its identity)."""
    password_file: str | None = None
    """A file holding the password (its first line)."""
    dictionary_file: str | None = None
    """Router: the ``user:password`` lines of every user it admits (``followbot certs``'
    users.txt); a process that connects without one of them is refused."""

    @property
    def enabled(self) -> bool:
        return any((self.user, self.password_file, self.dictionary_file))


class AccessSettings(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """Router: who may do what on ``followbot/<robot>/``; everything else is dropped."""

    robot: str | None = None
    """The robot whose keys the rules cover."""
    identities: dict[str, list[str]] = {}
    """Identity (certificate common name, and user when ``auth`` is on) -> the roles it plays
    (see ROLES: service names, ``operator``, ``driver``). Empty: no access control."""

    @property
    def enabled(self) -> bool:
        return bool(self.identities)


def check_identity(name: str) -> str:
    """An identity is one key chunk and one file name: letters, digits, '_' and '-'."""
    if not _IDENTITY.match(name):
        raise ValueError(
            f"identity {name!r} must be 1-64 characters of letters, digits, '_' or '-' "
            "(it is a certificate common name, a user name and a file name)"
        )
    return name


def _file(field: str, path: str) -> str:
    if not Path(path).is_file():
        raise ValueError(
            f"zenoh.{field}: no file {path} (make the certificates with `followbot certs`)"
        )
    return str(Path(path).resolve())


def zenoh_entries(
    tls: TlsSettings, auth: AuthSettings, access: AccessSettings, endpoints: list[str]
) -> list[tuple[str, object]]:
    """Zenoh config (key, value) pairs for the three sections; ``endpoints`` are the process's
    connect and listen endpoints (with TLS on, each must be ``tls/``). Raises ValueError with
    the setting's name for anything missing or inconsistent."""
    out: list[tuple[str, object]] = []
    if tls.enabled:
        missing = [f for f in ("ca", "cert", "key") if not getattr(tls, f)]
        if missing:
            raise ValueError(f"zenoh.tls: ca, cert and key go together; missing {missing[0]}")
        plain = [e for e in endpoints if not e.startswith("tls/")]
        if plain or not endpoints:
            raise ValueError(
                "zenoh.tls is on, so every connect/listen endpoint must be tls/host:port "
                f"(a plain one lets peers in without a certificate); got {plain or 'none'}"
            )
        ca, cert, key = (_file(f"tls.{f}", getattr(tls, f)) for f in ("ca", "cert", "key"))
        out += [
            ("transport/link/tls/root_ca_certificate", ca),
            ("transport/link/tls/enable_mtls", True),
            # one certificate both ways: shown when listening and when connecting
            ("transport/link/tls/listen_certificate", cert),
            ("transport/link/tls/listen_private_key", key),
            ("transport/link/tls/connect_certificate", cert),
            ("transport/link/tls/connect_private_key", key),
            ("transport/link/tls/verify_name_on_connect", tls.verify_name),
        ]
    if auth.enabled:
        if bool(auth.user) != bool(auth.password_file):
            raise ValueError("zenoh.auth: user and password_file go together")
        if auth.user:
            check_identity(auth.user)
            text = Path(_file("auth.password_file", auth.password_file)).read_text()
            password = text.strip().splitlines()[0].strip() if text.strip() else ""
            if not password:
                raise ValueError(f"zenoh.auth.password_file: {auth.password_file} is empty")
            out += [
                ("transport/auth/usrpwd/user", auth.user),
                ("transport/auth/usrpwd/password", password),
            ]
        if auth.dictionary_file:
            path = _file("auth.dictionary_file", auth.dictionary_file)
            out.append(("transport/auth/usrpwd/dictionary_file", path))
    if access.enabled:
        if not tls.enabled and not auth.dictionary_file:
            raise ValueError(
                "zenoh.access needs zenoh.tls (identities are certificate common names) or "
                "zenoh.auth.dictionary_file (identities are user names)"
            )
        out.append(
            ("access_control", access_control(access, by_cert=tls.enabled, by_user=auth.enabled))
        )
    return out


def access_control(
    access: AccessSettings, *, by_cert: bool = True, by_user: bool = True
) -> dict[str, Any]:
    """Zenoh's ``access_control`` section: default deny; every identity may read (subscribe,
    watch presence, receive); each may publish, answer, ask and declare presence only as its
    roles say. An identity is matched by certificate common name and/or user name (both must
    match when both are on)."""
    from followbot.schemas.keys import Keys

    if not access.robot:
        raise ValueError("zenoh.access.robot: name the robot whose keys the rules cover")
    keys = Keys(access.robot)
    rules: list[dict[str, Any]] = [
        _rule("read", "ingress", ["declare_subscriber", "declare_liveliness_subscriber",
                                  "liveliness_query"], [f"{keys.root}/**"]),
        # What the router passes on to a member: samples, presence, queries and their
        # replies, and the declarations that let publishers see their subscribers.
        _rule("deliver", "egress", ["put", "declare_subscriber", "liveliness_token",
                                    "declare_queryable", "query", "reply",
                                    "declare_liveliness_subscriber", "liveliness_query"],
              [f"{keys.root}/**"]),
    ]  # fmt: skip
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    members = []
    for identity, roles in sorted(access.identities.items()):
        check_identity(identity)
        unknown = [r for r in roles if r not in ROLES]
        if unknown:
            raise ValueError(
                f"zenoh.access.identities.{identity}: unknown role {unknown[0]!r}; roles: "
                f"{', '.join(sorted(ROLES))}"
            )
        subject: dict[str, Any] = {"id": identity}
        if by_cert:
            subject["cert_common_names"] = [identity]
        if by_user:
            subject["usernames"] = [identity]
        subjects.append(subject)
        members.append(identity)
        own = []
        rights = _rights(keys, roles)
        for message, key_exprs in rights.items():
            rule_id = f"{identity}: {message}"
            rules.append(_rule(rule_id, "ingress", [message], key_exprs))
            own.append(rule_id)
        if own:
            policies.append({"id": f"{identity} writes", "rules": own, "subjects": [identity]})
    if members:
        policies.insert(0, {"id": "members read", "rules": ["read", "deliver"],
                            "subjects": members})  # fmt: skip
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _rights(keys, roles: list[str]) -> dict[str, list[str]]:
    """Message kind -> the keys on which roles ``roles`` together may send it."""
    out: dict[str, list[str]] = {}

    def add(message: str, key: str) -> None:
        out.setdefault(message, [])
        if key not in out[message]:
            out[message].append(key)

    for name in roles:
        role = ROLES[name]
        for topic in role.publishes:
            add("put", keys.topic(topic))
        for topic in role.answers:
            add("declare_queryable", keys.topic(topic))
            add("reply", keys.topic(topic))
        for topic in role.asks:
            add("query", keys.topic(topic))
        for node in (name,) if role.nodes is None else role.nodes:
            add("put", keys.health(node))
            add("liveliness_token", keys.alive(node))
    return out


def _rule(rule_id: str, flow: str, messages: list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": [flow],
        "messages": messages,
        "key_exprs": key_exprs,
    }


# ----------------------------------------------------------------------------- compose files


class SecuritySpec(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """A compose file's ``security`` section (docs/compose.md, "Secure deployment")."""

    certs: str
    """The folder ``followbot certs`` wrote (ca.pem, <identity>.pem/.key/.password,
    users.txt); relative paths are from where ``followbot up`` runs."""
    router: str = "router"
    """The entry that routes and enforces the access rules (its identity holds users.txt)."""
    identities: dict[str, list[str]] = msgspec.field(
        default_factory=lambda: {"operator": ["operator"]}
    )
    """Identities that are not processes of this file, and their roles (ROLES): by default
    the operator's, for ``followbot target``."""


def compose_identities(compose: Compose) -> tuple[dict[str, list[str]], str]:
    """Every identity of a compose file -> its roles, and the router's identity. A process is
    one identity (one Zenoh session), named after the process, playing each service it runs."""
    security = compose.security or SecuritySpec(certs="")
    out: dict[str, list[str]] = {}
    for name, spec in compose.services.items():
        identity = check_identity(spec.process or name)
        out.setdefault(identity, []).append(spec.service or name)
    for identity, roles in security.identities.items():
        check_identity(identity)
        if identity in out:
            raise ValueError(
                f"{compose.path}: security.identities.{identity}: already a process of the file"
            )
        out[identity] = list(roles)
    for identity, roles in out.items():
        unknown = [r for r in roles if r not in ROLES]
        if unknown:
            raise ValueError(
                f"{compose.path}: {identity}: role {unknown[0]!r} has no access rights defined "
                f"(known: {', '.join(sorted(ROLES))})"
            )
    spec = compose.services.get(security.router)
    if compose.security is not None and spec is None:
        raise ValueError(
            f"{compose.path}: security.router: no service {security.router!r} in the file"
        )
    router = (spec.process or security.router) if spec is not None else security.router
    return out, router


def compose_security(compose: Compose, name: str) -> dict[str, Any]:
    """The ``zenoh`` settings the compose file's security section gives entry ``name`` (empty
    without one): its identity's certificate and password, and for the router also the users'
    dictionary and the access rules for every identity of the file."""
    security = compose.security
    if security is None:
        return {}
    identities, router = compose_identities(compose)
    spec = compose.services[name]
    identity = spec.process or name
    folder = Path(security.certs)
    files = {"ca": folder / "ca.pem", "cert": folder / f"{identity}.pem",
             "key": folder / f"{identity}.key"}  # fmt: skip
    password = folder / f"{identity}.password"
    needed = [*files.values(), folder / "users.txt" if identity == router else password]
    missing = [p for p in needed if not p.is_file()]
    if missing:
        raise ValueError(
            f"{compose.path}: security.certs: no {missing[0]} for {name!r}; make them with "
            f"`followbot certs {folder} --compose {compose.path}` (see docs/compose.md)"
        )
    zenoh: dict[str, Any] = {"tls": {k: str(p.resolve()) for k, p in files.items()}}
    if identity == router:  # checks the others' passwords; connects to nobody
        zenoh["auth"] = {"dictionary_file": str((folder / "users.txt").resolve())}
        zenoh["access"] = {"robot": compose.robot, "identities": identities}
    else:
        zenoh["auth"] = {"user": identity, "password_file": str(password.resolve())}
    return {"zenoh": zenoh}
