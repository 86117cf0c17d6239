"""Scenario evaluation: metrics, plots and the report of a lock-step run.

Pure functions on recorded messages: no Zenoh, no processes. The orchestrator runs a scenario
in lock-step, fills one :class:`ScanRecord` per scan and hands a :class:`ScenarioRun` to
:func:`compute_metrics`; :func:`plot_run` draws it and :func:`write_report` writes
``report.md`` and ``summary.json`` for any number of runs (scenarios x presets). These are
the only definitions of the metrics below: ``followbot eval``, ``followbot sweep`` and the
in-process loop of ``followbot.research.closedloop`` all compute them here.

Frames and time
===============

Truth people carry world (``x_m, y_m``) and robot-frame (``robot_x_m, robot_y_m``) positions;
candidates, verified candidates, the target estimate and the people tracks are in the robot
frame of the scan they derive from (laser at the robot origin). Errors are measured in that
robot frame; for world plots an estimate p is mapped with the true robot pose (x, y, yaw) of
its scan: w = R(yaw) p + (x, y).

Records are sorted by ``stamp_ns``. Time-weighted metrics give scan k the duration
dt_k = stamp_{k+1} - stamp_k; the last scan gets the median scan period (0 with one scan).

"Tracked" means the tracker's ``TrackState.status`` is ``tracking`` or ``coasting``; its error
e_k is the distance from (x_m, y_m) to the true target (robot frame). "The target" is the
person whose id is ``GroundTruth.target_id`` (else the one with ``is_target``).

Metrics (DESIGN.md "Metric definitions"; names as in reports and JSON)
=====================================================================

Candidate detection, thesis Table 5.1 (``candidates_*``)
    Over scans where the target is visible to the laser and a candidates message was
    recorded (``candidates_scans``): the candidate nearest the true target within 0.3 m is
    a two-leg detection when it has two legs, a one-leg detection when it has one, and a
    detection without leg information when it has none (camera-only detectors); no
    candidate within 0.3 m is "undetected". ``candidates_two_leg_share``,
    ``candidates_one_leg_share``, ``candidates_undetected_share`` and
    ``candidates_no_legs_share`` (the four sum to 1). Scans without a candidates message are
    left out (the run's ``timeouts`` say how many stage answers were missing).

Verification accuracy (``verification_*``)
    The target's candidate in a verification is the verified candidate nearest the true
    target, if within 0.3 m. ``verification_scans``: scans where the target is visible to the
    camera and the verification naming the scan chose a candidate (``chosen >= 0``);
    ``verification_accuracy`` = share of those where the chosen candidate is the target's.
    ``verification_rejected``: scans with the target in camera view whose verification chose
    none. ``verification_bystander_choices``: scans where the target is *not* visible to the
    camera and the verification chose a candidate that is not the target's (a bystander taken
    for the target); ``verification_bystander_share`` divides it by the scans with the target
    out of camera view that have a verification.

``rmse_m``
    sqrt(mean e_k^2) over scans where the target is visible to the laser and tracked
    (``scans_target_visible`` counts the visible scans).

``tracked_visible_share``
    Scans with the target visible to the laser and tracked with e_k <= 0.5 m, divided by the
    scans where the target is visible to the laser.

``tracked_visible_share_acquired``
    The same from the first tracked scan on: the time before the target model exists (thesis
    4.2: learnt while the target moves alone in front of the still robot, 2-4 s in most
    scenarios) is left out, so this says how well a target is kept once it is known.

``followed_share_acquired``
    Time tracked within e_k <= 0.5 m of the target, visible or not, divided by the time from
    the first tracked scan to the end of the run. The visible shares above cannot see a
    target lost for good out of the robot's view (the robot stopped facing away, the person
    walked on behind it): its scans are not visible, so they are not missed either. This one
    counts them (a target that really is out of every sensor's reach for a while lowers it
    too, so compare it between runs of one scenario).

``identity_switches``, ``wrong_target_s``
    At each tracked scan the estimate is "on" the nearest true person (visible or not) if that
    person is within 0.5 m, else on nobody. It is on another person when that nearest person
    is not the target (so: nearer another person than the target and within 0.5 m of that
    person). An identity switch is counted each time the estimate is on another person and the
    last person it was on (earlier scans, skipping scans on nobody or untracked) was the
    target. ``wrong_target_s``: total duration of scans on another person.

``acquired_s``
    Time from the first scan to the first scan with the target tracked (None: never; e.g. the
    thesis acquisition never built a target model because the target did not move close
    enough in front of the still robot).

``follow_distance_share``
    Time with the true robot-to-target distance in [1.0, 2.0] m divided by the time tracked
    (``tracked_s``).

``robot_bumps``
    The simulator's count of the robot's contacts with the world (``GroundTruth.robot_bumps``
    at the run's end; its bumper stops the base there, docs/scenarios.md). A follower that
    drives into furniture shows here, whatever its tracking figures.

``reacquire_s``
    An occlusion episode is a maximal run of scans with the target not visible to the laser,
    at least ``min_occlusion_s`` long (default 0.2 s, so a one-scan dropout at 8-10 Hz is not
    an occlusion; first hidden stamp to first visible-again stamp; a glimpse shorter than that,
    hidden again or at the end of the run, is part of the occlusion), with the target tracked
    (visible, e_k <= 0.5 m) at some time before it and visible after it: an occlusion before
    the target was first acquired is not one it can be *re*-acquired after (the time to the
    first acquisition is ``acquired_s``). Its re-acquisition time is from the stamp of the
    first visible-again scan to the first later scan where the target is visible and tracked
    with e_k <= 0.5 m. ``reacquire_s_episodes`` lists them (null: never re-acquired before
    the end of the run, also counted in ``reacquire_failures``); ``reacquire_s`` is the mean
    of the re-acquired episodes (None when there were none); ``occlusions`` counts episodes.
    Where that time goes, per episode, from the same first visible-again stamp:
    ``reacquire_laser_s_episodes`` to the first scan with a laser candidate within
    ``candidate_match_m`` of the target, ``reacquire_camera_s_episodes`` to the first scan
    with the target in the camera's view (null: not before the end of the run). Re-taking the
    target by appearance needs both; what is left after the later of the two is the tracker's
    and vision's decision. ``reacquire_turn_s_episodes``: the least time a camera turning at
    once, at ``camera_pan_rate_deg_s``, from where this one pointed at that first scan would
    need to bring the target's centre into its ``camera_hfov_deg`` -- a bound no tracker
    can beat by appearance whose camera was pointed there (0 when it was in view already).

CLEAR-MOT over all people (``mota``, ``motp_m``, ``misses``, ``false_positives``, ``id_switches``)
    Bernardin & Stiefelhagen (2008). Ground-truth objects: the truth people visible to the
    laser; hypotheses: the ``People`` tracks of the scan (none when no message). Per scan,
    the previous scan's matches are kept while both still exist and are within 0.75 m; the
    remaining objects and hypotheses are matched by the Hungarian method
    (``scipy.optimize.linear_sum_assignment``) on distance, pairs beyond 0.75 m forbidden.
    A match whose hypothesis differs from the object's last matched hypothesis (from any
    earlier scan) is an id switch. misses = unmatched objects, false positives = unmatched
    hypotheses; MOTA = 1 - (misses + false_positives + id_switches) / objects (None when there
    are no objects); MOTP = mean distance of the matches (None without matches);
    ``mot_objects``, ``mot_matches``.

Latency (``latency_ms``)
    Per stage (laser_legs, vision_verify, tracker, controller: arrival of its output minus
    arrival of the scan as seen by the evaluator): ``p50_ms``, ``p99_ms``, ``max_ms`` (numpy
    linear percentiles) and ``n``, over the records that carry the stage.

``real_time_factor``
    ``sim_s / wall_s`` (None when the wall time is unknown); ``timeouts`` as recorded, and
    ``timeouts_total``.

Thresholds live in :class:`EvaluationSettings` (defaults as above). Every value that cannot be
computed (empty denominator) is None, written as JSON null; :func:`write_report` also maps any
NaN/inf to null, so summary.json is strict JSON.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from followbot.schemas import (
    Candidate,
    GroundTruth,
    People,
    PersonCandidates,
    PersonTruth,
    TrackState,
    VelocityCommand,
    Verification,
)

__all__ = [
    "KEY_METRICS",
    "STAGES",
    "EvaluationSettings",
    "ScanRecord",
    "ScenarioRun",
    "compute_metrics",
    "plot_run",
    "summary",
    "write_report",
]

_NS = 1_000_000_000

#: Pipeline stages whose latency a record may carry, in pipeline order.
STAGES = ("laser_legs", "vision_verify", "tracker", "controller")
_TRACKED = frozenset({"tracking", "coasting"})


# --------------------------------------------------------------------------- input


class ScanRecord(msgspec.Struct, kw_only=True):
    """Everything the evaluator saw for one scan of a lock-step run."""

    stamp_ns: int  # sim-clock stamp of the scan
    truth: GroundTruth  # truth at the scan stamp
    candidates: PersonCandidates | None = None
    verification: Verification | None = None  # the verification naming this scan
    target: TrackState | None = None  # tracker output for this scan (base_link of that scan)
    people: People | None = None
    cmd: VelocityCommand | None = None
    latency_ms: dict[str, float] = {}  # per stage: output arrival minus scan arrival


class ScenarioRun(msgspec.Struct, kw_only=True):
    """One scenario run with one preset."""

    scenario: str
    preset: str
    records: list[ScanRecord]
    timeouts: dict[str, int] = {}
    wall_s: float = 0.0  # wall time of the run
    sim_s: float = 0.0  # simulated time covered


class EvaluationSettings(msgspec.Struct, frozen=True, kw_only=True):
    """Thresholds of the metric definitions (defaults: DESIGN.md "Metric definitions")."""

    candidate_match_m: float = 0.3  # Table 5.1 and verification: candidate within 0.3 m
    track_match_m: float = 0.5  # tracked_visible_share, identity switches, re-acquisition
    mot_match_m: float = 0.75  # CLEAR-MOT match threshold
    follow_band_m: tuple[float, float] = (1.0, 2.0)  # follow_distance_share
    # A hidden run shorter than this is a dropout, not an occlusion episode (not in DESIGN.md:
    # one or two missed scans at 8-10 Hz should not count as occlusions with 0 s re-acquisition).
    min_occlusion_s: float = 0.2
    # reacquire_turn_s_episodes: the simulator's camera (CameraSpec.hfov_deg, RobotSpec's
    # pan_rate_deg_s; DESIGN.md: pan <= 90 deg/s)
    camera_hfov_deg: float = 47.5
    camera_pan_rate_deg_s: float = 90.0

    def __post_init__(self) -> None:
        for name in (
            "candidate_match_m", "track_match_m", "mot_match_m", "camera_hfov_deg",
            "camera_pan_rate_deg_s",
        ):  # fmt: skip
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        lo, hi = self.follow_band_m
        if not 0 <= lo <= hi:
            raise ValueError(f"follow_band_m must be 0 <= lo <= hi, got {self.follow_band_m}")
        if not self.min_occlusion_s >= 0:
            raise ValueError(f"min_occlusion_s must be >= 0, got {self.min_occlusion_s}")


# --------------------------------------------------------------------------- helpers


def _target_truth(truth: GroundTruth) -> PersonTruth | None:
    for p in truth.people:
        if p.id == truth.target_id:
            return p
    return next((p for p in truth.people if p.is_target), None)


def _is_tracked(target: TrackState | None) -> bool:
    return target is not None and target.status in _TRACKED


def _durations_s(stamps_ns: Sequence[int]) -> np.ndarray:
    """dt_k = stamp_{k+1} - stamp_k; the last scan gets the median period (0 alone)."""
    t = np.asarray(stamps_ns, dtype=np.int64)
    if t.size < 2:
        return np.zeros(t.size)
    d = np.diff(t) / _NS
    return np.append(d, float(np.median(d)))


def _error_m(target: TrackState, person: PersonTruth) -> float:
    return math.hypot(target.x_m - person.robot_x_m, target.y_m - person.robot_y_m)


def _on_person(truth: GroundTruth, target: TrackState, max_m: float) -> PersonTruth | None:
    """The true person nearest the estimate, if within ``max_m`` (visible or not)."""
    on, on_d = None, math.inf
    for p in truth.people:
        d = _error_m(target, p)
        if d <= max_m and d < on_d:
            on, on_d = p, d
    return on


def _share(num: float, den: float) -> float | None:
    return num / den if den > 0 else None


def _to_world(truth: GroundTruth, x_m: float, y_m: float) -> tuple[float, float]:
    """Robot frame of the scan -> world, with the true robot pose: w = R(yaw) p + r."""
    c, s = math.cos(truth.robot_yaw_rad), math.sin(truth.robot_yaw_rad)
    return truth.robot_x_m + c * x_m - s * y_m, truth.robot_y_m + s * x_m + c * y_m


def _sorted_records(run: ScenarioRun) -> list[ScanRecord]:
    return sorted(run.records, key=lambda r: r.stamp_ns)


# --------------------------------------------------------------------------- metrics


def _candidate_detection(records: list[ScanRecord], s: EvaluationSettings) -> dict[str, Any]:
    counts = {"two_leg": 0, "one_leg": 0, "no_legs": 0, "undetected": 0}
    for rec in records:
        tgt = _target_truth(rec.truth)
        if tgt is None or not tgt.visible_laser or rec.candidates is None:
            continue
        best = _candidate_on(rec.candidates, tgt, s.candidate_match_m)
        if best is None:
            counts["undetected"] += 1
        else:
            counts[{2: "two_leg", 1: "one_leg"}.get(len(best.legs), "no_legs")] += 1
    n = sum(counts.values())
    return {
        "candidates_scans": n,
        "candidates_two_leg_share": _share(counts["two_leg"], n),
        "candidates_one_leg_share": _share(counts["one_leg"], n),
        "candidates_undetected_share": _share(counts["undetected"], n),
        "candidates_no_legs_share": _share(counts["no_legs"], n),
    }


def _first_after(records: list[ScanRecord], flags: list[bool], k: int) -> float | None:
    """Seconds from scan ``k`` to the first scan from ``k`` on whose flag is set (None: none)."""
    j = next((j for j in range(k, len(records)) if flags[j]), None)
    return None if j is None else (records[j].stamp_ns - records[k].stamp_ns) / _NS


def _candidate_on(
    cands: PersonCandidates | None, tgt: PersonTruth, within_m: float
) -> Candidate | None:
    """The candidate nearest the person, if one lies within ``within_m`` of them."""
    best, best_d = None, within_m
    for c in cands.candidates if cands is not None else ():
        d = math.hypot(c.x_m - tgt.robot_x_m, c.y_m - tgt.robot_y_m)
        if d <= best_d:
            best, best_d = c, d
    return best


def _target_candidate(ver: Verification, tgt: PersonTruth, max_m: float) -> int:
    """Index in ``ver.candidates`` of the one nearest the true target within max_m, or -1."""
    best, best_d = -1, max_m
    for i, c in enumerate(ver.candidates):
        d = math.hypot(c.x_m - tgt.robot_x_m, c.y_m - tgt.robot_y_m)
        if d <= best_d:
            best, best_d = i, d
    return best


def _verification(records: list[ScanRecord], s: EvaluationSettings) -> dict[str, Any]:
    judged = correct = rejected = hidden = bystander = 0
    for rec in records:
        ver, tgt = rec.verification, _target_truth(rec.truth)
        if ver is None or tgt is None:
            continue
        own = _target_candidate(ver, tgt, s.candidate_match_m)
        if tgt.visible_camera:
            if ver.chosen < 0:
                rejected += 1
                continue
            judged += 1
            correct += ver.chosen == own
        else:
            hidden += 1
            bystander += ver.chosen >= 0 and ver.chosen != own
    return {
        "verification_scans": judged,
        "verification_accuracy": _share(correct, judged),
        "verification_rejected": rejected,
        "verification_bystander_choices": bystander,
        "verification_bystander_share": _share(bystander, hidden),
    }


def _tracking(records: list[ScanRecord], dt_s: np.ndarray, s: EvaluationSettings) -> dict:
    sq: list[float] = []
    visible = good = switches = 0
    visible_acq = good_acq = 0  # from the first tracked scan on
    wrong_s = tracked_s = band_s = 0.0
    after_acq_s = followed_s = 0.0  # from the first tracked scan on: all time, time on target
    last_on: int | None = None  # id of the last person the estimate was on
    acquired_s: float | None = None  # first time the target was tracked (None: never)
    t0 = records[0].stamp_ns if records else 0
    lo, hi = s.follow_band_m
    for rec, dt in zip(records, dt_s.tolist(), strict=True):
        tgt = _target_truth(rec.truth)
        tracked = _is_tracked(rec.target)
        if tracked and acquired_s is None:
            acquired_s = (rec.stamp_ns - t0) / 1e9
        e = _error_m(rec.target, tgt) if tracked and tgt is not None else None
        if acquired_s is not None:
            after_acq_s += dt
            if e is not None and e <= s.track_match_m:
                followed_s += dt
        if tgt is not None and tgt.visible_laser:
            visible += 1
            visible_acq += acquired_s is not None
            if e is not None:
                sq.append(e * e)
                good += e <= s.track_match_m
                good_acq += e <= s.track_match_m
        if not tracked:
            continue
        tracked_s += dt
        if tgt is not None and lo <= math.hypot(tgt.robot_x_m, tgt.robot_y_m) <= hi:
            band_s += dt
        on = _on_person(rec.truth, rec.target, s.track_match_m)
        if on is None:
            continue
        if tgt is not None and on.id != tgt.id:
            wrong_s += dt
            if last_on == tgt.id:
                switches += 1
        last_on = on.id
    return {
        "scans_target_visible": visible,
        "rmse_m": math.sqrt(sum(sq) / len(sq)) if sq else None,
        "tracked_visible_share": _share(good, visible),
        "tracked_visible_share_acquired": _share(good_acq, visible_acq),
        "followed_share_acquired": _share(followed_s, after_acq_s),
        "identity_switches": switches,
        "wrong_target_s": wrong_s,
        "tracked_s": tracked_s,
        "acquired_s": acquired_s,
        "follow_distance_share": _share(band_s, tracked_s),
    }


def _reacquisition(records: list[ScanRecord], s: EvaluationSettings) -> dict[str, Any]:
    vis, ok, cand, cam = [], [], [], []
    for rec in records:
        tgt = _target_truth(rec.truth)
        v = tgt is not None and tgt.visible_laser
        vis.append(v)
        ok.append(v and _is_tracked(rec.target) and _error_m(rec.target, tgt) <= s.track_match_m)
        cand.append(v and _candidate_on(rec.candidates, tgt, s.candidate_match_m) is not None)
        cam.append(v and tgt.visible_camera)
    episodes: list[float | None] = []
    parts: dict[str, list[float | None]] = {"laser": [], "camera": [], "turn": []}
    k, n = 0, len(records)
    seen = False
    while k < n:
        if vis[k]:
            seen = seen or ok[k]  # tracked before: an occlusion from now on is re-acquisition
            k += 1
            continue
        start = k
        while True:  # to the end of the occlusion: a glimpse shorter than min_occlusion_s
            while k < n and not vis[k]:  # (hidden again after it, or the run ends) is part
                k += 1  # of it, as a dropout shorter than that is no occlusion
            m = k
            while m < n and vis[m]:
                m += 1
            end_ns = records[m].stamp_ns if m < n else records[-1].stamp_ns
            if k == n or (end_ns - records[k].stamp_ns) / _NS >= s.min_occlusion_s:
                break
            k = m
        if not seen or k == n:  # never seen before, or never seen again: no episode
            continue
        if (records[k].stamp_ns - records[start].stamp_ns) / _NS < s.min_occlusion_s:
            continue
        episodes.append(_first_after(records, ok, k))
        parts["laser"].append(_first_after(records, cand, k))
        parts["camera"].append(_first_after(records, cam, k))
        parts["turn"].append(_turn_s(records[k].truth, s))
    done = [e for e in episodes if e is not None]
    return {
        "occlusions": len(episodes),
        "reacquire_s": sum(done) / len(done) if done else None,
        "reacquire_s_episodes": episodes,
        "reacquire_failures": len(episodes) - len(done),
        "reacquire_laser_s_episodes": parts["laser"],
        "reacquire_camera_s_episodes": parts["camera"],
        "reacquire_turn_s_episodes": parts["turn"],
    }


def _turn_s(truth: GroundTruth, s: EvaluationSettings) -> float | None:
    """Least time to turn the camera from its pan in ``truth`` until the target's centre is
    in view (module docstring, ``reacquire_turn_s_episodes``)."""
    tgt = _target_truth(truth)
    if tgt is None:
        return None
    off = math.atan2(tgt.robot_y_m, tgt.robot_x_m) - truth.camera_pan_rad
    off = abs(math.atan2(math.sin(off), math.cos(off)))
    return max(0.0, off - math.radians(s.camera_hfov_deg) / 2) / math.radians(
        s.camera_pan_rate_deg_s
    )


def _clear_mot(records: list[ScanRecord], s: EvaluationSettings) -> dict[str, Any]:
    from scipy.optimize import linear_sum_assignment

    thr = s.mot_match_m
    objects = matches = misses = fps = switches = 0
    dist_sum = 0.0
    prev: dict[int, int] = {}  # object id -> hypothesis id, previous scan
    last: dict[int, int] = {}  # object id -> last hypothesis it was matched to, ever
    for rec in records:
        gt = {p.id: (p.robot_x_m, p.robot_y_m) for p in rec.truth.people if p.visible_laser}
        hyp = {t.id: (t.x_m, t.y_m) for t in rec.people.tracks} if rec.people else {}
        objects += len(gt)
        cur: dict[int, tuple[int, float]] = {}
        for o, h in prev.items():
            if o in gt and h in hyp:
                d = math.dist(gt[o], hyp[h])
                if d <= thr:
                    cur[o] = (h, d)
        used = {h for h, _ in cur.values()}
        free_o = [o for o in gt if o not in cur]
        free_h = [h for h in hyp if h not in used]
        if free_o and free_h:
            cost = np.array([[math.dist(gt[o], hyp[h]) for h in free_h] for o in free_o])
            big = 1e6  # forbidden pairs: any valid assignment costs less than one of these
            rows, cols = linear_sum_assignment(np.where(cost <= thr, cost, big))
            for i, j in zip(rows, cols, strict=True):
                if cost[i, j] <= thr:
                    cur[free_o[i]] = (free_h[j], float(cost[i, j]))
        for o, (h, d) in cur.items():
            if o in last and last[o] != h:
                switches += 1
            last[o] = h
            dist_sum += d
        matches += len(cur)
        misses += len(gt) - len(cur)
        fps += len(hyp) - len(cur)
        prev = {o: h for o, (h, _) in cur.items()}
    return {
        "mota": 1.0 - (misses + fps + switches) / objects if objects else None,
        "motp_m": dist_sum / matches if matches else None,
        "misses": misses,
        "false_positives": fps,
        "id_switches": switches,
        "mot_objects": objects,
        "mot_matches": matches,
    }


def _latency(records: list[ScanRecord]) -> dict[str, dict[str, float | int | None]]:
    values: dict[str, list[float]] = {}
    for rec in records:
        for stage, ms in rec.latency_ms.items():
            if ms is not None and math.isfinite(ms):
                values.setdefault(stage, []).append(float(ms))
    order = [st for st in STAGES if st in values] + sorted(set(values) - set(STAGES))
    out: dict[str, dict[str, float | int | None]] = {}
    for stage in order:
        v = np.asarray(values[stage])
        out[stage] = {
            "p50_ms": float(np.percentile(v, 50)),
            "p99_ms": float(np.percentile(v, 99)),
            "max_ms": float(v.max()),
            "n": int(v.size),
        }
    return out


def compute_metrics(run: ScenarioRun, settings: EvaluationSettings | None = None) -> dict:
    """Every metric of the module docstring for one run, as a JSON-ready dict (None = n/a)."""
    s = settings or EvaluationSettings()
    records = _sorted_records(run)
    dt_s = _durations_s([r.stamp_ns for r in records])
    metrics: dict[str, Any] = {
        "scenario": run.scenario,
        "preset": run.preset,
        "scans": len(records),
    }
    metrics.update(_tracking(records, dt_s, s))
    metrics.update(_clear_mot(records, s))
    metrics.update(_reacquisition(records, s))
    metrics.update(_candidate_detection(records, s))
    metrics.update(_verification(records, s))
    metrics["follow_band_m"] = list(s.follow_band_m)
    metrics["latency_ms"] = _latency(records)
    metrics["sim_s"] = run.sim_s
    metrics["wall_s"] = run.wall_s
    metrics["real_time_factor"] = run.sim_s / run.wall_s if run.wall_s > 0 else None
    metrics["timeouts"] = dict(run.timeouts)
    metrics["timeouts_total"] = int(sum(run.timeouts.values()))
    # the simulator's bumper: contacts of the robot's body with the world over the run
    metrics["robot_bumps"] = max((r.truth.robot_bumps for r in records), default=0)
    return metrics


# --------------------------------------------------------------------------- plots


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_") or "run"


def _plot_names(run: ScenarioRun) -> dict[str, str]:
    base = f"{_slug(run.scenario)}__{_slug(run.preset)}"
    return {
        "topdown": f"{base}_topdown.png",
        "distance": f"{base}_distance.png",
        "latency": f"{base}_latency.png",
    }


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "–" if not math.isfinite(value) else f"{value:.{digits}g}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_fmt(v, digits) for v in value) + "]"
    return str(value)


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.0f} %"


def _plot_topdown(
    plt, run: ScenarioRun, records: list[ScanRecord], m: dict, s: EvaluationSettings, path: Path
) -> None:
    fig, ax = plt.subplots(figsize=(7.5, 6.5), dpi=110)
    people: dict[int, list[tuple[float, float]]] = {}
    robot = np.array([(r.truth.robot_x_m, r.truth.robot_y_m) for r in records])
    target_id = None
    est, wrong = [], []
    for rec in records:
        tgt = _target_truth(rec.truth)
        if tgt is not None:
            target_id = tgt.id
        for p in rec.truth.people:
            people.setdefault(p.id, []).append((p.x_m, p.y_m))
        if _is_tracked(rec.target):
            est.append(_to_world(rec.truth, rec.target.x_m, rec.target.y_m))
            on = _on_person(rec.truth, rec.target, s.track_match_m)
            if tgt is not None and on is not None and on.id != tgt.id:
                wrong.append(est[-1])
        else:
            est.append((math.nan, math.nan))  # breaks the line while not tracked
    first_other = True
    for pid, pts in people.items():
        if pid == target_id:
            continue
        a = np.array(pts)
        ax.plot(
            a[:, 0],
            a[:, 1],
            color="0.55",
            lw=1.0,
            alpha=0.5,
            label="other people (truth)" if first_other else None,
        )
        ax.annotate(f"{pid}", a[-1], color="0.45", fontsize=8, alpha=0.8)
        first_other = False
    if target_id is not None and target_id in people:
        a = np.array(people[target_id])
        ax.plot(a[:, 0], a[:, 1], color="tab:green", lw=2.4, label=f"target {target_id} (truth)")
        ax.plot(*a[0], marker="o", color="tab:green", ms=7)
    e = np.array(est) if est else np.empty((0, 2))
    if np.isfinite(e).any():
        ax.plot(e[:, 0], e[:, 1], color="tab:orange", lw=1.3, label="target estimate (tracked)")
    if wrong:
        w = np.array(wrong)
        ax.plot(
            w[:, 0],
            w[:, 1],
            ls="none",
            marker="x",
            ms=5,
            color="tab:red",
            label="estimate on another person",
        )
    if robot.size:
        ax.plot(robot[:, 0], robot[:, 1], color="black", lw=1.6, ls="--", label="robot path")
        ax.plot(*robot[0], marker="s", color="black", ms=7, label="robot start")
        ax.plot(*robot[-1], marker=">", color="black", ms=7)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.grid(True, alpha=0.3)
    ax.set_title(
        f"{run.scenario} / {run.preset}: RMSE {_fmt(m.get('rmse_m'))} m, "
        f"tracked {_pct(m.get('tracked_visible_share'))} of visible, "
        f"ID switches {_fmt(m.get('identity_switches'))}",
        fontsize=10,
    )
    ax.legend(loc="best", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _plot_distance(
    plt, run: ScenarioRun, records: list[ScanRecord], m: dict, s: EvaluationSettings, path: Path
) -> None:
    fig, ax = plt.subplots(figsize=(9.0, 4.2), dpi=110)
    t0 = records[0].stamp_ns if records else 0
    t = np.array([(r.stamp_ns - t0) / _NS for r in records])
    true_d, est_d, hidden, wrong = [], [], [], []
    for rec in records:
        tgt = _target_truth(rec.truth)
        true_d.append(math.hypot(tgt.robot_x_m, tgt.robot_y_m) if tgt else math.nan)
        hidden.append(tgt is None or not tgt.visible_laser)
        tracked = _is_tracked(rec.target)
        est_d.append(math.hypot(rec.target.x_m, rec.target.y_m) if tracked else math.nan)
        on = _on_person(rec.truth, rec.target, s.track_match_m) if tracked else None
        wrong.append(tgt is not None and on is not None and on.id != tgt.id)
    lo, hi = m.get("follow_band_m") or EvaluationSettings().follow_band_m
    ax.axhspan(lo, hi, color="tab:green", alpha=0.12, label=f"follow band [{lo:g}, {hi:g}] m")
    if t.size:
        h = np.array(hidden)
        ymax = np.nanmax([*true_d, *est_d, hi]) if np.isfinite(true_d + est_d).any() else hi
        ax.fill_between(
            t,
            0,
            ymax * 1.05,
            where=h,
            step="mid",
            color="0.6",
            alpha=0.25,
            label="target hidden from laser",
        )
        if any(wrong):
            ax.fill_between(
                t,
                0,
                ymax * 1.05,
                where=np.array(wrong),
                step="mid",
                color="tab:red",
                alpha=0.15,
                label="estimate on another person",
            )
        ax.plot(t, true_d, color="tab:green", lw=1.8, label="true distance")
        ax.plot(t, est_d, color="tab:orange", lw=1.0, label="estimated (tracked)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("robot to target (m)")
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    ax.set_title(
        f"{run.scenario} / {run.preset}: in band {_pct(m.get('follow_distance_share'))} "
        "of tracked time",
        fontsize=10,
    )
    ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _plot_latency(plt, run: ScenarioRun, records: list[ScanRecord], m: dict, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(8.0, 4.2), dpi=110)
    values: dict[str, np.ndarray] = {}
    for stage in m.get("latency_ms", {}):
        v = [r.latency_ms[stage] for r in records if stage in r.latency_ms]
        v = np.asarray([x for x in v if x is not None and math.isfinite(x)], dtype=float)
        if v.size:
            values[stage] = v
    if values:
        allv = np.concatenate(list(values.values()))
        lo, hi = max(float(allv.min()), 1e-3), max(float(allv.max()), 1e-3)
        if hi / lo > 20:  # wide spread: log-spaced bins on a log axis
            bins = np.geomspace(lo, hi * 1.001, 40)
            ax.set_xscale("log")
        else:
            bins = np.linspace(min(0.0, float(allv.min())), hi * 1.001 + 1e-6, 40)
        for stage, v in values.items():
            p = m["latency_ms"][stage]
            ax.hist(
                np.clip(v, bins[0], bins[-1]),
                bins=bins,
                histtype="step",
                lw=1.6,
                label=f"{stage}: p50 {p['p50_ms']:.2f} ms, p99 {p['p99_ms']:.2f} ms (n={p['n']})",
            )
        ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
        ax.set_ylabel("scans")
    else:
        ax.text(0.5, 0.5, "no latency recorded", ha="center", va="center", transform=ax.transAxes)
        ax.set_yticks([])
    ax.set_xlabel("latency after the scan arrived (ms)")
    ax.grid(True, alpha=0.3)
    ax.set_title(f"{run.scenario} / {run.preset}: per-stage latency", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_run(
    run: ScenarioRun,
    metrics: dict | None,
    out_dir: str | Path,
    settings: EvaluationSettings | None = None,
) -> list[Path]:
    """Top-down paths, distance to target over time and latency histogram, as PNG files.

    Returns the written paths (topdown, distance, latency) inside ``out_dir``.
    """
    plt = _pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    s = settings or EvaluationSettings()
    m = metrics if metrics is not None else compute_metrics(run, s)
    records = _sorted_records(run)
    names = _plot_names(run)
    paths = [out / names[k] for k in ("topdown", "distance", "latency")]
    _plot_topdown(plt, run, records, m, s, paths[0])
    _plot_distance(plt, run, records, m, s, paths[1])
    _plot_latency(plt, run, records, m, paths[2])
    return paths


# --------------------------------------------------------------------------- report

#: (metric, heading, column, better) of the report's tables; better is "high", "low" or "".
KEY_METRICS: list[tuple[str, str, str, str]] = [
    ("acquired_s", "Target first tracked at (s; - = never)", "acq. s", "low"),
    ("tracked_visible_share", "Tracked while visible (share)", "tracked", "high"),
    ("tracked_visible_share_acquired", "... from the first acquisition on", "tr. acq.", "high"),
    ("followed_share_acquired", "On the target, visible or not, after acq.", "followed", "high"),
    ("rmse_m", "Target RMSE (m)", "RMSE m", "low"),
    ("identity_switches", "Identity switches", "ID sw.", "low"),
    ("wrong_target_s", "Time on a wrong person (s)", "wrong s", "low"),
    ("follow_distance_share", "Follow distance in band (share of tracked time)", "in band", "high"),
    ("robot_bumps", "Robot's contacts with the world (simulator's bumper)", "bumps", "low"),
    ("reacquire_s", "Mean re-acquisition time (s)", "reacq. s", "low"),
    ("mota", "MOTA", "MOTA", "high"),
    ("motp_m", "MOTP (m)", "MOTP m", "low"),
    ("candidates_two_leg_share", "Target found as two legs (share)", "2 legs", "high"),
    ("candidates_undetected_share", "Target undetected by the laser (share)", "undet.", "low"),
    ("verification_accuracy", "Verification accuracy", "verif.", "high"),
    ("e2e_p99_ms", "Scan to cmd_vel latency p99 (ms)", "e2e p99 ms", "low"),
    ("real_time_factor", "Real-time factor (sim s / wall s)", "RTF", ""),
]


def _jsonable(value: Any) -> Any:
    """Plain JSON types; NaN/inf become None; numpy scalars become Python numbers."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _key_value(m: dict, key: str) -> Any:
    if key == "e2e_p99_ms":
        return m.get("latency_ms", {}).get("controller", {}).get("p99_ms")
    return m.get(key)


