"""Every wire message of followbot (DESIGN.md "Processes and data flow").

Units are SI, frames REP-103 (x forward, y left, angles counter-clockwise), stamps integer
nanoseconds. Each class documents its topic; ``schemas.keys.TOPICS`` is the authoritative map
from topic to message type and ``docs/messages.md`` the reader's guide.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec
import numpy as np

from .base import (
    MAX_BYTES,
    MAX_ITEMS,
    Angle,
    Array,
    Count,
    Finite,
    Message,
    Name,
    NonNegative,
    Stamp,
    require,
)

__all__ = [
    "MAX_ANGULAR_RADPS",
    "MAX_BEAMS",
    "MAX_IMAGE_SIDE",
    "MAX_LINEAR_MPS",
    "MESSAGE_TYPES",
    "Candidate",
    "GroundTruth",
    "Health",
    "Horizon",
    "Image",
    "LaserScan",
    "Leg",
    "Odometry",
    "PanCommand",
    "People",
    "PersonCandidates",
    "PersonTrack",
    "PersonTruth",
    "TargetCommand",
    "TargetModel",
    "TrackState",
    "VelocityCommand",
    "Verification",
    "VerifiedCandidate",
]

#: Largest scan accepted (0.036 deg over 360 deg); real scanners give 100-3000 beams.
MAX_BEAMS = 10_000
#: Largest image side accepted, in pixels.
MAX_IMAGE_SIDE = 4096

_Items = msgspec.Meta(max_length=MAX_ITEMS)
_Probability = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]


# --------------------------------------------------------------------------- sensors


def _ranges_length(r: Array, what: str, items: str) -> int:
    """The length of ``r``, checked: 1-D float32/float64 of 1 to MAX_BEAMS values."""
    # if/raise, not require(): these run on every message, and an f-string argument would be
    # formatted each time, not only on failure
    if len(r.shape) != 1:
        raise ValueError(f"{what} must be 1-D, got shape {r.shape}")
    n = r.shape[0]
    if not 0 < n <= MAX_BEAMS:
        raise ValueError(f"{what} has {n} {items}, expected 1..{MAX_BEAMS}")
    if r.dtype not in ("<f4", "<f8"):
        raise ValueError(f"{what} must be float32/float64, got {r.dtype}")
    return n


class LaserScan(Message, tag="laser_scan", kw_only=True):
    """sensors/scan: one sweep of a 2D laser (as sensor_msgs/LaserScan).

    Beam ``i`` points at ``angle_min_rad + i * angle_increment_rad`` in ``frame_id``.
    A range that is NaN, inf, 0, below ``range_min_m`` or above ``range_max_m`` means
    "no return"; consumers treat it so, it is not an error.
    """

    angle_min_rad: Angle
    angle_increment_rad: Annotated[float, msgspec.Meta(ge=-math.pi, le=math.pi)]
    range_min_m: NonNegative
    range_max_m: NonNegative
    ranges: Array
    """1-D float32 or float64, metres; 1 to MAX_BEAMS beams."""
    intensities: Array | None = None
    """Optional, same length as ``ranges``."""
    scan_time_s: NonNegative = 0.0
    """Time between scans."""
    time_increment_s: NonNegative = 0.0
    """Time between beams."""

    def __post_init__(self) -> None:
        n = _ranges_length(self.ranges, "ranges", "beams")
        require(self.angle_increment_rad != 0.0 or n == 1, "angle_increment_rad is 0")
        if not abs(self.angle_increment_rad) * (n - 1) <= 2 * math.pi + 1e-6:
            raise ValueError(
                f"{n} beams of {self.angle_increment_rad} rad span more than a full turn"
            )
        require(self.range_min_m < self.range_max_m, "range_min_m must be < range_max_m")
        if self.intensities is not None and self.intensities.shape != self.ranges.shape:
            raise ValueError(
                f"intensities shape {self.intensities.shape} != ranges shape {self.ranges.shape}"
            )

    @classmethod
    def from_ranges(
        cls,
        ranges: np.ndarray,
        *,
        stamp_ns: int,
        angle_min_rad: float,
        angle_increment_rad: float,
        range_min_m: float = 0.01,
        range_max_m: float = 30.0,
        intensities: np.ndarray | None = None,
        frame_id: str = "base_laser",
        seq: int = 0,
        scan_time_s: float = 0.0,
    ) -> LaserScan:
        ranges = np.asarray(ranges)
        if ranges.dtype not in (np.float32, np.float64):
            ranges = ranges.astype(np.float32)
        return cls(
            stamp_ns=stamp_ns,
            frame_id=frame_id,
            seq=seq,
            angle_min_rad=angle_min_rad,
            angle_increment_rad=angle_increment_rad,
            range_min_m=range_min_m,
            range_max_m=range_max_m,
            ranges=Array.from_numpy(ranges),
            intensities=None if intensities is None else Array.from_numpy(intensities),
            scan_time_s=scan_time_s,
        )

    def ranges_m(self) -> np.ndarray:
        """Ranges as a read-only array view (no copy)."""
        return self.ranges.numpy()

    def angles_rad(self) -> np.ndarray:
        """Bearing of every beam."""
        n = self.ranges.shape[0]
        return self.angle_min_rad + self.angle_increment_rad * np.arange(n, dtype=np.float64)


ImageEncoding = Literal["bgr8", "mono8", "jpeg"]
_CHANNELS = {"bgr8": 3, "mono8": 1}


class Image(Message, tag="image", kw_only=True):
    """sensors/image: one camera frame, raw BGR/mono or JPEG, with the pan angle at capture.

    ``pan_rad`` is the camera's pan relative to the robot's +x axis when the frame was taken
    (0 = looking forward, positive = left). ``intrinsics_id`` names the camera calibration in the
    vision settings (focal length, principal point), so one message type serves several cameras.
    """

    width: Annotated[int, msgspec.Meta(ge=1, le=MAX_IMAGE_SIDE)]
    height: Annotated[int, msgspec.Meta(ge=1, le=MAX_IMAGE_SIDE)]
    encoding: ImageEncoding
    data: memoryview
    pan_rad: Angle = 0.0
    intrinsics_id: Name = "default"

    def __post_init__(self) -> None:
        n = len(self.data)
        if self.encoding == "jpeg":
            if not 0 < n <= MAX_BYTES:
                raise ValueError(f"JPEG payload of {n} bytes")
            require(bytes(self.data[:2]) == b"\xff\xd8", "JPEG payload lacks the SOI marker")
        else:
            want = self.width * self.height * _CHANNELS[self.encoding]
            if n != want:
                raise ValueError(
                    f"{self.encoding} {self.width}x{self.height} needs {want} bytes, got {n}"
                )

    @classmethod
    def from_array(
        cls,
        pixels: np.ndarray,
        *,
        stamp_ns: int,
        pan_rad: float = 0.0,
        frame_id: str = "camera",
        seq: int = 0,
        intrinsics_id: str = "default",
    ) -> Image:
        """Wrap a HxWx3 BGR or HxW mono uint8 array without copying it (if C-contiguous)."""
        pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
        if pixels.ndim == 3 and pixels.shape[2] == 3:
            encoding = "bgr8"
        elif pixels.ndim == 2:
            encoding = "mono8"
        else:
            raise ValueError(f"expected HxWx3 BGR or HxW mono pixels, got shape {pixels.shape}")
        return cls(
            stamp_ns=stamp_ns,
            frame_id=frame_id,
            seq=seq,
            width=pixels.shape[1],
            height=pixels.shape[0],
            encoding=encoding,
            data=memoryview(pixels).cast("B"),
            pan_rad=pan_rad,
            intrinsics_id=intrinsics_id,
        )

    @classmethod
    def jpeg_from_array(cls, pixels: np.ndarray, *, quality: int = 90, **kw) -> Image:
        """Compress BGR pixels to JPEG (for links between machines)."""
        import cv2  # lazy: only JPEG users pay for it

        ok, buf = cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, quality])
        if not ok:
            raise ValueError("JPEG encoding failed")
        img = cls.from_array(pixels, **kw)
        img.encoding = "jpeg"
        img.data = memoryview(buf.tobytes())
        return img

    def pixels(self) -> np.ndarray:
        """HxWx3 (bgr8, jpeg) or HxW (mono8) uint8 pixels.

        Raw encodings return a read-only view into the payload (no copy). JPEG is decoded and
        must match ``width`` x ``height``; a corrupt JPEG raises ``ValueError``.
        """
        if self.encoding == "jpeg":
            import cv2

            out = cv2.imdecode(np.frombuffer(self.data, np.uint8), cv2.IMREAD_COLOR)
            if out is None:
                raise ValueError("corrupt JPEG payload")
            if out.shape[:2] != (self.height, self.width):
                raise ValueError(
                    f"JPEG is {out.shape[1]}x{out.shape[0]}, message says "
                    f"{self.width}x{self.height}"
                )
            return out
        flat = np.frombuffer(self.data, dtype=np.uint8)
        if self.encoding == "mono8":
            return flat.reshape(self.height, self.width)
        return flat.reshape(self.height, self.width, 3)


class Odometry(Message, tag="odometry", kw_only=True):
    """sensors/odom: the robot's dead-reckoned pose in ``frame_id`` (odom) and its twist.

    The pose drifts; only differences between two stamps are meaningful (ego-motion).
    """

    child_frame_id: Name = "base_link"
    x_m: Finite
    y_m: Finite
    yaw_rad: Angle
    v_mps: Finite = 0.0
    """Forward speed in the base frame."""
    w_radps: Finite = 0.0
    """Turn rate, counter-clockwise positive."""


# --------------------------------------------------------------------------- perception


class Leg(msgspec.Struct, kw_only=True):
    """One leg: its position and the beams of the scan it was found on (inclusive span)."""

    x_m: Finite
    y_m: Finite
    first_beam: Count
    last_beam: Count
    width_m: NonNegative = 0.0

    def __post_init__(self) -> None:
        require(self.first_beam <= self.last_beam, "leg first_beam > last_beam")


class Candidate(msgspec.Struct, kw_only=True):
    """A person-like thing in the laser scan (laser frame of the scan).

    A camera candidate source (camera_blobs) reports the floor point under an image region in
    the same frame, and the region itself in ``box_px``."""

    x_m: Finite
    y_m: Finite
    range_m: NonNegative
    bearing_rad: Angle
    width_m: NonNegative = 0.0
    legs: Annotated[list[Leg], msgspec.Meta(max_length=2)] = []
    """Zero (non-laser detectors), one or two legs."""
    pattern: Name = ""
    """Detector-specific: two_legs, one_leg, LA, FS, SL, circle, segment, ..."""
    confidence: _Probability = 1.0
    box_px: Annotated[list[NonNegative], msgspec.Meta(min_length=4, max_length=4)] | None = None
    """Camera candidates: the image region it was seen as, ``[x, y, w, h]`` in pixels of the
    frame named by the message's ``image_stamp_ns``, (x, y) its centre (seed 001 3.2). None:
    not seen in an image (laser candidates)."""

    def __post_init__(self) -> None:
        if self.box_px is not None:
            require(self.box_px[2] > 0 and self.box_px[3] > 0, "box_px with zero width or height")


class Horizon(msgspec.Struct, kw_only=True):
    """What the laser could see in one scan: the nearest return in each bearing bin, in the
    scan's frame. Bin ``i`` covers bearings ``angle_min_rad + [i, i + 1) * increment_rad``.

    ``ranges`` is 1-D float32 or float64, metres, 1 to MAX_BEAMS bins; +inf where no beam of the
    bin returned (the laser looked and saw nothing out to its maximum range). A bearing outside
    the bins was not looked at. The tracker reads it to tell a person hidden behind something
    nearer (a miss that says nothing) from one who is not where expected (a miss that counts).
    """

    angle_min_rad: Angle
    increment_rad: Annotated[float, msgspec.Meta(gt=0.0, le=math.pi)]
    ranges: Array

    def __post_init__(self) -> None:
        n = _ranges_length(self.ranges, "horizon ranges", "bins")
        if not self.increment_rad * n <= 2 * math.pi + 1e-6:
            raise ValueError(f"{n} bins of {self.increment_rad} rad span more than a full turn")


class PersonCandidates(Message, tag="person_candidates", kw_only=True):
    """perception/candidates: every person candidate of one scan, stamped with the scan's stamp.

    Published once per scan, also when empty, so downstream stages see that the scan was seen.
    """

    detector: Name = ""
    n_beams: Count = 0
    """Beams of the source scan: every leg's beam span lies in [0, n_beams)."""
    candidates: Annotated[list[Candidate], _Items] = []
    horizon: Horizon | None = None
    """The scan's nearest returns by bearing (laser detectors; None: not known). Lets the
    tracker tell a lost target hidden behind something nearer, and look where it will come
    out (tracker ``look_occluder_edge``)."""
    reach_m: Annotated[float, msgspec.Meta(gt=0.0)] | None = None
    """How far from the laser the detector can find anyone (metres): its range clip (the
    thesis's 3.5 m, 4.3.1) or the scan's maximum range, whichever is nearer (laser detectors;
    None: not known). Lets the tracker look for a target that walked out of reach where it
    would come back into it (tracker ``look_within_reach``)."""
    image_stamp_ns: Stamp = 0
    """Camera candidate sources: the stamp of the frame the candidates were found in (the
    newest at or before the scan's stamp); 0: not from an image."""
    image_width: Annotated[int, msgspec.Meta(ge=0, le=MAX_IMAGE_SIDE)] = 0
    """Camera candidate sources: that frame's width in pixels (``box_px`` is in its pixels);
    0: not from an image."""

    def __post_init__(self) -> None:
        for c in self.candidates:
            for leg in c.legs:
                if leg.last_beam >= self.n_beams:
                    raise ValueError(
                        f"leg beam span {leg.first_beam}..{leg.last_beam} "
                        f"outside {self.n_beams} beams"
                    )


