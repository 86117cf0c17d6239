"""The simulation clock: world, people, robot and sensors advanced together, deterministically.

Time is an integer number of nanoseconds (``t_ns``). The robot's dynamics run on a fixed grid
of ``physics_dt_ns`` (5 ms): :meth:`Simulation.advance_to` performs every physics tick up to the
requested time, so the state at time t does not depend on how the caller chunked time. People
are closed-form functions of time (``people.py``). Sensors read the state at the current time:

* :meth:`scan` -> ``LaserScan`` (beams cast against walls, boxes, circles and every leg),
* :meth:`image` -> ``Image`` (BGR render, with the pan angle at capture),
* :meth:`odometry` -> ``Odometry`` (the drifting dead-reckoned pose and measured twist),
* :meth:`truth` -> ``GroundTruth``.

Each sensor draws from its own random stream (spawned from the scenario seed), so e.g. asking
for more images does not change the laser noise. :meth:`tick` drives a whole run: it jumps to the
next sensor instant (laser, camera and odometry each at their own rate; truth with every scan)
and returns the messages due then, in a fixed order. The same scenario, seed and sequence of
commands give a byte-identical message stream.

Giving way: scripts are written in the world frame, so a robot that follows can stop right in
a person's scripted path. Each person whose scripted body centre comes within
``robot.radius_m + robot.people_clearance_m`` (c) of the robot's centre steps aside. Seen along
their direction of walking, a walker's sideways offset from the robot is raised to at least
c (1 + cos(pi a / L)) / 2 while the offset a along it is within L = 2.5 c, on the side they
were already on (left when dead ahead): a smooth swerve that keeps outside the circle of
radius c and rejoins the script behind the robot. A standing person is pushed straight away
from the robot to distance c. People give way to each other the same way first
(``people_spacing_m`` as c, relative motion for the direction of walking, each stepping half
the way aside), then to the robot. Body and legs move together; the velocity stays the scripted one.
It is a pure function of the scripted state and the robot's pose (``give_way``), so the
state at time t still does not depend on how time was chunked.

Ground truth frames: world positions are in the scenario's world frame; ``robot_*`` fields are
in the robot's base frame at that instant, q = R(-yaw) (p - r). ``robot_vx/vy`` is the
person's ground velocity expressed in the base frame, R(-yaw) p' (what an ego-motion
compensated tracker estimates), not the apparent velocity seen from the moving robot.
"""

from __future__ import annotations

import math

import numpy as np

from followbot.schemas import GroundTruth, Image, LaserScan, Message, Odometry, PersonTruth
from followbot.services.common.geometry import wrap_angle

from .camera import CameraModel, CameraMotion
from .dress import dressed, with_appearance
from .laser import LaserModel
from .people import Person, PersonState
from .robot import DiffDriveRobot
from .scenario import AppearanceSpec, Scenario
from .world import StaticWorld

__all__ = ["Simulation"]

_NS = 1_000_000_000


def _period_ns(rate_hz: float) -> int:
    return max(1, round(_NS / rate_hz))


GIVE_WAY_REACH = 2.5
"""A walker starts stepping aside this many clearances before passing the robot."""


def _swerve(
    d: np.ndarray, w: np.ndarray, clearance_m: float, apart: tuple[float, float] = (0.0, 1.0)
) -> np.ndarray | None:
    """Sideways step that moves offset ``d`` (from what is passed) out to the swerve curve for
    relative velocity ``w`` (module doc, "Giving way"); None when no step is needed. Standing
    on the very spot of what is passed, the step is ``clearance_m`` along the unit ``apart``."""
    speed = math.hypot(w[0], w[1])
    if speed > 1e-3:
        u = w / speed
        n = np.array([-u[1], u[0]])  # left of the direction of relative motion
        along, side = float(u @ d), float(n @ d)
        reach = GIVE_WAY_REACH * clearance_m
        if abs(along) >= reach:
            return None
        # a raised-cosine bump c (1 + cos(pi a / reach)) / 2 lies outside the circle of radius
        # c for reach >= 2.22 c, and turns a walker aside smoothly (at most pi c / (2 reach)
        # sideways per metre passed)
        bump = 0.5 * clearance_m * (1.0 + math.cos(math.pi * along / reach))
        need = max(bump, math.sqrt(max(clearance_m**2 - along**2, 0.0)))
        if abs(side) >= need:
            return None
        return (need - abs(side)) * (n if side >= 0.0 else -n)
    dist = math.hypot(d[0], d[1])
    if dist >= clearance_m:
        return None
    if dist > 1e-9:
        return d * ((clearance_m - dist) / dist)
    return clearance_m * np.array(apart)


