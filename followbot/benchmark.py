"""``followbot benchmark``: the real-data suite, one report over a data folder.

    followbot benchmark                                  # ../shared/data, the defaults
    followbot benchmark --all-presets --output out/bench-all
    followbot benchmark --only detectors legs360 --quick

Reads the recordings of DATA_DIR (default: $FOLLOWBOT_DATA, else ../shared/data beside the
repository; see each folder's README) and writes DIR/benchmark.md, DIR/benchmark.json and PNG
plots. Each recording goes through the pipeline a user gets -- laser_legs and tracker as
processes over Zenoh in lock-step with the recording, exactly as ``followbot track`` runs
them, with the chosen preset and no camera (the target is then the nearest person ahead:
tracker ``acquire: nearest``, at most identity.acquire_range_m away and
identity.acquire_bearing_deg either side of straight ahead, at the first scan with such a
candidate). A section whose data is missing is skipped with the reason, in the report and on
stderr.

Sections (``--only`` picks some):

  detectors     leg_tracker/: every registered leg detector, behind the robot-body filter as
                the laser_legs service builds it, on the held-out split (positive_6 and
                positive_7; negative_2's /rear_scan and /right_scan, nobody in them).
                leg recall: share of hand-labelled legs with a detected leg within 0.15 m;
                recall <= 3.5 m: the same for labelled legs within 3.5 m of the laser;
                false candidates/scan: person candidates per negative scan (all false);
                false legs/scan: the legs of those candidates; us/scan: median detection time.
                Not preset-dependent: run once.
  false_people  carmen/*.log.gz and negative_2 (held-out topics, each its own run): what the
                tracker publishes on tracking/people (confirmed person tracks, and the
                target). Nobody walks in these recordings (carmen's README: treat every person
                reported as false), so every person published is false.
                false people/scan: tracks published per scan; scans with a false person: the
                share of scans where at least one was published; most at once; person ids.
  legs360       legs360/: one person walking round a 360 deg scanner, legs labelled per scan
                (the person is the midpoint of the labelled legs). Over the labelled scans:
                walker tracked: share with a published track within 0.5 m of the person;
                walker followed: share with the target (tracking/target, tracking or
                coasting) within 0.5 m of the person; ghosts/scan: every other published
                track (the nearest track within 0.5 m is the walker's); scans with a ghost.
  appearance    pets09/ with opencv-doc's vtest.avi (``make opencv-data``; --video): the
                preset's verifier on frames 0-399, both protocols of ``followbot appearance``
                (one view, following) at lags 25 and 100 frames, with its defaults. rank-1:
                the person picked among everyone in the later frame; target rejected: the
                person's distance fails the threshold; someone accepted, target removed:
                another box passes it. Skipped when the video is absent.
  demo          leg_tracker/demo_stationary_simple_environment.bag: a still robot with people
                walking round it (no labels). new person ids/min: distinct track ids
                published, per minute of recording (one person lost and found again counts
                twice: the churn a user sees); target: when it was first chosen (above),
                the share of scans it is tracked from then on, how often it was lost (status
                lost) and how often taken back (tracked again after a loss; by the laser near
                where it was lost, so possibly by another track id: the ids are counted), and
                how many of those re-takes were by a track already published before the loss
                (someone who was elsewhere when the target vanished: most likely another
                person; no labels needed).

Every pipeline run also gives its throughput (throughput section): scans per second from the
first scan sent to the last answered (reading the file included, start-up not), and the
recording's own duration over that time (x real time). A recording without odometry (the
leg_tracker bags, legs360) runs with the laser_odometry stage first, which estimates it from
the scans (``--laser-odometry auto``; ``off`` runs them without odometry, ``on`` replaces
the CARMEN logs' odometry too). Lock-step runs are deterministic, so
every figure but the throughput repeats exactly on the same code and data.

``--quick`` runs a small slice (positive_6; the first 100 scans of each held-out negative_2
topic for the detectors, the first 200 of /rear_scan for false people; the first 200 scans
of the first CARMEN log; all of legs360; frames 0-149 of pets09; the first 300 scans of the
demo): tests/test_benchmark.py runs it in ``make test`` against floors and ceilings.
docs/benchmark.md explains the figures and holds today's table for every preset.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import itertools
import json
import math
import os
import subprocess
import sys
import time
import traceback
import typing
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import msgspec

from followbot import progress
from followbot.presetargs import add_preset_arguments

__all__ = [
    "LogRun",
    "churn_figures",
    "false_people_figures",
    "main",
    "preset_names",
    "read_walker",
    "walker_figures",
]

#: Sections in the order they run and appear, with one line of what each measures.
SECTIONS = {
    "detectors": "leg recall and false person candidates per scan, every detector",
    "false_people": "false people per scan, CARMEN logs and negative_2",
    "legs360": "the walker tracked in every scan, and no ghosts",
    "appearance": "the verifier on pets09 frames 0-399",
    "demo": "track id churn and target losses on demo_stationary",
}
STAGES = ["laser_legs", "tracker"]
#: legs360: a published track within this distance of the walker is the walker (m).
WALKER_RADIUS_M = 0.5
APPEARANCE_LAGS = (25, 100)
APPEARANCE_FRAMES = (0, 400)
DEMO_BAG = "demo_stationary_simple_environment.bag"
PETS09_BOXES = "S2L1_frames_000-399.csv"
CARMEN_GLOBS = ("*.log", "*.log.gz", "*.clf", "*.clf.gz")
#: The slice ``--quick`` runs.
QUICK = {
    "positives": 1,
    "detector_negative_scans": 100,
    "negative_scans": 200,
    "negative_topics": 1,
    "carmen_logs": 1,
    "carmen_scans": 200,
    "appearance_frames": (0, 150),
    "demo_scans": 300,
}
#: Where opencv-doc's examples/data may be (`make opencv-data` unpacks it into the first).
_CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "followbot"
VIDEO_DIRS = (
    _CACHE / "opencv-doc/usr/share/doc/opencv-doc/examples/data",
    Path("/usr/share/doc/opencv-doc/examples/data"),
)
HAS_TARGET = ("tracking", "coasting")
#: How long a scan waits for the stages' answers (s): generous, for a loaded machine; a scan
#: left unanswered goes on without the answer and is counted (stage_timeouts).
ANSWER_TIMEOUT_S = 10.0
#: A stage that leaves this many scans in a row unanswered is broken: the run of that
#: recording stops and is reported as skipped, with the end of the stage's log.
GIVE_UP_AFTER = 5


class BenchmarkError(RuntimeError):
    """A part of the benchmark that could not run; says why."""


def default_data_dir() -> Path:
    """$FOLLOWBOT_DATA, else ../shared/data beside the repository (the followbot package's
    parent folder)."""
    if env := os.environ.get("FOLLOWBOT_DATA"):
        return Path(env)
    return Path(__file__).resolve().parents[1].parent / "shared" / "data"


def preset_names() -> list[str]:
    """Every preset followbot knows by name: the runnable ones (compose PRESETS) first, then
    the ones a compose file may name but that do not run yet."""
    from followbot.services.runtime.compose import PRESETS, Compose

    hint = typing.get_type_hints(Compose)["preset"]
    named = [n for arg in typing.get_args(hint) for n in typing.get_args(arg)]
    return list(PRESETS) + [n for n in named if n not in PRESETS]


def find_video(given: str | None) -> Path | None:
    """vtest.avi: ``given``, else $FOLLOWBOT_OPENCV_DATA/vtest.avi, else opencv-doc's."""
    if given:
        return Path(given)
    dirs = [Path(d) for d in [os.environ.get("FOLLOWBOT_OPENCV_DATA", "")] if d] + list(VIDEO_DIRS)
    return next((d / "vtest.avi" for d in dirs if (d / "vtest.avi").is_file()), None)


