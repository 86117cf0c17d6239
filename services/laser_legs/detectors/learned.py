"""A learned leg classifier: random trees (OpenCV ``cv2.ml.RTrees``) on per-cluster shape
features — beyond the seeds (issue 4). In the spirit of Arras et al. (ICRA 2007) and the
leg_tracker project whose recordings we evaluate on.

1. Segments: consecutive valid beams whose points are closer than ``cluster_gap_m``
   (Euclidean, so the criterion means the same at any range), with ``min_points`` or more
   points and an end-to-end width up to ``max_width_m``.
2. Features of each segment (:data:`FEATURES`): point count, width, range, line-fit and
   circle-fit residuals, fitted radius, boundary length and regularity, inscribed-angle mean
   and spread, principal-axis ratio, mean distance to the centroid, and the range steps to the
   neighbouring beams on both sides (is the segment in front of its background?).
3. The forest's vote share for "leg" is the leg's confidence; legs above ``threshold`` are
   paired as in the thesis (500 mm, closest first) into persons.

The model file ships with the package (``services/laser_legs/models/``); it is produced by
``python -m followbot.services.laser_legs.train`` (reproducible: fixed seeds, documented data
split). ``model_path`` selects another file.
"""

from __future__ import annotations

import functools
import math
from importlib import resources
from pathlib import Path

import msgspec
import numpy as np

from followbot.schemas import LaserScan, Leg, PersonCandidates

from ..core import Prediction, candidates_message, pair_legs, person, valid_mask

__all__ = [
    "FEATURES",
    "LearnedSettings",
    "RandomTreesLegDetector",
    "default_model_path",
    "segment_features",
    "segments",
]

FEATURES = (
    "n_points",
    "width_m",
    "range_m",
    "line_residual_m",
    "circle_residual_m",
    "circle_radius_m",
    "boundary_length_m",
    "boundary_regularity_m",
    "inscribed_mean_rad",
    "inscribed_std_rad",
    "axis_ratio",
    "spread_m",
    "step_before_m",
    "step_after_m",
)

#: Range steps to the neighbours are capped here (a beam without return counts as far).
_STEP_CAP_M = 2.0

MODEL_FILE = "learned_rtrees.yml.gz"


def default_model_path() -> Path:
    return Path(str(resources.files("followbot.services.laser_legs") / "models" / MODEL_FILE))


class LearnedSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of :class:`RandomTreesLegDetector`."""

    model_path: str = ""  # "" = the model shipped with the package
    threshold: float = 0.65  # vote share for "leg": chosen by train.py (validation split)
    cluster_gap_m: float = 0.13  # not in the seeds (leg_tracker's cluster distance)
    min_points: int = 3
    max_width_m: float = 0.6
    pair_distance_m: float = 0.500  # thesis 4.3.3
    gate_m: float = 0.400  # thesis 4.3.2 criterion 3, when a prediction is given

    def __post_init__(self) -> None:
        if not 0.0 <= self.threshold <= 1.0:
            raise ValueError("threshold must be in [0, 1]")
        if self.min_points < 3:
            raise ValueError("min_points must be >= 3")
        for name in ("cluster_gap_m", "max_width_m", "gate_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")


def segments(
    scan: LaserScan, cluster_gap_m: float = 0.13, min_points: int = 3, max_width_m: float = 0.6
):
    """Segments of one scan: (starts, ends, x, y, r, valid) with inclusive beam spans."""
    raw = scan.ranges_m().astype(np.float64)
    n = raw.shape[0]
    valid = valid_mask(raw, scan.range_min_m, scan.range_max_m)
    ang = scan.angles_rad()
    r = np.where(valid, raw, 0.0)
    x, y = r * np.cos(ang), r * np.sin(ang)
    gap = np.hypot(np.diff(x), np.diff(y))
    # a cut before beam k when beam k or k-1 has no return or the points are far apart
    cut = np.ones(n + 1, dtype=bool)
    cut[1:n] = (gap >= cluster_gap_m) | ~valid[1:] | ~valid[:-1]
    bounds = np.flatnonzero(cut)
    starts, ends = bounds[:-1], bounds[1:] - 1
    keep = valid[starts] & (ends - starts + 1 >= min_points)
    starts, ends = starts[keep], ends[keep]
    w = np.hypot(x[ends] - x[starts], y[ends] - y[starts])
    keep = w <= max_width_m
    return starts[keep], ends[keep], x, y, r, valid


def _step(r: np.ndarray, valid: np.ndarray, k: int, ref: float) -> float:
    """Range of beam k minus ``ref`` (positive: the neighbour is behind), capped."""
    if k < 0 or k >= r.shape[0] or not valid[k]:
        return _STEP_CAP_M
    return float(min(max(r[k] - ref, -_STEP_CAP_M), _STEP_CAP_M))


def segment_features(starts, ends, x, y, r, valid) -> np.ndarray:
    """(k, len(FEATURES)) float32 features of the segments."""
    out = np.empty((len(starts), len(FEATURES)), dtype=np.float32)
    for i, (a, b) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        px, py = x[a : b + 1], y[a : b + 1]
        n = b - a + 1
        cx, cy = px.mean(), py.mean()
        dx, dy = px - cx, py - cy
        width = math.hypot(px[-1] - px[0], py[-1] - py[0])
        # principal axes: line-fit residual is the minor axis' spread
        sxx, syy, sxy = (dx * dx).mean(), (dy * dy).mean(), (dx * dy).mean()
        tr, det = sxx + syy, sxx * syy - sxy * sxy
        disc = math.sqrt(max(tr * tr / 4 - det, 0.0))
        lam1, lam2 = tr / 2 + disc, max(tr / 2 - disc, 0.0)
        line_res = math.sqrt(lam2)
        axis_ratio = math.sqrt(lam2 / lam1) if lam1 > 1e-12 else 0.0
        # algebraic circle fit (Kasa): x^2 + y^2 + D x + E y + F = 0, on centred points
        A = np.column_stack([dx, dy, np.ones(n)])
        rhs = -(dx * dx + dy * dy)
        sol, *_ = np.linalg.lstsq(A, rhs, rcond=None)
        ccx, ccy = -sol[0] / 2, -sol[1] / 2
        rad2 = ccx * ccx + ccy * ccy - sol[2]
        rad = math.sqrt(rad2) if rad2 > 0 else 0.0
        rad = min(rad, 1.0)
        circ_res = float(np.sqrt(np.mean((np.hypot(dx - ccx, dy - ccy) - rad) ** 2)))
        steps = np.hypot(np.diff(px), np.diff(py))
        # inscribed angles at interior points towards the end points
        if n >= 3:
            ax, ay = px[0] - px[1:-1], py[0] - py[1:-1]
            bx, by = px[-1] - px[1:-1], py[-1] - py[1:-1]
            ang = np.abs(np.arctan2(ax * by - ay * bx, ax * bx + ay * by))
            ia_mean, ia_std = float(ang.mean()), float(ang.std())
        else:
            ia_mean, ia_std = math.pi, 0.0
        rng = math.hypot(cx, cy)
        out[i] = (
            n,
            width,
            rng,
            line_res,
            min(circ_res, 1.0),
            rad,
            float(steps.sum()),
            float(steps.std()),
            ia_mean,
            ia_std,
            axis_ratio,
            float(np.hypot(dx, dy).mean()),
            _step(r, valid, a - 1, float(r[a])),
            _step(r, valid, b + 1, float(r[b])),
        )
    return out


class RandomTreesLegDetector:
    """Random-trees classifier on segment features; legs paired into persons."""

    name = "learned"
    settings_type = LearnedSettings

    def __init__(self, settings: LearnedSettings | None = None, model=None) -> None:
        self.settings = settings or LearnedSettings()
        self._model = model
        self._path = Path(self.settings.model_path) if self.settings.model_path else None

    @property
    def model(self):
        """The cv2.ml.RTrees model, loaded on first use (cv2 is imported lazily)."""
        if self._model is None:
            self._model = load_model(self._path or default_model_path())
        return self._model

    def leg_scores(self, features: np.ndarray) -> np.ndarray:
        """Vote share for "leg" of each row of ``features``."""
        if features.shape[0] == 0:
            return np.zeros(0)
        return vote_share(self.model, features)

    def detect(self, scan: LaserScan, prediction: Prediction = None) -> PersonCandidates:
        s = self.settings
        starts, ends, x, y, r, valid = segments(scan, s.cluster_gap_m, s.min_points, s.max_width_m)
        if starts.shape[0] == 0:
            return candidates_message(scan, self.name, [])
        feats = segment_features(starts, ends, x, y, r, valid)
        score = self.leg_scores(feats)
        keep = np.flatnonzero(score >= s.threshold)
        legs: list[Leg] = []
        conf: list[float] = []
        for i in keep.tolist():
            a, b = int(starts[i]), int(ends[i])
            lx, ly = float(x[a : b + 1].mean()), float(y[a : b + 1].mean())
            if prediction is not None:
                px, py = float(prediction[0]), float(prediction[1])
                if (
                    math.isfinite(px)
                    and math.isfinite(py)
                    and math.hypot(lx - px, ly - py) >= (s.gate_m)
                ):
                    continue
            legs.append(Leg(x_m=lx, y_m=ly, first_beam=a, last_beam=b, width_m=float(feats[i, 1])))
            conf.append(float(score[i]))
        groups = pair_legs([g.x_m for g in legs], [g.y_m for g in legs], s.pair_distance_m)
        out = [
            person(
                [legs[i] for i in g],
                "two_legs" if len(g) == 2 else "one_leg",
                min(1.0, max(conf[i] for i in g)),
            )
            for g in groups
        ]
        return candidates_message(scan, self.name, out)


# --------------------------------------------------------------------------- model file


@functools.lru_cache(maxsize=4)
def load_model(path: Path):
    """Load an RTrees model (cached per path; the model is only read, never trained further);
    ``.gz`` files are decompressed to a temporary file first."""
    import gzip
    import tempfile

    import cv2

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"no learned leg model at {path}; train one with "
            "`python -m followbot.services.laser_legs.train`"
        )
    if path.suffix == ".gz":
        with tempfile.TemporaryDirectory() as tmp:
            plain = Path(tmp) / path.stem
            plain.write_bytes(gzip.decompress(path.read_bytes()))
            return cv2.ml.RTrees_load(str(plain))
    return cv2.ml.RTrees_load(str(path))


def save_model(model, path: Path) -> None:
    import gzip
    import tempfile

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gz":
        with tempfile.TemporaryDirectory() as tmp:
            plain = Path(tmp) / path.stem
            model.save(str(plain))
            # mtime=0: the same model gives the same bytes
            path.write_bytes(gzip.compress(plain.read_bytes(), mtime=0))
    else:
        model.save(str(path))


def vote_share(model, features: np.ndarray) -> np.ndarray:
    """Share of the trees voting for class 1 ("leg")."""
    votes = model.getVotes(np.ascontiguousarray(features, dtype=np.float32), 0)
    # row 0 holds the class labels, the next rows the votes per sample
    labels = votes[0]
    counts = votes[1:].astype(np.float64)
    total = counts.sum(axis=1)
    pos = counts[:, labels == 1].sum(axis=1) if (labels == 1).any() else np.zeros(len(counts))
    return np.where(total > 0, pos / np.maximum(total, 1), 0.0)
