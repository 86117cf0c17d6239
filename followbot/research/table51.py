"""Thesis Table 5.1 in the simulator: ``python -m followbot.research.table51``.

Thesis 5.2.1: the robot stands still while a person walks back and forth on an arc of radius
1.2 m round it; over 1000 scans, the share of scans in which the person yields a two-leg
candidate, a one-leg candidate, or no candidate. The simulator's built-in scenario
``thesis_5_2_1_arc`` reproduces the set-up (100 deg, 0.5 deg SICK-like laser, 15 mm noise,
120 ms between scans, a gait with swinging legs). Scoring uses the simulator's ground truth
(``GroundTruth``, the target person's position in the robot frame): a scan counts as

* ``two_legs`` when a two-leg candidate lies within 0.3 m of the true target,
* else ``one_leg`` when a one-leg candidate does,
* else ``undetected``

(DESIGN.md "Metric definitions"). Candidates far from the target are counted as false
candidates per scan. Deterministic: same scenario, seed and detectors give the same table.
"""

from __future__ import annotations

import argparse
import math
import sys

import msgspec

from followbot.services.laser_legs.core import LegDetector
from followbot.services.laser_legs.detectors import make_detector

__all__ = ["Row", "main", "run", "table"]

#: thesis Table 5.1 (one leg, two legs, undetected, in %)
THESIS_TABLE = {"thesis": (20.2, 78.4, 1.4), "arc": (48.8, 31.8, 19.4)}
MATCH_M = 0.3


class Row(msgspec.Struct, kw_only=True):
    detector: str
    scans: int = 0
    visible: int = 0
    """Scans where the simulator says the target is visible to the laser."""
    one_leg: int = 0
    two_legs: int = 0
    undetected: int = 0
    false_candidates: int = 0

    def pct(self, n: int) -> float:
        return 100.0 * n / self.scans if self.scans else math.nan


def classify(result, tx: float, ty: float, match_m: float = MATCH_M) -> tuple[str, int]:
    """(``two_legs`` | ``one_leg`` | ``undetected``, number of candidates not on the target)."""
    near = [c for c in result.candidates if math.hypot(c.x_m - tx, c.y_m - ty) <= match_m]
    far = len(result.candidates) - len(near)
    if any(len(c.legs) == 2 for c in near):
        return "two_legs", far
    if near:
        return "one_leg", far
    return "undetected", far


def run(
    detectors: list[str | tuple[str, LegDetector]],
    scans: int = 1000,
    scenario: str = "thesis_5_2_1_arc",
    seed: int | None = None,
) -> list[Row]:
    from followbot.services.sim.scenario import load_builtin  # the simulator core
    from followbot.services.sim.simulation import Simulation

    sc = load_builtin(scenario)
    sim = Simulation(sc, seed=seed)
    dets = [(d, make_detector(d)) if isinstance(d, str) else d for d in detectors]
    rows = {name: Row(detector=name) for name, _ in dets}
    period_ns = round(1e9 / sc.laser.rate_hz)
    # the laser frame is the base frame shifted forward by the mount offset
    mount_x = sc.laser.mount_x_m
    for k in range(scans):
        sim.advance_to(k * period_ns)
        scan = sim.scan()
        truth = sim.truth()
        target = next(p for p in truth.people if p.is_target)
        tx, ty = target.robot_x_m - mount_x, target.robot_y_m
        for name, det in dets:
            row = rows[name]
            kind, far = classify(det.detect(scan), tx, ty)
            row.scans += 1
            row.visible += target.visible_laser
            row.false_candidates += far
            setattr(row, kind, getattr(row, kind) + 1)
    return [rows[n] for n, _ in dets]


def table(rows: list[Row]) -> str:
    lines = [
        "| detector | one leg % | two legs % | undetected % | thesis Table 5.1 (one / two / "
        "none %) | false candidates/scan | scans (target visible) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ref = THESIS_TABLE.get(r.detector)
        ref_s = " / ".join(f"{v:.1f}" for v in ref) if ref else "-"
        lines.append(
            f"| {r.detector} | {r.pct(r.one_leg):.1f} | {r.pct(r.two_legs):.1f} "
            f"| {r.pct(r.undetected):.1f} | {ref_s} | {r.false_candidates / r.scans:.2f} "
            f"| {r.scans} ({r.visible}) |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--detectors", nargs="*", default=["thesis", "arc"])
    p.add_argument("--scans", type=int, default=1000)
    p.add_argument("--scenario", default="thesis_5_2_1_arc")
    p.add_argument("--seed", type=int, default=None, help="default: the scenario's seed")
    args = p.parse_args(argv)
    sys.stdout.write(table(run(args.detectors, args.scans, args.scenario, args.seed)) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
