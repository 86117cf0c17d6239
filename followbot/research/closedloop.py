"""In-process closed loop: the simulator and the real stages, one scan at a time.

laser_legs, the tracker and the controller are the services' own nodes (each service's
``setup``, with a preset's settings made for lock-step as ``followbot eval`` makes them) on an
in-memory bus whose delivery is synchronous: every stage answers a scan before the simulator
moves on, in one process and one thread, so a run is deterministic and takes no Zenoh. What
each stage does to a scan is what it does in ``followbot eval``: criterion 3 on the tracker's
answer to the previous scan, the horizon, the robot-body filter, the obstacle guard.

What differs from ``followbot eval``:

- vision is an oracle stand-in, not vision_verify: for every scan it publishes a Verification
  choosing the candidate nearest the true target (within 0.3 m) when the camera sees it
  (``vision="none"``: no verifications, and the tracker sees no vision service alive);
- the target model comes from the truth at the first scan with a target, also without vision
  (thesis 4.2: model construction finds the target's laser position), so the tracker is
  measured, not the acquisition;
- research options the eval has not: ``drive`` (a constant base command instead of the
  controller's), ``candidates="truth"`` (the true target position instead of laser_legs, to
  isolate the tracker from the detector), ``odometry=False`` (no ego-motion compensation).

Each scan becomes a :class:`followbot.evaluation.ScanRecord`, so the metrics are the eval's
own (:func:`metrics` is :func:`followbot.evaluation.compute_metrics`).

    python -m followbot.research.closedloop thesis_5_2_4_two_people --estimator ukf
"""

from __future__ import annotations

import argparse
import json
import math
from typing import Any, Literal

import numpy as np

from followbot.evaluation import ScanRecord, ScenarioRun, compute_metrics
from followbot.runner import sensor_mounts, stage_settings
from followbot.schemas import (
    Candidate,
    GroundTruth,
    Keys,
    LaserScan,
    Odometry,
    PanCommand,
    PersonCandidates,
    TargetModel,
    VelocityCommand,
    Verification,
    VerifiedCandidate,
    decode,
    encode,
    topic_type,
)
from followbot.services.controller.node import ControllerNodeSettings
from followbot.services.controller.node import setup as controller_setup
from followbot.services.laser_legs.node import LaserLegsSettings
from followbot.services.laser_legs.node import setup as laser_legs_setup
from followbot.services.runtime.bus import FakeNetwork
from followbot.services.runtime.node import Node
from followbot.services.runtime.settings import load_settings
from followbot.services.sim.scenario import Scenario, load_builtin
from followbot.services.sim.simulation import Simulation
from followbot.services.tracker.node import TrackerNodeSettings
from followbot.services.tracker.node import setup as tracker_setup

__all__ = ["mean_speeds", "metrics", "run", "world_error_m", "world_estimate"]

_NS = 1_000_000_000
#: what the in-process evaluator keeps of each scan: topic -> ScanRecord field
_ANSWERS = {
    "perception/candidates": "candidates",
    "tracking/target": "target",
    "tracking/people": "people",
    "control/cmd_vel": "cmd",
}
_MATCH_M = 0.3  # the oracle's choice: the candidate within this of the true target


class StageDidNotAnswer(RuntimeError):
    """A stage gave no answer to a scan although every input it waits for was delivered."""


def _target(truth: GroundTruth):
    return next((p for p in truth.people if p.is_target), None)


def _oracle(
    cands: PersonCandidates, truth: GroundTruth, camera_fov_rad: float, model_id: int
) -> Verification:
    """The verification of a camera that knows the truth: every candidate in view is judged,
    the one nearest the true target is chosen when the target is in view."""
    tgt = _target(truth)
    vcs, best, best_d = [], -1, _MATCH_M
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
        model_id=model_id,
        verifier="oracle",
        candidates=vcs,
        chosen=best,
    )


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


def _truth_candidates(scan: LaserScan, tgt, noise_m: float, rng) -> PersonCandidates:
    """The true target (when the laser sees it), with ``noise_m`` of Gaussian noise."""
    cands = []
    if tgt is not None and tgt.visible_laser:
        x = tgt.robot_x_m + (rng.normal(0, noise_m) if noise_m else 0.0)
        y = tgt.robot_y_m + (rng.normal(0, noise_m) if noise_m else 0.0)
        cands.append(
            Candidate(x_m=x, y_m=y, range_m=math.hypot(x, y), bearing_rad=math.atan2(y, x))
        )
    return PersonCandidates(stamp_ns=scan.stamp_ns, frame_id=scan.frame_id, candidates=cands)


