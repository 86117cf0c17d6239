"""Evaluation of the verifiers in the simulator, and of the histograms on real footage.

    python -m followbot.research.vision_evaluate sim [--verifier NAME ...]
        [--scenario NAME ...] [--threshold D] [--json FILE]
    python -m followbot.research.vision_evaluate calibrate [--verifier NAME ...]
    python -m followbot.research.vision_evaluate vtest PATH/TO/vtest.avi
    python -m followbot.research.vision_evaluate realistic [--verifier NAME ...]
        [--scenario lookalikes] [--without PART ...] [--json FILE]

``sim``: two test scenes. In both the robot stands still until the model is built from frame
and laser differencing (thesis 4.2). In ``thesis_5_2_4_two_people`` a follower driven by
ground truth (thesis 3.7 rules: turn beyond 6 deg, stop within 1.2 m, pan = heading) then
keeps the target in front, so the verifier sees what it would see behind a perfect tracker.
In ``hidden_target_bystanders`` the robot stays still while the target hides behind a
partition and then leaves the camera's view, each time with a bystander walking in view. Each
scan goes through the thesis leg detector (ranges unclipped), is paired with the nearest image
(within 60 ms), and every verifier judges the same candidates. A candidate is the target's (a
bystander's) when it lies within 0.5 m of that person's true position.

Figures per verifier (``target_in_view`` scans: the target is visible to the camera and one
of its candidates projects into the image):

* ``correct_share``: chosen candidate is the target's, / target_in_view scans;
* ``wrong_share`` / ``rejected_share``: another candidate chosen / nothing chosen;
* ``bystander_choices_hidden``: while none of the target's candidates is judged and some other
  candidate is (``hidden_with_others`` scans), scans where a candidate is chosen, with the
  rejection threshold and without; ``hidden_chosen_by``: whose candidate (-1: no person's).

``calibrate``: the rejection threshold of a verifier from *training* scenes
(:data:`CALIBRATION_SCENARIOS`, not the test scenes above), see :func:`calibrate`.

``realistic``: ``followbot appearance``'s figures on a simulated scene (default
``lookalikes``): the robot follows its target on ground truth 2 m behind, every person in view
is boxed from the true geometry, and the frames and boxes go through the footage measurement
(:func:`evaluate_realistic`; docs/vision_verify.md "Simulator and pets09 side by side").
``--without`` switches one part of the scene's realism off (:data:`REALISM`).

``vtest``: OpenCV's pedestrian clip (Debian's opencv-doc, examples/data/vtest.avi). People are
boxed by frame differencing (the thesis's smoothing and threshold, then connected blobs), each
box is tracked to the next frame by overlap, and the histogram distance is reported for the
same pedestrian one frame later versus different pedestrians in the same frame, with timings.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field

import msgspec
import numpy as np

__all__ = [
    "REALISM",
    "SimScore",
    "evaluate_realistic",
    "evaluate_sim",
    "evaluate_vtest",
    "follow_truth",
    "main",
    "realistic_frames",
    "sim_boxes",
]

_NS = 1_000_000_000


@dataclass
class SimScore:
    verifier: str
    scenario: str
    threshold: float | None
    model_built_s: float | None = None
    scans: int = 0
    scans_judged: int = 0
    target_in_view: int = 0
    correct: int = 0
    wrong: int = 0
    rejected: int = 0
    correct_no_threshold: int = 0
    hidden_with_others: int = 0
    bystander_hidden: int = 0
    bystander_hidden_no_threshold: int = 0
    hidden_chosen_by: dict[int, int] = field(default_factory=dict)
    """While the target is hidden: how often each person's candidate (-1: not a person) was
    chosen with the threshold ..."""
    hidden_chosen_by_no_threshold: dict[int, int] = field(default_factory=dict)
    """... and without it."""
    judge_ms: list[float] = field(default_factory=list)
    target_d: list[float] = field(default_factory=list)
    other_d: list[float] = field(default_factory=list)
    apart_d: list[float] = field(default_factory=list)
    """Other people's distances whose rectangle shares under a quarter of its width with every
    rectangle of the target's candidates (the bystander alone in its rectangle)."""

    def summary(self) -> dict:
        tv = max(1, self.target_in_view)
        ms = np.array(self.judge_ms) if self.judge_ms else np.array([math.nan])
        td = np.array(self.target_d) if self.target_d else np.array([math.nan])
        od = np.array(self.other_d) if self.other_d else np.array([math.nan])
        return {
            "verifier": self.verifier,
            "scenario": self.scenario,
            "threshold": self.threshold,
            "model_built_s": self.model_built_s,
            "scans": self.scans,
            "scans_judged": self.scans_judged,
            "target_in_view": self.target_in_view,
            "correct_share": self.correct / tv,
            "wrong_share": self.wrong / tv,
            "rejected_share": self.rejected / tv,
            "correct_share_no_threshold": self.correct_no_threshold / tv,
            "hidden_with_others": self.hidden_with_others,
            "bystander_choices_hidden": self.bystander_hidden,
            "bystander_choices_hidden_no_threshold": self.bystander_hidden_no_threshold,
            "hidden_chosen_by": {str(k): v for k, v in sorted(self.hidden_chosen_by.items())},
            "hidden_chosen_by_no_threshold": {
                str(k): v for k, v in sorted(self.hidden_chosen_by_no_threshold.items())
            },
            "target_distance_p50_p95": [
                float(np.nanpercentile(td, 50)),
                float(np.nanpercentile(td, 95)),
            ],
            "other_distance_p5_p50": [
                float(np.nanpercentile(od, 5)),
                float(np.nanpercentile(od, 50)),
            ],
            "judge_ms_p50_p99": [float(np.nanpercentile(ms, 50)), float(np.nanpercentile(ms, 99))],
        }


