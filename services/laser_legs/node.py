"""laser_legs: person candidates (legs) from every laser scan.

Subscribes ``sensors/scan`` (every scan, in order, handled inline on Zenoh's delivery thread:
detection takes ~0.1 ms), ``tracking/target`` (for the thesis's criterion 3: the target's
predicted position gates the legs, see ``prediction``) and ``sensors/odom`` (criterion 3's
ego-motion; and the laser's pose at each scan, odometry composed with ``laser_mount``, given to
the detector: ``learned`` registers its static background with it instead of matching scans),
and publishes
``perception/candidates`` exactly once per scan, stamped with the scan's stamp, also when no
candidate is found and also when the detector fails (then empty; the error is counted in
Health) — the lock-step rule 2 of docs/runtime.md.

    followbot run laser_legs --set detector=bellotto
    followbot run laser_legs --set detector=thesis --set 'detector_settings={clip_range_m: null}'
    followbot run laser_legs --set self_filter=null     # keep candidates on the robot's body
"""

from __future__ import annotations

import math
from typing import Annotated, Any, ClassVar

import msgspec

from followbot.schemas import LaserScan
from followbot.services.runtime.lockstep import HeldInputs
from followbot.services.runtime.node import Node
from followbot.services.runtime.service import service_main
from followbot.services.runtime.settings import NodeSettings, SettingsError, removed

from .beams import detector_clip_m, horizon, scan_reach_m
from .core import LegDetector
from .detectors import REGISTRY, detector_settings, make_detector
from .message import empty_candidates
from .prediction import TargetPredictor
from .self_filter import SelfFilteredDetector, SelfFilterSettings

__all__ = ["LaserLegsSettings", "build_detector", "check", "main", "setup"]


class LaserLegsSettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    retired_settings: ClassVar[dict[str, str]] = {
        "laser_pose_in_base": (
            "was replaced by laser_mount, one setting every stage reads: write "
            "laser_mount: {x_m: X, y_m: Y, yaw_deg: DEGREES} at the top of your settings "
            "(docs/robot.md)"
        ),
        "detector_settings_while_lost": removed(
            "a second detector while the target is lost, measured with the tracker's removed "
            "look_far_walking_m and left off, see docs/tracker_log.md"
        ),
        "while_lost_new_near_look_m": removed(
            "it only applied with detector_settings_while_lost, also removed"
        ),
    }

    detector: str = "thesis"
    """Leg detector by name (entry points of followbot.detectors): thesis, arc, bellotto, ..."""
    detector_settings: dict[str, Any] = {}
    """Overrides of the detector's own settings, validated by its settings Struct."""
    use_target_prediction: bool = True
    """Criterion 3: gate legs on the tracked target's predicted position (thesis 4.3.2)."""
    prediction_max_age_s: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.5
    """A target older than this (scan stamp minus target stamp) is not used for gating."""
    odometry_max_extrapolation_s: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.2
    """Criterion 3's ego-motion and the detector's laser pose: the robot's pose at a scan
    stamp past the last odometry is extrapolated with its last twist for at most this long
    (s); later, no prediction and no pose (``learned`` then matches the scan itself)."""
    lockstep_target_wait_s: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.0
    """Lock-step runs: hold a scan until the tracker's target for the previous scan has
    arrived (it races the next scan over another link), at most this long. 0 (live): never
    wait, use whatever target is newest."""
    lockstep_odometry_wait_s: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.0
    """Lock-step runs: hold scan k until odometry stamped at or after k has arrived (two
    topics reach a node in no guaranteed order), at most this long. 0 (live, or no
    odometry): never wait."""
    horizon_bin_deg: Annotated[float, msgspec.Meta(gt=0, le=45)] | None = 1.0
    """Publish with each scan's candidates the nearest return per bin of this many degrees
    (perception/candidates ``horizon``; the scan's resolution when coarser), so the tracker can
    tell a person hidden behind something from one who is gone. null: not published."""
    self_filter: SelfFilterSettings | None = SelfFilterSettings()
    """Drop candidates on the robot's own body, recognised from the scans (beams steady while
    the world moves past; see services/laser_legs/self_filter.py). null: off."""

    def __post_init__(self) -> None:
        super().__post_init__()
        # checked while the settings load, so a bad detector or key fails before any network
        # is opened (exit code 2, the message naming the key)
        build_detector(self, check_only=True)


def build_detector(settings: LaserLegsSettings, *, check_only: bool = False) -> LegDetector | None:
    """The configured detector; a bad name or setting is a SettingsError (a ValueError) naming
    it. ``check_only`` validates the detector's settings without building the detector."""
    try:
        cls = REGISTRY.load(settings.detector)
    except LookupError as exc:
        raise SettingsError(f"detector: {exc}") from None
    overrides = dict(settings.detector_settings)
    key = "detector_settings"
    try:
        if check_only:
            detector_settings(settings.detector, overrides)
            return None
        detector = make_detector(settings.detector, overrides)
    except (ValueError, TypeError) as exc:
        fields = ", ".join(getattr(cls.settings_type, "__struct_fields__", ()))
        raise SettingsError(f"{key}: {exc} (valid keys: {fields})") from None
    if settings.self_filter is not None:
        return SelfFilteredDetector(detector, settings.self_filter)
    return detector


def check(settings: LaserLegsSettings) -> None:
    """Build the configured detectors and load every file they read (a learned detector's
    model), before any network is opened: a missing or bad file is a ValueError naming it."""
    detector = build_detector(settings)
    inner = getattr(detector, "inner", detector)  # under the robot-body filter
    check_files = getattr(inner, "check", None)
    if callable(check_files):
        check_files()


