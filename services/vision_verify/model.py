"""Target model construction (thesis 3.3, 4.2): where the one moving person is, image and laser.

Image (thesis 4.2.1.1). Two successive frames -> grey -> smoothed with the separable kernel
[0.25, 0.5, 0.25] in x and y -> |difference| -> threshold 80 of 255 -> bounding rectangle of
the changed pixels. A rectangle smaller than 0.4 W H (30 720 px at 320 x 240) is not enough
movement: the next pair of frames is tried. The rectangle's vertical centre is then put on the
image's horizontal centre line (thesis 3.5.1.2), so every later rectangle is centred there too.

Laser (thesis 3.3.2, 4.2.2). The previous scan is the reference (at least ``min_pair_s`` older:
a faster scanner's scans in between are skipped, as are a faster camera's frames between the
two compared); beams whose range changed by
more than 30 mm (twice the scanner's +-15 mm) that fall on a leg of a candidate of the
reference scan mark that candidate as moving. Exactly one moving candidate locates the person
(x_model, y_model); its position is taken from the current scan's candidate nearest to it.

The two are paired when their stamps are within a tolerance and the laser position projects
into the image rectangle (the same person moved in both), and the pan did not change between
the two frames (the thesis builds the model with the camera still). The camera's pan may be
any fixed angle.

Models are saved to and loaded from files as the msgpack-encoded TargetModel wire message; the
service keeps them in one folder (:class:`ModelFiles`, docs/vision_verify.md "Model files").
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import secrets
import stat
import tempfile
from pathlib import Path
from typing import Annotated

import cv2
import msgspec
import numpy as np

from followbot.schemas import PersonCandidates, RejectedMessage, TargetModel, decode, encode

from .core import Camera, ImageFeatures, Model, Rect, Verifier, View, clip_rect

__all__ = [
    "MAX_MODEL_BYTES",
    "AcquireSettings",
    "Acquisition",
    "ModelBuilder",
    "ModelFileError",
    "ModelFiles",
    "build_model",
    "default_models_dir",
    "load_model",
    "motion_rect",
    "moving_candidates",
    "moving_legs",
    "moving_pairs",
    "recentre",
    "save_model",
    "smooth_grey",
]

_KERNEL = np.array([0.25, 0.5, 0.25], dtype=np.float32)  # thesis 4.2.1.1: 3-tap kernel


class AcquireSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Learning a model from the target moving alone in front of the still robot (thesis
    4.2): ``--set acquire.auto=true``."""

    auto: bool = False
    """Learn a model on start, without a command (one mover, still robot), when nobody on the
    network holds one: it is used only after a query sent once ``recovery.holder`` was seen
    alive (or ``recovery.holder_wait_s`` after start) found no model, and is dropped if a
    model is recovered first (docs/vision_verify.md "The target model")."""
    timeout_s: Annotated[float, msgspec.Meta(gt=0)] = 30.0
    """An acquisition (an acquire command, or ``auto``) that has learnt no model after this
    long (s) gives up, with a warning (counted as acquire_timeout)."""
    diff_threshold: float = 80.0  # thesis 4.2.1.1: 80 of 255
    min_area_fraction: float = 0.4  # thesis eq. 4-2: T_A = 0.4 x 320 x 240
    laser_threshold_m: float = 0.030  # thesis 4.2.2: 30 mm (laser accuracy +-15 mm)
    min_changed_beams: int = 2
    """Changed beams a leg must hold to count as moving (1 would let single noisy beams in)."""
    min_changed_fraction: float = 0.5
    """... and the share of its beams that must have changed (see moving_candidates)."""
    pair_tolerance_s: float = 0.15
    """Largest stamp difference between the image pair and the laser fix that are paired."""
    min_pair_s: Annotated[float, msgspec.Meta(ge=0)] = 0.08
    """The two scans (and the two frames) compared are at least this far apart: a faster
    sensor's scans or frames in between are skipped. Thesis 4.2 compares consecutive scans
    about 120 ms apart, in which a walking leg moves ~60 mm, twice ``laser_threshold_m``; at
    40 Hz it moves ~15 mm and nobody would ever be seen moving (the simulator's two-person
    scenario at 40 Hz: no model in 40 s). 0.08: every scan up to 12.5 Hz, every second at
    25 Hz, every fourth at 40 Hz."""
    match_radius_m: float = 0.4
    """Reference-scan mover to current-scan candidate: nearest within this radius."""
    column_margin_px: float = 20.0
    """The laser fix must project inside the motion rectangle widened by this margin."""
    max_width_m: float = 1.2
    """A motion rectangle wider than this at the laser fix's depth holds more than one mover."""
    nearer_in_rect_m: float | None = 0.5
    """Beyond the thesis: refuse a fix when another laser candidate stands inside the motion
    rectangle's columns this much nearer than the fix -- the nearer one hides what lies behind
    it, so the image's motion is as likely its own (a door frame's flickering edge far behind
    the target setting off is otherwise taken as the mover; docs/tracker_log.md). None: off."""
    alone_s: float = 0.5
    """The window (s) in which the mover must have moved alone (see crowd_pairs)."""
    crowd_pairs: int = 2
    """The mover must have moved alone: ``crowd_pairs`` or more scan pairs within the last
    ``alone_s`` that saw two movers, or one mover somewhere else (farther than
    match_radius_m), refuse the fix (one such pair is let through: a leg of a standing person
    half hidden by the mover changes too). Beyond the thesis (which checks one scan pair): two
    people who set off together are seen moving one at a time, as their gaits alternate, and
    the model went to either of them."""


