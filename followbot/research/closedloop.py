"""In-process closed loop: simulator -> leg detector -> tracker -> controller -> simulator.

The same sequence of messages a lock-step run over Zenoh would see, in one process and one
thread, for tests and figures. Vision is a stand-in: ``vision="oracle"``
publishes, for every scan, a Verification choosing the candidate nearest the true target when
the camera sees it (the tracker is measured, not a verifier); ``vision_lag_scans`` delays it.
The target model is given at the first scan from the truth (thesis 4.2: model construction
finds the target's laser position).

    python -m followbot.research.closedloop thesis_5_2_4_two_people --estimator ukf

Metrics follow DESIGN.md "Metric definitions".
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any, Literal

import msgspec
import numpy as np

from followbot.schemas import (
    GroundTruth,
    LaserScan,
    Odometry,
    PersonCandidates,
    TargetModel,
    TrackState,
    Verification,
    VerifiedCandidate,
)
from followbot.services.controller.avoid import scan_points, scan_view
from followbot.services.controller.core import ControllerSettings, FollowController
from followbot.services.laser_legs.detectors import make_detector
from followbot.services.runtime.mount import LaserMount
from followbot.services.sim.scenario import Scenario, load_builtin
from followbot.services.sim.simulation import Simulation
from followbot.services.tracker.core import Tracker, TrackerSettings

__all__ = ["Record", "metrics", "run"]

_NS = 1_000_000_000


class Record(msgspec.Struct):
    """One scan of a run: the estimate and the truth, both in the base frame of the scan."""

    t_s: float
    status: str
    est: tuple[float, float, float, float]
    true: tuple[float, float, float, float] | None
    visible: bool
    others: list[tuple[float, float]]
    robot: tuple[float, float, float]
    """True robot pose (world)."""
    true_world: tuple[float, float] | None
    flags: list[str]
    n_people: int


def _oracle(cands: PersonCandidates, truth: GroundTruth, camera_fov_rad: float) -> Verification:
    tgt = next((p for p in truth.people if p.is_target), None)
    vcs, best, best_d = [], -1, 0.3
    for i, c in enumerate(cands.candidates):
        rel = math.atan2(c.y_m, c.x_m) - truth.camera_pan_rad
        in_view = abs(math.atan2(math.sin(rel), math.cos(rel))) < camera_fov_rad / 2
        d = math.inf if tgt is None else math.hypot(c.x_m - tgt.robot_x_m, c.y_m - tgt.robot_y_m)
        vcs.append(
            VerifiedCandidate(
                index=i,
                x_m=c.x_m,
                y_m=c.y_m,
                in_view=in_view,
                distance=min(d, 10.0) if in_view else None,
            )
        )
        if in_view and tgt is not None and tgt.visible_camera and d < best_d:
            best, best_d = i, d
    return Verification(
        stamp_ns=cands.stamp_ns,
        image_stamp_ns=cands.stamp_ns,
        model_id=1,
        verifier="oracle",
        candidates=vcs,
        chosen=best,
    )


def run(
    scenario: Scenario | str,
    *,
    estimator: str = "particle",
    tracker: dict[str, Any] | None = None,
    controller: bool | ControllerSettings = True,
    vision: Literal["oracle", "none"] = "oracle",
    seed: int | None = None,
    duration_s: float | None = None,
    drive: tuple[float, float] | None = None,
    candidates: Literal["detector", "truth"] = "detector",
    truth_noise_m: float = 0.0,
    odometry: bool = True,
) -> list[Record]:
    """Run ``scenario`` closed loop; one :class:`Record` per scan.

    ``drive=(v, w)`` replaces the controller's base command by a constant one (the camera still
    follows the controller's pan);
    ``candidates="truth"`` replaces the detector by the true target position (plus
    ``truth_noise_m`` of Gaussian noise) to isolate the tracker from the detector;
    ``odometry=False`` withholds odometry from the tracker (no ego-motion compensation).
    """
    sc = load_builtin(scenario) if isinstance(scenario, str) else scenario
    sim = Simulation(sc, seed=seed)
    detector = make_detector("thesis")
    settings = msgspec.convert({"estimator": estimator, **(tracker or {})}, TrackerSettings)
    trk = Tracker(settings, sc.laser.mount())
    trk.set_vision_alive(vision != "none")
    ctl = None
    if controller:
        ctl = FollowController(controller if isinstance(controller, ControllerSettings) else None)
    noise_rng = np.random.default_rng(12345)
    fov = math.radians(sc.camera.hfov_deg)
    end_ns = sim.duration_ns if duration_s is None else int(duration_s * _NS)
    records: list[Record] = []
    last_stamp: int | None = None
    scan: LaserScan | None = None
    if drive is not None:
        sim.command_velocity(*drive)
    while sim.t_ns < end_ns:
        msgs = sim.tick()
        for m in msgs:
            if isinstance(m, Odometry) and odometry:
                trk.add_odometry(m)
        for m in msgs:
            if isinstance(m, LaserScan):
                scan = m
            elif isinstance(m, GroundTruth) and scan is not None:
                truth = m
                tgt = next((p for p in truth.people if p.is_target), None)
                if candidates == "truth":
                    cands = _truth_candidates(scan, tgt, truth_noise_m, noise_rng)
                else:
                    cands = detector.detect(scan)
                if not records and tgt is not None:
                    trk.set_target_model(_oracle_model(scan.stamp_ns, tgt))
                state, people = trk.step(cands)
                if vision == "oracle":
                    trk.add_verification(_oracle(cands, truth, fov))
                if ctl is not None:
                    dt = 0.12 if last_stamp is None else (scan.stamp_ns - last_stamp) / _NS
                    _command(sim, ctl, state, dt, scan, sc.laser.mount())
                if drive is not None:
                    sim.command_velocity(*drive)  # the base is driven; the camera still pans
                last_stamp = scan.stamp_ns
                records.append(_record(truth, state, len(people.tracks)))
                scan = None
    return records


def _oracle_model(stamp_ns: int, tgt) -> TargetModel:
    """The target model an oracle camera builds of the true target at ``stamp_ns``."""
    return TargetModel(
        stamp_ns=stamp_ns,
        model_id=1,
        verifier="oracle",
        x_m=tgt.robot_x_m,
        y_m=tgt.robot_y_m,
        rect_width_px=60,
        rect_height_px=200,
        image_width=320,
        image_height=240,
    )


def _command(sim, ctl, state: TrackState, dt: float, scan: LaserScan, mount: LaserMount) -> None:
    """The controller's command for ``state``, sent to the simulated base and camera."""
    pts = view = None
    if ctl.guard is not None:  # the controller's obstacle guard sees the scan
        pts = scan_points(scan, mount)
        view = scan_view(scan, mount)
    cmd = ctl.on_target(state, dt, pts, view)
    sim.command_velocity(cmd.linear_mps, cmd.angular_radps)
    sim.command_pan(cmd.pan_rad)


