"""``followbot benchmark [DATA_DIR]``: the real-data suite, one report.

    followbot benchmark --output out/bench                    # defaults, every section
    followbot benchmark --all-presets --output out/bench-all  # defaults and every preset
    followbot benchmark --quick --only detectors people --output out/bench-quick

DATA_DIR (default ``../shared/data`` beside the repository, or ``$FOLLOWBOT_DATA``) holds the
folders ``leg_tracker/``, ``carmen/``, ``legs360/`` and ``pets09/`` (each with its README and
LICENSE). A section whose data is missing is skipped, and the report says why.

Sections (``--only``):

  detectors   every leg detector, alone: leg recall on the held-out leg_tracker positives
              (positive_6, positive_7; a labelled leg is found when a detected leg lies within
              0.15 m) and false person *candidates* per scan on negative_2's held-out topics
              (/rear_scan, /right_scan: a room with nobody in it). Not preset-dependent.
  people      the pipeline a user gets (``followbot track``: laser_legs and tracker as
              processes, in lock-step) on each CARMEN log, negative_2's held-out topics, legs360
              and demo_stationary. False *people* per scan are the person tracks the tracker
              publishes (tracking/people) where nobody is: every one on CARMEN and negative_2,
              and on legs360 every one farther than 0.5 m from the labelled walker. Also the
              share of scans with any false person; on legs360 the share of labelled scans
              whose walker is tracked, and followed as the target, within 0.5 m; on
              demo_stationary (people round a still robot, unlabelled) new person ids per
              minute, and the target (the nearest person ahead when it is first chosen, as
              ``track`` does without a camera): its id changes, how often it is lost, and
              how often a target is taken again after a loss; and scans per second of the
              whole pipeline on each log.
  appearance  the verifier of each preset on pets09 frames 0-399 (``followbot appearance``:
              one-view and following protocols at 25 and 100 frames), when opencv-doc's
              vtest.avi is on this machine (``make opencv-data``).

Writes ``benchmark.md``, ``benchmark.json`` and PNG plots into ``--output``. ``--quick`` runs a
small slice of each log (for ``make test``): its figures are not the benchmark's.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import os
import re
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from followbot import progress

__all__ = ["PRESET_CHOICES", "SECTIONS", "default_data_dir", "main", "run"]

SECTIONS = ("detectors", "people", "appearance")
#: "default" is followbot with no preset.
PRESET_CHOICES = ("default", "thesis", "bellotto", "livingston", "ristic", "zhuang")
#: legs360: a person track this near the labelled walker is the walker.
WALKER_RADIUS_M = 0.5
#: --quick: scans per log and frames of pets09.
QUICK_SCANS = 150
QUICK_FRAMES = 120


def default_data_dir() -> Path:
    env = os.environ.get("FOLLOWBOT_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parent.parent.parent / "shared" / "data"


# --------------------------------------------------------------------------- detectors


def detectors_section(data: Path, quick: bool) -> dict:
    """Leg recall and false candidates per scan of every registered detector."""
    from followbot.research.realdata import (
        HELD_OUT_NEGATIVE_TOPICS,
        HELD_OUT_POSITIVES,
        read_negative,
        read_positive,
        score,
    )
    from followbot.services.laser_legs.detectors import REGISTRY, make_detector

    folder = data / "leg_tracker"
    if not (folder / "negative_2.bag").is_file():
        return {"skipped": f"{folder}/negative_2.bag not found"}
    positives = [s for name in HELD_OUT_POSITIVES for s in read_positive(name, folder)]
    negatives = [s for t in HELD_OUT_NEGATIVE_TOPICS for s in read_negative(t, folder)]
    if quick:
        positives, negatives = positives[:QUICK_SCANS], negatives[:QUICK_SCANS]
    rows = []
    for name in REGISTRY.names():
        progress.show(f"  detectors: {name}")
        s = score(make_detector(name), positives, negatives, name=name)
        rows.append(
            {
                "detector": name,
                "leg_recall": _r(s.recall),
                "leg_recall_within_3_5_m": _r(s.recall_near),
                "false_candidates_per_scan": _r(s.false_candidates_per_scan),
                "us_per_scan_p50": _r(s.median_time_us, 1),
                "labelled_legs": s.labelled_legs,
                "negative_scans": s.negative_scans,
            }
        )
    progress.finish()
    return {
        "positives": list(HELD_OUT_POSITIVES),
        "negative_topics": list(HELD_OUT_NEGATIVE_TOPICS),
        "rows": rows,
    }


# --------------------------------------------------------------------------- people


class Log:
    """One recording ``followbot track`` reads, and how it is judged."""

    def __init__(self, name: str, path: Path, kind: str, scan_topic: str | None = None):
        self.name, self.path, self.kind, self.scan_topic = name, path, kind, scan_topic


def people_logs(data: Path) -> tuple[list[Log], list[str]]:
    """The recordings of the people section, and why any expected one is missing."""
    logs: list[Log] = []
    missing: list[str] = []
    carmen = sorted((data / "carmen").glob("*.log.gz"))
    if not carmen:
        missing.append(f"no CARMEN logs in {data / 'carmen'}")
    logs += [Log(p.name.split("-corrected")[0], p, "empty") for p in carmen]
    neg = data / "leg_tracker" / "negative_2.bag"
    if neg.is_file():
        for topic in ("/rear_scan", "/right_scan"):
            logs.append(Log(f"negative_2{topic.replace('/', ':')}", neg, "empty", topic))
    else:
        missing.append(f"{neg} not found")
    l360 = data / "legs360" / "legs360.bag"
    if l360.is_file():
        logs.append(Log("legs360", l360, "walker"))
    else:
        missing.append(f"{l360} not found")
    demo = data / "leg_tracker" / "demo_stationary_simple_environment.bag"
    if demo.is_file():
        logs.append(Log("demo_stationary", demo, "people"))
    else:
        missing.append(f"{demo} not found")
    return logs, missing


def track(log: Log, preset: str, out: Path, quick: bool) -> dict:
    """Run ``followbot track`` on ``log``; its outputs and the scans it tracked."""
    cmd = [sys.executable, "-m", "followbot", "track", str(log.path), "--output", str(out)]
    if preset != "default":
        cmd += ["--preset", preset]
    if log.scan_topic:
        cmd += ["--scan-topic", log.scan_topic]
    if quick:
        cmd += ["--max-scans", str(QUICK_SCANS)]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    wall = time.monotonic() - t0
    m = re.search(r"tracked (\d+) scans in ([\d.]+) s", proc.stdout)
    if proc.returncode != 0 or m is None:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        return {"error": f"followbot track exited {proc.returncode}: " + " | ".join(tail)}
    scans, seconds = int(m.group(1)), float(m.group(2))
    return {
        "scans": scans,
        "scans_per_s": _r(scans / seconds if seconds > 0 else math.nan, 1),
        "wall_s": _r(wall, 1),
        "people": _read_rows(out / "people.csv"),
        "target": _read_rows(out / "target.csv"),
        "stamps": _scan_stamps(log, scans),
    }


def _read_rows(path: Path) -> list[tuple[int, int, float, float]]:
    with path.open() as f:
        return [
            (int(r["stamp_ns"]), int(r["id"]), float(r["x_m"]), float(r["y_m"]))
            for r in csv.DictReader(f)
        ]


def _scan_stamps(log: Log, scans: int) -> list[int] | None:
    """The stamps of the first ``scans`` scans of a walker log (for its labels), else None."""
    if log.kind != "walker":
        return None
    from followbot.bags import open_recording

    rec = open_recording(log.path)
    stamps = [msg.stamp_ns for _, topic, msg in rec.messages() if topic == "sensors/scan"]
    return stamps[:scans]


def judge(log: Log, result: dict, data: Path) -> dict:
    """The figures of one tracked log."""
    scans = result["scans"]
    people, target = result["people"], result["target"]
    row: dict = {"scans": scans, "scans_per_s": result["scans_per_s"]}
    if log.kind == "empty":
        stamps = {p[0] for p in people}
        row["false_people_per_scan"] = _r(len(people) / scans if scans else math.nan)
        row["scans_with_a_false_person"] = _r(len(stamps) / scans if scans else math.nan)
    elif log.kind == "walker":
        row.update(_judge_walker(people, target, result["stamps"] or [], data))
    else:
        row.update(_judge_people(people, target, scans))
    return row


def _walker_labels(data: Path) -> dict[int, np.ndarray]:
    """legs360: stamp -> the walker's position (the midpoint of the labelled legs)."""
    legs: dict[int, list[tuple[float, float]]] = defaultdict(list)
    with (data / "legs360" / "legs360_labels.csv").open() as f:
        for r in csv.DictReader(f):
            legs[int(r["stamp_ns"])].append((float(r["x_m"]), float(r["y_m"])))
    return {t: np.mean(np.array(v), axis=0) for t, v in legs.items()}


