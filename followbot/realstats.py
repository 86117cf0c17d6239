"""Laser statistics that tell real scans from simulated ones: ``followbot realstats``.

Each figure is a function of scans (and, for legs, of leg positions in the scan's frame), so
the same code measures the real recordings and the simulator's output (docs/realism.md):

* **returns per leg** against range: valid beams whose point lies within
  :data:`LEG_WINDOW_M` of a labelled leg, and that count over the beams a leg of radius
  :data:`LEG_RADIUS_M` spans at that range and the scan's resolution (``expected``);
* **dropouts**: the share of labelled legs with fewer than half the expected returns;
* **one leg seen, the other missing**: labels paired into people (closer than
  :data:`PAIR_M`, nearest first); the share of people with a single labelled leg;
* **duplicated beams**: the share of a leg's beams whose range equals the previous beam's;
* **leg edges**: for a leg with background at least :data:`EDGE_BACKGROUND_M` behind it, the
  beam just outside the leg on each side is a *mixed pixel* (a range between leg and
  background, at least :data:`EDGE_GAP_M` from each) or *invalid* (no return), else clean;
* **range noise** against range: the robust per-beam spread over time on a still scanner,
  in stretches of :data:`NOISE_WINDOW` scans (1.4826 x the median absolute deviation from
  the beam's median; a beam counts when 90 % of the stretch reads within
  :data:`STATIC_BAND_M` of its median, so passers-by and a moving robot are left out);
* **invalid beams**: their share in all beams, the share of beams on a continuous surface
  (the beams two either side valid and within :data:`SURFACE_STEP_M` of each other) that
  read invalid, the mean length of a run of invalid beams, and the largest valid range
  (99.9th percentile);
* **false person candidates** per scan of a detector on scans with nobody in them, and the
  share of scans with any.

Leg labels of the real data are hand-labelled leg clusters, so a leg that returned nothing is
never labelled: these figures describe the legs that were seen. The simulator's labels are
chosen the same way (legs with at least one return within the window).
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

import msgspec
import numpy as np

from followbot.schemas import LaserScan

__all__ = [
    "RANGE_BINS_M",
    "EdgeFigures",
    "LegFigures",
    "NoiseFigures",
    "RealFigures",
    "ScanFigures",
    "false_candidates",
    "leg_figures",
    "main",
    "measure_real",
    "noise_figures",
    "scan_figures",
    "valid_mask",
]

log = logging.getLogger(__name__)

#: Range bins (m) for the figures against range: [0.5, 1), [1, 2), [2, 3), [3, 5).
RANGE_BINS_M = (0.5, 1.0, 2.0, 3.0, 5.0)
#: A beam belongs to a labelled leg when its point lies this close to the label.
LEG_WINDOW_M = 0.10
#: The leg radius for the beams a leg is expected to span (a 12 cm wide leg).
LEG_RADIUS_M = 0.06
#: Labels closer than this are two legs of one person (DESIGN.md, thesis 4.3.3: 500 mm).
PAIR_M = 0.5
#: A leg edge counts only with background at least this far behind the leg.
EDGE_BACKGROUND_M = 0.3
#: A mixed pixel lies at least this far from both the leg and the background.
EDGE_GAP_M = 0.05
#: Range changes beyond this over time are someone passing, not noise.
STATIC_BAND_M = 0.10
#: Scans per stretch measured for range noise.
NOISE_WINDOW = 50
#: Beams two apart on one continuous surface differ by less than this.
SURFACE_STEP_M = 0.10


def valid_mask(scan: LaserScan) -> tuple[np.ndarray, np.ndarray]:
    """(ranges as float64, mask of beams with a return) by the LaserScan rules."""
    r = scan.ranges_m().astype(np.float64)
    ok = np.isfinite(r) & (r > 0) & (r >= scan.range_min_m) & (r <= scan.range_max_m)
    return r, ok


def _bin_of(range_m: float) -> int:
    """Index into RANGE_BINS_M's bins, -1 outside them."""
    i = int(np.searchsorted(RANGE_BINS_M, range_m, side="right")) - 1
    return i if 0 <= i < len(RANGE_BINS_M) - 1 else -1