# --------------------------------------------------------------------------- pipeline runs


@dataclass
class LogRun:
    """What the pipeline published for one recording, per scan stamp."""

    log: str
    scans: int = 0
    seconds: float = 0.0
    """From the first scan sent to the last answered."""
    stamps: list[int] = field(default_factory=list)
    """The scans sent, in order."""
    people: dict[int, list[tuple[int, float, float]]] = field(default_factory=dict)
    """Scan stamp -> the published tracks (id, x_m, y_m)."""
    targets: dict[int, tuple[str, int, float, float]] = field(default_factory=dict)
    """Scan stamp -> the target (status, track id, x_m, y_m)."""
    timeouts: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    """Records of the file not read, by reason."""
    laser_mount: str = ""
    """The laser's mount pose the stages were given, and where it came from."""
    odometry: str = ""
    """Where the tracker's odometry came from: recording, laser_odometry or none."""

    @property
    def span_s(self) -> float:
        """The recording time the scans cover (first to last stamp)."""
        return (self.stamps[-1] - self.stamps[0]) / 1e9 if len(self.stamps) > 1 else 0.0

    def throughput(self) -> dict:
        return {
            "scans": self.scans,
            "seconds": round(self.seconds, 2),
            "scans_per_s": _r(self.scans / self.seconds if self.seconds > 0 else None, 1),
            "recording_s": round(self.span_s, 1),
            "x_real_time": _r(self.span_s / self.seconds if self.seconds > 0 else None, 1),
            "stage_timeouts": self.timeouts,
            "laser_mount": self.laser_mount,
            "odometry": self.odometry,
        }


def track_log(
    path: Path,
    preset: str,
    overrides: list[str],
    out: Path,
    *,
    label: str,
    scan_topic: str | None = None,
    max_scans: int | None = None,
    laser_odometry: str = "auto",
) -> LogRun:
    """``path`` through laser_legs and tracker with ``preset``, as ``followbot track`` runs it
    (its default scan source and odometry, or ``scan_topic`` alone; laser_odometry first as
    ``--laser-odometry`` says); stage logs in ``out``."""
    from followbot.bags import RecordingError, open_recording
    from followbot.track import (
        PipelineError,
        laser_mount_of,
        open_with_defaults,
        run_pipeline,
        tracking_settings,
        use_laser_odometry,
        write_csv,
    )

    try:
        if scan_topic is None:
            rec = open_with_defaults(str(path), {})
        else:
            rec = open_recording(path, {scan_topic: "sensors/scan"})
            rec.mapping = {s: d for s, d in rec.mapping.items() if s == scan_topic}
    except (RecordingError, ValueError) as exc:
        raise BenchmarkError(str(exc)) from None
    odometry = "sensors/odom" in rec.mapping.values()
    laser = use_laser_odometry(laser_odometry, odometry)
    if laser:
        rec.mapping = {s: d for s, d in rec.mapping.items() if d != "sensors/odom"}
    settings = tracking_settings(
        preset, STAGES, False, overrides, odometry=odometry, laser_odometry=laser
    )
    if isinstance(settings, str):
        raise BenchmarkError(settings)
    stages = (["laser_odometry"] if laser else []) + STAGES
    # where the laser sits, found as `followbot track` finds it (a bag's tf, a CARMEN log's
    # ROBOTLASER records, else the base's origin)
    try:
        mount, source = laser_mount_of(rec, None, "base_link", None)
    except RecordingError as exc:
        raise BenchmarkError(str(exc)) from None
    if not mount.is_identity:
        for stage in settings.values():
            stage["laser_mount"] = msgspec.to_builtins(mount)
    run = LogRun(log=label, laser_mount=f"{mount.describe()} ({source})")
    run.odometry = "laser_odometry" if laser else ("recording" if odometry else "none")

    def on_people(m, _payload: bytes) -> None:
        run.people[m.stamp_ns] = [(t.id, t.x_m, t.y_m) for t in m.tracks]

    def on_target(m, _payload: bytes) -> None:
        run.targets[m.stamp_ns] = (m.status, m.track_id, m.x_m, m.y_m)

    try:
        done = run_pipeline(
            rec, stages, settings, out, max_scans=max_scans, on_people=on_people,
            on_target=on_target, label=label, timeout_s=ANSWER_TIMEOUT_S,
            give_up_after=GIVE_UP_AFTER,
        )  # fmt: skip
    except (PipelineError, RecordingError) as exc:
        raise BenchmarkError(str(exc)) from None
    run.scans, run.seconds, run.stamps = done.scans, done.seconds, done.scan_stamps
    run.timeouts = done.timeouts
    run.skipped = dict(rec.skipped)
    # what a user of `followbot track` would get, for a look at what was counted
    write_csv(
        out / "people.csv",
        [[s, i, x, y, 0.0, 0.0] for s in run.stamps for i, x, y in run.people.get(s, [])],
    )
    write_csv(
        out / "target.csv",
        [[s, t[1], t[2], t[3], 0.0, 0.0] for s in run.stamps
         if (t := run.targets.get(s)) and t[0] in HAS_TARGET],
    )  # fmt: skip
    return run


# --------------------------------------------------------------------------- figures


