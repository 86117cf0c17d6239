"""A verifier that learns who it follows: stripe colour, colour names, texture, an online
logistic model, and a calibrated probability that a candidate is the target.

Features (one vector per rectangle, :func:`describe_patch`). The rectangle is resized to
``PATCH_W`` x ``PATCH_H`` pixels (area averaging), so a person far away and one near give
vectors of the same length and about the same content, and converted to CIE Lab (float).

* *stripes*: the patch is cut into ``STRIPES`` horizontal stripes (head to feet); per stripe the
  mean a* and b* (chromaticity: a colour's hue and saturation, unchanged by how bright it is
  lit), the mean L* less the patch's mean L* (which stripes are lighter than the rest: clothes'
  contrast, not the scene's lighting) and the spread of L* (patterned or plain);
* *brightness*: the patch's mean L*, once (light or dark clothes; weighted low, it is what
  lighting changes most);
* *colour names*: each pixel's soft membership of eleven basic colour names (black, white,
  grey, red, orange, yellow, green, blue, purple, pink, brown: nearest prototypes in Lab), as
  shares over three parts (head and shoulders, torso, legs);
* *texture*: histograms of uniform local binary patterns (8 neighbours, 10 codes) of the upper
  and lower halves.

Each group is scaled so a typical difference between two people is about 1 per dimension.

Decision. Against the target's look ``mu`` (the mean of the target's stored views), a
candidate's vector ``x`` gives ``z = |x - mu|`` per dimension, and

    P(target | x) = sigmoid(b - w . z),   w >= 0

a weighted L1 distance turned into a probability. Once bystanders are known the logit also
gets the *nearest-view contrast* ``contrast_scale * (d_B - d_T) + contrast_bias``: ``d_T`` and
``d_B`` are the mean weighted L1 distances (same ``w``) to the ``neighbours`` nearest stored
views of the target and of the bystanders. It says "more like the target than like anyone
seen beside it", which the mean alone misses when a bystander is dressed like the target but
was seen before (docs/vision_verify.md has the measurements). Before any bystander is seen ``w`` and
``b`` are the prior (:data:`PRIOR_GROUP_WEIGHTS` times ``prior_scale``, ``prior_bias``): a
generic metric, calibrated once on development footage (docs/vision_verify.md). While
following, :meth:`OnlineVerifier.update` stores the target's views and the bystanders' (the
other candidates of the same frames) in two reservoirs (uniform samples of everything seen,
so early views and distances are not forgotten), and refits ``w, b`` by a class-balanced
logistic regression pulled towards the prior (``l2``): the dimensions that tell this target
from these people gain weight, those in which they all look alike lose it. Weights stay
non-negative, so looking less like the target never makes a candidate more likely to be it.
The balanced fit keeps ``p = 0.5`` the point where a candidate is as much like the target as
like the bystanders, on any footage.

The service's distance is ``1 - p`` (``default_threshold`` 0.5 rejects p < 0.5); the
verification carries ``p`` itself too (``VerifiedCandidate.probability``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import Annotated

import cv2
import msgspec
import numpy as np

from ..core import ImageFeatures, Model, Rect, View, clip_rect

__all__ = [
    "FEATURE_DIM",
    "OnlineSettings",
    "OnlineVerifier",
    "describe_patch",
]

PATCH_W, PATCH_H = 16, 48
STRIPES = 12
_CENTRE = (3, 13)  # patch columns of the stripes and colour names (a box's sides are background)
PARTS = ((0, 10), (10, 26), (26, 48))  # rows of the patch: head and shoulders, torso, legs

# sRGB prototypes of the eleven basic colour names (Berlin and Kay), as Lab below
_NAMES_RGB = np.array(
    [
        (0, 0, 0),  # black
        (255, 255, 255),  # white
        (128, 128, 128),  # grey
        (200, 30, 30),  # red
        (240, 140, 30),  # orange
        (230, 220, 50),  # yellow
        (50, 150, 50),  # green
        (40, 60, 190),  # blue
        (120, 50, 150),  # purple
        (240, 150, 180),  # pink
        (120, 75, 40),  # brown
    ],
    dtype=np.float32,
)
N_NAMES = len(_NAMES_RGB)
_NAME_SIGMA = 18.0  # Lab units: how soft a pixel's membership of the names is
_LBP_BINS = 10

# feature layout: (group, length, scale dividing the raw values)
_GROUPS = (
    ("stripe_ab", 2 * STRIPES, 12.0),
    ("stripe_l", STRIPES, 10.0),
    ("stripe_spread", STRIPES, 6.0),
    ("brightness", 1, 15.0),
    ("names", N_NAMES * len(PARTS), 0.15),
    ("texture", 2 * _LBP_BINS, 0.08),
)
FEATURE_DIM = sum(n for _, n, _ in _GROUPS)

#: Prior weight per dimension of each group (before any bystander is seen).
PRIOR_GROUP_WEIGHTS = {
    "stripe_ab": 1.0,
    "stripe_l": 0.6,
    "stripe_spread": 0.3,
    "brightness": 0.5,
    "names": 0.5,
    "texture": 0.2,
}


def _layout() -> tuple[np.ndarray, np.ndarray]:
    inv_scale, prior = [], []
    for name, n, scale in _GROUPS:
        inv_scale += [1.0 / scale] * n
        prior += [PRIOR_GROUP_WEIGHTS[name]] * n
    prior_w = np.array(prior, dtype=np.float64)
    return np.array(inv_scale, dtype=np.float32), prior_w / prior_w.sum()


_INV_SCALE, _PRIOR_SHAPE = _layout()


def _names_lab() -> np.ndarray:
    rgb = (_NAMES_RGB / 255.0).reshape(1, -1, 3)
    return cv2.cvtColor(rgb[..., ::-1].copy(), cv2.COLOR_BGR2Lab).reshape(-1, 3)


_NAMES_LAB = _names_lab()
# uniform LBP: codes with at most two 0/1 transitions around the circle map to their number
# of ones (0..8), every other code to 9
_LBP_LUT = np.array(
    [
        bin(c).count("1")
        if bin(c ^ (((c << 1) | (c >> 7)) & 0xFF)).count("1") <= 2
        else _LBP_BINS - 1
        for c in range(256)
    ],
    dtype=np.uint8,
)
_LBP_OFFSETS = ((-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1))


def describe_patch(bgr: np.ndarray, rows: tuple[int, int] | None = None) -> np.ndarray:
    """The scaled feature vector (``FEATURE_DIM`` float32) of a BGR patch of a person.

    ``rows``: the patch shows only rows ``rows[0]:rows[1]`` of the person's ``PATCH_H``-row
    body (the image's border cut the rest, e.g. the head of a person near a robot-height
    camera); each feature is then taken from the body rows it belongs to, and the features
    of rows not seen are NaN (None: the whole body)."""
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.shape[0] < 2 or bgr.shape[1] < 2:
        raise ValueError(f"expected an h x w x 3 patch of at least 2 x 2 pixels, got {bgr.shape}")
    r0, r1 = (0, PATCH_H) if rows is None else rows
    if not 0 <= r0 < r1 <= PATCH_H:
        raise ValueError(f"rows {rows} are not a span of 0..{PATCH_H}")
    small = cv2.resize(bgr, (PATCH_W, r1 - r0), interpolation=cv2.INTER_AREA)
    if r1 - r0 < PATCH_H:  # the rows not seen repeat the nearest seen row (masked below)
        small = cv2.copyMakeBorder(small, r0, PATCH_H - r1, 0, 0, cv2.BORDER_REPLICATE)
    lab = cv2.cvtColor(small.astype(np.float32) * np.float32(1 / 255), cv2.COLOR_BGR2Lab)
    seen = np.zeros(PATCH_H, dtype=bool)
    seen[r0:r1] = True
    x = np.concatenate([_stripes(lab, seen), _names(lab, seen), _texture(small, seen)]).astype(
        np.float32
    )
    return x * _INV_SCALE


def _share(seen: np.ndarray, a: int, b: int) -> float:
    return float(seen[a:b].mean())


def _stripes(lab: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Per stripe the centre columns' mean a*, b*, the mean L* less that of the seen body, the
    spread of L*; then the seen body's mean L*. A stripe less than half seen is NaN."""
    rows = PATCH_H // STRIPES
    c0, c1 = _CENTRE  # the body's columns, less the background's
    keep = seen.astype(np.float64)
    # per patch row: sums over the centre columns (a*, b*, L*) and over the whole width (L*, L*^2)
    centre = lab[:, c0:c1].sum(axis=1, dtype=np.float64) * keep[:, None]
    L = lab[..., 0].astype(np.float64)
    whole = np.stack([L.sum(axis=1), (L * L).sum(axis=1)], axis=1) * keep[:, None]
    n = keep.reshape(STRIPES, rows).sum(axis=1)
    part = centre.reshape(STRIPES, rows, 3).sum(axis=1)
    wide = whole.reshape(STRIPES, rows, 2).sum(axis=1)
    mean_L = float(centre[:, 0].sum() / (keep.sum() * (c1 - c0)))
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = n >= 0.5 * rows
        per = part / (n * (c1 - c0))[:, None]
        ab = np.where(ok[:, None], per[:, 1:], np.nan)
        light = np.where(ok, per[:, 0] - mean_L, np.nan)
        m1 = wide[:, 0] / (n * PATCH_W)
        var = np.maximum(wide[:, 1] / (n * PATCH_W) - m1 * m1, 0.0)
        spread = np.where(ok, np.sqrt(var), np.nan)
    return np.concatenate([ab.ravel(), light, spread, [mean_L]])