def _bin_names() -> list[str]:
    return [f"{a:g}-{b:g} m" for a, b in itertools.pairwise(RANGE_BINS_M)]


class EdgeFigures(msgspec.Struct, kw_only=True):
    sides: int = 0
    """Leg sides with background behind them."""
    mixed: int = 0
    invalid: int = 0

    @property
    def mixed_share(self) -> float:
        return self.mixed / self.sides if self.sides else math.nan

    @property
    def invalid_share(self) -> float:
        return self.invalid / self.sides if self.sides else math.nan


class LegFigures(msgspec.Struct, kw_only=True):
    bins: list[str] = msgspec.field(default_factory=_bin_names)
    legs: list[int] = []
    """Labelled legs per range bin."""
    returns_per_leg: list[float] = []
    returns_over_expected: list[float] = []
    dropout_share: list[float] = []
    """Per bin: legs with fewer than half the expected returns."""
    dropout_share_all: float = math.nan
    one_leg_share: float = math.nan
    """People (labels paired within PAIR_M) with one labelled leg."""
    duplicate_share: float = math.nan
    """A leg's beams equal to the previous beam's range."""
    edges: EdgeFigures = msgspec.field(default_factory=EdgeFigures)


def _leg_beams(r, ok, x, y, lx, ly):
    """Indices of valid beams within LEG_WINDOW_M of (lx, ly)."""
    d = np.hypot(x - lx, y - ly)
    return np.flatnonzero(ok & (d < LEG_WINDOW_M))


def _edge(r, ok, idx, step) -> str | None:
    """'mixed' | 'invalid' | 'clean' for the beam past a leg's end ``idx`` in direction
    ``step``, None when there is no background well behind the leg there."""
    n = r.shape[0]
    e = idx + step
    if not 0 <= e < n:
        return None
    leg_r = r[idx]
    # background: the first valid beam beyond the edge beam, within three beams
    bg = None
    for k in range(1, 4):
        j = e + k * step
        if 0 <= j < n and ok[j]:
            bg = r[j]
            break
    if bg is None or bg < leg_r + EDGE_BACKGROUND_M:
        return None
    if not ok[e]:
        return "invalid"
    if leg_r + EDGE_GAP_M < r[e] < bg - EDGE_GAP_M:
        return "mixed"
    return "clean"


def _pair_count(legs_xy: np.ndarray) -> tuple[int, int]:
    """(people, people with one leg): labels paired nearest first within PAIR_M."""
    n = legs_xy.shape[0]
    if n == 0:
        return 0, 0
    d = np.hypot(*(legs_xy[:, None, :] - legs_xy[None, :, :]).transpose(2, 0, 1))
    iu = np.triu_indices(n, 1)
    order = np.argsort(d[iu])
    used = np.zeros(n, bool)
    pairs = 0
    for k in order:
        i, j = iu[0][k], iu[1][k]
        if d[i, j] >= PAIR_M:
            break
        if not used[i] and not used[j]:
            used[i] = used[j] = True
            pairs += 1
    singles = int((~used).sum())
    return pairs + singles, singles


