"""Which laser candidate is the target, by appearance: histograms, geometry, choice (no Zenoh).

DESIGN.md "Target model" and "Verification" (thesis 3.3.1, 3.5, 4.2.1, 4.4):

Colour (thesis 3.3.1.1, 4.2.1.2). HSV on OpenCV's scale (H in [0, 180), S, V in [0, 255]).
A pixel with V < 51 or S < 51 has no perceivable hue and goes to one of NV = 8 brightness bins
(by V); every other pixel to one of NH x NS = 10 x 10 hue-saturation bins. The rectangle is cut
into an upper and a lower half; each half gets its own 108-bin histogram

    half = [HS bins (10 x 10, row-major by hue), V bins (8)],   normalised to sum 1,

and the colour histogram is ``0.5 * [upper, lower]`` (216 bins summing to 1).

Edges (thesis 3.3.1.2, 4.2.1.3). Sobel Gx, Gy on the intensity image,
M = sqrt(Gx^2 + Gy^2), phi = atan2(Gy, Gx) in [0, 360) deg; pixels with M > 0.4 max(M) vote
into 72 bins of 5 deg; normalised to sum 1 (all zero when the patch has no edge at all).

Distance (thesis eq. 3-22, 3-23). Bhattacharyya d(p, q) = sqrt(1 - sum_i sqrt(p_i q_i)) via
``cv2.compareHist(..., HISTCMP_BHATTACHARYYA)`` on float32 histograms (identical for
normalised ones); d_image = d_colour + d_edge in [0, 2]. An empty histogram is at distance 1.

Rectangles (thesis 3.5.1, eq. 3-18..3-21). A candidate at (x, y) in the laser frame is moved
into the camera frame: subtract the camera's offset on the robot, rotate by minus the pan angle
the image carries,

    x_c = cos(pan) dx + sin(pan) dy,    y_c = -sin(pan) dx + cos(pan) dy,

then the rectangle has centre u = c_x - f y_c / x_c, v = c_y (the model rectangle is centred on
the image's horizontal centre line, so every rectangle is), and size w = w_model d_model / x_c,
h = h_model d_model / x_c, d_model being the model's depth x_c when it was learnt. A candidate
with x_c below ``min_depth_m`` (behind the camera, or at it) or whose centre column falls
outside the image is not judged (thesis 4.4.3: the centre decides whether it is in view).

Choice (thesis 3.5.3): the smallest distance wins. Unlike the thesis, a rejection threshold
may refuse every candidate (``chosen = -1``), so a bystander is not taken for an occluded
target. A slow update of a model (the thesis's first item of future work),
:func:`adapt_features`, blends a later view's histograms into it; the service does not use it
(the model drifts towards what surrounds the target, docs/vision_verify.md), the footage
measurement's *following* protocol does.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable, Sequence
from typing import Annotated, Literal, Protocol, runtime_checkable

import cv2
import msgspec
import numpy as np

from followbot.schemas import Array, Horizon, TargetModel

__all__ = [
    "COLOUR_BINS",
    "EDGE_BINS",
    "MAX_MODEL_ID",
    "Camera",
    "ImageFeatures",
    "InvalidModel",
    "Judgement",
    "Model",
    "Rect",
    "Verifier",
    "View",
    "adapt_features",
    "bhattacharyya",
    "blend",
    "check_histogram",
    "checked_model",
    "choose",
    "colour_histogram",
    "confident",
    "covered_fraction",
    "edge_histogram",
    "horizon_covers",
    "judge",
    "occlude",
    "project",
]

# thesis 4.2.1.2: NH = NS = 10 colour bins, NV = 8 brightness bins, thresholds 51 of 255
N_HUE, N_SAT, N_VAL = 10, 10, 8
SV_MIN = 51
HALF_BINS = N_HUE * N_SAT + N_VAL  # 108
COLOUR_BINS = 2 * HALF_BINS  # 216
# thesis 4.2.1.3: 72 bins of 5 deg, strong edges only (> 0.4 of the largest magnitude)
EDGE_BINS = 72
EDGE_FRACTION = 0.4

#: Axis-aligned pixel rectangle ``(x0, y0, x1, y1)``, half-open: columns x0..x1-1.
Rect = tuple[int, int, int, int]

ViewStatus = Literal["ok", "invalid", "behind", "out_of_view", "too_small", "too_large", "occluded"]


# --------------------------------------------------------------------------- camera


class Camera(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Intrinsics and extrinsics of one camera (one ``intrinsics_id`` of the Image message).

    The camera sits at (``offset_x_m``, ``offset_y_m``) in the base frame (its pan axis; the
    service turns each scan's candidates from the laser frame into the base frame with the
    robot's ``laser_mount``), ``height_m`` above the floor, looking horizontally along the
    base's +x turned by ``yaw_deg`` and by the pan angle the image carries.
    """

    width: Annotated[int, msgspec.Meta(ge=16, le=4096)] = 320
    height: Annotated[int, msgspec.Meta(ge=16, le=4096)] = 240
    hfov_deg: Annotated[float, msgspec.Meta(gt=1.0, lt=170.0)] = 47.5
    """Horizontal field of view; gives the focal length unless ``focal_px`` is set
    (thesis 3.5.1.1: 47.5 deg at 320 px, f = 160 / tan(23.75 deg) ~ 363 px)."""
    focal_px: Annotated[float, msgspec.Meta(gt=0.0, le=1e5)] | None = None
    cx_px: float | None = None
    """Principal point column (default width / 2)."""
    cy_px: float | None = None
    """Principal point row (default height / 2)."""
    offset_x_m: float = 0.0
    """Metres ahead of the base's origin."""
    offset_y_m: float = 0.0
    """Metres left of the base's origin."""
    yaw_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    """The camera's heading when the image's ``pan_rad`` is 0, counter-clockwise from the
    base's +x: a fixed camera turned on its mount (0 for a camera whose driver reports its pan
    from the base's +x, as the Image message asks)."""
    height_m: Annotated[float, msgspec.Meta(ge=0.0, le=10.0)] = 1.0
    min_depth_m: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 0.3
    """Candidates nearer than this along the optical axis (or behind the camera) are skipped."""

    @property
    def f(self) -> float:
        if self.focal_px is not None:
            return self.focal_px
        return (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def cx(self) -> float:
        return self.width / 2.0 if self.cx_px is None else self.cx_px

    @property
    def cy(self) -> float:
        return self.height / 2.0 if self.cy_px is None else self.cy_px

    def to_camera(self, x_m: np.ndarray, y_m: np.ndarray, pan_rad: float):
        """Base-frame points to the camera frame (x_c forward along the optical axis, y_c left)."""
        dx = np.asarray(x_m, dtype=np.float64) - self.offset_x_m
        dy = np.asarray(y_m, dtype=np.float64) - self.offset_y_m
        heading = pan_rad + math.radians(self.yaw_deg)
        c, s = math.cos(heading), math.sin(heading)
        return c * dx + s * dy, -s * dx + c * dy

    def column(self, x_c, y_c):
        """Image column of a camera-frame point (thesis eq. 3-18): u = c_x - f y_c / x_c."""
        return self.cx - self.f * y_c / x_c

    def bearing(self, u_px):
        """Camera-frame bearing of an image column (seed 002 eq. 1): atan((c_x - u) / f)."""
        return np.arctan((self.cx - np.asarray(u_px, dtype=np.float64)) / self.f)

    def elevation(self, v_px):
        """Elevation below the optical axis of an image row (seed 002 eq. 1): atan((v - c_y)/f)."""
        return np.arctan((np.asarray(v_px, dtype=np.float64) - self.cy) / self.f)


class View(msgspec.Struct, kw_only=True):
    """One candidate as the camera sees it."""

    index: int
    x_m: float
    y_m: float
    depth_m: float = math.nan
    """Camera-frame x_c (along the optical axis)."""
    lateral_m: float = math.nan
    """Camera-frame y_c (left of the optical axis)."""
    u_px: float = math.nan
    rect: Rect | None = None
    """The pixels judged: the projected rectangle, less what nearer candidates hide."""
    projected: Rect | None = None
    """The whole projected rectangle (set by :func:`occlude` when it cut ``rect``)."""
    body: tuple[float, float, float, float] | None = None
    """The person's whole rectangle at this depth, before the image's borders clip it
    (``x0, y0, x1, y1`` in pixels, may reach outside the image)."""
    status: ViewStatus = "ok"

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def project(
    camera: Camera,
    xy_m: np.ndarray,
    pan_rad: float,
    rect_w_px: float,
    rect_h_px: float,
    model_depth_m: float,
    *,
    min_side_px: int = 8,
    max_width_factor: float = 3.0,
) -> list[View]:
    """Rectangles of candidates ``xy_m`` (N x 2, base frame) in an image taken at ``pan_rad``.

    ``rect_w_px`` x ``rect_h_px`` is the model's rectangle, learnt at depth ``model_depth_m``.
    A rectangle wider than ``max_width_factor`` image widths (a candidate almost at the lens) is
    ``too_large``; one whose clipped sides are shorter than ``min_side_px`` is ``too_small``.
    """
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    views: list[View] = []
    if xy.shape[0] == 0:
        return views
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        xc, yc = camera.to_camera(xy[:, 0], xy[:, 1], pan_rad)
        u = camera.column(xc, yc)
        scale = model_depth_m / xc
        w, h = rect_w_px * scale, rect_h_px * scale  # inf for a candidate at the lens
    cy, width, height = camera.cy, camera.width, camera.height
    min_depth, max_w = camera.min_depth_m, max_width_factor * width
    finite = np.isfinite(xy).all(axis=1).tolist()
    cols = (xy.tolist(), finite, xc.tolist(), yc.tolist(), u.tolist(), w.tolist(), h.tolist())
    rows = zip(*cols, strict=True)
    for i, ((x, y), fin, xci, yci, ui, wi, hi) in enumerate(rows):  # Python floats: fast
        v = View(index=i, x_m=x, y_m=y)
        views.append(v)
        if not fin:
            v.status = "invalid"
            continue
        v.depth_m, v.lateral_m = xci, yci
        if not xci >= min_depth:
            v.status = "behind"
            continue
        v.u_px = ui
        if not 0.0 <= ui < width:
            v.status = "out_of_view"
            continue
        if not wi <= max_w:
            v.status = "too_large"
            continue
        x0 = max(0, round(ui - wi / 2))
        x1 = min(width, round(ui + wi / 2))
        y0 = max(0, round(cy - hi / 2))
        y1 = min(height, round(cy + hi / 2))
        if x1 - x0 < min_side_px or y1 - y0 < min_side_px:
            v.status = "too_small"
            continue
        v.rect = (x0, y0, x1, y1)
        v.body = (ui - wi / 2, cy - hi / 2, ui + wi / 2, cy + hi / 2)
    return views


def horizon_covers(
    camera: Camera,
    horizon: Horizon,
    pan_rad: float,
    half_width_m: float,
    max_leg_m: float = 0.25,
    jump_m: float = 0.1,
) -> np.ndarray:
    """(k, 3) ``depth, u0, u1``: the image columns that the person above each leg-like laser
    return of ``horizon`` (the scan's nearest return per bearing bin, laser frame) would hide,
    with its camera depth; only returns in front of the camera whose columns reach into the
    image. The laser sees at leg height what stands between the camera and a candidate: a
    passer-by that the detector did not report (thesis criterion 3 keeps only legs near the
    target) still hides the target.

    Leg-like: a run of neighbouring bins whose ranges step less than ``jump_m``, whose end
    points lie at most ``max_leg_m`` apart, and which stands in front of both its neighbours
    (each farther by ``jump_m`` or more, or no return): a piece of a wall between two nearer
    legs is narrow too, but lies behind them. Each of its returns is widened
    ``half_width_m`` to each side (the body above the leg). Wider runs -- walls, a pillar's
    face, furniture -- say nothing of what stands above them and hide nothing here (widened,
    they hid a target coming out beside a pillar: 76 closed-loop runs, docs/tracker_log.md)."""
    r = horizon.ranges.numpy().astype(np.float64)
    n = r.shape[0]
    centre = horizon.angle_min_rad + (np.arange(n) + 0.5) * horizon.increment_rad
    seen = np.isfinite(r)
    x, y = np.where(seen, r, 0.0) * np.cos(centre), np.where(seen, r, 0.0) * np.sin(centre)
    # runs of neighbouring returns: a break at a missing return or a range step
    with np.errstate(invalid="ignore"):
        step = ~(seen[1:] & seen[:-1] & (np.abs(np.diff(r)) < jump_m))
    starts = np.flatnonzero(np.concatenate(([True], step)))
    ends = np.concatenate((starts[1:], [n])) - 1
    width = np.hypot(x[ends] - x[starts], y[ends] - y[starts])
    padded = np.concatenate(([np.inf], np.where(seen, r, np.inf), [np.inf]))
    with np.errstate(invalid="ignore"):
        standing = (padded[starts] >= r[starts] + jump_m) & (padded[ends + 2] >= r[ends] + jump_m)
    leg_run = np.repeat((width <= max_leg_m) & standing, ends - starts + 1)
    keep = seen & leg_run
    r, x, y = r[keep], x[keep], y[keep]
    xc, yc = camera.to_camera(x, y, pan_rad)
    front = xc >= camera.min_depth_m
    xc, yc, r = xc[front], yc[front], r[front]
    half = half_width_m + 0.5 * r * horizon.increment_rad  # the bin's own width too
    u0 = camera.column(xc, yc + half)  # (y_c to the left: smaller columns)
    u1 = camera.column(xc, yc - half)
    inside = (u1 > 0) & (u0 < camera.width)
    return np.column_stack([xc, u0, u1])[inside]


def occlude(
    views: Sequence[View],
    min_visible_fraction: float,
    min_side_px: int = 8,
    covers: np.ndarray | None = None,
    margin_m: float = 0.3,
) -> None:
    """Cut from each rectangle the columns that nearer candidates' rectangles cover, in place.

    Beyond the thesis: it compares each candidate's whole rectangle, so a person behind a nearer
    one is judged by the nearer one's pixels, and clutter behind the target by the target's
    (in the simulator's two-person scene, every wrong choice of the histogram verifier). The
    laser gives the depth order, so the columns a nearer candidate's rectangle covers are not
    this candidate's. A candidate keeps the widest run of its columns that no nearer rectangle
    covers; when that run is under ``min_visible_fraction`` of its width, or under
    ``min_side_px``, it is ``occluded`` and not judged (no evidence either way). Rectangles are
    person-sized, so a nearer candidate that is not a person (a post) hides too much: the cost
    is a verification missed, never a wrong one.

    ``covers`` (:func:`horizon_covers`): more column spans with their depths, e.g. what the
    laser saw; each hides the candidates more than ``margin_m`` behind it.
    """
    ok = sorted((v for v in views if v.ok), key=lambda v: v.depth_m)
    nearer: list[tuple[float, float]] = []  # column spans of the nearer candidates' rectangles
    for v in ok:
        x0, y0, x1, y1 = v.rect
        full = x1 - x0
        free = [(x0, x1)]
        spans = list(nearer)
        if covers is not None and len(covers):
            front = in_front(covers, v.depth_m, margin_m)
            spans += [
                (math.floor(a), math.ceil(b)) for a, b in front[:, 1:].tolist() if b > x0 and a < x1
            ]
        for a, b in spans:
            free = [
                piece
                for f0, f1 in free
                for piece in ((f0, min(f1, a)), (max(f0, b), f1))
                if piece[1] > piece[0]
            ]
        nearer.append((x0, x1))
        f0, f1 = max(free, key=lambda f: f[1] - f[0], default=(x0, x0))
        if f1 - f0 < max(min_side_px, min_visible_fraction * full):
            v.status = "occluded"
        elif (f0, f1) != (x0, x1):
            v.projected, v.rect = v.rect, (f0, y0, f1, y1)


def clip_rect(rect: Rect, width: int, height: int) -> Rect | None:
    """``rect`` clipped to a ``width`` x ``height`` image; None when under 2 px is left."""
    x0, y0, x1, y1 = rect
    x0, y0 = max(0, int(x0)), max(0, int(y0))
    x1, y1 = min(width, int(x1)), min(height, int(y1))
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return (x0, y0, x1, y1)


# --------------------------------------------------------------------------- histograms


def _bins(n_bins: int, hi: float) -> np.ndarray:
    """OpenCV's own uniform bin over [0, hi) of every value 0..255 (int64, -1 out of range).

    Taken from ``cv2.calcBackProject`` of the 256 values, so they are exactly the bins
    ``cv2.calcHist`` counts the values in."""
    values = np.arange(256, dtype=np.uint8).reshape(1, 256)
    ids = np.arange(1, n_bins + 1, dtype=np.float32)  # 0 in the result: out of range
    return cv2.calcBackProject([values], [0], ids, [0, hi], 1).ravel().astype(np.int64) - 1


_LUTS: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


def _colour_luts() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tables for the per-pixel colour bin (see :meth:`ImageFeatures.colour_index`)."""
    global _LUTS
    if _LUTS is None:
        h, s, v = _bins(N_HUE, 180), _bins(N_SAT, 256), _bins(N_VAL, 256)
        hue = np.where(h >= 0, N_SAT * h, 255)  # 10 x hue bin (0..90)
        sat = np.where(s >= 0, s, 255)  # saturation bin ...
        sat[:SV_MIN] = 255  # ... or 255 when S < 51
        val = N_HUE * N_SAT + v  # 100 + brightness bin ...
        val[:SV_MIN] |= 0x80  # ... with the top bit set when V < 51
        _LUTS = (hue.astype(np.uint8), sat.astype(np.uint8), val.astype(np.uint8))
    return _LUTS


_SCRATCH = threading.local()


def _scratch(name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
    """A reusable C-contiguous work array of ``shape`` (its contents are garbage).

    Per-rectangle temporaries live here rather than in fresh arrays: a fresh array above
    glibc's mmap threshold (~128 kB, a 200 x 160 float32 image) page-faults on every call,
    which costs more than the arithmetic. One buffer per name and thread, grown on demand."""
    bufs = _SCRATCH.__dict__.setdefault("bufs", {})
    n = math.prod(shape)
    buf = bufs.get(name)
    if buf is None or buf.dtype != dtype or buf.size < n:
        buf = bufs[name] = np.empty(max(n, 1 << 16), dtype=dtype)
    return buf[:n].reshape(shape)


class ImageFeatures:
    """Per-image work shared by every rectangle of one frame, computed once and lazily.

    Colour: the frame is converted to HSV once, and every pixel's colour bin (0..107 of a half
    histogram) is looked up once into a uint8 *index image*; a rectangle's half histogram is
    then one ``calcHist`` of 108 bins over that image. Edges: a rectangle's Sobel gradients are
    taken on the rectangle grown by one pixel (cut back after), so at its border they see the
    frame's real neighbours and equal the whole-frame gradients; the strong edges' orientations
    are counted by one masked ``calcHist``. Temporaries live in reused work arrays, and no
    frame-sized float array is made (each would page-fault afresh on every frame).
    ``reference.py`` computes the same histograms the plain way; the tests check they agree.
    """

    def __init__(self, bgr: np.ndarray) -> None:
        if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
            raise ValueError(f"expected HxWx3 uint8 BGR pixels, got {bgr.dtype} {bgr.shape}")
        self.bgr = bgr
        self.height, self.width = bgr.shape[:2]
        self._hsv: np.ndarray | None = None
        self._index: np.ndarray | None = None
        self._grey: np.ndarray | None = None
        self._block: tuple[Rect, np.ndarray, np.ndarray] | None = None
        self.cache: dict[str, object] = {}
        """Per-frame results of a verifier (detections, back-projections), by its own keys."""

    def hsv(self) -> np.ndarray:
        if self._hsv is None:
            self._hsv = cv2.cvtColor(self.bgr, cv2.COLOR_BGR2HSV)
        return self._hsv

    def colour_index(self) -> np.ndarray:
        """Per pixel its bin of a half colour histogram (uint8, 0..107), once per frame.

        thesis 4.2.1.2: S >= 51 and V >= 51 -> HS bin ``10 hue_bin + sat_bin``; otherwise the
        brightness bin ``100 + v_bin``. With a = 10 hue_bin, b = sat_bin (255 when S < 51),
        c = 100 + v_bin (+128 when V < 51): index = min(a + b + (c & 128), c & 127), the sum
        saturating at 255 (an HS bin is < 100 <= every brightness bin)."""
        if self._index is None:
            lut_h, lut_s, lut_v = _colour_luts()
            shape = (self.height, self.width)
            hsv = self._hsv  # when a verifier has asked for it; otherwise a work array
            if hsv is None:
                hsv = _scratch("hsv", (*shape, 3), np.uint8)
                cv2.cvtColor(self.bgr, cv2.COLOR_BGR2HSV, dst=hsv)
            h, s, v = planes = _scratch("hsv_planes", (3, *shape), np.uint8)
            cv2.split(hsv, list(planes))
            a, b, c = _scratch("hsv_bins", (3, *shape), np.uint8)
            cv2.LUT(h, lut_h, dst=a)
            cv2.LUT(s, lut_s, dst=b)
            cv2.LUT(v, lut_v, dst=c)
            # (numpy for the constants: OpenCV takes a 1 x 1 image for a scalar)
            cv2.add(a, b, dst=a)  # saturating: 255 unless S >= 51
            np.bitwise_and(c, np.uint8(0x80), out=b)
            cv2.add(a, b, dst=a)  # 255 unless S >= 51 and V >= 51
            np.bitwise_and(c, np.uint8(0x7F), out=c)
            self._index = np.minimum(a, c)
        return self._index

    def grey(self) -> np.ndarray:
        if self._grey is None:
            self._grey = cv2.cvtColor(self.bgr, cv2.COLOR_BGR2GRAY)
        return self._grey

    def colour(self, rect: Rect) -> np.ndarray:
        """216-bin HS colour histogram of ``rect`` (float32, sums to 1)."""
        index = self.colour_index()
        x0, y0, x1, y1 = rect
        mid = (y0 + y1) // 2
        out = np.zeros(COLOUR_BINS, dtype=np.float32)
        if x1 <= x0:
            return out
        for k, (a, b) in enumerate(((y0, mid), (mid, y1))):
            if b <= a:
                continue
            seg = out[k * HALF_BINS : (k + 1) * HALF_BINS]
            part = index[a:b, x0:x1]
            cv2.calcHist([part], [0], None, [HALF_BINS], [0, HALF_BINS], hist=seg.reshape(-1, 1))
            total = float(seg.sum())
            if total > 0:
                seg *= 0.5 / total  # each half sums to 1, then both scaled by 0.5
        return out

    def _polar(self, box: Rect, m: np.ndarray, ang: np.ndarray) -> None:
        """Gradient magnitude and orientation (deg) of ``box`` into ``m`` and ``ang``."""
        x0, y0, x1, y1 = box
        # the box grown by a pixel where the frame has one: Sobel sees real neighbours there,
        # and reflects only at the frame's own border, like a whole-frame Sobel
        gx0, gy0 = max(0, x0 - 1), max(0, y0 - 1)
        grown = self.grey()[gy0 : min(self.height, y1 + 1), gx0 : min(self.width, x1 + 1)]
        cut = (slice(y0 - gy0, y1 - gy0), slice(x0 - gx0, x1 - gx0))
        sx, sy = _scratch("sobel", (2, *grown.shape), np.int16)
        cv2.spatialGradient(grown, sx, sy)  # thesis 3.3.1.2: S_x, S_y (3 x 3 Sobel)
        gx, gy = _scratch("gxy", (2, y1 - y0, x1 - x0), np.float32)
        np.copyto(gx, sx[cut])  # exact integers: the same as a float32 Sobel
        np.copyto(gy, sy[cut])
        # eq. 3-4 and 3-5: magnitude and orientation in [0, 360) deg
        cv2.cartToPolar(gx, gy, magnitude=m, angle=ang, angleInDegrees=True)

    def share_gradients(self, rects: Sequence[Rect]) -> None:
        """Compute the gradients of the bounding box of ``rects`` once, for :meth:`edges`, when
        the rectangles overlap so much (their areas add up to over 1.5 times the box's) that
        this is cheaper than each rectangle's own. The histograms are the same either way."""
        if len(rects) < 2:
            return
        bx0, by0 = min(r[0] for r in rects), min(r[1] for r in rects)
        bx1, by1 = max(r[2] for r in rects), max(r[3] for r in rects)
        area = sum((r[2] - r[0]) * (r[3] - r[1]) for r in rects)
        if area <= 1.5 * (bx1 - bx0) * (by1 - by0):
            return
        m, ang = np.empty((2, by1 - by0, bx1 - bx0), dtype=np.float32)  # kept with the frame
        self._polar((bx0, by0, bx1, by1), m, ang)
        self._block = ((bx0, by0, bx1, by1), m, ang)

    def edges(self, rect: Rect) -> np.ndarray:
        """72-bin edge-orientation histogram of ``rect`` (float32, sums to 1 or all zero)."""
        x0, y0, x1, y1 = rect
        if x1 <= x0 or y1 <= y0:
            return np.zeros(EDGE_BINS, dtype=np.float32)
        block = self._block
        if block is not None and _inside(rect, block[0]):
            bx0, by0 = block[0][:2]
            roi = (slice(y0 - by0, y1 - by0), slice(x0 - bx0, x1 - bx0))
            m, ang = block[1][roi], block[2][roi]
        else:
            m, ang = _scratch("polar", (2, y1 - y0, x1 - x0), np.float32)
            self._polar(rect, m, ang)
        peak = float(m.max())
        if peak <= 0.0:
            return np.zeros(EDGE_BINS, dtype=np.float32)
        strong = _scratch("strong", m.shape, np.bool_)
        np.greater(m, np.float32(EDGE_FRACTION * peak), out=strong)  # eq. 4-3: 0.4 Mag_max
        hist = cv2.calcHist([ang], [0], strong.view(np.uint8), [EDGE_BINS], [0, 360])[:, 0]
        total = float(hist.sum())
        return hist / total if total > 0 else hist

    def histograms(self, rect: Rect) -> dict[str, np.ndarray]:
        return {"colour_hs": self.colour(rect), "edge_orientation": self.edges(rect)}


def _inside(rect: Rect, box: Rect) -> bool:
    return box[0] <= rect[0] and box[1] <= rect[1] and rect[2] <= box[2] and rect[3] <= box[3]


def colour_histogram(bgr: np.ndarray) -> np.ndarray:
    """216-bin HS colour histogram of a whole BGR patch."""
    return ImageFeatures(bgr).colour((0, 0, bgr.shape[1], bgr.shape[0]))


def edge_histogram(bgr: np.ndarray) -> np.ndarray:
    """72-bin edge-orientation histogram of a whole BGR patch."""
    return ImageFeatures(bgr).edges((0, 0, bgr.shape[1], bgr.shape[0]))


def bhattacharyya(p: np.ndarray, q: np.ndarray) -> float:
    """sqrt(1 - sum sqrt(p q)) for normalised histograms (eq. 3-22); 1 if either is empty."""
    if p.shape != q.shape:
        raise ValueError(f"histograms differ in shape: {p.shape} vs {q.shape}")
    p = np.ascontiguousarray(p, dtype=np.float32)
    q = np.ascontiguousarray(q, dtype=np.float32)
    if not (p.sum() > 0 and q.sum() > 0):
        return 1.0
    d = cv2.compareHist(p, q, cv2.HISTCMP_BHATTACHARYYA)
    return min(1.0, max(0.0, float(d)))


# --------------------------------------------------------------------------- model


class Model(msgspec.Struct, kw_only=True):
    """The target model as the verifiers use it (the wire form is :class:`TargetModel`)."""

    model_id: int
    verifier: str
    x_m: float
    y_m: float
    """Laser position when learnt (x_model, y_model)."""
    depth_m: float
    """Camera-frame depth when learnt (the d_model of the rectangle's scale)."""
    rect_w_px: float
    rect_h_px: float
    image_width: int
    image_height: int
    features: dict[str, np.ndarray]
    pan_rad: float = 0.0
    stamp_ns: int = 0

    def to_message(self) -> TargetModel:
        feats = {k: Array.from_numpy(np.ascontiguousarray(v)) for k, v in self.features.items()}
        return TargetModel(
            stamp_ns=self.stamp_ns,
            frame_id="base_laser",
            model_id=self.model_id,
            verifier=self.verifier,
            x_m=self.x_m,
            y_m=self.y_m,
            rect_width_px=self.rect_w_px,
            rect_height_px=self.rect_h_px,
            image_width=self.image_width,
            image_height=self.image_height,
            features=feats,
            pan_rad=self.pan_rad,
        )

    @classmethod
    def from_message(cls, msg: TargetModel, camera: Camera) -> Model:
        feats = {
            k: np.array(a.numpy(), dtype=np.uint8 if a.dtype == "|u1" else np.float32)
            for k, a in msg.features.items()
        }
        pan_rad = msg.pan_rad
        depth, _ = camera.to_camera(np.array(msg.x_m), np.array(msg.y_m), pan_rad)
        depth = float(depth)
        if not depth >= camera.min_depth_m:
            raise ValueError(f"model position ({msg.x_m}, {msg.y_m}) is not in front of the camera")
        return cls(
            model_id=msg.model_id,
            verifier=msg.verifier,
            x_m=msg.x_m,
            y_m=msg.y_m,
            depth_m=depth,
            rect_w_px=msg.rect_width_px,
            rect_h_px=msg.rect_height_px,
            image_width=msg.image_width,
            image_height=msg.image_height,
            features=feats,
            pan_rad=pan_rad,
            stamp_ns=msg.stamp_ns,
        )


#: Largest ``model_id`` accepted. Ids count the models built or loaded, one more each time
#: (0 means "no model" in a Verification); a million is a new model a minute for two years.
MAX_MODEL_ID = 1_000_000

_F32_MAX = float(np.finfo(np.float32).max)


class InvalidModel(ValueError):
    """A target model that must not be used. ``kind`` names the check it failed (one of a few
    fixed words, for counting); the message says what is wrong with it."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def checked_model(
    message: TargetModel,
    verifier: Verifier,
    cameras: Iterable[Camera],
    *,
    max_bytes: int | None = None,
) -> Model:
    """The model in ``message`` as ``verifier`` will judge with it, or :class:`InvalidModel`.

    Every model passes here before it replaces the one in use, whether it came from the
    network, a query reply or a file. It must be for this verifier, have a ``model_id`` in
    1..:data:`MAX_MODEL_ID`, have been learnt on an image the size of one of ``cameras``, with
    a rectangle no larger than that image and its position in front of the camera; its
    features must be finite (and fit float32), at most ``max_bytes`` in all, and pass the
    verifier's own ``check_model`` (histogram sizes and sums, see each verifier).
    """
    mid = message.model_id
    if message.verifier != verifier.name:
        raise InvalidModel(
            "wrong_verifier",
            f"model {mid} is for verifier {message.verifier!r}, this service runs "
            f"{verifier.name!r}",
        )
    if not 1 <= mid <= MAX_MODEL_ID:
        raise InvalidModel("bad_model_id", f"model_id {mid} is outside 1..{MAX_MODEL_ID}")
    size = (message.image_width, message.image_height)
    cams = list(cameras)
    camera = next((c for c in cams if (c.width, c.height) == size), None)
    if camera is None:
        have = ", ".join(f"{c.width}x{c.height}" for c in cams)
        raise InvalidModel(
            "unknown_image_size",
            f"model {mid} was learnt on a {size[0]}x{size[1]} image; the cameras here are {have}",
        )
    if message.rect_width_px > size[0] or message.rect_height_px > size[1]:
        raise InvalidModel(
            "bad_rectangle",
            f"model {mid}: rectangle {message.rect_width_px:g}x{message.rect_height_px:g} px "
            f"is larger than its {size[0]}x{size[1]} image",
        )
    nbytes = sum(len(a.data) for a in message.features.values())
    if max_bytes is not None and nbytes > max_bytes:
        raise InvalidModel(
            "too_large", f"model {mid}: {nbytes} bytes of features, more than {max_bytes}"
        )
    for name, arr in message.features.items():
        if arr.dtype in ("<f4", "<f8"):
            raw = arr.numpy()
            if not (np.isfinite(raw).all() and (np.abs(raw) <= _F32_MAX).all()):
                raise InvalidModel(
                    "non_finite", f"model {mid}: feature {name!r} holds NaN or infinite values"
                )
    try:
        model = Model.from_message(message, camera)
    except ValueError as exc:
        raise InvalidModel("behind_camera", f"model {mid}: {exc}") from None
    check = getattr(verifier, "check_model", None)
    if check is not None:
        try:
            check(model)
        except ValueError as exc:
            raise InvalidModel("bad_features", f"model {mid}: {exc}") from None
    return model


def check_histogram(
    features: dict[str, np.ndarray],
    name: str,
    bins: int,
    sums: Sequence[float] = (1.0,),
    tolerance: float = 1e-3,
) -> np.ndarray:
    """``features[name]``, checked to be a float histogram of ``bins`` non-negative values
    whose sum is one of ``sums`` (within ``tolerance``); ValueError saying what is wrong."""
    h = features.get(name)
    if h is None:
        raise ValueError(f"no {name!r} feature")
    if h.dtype.kind != "f" or h.shape != (bins,):
        raise ValueError(f"{name!r} is {h.dtype} {h.shape}, expected {bins} float bins")
    if not np.isfinite(h).all() or (h < 0).any():
        raise ValueError(f"{name!r} has negative or non-finite bins")
    total = float(h.sum(dtype=np.float64))
    if not any(abs(total - s) <= tolerance for s in sums):
        want = " or ".join(f"{s:g}" for s in sums)
        raise ValueError(f"{name!r} sums to {total:.6g}, expected {want}")
    return h


@runtime_checkable
class Verifier(Protocol):
    """What every verifier plugin offers (entry-point group ``followbot.verifiers``).

    ``learn`` describes the target in the model rectangle; ``distances`` judges the candidates'
    views of one frame against the model (None for views not judged); ``describe`` gives the
    features of one rectangle, for :func:`adapt_features` (None: the verifier does not adapt).
    A verifier may also have ``check_model(model)``, raising ValueError when the model's
    features are not what its ``learn`` gives (:func:`checked_model` calls it).
    """

    name: str

    def learn(self, frame: ImageFeatures, rect: Rect, view: View) -> dict[str, np.ndarray]: ...

    def distances(
        self, frame: ImageFeatures, views: Sequence[View], model: Model
    ) -> list[float | None]: ...

    def describe(self, frame: ImageFeatures, rect: Rect) -> dict[str, np.ndarray] | None: ...


class Judgement(msgspec.Struct, kw_only=True):
    views: list[View]
    distances: list[float | None]
    chosen: int
    """Index into ``views`` of the target, or -1."""


def choose(distances: Sequence[float | None], threshold: float | None) -> int:
    """Index of the smallest distance (eq. 3-23); -1 if none, or if it exceeds ``threshold``."""
    best, best_d = -1, math.inf
    for i, d in enumerate(distances):
        if d is not None and d < best_d:
            best, best_d = i, d
    if best >= 0 and threshold is not None and best_d > threshold:
        return -1
    return best


def judge(
    verifier: Verifier,
    frame: ImageFeatures,
    camera: Camera,
    model: Model,
    xy_m: np.ndarray,
    pan_rad: float,
    threshold: float | None,
    *,
    min_visible_fraction: float | None = 0.5,
    horizon: Horizon | None = None,
    horizon_margin_m: float | None = None,
    horizon_half_width_m: float = 0.2,
    abstain_fraction: float | None = None,
    **project_kw,
) -> Judgement:
    """Project every candidate, cut what nearer candidates hide (:func:`occlude`; None: not)
    and, with ``horizon`` and ``horizon_margin_m``, what the laser saw in front of them
    (:func:`horizon_covers`), let the verifier judge those in view, choose the target.

    ``abstain_fraction`` (with ``horizon_margin_m``): the laser's covers are not cut; instead a
    candidate judged above ``threshold`` whose rectangle they cover at least this much is
    reported unjudged (``occluded``): a view with someone unreported in front of it is
    trusted when it matches, not when it rejects."""
    views = project(
        camera, xy_m, pan_rad, model.rect_w_px, model.rect_h_px, model.depth_m, **project_kw
    )
    covers = margin = None
    if horizon is not None and horizon_margin_m is not None:
        covers = horizon_covers(camera, horizon, pan_rad, horizon_half_width_m)
        margin = horizon_margin_m
    if min_visible_fraction is not None:
        min_side = project_kw.get("min_side_px", 8)
        if covers is not None and abstain_fraction is None:  # the laser's covers cut
            occlude(views, min_visible_fraction, min_side, covers, margin)
        else:
            occlude(views, min_visible_fraction, min_side)
    frame.cache["camera"] = camera
    distances = verifier.distances(frame, views, model)
    if len(distances) != len(views):
        raise ValueError(f"{verifier.name} gave {len(distances)} distances for {len(views)} views")
    distances = [
        d if (v.ok and d is not None and math.isfinite(d)) else None
        for v, d in zip(views, distances, strict=True)
    ]
    if abstain_fraction is not None and covers is not None and threshold is not None:
        for i, (v, d) in enumerate(zip(views, distances, strict=True)):
            if d is None or d <= threshold:
                continue
            if covered_fraction(v.rect, in_front(covers, v.depth_m, margin)) >= abstain_fraction:
                v.status, distances[i] = "occluded", None
    return Judgement(views=views, distances=distances, chosen=choose(distances, threshold))


def in_front(covers: np.ndarray, depth_m: float, margin_m: float) -> np.ndarray:
    """The rows of ``covers`` (:func:`horizon_covers`) more than ``margin_m`` nearer than
    ``depth_m``."""
    return covers[covers[:, 0] < depth_m - margin_m]


def covered_fraction(rect: Rect, covers: np.ndarray) -> float:
    """The share of ``rect``'s columns that the spans ``covers[:, 1:3]`` cover (their union)."""
    x0, _, x1, _ = rect
    if x1 <= x0 or not len(covers):
        return 0.0
    spans = sorted(
        (max(a, x0), min(b, x1)) for a, b in covers[:, 1:3].tolist() if b > x0 and a < x1
    )
    total, end = 0.0, float(x0)
    for a, b in spans:
        if b > end:
            total += b - max(a, end)
            end = b
    return total / (x1 - x0)


# --------------------------------------------------------------------------- online update


def confident(
    distances: Sequence[float | None], chosen: int, max_distance: float, min_margin: float
) -> bool:
    """Whether the chosen match is sure enough to learn from: close to the model, and clearly
    closer than every other candidate judged."""
    if chosen < 0 or distances[chosen] is None or distances[chosen] > max_distance:
        return False
    others = [d for i, d in enumerate(distances) if i != chosen and d is not None]
    return not others or min(others) - distances[chosen] >= min_margin


def blend(model: np.ndarray, seen: np.ndarray, rate: float) -> np.ndarray:
    """(1 - rate) model + rate seen, renormalised to the model's sum (a slow exponential update)."""
    out = (1.0 - rate) * model.astype(np.float32) + rate * seen.astype(np.float32)
    total, want = float(out.sum()), float(model.sum())
    if total > 0 and want > 0:
        out *= want / total
    return out.astype(np.float32)


def adapt_features(
    features: dict[str, np.ndarray], seen: dict[str, np.ndarray], rate: float
) -> dict[str, np.ndarray]:
    """Blend every feature present in both; keep the others."""
    out = dict(features)
    for k, v in seen.items():
        if k in out and out[k].shape == v.shape and v.sum() > 0:
            out[k] = blend(out[k], v, rate)
    return out
