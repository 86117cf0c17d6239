"""The default pipeline under load: laser_legs → tracker → controller as real processes.

Measured in one run (``followbot bench`` calls :func:`run`):

* per stage, in one process: the defaults' stages (the followbot preset: the learned
  detector, the particle-filter tracker with the evidence initiator) and the controller on
  the same scans, p50/p99, for 1, 5 and 10 people in view, back to back and with a 25 ms
  sleep before each scan (as at 40 Hz: caches go cold between scans);
* end to end over Zenoh: scan published → the cmd_vel that names its stamp received, p50/p99,
  for 1, 5 and 10 people (three separate processes, four hops);
* the highest scan rate the processes sustain: every scan answered, p99 under 50 ms (a rate
  answered only through a growing backlog is not sustained);
* the same end to end at 200 scans/s, where no process idles between scans;
* the ratio of end to end to (sum of in-process stage times + 4 hops at the bare floor), with
  the floor measured at 500 scans/s and at 40 scans/s: between scans 25 ms apart every
  process sleeps, and waking the receiving threads costs each hop about 0.2 ms more than
  when they are kept busy (``followbot bench``'s "bare, at 40 Hz" line).

Vision is not on this path: the tracker never waits for it (DESIGN.md, timing model).
"""

from __future__ import annotations

import math
import os
import sys
import time

import msgspec
import numpy as np

from followbot.schemas import LaserScan, Odometry

N_BEAMS = 720
#: A rate is sustained when every scan is answered with p99 latency under this (no backlog).
SUSTAINED_P99_MS = 50.0
FOV_RAD = math.radians(270.0)
LEG_RADIUS_M = 0.06
# A 12 m x 12 m room round the robot.
_ROOM = np.array([[-6, -6, 6, -6], [6, -6, 6, 6], [6, 6, -6, 6], [-6, 6, -6, -6]], dtype=np.float64)


def people_circles(k: int, t_s: float) -> np.ndarray:
    """Leg circles (2k x 3) of ``k`` people spread over the field of view, walking slowly."""
    rows = []
    for i in range(k):
        bearing = math.radians(-100 + 200 * (i + 0.5) / k)
        r = 1.3 + 0.22 * i
        cx, cy = r * math.cos(bearing), r * math.sin(bearing)
        # sideways sway of 0.3 m, legs 0.2 m apart, swinging 0.15 m
        sway = 0.3 * math.sin(0.5 * t_s + i)
        tx, ty = -math.sin(bearing), math.cos(bearing)
        cx, cy = cx + sway * tx, cy + sway * ty
        swing = 0.15 * math.sin(4 * math.pi * t_s + i)
        for side in (-1, 1):
            rows.append(
                [cx + side * 0.1 * math.cos(bearing) + side * swing * tx,
                 cy + side * 0.1 * math.sin(bearing) + side * swing * ty,
                 LEG_RADIUS_M]
            )  # fmt: skip
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def scan_bank(k: int, n: int, rate_hz: float = 40.0, seed: int = 0) -> list[LaserScan]:
    """``n`` consecutive scans of ``k`` people (15 mm noise); stamps are set by the sender."""
    from followbot.services.sim.laser import cast_rays

    rng = np.random.default_rng(seed)
    a0, inc = -FOV_RAD / 2, FOV_RAD / (N_BEAMS - 1)
    out = []
    for j in range(n):
        ranges, _ = cast_rays(
            (0.0, 0.0), a0, inc, N_BEAMS, _ROOM, people_circles(k, j / rate_hz), 30.0
        )
        ranges = ranges + rng.normal(0, 0.015, ranges.shape)
        out.append(
            LaserScan.from_ranges(
                ranges.astype(np.float32), stamp_ns=0, frame_id="base_laser",
                angle_min_rad=a0, angle_increment_rad=inc, range_min_m=0.02, range_max_m=30.0,
            )
        )  # fmt: skip
    return out


def _pct(values) -> tuple[float, float]:
    a = np.asarray(values, dtype=np.float64)
    return float(np.percentile(a, 50)), float(np.percentile(a, 99))


def preset_settings(service: str) -> dict:
    """The settings the defaults (the followbot preset) give ``service``."""
    from followbot.services.runtime.compose import PRESETS

    return dict(PRESETS["followbot"].get(service, {}))


