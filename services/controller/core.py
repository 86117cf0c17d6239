"""The controller: the thesis's following rule, with acceleration and rate limits always enforced.

Pure logic, no Zenoh (the node is ``node.py``). Thesis 3.7, 4.6; DESIGN.md "Control".

Rule (from the target's estimate in the base frame of its scan):

    r = sqrt(x^2 + y^2),  theta = atan2(y, x),  v_h = sqrt(vx^2 + vy^2)        (eq. 3-39)
    turn       only when |theta| > 6 deg: w* = turn_gain * theta, else 0
    translate  r < 1.2 m: 0;  1.2 <= r <= 1.5 m: v_h (the person's speed);  r > 1.5 m: v_max
    pan        pan* = theta (eq. 4-10: the camera looks at the target while the base turns)

(x, y) is the tracker's filter estimate: the reported position less its lone-leg shift
(TrackState.shift_*), the point laser_legs gates criterion 3 on.

``rule: zhuang`` replaces the rule by seed 001's (zhuang.py), the camera's pan held at 0.

By status: ``tracking`` applies the rule; ``coasting`` keeps the previous goal (thesis 3.6.2.8:
fewer than 9 misses keep the previous command); ``lost`` and ``initialising`` stop; the
watchdog (no fresh target, tracker gone) stops. While lost the camera pans to the person or
point the tracker names for a look (TrackState.look_*; ``pan.look_when_lost``, beyond the
thesis), else it holds its angle. (The tracker names a look only while the target is lost.)

Limits (``limits.*``), applied to every command whatever produced it (dt: time since the
previous command):

    |v| <= v_max (0.75 m/s),  |v - v_prev| <= a dt (a = accel, or decel when |v| shrinks)
    |w| <= w_max (100 deg/s), |w - w_prev| <= alpha dt
    |pan| <= 100 deg,         |pan - pan_prev| <= 90 deg/s * dt

so a stop is a ramp: from v_max at 2 m/s^2 braking the base is at rest within 0.375 s.

Obstacles (``guard.*``, beyond the thesis; guard.py, avoid.py): before the limits, a command
whose arc would run the base into something the last laser scan shows is turned, slowed or
stopped (reasons ``avoid_turn`` / ``avoid_slow`` / ``avoid_stop``); with no scan known, the
base stops (reason ``no_scan``; turning on the spot and the camera go on).
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

import msgspec
import numpy as np

from followbot.schemas import MAX_ANGULAR_RADPS, MAX_LINEAR_MPS, TrackState
from followbot.services.runtime.settings import removed, renamed

from .guard import Guard, GuardSettings
from .zhuang import ZhuangRule, ZhuangSettings

__all__ = [
    "RETIRED_SETTINGS",
    "Command",
    "ControllerSettings",
    "FollowController",
    "LimitsSettings",
    "PanSettings",
]

_Pos = Annotated[float, msgspec.Meta(gt=0)]

_LOG = "docs/tracker_log.md"

#: Settings that are gone or moved: a file or --set naming one is refused with this.
RETIRED_SETTINGS: dict[str, str] = {
    "laser_mount_x_m": (
        "was replaced by laser_mount, one setting every stage reads: write "
        "laser_mount: {x_m: X, y_m: Y, yaw_deg: DEGREES} at the top of your settings "
        "(docs/robot.md)"
    ),
    "follow_report": removed(
        f"following the reported position instead of the filter estimate, measured and left "
        f"off, see {_LOG}"
    ),
    "avoid_memory_s": removed(
        f"remembering returns outside the laser's view, measured and left off, see {_LOG}"
    ),
    "max_speed_mps": renamed("limits.max_speed_mps"),
    "max_turn_deg_s": renamed("limits.max_turn_deg_s"),
    "hardware_max_speed_mps": renamed("limits.hardware_max_speed_mps"),
    "hardware_max_turn_deg_s": renamed("limits.hardware_max_turn_deg_s"),
    "accel_mps2": renamed("limits.accel_mps2"),
    "decel_mps2": renamed("limits.decel_mps2"),
    "turn_accel_deg_s2": renamed("limits.turn_accel_deg_s2"),
    "reverse": renamed("limits.reverse"),
    "pan_rate_deg_s": renamed("pan.rate_deg_s"),
    "pan_limit_deg": renamed("pan.limit_deg"),
    "pan_to_look": renamed("pan.look_when_lost"),
    "avoid_obstacles": renamed("guard.enabled"),
    "obstacle_margin_m": renamed("guard.margin_m"),
    "avoid_horizon_s": renamed("guard.horizon_s"),
    "avoid_turn_candidates": renamed("guard.turn_candidates"),
    "avoid_min_speed_mps": renamed("guard.min_speed_mps"),
    "avoid_min_progress": renamed("guard.min_progress"),
    "avoid_between_m": renamed("guard.between_m"),
    "avoid_wait_moving_only": renamed("guard.wait_moving_only"),
    "avoid_wait_s": renamed("guard.wait_s"),
    "avoid_escape_m": renamed("guard.escape_m"),
    "avoid_escape_commit": renamed("guard.escape_commit"),
    "avoid_escape_for_s": renamed("guard.escape_for_s"),
    "avoid_escape_after_s": renamed("guard.escape_after_s"),
    "avoid_check_limited": renamed("guard.check_limited"),
    "avoid_ignore_target_m": renamed("guard.ignore_target_m"),
}


class LimitsSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What every command obeys, whatever produced it: ``--set limits.max_speed_mps=0.5``."""

    max_speed_mps: _Pos = 0.75
    """v_max (m/s): the rule's speed beyond match_distance_m and the cap of every command
    (thesis 4.6); at most hardware_max_speed_mps."""
    # thesis 5.2.5: rotation at most 100 deg/s
    max_turn_deg_s: _Pos = 100.0
    hardware_max_speed_mps: Annotated[float, msgspec.Meta(gt=0, le=MAX_LINEAR_MPS)] = 1.0
    """The base's own speed cap: max_speed_mps may not exceed it (a settings file asking for
    more is refused), and no command exceeds it. Set it to what the base is rated for."""
    hardware_max_turn_deg_s: Annotated[
        float, msgspec.Meta(gt=0, le=math.degrees(MAX_ANGULAR_RADPS))
    ] = 180.0
    """The base's own turn-rate cap: max_turn_deg_s may not exceed it."""
    accel_mps2: _Pos = 0.5
    """Speeding up: |v| grows by at most this much per second (m/s^2)."""
    decel_mps2: _Pos = 2.0
    """Braking (|v| decreasing) may be harder than speeding up (m/s^2)."""
    turn_accel_deg_s2: _Pos = 300.0
    """The turn rate changes by at most this much per second (deg/s^2; the simulator's robot
    has the same limit)."""
    reverse: bool = False
    """Never drive backwards unless allowed (the thesis robot only follows)."""

    def __post_init__(self) -> None:
        if self.max_speed_mps > self.hardware_max_speed_mps:
            raise ValueError(
                f"limits.max_speed_mps {self.max_speed_mps} exceeds "
                f"limits.hardware_max_speed_mps {self.hardware_max_speed_mps} (the base's own "
                "cap; raise that only if the base is rated for it)"
            )
        if self.max_turn_deg_s > self.hardware_max_turn_deg_s:
            raise ValueError(
                f"limits.max_turn_deg_s {self.max_turn_deg_s} exceeds "
                f"limits.hardware_max_turn_deg_s {self.hardware_max_turn_deg_s} (the base's "
                "own cap)"
            )


class PanSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The camera's pan: ``--set pan.rate_deg_s=60``."""

    rate_deg_s: _Pos = 90.0
    """The camera pan turns at most this fast (deg/s; thesis 5.2.5)."""
    limit_deg: Annotated[float, msgspec.Meta(ge=0, le=180)] = 100.0
    """The camera pans at most this far either side of ahead (deg; thesis 5.2.5)."""
    look_when_lost: bool = True
    """Beyond the thesis: while the target is lost, pan the camera to the person or point the
    tracker names (TrackState.look_*) so vision can re-identify the target; the base stays
    still. False: the camera holds its angle."""


class ControllerSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    retired_settings: ClassVar[dict[str, str]] = RETIRED_SETTINGS

    # thesis 4.6: turn only beyond [-6 deg, +6 deg]
    dead_band_deg: Annotated[float, msgspec.Meta(ge=0, le=180)] = 6.0
    # thesis 4.6: r < 1.2 m stop, 1.2..1.5 m the person's speed, > 1.5 m v_max = 0.75 m/s
    stop_distance_m: Annotated[float, msgspec.Meta(ge=0)] = 1.2
    match_distance_m: Annotated[float, msgspec.Meta(ge=0)] = 1.5
    """From stop_distance_m up to this range (m) the base matches the person's speed; beyond
    it, it drives at limits.max_speed_mps (thesis 4.6)."""
    turn_gain_per_s: _Pos = 1.5
    """w* = gain * theta: the base turns to the heading in about 1/gain seconds."""
    body_radius_m: _Pos = 0.25
    """The base seen from above as a disc (the simulator's robot.radius_m); the guard keeps
    it off obstacles."""
    limits: LimitsSettings = msgspec.field(default_factory=LimitsSettings)
    """Speed, turn-rate and acceleration limits of every command."""
    pan: PanSettings = msgspec.field(default_factory=PanSettings)
    """The camera's pan."""
    guard: GuardSettings = msgspec.field(default_factory=GuardSettings)
    """The obstacle guard (guard.py, avoid.py)."""
    rule: Literal["thesis", "zhuang"] = "thesis"
    """The following rule: thesis (above), or zhuang -- seed 001's: turn by k_p times the
    target's image column off centre outside a dead band, forward / back by distance bands,
    the camera's pan held at 0 (zhuang.py; settings under ``zhuang``). Limits and watchdog
    apply to both."""
    zhuang: ZhuangSettings = msgspec.field(default_factory=ZhuangSettings)
    """Seed 001's rule, with ``rule: zhuang``."""