# --------------------------------------------------------------------------- image


def smooth_grey(bgr: np.ndarray) -> np.ndarray:
    """Intensity smoothed with [0.25 0.5 0.25] horizontally and vertically (float32)."""
    grey = bgr if bgr.ndim == 2 else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    return cv2.sepFilter2D(grey, cv2.CV_32F, _KERNEL, _KERNEL)


def motion_rect(
    prev: np.ndarray, cur: np.ndarray, threshold: float = 80.0
) -> tuple[Rect | None, int]:
    """Bounding rectangle of the pixels that changed by more than ``threshold`` between two
    smoothed intensity images (from :func:`smooth_grey`), and how many pixels changed."""
    if prev.shape != cur.shape:
        raise ValueError(f"frames differ in size: {prev.shape} vs {cur.shape}")
    changed = (cv2.absdiff(prev, cur) > threshold).view(np.uint8)
    n = int(cv2.countNonZero(changed))
    if n == 0:
        return None, 0
    x, y, w, h = cv2.boundingRect(cv2.findNonZero(changed))
    return (x, y, x + w, y + h), n


def recentre(rect: Rect, width: int, height: int, cy: float) -> Rect | None:
    """``rect`` moved vertically so its centre is on row ``cy`` (thesis 3.5.1.2), clipped."""
    x0, y0, x1, y1 = rect
    h = y1 - y0
    top = round(cy - h / 2)
    return clip_rect((x0, top, x1, top + h), width, height)


# --------------------------------------------------------------------------- laser


def moving_candidates(
    ref_ranges: np.ndarray,
    cur_ranges: np.ndarray,
    ref_candidates: PersonCandidates,
    threshold_m: float = 0.03,
    min_beams: int = 2,
    min_fraction: float = 0.0,
) -> list[int]:
    """Indices of the candidates with a leg holding >= ``min_beams`` beams, and at least
    ``min_fraction`` of its beams, whose range changed by more than ``threshold_m`` (thesis
    4.2.2); beams without a return (NaN, 0) in either scan do not count. A beam that saw
    nothing within range (+inf, REP-117) in one scan and a leg in the other did change: a
    leg that steps in front of open space beyond the scanner's reach is a leg that moved.

    The fraction is beyond the thesis: its 30 mm is twice the scanner's +-15 mm accuracy, but
    with Gaussian noise of 15 mm (the simulator's) the difference of two readings exceeds 30 mm
    on 16 % of the beams, so a standing person's leg of ~9 beams showed 2 changed beams in 41 %
    of the scan pairs; half of its beams, in 4 % (a moving leg: 55 %)."""
    return list(
        moving_legs(ref_ranges, cur_ranges, ref_candidates, threshold_m, min_beams, min_fraction)
    )