class TargetModel(Message, tag="target_model", kw_only=True):
    """perception/target_model: what the target looks like, and where it was when learnt.

    ``features`` holds the verifier's descriptors, e.g. for the thesis histogram verifier
    ``colour_hs`` (216 bins) and ``edge_orientation`` (72 bins), each summing to 1, and
    ``patch_bgr`` (uint8 pixels of the model's rectangle, grown by a pixel) with
    ``patch_rect`` (where the rectangle lies in it), from which it recomputes the histograms of
    the part of the body a clipped or occluded candidate shows. Features are float, or uint8
    (image pixels).
    Also answered as a Zenoh query on the same key, so a restarted stage can recover it.
    """

    model_id: Count
    """Increments each time a model is (re)built; verifications name the model they used."""
    verifier: Name
    x_m: Finite
    y_m: Finite
    """Where the target was when the model was built (x_model, y_model), base frame of that
    scan."""
    rect_width_px: Annotated[float, msgspec.Meta(gt=0, le=MAX_IMAGE_SIDE)]
    rect_height_px: Annotated[float, msgspec.Meta(gt=0, le=MAX_IMAGE_SIDE)]
    image_width: Annotated[int, msgspec.Meta(ge=1, le=MAX_IMAGE_SIDE)]
    image_height: Annotated[int, msgspec.Meta(ge=1, le=MAX_IMAGE_SIDE)]
    features: Annotated[dict[Name, Array], msgspec.Meta(max_length=16)] = {}
    pan_rad: Angle = 0.0
    """Camera pan when the model was learnt (with x_m, y_m it gives the model's depth)."""

    def __post_init__(self) -> None:
        for name, arr in self.features.items():
            require(
                arr.dtype in ("<f4", "<f8", "|u1"),
                f"feature {name!r} must be float or uint8, got {arr.dtype}",
            )


