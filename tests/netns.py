"""Two test hosts on one machine: Linux network namespaces joined by a veth pair.

``two_hosts()`` makes namespaces ``<id>_robot`` and ``<id>_offboard`` with addresses
10.<a>.<b>.1 and .2 on a private /24 that exists only between them, loopback up, and removes
them afterwards. ``one_host()`` makes one namespace with only its loopback: a machine of its
own whose rendezvous port (the embedded default's 127.0.0.1:7447) no other test or program
can hold. Needs root and iproute2; :func:`unavailable` says why not, for a skip.
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
from contextlib import contextmanager
from dataclasses import dataclass


@dataclass
class Host:
    name: str
    netns: str
    address: str

    def argv(self, *cmd: str) -> list[str]:
        return ["ip", "netns", "exec", self.netns, *cmd]


def unavailable() -> str | None:
    if shutil.which("ip") is None:
        return "iproute2 (`ip`) is not installed"
    if os.geteuid() != 0:
        return "network namespaces need root"
    probe = f"fbprobe{os.getpid()}"
    r = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if r.returncode != 0:
        return f"`ip netns add` is not allowed here: {r.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


@contextmanager
def two_hosts():
    tag = f"fb{os.getpid() % 10000}{random.randrange(1000)}"
    a, b = random.randrange(200, 250), random.randrange(1, 254)
    robot = Host("robot", f"{tag}_robot", f"10.{a}.{b}.1")
    off = Host("offboard", f"{tag}_off", f"10.{a}.{b}.2")
    made: list[str] = []
    try:
        for h in (robot, off):
            _ip("netns", "add", h.netns)
            made.append(h.netns)
        _ip("link", "add", f"{tag}a", "type", "veth", "peer", "name", f"{tag}b")
        _ip("link", "set", f"{tag}a", "netns", robot.netns)
        _ip("link", "set", f"{tag}b", "netns", off.netns)
        for h, dev in ((robot, f"{tag}a"), (off, f"{tag}b")):
            _ip("-n", h.netns, "addr", "add", f"{h.address}/24", "dev", dev)
            _ip("-n", h.netns, "link", "set", dev, "up")
            _ip("-n", h.netns, "link", "set", "lo", "up")
        yield robot, off
    finally:
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


@contextmanager
def one_host():
    """A namespace with loopback up and nothing else (a private 127.0.0.1)."""
    host = Host("solo", f"fb{os.getpid() % 10000}{random.randrange(1000)}_solo", "127.0.0.1")
    _ip("netns", "add", host.netns)
    try:
        _ip("-n", host.netns, "link", "set", "lo", "up")
        yield host
    finally:
        subprocess.run(["ip", "netns", "del", host.netns], capture_output=True)