class _Stage:
    """laser_legs' loop: each scan -> the detector (gated by the target's prediction when
    criterion 3 is on) -> one PersonCandidates, with its horizon and reach.

    Lock-step: a scan is held (runtime.lockstep.HeldInputs) until the odometry of its instant
    and the tracker's answer to the previous scan have arrived (see the settings)."""

    def __init__(self, node: Node, settings: LaserLegsSettings) -> None:
        self.node, self.s = node, settings
        self.detector = build_detector(settings)
        # reach_m: the detector's clip (fixed), met with each scan's range_max_m
        self.clip_m = detector_clip_m(self.detector)
        self.out = node.publisher("perception/candidates")
        self.predictor = TargetPredictor(
            max_age_s=settings.prediction_max_age_s,
            laser_pose=settings.laser_mount.pose(),  # tracking/target is in the base frame
            max_extrapolation_s=settings.odometry_max_extrapolation_s,
        )
        deg = settings.horizon_bin_deg
        self.bin_rad = None if deg is None else math.radians(deg)
        self.stamps = {"scan": -1, "target": -1, "odom": -1}
        self.horizon_errors = 0
        gated = settings.use_target_prediction
        self.target_wait = settings.lockstep_target_wait_s if gated else 0.0
        self.odom_wait = settings.lockstep_odometry_wait_s  # the detector's pose needs it too
        self.posed = 0  # scans given to the detector with the laser's odometry pose
        self.held = HeldInputs(
            node, self.process, self.ready, max(self.target_wait, self.odom_wait), "scans"
        )

    def ready(self, scan: LaserScan) -> bool:
        # the odometry of the scan's instant (sent before the scan, on another topic)
        if self.odom_wait > 0 and self.stamps["odom"] < scan.stamp_ns:
            return False
        # the tracker answers every scan, so once it has answered any, wait for its answer
        # to the previous scan before gating the next one on it
        t = self.stamps["target"]
        return self.target_wait <= 0 or t < 0 or t >= self.stamps["scan"]

    def on_target(self, target) -> None:
        self.predictor.add_target(target)
        self.stamps["target"] = max(self.stamps["target"], target.stamp_ns)
        self.held.release()

    def on_odometry(self, odom) -> None:
        self.predictor.add_odometry(odom)
        self.stamps["odom"] = max(self.stamps["odom"], odom.stamp_ns)
        self.held.release()

    def process(self, scan: LaserScan) -> None:
        self.stamps["scan"] = max(self.stamps["scan"], scan.stamp_ns)
        use = self.s.use_target_prediction
        prediction = self.predictor.predict(scan) if use else None
        try:
            seen = None if self.bin_rad is None else horizon(scan, self.bin_rad)
        except Exception:  # never on a valid scan (property-tested); the candidates still go
            self.node.log.exception(
                "horizon of scan %d failed; candidates sent without it", scan.seq
            )
            self.horizon_errors += 1
            seen = None
        reach = scan_reach_m(self.clip_m, scan)
        pose = self.predictor.laser_pose_at(scan.stamp_ns)
        self.posed += pose is not None
        try:
            result = self.detector.detect(scan, prediction, pose)
        except Exception:
            # rule 2: one output per scan even when the detector fails; the error is counted
            empty = empty_candidates(scan, self.detector.name)
            self.out.put(msgspec.structs.replace(empty, horizon=seen, reach_m=reach))
            raise
        self.out.put(msgspec.structs.replace(result, horizon=seen, reach_m=reach))

    def restart(self) -> None:
        """The scans' source restarted with a new clock: start as if new (detectors with a
        history, e.g. a learned background, forget it; held scans and the target go)."""
        self.detector = build_detector(self.s)
        self.held.clear()
        self.stamps.update(scan=-1, target=-1, odom=-1)
        self.predictor.reset()

    def restart_target(self) -> None:
        self.predictor.target = None
        self.stamps["target"] = -1

    def restart_odometry(self) -> None:
        self.predictor.reset_odometry()
        self.stamps["odom"] = -1
        # a new odometry frame: a history registered in the old one (learned's background)
        # would place the next scans wrongly
        inner = getattr(self.detector, "inner", self.detector)  # under the robot-body filter
        reset = getattr(inner, "reset", None)
        if callable(reset):
            reset()

    def notes(self) -> None:
        d = self.detector
        self.node.notes = [
            f"detector={d.name}",
            f"body_candidates_dropped={getattr(d, 'dropped', 0)}",
            f"body_beams={getattr(d, 'body_beams', 0)}",
            f"gated_scans={self.predictor.used}",
            f"odometry_posed_scans={self.posed}",
            f"prediction_skipped={self.predictor.skipped}",
            f"lockstep_waits={self.held.waits}",
            f"lockstep_wait_timeouts={self.held.timeouts}",
            f"horizon_errors={self.horizon_errors}",
        ]


def setup(node: Node, settings: LaserLegsSettings) -> TargetPredictor:
    st = _Stage(node, settings)
    node.subscribe(
        "sensors/scan",
        st.held.offer,
        policy="all",
        dispatch="inline",
        on_restart=st.restart,
        expect_within_s=1.0,
    )
    if settings.use_target_prediction:
        node.subscribe("tracking/target", st.on_target, policy="all", on_restart=st.restart_target)
    node.subscribe("sensors/odom", st.on_odometry, policy="all", on_restart=st.restart_odometry)
    st.notes()
    node.every(settings.health_period_s, st.notes, name="notes")
    node.log.info("detector %s, criterion 3 %s", st.detector.name, settings.use_target_prediction)
    return st.predictor


def main(argv: list[str] | None = None) -> int:
    return service_main("laser_legs", LaserLegsSettings, setup, argv, __doc__, check)