def _moved(state: PersonState, shift: np.ndarray) -> PersonState:
    return PersonState(
        state.position + shift, state.velocity, state.heading_rad, state.legs + shift
    )


def give_way(
    state: PersonState, robot_pose: tuple[float, float, float], clearance_m: float
) -> PersonState:
    """``state`` moved sideways so the body centre stays at least ``clearance_m`` (c) from the
    robot's centre (module doc, "Giving way"); the same object when it need not move."""
    d = state.position - np.array(robot_pose[:2], dtype=float)
    left = (-math.sin(robot_pose[2]), math.cos(robot_pose[2]))  # on the robot's centre: its left
    shift = _swerve(d, state.velocity, clearance_m, left)
    return state if shift is None else _moved(state, shift)


def give_way_to_each_other(states: list[PersonState], spacing_m: float) -> list[PersonState]:
    """Every pair closer than the swerve curve of ``spacing_m`` steps apart, each half the
    way, sideways to their relative motion (module doc, "Giving way"); one pass over the
    pairs on the scripted positions, so a crowd of three in one spot may stay a little
    closer than ``spacing_m``."""
    n = len(states)
    shifts = [np.zeros(2) for _ in range(n)]
    moved = False
    for i in range(n):
        for j in range(i + 1, n):
            d = states[i].position - states[j].position
            if abs(d[0]) >= GIVE_WAY_REACH * spacing_m or abs(d[1]) >= GIVE_WAY_REACH * spacing_m:
                continue
            # on one spot: apart along y, either way will do
            step = _swerve(d, states[i].velocity - states[j].velocity, spacing_m)
            if step is not None:
                shifts[i] += 0.5 * step
                shifts[j] -= 0.5 * step
                moved = True
    if not moved:
        return states
    return [s if not sh.any() else _moved(s, sh) for s, sh in zip(states, shifts, strict=True)]


