"""The tracker: every person in the laser, one of them the target; ego-motion, late vision.

Pure logic on numpy arrays and messages, no Zenoh (the node is ``node.py``). DESIGN.md
"Particle filter" and "Timing model"; thesis 3.6, 4.5. Each role lives in its own module:

- egomotion.py -- the odometry pose at a scan's stamp, the SE(2) change between scans;
- lifecycle.py -- tracks: start, confirmation, misses, deletion, coasting;
- initiators.py -- when a tentative track is a person (the ``initiator`` setting);
- association.py -- units, gates and the assignment rule;
- identity.py -- which track is the target: acquisition, late vision, rollback;
- search.py -- where to look for a lost target;
- report.py -- TrackState and People;
- estimators/ -- one person's state: the particle filter, the UKF, ...

One step per candidates message (:meth:`Tracker.step`), its candidates first turned from the
laser frame into the base frame (the laser's mount, services/runtime/mount.py), the frame
odometry moves and every output is in:

1. ego-motion: the robot's pose at the scan's stamp (interpolated odometry); every track and
   the lost target's last position are carried into the new base frame. Without odometry for
   the scan the step goes on uncompensated and the status carries the flag ``no_odometry``;
2. predict every track by the time between the scans, then coast those that missed;
3. apply the verifications that are due -- they settle *which* track is the target;
4. hand every estimator the scan's candidates (Estimator.observe), associate them with tracks;
5. update the matched tracks; count a miss on the others; start a track on every unmatched
   candidate; delete the tracks past their misses;
6. acquire (without vision) or search for a lost target;
7. report the target (``TrackState``) and every person (``People``; the initiator says which
   tracks are people, initiators.py), and record
   which track took which candidate (the history late vision needs).
"""

from __future__ import annotations

import msgspec
import numpy as np

from followbot.schemas import (
    Odometry,
    People,
    PersonCandidates,
    TargetModel,
    TrackState,
    Verification,
)
from followbot.services.common.geometry import Pose, se2_change, transform_points
from followbot.services.common.odometry import OdometryBuffer
from followbot.services.runtime.mount import LaserMount, candidates_in_base

from . import report
from .association import Association, Associator
from .egomotion import thesis_printed_transform
from .estimators import estimator_factory
from .identity import Identity, Scan
from .lifecycle import ScanTime, Track, Tracks
from .search import Search
from .settings import TrackerSettings

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


class _Rest(msgspec.Struct):
    """What :meth:`Tracker.step_rest` finishes of the scan :meth:`Tracker.step_target` began."""

    stamp: int
    frame_id: str
    scan: Scan | None  # None: an out-of-order scan, which changes nothing
    learn: list[tuple[Track, int]]
    pose: Pose | None = None


