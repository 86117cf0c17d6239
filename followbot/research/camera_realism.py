"""How real the simulated camera is: the same image statistics on real footage and on renders.

    python -m followbot.research.camera_realism [--video vtest.avi] [--boxes S2L1.csv]
        [--scenario lookalikes] [--json FILE]

Statistics (each computed by the same function on both sides):

* **noise**: grey-level noise on flat background (outside every person box dilated by 8 px,
  where the smoothed gradient is under 1 grey level per pixel): the standard deviation of the
  grey image less its Gaussian blur (5 x 5, sigma 1). It takes in fine texture too, and it is
  measured within one frame, so it also holds for a moving camera. Beside it the temporal
  noise of still background: consecutive frames' difference where no channel changed by
  more than 20 (motion left out), its standard deviation / sqrt(2); a compressed video
  repeats unchanged blocks, so on vtest three quarters of these differences are 0.
* **edge width**: how soft the image is (optics, demosaicing, compression): for strong
  vertical edges (a peak of the difference between neighbouring pixels above 20 grey
  levels), the number of pixel steps over which the difference stays above half its peak,
  along the row (the gradient's full width at half maximum). A hard polygon edge is 1.
* **edge width on people, horizontal / vertical**: the same measure inside person boxes along
  rows (edges across the direction people walk: smeared by motion blur) and along columns
  (edges along it: not smeared); their ratio shows motion blur.
* **clothes**: per usable person box (>= 80 % visible, >= 40 px tall), the median colour of a
  top window (columns 0.3-0.7, rows 0.2-0.45 of the box) and a trousers window (rows
  0.6-0.85), in CIE Lab: the share that is dark (L* < 30), neutral (chroma < 12, not dark),
  blue-ish (hue 200-300 deg, chroma >= 12) and other colours; and the median chroma. One box
  per person and 10 frames (people change little frame to frame).

Real: PETS 2009 S2.L1 view 1 (``vtest.avi``) frames 0-399 with the pets09 boxes (the
development split). Simulated: a built-in scenario (``lookalikes`` by default), the robot
standing still for the first part (noise and edges) while it is, then following the target
on ground truth; boxes from the true geometry (:func:`person_boxes`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable, Iterator

import cv2
import numpy as np

__all__ = [
    "clothes_figures",
    "edge_widths",
    "main",
    "measure_frames",
    "noise_std",
    "person_boxes",
    "sim_frames",
    "temporal_noise_std",
    "video_frames",
]

Rect = tuple[int, int, int, int]


def _background_mask(shape: tuple[int, int], boxes: Iterable[Rect], pad: int = 8) -> np.ndarray:
    mask = np.ones(shape, dtype=bool)
    h, w = shape
    for x0, y0, x1, y1 in boxes:
        mask[max(0, y0 - pad) : min(h, y1 + pad), max(0, x0 - pad) : min(w, x1 + pad)] = False
    return mask


def noise_std(grey: np.ndarray, mask: np.ndarray) -> float | None:
    """Spatial noise (module docstring) of a grey frame on ``mask``; None: too few flat pixels."""
    g = grey.astype(np.float32)
    smooth = cv2.GaussianBlur(g, (5, 5), 1.5)
    grad = np.hypot(cv2.Sobel(smooth, cv2.CV_32F, 1, 0), cv2.Sobel(smooth, cv2.CV_32F, 0, 1))
    flat = mask & (grad / 8.0 < 1.0)
    if np.count_nonzero(flat) < 500:
        return None
    return float(np.std((g - cv2.GaussianBlur(g, (5, 5), 1.0))[flat]))


def temporal_noise_std(prev: np.ndarray, cur: np.ndarray, mask: np.ndarray) -> float | None:
    """Temporal noise (module docstring) of two BGR frames on ``mask``."""
    d = cur.astype(np.int16)[mask] - prev.astype(np.int16)[mask]
    d = d[np.abs(d).max(axis=1) <= 20]
    if d.shape[0] < 500:
        return None
    return float(d.std() / math.sqrt(2.0))


def edge_widths(
    grey: np.ndarray, axis: int = 1, min_peak: float = 20.0, mask: np.ndarray | None = None
) -> np.ndarray:
    """Gradient full widths at half maximum (px) of strong edges across ``axis`` (1: along
    rows, vertical edges; 0: along columns, horizontal edges) whose peak lies on ``mask``.
    The gradient is the difference of neighbouring pixels, so a hard step is 1 px wide."""
    g = grey.astype(np.float32)
    if axis == 0:
        g = g.T
        mask = None if mask is None else mask.T
    gx = np.abs(np.diff(g, axis=1))  # gx[:, j]: between pixels j and j + 1
    peak = (gx[:, 1:-1] >= gx[:, :-2]) & (gx[:, 1:-1] > gx[:, 2:]) & (gx[:, 1:-1] > min_peak)
    if mask is not None:
        peak &= mask[:, 1:-2]
    rows, cols = np.nonzero(peak)
    cols = cols + 1
    out = []
    w = gx.shape[1]
    for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
        half = 0.5 * gx[r, c]
        a = c
        while a > 0 and gx[r, a - 1] > half:
            a -= 1
        b = c
        while b < w - 1 and gx[r, b + 1] > half:
            b += 1
        if a > 0 and b < w - 1:  # the whole edge is inside the image
            out.append(b - a + 1)
    return np.asarray(out, dtype=float)


def _lab_of(bgr: np.ndarray) -> tuple[float, float, float]:
    """CIE Lab (L* 0-100, a*, b*) of one BGR colour."""
    px = np.asarray(bgr, dtype=np.float32).reshape(1, 1, 3) / 255.0
    lab = cv2.cvtColor(px, cv2.COLOR_BGR2Lab)[0, 0]
    return float(lab[0]), float(lab[1]), float(lab[2])


def _window(img: np.ndarray, box: Rect, rows: tuple[float, float]) -> np.ndarray | None:
    x0, y0, x1, y1 = box
    w, h = x1 - x0, y1 - y0
    a, b = y0 + int(rows[0] * h), y0 + int(rows[1] * h)
    c, d = x0 + int(0.3 * w), x0 + int(0.7 * w)
    patch = img[max(0, a) : max(0, b), max(0, c) : max(0, d)]
    return None if patch.size == 0 else patch.reshape(-1, 3)


def colour_class(lab: tuple[float, float, float]) -> str:
    """dark, neutral, blue or colour (module docstring, "clothes")."""
    L, a, b = lab
    chroma = math.hypot(a, b)
    if L < 30:
        return "dark"
    if chroma < 12:
        return "neutral"
    hue = math.degrees(math.atan2(b, a)) % 360
    return "blue" if 200 <= hue <= 300 else "colour"


def clothes_figures(samples: dict[str, list[tuple[float, float, float]]]) -> dict:
    """Shares of colour classes and median chroma, per garment, from Lab samples."""
    out = {}
    for part, labs in samples.items():
        classes = [colour_class(lab) for lab in labs]
        n = max(1, len(classes))
        out[part] = {
            "boxes": len(classes),
            **{k: round(classes.count(k) / n, 3) for k in ("dark", "neutral", "blue", "colour")},
            "chroma_p50": round(float(np.median([math.hypot(a, b) for _, a, b in labs])), 1)
            if labs
            else None,
            "lightness_p50": round(float(np.median([L for L, _, _ in labs])), 1) if labs else None,
        }
    return out


def measure_frames(frames: Iterator[tuple[np.ndarray, list[tuple[int, Rect, float]]]]) -> dict:
    """The statistics over ``frames``: (BGR image, [(person id, box, visible share)])."""
    noise, temporal, edges, people_h, people_v = [], [], [], [], []
    samples: dict[str, list] = {"top": [], "trousers": []}
    seen: dict[int, int] = {}
    prev = None
    for k, (img, boxes) in enumerate(frames):
        h, w = img.shape[:2]
        mask = _background_mask((h, w), [b for _, b, _ in boxes])
        grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if prev is not None and k % 5 == 0:
            for out, s in ((temporal, temporal_noise_std(prev, img, mask)),
                           (noise, noise_std(grey, mask))):  # fmt: skip
                if s is not None:
                    out.append(s)
            edges.extend(edge_widths(grey, mask=mask).tolist())
        prev = img
        for pid, box, vis in boxes:
            x0, y0, x1, y1 = (max(0, box[0]), max(0, box[1]), min(w, box[2]), min(h, box[3]))
            if vis < 0.8 or box[3] - box[1] < 40 or x1 - x0 < 8:
                continue
            crop = grey[y0:y1, x0:x1]
            people_h.extend(edge_widths(crop, 1).tolist())
            people_v.extend(edge_widths(crop, 0).tolist())
            if k - seen.get(pid, -(10**9)) >= 10:
                seen[pid] = k
                for part, rows in (("top", (0.2, 0.45)), ("trousers", (0.6, 0.85))):
                    patch = _window(img, box, rows)
                    if patch is not None:
                        samples[part].append(_lab_of(np.median(patch, axis=0)))

    def p50(a):
        return round(float(np.median(a)), 2) if len(a) else None

    return {
        "noise_std": p50(noise),
        "temporal_noise_std": p50(temporal),
        "edge_width_px_p50": p50(edges),
        "edge_width_px_mean": round(float(np.mean(edges)), 2) if edges else None,
        "person_edge_width_along_rows_mean": round(float(np.mean(people_h)), 2)
        if people_h
        else None,
        "person_edge_width_along_columns_mean": round(float(np.mean(people_v)), 2)
        if people_v
        else None,
        "clothes": clothes_figures(samples),
    }


# --------------------------------------------------------------------------- sources


def video_frames(video: str, boxes_csv: str, first: int = 0, end: int = 400):
    """Frames of a video with their boxes (footage box file) and each box's visible share."""
    from followbot.services.vision_verify.footage import (
        _pixels,
        open_video,
        read_boxes,
        visible_fractions,
    )

    boxes = read_boxes(boxes_csv)
    cap = open_video(video)
    try:
        f = 0
        while f < end:
            ok, bgr = cap.read()
            if not ok:
                return
            if f >= first:
                bs = boxes.frames.get(f, [])
                vis = visible_fractions(bs, bgr.shape[1], bgr.shape[0])
                yield bgr, [(b.id, _pixels(b), v) for b, v in zip(bs, vis, strict=True)]
            f += 1
    finally:
        cap.release()


