"""The ``--preset`` and ``--set`` options of the commands that run the pipeline (``followbot
benchmark``, ``track``, ``eval``, ``demo``): defined once, so each takes the same flags with
the same help text and the same default preset.
"""

from __future__ import annotations

import argparse

__all__ = ["DEFAULT_PRESET", "add_preset_arguments"]

#: The preset a command runs when none is named: the defaults (compose PRESETS["followbot"]).
DEFAULT_PRESET = "followbot"


def add_preset_arguments(
    parser: argparse.ArgumentParser,
    *,
    repeatable: bool = False,
    preset_group: argparse._ActionsContainer | None = None,
    set_note: str = "",
) -> None:
    """Add ``--preset NAME`` (one of compose's PRESETS; default :data:`DEFAULT_PRESET`) and
    ``--set SERVICE.KEY=VALUE`` (repeatable, a list) to ``parser``.

    ``repeatable``: ``--preset`` may be given several times and gathers a list, None when not
    given (the command then runs :data:`DEFAULT_PRESET`); ``preset_group``: where ``--preset``
    goes instead of ``parser`` (e.g. a mutually exclusive group); ``set_note``: what ``--set``
    does not reach in this command, added to its help."""
    from followbot.services.runtime.compose import PRESETS

    names = list(PRESETS)
    (parser if preset_group is None else preset_group).add_argument(
        "--preset",
        choices=names,
        metavar="NAME",
        action="append" if repeatable else "store",
        default=None if repeatable else DEFAULT_PRESET,
        help=f"system preset: {', '.join(names)} (default: {DEFAULT_PRESET}, the defaults; "
        f"thesis: the thesis as published){'; repeatable' if repeatable else ''}",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SERVICE.KEY=VALUE",
        help="a stage setting on top of the preset, e.g. tracker.max_misses=4 or "
        "laser_legs.detector_settings.pairing=matching (repeatable"
        + (f"; {set_note}" if set_note else "")
        + ")",
    )
