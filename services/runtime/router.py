"""router: a Zenoh router as a followbot service, for deployments across machines.

There is no ``zenohd`` on the package registries; this is a Python process in router mode.
By default it listens on loopback only (tcp/127.0.0.1:7447); to serve other machines name the
address they reach it at, and point every service at it, e.g. ``--mode client --connect
tcp/<router-host>:7447``, or use peers with ``--connect``. It publishes Health and a
liveliness token like any service. With ``zenoh.tls``, ``zenoh.auth`` and ``zenoh.access`` it
admits only processes with a certificate of the deployment's CA and enforces who may publish
what (docs/compose.md, "Secure deployment").

    followbot run router                                   # tcp/127.0.0.1:7447
    followbot run router --listen tcp/192.168.1.10:7447    # the robot's address on the LAN

In peer mode (``--mode peer``) it is a member of a peer mesh that also serves clients on its
listen endpoints: ``followbot up`` runs it so, joined to this machine's rendezvous, as the
hub its services connect to. A Zenoh router linked to one peer of a mesh does not reach that
peer's other peers (measured with zenoh 1.10: no data or liveliness crossed); a peer does.
"""

from __future__ import annotations

import msgspec

from .node import Node
from .service import service_main
from .settings import DEFAULT_ENDPOINT, NodeSettings, ZenohSettings

__all__ = ["RouterSettings", "main"]


def _router_zenoh() -> ZenohSettings:
    return ZenohSettings(mode="router", listen=[DEFAULT_ENDPOINT])


class RouterSettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    zenoh: ZenohSettings = msgspec.field(default_factory=_router_zenoh)


def setup(node: Node, settings: RouterSettings) -> None:
    if settings.zenoh.mode == "client":
        raise ValueError("the router service needs zenoh.mode=router (or peer), got client")
    node.log.info(
        "routing on %s (%s mode)",
        ", ".join(settings.zenoh.listen) or "(no listen endpoint)",
        settings.zenoh.mode,
    )


def main(argv: list[str] | None = None) -> int:
    return service_main("router", RouterSettings, setup, argv, __doc__)
