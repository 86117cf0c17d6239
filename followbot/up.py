"""``followbot up COMPOSE.yaml [--host NAME]``: start and supervise a deployment.

Starts every service of the compose file (or those of one host) as its own process with its
merged settings, prefixes their logs with the service name, restarts a service that crashes
(exponential backoff 1 s → 30 s, reset after 30 s of good running), and on Ctrl-C or SIGTERM
stops them all (SIGTERM, then SIGKILL after 5 s) and exits 0. A service that exits 2 has bad
settings and is not restarted. See docs/compose.md.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

BACKOFF_S = (1.0, 30.0)
HEALTHY_AFTER_S = 30.0
STOP_GRACE_S = 5.0


@dataclass
class Child:
    name: str
    service: str
    config: Path
    restart: str
    stop_all_on_exit: bool
    proc: subprocess.Popen | None = None
    started: float = 0.0
    backoff: float = BACKOFF_S[0]
    restart_at: float | None = None
    done: bool = False
    failed: bool = False
    restarts: int = 0
    reader: threading.Thread | None = field(default=None, repr=False)


class Supervisor:
    def __init__(self, children: list[Child], log_dir: Path) -> None:
        self.children = children
        self.log_dir = log_dir
        self.width = max(len(c.name) for c in children)
        self._out = threading.Lock()
        self._stop: list[int] = []

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
            cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
            start_new_session=True,  # Ctrl-C reaches the supervisor only; it stops the rest
        )  # fmt: skip
        child.started = time.monotonic()
        child.restart_at = None
        child.reader = threading.Thread(target=self._pump, args=(child, child.proc), daemon=True)
        child.reader.start()
        self.say("up", f"started {child.name} (pid {child.proc.pid})")

    def stop_all(self) -> None:
        running = [c for c in self.children if c.proc and c.proc.poll() is None]
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

    def run(self) -> int:
        previous = {
            s: signal.signal(s, lambda signum, _f: self._stop.append(signum))
            for s in (signal.SIGINT, signal.SIGTERM)
        }
        try:
            for c in self.children:
                self.start(c)
            while not self._stop:
                now = time.monotonic()
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
                        self.say("up", f"{c.name} exited 2 (bad settings); not restarting")
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
                if all(c.done or c.failed for c in self.children):
                    return 1 if any(c.failed for c in self.children) else 0
                time.sleep(0.1)
            self.say("up", "stopping")
            self.stop_all()
            return 0
        finally:
            for s, h in previous.items():
                signal.signal(s, h)


def main(argv: list[str] | None = None) -> int:
    from followbot.services.runtime.compose import (
        ComposeError,
        check_services,
        group_settings,
        load_compose,
        process_groups,
        service_settings,
    )
    from followbot.services.runtime.plugins import Registry

    p = argparse.ArgumentParser(
        prog="followbot up",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("compose", help="compose file (YAML; see docs/compose.md)")
    p.add_argument("--host", help="start only the services placed on this host")
    p.add_argument("--log-dir", default="out/up", help="per-service log files (out/up)")
    p.add_argument("--check", action="store_true", help="validate everything, start nothing")
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
    children = []
    for process, members in process_groups(compose, names):
        spec = compose.services[members[0]]
        config = log_dir / f"{process}.settings.yaml"
        try:
            if len(members) == 1 and spec.process is None:
                settings = service_settings(compose, process)
                service = spec.service or process
            else:  # several services in one process (docs/runtime.md)
                settings = group_settings(compose, members)
                service = "+".join(compose.services[m].service or m for m in members)
        except ComposeError as exc:
            print(f"followbot up: {exc}", file=sys.stderr)
            return 2
        config.write_text(yaml.safe_dump(settings, sort_keys=False))
        children.append(Child(process, service, config, spec.restart, spec.stop_all_on_exit))
    # Validate every service's merged settings the way the service itself will.
    checks = {}
    for c in children:
        cmd = [sys.executable, "-m", "followbot", "run", c.service, "--config", str(c.config)]
        checks[c.name] = subprocess.run([*cmd, "--print-settings"], capture_output=True, text=True)
    bad = {n: r.stderr.strip() for n, r in checks.items() if r.returncode != 0}
    if bad:
        for n, err in bad.items():
            print(f"followbot up: services.{n}: {err}", file=sys.stderr)
        return 2
    if args.check:
        print(f"{args.compose}: OK ({', '.join(names)})")
        return 0
    where = f" on host {args.host}" if args.host else ""
    started = ", ".join(c.name if c.service == c.name else f"{c.name} ({c.service})"
                        for c in children)  # fmt: skip
    print(f"followbot up: {compose.name}{where}: {started}; logs in {log_dir}/")
    return Supervisor(children, log_dir).run()


if __name__ == "__main__":
    raise SystemExit(main())
