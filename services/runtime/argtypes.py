"""argparse ``type=`` functions for durations, counts and rates.

A bad value stops the command at once with argparse's usage line and a message naming the
option and the rule, e.g. ``argument --duration: must be a finite number > 0, got '-1'``:
a negative duration, a zero count or ``nan`` never reaches the code that would misuse it.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = ["non_negative_float", "positive_float", "positive_int"]


def _checked(name: str, convert: Callable, ok: Callable[[float], bool], rule: str) -> Callable:
    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}")
        return value

    parse.__name__ = name
    return parse


#: Seconds, a rate, a multiplier: finite and > 0.
positive_float = _checked(
    "positive_float", float, lambda v: math.isfinite(v) and v > 0, "a finite number > 0"
)
#: A wait that may be zero (0 = do not wait), a rate where 0 means "as fast as possible".
non_negative_float = _checked(
    "non_negative_float", float, lambda v: math.isfinite(v) and v >= 0, "a finite number >= 0"
)
#: A count of things (scans, jobs): a whole number > 0.
positive_int = _checked("positive_int", int, lambda v: v > 0, "a whole number > 0")