def _judge_walker(people, target, stamps: list[int], data: Path) -> dict:
    walker = _walker_labels(data)
    by_stamp: dict[int, list[tuple[float, float]]] = defaultdict(list)
    for t, _, x, y in people:
        by_stamp[t].append((x, y))
    target_at = {t: (x, y) for t, _, x, y in target}
    labelled = [t for t in stamps if t in walker]
    tracked = followed = ghosts = ghost_scans = 0
    for t in stamps:
        w = walker.get(t)
        near = [p for p in by_stamp.get(t, []) if w is not None and _dist(p, w) <= WALKER_RADIUS_M]
        far = len(by_stamp.get(t, [])) - len(near)
        ghosts += far
        ghost_scans += far > 0
        if w is not None:
            tracked += bool(near)
            followed += t in target_at and _dist(target_at[t], w) <= WALKER_RADIUS_M
    n = len(stamps)
    return {
        "labelled_scans": len(labelled),
        "walker_tracked": _r(tracked / len(labelled) if labelled else math.nan),
        "walker_followed": _r(followed / len(labelled) if labelled else math.nan),
        "false_people_per_scan": _r(ghosts / n if n else math.nan),
        "scans_with_a_false_person": _r(ghost_scans / n if n else math.nan),
    }


def _judge_people(people, target, scans: int) -> dict:
    stamps = sorted({p[0] for p in people} | {t[0] for t in target})
    minutes = (stamps[-1] - stamps[0]) / 60e9 if len(stamps) > 1 else math.nan
    ids = {p[1] for p in people}
    # the target over the scans: lost when a scan that had it is followed by one without
    have = {t[0]: t[1] for t in target}
    all_stamps = sorted({p[0] for p in people} | set(have))
    lost = retaken = switches = 0
    prev_id = None
    present = False
    for t in all_stamps:
        now = t in have
        if present and not now:
            lost += 1
        if now and not present and prev_id is not None:
            retaken += 1
        if now:
            if prev_id is not None and have[t] != prev_id:
                switches += 1
            prev_id = have[t]
        present = now
    first = min(have) if have else None
    after = [t for t in all_stamps if first is not None and t >= first]
    held = sum(1 for t in after if t in have)
    return {
        "new_person_ids_per_minute": _r(
            len(ids) / minutes if minutes and minutes > 0 else math.nan, 1
        ),
        "target_held_after_first_chosen": _r(held / len(after) if after else math.nan),
        "target_lost": lost,
        "target_taken_again": retaken,
        "target_id_changes": switches,
        "minutes": _r(minutes, 2),
        "scans_seen": scans,
    }


