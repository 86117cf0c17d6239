"""``followbot target acquire|reset|save|load``: tell vision_verify what to do with the model.

Publishes a TargetCommand on perception/target_command (waiting up to --wait seconds for
vision_verify to be listening) and, for acquire, waits for the new model on
perception/target_model and prints it.
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
    p.add_argument("--path", default="", help="model file for save/load (default: the service's)")
    p.add_argument(
        "--wait", type=positive_float, default=5.0, help="seconds to wait for vision_verify (5)"
    )
    p.add_argument(
        "--timeout", type=positive_float, default=30.0,
        help="acquire: seconds to wait for a model (30)",
    )  # fmt: skip
    add_zenoh_arguments(p)
    args = p.parse_args(argv)
    settings = load_settings(NodeSettings, None, [*overrides_from_args(args), "log_level=warning"])
    models: list[TargetModel] = []
    try:
        with zenoh_node("target_cli", settings) as node:
            pub = node.publisher("perception/target_command", reliable=True)
            node.subscribe("perception/target_model", models.append)
            if not node.wait_for_subscribers(pub, args.wait):
                print(f"followbot target: no vision_verify listening on robot '{settings.robot}' "
                      f"after {args.wait:.0f} s", file=sys.stderr)  # fmt: skip
                return 1
            pub.put(TargetCommand(stamp_ns=time.time_ns(), action=args.action, path=args.path))
            print(f"sent {args.action}")
            if args.action != "acquire":
                return 0
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
