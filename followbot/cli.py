"""The ``followbot`` command.

followbot run <service> [--config FILE] [--set key=value] ...   run one service
followbot run <a>+<b>+... [--config FILE] ...                   run several in one process
followbot services                                              list runnable services
followbot status [--robot R] [--watch]                          live services and their health
followbot topics                                                list topics and types
followbot schemas [--output DIR | --check]                      JSON Schema of messages
followbot settings [--markdown FILE | --check FILE]             settings reference
followbot demo                                                  live pipeline smoke
followbot bench [--json FILE]                                   benchmarks
followbot appearance VIDEO BOXES [--lags 25,100] ...            a verifier on boxed footage
followbot benchmark [DATA_DIR] [--all-presets] [--quick] ...    the real-data suite: report
followbot realstats [--data DIR] [--sim] [--json FILE]          real vs simulated laser figures
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from followbot import __version__

_RUN_EPILOG = """\
Each service takes --help of its own, e.g. `followbot run synthetic --help`, which lists its
settings and their defaults. Common options: --config FILE (YAML/JSON settings, unknown keys are
an error), --set key=value (repeatable), --duration S, and zenoh's --mode/--connect/--listen.
"""


def _services():
    from followbot.services.runtime.plugins import Registry

    return Registry("services")


def _cmd_run(args: argparse.Namespace, rest: list[str]) -> int:
    from followbot.services.runtime.lifeline import watch_lifeline
    from followbot.services.runtime.plugins import UnknownPlugin

    watch_lifeline()  # started by `followbot up`: end with it, however it ends

    if "+" in args.service:  # several services in one process (docs/runtime.md)
        from followbot.services.runtime.container import exit_now
        from followbot.services.runtime.container import main as run_together

        exit_now(run_together(args.service.split("+"), args.args))
    try:
        main = _services().load(args.service)
    except UnknownPlugin as exc:
        print(f"followbot run: {exc}", file=sys.stderr)
        return 2
    return int(main(args.args) or 0)


def _cmd_services(_args, _rest) -> int:
    for name in _services().names():
        print(name)
    return 0


def _cmd_topics(_args, _rest) -> int:
    from followbot.schemas import TOPICS

    width = max(len(t) for t in TOPICS)
    for topic, t in TOPICS.items():
        print(f"{topic:<{width}}  {t.__name__}")
    print(f"{'health/<service>':<{width}}  Health")
    return 0


def _cmd_schemas(args: argparse.Namespace, _rest) -> int:
    from followbot.schemas.export import (
        CONTRACT_FILE,
        compatibility_problems,
        message_schemas,
        write_schemas,
    )

    if args.markdown:
        from followbot.schemas.docgen import write_markdown

        write_markdown(Path(args.markdown))
        print(f"wrote {args.markdown}")
        return 0
    if args.check:
        old = json.loads(CONTRACT_FILE.read_text())
        problems = compatibility_problems(old, message_schemas())
        for p in problems:
            print(f"incompatible: {p}")
        if not problems:
            print(f"compatible with {CONTRACT_FILE}")
        return 1 if problems else 0
    if args.output:
        for path in write_schemas(Path(args.output)):
            print(f"wrote {path}")
        return 0
    json.dump(message_schemas(), sys.stdout, indent=2, sort_keys=True)
    print()
    return 0


#: Commands that hand every argument after their name to a module's ``main(argv)``.
PASSTHROUGH: dict[str, tuple[str, str, str]] = {
    # name: (module, function, help)
    "demo": ("followbot.demo", "main", "the whole system follows a person in the simulator"),
    "smoke": ("followbot.smoke", "main", "transport smoke: synthetic sensors to a monitor"),
    "up": ("followbot.up", "main", "start and supervise a deployment from a compose file"),
    "status": ("followbot.status", "main", "every live service of a robot: health, host, pid"),
    "target": ("followbot.target", "main", "acquire / reset / save / load the target model"),
    "eval": ("followbot.eval_cli", "main", "scenarios x presets through the pipeline: report"),
    "sweep": ("followbot.sweep", "main", "every scenario over several seeds: closed-loop figures"),
    "track": ("followbot.track", "main", "run the pipeline over a recording; tracks to CSV"),
    "appearance": (
        "followbot.appearance",
        "main",
        "a verifier on footage with person boxes: does it pick the right person?",
    ),
    "record": ("followbot.recording", "record_main", "record topics to MCAP"),
    "replay": ("followbot.recording", "replay_main", "replay an MCAP file or a ROS 1/2 bag"),
    "bench": ("followbot.bench", "main", "run the benchmarks"),
    "realstats": (
        "followbot.realstats",
        "main",
        "laser statistics of the real recordings, and of the simulator side by side",
    ),
    "certs": ("followbot.certs", "main", "a CA and per-service certificates for secure Zenoh"),
    "benchmark": (
        "followbot.benchmark",
        "main",
        "the real-data suite: detectors, false people, legs360, footage, id churn (report)",
    ),
    "settings": (
        "followbot.settingsdoc",
        "main",
        "every service's and plugin's settings: key, type, default, meaning",
    ),
}


def _cmd_passthrough(args: argparse.Namespace, rest: list[str]) -> int:
    import importlib

    module, function, _ = PASSTHROUGH[args.command]
    return getattr(importlib.import_module(module), function)(rest)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="followbot",
        description=(
            "followbot: a robot follows one chosen person. Laser legs, camera verification, "
            "a particle filter and a controller, each its own process over Eclipse Zenoh."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Topics and message formats: docs/messages.md. Runtime: docs/runtime.md.",
    )
    parser.add_argument("--version", action="version", version=f"followbot {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser(
        "run",
        help="run one service (its options follow the name; see `followbot run NAME --help`)",
        epilog=_RUN_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        add_help=True,
    )
    p.add_argument(
        "service",
        help="service name (see `followbot services`), or several joined by + to run them in "
        "one process (e.g. laser_legs+tracker+controller)",
    )
    p.add_argument("args", nargs=argparse.REMAINDER, help="the service's own options")
    p.set_defaults(fn=_cmd_run)

    p = sub.add_parser("services", help="list the services `followbot run` knows")
    p.set_defaults(fn=_cmd_services)

    p = sub.add_parser("topics", help="list the topics and the message type of each")
    p.set_defaults(fn=_cmd_topics)

    p = sub.add_parser("schemas", help="print or write the JSON Schema of every message")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--output", metavar="DIR", help="write messages.schema.json into DIR")
    g.add_argument("--markdown", metavar="FILE", help="write the Markdown reference (docs)")
    g.add_argument(
        "--check",
        action="store_true",
        help="exit 1 if the messages are incompatible with the committed contract",
    )
    p.set_defaults(fn=_cmd_schemas)

    for name, (_, _, help_text) in PASSTHROUGH.items():
        p = sub.add_parser(name, help=f"{help_text} (`followbot {name} --help`)", add_help=False)
        p.set_defaults(fn=_cmd_passthrough, passthrough=True)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    # `run NAME ...`, `demo ...` and `bench ...` hand everything after them to the subcommand.
    args, rest = parser.parse_known_args(argv)
    if rest and not getattr(args, "passthrough", False):
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    return args.fn(args, rest)


if __name__ == "__main__":
    raise SystemExit(main())