class TargetCommand(Message, tag="target_command", kw_only=True):
    """perception/target_command: ask vision_verify to (re)build, drop, save or load the model."""

    action: Literal["acquire", "reset", "save", "load"]
    path: Name = ""
    """File for save/load."""


class VerifiedCandidate(msgspec.Struct, kw_only=True):
    """How one candidate of a scan looked to the verifier."""

    index: Count
    """Index in the PersonCandidates message of the judged scan."""
    x_m: Finite
    y_m: Finite
    """The candidate's position in the base frame of the judged scan."""
    in_view: bool
    distance: NonNegative | None = None
    """Appearance distance to the model (smaller is more alike); None when not in view."""
    probability: _Probability | None = None
    """Calibrated probability that this candidate is the target, from a verifier that gives
    one (``online``: distance = 1 - probability, so its threshold 0.5 means "less likely than
    not"); None from the others, or when not in view."""


class Verification(Message, tag="verification", kw_only=True):
    """perception/verification: which candidate of one scan is the target, by appearance.

    ``stamp_ns`` is the stamp of the *scan* whose candidates were judged (so a late verification
    can be applied to the state as of that scan); ``image_stamp_ns`` that of the image used.
    """

    image_stamp_ns: Stamp
    model_id: Count
    verifier: Name
    candidates: Annotated[list[VerifiedCandidate], _Items] = []
    chosen: int = -1
    """Index into ``candidates`` of the target, or -1 when none is taken."""
    threshold: NonNegative | None = None
    """Rejection threshold in force (None: always take the best)."""

    def __post_init__(self) -> None:
        if not -1 <= self.chosen < len(self.candidates):
            raise ValueError(f"chosen={self.chosen} with {len(self.candidates)} candidates")
        if self.chosen >= 0:
            require(self.candidates[self.chosen].in_view, "chosen candidate is not in view")