def moving_legs(
    ref_ranges: np.ndarray,
    cur_ranges: np.ndarray,
    candidates: PersonCandidates,
    threshold_m: float = 0.03,
    min_beams: int = 2,
    min_fraction: float = 0.0,
) -> dict[int, list[int]]:
    """{candidate index: indices of its legs that moved} (see :func:`moving_candidates`)."""
    ref = np.asarray(ref_ranges, dtype=np.float64)
    cur = np.asarray(cur_ranges, dtype=np.float64)
    if ref.shape != cur.shape:
        return {}
    with np.errstate(invalid="ignore"):
        # +inf is a reading (nothing within range); inf - inf is NaN, which is no change
        valid = ~np.isnan(ref) & ~np.isnan(cur) & (ref > 0) & (cur > 0)
        changed = valid & (np.abs(cur - ref) > threshold_m)
    counts = np.concatenate([[0], np.cumsum(changed)])
    out: dict[int, list[int]] = {}
    for i, c in enumerate(candidates.candidates):
        for j, leg in enumerate(c.legs):
            a, b = leg.first_beam, min(leg.last_beam, ref.shape[0] - 1)
            if a > b:
                continue
            n = int(counts[b + 1] - counts[a])
            if n >= min_beams and n >= min_fraction * (b - a + 1):
                out.setdefault(i, []).append(j)
    return out


def moving_pairs(
    ref_ranges: np.ndarray,
    cur_ranges: np.ndarray,
    ref_candidates: PersonCandidates,
    cur_candidates: PersonCandidates,
    threshold_m: float = 0.03,
    min_beams: int = 2,
    match_radius_m: float = 0.5,
    min_fraction: float = 0.0,
) -> list[tuple[int, int]]:
    """(reference index, current index) of the candidates that moved: changed beams under its
    legs in *both* scans, and the two positions within ``match_radius_m`` of each other.

    Beyond the thesis (4.2.2 looks at one scan): a person standing behind the one who moves is
    covered in one scan and seen in the other, so the changed beams fall on their legs in one
    of the two scans only; a person who moves has changed beams under its legs in both (where
    it went and where it was). Without this a bystander just behind the target was taken as the
    mover (thesis_5_2_4_side_by_side, ..._swapped)."""
    return _movers(
        ref_ranges, cur_ranges, ref_candidates, cur_candidates, threshold_m, min_beams,
        match_radius_m, min_fraction,
    )[0]  # fmt: skip


def _movers(
    ref_ranges, cur_ranges, ref_candidates, cur_candidates, threshold_m, min_beams,
    match_radius_m, min_fraction,
) -> tuple[list[tuple[int, int]], list[int]]:  # fmt: skip
    """:func:`moving_pairs`, and every candidate of the current scan with changed beams
    under its legs (paired or not)."""
    args = (threshold_m, min_beams, min_fraction)
    ref_movers = moving_candidates(ref_ranges, cur_ranges, ref_candidates, *args)
    cur_movers = moving_candidates(ref_ranges, cur_ranges, cur_candidates, *args)
    pairs = []
    for i in ref_movers:
        a = ref_candidates.candidates[i]
        best, best_d = -1, match_radius_m
        for j in cur_movers:
            b = cur_candidates.candidates[j]
            d = math.hypot(b.x_m - a.x_m, b.y_m - a.y_m)
            if d < best_d:
                best, best_d = j, d
        if best >= 0:
            pairs.append((i, best))
    return pairs, cur_movers


# --------------------------------------------------------------------------- builder


class Acquisition(msgspec.Struct, kw_only=True):
    """What the model is made of: the frame, the rectangle, the laser position."""

    stamp_ns: int
    bgr: np.ndarray
    rect: Rect
    pan_rad: float
    x_m: float
    y_m: float