class _Pipeline:
    """The stages' nodes on one in-memory network, and the ears of the evaluator on it."""

    def __init__(self, settings: dict[str, dict[str, Any]], vision: bool) -> None:
        self.vision = vision
        self.net = FakeNetwork()
        self.nodes: list[Node] = []
        stages = {
            "laser_legs": (LaserLegsSettings, laser_legs_setup),
            "tracker": (TrackerNodeSettings, tracker_setup),
            "controller": (ControllerNodeSettings, controller_setup),
        }
        for name, values in settings.items():
            cls, setup = stages[name]
            node = Node(name, load_settings(cls, base=values), self.net.bus(name))
            setup(node, node.settings)
            self.nodes.append(node)
        self.keys: Keys = self.nodes[0].keys
        for node in self.nodes:
            node.announce()
        if vision:  # the oracle stands in for vision_verify: the tracker sees it alive
            self.net.bus("vision_verify").liveliness_token(self.keys.alive("vision_verify"))
        self.heard: dict[str, Any] = {}
        ears = self.net.bus("closedloop")
        for topic in (*_ANSWERS, "control/pan"):
            ears.subscribe(self.keys.topic(topic), lambda p, t=topic: self._hear(t, p))
        self.spin()

    def _hear(self, topic: str, payload: bytes) -> None:
        msg = decode(topic_type(topic), payload)
        self.heard.setdefault(topic, []).append(msg)

    def spin(self) -> None:
        """Let every node handle what it was sent, until none has anything left."""
        while sum(node.spin_once() for node in self.nodes):
            pass

    def put(self, topic: str, message) -> None:
        self.net.put(self.keys.topic(topic), encode(message))
        self.spin()

    def answers(self, stamp_ns: int) -> dict[str, Any]:
        """The messages heard since the last call that name ``stamp_ns`` (one per topic)."""
        out: dict[str, Any] = {}
        for topic, msgs in self.heard.items():
            mine = [m for m in msgs if m.stamp_ns == stamp_ns]
            if mine:
                out[topic] = mine[-1]
        self.heard.clear()
        return out


def run(
    scenario: Scenario | str,
    *,
    preset: str = "thesis",
    estimator: str | None = None,
    tracker: dict[str, Any] | None = None,
    laser_legs: dict[str, Any] | None = None,
    vision: Literal["oracle", "none"] = "oracle",
    seed: int | None = None,
    duration_s: float | None = None,
    drive: tuple[float, float] | None = None,
    candidates: Literal["detector", "truth"] = "detector",
    truth_noise_m: float = 0.0,
    odometry: bool = True,
) -> list[ScanRecord]:
    """Run ``scenario`` closed loop with ``preset``'s stages; one ScanRecord per scan.

    ``estimator``, ``tracker`` and ``laser_legs`` override the preset's settings of those
    stages (``tracker={"estimator_settings": {...}}``);
    ``drive=(v, w)`` replaces the controller's base command by a constant one (the camera
    still follows the controller's pan);
    ``candidates="truth"`` replaces laser_legs by the true target position (plus
    ``truth_noise_m`` of Gaussian noise) to isolate the tracker from the detector;
    ``odometry=False`` withholds odometry from the stages (no ego-motion compensation).
    Raises :class:`StageDidNotAnswer` when the tracker or the controller leaves a scan
    unanswered (a stage waiting for an input this loop does not send).
    """
    sc = load_builtin(scenario) if isinstance(scenario, str) else scenario
    wanted = stage_settings(preset, True, odometry=odometry, vision=vision != "none")
    del wanted["vision_verify"]
    if candidates == "truth":
        del wanted["laser_legs"]
    else:
        wanted["laser_legs"].update(laser_legs or {})
    wanted["tracker"].update(tracker or {})
    if estimator is not None:
        wanted["tracker"]["estimator"] = estimator
    for values in wanted.values():
        values.update(sensor_mounts(sc))
    loop = _Loop(sc, seed, _Pipeline(wanted, vision == "oracle"), drive)
    if candidates == "truth":
        loop.truth_noise_m = truth_noise_m
    loop.odometry = odometry
    end_ns = loop.sim.duration_ns if duration_s is None else int(duration_s * _NS)
    while loop.sim.t_ns < end_ns:
        loop.tick()
    return loop.records