def _names(lab: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Soft colour names (Gaussian membership of each pixel in each prototype) as shares over
    head and shoulders, torso and legs; a part less than half seen is NaN."""
    d2 = ((lab.reshape(-1, 1, 3) - _NAMES_LAB.reshape(1, -1, 3)) ** 2).sum(axis=2)
    m = np.exp(-(d2 - d2.min(axis=1, keepdims=True)) / (2 * _NAME_SIGMA**2))
    m /= m.sum(axis=1, keepdims=True)
    m = m.reshape(PATCH_H, PATCH_W, N_NAMES)
    out = np.full((len(PARTS), N_NAMES), np.nan)
    for k, (a, b) in enumerate(PARTS):
        if _share(seen, a, b) >= 0.5:
            out[k] = m[a:b][seen[a:b]].mean(axis=(0, 1))
    return out.ravel()


def _texture(small: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Uniform LBP histograms of the upper and lower halves (inner pixels whose 3 x 3
    neighbourhood was seen); a half less than half seen is NaN."""
    grey = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY).astype(np.int16)
    centre = grey[1:-1, 1:-1]
    code = np.zeros(centre.shape, dtype=np.uint8)
    h, w = grey.shape
    for bit, (dy, dx) in enumerate(_LBP_OFFSETS):
        nb = grey[1 + dy : h - 1 + dy, 1 + dx : w - 1 + dx]
        code |= (nb >= centre).astype(np.uint8) << bit
    u = _LBP_LUT[code]
    ok = seen[:-2] & seen[1:-1] & seen[2:]  # inner row j is patch row j + 1
    half = u.shape[0] // 2
    out = np.full((2, _LBP_BINS), np.nan)
    for k, (a, b) in enumerate(((0, half), (half, u.shape[0]))):
        rows = ok[a:b]
        if rows.mean() >= 0.5:
            out[k] = np.bincount(u[a:b][rows].ravel(), minlength=_LBP_BINS) / u[a:b][rows].size
    return out.ravel()


class OnlineSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    default_threshold: Annotated[float, msgspec.Meta(gt=0, lt=1)] = 0.5
    """Rejection threshold on the distance 1 - p: 0.5 rejects a candidate less likely than
    not to be the target."""
    prior_scale: Annotated[float, msgspec.Meta(gt=0)] = 10.5
    """The prior metric's slope: logit = prior_bias - prior_scale * (weighted mean of z).
    10.5 and 4.6: the class-balanced logistic fit of target against bystanders, one view at a
    25-frame gap, pets09 frames 0-399 (docs/vision_verify.md)."""
    prior_bias: float = 4.6
    """The prior's logit at z = 0 (a candidate exactly like the target's look)."""
    target_views: Annotated[int, msgspec.Meta(ge=1, le=256)] = 32
    """Views of the target kept (a uniform sample of all seen)."""
    bystander_views: Annotated[int, msgspec.Meta(ge=1, le=512)] = 96
    """Views of bystanders kept (a uniform sample of all seen)."""
    l2: Annotated[float, msgspec.Meta(ge=0)] = 0.05
    """Pull of the fitted weights towards the prior (per view, on squared differences)."""
    iterations: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 40
    """Gradient steps of each refit."""
    bystander_gap_m: Annotated[float, msgspec.Meta(ge=0)] = 0.5
    """While following, a candidate nearer the target than this is not learnt as a bystander:
    it may be the target's own other leg (the laser did not pair them) or a part of it, and
    learning it as someone else teaches the model that the target is not the target."""
    worst_part_weight: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.5
    """A candidate is judged per body part (top, middle, bottom third); with all three seen,
    the worst-matching part counts this much against 1 for the others, so one part changed by
    a desk in front of the legs, a bag or an arm counts less, while a lookalike who differs
    in one part only still differs. 1: every part alike; 0: the worst left out (then a
    passer-by in the target's shirt passes; docs/vision_verify.md has the figures)."""
    person_width_m: Annotated[float, msgspec.Meta(gt=0)] | None = 0.6
    """The columns looked at: at most this wide at the candidate's depth, centred on its
    bearing (the model's rectangle comes from the acquisition's motion blob, which can hold
    people walking behind the target: crowd_ten's was 1 m wide). None: the whole rectangle."""
    neighbours: Annotated[int, msgspec.Meta(ge=1, le=32)] = 3
    """Stored views averaged for the nearest-view contrast (the k nearest target views and
    the k nearest bystander views)."""
    contrast_scale: Annotated[float, msgspec.Meta(ge=0)] = 2.0
    """Weight of the contrast (distance to the nearest bystander views less distance to the
    nearest target views, in the learnt metric) added to the logit once bystanders are known;
    0: the metric against the target's mean alone."""
    contrast_bias: float = -1.5
    """Added to the logit with the contrast: below 0 a candidate must look more like the
    target than like any bystander seen by a margin. -1.5 puts pets09's (frames 0-399,
    following at 25 frames) rate of someone accepted with the target absent below its rate
    of the target rejected (12 / 19 %): a wrong person is the worse error."""


