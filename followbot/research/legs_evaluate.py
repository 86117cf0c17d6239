"""Real-data table for every leg detector: ``python -m followbot.research.legs_evaluate``.

Leg recall on the labelled positives (a labelled leg is found when a detected leg lies within
0.15 m) and false person candidates per scan on negative_2 (nobody there), on the held-out
split of issue 4 (positive_6, positive_7; negative_2 /rear_scan, /right_scan) and on all the
data. Also the median detection time per scan. See ``realdata`` for the data and pairing.
Every detector runs behind the node's default robot-body filter (``self_filter``) unless
``--no-self-filter`` is given; the ``*_noself`` rows run without it.
"""

from __future__ import annotations

import argparse
import logging
import sys

from followbot.research.realdata import (
    HELD_OUT_NEGATIVE_TOPICS,
    HELD_OUT_POSITIVES,
    NEGATIVE_TOPICS,
    POSITIVES,
    Score,
    data_dir,
    read_negative,
    read_positive,
    score,
)
from followbot.services.laser_legs.core import LegDetector
from followbot.services.laser_legs.detectors import DETECTORS, make_detector
from followbot.services.laser_legs.self_filter import SelfFilteredDetector

log = logging.getLogger(__name__)

#: The static background train.py's earlier rule chose (the highest validation recall with at
#: most 0.4 false persons per scan; train.py --min-recall none), under which the rows below
#: that name it were measured.
_EARLIER_BACKGROUND = {"background_static_fraction": 0.9, "background_penalty": 0.15}

#: Variants worth a row beside the defaults: name -> (detector, settings overrides).
VARIANTS: dict[str, tuple[str, dict]] = {
    "thesis_noclip": ("thesis", {"clip_range_m": None}),
    "thesis_bridge": ("thesis", {"cluster_bridge_m": 0.12}),
    "arc_noclip": ("arc", {"clip_range_m": None}),
    # the learned detector without its temporal confirmation (tracks), at the thresholds
    # chosen without it; and without the static background too
    "learned_notrack": (
        "learned",
        {
            "track_memory_s": None,
            "threshold": 0.25,
            "pair_threshold": 0.10,
            **_EARLIER_BACKGROUND,
        },
    ),
    "learned_nobg": (
        "learned",
        {
            "background_memory_s": None,
            "track_memory_s": None,
            "threshold": 0.35,
            "pair_threshold": 0.15,
        },
    ),
    # the background and thresholds train.py's earlier rule chose
    "learned_maxrecall": (
        "learned",
        {"threshold": 0.10, "pair_threshold": 0.05, **_EARLIER_BACKGROUND},
    ),
    # the default without the robot-body filter (the node's self_filter: null)
    "learned_noself": ("learned", {}),
    "thesis_noself": ("thesis", {}),
}

#: Variants scored without the robot-body filter.
UNFILTERED = frozenset({"learned_noself", "thesis_noself"})


def build(name: str, *, self_filter: bool = True) -> LegDetector:
    """The detector or variant called ``name``, behind the robot-body filter as the node runs
    it unless ``self_filter`` is false or the variant is one of ``UNFILTERED``."""
    base, overrides = VARIANTS.get(name, (name, {}))
    det = make_detector(base, overrides or None)
    if self_filter and name not in UNFILTERED:
        return SelfFilteredDetector(det)
    return det


def run(names: list[str], *, self_filter: bool = True) -> list[tuple[str, Score, Score]]:
    held_pos = [s for n in HELD_OUT_POSITIVES for s in read_positive(n)]
    held_neg = [s for t in HELD_OUT_NEGATIVE_TOPICS for s in read_negative(t)]
    all_pos = [s for n in POSITIVES for s in read_positive(n)]
    all_neg = [s for t in NEGATIVE_TOPICS for s in read_negative(t)]
    rows = []
    for name in names:
        det = build(name, self_filter=self_filter)
        rows.append(
            (
                name,
                score(det, held_pos, held_neg, name=name),
                score(det, all_pos, all_neg, name=name),
            )
        )
    return rows


def table(rows: list[tuple[str, Score, Score]]) -> str:
    head = (
        "| detector | held-out leg recall | held-out recall <= 3.5 m | held-out false persons/scan "
        "| all leg recall | all false persons/scan | all false legs/scan | median us/scan |\n"
        "|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for name, h, a in rows:
        lines.append(
            f"| {name} | {h.recall:.3f} | {h.recall_near:.3f} | {h.false_candidates_per_scan:.2f} "
            f"| {a.recall:.3f} | {a.false_candidates_per_scan:.2f} | {a.false_legs_per_scan:.2f} "
            f"| {a.median_time_us:.0f} |"
        )
    h, a = rows[0][1], rows[0][2]
    lines.append("")
    lines.append(
        f"held-out: {h.positive_scans} labelled scans ({h.labelled_legs} legs, "
        f"{h.labelled_legs_near} within 3.5 m), {h.negative_scans} negative scans; "
        f"all: {a.positive_scans} labelled scans ({a.labelled_legs} legs), "
        f"{a.negative_scans} negative scans."
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--detectors",
        nargs="*",
        default=[*DETECTORS, *VARIANTS],
        help=f"names among {sorted([*DETECTORS, *VARIANTS])}",
    )
    p.add_argument(
        "--no-self-filter",
        action="store_true",
        help="score the detectors without the robot-body filter the node applies by default",
    )
    args = p.parse_args(argv)
    if not data_dir().is_dir():
        log.error("no leg_tracker data at %s (set FOLLOWBOT_LEG_DATA)", data_dir())
        return 2
    sys.stdout.write(table(run(args.detectors, self_filter=not args.no_self_filter)) + "\n")
    return 0


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO)
    raise SystemExit(main())