def leg_figures(items: Iterable[tuple[LaserScan, np.ndarray]]) -> LegFigures:
    """Leg figures of scans with labelled legs ((k, 2) positions in the scan's frame)."""
    nb = len(RANGE_BINS_M) - 1
    legs = np.zeros(nb, int)
    ret = np.zeros(nb)
    ratio = np.zeros(nb)
    drop = np.zeros(nb, int)
    people = singles = 0
    dup = dup_n = 0
    edges = EdgeFigures()
    for scan, labels in items:
        r, ok = valid_mask(scan)
        a = scan.angles_rad()
        x = np.where(ok, r * np.cos(a), np.nan)
        y = np.where(ok, r * np.sin(a), np.nan)
        inc = abs(scan.angle_increment_rad)
        p, s = _pair_count(labels)
        people += p
        singles += s
        for lx, ly in labels:
            rho = math.hypot(lx, ly)
            b = _bin_of(rho)
            beams = _leg_beams(r, ok, x, y, lx, ly)
            expected = 2.0 * math.asin(min(LEG_RADIUS_M / rho, 1.0)) / inc
            if b >= 0:
                legs[b] += 1
                ret[b] += beams.size
                ratio[b] += beams.size / max(expected, 1.0)
                drop[b] += beams.size < 0.5 * expected
            if beams.size >= 2:
                lo, hi = beams.min(), beams.max()
                seg = r[lo : hi + 1]
                both = ok[lo + 1 : hi + 1] & ok[lo:hi]
                dup += int(((seg[1:] == seg[:-1]) & both).sum())
                dup_n += int(both.sum())
            if beams.size:
                for idx, step in ((beams.min(), -1), (beams.max(), 1)):
                    kind = _edge(r, ok, int(idx), step)
                    if kind is None:
                        continue
                    edges.sides += 1
                    edges.mixed += kind == "mixed"
                    edges.invalid += kind == "invalid"
    with np.errstate(invalid="ignore", divide="ignore"):
        return LegFigures(
            legs=legs.tolist(),
            returns_per_leg=_nan_list(ret / legs),
            returns_over_expected=_nan_list(ratio / legs),
            dropout_share=_nan_list(drop / legs),
            dropout_share_all=float(drop.sum() / legs.sum()) if legs.sum() else math.nan,
            one_leg_share=singles / people if people else math.nan,
            duplicate_share=dup / dup_n if dup_n else math.nan,
            edges=edges,
        )


def _nan_list(a: np.ndarray) -> list[float]:
    return [float(v) for v in a]


class NoiseFigures(msgspec.Struct, kw_only=True):
    bins: list[str] = msgspec.field(default_factory=_bin_names)
    beams: list[int] = []
    """Static beams per range bin."""
    std_m: list[float] = []
    """Median over the bin's beams of each beam's robust spread over time."""


def noise_figures(scans: Sequence[LaserScan], window: int = NOISE_WINDOW) -> NoiseFigures:
    """Range noise against range from the still stretches of ``scans`` (see the module doc):
    each run of ``window`` scans is measured on its own, so a robot that stands still only
    at times still gives figures, and a moving one gives few static beams."""
    stds: list[np.ndarray] = []
    meds: list[np.ndarray] = []
    for start in range(0, max(len(scans) - window + 1, 0), window):
        part = scans[start : start + window]
        if len({s.ranges.shape[0] for s in part}) != 1:
            continue
        rs, oks = zip(*(valid_mask(s) for s in part), strict=True)
        R = np.where(np.stack(oks), np.stack(rs), np.nan)
        seen = np.isfinite(R).sum(axis=0) >= 0.5 * window
        if not seen.any():
            continue
        R = R[:, seen]
        med = np.nanmedian(R, axis=0)  # every column has valid readings (seen)
        dev = R - med
        near = np.abs(dev) < STATIC_BAND_M
        # a static beam: most scans of the window read within the band of its median
        static = near.sum(axis=0) >= 0.9 * window
        if not static.any():
            continue
        dev = np.where(near, dev, np.nan)[:, static]  # static columns: 90 % within the band
        mad = np.nanmedian(np.abs(dev - np.nanmedian(dev, axis=0)), axis=0)
        stds.append(1.4826 * mad)
        meds.append(med[static])
    std = np.concatenate(stds) if stds else np.zeros(0)
    med = np.concatenate(meds) if meds else np.zeros(0)
    beams, out = [], []
    for b in range(len(RANGE_BINS_M) - 1):
        m = (med >= RANGE_BINS_M[b]) & (med < RANGE_BINS_M[b + 1])
        beams.append(int(m.sum()))
        out.append(float(np.median(std[m])) if m.any() else math.nan)
    return NoiseFigures(beams=beams, std_m=out)


class ScanFigures(msgspec.Struct, kw_only=True):
    scans: int = 0
    invalid_share: float = math.nan
    """Beams with no return, of all beams."""
    surface_invalid_share: float = math.nan
    """Beams on a continuous surface that read invalid."""
    invalid_run_beams: float = math.nan
    """Mean length of a run of invalid beams."""
    neighbour_equal_share: float = math.nan
    """Valid beams whose range equals the previous beam's (duplicated beams)."""
    max_valid_range_m: float = math.nan
    """99.9th percentile of the valid ranges."""