def _dist(p, q) -> float:
    return math.hypot(p[0] - q[0], p[1] - q[1])


def people_section(data: Path, presets: list[str], out: Path, quick: bool) -> dict:
    logs, missing = people_logs(data)
    if not logs:
        return {"skipped": "; ".join(missing)}
    result: dict = {"missing": missing, "presets": {}}
    for preset in presets:
        rows = {}
        for i, log in enumerate(logs):
            progress.show(f"  people: {preset}: {log.name} ({i + 1}/{len(logs)})")
            run_dir = out / "runs" / preset / log.name.replace(":", "_")
            tracked = track(log, preset, run_dir, quick)
            rows[log.name] = (
                {"error": tracked["error"]} if "error" in tracked else judge(log, tracked, data)
            )
        result["presets"][preset] = rows
    progress.finish()
    return result


# --------------------------------------------------------------------------- appearance


def _preset_verifier(preset: str) -> str | None:
    from followbot.services.runtime.compose import PRESETS
    from followbot.services.vision_verify.node import VisionVerifySettings

    if preset == "default":
        return VisionVerifySettings().verifier
    return PRESETS.get(preset, {}).get("vision_verify", {}).get("verifier")


def _vtest() -> Path | None:
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "followbot"
    for d in (
        os.environ.get("FOLLOWBOT_OPENCV_DATA", ""),
        str(cache / "opencv-doc/usr/share/doc/opencv-doc/examples/data"),
        "/usr/share/doc/opencv-doc/examples/data",
    ):
        if d and (Path(d) / "vtest.avi").is_file():
            return Path(d) / "vtest.avi"
    return None