def follow_truth(sim, truth, target_id: int, stop_m: float = 1.2) -> None:
    """Thesis 3.7 control on the true target position (a perfect tracker's estimate): stop
    within ``stop_m`` (thesis 1.2 m), 0.5 m/s up to 0.3 m beyond it, else 0.75 m/s."""
    person = next((p for p in truth.people if p.id == target_id), None)
    if person is None:
        sim.command_velocity(0.0, 0.0)
        return
    x, y = person.robot_x_m, person.robot_y_m
    r, theta = math.hypot(x, y), math.atan2(y, x)
    w = 0.0 if abs(theta) < math.radians(6) else max(-1.745, min(1.745, 1.5 * theta))
    v = 0.0 if r < stop_m else (0.5 if r <= stop_m + 0.3 else 0.75)  # thesis 3.7
    sim.command_velocity(v, w)
    sim.command_pan(theta)


def evaluate_sim(
    verifier_name: str,
    *,
    scenario: str = "thesis_5_2_4_two_people",
    swap_target: bool = False,
    threshold: float | None = None,
    duration_s: float | None = None,
    adapt_rate: float = 0.0,
    follow: bool = True,
) -> SimScore:
    from followbot.schemas import GroundTruth, Image, LaserScan
    from followbot.services.laser_legs.detectors.thesis import ClusterLegDetector, ThesisSettings
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation
    from followbot.services.vision_verify.core import (
        Camera,
        ImageFeatures,
        adapt_features,
        confident,
        judge,
    )
    from followbot.services.vision_verify.model import ModelBuilder, build_model
    from followbot.services.vision_verify.verifiers import make_verifier

    spec = load_builtin(scenario)
    if swap_target:
        people = [msgspec.structs.replace(p, is_target=not p.is_target) for p in spec.people]
        spec = msgspec.structs.replace(spec, people=people)
    if duration_s is not None:
        spec = msgspec.structs.replace(spec, duration_s=duration_s)
    target_id = next(p.id for p in spec.people if p.is_target)
    sim = Simulation(spec)
    cs = spec.camera
    camera = Camera(
        width=cs.width,
        height=cs.height,
        hfov_deg=cs.hfov_deg,
        height_m=cs.height_m,
        offset_x_m=cs.mount_x_m - spec.laser.mount_x_m,
    )
    verifier = make_verifier(verifier_name)
    if threshold is None:
        threshold = verifier.default_threshold
    detector = ClusterLegDetector(ThesisSettings(clip_range_m=None))
    builder = ModelBuilder(camera)
    score = SimScore(
        verifier=verifier_name,
        scenario=scenario + ("/person2" if swap_target else ""),
        threshold=threshold,
    )
    model = None
    image: Image | None = None
    pixels = None
    pending: list = []  # scans waiting for their image (same tick)
    while not sim.finished:
        msgs = sim.tick()
        truth = None
        for m in msgs:
            if isinstance(m, Image):
                image, pixels = m, m.pixels().copy()
                if model is None:
                    acq = builder.add_image(m.stamp_ns, pixels, m.pan_rad)
                    if acq is not None:
                        model = build_model(verifier, camera, acq, 1)
                        score.model_built_s = m.stamp_ns / _NS
            elif isinstance(m, LaserScan):
                cands = detector.detect(m)
                if model is None:
                    acq = builder.add_scan(m.stamp_ns, m.ranges_m(), cands)
                    if acq is not None:
                        model = build_model(verifier, camera, acq, 1)
                        score.model_built_s = m.stamp_ns / _NS
                pending.append((m.stamp_ns, cands))
            elif isinstance(m, GroundTruth):
                truth = m
                pending[-1] = (*pending[-1], m)
        for stamp, cands, tr in pending:
            score.scans += 1
            if model is not None and follow:
                follow_truth(sim, tr, target_id)
            if model is None or image is None or abs(image.stamp_ns - stamp) > 0.06 * _NS:
                continue
            score.scans_judged += 1
            xy = np.array([[c.x_m, c.y_m] for c in cands.candidates]).reshape(-1, 2)
            t0 = time.perf_counter()
            frame = ImageFeatures(pixels)
            j = judge(verifier, frame, camera, model, xy, image.pan_rad, None)
            score.judge_ms.append((time.perf_counter() - t0) * 1e3)
            _score_scan(score, j, xy, tr, target_id, threshold)
            if adapt_rate > 0:
                from followbot.services.vision_verify.core import choose

                ch = choose(j.distances, threshold)
                if confident(j.distances, ch, 0.5 * threshold, 0.2):
                    seen = verifier.describe(frame, j.views[ch].rect)
                    if seen is not None:
                        model.features = adapt_features(model.features, seen, adapt_rate)
        pending.clear()
        del truth
    return score


