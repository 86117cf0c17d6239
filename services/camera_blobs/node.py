"""camera_blobs: person candidates from the camera alone, by the target's colour (seed 001).

Seed 001 (Zhuang et al.) has no laser: the followed person wears one plain colour, learnt in
hue and saturation (3.1); each frame's pixels of that colour are grouped into regions (3.2),
and each region is a candidate. This stage publishes them on ``perception/candidates``, the
topic laser_legs publishes on, so the tracker and everything after it are the same services
whatever finds the candidates (core.py holds the image work, this file the service).

Each region ``[x, y, w, h]`` (pixels, (x, y) its centre) becomes one :class:`Candidate
<followbot.schemas.Candidate>`: its ``box_px``, and the floor point under the region's bottom
edge (equations 15-16 through ``camera``, services/runtime/ground_plane.py) as its position,
range and bearing, in the laser frame like every candidate (turned with ``laser_mount``; the
tracker turns it back). The bottom edge is read on the plane ``region_bottom_m`` above the
floor (trousers stop short of it). Regions whose bottom edge is at or above the horizon have no
floor point and are dropped (counted).

Inputs and answers (``answer_on``):

``image`` (a camera-only robot)
    one PersonCandidates per frame of ``sensors/image``, stamped with the frame's stamp.
``scan`` (the simulator's lock-step pipeline, where the scan is the clock)
    one PersonCandidates per ``sensors/scan``, stamped with the scan's stamp (lock-step rule
    2 of docs/runtime.md), from the newest frame at or before it (``image_stamp_ns``). The
    laser's ranges are not read. A frame older than ``max_image_age_s`` gives an empty answer
    (counted). In lock-step (``lockstep_image_wait_s`` > 0) scan k is held until a frame
    stamped within one ``image_period_s`` before it has arrived (it races the scan over
    another link; runtime.lockstep.HeldInputs), so the answer does not depend on timing.

The colour: either ``colour`` (thresholds given) or ``learn_rect``, the rectangle the user
drags on the target's clothing in the first frame (seed 3.1), learnt from the first frame that
arrives. Until a colour is known every answer is empty; a rectangle the colour cannot be learnt
from (too grey, outside the image) is logged with the reason and tried again on the next frame.

    followbot run camera_blobs --set 'learn_rect=[150, 140, 20, 40]'
    followbot run camera_blobs --set answer_on=scan --set camera.height_m=0.4
"""

from __future__ import annotations

import logging
import math
from collections import deque
from typing import Annotated, Literal

import msgspec
import numpy as np

from followbot.schemas import Candidate, Image, LaserScan, PersonCandidates
from followbot.services.runtime.ground_plane import GroundCamera
from followbot.services.runtime.lockstep import HeldInputs
from followbot.services.runtime.node import Node
from followbot.services.runtime.service import service_main
from followbot.services.runtime.settings import NodeSettings
from followbot.services.runtime.stats import RateLimitedLog

from .core import BlobSettings, ColourError, ColourModel, classify, learn_colour, regions

__all__ = ["BlobFinder", "CameraBlobsSettings", "check", "main", "setup"]

_NS = 1_000_000_000
DETECTOR = "colour_blobs"


class CameraBlobsSettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    colour: ColourModel | None = None
    """The target's colour as thresholds (hue_lo, hue_hi, sat_lo, sat_hi, min_value; OpenCV's
    HSV scale). Give this or learn_rect."""
    learn_rect: Annotated[list[float], msgspec.Meta(min_length=4, max_length=4)] | None = None
    """[x0, y0, width, height] in pixels of the first frame: the rectangle on the target's
    clothing the colour is learnt from (seed 3.1, the user's mouse drag)."""
    blobs: BlobSettings = msgspec.field(default_factory=BlobSettings)
    """Colour learning and region settings (services/camera_blobs/core.py)."""
    camera: GroundCamera = msgspec.field(default_factory=GroundCamera)
    """The camera over the floor (height, elevation, field of view, mount): a region's floor
    point comes from it (equations 15-16). A frame of another size than width x height is read
    as the same camera at that size."""
    region_bottom_m: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.0
    """How far above the floor a region's bottom edge is (m), its floor point read on that
    plane: trousers that end well above the shoes. 0: the region reaches the floor (the seed;
    in the simulator trousers end 0-3 cm above it)."""
    answer_on: Literal["image", "scan"] = "image"
    """image: one answer per camera frame (a robot without a laser). scan: one answer per
    sensors/scan stamp from the newest frame (the lock-step pipeline's clock)."""
    max_image_age_s: Annotated[float, msgspec.Meta(gt=0, le=10)] = 0.25
    """answer_on scan: a newest frame older than this before the scan gives an empty answer."""
    lockstep_image_wait_s: Annotated[float, msgspec.Meta(ge=0, le=10)] = 0.0
    """answer_on scan, lock-step runs: hold a scan until a frame stamped within image_period_s
    before it has arrived, at most this long. 0 (live): never wait."""
    image_period_s: Annotated[float, msgspec.Meta(gt=0, le=10)] = 0.1
    """The camera's frame period (the simulator's 10 Hz), for lock-step holding only."""