class Command(msgspec.Struct, frozen=True):
    linear_mps: float
    angular_radps: float
    pan_rad: float
    reason: str


def _toward(value: float, goal: float, max_step: float) -> float:
    return value + min(max(goal - value, -max_step), max_step)


def _clamp(value: float, limit: float) -> float:
    return min(max(value, -limit), limit)


class FollowController:
    """Turns TrackStates into limited (v, w, pan) commands. One loop drives it."""

    def __init__(self, settings: ControllerSettings | None = None) -> None:
        self.settings = s = settings or ControllerSettings()
        if s.match_distance_m < s.stop_distance_m:
            raise ValueError("match_distance_m must be >= stop_distance_m")
        self._w_max = math.radians(s.limits.max_turn_deg_s)
        self._alpha = math.radians(s.limits.turn_accel_deg_s2)
        self._pan_max = math.radians(s.pan.limit_deg)
        self._pan_rate = math.radians(s.pan.rate_deg_s)
        self._dead = math.radians(s.dead_band_deg)
        self.v = 0.0
        self.w = 0.0
        self.pan = 0.0
        self._goal = (0.0, 0.0, 0.0)
        self._zhuang = ZhuangRule(s.zhuang)
        self.guard = (
            Guard(
                s.guard,
                body_radius_m=s.body_radius_m,
                decel_mps2=s.limits.decel_mps2,
                max_turn_radps=self._w_max,
            )
            if s.guard.enabled
            else None
        )

    # ------------------------------------------------------------------ the rule

    def goal(self, target: TrackState) -> tuple[float, float, float, str]:
        """(v*, w*, pan*, reason) of the thesis rule, before limits."""
        s = self.settings
        status = target.status
        if status == "coasting":
            v, w, pan = self._goal
            return v, w, pan, "coasting"
        if s.rule == "zhuang":  # seed 001: a fixed camera, pan held at 0
            if status != "tracking":
                return 0.0, 0.0, 0.0, status
            v, w = self._zhuang.follow(target.x_m, target.y_m)
            return v, w, 0.0, "zhuang"
        looks = target.look_track_id >= 0 or (target.look_x_m, target.look_y_m) != (0.0, 0.0)
        if status == "lost" and s.pan.look_when_lost and looks:
            return 0.0, 0.0, math.atan2(target.look_y_m, target.look_x_m), status  # stop, look
        if status != "tracking":
            return 0.0, 0.0, self.pan, status  # lost / initialising: stop, camera stays
        # the filter estimate: the report less its lone-leg shift
        x, y = target.x_m - target.shift_x_m, target.y_m - target.shift_y_m
        r = math.hypot(x, y)
        theta = math.atan2(y, x)
        speed = math.hypot(target.vx_mps, target.vy_mps)
        w = s.turn_gain_per_s * theta if abs(theta) > self._dead else 0.0
        if r < s.stop_distance_m:
            v, reason = 0.0, "stop_close"
        elif r <= s.match_distance_m:
            v, reason = speed, "match_speed"
        else:
            v, reason = s.limits.max_speed_mps, "max_speed"
        return v, w, theta, reason

    # ------------------------------------------------------------------ commands

    def on_target(
        self,
        target: TrackState,
        dt_s: float,
        obstacles: np.ndarray | None = None,
        view: tuple[float, float, float] | None = None,
    ) -> Command:
        """The command for ``target``; ``obstacles``: the last scan's returns in the base
        frame, (N, 2) (guard.enabled; None: no scan known); ``view``: that scan's
        avoid.scan_view (the escape keeps the target inside it; None: unknown)."""
        v, w, pan, reason = self.goal(target)
        if target.status == "tracking":
            self._goal = (v, w, pan)
        elif target.status != "coasting":
            self._goal = (0.0, 0.0, self.pan)
        if self.guard is not None:

            def limited(v_: float, w_: float) -> tuple[float, float]:
                return self._limited(v_, w_, pan, dt_s)[:2]

            v, w, reason = self.guard.step(
                (v, w, reason), target, obstacles, view, dt_s, (self.v, self.w), limited
            )
        return self._limit(v, w, pan, reason, dt_s)

    def stop(self, dt_s: float, reason: str = "watchdog") -> Command:
        """Brake towards zero velocity (the watchdog); the camera holds its angle."""
        self._goal = (0.0, 0.0, self.pan)
        return self._limit(0.0, 0.0, self.pan, reason, dt_s)

    def _limit(self, v: float, w: float, pan: float, reason: str, dt_s: float) -> Command:
        if not (math.isfinite(v) and math.isfinite(w) and math.isfinite(pan)):
            v, w, pan, reason = 0.0, 0.0, self.pan, "invalid"
        v, w, pan = self._limited(v, w, pan, dt_s)
        self.v, self.w, self.pan = v, w, pan
        return Command(v, w, pan, reason)

    def _limited(self, v: float, w: float, pan: float, dt_s: float) -> tuple[float, float, float]:
        """(v, w, pan) after the limits, from the last command; changes nothing."""
        s = self.settings.limits
        dt = max(0.0, dt_s) if math.isfinite(dt_s) else 0.0
        lo = -s.max_speed_mps if s.reverse else 0.0
        v = min(max(v, lo), s.max_speed_mps)
        # speeding up at accel, braking (towards zero) at decel
        speeding_up = abs(v) > abs(self.v) and v * self.v >= 0
        step = (s.accel_mps2 if speeding_up else s.decel_mps2) * dt
        v = _toward(self.v, v, step)
        if abs(v) > abs(self.v) and abs(v - self.v) > s.accel_mps2 * dt:
            v = self.v + math.copysign(s.accel_mps2 * dt, v - self.v)
        w = _toward(self.w, _clamp(w, self._w_max), self._alpha * dt)
        pan = _toward(self.pan, _clamp(pan, self._pan_max), self._pan_rate * dt)
        return v, w, pan

    @property
    def at_rest(self) -> bool:
        return self.v == 0.0 and self.w == 0.0