def _owner(xy: np.ndarray, truth, radius_m: float = 0.5) -> list[int]:
    """Per candidate: the id of the true person within ``radius_m`` (nearest), or -1."""
    out = []
    for x, y in xy:
        best, who = radius_m, -1
        for p in truth.people:
            d = math.hypot(p.robot_x_m - x, p.robot_y_m - y)
            if d < best:
                best, who = d, p.id
        out.append(who)
    return out


def _shared_width(rect, others) -> float:
    """Largest share of ``rect``'s width that one of ``others`` also covers."""
    x0, _, x1, _ = rect
    best = 0.0
    for o in others:
        best = max(best, max(0, min(x1, o[2]) - max(x0, o[0])) / max(1, x1 - x0))
    return best


def _score_scan(score: SimScore, j, xy, truth, target_id: int, threshold) -> None:
    from followbot.services.vision_verify.core import choose

    owners = _owner(xy, truth)
    target = next(p for p in truth.people if p.id == target_id)
    in_view = [v.ok and j.distances[i] is not None for i, v in enumerate(j.views)]
    target_idx = [i for i, o in enumerate(owners) if o == target_id and in_view[i]]
    others = [i for i in range(len(owners)) if owners[i] != target_id and in_view[i]]
    for i in target_idx:
        score.target_d.append(j.distances[i])
    for i in others:
        if owners[i] >= 0:
            score.other_d.append(j.distances[i])
            whole = [j.views[k].projected or j.views[k].rect for k in target_idx]
            if _shared_width(j.views[i].projected or j.views[i].rect, whole) < 0.25:
                score.apart_d.append(j.distances[i])
    with_t = choose(j.distances, threshold)
    without = choose(j.distances, None)
    if target.visible_camera and target_idx:
        score.target_in_view += 1
        if with_t in target_idx:
            score.correct += 1
        elif with_t < 0:
            score.rejected += 1
        else:
            score.wrong += 1
        if without in target_idx:
            score.correct_no_threshold += 1
    elif not target_idx and others:
        score.hidden_with_others += 1
        if with_t >= 0:
            score.bystander_hidden += 1
            who = owners[with_t]
            score.hidden_chosen_by[who] = score.hidden_chosen_by.get(who, 0) + 1
        if without >= 0:
            score.bystander_hidden_no_threshold += 1
            who = owners[without]
            by = score.hidden_chosen_by_no_threshold
            by[who] = by.get(who, 0) + 1