def appearance_section(data: Path, presets: list[str], out: Path, quick: bool) -> dict:
    from followbot import appearance

    boxes = data / "pets09" / "S2L1_frames_000-399.csv"
    video = _vtest()
    if not boxes.is_file():
        return {"skipped": f"{boxes} not found"}
    if video is None:
        return {"skipped": "opencv-doc's vtest.avi not found: `make opencv-data` fetches it"}
    verifiers = {}
    for preset in presets:
        name = _preset_verifier(preset)
        if name is not None:
            verifiers.setdefault(name, []).append(preset)
    rows = {}
    for name, used_by in verifiers.items():
        progress.show(f"  appearance: {name} on pets09")
        path = out / f"appearance_{name}.json"
        frames = f"0:{QUICK_FRAMES}" if quick else "0:400"
        lags = "25" if quick else "25,100"
        argv = [str(video), str(boxes), "--verifier", name, "--frames", frames, "--lags", lags]
        with contextlib.redirect_stdout(io.StringIO()):  # its table is in the report
            code = appearance.main([*argv, "--json", str(path), "--quiet"])
        if code != 0:
            rows[name] = {"presets": used_by, "error": f"followbot appearance exited {code}"}
            continue
        summary = json.loads(path.read_text())
        rows[name] = {
            "presets": used_by,
            "threshold": summary["threshold"],
            "results": [
                {
                    k: r[k]
                    for k in (
                        "protocol",
                        "lag",
                        "choices",
                        "rank1",
                        "chance",
                        "target_rejected",
                        "accepted_without_target",
                        "ms_per_candidate_p50",
                    )
                }
                for r in summary["results"]
            ],
        }
    progress.finish()
    return {"video": str(video), "boxes": str(boxes), "verifiers": rows}


# --------------------------------------------------------------------------- report


def _r(x: float, digits: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), digits)


def _f(x, pct: bool = False) -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and pct:
        return f"{100 * x:.1f} %"
    return f"{x}"