def scan_figures(scans: Iterable[LaserScan]) -> ScanFigures:
    n = inv = surf = surf_inv = runs = eq = eq_n = 0
    valid: list[np.ndarray] = []
    count = 0
    for scan in scans:
        count += 1
        r, ok = valid_mask(scan)
        n += r.size
        inv += int((~ok).sum())
        # runs of invalid beams: starts where an invalid beam follows a valid one (or beam 0)
        bad = ~ok
        runs += int(bad[0]) + int((bad[1:] & ~bad[:-1]).sum())
        if r.size >= 5:
            a, b = r[:-4], r[4:]
            with np.errstate(invalid="ignore"):  # inf - inf beyond range: not a surface
                cont = ok[:-4] & ok[4:] & (np.abs(a - b) < SURFACE_STEP_M)
            mid = ok[2:-2]
            surf += int(cont.sum())
            surf_inv += int((cont & ~mid).sum())
        both = ok[1:] & ok[:-1]
        eq += int(((r[1:] == r[:-1]) & both).sum())
        eq_n += int(both.sum())
        valid.append(r[ok][::4])
    allv = np.concatenate(valid) if valid else np.zeros(0)
    return ScanFigures(
        scans=count,
        invalid_share=inv / n if n else math.nan,
        surface_invalid_share=surf_inv / surf if surf else math.nan,
        invalid_run_beams=inv / runs if runs else math.nan,
        neighbour_equal_share=eq / eq_n if eq_n else math.nan,
        max_valid_range_m=float(np.percentile(allv, 99.9)) if allv.size else math.nan,
    )


class CandidateFigures(msgspec.Struct, kw_only=True):
    scans: int = 0
    candidates: int = 0
    scans_with_any: int = 0

    @property
    def per_scan(self) -> float:
        return self.candidates / self.scans if self.scans else math.nan

    @property
    def any_share(self) -> float:
        return self.scans_with_any / self.scans if self.scans else math.nan

    def add(self, other: CandidateFigures) -> None:
        self.scans += other.scans
        self.candidates += other.candidates
        self.scans_with_any += other.scans_with_any


def default_detector():
    """The detector ``followbot run laser_legs`` builds with its default settings."""
    from followbot.services.laser_legs.node import LaserLegsSettings, build_detector

    return build_detector(LaserLegsSettings())


def false_candidates(
    scans: Iterable[LaserScan], detector=None, *, exclude=None
) -> CandidateFigures:
    """Person candidates per scan of ``detector`` (default: the node's) on scans where every
    candidate is false; ``exclude(i, xy)`` may drop candidates at real people (simulator)."""
    detector = detector if detector is not None else default_detector()
    reset = getattr(detector, "reset", None)
    if callable(reset):
        reset()
    out = CandidateFigures()
    for i, scan in enumerate(scans):
        cands = detector.detect(scan).candidates
        if exclude is not None:
            cands = [c for c in cands if not exclude(i, (c.x_m, c.y_m))]
        out.scans += 1
        out.candidates += len(cands)
        out.scans_with_any += bool(cands)
    return out


# ---------------------------------------------------------------------------- real data

#: CARMEN logs of ../shared/data/carmen measured (people are rare in them).
CARMEN_LOGS = (
    "aces", "belgioioso", "csail", "edmonton", "fhw", "freiburg-101", "orebro", "seattle",
)  # fmt: skip


class RealFigures(msgspec.Struct, kw_only=True):
    """Every figure measured on the real recordings (what ``--json`` writes)."""

    legs: LegFigures
    """leg_tracker positive_*_extracted.bag (every positive)."""
    noise: NoiseFigures
    """demo_stationary_simple_environment.bag and negative_2.bag, still stretches."""
    scans: ScanFigures
    """negative_2.bag, the three lasers (the scanner of the positives)."""
    false_negative_2: dict[str, float]
    """per_scan and any_share of the default detector on negative_2."""
    false_carmen: dict[str, dict[str, float]]
    """Per CARMEN log, and "all"."""