def person_boxes(sim) -> list[tuple[int, Rect, float]]:
    """Every visible person's whole-body box in the simulator's camera view now
    (:func:`..vision_evaluate.sim_boxes`), rounded, with its visible share by the footage rule
    (image border, nearer boxes)."""
    from followbot.research.vision_evaluate import sim_boxes
    from followbot.services.vision_verify.footage import _pixels, visible_fractions

    boxes = sim_boxes(sim)
    vis = visible_fractions(boxes, sim.camera.width, sim.camera.height)
    return [(b.id, _pixels(b), v) for b, v in zip(boxes, vis, strict=True)]


def sim_frames(scenario: str, follow_from_s: float = 10.0):
    """Frames of a built-in scenario with true person boxes; the robot stands still until
    ``follow_from_s``, then follows the target on ground truth (:func:`..vision_evaluate.
    follow_truth` at 2 m)."""
    from followbot.research.vision_evaluate import follow_truth
    from followbot.schemas import GroundTruth, Image
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation

    sim = Simulation(load_builtin(scenario))
    while not sim.finished:
        for m in sim.tick():
            if isinstance(m, Image):
                yield m.pixels().copy(), person_boxes(sim)
            elif isinstance(m, GroundTruth) and sim.t_s >= follow_from_s:
                follow_truth(sim, m, sim.target_id, 2.0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m followbot.research.camera_realism")
    ap.add_argument("--video", help="real footage (vtest.avi); omitted: simulator only")
    ap.add_argument("--boxes", help="its person boxes (pets09 CSV)")
    ap.add_argument("--scenario", default="lookalikes")
    ap.add_argument("--json", help="write the figures here")
    a = ap.parse_args(argv)
    out = {}
    if a.video:
        if not a.boxes:
            ap.error("--video needs --boxes")
        out["real"] = measure_frames(video_frames(a.video, a.boxes))
        print(json.dumps({"real": out["real"]}), flush=True)
    for key, start in (("sim_still", math.inf), ("sim_following", 0.0)):
        out[key] = measure_frames(sim_frames(a.scenario, follow_from_s=start))
        print(json.dumps({key: out[key]}), flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
