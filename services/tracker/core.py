"""The tracker: every person in the laser, one of them the target; ego-motion, late vision.

Pure logic on numpy arrays and messages, no Zenoh (the node is ``node.py``). DESIGN.md
"Particle filter" and "Timing model"; thesis 3.6, 4.5.

Ego-motion (thesis 3.6.2.3, corrected)
--------------------------------------
Odometry gives the robot's pose T = (t, theta) in the odometry frame. A point p0 in the base
frame at pose T0 is, in the base frame at pose T1,

    p1 = T1^-1 T0 p0 = R(theta0 - theta1) p0 + R(-theta1) (t0 - t1)        (:func:`se2_change`)

Eq. 3-31 as printed subtracts the odometry translation t1 - t0 without rotating it into the new
base frame (:func:`thesis_printed_transform`, kept for the test that shows the difference).
The pose at a scan's stamp is interpolated between the odometry messages around it (linear in
x, y, shortest-way in yaw), or extrapolated a little with the last twist
(:class:`OdometryBuffer`). Without odometry for a scan the step goes on uncompensated and the
status carries the flag ``no_odometry``.

One step per candidates message (:meth:`Tracker.step`)
------------------------------------------------------
1. ego-motion of every track from the previous scan's frame to this one;
2. predict every track by the time between the scans;
3. apply the verifications that are due (below) -- they settle *which* track is the target;
4. associate candidates with tracks: distances from each estimator, gated, then the assignment
   of greatest total (widest gate - distance) (Hungarian, ``scipy.optimize.linear_sum_assignment``;
   ``assignment: most_matches``: least total distance among those with the most pairs);
5. update the matched tracks; count a miss on the others; start a track on every unmatched
   candidate; delete a track after more than ``max_misses`` consecutive misses (thesis: 8, about
   1 s) or when its estimator says so (the UKF's variance rule);
6. record which track took which candidate of this scan (the history late vision needs);
7. report the target (``TrackState``) and every confirmed person (``People``).

Target status: ``initialising`` (no target yet), ``tracking`` (the target took a candidate
this scan), ``coasting`` (1..max_misses misses: the estimate is a prediction), ``lost`` (more
than max_misses misses: the robot stops; the target's track is deleted and a new one is taken
only by appearance, or -- without vision -- near where it was lost).

Late vision (DESIGN.md "Timing model")
--------------------------------------
A :class:`~followbot.schemas.Verification` names the scan stamp whose candidates it judged.
The tracker keeps, for the last ``history_scans`` scans, which track took each candidate and
the odometry pose at the scan, so a verification is applied to the state *as of that scan*:
the chosen candidate's track (or, if that track is gone, the track nearest to the chosen
position carried to the current frame by odometry) becomes the target when there is none, and
replaces the current target after ``switch_votes`` consecutive verifications that prefer it.
In lock-step runs ``vision_lag_scans = N`` holds the verification of scan k until the step of
scan k + N (at least the next step: the tracker never waits for vision).

Negative evidence rolls the target back (beyond the thesis). When a verification says the
candidate the target took at scan k is *not* the target (appearance distance above the
verifier's threshold) -- typically another person walking between the robot and the target,
or a leg of a passer-by paired with one of the target's -- the target's updates since scan k
followed someone else. The tracker keeps, for each scan, a snapshot of the target's estimator
after the prediction and before the update; on such a verification (``rollback: true``) it
(1) turns the current estimator, which now follows the other person, into a new track of its
own, and (2) gives the target the snapshot of scan k carried to now by odometry and the
motion model, as a coasting track. The two then compete for the next candidates in the
assignment, so the target no longer jumps onto the person who hid it. ``reject_votes``
consecutive rejections still drop the target.
"""

from __future__ import annotations

import bisect
import copy
import math
import statistics
from collections import OrderedDict, deque
from typing import Annotated, Any, ClassVar, Literal

import msgspec
import numpy as np
from scipy.optimize import linear_sum_assignment

from followbot.geometry import Pose, se2_change, transform_points
from followbot.geometry import rotation as _rot
from followbot.schemas import (
    Horizon,
    Odometry,
    People,
    PersonCandidates,
    PersonTrack,
    TargetModel,
    TrackState,
    Verification,
)
from followbot.services.runtime.settings import removed

from .estimators import Estimator, estimator_factory, wrap_angle

__all__ = [
    "OdometryBuffer",
    "Pose",
    "Track",
    "Tracker",
    "TrackerSettings",
    "se2_change",
    "thesis_printed_transform",
    "transform_points",
]

_NS = 1_000_000_000
_NO_VISION = ("no_vision", "vision_stale")


# --------------------------------------------------------------------------- ego-motion


_I2 = np.eye(2)


def hidden_from_laser(
    points: np.ndarray, horizon: Horizon, margin_m: float, radius_m: float, samples: int = 5
) -> np.ndarray:
    """True for each point of ``points`` (k, 2; the scan's frame) that the laser could not have
    seen in the scan whose ``horizon`` this is: of ``samples`` bearings spread over the point's
    width (``radius_m`` either side), at least half lie outside the horizon's bins or have a
    return nearer than the point's range minus ``margin_m``. A non-finite point: False."""
    r = horizon.ranges.numpy()
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    rho = np.hypot(pts[:, 0], pts[:, 1])
    finite = np.isfinite(rho)
    rho = np.where(finite, rho, 1.0)
    phi = np.where(finite, np.arctan2(pts[:, 1], pts[:, 0]), 0.0)
    half = np.arctan2(radius_m, rho)  # up to 90 deg for a point at the laser
    bearings = phi[:, None] + half[:, None] * np.linspace(-1.0, 1.0, samples)[None, :]
    u = np.mod(bearings - horizon.angle_min_rad, 2.0 * math.pi) / horizon.increment_rad
    k = np.floor(u).astype(np.intp)
    inside = k < r.shape[0]
    limit = np.broadcast_to(rho[:, None] - margin_m, k.shape)
    covered = np.zeros(k.shape, dtype=bool)
    covered[inside] = r[k[inside]] < limit[inside]  # NaN bins: not covered
    return finite & (np.count_nonzero(~inside | covered, axis=1) * 2 >= samples)


def occluder_edge(
    point: np.ndarray,
    velocity: np.ndarray,
    horizon: Horizon,
    margin_m: float,
    radius_m: float,
    min_speed_mps: float = 0.05,
) -> np.ndarray | None:
    """Where a person hidden at ``point`` (the scan's frame), walking at ``velocity``, should come
    out: past the edge of what hides them, on the side they walk towards; None when the point is
    not hidden (:func:`hidden_from_laser`, same ``margin_m`` and ``radius_m``), the cover reaches
    beyond the horizon's bins (no edge seen), or the point is not finite.

    The horizon's bins are walked from the point's bearing in the direction its bearing changes
    (the sign of ``point x velocity``; both ways, the nearer edge, when the speed across the
    line of sight is below ``min_speed_mps``) to the first bin whose return is not nearer than
    the point's range minus ``margin_m``. The answer lies at the point's range, at that bin's
    near boundary turned a further ``atan(radius_m / range)`` (a person's centre just clear of
    the edge). A full-circle horizon wraps round."""
    p = np.asarray(point, dtype=float).reshape(2)
    rho = float(np.hypot(p[0], p[1]))
    if not (math.isfinite(rho) and rho > 1e-6):
        return None
    if not hidden_from_laser(p[None], horizon, margin_m, radius_m)[0]:
        return None
    r = horizon.ranges.numpy()
    n, inc, a0 = r.shape[0], horizon.increment_rad, horizon.angle_min_rad
    full = n * inc >= 2.0 * math.pi - 1e-6
    phi = math.atan2(p[1], p[0])
    b0 = math.floor(((phi - a0) % (2.0 * math.pi)) / inc)
    if b0 >= n:
        return None  # outside the laser's view: nothing tells where the cover ends
    v = np.asarray(velocity, dtype=float).reshape(2)
    across = float(p[0] * v[1] - p[1] * v[0]) / rho  # speed across the line of sight
    ways = [1 if across > 0 else -1] if abs(across) >= min_speed_mps else [1, -1]
    limit = rho - margin_m
    best: tuple[int, int] | None = None  # (bins walked, direction)
    for d in ways:
        for k in range(n):
            b = b0 + d * k
            if full:
                b %= n
            elif not 0 <= b < n:
                break  # the cover runs out of the view
            if not r[b] < limit:  # (NaN: not covered, as in hidden_from_laser)
                if best is None or k < best[0]:
                    best = (k, d)
                break
    if best is None:
        return None
    k, d = best
    edge = a0 + (b0 + d * k + (0 if d > 0 else 1)) * inc
    bearing = edge + d * math.atan2(radius_m, rho)
    return np.array([rho * math.cos(bearing), rho * math.sin(bearing)])


def thesis_printed_transform(points: np.ndarray, pose0: Pose, pose1: Pose) -> np.ndarray:
    """Eq. 3-31 exactly as printed (thesis p. 3.6.2.3), for comparison only: wrong whenever the
    robot both turns and moves, because the translation is not rotated into the new frame.

        d0 = |p0|, theta0 = atan2(y0, x0), theta_r = theta_r1 - theta_r0
        x1 = d0 cos(theta0 + theta_r) - (x_r1 - x_r0)
        y1 = d0 sin(theta0 + theta_r) - (y_r1 - y_r0)
    """
    p = np.asarray(points, dtype=float)
    d0 = np.hypot(p[:, 0], p[:, 1])
    a0 = np.arctan2(p[:, 1], p[:, 0])
    th_r = pose1[2] - pose0[2]
    return np.column_stack(
        [
            d0 * np.cos(a0 + th_r) - (pose1[0] - pose0[0]),
            d0 * np.sin(a0 + th_r) - (pose1[1] - pose0[1]),
        ]
    )


