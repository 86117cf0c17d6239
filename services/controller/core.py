"""The controller: the thesis's following rule, with acceleration and rate limits always enforced.

Pure logic, no Zenoh (the node is ``node.py``). Thesis 3.7, 4.6; DESIGN.md "Control".

Rule (from the target's estimate in the base frame of its scan):

    r = sqrt(x^2 + y^2),  theta = atan2(y, x),  v_h = sqrt(vx^2 + vy^2)        (eq. 3-39)
    turn       only when |theta| > 6 deg: w* = turn_gain * theta, else 0
    translate  r < 1.2 m: 0;  1.2 <= r <= 1.5 m: v_h (the person's speed);  r > 1.5 m: v_max
    pan        pan* = theta (eq. 4-10: the camera looks at the target while the base turns)

By status: ``tracking`` applies the rule; ``coasting`` keeps the previous goal (thesis 3.6.2.8:
fewer than 9 misses keep the previous command); ``lost`` and ``initialising`` stop; the
watchdog (no fresh target, tracker gone) stops. While lost the camera pans to the person the
tracker names for a look (``pan_to_look``, beyond the thesis), else it holds its angle; so
does it while coasting when the tracker names a look (a target hidden past the miss budget,
tracker setting ``occlusion_look``), the base keeping its coasting command.

Limits, applied to every command whatever produced it (dt: time since the previous command):

    |v| <= v_max (0.75 m/s),  |v - v_prev| <= a dt (a = accel, or decel when |v| shrinks)
    |w| <= w_max (100 deg/s), |w - w_prev| <= alpha dt
    |pan| <= 100 deg,         |pan - pan_prev| <= 90 deg/s * dt

so a stop is a ramp: from v_max at 2 m/s^2 braking the base is at rest within 0.375 s.

Obstacles (``avoid_obstacles``, beyond the thesis; avoid.py): before the limits, a command
whose arc would run the base into something the last laser scan shows is turned, slowed or
stopped (reasons ``avoid_turn`` / ``avoid_slow`` / ``avoid_stop``); with no scan known, the
base stops (reason ``no_scan``; turning on the spot and the camera go on).
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar

import msgspec
import numpy as np

from followbot.schemas import MAX_ANGULAR_RADPS, MAX_LINEAR_MPS, TrackState

from .avoid import ObstacleGuard, moved_into_frame, outside_view

__all__ = ["Command", "ControllerSettings", "FollowController"]

_Pos = Annotated[float, msgspec.Meta(gt=0)]

MEMORY_RANGE_M = 2.0
"""avoid_memory_s: only returns this near the base are remembered."""
MEMORY_CELL_M = 0.02
"""avoid_memory_s: the remembered returns are thinned to one per square cell of this side."""


class ControllerSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    retired_settings: ClassVar[dict[str, str]] = {
        "laser_mount_x_m": (
            "was replaced by laser_mount, one setting every stage reads: write "
            "laser_mount: {x_m: X, y_m: Y, yaw_deg: DEGREES} at the top of your settings "
            "(docs/robot.md)"
        ),
    }

    # thesis 4.6: turn only beyond [-6 deg, +6 deg]
    dead_band_deg: Annotated[float, msgspec.Meta(ge=0, le=180)] = 6.0
    # thesis 4.6: r < 1.2 m stop, 1.2..1.5 m the person's speed, > 1.5 m v_max = 0.75 m/s
    stop_distance_m: Annotated[float, msgspec.Meta(ge=0)] = 1.2
    match_distance_m: Annotated[float, msgspec.Meta(ge=0)] = 1.5
    max_speed_mps: _Pos = 0.75
    # thesis 5.2.5: rotation at most 100 deg/s; pan 90 deg/s within +-100 deg
    max_turn_deg_s: _Pos = 100.0
    hardware_max_speed_mps: Annotated[float, msgspec.Meta(gt=0, le=MAX_LINEAR_MPS)] = 1.0
    """The base's own speed cap: max_speed_mps may not exceed it (a settings file asking for
    more is refused), and no command exceeds it. Set it to what the base is rated for."""
    hardware_max_turn_deg_s: Annotated[
        float, msgspec.Meta(gt=0, le=math.degrees(MAX_ANGULAR_RADPS))
    ] = 180.0
    """The base's own turn-rate cap: max_turn_deg_s may not exceed it."""
    pan_rate_deg_s: _Pos = 90.0
    pan_limit_deg: Annotated[float, msgspec.Meta(ge=0, le=180)] = 100.0
    turn_gain_per_s: _Pos = 1.5
    """w* = gain * theta: the base turns to the heading in about 1/gain seconds."""
    accel_mps2: _Pos = 0.5
    decel_mps2: _Pos = 2.0
    """Braking (|v| decreasing) may be harder than speeding up."""
    turn_accel_deg_s2: _Pos = 300.0
    reverse: bool = False
    """Never drive backwards unless allowed (the thesis robot only follows)."""
    pan_to_look: bool = True
    """Beyond the thesis: while the target is lost, pan the camera to the person the tracker
    names (TrackState.look_*) so vision can re-identify the target; the base stays still.
    Also while coasting, when the tracker names a look (occlusion_look), the base keeping its
    coasting command."""
    follow_report: bool = False
    """False: the rule follows the tracker's filter estimate, the report less its lone-leg
    shift (TrackState.shift_*; zero unless the tracker's lone_leg_output_m is set), as
    laser_legs gates criterion 3 there: refining the report then moves no part of the loop.
    True: the reported position (moved out for lone legs), which changes the robot's path
    (docs/tracker_log.md, fifteenth session: 76 runs, crowd_ten seed 6 lost its target)."""
    avoid_obstacles: bool = True
    """Beyond the thesis: turn, slow or stop a command whose arc would run the base into
    something the laser sees (avoid.py; the node then also subscribes sensors/scan). False:
    the thesis's rule alone, which drives straight at the target through whatever is between."""
    body_radius_m: _Pos = 0.25
    """The base seen from above as a disc (the simulator's robot.radius_m)."""
    obstacle_margin_m: Annotated[float, msgspec.Meta(ge=0)] = 0.05
    avoid_horizon_s: _Pos = 1.0
    """How far ahead the arc is checked: this many seconds of travel plus the braking
    distance (at decel_mps2)."""
    avoid_turn_candidates: Annotated[int, msgspec.Meta(ge=2, le=1000)] = 21
    avoid_min_speed_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.05
    avoid_min_progress: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.5
    """A way round must bring the base at least this share of the command's own gain nearer
    the target (avoid.py)."""
    avoid_between_m: Annotated[float, msgspec.Meta(ge=0)] = 0.25
    """What lies within this of the line to the target is "on the line" (avoid_wait_s). 0.25
    with avoid_wait_moving_only since the seventeenth session (0.125 before; docs/tracker_log.md:
    76 runs, switch runs 3 -> 1)."""
    avoid_wait_moving_only: bool = True
    """Wait (avoid_wait_s) only for something on the line that moved since the scan before
    (the previous scan moved by the base's own last command); a box or a pillar there is gone
    round at once."""
    avoid_wait_s: Annotated[float, msgspec.Meta(ge=0)] = 1.5
    """Something on the line to the target is waited for this long before the base goes
    round it (avoid.py; 0: at once)."""
    avoid_memory_s: Annotated[float, msgspec.Meta(ge=0)] = 0.0
    """Beyond the thesis, with avoid_obstacles (off by default; e.g. 3.0): returns seen in the
    last avoid_memory_s that the laser no longer covers (outside its field of view: beside
    or behind the base) are remembered, moved with the base's own commanded motion, and kept
    off by the body and 0.01 m (avoid.ObstacleGuard.thresholds); inside the field of view the
    current scan alone counts. The thesis's laser sees +-50 deg: turning back towards its
    target a base swings into the box corner or door jamb it no longer sees
    (livingston_box_occlusion with the escape; thesis_5_2_3_room_corridor's own seed, the
    one contact of the 76 runs). 76 runs with 3 s (nineteenth session, docs/tracker_log.md): no
    contact, but room_corridor's robot then stood for good in its door in 3 of 4 seeds
    (tracked >= 98 % 67 -> 64, RMSE <= 0.08 m 73 -> 70); with avoid_escape_m 0.3 as well, no
    contact and room_corridor clean, but 65 / 72 (livingston_box_occlusion seed 6 tracked
    1.00 -> 0.90, the office's seed 3 0.89 -> 0.64). Twenty-second session, with the
    committed escape: 3 s gives no contact but 72 / 65 (75 / 68 without; livingston's box
    and room_corridor's door stand the base); the memory only for a last contact check (built
    and removed) still touched a jamb once -- a remembered return is a noisy laser return
    moved by the commands, 1-2 cm off the corner -- and lost as much. 0: the last scan only."""
    avoid_escape_m: Annotated[float, msgspec.Meta(ge=0)] = 0.3
    """Stopped short with the target tracked, the base turns to a free heading towards the
    target and drives at least this far along it (avoid.py, reason avoid_escape; 0: off, it
    stands there). Default since the twenty-first session, with avoid_escape_commit: over the
    76-run sweep (docs/tracker_log.md) RMSE <= 0.08 m 74 -> 75, ristic_wall_corridor seed 1 no
    longer stands at the corridor's mouth (tracked 0.85 -> 1.00), no contact. Without the
    commitment (eighteenth and twentieth sessions) it stayed off: runs with a contact 1 -> 6,
    then 0 -> 4 (livingston_box_occlusion's box)."""
    avoid_escape_commit: bool = True
    """With avoid_escape_m: an escape, once begun, is driven to its end before the rule has
    the base again -- turn on the spot until it faces the end point, then drive there (kept
    in the base frame as the base moves; given up when the run there is no longer free, the
    target is lost or near enough to stop for, or after avoid_escape_for_s). The end is past
    the corner: the shortest run (1, 1.5, 2 x avoid_escape_m) and then the heading nearest
    the target's whose end leaves the straight way on towards the target free for the body
    and the margin (avoid.ObstacleGuard.escape_goal, onward), the target kept 10 deg inside
    the laser's view. False: the escape is chosen afresh each step from where the base
    stands, the nearest free heading 0.3 m on, so the rule's own arc, free again a few
    centimetres on, turned the base back into the corner it was escaping
    (ristic_wall_corridor seed 1, twentieth session: 45 deg left, a few cm, back, stopped)."""
    avoid_escape_for_s: Annotated[float, msgspec.Meta(gt=0)] = 4.0
    """avoid_escape_commit: an escape not at its end after this long is given up."""
    avoid_escape_after_s: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """The escape waits until the base has stood this long (reason avoid_stop) with the target
    known: stopped for a moment beside a box it is gone round as before; standing for good at
    a corridor's mouth it is not (the eighteenth session: escaping at once turned the base
    back and forth beside livingston_box_occlusion's box until it touched it)."""
    avoid_check_limited: bool = True
    """With avoid_obstacles: the arc the base will drive this step -- the guard's command after
    the acceleration and turn-rate limits -- is checked as the goal's is, and the base brakes
    (avoid_stop; turning on the spot stays free) when it is not free. The limits bend the
    arc: speeding up from a standstill the base turns at the rule's rate at a fraction of the
    speed, a much tighter arc than the goal's (livingston_box_occlusion with the escape: 0.24
    m/s at 70 deg/s swung the base into the box it had just turned away from). A contact
    check (the body and 0.01 m), not the margin's. Nineteenth session: default, and no run of
    the 76 changes with it (none met the case; test_the_arc_the_limits_leave_is_checked_too
    does). False: the goal's arc only."""
    avoid_ignore_target_m: Annotated[float, msgspec.Meta(ge=0)] = 0.5
    """Returns within this of the target's estimate are the target's legs, not obstacles
    (the rule stops 1.2 m short of them anyway)."""

    def __post_init__(self) -> None:
        if self.max_speed_mps > self.hardware_max_speed_mps:
            raise ValueError(
                f"max_speed_mps {self.max_speed_mps} exceeds hardware_max_speed_mps "
                f"{self.hardware_max_speed_mps} (the base's own cap; raise that only if the "
                "base is rated for it)"
            )
        if self.max_turn_deg_s > self.hardware_max_turn_deg_s:
            raise ValueError(
                f"max_turn_deg_s {self.max_turn_deg_s} exceeds hardware_max_turn_deg_s "
                f"{self.hardware_max_turn_deg_s} (the base's own cap)"
            )


