"""The simulated robot: a differential-drive base, a camera pan unit and wheel odometry.

Base. The commanded (v*, w*) is clamped to the speed limits (thesis 4.6: 0.75 m/s, 100 deg/s);
the actual (v, w) move towards it at most a_max dt and alpha_max dt per step; the pose then
follows the exact arc for constant (v, w) over the step:

    w != 0:  x += v/w (sin(th + w dt) - sin th),  y -= v/w (cos(th + w dt) - cos th)
    w == 0:  x += v dt cos th,                   y += v dt sin th
    th += w dt

A command older than ``cmd_timeout_s`` is replaced by (0, 0) (the base's watchdog).

Bumper (``bumper``, on by default). The base is a disc of ``radius_m``: a step that would bring
its centre nearer than that to a wall, a box or a circle of the static world (and nearer than
it already was) is not taken -- the base stops there (v = 0; turning on the spot stays free,
and so does any motion away) and ``bumps`` counts the contact. A real base's bumper or stalled
motors do the same; before this the simulated robot drove through furniture (a following robot
cut the corner of occlusion_pillar's pillar to 6 mm of its centre, and parked in the cluttered
office's shelf). People are not obstacles here: they give way (simulation.py).

Pan unit. The pan angle moves towards the commanded angle (clamped to +-100 deg) at no more
than 90 deg/s (thesis 5.2.5).

Odometry. The true motion of a step is turned into wheel travel (b: wheel base)

    d_r = ds + b dth / 2,   d_l = ds - b dth / 2,

each wheel reading is corrupted as d' = d (1 + k + |slip|) + n sqrt(|d|) with a fixed scale
error k per wheel (calibration), a slip fraction drawn every step (slip always over-reports
distance), and white noise n; then ds' = (d_r' + d_l') / 2, dth' = (d_r' - d_l') / b is
integrated as an arc (chord ds' sin(dth'/2) / (dth'/2) along the mid-step heading), so with
the noise off odometry reproduces the true motion exactly. The odometry frame starts at the
robot's start pose, so odometry reads (0, 0, 0) at t = 0. Errors accumulate like on a real
base: the heading error grows with distance and bends the whole path.
"""

from __future__ import annotations

import math

import numpy as np

from followbot.services.common.geometry import wrap_angle

from .scenario import RobotSpec
from .world import StaticWorld

__all__ = ["DiffDriveRobot"]

_CONTACT_HYSTERESIS_M = 0.01
"""A contact ends once the body is this far clear of the world again (creeping up to a wall
step by step is one contact)."""


def _approach(value: float, goal: float, max_change: float) -> float:
    return value + min(max(goal - value, -max_change), max_change)