# --------------------------------------------------------------------------- tracking

TrackStatus = Literal["initialising", "tracking", "coasting", "lost"]
_Cov = Annotated[list[Finite], msgspec.Meta(min_length=16, max_length=16)]


class TrackState(Message, tag="track_state", kw_only=True):
    """tracking/target: the followed person's state in the base frame of the scan's stamp.

    ``covariance`` is the row-major 4x4 covariance of [x, y, vx, vy] (for the particle filter,
    the weighted spread of the particles). Position and velocity are meaningful only while
    ``status`` is tracking or coasting.
    """

    status: TrackStatus
    track_id: int = -1
    x_m: Finite = 0.0
    y_m: Finite = 0.0
    vx_mps: Finite = 0.0
    vy_mps: Finite = 0.0
    covariance: _Cov = msgspec.field(default_factory=lambda: [0.0] * 16)
    misses: Count = 0
    """Consecutive scans without a measurement of the target."""
    sources: Annotated[list[Name], msgspec.Meta(max_length=8)] = []
    """What fed the last update: laser, vision, odometry."""
    flags: Annotated[list[Name], msgspec.Meta(max_length=16)] = []
    """Degradations in force, e.g. no_odometry, no_vision."""
    estimator: Name = ""
    look_track_id: int = -1
    """While ``lost``: the tracked person (tracking/people id) the camera should look at so
    vision can tell whether it is the target; -1: none. The controller pans there."""
    look_x_m: Finite = 0.0
    look_y_m: Finite = 0.0
    """Where that person is (base frame of the scan's stamp); with ``look_track_id`` -1, a
    point to look at where nobody is tracked yet (where the lost target should be now), or
    (0, 0): nowhere. The controller pans there."""
    shift_x_m: Finite = 0.0
    shift_y_m: Finite = 0.0
    """The part of (x_m, y_m) that is the tracker's correction for legs seen alone (tracker
    setting lone_leg_output_m): (x_m - shift_x_m, y_m - shift_y_m) is its filter's own
    estimate, the one it associates candidates with, and laser_legs gates there
    (criterion 3). (0, 0) without the correction."""


