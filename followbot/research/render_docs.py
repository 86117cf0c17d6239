"""Pictures of the simulator for docs/scenarios.md: camera frames and top-down plots.

    python -m followbot.research.render_docs            # writes docs/img/*.png
    python -m followbot.research.render_docs --out DIR

Deterministic: each picture comes from a fixed scenario, seed and instant. Where the scenario
is about following, the robot is steered by a stand-in for the pipeline that reads the ground
truth (:func:`truth_follower`: turn towards the target, keep 1.2-1.5 m, pan the camera at it),
so the frames show what a following robot would see. The top-down plot draws the walls, boxes
and round obstacles, each person's path (coloured by shirt; the target's thick), the robot's
path, and one laser scan as dots.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np

from followbot.schemas import GroundTruth, LaserScan
from followbot.services.sim.scenario import load_builtin
from followbot.services.sim.simulation import Simulation

__all__ = ["FRAMES", "PLOTS", "main", "render_frame", "render_plot", "truth_follower"]

#: (scenario, sim time s, follow the target?) of each camera frame.
FRAMES: list[tuple[str, float, bool]] = [
    ("thesis_5_2_4_two_people", 5.8, True),
    ("thesis_5_2_3_room_corridor", 5.0, True),
    ("bellotto_cluttered_office", 12.0, False),
    ("crowd_ten", 14.0, False),
]
#: (scenario, sim time of the drawn scan s, follow the target?) of each top-down plot.
PLOTS: list[tuple[str, float, bool]] = [
    ("thesis_5_2_4_two_people", 5.8, True),
    ("bellotto_cluttered_office", 12.0, False),
    ("thesis_5_2_3_room_corridor", 16.0, True),
    ("crowd_ten", 14.0, False),
]

_NS = 1_000_000_000


def truth_follower(sim: Simulation, truth: GroundTruth) -> None:
    """Steer ``sim``'s robot at the target from ground truth (a stand-in for the pipeline)."""
    target = next((p for p in truth.people if p.is_target), None)
    if target is None:
        sim.command_velocity(0.0, 0.0)
        return
    r = math.hypot(target.robot_x_m, target.robot_y_m)
    bearing = math.atan2(target.robot_y_m, target.robot_x_m)
    v = 0.0 if r < 1.2 else min(0.75, 0.6 * (r - 1.2) + 0.3)
    sim.command_velocity(v, max(-1.7, min(1.7, 1.5 * bearing)))
    sim.command_pan(0.0)  # the base turns to the target; keep the camera straight ahead


def _run_to(name: str, t_s: float, follow: bool):
    """Run a scenario to ``t_s``; returns the sim, robot poses, last scan and last truth."""
    sim = Simulation(load_builtin(name))
    poses: list[tuple[float, float]] = []
    scan: LaserScan | None = None
    truth: GroundTruth | None = None
    end_ns = round(t_s * _NS)
    while sim.next_tick_ns <= end_ns:
        for msg in sim.tick():
            if isinstance(msg, LaserScan):
                scan = msg
            elif isinstance(msg, GroundTruth):
                truth = msg
                poses.append((msg.robot_x_m, msg.robot_y_m))
                if follow:
                    truth_follower(sim, msg)
    return sim, poses, scan, truth


def render_frame(name: str, t_s: float, follow: bool) -> np.ndarray:
    """The camera image (BGR) of scenario ``name`` at ``t_s``."""
    sim, *_ = _run_to(name, t_s, follow)
    return sim.image().pixels().copy()


