"""The simulator's laser measured with the real-data statistics (followbot.realstats).

:func:`measure_sim` runs the simulator in process (no Zenoh: only the scans matter) in
settings like the real recordings' and measures them with the same functions as the real
scans:

* legs: a still scanner like the leg_tracker robot's (270 deg at 0.3516 deg, 10.8 m) in a
  room where people walk at 0.5-5 m; the labels are the simulated legs seen by at least one
  beam, placed where a leg cluster's centre lies (the leg centre moved 0.78 radius toward
  the scanner: the centroid of a half circle's front), as the real labels are leg clusters;
* range noise and invalid beams: the same scanner, still, in the room with nobody in it;
* false person candidates: the furnished-room scenarios, the robot turning on the spot so it
  sees the whole room; a candidate within 0.5 m of a person is a true one and not counted.

:func:`compare` puts the real and simulated figures side by side (docs/realism.md).
"""

from __future__ import annotations

import math

import msgspec
import numpy as np

from followbot.realstats import (
    RANGE_BINS_M,
    CandidateFigures,
    LegFigures,
    NoiseFigures,
    RealFigures,
    ScanFigures,
    false_candidates,
    leg_figures,
    noise_figures,
    scan_figures,
    valid_mask,
)
from followbot.schemas import GroundTruth, LaserScan
from followbot.services.sim.scenario import LaserSpec, Scenario, load_builtin, parse_scenario
from followbot.services.sim.simulation import Simulation

__all__ = ["FURNISHED", "SimFigures", "compare", "measure_sim", "within_band"]

#: The furnished-room scenarios measured for false candidates.
FURNISHED = ("furnished_office", "furnished_kitchen")

#: The leg_tracker bags' scanner (measured: 768 beams from -135 deg at 0.3515625 deg; valid
#: ranges up to 10.8 m, the 99.9th percentile on negative_2).
REAL_SCANNER = {
    "fov_deg": 270.0,
    "resolution_deg": 0.3515625,
    "range_max_m": 10.8,
    "rate_hz": 15.0,
    "model": "measured",
}

#: A lab room 10 x 8 m with a cabinet, two crates and a pillar, the scanner in the middle.
_ROOM = {
    "walls": [{"points": [[-4, -4], [6, -4], [6, 4], [-4, 4]], "closed": True}],
    "boxes": [
        {"centre": [4.5, 3.0], "size_m": [1.2, 0.5]},
        {"centre": [-0.9, 0.9], "size_m": [0.4, 0.4]},
        {"centre": [-2.0, -2.3], "size_m": [0.6, 0.4]},
    ],
    "circles": [{"centre": [-2.5, 2.5], "radius_m": 0.15, "height_m": 2.0}],
}

#: People crossing the room at ranges from 0.5 to 5 m, walking and standing.
_WALKERS = [
    {"id": 1, "start": [0.6, -3.0], "path": [{"kind": "walk", "to": [0.6, 3.0]}], "loop": False},
    {"id": 2, "start": [5.0, 3.0], "path": [{"kind": "walk", "to": [5.0, -3.0]}]},
    {"id": 3, "start": [1.0, 0.3], "path": [{"kind": "walk", "to": [5.0, 1.5]}]},
    {"id": 4, "start": [-3.0, -1.0], "path": [{"kind": "walk", "to": [-0.7, -1.0]}]},
    {
        "id": 5,
        "start": [2.0, -2.0],
        "path": [{"kind": "pause", "duration_s": 4}, {"kind": "walk", "to": [3.5, 2.5]}],
        "gait": {"stance": "apart"},
    },
    {"id": 6, "start": [-1.5, 3.0], "path": [{"kind": "walk", "to": [-2.5, -3.0]}]},
]


class SimFigures(msgspec.Struct, kw_only=True):
    legs: LegFigures
    legs_without_returns: float
    """Share of the simulated legs in view with no return at all (never labelled in real
    data, so not compared)."""
    noise: NoiseFigures
    scans: ScanFigures
    false_furnished: dict[str, dict[str, float]]


def _scenario(name: str, laser: dict, people: list, duration_s: float, seed: int) -> Scenario:
    return parse_scenario(
        {
            "name": name,
            "duration_s": duration_s,
            "seed": seed,
            "world": _ROOM,
            "laser": laser,
            "people": people,
            "robot": {"start": [0.0, 0.0]},
        },
        source=name,
    )


def _run(sim: Simulation) -> list[tuple[LaserScan, GroundTruth]]:
    """Every (scan, truth) pair of a run, the robot driven by ``sim``'s commands."""
    out = []
    scan = None
    while not sim.finished:
        for msg in sim.tick():
            if isinstance(msg, LaserScan):
                scan = msg
            elif isinstance(msg, GroundTruth) and scan is not None:
                out.append((scan, msg))
                scan = None
    return out


def _labels(scan: LaserScan, truth: GroundTruth, spec: LaserSpec, leg_radius_m: float):
    """(labels of the legs seen, legs in view without any return)."""
    r, ok = valid_mask(scan)
    a = scan.angles_rad()
    x, y = r * np.cos(a), r * np.sin(a)
    labels, unseen = [], 0
    for p in truth.people:
        legs = np.asarray(p.legs_robot_m, dtype=float).reshape(-1, 2)
        for lx, ly in legs:
            lx -= spec.mount_x_m
            rho = math.hypot(lx, ly)
            if rho < RANGE_BINS_M[0] or rho > RANGE_BINS_M[-1]:
                continue
            cx = lx - 0.78 * leg_radius_m * lx / rho
            cy = ly - 0.78 * leg_radius_m * ly / rho
            if (ok & (np.hypot(x - cx, y - cy) < 0.1)).any():
                labels.append((cx, cy))
            else:
                unseen += 1
    return np.asarray(labels, dtype=float).reshape(-1, 2), unseen


