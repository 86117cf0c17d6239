"""Which track is the target: acquisition, late vision against the scan history, rollback.

Acquisition. With vision, a target model (perception/target_model: its laser position) or a
verification's chosen candidate makes a track the target; without a camera (``acquire:
nearest``), the nearest person ahead (a track the initiator confirmed) within
``identity.acquire_range_m``.

Late vision (DESIGN.md "Timing model"). A :class:`~followbot.schemas.Verification` names the
scan stamp whose candidates it judged. The tracker keeps, for the last ``history_scans``
scans, which track took each candidate and the odometry pose at the scan (:class:`Scan`), so
a verification is applied to the state *as of that scan*: the chosen candidate's track (or,
if that track is gone, the track nearest to the chosen position carried to the current frame
by odometry) becomes the target when there is none, and replaces the current target after
``identity.switch_votes`` consecutive verifications that prefer it. In lock-step runs
``vision_lag_scans = N`` holds the verification of scan k until the step of scan k + N (at
least the next step: the tracker never waits for vision).

Negative evidence rolls the target back (beyond the thesis). When a verification says the
candidate the target took at scan k is *not* the target (appearance distance above the
verifier's threshold) -- typically another person walking between the robot and the target,
or a passer-by's leg paired with one of the target's -- the target's updates since scan k
followed someone else. The tracker keeps, for each scan, a snapshot of the target's estimator
after the prediction and before the update; on such a verification (``identity.rollback: true``) it
(1) turns the current estimator, which now follows the other person, into a new track of its
own, and (2) gives the target the snapshot of scan k carried to now by odometry and the
motion model, as a coasting track. The two then compete for the next candidates in the
assignment, so the target no longer jumps onto the person who hid it. ``identity.reject_votes``
consecutive rejections still drop the target.

Re-acquisition of a lost target: by appearance, only where it can be (search.py's gate); by
the laser near where it was lost (``laser_reacquire_*``), with vision too unless vision ruled
that track out or the loss was vision's own veto (``laser_reacquire_with_vision``).
"""

from __future__ import annotations

import math
from collections import OrderedDict, deque
from typing import Any

import msgspec
import numpy as np

from followbot.schemas import TargetModel, Verification, VerifiedCandidate
from followbot.services.common.geometry import Pose, se2_change, transform_points
from followbot.services.common.odometry import OdometryBuffer

from .evidence import EVIDENCE
from .lifecycle import ScanTime, Track, Tracks
from .search import Search
from .settings import TrackerSettings

__all__ = ["Identity", "Scan"]

_NS = 1_000_000_000


class Scan(msgspec.Struct):
    """What late vision needs of one stepped scan."""

    index: int
    pose: Pose | None
    assoc: dict[int, int]  # candidate index -> track id
    # the target's id and estimator after this scan's prediction, before its update
    target_prior: tuple[int, Any] | None = None