_FEATURES = ("target_views", "state")  # and bystander_views once any is seen
# state: [target views seen, bystander views seen, bias, w_1 .. w_D]
_STATE_LEN = 3 + FEATURE_DIM
# a stored view's features not seen (NaN in memory) travel as 0 with a 0 in its "*_seen" mask
_SEEN = {"target_views": "target_seen", "bystander_views": "bystander_seen"}
MIN_BODY_ROWS = PATCH_H // 4
"""A view showing less than a quarter of the body's rows is not judged."""


def _body_rows(rect: Rect, body: tuple[float, float, float, float] | None):
    """The rows of the ``PATCH_H``-row body that the clipped ``rect`` shows: None (all), a
    (first, end) span, or False when under ``MIN_BODY_ROWS``."""
    if body is None:
        return None
    top, height = body[1], body[3] - body[1]
    if not height > 0:
        return None
    r0 = min(PATCH_H, max(0, round((rect[1] - top) / height * PATCH_H)))
    r1 = min(PATCH_H, max(0, round((rect[3] - top) / height * PATCH_H)))
    if r0 == 0 and r1 == PATCH_H:
        return None
    return (r0, r1) if r1 - r0 >= MIN_BODY_ROWS else False


def _unpack(features: dict[str, np.ndarray], key: str) -> np.ndarray | None:
    """A stored bank with NaN where its mask says not seen (None: no such bank)."""
    bank = features.get(key)
    if bank is None:
        return None
    seen = features.get(_SEEN[key])
    if seen is None:
        return bank
    return np.where(seen.astype(bool), bank, np.float32(np.nan))