class ModelBuilder:
    """Feed it images and scans (with their candidates) while the robot stands still; it
    returns an :class:`Acquisition` once the image and the laser agree on one moving person."""

    def __init__(self, camera: Camera, settings: AcquireSettings | None = None) -> None:
        self.camera = camera
        self.settings = settings or AcquireSettings()
        self._prev: tuple[int, np.ndarray, float] | None = None  # stamp, smoothed, pan
        self._motion: tuple[int, np.ndarray, Rect, float] | None = None  # stamp, bgr, rect, pan
        self._ref: tuple[int, np.ndarray, PersonCandidates] | None = None
        self._fix: tuple[int, float, float] | None = None  # stamp, x, y
        self._fix_others: np.ndarray = np.empty((0, 2))  # the fix scan's other candidates
        self._last_mover: tuple[int, float, float] | None = None  # stamp, x, y
        self._crowd: list[int] = []  # stamps of recent scan pairs that saw another mover
        self.attempts = {
            "image_pairs": 0,
            "small_motion": 0,
            "laser_pairs": 0,
            "ambiguous": 0,
            "mismatch": 0,
        }

    def add_image(self, stamp_ns: int, bgr: np.ndarray, pan_rad: float) -> Acquisition | None:
        s, cam = self.settings, self.camera
        if self._prev is not None and 0 <= stamp_ns - self._prev[0] < s.min_pair_s * 1e9:
            return None  # too soon after the frame it would be compared with
        cur = smooth_grey(bgr)
        prev, self._prev = self._prev, (stamp_ns, cur, pan_rad)
        if prev is None or prev[1].shape != cur.shape or abs(prev[2] - pan_rad) > 1e-3:
            return None
        self.attempts["image_pairs"] += 1
        rect, _ = motion_rect(prev[1], cur, s.diff_threshold)
        h, w = cur.shape
        if rect is None or (rect[2] - rect[0]) * (rect[3] - rect[1]) < s.min_area_fraction * w * h:
            self.attempts["small_motion"] += 1  # thesis 4.2.1.1: try two more frames
            return None
        rect = recentre(rect, w, h, cam.cy)
        if rect is None:
            return None
        self._motion = (stamp_ns, bgr, rect, pan_rad)
        return self._try()

    def add_scan(
        self, stamp_ns: int, ranges: np.ndarray, candidates: PersonCandidates
    ) -> Acquisition | None:
        s = self.settings
        if self._ref is not None and 0 <= stamp_ns - self._ref[0] < s.min_pair_s * 1e9:
            return None  # too soon after the scan it would be compared with
        ref, self._ref = self._ref, (stamp_ns, np.array(ranges, dtype=np.float64), candidates)
        if ref is None:
            return None
        self.attempts["laser_pairs"] += 1
        movers, changed = _movers(
            ref[1], ranges, ref[2], candidates, s.laser_threshold_m, s.min_changed_beams,
            s.match_radius_m, s.min_changed_fraction,
        )  # fmt: skip
        window_ns = s.alone_s * 1e9
        # Beyond the thesis: a candidate of this scan whose legs' beams changed but that has no
        # counterpart in the reference (not detected there: it stood still, or stepped out
        # from behind someone) may be the one who moved; within max_width_m of the pair found
        # (where the image's motion cannot tell the two apart) the pair is not alone
        # (thesis_5_2_4_turn_apart at 40 Hz: the target, undetected while it stood, set off
        # and its step changed a beam by the non-target, who was taken as the mover)
        alone = len(movers) == 1 and not self._near_other_mover(candidates, movers[0][1], changed)
        if len(movers) > 1 or (movers and not alone):
            self._crowd.append(stamp_ns)
        elif len(movers) == 1:
            x, y = self._mover_position(ref[1], ranges, candidates, movers[0][1])
            last, self._last_mover = self._last_mover, (stamp_ns, x, y)
            if (
                last is not None
                and stamp_ns - last[0] <= window_ns
                and math.hypot(x - last[1], y - last[2]) > s.match_radius_m
            ):
                self._crowd.append(stamp_ns)  # someone else moved in the previous pairs
        else:
            return None
        self._crowd = [t for t in self._crowd if stamp_ns - t <= window_ns]
        if not alone or len(self._crowd) >= s.crowd_pairs:
            self.attempts["ambiguous"] += 1  # thesis 4.2: the target must move alone
            return None
        self._fix = (stamp_ns, x, y)
        self._fix_others = np.array(
            [[c.x_m, c.y_m] for i, c in enumerate(candidates.candidates) if i != movers[0][1]],
            dtype=np.float64,
        ).reshape(-1, 2)
        return self._try()

    def _near_other_mover(
        self, candidates: PersonCandidates, mover: int, changed: list[int]
    ) -> bool:
        """Another candidate of ``changed`` within ``max_width_m`` of candidate ``mover``."""
        c = candidates.candidates
        return any(
            j != mover
            and math.hypot(c[j].x_m - c[mover].x_m, c[j].y_m - c[mover].y_m)
            <= self.settings.max_width_m
            for j in changed
        )

    def _mover_position(
        self, ref: np.ndarray, cur: np.ndarray, candidates: PersonCandidates, index: int
    ) -> tuple[float, float]:
        """Where the mover is in the current scan: the mean of its legs that moved. A pair
        of legs may hold a leg of someone standing next to the mover (the thesis pairs legs
        up to 500 mm apart); the pair's centre then lies between the two people."""
        s = self.settings
        c = candidates.candidates[index]
        legs = moving_legs(
            ref, cur, candidates, s.laser_threshold_m, s.min_changed_beams,
            s.min_changed_fraction,
        ).get(index, [])  # fmt: skip
        if not legs or len(legs) == len(c.legs):
            return c.x_m, c.y_m
        return (
            float(np.mean([c.legs[j].x_m for j in legs])),
            float(np.mean([c.legs[j].y_m for j in legs])),
        )

    def _try(self) -> Acquisition | None:
        if self._motion is None or self._fix is None:
            return None
        t_img, bgr, rect, pan = self._motion
        t_fix, x, y = self._fix
        if abs(t_img - t_fix) > self.settings.pair_tolerance_s * 1e9:
            return None
        xc, yc = self.camera.to_camera(np.array(x), np.array(y), pan)
        m = self.settings.column_margin_px
        if not (float(xc) >= self.camera.min_depth_m):
            self.attempts["mismatch"] += 1
            return None
        u = float(self.camera.column(xc, yc))
        too_wide = (rect[2] - rect[0]) > self.settings.max_width_m * self.camera.f / float(xc)
        if too_wide or not (rect[0] - m <= u <= rect[2] + m) or self._nearer_in(rect, xc, pan):
            self.attempts["mismatch"] += 1  # image and laser saw different movers
            self._motion = None
            return None
        return Acquisition(stamp_ns=t_img, bgr=bgr, rect=rect, pan_rad=pan, x_m=x, y_m=y)

    def _nearer_in(self, rect: Rect, depth: float, pan: float) -> bool:
        """nearer_in_rect_m: another candidate of the fix's scan inside the rectangle's
        columns, that much nearer the camera than the fix."""
        margin = self.settings.nearer_in_rect_m
        others = self._fix_others
        if margin is None or not others.shape[0]:
            return False
        xc, yc = self.camera.to_camera(others[:, 0], others[:, 1], pan)
        ahead = xc >= self.camera.min_depth_m
        if not ahead.any():
            return False
        u = self.camera.column(xc[ahead], yc[ahead])
        inside = (u >= rect[0]) & (u <= rect[2]) & (xc[ahead] < float(depth) - margin)
        return bool(inside.any())


