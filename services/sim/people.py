"""Simulated people: a scripted path for the body and a gait model for the two legs.

Path. A person's script (walk to a point, walk an arc, pause, turn) is compiled once into a
list of :class:`Phase` objects with start times, so the body's position p(t), velocity p'(t),
heading h(t) and walked distance s(t) are closed-form functions of time -- no integration, no
randomness, the same answer for the same t however often it is asked.

    line:  p(t) = p0 + v (t - t0) u,             u = (p1 - p0) / |p1 - p0|,  h = atan2(u)
    arc:   p(t) = c + R (cos a, sin a),          a = a0 + sgn v (t - t0) / R,  h = a + sgn pi/2
    pause / turn:  p(t) = p0,   h turns towards the goal at the turn rate (turn only)

At the start of a walk the body heading swings from the previous heading to the path heading
at the turn rate, so a person turning a corner rotates rather than snapping round.

Gait (legs at laser height, body frame: x along the heading, y to the left). With step length
L (the distance between the legs at laser height; thesis 5.2.2: 300 mm) the stride phase is
u = (s / L) mod 2. Leg A is in stance for u in [0, 1) and swings for u in [1, 2); leg B is half a
stride behind:

    stance:  x_A(u) =  L/2 - L u                           (fixed on the floor while p moves L)
    swing:   x_A(u) = -L/2 + L (1 - cos(pi (u - 1))) / 2   (smooth, leaves and lands at rest)
    x_B(u) = x_A(u + 1),   y_A = +w/2,   y_B = -w/2        (w: hip width)

so cadence = v / L (0.6 m/s at 0.3 m gives two steps a second) and the leg separation along the
path swings between L and 0. Standing, the legs take a stance pose (together: side by side,
touching; apart: wider and one a little ahead). Between walking and standing the leg offsets
blend linearly over ``BLEND_S`` seconds (a person finishes a step as they stop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from followbot.services.common.geometry import wrap_angle

from .scenario import ArcStep, PauseStep, PersonSpec, TurnStep, WalkStep

__all__ = ["BLEND_S", "Person", "PersonState", "Phase", "compile_path"]

#: Seconds over which the legs move between the walking and the standing pose.
BLEND_S = 0.5


@dataclass(frozen=True, slots=True)
class Phase:
    """One piece of a compiled path, valid for t in [t0, t0 + duration_s)."""

    kind: str  # "line", "arc", "stand"
    t0: float
    duration_s: float
    p0: tuple[float, float]
    heading0_rad: float
    """Body heading when the phase starts (the previous phase's end heading)."""
    path_heading_rad: float
    """Line: direction of travel. Arc: start angle a0 round the centre. Stand: goal heading."""
    speed_mps: float = 0.0
    s0_m: float = 0.0
    centre: tuple[float, float] = (0.0, 0.0)
    radius_m: float = 0.0
    sign: float = 1.0
    turn_rate_radps: float = math.pi
    after_stand: bool = False
    """The phase follows a standing phase (legs blend out of the stance pose)."""
    after_walk: bool = False
    """A standing phase that follows a walk (legs blend into the stance pose)."""

    @property
    def t1(self) -> float:
        return self.t0 + self.duration_s


@dataclass(slots=True)
class _PathEnd:
    """Where the phases compiled so far leave the person; each step starts from here."""

    t_s: float
    s_m: float
    """Distance walked."""
    p: tuple[float, float]
    heading_rad: float
    walking: bool = False
    """The last phase was a walk (the next stand blends into the stance pose, and back)."""


def compile_path(spec: PersonSpec) -> tuple[list[Phase], float]:
    """Compile a person's script into phases; returns (phases, total walked distance)."""
    turn_rate = math.radians(spec.gait.turn_rate_deg_s)
    start = (float(spec.start[0]), float(spec.start[1]))
    end = _PathEnd(0.0, 0.0, start, math.radians(spec.heading_deg))
    phases: list[Phase] = []
    for step in spec.path:
        match step:
            case WalkStep():
                phase = _line_phase(end, step, spec.speed_mps, turn_rate)
            case ArcStep():
                phase = _arc_phase(end, step, spec.speed_mps, turn_rate)
            case PauseStep():
                phase = _pause_phase(end, step, turn_rate)
            case TurnStep():
                phase = _turn_phase(end, step, turn_rate)
            case _:
                phase = None
        if phase is not None:
            phases.append(phase)
    return phases, end.s_m


def _line_phase(
    end: _PathEnd, step: WalkStep, default_speed_mps: float, turn_rate: float
) -> Phase | None:
    """A straight walk to ``step.to``; None (and nothing moves) when already there."""
    p = end.p
    d = (step.to[0] - p[0], step.to[1] - p[1])
    dist = math.hypot(*d)
    if dist < 1e-9:
        return None
    v = step.speed_mps or default_speed_mps
    hp = math.atan2(d[1], d[0])
    phase = Phase(
        "line",
        end.t_s,
        dist / v,
        p,
        end.heading_rad,
        hp,
        v,
        end.s_m,
        turn_rate_radps=turn_rate,
        after_stand=not end.walking,
    )
    end.t_s, end.s_m, end.p = end.t_s + dist / v, end.s_m + dist, (step.to[0], step.to[1])
    end.heading_rad, end.walking = hp, True
    return phase


def _arc_phase(
    end: _PathEnd, step: ArcStep, default_speed_mps: float, turn_rate: float
) -> Phase | None:
    """A walk round ``step.centre`` by ``step.sweep_deg`` (positive: anticlockwise), ending
    tangent to the circle; None when the person stands on the centre or the sweep is 0."""
    p = end.p
    c = (float(step.centre[0]), float(step.centre[1]))
    r = math.hypot(p[0] - c[0], p[1] - c[1])
    sweep = math.radians(step.sweep_deg)
    if r < 1e-6 or abs(sweep) < 1e-12:
        return None
    v = step.speed_mps or default_speed_mps
    dist = r * abs(sweep)
    a0 = math.atan2(p[1] - c[1], p[0] - c[0])
    sign = 1.0 if sweep > 0 else -1.0
    phase = Phase(
        "arc",
        end.t_s,
        dist / v,
        p,
        end.heading_rad,
        a0,
        v,
        end.s_m,
        c,
        r,
        sign,
        turn_rate,
        after_stand=not end.walking,
    )
    a1 = a0 + sweep
    end.t_s, end.s_m = end.t_s + dist / v, end.s_m + dist
    end.p = (c[0] + r * math.cos(a1), c[1] + r * math.sin(a1))
    end.heading_rad, end.walking = wrap_angle(a1 + sign * math.pi / 2), True
    return phase


def _pause_phase(end: _PathEnd, step: PauseStep, turn_rate: float) -> Phase:
    """Standing still for ``step.duration_s``, heading kept."""
    phase = Phase(
        "stand",
        end.t_s,
        step.duration_s,
        end.p,
        end.heading_rad,
        end.heading_rad,
        s0_m=end.s_m,
        after_walk=end.walking,
        turn_rate_radps=turn_rate,
    )
    end.t_s, end.walking = end.t_s + step.duration_s, False
    return phase


def _turn_phase(end: _PathEnd, step: TurnStep, turn_rate: float) -> Phase:
    """Turning on the spot to ``step.heading_deg`` the short way round, at the turn rate."""
    goal = math.radians(step.heading_deg)
    dur = abs(wrap_angle(goal - end.heading_rad)) / turn_rate
    phase = Phase(
        "stand",
        end.t_s,
        dur,
        end.p,
        end.heading_rad,
        goal,
        s0_m=end.s_m,
        after_walk=end.walking,
        turn_rate_radps=turn_rate,
    )
    end.t_s, end.heading_rad, end.walking = end.t_s + dur, wrap_angle(goal), False
    return phase


@dataclass(frozen=True, slots=True)
class PersonState:
    """Where a person and their legs are at one instant (world frame)."""

    position: np.ndarray
    """(2,) body centre, m."""
    velocity: np.ndarray
    """(2,) m/s."""
    heading_rad: float
    legs: np.ndarray
    """(2, 2) leg centres at laser height, rows = legs."""


class Person:
    """A scripted person with a gait; :meth:`state` is a pure function of time."""

    def __init__(self, spec: PersonSpec) -> None:
        self.spec = spec
        self.id = spec.id
        self.is_target = spec.is_target
        self.leg_radius_m = spec.gait.leg_radius_m
        self.phases, self.path_length_m = compile_path(spec)
        self.duration_s = self.phases[-1].t1 if self.phases else 0.0
        if not (spec.loop and self.duration_s > 0):
            # after the script (or with none) the person stands where it ended, for ever
            end = self.state_at_end()
            self.phases.append(
                Phase(
                    "stand",
                    self.duration_s,
                    math.inf,
                    end[0],
                    end[1],
                    end[1],
                    s0_m=self.path_length_m,
                    after_walk=bool(self.phases) and self.phases[-1].kind != "stand",
                )
            )
        g = spec.gait
        self._step_m = g.step_length_m
        self._hip_m = g.hip_width_m
        if g.stance == "together":
            gap = 2.0 * g.leg_radius_m + 0.02  # thesis 4.3 criterion: a leg pair < 500 mm apart
            self._stand = np.array([[0.0, gap / 2], [0.0, -gap / 2]])
        else:
            self._stand = np.array([[0.06, 0.15], [-0.06, -0.15]])

    # ------------------------------------------------------------------ path

    def state_at_end(self) -> tuple[tuple[float, float], float]:
        """Position and heading where the compiled script ends."""
        if not self.phases:
            return (float(self.spec.start[0]), float(self.spec.start[1])), math.radians(
                self.spec.heading_deg
            )
        last = self.phases[-1]
        if last.kind == "line":
            c, sn = math.cos(last.path_heading_rad), math.sin(last.path_heading_rad)
            d = last.speed_mps * last.duration_s
            return (last.p0[0] + d * c, last.p0[1] + d * sn), last.path_heading_rad
        if last.kind == "arc":
            a = last.path_heading_rad + last.sign * last.speed_mps * last.duration_s / last.radius_m
            p = (
                last.centre[0] + last.radius_m * math.cos(a),
                last.centre[1] + last.radius_m * math.sin(a),
            )
            return p, wrap_angle(a + last.sign * math.pi / 2)
        return last.p0, last.path_heading_rad

    def _locate(self, t: float) -> tuple[Phase, float, float]:
        """Phase in force at t, the time into it, and the walked distance of earlier loops."""
        extra_s = 0.0
        if self.spec.loop and self.duration_s > 0 and t >= self.duration_s:
            n = math.floor(t / self.duration_s)
            t -= n * self.duration_s
            extra_s = n * self.path_length_m
        lo, hi = 0, len(self.phases) - 1
        while lo < hi:  # last phase with t0 <= t
            mid = (lo + hi + 1) // 2
            if self.phases[mid].t0 <= t:
                lo = mid
            else:
                hi = mid - 1
        ph = self.phases[lo]
        return ph, t - ph.t0, extra_s

    def state(self, t_s: float) -> PersonState:
        ph, tau, extra_s = self._locate(max(t_s, 0.0))
        if ph.kind == "line":
            u = np.array([math.cos(ph.path_heading_rad), math.sin(ph.path_heading_rad)])
            p = np.asarray(ph.p0) + ph.speed_mps * tau * u
            vel = ph.speed_mps * u
            hp = ph.path_heading_rad
            s = ph.s0_m + ph.speed_mps * tau
        elif ph.kind == "arc":
            a = ph.path_heading_rad + ph.sign * ph.speed_mps * tau / ph.radius_m
            radial = np.array([math.cos(a), math.sin(a)])
            tangent = ph.sign * np.array([-radial[1], radial[0]])
            p = np.asarray(ph.centre) + ph.radius_m * radial
            vel = ph.speed_mps * tangent
            hp = a + ph.sign * math.pi / 2
            s = ph.s0_m + ph.speed_mps * tau
        else:  # stand / turn on the spot
            p = np.asarray(ph.p0, dtype=float)
            vel = np.zeros(2)
            d = wrap_angle(ph.path_heading_rad - ph.heading0_rad)
            turned = min(abs(d), ph.turn_rate_radps * tau)
            h = wrap_angle(ph.heading0_rad + math.copysign(turned, d))
            sigma = min(1.0, tau / BLEND_S) if ph.after_walk else 1.0
            return PersonState(p, vel, h, self._legs(p, h, ph.s0_m + extra_s, sigma))
        # body heading swings from the previous heading to the path's at the turn rate
        d = wrap_angle(ph.heading0_rad - hp)
        left = max(0.0, abs(d) - ph.turn_rate_radps * tau)
        h = wrap_angle(hp + math.copysign(left, d))
        sigma = max(0.0, 1.0 - tau / BLEND_S) if ph.after_stand else 0.0
        return PersonState(p, vel, h, self._legs(p, h, s + extra_s, sigma))

    # ------------------------------------------------------------------ gait

    def _walk_offsets(self, s_m: float) -> np.ndarray:
        big_l = self._step_m
        u = (s_m / big_l) % 2.0
        xa = self._along(u, big_l)
        xb = self._along((u + 1.0) % 2.0, big_l)
        return np.array([[xa, self._hip_m / 2], [xb, -self._hip_m / 2]])

    @staticmethod
    def _along(u: float, big_l: float) -> float:
        if u < 1.0:  # stance: fixed on the floor
            return big_l / 2 - big_l * u
        return -big_l / 2 + big_l * (1.0 - math.cos(math.pi * (u - 1.0))) / 2  # swing

    def _legs(self, p: np.ndarray, h: float, s_m: float, sigma: float) -> np.ndarray:
        """Leg centres: gait offsets at walked distance s blended (sigma) into the stance pose.

        While standing s stays where walking stopped, so the legs blend from where they were.
        """
        off = (1.0 - sigma) * self._walk_offsets(s_m) + sigma * self._stand
        c, sn = math.cos(h), math.sin(h)
        rot = np.array([[c, -sn], [sn, c]])
        return p + off @ rot.T