def in_process(k: int, n: int = 400, gap_s: float = 0.0) -> dict[str, dict[str, float]]:
    """Each stage's time per scan, all in this process, p50/p99 in ms. ``gap_s``: sleep this
    long before each scan, as a process does between scans at 1 / gap_s Hz (its caches go
    cold and the CPU may idle down: the stages then take 1.4-2 times as long here)."""
    from followbot.services.controller.core import FollowController
    from followbot.services.laser_legs import make_detector
    from followbot.services.tracker.core import Tracker
    from followbot.services.tracker.settings import TrackerSettings

    legs = preset_settings("laser_legs")
    detector = make_detector(legs.get("detector", "thesis"), legs.get("detector_settings"))
    tracker = Tracker(msgspec.convert(preset_settings("tracker"), TrackerSettings))
    controller = FollowController()
    times: dict[str, list[float]] = {"laser_legs": [], "tracker": [], "controller": []}
    answer: list[float] = []  # the tracker's step_target alone: what a scan's cmd_vel waits for
    period_ns = 25_000_000
    for j, scan in enumerate(scan_bank(k, n)):
        stamp = 1_000_000_000 + j * period_ns
        scan.stamp_ns = stamp
        tracker.add_odometry(Odometry(stamp_ns=stamp, frame_id="odom", x_m=0, y_m=0, yaw_rad=0))
        if gap_s:
            time.sleep(gap_s)
        t0 = time.perf_counter_ns()
        cands = detector.detect(scan)
        t1 = time.perf_counter_ns()
        target = tracker.step_target(cands)
        t_answer = time.perf_counter_ns()
        tracker.step_rest()
        t2 = time.perf_counter_ns()
        controller.on_target(target, period_ns / 1e9)
        t3 = time.perf_counter_ns()
        if j >= 20:  # warm-up: let tracks form
            times["laser_legs"].append((t1 - t0) / 1e6)
            times["tracker"].append((t2 - t1) / 1e6)
            answer.append((t_answer - t1) / 1e6)
            times["controller"].append((t3 - t2) / 1e6)
    out = {}
    for stage, v in times.items():
        p50, p99 = _pct(v)
        out[stage] = {"stage_p50_ms": p50, "stage_p99_ms": p99}
    p50, p99 = _pct(answer)
    out["tracker"].update(answer_p50_ms=p50, answer_p99_ms=p99)
    return out


class Pipeline:
    """laser_legs, tracker and controller as processes, fed and watched by this one.
    ``together``: the three in one process (``followbot run laser_legs+tracker+controller``)."""

    SERVICES = ("laser_legs", "tracker", "controller")

    def __init__(self, log_dir, together: bool = False) -> None:
        from followbot.services.runtime.bus import ZenohBus
        from followbot.services.runtime.node import Node
        from followbot.services.runtime.session import free_loopback_endpoint, open_session
        from followbot.services.runtime.settings import NodeSettings, ZenohSettings

        self.endpoint = free_loopback_endpoint()
        self.robot = f"bench{os.getpid()}"
        self.session = open_session(ZenohSettings(listen=[self.endpoint]))
        self.node = Node(
            "bench_src", NodeSettings(robot=self.robot, health_period_s=3600),
            ZenohBus(self.session),
        )  # fmt: skip
        self.scans = self.node.publisher("sensors/scan")
        self.odom = self.node.publisher("sensors/odom")
        self.arrivals: dict[int, int] = {}  # scan stamp -> receive time (monotonic ns)
        self.alive: set[str] = set()
        self.node.subscribe("control/cmd_vel", self._on_cmd)
        for s in self.SERVICES:
            self.node.watch_alive(
                s, lambda up, s=s: (self.alive.add if up else self.alive.discard)(s)
            )
        from followbot.runner import StageProcesses

        log_dir.mkdir(parents=True, exist_ok=True)
        self.stages = StageProcesses(log_dir)
        settings = {"robot": self.robot, "zenoh": {"connect": [self.endpoint]},
                    "log_level": "warning"}  # fmt: skip
        if together:
            # one process: each service's own choices in its section of the settings
            sections = {s: preset_settings(s) for s in self.SERVICES}
            self.stages.start("+".join(self.SERVICES), {**settings, **sections})
        else:
            for s in self.SERVICES:
                self.stages.start(s, {**settings, **preset_settings(s)})

    def _on_cmd(self, cmd) -> None:
        self.arrivals.setdefault(cmd.stamp_ns, time.monotonic_ns())

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        deadline = time.monotonic() + timeout_s
        bank = scan_bank(1, 10)
        while time.monotonic() < deadline:
            self.node.spin_once()  # liveliness events
            if self.alive >= set(self.SERVICES):
                stamp = self.send(bank[0])
                time.sleep(0.05)
                if stamp in self.arrivals:
                    return
            time.sleep(0.05)
        raise RuntimeError(
            f"the pipeline did not come up in {timeout_s:.0f} s (alive: {self.alive})"
        )

    def send(self, scan: LaserScan) -> int:
        stamp = time.monotonic_ns()
        self.odom.put(Odometry(stamp_ns=stamp, frame_id="odom", x_m=0.0, y_m=0.0, yaw_rad=0.0))
        scan.stamp_ns = stamp
        self.scans.put(scan)
        return stamp

    def stream(self, bank: list[LaserScan], rate_hz: float, n: int) -> list[int]:
        """Send ``n`` scans at ``rate_hz`` (busy-waiting the last ms); the stamps sent."""
        period = 1e9 / rate_hz
        t0 = time.monotonic_ns()
        stamps = []
        for j in range(n):
            due = t0 + j * period
            while (left := due - time.monotonic_ns()) > 0:
                if left > 1_500_000:
                    time.sleep((left - 1_000_000) / 1e9)
            stamps.append(self.send(bank[j % len(bank)]))
        return stamps

    def answered(self, stamps: list[int], wait_s: float = 1.5) -> list[float]:
        """Latencies (ms) of the answered stamps, after waiting for stragglers."""
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and not all(s in self.arrivals for s in stamps):
            time.sleep(0.01)
        return [(self.arrivals[s] - s) / 1e6 for s in stamps if s in self.arrivals]

    def close(self) -> None:
        self.stages.stop()
        self.node.close()
        self.session.close()