class _Frame(msgspec.Struct):
    stamp_ns: int
    pan_rad: float
    width: int
    height: int
    boxes: np.ndarray  # (n, 4) [x, y, w, h]


class BlobFinder:
    """Frames -> regions of the target's colour -> candidates. No Zenoh (the node drives it)."""

    def __init__(self, settings: CameraBlobsSettings) -> None:
        self.s = settings
        self.colour: ColourModel | None = settings.colour
        self.colour_error = ""
        self.above_horizon = 0

    def regions_of(self, pixels: np.ndarray) -> np.ndarray:
        """(n, 4) regions of a BGR frame; learns the colour first if it is not known yet.
        Empty while no colour is known (``colour_error`` says why)."""
        if self.colour is None:
            rect = tuple(self.s.learn_rect)  # type: ignore[arg-type]
            try:
                self.colour = learn_colour(pixels, rect, self.s.blobs)
                self.colour_error = ""
            except ColourError as exc:
                self.colour_error = str(exc)
                return np.zeros((0, 4))
        return regions(classify(pixels, self.colour), self.s.blobs)

    def candidates(self, frame: _Frame, mount) -> list[Candidate]:
        """One candidate per region whose bottom edge sees the floor, in the laser frame."""
        if len(frame.boxes) == 0:
            return []
        cam = self.s.camera
        if (frame.width, frame.height) != (cam.width, cam.height):
            cam = cam.scaled(frame.width, frame.height)
        cam = cam.above_floor(self.s.region_bottom_m)
        b = frame.boxes
        fx, fy = cam.pixel_to_floor(b[:, 0], b[:, 1] + b[:, 3] / 2.0, frame.pan_rad)
        ok = np.isfinite(fx) & np.isfinite(fy)
        self.above_horizon += int(np.sum(~ok))
        if not ok.any():
            return []
        base = np.column_stack([fx[ok], fy[ok]])
        laser = mount.to_laser(base)
        depth = np.hypot(base[:, 0] - cam.mount_x_m, base[:, 1])
        out = []
        for (x, y), d, box in zip(laser, depth, b[ok], strict=True):
            out.append(
                Candidate(
                    x_m=float(x),
                    y_m=float(y),
                    range_m=float(math.hypot(x, y)),
                    bearing_rad=float(math.atan2(y, x)),
                    width_m=float(box[2] * d / cam.focal_px),
                    pattern="blob",
                    box_px=[float(v) for v in box],
                )
            )
        return out