ESCAPE_VIEW_MARGIN_RAD = math.radians(10.0)
"""avoid_escape_commit: the escape's heading keeps the target this far inside the laser's
field of view (livingston_box_occlusion's +-50 deg laser: an escape 60 deg off the target
turned it out of view and it was lost)."""


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
        self._w_max = math.radians(s.max_turn_deg_s)
        self._alpha = math.radians(s.turn_accel_deg_s2)
        self._pan_max = math.radians(s.pan_limit_deg)
        self._pan_rate = math.radians(s.pan_rate_deg_s)
        self._dead = math.radians(s.dead_band_deg)
        self.v = 0.0
        self.w = 0.0
        self.pan = 0.0
        self._goal = (0.0, 0.0, 0.0)
        self._goal_reason = "initialising"
        self._waited_s = 0.0  # avoid_wait_s: how long the base has waited so far
        self._previous: np.ndarray | None = None  # avoid_wait_moving_only: the scan before
        self._escaping = False  # the last command was an escape (avoid_escape_m)
        self._stood_s = 0.0  # avoid_escape_after_s: how long the guard has stopped the base
        # avoid_escape_commit: the escape's end point in the base frame, and its age
        self._escape_goal: tuple[float, float] | None = None
        self._escape_age_s = 0.0
        # avoid_memory_s: earlier scans' returns in the current base frame, and their ages
        self._memory: tuple[np.ndarray, np.ndarray] = (np.empty((0, 2)), np.empty(0))
        self.guard = (
            ObstacleGuard(
                body_radius_m=s.body_radius_m,
                margin_m=s.obstacle_margin_m,
                horizon_s=s.avoid_horizon_s,
                decel_mps2=s.decel_mps2,
                max_turn_radps=self._w_max,
                turn_candidates=s.avoid_turn_candidates,
                min_speed_mps=s.avoid_min_speed_mps,
                ignore_near_target_m=s.avoid_ignore_target_m,
                min_progress=s.avoid_min_progress,
                between_m=s.avoid_between_m,
                wait_moving_only=s.avoid_wait_moving_only,
                escape_m=s.avoid_escape_m,
            )
            if s.avoid_obstacles
            else None
        )

    # ------------------------------------------------------------------ the rule

    def goal(self, target: TrackState) -> tuple[float, float, float, str]:
        """(v*, w*, pan*, reason) of the thesis rule, before limits."""
        s = self.settings
        status = target.status
        looks = target.look_track_id >= 0 or (target.look_x_m, target.look_y_m) != (0.0, 0.0)
        if status == "coasting":
            v, w, pan = self._goal
            if s.pan_to_look and looks:  # hidden past the miss budget (occlusion_look): search
                pan = math.atan2(target.look_y_m, target.look_x_m)
            return v, w, pan, "coasting"
        if status == "lost" and s.pan_to_look and looks:
            return 0.0, 0.0, math.atan2(target.look_y_m, target.look_x_m), status  # stop, look
        if status != "tracking":
            return 0.0, 0.0, self.pan, status  # lost / initialising: stop, camera stays
        x, y = target.x_m, target.y_m
        if not s.follow_report:
            x, y = x - target.shift_x_m, y - target.shift_y_m
        r = math.hypot(x, y)
        theta = math.atan2(y, x)
        speed = math.hypot(target.vx_mps, target.vy_mps)
        w = s.turn_gain_per_s * theta if abs(theta) > self._dead else 0.0
        if r < s.stop_distance_m:
            v, reason = 0.0, "stop_close"
        elif r <= s.match_distance_m:
            v, reason = speed, "match_speed"
        else:
            v, reason = s.max_speed_mps, "max_speed"
        return v, w, theta, reason

    # ------------------------------------------------------------------ commands

    def remembered(
        self,
        obstacles: np.ndarray,
        view: tuple[float, float, float] | None,
        dt_s: float,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """avoid_memory_s: the scan's ``obstacles`` and the remembered returns outside its
        ``view`` (avoid.scan_view), with the mask of the remembered ones (None: none). The
        memory is moved by the last command over ``dt_s`` and aged; what the scan covers is
        dropped from it (the scan alone counts there), what is left is thinned to one return
        per MEMORY_CELL_M cell (the newest), and this scan's returns within MEMORY_RANGE_M
        join it (calling again with the same scan and dt 0 changes nothing)."""
        keep = self.settings.avoid_memory_s
        dt = max(0.0, dt_s) if math.isfinite(dt_s) else 0.0
        if keep <= 0.0 or view is None:
            if self._memory[0].shape[0]:  # forgotten (nothing to allocate when it is off)
                self._memory = (np.empty((0, 2)), np.empty(0))
            return obstacles, None
        pts, age = self._memory
        if dt > 0.0 and pts.shape[0]:
            age = age + dt
            young = age <= keep
            pts = moved_into_frame(pts[young], self.v, self.w, dt)
            age = age[young]
        out = outside_view(pts, view)
        pts, age = pts[out], age[out]
        if pts.shape[0]:  # one per cell, the newest
            order = np.argsort(age, kind="stable")
            cells = np.floor(pts[order] / MEMORY_CELL_M).astype(np.int64)
            _, first = np.unique(cells, axis=0, return_index=True)
            pts, age = pts[order][first], age[order][first]
        near = np.hypot(obstacles[:, 0], obstacles[:, 1]) <= MEMORY_RANGE_M
        # (what is farther cannot come beside the base soon without the laser seeing it)
        self._memory = (
            np.vstack([pts, obstacles[near]]),
            np.concatenate([age, np.zeros(int(near.sum()))]),
        )
        if not pts.shape[0]:
            return obstacles, None
        mask = np.zeros(obstacles.shape[0] + pts.shape[0], dtype=bool)
        mask[obstacles.shape[0] :] = True
        return np.vstack([obstacles, pts]), mask

    def on_target(
        self,
        target: TrackState,
        dt_s: float,
        obstacles: np.ndarray | None = None,
        view: tuple[float, float, float] | None = None,
    ) -> Command:
        """The command for ``target``; ``obstacles``: the last scan's returns in the base
        frame, (N, 2) (avoid_obstacles; None: no scan known); ``view``: that scan's
        avoid.scan_view (avoid_memory_s; None: the scan alone)."""
        v, w, pan, reason = self.goal(target)
        scan, memory = obstacles, None
        if obstacles is not None and self.guard is not None:
            obstacles, memory = self.remembered(obstacles, view, dt_s)
        if target.status == "tracking":
            self._goal = (v, w, pan)
        elif target.status != "coasting":
            self._goal = (0.0, 0.0, self.pan)
        s = self.settings
        dt = max(0.0, dt_s) if math.isfinite(dt_s) else 0.0
        if self._escape_goal is not None:  # moved by the last command, like the memory
            gx, gy = moved_into_frame(np.array([self._escape_goal]), self.v, self.w, dt)[0]
            self._escape_goal, self._escape_age_s = (float(gx), float(gy)), self._escape_age_s + dt
            if self._escape_age_s > s.avoid_escape_for_s or target.status not in (
                "tracking",
                "coasting",
            ):
                self._escape_goal = None
        if self.guard is not None and v > 0.0:
            if obstacles is None:
                v, reason = 0.0, "no_scan"
            else:
                xy = None
                if target.status in ("tracking", "coasting"):
                    xy = (target.x_m - target.shift_x_m, target.y_m - target.shift_y_m)
                # an escape under way is not broken off to wait: turning on the spot makes
                # the walls near the line to the target look moved (avoid.py, escape)
                may = self._waited_s >= s.avoid_wait_s or self._escaping
                before = None
                if self._previous is not None and math.isfinite(dt_s):
                    before = moved_into_frame(self._previous, self.v, self.w, dt)
                # an escape begins only towards a target the laser has now (tracking): a
                # coasting one is a guess, and turning the base away on a guess turns the
                # laser and the camera off where it is hidden (bellotto_cluttered_office
                # seed 3 with the escape: followed 0.55 -> 0.27); one under way goes on
                escape = self._escaping or (
                    self._stood_s >= s.avoid_escape_after_s and target.status == "tracking"
                )
                step = None
                if self._escape_goal is not None:  # an escape under way: driven to its end
                    step = self.guard.toward_goal(v, self._escape_goal, obstacles, memory)
                    if step is None:
                        self._escape_goal = None
                if step is not None:
                    v, w, why = step
                else:
                    v0 = v
                    plan = s.avoid_escape_commit  # the escape planned here, not step by step
                    v, w, why = self.guard.apply(
                        v, w, obstacles, xy, may_swerve=may, previous=before,
                        may_escape=escape and not plan, remembered=memory,
                    )  # fmt: skip
                    # stopped where the guard would escape (avoid.py): the end past the
                    # corner, with the target kept in the laser's view
                    stopped = why == "avoid_stop" and xy is not None
                    if plan and escape and stopped and self.guard.escape_m > 0.0:
                        keep = None
                        if view is not None:
                            keep = (
                                view.lo_rad + ESCAPE_VIEW_MARGIN_RAD,
                                view.hi_rad - ESCAPE_VIEW_MARGIN_RAD,
                            )
                        goal = self.guard.escape_goal(obstacles, xy, memory, True, keep)
                        self._escape_goal, self._escape_age_s = goal, 0.0
                        if goal is not None:
                            v, w, why = self.guard.toward_goal(v0, goal, obstacles, memory) or (
                                v,
                                w,
                                why,
                            )
                reason = why or reason
                if s.avoid_check_limited and reason != "avoid_escape" and v > 0.0:
                    # the limits bend the arc: from a standstill the base turns at once but
                    # speeds up slowly (a tighter arc than the goal's); the arc it will
                    # drive must be free too, else it brakes (turning on the spot is free).
                    # Already braking at the limit (faster than asked) it cannot do more.
                    v_l, w_l, _ = self._limited(v, w, pan, dt_s)
                    bent = (v_l, w_l) != (v, w)  # (unbent, the guard has checked that arc)
                    if bent and v_l <= v and self.guard.blocked(v_l, w_l, obstacles, xy, memory):
                        v, reason = 0.0, "avoid_stop"
        if scan is not None:
            self._previous = scan
        self._escaping = reason == "avoid_escape"
        if not self._escaping:  # stopped for, lost, no scan ...: the escape is over
            self._escape_goal = None
        if reason == "avoid_stop" and target.status in ("tracking", "coasting"):
            self._stood_s += dt
        elif not self._escaping:
            self._stood_s = 0.0
        if reason == "avoid_wait":
            self._waited_s += dt
        elif reason != "avoid_turn":
            self._waited_s = 0.0
        return self._limit(v, w, pan, reason, dt_s)

    @property
    def escape_goal(self) -> tuple[float, float] | None:
        """avoid_escape_commit: the end point (base frame) of the escape under way, or None."""
        return self._escape_goal

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
        s = self.settings
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
