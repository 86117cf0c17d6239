"""The obstacle guard's settings (``guard.*``) and the state it keeps from one command to the next.

avoid.py's :class:`~.avoid.ObstacleGuard` judges one command against one scan and keeps
nothing. Following needs memory on top of that, which :class:`Guard` holds:

* how long the base has waited for something on the line to the target (``wait_s``) and the
  scan before, moved by the base's own last command (``wait_moving_only``);
* how long the guard has stopped the base with the target known (``escape_after_s``);
* the escape under way (``escape_commit``): its end point, kept in the base frame as the
  base moves, driven to before the rule has the base again, given up after ``escape_for_s``,
  when the run there is no longer free, or when the target is lost or near enough to stop for.

The controller calls :meth:`Guard.step` with the rule's command before the limits, once per
target; the guard answers the command to limit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Annotated

import msgspec
import numpy as np

from followbot.schemas import TrackState

from .avoid import ObstacleGuard, moved_into_frame

__all__ = ["ESCAPE_VIEW_MARGIN_RAD", "Guard", "GuardSettings"]

_Pos = Annotated[float, msgspec.Meta(gt=0)]

ESCAPE_VIEW_MARGIN_RAD = math.radians(10.0)
"""escape_commit: the escape's heading keeps the target this far inside the laser's field of
view (a narrow laser turned 60 deg off its target no longer sees it)."""

#: (v, w) -> (v, w) after the controller's limits from its last command, over this step.
Limited = Callable[[float, float], tuple[float, float]]


class GuardSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The obstacle guard (beyond the thesis; avoid.py): ``--set guard.wait_s=0``."""

    enabled: bool = True
    """Turn, slow or stop a command whose arc would run the base into something the laser
    sees (the node then also subscribes sensors/scan). False: the thesis's rule alone, which
    drives straight at the target through whatever is between."""
    margin_m: Annotated[float, msgspec.Meta(ge=0)] = 0.05
    """Clearance (m) kept between the body (body_radius_m) and any return."""
    horizon_s: _Pos = 1.0
    """How far ahead the arc is checked: this many seconds of travel plus the braking
    distance (at limits.decel_mps2)."""
    turn_candidates: Annotated[int, msgspec.Meta(ge=2, le=1000)] = 21
    """How many turn rates, evenly spaced from -limits.max_turn_deg_s to +max_turn_deg_s,
    are tried when the command's own arc is blocked."""
    min_speed_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.05
    """A command slowed to stop short below this speed (m/s) stops instead (reason
    avoid_stop; turning on the spot goes on)."""
    min_progress: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.5
    """A way round must bring the base at least this share of the command's own gain nearer
    the target (avoid.py)."""
    between_m: Annotated[float, msgspec.Meta(ge=0)] = 0.25
    """What lies within this (m) of the line to the target is "on the line" (wait_s)
    (docs/tracker_log.md)."""
    wait_moving_only: bool = True
    """Wait (wait_s) only for something on the line that moved since the scan before (the
    previous scan moved by the base's own last command); a box or a pillar there is gone
    round at once."""
    wait_s: Annotated[float, msgspec.Meta(ge=0)] = 1.5
    """Something on the line to the target is waited for this long (s) before the base goes
    round it (reason avoid_wait; 0: at once)."""
    escape_m: Annotated[float, msgspec.Meta(ge=0)] = 0.3
    """Stopped short with the target tracked, the base turns to a free heading towards the
    target and drives at least this far (m) along it (reason avoid_escape; 0: off, it stands
    there). Default chosen by the closed-loop runs of docs/tracker_log.md."""
    escape_commit: bool = True
    """With escape_m: an escape, once begun, is driven to its end before the rule has the
    base again -- turn on the spot until it faces the end point, then drive there. The end
    is past the corner: the shortest run (1, 1.5, 2 x escape_m), then the heading nearest
    the target's whose end leaves the straight way on towards the target free for the body
    and the margin, the target kept 10 deg inside the laser's view. False: the escape is
    chosen afresh each step from where the base stands (the nearest free heading escape_m
    on), which lets the rule's own arc, free again a few centimetres on, turn the base back
    into the corner it was escaping."""
    escape_for_s: _Pos = 4.0
    """escape_commit: an escape not at its end after this long (s) is given up."""
    escape_after_s: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """The escape waits until the base has stood this long (s, reason avoid_stop) with the
    target known: stopped for a moment beside a box, the base goes round it as before;
    escaping at once turns it back and forth beside the box."""
    check_limited: bool = True
    """The arc the base will drive this step -- the guard's command after the acceleration
    and turn-rate limits -- is checked too, for contact (the body and 0.01 m), and the base
    brakes (avoid_stop; turning on the spot stays free) when it is not free. The limits bend
    the arc: speeding up from a standstill the base turns at the rule's rate at a fraction of
    the speed, a much tighter arc than the goal's. False: the goal's arc only."""
    ignore_target_m: Annotated[float, msgspec.Meta(ge=0)] = 0.5
    """Returns within this (m) of the target's estimate are the target's legs, not obstacles
    (the rule stops 1.2 m short of them anyway)."""