def _grouped(
    runs_and_metrics: Iterable[tuple[ScenarioRun, dict | None]],
) -> tuple[list[str], list[str], dict[tuple[str, str], tuple[ScenarioRun, dict]]]:
    scenarios: list[str] = []
    presets: list[str] = []
    table: dict[tuple[str, str], tuple[ScenarioRun, dict]] = {}
    for run, metrics in runs_and_metrics:
        key = (run.scenario, run.preset)
        if key in table:
            raise ValueError(f"scenario {run.scenario!r} with preset {run.preset!r} given twice")
        table[key] = (run, metrics if metrics is not None else compute_metrics(run))
        if run.scenario not in scenarios:
            scenarios.append(run.scenario)
        if run.preset not in presets:
            presets.append(run.preset)
    return scenarios, presets, table


def summary(runs_and_metrics: Iterable[tuple[ScenarioRun, dict | None]]) -> dict:
    """The summary.json document (see :func:`write_report`), NaN-free."""
    scenarios, presets, table = _grouped(runs_and_metrics)
    return _summary(scenarios, presets, table)


def _summary(scenarios, presets, table) -> dict:
    doc: dict[str, Any] = {"scenarios": {}}
    for sc in scenarios:
        first = next(p for p in presets if (sc, p) in table)
        doc["scenarios"][sc] = table[(sc, first)][1]
    if len(presets) > 1:
        doc["presets"] = {
            p: {"scenarios": {sc: table[(sc, p)][1] for sc in scenarios if (sc, p) in table}}
            for p in presets
        }
    return _jsonable(doc)