class OdometryBuffer:
    """Odometry poses by stamp; the pose at any stamp in range, interpolated.

    Out-of-order messages are inserted in order; the oldest are forgotten beyond ``capacity``.
    A stamp after the newest message is extrapolated along the last twist (an arc) for at most
    ``max_extrapolation_ns``; a stamp before the oldest has no pose.
    """

    def __init__(self, capacity: int = 4096, max_extrapolation_ns: int = 100_000_000) -> None:
        self.capacity = capacity
        self.max_extrapolation_ns = max_extrapolation_ns
        self._stamps: list[int] = []
        self._poses: list[tuple[float, float, float, float, float]] = []

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, odom: Odometry) -> None:
        item = (odom.x_m, odom.y_m, odom.yaw_rad, odom.v_mps, odom.w_radps)
        stamps = self._stamps
        if not stamps or odom.stamp_ns > stamps[-1]:
            stamps.append(odom.stamp_ns)
            self._poses.append(item)
        else:
            i = bisect.bisect_left(stamps, odom.stamp_ns)
            if i < len(stamps) and stamps[i] == odom.stamp_ns:
                self._poses[i] = item
            else:
                stamps.insert(i, odom.stamp_ns)
                self._poses.insert(i, item)
        if len(stamps) > self.capacity:
            drop = len(stamps) - self.capacity // 2
            del stamps[:drop]
            del self._poses[:drop]

    def pose_at(self, stamp_ns: int) -> Pose | None:
        stamps = self._stamps
        if not stamps or stamp_ns < stamps[0]:
            return None
        if stamp_ns >= stamps[-1]:
            dt_ns = stamp_ns - stamps[-1]
            if dt_ns > self.max_extrapolation_ns:
                return None
            x, y, th, v, w = self._poses[-1]
            dt = dt_ns / _NS
            if abs(w) > 1e-9:
                x += v / w * (math.sin(th + w * dt) - math.sin(th))
                y -= v / w * (math.cos(th + w * dt) - math.cos(th))
            else:
                x += v * dt * math.cos(th)
                y += v * dt * math.sin(th)
            return (x, y, th + w * dt)
        i = bisect.bisect_right(stamps, stamp_ns)  # stamps[i-1] <= stamp < stamps[i]
        s0, s1 = stamps[i - 1], stamps[i]
        p0, p1 = self._poses[i - 1], self._poses[i]
        f = (stamp_ns - s0) / (s1 - s0)
        dth = float(wrap_angle(p1[2] - p0[2]))
        return (p0[0] + f * (p1[0] - p0[0]), p0[1] + f * (p1[1] - p0[1]), p0[2] + f * dth)


# --------------------------------------------------------------------------- settings, tracks


_LOG = "docs/tracker_log.md"

#: Settings that are gone: experiments measured and left off (their record: docs/tracker_log.md).
RETIRED_SETTINGS: dict[str, str] = {
    "occlusion_max_s": removed(f"keeping a hidden target past max_misses, measured in {_LOG}"),
    "occlusion_look": removed("it only applied with occlusion_max_s, also removed"),
    "front_approach_factor": removed(f"an experiment measured and left off, see {_LOG}"),
    "lone_leg_offset_m": removed(
        f"measured and left off; lone_leg_output_m moves the report, {_LOG}"
    ),
    "lone_leg_clear_m": removed("it only applied with lone_leg_offset_m, also removed"),
    "look_near_walkers": removed(f"an experiment measured and left off, see {_LOG}"),
    "look_out_of_view_deg": removed(f"an experiment measured and left off, see {_LOG}"),
    "look_far_walking_m": removed(f"an experiment measured and left off, see {_LOG}"),
    "look_confirm_hits": removed(f"the camera turns to a track once confirm_hits, see {_LOG}"),
    "switch_needs_target_seen": removed(f"an experiment measured and left off, see {_LOG}"),
}


class TrackerSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    retired_settings: ClassVar[dict[str, str]] = RETIRED_SETTINGS

    estimator: str = "particle"
    """Estimator plugin (entry-point group followbot.estimators): particle, ukf, ..."""
    estimator_settings: dict[str, Any] = {}
    """Overrides of the estimator's own settings, e.g. {particles: 500, resampler: sorted_copy}."""
    seed: int = 0
    """Seed of every random draw (each track's Generator is seeded with [seed, track id])."""
    # thesis 3.6.2.8 / DESIGN.md: lost after more than 8 consecutive misses (~1 s at 120 ms)
    max_misses: Annotated[int, msgspec.Meta(ge=0, le=10_000)] = 8
    occlusion_margin_m: Annotated[float, msgspec.Meta(ge=0)] = 0.3
    """A return counts as hiding a track when it is this much nearer than the track's predicted
    range (a person's legs lie ~0.1 m either side of their centre)."""
    occlusion_radius_m: Annotated[float, msgspec.Meta(gt=0)] = 0.2
    """Half-width of a person as the laser sees them: the bearings checked round the
    prediction. The track is hidden when at least half of them are covered or out of view."""
    confirm_hits: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 2
    """A new track is reported in tracking/people once it took this many candidates."""
    acquire: Literal["vision", "nearest"] = "vision"
    """How the first target is chosen: by vision (a verification or perception/target_model),
    or, without a camera, the nearest candidate ahead within acquire_range_m."""
    acquire_range_m: Annotated[float, msgspec.Meta(gt=0)] = 3.0
    acquire_bearing_deg: Annotated[float, msgspec.Meta(gt=0, le=180)] = 45.0
    model_match_m: Annotated[float, msgspec.Meta(gt=0)] = 0.5
    """A target model's position takes the nearest track within this distance, else a new one."""
    laser_reacquire_m: Annotated[float, msgspec.Meta(ge=0)] = 0.7
    """Without vision only: a lost target is re-taken by the track nearest to where it was lost,
    within this distance (0: never without vision)."""
    laser_reacquire_min_speed_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.25
    """... and only a track walking at least this fast (its recent velocity): clutter where
    the target vanished stays put (0: any track). Beyond the thesis; 76 closed-loop runs
    (docs/tracker_log.md): the cluttered office's 1.2 s on wrong people went to 0."""
    laser_reacquire_min_range_m: Annotated[float, msgspec.Meta(ge=0)] = 0.3
    """... and only a track at least this far from the laser: nearer, it is the robot's own
    body or something it drove up to, not a person (a person's centre lies a leg's radius
    plus the robot's half-width away at the least). Ninth session: with occlusion_max_s the
    robot coasted up to the pillar that hid the target and took its edge, 0.12 m away, for
    the target (occlusion_pillar)."""
    laser_reacquire_max_s: Annotated[float, msgspec.Meta(ge=0)] | None = 3.0
    """... and only this long after the loss (None: any time). Beyond the thesis: a walker is
    0.7 m on in under 3 s; later, whoever passes where the target was lost is someone else.
    76 closed-loop runs (docs/tracker_log.md): time on wrong people 16.2 -> 8.4 s (crowd_ten
    14.2 -> 6.4 s)."""
    switch_votes: Annotated[int, msgspec.Meta(ge=1, le=100)] = 2
    """Consecutive verifications preferring another track before the target moves to it."""
    reacquire_max_distance: Annotated[float, msgspec.Meta(ge=0)] | None = None
    """A lost target is re-taken by appearance only when vision's distance is at most this
    (None: the verifier's own threshold). In the simulator 94 % of the target's judgements lie
    at or below 0.7 and 17 % of the bystanders' (at 0.8: 98 % and 49 %)."""
    reject_votes: Annotated[int, msgspec.Meta(ge=0, le=100)] = 2
    """Drop the target after this many consecutive verifications that saw its candidate and
    rejected it (appearance distance above the verifier's threshold): the robot stops rather
    than follow someone vision says is not the target (0: never). Beyond the thesis, which
    always takes the nearest match."""
    reject_min_range_m: Annotated[float, msgspec.Meta(ge=0)] = 0.7
    """Beyond the thesis: a rejection of the target's candidate nearer than this to the robot
    counts for nothing (neither rollback nor reject_votes) while near_guard_m holds; an
    acceptance still counts. So near, the camera sees too little of a person to say it is
    someone else: a target 0.5 m away shows a third of its body, was judged 0.80-0.85 against
    0.8 and dropped, then lost for 8-16 s (ristic_circles). 0: every rejection counts."""
    reject_hysteresis: Annotated[float, msgspec.Meta(ge=0)] = 0.1
    """Beyond the thesis: while the target is surely the one vision last accepted (as for
    near_guard_m), a rejection of its candidate counts only when the distance exceeds the
    threshold by more than this: a target judged around the threshold (door_corner seed 3:
    0.74-0.86 against 0.8, scan after scan) is not dropped on every second look. Default
    since the fifteenth session: of 76 runs 8 change, none of the sweep's counts (door_corner
    seed 3 tracked 0.54 -> 0.75; RMSE lower in 6 of the other 7; docs/tracker_log.md). 0: off."""
    near_guard_m: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """... only while the target is surely the one vision last accepted: its track took a
    candidate on every scan since, and no other track came within this distance of it. A
    target that was hidden, or passed someone (or something) on the way, is judged as usual.
    0: near rejections never count, whatever happened (in the cluttered office the robot then
    followed clutter near it and once a bystander). 76 closed-loop runs (docs/tracker_log.md):
    ristic_circles tracked 1.00 of the visible time in all 8 seeds (0.97 without), RMSE 0.084
    m (0.095)."""
    front_margin_m: Annotated[float, msgspec.Meta(gt=0)] | None = 0.2
    """Beyond the thesis: the target does not take a candidate this much nearer to the laser
    than its prediction and on its bearing (within occlusion_radius_m of it) when another
    track's gate holds it too: that is someone passing in front, who hides it
    (thesis_5_2_4_side_by_side: the bystander crossed 0.27 m in front and the target took
    them). Alone, such a candidate is taken (the target walking towards the robot, ahead of
    its lagging estimate) unless front_approach_factor says otherwise. None: off."""
    assignment: Literal["most_matches", "weighted"] = "weighted"
    """How the gated distances become an assignment. ``most_matches`` (before the fourteenth
    session): as many track-candidate pairs as the gates allow, and among those the least
    total distance (every gated-out pair priced above any total). That can take a track's best
    candidate away to let another track match at all: in crowd_ten (own seed, 36.48 s) the
    target gave its own lone leg (0.11 m away) to a track 8 misses old (0.59 m, gate 0.74 m)
    and took a cross pair of its far leg and a passer-by's (0.39 m) -- and followed the
    passer-by. ``weighted``: the assignment of
    greatest total weight, a gated pair weighing (G - distance) with G the widest gate of the
    scan's tracks: a track left unmatched costs G, so a second match is made only when it
    adds less than G to the total distance (there: 0.11 + a miss against 0.39 + 0.59, G =
    0.74). One G for all: weighing by each track's own gate (tried) made coasting tracks,
    whose gates grow, win candidates from nearer tracks (76 runs: 37 s on wrong people).
    Default since the fourteenth session: of 76 closed-loop runs only crowd_ten's own seed
    changes (RMSE 0.384 -> 0.077 m, 5.4 -> 0 s on the passer-by; docs/tracker_log.md). Beyond the
    thesis, whose nearest neighbour takes one person."""
    split_pair_m: Annotated[float, msgspec.Meta(ge=0)] = 0.4
    """A two-leg candidate whose legs are farther apart than this may be one leg each of two
    people (the thesis pairs legs up to 500 mm apart; when one of the target's legs is hidden
    its other leg pairs with a passer-by's). When each leg lies in the gate of a different
    track the pair is split, one leg to each; otherwise a track may take either leg alone
    when that leg is nearer its prediction than the pair's centre. 0: always the centre. In
    the simulator a person's own legs were at most 0.36 m apart, such cross pairs 0.40-0.49."""
    one_leg_noise_scale: Annotated[float, msgspec.Meta(ge=1, le=100)] = 1.0
    """Beyond the thesis: a track updated with a lone leg (a one-leg candidate, or one leg of
    a split pair) scales its measurement noise by this. The thesis treats every candidate
    alike (1); a lone leg lies ~0.13 m from the person's centre on average in the simulator
    (two legs' middle: ~0.04 m), wherever the hidden leg happens to be in its stride."""
    lone_leg_output_m: Annotated[float, msgspec.Meta(ge=0, le=0.5)] = 0.1
    """Beyond the thesis: the target's *reported* position takes a leg seen alone for a person
    centred this far beyond it along its bearing (as lone_leg_offset_m), while the filter
    that associates candidates keeps the leg where it was measured. The filter's estimate
    after each update is carried forward together with a shift: what the estimate would be
    had every lone leg of its updates been moved out (the cloud weighed once more for the
    moved leg; each update keeps 1 - k of the earlier shift, k the share by which it moved
    the estimate). tracking/target and the target's entry in tracking/people report the
    estimate plus the shift (tracking/target also the shift itself, ``shift_x_m``/``_y_m``,
    so laser_legs gates criterion 3 at the estimate); association, gates, coasting and
    rollbacks use the estimate alone, so whom the target takes is the thesis's decision
    (lone_leg_offset_m moved the filter itself, and moved the target onto whoever walked
    behind it: docs/tracker_log.md).
    Particle estimator only (its cloud is what is weighed again; the others report their
    estimate); 0: off. Default 0.1 since the fifteenth session, with the controller following
    the estimate, not the report (controller ``follow_report``): the whole loop then runs
    as without it and only the report moves -- 76 runs (docs/tracker_log.md): RMSE <= 0.08 m on
    75 (69), e.g. bellotto_cluttered_office 0.088 -> 0.064 m, crowd_ten 0.078 -> 0.046 m,
    hidden_target_bystanders 0.053 -> 0.061 m the one scenario worse. (In the thirteenth
    session, with the robot following the report, its changed paths lost targets.)"""
    rollback: bool = True
    """Roll the target back to its state before a candidate that vision rejected (module doc);
    false: only count the rejection towards reject_votes (the behaviour before this)."""
    rollback_max_s: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """Farthest back (scan time before the rejected scan) a rollback goes."""
    rollback_jump_m: Annotated[float, msgspec.Meta(ge=0)] = 0.15
    """... only when that candidate also lay this far or farther from the target's prediction
    (0.15 m: 1.25 m/s over one 120 ms scan). The target itself, seen where it was expected
    while its look changes (turning round, lighting), is not split off by a rejection."""
    coast_velocity_s: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """Beyond the thesis: a track that missed its candidate (hidden behind someone) moves on at
    the person's recent velocity (the median of its step velocities over this many seconds:
    one update pulled aside by a passer-by's leg does not turn it) instead of staying where it
    was last seen. Only for estimators whose own prediction has
    no velocity memory (the thesis's particle filter, whose velocities are redrawn around
    zero every step): there a hidden walker was left behind, and a robot following at walking
    speed saw the left-behind track drift towards itself and onto a passer-by
    (thesis_5_2_4_side_by_side). 0: off, as the thesis."""
    coast_max_speed_mps: Annotated[float, msgspec.Meta(gt=0)] = 2.5
    """The coasting velocity is clipped to this speed (a brisk walk)."""
    look_while_lost: bool = True
    """Beyond the thesis: while the target is lost (and vision alive), name in tracking/target
    a person for the camera to look at (``look_*``), so vision can judge them and re-acquire
    the target by appearance; the controller pans there, the base stays still. Moving tracks
    first, nearest to where the target was lost (with look_gate_m: to where it should be now)
    first; each in turn until vision has judged it (or look_dwell_s passed), those vision
    rejected look_rejections times are skipped. False: the thesis's camera stays where the
    target was lost. Default since the seventh session, with look_gate_m (docs/tracker_log.md):
    84 closed-loop runs, occlusion_pillar re-acquired in 0.0-1.56 s instead of ~21 s."""
    look_dwell_s: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    look_rejections: Annotated[int, msgspec.Meta(ge=1, le=100)] = 2
    look_min_range_m: Annotated[float, msgspec.Meta(ge=0)] = 0.3
    """Nearer than this the camera is not turned to a person (it would see too little of them
    to judge). 0.5 before the fifteenth session: in bellotto_cluttered_office the target comes
    back 0.45-0.5 m beside the stopped robot, and the camera waited until it was 0.5 m away
    before turning ~90 deg to it; with look_new_first, 0.3 re-takes it 0.1-1.4 s sooner (of 76
    runs only the office's change; docs/tracker_log.md). Also the nearest a newcomer may be to end
    the search for a hidden target's guess (occlusion_look)."""
    look_moving_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.25
    look_gate_m: Annotated[float, msgspec.Meta(gt=0)] | None = 0.5
    """Beyond the thesis, with look_while_lost: look only at tracks near where the lost target
    should be now -- within look_gate_m + look_gate_mps x (time since the loss) of its last
    position moved on at its coasting velocity (for at most look_predict_s) -- and re-take by
    appearance only such a track, for look_max_s after the loss; with no such track the
    camera looks at that predicted point. (A verification that drops the target by rejecting
    it and chooses another track is a switch: that track is taken wherever it is.) Then the
    camera looks at that point only, and vision may re-take anyone it accepts there (as with
    look_while_lost off, whose camera stays where the target was lost). None: look at every
    track in turn, for as long as the target is lost."""
    look_gate_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.5
    look_gate_since_seen: bool = True
    """Beyond the thesis (twelfth session): the gate grows with the time since the target was
    last *seen* (its last laser update), not since the loss was declared. The loss comes after
    the miss budget (8 scans, ~1 s at 8.3 Hz), and a hidden person walks on meanwhile: in
    occlusion_pillar (seed 6) the target came out 1.46 m from the gate's centre, 1.6 s after
    the loss but 2.6 s after it was last seen, and the camera turned to it only 0.84 s later,
    when the gate had grown that far. Vision re-takes someone in that outer ring (outside the
    radius grown since the loss) only on a close match, look_wide_max_distance, as it does
    far from where the target went. False: since the loss (the seventh session's gate)."""
    look_predict_s: Annotated[float, msgspec.Meta(ge=0)] = 2.0
    look_within_reach: bool = True
    """Beyond the thesis, with look_gate_m: where the lost target should be is kept within
    the detector's reach (perception/candidates ``reach_m``: laser_legs' clip_range_m, the
    thesis's 3.5 m, 4.3.1): a target who walked out of reach is looked for, and re-taken on
    an ordinary acceptance, where it would come back into it, not where it would be had it
    walked on for look_predict_s. In ristic_wall_corridor (seed 1) the target walked on into
    the dead-end corridor past 3.5 m and came back 13 s later, accepted by vision at
    0.65-0.74 from 3.3 m on, but 1.9 m from the point 4.9 m away, so re-taken only 5 s later
    on a close match (look_wide_max_distance). Default since the twentieth session: of 76
    runs only that one changes (tracked 0.75 -> 0.85, docs/tracker_log.md). Candidates without a
    reach (recordings from before it, other publishers): as False, the point walks on."""
    look_max_s: Annotated[float, msgspec.Meta(ge=0)] = 4.0
    look_wide_max_distance: Annotated[float, msgspec.Meta(ge=0)] | None = 0.45
    """Beyond the thesis, with look_gate_m: past look_max_s the camera also looks, in turn,
    at each newcomer -- a person first tracked after the loss -- farther than
    look_wide_gate_m from where the target should be, with a dwell on that point between
    rounds, and vision re-takes someone that far away only on a close match: distance at
    most this. Nearer, as before (the camera looks at the point, anyone vision accepts is
    taken). For a target that comes back somewhere else than where it went out of view,
    e.g. round a shelf and past the stopped robot (bellotto_cluttered_office), which the
    look at one point never sees. None: off. 0.45: below every bystander's distance in 30
    closed-loop runs (15 scenarios, own seed and seed 1, the camera looking at everyone while
    lost: lowest 0.468; 54 % of the target's judgements lie at or below it). Default since
    the tenth session (docs/tracker_log.md: of 76 runs only the cluttered office's change)."""
    look_wide_gate_m: Annotated[float, msgspec.Meta(gt=0)] = 1.5
    """Set from two re-appearances looked at before the runs: in ristic_wall_corridor the
    target came back 0.6 m from where it should be (16 s after the loss), in
    bellotto_cluttered_office 2.2 m away, beside the robot."""
    look_keep_misses: Annotated[int, msgspec.Meta(ge=0, le=100)] = 2
    """Beyond the thesis, with look_while_lost: the camera keeps looking at the person it
    turned to while their track has missed at most this many scans in a row (within
    look_dwell_s). 0 (before the fifteenth session): a single missed scan sent it to the next
    person or the point, and a track that flickers (someone half hidden among the shelves)
    made the camera swing 10 deg to and fro without reaching anyone (docs/tracker_log.md)."""
    look_turn_deg_s: Annotated[float, msgspec.Meta(gt=0)] | None = 90.0
    """Beyond the thesis, with look_while_lost: the camera's pan rate (90 deg/s, thesis
    5.2.5). The look_dwell_s on a person runs from when a camera turning at this rate from
    where it was last sent can point at them, not from when it is sent: in the cluttered
    office (with the robot kept off the shelf) the camera, sent 178 deg round to the target
    coming back past the robot, was sent on to someone else after 1 s, still 60 deg short of
    her (seventeenth session; default since then, docs/tracker_log.md). None: from when it is
    sent."""
    look_new_first: bool = True
    """Beyond the thesis, with look_wide_max_distance: a newcomer not yet looked at since the
    loss ends the camera's dwell on where the target should be at once (the dwell is
    between rounds of looking again at the same people). Default since the fifteenth session
    (with look_min_range_m 0.3, docs/tracker_log.md): in bellotto_cluttered_office the target
    came back during a dwell and waited up to 1 s for the camera. False: the dwell runs out."""
    look_occluder_edge: bool = True
    """Beyond the thesis, with look_gate_m: when nobody is there to look at and the point where
    the lost target should be is hidden from the laser (something nearer covers it in the
    scan's horizon), the camera looks past the edge of that cover on the side the target was
    walking towards, where it will come out (:func:`occluder_edge`), not at the hidden point
    itself. The gate, and whom vision may re-take, do not change. Default since the
    fourteenth session (docs/tracker_log.md): in occlusion_pillar the target goes round the pillar
    while its straight-line prediction stays behind it, and the camera had to turn ~55 deg
    (0.6 s at 90 deg/s) once the laser found it; over 76 runs tracked >= 98 % on 61 (57),
    re-acquired within 1 s 31 of 55 occlusions (28 of 54), nothing else worse than one
    re-acquisition in the cluttered office 0.24 s later. False: the hidden point."""
    vision_lag_scans: Annotated[int, msgspec.Meta(ge=0, le=1000)] = 0
    """Lock-step: apply the verification of scan k at the step of scan k + N (>= k + 1)."""
    vision_stale_s: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    """No verification that judged a candidate newer than this (scan clock) -> flag
    vision_stale, gate on laser alone (and re-acquire a lost target near where it was lost)."""
    history_scans: Annotated[int, msgspec.Meta(ge=1, le=100_000)] = 64
    max_odometry_extrapolation_s: Annotated[float, msgspec.Meta(ge=0)] = 0.1
    default_dt_s: Annotated[float, msgspec.Meta(gt=0)] = 0.12
    """Time step of the first scan (thesis 4.1.1: 120 ms)."""
    max_dt_s: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    """Longer gaps between scans are clamped (a paused recording must not explode the cloud)."""

    def __post_init__(self) -> None:
        # checked while the settings load, so an unknown estimator or a bad estimator setting
        # fails before any network is opened (exit code 2, the message naming it)
        try:
            estimator_factory(self.estimator, self.estimator_settings)
        except LookupError as exc:  # plugins.UnknownPlugin
            raise ValueError(str(exc).strip("'\"")) from None