def _furnished_false(name: str, seed: int) -> CandidateFigures:
    """False candidates per scan of the default detector in a furnished scenario, the robot
    turning on the spot at 20 deg/s (a candidate within 0.5 m of a person is true)."""
    scenario = load_builtin(name)
    scenario = msgspec.structs.replace(scenario, duration_s=min(scenario.duration_s, 36.0))
    sim = Simulation(scenario, seed=seed)
    runs = []
    scan = None
    while not sim.finished:
        sim.command_velocity(0.0, math.radians(20.0))
        for msg in sim.tick():
            if isinstance(msg, LaserScan):
                scan = msg
            elif isinstance(msg, GroundTruth) and scan is not None:
                runs.append((scan, msg))
                scan = None
    mount = scenario.laser.mount_x_m

    def at_person(i: int, xy: tuple[float, float]) -> bool:
        truth = runs[i][1]
        return any(
            math.hypot(xy[0] - (p.robot_x_m - mount), xy[1] - p.robot_y_m) < 0.5
            for p in truth.people
        )

    return false_candidates([s for s, _ in runs], exclude=at_person)


def measure_sim(*, seed: int = 1, duration_s: float = 20.0) -> SimFigures:
    """Every figure of :class:`~followbot.realstats.RealFigures`, measured on the simulator's
    ``measured`` laser model (module doc)."""
    scenario = _scenario("realism_legs", REAL_SCANNER, _WALKERS, duration_s, seed)
    runs = _run(Simulation(scenario))
    items, unseen, seen = [], 0, 0
    radius = scenario.people[0].gait.leg_radius_m
    for scan, truth in runs:
        labels, n_unseen = _labels(scan, truth, scenario.laser, radius)
        items.append((scan, labels))
        unseen += n_unseen
        seen += labels.shape[0]
    legs = leg_figures(items)
    still = _scenario("realism_static", REAL_SCANNER, [], 10.0, seed)
    static = [s for s, _ in _run(Simulation(still))]
    furnished: dict[str, dict[str, float]] = {}
    total = CandidateFigures()
    for name in FURNISHED:
        c = _furnished_false(name, seed)
        total.add(c)
        furnished[name] = {"scans": c.scans, "per_scan": c.per_scan, "any_share": c.any_share}
    furnished["all"] = {"scans": total.scans, "per_scan": total.per_scan,
                        "any_share": total.any_share}  # fmt: skip
    return SimFigures(
        legs=legs,
        legs_without_returns=unseen / (seen + unseen) if seen + unseen else math.nan,
        noise=noise_figures(static),
        scans=scan_figures(static),
        false_furnished=furnished,
    )


def rows(real: RealFigures, sim: SimFigures) -> list[tuple[str, float, float]]:
    """(statistic, real, simulated) for every compared figure."""
    rl, sl = real.legs, sim.legs
    out = [
        (f"returns per leg, {b}", rl.returns_per_leg[i], sl.returns_per_leg[i])
        for i, b in enumerate(rl.bins)
    ]
    out += [
        ("legs with dropouts (< half the expected returns)", rl.dropout_share_all,
         sl.dropout_share_all),
        ("people with one leg seen", rl.one_leg_share, sl.one_leg_share),
        ("duplicated beams on legs", rl.duplicate_share, sl.duplicate_share),
        ("leg edges: mixed pixel", rl.edges.mixed_share, sl.edges.mixed_share),
        ("leg edges: no return", rl.edges.invalid_share, sl.edges.invalid_share),
    ]  # fmt: skip
    out += [
        (f"range noise std (m), {b}", real.noise.std_m[i], sim.noise.std_m[i])
        for i, b in enumerate(real.noise.bins)
        if math.isfinite(real.noise.std_m[i])
    ]
    carmen, furnished = real.false_carmen["all"], sim.false_furnished["all"]
    out += [
        ("invalid beams on continuous surfaces", real.scans.surface_invalid_share,
         sim.scans.surface_invalid_share),
        ("duplicated beams (neighbour equal), whole scan", real.scans.neighbour_equal_share,
         sim.scans.neighbour_equal_share),
        ("false candidates per scan: CARMEN logs vs furnished rooms", carmen["per_scan"],
         furnished["per_scan"]),
        ("scans with a false candidate: CARMEN logs vs furnished rooms", carmen["any_share"],
         furnished["any_share"]),
    ]  # fmt: skip
    return out


def within_band(real: float, sim: float, band: float = 0.30) -> bool:
    return math.isfinite(real) and math.isfinite(sim) and abs(sim - real) <= band * abs(real)


def compare(real: RealFigures, sim: SimFigures) -> str:
    """The side-by-side table as Markdown."""
    lines = ["| statistic | real | simulated | sim / real |", "|---|---|---|---|"]
    for name, a, b in rows(real, sim):
        ratio = b / a if a else math.nan
        mark = "" if within_band(a, b) else " (outside +-30 %)"
        lines.append(f"| {name} | {a:.4g} | {b:.4g} | {ratio:.2f}{mark} |")
    lines.append("")
    lines.append(
        f"Simulated legs in view with no return at all (not labelled in real data): "
        f"{sim.legs_without_returns:.1%}"
    )
    return "\n".join(lines)