class Identity:
    """The target's track id and the evidence that chose it. Not thread-safe."""

    def __init__(
        self,
        settings: TrackerSettings,
        tracks: Tracks,
        search: Search,
        odometry: OdometryBuffer,
        now: ScanTime,
    ) -> None:
        self.settings = settings
        self._tracks = tracks
        self._search = search
        self.odometry = odometry
        self._now = now
        self.target_id = -1
        self.had_target = False
        self.dropped_by_vision = False  # the last loss was vision's veto, not the laser's
        self.vision_alive = False
        self.vision_stamp: int | None = None  # newest scan a verification judged
        self.vision_sources = False  # vision chose or confirmed the target this step
        self.index = 0  # scans stepped
        self.history: OrderedDict[int, Scan] = OrderedDict()
        self._pending: list[Verification] = []
        self._model: TargetModel | None = None
        self._evidence = EVIDENCE[settings.identity.vision_evidence](settings)
        self._confirmed_index = -1  # last scan whose verification accepted the target's candidate
        # scans at which the target missed or had another track within identity.near_guard_m
        self._breaks: deque[int] = deque()
        # counters for health and tests
        self.target_rejections = 0  # targets dropped because vision rejected them
        self.verifications_applied = 0
        self.verifications_unmatched = 0
        self.verifications_same_image = 0  # a faster laser's scans judged on one image
        self._last_image_ns = 0  # the image the last applied verification judged
        self.target_switches = 0
        self.rollbacks = 0  # target tracks split by a rejecting verification
        self.rejections_near = 0  # rejections not counted: the candidate too near the camera

    # ------------------------------------------------------------------ inputs

    def add_verification(self, verification: Verification) -> None:
        self._pending.append(verification)

    def set_target_model(self, model: TargetModel) -> None:
        self._model = model

    def forget_target(self) -> None:
        self.target_id = -1
        self.had_target = False
        self._evidence.forget()
        self._breaks.clear()

    # ------------------------------------------------------------------ target changes

    def set_target(self, tid: int) -> None:
        self._evidence.new_target()
        if self.target_id >= 0 and tid != self.target_id:
            self.target_switches += 1
        if tid != self.target_id:  # the shift is kept for the target only, from now on
            for i in (self.target_id, tid):
                if i in self._tracks.by_id:
                    self._tracks.by_id[i].shift = np.zeros(2)
        self.target_id = tid
        self._confirmed_index = self.index - 1  # chosen by vision (or a model) just now
        self.had_target = True
        self._search.lost_at = None

    def lose_target(self, track: Track, by_vision: bool = False) -> None:
        """The target is lost: its track ran out of misses, or vision dropped it."""
        self._search.note_loss(track)
        self.target_id = -1
        self.dropped_by_vision = by_vision
        self._evidence.forget()

    def prior(self) -> tuple[int, Any] | None:
        """The target's id and a copy of its estimator now (after the prediction, before the
        update), for a later rollback; None without rollback or target."""
        if not self.settings.identity.rollback or self.target_id < 0:
            return None
        return self.target_id, self._tracks.by_id[self.target_id].estimator.snapshot()

    def vision_flags(self, stamp: int) -> list[str]:
        """``no_vision`` (vision_verify absent) or ``vision_stale`` (no judgement for
        vision_stale_s), or nothing."""
        if not self.vision_alive:
            return ["no_vision"]
        if (
            self.vision_stamp is None
            or stamp - self.vision_stamp > self.settings.vision_stale_s * _NS
        ):
            return ["vision_stale"]
        return []

    def end_scan(self, stamp: int, scan: Scan) -> None:
        """Remember the scan stepped at ``stamp`` for late verifications."""
        s = self.settings
        if (
            s.identity.near_guard_m > 0
            and s.identity.reject_min_range_m > 0
            and self.target_id in self._tracks.by_id
        ):
            self._note_break()  # this scan's index: before it moves on
        self.history[stamp] = scan
        while len(self.history) > s.history_scans:
            self.history.popitem(last=False)
        self.index += 1

    # ------------------------------------------------------------------ acquisition

    def acquire_by_laser(self, z: np.ndarray, matched: dict[int, int], vision: bool) -> None:
        """Without vision: the first target is the nearest person ahead (``acquire: nearest``:
        a track the initiator confirmed, by the candidate it took this scan); a lost one is
        re-taken by a walker near where it was lost, soon after."""
        s, si = self.settings, self.settings.identity
        if not self.had_target and s.acquire == "nearest" and len(z):
            r = np.hypot(z[:, 0], z[:, 1])
            bearing = np.abs(np.arctan2(z[:, 1], z[:, 0]))
            ahead = (bearing <= math.radians(si.acquire_bearing_deg)) & (r <= si.acquire_range_m)
            people = [(float(r[ci]), tid) for tid, ci in matched.items()
                      if ahead[ci] and self._tracks.by_id[tid].person]  # fmt: skip
            if people:
                self.set_target(min(people)[1])
                return
        if not self.had_target:
            return
        if vision and (not si.laser_reacquire_with_vision or self.dropped_by_vision):
            return  # a target vision dropped is not brought back by the laser
        best = self._laser_retake(z, matched)
        if best >= 0 and not (vision and self._vetoed(best)):
            self.set_target(best)

    def _vetoed(self, tid: int) -> bool:
        """Vision has said track ``tid`` is not the target: rejected since the loss (the
        search's count), or its evidence at the level that drops a target."""
        return self._search.rejections(tid) > 0 or self._evidence.vetoed(tid)

    def _laser_retake(self, z: np.ndarray, matched: dict[int, int]) -> int:
        """Without vision, the track to re-take a lost target, or -1: the one nearest to where
        the target was lost (search.py notes where), within laser_reacquire_m, walking at
        laser_reacquire_min_speed_mps or faster, at least laser_reacquire_min_range_m from the
        laser, within laser_reacquire_max_s of the loss."""
        si = self.settings.identity
        lost_at = self._search.lost_at
        if lost_at is None or si.laser_reacquire_m <= 0:
            return -1
        max_s = si.laser_reacquire_max_s
        if max_s is not None and self._now.stamp_ns - self._search.lost_ns > max_s * _NS:
            return -1  # lost too long ago: whoever passes there now is someone else
        best, best_d = -1, si.laser_reacquire_m
        for tid, ci in matched.items():
            d = float(np.hypot(*(z[ci] - lost_at)))
            if (
                d <= best_d
                and float(np.hypot(*z[ci])) >= si.laser_reacquire_min_range_m
                and self._tracks.walking(tid, si.laser_reacquire_min_speed_mps)
            ):
                best, best_d = tid, d
        return best

    def apply_vision(self, pose: Pose | None) -> None:
        """The verifications that are due, then a new target model (step 3 of a scan)."""
        self.vision_sources = False
        self._apply_due_verifications(pose)
        if self._model is not None:
            self._take_model(pose)

    def _take_model(self, pose: Pose | None) -> None:
        """A target model's laser position is where the target is (thesis 4.5)."""
        model, self._model = self._model, None
        xy = np.array([[model.x_m, model.y_m]])
        then = self.odometry.pose_at(model.stamp_ns)
        if then is not None and pose is not None:
            xy = transform_points(xy, then, pose)
        tid = self._tracks.nearest(xy[0], self.settings.identity.model_match_m)
        if tid < 0:
            tid = self._tracks.new(xy[0], model.stamp_ns).id
        self.set_target(tid)
        self.vision_sources = True
        self.vision_stamp = max(self.vision_stamp or 0, self._now.stamp_ns)  # vision's own word

    # ------------------------------------------------------------------ late vision

    def _apply_due_verifications(self, pose: Pose | None) -> None:
        if not self._pending:
            return
        lag = max(self.settings.vision_lag_scans, 1)
        keep: list[Verification] = []
        for v in self._pending:
            scan = self.history.get(v.stamp_ns)
            if scan is None:
                if v.stamp_ns >= self._now.stamp_ns:
                    keep.append(v)  # its scan has not been processed yet
                else:
                    self.verifications_unmatched += 1  # too old, or names no scan seen here
                continue
            if self.index - scan.index < lag:
                keep.append(v)
                continue
            self._apply_verification(v, scan, pose)
        self._pending = keep

    def _apply_verification(self, v: Verification, scan: Scan, pose: Pose | None) -> None:
        self.verifications_applied += 1
        judged = any(c.distance is not None for c in v.candidates)
        if judged and (self.vision_stamp is None or v.stamp_ns > self.vision_stamp):
            # vision that judges nothing (no image, target out of view, a face verifier that
            # sees no face) is no evidence: after vision_stale_s the laser gates alone
            self.vision_stamp = v.stamp_ns
        if judged and v.image_stamp_ns:
            if v.image_stamp_ns == self._last_image_ns:
                # a laser faster than the camera: this scan was judged on the image the last
                # one was; the same look again is not new evidence (votes would count it
                # twice, summed log-odds four times at 40 Hz with a 10 Hz camera)
                self.verifications_same_image += 1
                return
            self._last_image_ns = v.image_stamp_ns
        held = self.target_id
        self._evidence.judged(v, scan.assoc, self._tracks.by_id)
        self._judge_target(v, scan)
        if v.chosen < 0:
            return
        chosen = v.candidates[v.chosen]
        tid = self._chosen_track(chosen, scan, pose)
        if tid < 0:
            return
        if self.target_id < 0:
            self._reacquire(tid, chosen.distance, v.threshold, dropped_now=held >= 0)
            return
        if tid == self.target_id:
            self._evidence.chose_target()
            self.vision_sources = True
            return
        if self._evidence.prefers(tid, self.target_id) or self._repairs_split(tid):
            self.set_target(tid)
            self.vision_sources = True

    def _chosen_track(self, chosen: VerifiedCandidate, scan: Scan, pose: Pose | None) -> int:
        """The track that took the chosen candidate at that scan, or, that track gone, the
        track nearest the chosen position carried to now; -1 if none."""
        tid = scan.assoc.get(chosen.index, -1)
        if tid in self._tracks.by_id:
            return tid
        xy = np.array([[chosen.x_m, chosen.y_m]])
        if scan.pose is not None and pose is not None:
            xy = transform_points(xy, scan.pose, pose)
        return self._tracks.nearest(xy[0], self.settings.identity.model_match_m)

    def _reacquire(
        self, tid: int, distance: float | None, threshold: float | None, dropped_now: bool
    ) -> None:
        """Vision chose track ``tid`` while there is no target: (re-)acquisition by
        appearance. A target lost earlier is re-taken only on enough evidence (evidence.py:
        identity.reacquire_max_distance, or evidence_reacquire) and where it can be
        (search.py); one dropped by this very verification is a switch, taken anywhere."""
        if self.had_target and not self._evidence.may_reacquire(tid, distance, threshold):
            return  # re-acquisition asks for more than verification does
        if not dropped_now and self.had_target and not self._search.may_retake(tid, distance):
            return
        self.set_target(tid)
        self.vision_sources = True

    def _repairs_split(self, tid: int) -> bool:
        """Vision chose a track next to the target while the target coasts: after a rollback
        on a false rejection the real target may be that track; take it at once."""
        target = self._tracks.by_id.get(self.target_id)
        if target is None or target.misses == 0:
            return False
        d = float(np.hypot(*(self._tracks.by_id[tid].position - target.position)))
        return d <= self.settings.identity.model_match_m

    def _judge_target(self, v: Verification, scan: Scan) -> None:
        """Negative evidence: vision saw the target's candidate and said it is not the target.
        (While the target is lost: which tracks vision has rejected, for the search.)"""
        s = self.settings
        lost = self.target_id < 0 and self.had_target
        if lost and s.search.enabled and v.threshold is not None:
            for c in v.candidates:
                tid = scan.assoc.get(c.index, -1)
                if tid >= 0 and c.in_view and c.distance is not None and c.distance > v.threshold:
                    self._search.note_rejection(tid)
        if self.target_id < 0 or v.threshold is None or not self._evidence.vetoes:
            return
        mine = [i for i, tid in scan.assoc.items() if tid == self.target_id]
        judged = {c.index: c for c in v.candidates}
        seen = [judged[i] for i in mine if i in judged and judged[i].in_view]
        if not seen or seen[0].distance is None:
            return  # not in view: no evidence either way
        if v.chosen >= 0 and v.candidates[v.chosen].index in mine:
            self._evidence.accepted()
            self._confirmed_index = max(self._confirmed_index, scan.index)
            return
        if seen[0].distance <= v.threshold or not self._rejection_counts(seen[0], v, scan):
            return  # close enough (only another was closer: the switch votes decide)
        if s.identity.rollback:
            self._rollback(v.stamp_ns, scan, (seen[0].x_m, seen[0].y_m))
        if self._evidence.rejected(self.target_id):
            self.target_rejections += 1
            self.lose_target(self._tracks.by_id[self.target_id], by_vision=True)

    def _rejection_counts(self, seen: VerifiedCandidate, v: Verification, scan: Scan) -> bool:
        """A rejection of the target's candidate counts, unless it is too near the camera
        (identity.reject_min_range_m) or just above the threshold (identity.reject_hysteresis)
        for a target surely the one vision last accepted."""
        s = self.settings
        if math.hypot(seen.x_m, seen.y_m) < s.identity.reject_min_range_m and (
            s.identity.near_guard_m <= 0 or self._surely_the_target(scan.index)
        ):
            self.rejections_near += 1
            return False  # too near for the camera to tell
        h = self._evidence.hysteresis
        surely = h > 0 and seen.distance <= v.threshold + h
        return not (surely and self._surely_the_target(scan.index))

    def _note_break(self) -> None:
        """Remember this scan when the target missed or another track is near it."""
        target = self._tracks.by_id[self.target_id]
        broken = target.misses > 0
        if not broken:
            xy = target.position
            guard = self.settings.identity.near_guard_m
            broken = any(
                float(np.hypot(*(t.position - xy))) < guard
                for t in self._tracks.by_id.values()
                if t is not target
            )
        if broken:
            self._breaks.append(self.index)
            while len(self._breaks) > self.settings.history_scans:
                self._breaks.popleft()

    def _surely_the_target(self, index: int) -> bool:
        """No break between the last acceptance of the target and scan ``index``."""
        if self.index - self._confirmed_index > self.settings.history_scans:
            return False  # the breaks of that time are forgotten
        return not any(self._confirmed_index < b <= index for b in self._breaks)

    # ------------------------------------------------------------------ rollback

    def _rollback(self, stamp_k: int, scan: Scan, taken: tuple[float, float]) -> None:
        """Vision rejected what the target took at scan k: split the track (module doc).

        The target goes back to before the first of its updates that vision has not
        confirmed (at most ``identity.rollback_max_s`` before scan k): a passer-by often pulls the
        target a scan or two before vision sees the two apart, in scans it did not judge."""
        tid = self.target_id
        if tid not in self._tracks.by_id:
            return
        s = self.settings
        start = self._rollback_start(tid, stamp_k, scan)
        if start is None:
            return
        stamp_j, scan_j = start
        before = scan_j.target_prior[1]
        xy = np.array([taken])
        if scan.pose is not None and scan_j.pose is not None:
            xy = transform_points(xy, scan.pose, scan_j.pose)  # into scan j's frame
        jump = math.hypot(xy[0, 0] - before.mean[0], xy[0, 1] - before.mean[1])
        if jump < s.identity.rollback_jump_m:
            return
        track = self._tracks.by_id[tid]
        # 1. what the target followed since scan j is somebody else: their own track
        other = self._tracks.split_off(track, hits=max(track.hits, s.confirm_hits))
        for st in self.history.values():  # scans j.. : those candidates were the other's
            if st.index >= scan_j.index:
                st.assoc = {c: other.id if t == tid else t for c, t in st.assoc.items()}
                if st.target_prior is not None and st.index > scan_j.index:
                    st.target_prior = None  # snapshots taken after the wrong updates
        scan_j.target_prior = None  # used: the target's new estimator is this snapshot
        # 2. the target as it was before scan j's update, carried to now
        stamp_now, pose_now = self._now.stamp_ns, self._now.pose
        if scan_j.pose is not None and pose_now is not None:
            rotation, translation = se2_change(scan_j.pose, pose_now)
            before.ego_motion(rotation, translation)
        misses = max(1, self.index - scan_j.index)
        before.predict(min((stamp_now - stamp_j) / _NS, s.max_dt_s), misses)
        track.estimator = before
        track.shift = np.zeros(2)  # (the snapshot's updates are not the ones shifted)
        track.misses = misses
        self.rollbacks += 1

    def _rollback_start(self, tid: int, stamp_k: int, scan: Scan) -> tuple[int, Scan] | None:
        """(stamp, scan) of the first scan since the last acceptance, up to scan k and at most
        identity.rollback_max_s before it, that kept a snapshot of target ``tid``."""
        for stamp_j, st in self.history.items():
            if (
                st.index > self._confirmed_index
                and st.index <= scan.index
                and st.target_prior is not None
                and st.target_prior[0] == tid
                and stamp_k - stamp_j <= self.settings.identity.rollback_max_s * _NS
            ):
                return stamp_j, st
        return None