class _Loop:
    """The simulator, the stages, the oracle and the records of one run."""

    def __init__(self, sc: Scenario, seed, pipe: _Pipeline, drive) -> None:
        self.sim = Simulation(sc, seed=seed)
        self.pipe, self.drive = pipe, drive
        self.fov_rad = math.radians(sc.camera.hfov_deg)
        self.truth_noise_m: float | None = None  # None: laser_legs finds the candidates
        self.odometry = True
        self.model_id = 0  # the oracle's target model (0: none sent yet)
        self.rng = np.random.default_rng(12345)
        self.records: list[ScanRecord] = []
        if drive is not None:
            self.sim.command_velocity(*drive)

    def tick(self) -> None:
        """The simulator's next sensor instant: odometry, then the scan through the stages."""
        msgs = self.sim.tick()
        if self.odometry:
            for m in msgs:
                if isinstance(m, Odometry):
                    self.pipe.put("sensors/odom", m)
        scan = next((m for m in msgs if isinstance(m, LaserScan)), None)
        if scan is not None:
            truth = next(m for m in msgs if isinstance(m, GroundTruth))
            self.records.append(self.step(scan, truth))

    def step(self, scan: LaserScan, truth: GroundTruth) -> ScanRecord:
        """One scan through the stages; the simulator obeys the controller; its record."""
        pipe, tgt = self.pipe, _target(truth)
        if not self.model_id and tgt is not None:
            self.model_id = 1
            pipe.put("perception/target_model", _oracle_model(scan.stamp_ns, tgt))
        if self.truth_noise_m is not None:
            cands = _truth_candidates(scan, tgt, self.truth_noise_m, self.rng)
            pipe.put("perception/candidates", cands)
        pipe.put("sensors/scan", scan)
        got = pipe.answers(scan.stamp_ns)
        for topic in ("perception/candidates", "tracking/target", "control/cmd_vel"):
            if topic not in got:
                raise StageDidNotAnswer(f"no {topic} for the scan stamped {scan.stamp_ns}")
        verification = None
        if pipe.vision:
            cands = got["perception/candidates"]
            verification = _oracle(cands, truth, self.fov_rad, self.model_id)
            pipe.put("perception/verification", verification)
        cmd: VelocityCommand = got["control/cmd_vel"]
        self.sim.command_velocity(*(self.drive or (cmd.linear_mps, cmd.angular_radps)))
        pan: PanCommand | None = got.get("control/pan")
        if pan is not None:
            self.sim.command_pan(pan.pan_rad)
        return ScanRecord(
            stamp_ns=scan.stamp_ns,
            truth=truth,
            candidates=got["perception/candidates"],
            verification=verification,
            target=got["tracking/target"],
            people=got.get("tracking/people"),
            cmd=cmd,
        )


def metrics(records: list[ScanRecord], scenario: str = "", preset: str = "") -> dict[str, Any]:
    """The eval's metrics of one run (followbot/evaluation.py defines each one)."""
    run_ = ScenarioRun(scenario=scenario, preset=preset, records=records)
    if records:
        run_.sim_s = (records[-1].stamp_ns - records[0].stamp_ns) / _NS
    return compute_metrics(run_)


def world_estimate(r: ScanRecord) -> tuple[float, float]:
    """The target estimate of ``r`` carried to world coordinates with the true robot pose."""
    x, y, yaw = r.truth.robot_x_m, r.truth.robot_y_m, r.truth.robot_yaw_rad
    c, s = math.cos(yaw), math.sin(yaw)
    return (x + c * r.target.x_m - s * r.target.y_m, y + s * r.target.x_m + c * r.target.y_m)


def world_error_m(r: ScanRecord) -> float:
    """Distance in the world between the target estimate and the true target."""
    tgt = _target(r.truth)
    ex, ey = world_estimate(r)
    return math.hypot(ex - tgt.x_m, ey - tgt.y_m)


def mean_speeds(records: list[ScanRecord]) -> tuple[float, float]:
    """(estimated, true) mean speed of the target over the scans it is tracked (status
    ``tracking``), m/s; NaN without such scans."""
    est, true = [], []
    for r in records:
        tgt = _target(r.truth)
        if r.target.status == "tracking" and tgt is not None:
            est.append(math.hypot(r.target.vx_mps, r.target.vy_mps))
            true.append(math.hypot(tgt.robot_vx_mps, tgt.robot_vy_mps))
    if not est:
        return math.nan, math.nan
    return float(np.mean(est)), float(np.mean(true))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("scenarios", nargs="*", help="built-in scenarios (default: all of them)")
    p.add_argument("--preset", default="thesis", help="the stages' preset (default: thesis)")
    p.add_argument("--estimator", action="append", help="tracker estimator (repeatable)")
    p.add_argument("--vision", default="oracle", choices=["oracle", "none"])
    p.add_argument("--vision-lag-scans", type=int, help="the tracker's vision_lag_scans")
    p.add_argument("--duration", type=float, help="seconds of each scenario (default: all)")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    a = p.parse_args(argv)
    from followbot.services.sim.scenario import builtin_names

    lag = {} if a.vision_lag_scans is None else {"vision_lag_scans": a.vision_lag_scans}
    out = []
    for name in a.scenarios or builtin_names():
        for est in a.estimator or [None]:
            recs = run(name, preset=a.preset, estimator=est, vision=a.vision,
                       duration_s=a.duration, tracker=lag)  # fmt: skip
            m = metrics(recs, name, a.preset)
            m["estimator"] = est or "(preset's)"
            out.append(m)
            if not a.json:
                print(_line(name, est or a.preset, m))
    if a.json:
        print(json.dumps(out, indent=2, default=str))
    return 0


def _line(name: str, est: str, m: dict[str, Any]) -> str:
    def f(v, fmt):
        return "-" if v is None else format(v, fmt)

    return (
        f"{name:28s} {est:13s} rmse {f(m['rmse_m'], '.3f')} m"
        f"  tracked {f(m['tracked_visible_share'], '.3f')}"
        f"  switches {m['identity_switches']}  wrong {m['wrong_target_s']:.1f} s"
        f"  follow {f(m['follow_distance_share'], '.2f')}  reacq {f(m['reacquire_s'], '.2f')} s"
    )


if __name__ == "__main__":
    raise SystemExit(main())