def markdown(report: dict) -> str:
    lines = [
        "# followbot benchmark",
        "",
        f"Data: `{report['data']}`. Presets: {', '.join(report['presets'])}."
        + (
            " **Quick run** (a slice of each log): not the benchmark's figures."
            if report["quick"]
            else ""
        ),
        f"Command: `{report['command']}`; {report['seconds']:.0f} s.",
        "",
    ]
    det = report["sections"].get("detectors")
    if det is not None:
        lines += ["## Leg detectors (leg_tracker, held out)", ""]
        if "skipped" in det:
            lines += [f"Skipped: {det['skipped']}.", ""]
        else:
            lines += [
                *_header(
                    "detector",
                    "leg recall",
                    "recall within 3.5 m",
                    "false candidates / scan (negative_2)",
                    "µs / scan p50",
                ),
            ]
            for r in det["rows"]:
                lines.append(
                    f"| {r['detector']} | {_f(r['leg_recall'])} | "
                    f"{_f(r['leg_recall_within_3_5_m'])} | "
                    f"{_f(r['false_candidates_per_scan'])} | {_f(r['us_per_scan_p50'])} |"
                )
            lines.append("")
    ppl = report["sections"].get("people")
    if ppl is not None:
        lines += _people_markdown(ppl)
    app = report["sections"].get("appearance")
    if app is not None:
        lines += ["## Appearance on pets09 frames 0-399", ""]
        if "skipped" in app:
            lines += [f"Skipped: {app['skipped']}.", ""]
        else:
            lines += [
                *_header(
                    "verifier (presets)",
                    "protocol",
                    "lag",
                    "rank-1",
                    "chance",
                    "target rejected",
                    "someone accepted, target absent",
                    "ms / candidate",
                ),
            ]
            for name, v in app["verifiers"].items():
                who = f"{name} ({', '.join(v['presets'])})"
                if "error" in v:
                    lines.append(f"| {who} | {v['error']} | | | | | | |")
                    continue
                for r in v["results"]:
                    lines.append(
                        f"| {who} | {r['protocol']} | {r['lag']} | {_f(r['rank1'], True)} | "
                        f"{_f(r['chance'], True)} | {_f(r['target_rejected'], True)} | "
                        f"{_f(r['accepted_without_target'], True)} | "
                        f"{_f(r['ms_per_candidate_p50'])} |"
                    )
            lines.append("")
    return "\n".join(lines)


def _header(*columns: str) -> list[str]:
    return ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def _people_markdown(ppl: dict) -> list[str]:
    lines = ["## The pipeline on real logs (`followbot track`)", ""]
    if "skipped" in ppl:
        return [*lines, f"Skipped: {ppl['skipped']}.", ""]
    for why in ppl.get("missing", []):
        lines.append(f"- not run: {why}")
    lines += [
        "",
        "False people where nobody is (CARMEN offices, negative_2) and on legs360 (one walker):",
        "",
        *_header(
            "preset",
            "log",
            "scans",
            "false people / scan",
            "scans with a false person",
            "walker tracked",
            "walker followed",
            "scans / s",
        ),
    ]
    for preset, rows in ppl["presets"].items():
        for name, r in rows.items():
            if "error" in r:
                lines.append(f"| {preset} | {name} | {r['error']} | | | | | |")
            elif "false_people_per_scan" in r:
                lines.append(
                    f"| {preset} | {name} | {r['scans']} | {_f(r['false_people_per_scan'])} | "
                    f"{_f(r['scans_with_a_false_person'], True)} | "
                    f"{_f(r.get('walker_tracked'), True)} | {_f(r.get('walker_followed'), True)} | "
                    f"{_f(r['scans_per_s'])} |"
                )
    lines += [
        "",
        "demo_stationary (people round a still robot; the target is the nearest person ahead "
        "when first chosen):",
        "",
        *_header(
            "preset",
            "new person ids / min",
            "target held after first chosen",
            "target lost",
            "taken again",
            "target id changes",
            "scans / s",
        ),
    ]
    for preset, rows in ppl["presets"].items():
        r = rows.get("demo_stationary")
        if r and "error" not in r:
            lines.append(
                f"| {preset} | {_f(r['new_person_ids_per_minute'])} | "
                f"{_f(r['target_held_after_first_chosen'], True)} | {r['target_lost']} | "
                f"{r['target_taken_again']} | {r['target_id_changes']} | {_f(r['scans_per_s'])} |"
            )
    lines.append("")
    return lines