class _Stage:
    """The node's state and handlers (the node runs them one at a time)."""

    def __init__(self, node: Node, settings: CameraBlobsSettings) -> None:
        self.node, self.s = node, settings
        self.finder = BlobFinder(settings)
        self.frames: deque[_Frame] = deque(maxlen=8)
        self.out = node.publisher("perception/candidates")
        self.counts = {"frames": 0, "bad_frames": 0, "stale": 0, "no_frame": 0}
        self.bad_log = RateLimitedLog(node.log, 5.0)
        wait = settings.lockstep_image_wait_s if settings.answer_on == "scan" else 0.0
        self.held = HeldInputs(node, self.answer_scan, self.ready, wait, "scans")
        self.wait = wait

    # ------------------------------------------------------------------ inputs

    def on_image(self, img: Image) -> None:
        try:
            pixels = img.pixels()
            if pixels.ndim != 3:
                raise ValueError(f"{img.encoding} frame: the colour model needs BGR pixels")
            boxes = self.finder.regions_of(pixels)
        except ValueError as exc:  # a corrupt JPEG, a mono camera: counted, never a crash
            self.counts["bad_frames"] += 1
            self.bad_log.log(logging.WARNING, "bad", "frame %d refused: %s", img.stamp_ns, exc)
            return
        if self.finder.colour_error:
            self.bad_log.log(
                logging.ERROR, "colour", "no colour learnt: %s", self.finder.colour_error
            )
        self.counts["frames"] += 1
        frame = _Frame(img.stamp_ns, img.pan_rad, img.width, img.height, boxes)
        if self.frames and frame.stamp_ns <= self.frames[-1].stamp_ns:
            self.frames.clear()  # an older stamp: the source restarted (or repeats itself)
        self.frames.append(frame)
        if self.s.answer_on == "image":
            self.publish(frame.stamp_ns, "camera", img.seq, frame)
        else:
            self.held.release()

    def ready(self, scan: LaserScan) -> bool:
        """Lock-step: the frame that belongs to scan k (within one period before it) is here."""
        if self.wait <= 0:
            return True
        newest = self.frames[-1].stamp_ns if self.frames else -1
        return newest > scan.stamp_ns - self.s.image_period_s * _NS

    def answer_scan(self, scan: LaserScan) -> None:
        frame = None
        for f in reversed(self.frames):
            if f.stamp_ns <= scan.stamp_ns:
                frame = f
                break
        if frame is None:
            self.counts["no_frame"] += 1
        elif scan.stamp_ns - frame.stamp_ns > self.s.max_image_age_s * _NS:
            self.counts["stale"] += 1
            frame = None
        self.publish(scan.stamp_ns, scan.frame_id, scan.seq, frame)

    def publish(self, stamp_ns: int, frame_id: str, seq: int, frame: _Frame | None) -> None:
        cands = [] if frame is None else self.finder.candidates(frame, self.s.laser_mount)
        self.out.put(
            PersonCandidates(
                stamp_ns=stamp_ns,
                frame_id=frame_id,
                seq=seq,
                detector=DETECTOR,
                candidates=cands[:256],
                image_stamp_ns=0 if frame is None else frame.stamp_ns,
                image_width=0 if frame is None else frame.width,
            )
        )

    def restart(self) -> None:
        """The source restarted with a new clock: its frames and held scans belong to the old."""
        self.frames.clear()
        self.held.clear()

    def notes(self) -> None:
        c = self.counts
        self.node.notes = [
            f"colour={'learnt' if self.finder.colour is not None else 'none'}",
            f"frames={c['frames']}",
            f"bad_frames={c['bad_frames']}",
            f"scans_without_frame={c['no_frame']}",
            f"scans_stale_frame={c['stale']}",
            f"regions_above_horizon={self.finder.above_horizon}",
            f"lockstep_waits={self.held.waits}",
            f"lockstep_wait_timeouts={self.held.timeouts}",
        ]


def check(settings: CameraBlobsSettings) -> None:
    """A colour to follow must be named (exactly one of ``colour`` and ``learn_rect``), and
    the learning rectangle must lie in the camera's image (a frame of another size is the same
    camera scaled, so the rectangle is checked against the configured size)."""
    if (settings.colour is None) == (settings.learn_rect is None):
        raise ValueError(
            "camera_blobs needs the target's colour: give learn_rect ([x0, y0, width, "
            "height] on the target's clothing in the first frame) or colour (thresholds), "
            "exactly one of them"
        )
    settings.camera.above_floor(settings.region_bottom_m)  # below the camera
    if settings.learn_rect is not None:
        x0, y0, w, h = settings.learn_rect
        cam = settings.camera
        if not (w > 0 and h > 0):
            raise ValueError(f"learn_rect {settings.learn_rect}: width and height must be > 0")
        if x0 < 0 or y0 < 0 or x0 + w > cam.width or y0 + h > cam.height:
            raise ValueError(
                f"learn_rect {settings.learn_rect} is not inside the camera's "
                f"{cam.width}x{cam.height} image (camera.width, camera.height)"
            )


def setup(node: Node, settings: CameraBlobsSettings) -> BlobFinder:
    st = _Stage(node, settings)
    node.subscribe(
        "sensors/image", st.on_image, policy="all", on_restart=st.restart, expect_within_s=1.0
    )
    if settings.answer_on == "scan":
        node.subscribe(
            "sensors/scan", st.held.offer, policy="all", on_restart=st.restart, expect_within_s=1.0
        )
    st.notes()
    node.every(settings.health_period_s, st.notes, name="notes")
    node.log.info("answer on %s, colour %s", settings.answer_on, settings.colour or "to learn")
    return st.finder


def main(argv: list[str] | None = None) -> int:
    return service_main("camera_blobs", CameraBlobsSettings, setup, argv, __doc__, check)