class Track:
    """One tracked person: an estimator plus the bookkeeping of the tracker."""

    __slots__ = (
        "anchor",
        "born_ns",
        "estimator",
        "hits",
        "id",
        "last_seen_ns",
        "misses",
        "shift",
        "steps",
    )

    def __init__(self, track_id: int, estimator: Estimator, stamp_ns: int) -> None:
        self.id = track_id
        self.estimator = estimator
        self.misses = 0
        self.hits = 1
        self.born_ns = stamp_ns
        self.last_seen_ns = stamp_ns
        self.anchor: tuple[float, float] | None = None
        """Position after the last update, in the odometry frame (for coasting)."""
        self.steps: deque[tuple[int, float, float]] = deque()
        """(stamp, vx, vy): velocity between two updates, odometry frame, recent updates."""
        self.shift = np.zeros(2)
        """Added to the estimate in what the tracker reports (lone_leg_output_m), base frame."""

    @property
    def reported(self) -> np.ndarray:
        """(2,) the position the tracker reports: the estimate plus its lone-leg shift."""
        return self.estimator.mean[:2] + self.shift

    @property
    def position(self) -> np.ndarray:
        return self.estimator.mean[:2]


class _Scan(msgspec.Struct):
    index: int
    pose: Pose | None
    assoc: dict[int, int]  # candidate index -> track id
    # the target's id and estimator after this scan's prediction, before its update
    target_prior: tuple[int, Any] | None = None


class _Rest(msgspec.Struct):
    """What :meth:`Tracker.step_rest` finishes of the scan :meth:`Tracker.step_target` began."""

    stamp: int
    frame_id: str
    scan: _Scan | None  # None: an out-of-order scan, which changes nothing
    learn: list[tuple[Track, int]]
    pose: Pose | None = None


# --------------------------------------------------------------------------- the tracker