class PersonTrack(msgspec.Struct, kw_only=True):
    """One tracked person (tracking/people)."""

    id: Count
    x_m: Finite
    y_m: Finite
    vx_mps: Finite = 0.0
    vy_mps: Finite = 0.0
    covariance: _Cov = msgspec.field(default_factory=lambda: [0.0] * 16)
    misses: Count = 0
    age_s: NonNegative = 0.0
    confidence: _Probability = 1.0


class People(Message, tag="people", kw_only=True):
    """tracking/people: every tracked person with a stable id; ``target_id`` names the target."""

    tracks: Annotated[list[PersonTrack], _Items] = []
    target_id: int = -1
    estimator: Name = ""

    def __post_init__(self) -> None:
        ids = [t.id for t in self.tracks]
        require(len(set(ids)) == len(ids), "duplicate track ids")


# --------------------------------------------------------------------------- control


#: Physical bounds of any command on the wire: no person-following base goes faster, so a
#: command beyond them is a fault or an attack and is rejected by every receiver.
MAX_LINEAR_MPS = 3.0
MAX_ANGULAR_RADPS = 2 * math.pi


class VelocityCommand(Message, tag="velocity_command", kw_only=True):
    """control/cmd_vel: base velocity; ``stamp_ns`` is the scan stamp the command derives from.
    Bounded on the wire: |linear| <= 3 m/s, |angular| <= 2 pi rad/s."""

    linear_mps: Annotated[float, msgspec.Meta(ge=-MAX_LINEAR_MPS, le=MAX_LINEAR_MPS)]
    angular_radps: Annotated[float, msgspec.Meta(ge=-MAX_ANGULAR_RADPS, le=MAX_ANGULAR_RADPS)]
    reason: Name = ""
    """Why. The thesis rule: ``max_speed`` (> 1.5 m), ``match_speed`` (1.2-1.5 m),
    ``stop_close`` (< 1.2 m), ``coasting`` (the last goal kept), ``lost`` / ``initialising``
    (stop). The obstacle guard: ``avoid_turn``, ``avoid_slow``, ``avoid_stop``, ``avoid_wait``,
    ``avoid_escape``, ``no_scan`` (stop). The safety stops: ``stale``, ``tracker_gone``,
    ``watchdog``, ``invalid`` (a non-finite command replaced by a stop). docs/tracker.md,
    Controller."""