def _carmen_scans(path: Path) -> list[LaserScan]:
    from followbot.bags import open_recording

    rec = open_recording(path)
    return [m for _, topic, m in rec.messages() if topic == "sensors/scan"]


def _cand_dict(c: CandidateFigures) -> dict[str, float]:
    return {"scans": c.scans, "per_scan": c.per_scan, "any_share": c.any_share}


def measure_real(data: Path, *, carmen: bool = True) -> RealFigures:
    """Measure every figure on the recordings under ``data`` (../shared/data layout)."""
    from followbot.bags import open_recording
    from followbot.research.realdata import (
        NEGATIVE_TOPICS,
        POSITIVES,
        read_negative,
        read_positive,
    )

    legs_dir = data / "leg_tracker"
    items = [(it.scan, it.legs_xy) for n in POSITIVES for it in read_positive(n, legs_dir)]
    log.info("legs: %d labelled scans", len(items))
    legs = leg_figures(items)
    rec = open_recording(legs_dir / "demo_stationary_simple_environment.bag")
    still = [m for _, _, m in rec.messages() if isinstance(m, LaserScan)]
    negatives = [s for t in NEGATIVE_TOPICS for s in read_negative(t, legs_dir)]
    noise = _pooled_noise([still, *(read_negative(t, legs_dir) for t in NEGATIVE_TOPICS)])
    scans = scan_figures(negatives)
    neg = CandidateFigures()
    for t in NEGATIVE_TOPICS:  # each laser is its own stream to the detector
        neg.add(false_candidates(read_negative(t, legs_dir)))
    per_log: dict[str, dict[str, float]] = {}
    if carmen:
        total = CandidateFigures()
        for name in CARMEN_LOGS:
            path = data / "carmen" / f"{name}-corrected.log.gz"
            if not path.exists():
                continue
            c = false_candidates(_carmen_scans(path))
            total.add(c)
            per_log[name] = _cand_dict(c)
            log.info("carmen %s: %.2f false candidates per scan", name, c.per_scan)
        per_log["all"] = _cand_dict(total)
    return RealFigures(
        legs=legs, noise=noise, scans=scans, false_negative_2=_cand_dict(neg), false_carmen=per_log
    )


def _pooled_noise(streams: list[Sequence[LaserScan]]) -> NoiseFigures:
    """Noise figures of several scanners' streams at once (each stream measured alone)."""
    big = [s for stream in streams for s in stream[: len(stream) // NOISE_WINDOW * NOISE_WINDOW]]
    return noise_figures(big)


def default_data_dir() -> Path:
    """<repo>/../shared/data (the folder the team's recordings are in)."""
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="followbot realstats",
        description=(
            "Measure the laser statistics that tell real scans from simulated ones (returns "
            "per leg against range, leg dropouts, one leg missing, duplicated beams, mixed "
            "pixels at leg edges, range noise against range, invalid beams, false person "
            "candidates of the default detector) on the real recordings, and with --sim the "
            "same figures on the simulator's measured laser model, side by side. "
            "Definitions: docs/realism.md."
        ),
    )
    p.add_argument(
        "--data",
        type=Path,
        default=default_data_dir(),
        help="folder holding leg_tracker/ and carmen/ (default: ../shared/data)",
    )
    p.add_argument("--json", type=Path, metavar="FILE", help="write the real figures as JSON")
    p.add_argument("--no-carmen", action="store_true", help="skip the CARMEN logs (faster)")
    p.add_argument(
        "--sim",
        action="store_true",
        help="also measure the simulator (followbot/research/realism.py), side by side",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if not (args.data / "leg_tracker").is_dir():
        print(f"followbot realstats: {args.data}/leg_tracker not found (give --data)",
              file=sys.stderr)  # fmt: skip
        return 2
    real = measure_real(args.data, carmen=not args.no_carmen)
    if args.json is not None:
        args.json.write_bytes(msgspec.json.format(msgspec.json.encode(real), indent=2) + b"\n")
    if args.sim:
        from followbot.research.realism import compare, measure_sim

        sim = measure_sim()
        print(compare(real, sim))
    else:
        print(json.dumps(msgspec.to_builtins(real), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