def _pack(bank: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    seen = ~np.isnan(bank)
    return np.where(seen, bank, np.float32(0)), seen.astype(np.uint8)


def _parts_of_dims() -> np.ndarray:
    """The body part (0 top, 1 middle, 2 bottom) each feature dimension describes: the stripes
    by thirds of the body's height, the colour names by ``PARTS`` (head and shoulders, torso,
    legs), the texture's upper half with the middle; the whole body's brightness with the
    middle."""
    part = np.empty(FEATURE_DIM, dtype=np.int8)
    stripe = [i * len(PARTS) // STRIPES for i in range(STRIPES)]  # the stripes in thirds
    at = 0
    for name, n, _ in _GROUPS:
        if name == "stripe_ab":
            part[at : at + n] = np.repeat(stripe, 2)
        elif name in ("stripe_l", "stripe_spread"):
            part[at : at + n] = stripe
        elif name == "brightness":
            part[at : at + n] = 1
        elif name == "names":
            part[at : at + n] = np.repeat(np.arange(len(PARTS)), N_NAMES)
        else:  # texture: the upper half (head and torso) and the lower (legs)
            part[at : at + n] = np.repeat([1, 2], _LBP_BINS)
        at += n
    return part


_PART = _parts_of_dims()


def _part_l1(z: np.ndarray, w: np.ndarray, worst_weight: float) -> np.ndarray:
    """The weighted L1 distance judged per body part: in each part the weighted mean of ``z``
    over the dimensions seen (not NaN), then the mean over the parts seen, scaled to all
    dimensions' weight (last axis: the dimensions). With all three parts seen the
    worst-matching one counts ``worst_weight`` (the others 1): a desk in front of the legs, a
    bag, an arm across the chest change one part, not the person."""
    seen = ~np.isnan(z)
    zw = np.where(seen, z, 0.0) * w
    sw = seen * w
    means = []
    for k in range(len(PARTS)):
        m = k == _PART
        weight = sw[..., m].sum(axis=-1)
        mean = zw[..., m].sum(axis=-1) / np.maximum(weight, 1e-12)
        means.append(np.where(weight > 0, mean, np.nan))
    per = np.stack(means, axis=-1)
    shown = (~np.isnan(per)).sum(axis=-1)
    total = np.where(np.isnan(per), 0.0, per).sum(axis=-1)
    if worst_weight < 1.0:
        worst = np.where(np.isnan(per), -np.inf, per).max(axis=-1)
        full = shown == len(PARTS)
        cut = 1.0 - worst_weight
        total = np.where(full, total - cut * worst, total)
        shown = np.where(full, shown - cut, shown)
    return total / np.maximum(shown, 1) * float(w.sum())


class OnlineVerifier:
    """Stripe colour, colour names and texture, with a per-target online logistic model."""

    name = "online"
    settings_type = OnlineSettings
    calibrated = True
    """Its distance is 1 - P(target) (the service reports the probability too)."""

    def __init__(self, settings: OnlineSettings | None = None) -> None:
        self.settings = settings or OnlineSettings()
        self.default_threshold = self.settings.default_threshold
        self._prior_w = (self.settings.prior_scale * _PRIOR_SHAPE).astype(np.float32)

    # ------------------------------------------------------------------ features

    def features(self, frame: ImageFeatures, rect: Rect, body=None) -> np.ndarray | None:
        """The feature vector of ``rect`` in ``frame`` (cached per frame), NaN where the body
        (``body``: the person's whole rectangle, which the image border may cut) was not
        seen; None when the rectangle has under 2 x 2 pixels inside the image or shows under
        a quarter of the body."""
        r = clip_rect(rect, frame.width, frame.height)
        if r is None:
            return None
        rows = _body_rows(r, body)
        if rows is False:
            return None
        cache = frame.cache.setdefault("online_features", {})
        x = cache.get((r, rows))
        if x is None:
            x0, y0, x1, y1 = r
            x = cache[r, rows] = describe_patch(frame.bgr[y0:y1, x0:x1], rows)
        return x

    def _view_features(self, frame: ImageFeatures, v: View) -> np.ndarray | None:
        if not v.ok or v.rect is None:
            return None
        return self.features(frame, self._window(frame, v.rect, v), v.body)

    def _window(self, frame: ImageFeatures, rect: Rect, v: View) -> Rect:
        """``rect``'s columns within ``person_width_m`` of the view's bearing (the rectangle
        as it is without a camera in the frame's cache, a depth or a column)."""
        camera = frame.cache.get("camera")
        width = self.settings.person_width_m
        if camera is None or width is None or not (v.depth_m > 0 and math.isfinite(v.u_px)):
            return rect
        half = 0.5 * camera.f * width / v.depth_m
        x0, y0, x1, y1 = rect
        a, b = max(x0, round(v.u_px - half)), min(x1, round(v.u_px + half))
        return (a, y0, b, y1) if b - a >= 2 else rect

    # ------------------------------------------------------------------ the Verifier protocol

    def learn(self, frame: ImageFeatures, rect: Rect, view: View) -> dict[str, np.ndarray]:
        x = self.features(frame, self._window(frame, rect, view), view.body)
        if x is None:
            raise ValueError(f"rectangle {rect} has no pixels inside the image")
        state = np.zeros(_STATE_LEN, dtype=np.float32)
        state[0] = 1
        state[2] = self.settings.prior_bias
        state[3:] = self._prior_w
        # no bystander_views until one is seen (an empty array cannot travel)
        targets, seen = _pack(x.reshape(1, -1))
        return {"target_views": targets, "target_seen": seen, "state": state}

    def describe(self, frame: ImageFeatures, rect: Rect) -> None:
        return None  # no blending: the online model learns through update()

    def check_model(self, model: Model) -> None:
        """ValueError unless the features are what :meth:`learn` and :meth:`update` give."""
        f = model.features
        for k in _FEATURES:
            if k not in f:
                raise ValueError(f"no {k!r} feature")
            if f[k].dtype.kind != "f":
                raise ValueError(f"{k!r} is {f[k].dtype}, expected float")
        t, b, state = f["target_views"], f.get("bystander_views"), f["state"]
        for k, a, most in (
            ("target_views", t, self.settings.target_views),
            ("bystander_views", b, self.settings.bystander_views),
        ):
            if a is None:
                continue
            if (
                a.dtype.kind != "f"
                or a.ndim != 2
                or a.shape[1] != FEATURE_DIM
                or not 1 <= a.shape[0] <= 512
            ):
                raise ValueError(
                    f"{k!r} has shape {a.shape}, expected up to {most} rows of {FEATURE_DIM}"
                )
            seen = f.get(_SEEN[k])
            if seen is not None and (seen.shape != a.shape or seen.dtype != np.uint8):
                raise ValueError(f"{_SEEN[k]!r} is not a uint8 mask of {k!r}'s shape")
        if state.shape != (_STATE_LEN,):
            raise ValueError(f"'state' has shape {state.shape}, expected ({_STATE_LEN},)")
        if (state[3:] < 0).any():
            raise ValueError("'state' holds negative weights")

    def probabilities(self, xs: np.ndarray, features: dict[str, np.ndarray]) -> np.ndarray:
        """P(target) of each row of ``xs`` (NaN: not seen) under the model ``features``: the
        metric against the target's mean look, plus, once bystanders are known, the
        nearest-view contrast."""
        targets = _unpack(features, "target_views")
        state = features["state"]
        w = state[3:]
        mu = _mean_seen(targets)
        s = self.settings
        logit = float(state[2]) - _part_l1(np.abs(xs - mu), w, s.worst_part_weight)
        bystanders = _unpack(features, "bystander_views")
        if bystanders is not None and len(bystanders) and s.contrast_scale > 0:
            near_t = _nearest(xs, targets, w, s.neighbours, s.worst_part_weight)
            near_b = _nearest(xs, bystanders, w, s.neighbours, s.worst_part_weight)
            logit = logit + s.contrast_scale * (near_b - near_t) + s.contrast_bias
        return 1.0 / (1.0 + np.exp(-np.clip(logit, -30, 30)))

    def distances(
        self, frame: ImageFeatures, views: Sequence[View], model: Model
    ) -> list[float | None]:
        if "target_views" not in model.features or "state" not in model.features:
            raise ValueError("the model has no target_views/state features (not an online model)")
        xs, where = [], []
        for i, v in enumerate(views):
            x = self._view_features(frame, v)
            if x is not None:
                xs.append(x)
                where.append(i)
        out: list[float | None] = [None] * len(views)
        if xs:
            p = self.probabilities(np.stack(xs), model.features)
            for i, pi in zip(where, p.tolist(), strict=True):
                out[i] = 1.0 - pi
        return out

    # ------------------------------------------------------------------ learning

    def update(
        self, frame: ImageFeatures, views: Sequence[View], target: int, model: Model
    ) -> dict[str, np.ndarray] | None:
        """The model's features after seeing ``views[target]`` as the target and every other
        view in view as a bystander (a new dict; the model's arrays are not changed). None
        when the target's view has no pixels."""
        tv = views[target]
        x_t = None
        if tv.rect is not None:
            x_t = self.features(frame, self._window(frame, tv.rect, tv), tv.body)
        if x_t is None:
            return None
        f = model.features
        state = f["state"].copy()
        s = self.settings
        targets, n_t = _reservoir(
            _unpack(f, "target_views"), x_t[None], int(state[0]), s.target_views
        )
        others = [
            x
            for i, v in enumerate(views)
            if i != target and self._someone_else(tv, v)
            for x in [self._view_features(frame, v)]
            if x is not None
        ]
        bystanders = _unpack(f, "bystander_views")
        if bystanders is None:
            bystanders = np.zeros((0, FEATURE_DIM), np.float32)
        n_b = int(state[1])
        if others:
            bystanders, n_b = _reservoir(bystanders, np.stack(others), n_b, s.bystander_views)
        state[0], state[1] = n_t, n_b
        packed, seen = _pack(targets)
        learnt = {"target_views": packed, "target_seen": seen, "state": state}
        if len(bystanders):
            state[2], state[3:] = self._fit(targets, bystanders, state[2], state[3:])
            learnt["bystander_views"], learnt["bystander_seen"] = _pack(bystanders)
        return learnt

    def _someone_else(self, target: View, v: View) -> bool:
        """Whether ``v`` may be learnt as a bystander: at least ``bystander_gap_m`` from the
        target (a leg of the target's own that the laser did not pair, or the target's
        other half, is not someone else)."""
        gap = self.settings.bystander_gap_m
        return not math.hypot(v.x_m - target.x_m, v.y_m - target.y_m) < gap

    def _fit(
        self, targets: np.ndarray, bystanders: np.ndarray, bias: float, w: np.ndarray
    ) -> tuple[float, np.ndarray]:
        """Class-balanced logistic regression on z = |x - mu|, warm-started at (bias, w),
        pulled towards the prior, weights kept non-negative (projected gradient descent).
        A difference not seen (NaN) is filled with its class's mean difference: it pulls the
        weights neither way."""
        s = self.settings
        z_pos, z_neg = _differences(targets, bystanders)
        z = np.concatenate([z_pos, z_neg]).astype(np.float64)
        y = np.concatenate([np.ones(len(z_pos)), np.zeros(len(z_neg))])
        weight = np.concatenate(
            [np.full(len(z_pos), 0.5 / len(z_pos)), np.full(len(z_neg), 0.5 / len(z_neg))]
        )
        w0 = self._prior_w.astype(np.float64)
        b0 = s.prior_bias
        w, b = w.astype(np.float64), float(bias)
        # step size from a bound on the loss's curvature (z's largest row norm squared / 4)
        lip = 0.25 * float((z * z).sum(axis=1).max() + 1.0) + 2 * s.l2
        step = 1.0 / lip
        for _ in range(s.iterations):
            p = 1.0 / (1.0 + np.exp(-np.clip(b - z @ w, -30, 30)))
            g = weight * (p - y)  # d loss / d logit
            grad_w = -(z.T @ g) + 2 * s.l2 * (w - w0)
            grad_b = float(g.sum()) + 2 * s.l2 * (b - b0)
            w = np.maximum(0.0, w - step * grad_w)
            b -= step * grad_b
        return b, w.astype(np.float32)


def _mean_seen(bank: np.ndarray) -> np.ndarray:
    """Per dimension the mean of the rows that saw it (NaN where none did)."""
    if not np.isnan(bank).any():
        return bank.mean(axis=0)
    seen = ~np.isnan(bank)
    count = seen.sum(axis=0)
    mean = np.where(seen, bank, 0.0).sum(axis=0) / np.maximum(count, 1)
    return np.where(count > 0, mean, np.nan).astype(np.float32)


def _differences(targets: np.ndarray, bystanders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|each target view - the mean of the others| and |each bystander - the target's mean|,
    with the differences not seen filled by their class's mean (0 where none was seen). The
    target's mean is :func:`_mean_seen`'s, the one judging uses: a dimension no target view
    saw is not compared (a bystander's |b - 0| there would pull a weight the judgement never
    uses on the target's mean)."""
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns give NaN, filled below
        n = len(targets)
        seen = ~np.isnan(targets)
        total = np.where(seen, targets, 0.0).sum(axis=0)
        count = seen.sum(axis=0)
        mu = np.where(count > 0, total / np.maximum(count, 1), np.nan)  # as _mean_seen
        if n > 1:  # each target view against the mean of the others (not of itself)
            others = (total - np.where(seen, targets, 0.0)) / np.maximum(count - seen, 1)
            others[(count - seen) == 0] = np.nan
        else:
            others = targets
        z_pos = np.abs(targets - others)
        z_neg = np.abs(bystanders - mu)
        for z in (z_pos, z_neg):
            fill = np.nan_to_num(np.nanmean(z, axis=0))
            bad = np.isnan(z)
            z[bad] = np.broadcast_to(fill, z.shape)[bad]
    return z_pos, z_neg


def _nearest(
    xs: np.ndarray, bank: np.ndarray, w: np.ndarray, k: int, worst_weight: float
) -> np.ndarray:
    """Per row of ``xs``, the mean weighted L1 distance (over what both saw) to its ``k``
    nearest rows of ``bank``."""
    d = _part_l1(np.abs(xs[:, None, :] - bank[None, :, :]), w, worst_weight)
    k = min(k, d.shape[1])
    return np.partition(d, k - 1, axis=1)[:, :k].mean(axis=1)


def _reservoir(bank: np.ndarray, new: np.ndarray, seen: int, size: int) -> tuple[np.ndarray, int]:
    """``bank`` (a uniform sample of the ``seen`` rows so far) with the rows of ``new`` added
    by reservoir sampling, at most ``size`` rows; a new array and the new count. The draws are
    seeded by the count, so the same inputs give the same bank."""
    rows = list(bank)
    for x in new:
        seen += 1
        if len(rows) < size:
            rows.append(x)
        else:
            j = int(np.random.default_rng(seen).integers(seen))
            if j < size:
                rows[j] = x
    return np.array(rows, dtype=np.float32).reshape(-1, FEATURE_DIM), seen