class Simulation:
    """One run of a scenario. Not thread-safe; drive it from one loop."""

    def __init__(
        self, scenario: Scenario, *, seed: int | None = None, physics_dt_ns: int = 5_000_000
    ) -> None:
        if physics_dt_ns <= 0:
            raise ValueError(f"physics_dt_ns must be > 0, got {physics_dt_ns}")
        self.scenario = scenario
        self.seed = scenario.seed if seed is None else seed
        robot_ss, laser_ss, camera_ss, bank_ss = np.random.SeedSequence(self.seed).spawn(4)
        self._laser_rng = np.random.default_rng(laser_ss)
        self._camera_rng = np.random.default_rng(camera_ss)
        self.world = StaticWorld.from_spec(scenario.world)
        looks = dressed(scenario.people, self.seed)
        self.people = [
            Person(p if p.dress is None else with_appearance(p, looks[p.id]))
            for p in scenario.people
        ]
        self.target_id = scenario.target_id
        self.robot = DiffDriveRobot(scenario.robot, np.random.default_rng(robot_ss), self.world)
        self.laser = LaserModel(scenario.laser)
        self.camera = CameraModel(scenario.camera, self.world, np.random.default_rng(bank_ss))
        self.physics_dt_ns = physics_dt_ns
        self.t_ns = 0
        self._physics_t_ns = 0
        self._seq = {"scan": 0, "image": 0, "odom": 0, "truth": 0}
        self._periods = {
            "scan": _period_ns(scenario.laser.rate_hz),
            "image": _period_ns(scenario.camera.rate_hz),
            "odom": _period_ns(scenario.robot.odometry.rate_hz),
        }
        self._next = dict.fromkeys(self._periods, 0)
        # static geometry the laser sees at its height
        h = scenario.laser.height_m
        self._laser_segments = self.world.segments_taller_than(h)
        self._laser_circles = self.world.circles_taller_than(h)
        self._n_static = self._laser_segments.shape[0] + self._laser_circles.shape[0]
        self._states_at: int | None = None
        self._states: list[PersonState] = []
        self._cast_at: int | None = None
        self._cast: tuple[np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ clock, commands

    @property
    def t_s(self) -> float:
        return self.t_ns / _NS

    @property
    def duration_ns(self) -> int:
        return round(self.scenario.duration_s * _NS)

    @property
    def finished(self) -> bool:
        return self.t_ns >= self.duration_ns

    @property
    def next_tick_ns(self) -> int:
        """Sim time of the next sensor instant, the one :meth:`tick` will jump to."""
        return min(self._next.values())

    def command_velocity(self, v_mps: float, w_radps: float) -> None:
        """control/cmd_vel: takes effect from the next physics tick."""
        self.robot.command_velocity(v_mps, w_radps)

    def command_pan(self, pan_rad: float) -> None:
        """control/pan: the pan unit moves towards it at its rate limit."""
        self.robot.command_pan(pan_rad)

    def advance_to(self, t_ns: int) -> None:
        """Run every physics tick up to ``t_ns`` and set the clock there (never backwards)."""
        t_ns = int(t_ns)
        if t_ns < self.t_ns:
            raise ValueError(f"cannot go back in time from {self.t_ns} ns to {t_ns} ns")
        dt_s = self.physics_dt_ns / _NS
        while self._physics_t_ns + self.physics_dt_ns <= t_ns:
            self.robot.step(dt_s)
            self._physics_t_ns += self.physics_dt_ns
        self.t_ns = t_ns

    def step(self, dt_ns: int) -> None:
        self.advance_to(self.t_ns + int(dt_ns))

    def tick(self) -> list[Message]:
        """Jump to the next sensor instant; return its messages (scan, truth, image, odom order)."""
        t = min(self._next.values())
        self.advance_to(t)
        out: list[Message] = []
        if self._next["scan"] == t:
            out.append(self.scan())
            out.append(self.truth())
            self._next["scan"] += self._periods["scan"]
        if self._next["image"] == t:
            out.append(self.image())
            self._next["image"] += self._periods["image"]
        if self._next["odom"] == t:
            out.append(self.odometry())
            self._next["odom"] += self._periods["odom"]
        return out

    # ------------------------------------------------------------------ state

    def people_states(self) -> list[PersonState]:
        if self._states_at != self.t_ns:
            t = self.t_s
            states = [p.state(t) for p in self.people]
            if self.scenario.people_spacing_m is not None:
                states = give_way_to_each_other(states, self.scenario.people_spacing_m)
            c = self.scenario.robot.people_clearance_m
            if c is not None:
                r = self.scenario.robot.radius_m + c
                states = [give_way(s, self.robot.pose, r) for s in states]
            self._states = states
            self._states_at = self.t_ns
        return self._states

    def lighting_gain(self) -> float:
        keys = self.scenario.lighting
        if not keys:
            return 1.0
        t = self.t_s
        times = [k.t_s for k in keys]
        return float(np.interp(t, times, [k.gain for k in keys]))

    def _true_cast(self) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free ranges and hit indices at the current time (cached per instant)."""
        if self._cast_at != self.t_ns or self._cast is None:
            states = self.people_states()
            legs = [
                np.column_stack([s.legs, np.full(2, p.leg_radius_m)])
                for p, s in zip(self.people, states, strict=True)
            ]
            circles = np.vstack([self._laser_circles, *legs]) if legs else self._laser_circles
            self._cast = self.laser.cast(self.robot.pose, self._laser_segments, circles)
            self._cast_at = self.t_ns
        return self._cast

    # ------------------------------------------------------------------ sensors

    def _next_seq(self, name: str) -> int:
        seq = self._seq[name]
        self._seq[name] = seq + 1
        return seq

    def scan(self) -> LaserScan:
        true_ranges, hit = self._true_cast()
        ranges = self.laser.corrupt(
            true_ranges,
            self._laser_rng,
            hit=hit,
            first_leg=self._laser_segments.shape[0] + self._laser_circles.shape[0],
            n_legs=2 * len(self.people),
        )
        return self.laser.to_message(ranges, stamp_ns=self.t_ns, seq=self._next_seq("scan"))

    def image_pixels(self) -> np.ndarray:
        people = [
            (s, p.spec.appearance, p.leg_radius_m)
            for p, s in zip(self.people, self.people_states(), strict=True)
        ]
        r = self.robot
        v = r.world_velocity()
        motion = CameraMotion(float(v[0]), float(v[1]), r.w_radps + r.pan_rate_radps)
        return self.camera.render(
            r.pose, r.pan_rad, people, self.lighting_gain(), self._camera_rng, motion
        )

    def appearance(self, person_id: int) -> AppearanceSpec:
        """What person ``person_id`` wears (their ``appearance``, or what ``dress`` drew)."""
        return next(p.spec.appearance for p in self.people if p.id == person_id)

    def image(self) -> Image:
        pixels = self.image_pixels()
        return Image.from_array(
            pixels,
            stamp_ns=self.t_ns,
            pan_rad=float(wrap_angle(self.robot.pan_rad)),
            seq=self._next_seq("image"),
        )

    def odometry(self) -> Odometry:
        r = self.robot
        return Odometry(
            stamp_ns=self.t_ns,
            frame_id="odom",
            seq=self._next_seq("odom"),
            x_m=float(r.odom_x_m),
            y_m=float(r.odom_y_m),
            yaw_rad=float(r.odom_yaw_rad),
            v_mps=float(r.odom_v_mps),
            w_radps=float(r.odom_w_radps),
        )

    def truth(self) -> GroundTruth:
        r = self.robot
        x, y, yaw = r.pose
        c, s = math.cos(yaw), math.sin(yaw)
        rot = np.array([[c, s], [-s, c]])  # R(-yaw): world -> base frame
        _, hit = self._true_cast()
        leg_hits = hit[hit >= self._n_static] - self._n_static
        beams_on = np.bincount(leg_hits // 2, minlength=len(self.people))
        pan = r.pan_rad
        people: list[PersonTruth] = []
        for k, (person, st) in enumerate(zip(self.people, self.people_states(), strict=True)):
            q = rot @ (st.position - np.array([x, y]))
            vq = rot @ st.velocity
            legs = (st.legs - np.array([x, y])) @ rot.T
            torso_z = 0.67 * person.spec.appearance.height_m
            people.append(
                PersonTruth(
                    id=person.id,
                    x_m=float(st.position[0]),
                    y_m=float(st.position[1]),
                    vx_mps=float(st.velocity[0]),
                    vy_mps=float(st.velocity[1]),
                    robot_x_m=float(q[0]),
                    robot_y_m=float(q[1]),
                    robot_vx_mps=float(vq[0]),
                    robot_vy_mps=float(vq[1]),
                    legs_robot_m=[float(v) for v in legs.reshape(-1)],
                    is_target=person.is_target,
                    visible_laser=bool(beams_on[k] >= self.scenario.laser.min_visible_beams),
                    visible_camera=self.camera.sees(r.pose, pan, st.position, torso_z),
                )
            )
        return GroundTruth(
            stamp_ns=self.t_ns,
            frame_id="world",
            seq=self._next_seq("truth"),
            robot_x_m=float(x),
            robot_y_m=float(y),
            robot_yaw_rad=float(yaw),
            robot_v_mps=float(r.v_mps),
            robot_w_radps=float(r.w_radps),
            camera_pan_rad=float(wrap_angle(pan)),
            target_id=self.target_id,
            people=people,
            robot_bumps=r.bumps,
        )
