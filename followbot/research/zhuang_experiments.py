"""Seed 001's two experiments replayed in the simulator, in one process (no Zenoh):
``python -m followbot.research.zhuang_experiments --output docs/img``.

Each camera frame of a zhuang_* scenario goes through the camera stage (colour classes and
regions, services/camera_blobs/core.py), the hybrid filter with the robot's odometry between
frames (services/tracker/estimators/hybrid.py) and the seed's rule (services/controller/
zhuang.py), whose command drives the simulated robot. The colour is learnt on the first frame
from a rectangle on the target's trousers, as the seed's user drags one with the mouse (placed
here from the simulator's truth: the one thing the user tells the robot). Prints per run the
image-column error of the estimate against the truth, the share of frames the person is in the
dead band, the follow distance, and the frames whose estimate (its floor point) is within 0.5 m
of the target, or nearer another person than the target and within 0.5 m of them; writes a
plot of estimated against true column over time (the seed's figure 5) per run.

The runs measure the algorithm's parts together; the services carrying them over Zenoh are
not part of this replay.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["ExperimentResult", "main", "run_experiment"]

RUNS = {  # scenario -> the robot may translate (fixating: it only turns, seed 5.1)
    "zhuang_fixating": False,
    "zhuang_corridor": True,
    "zhuang_same_colour": True,
    "zhuang_crossing": True,
}


@dataclass
class ExperimentResult:
    scenario: str
    t_s: list[float] = field(default_factory=list)
    true_col: list[float] = field(default_factory=list)
    est_col: list[float] = field(default_factory=list)
    distance_m: list[float] = field(default_factory=list)
    on_other: list[bool] = field(default_factory=list)
    on_target: list[bool] = field(default_factory=list)
    measured: list[bool] = field(default_factory=list)

    def figures(self, width: int) -> dict[str, float]:
        err = np.abs(np.array(self.est_col) - np.array(self.true_col))
        ok = np.isfinite(err)
        k = width / 192
        col = np.array(self.true_col)
        in_band = (col >= 76 * k) & (col <= 116 * k)
        d = np.array(self.distance_m)
        later = np.array(self.t_s) >= 4.0  # after the first turn toward the person
        return {
            "frames": len(self.t_s),
            "col_rmse_px": float(np.sqrt(np.mean(err[ok] ** 2))),
            "col_err_p95_px": float(np.percentile(err[ok], 95)),
            "in_dead_band_share": float(np.mean(in_band[later])),
            "distance_in_band_share": float(np.mean((d[later] >= 1.5) & (d[later] <= 2.5))),
            "frames_on_target": int(np.sum(self.on_target)),
            "frames_on_other_person": int(np.sum(self.on_other)),
            "measured_share": float(np.mean(self.measured)),
        }


def _se2_change(p0, p1) -> tuple[np.ndarray, np.ndarray]:
    """Base frame at p0 -> base frame at p1 (odometry poses): p1 = R(th0 - th1) p0 +
    R(-th1) (t0 - t1)."""

    def rot(a):
        return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])

    r = rot(p0[2] - p1[2])
    t = rot(-p1[2]) @ (np.array(p0[:2]) - np.array(p1[:2]))
    return r, t


def run_experiment(
    name: str, seed: int | None = None, learn_on: str = "trousers"
) -> tuple[ExperimentResult, int]:
    """One scenario, the colour learnt from the target's ``learn_on`` (trousers or shirt: then
    the regions' floor points are read on the shirt hem's plane)."""
    from followbot.runner import learn_rect, shirt_hem_m
    from followbot.schemas import Image, Odometry
    from followbot.services.camera_blobs.core import classify, learn_colour, regions
    from followbot.services.controller.zhuang import ZhuangRule
    from followbot.services.runtime.ground_plane import GroundCamera
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation
    from followbot.services.tracker.estimators.hybrid import HybridFilter, HybridSettings

    scenario = load_builtin(name)
    sim = Simulation(scenario, seed=seed)
    cs = scenario.camera
    cam = GroundCamera(
        width=cs.width, height=cs.height, hfov_deg=cs.hfov_deg, height_m=cs.height_m,
        mount_x_m=cs.mount_x_m,
    )  # fmt: skip
    rule, translate = ZhuangRule(), RUNS.get(name, True)
    out = ExperimentResult(name)
    colour = hpf = None
    odom = last_pose = None
    last_t = 0.0
    rng = np.random.default_rng(0 if seed is None else seed)
    while not sim.finished:
        for msg in sim.tick():
            if isinstance(msg, Odometry):
                odom = (msg.x_m, msg.y_m, msg.yaw_rad)
            if not isinstance(msg, Image):
                continue
            truth = sim.truth()
            target = next(p for p in truth.people if p.is_target)
            others = [p for p in truth.people if not p.is_target]
            tu, _ = cam.floor_to_pixel(target.robot_x_m, target.robot_y_m)
            img = msg.pixels()
            if colour is None:  # the user's rectangle, placed from the truth at the start
                colour = learn_colour(img, learn_rect(scenario, learn_on))
            boxes = regions(classify(img, colour))
            t = msg.stamp_ns / 1e9
            if hpf is None:
                if len(boxes) == 0:
                    continue
                first = boxes[np.argmin(np.abs(boxes[:, 0] - float(tu)))]
                bottom = shirt_hem_m(scenario) if learn_on == "shirt" else 0.0
                hs = HybridSettings(camera=cam, region_bottom_m=bottom)
                hpf = HybridFilter(first, hs, rng)
                measured = True
            else:
                motion = _se2_change(last_pose, odom) if odom and last_pose else (None, None)
                measured = hpf.step(boxes, t - last_t, *motion)
            last_t, last_pose = t, odom
            fx, fy = hpf.floor_point()
            dist = math.hypot(fx - cam.mount_x_m, fy)
            v, w = rule.command(float(hpf.position[0]), cam.width, dist)
            sim.command_velocity(v if translate else 0.0, max(-1.7, min(1.7, w)))
            out.t_s.append(t)
            out.true_col.append(float(tu))
            out.est_col.append(float(hpf.position[0]))
            out.distance_m.append(math.hypot(target.robot_x_m, target.robot_y_m))
            near_t = math.hypot(fx - target.robot_x_m, fy - target.robot_y_m)
            out.on_target.append(near_t < 0.5)
            out.on_other.append(
                any(
                    math.hypot(fx - o.robot_x_m, fy - o.robot_y_m) < min(0.5, near_t)
                    for o in others
                )
            )
            out.measured.append(bool(measured))
    return out, cam.width


def plot(result: ExperimentResult, width: int, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(result.t_s, result.true_col, label="true column", lw=1.5)
    ax.plot(result.t_s, result.est_col, label="estimate (MAP)", lw=1.0, ls="--")
    k = width / 192
    ax.axhspan(76 * k, 116 * k, color="0.85", label="dead band (76-116 of 192)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"image column (px of {width})")
    ax.set_ylim(0, width)
    ax.set_title(f"{result.scenario}: estimated and true image position", fontsize=10)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m followbot.research.zhuang_experiments",
        description="Replay seed 001's fixating and following experiments in the simulator "
        "(camera stage + hybrid filter + the seed's rule in one process); print figures and "
        "write a plot of estimated against true image column per scenario.",
    )
    p.add_argument("--output", type=Path, default=Path("out/zhuang"), help="(out/zhuang)")
    p.add_argument("--scenarios", default=",".join(RUNS), help="comma-separated (all three)")
    p.add_argument("--seed", type=int, default=None, help="(each scenario's own)")
    p.add_argument(
        "--learn-on", choices=("trousers", "shirt"), default="trousers",
        help="the clothing the colour is learnt from (trousers)",
    )  # fmt: skip
    args = p.parse_args(argv)
    args.output.mkdir(parents=True, exist_ok=True)
    for name in args.scenarios.split(","):
        result, width = run_experiment(name.strip(), args.seed, args.learn_on)
        figs = result.figures(width)
        print(f"{name}: " + ", ".join(f"{k} {v:.3g}" for k, v in figs.items()))
        plot(result, width, args.output / f"{name}.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
