"""``followbot target acquire|reset|save|load``: tell vision_verify what to do with the model.

Publishes a TargetCommand on perception/target_command (waiting up to --wait seconds for
vision_verify to be listening). For reset, save and load it then waits (up to --wait seconds)
for vision_verify's health report naming the command, prints what it did or why it refused,
and exits 1 on a refusal. For acquire it waits for the new model on perception/target_model
and prints it.

save and load take --path NAME: a file name in vision_verify's models folder (its
``files.folder`` setting, by default ~/.local/share/followbot/models); without it, the
service's ``files.default_name`` setting (target.model).
"""

from __future__ import annotations

import argparse
import sys
import time

from followbot.services.runtime.argtypes import positive_float


def main(argv: list[str] | None = None) -> int:
    from followbot.schemas import TargetCommand, TargetModel
    from followbot.services.runtime.node import zenoh_node
    from followbot.services.runtime.session import (
        SessionError,
        add_zenoh_arguments,
        overrides_from_args,
    )
    from followbot.services.runtime.settings import NodeSettings, load_settings

    p = argparse.ArgumentParser(prog="followbot target", description=__doc__)
    p.add_argument("action", choices=["acquire", "reset", "save", "load"])
    p.add_argument(
        "--path",
        default="",
        help="save/load: a file name in vision_verify's models folder (files.folder; default: "
        "its files.default_name)",
    )
    p.add_argument(
        "--wait",
        type=positive_float,
        default=5.0,
        help="seconds to wait for vision_verify to listen, and then for its answer (5)",
    )
    p.add_argument(
        "--timeout", type=positive_float, default=30.0,
        help="acquire: seconds to wait for a model (30)",
    )  # fmt: skip
    add_zenoh_arguments(p)
    args = p.parse_args(argv)
    settings = load_settings(NodeSettings, None, [*overrides_from_args(args), "log_level=warning"])
    models: list[TargetModel] = []
    healths: list[bytes] = []
    try:
        with zenoh_node("target_cli", settings) as node:
            pub = node.publisher("perception/target_command", reliable=True)
            node.subscribe("perception/target_model", models.append)
            node.bus.subscribe(node.keys.health("vision_verify"), healths.append)
            if not node.wait_for_subscribers(pub, args.wait):
                print(f"followbot target: no vision_verify listening on robot '{settings.robot}' "
                      f"after {args.wait:.0f} s", file=sys.stderr)  # fmt: skip
                return 1
            stamp = time.time_ns()
            pub.put(TargetCommand(stamp_ns=stamp, action=args.action, path=args.path))
            print(f"sent {args.action}")
            if args.action != "acquire":
                return _report(healths, f"command {args.action} {stamp} ", args.wait)
            print("waiting for the target to move in front of the still robot ...")
            deadline = time.monotonic() + args.timeout
            while not models and time.monotonic() < deadline:
                time.sleep(0.05)
    except SessionError as exc:
        print(f"followbot target: {exc}", file=sys.stderr)
        return 1
    if not models:
        print(f"followbot target: no model within {args.timeout:.0f} s", file=sys.stderr)
        return 1
    m = models[-1]
    print(f"model {m.model_id} ({m.verifier}) at x={m.x_m:.2f} m y={m.y_m:.2f} m, "
          f"rectangle {m.rect_width_px:.0f}x{m.rect_height_px:.0f} px")  # fmt: skip
    return 0


def _report(payloads: list[bytes], prefix: str, wait_s: float) -> int:
    """Print vision_verify's outcome of the command (a Health note starting with ``prefix``,
    node.py ``_report``); 1 if it refused it, 0 if it did it or did not say within
    ``wait_s``."""
    from followbot.schemas import Health, RejectedMessage, decode

    deadline = time.monotonic() + wait_s
    seen = 0
    while time.monotonic() < deadline:
        while seen < len(payloads):
            seen += 1
            try:
                health = decode(Health, payloads[seen - 1])
            except RejectedMessage:
                continue
            for note in health.notes:
                if note.startswith(prefix):
                    outcome = note[len(prefix) :]
                    if outcome.startswith("refused"):
                        print(f"followbot target: vision_verify {outcome}", file=sys.stderr)
                        return 1
                    print(f"vision_verify: {outcome}")
                    return 0
        time.sleep(0.05)
    print(f"no answer from vision_verify within {wait_s:.0f} s (see its log)")
    return 0