def build_model(verifier: Verifier, camera: Camera, acq: Acquisition, model_id: int) -> Model:
    """Learn the verifier's features in the acquisition's rectangle."""
    xc, yc = camera.to_camera(np.array(acq.x_m), np.array(acq.y_m), acq.pan_rad)
    depth, lateral = float(xc), float(yc)
    if not depth >= camera.min_depth_m:
        raise ValueError(
            f"target at ({acq.x_m:.2f}, {acq.y_m:.2f}) m is not in front of the camera"
        )
    h, w = acq.bgr.shape[:2]
    rect = clip_rect(acq.rect, w, h)
    if rect is None:
        raise ValueError(f"empty model rectangle {acq.rect}")
    frame = ImageFeatures(acq.bgr)
    frame.cache["camera"] = camera
    view = View(
        index=0,
        x_m=acq.x_m,
        y_m=acq.y_m,
        depth_m=depth,
        lateral_m=lateral,
        u_px=float(camera.column(depth, lateral)),
        rect=rect,
    )
    return Model(
        model_id=model_id,
        verifier=verifier.name,
        x_m=acq.x_m,
        y_m=acq.y_m,
        depth_m=depth,
        rect_w_px=float(rect[2] - rect[0]),
        rect_h_px=float(rect[3] - rect[1]),
        image_width=w,
        image_height=h,
        features=verifier.learn(frame, rect, view),
        pan_rad=acq.pan_rad,
        stamp_ns=acq.stamp_ns,
    )


