"""``followbot up COMPOSE.yaml [--host NAME]``: start and supervise a deployment.

Before anything starts, every service checks its merged settings and every file it will load
(a scenario, a model) with its own code; ``--check`` stops there.

Topology: services whose settings name no Zenoh endpoints become clients of a router that
``up`` starts first (on a free loopback port, or the compose file's ``router.listen``) and
waits for, so no service can start cut off from the others. The router (the router service
in peer mode) is also a member of this machine's loopback rendezvous mesh (Zenoh's embedded
default), so ``followbot status``, ``target``, ``replay`` ... started with no flags reach the
deployment. Services whose settings name
endpoints keep them; router-mode services among them start first.

Then ``up`` refuses to start a service whose name is already alive on the bus (another
deployment, or the leftovers of one), naming its host and pid; ``--replace`` stops such
processes of this machine (SIGTERM, then SIGKILL) and starts anyway.

Supervision: logs prefixed with the service name (and in ``--log-dir``); a crashed service is
restarted (backoff 1 s -> 30 s, reset after 30 s of good running), one that exits 2 (bad
settings or files) is not; status changes on the bus (ok / degraded / error with reasons) and
services that appear or disappear are reported. The services end with ``up`` however it ends
(even SIGKILL). Ctrl-C or SIGTERM stops them all (SIGTERM, then SIGKILL after 5 s).

Exit codes: 0 after Ctrl-C/SIGTERM, or when a ``stop_all_on_exit`` service finished (exit 0);
1 when a ``stop_all_on_exit`` service ended with a failure, when every service ended and one
failed, when a service name is already alive, or when the router did not start; 2 for a bad
compose file, settings or file. See docs/compose.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import yaml

BACKOFF_S = (1.0, 30.0)
HEALTHY_AFTER_S = 30.0
STOP_GRACE_S = 5.0
#: How long `up` waits for a router to accept connections.
ROUTER_START_S = 20.0
#: How long `up` listens for services already alive before starting its own.
ALIVE_LISTEN_S = 1.0
#: How long it then waits for their Health, which names host and pid.
HEALTH_WAIT_S = 2.5
#: Name of the router `up` starts itself.
ROUTER = "router"


@dataclass
class Child:
    name: str
    service: str
    config: Path
    restart: str
    stop_all_on_exit: bool
    runs: list[str] = field(default_factory=list)
    """The services it runs (the names their liveliness tokens carry)."""
    router_at: list[str] = field(default_factory=list)
    """A router: the TCP endpoints it must accept connections on before the others start."""
    fallback: Callable[[], object] | None = field(default=None, repr=False)
    """A router that exits before it accepts connections: call this, then start it again."""
    proc: subprocess.Popen | None = None
    started: float = 0.0
    backoff: float = BACKOFF_S[0]
    restart_at: float | None = None
    done: bool = False
    failed: bool = False
    restarts: int = 0
    reader: threading.Thread | None = field(default=None, repr=False)


class Refused(Exception):
    """`up` will not go on (the message says why); exit code 1."""


class Supervisor:
    def __init__(self, children: list[Child], log_dir: Path, robot: str) -> None:
        from followbot.services.runtime.lifeline import Lifeline

        self.children = children
        self.log_dir = log_dir
        self.robot = robot
        self.width = max(len(c.name) for c in children)
        self._out = threading.Lock()
        self._stop: list[int] = []
        self.lifeline = Lifeline()
        self.watch = None  # followbot.status.BusWatch, once the bus is reachable

    def say(self, name: str, line: str) -> None:
        with self._out:
            sys.stdout.write(f"{name:<{self.width}} | {line}\n")
            sys.stdout.flush()

    def _pump(self, child: Child, proc: subprocess.Popen) -> None:
        with (self.log_dir / f"{child.name}.log").open("a") as log:
            for raw in proc.stdout:  # type: ignore[union-attr]
                line = raw.rstrip("\n")
                log.write(line + "\n")
                log.flush()
                self.say(child.name, line)

    def start(self, child: Child) -> None:
        cmd = [
            sys.executable,
            "-m",
            "followbot",
            "run",
            child.service,
            "--config",
            str(child.config),
        ]
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env.setdefault("RUST_LOG", "error")
        child.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True,  # Ctrl-C reaches the supervisor only; it stops the rest
            **self.lifeline.popen_kwargs(env),  # ... and they end when it dies, however
        )  # fmt: skip
        child.started = time.monotonic()
        child.restart_at = None
        child.reader = threading.Thread(target=self._pump, args=(child, child.proc), daemon=True)
        child.reader.start()
        self.say("up", f"started {child.name} (pid {child.proc.pid})")

    def stop(self, children: list[Child]) -> None:
        running = [c for c in children if c.proc and c.proc.poll() is None]
        for c in running:
            c.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        for c in running:
            try:
                c.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.say("up", f"{c.name} did not stop in {STOP_GRACE_S:.0f} s; killing it")
                c.proc.kill()
                c.proc.wait()
        for c in running:
            if c.reader:
                c.reader.join(timeout=2)

    def stop_all(self) -> None:
        """The services first, then the routers they talk through (so their tokens' removal
        still reaches everyone)."""
        self.stop([c for c in self.children if not c.router_at])
        self.stop([c for c in self.children if c.router_at])

    # ------------------------------------------------------------------ start-up

    def start_routers(self) -> None:
        """Start the routers and wait until each accepts connections (Refused if one ends or
        does not accept within ROUTER_START_S)."""
        routers = [c for c in self.children if c.router_at]
        for c in routers:
            self.start(c)
        for c in routers:
            deadline = time.monotonic() + ROUTER_START_S
            pending = list(c.router_at)
            while pending:
                if self._stop:  # Ctrl-C while waiting: run() stops what was started
                    return
                if c.proc.poll() is not None and c.fallback is not None:
                    c.reader.join(timeout=2)
                    c.fallback()
                    c.fallback = None
                    self.start(c)
                    continue
                if c.proc.poll() is not None:
                    c.reader.join(timeout=2)
                    raise Refused(f"{c.name} exited {c.proc.returncode} before accepting "
                                  f"connections on {', '.join(c.router_at)}")  # fmt: skip
                if time.monotonic() > deadline:
                    raise Refused(f"{c.name} did not accept connections on {pending[0]} "
                                  f"within {ROUTER_START_S:.0f} s")  # fmt: skip
                if _accepts(pending[0]):
                    pending.pop(0)
                else:
                    time.sleep(0.05)
            self.say("up", f"{c.name} accepts connections on {', '.join(c.router_at)}")

    def check_alive(self, replace: bool) -> None:
        """Refuse (or with ``replace``, stop) services of ours already alive on the bus."""
        if self.watch is None:
            return
        ours = {s for c in self.children if not c.router_at for s in c.runs}
        time.sleep(ALIVE_LISTEN_S)
        alive, _ = self.watch.snapshot()
        clash = sorted(ours & set(alive))
        if not clash:
            return
        self.watch.wait_for_health(set(clash), HEALTH_WAIT_S)
        _, health = self.watch.snapshot()
        where = {}
        for s in clash:
            h = health.get(s)
            where[s] = (h[0].host, h[0].pid) if h else (None, None)
        said = ", ".join(
            f"{s} (host {host}, pid {pid})" if host else f"{s} (host and pid unknown: no Health)"
            for s, (host, pid) in where.items()
        )
        if not replace:
            raise Refused(
                f"already alive on the bus for robot {self.robot!r}: {said}. Stop them first, "
                "or start with --replace"
            )
        self.say("up", f"--replace: already alive: {said}")
        self.replace(where)

    def replace(self, where: dict[str, tuple[str | None, int | None]]) -> None:
        here = socket.gethostname()[:256]  # as Health carries it
        pids = set()
        for s, (host, pid) in where.items():
            if host == here and pid and _is_followbot(pid):
                pids.add(pid)
            else:
                self.say("up", f"--replace: cannot stop {s} (host {host}, pid {pid}): not a "
                               "followbot process of this machine; it stays alive")  # fmt: skip
        for pid in sorted(pids):
            self.say("up", f"--replace: stopping pid {pid} (SIGTERM)")
            _signal(pid, signal.SIGTERM)
        deadline = time.monotonic() + STOP_GRACE_S
        while pids and time.monotonic() < deadline:
            pids = {p for p in pids if _exists(p)}
            time.sleep(0.1)
        for pid in sorted(pids):
            self.say("up", f"--replace: pid {pid} did not stop in {STOP_GRACE_S:.0f} s; killing it")
            _signal(pid, signal.SIGKILL)
        # wait for the old tokens to go, so the new ones are the only ones
        names = set(where)
        deadline = time.monotonic() + 2 * STOP_GRACE_S
        while time.monotonic() < deadline:
            alive, _ = self.watch.snapshot()
            if not names & set(alive):
                break
            time.sleep(0.1)

    # ------------------------------------------------------------------ supervision

    def report_bus(self) -> None:
        """Print what changed on the bus: services appearing and going, status changes."""
        if self.watch is None:
            return
        while not self.watch.events.empty():
            kind, service, health = self.watch.events.get_nowait()
            if kind == "alive":
                self.say("up", f"{service} is alive on the bus")
            elif kind == "gone":
                self.say("up", f"{service} is gone from the bus (liveliness lost)")
            else:
                why = f": {'; '.join(health.reasons)}" if health.reasons else ""
                self.say("up", f"{service} {health.status}{why}")

    def run(self, replace: bool = False, open_watch=None) -> int:
        previous = {
            s: signal.signal(s, lambda signum, _f: self._stop.append(signum))
            for s in (signal.SIGINT, signal.SIGTERM)
        }
        try:
            try:
                self.start_routers()
                if open_watch is not None:
                    self.watch = open_watch()
                if not self._stop:
                    self.check_alive(replace)
            except Refused as exc:
                print(f"followbot up: {exc}", file=sys.stderr, flush=True)
                self.stop_all()
                return 1
            for c in self.children:
                if not c.router_at and not self._stop:
                    self.start(c)
            while not self._stop:
                now = time.monotonic()
                self.report_bus()
                for c in self.children:
                    if c.done or c.failed:
                        continue
                    if c.restart_at is not None:
                        if now >= c.restart_at:
                            c.restarts += 1
                            self.start(c)
                        continue
                    code = c.proc.poll() if c.proc else None
                    if code is None:
                        if now - c.started > HEALTHY_AFTER_S:
                            c.backoff = BACKOFF_S[0]
                        continue
                    if c.reader:
                        c.reader.join(timeout=2)
                    if code == 0 and c.stop_all_on_exit:
                        self.say("up", f"{c.name} finished; stopping everything")
                        self.stop_all()
                        return 0
                    if code == 2:
                        self.say("up", f"{c.name} exited 2 (bad settings or files); not restarting")
                        c.failed = True
                    elif (code == 0 and c.restart != "always") or (
                        code != 0 and c.restart == "never"
                    ):
                        self.say("up", f"{c.name} exited {code}")
                        c.done, c.failed = code == 0, code != 0
                    else:
                        self.say("up", f"{c.name} exited {code}; restarting in {c.backoff:.0f} s")
                        c.restart_at = now + c.backoff
                        c.backoff = min(c.backoff * 2, BACKOFF_S[1])
                    if c.failed and c.stop_all_on_exit:
                        self.say("up", f"{c.name} failed and is stop_all_on_exit; stopping "
                                       "everything")  # fmt: skip
                        self.stop_all()
                        return 1
                services = [c for c in self.children if not c.router_at]
                if all(c.done or c.failed for c in services):
                    self.stop_all()
                    return 1 if any(c.failed for c in services) else 0
                time.sleep(0.1)
            self.say("up", "stopping")
            self.stop_all()
            return 0
        finally:
            for s, h in previous.items():
                signal.signal(s, h)
            if self.watch is not None:
                self.watch.close()
            self.lifeline.close()


def _accepts(endpoint: str) -> bool:
    """Whether a TCP endpoint (``tcp/host:port``) accepts a connection now."""
    host, _, port = endpoint.removeprefix("tcp/").rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=0.5):
            return True
    except (OSError, ValueError):
        return False


def _is_followbot(pid: int) -> bool:
    try:
        return b"followbot" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _signal(pid: int, sig: int) -> None:
    with contextlib.suppress(OSError):
        os.kill(pid, sig)


def _write_router_settings(log_dir: Path, robot: str, listen: str, hub: bool) -> Path:
    """The settings file of the router `up` starts: the router service in peer mode, serving
    its clients on ``listen`` and a member of this machine's rendezvous mesh, so processes
    started with no flags reach the deployment (a Zenoh router linked to the rendezvous would
    not reach the mesh's other peers: services/runtime/router.py). ``hub`` binds the rendezvous
    too, failing if another process has it; else the router connects to the rendezvous and
    keeps retrying. Both through a zenoh JSON5 file: the settings cannot say either."""
    from followbot.services.runtime.settings import DEFAULT_ENDPOINT

    zenoh: dict = {"mode": "peer", "listen": [listen], "connect": []}
    if hub:
        zenoh["listen"].append(DEFAULT_ENDPOINT)
        conf = {"listen": {"exit_on_failure": True}}
    else:
        conf = {"connect": {"endpoints": [DEFAULT_ENDPOINT], "timeout_ms": -1}}
    path = log_dir / f"{ROUTER}.zenoh.json5"
    path.write_text(json.dumps(conf) + "\n")
    zenoh["config"] = str(path)
    path = log_dir / f"{ROUTER}.settings.yaml"
    path.write_text(yaml.safe_dump({"robot": robot, "zenoh": zenoh}, sort_keys=False))
    return path


def _open_watch(robot: str, endpoints: list[str], client: bool):
    """A Zenoh session of `up` itself and a BusWatch on it (None, with a warning, if it
    cannot be opened). ``client``: of the router at ``endpoints``; else a peer that connects
    to ``endpoints`` and keeps retrying in the background (the services may start them)."""
    import zenoh

    from followbot.services.runtime.session import zenoh_config
    from followbot.services.runtime.settings import ZenohSettings
    from followbot.status import BusWatch

    try:
        if client:
            conf = zenoh_config(ZenohSettings(mode="client", connect=endpoints,
                                              connect_timeout_s=5))  # fmt: skip
        else:
            conf = zenoh_config(ZenohSettings(mode="peer", connect=endpoints,
                                              listen=["tcp/127.0.0.1:0"]))  # fmt: skip
            conf.insert_json5("connect/timeout_ms", "-1")
        session = zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError, ValueError from the config
        print(f"followbot up: cannot watch the bus at {', '.join(endpoints)}: {exc}",
              file=sys.stderr, flush=True)  # fmt: skip
        return None

    class Watch(BusWatch):
        def close(self) -> None:
            super().close()
            session.close()

    return Watch(session, robot)


def main(argv: list[str] | None = None) -> int:
    from followbot.services.runtime.compose import (
        ComposeError,
        check_services,
        client_of,
        group_settings,
        is_router,
        load_compose,
        on_embedded_default,
        process_groups,
        reachable,
        service_settings,
    )
    from followbot.services.runtime.plugins import Registry
    from followbot.services.runtime.session import free_loopback_endpoint

    p = argparse.ArgumentParser(
        prog="followbot up",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("compose", help="compose file (YAML; see docs/compose.md)")
    p.add_argument("--host", help="start only the services placed on this host")
    p.add_argument("--log-dir", default="out/up", help="per-service log files (out/up)")
    p.add_argument("--check", action="store_true",
                   help="validate the file, every service's settings and the files they load; "
                        "start nothing")  # fmt: skip
    p.add_argument("--replace", action="store_true",
                   help="stop this machine's followbot processes that run a service of ours "
                        "under the same robot, instead of refusing to start")  # fmt: skip
    args = p.parse_args(argv)
    try:
        compose = load_compose(args.compose)
        check_services(compose, Registry("services").names())
    except ComposeError as exc:
        print(f"followbot up: {exc}", file=sys.stderr)
        return 2
    names = [n for n, s in compose.services.items() if args.host in (None, s.host)]
    if not names:
        print(
            f"followbot up: no service of {args.compose} is placed on host {args.host!r}; "
            f"hosts: {', '.join(compose.hosts_named())}",
            file=sys.stderr,
        )
        return 2
    log_dir = Path(args.log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    router_listen = compose.router.listen or free_loopback_endpoint()
    router_endpoint = reachable(router_listen)
    children = []
    auto_router = False
    watch_at: list[str] = []
    for process, members in process_groups(compose, names):
        spec = compose.services[members[0]]
        config = log_dir / f"{process}.settings.yaml"
        runs = [compose.services[m].service or m for m in members]
        try:
            if len(members) == 1 and spec.process is None:
                settings = service_settings(compose, process)
            else:  # several services in one process (docs/runtime.md)
                settings = group_settings(compose, members)
        except ComposeError as exc:
            print(f"followbot up: {exc}", file=sys.stderr)
            return 2
        router_at = []
        if on_embedded_default(settings):
            settings = client_of(settings, router_endpoint)
            auto_router = True
        elif is_router(settings):
            listen = settings["zenoh"].get("listen") or []
            router_at = [reachable(e) for e in listen if str(e).startswith("tcp/")]
        zenoh = settings.get("zenoh") or {}
        watch_at += [reachable(e) for e in [*zenoh.get("connect", []), *zenoh.get("listen", [])]]
        config.write_text(yaml.safe_dump(settings, sort_keys=False))
        child = Child(process, "+".join(runs), config, spec.restart, spec.stop_all_on_exit, runs)
        child.router_at = router_at
        children.append(child)
    # Validate every service's merged settings and files the way the service itself will.
    # All at once: each is a Python start-up, some load models.
    checks = {}
    for c in children:
        cmd = [sys.executable, "-m", "followbot", "run", c.service, "--config", str(c.config)]
        checks[c.name] = subprocess.Popen(
            [*cmd, "--print-settings"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
    errors = {n: proc.communicate()[1] for n, proc in checks.items()}
    bad = {n: errors[n].strip() for n, proc in checks.items() if proc.returncode != 0}
    if bad:
        for n, err in bad.items():
            print(f"followbot up: services.{n}: {err}", file=sys.stderr)
        return 2
    if args.check:
        print(f"{args.compose}: OK ({', '.join(names)})")
        return 0
    if auto_router:
        if any(c.name == ROUTER for c in children):
            print(f"followbot up: a service named {ROUTER!r} needs Zenoh endpoints of its own "
                  f"(up starts a router of that name for the others)", file=sys.stderr)  # fmt: skip
            return 2
        from followbot.services.runtime.session import _rendezvous_free

        hub = _rendezvous_free()
        config = _write_router_settings(log_dir, compose.robot, router_listen, hub)
        router = Child(ROUTER, ROUTER, config, "always", False, [ROUTER], [router_endpoint])
        if hub:  # if another process binds the rendezvous first, join it instead
            router.fallback = lambda: _write_router_settings(
                log_dir, compose.robot, router_listen, hub=False
            )
        children.insert(0, router)
        watch_at = [router_endpoint]
    where = f" on host {args.host}" if args.host else ""
    started = ", ".join(c.name if c.service == c.name else f"{c.name} ({c.service})"
                        for c in children)  # fmt: skip
    print(f"followbot up: {compose.name}{where}: {started}; logs in {log_dir}/", flush=True)
    watch_at = list(dict.fromkeys(e for e in watch_at if e.startswith("tcp/")))
    sup = Supervisor(children, log_dir, compose.robot)
    return sup.run(
        args.replace,
        lambda: _open_watch(compose.robot, watch_at, client=auto_router) if watch_at else None,
    )


if __name__ == "__main__":
    raise SystemExit(main())