# --------------------------------------------------------------------------- realistic

#: What ``realistic --without`` can switch off in the scenario, and how.
REALISM = {
    "motion_blur": ("camera", {"exposure_ms": 0.0}),
    "softness": ("camera", {"optics_blur_px": 0.0}),
    "jpeg": ("camera", {"jpeg_quality": None}),
    "noise": ("camera", {"noise_std": 0.0}),
    "shade": ("world", {"light_zones": []}),
    "lighting_change": ("scenario", {"lighting": []}),
    "lookalikes": ("people", {}),
}


def _without(spec, parts: list[str]):
    """``spec`` with the named parts of :data:`REALISM` switched off (lookalikes: dressed as
    pedestrians instead, each by their own draw)."""
    for part in parts:
        where, changes = REALISM[part]
        if where == "scenario":
            spec = msgspec.structs.replace(spec, **changes)
        elif where == "people":
            people = [
                msgspec.structs.replace(
                    p, dress=msgspec.structs.replace(p.dress, style="pedestrian", of=None)
                )
                if p.dress is not None and p.dress.style == "lookalike"
                else p
                for p in spec.people
            ]
            spec = msgspec.structs.replace(spec, people=people)
        else:
            sub = msgspec.structs.replace(getattr(spec, where), **changes)
            spec = msgspec.structs.replace(spec, **{where: sub})
    return spec


def sim_boxes(sim) -> list:
    """Every person's whole-body box (footage ``Box``, unclipped) in the simulator's camera
    view now: in front of the camera, the body centre's column in the image and not behind
    a wall (``CameraModel.sees`` at 1 m)."""
    from followbot.services.vision_verify.footage import Box

    cam, pose, pan = sim.camera, sim.robot.pose, sim.robot.pan_rad
    out = []
    for p, st in zip(sim.people, sim.people_states(), strict=True):
        rect = cam.person_box(pose, pan, st, p.spec.appearance)
        if rect is not None and cam.sees(pose, pan, st.position, 1.0):
            x0, y0, x1, y1 = rect
            out.append(Box(p.id, x0, y0, x1 - x0, y1 - y0))
    return out


def realistic_frames(scenario: str, *, without: list[str] = (), stop_m: float = 2.0):
    """The scenario's frames with true person boxes, (index, BGR, boxes), while the robot
    follows the target on ground truth (:func:`follow_truth` at ``stop_m``); and the number of
    frames it will yield."""
    from followbot.schemas import GroundTruth, Image
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation

    spec = _without(load_builtin(scenario), list(without))
    sim = Simulation(spec)
    n = math.floor(spec.duration_s * spec.camera.rate_hz - 1e-9) + 1

    def frames():
        k = 0
        while not sim.finished and k < n:
            for m in sim.tick():
                if isinstance(m, Image) and k < n:
                    yield k, m.pixels().copy(), sim_boxes(sim)
                    k += 1
                elif isinstance(m, GroundTruth):
                    follow_truth(sim, m, sim.target_id, stop_m)

    return frames(), n


def evaluate_realistic(
    verifier_name: str,
    *,
    scenario: str = "lookalikes",
    without: list[str] = (),
    lags: tuple[int, ...] = (25, 100),
    stop_m: float = 2.0,
    min_visible: float = 0.5,
) -> dict:
    """``followbot appearance``'s figures on the simulator: the scenario rendered while the
    robot follows its target, each visible person boxed from the true geometry, every person
    a choice as on footage (docs/vision_verify.md "Simulator and pets09 side by side")."""
    from followbot.services.vision_verify.footage import evaluate_frames
    from followbot.services.vision_verify.verifiers import make_verifier

    unknown = sorted(set(without) - set(REALISM))
    if unknown:
        raise ValueError(f"unknown --without {unknown}; choose from {sorted(REALISM)}")
    frames, n = realistic_frames(scenario, without=list(without), stop_m=stop_m)
    report = evaluate_frames(
        frames, f"sim:{scenario}", make_verifier(verifier_name), lags=lags, end=n,
        min_visible=min_visible,
    )  # fmt: skip
    out = report.summary()
    out["without"] = list(without)
    return out


# --------------------------------------------------------------------------- calibration

#: Scenarios the rejection thresholds are calibrated on (training). The figures of ``sim`` come
#: from other scenarios (test), so a threshold is never fitted to the scenes it is judged on.
CALIBRATION_SCENARIOS = ("thesis_5_2_4_side_by_side", "thesis_5_2_4_turn_apart")


