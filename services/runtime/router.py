"""router: a Zenoh router as a followbot service, for deployments across machines.

There is no ``zenohd`` on the package registries; this is a Python process in router mode.
Run one where every machine can reach it (by default it listens on all interfaces, port 7447)
and point every service at it, e.g. ``--mode client --connect tcp/<router-host>:7447``, or use
peers with ``--connect``. It publishes Health and a liveliness token like any service.

    followbot run router                                   # tcp/0.0.0.0:7447
    followbot run router --listen tcp/127.0.0.1:7500       # loopback only, another port

In peer mode (``--mode peer``) it is a member of a peer mesh that also serves clients on its
listen endpoints: ``followbot up`` runs it so, joined to this machine's rendezvous, as the
hub its services connect to. A Zenoh router linked to one peer of a mesh does not reach that
peer's other peers (measured with zenoh 1.10: no data or liveliness crossed); a peer does.
"""

from __future__ import annotations

import msgspec

from .node import Node
from .service import service_main
from .settings import NodeSettings, ZenohSettings

__all__ = ["RouterSettings", "main"]


def _router_zenoh() -> ZenohSettings:
    return ZenohSettings(mode="router", listen=["tcp/0.0.0.0:7447"])


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