def _r(x: float | None, digits: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(x, digits)


def false_people_figures(runs: list[LogRun]) -> dict:
    """Over every scan of ``runs`` (every published person false)."""
    counts = [len(r.people.get(s, [])) for r in runs for s in r.stamps]
    n = len(counts)
    return {
        "scans": n,
        "false_people_per_scan": _r(sum(counts) / n if n else None),
        "scans_with_false_person": _r(sum(c > 0 for c in counts) / n if n else None),
        "most_at_once": max(counts, default=0),
        "person_ids": sum(
            len({i for s in r.stamps for i, *_ in r.people.get(s, [])}) for r in runs
        ),
        "scans_unanswered": sum(s not in r.people for r in runs for s in r.stamps),
    }


def read_walker(path: Path) -> dict[int, tuple[float, float]]:
    """legs360_labels.csv -> {scan stamp_ns: the walker (midpoint of the labelled legs, or the
    one leg)}. A malformed row raises BenchmarkError naming its line."""
    legs: dict[int, list[tuple[float, float]]] = {}
    with path.open(newline="") as f:
        rows = csv.DictReader(f)
        need = {"stamp_ns", "x_m", "y_m"}
        if not need <= set(rows.fieldnames or ()):
            raise BenchmarkError(f"{path}: expected the columns {sorted(need)}")
        for line, row in enumerate(rows, start=2):
            try:
                stamp, x, y = int(row["stamp_ns"]), float(row["x_m"]), float(row["y_m"])
            except (TypeError, ValueError):
                raise BenchmarkError(f"{path}: line {line}: not a label: {row}") from None
            legs.setdefault(stamp, []).append((x, y))
    return {
        s: (sum(x for x, _ in p) / len(p), sum(y for _, y in p) / len(p)) for s, p in legs.items()
    }


def walker_figures(
    run: LogRun, walker: dict[int, tuple[float, float]], radius_m: float = WALKER_RADIUS_M
) -> dict:
    """The walker tracked and followed, and ghosts, over the labelled scans of ``run``."""
    labelled = tracked = followed = ghosts = ghost_scans = 0
    for s in run.stamps:
        if s not in walker:
            continue
        wx, wy = walker[s]
        labelled += 1
        tracks = run.people.get(s, [])
        near = [t for t in tracks if math.hypot(t[1] - wx, t[2] - wy) <= radius_m]
        tracked += bool(near)
        extra = len(tracks) - bool(near)
        ghosts += extra
        ghost_scans += extra > 0
        t = run.targets.get(s)
        if t and t[0] in HAS_TARGET and math.hypot(t[2] - wx, t[3] - wy) <= radius_m:
            followed += 1
    n = labelled
    return {
        "labelled_scans": n,
        "unlabelled_scans": run.scans - n,
        "radius_m": radius_m,
        "walker_tracked": _r(tracked / n if n else None),
        "walker_followed": _r(followed / n if n else None),
        "ghosts_per_scan": _r(ghosts / n if n else None),
        "scans_with_ghost": _r(ghost_scans / n if n else None),
    }


def churn_figures(run: LogRun) -> dict:
    """New person ids per minute, and the target's first choice, losses and re-takes."""
    minutes = run.span_s / 60.0
    ids = {i for s in run.stamps for i, *_ in run.people.get(s, [])}
    per_scan = [len(run.people.get(s, [])) for s in run.stamps]
    first = None
    has = False
    losses = taken_back = by_older = 0
    lost_at = None
    lost_s: list[float] = []
    with_target = after = 0
    target_ids = set()
    seen: set[int] = set()  # every track id published so far
    seen_at_loss: set[int] = set()
    for s in run.stamps:
        t = run.targets.get(s)
        if t is None:  # no answer for this scan: nothing known, nothing changes
            seen.update(i for i, *_ in run.people.get(s, []))
            continue
        now = t[0] in HAS_TARGET
        if now:
            target_ids.add(t[1])
            if first is None:
                first = s
        if first is not None:
            after += 1
            with_target += now
        if has and not now:
            losses += 1
            lost_at = s
            seen_at_loss = set(seen)
        elif now and not has and lost_at is not None:
            taken_back += 1
            lost_s.append((s - lost_at) / 1e9)
            by_older += t[1] in seen_at_loss  # a track that was someone else's before the loss
        has = now
        seen.update(i for i, *_ in run.people.get(s, []))
    t0 = run.stamps[0] if run.stamps else 0
    return {
        "scans": run.scans,
        "minutes": _r(minutes),
        "person_ids": len(ids),
        "new_ids_per_min": _r(len(ids) / minutes if minutes > 0 else None, 1),
        "people_per_scan": _r(sum(per_scan) / len(per_scan) if per_scan else None, 2),
        "target_first_s": _r((first - t0) / 1e9 if first is not None else None, 1),
        "target_tracked_after_first": _r(with_target / after if after else None),
        "target_losses": losses,
        "target_taken_back": taken_back,
        "target_taken_back_by_older_track": by_older,
        "target_lost_at_end": bool(first is not None and not has),
        "target_ids": len(target_ids),
        "lost_s_median": _r(sorted(lost_s)[len(lost_s) // 2] if lost_s else None, 1),
        "scans_unanswered": sum(s not in run.targets for s in run.stamps),
    }


# --------------------------------------------------------------------------- sections


class Benchmark:
    """One run of the suite: what it ran, what it skipped and why, and the figures."""

    def __init__(self, args: argparse.Namespace, presets: list[str]) -> None:
        self.args = args
        self.data = Path(args.data_dir)
        self.out = Path(args.output)
        self.quick = args.quick
        self.presets = presets
        self.sections = args.only or list(SECTIONS)
        self.results: dict = {s: {} for s in SECTIONS}
        self.results["throughput"] = {}
        self.skipped: list[dict] = []
        self.runs: dict[str, dict[str, LogRun]] = {p: {} for p in presets}
        self.section_s: dict[str, float] = {}

    def skip(self, where: str, why: str) -> None:
        self.skipped.append({"what": where, "why": why})
        print(f"benchmark: skipped {where}: {why}", file=sys.stderr)

    def missing(self, path: Path) -> str | None:
        return None if path.exists() else f"{path} is absent"

    # ------------------------------------------------------------------ detectors

    def detectors(self) -> None:
        from followbot.research.realdata import (
            HELD_OUT_NEGATIVE_TOPICS,
            HELD_OUT_POSITIVES,
            read_negative,
            read_positive,
            score,
        )
        from followbot.services.laser_legs.detectors import REGISTRY
        from followbot.services.laser_legs.node import LaserLegsSettings, build_detector

        leg = self.data / "leg_tracker"
        names = HELD_OUT_POSITIVES[: QUICK["positives"]] if self.quick else HELD_OUT_POSITIVES
        files = [leg / f"{n}_extracted.bag" for n in names] + [leg / "negative_2.bag"]
        if why := next(filter(None, map(self.missing, files)), None):
            return self.skip("detectors", why)
        positives = [s for n in names for s in read_positive(n, leg)]
        cut = QUICK["detector_negative_scans"] if self.quick else None
        negatives = [s for t in HELD_OUT_NEGATIVE_TOPICS for s in read_negative(t, leg)[:cut]]
        rows = []
        detectors = REGISTRY.names()
        for k, name in enumerate(detectors):
            progress.show(f"  detector {name} {progress.count_bar(k, len(detectors))}")
            try:
                det = build_detector(LaserLegsSettings(detector=name))
            except Exception as exc:  # a plugin that cannot be built is reported, not fatal
                self.skip(f"detectors: {name}", f"cannot be built: {exc}")
                continue
            sc = score(det, positives, negatives, name=name)
            rows.append({
                "detector": name,
                "leg_recall": _r(sc.recall),
                "leg_recall_within_3_5_m": _r(sc.recall_near),
                "false_candidates_per_scan": _r(sc.false_candidates_per_scan),
                "false_legs_per_scan": _r(sc.false_legs_per_scan),
                "us_per_scan_p50": _r(sc.median_time_us, 0),
            })  # fmt: skip
        progress.finish()
        self.results["detectors"] = {
            "positives": list(names),
            "negative_topics": list(HELD_OUT_NEGATIVE_TOPICS),
            "positive_scans": len(positives),
            "labelled_legs": sum(int(p.legs_xy.shape[0]) for p in positives),
            "negative_scans": len(negatives),
            "rows": rows,
        }

    # ------------------------------------------------------------------ pipeline sections

    def _track(self, preset: str, key: str, path: Path, **kw) -> LogRun | None:
        """``path`` through the pipeline once per preset (shared by the sections)."""
        if key in self.runs[preset]:
            return self.runs[preset][key]
        out = self.out / "runs" / preset / key.replace("/", "_")
        try:
            run = track_log(
                path, preset, self.args.set, out, label=f"{preset}: {key}",
                laser_odometry=self.args.laser_odometry, **kw,
            )  # fmt: skip
        except BenchmarkError as exc:
            self.skip(f"{preset}: {key}", str(exc))
            return None
        self.runs[preset][key] = run
        self.results["throughput"].setdefault(preset, {})[key] = run.throughput()
        return run

    def carmen_logs(self) -> list[Path]:
        folder = self.data / "carmen"
        logs = sorted({p for g in CARMEN_GLOBS for p in folder.glob(g)})
        return logs[: QUICK["carmen_logs"]] if self.quick else logs

    def false_people(self, preset: str) -> None:
        from followbot.research.realdata import HELD_OUT_NEGATIVE_TOPICS

        out = {"logs": {}}
        logs = self.carmen_logs()
        if not logs:
            self.skip(f"false_people: {preset}: carmen", f"no CARMEN log in {self.data / 'carmen'}")
        carmen_runs = []
        for log in logs:
            name = log.name.split(".")[0]
            limit = QUICK["carmen_scans"] if self.quick else None
            run = self._track(preset, f"carmen/{name}", log, max_scans=limit)
            if run is not None:
                carmen_runs.append(run)
                out["logs"][f"carmen/{name}"] = false_people_figures([run])
        if carmen_runs:
            out["carmen_all"] = {
                **false_people_figures(carmen_runs),
                "logs": len(carmen_runs),
                "of": len(logs),
            }
        negative = self.data / "leg_tracker" / "negative_2.bag"
        topics = HELD_OUT_NEGATIVE_TOPICS[: QUICK["negative_topics"] if self.quick else None]
        neg_runs = []
        if why := self.missing(negative):
            self.skip(f"false_people: {preset}: negative_2", why)
            topics = ()
        for topic in topics:
            key = f"negative_2{topic}"
            limit = QUICK["negative_scans"] if self.quick else None
            run = self._track(preset, key, negative, scan_topic=topic, max_scans=limit)
            if run is not None:
                neg_runs.append(run)
                out["logs"][key] = false_people_figures([run])
        if neg_runs:
            out["negative_2_all"] = {
                **false_people_figures(neg_runs),
                "logs": len(neg_runs),
                "of": len(topics),
            }
        if out["logs"]:
            self.results["false_people"][preset] = out

    def legs360(self, preset: str) -> None:
        folder = self.data / "legs360"
        bag, labels = folder / "legs360.bag", folder / "legs360_labels.csv"
        if why := self.missing(bag) or self.missing(labels):
            return self.skip(f"legs360: {preset}", why)
        try:
            walker = read_walker(labels)
        except (OSError, BenchmarkError) as exc:
            return self.skip(f"legs360: {preset}", str(exc))
        run = self._track(preset, "legs360", bag)
        if run is not None:
            self.results["legs360"][preset] = walker_figures(run, walker)

    def demo(self, preset: str) -> None:
        bag = self.data / "leg_tracker" / DEMO_BAG
        if why := self.missing(bag):
            return self.skip(f"demo: {preset}", why)
        limit = QUICK["demo_scans"] if self.quick else None
        run = self._track(preset, "demo_stationary", bag, max_scans=limit)
        if run is not None:
            self.results["demo"][preset] = churn_figures(run)

    # ------------------------------------------------------------------ appearance

    def appearance(self) -> None:
        from followbot.services.runtime.compose import PRESETS

        boxes = self.data / "pets09" / PETS09_BOXES
        if why := self.missing(boxes):
            return self.skip("appearance", why)
        video = find_video(self.args.video)
        if video is None or not video.is_file():
            return self.skip(
                "appearance",
                f"vtest.avi not found ({video or 'looked in ' + ', '.join(map(str, VIDEO_DIRS))}"
                "); `make opencv-data` fetches Debian's opencv-doc, or give --video PATH",
            )
        by_verifier: dict[str, list[str]] = {}
        for p in self.presets:
            vv = PRESETS[p].get("vision_verify", {})
            by_verifier.setdefault(vv.get("verifier", _service_default("verifier")), []).append(p)
        res: dict = {"video": str(video), "boxes": str(boxes), "verifiers": {}}
        for name, presets in by_verifier.items():
            try:
                summary = appearance_summary(
                    video, boxes, name, self.out / f"appearance_{name}.json", quick=self.quick
                )
            except BenchmarkError as exc:
                self.skip(f"appearance: {name}", str(exc))
                continue
            summary["presets"] = presets
            res["verifiers"][name] = summary
        if res["verifiers"]:
            self.results["appearance"] = res

    # ------------------------------------------------------------------ the whole run

    def run(self) -> dict:
        t_all = time.monotonic()
        pipeline = [s for s in ("false_people", "legs360", "demo") if s in self.sections]
        if "detectors" in self.sections:
            self._timed("detectors", self.detectors)
        for preset in self.presets:
            for section in pipeline:
                self._timed(section, getattr(self, section), preset)
        if "appearance" in self.sections:
            self._timed("appearance", self.appearance)
        for s in SECTIONS:
            if s not in self.sections:
                self.results[s] = {"skipped": "not chosen (--only)"}
            elif not self.results[s]:
                self.results[s] = {"skipped": "no data (see skipped)"}
        if not self.results["throughput"]:
            self.results["throughput"] = {"skipped": "no recording went through the pipeline"}
        return {
            "meta": self.meta(time.monotonic() - t_all),
            **self.results,
            "skipped": self.skipped,
        }

    def _timed(self, section: str, fn, *args) -> None:
        t0 = time.monotonic()
        try:
            fn(*args)
        except Exception as exc:  # a fault in one section must not lose the others' figures
            traceback.print_exc()
            where = f"{section}: {args[0]}" if args else section
            self.skip(where, f"failed: {type(exc).__name__}: {exc} (traceback on stderr)")
        self.section_s[section] = round(self.section_s.get(section, 0.0) + time.monotonic() - t0, 1)

    def meta(self, seconds: float) -> dict:
        from followbot import __version__
        from followbot.services.runtime.compose import PRESETS
        from followbot.sweep import code_fingerprint

        return {
            "command": "followbot benchmark " + " ".join(self.args.argv),
            "data_dir": str(self.data),
            "quick": self.quick,
            "subsampling": "--quick: the slice of QUICK" if self.quick else "none",
            "presets": {p: PRESETS.get(p, {}) for p in self.presets},
            "overrides": self.args.set,
            "laser_odometry": self.args.laser_odometry,
            "sections": self.sections,
            "followbot_version": __version__,
            "code_fingerprint": code_fingerprint(),
            "git_commit": _git_commit(),
            "cpus": os.cpu_count(),
            "seconds": round(seconds, 1),
            "section_seconds": self.section_s,
            "acquire": _acquire_rule(),
        }


def _part(preset: dict, service: str, key: str) -> str:
    """The implementation ``preset`` runs for one role of ``service``: its own choice, else the
    service's default; "-" when the preset does not run the service (the camera-only one)."""
    if service in preset:
        return preset[service].get(key, _DEFAULT_PART[key]())
    return "-" if "camera_blobs" in preset else _DEFAULT_PART[key]()


def _default_detector() -> str:
    from followbot.services.laser_legs.node import LaserLegsSettings

    return LaserLegsSettings().detector


def _default_estimator() -> str:
    from followbot.services.tracker.settings import TrackerSettings

    return TrackerSettings().estimator


_DEFAULT_PART = {
    "detector": _default_detector,
    "estimator": _default_estimator,
    "verifier": lambda: _service_default("verifier"),
}


def _service_default(key: str):
    from followbot.appearance import _service_defaults

    return _service_defaults()[key]


def appearance_summary(
    video: Path, boxes: Path, verifier_name: str, out: Path, *, quick: bool
) -> dict:
    """``followbot appearance VIDEO BOXES --verifier NAME --lags 25,100 --frames 0:400 --json
    OUT`` (itself, so every other option is its default), as its summary dict. Its table goes
    nowhere (the report has it); its progress and errors go to stderr as usual."""
    from followbot import appearance

    first, end = QUICK["appearance_frames"] if quick else APPEARANCE_FRAMES
    argv = [
        str(video), str(boxes), "--verifier", verifier_name, "--frames", f"{first}:{end}",
        "--lags", ",".join(map(str, APPEARANCE_LAGS)), "--json", str(out),
    ]  # fmt: skip
    err = _LastLine(sys.stderr)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = appearance.main(argv)
    if code != 0:
        raise BenchmarkError(f"followbot appearance exited {code}: {err.last}")
    return json.loads(out.read_text())


class _LastLine(io.TextIOBase):
    """Passes writes on to ``stream``, keeping the last non-empty line (an error's reason)."""

    def __init__(self, stream) -> None:
        self.stream, self.last = stream, ""

    def write(self, text: str) -> int:
        lines = [x for x in text.replace("\r", "\n").splitlines() if x.strip()]
        if lines:
            self.last = lines[-1].strip()
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return self.stream.isatty()


def _acquire_rule() -> str:
    from followbot.services.tracker.settings import IdentitySettings

    s = IdentitySettings()
    return (
        f"the nearest candidate ahead within {s.acquire_range_m} m and "
        f"{s.acquire_bearing_deg} deg either side (tracker acquire: nearest)"
    )


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "-C", str(Path(__file__).resolve().parents[1]), "rev-parse", "--short", "HEAD"],
            capture_output=True, text=True, timeout=10,
        )  # fmt: skip
        dirty = subprocess.run(
            ["git", "-C", str(Path(__file__).resolve().parents[1]), "status", "--porcelain",
             "--untracked-files=no"],
            capture_output=True, text=True, timeout=10,
        )  # fmt: skip
    except (OSError, subprocess.TimeoutExpired):
        return None
    if not out.stdout.strip():
        return None
    return out.stdout.strip() + (" with uncommitted changes" if dirty.stdout.strip() else "")


# --------------------------------------------------------------------------- report


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def _num(x, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def summary_rows(result: dict) -> list[tuple[str, dict[str, str]]]:
    """The headline figures: (figure, {preset: cell})."""
    presets = list(result["meta"]["presets"])
    rows: list[tuple[str, dict[str, str]]] = []

    def add(label: str, cell) -> None:
        cells = {p: cell(p) for p in presets}
        if any(c != "-" for c in cells.values()):
            rows.append((label, cells))

    meta = result["meta"]["presets"]
    add("laser detector", lambda p: _part(meta[p], "laser_legs", "detector"))
    add("tracker estimator", lambda p: _part(meta[p], "tracker", "estimator"))

    def fp(group: str, key: str, fmt):
        def cell(p: str) -> str:
            f = result["false_people"].get(p, {}).get(group, {})
            text = fmt(f.get(key))
            if f and f["logs"] < f["of"]:  # a recording failed: say the figure lacks it
                text += f" ({f['logs']} of {f['of']} recordings)"
            return text

        return cell

    add("CARMEN: false people per scan", fp("carmen_all", "false_people_per_scan", _num))
    add("CARMEN: scans with a false person", fp("carmen_all", "scans_with_false_person", _pct))
    add("negative_2: false people per scan", fp("negative_2_all", "false_people_per_scan", _num))
    add("negative_2: scans with a false person",
        fp("negative_2_all", "scans_with_false_person", _pct))  # fmt: skip

    def sec(section: str, key: str, fmt):
        return lambda p: fmt(result[section].get(p, {}).get(key))

    add("legs360: walker tracked", sec("legs360", "walker_tracked", _pct))
    add("legs360: walker followed as the target", sec("legs360", "walker_followed", _pct))
    add("legs360: ghosts per scan", sec("legs360", "ghosts_per_scan", _num))
    add("legs360: scans with a ghost", sec("legs360", "scans_with_ghost", _pct))
    add("demo_stationary: new person ids per minute",
        sec("demo", "new_ids_per_min", lambda x: _num(x, 1)))  # fmt: skip
    add("demo_stationary: target tracked after first chosen",
        sec("demo", "target_tracked_after_first", _pct))  # fmt: skip

    def lost(p) -> str:
        f = result["demo"].get(p)
        if f is None:
            return "-"
        older = f.get("target_taken_back_by_older_track", "-")
        return f"{f['target_losses']} / {f['target_taken_back']} / {older}"

    add("demo_stationary: target lost / taken back / by a track seen before the loss", lost)
    verifiers = result["appearance"].get("verifiers", {})
    for protocol in ("one view", "following"):
        for lag in APPEARANCE_LAGS:

            def cell(p, protocol=protocol, lag=lag) -> str:
                name = _part(meta[p], "vision_verify", "verifier")
                rows_ = verifiers.get(name, {}).get("results", [])
                r = next((r for r in rows_ if r["protocol"] == protocol and r["lag"] == lag), None)
                if r is None:
                    return "-"
                return (f"{_pct(r['rank1'])} / {_pct(r['target_rejected'])} / "
                        f"{_pct(r['accepted_without_target'])}")  # fmt: skip

            add(f"pets09 {protocol}, lag {lag}: rank-1 / target rejected / someone accepted", cell)

    def speed(p) -> str:
        runs = result["throughput"].get(p, {})
        if not isinstance(runs, dict) or not runs:
            return "-"
        scans = sum(r["scans"] for r in runs.values())
        secs = sum(r["seconds"] for r in runs.values())
        slow = min((r["scans_per_s"] or 0.0 for r in runs.values()), default=0.0)
        return f"{scans / secs:.0f} (slowest log {slow:.0f})" if secs else "-"

    add("scans per second, all logs", speed)
    return rows


def markdown(result: dict) -> str:
    meta = result["meta"]
    presets = list(meta["presets"])
    lines = [
        "# followbot benchmark",
        "",
        f"`{meta['command']}` -- data {meta['data_dir']}; followbot {meta['followbot_version']}"
        f" (commit {meta['git_commit'] or '?'}, code {meta['code_fingerprint']}); "
        f"{meta['seconds']:.0f} s on {meta['cpus']} CPUs; subsampling: {meta['subsampling']}.",
        "",
    ]
    if meta["overrides"]:
        lines += [f"Settings changed: {', '.join(meta['overrides'])}.", ""]
    lines += [
        "Every recording ran through laser_legs and tracker as processes in lock-step (as "
        "`followbot track`; laser_odometry first where the throughput table says so: "
        f"--laser-odometry {meta.get('laser_odometry', 'auto')}), without a camera: the target "
        "is " + meta["acquire"] + ".",
        "",
    ]
    rows = summary_rows(result)
    if rows and presets:
        table = _table(
            ["figure", *presets], [[label, *(c[p] for p in presets)] for label, c in rows]
        )
        lines += ["## Summary", "", *table, ""]
    lines += _section(
        "Laser detectors (held-out leg_tracker data)", result["detectors"], _detectors_md
    )
    lines += _section(
        "False people (CARMEN logs, negative_2)", result["false_people"], _false_people_md
    )
    lines += _section("legs360: the walker and ghosts", result["legs360"], _legs360_md)
    lines += _section("Appearance on pets09", result["appearance"], _appearance_md)
    lines += _section("demo_stationary: id churn and the target", result["demo"], _demo_md)
    lines += _section("Throughput", result["throughput"], _throughput_md)
    if result["skipped"]:
        lines += ["## Skipped", ""]
        lines += [f"- {s['what']}: {s['why']}" for s in result["skipped"]]
        lines.append("")
    return "\n".join(lines)


def _section(title: str, d: dict, body: Callable[[dict], list[str]]) -> list[str]:
    """A report section: ``## title``, then ``body(d)``, or why the section was skipped."""
    if "skipped" in d:
        return [f"## {title}", "", f"Skipped: {d['skipped']}.", ""]
    return [f"## {title}", "", *body(d)]


def _table(
    columns: Sequence[str],
    rows: Iterable[Sequence[object]],
    title: str | None = None,
    intro: str | None = None,
) -> list[str]:
    """A Markdown table as lines: ``### title`` and ``intro`` (each followed by a blank line)
    when given, the header row of ``columns``, then one line per row (each cell as str)."""
    lines = [] if title is None else [f"### {title}", ""]
    if intro is not None:
        lines += [intro, ""]
    lines += ["| " + " | ".join(columns) + " |", "|---" * len(columns) + "|"]
    return lines + ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]


def _detectors_md(d: dict) -> list[str]:
    intro = (
        f"{d['positive_scans']} labelled scans of {', '.join(d['positives'])} "
        f"({d['labelled_legs']} legs); {d['negative_scans']} scans of negative_2 "
        f"{' and '.join(d['negative_topics'])} (nobody there). Each detector behind the "
        "robot-body filter, as the laser_legs service builds it."
    )
    columns = ["detector", "leg recall", "recall <= 3.5 m", "false candidates/scan",
               "false legs/scan", "us/scan p50"]  # fmt: skip
    rows = [
        [
            r["detector"],
            _num(r["leg_recall"], 3),
            _num(r["leg_recall_within_3_5_m"], 3),
            _num(r["false_candidates_per_scan"]),
            _num(r["false_legs_per_scan"]),
            _num(r["us_per_scan_p50"], 0),
        ]
        for r in d["rows"]
    ]
    return [*_table(columns, rows, intro=intro), "", "![detectors](detectors.png)", ""]


def _false_people_md(d: dict) -> list[str]:
    columns = ["recording", "scans", "false people/scan", "scans with a false person",
               "most at once", "person ids"]  # fmt: skip
    lines: list[str] = []
    for preset, res in d.items():
        items = list(res["logs"].items())
        items += [(f"**{k}**", res[k]) for k in ("carmen_all", "negative_2_all") if k in res]
        rows = [
            [
                name,
                f["scans"],
                _num(f["false_people_per_scan"]),
                _pct(f["scans_with_false_person"]),
                f["most_at_once"],
                f["person_ids"],
            ]
            for name, f in items
        ]
        lines += [*_table(columns, rows, title=preset), ""]
    return [*lines, "![false people](false_people.png)", ""]


def _legs360_md(d: dict) -> list[str]:
    columns = ["preset", "labelled scans", "walker tracked", "walker followed", "ghosts/scan",
               "scans with a ghost"]  # fmt: skip
    rows = [
        [
            preset,
            f["labelled_scans"],
            _pct(f["walker_tracked"]),
            _pct(f["walker_followed"]),
            _num(f["ghosts_per_scan"]),
            _pct(f["scans_with_ghost"]),
        ]
        for preset, f in d.items()
    ]
    radius = next(iter(d.values()))["radius_m"]
    return [
        *_table(columns, rows),
        "",
        f"A track within {radius} m of the walker is the walker's.",
        "",
    ]


def _appearance_md(d: dict) -> list[str]:
    from followbot.appearance import format_table

    lines: list[str] = []
    for name, summary in d["verifiers"].items():
        lines += [f"### {name} ({', '.join(summary['presets'])})", "", format_table(summary), ""]
        lines += [f"![{name}](appearance_{name}.png)", ""]
    return lines


def _demo_md(d: dict) -> list[str]:
    columns = ["preset", "scans", "minutes", "person ids", "new ids/min", "people/scan",
               "target first chosen at", "tracked after", "losses", "taken back",
               "by a track seen before the loss", "lost at the end", "target ids"]  # fmt: skip
    rows = [
        [
            preset,
            f["scans"],
            _num(f["minutes"]),
            f["person_ids"],
            _num(f["new_ids_per_min"], 1),
            _num(f["people_per_scan"]),
            "never" if f["target_first_s"] is None else f"{f['target_first_s']} s",
            _pct(f["target_tracked_after_first"]),
            f["target_losses"],
            f["target_taken_back"],
            f.get("target_taken_back_by_older_track", "-"),
            "yes" if f["target_lost_at_end"] else "no",
            f["target_ids"],
        ]
        for preset, f in d.items()
    ]
    return [*_table(columns, rows), "", "![demo](demo.png)", ""]


def _throughput_md(d: dict) -> list[str]:
    intro = (
        "Scans per second through laser_legs and tracker in lock-step (and laser_odometry "
        "where the odometry is laser_odometry's), reading the file included; x real time: the "
        "recording's duration over the time taken. On a shared machine these vary from run "
        "to run."
    )
    columns = ["preset", "recording", "odometry", "scans", "s", "scans/s", "x real time",
               "unanswered scans"]  # fmt: skip
    rows = [
        [
            preset,
            name,
            r.get("odometry") or "?",
            r["scans"],
            r["seconds"],
            _num(r["scans_per_s"], 0),
            _num(r["x_real_time"], 1),
            ", ".join(f"{s} {n}" for s, n in r["stage_timeouts"].items()) or "-",
        ]
        for preset, runs in d.items()
        for name, r in runs.items()
    ]
    lines = _table(columns, rows, intro=intro)
    unanswered = sum(
        sum(r["stage_timeouts"].values()) for runs in d.values() for r in runs.values()
    )
    if unanswered:
        lines += [
            "",
            f"{unanswered} scans went on without a stage's answer (after "
            f"{ANSWER_TIMEOUT_S:.0f} s): the figures of those recordings may differ from run "
            "to run (a loaded machine, or a stage that failed on them: see its log in runs/).",
        ]
    return [*lines, "", "![throughput](throughput.png)", ""]


# --------------------------------------------------------------------------- plots


def top_down(ax, run: LogRun, gap_s: float = 0.5) -> None:
    """``run``'s people tracks seen from above (REP-103: x forward, up; y left, to the left),
    thin grey, and the target thick, one colour per track id it was on: a star where the
    target was first chosen, a cross where it was lost (status no longer tracking or
    coasting), a circle where it was taken back. A track's line breaks where it was not
    published for ``gap_s``."""
    lines: dict[int, list[list[tuple[float, float]]]] = {}
    last: dict[int, int] = {}
    for s in run.stamps:
        for i, x, y in run.people.get(s, []):
            if i not in lines or s - last[i] > gap_s * 1e9:
                lines.setdefault(i, []).append([])
            lines[i][-1].append((x, y))
            last[i] = s
    for pieces in lines.values():
        for piece in pieces:
            xs, ys = zip(*piece, strict=True)
            ax.plot(ys, xs, color="0.6", lw=0.6)
    target: list[tuple[int, float, float] | None] = []
    for s in run.stamps:
        t = run.targets.get(s)
        if t is not None:
            target.append((t[1], t[2], t[3]) if t[0] in HAS_TARGET else None)
    colours = itertools.cycle(f"C{k}" for k in range(10))  # one per track id, repeating
    seen: dict[int, str] = {}
    piece: list[tuple[float, float]] = []
    prev = None
    marks = {"first chosen": [], "lost": [], "taken back": []}

    def flush(tid) -> None:
        if piece and tid is not None:
            xs, ys = zip(*piece, strict=True)
            ax.plot(ys, xs, color=seen[tid], lw=2.2, alpha=0.85)

    for now in target:
        if prev is not None and (now is None or now[0] != prev[0]):
            flush(prev[0])
            piece = [piece[-1]] if now is not None and piece else []
            if now is None:
                marks["lost"].append(prev[1:])
        if now is not None:
            if now[0] not in seen:
                seen[now[0]] = next(colours)
            if not marks["first chosen"]:
                marks["first chosen"].append(now[1:])
            elif prev is None:
                marks["taken back"].append(now[1:])
            piece.append(now[1:])
        prev = now
    if prev is not None:
        flush(prev[0])
    for (name, pts), style in zip(marks.items(), ("*", "x", "o"), strict=True):
        if pts:
            xs, ys = zip(*pts, strict=True)
            ax.plot(ys, xs, style, color="k", ms=9 if style == "*" else 6, mfc="none"
                    if style == "o" else None, label=f"target {name} ({len(pts)})")  # fmt: skip
    ax.plot([0], [0], "^", color="k", ms=10, label="laser (facing up)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.invert_xaxis()  # y (left) to the left
    ax.set_xlabel("y (m, left)")
    ax.set_ylabel("x (m, forward)")
    ax.grid(alpha=0.3)
    ax.plot([], [], color="0.6", lw=0.6, label="people tracks")
    ax.plot([], [], color="C0", lw=2.2, label=f"target, a colour per track id ({len(seen)})")


def plots(result: dict, runs: dict[str, dict[str, LogRun]], out: Path) -> list[Path]:
    """PNG plots of the figures; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from followbot.appearance import plot as appearance_plot

    written: list[Path] = []

    def save(fig, name: str) -> None:
        path = out / name
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)

    det = result["detectors"]
    if "rows" in det:
        fig, ax = plt.subplots(figsize=(6, 4.5), constrained_layout=True)
        for r in det["rows"]:
            ax.plot(r["false_candidates_per_scan"], r["leg_recall"], "o")
            ax.annotate(r["detector"], (r["false_candidates_per_scan"], r["leg_recall"]),
                        textcoords="offset points", xytext=(5, 3))  # fmt: skip
        ax.set_xlabel("false person candidates per scan (negative_2)")
        ax.set_ylabel("leg recall (held-out positives)")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.set_title("leg detectors on held-out real data")
        save(fig, "detectors.png")
    fp = {p: v for p, v in result["false_people"].items() if isinstance(v, dict) and "logs" in v}
    if fp:
        logs = sorted({k for v in fp.values() for k in v["logs"]})
        fig, ax = plt.subplots(figsize=(max(6, 0.8 * len(logs) + 2), 4.5), constrained_layout=True)
        width = 0.8 / len(fp)
        for k, (preset, v) in enumerate(fp.items()):
            ys = [v["logs"].get(log, {}).get("false_people_per_scan") or 0.0 for log in logs]
            ax.bar([i + k * width for i in range(len(logs))], ys, width, label=preset)
        ax.set_xticks([i + 0.4 - width / 2 for i in range(len(logs))])
        ax.set_xticklabels([log.removeprefix("carmen/") for log in logs], rotation=40, ha="right")
        ax.set_ylabel("false people per scan")
        ax.set_title("people published where nobody walks")
        ax.legend()
        ax.grid(alpha=0.3, axis="y")
        save(fig, "false_people.png")
    for name, summary in result["appearance"].get("verifiers", {}).items():
        path = out / f"appearance_{name}.png"
        appearance_plot(summary, str(path))
        written.append(path)
    demo = {p: r["demo_stationary"] for p, r in runs.items() if "demo_stationary" in r}
    if demo and "skipped" not in result["demo"]:
        fig, axes = plt.subplots(len(demo), 2, figsize=(13, 4.2 * len(demo) + 0.6), squeeze=False,
                                 width_ratios=(2.2, 1), constrained_layout=True)  # fmt: skip
        for (ax, top), (preset, run) in zip(axes, demo.items(), strict=True):
            t0 = run.stamps[0] if run.stamps else 0
            ts = [(s - t0) / 1e9 for s in run.stamps]
            ax.step(ts, [len(run.people.get(s, [])) for s in run.stamps], where="post",
                    lw=0.8, label="people published")  # fmt: skip
            has = [run.targets.get(s, ("",))[0] in HAS_TARGET for s in run.stamps]
            high = max((len(v) for v in run.people.values()), default=1) + 0.5
            ax.fill_between(ts, 0, high, where=has, step="post", alpha=0.2, color="green",
                            label="target tracked")  # fmt: skip
            ax.set_ylabel(f"{preset}: people")
            ax.set_xlim(0, ts[-1] if ts else 1)
            ax.set_xlabel("time (s)")
            top_down(top, run)
            top.set_title(preset, fontsize=9)
        axes[0, 0].legend(loc="upper right")
        axes[0, 1].legend(loc="upper right", fontsize=7)
        fig.suptitle("demo_stationary: people tracks per scan and the target; seen from above")
        save(fig, "demo.png")
    tp = {p: v for p, v in result["throughput"].items() if isinstance(v, dict) and v}
    if tp and "skipped" not in result["throughput"]:
        logs = list(dict.fromkeys(k for v in tp.values() for k in v))
        fig, ax = plt.subplots(figsize=(max(6, 0.8 * len(logs) + 2), 4.5), constrained_layout=True)
        width = 0.8 / len(tp)
        for k, (preset, v) in enumerate(tp.items()):
            ys = [v.get(log, {}).get("scans_per_s") or 0.0 for log in logs]
            ax.bar([i + k * width for i in range(len(logs))], ys, width, label=preset)
        ax.set_xticks([i + 0.4 - width / 2 for i in range(len(logs))])
        ax.set_xticklabels(logs, rotation=40, ha="right")
        ax.set_ylabel("scans per second (lock-step)")
        ax.legend()
        ax.grid(alpha=0.3, axis="y")
        save(fig, "throughput.png")
    return written


# --------------------------------------------------------------------------- command line


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="followbot benchmark", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    p.add_argument(
        "data_dir", nargs="?", default=str(default_data_dir()), metavar="DATA_DIR",
        help=f"the data folder (default: {default_data_dir()})",
    )  # fmt: skip
    p.add_argument(
        "--output", default="out/benchmark", metavar="DIR",
        help="where benchmark.md, benchmark.json, the plots and each run's stage logs go "
        "(out/benchmark)",
    )  # fmt: skip
    which = p.add_mutually_exclusive_group()
    add_preset_arguments(
        p,
        preset_group=which,
        set_note="not for the detectors and appearance sections, which measure each detector "
        "and verifier with its defaults",
    )
    which.add_argument(
        "--all-presets", action="store_true",
        help="every preset in turn; one that cannot run is listed as skipped with the reason",
    )  # fmt: skip
    p.add_argument("--quick", action="store_true", help="a small slice (above): about 30 s")
    p.add_argument(
        "--only", nargs="+", choices=list(SECTIONS), metavar="SECTION",
        help=f"run only these sections: {', '.join(SECTIONS)}",
    )  # fmt: skip
    p.add_argument(
        "--laser-odometry", choices=("auto", "on", "off"), default="auto",
        help="the laser_odometry stage first, estimating odometry from the scans: auto "
        "(default) for recordings without odometry, on for every recording, off never",
    )  # fmt: skip
    p.add_argument("--video", metavar="FILE", help="vtest.avi (default: opencv-doc's)")
    return p


def main(argv: list[str] | None = None) -> int:
    from followbot.runner import RunError, invalid_stage_settings, preset_stages
    from followbot.track import tracking_settings

    argv = list(sys.argv[1:] if argv is None else argv)
    p = build_parser()
    args = p.parse_args(argv)
    args.argv = argv
    data = Path(args.data_dir)
    if not data.is_dir():
        print(f"followbot benchmark: no data folder at {data}", file=sys.stderr)
        return 2
    chosen = preset_names() if args.all_presets else [args.preset]
    presets, refused = [], {}
    pipeline = set(args.only or SECTIONS) & {"false_people", "legs360", "demo"}
    for preset in chosen:
        if "laser_legs" not in preset_stages(preset):
            # seed 001 follows from the camera alone; these recordings are laser logs
            refused[preset] = f"preset {preset} is camera-only: the recordings here have no camera"
            continue
        try:
            laser = args.laser_odometry != "off"  # its --set checked too when it may run
            settings = tracking_settings(
                preset, STAGES, False, args.set, odometry=True, laser_odometry=laser
            )
        except RunError as exc:
            refused[preset] = str(exc)
            continue
        if isinstance(settings, str):
            print(f"followbot benchmark: {settings}", file=sys.stderr)
            return 2
        # each stage checks its settings as it will when started (a bad --set: an error now)
        bad = invalid_stage_settings(settings) if pipeline else {}
        if bad:
            for stage, why in bad.items():
                print(f"followbot benchmark: {preset}: {stage}: {why}", file=sys.stderr)
            return 2
        presets.append(preset)
    if not presets:
        for preset, why in refused.items():
            print(f"followbot benchmark: {preset}: {why}", file=sys.stderr)
        return 2
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    bench = Benchmark(args, presets)
    for preset, why in refused.items():
        bench.skip(f"preset {preset}", why)
    result = bench.run()
    (out / "benchmark.json").write_text(json.dumps(result, indent=2) + "\n")
    try:
        written = plots(result, bench.runs, out)
    except Exception as exc:  # the figures are written; a plot that fails is reported
        print(f"followbot benchmark: plots: {exc}", file=sys.stderr)
        written = []
    text = markdown(result)
    (out / "benchmark.md").write_text(text + "\n")
    print(text)
    print(f"wrote {out / 'benchmark.md'}, {out / 'benchmark.json'}"
          + "".join(f", {w.name}" for w in written))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
