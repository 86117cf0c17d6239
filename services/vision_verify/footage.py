"""A verifier measured on footage with person boxes: can it pick the target among everyone?

Inputs: a video OpenCV can read and a box file (:func:`read_boxes`) giving each person's box,
with one id per person, in the frames where they are. No laser: the boxes are the candidates.

A box is *usable* in a frame when its share of pixels that are inside the image and not hidden
by a nearer box (:func:`visible_fractions`) is at least ``min_visible``; it is judged on its
part inside the image (the histogram verifier compares a box cut by the border with the same
part of the model, as in the service). A *choice* (p, t, N) is a person p usable in frame t - N
(the model frame) and in frame t (the choice frame), with at least one other usable box in
frame t, both frames inside the range evaluated. Every such choice is judged twice:

* **one view**: the model is learnt from p's box in frame t - N alone;
* **following**: the model is learnt from p's first usable box in the range, then updated with
  p's box in every later frame up to and including t - N: what a robot has seen after
  tracking p with confidence until N frames ago. A verifier that learns online (``update``:
  online) learns p as the target and the other people's boxes as bystanders; any other blends
  p's features into the model (``describe`` + :func:`..core.adapt_features` at
  ``adapt_rate``) and learns nothing from the others. A verifier with neither (``describe``
  gives None: face) keeps its model from p's first view.

Then the verifier judges every usable box of frame t against the model, and

* **rank-1**: p's distance is below every other box's (a tie is a miss; an unjudged p too);
* **chance**: 1 / (usable boxes in frame t), what a blind pick gets;
* **target rejected**: p's distance is above the verifier's threshold, or p is unjudged;
* **someone accepted, target removed**: another box's distance is at or below the threshold
  (the choice the verifier would make if p's box were not offered). Each box's distance does
  not depend on which other boxes are judged with it (the conformance test checks this for
  every registered verifier), so the same distances serve.

Each share is over the choices of one protocol and lag. No camera calibration comes with
footage, so each box gets the geometry of a level pinhole camera (60 deg horizontal field of
view) and a person 1.7 m tall: depth f 1.7 / box height, lateral offset from the box's centre
column. Only the face verifier uses it (bearing and elevation of the face it expects).
"""

from __future__ import annotations

import csv
import math
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple

import msgspec
import numpy as np

from .core import Camera, ImageFeatures, Model, Rect, Verifier, View, adapt_features, confident

__all__ = [
    "Box",
    "BoxFile",
    "BoxFileError",
    "Candidate",
    "Choice",
    "FootageError",
    "Outcome",
    "Report",
    "Tally",
    "evaluate",
    "evaluate_frames",
    "footage_camera",
    "frame_candidates",
    "learn_model",
    "read_boxes",
    "score",
    "view_of",
    "visible_fractions",
]

PROTOCOLS = ("one view", "following")
#: The pets09 CSV's columns (docs/vision_verify.md "Real footage").
CSV_COLUMNS = ("frame", "id", "x_px", "y_px", "w_px", "h_px")
PERSON_HEIGHT_M = 1.7
"""A box's person height for the pseudo geometry (module docstring)."""
FOV_DEG = 60.0


class BoxFileError(ValueError):
    """The box file cannot be read or holds no usable box."""


class FootageError(ValueError):
    """The video cannot be read."""


# --------------------------------------------------------------------------- box files


class Box(NamedTuple):
    """One person's box in one frame, in pixels; it may reach past the image's border."""

    id: int
    x: float
    y: float
    w: float
    h: float


@dataclass
class BoxFile:
    path: str
    format: Literal["mot", "csv"]
    first_frame: int
    """The number the file gives the video's first frame (MOT: 1, the pets09 CSV: 0)."""
    frames: dict[int, list[Box]]
    """Boxes by 0-based video frame."""
    rows: int = 0
    rejected: dict[str, list[int]] = field(default_factory=dict)
    """Rows not used, by reason: [count, line number of the first]."""

    @property
    def boxes(self) -> int:
        return sum(len(b) for b in self.frames.values())

    def reject(self, reason: str, line: int) -> None:
        entry = self.rejected.setdefault(reason, [0, line])
        entry[0] += 1

    def summary(self) -> dict:
        return {
            "path": self.path,
            "format": self.format,
            "first_frame": self.first_frame,
            "rows": self.rows,
            "boxes": self.boxes,
            "rejected": {k: {"rows": n, "first_line": ln} for k, (n, ln) in self.rejected.items()},
        }