# --------------------------------------------------------------------------- files

#: Default bound on a model file's size: a histogram model holds the pixels it was learnt
#: from (0.1 MB for the simulator's 135 x 240 px person in a 320 x 240 frame; a whole
#: 1280 x 720 frame would be 2.8 MB).
MAX_MODEL_BYTES = 4 * 1024 * 1024

#: What a model name may be: a plain file name, no folder, not hidden (so never "." or "..").
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]{0,127}")


class ModelFileError(ValueError):
    """A model file that cannot be saved or loaded; ``kind`` names why in a few fixed words
    (for counting), the message says it in full."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def default_models_dir() -> Path:
    """``$XDG_DATA_HOME/followbot/models``, by default ``~/.local/share/followbot/models``."""
    data = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(data) / "followbot" / "models"


class ModelFiles:
    """The model files of one folder, by name: the only files the service reads or writes on
    a command from the network.

    A name is a plain file name in the folder (letters, digits, ``.``, ``_``, ``-``; up to 128
    characters; not starting with ``.``): no folders, no ``..``, no absolute paths. Nothing
    but the folder itself is ever created, and only by :meth:`save`. Only regular files are
    read: symbolic links, FIFOs, devices and folders are refused from what ``lstat`` says
    before anything is opened, and the file is opened with ``O_NOFOLLOW | O_NONBLOCK``, so
    no path can make the caller wait on a pipe. Files larger than ``max_bytes`` are refused
    on both ways.
    """

    def __init__(self, folder: str | os.PathLike, max_bytes: int = MAX_MODEL_BYTES) -> None:
        self.folder = Path(folder).expanduser().absolute()
        self.max_bytes = max_bytes

    def check_name(self, name: str) -> str:
        """``name`` if it names a file of the folder; ModelFileError otherwise."""
        if not _NAME.fullmatch(name):
            raise ModelFileError(
                "bad_name",
                f"{name!r} is not a model name: a file name in {self.folder} (letters, digits, "
                "'.', '_', '-', at most 128, not starting with '.'), no folders or '..'",
            )
        return name

    def save(self, name: str, message: TargetModel) -> Path:
        """Write ``message`` to ``name`` atomically (a reader never sees half a file); the
        path written. Refused when it would be over ``max_bytes`` or ``name`` is taken by
        something that is not a regular file."""
        self.check_name(name)
        data = encode(message)
        if len(data) > self.max_bytes:
            raise ModelFileError(
                "too_large",
                f"model {message.model_id} takes {len(data)} bytes, more than the "
                f"{self.max_bytes} a model file may have",
            )
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            dir_fd = os.open(self.folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        except OSError as exc:
            raise ModelFileError(
                "io_error", f"cannot use the models folder {self.folder}: {exc.strerror}"
            ) from None
        try:
            self._require_regular_or_absent(name, dir_fd)
            tmp = f".{name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
            flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
            try:
                fd = os.open(tmp, flags, 0o644, dir_fd=dir_fd)
                try:
                    with os.fdopen(fd, "wb") as fh:
                        fh.write(data)
                    os.replace(tmp, name, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
                except BaseException:
                    with contextlib.suppress(OSError):
                        os.unlink(tmp, dir_fd=dir_fd)
                    raise
            except OSError as exc:
                raise ModelFileError(
                    "io_error", f"cannot write {self.folder / name}: {exc.strerror}"
                ) from None
        finally:
            os.close(dir_fd)
        return self.folder / name

    def load(self, name: str) -> TargetModel:
        """The model in file ``name`` of the folder; ModelFileError saying why not."""
        self.check_name(name)
        try:
            dir_fd = os.open(self.folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        except FileNotFoundError:
            raise ModelFileError(
                "missing", f"no model file {name!r}: there is no models folder {self.folder}"
            ) from None
        except OSError as exc:
            raise ModelFileError(
                "io_error", f"cannot open the models folder {self.folder}: {exc.strerror}"
            ) from None
        try:
            if not self._require_regular_or_absent(name, dir_fd):
                raise ModelFileError("missing", f"no model file {name!r} in {self.folder}")
            data = _read_regular(name, dir_fd, self.max_bytes, self.folder / name)
        finally:
            os.close(dir_fd)
        return _decode_model(data, self.folder / name)

    def _require_regular_or_absent(self, name: str, dir_fd: int) -> bool:
        """Whether ``name`` exists; ModelFileError when it is not a regular file."""
        try:
            st = os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise ModelFileError(
                "io_error", f"cannot look at {self.folder / name}: {exc.strerror}"
            ) from None
        if not stat.S_ISREG(st.st_mode):
            raise ModelFileError(
                "not_regular",
                f"{self.folder / name} is a {_file_kind(st.st_mode)}, not a regular file",
            )
        return True


def _file_kind(mode: int) -> str:
    for test, what in (
        (stat.S_ISLNK, "symbolic link"),
        (stat.S_ISFIFO, "named pipe (FIFO)"),
        (stat.S_ISCHR, "character device"),
        (stat.S_ISBLK, "block device"),
        (stat.S_ISDIR, "folder"),
        (stat.S_ISSOCK, "socket"),
    ):
        if test(mode):
            return what
    return "special file"


def _read_regular(
    name: str | os.PathLike, dir_fd: int | None, max_bytes: int, shown: str | os.PathLike
) -> bytes:
    """The bytes of regular file ``name`` (at most ``max_bytes``), opened without blocking
    (``O_NONBLOCK``: a FIFO would otherwise wait for a writer) and, inside a folder
    (``dir_fd``), without following a symbolic link; ModelFileError otherwise."""
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC
    if dir_fd is not None:
        flags |= os.O_NOFOLLOW
    try:
        fd = os.open(name, flags, dir_fd=dir_fd)
    except OSError as exc:
        raise ModelFileError("io_error", f"cannot open {shown}: {exc.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ModelFileError(
                "not_regular", f"{shown} is a {_file_kind(st.st_mode)}, not a regular file"
            )
        if st.st_size > max_bytes:
            raise ModelFileError(
                "too_large", f"{shown} has {st.st_size} bytes, more than the {max_bytes} allowed"
            )
        chunks, total = [], 0
        while True:  # the size may change while we read: never take more than the bound
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise ModelFileError(
                    "too_large", f"{shown} has more than the {max_bytes} bytes allowed"
                )
    except OSError as exc:
        raise ModelFileError("io_error", f"cannot read {shown}: {exc.strerror}") from None
    finally:
        os.close(fd)
    return b"".join(chunks)


def _decode_model(data: bytes, shown: str | os.PathLike) -> TargetModel:
    try:
        return decode(TargetModel, data)
    except RejectedMessage as exc:
        raise ModelFileError("not_a_model", f"{shown}: not a target model: {exc}") from None


def save_model(path: str | os.PathLike, message: TargetModel) -> None:
    """Write the model to ``path`` (a trusted path: tools and tests; the service writes
    through :class:`ModelFiles`) atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(encode(message))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_model(path: str | os.PathLike, max_bytes: int = MAX_MODEL_BYTES) -> TargetModel:
    """Read a model file (a trusted path; the service reads through :class:`ModelFiles`):
    ``ModelFileError`` (a ValueError) naming the file when it is missing, not a regular
    file, larger than ``max_bytes`` or not a model. Never waits on a FIFO."""
    return _decode_model(_read_regular(path, None, max_bytes, path), path)
