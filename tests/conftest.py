"""Shared fixtures: free loopback ports, followbot subprocesses, a Zenoh session for tests."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def shortened_scenario(name: str, duration_s: float, folder: Path) -> Path:
    """A built-in scenario's file cut to its first ``duration_s``, written into ``folder``."""
    from importlib import resources

    import yaml

    text = resources.files("followbot.services.sim").joinpath("scenarios", f"{name}.yaml")
    spec = yaml.safe_load(text.read_text())
    spec["duration_s"] = duration_s
    path = folder / f"{name}_{duration_s:g}s.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def pytest_addoption(parser):
    parser.addoption("--run-soak", action="store_true", help="run the long soak tests")
    parser.addoption(
        "--run-chaos", action="store_true", help="run the fault-injection and start-up checks"
    )


def pytest_collection_modifyitems(config, items):
    opt_in = {
        "soak": ("--run-soak", "soak test: opt in with `make soak` (--run-soak)"),
        "chaos": (
            "--run-chaos",
            "fault injection or start-up check: opt in with `make chaos` (--run-chaos)",
        ),
    }
    for marker, (option, reason) in opt_in.items():
        if config.getoption(option):
            continue
        skip = pytest.mark.skip(reason=reason)
        for item in items:
            if marker in item.keywords:
                item.add_marker(skip)


@pytest.fixture
def endpoint() -> str:
    """A free loopback endpoint (never hard-code ports in tests)."""
    from followbot.services.runtime.session import free_loopback_endpoint

    return free_loopback_endpoint()


@pytest.fixture
def robot() -> str:
    """A robot name of its own per test, so tests never hear each other."""
    return "t" + uuid.uuid4().hex[:10]


class Proc:
    """A followbot subprocess whose output is kept for assertions."""

    def __init__(self, args: list[str], log: Path) -> None:
        self.log = log
        self._fh = log.open("w")
        env = dict(os.environ, PYTHONUNBUFFERED="1", RUST_LOG="error")
        self.p = subprocess.Popen(
            [sys.executable, "-m", "followbot", *args],
            stdout=self._fh,
            stderr=subprocess.STDOUT,
            env=env,
        )

    def wait(self, timeout: float) -> int:
        try:
            return self.p.wait(timeout)
        finally:
            self._fh.flush()

    def signal(self, sig: int) -> None:
        self.p.send_signal(sig)

    @property
    def output(self) -> str:
        self._fh.flush()
        return self.log.read_text()

    def wait_for_output(self, text: str, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.output:
                return
            if self.p.poll() is not None:
                break
            time.sleep(0.02)
        raise AssertionError(f"{text!r} not seen in output:\n{self.output}")

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGKILL)
            self.p.wait(5)
        self._fh.close()


@pytest.fixture
def spawn(tmp_path) -> Iterator:
    procs: list[Proc] = []

    def _spawn(*args: str) -> Proc:
        proc = Proc(list(args), tmp_path / f"proc{len(procs)}.log")
        procs.append(proc)
        return proc

    yield _spawn
    for p in procs:
        p.kill()


class LivelinessWatch:
    """Watches one liveliness key from a test's own Zenoh session (history included)."""

    def __init__(self, session, key: str) -> None:
        import zenoh

        self.key = key
        self.events: queue.SimpleQueue = queue.SimpleQueue()
        self._sub = session.liveliness().declare_subscriber(
            key,
            lambda s: self.events.put("PUT" if s.kind == zenoh.SampleKind.PUT else "DELETE"),
            history=True,
        )

    def expect(self, kind: str = "PUT", timeout: float = 10.0) -> None:
        """Wait for the token to appear (PUT) or go (DELETE); fail after ``timeout``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                if self.events.get(timeout=max(0.0, deadline - time.monotonic())) == kind:
                    return
            except queue.Empty:
                break
        raise AssertionError(f"no liveliness {kind} of {self.key} within {timeout} s")

    def undeclare(self) -> None:
        self._sub.undeclare()


@pytest.fixture
def zenoh_session(endpoint):
    """A Zenoh session of the test itself that listens on ``endpoint``."""
    from followbot.services.runtime.session import open_session
    from followbot.services.runtime.settings import ZenohSettings

    session = open_session(ZenohSettings(listen=[endpoint]))
    try:
        yield session
    finally:
        session.close()
