"""A supervisor's children end when it dies, whatever signal killed it (``followbot up``).

Two mechanisms, because either alone has a gap:

- **Parent-death signal** (Linux): each child asks the kernel, between fork and exec, to send
  it SIGTERM when its parent dies (``prctl(PR_SET_PDEATHSIG)``). Immediate, even after SIGKILL,
  but Linux-only, and it follows the parent *thread* that forked the child.
- **Lifeline pipe** (anywhere): the supervisor holds the write end of a pipe, each child the
  read end; nothing is ever written. When the supervisor dies, the kernel closes its end and
  the child's read returns end-of-file: the child stops itself (SIGTERM to itself, so it stops
  as on Ctrl-C; if it has not ended after ``GRACE_S``, it exits at once).

The supervisor side is :class:`Lifeline`; the child side is :func:`watch_lifeline`, which
``followbot run`` calls when the environment names a lifeline descriptor.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

__all__ = ["ENV", "GRACE_S", "Lifeline", "watch_lifeline"]

#: Environment variable naming the descriptor of the lifeline's read end in a child.
ENV = "FOLLOWBOT_LIFELINE_FD"
#: How long a child whose supervisor died may take to stop before it exits at once.
GRACE_S = 5.0

_PR_SET_PDEATHSIG = 1

log = logging.getLogger("followbot.lifeline")


def _prctl() -> Callable[..., int] | None:
    """libc's prctl, looked up in the parent (nothing may be loaded between fork and exec)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


class Lifeline:
    """The supervisor's end: :meth:`popen_kwargs` for every child it starts."""

    def __init__(self) -> None:
        self._read, self._write = os.pipe()  # neither inherited unless passed
        self._prctl = _prctl()
        self._pid = os.getpid()

    def _preexec(self) -> None:
        # In the child, between fork and exec: only async-signal-safe work here.
        if self._prctl is not None:
            self._prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        if os.getppid() != self._pid:  # the supervisor died before the prctl took effect
            os._exit(1)

    def popen_kwargs(self, env: dict[str, str]) -> dict[str, Any]:
        """Arguments for ``subprocess.Popen`` (``env`` gains the lifeline's descriptor)."""
        return {
            "pass_fds": (self._read,),
            "preexec_fn": self._preexec,
            "env": dict(env, **{ENV: str(self._read)}),
        }

    def close(self) -> None:
        for fd in (self._read, self._write):
            with contextlib.suppress(OSError):
                os.close(fd)


def watch_lifeline() -> None:
    """In a child of :class:`Lifeline`: stop this process when the supervisor dies. Does
    nothing when the environment names no lifeline (a service started by hand)."""
    value = os.environ.pop(ENV, None)
    if value is None:
        return
    try:
        fd = int(value)
        os.fstat(fd)
    except (ValueError, OSError):
        log.warning("%s=%r is not an open descriptor; not watching the supervisor", ENV, value)
        return

    def watch() -> None:
        while True:
            try:
                if not os.read(fd, 1):
                    break
            except InterruptedError:
                continue
            except OSError:
                break
        log.warning("the supervisor is gone; stopping")
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(GRACE_S)
        logging.shutdown()
        os._exit(1)

    threading.Thread(target=watch, name="lifeline", daemon=True).start()