class PanCommand(Message, tag="pan_command", kw_only=True):
    """control/pan: camera pan angle to go to (0 = forward, positive = left)."""

    pan_rad: Annotated[float, msgspec.Meta(ge=-math.pi, le=math.pi)]
    reason: Name = ""


# --------------------------------------------------------------------------- operations

_Counters = Annotated[dict[Name, Count], _Items]


class Health(Message, tag="health", kw_only=True):
    """health/<service>: a service's vital signs, published periodically.

    ``stamp_ns`` is wall-clock time (``time.time_ns()``). Rates are over the last period.
    """

    service: Name
    node_id: Name = ""
    status: Literal["ok", "degraded", "error"] = "ok"
    uptime_s: NonNegative = 0.0
    rates_hz: Annotated[dict[Name, NonNegative], _Items] = {}
    received: _Counters = {}
    rejected: _Counters = {}
    """Payloads that failed to decode or validate, per input topic."""
    dropped: _Counters = {}
    """Samples lost to a full input queue, per input topic."""
    errors: Count = 0
    """Exceptions raised by the service's own handlers (caught, logged, counted)."""
    proc_p50_ms: NonNegative = 0.0
    proc_p99_ms: NonNegative = 0.0
    last_error: Annotated[str, msgspec.Meta(max_length=1024)] = ""
    rss_mb: NonNegative = 0.0
    """Resident memory of the process, MiB (0 where the platform does not say)."""
    notes: Annotated[list[Name], msgspec.Meta(max_length=16)] = []
    reasons: Annotated[list[Name], msgspec.Meta(max_length=16)] = []
    """Why ``status`` is not ``ok``, one short phrase each (e.g. ``rejecting every sensors/scan``,
    ``no target model``, ``no peers``); empty when ``ok``."""
    host: Name = ""
    """Host name of the machine the service runs on."""
    pid: Count = 0
    """Process id of the service on that host."""


class PersonTruth(msgspec.Struct, kw_only=True):
    """One simulated person: world frame and robot (base_link) frame."""

    id: Count
    x_m: Finite
    y_m: Finite
    vx_mps: Finite = 0.0
    vy_mps: Finite = 0.0
    robot_x_m: Finite = 0.0
    robot_y_m: Finite = 0.0
    robot_vx_mps: Finite = 0.0
    robot_vy_mps: Finite = 0.0
    legs_robot_m: Annotated[list[Finite], msgspec.Meta(max_length=4)] = []
    """Leg centres in the robot frame as [x0, y0, x1, y1]."""
    is_target: bool = False
    visible_laser: bool = False
    visible_camera: bool = False


class GroundTruth(Message, tag="ground_truth", kw_only=True):
    """sim/truth: what really happened, for evaluation (simulator only)."""

    robot_x_m: Finite
    robot_y_m: Finite
    robot_yaw_rad: Angle
    robot_v_mps: Finite = 0.0
    robot_w_radps: Finite = 0.0
    camera_pan_rad: Angle = 0.0
    target_id: int = -1
    people: Annotated[list[PersonTruth], _Items] = []
    robot_bumps: Count = 0
    """Times the robot's body has run into the static world since the start (the simulator's
    bumper stopped it; a run of blocked steps counts once)."""


#: Every top-level message type, for union decoders and schema export.
MESSAGE_TYPES: tuple[type[Message], ...] = (
    LaserScan,
    Image,
    Odometry,
    PersonCandidates,
    TargetModel,
    TargetCommand,
    Verification,
    TrackState,
    People,
    VelocityCommand,
    PanCommand,
    Health,
    GroundTruth,
)