def calibrate(verifier_name: str, scenarios: tuple[str, ...] = CALIBRATION_SCENARIOS) -> dict:
    """The rejection threshold from training scenes: midway between the 99th percentile of the
    target's distances (target in view) and the 1st percentile of the distances of other people
    standing apart from the target in the image (``SimScore.apart_d``; a bystander's rectangle
    that also holds the target says little about a bystander seen alone).

    Each scene is run as in :func:`evaluate_sim` (model learnt by differencing, robot following
    the target on ground truth), so the distances are those a verifier meets behind a tracker."""
    target, other = [], []
    for name in scenarios:
        sc = evaluate_sim(verifier_name, scenario=name, follow=True)
        target += sc.target_d
        other += sc.apart_d
    t, o = np.array(target), np.array(other)
    t99, o1 = float(np.percentile(t, 99)), float(np.percentile(o, 1))
    return {
        "verifier": verifier_name,
        "scenarios": list(scenarios),
        "target_distances": int(t.size),
        "apart_distances": int(o.size),
        "target_p50_p99_max": [float(np.median(t)), t99, float(t.max())],
        "apart_min_p1_p50": [float(o.min()), o1, float(np.median(o))],
        "threshold": round(0.5 * (t99 + o1), 2),
    }


# --------------------------------------------------------------------------- real footage


def pedestrian_boxes(prev_grey, grey, *, threshold: float = 30.0, min_area_px: int = 600):
    """Boxes (x0, y0, x1, y1) of moving blobs between two frames: thesis smoothing and
    differencing, then dilation and connected components (vtest's people are small, so the
    threshold is lower than the thesis's 80 and blobs are kept apart)."""
    import cv2

    from followbot.services.vision_verify.model import smooth_grey

    d = cv2.absdiff(smooth_grey(prev_grey), smooth_grey(grey))
    mask = (d > threshold).astype(np.uint8)
    mask = cv2.dilate(mask, np.ones((7, 3), np.uint8), iterations=2)
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask)
    boxes = []
    for k in range(1, n):
        x, y, w, h, area = stats[k]
        if area >= min_area_px and h >= 1.2 * w and h >= 30:  # upright: a pedestrian
            boxes.append((int(x), int(y), int(x + w), int(y + h)))
    return boxes