def _truth_candidates(scan: LaserScan, tgt, noise_m: float, rng) -> PersonCandidates:
    from followbot.schemas import Candidate

    cands = []
    if tgt is not None and tgt.visible_laser:
        x = tgt.robot_x_m + (rng.normal(0, noise_m) if noise_m else 0.0)
        y = tgt.robot_y_m + (rng.normal(0, noise_m) if noise_m else 0.0)
        cands.append(
            Candidate(x_m=x, y_m=y, range_m=math.hypot(x, y), bearing_rad=math.atan2(y, x))
        )
    return PersonCandidates(stamp_ns=scan.stamp_ns, frame_id=scan.frame_id, candidates=cands)


def _record(truth: GroundTruth, st: TrackState, n_people: int) -> Record:
    tgt = next((p for p in truth.people if p.is_target), None)
    others = [(p.robot_x_m, p.robot_y_m) for p in truth.people if not p.is_target]
    return Record(
        t_s=truth.stamp_ns / _NS,
        status=st.status,
        est=(st.x_m, st.y_m, st.vx_mps, st.vy_mps),
        true=None
        if tgt is None
        else (tgt.robot_x_m, tgt.robot_y_m, tgt.robot_vx_mps, tgt.robot_vy_mps),
        visible=bool(tgt is not None and tgt.visible_laser),
        others=others,
        robot=(truth.robot_x_m, truth.robot_y_m, truth.robot_yaw_rad),
        true_world=None if tgt is None else (tgt.x_m, tgt.y_m),
        flags=list(st.flags),
        n_people=n_people,
    )