class Tracker:
    """All people in the laser, one of them the target. Not thread-safe: one loop drives it."""

    def __init__(
        self, settings: TrackerSettings | None = None, mount: LaserMount | None = None
    ) -> None:
        self.settings = s = settings or TrackerSettings()
        self.mount = mount = mount or LaserMount()
        self._make = estimator_factory(s.estimator, s.estimator_settings)
        self._cls = self._make.estimator_class  # its batch steps (update_all, ...)
        self.estimator_name = s.estimator
        self.odometry = OdometryBuffer(max_extrapolation_s=s.max_odometry_extrapolation_s)
        self._now = ScanTime()
        self._tracks = Tracks(s, self._make, self._now)
        self.search = Search(s, self._tracks, self._now, mount)
        self.identity = Identity(s, self._tracks, self.search, self.odometry, self._now)
        self._associator = Associator(s, self._cls, mount)
        self._last_stamp: int | None = None
        self._last_pose: Pose | None = None
        self.steps_without_odometry = 0
        self._rest: _Rest | None = None  # what step_rest still has to do

    @property
    def tracks(self) -> dict[int, Track]:
        return self._tracks.by_id

    @property
    def target_id(self) -> int:
        return self.identity.target_id

    @property
    def vision_alive(self) -> bool:
        return self.identity.vision_alive

    # ------------------------------------------------------------------ inputs

    def add_odometry(self, odom: Odometry) -> None:
        self.odometry.add(odom)

    def add_verification(self, verification: Verification) -> None:
        """Queue a verification; it is applied at a later :meth:`step` (never waits for it)."""
        self.identity.add_verification(verification)

    def set_target_model(self, model: TargetModel) -> None:
        """A (re)built target model: its laser position is where the target is (thesis 4.5)."""
        self.identity.set_target_model(model)

    def set_vision_alive(self, alive: bool) -> None:
        self.identity.vision_alive = alive

    def reset(self) -> None:
        """Forget every track and the target (thesis: re-initialise)."""
        self.tracks.clear()
        self._rest = None
        self.identity.forget_target()
        self.search.lost_at = None
        self.search.forget_looks()

    def restart_clock(self) -> None:
        """The candidates' source restarted with a new clock: start afresh (every track, the
        target and the history go; whether vision is there stays)."""
        alive = self.vision_alive
        self.__init__(self.settings, self.mount)
        self.set_vision_alive(alive)

    def restart_odometry(self) -> None:
        """The odometry's source restarted with a new clock: forget its history."""
        self.odometry = OdometryBuffer(
            max_extrapolation_s=self.settings.max_odometry_extrapolation_s
        )
        self.identity.odometry = self.odometry

    def lose_target_stale(self, frame_id: str) -> TrackState | None:
        """No scan has moved the clock forward for too long (the node judges it on its wall
        clock): the target is declared lost, and the state saying so is returned (None when
        there is no target). Its last position stays the place to look for it again."""
        if self.target_id < 0:
            return None
        self.identity.lose_target(self.tracks[self.target_id])
        return self._target_state(self._last_stamp or 0, frame_id, ["stale_input"], [])

    def velocity_of(self, track_id: int) -> np.ndarray:
        """A track's coasting velocity (robot frame of the last scan), (0, 0) if unknown."""
        t = self.tracks.get(track_id)
        return np.zeros(2) if t is None else self._tracks.velocity(t, self._last_pose)

    # ------------------------------------------------------------------ the step

    def step(self, candidates: PersonCandidates) -> tuple[TrackState, People]:
        """One scan: :meth:`step_target` then :meth:`step_rest`; the two outputs."""
        target = self.step_target(candidates)
        return target, self.step_rest()

    def step_target(self, candidates: PersonCandidates) -> TrackState:
        """Steps 1-6 of a scan, and its TrackState; :meth:`step_rest` must follow (before the
        next scan; :meth:`step_target` calls it itself if not).

        A node publishes the target between the two, so the controller's input leaves before
        the bookkeeping: resampling the clouds, the tracks' velocity history, the history
        late verifications consult, and the People message. The numbers are the same as
        doing it all at once."""
        if self._rest is not None:
            self.step_rest()
        candidates = candidates_in_base(candidates, self.mount)
        stamp, frame_id = candidates.stamp_ns, candidates.frame_id
        if self._last_stamp is not None and stamp <= self._last_stamp:
            # a repeated or older scan: the state cannot go back; answer without changing it
            self._rest = _Rest(stamp, frame_id, None, [], None)
            return self._target_state(stamp, frame_id, ["out_of_order"], [])
        flags: list[str] = []
        sources: list[str] = []
        self.search.reach = candidates.reach_m
        pose = self._predict(stamp, flags, sources)
        prior = self.identity.prior()  # the target before this scan's update (rollback)
        self.identity.apply_vision(pose)  # 3. late vision, as of the scans it names
        self.search.horizon = candidates.horizon
        for t in self.tracks.values():  # the estimators that weigh every candidate keep them
            t.estimator.observe(candidates)
        z = np.array([[c.x_m, c.y_m] for c in candidates.candidates], dtype=float).reshape(-1, 2)
        a = self._associator.associate(self.tracks, candidates, z, self.target_id)
        learn = self._update(a, stamp)
        matched = self._lifecycle(a, stamp)
        flags += self.identity.vision_flags(stamp)
        if self.target_id < 0:  # 6. acquisition without vision, laser-only re-acquisition
            vision = not any(f in _NO_VISION for f in flags)
            self.identity.acquire_by_laser(z, matched, vision)
        lost = self.target_id < 0 and self.identity.had_target and self.vision_alive
        self.search.step(lost, stamp)
        if self.target_id >= 0 and self.target_id in matched:
            sources.insert(0, "laser")
        if self.identity.vision_sources:
            sources.append("vision")
        if prior is not None and prior[0] != self.target_id:
            prior = None  # vision moved the target during this step
        scan = Scan(self.identity.index, pose, {c: tid for tid, c in matched.items()}, prior)
        self._rest = _Rest(stamp, frame_id, scan, learn, pose)
        return self._target_state(stamp, frame_id, flags, sources)

    def _predict(self, stamp: int, flags: list[str], sources: list[str]) -> Pose | None:
        """Steps 1 and 2: ego-motion and prediction of every track; returns the scan's pose."""
        s = self.settings
        dt = s.default_dt_s if self._last_stamp is None else (stamp - self._last_stamp) / _NS
        dt = min(dt, s.max_dt_s)
        pose = self.odometry.pose_at(stamp)
        rotation = translation = None
        if pose is not None and self._last_pose is not None:
            rotation, translation = se2_change(self._last_pose, pose)
            self.search.ego_motion(rotation, translation)
            sources.append("odometry")
        elif pose is None:
            flags.append("no_odometry")
            self.steps_without_odometry += 1
        self._last_pose = pose
        self._last_stamp = stamp
        self._now.stamp_ns, self._now.pose = stamp, pose
        self._tracks.predict(rotation, translation, dt)
        target = self.tracks.get(self.target_id)
        if rotation is not None and target is not None and s.lone_leg_output_m:
            target.shift = rotation @ target.shift  # a vector: turns, no translation
        self._tracks.coast(dt)
        return pose

    def _update(self, a: Association, stamp: int) -> list[tuple[Track, int]]:
        """Step 5, first half: update the matched tracks, count hits and misses; returns what
        step_rest learns velocities from."""
        s = self.settings
        ids = list(self.tracks)
        updated = [self.tracks[tid] for tid in ids if tid in a.matched]
        zs = [a.point(t.id) for t in updated]
        lone = [a.lone_leg(t.id) for t in updated]
        scales = None
        if s.association.one_leg_noise_scale != 1.0:
            scales = np.where(lone, s.association.one_leg_noise_scale, 1.0)
        if updated:
            self._cls.update_all([t.estimator for t in updated], np.array(zs), scales)
        if s.lone_leg_output_m:
            for i, t in enumerate(updated):
                if t.id == self.target_id:
                    scale = 1.0 if scales is None else float(scales[i])
                    report.shift_after_update(t, zs[i], lone[i], scale, s.lone_leg_output_m)
        cands = a.candidates.candidates
        took = {tid: cands[a.unit_cand[u]] for tid, u in a.matched.items()}
        return self._tracks.count(ids, took, stamp, a.candidates)

    def _lifecycle(self, a: Association, stamp: int) -> dict[int, int]:
        """Step 5, second half: start a track on each unit nobody took, delete the tracks past
        their misses; returns track id -> the message's candidate index."""
        taken = set(a.matched.values())
        for u in range(len(a.unit_cand)):
            if u not in taken:
                c = a.candidates.candidates[a.unit_cand[u]]
                a.matched[self._tracks.new(a.points[a.first[u]], stamp, c, a.candidates).id] = u
        matched = a.by_candidate(self.target_id)
        for t in self._tracks.delete_lost():
            if t.id == self.target_id:
                self.identity.lose_target(t)
            # a track its estimator gave up on even as it took a candidate (a UKF whose spread
            # outgrew its bound over a long gap) is gone: nobody may choose it as the target
            matched.pop(t.id, None)
        return matched

    def step_rest(self) -> People:
        """Finish the scan :meth:`step_target` began; returns its People message."""
        rest, self._rest = self._rest, None
        if rest is None:
            raise RuntimeError("step_rest() without a step_target() before it")
        self._cls.prepare_all([t.estimator for t in self.tracks.values()])  # resampling, ...
        for t, seen in rest.learn:
            self._tracks.learn_velocity(t, rest.stamp, rest.pose, seen)
        if rest.scan is not None:
            self.identity.end_scan(rest.stamp, rest.scan)
        return report.people(
            rest.stamp, rest.frame_id, self.tracks, self.target_id, self.estimator_name,
            self.settings,
        )  # fmt: skip

    # ------------------------------------------------------------------ outputs

    def status(self) -> str:
        return report.status(self.tracks.get(self.target_id), self.identity.had_target)

    def _target_state(
        self, stamp: int, frame_id: str, flags: list[str], sources: list[str]
    ) -> TrackState:
        look = self.search.output(self.target_id)
        return report.target_state(
            stamp,
            frame_id,
            target=self.tracks.get(self.target_id),
            had_target=self.identity.had_target,
            lost_at=self.search.lost_at,
            look=look,
            estimator=self.estimator_name,
            flags=flags,
            sources=sources,
        )