def _number(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(text)
    return value


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _whole(text: str) -> int:
    value = float(text)
    if not (math.isfinite(value) and value == int(value)):
        raise ArithmeticError(text)
    return int(value)


def read_boxes(
    path: str | Path,
    format: Literal["auto", "mot", "csv"] = "auto",
    first_frame: int | None = None,
) -> BoxFile:
    """Read a box file; bad rows are counted by reason (:attr:`BoxFile.rejected`), not fatal.

    Formats: ``csv``, a header naming ``frame,id,x_px,y_px,w_px,h_px`` (any order, more columns
    allowed; the pets09 file); ``mot``, MOTChallenge rows ``frame,id,x,y,w,h[,flag,...]`` with
    no header, whose rows with a 7th column of 0 (ground truth's "ignore this box") are skipped.
    ``auto``: ``csv`` when a field of the first line is not a number (a header). Frame numbers
    are mapped to video frames by subtracting ``first_frame`` (default: 1 for MOT, which
    counts from 1; 0 for csv).
    :class:`BoxFileError` when the file cannot be read or no row gives a box."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig", errors="replace")  # -sig: a leading BOM
    except OSError as exc:
        raise BoxFileError(f"cannot read box file {path}: {exc.strerror}") from None
    lines = text.splitlines()
    first = next((ln for ln in lines if ln.strip()), "")
    if format == "auto":
        format = "csv" if not all(_is_number(c) for c in first.split(",")) else "mot"
    if format not in ("mot", "csv"):
        raise ValueError(f"unknown box file format {format!r}: auto, mot or csv")
    if first_frame is None:
        first_frame = 1 if format == "mot" else 0
    out = BoxFile(path=str(path), format=format, first_frame=first_frame, frames={})
    rows = csv.reader(lines)
    start = 1
    if format == "csv":
        header = [h.strip() for h in next(rows, [])]
        missing = [c for c in CSV_COLUMNS if c not in header]
        if missing:
            raise BoxFileError(
                f"{path}: the header names no {', '.join(missing)} column "
                f"(expected {','.join(CSV_COLUMNS)}; a MOT file has no header: --format mot)"
            )
        cols = [header.index(c) for c in CSV_COLUMNS]
        start = 2
    else:
        cols = list(range(6))
    seen: set[tuple[int, int]] = set()
    for line_no, row in enumerate(rows, start=start):
        if not any(c.strip() for c in row):
            continue
        out.rows += 1
        if len(row) <= max(cols):
            out.reject("too few columns", line_no)
            continue
        try:
            frame, pid = _whole(row[cols[0]]), _whole(row[cols[1]])
            x, y, w, h = (_number(row[c]) for c in cols[2:])
            flag = _number(row[6]) if format == "mot" and len(row) > 6 else 1.0
        except ArithmeticError:
            out.reject("frame or id not a whole number", line_no)
            continue
        except ValueError:
            out.reject("not a finite number", line_no)
            continue
        if flag == 0:
            out.reject("marked to ignore (MOT flag 0)", line_no)
        elif pid < 0:
            out.reject("no identity (id < 0: a detections file?)", line_no)
        elif not (w > 0 and h > 0):
            out.reject("empty box (width or height <= 0)", line_no)
        elif frame - first_frame < 0:
            out.reject(f"frame before the first ({first_frame})", line_no)
        elif (frame, pid) in seen:
            out.reject("id twice in one frame", line_no)
        else:
            seen.add((frame, pid))
            out.frames.setdefault(frame - first_frame, []).append(Box(pid, x, y, w, h))
    if not out.frames:
        why = ", ".join(f"{k}: {n}" for k, (n, _) in out.rejected.items()) or "no rows"
        raise BoxFileError(f"{path}: no usable box ({out.rows} rows; {why})")
    return out


# --------------------------------------------------------------------------- boxes in a frame


def _pixels(b: Box) -> Rect:
    """The box rounded to whole pixels (unclipped): columns x0..x1-1, rows y0..y1-1."""
    return (
        math.floor(b.x + 0.5),
        math.floor(b.y + 0.5),
        math.floor(b.x + b.w + 0.5),
        math.floor(b.y + b.h + 0.5),
    )


def visible_fractions(
    boxes: Sequence[Box], width: int, height: int, occlusion: bool = True
) -> list[float]:
    """Each box's share of pixels inside the ``width`` x ``height`` image and, with
    ``occlusion``, not covered by a nearer box: one whose bottom edge is lower in the image
    (people standing on one floor, seen from above their feet, as in most surveillance and
    robot footage). A box under one pixel has 0."""
    rects = [_pixels(b) for b in boxes]
    out = []
    for i, (x0, y0, x1, y1) in enumerate(rects):
        area = (x1 - x0) * (y1 - y0)
        if area <= 0:
            out.append(0.0)
            continue
        shown = np.zeros((y1 - y0, x1 - x0), dtype=bool)
        shown[max(0, -y0) : max(0, height - y0), max(0, -x0) : max(0, width - x0)] = True
        if occlusion:
            for k, (a0, b0, a1, b1) in enumerate(rects):
                if k != i and b1 > y1:  # nearer: its feet are lower in the image
                    shown[max(0, b0 - y0) : max(0, b1 - y0), max(0, a0 - x0) : max(0, a1 - x0)] = (
                        False
                    )
        out.append(float(np.count_nonzero(shown)) / area)
    return out


class Candidate(NamedTuple):
    """A usable box of one frame."""

    id: int
    body: Rect
    """The whole box in pixels, may reach outside the image."""
    rect: Rect
    """The part inside the image."""
    visible: float


def frame_candidates(
    boxes: Sequence[Box], width: int, height: int, min_visible: float, occlusion: bool = True
) -> tuple[list[Candidate], int]:
    """The usable boxes of one frame (``visible_fractions`` >= ``min_visible``, at least 2 x 2
    pixels inside the image), and how many were not."""
    out, skipped = [], 0
    for b, vis in zip(boxes, visible_fractions(boxes, width, height, occlusion), strict=True):
        body = _pixels(b)
        rect = (max(0, body[0]), max(0, body[1]), min(width, body[2]), min(height, body[3]))
        if vis < min_visible or rect[2] - rect[0] < 2 or rect[3] - rect[1] < 2:
            skipped += 1
            continue
        out.append(Candidate(b.id, body, rect, vis))
    return out, skipped


def footage_camera(width: int, height: int) -> Camera:
    """The pseudo camera of the module docstring."""
    return Camera(width=width, height=height, hfov_deg=FOV_DEG)


def view_of(c: Candidate, index: int, camera: Camera) -> View:
    """A candidate as the verifiers see it, with the pseudo geometry (module docstring)."""
    x0, y0, x1, y1 = c.body
    depth = camera.f * PERSON_HEIGHT_M / (y1 - y0)
    u = 0.5 * (x0 + x1)
    lateral = (camera.cx - u) * depth / camera.f
    return View(
        index=index,
        x_m=depth,
        y_m=lateral,
        depth_m=depth,
        lateral_m=lateral,
        u_px=u,
        rect=c.rect,
        body=(float(x0), float(y0), float(x1), float(y1)),
    )


# --------------------------------------------------------------------------- scoring


class Choice(NamedTuple):
    """One choice judged, for callers that look at them one by one."""

    protocol: str
    lag: int
    frame: int
    """The choice frame (the model's is ``frame - lag``)."""
    target: int
    """The target's id."""
    ids: list[int]
    """The ids of the boxes judged, in order."""
    distances: list[float | None]
    outcome: Outcome


class Outcome(NamedTuple):
    correct: bool
    unjudged: bool
    """The verifier gave the target no distance (e.g. face: no face found)."""
    rejected: bool
    accepted_without_target: bool


def score(distances: Sequence[float | None], target: int, threshold: float | None) -> Outcome:
    """One choice: rank-1, target rejected (unjudged counts as rejected), someone else at or
    below ``threshold`` (None: no threshold, neither of the last two)."""
    d_t = distances[target]
    others = [d for i, d in enumerate(distances) if i != target and d is not None]
    correct = d_t is not None and all(d_t < d for d in others)
    if threshold is None:
        return Outcome(correct, d_t is None, False, False)
    rejected = d_t is None or d_t > threshold
    return Outcome(correct, d_t is None, rejected, any(d <= threshold for d in others))


@dataclass
class Tally:
    """The figures of one protocol at one lag."""

    protocol: str
    lag: int
    choices: int = 0
    correct: int = 0
    chance: float = 0.0
    unjudged: int = 0
    rejected: int = 0
    accepted: int = 0
    wall_ms: list[float] = field(default_factory=list)
    cpu_ms: list[float] = field(default_factory=list)

    def add(self, o: Outcome, candidates: int, wall_ms: float, cpu_ms: float) -> None:
        self.choices += 1
        self.correct += o.correct
        self.chance += 1.0 / candidates
        self.unjudged += o.unjudged
        self.rejected += o.rejected
        self.accepted += o.accepted_without_target
        self.wall_ms.append(wall_ms / candidates)
        self.cpu_ms.append(cpu_ms / candidates)

    def summary(self) -> dict:
        n = self.choices

        def share(k: float) -> float | None:
            return round(k / n, 4) if n else None

        def p50(a: list[float]) -> float | None:
            return round(float(np.median(a)), 4) if a else None

        return {
            "protocol": self.protocol,
            "lag": self.lag,
            "choices": n,
            "rank1": share(self.correct),
            "chance": share(self.chance),
            "target_rejected": share(self.rejected),
            "target_unjudged": share(self.unjudged),
            "accepted_without_target": share(self.accepted),
            "ms_per_candidate_p50": p50(self.wall_ms),
            "cpu_ms_per_candidate_p50": p50(self.cpu_ms),
        }


# --------------------------------------------------------------------------- evaluation


@dataclass
class Report:
    video: str
    width: int
    height: int
    frames: tuple[int, int]
    """Video frames evaluated, [first, end)."""
    verifier: str
    settings: dict
    threshold: float | None
    adapts: bool
    """Whether the verifier has an online update (else *following* keeps the first view)."""
    tallies: list[Tally]
    counts: dict[str, int] = field(default_factory=dict)
    first_call_ms: list[float] = field(default_factory=list)
    """Wall time of the first judgement on each frame (it pays the frame's preparation)."""
    elapsed_s: float = 0.0

    def summary(self) -> dict:
        a = self.first_call_ms
        return {
            "video": self.video,
            "image_size": [self.width, self.height],
            "frames": list(self.frames),
            "verifier": self.verifier,
            "settings": self.settings,
            "threshold": self.threshold,
            "adapts": self.adapts,
            "results": [t.summary() for t in self.tallies],
            "counts": dict(sorted(self.counts.items())),
            "first_judgement_per_frame_ms_p50": round(float(np.median(a)), 3) if a else None,
            "elapsed_s": round(self.elapsed_s, 2),
        }


def learn_model(
    verifier: Verifier,
    frame: ImageFeatures,
    c: Candidate,
    camera: Camera,
    model_id: int,
) -> Model:
    """The model of candidate ``c``, learnt by ``verifier`` on ``frame``."""
    view = view_of(c, 0, camera)
    x0, y0, x1, y1 = c.rect
    return Model(
        model_id=model_id,
        verifier=verifier.name,
        x_m=view.x_m,
        y_m=view.y_m,
        depth_m=view.depth_m,
        rect_w_px=float(x1 - x0),
        rect_h_px=float(y1 - y0),
        image_width=frame.width,
        image_height=frame.height,
        features=verifier.learn(frame, c.rect, view),
    )


def _distances(verifier: Verifier, frame: ImageFeatures, views: list[View], model: Model):
    """The verifier's distances as the service takes them (non-finite: not judged)."""
    ds = verifier.distances(frame, views, model)
    if len(ds) != len(views):
        raise ValueError(f"{verifier.name} gave {len(ds)} distances for {len(views)} views")
    return [d if d is not None and math.isfinite(d) else None for d in ds]


def open_video(path: str | Path):
    """``cv2.VideoCapture`` of ``path`` that has a first frame; :class:`FootageError` if not."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise FootageError(f"no video file {path}")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise FootageError(f"OpenCV cannot open {path} as a video (not a video, or no decoder)")
    return cap


@dataclass(frozen=True)
class FollowRule:
    """How the *following* protocol updates a model from the target's later boxes."""

    rate: float = 0.02
    """Update rate per frame (0: the first view only)."""
    when: Literal["always", "confident"] = "always"
    """``always``: on every usable box of the target; ``confident``: only when the verifier
    itself picks the target (:func:`..core.confident`)."""
    max_distance: float = 0.4
    """``confident``: the target's distance is at most this ..."""
    margin: float = 0.2
    """... and at least this much below every other box's."""


@dataclass
class _Run:
    """What one evaluation accumulates, frame by frame: the choices due in later frames, each
    person's following model, and the figures."""

    verifier: Verifier
    lags: list[int]
    end: int
    rule: FollowRule
    on_choice: Callable[[Choice], None] | None
    threshold: float | None = None
    tallies: dict[tuple[str, int], Tally] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    pending: dict[int, list[tuple[str, int, int, Model]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    following: dict[int, Model] = field(default_factory=dict)
    first_call_ms: list[float] = field(default_factory=list)
    adapts: bool = True
    """False once the verifier turned out to have no online update."""

    def __post_init__(self) -> None:
        self.threshold = getattr(self.verifier, "default_threshold", None)
        self.tallies = {(p, n): Tally(p, n) for p in PROTOCOLS for n in self.lags}
        self._ids = iter(range(1, 1 << 62))  # a fresh id for each model (verifiers cache by id)

    def frame(self, f: int, frame: ImageFeatures, cands: list[Candidate], camera: Camera) -> None:
        """One video frame: judge the choices due in it, then learn its models."""
        views = [view_of(c, i, camera) for i, c in enumerate(cands)]
        self.judge_due(f, frame, cands, views)
        self.learn(f, frame, cands, views, camera)

    def judge_due(
        self, f: int, frame: ImageFeatures, cands: list[Candidate], views: list[View]
    ) -> None:
        """The choices whose choice frame is ``f``, each against the model it waited with."""
        index = {c.id: i for i, c in enumerate(cands)}
        timed_first = False
        for protocol, lag, pid, model in self.pending.pop(f, ()):
            target = index.get(pid)
            if target is None:
                self.counts["choices_target_not_usable"] += 1
                continue
            if len(cands) < 2:
                self.counts["choices_alone"] += 1
                continue
            t0, c0 = time.perf_counter(), time.thread_time()
            ds = _distances(self.verifier, frame, views, model)
            wall = (time.perf_counter() - t0) * 1e3
            cpu = (time.thread_time() - c0) * 1e3
            if not timed_first:  # the first judgement pays the frame's preparation
                self.first_call_ms.append(wall)
                timed_first = True
            outcome = score(ds, target, self.threshold)
            self.tallies[protocol, lag].add(outcome, len(cands), wall, cpu)
            if self.on_choice is not None:
                ids = [c.id for c in cands]
                self.on_choice(Choice(protocol, lag, f, pid, ids, ds, outcome))

    def learn(
        self,
        f: int,
        frame: ImageFeatures,
        cands: list[Candidate],
        views: list[View],
        camera: Camera,
    ) -> None:
        """Each person's one-view model of frame ``f`` and following model updated with it,
        both waiting for the choices ``lags`` frames later."""
        due = [n for n in self.lags if f + n < self.end]
        for i, c in enumerate(cands):
            follow = self.following.get(c.id)
            one = None
            if due or follow is None:
                one = learn_model(self.verifier, frame, c, camera, next(self._ids))
            if follow is None:
                follow = one
            elif self.rule.rate > 0:
                follow = _updated(
                    self.verifier, frame, views, i, follow, self.rule, next(self._ids)
                )
                if follow is None:
                    self.adapts = False
                    follow = self.following[c.id]
            self.following[c.id] = follow
            for n in due:
                self.pending[f + n].append(("one view", n, c.id, one))
                self.pending[f + n].append(("following", n, c.id, follow))


def evaluate(
    video: str | Path,
    boxes: BoxFile,
    verifier: Verifier,
    *,
    frames: tuple[int, int | None] = (0, None),
    **options: Any,
) -> Report:
    """Both protocols (module docstring) at every lag over video frames ``frames`` [first,
    end) (end None: up to the last frame with boxes, or the video's end); ``options`` are
    :func:`evaluate_frames`'s (lags, box usability, the following model's update rule,
    callbacks)."""
    first = frames[0]
    end = frames[1] if frames[1] is not None else max(boxes.frames) + 1
    if first < 0 or end <= first:
        raise ValueError(f"empty frame range {first}:{end}")
    cap = open_video(video)
    try:
        frames_in = ((f, bgr, boxes.frames.get(f, [])) for f, bgr in _read_frames(cap, first, end))
        report = evaluate_frames(frames_in, str(video), verifier, end=end, **options)
    finally:
        cap.release()
    read = report.frames[1]
    if read < end:
        report.counts["boxes_after_the_video"] = sum(
            len(b) for k, b in boxes.frames.items() if read <= k < end
        )
    report.frames = (first, read)
    return report


def evaluate_frames(
    frames: Iterable[tuple[int, np.ndarray, Sequence[Box]]],
    name: str,
    verifier: Verifier,
    *,
    lags: Iterable[int] = (25, 100),
    end: int,
    min_visible: float = 0.5,
    occlusion: bool = True,
    adapt_rate: float = 0.02,
    adapt_when: Literal["always", "confident"] = "always",
    confident_max_distance: float = 0.4,
    confident_margin: float = 0.2,
    on_frame: Callable[[int, int, int], None] | None = None,
    on_choice: Callable[[Choice], None] | None = None,
) -> Report:
    """:func:`evaluate` on frames from anywhere (a video, a simulator): ``frames`` yields
    (frame index, BGR image, the frame's boxes) in increasing index, the last below ``end``
    (choices are made only for model frames at least a lag before ``end``); ``name`` names the
    source in the report.

    ``adapt_rate``: the following model's update rate per frame; ``adapt_when="confident"``
    updates only when the verifier itself picks the target with the service's rule
    (:func:`..core.confident`: distance <= ``confident_max_distance``, ``confident_margin``
    below every other box), ``"always"`` whenever the target's box is usable. ``on_frame(frame,
    first, end)`` is called after each frame (progress), ``on_choice`` with every choice
    judged."""
    lags = sorted(set(lags))
    if not lags or lags[0] < 1:
        raise ValueError("lags must be whole numbers of frames >= 1")
    if not 0.0 <= adapt_rate <= 1.0:
        raise ValueError(f"adapt_rate must be in [0, 1], got {adapt_rate}")
    rule = FollowRule(adapt_rate, adapt_when, confident_max_distance, confident_margin)
    run = _Run(verifier, lags, end, rule, on_choice)
    t_start = time.perf_counter()
    camera, first, read = None, None, 0
    for f, bgr, frame_boxes in frames:
        if camera is None:
            first = f
            camera = footage_camera(bgr.shape[1], bgr.shape[0])
            width, height = bgr.shape[1], bgr.shape[0]
            if hasattr(verifier, "camera"):
                verifier.camera = camera
        frame = ImageFeatures(bgr)
        frame.cache["camera"] = camera
        cands, hidden = frame_candidates(frame_boxes, width, height, min_visible, occlusion)
        run.counts["boxes"] += len(cands) + hidden
        run.counts["boxes_not_usable"] += hidden
        run.frame(f, frame, cands, camera)
        if on_frame is not None:
            on_frame(f, first, end)
        read = f + 1
    if camera is None:
        raise FootageError(f"{name}: no frame could be read before frame {end}")
    return Report(
        video=name,
        width=width,
        height=height,
        frames=(first, read),
        verifier=verifier.name,
        settings=msgspec.to_builtins(getattr(verifier, "settings", None)) or {},
        threshold=run.threshold,
        adapts=run.adapts and adapt_rate > 0,
        tallies=list(run.tallies.values()),
        counts=dict(run.counts),
        first_call_ms=run.first_call_ms,
        elapsed_s=time.perf_counter() - t_start,
    )


def _read_frames(cap, first: int, end: int) -> Iterator[tuple[int, np.ndarray]]:
    """Video frames ``first`` .. ``end - 1`` with their index, decoded; fewer when the video
    ends sooner (the frames before ``first`` are skipped, not decoded)."""
    f = 0
    while f < first and cap.grab():
        f += 1
    while f < end:
        ok, bgr = cap.read()
        if not ok:
            return
        yield f, bgr
        f += 1


def _updated(
    verifier: Verifier,
    frame: ImageFeatures,
    views: list[View],
    target: int,
    model: Model,
    rule: FollowRule,
    model_id: int,
) -> Model | None:
    """``model`` updated with the target's box (a new Model; the old one is unchanged, it is
    some pending choice's snapshot); None when the verifier has no update."""
    if rule.when == "confident":
        ds = _distances(verifier, frame, views, model)
        if not confident(ds, target, rule.max_distance, rule.margin):
            return model
    update = getattr(verifier, "update", None)
    if update is not None:  # a verifier that learns from the target and the bystanders
        learnt = update(frame, views, target, model)
        if learnt is None:
            return model
        return msgspec.structs.replace(model, model_id=model_id, features=learnt)
    seen = verifier.describe(frame, views[target].rect)
    if seen is None:
        return None
    return msgspec.structs.replace(
        model, model_id=model_id, features=adapt_features(model.features, seen, rule.rate)
    )