def _end_to_end(pipe: Pipeline, k: int, rate_hz: float, warm_up: int, count: int) -> dict:
    """Latency p50/p99 of ``count`` scans of ``k`` people at ``rate_hz``, after ``warm_up``
    scans while the tracks form."""
    bank = scan_bank(k, 200)
    pipe.stream(bank, rate_hz, warm_up)
    stamps = pipe.stream(bank, rate_hz, count)
    lat = pipe.answered(stamps)
    p50, p99 = _pct(lat) if lat else (math.nan, math.nan)
    return {"p50_ms": p50, "p99_ms": p99, "sent": len(stamps), "answered": len(lat)}


def run(
    log_dir,
    quick: bool = False,
    hop_floor_p50_ms: float | None = None,
    hop_floor_40hz_p50_ms: float | None = None,
) -> dict:
    people = (1, 5, 10)
    n = 150 if quick else 600
    out: dict = {"in_process": {}, "in_process_40hz": {}, "e2e": {}, "e2e_200hz": {},
                 "e2e_together": {}, "sustained": []}  # fmt: skip
    for k in people:
        print(f"  in-process stages, {k} people ...", file=sys.stderr, flush=True)
        out["in_process"][k] = in_process(k, n=min(n, 300))
        out["in_process_40hz"][k] = in_process(k, n=min(n, 300) // 2, gap_s=0.025)
    pipe = Pipeline(log_dir)
    try:
        print("  starting laser_legs, tracker, controller ...", file=sys.stderr, flush=True)
        pipe.wait_ready()
        # (key, rate, warm-up scans while the tracks form)
        for key, rate, warm_up in (("e2e", 40.0, 40), ("e2e_200hz", 200.0, 100)):
            for k in people:
                print(f"  end to end at {rate:.0f} Hz, {k} people ...", file=sys.stderr,
                      flush=True)  # fmt: skip
                out[key][k] = _end_to_end(pipe, k, rate, warm_up, n // 2 if quick else n)
        bank = scan_bank(5, 200)
        best = 0
        for rate in (100, 200, 300, 500, 750, 1000, 1500, 2000):
            print(f"  sustained rate {rate} scans/s, 5 people ...", file=sys.stderr, flush=True)
            stamps = pipe.stream(bank, rate, int(rate * (1.0 if quick else 2.0)))
            lat = pipe.answered(stamps, wait_s=2.0)
            p50, p99 = _pct(lat) if lat else (math.nan, math.nan)
            # sustained: every scan answered, and no backlog building up (p99 stays small)
            ok = len(lat) == len(stamps) and p99 <= SUSTAINED_P99_MS
            out["sustained"].append({"rate_hz": rate, "sent": len(stamps), "answered": len(lat),
                                     "p50_ms": p50, "p99_ms": p99, "ok": ok})  # fmt: skip
            if not ok:
                break
            best = rate
            time.sleep(0.5)
        out["max_sustained_scans_per_s"] = best
    finally:
        pipe.close()
    # the same stages as one process (followbot run laser_legs+tracker+controller): two hops
    pipe = Pipeline(log_dir, together=True)
    try:
        print("  starting laser_legs+tracker+controller (one process) ...", file=sys.stderr,
              flush=True)  # fmt: skip
        pipe.wait_ready()
        for k in people:
            print(f"  end to end at 40 Hz, one process, {k} people ...", file=sys.stderr,
                  flush=True)  # fmt: skip
            out["e2e_together"][k] = _end_to_end(pipe, k, 40.0, 40, n // 2 if quick else n)
    finally:
        pipe.close()
    for key in ("e2e", "e2e_200hz", "e2e_together"):  # the worst number of people
        for q in ("p50_ms", "p99_ms"):
            out[f"{key}_{q}"] = max(e[q] for e in out[key].values())
    stages10 = out["in_process"][people[-1]]
    out["stages"] = stages10
    out["stages_40hz"] = out["in_process_40hz"][people[-1]]
    for key, floor in (("", hop_floor_p50_ms), ("_40hz", hop_floor_40hz_p50_ms)):
        if floor is not None:
            stages = out[f"stages{key}"]
            budget = sum(s["stage_p50_ms"] for s in stages.values()) + 4 * floor
            out[f"budget{key}_ms"] = budget
            out[f"e2e_over_budget{key}"] = out["e2e_p50_ms"] / budget
    return out


def format_report(p: dict) -> str:
    head = "in one process, per scan             p50 ms   p99 ms   at 40 Hz: p50    p99"
    lines = ["", "pipeline (laser_legs -> tracker -> controller)", "", head]
    cold = p.get("in_process_40hz", {})
    for k, stages in p["in_process"].items():
        for stage, s in stages.items():
            c = cold.get(k, {}).get(stage)
            at40 = f"  {c['stage_p50_ms']:7.3f}  {c['stage_p99_ms']:7.3f}" if c else ""
            lines.append(f"  {k:>2} people  {stage:<12}           {s['stage_p50_ms']:7.3f}  "
                         f"{s['stage_p99_ms']:7.3f}  {at40}")  # fmt: skip
            if "answer_p50_ms" in s:  # the part before tracking/target is published
                c40 = (f"  {c['answer_p50_ms']:7.3f}  {c['answer_p99_ms']:7.3f}"
                       if c and "answer_p50_ms" in c else "")  # fmt: skip
                a50, a99 = s["answer_p50_ms"], s["answer_p99_ms"]
                lines.append(f"  {k:>2} people    (to its answer)        "
                             f"{a50:7.3f}  {a99:7.3f}  {c40}")  # fmt: skip
    for key, title, target in (
        ("e2e", "end to end over Zenoh, scan -> cmd_vel  p50 ms   p99 ms   answered   target",
         "    p50 <= 2, p99 <= 5"),
        ("e2e_together",
         "the same, the three stages in one process (laser_legs+tracker+controller)",
         "    p50 <= 2, p99 <= 5"),
        ("e2e_200hz", "the same at 200 Hz (no process idles)  p50 ms   p99 ms   answered", ""),
    ):  # fmt: skip
        lines += ["", title]
        for k, e in p.get(key, {}).items():
            lines.append(f"  {k:>2} people                         {e['p50_ms']:7.3f}  "
                         f"{e['p99_ms']:7.3f}   {e['answered']}/{e['sent']}{target}")  # fmt: skip
    lines += ["", "sustained rate, 5 people              answered   p99 ms"]
    for s in p["sustained"]:
        mark = (
            ""
            if s["ok"]
            else (
                "   <- scans lost" if s["answered"] < s["sent"] else "   <- backlog (p99 > 50 ms)"
            )
        )
        answered = f"{s['answered']:>6}/{s['sent']:<6}"
        lines.append(
            f"  {s['rate_hz']:>5} scans/s                   {answered} {s['p99_ms']:7.2f}{mark}"
        )
    lines.append(f"  highest sustained (all answered, p99 <= {SUSTAINED_P99_MS:.0f} ms): "
                 f"{p['max_sustained_scans_per_s']} scans/s"
                 "   (target >= 500)")  # fmt: skip
    for key, what in (("", "floor"), ("_40hz", "40 Hz floor, stages at 40 Hz")):
        if f"e2e_over_budget{key}" in p:
            lines.append(
                f"  e2e p50 at 40 Hz / (stages p50 + 4 hops at the {what} = "
                f"{p[f'budget{key}_ms']:.3f} ms): {p[f'e2e_over_budget{key}']:.2f}x"
                "   (target <= 3x)"
            )
    return "\n".join(lines)