def plot(report: dict, out: Path) -> list[Path]:
    """False people per scan per log and preset; detectors' recall against false candidates."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    ppl = report["sections"].get("people") or {}
    if ppl.get("presets"):
        presets = list(ppl["presets"])
        logs = [n for n in next(iter(ppl["presets"].values())) if n != "demo_stationary"]
        fig, ax = plt.subplots(figsize=(max(6, len(logs) * 0.9), 3.8), constrained_layout=True)
        width = 0.8 / len(presets)
        for i, preset in enumerate(presets):
            vals = [
                (ppl["presets"][preset].get(n) or {}).get("false_people_per_scan") or 0.0
                for n in logs
            ]
            ax.bar(np.arange(len(logs)) + i * width, vals, width, label=preset)
        ax.set_xticks(np.arange(len(logs)) + 0.4 - width / 2, logs, rotation=30, ha="right")
        ax.set_ylabel("false people per scan")
        ax.legend()
        ax.grid(axis="y", alpha=0.3)
        path = out / "false_people.png"
        fig.savefig(path)
        plt.close(fig)
        written.append(path)
    det = report["sections"].get("detectors") or {}
    if det.get("rows"):
        fig, ax = plt.subplots(figsize=(5, 4), constrained_layout=True)
        for r in det["rows"]:
            ax.plot(r["false_candidates_per_scan"], r["leg_recall"], "o")
            ax.annotate(r["detector"], (r["false_candidates_per_scan"], r["leg_recall"]))
        ax.set_xlabel("false candidates per scan (negative_2)")
        ax.set_ylabel("leg recall (positive_6, positive_7)")
        ax.grid(alpha=0.3)
        path = out / "detectors.png"
        fig.savefig(path)
        plt.close(fig)
        written.append(path)
    return written


def run(data: Path, out: Path, presets: list[str], sections: list[str], quick: bool) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    report: dict = {"data": str(data), "presets": presets, "quick": quick, "sections": {}}
    if "detectors" in sections:
        report["sections"]["detectors"] = detectors_section(data, quick)
    if "people" in sections:
        report["sections"]["people"] = people_section(data, presets, out, quick)
    if "appearance" in sections:
        report["sections"]["appearance"] = appearance_section(data, presets, out, quick)
    report["seconds"] = time.monotonic() - t0
    return report


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="followbot benchmark",
        description=__doc__.split("\n\n", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("data", nargs="?", type=Path, help="the data folder (default ../shared/data)")
    p.add_argument("--output", required=True, type=Path, help="folder for the report")
    p.add_argument(
        "--preset",
        action="append",
        choices=PRESET_CHOICES,
        help="a preset to run (repeatable; default: followbot's defaults only)",
    )
    p.add_argument("--all-presets", action="store_true", help="the defaults and every preset")
    p.add_argument("--only", nargs="+", choices=SECTIONS, help="these sections only")
    p.add_argument("--quick", action="store_true", help="a small slice of each log (for tests)")
    return p


def _runnable(preset: str) -> str | None:
    """Why ``preset`` cannot run today, or None."""
    if preset == "default":
        return None
    from followbot.services.runtime.compose import PRESETS

    return None if preset in PRESETS else f"preset {preset!r} is not available in this build"


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    data = args.data or default_data_dir()
    if not data.is_dir():
        print(f"followbot benchmark: data folder {data} not found", file=sys.stderr)
        return 2
    wanted = list(PRESET_CHOICES) if args.all_presets else (args.preset or ["default"])
    presets = []
    for p in dict.fromkeys(wanted):
        why = _runnable(p)
        if why:
            print(f"followbot benchmark: skipping {why}", file=sys.stderr)
        else:
            presets.append(p)
    sections = args.only or list(SECTIONS)
    report = run(data, args.output, presets, sections, args.quick)
    report["command"] = "followbot benchmark " + " ".join(
        argv if argv is not None else sys.argv[1:]
    )
    (args.output / "benchmark.json").write_text(json.dumps(report, indent=2) + "\n")
    text = markdown(report)
    (args.output / "benchmark.md").write_text(text + "\n")
    plot(report, args.output)
    print(text)
    print(f"wrote {args.output}/benchmark.md, benchmark.json and plots")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