class Tracker:
    """All people in the laser, one of them the target. Not thread-safe: one loop drives it."""

    def __init__(self, settings: TrackerSettings | None = None) -> None:
        self.settings = s = settings or TrackerSettings()
        self._make = estimator_factory(s.estimator, s.estimator_settings)
        # optional batch steps of the estimator class (ParticleEstimator.motion_all, ...)
        self._cls = self._make.estimator_class
        self.estimator_name = s.estimator
        self.odometry = OdometryBuffer(
            max_extrapolation_ns=int(s.max_odometry_extrapolation_s * _NS)
        )
        self.tracks: dict[int, Track] = {}
        self.target_id = -1
        self._next_id = 1
        self._had_target = False
        self._lost_at: np.ndarray | None = None  # last target position, carried by ego-motion
        self._lost_ns = 0  # scan stamp at which the target was lost
        self._lost_seen_ns = 0  # ... and at which it was last seen before that
        self._lost_v = np.zeros(2)  # its coasting velocity then, carried by ego-motion
        self._horizon: Horizon | None = None  # the last scan's (look_occluder_edge)
        self._reach: float | None = None  # the last scan's detector reach (look_within_reach)
        self._last_stamp: int | None = None
        self._last_pose: Pose | None = None
        self._index = 0
        self._history: OrderedDict[int, _Scan] = OrderedDict()
        self._pending: list[Verification] = []
        self._model: TargetModel | None = None
        self._switch: tuple[int, int] = (-1, 0)  # (track preferred by vision, consecutive votes)
        self._rejects = 0  # consecutive verifications that rejected the target's candidate
        self.target_rejections = 0  # targets dropped because vision rejected them
        self._vision_stamp: int | None = None
        self._vision_sources = False
        self.vision_alive = False
        # counters for health and tests
        self.verifications_applied = 0
        self.verifications_unmatched = 0
        self.target_switches = 0
        self.rollbacks = 0  # target tracks split by a rejecting verification
        self.rejections_near = 0  # rejections not counted: the candidate too near the camera
        self._confirmed_index = -1  # last scan whose verification accepted the target's candidate
        # scans at which the target missed or had another track within near_guard_m
        self._breaks: deque[int] = deque()
        # look_while_lost: (track looked at, since when), tracks judged since the loss
        self._look: tuple[int, int] = (-1, 0)
        self._look_rejected: dict[int, int] = {}
        self._look_done: set[int] = set()  # looked at for look_dwell_s without a judgement
        self._looked: set[int] = set()  # looked at since the loss (look_new_first)
        self._look_bearing: float | None = None  # look_turn_deg_s: where the camera was sent
        self._now: tuple[int, Pose | None] = (0, None)
        self.steps_without_odometry = 0
        self._rest: _Rest | None = None  # what step_rest still has to do

    # ------------------------------------------------------------------ inputs

    def add_odometry(self, odom: Odometry) -> None:
        self.odometry.add(odom)

    def add_verification(self, verification: Verification) -> None:
        """Queue a verification; it is applied at a later :meth:`step` (never waits for it)."""
        self._pending.append(verification)

    def set_target_model(self, model: TargetModel) -> None:
        """A (re)built target model: its laser position is where the target is (thesis 4.5)."""
        self._model = model

    def set_vision_alive(self, alive: bool) -> None:
        self.vision_alive = alive

    def reset(self) -> None:
        """Forget every track and the target (thesis: re-initialise)."""
        self.tracks.clear()
        self._rest = None
        self.target_id = -1
        self._had_target = False
        self._lost_at = None
        self._switch = (-1, 0)
        self._breaks.clear()
        self._forget_looks()

    def restart_clock(self) -> None:
        """The candidates' source restarted with a new clock: start afresh (every track, the
        target and the history go; whether vision is there stays)."""
        alive = self.vision_alive
        self.__init__(self.settings)
        self.vision_alive = alive

    def restart_odometry(self) -> None:
        """The odometry's source restarted with a new clock: forget its history."""
        self.odometry = OdometryBuffer(
            max_extrapolation_ns=int(self.settings.max_odometry_extrapolation_s * _NS)
        )

    def lose_target_stale(self, frame_id: str) -> TrackState | None:
        """No scan has moved the clock forward for too long (the node judges it on its wall
        clock): the target is declared lost, and the state saying so is returned (None when
        there is no target). Its last position stays the place to look for it again."""
        if self.target_id < 0:
            return None
        self._lose_target(self.tracks[self.target_id])
        return self._target_output(self._last_stamp or 0, frame_id, ["stale_input"], [])

    # ------------------------------------------------------------------ the step

    def step(self, candidates: PersonCandidates) -> tuple[TrackState, People]:
        """One scan: ego-motion, predict, late vision, associate, update; the two outputs.
        (:meth:`step_target` then :meth:`step_rest`.)"""
        target = self.step_target(candidates)
        return target, self.step_rest()

    def step_target(self, candidates: PersonCandidates) -> TrackState:
        """The part of a scan's step the target's estimate needs; :meth:`step_rest` must
        follow (before the next scan; :meth:`step_target` calls it itself if not).

        A node publishes the target between the two, so the controller's input leaves before
        the bookkeeping: resampling the clouds, the tracks' velocity history, the history
        late verifications consult, and the People message. The numbers are the same as
        doing it all at once."""
        if self._rest is not None:
            self.step_rest()
        s = self.settings
        stamp = candidates.stamp_ns
        flags: list[str] = []
        sources: list[str] = []
        if self._last_stamp is not None and stamp <= self._last_stamp:
            # a repeated or older scan: the state cannot go back; answer without changing it
            self._rest = _Rest(stamp, candidates.frame_id, None, [], None)
            return self._target_output(stamp, candidates.frame_id, ["out_of_order"], [])
        dt = s.default_dt_s if self._last_stamp is None else (stamp - self._last_stamp) / _NS
        dt = min(dt, s.max_dt_s)
        self._reach = candidates.reach_m  # look_within_reach

        # 1. ego-motion
        pose = self.odometry.pose_at(stamp)
        rotation = translation = None
        if pose is not None and self._last_pose is not None:
            rotation, translation = se2_change(self._last_pose, pose)
            if self._lost_at is not None:
                self._lost_at = rotation @ self._lost_at + translation
                self._lost_v = rotation @ self._lost_v
            sources.append("odometry")
        elif pose is None:
            flags.append("no_odometry")
            self.steps_without_odometry += 1
        self._last_pose = pose
        self._last_stamp = stamp

        # 2. predict (after the ego-motion): all tracks in one batch where the estimator can
        motion_all = getattr(self._cls, "motion_all", None)
        if motion_all is not None and len(self.tracks) > 1:
            motion_all([t.estimator for t in self.tracks.values()], rotation, translation, dt)
        else:
            for t in self.tracks.values():
                if rotation is not None:
                    t.estimator.ego_motion(rotation, translation)
                t.estimator.predict(dt, t.misses)
        shifted = self.tracks.get(self.target_id) if s.lone_leg_output_m else None
        if rotation is not None and shifted is not None:
            shifted.shift = rotation @ shifted.shift  # a vector: turns, no translation
        if s.coast_velocity_s > 0:
            for t in self.tracks.values():  # hidden since the last scan: moving on (settings)
                if t.misses > 0 and t.steps and getattr(t.estimator, "coasts_in_place", False):
                    t.estimator.ego_motion(_I2, self._velocity(t, pose) * dt)

        # the target before this scan's update, for a rollback by late vision
        prior = None
        if self.settings.rollback and self.target_id >= 0:  # (not vision_alive: timing)
            est = self.tracks[self.target_id].estimator
            snapshot = getattr(est, "snapshot", None)
            prior = (self.target_id, snapshot() if snapshot else copy.deepcopy(est))
        self._now = (stamp, pose)

        # 3. late vision, as of the scans it names
        self._vision_sources = False
        self._apply_due_verifications(pose)
        if self._model is not None:
            self._take_model(pose)

        # 4. associate
        self._horizon = candidates.horizon
        cands = candidates.candidates
        z = np.array([[c.x_m, c.y_m] for c in cands], dtype=float).reshape(-1, 2)
        # association units: a candidate, or one leg of a pair split between two tracks
        unit_cand, points, starts = self._units(candidates, z)
        ids = list(self.tracks)
        matched: dict[int, int] = {}  # track id -> unit index
        measured: dict[int, np.ndarray] = {}  # track id -> the point it is updated with
        if ids and len(unit_cand):
            cost_all = getattr(self._cls, "cost_all", None)
            if cost_all is not None and len(ids) > 1:
                ts = [self.tracks[tid] for tid in ids]
                cost_p = cost_all([t.estimator for t in ts], points, [t.misses for t in ts])
            else:
                cost_p = np.empty((len(ids), len(points)))
                for r, tid in enumerate(ids):
                    t = self.tracks[tid]
                    d = t.estimator.distance(points, t.misses)
                    cost_p[r] = np.where(d <= t.estimator.gate(t.misses), d, np.inf)
            if starts is None:  # one point per unit
                cost, best = cost_p, None
            else:  # a unit's cost is that of its best point (centre or one of its legs)
                cost = np.minimum.reduceat(cost_p, starts, axis=1)
                best = np.column_stack(
                    [np.argmin(g, axis=1) for g in np.split(cost_p, starts[1:], axis=1)]
                )
            if s.front_margin_m is not None and self.target_id in self.tracks:
                # someone passing in front of the target hides it: not the target's candidate
                # when another track can take it (alone, it may be the target coming closer)
                r = ids.index(self.target_id)
                held = self.tracks[self.target_id]
                pred = held.position
                centres = points[starts] if starts is not None else points
                r_pred = float(np.hypot(*pred))
                half = math.atan2(s.occlusion_radius_m, max(r_pred, 1e-6))
                dr = r_pred - np.hypot(centres[:, 0], centres[:, 1])
                db = np.abs(
                    wrap_angle(np.arctan2(centres[:, 1], centres[:, 0]) - math.atan2(*pred[::-1]))
                )
                others = np.isfinite(np.delete(cost, r, axis=0)).any(axis=0)
                block = (dr >= s.front_margin_m) & (db <= half) & others
                cost[r, block] = np.inf
            finite = np.isfinite(cost)
            if finite.any():
                if s.assignment == "weighted":
                    # one price G for a miss, the widest gate: every gated pair weighs >= 0
                    g = max(self.tracks[tid].estimator.gate(self.tracks[tid].misses) for tid in ids)
                    weight = np.where(finite, np.maximum(g - cost, 0.0), 0.0)
                    finite &= weight > 0  # at the gate itself: no better than a miss
                    rows, cols = linear_sum_assignment(weight, maximize=True)
                else:
                    big = 1e6 + 2.0 * float(cost[finite].max(initial=0.0))
                    rows, cols = linear_sum_assignment(np.where(finite, cost, big))
                for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
                    if finite[r, c]:
                        matched[ids[r]] = c
                        if best is not None and best[r, c]:
                            measured[ids[r]] = points[starts[c] + best[r, c]]

        # 5. update, count misses, start and delete tracks
        first = starts if starts is not None else np.arange(len(unit_cand))
        updated = [self.tracks[tid] for tid in ids if tid in matched]
        zs = [measured.get(t.id, points[first[matched[t.id]]]) for t in updated]
        scales = None
        lone = None
        if s.one_leg_noise_scale != 1.0 or s.lone_leg_output_m:
            # a lone leg, one leg of a pair, or a split pair's
            split = {c for c in unit_cand if unit_cand.count(c) > 1}
            lone = [
                t.id in measured
                or unit_cand[matched[t.id]] in split
                or len(cands[unit_cand[matched[t.id]]].legs) == 1
                for t in updated
            ]
            if s.one_leg_noise_scale != 1.0:
                scales = np.where(lone, s.one_leg_noise_scale, 1.0)
        update_all = getattr(self._cls, "update_all", None)
        if update_all is not None and len(updated) > 1:
            update_all([t.estimator for t in updated], np.array(zs), scales)
        else:
            for i, (t, zi) in enumerate(zip(updated, zs, strict=True)):
                t.estimator.update(zi, 1.0 if scales is None else float(scales[i]))
        if s.lone_leg_output_m and lone is not None:
            self._shift_target(updated, zs, lone, scales)
        learn: list[tuple[Track, int]] = []  # (track, seen before): velocities, in step_rest
        for tid in ids:
            t = self.tracks[tid]
            if tid in matched:
                if s.coast_velocity_s > 0:
                    learn.append((t, t.last_seen_ns))
                t.misses = 0
                t.hits += 1
                t.last_seen_ns = stamp
            else:
                t.misses += 1
        taken = set(matched.values())
        for u in range(len(unit_cand)):
            if u not in taken:
                tid = self._new_track(points[first[u]], stamp)
                matched[tid] = u
        # from units back to the message's candidates (a split pair: the target's side wins)
        by_cand: dict[int, int] = {}
        for tid, u in matched.items():
            c = unit_cand[u]
            if c not in by_cand or tid == self.target_id:
                by_cand[c] = tid
        matched = {tid: c for c, tid in by_cand.items()}
        for tid in list(self.tracks):
            t = self.tracks[tid]
            if t.misses > s.max_misses or t.estimator.expired():
                if tid == self.target_id:
                    self._lose_target(t)
                del self.tracks[tid]

        if not self.vision_alive:
            flags.append("no_vision")
        elif self._vision_stamp is None or stamp - self._vision_stamp > s.vision_stale_s * _NS:
            flags.append("vision_stale")

        # acquisition without vision (settings) and laser-only re-acquisition
        if self.target_id < 0:
            self._acquire_by_laser(z, matched, vision=not any(f in _NO_VISION for f in flags))
        lost = self.target_id < 0 and self._had_target and self.vision_alive
        # with look_gate_m, only while the gate applies (look_max_s)
        wide = s.look_wide_max_distance is not None
        if lost and s.look_while_lost and (s.look_gate_m is None or wide or self._look_gate()):
            self._choose_look(stamp)
        else:  # not searching: what the camera looked at during a loss is forgotten
            self._forget_looks()
        if self.target_id >= 0 and self.target_id in matched:
            sources.insert(0, "laser")
        if self._vision_sources:
            sources.append("vision")

        # 6. history for late verifications (kept in step_rest)
        if prior is not None and prior[0] != self.target_id:
            prior = None  # vision moved the target during this step
        assoc = {c: tid for tid, c in matched.items()}
        self._rest = _Rest(
            stamp, candidates.frame_id, _Scan(self._index, pose, assoc, prior), learn, pose
        )
        return self._target_output(stamp, candidates.frame_id, flags, sources)

    def _shift_target(
        self,
        updated: list[Track],
        zs: list[np.ndarray],
        lone: list[bool],
        scales: np.ndarray | None,
    ) -> None:
        """The target's reported shift after its update (lone_leg_output_m): the update would
        have moved the estimate by ``moved`` had its measurement lain ``b`` farther out; that
        is k b along the bearing, so the update keeps 1 - k of the earlier shift and, for a
        lone leg, adds ``moved``."""
        b = self.settings.lone_leg_output_m
        i = next((i for i, t in enumerate(updated) if t.id == self.target_id), None)
        if i is None:
            return  # the target was not updated: its shift stays
        t = updated[i]
        mean_if = getattr(t.estimator, "mean_if", None)
        r = float(np.hypot(*zs[i]))
        if mean_if is None or not r > 0:
            return
        u = zs[i] / r
        moved = mean_if(zs[i] + b * u, 1.0 if scales is None else float(scales[i]))[:2]
        moved -= t.estimator.mean[:2]
        if not np.isfinite(moved).all():
            t.shift = np.zeros(2)
            return
        k = min(max(float(moved @ u) / b, 0.0), 1.0)
        t.shift = (1.0 - k) * t.shift + (moved if lone[i] else 0.0)

    def step_rest(self) -> People:
        """Finish the scan :meth:`step_target` began; returns its People message."""
        rest, self._rest = self._rest, None
        if rest is None:
            raise RuntimeError("step_rest() without a step_target() before it")
        prepare_all = getattr(self._cls, "prepare_all", None)  # resampling, draws ahead
        if prepare_all is not None:
            prepare_all([t.estimator for t in self.tracks.values()])
        for t, seen in rest.learn:
            self._learn_velocity(t, rest.stamp, rest.pose, seen)
        if rest.scan is not None:
            s = self.settings
            if s.near_guard_m > 0 and s.reject_min_range_m > 0 and self.target_id in self.tracks:
                self._note_break()  # this scan's index: before it moves on
            self._history[rest.stamp] = rest.scan
            while len(self._history) > self.settings.history_scans:
                self._history.popitem(last=False)
            self._index += 1
        return self._people_output(rest.stamp, rest.frame_id)

    def _learn_velocity(
        self, t: Track, stamp: int, pose: Pose | None, seen_ns: int | None = None
    ) -> None:
        """Record the track's step velocity (odometry frame: nothing to turn with the robot);
        ``seen_ns``: when it was seen before this update (default: ``t.last_seen_ns``)."""
        m = t.estimator.mean
        x, y = float(m[0]), float(m[1])
        if pose is not None:
            c, sn = math.cos(pose[2]), math.sin(pose[2])
            x, y = pose[0] + c * x - sn * y, pose[1] + sn * x + c * y
        seen = t.last_seen_ns if seen_ns is None else seen_ns
        if t.anchor is not None and stamp > seen:
            gap = (stamp - seen) / _NS
            t.steps.append((stamp, (x - t.anchor[0]) / gap, (y - t.anchor[1]) / gap))
            oldest = stamp - self.settings.coast_velocity_s * _NS
            while t.steps[0][0] < oldest:
                t.steps.popleft()
        t.anchor = (x, y)

    def _velocity(self, t: Track, pose: Pose | None) -> np.ndarray:
        """The median of the track's recent step velocities, in the robot frame of ``pose``,
        clipped to ``coast_max_speed_mps`` (computed only for coasting tracks)."""
        if not t.steps:
            return np.zeros(2)
        # statistics.median: the same value as numpy's for these few samples, ~20x cheaper
        v = np.array(
            [
                statistics.median([st[1] for st in t.steps]),
                statistics.median([st[2] for st in t.steps]),
            ]
        )
        if pose is not None:
            v = _rot(-pose[2]) @ v
        speed = float(np.hypot(*v))
        cap = self.settings.coast_max_speed_mps
        return v * (cap / speed) if speed > cap else v

    def velocity_of(self, track_id: int) -> np.ndarray:
        """A track's coasting velocity (robot frame of the last scan), (0, 0) if unknown."""
        t = self.tracks.get(track_id)
        return np.zeros(2) if t is None else self._velocity(t, self._last_pose)

    def _units(
        self, candidates: PersonCandidates, z: np.ndarray
    ) -> tuple[list[int], np.ndarray, np.ndarray | None]:
        """What the tracks are associated with: per unit, the candidate it comes from and the
        points a track may be updated with (``starts``: where each unit's points begin; None
        when every unit is one point).

        A pair whose legs are more than ``split_pair_m`` apart may be one leg each of two
        people. When each leg lies in the gate of a different track, nearest first, it is
        split into two one-leg units; otherwise it stays one unit whose points are its centre
        and each of its legs (a track takes the one nearest its prediction)."""
        split = self.settings.split_pair_m
        cands = candidates.candidates
        wide = set()
        if split:
            wide = {
                c
                for c, cand in enumerate(cands)
                if len(cand.legs) == 2
                and math.hypot(
                    cand.legs[0].x_m - cand.legs[1].x_m, cand.legs[0].y_m - cand.legs[1].y_m
                )
                > split
            }
        if not wide:
            return list(range(len(cands))), z, None
        unit_cand: list[int] = []
        pts: list[np.ndarray] = []
        starts: list[int] = []
        for c, cand in enumerate(cands):
            legs = [np.array([leg.x_m, leg.y_m]) for leg in cand.legs]
            if c in wide and len({self._nearest_gated(leg) for leg in legs} - {-1}) == 2:
                for leg in legs:
                    unit_cand.append(c)
                    starts.append(len(pts))
                    pts.append(leg)
                continue
            unit_cand.append(c)
            starts.append(len(pts))
            pts.append(z[c])
            if c in wide:
                pts.extend(legs)
        return unit_cand, np.array(pts), np.array(starts)

    def _nearest_gated(self, xy: np.ndarray) -> int:
        """The track whose gate holds ``xy`` at the least distance, or -1."""
        best, best_d = -1, math.inf
        for tid, t in self.tracks.items():
            d = float(t.estimator.distance(xy[None], t.misses)[0])
            if d <= t.estimator.gate(t.misses) and d < best_d:
                best, best_d = tid, d
        return best

    # ------------------------------------------------------------------ target choice

    def _new_track(self, xy: np.ndarray, stamp_ns: int) -> int:
        tid = self._next_id
        self._next_id += 1
        rng = np.random.default_rng([self.settings.seed, tid])
        self.tracks[tid] = track = Track(tid, self._make(float(xy[0]), float(xy[1]), rng), stamp_ns)
        if self.settings.coast_velocity_s > 0:
            self._learn_velocity(track, stamp_ns, self._now[1])  # where it was first seen
        return tid

    def _predicted_lost(self) -> np.ndarray | None:
        """Where the lost target should be now: where it was lost, moved on at its coasting
        velocity for at most look_predict_s (None: no loss)."""
        if self._lost_at is None:
            return None
        elapsed = (self._now[0] - self._lost_ns) / _NS
        where = self._lost_at + self._lost_v * min(elapsed, self.settings.look_predict_s)
        limit = self._reach if self.settings.look_within_reach else None
        if limit is not None:  # beyond the detector's reach: where it would come back into it
            r = float(np.hypot(*where))
            if r > limit:
                where = where * (limit / r)
        return where

    def _look_gate(self, since_loss: bool = False) -> tuple[np.ndarray, float] | None:
        """look_gate_m: (where the lost target should be now, gate radius), or None when the
        gate does not apply (off, no loss, or look_max_s past). ``since_loss``: the radius
        grown since the loss, whatever look_gate_since_seen says."""
        s = self.settings
        where = self._predicted_lost()
        if s.look_gate_m is None or where is None:
            return None
        elapsed = (self._now[0] - self._lost_ns) / _NS
        if elapsed > s.look_max_s:
            return None
        if s.look_gate_since_seen and not since_loss:
            elapsed = (self._now[0] - self._lost_seen_ns) / _NS
        return where, s.look_gate_m + s.look_gate_mps * elapsed

    def _last_gate(self) -> tuple[np.ndarray, float] | None:
        """look_wide_max_distance: past look_max_s since the loss, (where the lost target should
        be now, look_wide_gate_m); else None."""
        s = self.settings
        where = self._predicted_lost()
        if s.look_wide_max_distance is None or s.look_gate_m is None or where is None:
            return None
        if (self._now[0] - self._lost_ns) / _NS <= s.look_max_s:
            return None  # the gate itself applies
        return where, s.look_wide_gate_m

    def _beyond_last_gate(self, tid: int) -> bool:
        last = self._last_gate()
        return last is not None and not self._inside(last, self.tracks.get(tid))

    @staticmethod
    def _inside(gate: tuple[np.ndarray, float] | None, t: Track | None) -> bool:
        """Track ``t`` lies in ``gate`` (from :meth:`_look_gate`; None: no gate, always)."""
        if gate is None:
            return True
        return t is not None and float(np.hypot(*(t.position - gate[0]))) <= gate[1]

    def _in_look_gate(self, tid: int) -> bool:
        return self._inside(self._look_gate(), self.tracks.get(tid))

    def _beyond_loss_gate(self, tid: int) -> bool:
        """look_gate_since_seen: track ``tid`` lies in the gate only because it grew from the
        last sighting (outside the radius grown since the loss)."""
        if not self.settings.look_gate_since_seen:
            return False
        return not self._inside(self._look_gate(since_loss=True), self.tracks.get(tid))

    def _forget_looks(self) -> None:
        self._look = (-1, 0)
        self._look_rejected.clear()
        self._look_done.clear()
        self._looked.clear()

    def _choose_look(self, stamp: int) -> None:
        """look_while_lost: keep looking at the current track until vision judged it or
        look_dwell_s passed, then the next (settings)."""
        s = self.settings
        gate = self._look_gate()
        last = None if gate is not None else self._last_gate()  # look_wide_max_distance
        tid, since = self._look
        if tid >= 0 and (
            tid not in self.tracks
            or self._look_rejected.get(tid, 0) >= s.look_rejections
            or stamp - since > s.look_dwell_s * _NS
        ):
            self._look_done.add(tid)
            tid = -1
        if tid >= 0 and self.tracks[tid].misses <= s.look_keep_misses:
            return
        dwelling = tid < 0 and last is not None and since and stamp - since <= s.look_dwell_s * _NS

        def eligible_here(t: Track) -> bool:
            if last is None:
                return self._inside(gate, t)
            # past look_max_s: someone who appeared since the loss, away from where the target
            # should be (there the camera looks at the point itself)
            return not self._inside(last, t) and t.born_ns > self._lost_ns

        eligible = [
            t
            for t in self.tracks.values()
            if t.hits >= s.confirm_hits
            and t.misses == 0
            and self._look_rejected.get(t.id, 0) < s.look_rejections
            and float(np.hypot(*t.position)) >= s.look_min_range_m
            and eligible_here(t)
        ]
        if dwelling:  # on where the target should be, between the rounds of newcomers
            if not (s.look_new_first and any(t.id not in self._looked for t in eligible)):
                return
            eligible = [t for t in eligible if t.id not in self._looked]
        fresh = [t for t in eligible if t.id not in self._look_done]
        if eligible and not fresh:  # each looked at once: round again
            self._look_done.clear()
            if last is not None:  # (via a dwell on the point)
                self._look = (-1, stamp)
                return
            fresh = eligible
        if not fresh:
            self._look = (-1, 0)
            return
        origin = np.zeros(2) if self._lost_at is None else self._lost_at
        if gate is not None:
            origin = gate[0]
        elif last is not None:
            origin = last[0]  # past look_max_s: still nearest where it should be first

        def rank(t: Track) -> tuple[bool, float]:
            return (
                not self._walking(t.id, s.look_moving_mps),
                float(np.hypot(*(t.position - origin))),
            )

        best = min(fresh, key=rank)
        start = since
        if best.id != tid:
            start = stamp
            if s.look_turn_deg_s is not None and self._look_bearing is not None:
                # the dwell runs from when the camera can be there, not from when it is sent
                turn = abs(
                    math.remainder(
                        math.atan2(best.position[1], best.position[0]) - self._look_bearing,
                        math.tau,
                    )
                )
                start = stamp + round(math.degrees(turn) / s.look_turn_deg_s * _NS)
        self._look = (best.id, start)
        self._looked.add(best.id)

    def _note_break(self) -> None:
        """Remember this scan when the target missed or another track is near it."""
        target = self.tracks[self.target_id]
        broken = target.misses > 0
        if not broken:
            xy = target.position
            guard = self.settings.near_guard_m
            broken = any(
                float(np.hypot(*(t.position - xy))) < guard
                for t in self.tracks.values()
                if t is not target
            )
        if broken:
            self._breaks.append(self._index)
            while len(self._breaks) > self.settings.history_scans:
                self._breaks.popleft()

    def _surely_the_target(self, index: int) -> bool:
        """No break between the last acceptance of the target and scan ``index``."""
        if self._index - self._confirmed_index > self.settings.history_scans:
            return False  # the breaks of that time are forgotten
        return not any(self._confirmed_index < b <= index for b in self._breaks)

    def _set_target(self, tid: int) -> None:
        self._rejects = 0
        if self.target_id >= 0 and tid != self.target_id:
            self.target_switches += 1
        if tid != self.target_id:  # the shift is kept for the target only, from now on
            for i in (self.target_id, tid):
                if i in self.tracks:
                    self.tracks[i].shift = np.zeros(2)
        self.target_id = tid
        self._confirmed_index = self._index - 1  # chosen by vision (or a model) just now
        self._had_target = True
        self._lost_at = None
        self._switch = (-1, 0)

    def _lose_target(self, track: Track) -> None:
        self._note_loss(track)
        self.target_id = -1
        self._switch = (-1, 0)

    def _note_loss(self, track: Track) -> None:
        """Where, when and how fast the target was lost (the look gate's origin)."""
        self._lost_at = np.array(track.position, dtype=float)
        self._lost_ns = self._now[0]
        self._lost_seen_ns = min(track.last_seen_ns, self._now[0])
        self._lost_v = self._velocity(track, self._now[1])

    def _acquire_by_laser(self, z: np.ndarray, matched: dict[int, int], vision: bool) -> None:
        s = self.settings
        if not self._had_target and s.acquire == "nearest" and len(z):
            r = np.hypot(z[:, 0], z[:, 1])
            bearing = np.abs(np.arctan2(z[:, 1], z[:, 0]))
            ahead = (bearing <= math.radians(s.acquire_bearing_deg)) & (r <= s.acquire_range_m)
            if ahead.any():
                c = int(np.argmin(np.where(ahead, r, np.inf)))
                for tid, ci in matched.items():
                    if ci == c:
                        self._set_target(tid)
                        return
        lost_at = self._lost_at
        if not self._had_target or vision or lost_at is None or s.laser_reacquire_m <= 0:
            return
        max_s = s.laser_reacquire_max_s
        if max_s is not None and self._now[0] - self._lost_ns > max_s * _NS:
            return  # lost too long ago: whoever passes there now is someone else
        best, best_d = -1, s.laser_reacquire_m
        for tid, ci in matched.items():
            d = float(np.hypot(*(z[ci] - lost_at)))
            if (
                d <= best_d
                and float(np.hypot(*z[ci])) >= s.laser_reacquire_min_range_m
                and self._walking(tid, s.laser_reacquire_min_speed_mps)
            ):
                best, best_d = tid, d
        if best >= 0:
            self._set_target(best)

    def _walking(self, tid: int, min_speed_mps: float) -> bool:
        """Track ``tid`` moves at ``min_speed_mps`` or faster (recent velocity); any track
        when ``min_speed_mps`` is 0."""
        if min_speed_mps <= 0:
            return True
        t = self.tracks.get(tid)
        return t is not None and float(np.hypot(*self._velocity(t, self._now[1]))) >= min_speed_mps

    def _take_model(self, pose: Pose | None) -> None:
        model, self._model = self._model, None
        xy = np.array([[model.x_m, model.y_m]])
        then = self.odometry.pose_at(model.stamp_ns)
        if then is not None and pose is not None:
            xy = transform_points(xy, then, pose)
        tid = self._nearest_track(xy[0], self.settings.model_match_m)
        if tid < 0:
            tid = self._new_track(xy[0], model.stamp_ns)
        self._set_target(tid)
        self._vision_sources = True
        self._vision_stamp = max(self._vision_stamp or 0, self._now[0])  # vision's own word

    def _nearest_track(self, xy: np.ndarray, within_m: float) -> int:
        best, best_d = -1, within_m
        for tid, t in self.tracks.items():
            d = float(np.hypot(*(t.position - xy)))
            if d <= best_d:
                best, best_d = tid, d
        return best

    def _apply_due_verifications(self, pose: Pose | None) -> None:
        if not self._pending:
            return
        lag = max(self.settings.vision_lag_scans, 1)
        keep: list[Verification] = []
        for v in self._pending:
            scan = self._history.get(v.stamp_ns)
            if scan is None:
                if self._last_stamp is None or v.stamp_ns >= self._last_stamp:
                    keep.append(v)  # its scan has not been processed yet
                else:
                    self.verifications_unmatched += 1  # too old, or names no scan seen here
                continue
            if self._index - scan.index < lag:
                keep.append(v)
                continue
            self._apply_verification(v, scan, pose)
        self._pending = keep

    def _apply_verification(self, v: Verification, scan: _Scan, pose: Pose | None) -> None:
        self.verifications_applied += 1
        judged = any(c.distance is not None for c in v.candidates)
        if judged and (self._vision_stamp is None or v.stamp_ns > self._vision_stamp):
            # vision that judges nothing (no image, target out of view, a face verifier that
            # sees no face) is no evidence: after vision_stale_s the laser gates alone
            self._vision_stamp = v.stamp_ns
        held = self.target_id
        self._judge_target(v, scan)
        if v.chosen < 0:
            return
        chosen = v.candidates[v.chosen]
        tid = scan.assoc.get(chosen.index, -1)
        if tid not in self.tracks:
            # that track is gone: carry the chosen position to now and take the nearest track
            xy = np.array([[chosen.x_m, chosen.y_m]])
            if scan.pose is not None and pose is not None:
                xy = transform_points(xy, scan.pose, pose)
            tid = self._nearest_track(xy[0], self.settings.model_match_m)
            if tid < 0:
                return
        if self.target_id < 0:
            limit = self.settings.reacquire_max_distance
            if self._had_target and limit is not None and not chosen.distance <= limit:
                return  # re-acquisition asks for a closer match than verification does
            # (held >= 0: dropped just now by this verification -- a switch, taken anywhere)
            if held < 0 and self._had_target:
                if self.settings.look_while_lost and not self._in_look_gate(tid):
                    return  # not where the lost target can be now (look_gate_m)
                wide = self.settings.look_wide_max_distance
                if (
                    wide is not None
                    and not chosen.distance <= wide
                    and (self._beyond_last_gate(tid) or self._beyond_loss_gate(tid))
                ):
                    return  # far from where the target went: only a close match re-takes it
            self._set_target(tid)  # (re-)acquisition by appearance
            self._vision_sources = True
            return
        if tid == self.target_id:
            self._switch = (-1, 0)
            self._vision_sources = True
            return
        prev, votes = self._switch
        votes = votes + 1 if prev == tid else 1
        self._switch = (tid, votes)
        if votes >= self.settings.switch_votes or self._repairs_split(tid):
            self._set_target(tid)
            self._vision_sources = True

    def _repairs_split(self, tid: int) -> bool:
        """Vision chose a track next to the target while the target coasts: after a rollback
        on a false rejection the real target may be that track; take it at once."""
        target = self.tracks.get(self.target_id)
        if target is None or target.misses == 0:
            return False
        d = float(np.hypot(*(self.tracks[tid].position - target.position)))
        return d <= self.settings.model_match_m

    def _judge_target(self, v: Verification, scan: _Scan) -> None:
        """Negative evidence: vision saw the target's candidate and said it is not the target.
        (While the target is lost: which tracks vision has rejected, for look_while_lost.)"""
        lost = self.target_id < 0 and self._had_target
        if lost and self.settings.look_while_lost and v.threshold is not None:
            for c in v.candidates:
                tid = scan.assoc.get(c.index, -1)
                if tid >= 0 and c.in_view and c.distance is not None and c.distance > v.threshold:
                    self._look_rejected[tid] = self._look_rejected.get(tid, 0) + 1
        if self.target_id < 0 or v.threshold is None or not self.settings.reject_votes:
            return
        mine = [i for i, tid in scan.assoc.items() if tid == self.target_id]
        judged = {c.index: c for c in v.candidates}
        seen = [judged[i] for i in mine if i in judged and judged[i].in_view]
        if not seen or seen[0].distance is None:
            return  # not in view: no evidence either way
        if v.chosen >= 0 and v.candidates[v.chosen].index in mine:
            self._rejects = 0
            self._confirmed_index = max(self._confirmed_index, scan.index)
            return
        if seen[0].distance <= v.threshold:
            return  # close enough, only another was closer: the switch votes decide
        if math.hypot(seen[0].x_m, seen[0].y_m) < self.settings.reject_min_range_m and (
            self.settings.near_guard_m <= 0 or self._surely_the_target(scan.index)
        ):
            self.rejections_near += 1
            return  # too near for the camera to tell (settings)
        h = self.settings.reject_hysteresis
        if h > 0 and seen[0].distance <= v.threshold + h and self._surely_the_target(scan.index):
            return  # hysteresis: a target held since its last acceptance (settings)
        if self.settings.rollback:
            self._rollback(v.stamp_ns, scan, (seen[0].x_m, seen[0].y_m))
        self._rejects += 1
        if self._rejects >= self.settings.reject_votes:
            self._rejects = 0
            self.target_rejections += 1
            self._lose_target(self.tracks[self.target_id])

    def _rollback(self, stamp_k: int, scan: _Scan, taken: tuple[float, float]) -> None:
        """Vision rejected what the target took at scan k: split the track (module doc).

        The target goes back to before the first of its updates that vision has not
        confirmed (at most ``rollback_max_s`` before scan k): a passer-by often pulls the
        target a scan or two before vision sees the two apart, in scans it did not judge."""
        tid = self.target_id
        if tid not in self.tracks:
            return
        s = self.settings
        start = None  # (stamp, scan) to go back to
        for stamp_j, st in self._history.items():
            if (
                st.index > self._confirmed_index
                and st.index <= scan.index
                and st.target_prior is not None
                and st.target_prior[0] == tid
                and stamp_k - stamp_j <= s.rollback_max_s * _NS
            ):
                start = (stamp_j, st)
                break
        if start is None:
            return
        stamp_j, scan_j = start
        before = scan_j.target_prior[1]
        xy = np.array([taken])
        if scan.pose is not None and scan_j.pose is not None:
            xy = transform_points(xy, scan.pose, scan_j.pose)  # into scan j's frame
        jump = math.hypot(xy[0, 0] - before.mean[0], xy[0, 1] - before.mean[1])
        if jump < s.rollback_jump_m:
            return
        stamp_now, pose_now = self._now
        track = self.tracks[tid]
        # 1. what the target followed since scan j is somebody else: their own track
        other = Track(self._next_id, track.estimator, track.born_ns)
        self._next_id += 1
        other.hits, other.misses = max(track.hits, s.confirm_hits), track.misses
        other.last_seen_ns = track.last_seen_ns
        self.tracks[other.id] = other
        for st in self._history.values():  # scans j.. : those candidates were the other's
            if st.index >= scan_j.index:
                st.assoc = {c: other.id if t == tid else t for c, t in st.assoc.items()}
                if st.target_prior is not None and st.index > scan_j.index:
                    st.target_prior = None  # snapshots taken after the wrong updates
        scan_j.target_prior = None  # used: the target's new estimator is this snapshot
        # 2. the target as it was before scan j's update, carried to now
        if scan_j.pose is not None and pose_now is not None:
            rotation, translation = se2_change(scan_j.pose, pose_now)
            before.ego_motion(rotation, translation)
        misses = max(1, self._index - scan_j.index)
        before.predict(min((stamp_now - stamp_j) / _NS, s.max_dt_s), misses)
        track.estimator = before
        track.shift = np.zeros(2)  # (the snapshot's updates are not the ones shifted)
        track.misses = misses
        self.rollbacks += 1

    # ------------------------------------------------------------------ outputs

    def status(self) -> str:
        if self.target_id >= 0:
            return "tracking" if self.tracks[self.target_id].misses == 0 else "coasting"
        return "lost" if self._had_target else "initialising"

    def _target_output(
        self, stamp: int, frame_id: str, flags: list[str], sources: list[str]
    ) -> TrackState:
        status = self.status()
        look_id, lx, ly = self._look_output()
        if self.target_id >= 0:
            t = self.tracks[self.target_id]
            m, cov = t.estimator.mean, t.estimator.covariance
            xy = t.reported
            target = TrackState(
                stamp_ns=stamp,
                frame_id=frame_id,
                status=status,
                track_id=t.id,
                x_m=float(xy[0]),
                y_m=float(xy[1]),
                vx_mps=float(m[2]),
                vy_mps=float(m[3]),
                covariance=cov.reshape(-1).tolist(),
                misses=t.misses,
                sources=sources,
                flags=flags,
                estimator=self.estimator_name,
                look_track_id=look_id,
                look_x_m=lx,
                look_y_m=ly,
                shift_x_m=float(t.shift[0]),
                shift_y_m=float(t.shift[1]),
            )
        else:
            x, y = (0.0, 0.0) if self._lost_at is None else map(float, self._lost_at)
            target = TrackState(
                stamp_ns=stamp,
                frame_id=frame_id,
                status=status,
                x_m=x,
                y_m=y,
                misses=0,
                sources=sources,
                flags=flags,
                estimator=self.estimator_name,
                look_track_id=look_id,
                look_x_m=lx,
                look_y_m=ly,
            )
        return target

    def _look_output(self) -> tuple[int, float, float]:
        """(look_track_id, look_x_m, look_y_m) for tracking/target: whom the camera should
        look at while the target is lost; (-1, 0, 0) otherwise."""
        if self.target_id >= 0:
            followed = self.tracks.get(self.target_id)
            if followed is not None:  # the camera follows it (pan = heading)
                xy = followed.position
                self._look_bearing = math.atan2(float(xy[1]), float(xy[0]))
            return -1, 0.0, 0.0
        look = self.tracks.get(self._look[0])
        lx, ly = (0.0, 0.0) if look is None else map(float, look.position)
        where = self._search_point() if look is None else None
        if where is not None:
            lx, ly = map(float, where)  # nobody to look at: where the target should be
        if (lx, ly) != (0.0, 0.0):
            self._look_bearing = math.atan2(ly, lx)
        return -1 if look is None else look.id, lx, ly

    def _search_point(self) -> np.ndarray | None:
        """Where the camera looks when it looks at nobody while the target is lost (look_gate_m):
        where the target should be, or past the edge of what hides that point
        (look_occluder_edge); None without a gate."""
        s = self.settings
        if not (s.look_while_lost and s.look_gate_m is not None):
            return None
        where = self._predicted_lost()
        if where is not None and s.look_occluder_edge and self._horizon is not None:
            edge = occluder_edge(
                where, self._lost_v, self._horizon, s.occlusion_margin_m, s.occlusion_radius_m
            )
            if edge is not None:
                where = edge  # hidden there: where it comes out of hiding
        return where

    def _people_output(self, stamp: int, frame_id: str) -> People:
        s = self.settings
        tracks = []
        for t in self.tracks.values():
            if t.hits < s.confirm_hits and t.id != self.target_id:
                continue
            m = t.estimator.mean
            xy = t.reported if t.id == self.target_id else m[:2]
            tracks.append(
                PersonTrack(
                    id=t.id,
                    x_m=float(xy[0]),
                    y_m=float(xy[1]),
                    vx_mps=float(m[2]),
                    vy_mps=float(m[3]),
                    covariance=t.estimator.covariance.reshape(-1).tolist(),
                    misses=t.misses,
                    age_s=max(0.0, (stamp - t.born_ns) / _NS),
                    confidence=max(0.0, 1.0 - t.misses / (s.max_misses + 1)),
                )
            )
        return People(
            stamp_ns=stamp,
            frame_id=frame_id,
            tracks=tracks[:256],
            target_id=self.target_id,
            estimator=self.estimator_name,
        )
