"""The tracker's settings, and the settings that were removed or renamed (a file naming one is
refused with the reason or the new key: services/runtime/settings.py ``retired_settings``).

The settings that tune one role are nested under its name -- ``association``, ``identity``,
``search`` (``--set search.gate_m=0.8``, or in a file ``search: {gate_m: 0.8}``); the rest
are top-level. The flat names of the nested ones (``look_gate_m``, ``switch_votes``, ...)
are refused with the dotted key to use instead.

Defaults marked "beyond the thesis" were chosen by closed-loop measurements; the line after
each such setting points into docs/tracker_log.md, where the runs are recorded.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal

import msgspec

from followbot.services.runtime.settings import removed, renamed

from .estimators import estimator_factory

__all__ = [
    "RETIRED_SETTINGS",
    "AssociationSettings",
    "EvidenceSettings",
    "IdentitySettings",
    "SearchSettings",
    "TrackerSettings",
]

_LOG = "docs/tracker_log.md"
_ISSUE35 = f'{_LOG} "Issue 35"'

#: Settings that are gone: experiments measured and left off (their record: docs/tracker_log.md).
RETIRED_SETTINGS: dict[str, str] = {
    "occlusion_max_s": removed(f"keeping a hidden target past max_misses, measured in {_LOG}"),
    "occlusion_look": removed("it only applied with occlusion_max_s, also removed"),
    "front_approach_factor": removed(f"an experiment measured and left off, see {_LOG}"),
    "lone_leg_offset_m": removed(
        f"measured and left off, {_LOG}; lone_leg_output_m moves the report"
    ),
    "lone_leg_clear_m": removed("it only applied with lone_leg_offset_m, also removed"),
    "look_near_walkers": removed(f"an experiment measured and left off, see {_LOG}"),
    "look_out_of_view_deg": removed(f"an experiment measured and left off, see {_LOG}"),
    "look_far_walking_m": removed(f"an experiment measured and left off, see {_LOG}"),
    "look_confirm_hits": removed(f"the camera turns to a track once confirm_hits, see {_LOG}"),
    "switch_needs_target_seen": removed(f"an experiment measured and left off, see {_LOG}"),
    "deleter": removed(
        f"its rule target_seconds was measured and not adopted, {_ISSUE35}; a track is "
        "deleted after max_misses"
    ),
    "target_keep_s": removed(f"it only applied with deleter target_seconds, {_ISSUE35}"),
    "identity.laser_retake": removed(
        f"its rule reach was measured and not adopted, {_ISSUE35}; the laser re-takes a "
        "lost target near where it was lost, identity.laser_reacquire_*"
    ),
    "identity.retake_gate_m": removed(f"it only applied with laser_retake reach, {_ISSUE35}"),
    "identity.retake_floor_mps": removed(f"it only applied with laser_retake reach, {_ISSUE35}"),
    "identity.retake_young_s": removed(f"it only applied with laser_retake reach, {_ISSUE35}"),
    "identity.retake_max_s": removed(f"it only applied with laser_retake reach, {_ISSUE35}"),
    # settings nested by role: the old flat key names the new dotted one
    "assignment": renamed("association.assignment"),
    "split_pair_m": renamed("association.split_pair_m"),
    "front_margin_m": renamed("association.front_margin_m"),
    "one_leg_noise_scale": renamed("association.one_leg_noise_scale"),
    "acquire_range_m": renamed("identity.acquire_range_m"),
    "acquire_bearing_deg": renamed("identity.acquire_bearing_deg"),
    "model_match_m": renamed("identity.model_match_m"),
    "switch_votes": renamed("identity.switch_votes"),
    "reacquire_max_distance": renamed("identity.reacquire_max_distance"),
    "reject_votes": renamed("identity.reject_votes"),
    "reject_min_range_m": renamed("identity.reject_min_range_m"),
    "reject_hysteresis": renamed("identity.reject_hysteresis"),
    "near_guard_m": renamed("identity.near_guard_m"),
    "rollback": renamed("identity.rollback"),
    "rollback_max_s": renamed("identity.rollback_max_s"),
    "rollback_jump_m": renamed("identity.rollback_jump_m"),
    "laser_reacquire_m": renamed("identity.laser_reacquire_m"),
    "laser_reacquire_min_speed_mps": renamed("identity.laser_reacquire_min_speed_mps"),
    "laser_reacquire_min_range_m": renamed("identity.laser_reacquire_min_range_m"),
    "laser_reacquire_max_s": renamed("identity.laser_reacquire_max_s"),
    "look_while_lost": renamed("search.enabled"),
    "look_dwell_s": renamed("search.dwell_s"),
    "look_rejections": renamed("search.rejections"),
    "look_min_range_m": renamed("search.min_range_m"),
    "look_moving_mps": renamed("search.moving_mps"),
    "look_gate_m": renamed("search.gate_m"),
    "look_gate_mps": renamed("search.gate_mps"),
    "look_gate_since_seen": renamed("search.gate_since_seen"),
    "look_predict_s": renamed("search.predict_s"),
    "look_within_reach": renamed("search.within_reach"),
    "look_max_s": renamed("search.max_s"),
    "look_wide_max_distance": renamed("search.wide_max_distance"),
    "look_wide_gate_m": renamed("search.wide_gate_m"),
    "look_keep_misses": renamed("search.keep_misses"),
    "look_turn_deg_s": renamed("search.turn_deg_s"),
    "look_new_first": renamed("search.new_first"),
    "look_occluder_edge": renamed("search.occluder_edge"),
}


class AssociationSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Which track takes which candidate (association.py)."""

    assignment: Literal["most_matches", "weighted"] = "weighted"
    """How the gated distances become an assignment (association.py). ``weighted``: the
    assignment of greatest total weight, a gated pair weighing (G - distance), G the widest
    gate of the scan's tracks, so a second match is made only when it adds less than a miss
    costs. ``most_matches``: as many pairs as the gates allow, then the least total distance;
    it can take a track's best candidate away to let another track match at all.
    docs/tracker_log.md: of 76 runs only one changes, the crowd's 5.4 s on a passer-by -> 0."""
    split_pair_m: Annotated[float, msgspec.Meta(ge=0)] = 0.4
    """A two-leg candidate whose legs are farther apart than this may be one leg each of two
    people. When each leg lies in the gate of a different track the pair is split, one leg to
    each; otherwise a track may take either leg alone when that leg is nearer its prediction
    than the pair's centre. 0: always the centre. (The thesis pairs legs up to 0.5 m apart; in
    the simulator a person's own legs were at most 0.36 m apart, cross pairs 0.40-0.49 m.)"""
    front_margin_m: Annotated[float, msgspec.Meta(gt=0)] | None = 0.2
    """Beyond the thesis: the target does not take a candidate this much nearer to the laser
    than its prediction and on its bearing (within occlusion_radius_m of it) when another
    track's gate holds it too: that is someone passing in front, who hides it. Alone, such a
    candidate is taken (the target walking towards the robot, ahead of its lagging estimate).
    None: off."""
    one_leg_noise_scale: Annotated[float, msgspec.Meta(ge=1, le=100)] = 1.0
    """Beyond the thesis: a track updated with a lone leg (a one-leg candidate, or one leg of
    a split pair) scales its measurement noise by this. A lone leg lies ~0.13 m from the
    person's centre on average in the simulator (two legs' middle: ~0.04 m). 1: the thesis,
    every candidate alike."""


class IdentitySettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Which track is the target: acquisition, vision's votes and rejections, rollback,
    re-acquisition without vision (identity.py)."""

    acquire_range_m: Annotated[float, msgspec.Meta(gt=0)] = 3.0
    """``acquire: nearest``: the farthest a first target may be."""
    acquire_bearing_deg: Annotated[float, msgspec.Meta(gt=0, le=180)] = 45.0
    """``acquire: nearest``: the widest bearing, either side of straight ahead."""
    model_match_m: Annotated[float, msgspec.Meta(gt=0)] = 0.5
    """A target model's position takes the nearest track within this distance, else a new one."""
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
    acceptance still counts. So near, the camera sees too little of a person (a third of the
    body at 0.5 m) to say it is someone else. 0: every rejection counts."""
    reject_hysteresis: Annotated[float, msgspec.Meta(ge=0)] = 0.1
    """Beyond the thesis: while the target is surely the one vision last accepted (as for
    near_guard_m), a rejection of its candidate counts only when the distance exceeds the
    threshold by more than this, so a target judged around the threshold scan after scan is
    not dropped on every second look. 0: off.
    docs/tracker_log.md: 8 of 76 runs change, none of the sweep's counts."""
    vision_evidence: Literal["votes", "probability"] = "votes"
    """How vision's judgements decide the target (evidence.py). ``votes`` (the thesis-era
    rules, tuned to the histogram verifier's distance): reject_votes, switch_votes,
    reacquire_max_distance and reject_hysteresis. ``probability`` (for a verifier whose output
    is a calibrated probability, e.g. ``online``): each track sums the log-odds of vision's
    judgements of it within +-evidence_cap; the target goes at evidence_veto, vision's choice
    replaces it at evidence_switch, a lost target is re-taken at evidence_reacquire; the four
    distance rules above do not apply (reject_votes 0 still turns rejections off)."""
    evidence_cap: Annotated[float, msgspec.Meta(gt=0, le=20)] = 3.0
    """``probability``: a track's summed log-odds are held within +-this (p 0.95), so old
    confirmations do not outweigh fresh rejections."""
    evidence_look_max: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    """``probability``: one look adds at most +-this (p 0.12 / 0.88): a probability is
    calibrated on people in view, not on a view of furniture the laser missed in front of the
    target (docs/tracker_log.md "Issue 36")."""
    evidence_veto: Annotated[float, msgspec.Meta(lt=0)] = -2.0
    """``probability``: the target is dropped once its sum is at or below this (from the cap:
    four looks at p 0.2, or three at p 0.12 and below)."""
    evidence_switch: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    """``probability``: the track vision chose replaces the target once its sum is at least
    this and above the target's (two looks at p 0.75, one at p 0.88)."""
    evidence_reacquire: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    """``probability``: a lost target is re-taken by vision's choice once that track's sum is
    at least this."""
    near_guard_m: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """The target is "surely the one vision last accepted" while its track took a candidate on
    every scan since and no other track came within this distance of it; a target that was
    hidden, or passed someone on the way, is judged as usual. 0: near rejections never count.
    docs/tracker_log.md: a target circling near the robot tracked 1.00 on all 8 seeds."""
    rollback: bool = True
    """Roll the target back to its state before a candidate that vision rejected (core.py's
    module doc); false: only count the rejection towards reject_votes."""
    rollback_max_s: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """Farthest back (scan time before the rejected scan) a rollback goes."""
    rollback_jump_m: Annotated[float, msgspec.Meta(ge=0)] = 0.15
    """... only when that candidate also lay this far or farther from the target's prediction
    (1.25 m/s over one 120 ms scan): the target itself, seen where it was expected while its
    look changes (turning round, lighting), is not split off by a rejection."""
    laser_reacquire_m: Annotated[float, msgspec.Meta(ge=0)] = 0.7
    """Without vision only: a lost target is re-taken by the track nearest to where it was
    lost, within this distance (0: never without vision)."""
    laser_reacquire_min_speed_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.25
    """... and only a track walking at least this fast (its recent velocity): clutter where
    the target vanished stays put (0: any track). Beyond the thesis.
    docs/tracker_log.md: 76 runs, 1.2 s on wrong people went to 0."""
    laser_reacquire_min_range_m: Annotated[float, msgspec.Meta(ge=0)] = 0.3
    """... and only a track at least this far from the laser: nearer, it is the robot's own
    body or something it drove up to, not a person (a person's centre lies a leg's radius
    plus the robot's half-width away at the least)."""
    laser_reacquire_max_s: Annotated[float, msgspec.Meta(ge=0)] | None = 3.0
    """... and only this long after the loss (None: any time): a walker is 0.7 m on in under
    3 s; later, whoever passes where the target was lost is someone else. Beyond the thesis.
    docs/tracker_log.md: time on wrong people over 76 runs 16.2 -> 8.4 s."""
    laser_reacquire_with_vision: bool = True
    """With vision too, the laser re-takes a lost target by the rule above, unless vision
    has rejected that track since the loss or its evidence is at the level that drops a
    target (vision confirms or vetoes a re-take; issue 35: it is not needed for it). False:
    with vision, only vision's choice re-takes."""


class SearchSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Where the camera looks for a lost target, and whom vision may re-take (search.py)."""

    enabled: bool = True
    """Beyond the thesis: while the target is lost (and vision alive), name in tracking/target
    a person for the camera to look at (``look_*``), so vision can judge them and re-acquire
    the target by appearance; the controller pans there, the base stays still. Walking tracks
    first, nearest to where the target should be first; each in turn until vision has judged
    it (or dwell_s passed); those vision rejected ``rejections`` times are skipped.
    False: the camera stays where the target was lost (the thesis).
    docs/tracker_log.md: a target behind a pillar re-acquired in 0.0-1.56 s instead of ~21 s."""
    dwell_s: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    """How long the camera stays on one person vision has not judged yet."""
    rejections: Annotated[int, msgspec.Meta(ge=1, le=100)] = 2
    """A person vision rejected this many times since the loss is not looked at again."""
    min_range_m: Annotated[float, msgspec.Meta(ge=0)] = 0.3
    """Nearer than this the camera is not turned to a person (it would see too little of them
    to judge). docs/tracker_log.md: 0.3 re-takes a target coming back beside the stopped robot
    0.1-1.4 s sooner than 0.5."""
    moving_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.25
    """A track at least this fast counts as walking (looked at first)."""
    gate_m: Annotated[float, msgspec.Meta(gt=0)] | None = 0.5
    """Beyond the thesis, while enabled: look only at tracks near where the lost target
    should be now -- within gate_m + gate_mps x (time since the loss) of its last
    position moved on at its coasting velocity (for at most predict_s) -- and re-take by
    appearance only such a track, for max_s after the loss; with no such track the
    camera looks at that predicted point. (A verification that drops the target by rejecting
    it and chooses another track is a switch: that track is taken wherever it is.) None: look
    at every track in turn, for as long as the target is lost."""
    gate_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.5
    """How fast the gate grows (a walker's pace)."""
    gate_since_seen: bool = True
    """The gate grows with the time since the target was last *seen* (its last laser update),
    not since the loss was declared, which comes a miss budget (~1 s) later while a hidden
    person walks on. Vision re-takes someone in that outer ring (outside the radius grown
    since the loss) only on a close match, wide_max_distance. False: since the loss."""
    predict_s: Annotated[float, msgspec.Meta(ge=0)] = 2.0
    """How long the lost target is carried on at its coasting velocity."""
    within_reach: bool = True
    """Where the lost target should be is kept within the detector's reach
    (perception/candidates ``reach_m``): a target who walked out of reach is looked for, and
    re-taken on an ordinary acceptance, where it would come back into it. Candidates without
    a reach: as False, the point walks on.
    docs/tracker_log.md: of 76 runs one changes, tracked 0.75 -> 0.85."""
    max_s: Annotated[float, msgspec.Meta(ge=0)] = 4.0
    """How long after the loss the look gate applies."""
    wide_max_distance: Annotated[float, msgspec.Meta(ge=0)] | None = 0.45
    """Past max_s the camera also looks, in turn, at each newcomer -- a person first
    tracked after the loss -- farther than wide_gate_m from where the target should be,
    with a dwell on that point between rounds, and vision re-takes someone that far away only
    on a close match: distance at most this. Nearer, anyone vision accepts is taken. For a
    target that comes back somewhere else than where it went out of view. None: off.
    docs/tracker_log.md: 0.45 lies below every bystander's distance in 30 runs (lowest 0.468)."""
    wide_gate_m: Annotated[float, msgspec.Meta(gt=0)] = 1.5
    """docs/tracker_log.md: targets came back 0.6 m and 2.2 m from where they should be."""
    keep_misses: Annotated[int, msgspec.Meta(ge=0, le=100)] = 2
    """The camera keeps looking at the person it turned to while their track has missed at
    most this many scans in a row (within dwell_s), so a track that flickers (someone
    half hidden) does not swing the camera to and fro. 0: a single miss moves it on."""
    turn_deg_s: Annotated[float, msgspec.Meta(gt=0)] | None = 90.0
    """The camera's pan rate (thesis 5.2.5: 90 deg/s). The dwell_s on a person runs from
    when a camera turning at this rate from where it was last sent can point at them, not
    from when it is sent (a turn of 178 deg takes 2 s). None: from when it is sent."""
    new_first: bool = True
    """A newcomer not yet looked at since the loss ends the camera's dwell on where the target
    should be at once (the dwell is between rounds of looking again at the same people).
    False: the dwell runs out first."""
    occluder_edge: bool = True
    """When nobody is there to look at and the point where the lost target should be is
    hidden from the laser (something nearer covers it in the scan's horizon), the camera looks
    past the edge of that cover on the side the target was walking towards, where it will come
    out (search.py's occluder_edge). The gate, and whom vision may re-take, do not change.
    docs/tracker_log.md: re-acquired within 1 s 31 of 55 occlusions (28 of 54 without)."""


class EvidenceSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """``initiator: evidence``: what makes a tentative track a person (initiators.py), judged
    on its sightings of the last ``window_s``. Every condition must hold at one update; the
    track is a person from then on."""

    window_s: Annotated[float, msgspec.Meta(gt=0)] = 3.0
    """How far back the sightings are judged: a track on clutter that took a candidate now
    and then, or hopped to other clutter after a long gap, shows no walk within it."""
    min_hits: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 5
    """Candidates the track took within the window, at the least (a scan rate of at least
    min_hits / window_s is needed to confirm anyone)."""
    min_travel_m: Annotated[float, msgspec.Meta(ge=0)] = 0.5
    """How far its estimate went within the window, from the first sighting to the last
    (odometry frame; without odometry the base frame), at the least. ROS leg_tracker: ~0.5 m."""
    min_straightness: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.6
    """That travel over the length of the path it took, at the least: a walker goes
    somewhere, a track jittering in place or hopping between clutter does not."""
    path_step_m: Annotated[float, msgspec.Meta(gt=0)] = 0.1
    """The path is measured between positions this far apart, so the estimate's jitter round
    a standing person does not count as walking."""
    max_speed_mps: Annotated[float, msgspec.Meta(gt=0)] = 2.5
    """The travel over the time it took, at the most (a brisk walk): a track that jumped from
    one thing to another is not a walker."""
    min_confidence: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.0
    """The mean detector confidence of the candidates it took, at the least (0: any)."""
    edge_margin_deg: Annotated[float, msgspec.Meta(ge=0, le=90)] = 10.0
    """A candidate with a leg this near either end of the laser's view (a laser that does
    not see all round) is no evidence: it is not a sighting (0: off)."""


class TrackerSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    retired_settings: ClassVar[dict[str, str]] = RETIRED_SETTINGS

    estimator: str = "particle"
    """Estimator plugin (entry-point group followbot.estimators): particle, ukf, ..."""
    estimator_settings: dict[str, Any] = {}
    """Overrides of the estimator's own settings, e.g. {particles: 500, resampler: sorted_copy}."""
    seed: int = 0
    """Seed of every random draw (each track's Generator is seeded with [seed, track id])."""
    max_misses: Annotated[int, msgspec.Meta(ge=0, le=10_000)] = 8
    """A track is deleted after more than this many consecutive misses (thesis 3.6.2.8: 8,
    about 1 s at 120 ms); the target is then lost."""
    initiator: Literal["hits", "evidence"] = "hits"
    """When a tentative track becomes a person -- reported in tracking/people, looked at while
    the target is lost, a first target for ``acquire: nearest`` (initiators.py): ``hits``
    (the thesis) once it took confirm_hits candidates; ``evidence`` once it travelled as a
    walker does (``evidence.*``). Either way it stays a person until deleted."""
    confirm_hits: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 2
    """``initiator: hits``: a new track is a person once it took this many candidates."""
    evidence: EvidenceSettings = msgspec.field(default_factory=EvidenceSettings)
    """``initiator: evidence``'s rule: ``--set evidence.min_travel_m=0.4``."""
    coast_velocity_s: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """Beyond the thesis: a track that missed its candidate moves on at the person's recent
    velocity -- the median of its step velocities over this many seconds, so one update
    pulled aside by a passer-by's leg does not turn it -- instead of staying where it was last
    seen. Only for estimators without velocity memory (the particle filter). 0: off."""
    coast_max_speed_mps: Annotated[float, msgspec.Meta(gt=0)] = 2.5
    """The coasting velocity is clipped to this speed (a brisk walk)."""
    occlusion_margin_m: Annotated[float, msgspec.Meta(ge=0)] = 0.3
    """A return counts as hiding a person when it is this much nearer than the person's
    range (a person's legs lie ~0.1 m either side of their centre)."""
    occlusion_radius_m: Annotated[float, msgspec.Meta(gt=0)] = 0.2
    """Half-width of a person as the laser sees them: the bearings checked round a position
    for cover, and the bearing window of association.front_margin_m."""
    lone_leg_output_m: Annotated[float, msgspec.Meta(ge=0, le=0.5)] = 0.1
    """Beyond the thesis: the target's *reported* position takes a leg seen alone for a person
    centred this far beyond it along its bearing (the near leg mostly hides the other), while
    the filter that associates candidates keeps the leg where it was measured. The estimate
    is carried forward with a shift: what it would be had every lone leg of its updates been
    moved out. tracking/target and the target's tracking/people entry report estimate plus
    shift (tracking/target also the shift, ``shift_x_m``/``_y_m``); association, gates,
    coasting and rollbacks use the estimate alone. Particle estimator only; 0: off.
    docs/tracker_log.md: RMSE <= 0.08 m on 75 of 76 runs (69 without)."""
    acquire: Literal["vision", "nearest"] = "vision"
    """How the first target is chosen: by vision (a verification or perception/target_model),
    or, without a camera, the nearest person ahead (a track the initiator confirmed) within
    identity.acquire_range_m."""
    vision_lag_scans: Annotated[int, msgspec.Meta(ge=0, le=1000)] = 0
    """Lock-step: apply the verification of scan k at the step of scan k + N (>= k + 1)."""
    vision_stale_s: Annotated[float, msgspec.Meta(gt=0)] = 2.0
    """No verification that judged a candidate newer than this (scan clock) -> flag
    vision_stale, gate on laser alone (and re-acquire a lost target near where it was lost)."""
    history_scans: Annotated[int, msgspec.Meta(ge=1, le=100_000)] = 64
    """Scans remembered for late verifications and rollbacks."""
    max_odometry_extrapolation_s: Annotated[float, msgspec.Meta(ge=0)] = 0.1
    """A scan newer than the newest odometry by at most this takes the pose extrapolated
    along the last twist; later, it goes uncompensated (flag ``no_odometry``)."""
    default_dt_s: Annotated[float, msgspec.Meta(gt=0)] = 0.12
    """Time step of the first scan (thesis 4.1.1: 120 ms)."""
    max_dt_s: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    """Longer gaps between scans are clamped (a paused recording must not explode the cloud)."""
    association: AssociationSettings = msgspec.field(default_factory=AssociationSettings)
    """Which track takes which candidate: ``--set association.assignment=most_matches``."""
    identity: IdentitySettings = msgspec.field(default_factory=IdentitySettings)
    """Which track is the target: ``--set identity.switch_votes=3``."""
    search: SearchSettings = msgspec.field(default_factory=SearchSettings)
    """Where to look for a lost target: ``--set search.gate_m=0.8``."""

    def __post_init__(self) -> None:
        # checked while the settings load, so an unknown estimator or a bad estimator setting
        # fails before any network is opened (exit code 2, the message naming it)
        try:
            estimator_factory(self.estimator, self.estimator_settings)
        except LookupError as exc:  # plugins.UnknownPlugin
            raise ValueError(str(exc).strip("'\"")) from None