def _iou(a, b) -> float:
    ix = max(0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union else 0.0


def evaluate_vtest(path: str, max_frames: int = 400) -> dict:
    """Histogram distances of the same pedestrian across frames vs different pedestrians."""
    import cv2

    from followbot.services.vision_verify.core import ImageFeatures, bhattacharyya

    cap = cv2.VideoCapture(path)
    if not cap.isOpened():
        raise ValueError(f"cannot open video {path}")
    prev_grey = None
    prev: list[tuple[tuple, dict]] = []
    same, cross = [], []
    hist_ms, frames, boxes_total = [], 0, 0
    try:
        while frames < max_frames:
            ok, bgr = cap.read()
            if not ok:
                break
            frames += 1
            grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
            cur: list[tuple[tuple, dict]] = []
            if prev_grey is not None:
                boxes = pedestrian_boxes(prev_grey, grey)
                boxes_total += len(boxes)
                frame = ImageFeatures(bgr)
                for b in boxes:
                    t0 = time.perf_counter()
                    h = frame.histograms(b)
                    hist_ms.append((time.perf_counter() - t0) * 1e3)
                    cur.append((b, h))

                def d(h1, h2):
                    return bhattacharyya(h1["colour_hs"], h2["colour_hs"]) + bhattacharyya(
                        h1["edge_orientation"], h2["edge_orientation"]
                    )

                for b, h in cur:  # the same pedestrian one frame later: best overlap > 0.5
                    match = max(prev, key=lambda p, b=b: _iou(p[0], b), default=None)
                    if match is not None and _iou(match[0], b) > 0.5:
                        same.append(d(h, match[1]))
                for i in range(len(cur)):  # different pedestrians of one frame (no overlap)
                    for k in range(i + 1, len(cur)):
                        if _iou(cur[i][0], cur[k][0]) == 0.0:
                            cross.append(d(cur[i][1], cur[k][1]))
            prev_grey, prev = grey, cur
    finally:
        cap.release()
    same_a, cross_a = np.array(same), np.array(cross)

    def pct(a, q):
        return float(np.percentile(a, q)) if a.size else None

    return {
        "video": path,
        "frames": frames,
        "boxes": boxes_total,
        "same_pairs": int(same_a.size),
        "cross_pairs": int(cross_a.size),
        "same_distance_p50_p90": [pct(same_a, 50), pct(same_a, 90)],
        "cross_distance_p10_p50": [pct(cross_a, 10), pct(cross_a, 50)],
        "same_below_cross_median": (
            float(np.mean(same_a < np.median(cross_a))) if same_a.size and cross_a.size else None
        ),
        "histograms_ms_p50_p99_per_box": [pct(np.array(hist_ms), 50), pct(np.array(hist_ms), 99)],
        "mean_box_px": None,
    }


# --------------------------------------------------------------------------- CLI


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m followbot.research.vision_evaluate")
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("sim", help="verifiers in the simulator's two-person scenario")
    s.add_argument("--verifier", action="append", default=[])
    s.add_argument("--json", help="write the figures here")
    s.add_argument("--adapt-rate", type=float, default=0.0)
    s.add_argument("--threshold", type=float, help="instead of each verifier's default")
    s.add_argument(
        "--scenario",
        action="append",
        default=[],
        help="default: the test scenes thesis_5_2_4_two_people (robot follows) and "
        "hidden_target_bystanders (still); any built-in scenario may be named (the robot "
        "follows), e.g. the calibration scenes thesis_5_2_4_side_by_side and "
        "thesis_5_2_4_turn_apart, or thesis_5_2_4_two_people_swapped",
    )
    r = sub.add_parser(
        "realistic", help="followbot appearance's figures on a realistic simulated scene"
    )
    r.add_argument("--verifier", action="append", default=[])
    r.add_argument("--scenario", default="lookalikes")
    r.add_argument("--lags", default="25,100", help="frames between model and choice")
    r.add_argument(
        "--without", action="append", default=[], choices=sorted(REALISM),
        help="switch one part of the scene's realism off (repeatable)",
    )  # fmt: skip
    r.add_argument("--stop-m", type=float, default=2.0, help="the follower's distance (2.0)")
    r.add_argument("--min-visible", type=float, default=0.5)
    r.add_argument("--json", help="write the figures here")
    c = sub.add_parser("calibrate", help="rejection thresholds from the training scenes")
    c.add_argument("--verifier", action="append", default=[])
    v = sub.add_parser("vtest", help="histograms on OpenCV's vtest.avi")
    v.add_argument("path")
    v.add_argument("--frames", type=int, default=400)
    args = ap.parse_args(argv)
    if args.cmd == "vtest":
        out = evaluate_vtest(args.path, args.frames)
        json.dump(out, sys.stdout, indent=2)
        print()
        return 0
    if args.cmd == "realistic":
        return _realistic(args)
    if args.cmd == "calibrate":
        for name in args.verifier or ["histogram", "meanshift"]:
            print(json.dumps(calibrate(name)), flush=True)
        return 0
    results = []
    runs = [
        ("thesis_5_2_4_two_people", dict(follow=True)),
        ("hidden_target_bystanders", dict(follow=False)),
    ]
    if args.scenario:
        runs = [(n, dict(follow=n != "hidden_target_bystanders")) for n in args.scenario]
    for name in args.verifier or ["histogram", "meanshift", "face"]:
        for scenario, kw in runs:
            r = evaluate_sim(
                name, scenario=scenario, threshold=args.threshold, adapt_rate=args.adapt_rate, **kw
            ).summary()
            r["robot"] = "follows the target (truth)" if kw["follow"] else "still"
            if scenario in CALIBRATION_SCENARIOS:
                r["note"] = "calibration (training) scene of the thresholds"
            results.append(r)
            print(json.dumps(r), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)
    return 0


def _realistic(args) -> int:
    from followbot.appearance import format_table

    lags = tuple(int(t) for t in args.lags.split(","))
    results = []
    for name in args.verifier or ["histogram", "online"]:
        out = evaluate_realistic(
            name, scenario=args.scenario, without=args.without, lags=lags,
            stop_m=args.stop_m, min_visible=args.min_visible,
        )  # fmt: skip
        results.append(out)
        print(format_table(out) + "\n", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