class Guard:
    """The obstacle guard of one base: :class:`~.avoid.ObstacleGuard` and its state."""

    def __init__(
        self,
        settings: GuardSettings,
        *,
        body_radius_m: float,
        decel_mps2: float,
        max_turn_radps: float,
    ) -> None:
        s = self.settings = settings
        self.geometry = ObstacleGuard(
            body_radius_m=body_radius_m,
            margin_m=s.margin_m,
            horizon_s=s.horizon_s,
            decel_mps2=decel_mps2,
            max_turn_radps=max_turn_radps,
            turn_candidates=s.turn_candidates,
            min_speed_mps=s.min_speed_mps,
            ignore_near_target_m=s.ignore_target_m,
            min_progress=s.min_progress,
            between_m=s.between_m,
            wait_moving_only=s.wait_moving_only,
            escape_m=s.escape_m,
        )
        self._waited_s = 0.0  # wait_s: how long the base has waited so far
        self._previous: np.ndarray | None = None  # wait_moving_only: the scan before
        self._escaping = False  # the last command was an escape
        self._stood_s = 0.0  # escape_after_s: how long the guard has stopped the base
        self._escape_goal: tuple[float, float] | None = None  # escape_commit: its end point
        self._escape_age_s = 0.0

    @property
    def escape_goal(self) -> tuple[float, float] | None:
        """escape_commit: the end point (base frame) of the escape under way, or None."""
        return self._escape_goal

    def step(
        self,
        command: tuple[float, float, str],
        target: TrackState,
        obstacles: np.ndarray | None,
        view: tuple[float, float, float] | None,
        dt_s: float,
        last: tuple[float, float],
        limited: Limited,
    ) -> tuple[float, float, str]:
        """The rule's ``command`` (v, w, reason) as the guard lets it go, for ``target`` and
        the scan's base-frame ``obstacles`` (N, 2) (None: no scan known, the base stops,
        reason no_scan) whose avoid.scan_view is ``view``; ``last``: the (v, w) the base
        drove over the ``dt_s`` since the previous step; ``limited``: the limits this step."""
        v, w, reason = command
        dt = max(0.0, dt_s) if math.isfinite(dt_s) else 0.0
        self._age_escape(target.status, dt, last)
        if v > 0.0:
            if obstacles is None:
                v, reason = 0.0, "no_scan"
            else:
                xy = None
                if target.status in ("tracking", "coasting"):
                    xy = (target.x_m - target.shift_x_m, target.y_m - target.shift_y_m)
                v, w, reason = self._guarded(
                    v, w, reason, target.status, xy, obstacles, view, dt_s, last
                )
                v, reason = self._check_limited(v, w, reason, xy, obstacles, limited)
        self._after(reason, target.status, obstacles, dt)
        return v, w, reason

    def _age_escape(self, status: str, dt: float, last: tuple[float, float]) -> None:
        """The escape's end point moved by the base's last command, and given up when too
        old or the target is neither tracked nor coasting."""
        if self._escape_goal is None:
            return
        gx, gy = moved_into_frame(np.array([self._escape_goal]), last[0], last[1], dt)[0]
        self._escape_goal, self._escape_age_s = (float(gx), float(gy)), self._escape_age_s + dt
        if self._escape_age_s > self.settings.escape_for_s or status not in (
            "tracking",
            "coasting",
        ):
            self._escape_goal = None

    def _guarded(
        self,
        v: float,
        w: float,
        reason: str,
        status: str,
        xy: tuple[float, float] | None,
        obstacles: np.ndarray,
        view: tuple[float, float, float] | None,
        dt_s: float,
        last: tuple[float, float],
    ) -> tuple[float, float, str]:
        """The command against the scan: the escape under way, else avoid.ObstacleGuard.apply
        (and, stopped where the guard would escape, the planned escape)."""
        s, g = self.settings, self.geometry
        if self._escape_goal is not None:  # an escape under way: driven to its end
            step = g.toward_goal(v, self._escape_goal, obstacles)
            if step is not None:
                return step
            self._escape_goal = None
        # an escape under way is not broken off to wait: turning on the spot makes the walls
        # near the line to the target look moved
        may = self._waited_s >= s.wait_s or self._escaping
        before = None
        if self._previous is not None and math.isfinite(dt_s):
            before = moved_into_frame(self._previous, last[0], last[1], max(0.0, dt_s))
        # an escape begins only towards a target the laser has now (tracking): a coasting one
        # is a guess, and turning the base away on a guess turns the laser and the camera off
        # where it is hidden; one under way goes on
        escape = self._escaping or (self._stood_s >= s.escape_after_s and status == "tracking")
        plan = s.escape_commit  # the escape planned here, not step by step
        v0 = v
        v, w, why = g.apply(
            v, w, obstacles, xy, may_swerve=may, previous=before, may_escape=escape and not plan
        )
        if plan and escape and why == "avoid_stop" and xy is not None and g.escape_m > 0.0:
            # stopped where the guard would escape: the end past the corner, with the target
            # kept in the laser's view
            keep = None
            if view is not None:
                keep = (view.lo_rad + ESCAPE_VIEW_MARGIN_RAD, view.hi_rad - ESCAPE_VIEW_MARGIN_RAD)
            goal = g.escape_goal(obstacles, xy, True, keep)
            self._escape_goal, self._escape_age_s = goal, 0.0
            if goal is not None:
                v, w, why = g.toward_goal(v0, goal, obstacles) or (v, w, why)
        return v, w, why or reason

    def _check_limited(
        self,
        v: float,
        w: float,
        reason: str,
        xy: tuple[float, float] | None,
        obstacles: np.ndarray,
        limited: Limited,
    ) -> tuple[float, str]:
        """check_limited: the limits bend the arc -- from a standstill the base turns at once
        but speeds up slowly (a tighter arc than the goal's); the arc it will drive must be
        free too, else it brakes (turning on the spot is free). Already braking at the limit
        (faster than asked) it cannot do more."""
        if not self.settings.check_limited or reason == "avoid_escape" or v <= 0.0:
            return v, reason
        v_l, w_l = limited(v, w)
        bent = (v_l, w_l) != (v, w)  # (unbent, the guard has checked that arc)
        if bent and v_l <= v and self.geometry.blocked(v_l, w_l, obstacles, xy):
            return 0.0, "avoid_stop"
        return v, reason

    def _after(self, reason: str, status: str, obstacles: np.ndarray | None, dt: float) -> None:
        """What the next step needs of this one: the scan, the escape, standing, waiting."""
        if obstacles is not None:
            self._previous = obstacles
        self._escaping = reason == "avoid_escape"
        if not self._escaping:  # stopped for, lost, no scan ...: the escape is over
            self._escape_goal = None
        if reason == "avoid_stop" and status in ("tracking", "coasting"):
            self._stood_s += dt
        elif not self._escaping:
            self._stood_s = 0.0
        if reason == "avoid_wait":
            self._waited_s += dt
        elif reason != "avoid_turn":
            self._waited_s = 0.0