def render_plot(name: str, t_s: float, follow: bool, path: Path) -> None:
    """A top-down plot of scenario ``name`` with the scan at ``t_s``, saved as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Polygon, Wedge

    sim, poses, scan, _ = _run_to(name, t_s, follow)
    sc = sim.scenario
    # the whole run for the people's paths (pure functions of time)
    times = np.arange(0.0, sc.duration_s, 0.1)
    fig, ax = plt.subplots(figsize=(8.0, 5.6), dpi=110)
    for x0, y0, x1, y1 in sim.world.segments[sim.world.segment_is_wall]:
        ax.plot([x0, x1], [y0, y1], color="0.15", lw=2.2, solid_capstyle="round")
    for box in sc.world.boxes:
        c, s = math.cos(math.radians(box.yaw_deg)), math.sin(math.radians(box.yaw_deg))
        hl, hw = box.size_m[0] / 2, box.size_m[1] / 2
        pts = [
            (box.centre[0] + c * dx - s * dy, box.centre[1] + s * dx + c * dy)
            for dx, dy in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))
        ]
        low = box.height_m <= sc.laser.height_m
        ax.add_patch(
            Polygon(
                pts,
                closed=True,
                fc=np.array(box.colour_rgb) / 255,
                ec="0.2",
                alpha=0.35 if low else 0.8,
                hatch="//" if low else None,
            )
        )
    for circ in sc.world.circles:
        low = circ.height_m <= sc.laser.height_m
        ax.add_patch(
            Circle(
                circ.centre,
                max(circ.radius_m, 0.03),
                fc=np.array(circ.colour_rgb) / 255,
                ec="0.2",
                alpha=0.35 if low else 0.9,
            )
        )
    for person in sim.people:
        track = np.array([person.state(float(t)).position for t in times])
        colour = np.array(person.spec.appearance.shirt_rgb) / 255
        lw, z = (3.0, 5) if person.is_target else (1.4, 4)
        label = f"{person.id}{' (target)' if person.is_target else ''}"
        ax.plot(track[:, 0], track[:, 1], color=colour, lw=lw, alpha=0.85, zorder=z, label=label)
        ax.plot(*track[0], "o", color=colour, mec="k", ms=7, zorder=z + 1)
        now = person.state(t_s)
        for leg in now.legs:
            ax.add_patch(Circle(leg, person.leg_radius_m, fc=colour, ec="k", lw=0.8, zorder=8))
    robot = np.array(poses)
    ax.plot(robot[:, 0], robot[:, 1], "--", color="0.35", lw=1.4, zorder=3, label="robot")
    x, y, yaw = sim.robot.pose
    fov = math.degrees(math.radians(sc.laser.fov_deg)) / 2
    ax.add_patch(
        Wedge(
            (x, y),
            0.6,
            math.degrees(yaw) - fov,
            math.degrees(yaw) + fov,
            fc="0.6",
            alpha=0.25,
            zorder=2,
        )
    )
    ax.add_patch(Circle((x, y), sc.robot.radius_m, fc="0.85", ec="k", zorder=9))
    ax.plot([x, x + 0.35 * math.cos(yaw)], [y, y + 0.35 * math.sin(yaw)], "k-", lw=2, zorder=10)
    if scan is not None:
        r = scan.ranges_m().astype(float)
        a = scan.angles_rad() + yaw
        ok = np.isfinite(r)
        ax.plot(
            x + r[ok] * np.cos(a[ok]),
            y + r[ok] * np.sin(a[ok]),
            ".",
            color="#e600e6",
            ms=2.2,
            zorder=11,
            label=f"scan at t = {t_s:g} s",
        )
    ax.set_aspect("equal")
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    title = f"{sc.name}: paths over {sc.duration_s:g} s, legs and scan at t = {t_s:g} s"
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/img", help="output folder (default docs/img)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, t_s, follow in FRAMES:
        img = render_frame(name, t_s, follow)
        path = out / f"frame_{name}_{t_s:g}s.png"
        cv2.imwrite(str(path), img)
        sys.stdout.write(f"wrote {path}\n")
    for name, t_s, follow in PLOTS:
        path = out / f"topdown_{name}.png"
        render_plot(name, t_s, follow, path)
        sys.stdout.write(f"wrote {path}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
