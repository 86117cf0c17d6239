"""The ``main`` every service shares: options, settings, a Zenoh node, then the loop."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import textwrap
import threading
from collections.abc import Callable, Sequence
from typing import TypeVar

import msgspec
import yaml

from .argtypes import positive_float
from .node import Node, configure_logging, zenoh_node
from .session import SessionError, add_zenoh_arguments, overrides_from_args
from .settings import NodeSettings, SettingsError, load_settings

__all__ = ["add_run_arguments", "preset_layer", "service_main", "settings_help"]

S = TypeVar("S", bound=NodeSettings)


def settings_help(settings_type: type[NodeSettings]) -> str:
    """The default settings as YAML, for ``--help``."""
    text = yaml.safe_dump(msgspec.to_builtins(settings_type()), sort_keys=False).rstrip()
    return (
        "settings (defaults shown; change with --config FILE or --set key=value, "
        "e.g. --set zenoh.mode=client):\n" + textwrap.indent(text, "  ")
    )


def add_run_arguments(
    parser: argparse.ArgumentParser,
    *,
    config_help: str = "settings file (YAML or JSON)",
    set_help: str = "override one setting (dotted key, YAML value); repeatable",
    print_help: str = "print the effective settings as YAML and exit",
) -> None:
    """The options of `followbot run`: --preset, --config, --set, --duration, --print-settings,
    zenoh's."""
    parser.add_argument(
        "--preset", metavar="NAME",
        help="start from a system preset's settings for this service (services/runtime/"
        "compose.py PRESETS: followbot, the defaults of followbot track/eval/up; thesis; "
        "...), under --config and --set (default: none, the settings' own defaults)",
    )  # fmt: skip
    parser.add_argument("--config", metavar="FILE", help=config_help)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help=set_help)
    parser.add_argument(
        "--duration", type=positive_float, metavar="S",
        help="stop after S seconds (default: never)",
    )  # fmt: skip
    parser.add_argument("--print-settings", action="store_true", help=print_help)
    add_zenoh_arguments(parser)


def preset_layer(preset: str | None, service: str) -> dict | None:
    """``--preset NAME``: the settings that preset gives ``service`` (None: no preset)."""
    if preset is None:
        return None
    from .compose import preset_settings

    try:
        return preset_settings(preset, service)
    except ValueError as exc:
        raise SettingsError(f"--preset: {exc}") from None


def service_main(
    service: str,
    settings_type: type[S],
    setup: Callable[[Node, S], object],
    argv: Sequence[str] | None,
    description: str,
    check: Callable[[S], object] | None = None,
) -> int:
    """Parse options, load settings, open a node, let ``setup`` declare its I/O, run the loop.

    ``check(settings)`` validates what the settings name beyond their types, every file the
    service will load (a scenario, a model) with the service's own loading code, raising
    ValueError (or OSError) with a message naming the setting and the file. It runs before any
    network is opened, at start and for ``--print-settings`` (which ``followbot up`` runs for
    every service before it starts anything, and for ``--check``).

    Exit codes: 0 after a clean stop (SIGINT, SIGTERM, --duration, or the service stopping
    itself), 2 for bad options, settings or files, 1 when the Zenoh session cannot be opened.
    """
    stop_requested: list[int] = []
    previous = {}
    if threading.current_thread() is threading.main_thread():  # else: run with others
        previous = {
            s: signal.signal(s, lambda signum, _f: stop_requested.append(signum))
            for s in (signal.SIGINT, signal.SIGTERM)
        }
    try:
        parser = argparse.ArgumentParser(
            prog=f"followbot run {service}",
            description=description,
            epilog=settings_help(settings_type),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        add_run_arguments(parser)
        args = parser.parse_args(argv)
        try:
            settings = load_settings(
                settings_type,
                args.config,
                [*args.set, *overrides_from_args(args)],
                preset_layer(args.preset, service),
            )
        except SettingsError as exc:
            print(f"followbot run {service}: {exc}", file=sys.stderr)
            return 2
        if check is not None:
            try:
                check(settings)
            except (ValueError, OSError) as exc:  # SettingsError is a ValueError
                print(f"followbot run {service}: {exc}", file=sys.stderr)
                return 2
        if args.print_settings:
            print(yaml.safe_dump(msgspec.to_builtins(settings), sort_keys=False), end="")
            return 0
        configure_logging(settings.log_level)
        log = logging.getLogger(f"followbot.{service}")
        try:
            with zenoh_node(service, settings) as node:
                try:
                    setup(node, settings)
                except (ValueError, SettingsError) as exc:
                    print(f"followbot run {service}: {exc}", file=sys.stderr)
                    return 2
                if stop_requested:
                    return 0
                code = node.run(args.duration)
            log.info("%s stopped", service)
            return code
        except SessionError as exc:
            log.error("%s", exc)
            return 1
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
