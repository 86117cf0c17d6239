"""``followbot appearance VIDEO BOXES``: how well a verifier picks a person among everyone.

    followbot appearance vtest.avi S2L1_frames_000-399.csv --lags 25,100
    followbot appearance clip.mp4 gt.txt --verifier meanshift --json out.json --plot out.png

For every person seen N frames before a frame (N: each of ``--lags``), the verifier learns
the person from their box and must pick them among everyone boxed in the later frame:

  one view    the model is learnt from the box N frames earlier alone;
  following   the model is learnt from the person's first box and updated with each later box
              up to N frames before the choice (the verifier's online update at --adapt-rate;
              what a robot has seen while tracking the person with confidence). A verifier
              without an update (face) keeps the first view.

Figures per protocol and lag: rank-1 (the person's distance is the lowest; chance beside it:
the mean of 1 / people in the frame), target rejected (their distance fails the verifier's
threshold, or the verifier cannot judge them), someone accepted with the target removed (any
other box passes the threshold), and the verifier's time per candidate (median).

Box files: MOTChallenge rows ``frame,id,x,y,w,h[,flag,...]`` (no header; frames counted from
1, so frame 1 is the video's first: --first-frame changes that; rows whose 7th column is 0
are skipped, as MOT ground truth marks boxes to ignore), or a CSV with the header
``frame,id,x_px,y_px,w_px,h_px`` (frames counted from 0). Boxes may reach past the image:
they are clipped. Bad rows are counted and reported, not fatal. docs/vision_verify.md
"Real footage" has the details and the figures on PETS 2009.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from followbot import progress

__all__ = ["format_table", "main", "plot"]


def _lags(text: str) -> list[int]:
    try:
        lags = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        lags = []
    if not lags or min(lags) < 1:
        raise argparse.ArgumentTypeError(
            f"must be whole numbers of frames >= 1 joined by commas, got {text!r}"
        )
    return sorted(set(lags))


def _frames(text: str) -> tuple[int, int | None]:
    a, sep, b = text.partition(":")
    try:
        first = int(a) if a.strip() else 0
        end = int(b) if b.strip() else None
    except ValueError:
        first, end = -1, None
    if not sep or first < 0 or (end is not None and end <= first):
        raise argparse.ArgumentTypeError(
            f"must be FIRST:END video frames, 0-based, END excluded (e.g. 0:400), got {text!r}"
        )
    return first, end


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a number in [0, 1], got {text!r}")
    return value


def _service_defaults() -> dict:
    """The vision_verify defaults this command follows (one place for them): the default
    preset's verifier (followbot's, as `track`, `eval` and `demo` run), and the service's rule
    by which a choice counts as confident (``learn.confident_*``)."""
    from followbot.presetargs import DEFAULT_PRESET
    from followbot.services.runtime.compose import PRESETS
    from followbot.services.vision_verify.settings import VisionVerifySettings

    s = VisionVerifySettings()
    preset = PRESETS[DEFAULT_PRESET].get("vision_verify", {})
    return {
        "verifier": preset.get("verifier", s.verifier),
        "confident_max_distance": s.learn.confident_max_distance,
        "confident_margin": s.learn.confident_margin,
    }


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="followbot appearance", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    p.add_argument("video", help="a video file OpenCV can read")
    p.add_argument("boxes", help="person boxes: a MOT file or a frame,id,x_px,y_px,w_px,h_px CSV")
    p.add_argument(
        "--format", choices=("auto", "mot", "csv"), default="auto",
        help="box file format (auto: csv when the first line has a header)",
    )  # fmt: skip
    p.add_argument(
        "--first-frame", type=int, metavar="K",
        help="the frame number the box file gives the video's first frame "
        "(default: 1 for MOT files, 0 for the CSV)",
    )  # fmt: skip
    p.add_argument(
        "--lags", type=_lags, default=[25, 100], metavar="N,N",
        help="frames between the model and the choice (25,100)",
    )  # fmt: skip
    p.add_argument(
        "--verifier", metavar="NAME",
        help="online, histogram, face, meanshift, colour or any installed verifier "
        "(default: the followbot preset's, online)",
    )  # fmt: skip
    p.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE",
        help="a verifier setting, e.g. --set default_threshold=0.7 (repeatable; "
        "`followbot run vision_verify --help` lists the verifiers' settings)",
    )  # fmt: skip
    p.add_argument(
        "--frames", type=_frames, default=(0, None), metavar="FIRST:END",
        help="video frames to use, 0-based, END excluded (default: all with boxes)",
    )  # fmt: skip
    p.add_argument(
        "--min-visible", type=_fraction, default=0.5, metavar="F",
        help="skip boxes with less than this share inside the image and not hidden by a "
        "nearer box (0.5)",
    )  # fmt: skip
    p.add_argument(
        "--occlusion", choices=("bottom", "none"), default="bottom",
        help="which boxes hide others: bottom (a box whose bottom edge is lower stands "
        "nearer and hides what it covers), none (only the image border hides)",
    )  # fmt: skip
    p.add_argument(
        "--adapt-rate", type=_fraction, default=0.02, metavar="R",
        help="following: the model's update rate per frame (0.02; 0: the first view only)",
    )  # fmt: skip
    p.add_argument(
        "--adapt-when", choices=("always", "confident"), default="always",
        help="following: update on every box of the target (always), or only when the "
        "verifier picks the target confidently, by the service's "
        "learn.confident_max_distance and learn.confident_margin (confident)",
    )  # fmt: skip
    p.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    p.add_argument("--plot", metavar="FILE", help="plot the figures against the lag (PNG, SVG)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    return p


def main(argv: list[str] | None = None) -> int:
    from followbot.services.runtime.settings import SettingsError, apply_overrides
    from followbot.services.vision_verify.footage import (
        BoxFileError,
        FootageError,
        evaluate,
        read_boxes,
    )
    from followbot.services.vision_verify.verifiers import make_verifier

    args = build_parser().parse_args(argv)

    def fail(msg: str) -> int:
        print(f"followbot appearance: {msg}", file=sys.stderr)
        return 2

    defaults = _service_defaults()
    name = args.verifier or defaults["verifier"]
    try:
        verifier = make_verifier(name, apply_overrides({}, args.set))
    except (SettingsError, ValueError) as exc:
        return fail(str(exc))
    try:
        boxes = read_boxes(args.boxes, args.format, args.first_frame)
    except BoxFileError as exc:
        return fail(str(exc))
    for reason, (n, line) in boxes.rejected.items():
        print(
            f"followbot appearance: {args.boxes}: {n} rows skipped: {reason} (first: line {line})",
            file=sys.stderr,
        )
    shown = [0.0]

    def on_frame(f: int, first: int, end: int) -> None:
        now = time.monotonic()
        if f + 1 == end or now - shown[0] >= (0.2 if progress.on_terminal() else 10.0):
            shown[0] = now
            progress.show(f"  {name}: frame {f + 1}/{end} " + _bar(f + 1 - first, end - first))

    try:
        report = evaluate(
            args.video, boxes, verifier, lags=args.lags, frames=args.frames,
            min_visible=args.min_visible, occlusion=args.occlusion == "bottom",
            adapt_rate=args.adapt_rate, adapt_when=args.adapt_when,
            confident_max_distance=defaults["confident_max_distance"],
            confident_margin=defaults["confident_margin"],
            on_frame=None if args.quiet else on_frame,
        )  # fmt: skip
    except (FootageError, ValueError) as exc:
        return fail(str(exc))
    finally:
        if not args.quiet:
            progress.finish()
    summary = report.summary()
    summary["boxes_file"] = boxes.summary()
    summary["options"] = {
        "lags": args.lags, "min_visible": args.min_visible, "occlusion": args.occlusion,
        "adapt_rate": args.adapt_rate, "adapt_when": args.adapt_when,
    }  # fmt: skip
    print(format_table(summary))
    try:
        if args.json:
            Path(args.json).write_text(json.dumps(summary, indent=2) + "\n")
        if args.plot:
            plot(summary, args.plot)
    except OSError as exc:
        return fail(f"cannot write {exc.filename}: {exc.strerror}")
    return 0


def _bar(done: int, total: int, width: int = 30) -> str:
    n = int(width * done / total) if total else width
    return f"[{'#' * n}{'.' * (width - n)}]"


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def format_table(summary: dict) -> str:
    """The figures as a Markdown table, with a heading line saying what was measured."""
    thr = summary["threshold"]
    first, end = summary["frames"]
    box = summary.get("boxes_file", {})
    bad = sum(r["rows"] for r in box.get("rejected", {}).values())
    counts = summary["counts"]
    lines = [
        f"{summary['verifier']} (threshold {thr}) on {Path(summary['video']).name}, "
        f"frames {first}-{end - 1}: {counts.get('boxes', 0)} boxes, "
        f"{counts.get('boxes_not_usable', 0)} not usable, {bad} bad rows"
        + ("" if summary["adapts"] else "; following: no online update, first view only"),
        "",
        "| protocol | lag | choices | rank-1 | chance | target rejected | someone accepted, "
        "target removed | ms/candidate p50 (CPU) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in summary["results"]:
        unjudged = r["target_unjudged"]
        rejected = _pct(r["target_rejected"])
        if unjudged:
            rejected += f" ({_pct(unjudged)} unjudged)"
        ms = r["ms_per_candidate_p50"]
        cpu = r["cpu_ms_per_candidate_p50"]
        lines.append(
            f"| {r['protocol']} | {r['lag']} | {r['choices']} | {_pct(r['rank1'])} | "
            f"{_pct(r['chance'])} | {rejected} | {_pct(r['accepted_without_target'])} | "
            + ("-" if ms is None else f"{ms:.3f} ({cpu:.3f})")
            + " |"
        )
    notes = [f"{text}: {counts[k]}" for k, text in _NOTES.items() if counts.get(k)]
    first_ms = summary.get("first_judgement_per_frame_ms_p50")
    if first_ms is not None:
        notes.append(f"first judgement on each frame, with the frame's preparation: {first_ms} ms")
    return "\n".join(lines + [""] * bool(notes) + [f"- {n}" for n in notes])


_NOTES = {
    "choices_target_not_usable": "choices dropped, the target gone or hidden in the later frame",
    "choices_alone": "choices dropped, the target alone in the later frame",
    "boxes_after_the_video": "boxes after the video's last frame",
}


def plot(summary: dict, path: str) -> None:
    """Rank-1 (with chance), target rejected and someone accepted against the lag."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (
        ("rank1", "rank-1"),
        ("target_rejected", "target rejected"),
        ("accepted_without_target", "someone accepted, target removed"),
    )
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), constrained_layout=True)
    for ax, (key, title) in zip(axes, panels, strict=True):
        for protocol, style in (("one view", "o-"), ("following", "s-")):
            rows = [r for r in summary["results"] if r["protocol"] == protocol]
            ax.plot([r["lag"] for r in rows], [r[key] for r in rows], style, label=protocol)
        if key == "rank1":
            rows = [r for r in summary["results"] if r["protocol"] == "one view"]
            ax.plot([r["lag"] for r in rows], [r["chance"] for r in rows], "k--", label="chance")
        ax.set_title(title)
        ax.set_xticks(sorted({r["lag"] for r in summary["results"]}))
        ax.set_xlabel("lag (frames)")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(
        f"{summary['verifier']} (threshold {summary['threshold']}) on {Path(summary['video']).name}"
    )
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
