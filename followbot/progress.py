"""Progress on stderr: one line rewritten in place on a terminal, a line per update in logs."""

from __future__ import annotations

import sys

__all__ = ["bar", "count_bar", "finish", "on_terminal", "show"]


def on_terminal() -> bool:
    return sys.stderr.isatty()


def show(text: str) -> None:
    """Show ``text`` as the current progress line."""
    sys.stderr.write(("\r" + text) if on_terminal() else (text + "\n"))
    sys.stderr.flush()


def finish() -> None:
    """End the line being rewritten (nothing to do in logs)."""
    if on_terminal():
        sys.stderr.write("\n")
        sys.stderr.flush()


def bar(done: float, total: float, width: int = 30) -> str:
    """``[#####.....]  3.0/10 s``"""
    frac = min(max(done / total, 0.0), 1.0) if total else 1.0
    n = int(frac * width)
    return f"[{'#' * n}{'.' * (width - n)}] {done:5.1f}/{total:.0f} s"


def count_bar(done: int, total: int, width: int = 30) -> str:
    """``[#####.....]`` for ``done`` of ``total`` items."""
    n = int(width * min(max(done / total, 0.0), 1.0)) if total else width
    return f"[{'#' * n}{'.' * (width - n)}]"
