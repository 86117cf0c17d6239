"""sim: the simulator as a service -- sensors out, commands in, on a real-time or lock-step clock.

    followbot run sim --set scenario=thesis_5_2_1_arc                 # real time (the demo)
    followbot run sim --set scenario=my.yaml --set mode=lockstep      # evaluation, tests
    followbot run sim --set scenario=crowd_ten --set rate=4           # 4x faster than real time

Publishes ``sensors/scan``, ``sensors/image`` (raw BGR, or JPEG with ``jpeg: true``),
``sensors/odom`` and ``sim/truth``, all stamped with the sim clock (ns from the scenario's
start); obeys ``control/cmd_vel`` and ``control/pan``. A velocity command older than the
scenario's ``robot.cmd_timeout_s`` (sim time) is dropped by the simulated base's own watchdog,
which stops the robot. At the scenario's end the service logs a summary line and exits 0.

Messages of one sensor instant go out in the order odometry, image, truth, scan: the scan
last. Odometry goes out at its own rate and, in lock-step, also at every scan instant that
rate misses (the stages wait for odometry stamped at or after a scan before they use it:
docs/runtime.md, rule 5).

Clocks (``mode``):

``realtime``
    The sim clock follows the wall clock times ``rate``. If the machine cannot keep up
    (more than 1 s of sim time behind), the clock is re-anchored and the slip is counted.
``lockstep``
    The protocol of docs/runtime.md. After each scan (stamp k) the service waits until every
    stage in ``stages`` that is alive (liveliness token ``alive/<stage>``) has published its
    output(s) naming stamp k -- by default laser_legs: perception/candidates, vision_verify:
    perception/verification, tracker: tracking/target, controller: control/cmd_vel and
    control/pan -- or ``lockstep_timeout_s`` passes (counted, logged, in Health notes). The
    stages alive when scan k is published are the ones awaited; a stage that disappears is no
    longer awaited. With no stage alive it runs as fast as it can. The controller's commands
    for stamp k are therefore applied at sim time k, and the run is deterministic; a command
    naming any other stamp (late after a timeout), or a second one for stamp k (a timer's), is
    ignored and counted.

The node loop is single-threaded, so nothing here sleeps: the barrier is a small state machine
advanced by the handlers of the stages' answers and by a 5 ms pump timer (start conditions,
timeouts, free running in batches of at most 20 ms so answers and liveliness stay served).

Start. The first tick waits until the services in ``wait_for_stages`` are alive and, with
``wait_for_subscribers``, until sensors/scan has a subscriber (both at most
``start_timeout_s``), then ``settle_s`` more so late joiners' subscriptions propagate.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from pathlib import Path
from typing import Annotated, Literal

import msgspec

from followbot.schemas import (
    GroundTruth,
    Image,
    LaserScan,
    Message,
    PanCommand,
    VelocityCommand,
    topic_type,
)
from followbot.services.runtime.node import Node
from followbot.services.runtime.service import service_main
from followbot.services.runtime.settings import NodeSettings
from followbot.services.runtime.stats import RateLimitedLog

from .scenario import Scenario, ScenarioError, load_builtin, load_scenario
from .simulation import Simulation

__all__ = ["DEFAULT_STAGES", "SimRunner", "SimSettings", "check", "load_scenario_setting", "main"]

#: Lock-step: the outputs each pipeline stage publishes once per scan stamp (docs/runtime.md).
DEFAULT_STAGES: dict[str, list[str]] = {
    "laser_legs": ["perception/candidates"],
    "vision_verify": ["perception/verification"],
    "tracker": ["tracking/target"],
    "controller": ["control/cmd_vel", "control/pan"],
}

#: Reasons of the controller's own (wall-clock) commands: not answers to a scan.
WATCHDOG_REASONS = frozenset({"stale", "tracker_gone", "watchdog"})

#: Period of the pump timer (start conditions, lock-step timeouts, real-time ticks), s.
_PUMP_S = 0.005
#: Longest stretch of ticks published in one go before the loop serves its inputs again, s.
_BATCH_S = 0.02
#: Real time: re-anchor the clock when this far behind (sim seconds).
_MAX_LAG_S = 1.0
_NS = 1_000_000_000


class SimSettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    scenario: str = "thesis_5_2_1_arc"
    """A built-in scenario name (services/sim/scenarios/*.yaml) or the path of a YAML file."""
    seed: int | None = None
    """Random seed (default: the scenario's own)."""
    duration_s: Annotated[float, msgspec.Meta(gt=0, le=1e6)] | None = None
    """Stop after this much sim time (default: the scenario's duration_s)."""
    mode: Literal["realtime", "lockstep"] = "realtime"
    """The clock: ``realtime`` follows the wall clock (times ``rate``); ``lockstep`` waits
    for the stages' answers to each scan (see "Clocks" above, docs/runtime.md)."""
    rate: Annotated[float, msgspec.Meta(gt=0, le=1000)] = 1.0
    """Real time: sim seconds per wall second."""
    publish_images: bool = True
    """Publish sensors/image; false: laser, odometry and truth only (no camera, faster)."""
    jpeg: bool = False
    """Send images as JPEG (worth it only across a slow link: ~0.5 ms each way)."""
    jpeg_quality: Annotated[int, msgspec.Meta(ge=1, le=100)] = 90
    """With ``jpeg``: the JPEG quality, 1 (smallest) to 100 (best)."""
    stages: dict[str, list[str]] = msgspec.field(
        default_factory=lambda: {k: list(v) for k, v in DEFAULT_STAGES.items()}
    )
    """Lock-step: stage (service name) -> the topics it answers each scan stamp on."""
    lockstep_timeout_s: Annotated[float, msgspec.Meta(gt=0, le=3600)] = 1.0
    """Lock-step: stop waiting for the stages' answers to a scan after this long (wall)."""
    wait_for_stages: list[str] = []
    """Hold the first tick until these services are alive (at most start_timeout_s)."""
    wait_for_subscribers: bool = False
    """Hold the first tick until sensors/scan has a subscriber (at most start_timeout_s)."""
    start_timeout_s: Annotated[float, msgspec.Meta(ge=0, le=3600)] = 10.0
    """Longest wait (wall s) for ``wait_for_stages`` / ``wait_for_subscribers``; then the
    first tick goes out anyway, with a warning."""
    settle_s: Annotated[float, msgspec.Meta(ge=0, le=60)] = 0.2
    """Wait this long after the start conditions hold, before the first tick."""


def load_scenario_setting(value: str) -> Scenario:
    """``scenario`` setting: a file path (has a '/' or ends in .yaml/.yml) or a built-in name."""
    if "/" in value or value.endswith((".yaml", ".yml")) or Path(value).is_file():
        return load_scenario(value)
    return load_builtin(value)


class SimRunner:
    """Drives one :class:`Simulation` on a :class:`Node`: publishes, obeys, holds the barrier."""

    def __init__(self, node: Node, sim: Simulation, settings: SimSettings) -> None:
        self.node, self.sim, self.settings = node, sim, settings
        self.log = node.log
        self._ratelog = RateLimitedLog(node.log)
        self.lockstep = settings.mode == "lockstep"
        # Lock-step must not lose a scan (a lost scan is a timeout): block rather than drop.
        rel = self.lockstep
        self._scan_pub = node.publisher("sensors/scan", reliable=rel)
        self._image_pub = node.publisher("sensors/image", reliable=rel)
        self._odom_pub = node.publisher("sensors/odom", reliable=rel)
        self._truth_pub = node.publisher("sim/truth", reliable=rel)
        self.end_ns = sim.duration_ns
        if settings.duration_s is not None:
            self.end_ns = round(settings.duration_s * _NS)

        self.state: Literal["starting", "settling", "running", "done"] = "starting"
        self._t_created = time.monotonic()
        self._t_settle = 0.0
        self.wall_start = 0.0
        self.wall_end = 0.0
        self.alive: set[str] = set()
        self.counts: Counter[str] = Counter()
        # lock-step barrier: the scan stamp awaited and, per stage, the topics still missing
        self.awaiting: int | None = None
        self.missing: dict[str, set[str]] = {}
        self.deadline = 0.0
        self.timeouts: Counter[str] = Counter()
        self.stray = 0
        """Answers naming a stamp other than the one awaited (late after a timeout, repeats)."""
        self.ignored_commands = 0
        """Commands not obeyed: before the start, or (lock-step) not naming the latest scan."""
        self.last_scan_ns = -1
        self._obeyed: dict[str, int] = {}  # topic -> stamp of the last command obeyed
        self.reanchored = 0
        self._notes_at = 0.0

        topic_stage: dict[str, str] = {}
        for stage, topics in settings.stages.items():
            for topic in topics:
                topic_type(topic)  # ValueError naming the valid topics
                if topic in topic_stage:
                    raise ValueError(
                        f"stages: topic {topic!r} given for both {topic_stage[topic]!r} "
                        f"and {stage!r}"
                    )
                topic_stage[topic] = stage
        self._topic_stage = topic_stage
        # Commands are always obeyed; the other stage outputs are only read in lock-step.
        inputs = {"control/cmd_vel", "control/pan"}
        if self.lockstep:
            inputs |= set(topic_stage)
        for topic in sorted(inputs):
            node.subscribe(topic, lambda m, t=topic: self._on_input(t, m), dispatch="loop")
        for stage in sorted(set(settings.stages) | set(settings.wait_for_stages)):
            node.watch_alive(stage, lambda alive, s=stage: self._on_alive(s, alive))
        node.every(_PUMP_S, self._pump, name="pump")
        node.on_stop(self._on_stop)
        self._update_notes(force=True)

    # ------------------------------------------------------------------ inputs

    def _on_input(self, topic: str, msg: Message) -> None:
        if isinstance(msg, VelocityCommand | PanCommand):
            if self.lockstep and msg.reason in WATCHDOG_REASONS:
                # The controller's wall-clock watchdog reuses the last target's stamp; it does
                # not answer a scan, and obeying it would depend on the machine's speed.
                self.ignored_commands += 1
                return
            if self.state != "running":
                self.ignored_commands += 1  # nothing can derive from a scan not yet sent
            elif self.lockstep and (
                msg.stamp_ns != self.last_scan_ns or self._obeyed.get(topic) == msg.stamp_ns
            ):
                # Lock-step obeys one command per topic per scan, derived from the latest
                # scan: one naming an older stamp (late after a timeout) or a second one for
                # the same stamp (a timer's) would land at a machine-dependent sim time.
                self.ignored_commands += 1
                self._ratelog.log(
                    logging.WARNING,
                    "stale-command",
                    "lock-step: ignored %s naming stamp %d (latest scan %d, %s); %d ignored so far",
                    topic,
                    msg.stamp_ns,
                    self.last_scan_ns,
                    "already obeyed" if msg.stamp_ns == self.last_scan_ns else "stale",
                    self.ignored_commands,
                )
            elif isinstance(msg, VelocityCommand):
                self.sim.command_velocity(msg.linear_mps, msg.angular_radps)
                self.counts["cmd_vel"] += 1
                self._obeyed[topic] = msg.stamp_ns
            else:
                self.sim.command_pan(msg.pan_rad)
                self.counts["pan"] += 1
                self._obeyed[topic] = msg.stamp_ns
        if self.lockstep and topic in self._topic_stage:
            self._on_answer(self._topic_stage[topic], topic, msg.stamp_ns)

    def _on_answer(self, stage: str, topic: str, stamp_ns: int) -> None:
        if self.awaiting is None or stamp_ns != self.awaiting:
            self.stray += 1
            return
        want = self.missing.get(stage)
        if want is None or topic not in want:
            return  # an answer from a stage not awaited for this stamp (joined later)
        want.discard(topic)
        if not want:
            del self.missing[stage]
            if not self.missing:
                self._release()

    def _on_alive(self, stage: str, alive: bool) -> None:
        if alive:
            if stage not in self.alive:
                self.log.info("%s is alive", stage)
            self.alive.add(stage)
            return
        if stage in self.alive:
            self.log.info("%s went away", stage)
        self.alive.discard(stage)
        if self.missing.pop(stage, None) is not None and not self.missing:
            self._release()

    # ------------------------------------------------------------------ barrier

    def _release(self) -> None:
        self.awaiting = None
        if self.state == "running":
            self._run_free()

    def _arm(self, stamp_ns: int) -> None:
        """Before publishing scan ``stamp_ns``: await the stages alive now (lock-step only)."""
        if not self.lockstep:
            return
        stages = self.alive & set(self.settings.stages)
        self.missing = {s: set(self.settings.stages[s]) for s in stages if self.settings.stages[s]}
        if self.missing:
            self.awaiting = stamp_ns
            self.deadline = time.monotonic() + self.settings.lockstep_timeout_s
        else:
            self.awaiting = None

    def _run_free(self) -> None:
        """Publish ticks until a barrier is armed, the run ends or the batch time is used up."""
        t_stop = time.monotonic() + _BATCH_S
        while self.state == "running" and self.awaiting is None:
            self._tick()
            if time.monotonic() >= t_stop:
                break

    # ------------------------------------------------------------------ ticks

    def _tick(self) -> None:
        """Publish the next sensor instant (scan last), or finish at the end of the run."""
        sim = self.sim
        if sim.next_tick_ns >= self.end_ns:
            self._finish()
            return
        scan: LaserScan | None = None
        odom = False
        for msg in sim.tick():
            if isinstance(msg, LaserScan):
                scan = msg
            elif isinstance(msg, Image):
                self._put_image(msg)
            elif isinstance(msg, GroundTruth):
                self._truth_pub.put(msg)
                self.counts["truth"] += 1
            else:
                self._odom_pub.put(msg)
                self.counts["odom"] += 1
                odom = True
        if scan is not None and self.lockstep and not odom:
            # rule 5: the stages hold scan k until odometry stamped k or later has come; when
            # the odometry rate does not divide the scan instants, send one at the scan's
            self._odom_pub.put(sim.odometry())
            self.counts["odom"] += 1
        if scan is not None:
            self.last_scan_ns = scan.stamp_ns
            self._arm(scan.stamp_ns)
            self._scan_pub.put(scan)
            self.counts["scan"] += 1

    def _put_image(self, msg: Image) -> None:
        if not self.settings.publish_images:
            return
        if self.settings.jpeg:
            msg = Image.jpeg_from_array(
                msg.pixels(),
                quality=self.settings.jpeg_quality,
                stamp_ns=msg.stamp_ns,
                pan_rad=msg.pan_rad,
                seq=msg.seq,
                frame_id=msg.frame_id,
            )
        self._image_pub.put(msg)
        self.counts["image"] += 1

    # ------------------------------------------------------------------ pump

    def _pump(self) -> None:
        now = time.monotonic()
        if self.state == "starting":
            if not self._ready(now):
                return
            self.state, self._t_settle = "settling", now + self.settings.settle_s
        if self.state == "settling":
            if now < self._t_settle:
                return
            self._start(now)
        if self.state != "running":
            return
        if self.lockstep:
            if self.awaiting is not None and now >= self.deadline:
                self._timeout()
            if self.awaiting is None:
                self._run_free()
        else:
            self._realtime(now)
        self._update_notes()

    def _ready(self, now: float) -> bool:
        s = self.settings
        waiting = [n for n in s.wait_for_stages if n not in self.alive]
        if s.wait_for_subscribers and not self._scan_pub.matching():
            waiting.append("a sensors/scan subscriber")
        if not waiting:
            return True
        if now - self._t_created >= s.start_timeout_s:
            self.log.warning(
                "still waiting for %s after %.1f s; starting anyway",
                ", ".join(waiting),
                s.start_timeout_s,
            )
            return True
        return False

    def _start(self, now: float) -> None:
        self.state = "running"
        self.wall_start = now
        sc = self.sim.scenario
        self.log.info(
            "scenario %s: seed %d, %.1f s of sim time, mode %s%s; stages alive: %s",
            sc.name,
            self.sim.seed,
            self.end_ns / _NS,
            self.settings.mode,
            f" x{self.settings.rate:g}" if not self.lockstep else "",
            ", ".join(sorted(self.alive)) or "none",
        )

    def _timeout(self) -> None:
        late = sorted(self.missing)
        for stage in late:
            self.timeouts[stage] += 1
        total = sum(self.timeouts.values())
        self._ratelog.log(
            logging.WARNING,
            "lockstep-timeout",
            "lock-step: no answer from %s for scan %d after %.2f s (%d timeouts so far)",
            ", ".join(f"{s} ({', '.join(sorted(self.missing[s]))})" for s in late),
            self.awaiting,
            self.settings.lockstep_timeout_s,
            total,
        )
        self.missing = {}
        self.awaiting = None

    def _realtime(self, now: float) -> None:
        sim = self.sim
        target_ns = (now - self.wall_start) * self.settings.rate * _NS
        t_stop = now + _BATCH_S
        while self.state == "running" and sim.next_tick_ns <= target_ns:
            self._tick()
            if time.monotonic() >= t_stop:
                break
        if self.state == "running" and sim.next_tick_ns >= self.end_ns and target_ns >= self.end_ns:
            self._finish()
            return
        lag_s = (target_ns - sim.next_tick_ns) / _NS
        if lag_s > _MAX_LAG_S:
            # cannot keep up: let the sim clock slip rather than burst to catch up
            self.wall_start += lag_s / self.settings.rate
            self.reanchored += 1
            self._ratelog.log(
                logging.WARNING,
                "behind",
                "real time: %.2f s behind; sim clock slipped (%d times so far)",
                lag_s,
                self.reanchored,
            )

    # ------------------------------------------------------------------ end

    def _finish(self) -> None:
        if self.state == "done":
            return
        self.state = "done"
        self.wall_end = time.monotonic()
        self.log.info("%s", self.summary())
        self._update_notes(force=True)
        self.node.stop()

    def _on_stop(self) -> None:
        if self.state != "done":
            self.wall_end = time.monotonic()
            self.log.info("stopped early: %s", self.summary())

    def summary(self) -> str:
        c = self.counts
        sim_s = self.sim.t_ns / _NS
        wall_s = max((self.wall_end or time.monotonic()) - (self.wall_start or time.monotonic()), 0)
        speed = sim_s / wall_s if wall_s > 0 else math.inf
        text = (
            f"scenario {self.sim.scenario.name} finished at sim t={sim_s:.2f} s: "
            f"{c['scan']} scans, {c['image']} images, {c['odom']} odom, {c['truth']} truth; "
            f"{c['cmd_vel']} cmd_vel, {c['pan']} pan obeyed; "
            f"{wall_s:.2f} s wall ({speed:.1f}x real time); mode {self.settings.mode}"
        )
        if self.lockstep:
            per = ", ".join(f"{s} {n}" for s, n in sorted(self.timeouts.items()))
            text += f"; {sum(self.timeouts.values())} timeouts" + (f" ({per})" if per else "")
            text += f", {self.stray} stray answers, {self.ignored_commands} commands ignored"
        else:
            text += f"; clock slipped {self.reanchored} times"
        if self.state != "done":
            text = text.replace(" finished at ", " stopped at ")
        return text

    def _update_notes(self, *, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now < self._notes_at:
            return
        self._notes_at = now + 0.25
        notes = [
            f"scenario={self.sim.scenario.name}",
            f"mode={self.settings.mode}",
            f"state={self.state}",
            f"sim_t_s={self.sim.t_ns / _NS:.3f}",
        ]
        if self.lockstep:
            notes.append(f"lockstep_timeouts={sum(self.timeouts.values())}")
            notes += [f"timeouts:{s}={n}" for s, n in sorted(self.timeouts.items())]
            notes.append(f"stray_answers={self.stray}")
            notes.append(f"ignored_commands={self.ignored_commands}")
        else:
            notes.append(f"clock_slips={self.reanchored}")
        self.node.notes = notes[:16]


def check(settings: SimSettings) -> Scenario:
    """Load and validate the scenario (a ValueError with the scenario's own error), before any
    network is opened: at start, and for ``--print-settings`` / ``followbot up --check``.

    The scenario's laser must sit where the robot's ``laser_mount`` setting says, the one value
    every stage reads: a simulated laser elsewhere would feed the stages scans they turn into
    the base frame wrongly."""
    try:
        scenario = load_scenario_setting(settings.scenario)
    except ScenarioError as exc:
        raise ValueError(f"scenario: {exc}") from None
    mount = scenario.laser.mount()
    if mount != settings.laser_mount:
        raise ValueError(
            f"scenario {scenario.name}: its laser sits at {mount.describe()}, but laser_mount "
            f"says {settings.laser_mount.describe()}; set laser_mount: {{x_m: {mount.x_m}, "
            f"y_m: {mount.y_m}, yaw_deg: {mount.yaw_deg}}} for every service (the top of a "
            "compose file; followbot eval does it itself)"
        )
    return scenario


def setup(node: Node, settings: SimSettings) -> SimRunner:
    sim = Simulation(check(settings), seed=settings.seed)
    return SimRunner(node, sim, settings)


def main(argv: list[str] | None = None) -> int:
    return service_main("sim", SimSettings, setup, argv, __doc__, check)