class DiffDriveRobot:
    """State and dynamics of the base, the pan unit and the odometry integrator."""

    def __init__(
        self, spec: RobotSpec, rng: np.random.Generator, world: StaticWorld | None = None
    ) -> None:
        self.spec = spec
        self._rng = rng
        self._world = world if spec.bumper else None
        self.bumps = 0
        """Contacts with the world so far (a run of blocked steps counts once)."""
        self._in_contact = False
        self.x_m = float(spec.start[0])
        self.y_m = float(spec.start[1])
        self.yaw_rad = math.radians(spec.yaw_deg)
        self.v_mps = 0.0
        self.w_radps = 0.0
        self.pan_rad = 0.0
        self.pan_rate_radps = 0.0
        """The pan unit's turn rate over the last step."""
        self._v_max = spec.max_speed_mps
        self._w_max = math.radians(spec.max_turn_deg_s)
        self._w_acc = math.radians(spec.max_turn_accel_deg_s2)
        self._pan_max = math.radians(spec.pan_limit_deg)
        self._pan_rate = math.radians(spec.pan_rate_deg_s)
        self.cmd_v = 0.0
        self.cmd_w = 0.0
        self.cmd_pan = 0.0
        self._cmd_age_s = math.inf
        # odometry: pose in the odom frame and the measured twist of the last step
        self.odom_x_m = 0.0
        self.odom_y_m = 0.0
        self.odom_yaw_rad = 0.0
        self.odom_v_mps = 0.0
        self.odom_w_radps = 0.0
        o = spec.odometry
        bias = rng.normal(0.0, 1.0, 2) * o.wheel_bias if o.noise else np.zeros(2)
        self._bias_r, self._bias_l = float(bias[0]), float(bias[1])

    # ------------------------------------------------------------------ commands

    def command_velocity(self, v_mps: float, w_radps: float) -> None:
        """Set (v*, w*); clamped to the limits, and forgotten after ``cmd_timeout_s``."""
        if not (math.isfinite(v_mps) and math.isfinite(w_radps)):
            raise ValueError(f"non-finite velocity command ({v_mps}, {w_radps})")
        self.cmd_v = min(max(v_mps, -self._v_max), self._v_max)
        self.cmd_w = min(max(w_radps, -self._w_max), self._w_max)
        self._cmd_age_s = 0.0

    def command_pan(self, pan_rad: float) -> None:
        if not math.isfinite(pan_rad):
            raise ValueError(f"non-finite pan command {pan_rad}")
        self.cmd_pan = min(max(pan_rad, -self._pan_max), self._pan_max)

    # ------------------------------------------------------------------ dynamics

    def step(self, dt_s: float) -> None:
        """Advance the base, the pan unit and the odometry by ``dt_s`` (keep it <= 20 ms)."""
        if dt_s <= 0.0:
            return
        self._cmd_age_s += dt_s
        live = self._cmd_age_s <= self.spec.cmd_timeout_s
        goal_v = self.cmd_v if live else 0.0
        goal_w = self.cmd_w if live else 0.0
        self.v_mps = _approach(self.v_mps, goal_v, self.spec.max_accel_mps2 * dt_s)
        self.w_radps = _approach(self.w_radps, goal_w, self._w_acc * dt_s)
        pan = _approach(self.pan_rad, self.cmd_pan, self._pan_rate * dt_s)
        self.pan_rate_radps = (pan - self.pan_rad) / dt_s
        self.pan_rad = pan

        v, w, th = self.v_mps, self.w_radps, self.yaw_rad
        if abs(w) > 1e-9:
            x = self.x_m + v / w * (math.sin(th + w * dt_s) - math.sin(th))
            y = self.y_m - v / w * (math.cos(th + w * dt_s) - math.cos(th))
        else:
            x = self.x_m + v * dt_s * math.cos(th)
            y = self.y_m + v * dt_s * math.sin(th)
        if v != 0.0 and self._blocked(x, y):
            x, y, v = self.x_m, self.y_m, 0.0
            self.v_mps = 0.0
        self.x_m, self.y_m = x, y
        self.yaw_rad = wrap_angle(th + w * dt_s)
        self._integrate_odometry(v * dt_s, w * dt_s, dt_s)

    def _blocked(self, x_m: float, y_m: float) -> bool:
        """Bumper: the step to (x, y) runs the body into the world (module doc)."""
        if self._world is None:
            return False
        r = self.spec.radius_m
        after = self._world.clearance_m(x_m, y_m)
        if after >= r or after >= self._world.clearance_m(self.x_m, self.y_m):
            if after > r + _CONTACT_HYSTERESIS_M:
                self._in_contact = False  # clear of it: a new contact counts anew
            return False
        if not self._in_contact:
            self.bumps += 1
            self._in_contact = True
        return True

    def _integrate_odometry(self, ds: float, dth: float, dt_s: float) -> None:
        o = self.spec.odometry
        b = self.spec.wheel_base_m
        if o.noise:
            d_r = ds + b * dth / 2
            d_l = ds - b * dth / 2
            z = self._rng.normal(0.0, 1.0, 4).tolist()  # fixed count of draws per step
            slip_r, slip_l = abs(z[0]) * o.slip_std, abs(z[1]) * o.slip_std
            d_r = d_r * (1.0 + self._bias_r + slip_r) + z[
                2
            ] * o.wheel_noise_m_per_sqrt_m * math.sqrt(abs(d_r))
            d_l = d_l * (1.0 + self._bias_l + slip_l) + z[
                3
            ] * o.wheel_noise_m_per_sqrt_m * math.sqrt(abs(d_l))
            ds, dth = (d_r + d_l) / 2, (d_r - d_l) / b
        # exact arc: chord = ds sin(dth/2) / (dth/2) along the mid-step heading
        chord = ds * (math.sin(dth / 2) / (dth / 2) if abs(dth) > 1e-9 else 1.0)
        mid = self.odom_yaw_rad + dth / 2
        self.odom_x_m += chord * math.cos(mid)
        self.odom_y_m += chord * math.sin(mid)
        self.odom_yaw_rad = wrap_angle(self.odom_yaw_rad + dth)
        self.odom_v_mps = ds / dt_s
        self.odom_w_radps = dth / dt_s

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x_m, self.y_m, self.yaw_rad)

    def world_velocity(self) -> np.ndarray:
        """(2,) the base's velocity in the world frame."""
        return self.v_mps * np.array([math.cos(self.yaw_rad), math.sin(self.yaw_rad)])