def _best(values: list[Any], better: str) -> Any:
    nums = [v for v in values if isinstance(v, int | float) and not isinstance(v, bool)]
    nums = [v for v in nums if math.isfinite(v)]
    if len(nums) < 2 or not better:
        return None
    return max(nums) if better == "high" else min(nums)


def _md_table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return [*lines, ""]


def write_report(
    runs_and_metrics: Iterable[tuple[ScenarioRun, dict | None]],
    out_dir: str | Path,
    *,
    plots: bool = True,
) -> Path:
    """Write ``report.md``, ``summary.json`` and (``plots=True``) ``plots/*.png``.

    ``runs_and_metrics``: (run, metrics) pairs, one per scenario and preset (metrics None:
    computed here). summary.json is ``{"scenarios": {name: {metric: value}}}`` for the first
    preset of each scenario; with several presets it also has
    ``"presets": {preset: {"scenarios": {name: {...}}}}``. Returns the report's path.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scenarios, presets, table = _grouped(runs_and_metrics)
    plot_dir = out / "plots"
    links: dict[tuple[str, str], list[Path]] = {}
    for key, (run, m) in table.items():
        if plots:
            links[key] = plot_run(run, m, plot_dir)
        else:
            links[key] = [plot_dir / n for n in _plot_names(run).values()]
            links[key] = [p for p in links[key] if p.exists()]

    doc = _summary(scenarios, presets, table)
    (out / "summary.json").write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")

    lines = [
        "# followbot evaluation",
        "",
        f"{len(scenarios)} scenario(s) x {len(presets)} preset(s): "
        + ", ".join(f"`{p}`" for p in presets)
        + ". Lock-step runs; definitions at the end and in `followbot/evaluation.py`. "
        "Machine-readable figures: [summary.json](summary.json).",
        "",
    ]
    if len(presets) == 1:
        lines += ["## Results", "", "Rows are scenarios (– = not applicable).", ""]
        rows = [
            [sc, *(_fmt(_key_value(table[(sc, presets[0])][1], k[0])) for k in KEY_METRICS)]
            for sc in scenarios
        ]
        lines += _md_table(["scenario", *(k[2] for k in KEY_METRICS)], rows)
        lines += [
            "Columns: "
            + "; ".join(f"{col}: {heading}" for _, heading, col, _ in KEY_METRICS)
            + ".",
            "",
        ]
    else:
        lines += [
            "## Presets side by side",
            "",
            "Rows are scenarios, columns presets; the best value of a row is in bold "
            "(– = not applicable).",
            "",
        ]
    for key, heading, _, better in KEY_METRICS if len(presets) > 1 else []:
        lines += [f"### {heading}", ""]
        rows = []
        for sc in scenarios:
            vals = [
                _key_value(table[(sc, p)][1], key) if (sc, p) in table else None for p in presets
            ]
            best = _best(vals, better)
            cells = [f"**{_fmt(v)}**" if best is not None and v == best else _fmt(v) for v in vals]
            rows.append([sc, *cells])
        lines += _md_table(["scenario", *presets], rows)

    lines += ["## Runs", ""]
    for sc in scenarios:
        for p in presets:
            if (sc, p) not in table:
                continue
            run, m = table[(sc, p)]
            lines += [f"### {sc} — {p}", ""]
            flat = [
                [f"`{k}`", _fmt(v)]
                for k, v in m.items()
                if k not in ("scenario", "preset", "latency_ms", "timeouts", "follow_band_m")
            ]
            flat.append(
                ["`timeouts`", ", ".join(f"{k}: {v}" for k, v in m["timeouts"].items()) or "none"]
            )
            lines += _md_table(["metric", "value"], flat)
            if m["latency_ms"]:
                lat = [
                    [st, _fmt(v["p50_ms"]), _fmt(v["p99_ms"]), _fmt(v["max_ms"]), str(v["n"])]
                    for st, v in m["latency_ms"].items()
                ]
                lines += _md_table(["stage", "p50 ms", "p99 ms", "max ms", "n"], lat)
            for path in links[(sc, p)]:
                rel = path.relative_to(out).as_posix()
                lines += [f"![{path.stem}]({rel})", ""]

    lines += ["## Metric definitions", "", *_definitions(), ""]
    report = out / "report.md"
    report.write_text("\n".join(lines))
    return report


def _definitions() -> list[str]:
    return [
        "- Tracked: the tracker reports `tracking` or `coasting`; errors are measured in the "
        "robot frame of the scan.",
        "- `rmse_m`: RMS distance estimate–true target over scans with the target visible to "
        "the laser and tracked.",
        "- `tracked_visible_share`: scans tracked within 0.5 m of the target ÷ scans with the "
        "target visible to the laser; `tracked_visible_share_acquired`: the same from the "
        "first tracked scan on (leaves out the time before the target model exists).",
        "- `followed_share_acquired`: time tracked within 0.5 m of the target, visible or not, ÷ "
        "time from the first tracked scan to the end (a target lost for good out of the "
        "robot's view, which the visible shares cannot see, lowers it).",
        "- `identity_switches`: the estimate moves onto another person (nearer to them than to "
        "the target and within 0.5 m) after having been on the target; `wrong_target_s`: time "
        "on another person.",
        "- `follow_distance_share`: time with the true distance in [1.0, 2.0] m ÷ time tracked.",
        "- `reacquire_s`: mean time from the target reappearing to the laser after an occlusion "
        "(hidden ≥ 0.2 s; a glimpse shorter than that is part of it) to being tracked within "
        "0.5 m again; `reacquire_laser_s_episodes` / `reacquire_camera_s_episodes`: from the "
        "same moment to the first laser candidate on the target / the target in the camera's "
        "view; `reacquire_turn_s_episodes`: the least time a camera turning at once at full "
        "rate from where this one pointed needs to have the target in view.",
        "- CLEAR-MOT (`mota`, `motp_m`, `misses`, `false_positives`, `id_switches`): truth "
        "people visible to the laser vs `tracking/people`, 0.75 m threshold, previous matches "
        "kept, the rest by the Hungarian method.",
        "- Candidate detection (thesis Table 5.1): the candidate nearest the target within "
        "0.3 m has two legs, one leg, or there is none (undetected).",
        "- `verification_accuracy`: with the target in camera view and a candidate chosen, the "
        "share where the chosen one is the target's (nearest within 0.3 m).",
        "- Latency: arrival of a stage's output minus arrival of the scan; `controller` is "
        "scan to cmd_vel.",
    ]