def world_estimate(r: Record) -> tuple[float, float]:
    """The estimate carried to world coordinates with the true robot pose."""
    x, y, yaw = r.robot
    c, s = math.cos(yaw), math.sin(yaw)
    return (x + c * r.est[0] - s * r.est[1], y + s * r.est[0] + c * r.est[1])


def metrics(records: list[Record], scan_period_s: float = 0.12) -> dict[str, float]:
    """DESIGN.md metrics of one run (target only)."""
    err, visible, tracked_close, follow, following = [], 0, 0, 0, 0
    switches, wrong, on_target = 0, 0, False
    reacq: list[float] = []
    hidden_run, hidden_since_visible_at = 0, None
    for r in records:
        tracked = r.status == "tracking"
        e = math.inf if r.true is None else math.hypot(r.est[0] - r.true[0], r.est[1] - r.true[1])
        if r.visible:
            visible += 1
            if tracked:
                err.append(e)
                if e <= 0.5:
                    tracked_close += 1
        if tracked or r.status == "coasting":
            near_other = [math.hypot(r.est[0] - ox, r.est[1] - oy) for ox, oy in r.others]
            on_other = bool(near_other) and min(near_other) < min(e, 0.5)
            if on_other:
                wrong += 1
                if on_target:
                    switches += 1
                on_target = False
            elif e <= 0.5:
                on_target = True
            if r.true is not None:
                following += 1
                follow += 1.0 <= math.hypot(r.true[0], r.true[1]) <= 2.0
        # re-acquisition after an occlusion of >= 3 scans
        if not r.visible:
            hidden_run += 1
        else:
            if hidden_run >= 3:
                hidden_since_visible_at = r.t_s
            hidden_run = 0
            if hidden_since_visible_at is not None and tracked and e <= 0.5:
                reacq.append(r.t_s - hidden_since_visible_at)
                hidden_since_visible_at = None
    speeds_est = [math.hypot(r.est[2], r.est[3]) for r in records if r.status == "tracking"]
    speeds_true = [
        math.hypot(r.true[2], r.true[3]) for r in records if r.status == "tracking" and r.true
    ]
    return {
        "scans": len(records),
        "rmse_m": float(np.sqrt(np.mean(np.square(err)))) if err else math.nan,
        "tracked_visible_share": tracked_close / visible if visible else math.nan,
        "identity_switches": switches,
        "wrong_target_s": wrong * scan_period_s,
        "follow_distance_share": follow / following if following else math.nan,
        "reacquire_s": max(reacq) if reacq else math.nan,
        "reacquisitions": len(reacq),
        "mean_speed_est_mps": float(np.mean(speeds_est)) if speeds_est else math.nan,
        "mean_speed_true_mps": float(np.mean(speeds_true)) if speeds_true else math.nan,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("scenarios", nargs="*")
    p.add_argument("--estimator", action="append")
    p.add_argument("--vision", default="oracle", choices=["oracle", "none"])
    p.add_argument("--vision-lag-scans", type=int, default=0)
    p.add_argument("--duration", type=float)
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    from followbot.services.sim.scenario import builtin_names

    names = a.scenarios or builtin_names()
    out = []
    for name in names:
        for est in a.estimator or ["particle"]:
            recs = run(
                name,
                estimator=est,
                vision=a.vision,
                duration_s=a.duration,
                tracker={"vision_lag_scans": a.vision_lag_scans},
            )
            m = {"scenario": name, "estimator": est, **metrics(recs)}
            out.append(m)
            if not a.json:
                print(
                    f"{name:28s} {est:9s} rmse {m['rmse_m']:.3f} m"
                    f"  tracked {m['tracked_visible_share']:.3f}"
                    f"  switches {m['identity_switches']}  wrong {m['wrong_target_s']:.1f} s"
                    f"  follow {m['follow_distance_share']:.2f}  reacq {m['reacquire_s']:.2f} s"
                    f"  speed {m['mean_speed_est_mps']:.3f}/{m['mean_speed_true_mps']:.3f}"
                )
    if a.json:
        print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
