"""``followbot appearance``: a verifier measured on footage with person boxes.

The figures are checked against values worked out by hand on a small synthetic clip: three
"people" (plain rectangles on a grey floor) walk right, one pixel a frame; at frame 20 the red
one (id 1) and the blue one (id 2) swap colours, the green one (id 3) stays green. The clip is
written losslessly (FFV1), so a person's box has exactly one colour, and ids 1 and 2 have the
same shape: their edge histograms are identical (green's too: its gradients point the other
way round, which gives the same four orientations), and the histogram verifier's distance
between two boxes is its colour distance alone (0 for the same colour, 1 for another).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from followbot.appearance import main
from followbot.services.vision_verify.core import ImageFeatures
from followbot.services.vision_verify.footage import (
    Box,
    BoxFileError,
    FootageError,
    evaluate,
    footage_camera,
    frame_candidates,
    learn_model,
    read_boxes,
    score,
    view_of,
    visible_fractions,
)
from followbot.services.vision_verify.verifiers import REGISTRY, make_verifier

W, H, FRAMES, SWAP = 160, 120, 40, 20
RED, BLUE, GREEN = (0, 0, 255), (255, 0, 0), (0, 255, 0)


def person_box(pid: int, f: int) -> tuple[int, int, int, int]:
    """x, y, w, h of person ``pid`` in frame ``f``."""
    return 5 + 50 * (pid - 1) + f, 40, 16, 40


def colour(pid: int, f: int) -> tuple[int, int, int]:
    if pid == 3:
        return GREEN
    first, second = (RED, BLUE) if pid == 1 else (BLUE, RED)
    return first if f < SWAP else second


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> tuple[Path, Path]:
    """The synthetic clip and its boxes (pets09 CSV format)."""
    d = tmp_path_factory.mktemp("clip")
    video, boxes = d / "swap.avi", d / "boxes.csv"
    out = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 10, (W, H))
    assert out.isOpened()
    rows = ["frame,id,x_px,y_px,w_px,h_px"]
    for f in range(FRAMES):
        img = np.full((H, W, 3), 128, np.uint8)
        for pid in (1, 2, 3):
            x, y, w, h = person_box(pid, f)
            img[y : y + h, x : x + w] = colour(pid, f)
            rows.append(f"{f},{pid},{x},{y},{w},{h}")
        out.write(img)
    out.release()
    boxes.write_text("\n".join(rows) + "\n")
    return video, boxes


# --------------------------------------------------------------------------- by hand

# Lag 10, choices from model frames t0 = 0..29 (t0 + 10 < 40), 30 per person, 90 in all.
#
# One view. Ids 1 and 2: the model has the colour of frame t0, the choice frame t0 + 10 the
# same colour when both are before the swap (t0 < 10) or both after (t0 >= 20): d = 0 for the
# target, d = 1 + edges >= 1 for the others -> right, target accepted, nobody else accepted.
# For t0 = 10..19 the swap lies between: the *other* one wears the model's colour now (d = 0,
# chosen, accepted without the target) and the target is at d = 1 (rejected at 0.8). 10 such
# choices each for ids 1 and 2; id 3 is always right.
ONE_VIEW_LAG10 = {"choices": 90, "rank1": 70 / 90, "rejected": 20 / 90, "accepted": 20 / 90}
# Lag 25: model frames t0 = 0..14, choice frames >= 25, all across the swap for ids 1, 2.
ONE_VIEW_LAG25 = {"choices": 45, "rank1": 15 / 45, "rejected": 30 / 45, "accepted": 30 / 45}
# Following at rate r = 0.1 (lag 10). Before the swap the model stays pure. From t0 = 20 on it
# has blended k = t0 - 19 views of the new colour: the old colour keeps weight a = 0.9^k, so
# (Bhattacharyya, each colour one bin per half) d(target) = sqrt(1 - sqrt(1 - a)) and
# d(the other, wearing the old colour) = sqrt(1 - sqrt(a)).
#   right when a < 0.5: k >= 7 (0.9^7 = 0.478, 0.9^6 = 0.531): t0 = 26..29, 4 choices
#   target rejected when d > 0.8, i.e. a > 0.8704: k = 1 (a = 0.9; 0.81 passes): 1 choice
#   the other accepted when d <= 0.8, i.e. a >= 0.1296: every k = 1..10: 10 choices
# per id 1, 2: right 10 (t0 < 10) + 0 (10..19) + 4 = 14; rejected 0 + 10 + 1 = 11;
# accepted 0 + 10 + 10 = 20. Id 3: 30 right, none rejected or accepted.
FOLLOWING_LAG10 = {"choices": 90, "rank1": 58 / 90, "rejected": 22 / 90, "accepted": 40 / 90}


def _check(result: dict, want: dict) -> None:
    assert result["choices"] == want["choices"]
    assert result["rank1"] == pytest.approx(want["rank1"], abs=1e-4)
    assert result["target_rejected"] == pytest.approx(want["rejected"], abs=1e-4)
    assert result["accepted_without_target"] == pytest.approx(want["accepted"], abs=1e-4)
    assert result["chance"] == pytest.approx(1 / 3, abs=1e-4)  # always three people


def test_the_figures_on_a_clip_with_a_colour_swap_are_the_ones_worked_out_by_hand(clip):
    video, boxes = clip
    choices = []
    report = evaluate(
        video, read_boxes(boxes), make_verifier("histogram"), lags=(10, 25), adapt_rate=0.1,
        on_choice=choices.append,
    )  # fmt: skip
    results = {(r["protocol"], r["lag"]): r for r in report.summary()["results"]}
    _check(results["one view", 10], ONE_VIEW_LAG10)
    _check(results["one view", 25], ONE_VIEW_LAG25)
    _check(results["following", 10], FOLLOWING_LAG10)
    # following at lag 25 only sees model frames before the swap: the same as one view
    _check(results["following", 25], ONE_VIEW_LAG25)
    # one choice spelled out: red (id 1) learnt in frame 15, sought in frame 25, where blue
    # (id 2) wears red: id 2 is chosen at distance 0, id 1 is at 1 (colour) + 0 (edges)
    c = next(
        c for c in choices
        if (c.protocol, c.lag, c.frame, c.target) == ("one view", 10, 25, 1)
    )  # fmt: skip
    d = dict(zip(c.ids, c.distances, strict=True))
    assert d[2] == pytest.approx(0.0, abs=1e-6) and d[1] == pytest.approx(1.0, abs=1e-6)
    # green: another colour; brighter than the floor, so each side's gradient points the
    # other way, but the four sides together give the same four orientations
    assert d[3] == pytest.approx(1.0, abs=1e-6)
    assert not c.outcome.correct and c.outcome.rejected and c.outcome.accepted_without_target
    assert report.adapts and report.threshold == 0.8
    assert report.counts == {"boxes": 120, "boxes_not_usable": 0}


def test_without_an_update_following_keeps_the_first_view(clip):
    video, boxes = clip
    report = evaluate(video, read_boxes(boxes), make_verifier("histogram"), lags=(10,),
                      adapt_rate=0.0)  # fmt: skip
    following = report.summary()["results"][1]
    # the first view is red for id 1 and blue for id 2: every choice frame after the swap
    # (t0 >= 10) goes to the other one: 10 right of 30 each, and id 3's 30
    assert following["protocol"] == "following" and not report.adapts
    assert following["rank1"] == pytest.approx(50 / 90, abs=1e-4)


def test_the_command_prints_the_table_and_writes_json_and_a_plot(clip, tmp_path):
    video, boxes = clip
    out, png = tmp_path / "out.json", tmp_path / "out.png"
    # the installed console script, as a user runs it
    run = subprocess.run(
        [Path(sys.executable).parent / "followbot", "appearance", str(video), str(boxes),
         "--lags", "10,25", "--adapt-rate", "0.1", "--json", str(out), "--plot", str(png),
         "--verifier", "histogram"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "| one view | 10 | 90 | 77.8 % | 33.3 % | 22.2 % | 22.2 % |" in run.stdout
    assert "| following | 10 | 90 | 64.4 % | 33.3 % | 24.4 % | 44.4 % |" in run.stdout
    summary = json.loads(out.read_text())
    assert summary["verifier"] == "histogram" and summary["frames"] == [0, 40]
    assert summary["boxes_file"]["format"] == "csv" and summary["boxes_file"]["boxes"] == 120
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_default_verifier_is_the_default_preset_s():
    from followbot.appearance import _service_defaults
    from followbot.services.runtime.compose import PRESETS

    assert _service_defaults()["verifier"] == PRESETS["followbot"]["vision_verify"]["verifier"]


def test_verifier_settings_and_frames_are_applied(clip, capsys):
    video, boxes = clip
    # frames 20-39 hold no swap: every choice is right (d = 0); with a threshold of 1.5 the
    # others, at d = 1, are all accepted when the target is removed
    code = main([str(video), str(boxes), "--lags", "10", "--frames", "20:40", "--quiet",
                 "--verifier", "histogram", "--set", "default_threshold=1.5"])  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert "histogram (threshold 1.5) on swap.avi, frames 20-39: 60 boxes" in out
    assert "| one view | 10 | 30 | 100.0 % | 33.3 % | 0.0 % | 100.0 % |" in out


def test_an_unknown_verifier_or_setting_is_named(clip, capsys):
    video, boxes = clip
    assert main([str(video), str(boxes), "--verifier", "nope"]) == 2
    assert "unknown verifier 'nope'; valid names: colour, face, histogram, meanshift" in (
        capsys.readouterr().err
    )
    assert main([str(video), str(boxes), "--set", "colour_wieght=1"]) == 2
    assert "colour_wieght" in capsys.readouterr().err


def test_meanshift_and_face_run_on_the_clip(clip):
    video, boxes = clip
    ms = evaluate(video, read_boxes(boxes), make_verifier("meanshift"), lags=(10,))
    r = ms.summary()["results"][0]
    assert r["choices"] == 90 and r["rank1"] > 0.5  # same colour before and after: right
    face = evaluate(video, read_boxes(boxes), make_verifier("face"), lags=(10,))
    r = face.summary()["results"][0]
    # rectangles have no face: nobody is judged, so no choice is right or accepted, every
    # target counts as rejected and is reported unjudged
    assert r["rank1"] == 0 and r["target_unjudged"] == 1 and r["accepted_without_target"] == 0
    assert not face.adapts


# --------------------------------------------------------------------------- scoring


def test_score_rules():
    assert score([0.2, 0.5, None], 0, 0.8) == (True, False, False, True)
    assert score([0.5, 0.5], 0, 0.8).correct is False  # a tie is no pick
    assert score([None, 0.9], 0, 0.8) == (False, True, True, False)  # unjudged: rejected
    assert score([0.8, 0.81], 0, 0.8) == (True, False, False, False)  # at the threshold: passes
    assert score([0.9, 0.3], 0, None) == (False, False, False, False)  # no threshold


@pytest.mark.parametrize("name", REGISTRY.names())
def test_a_box_distance_does_not_depend_on_the_other_boxes_judged(name, clip):
    """What lets "someone accepted, target removed" reuse the distances of the full frame."""
    video, _ = clip
    cap = cv2.VideoCapture(str(video))
    for _ in range(5):
        ok, bgr = cap.read()
    cap.release()
    assert ok
    camera = footage_camera(W, H)
    boxes = [Box(pid, *person_box(pid, 4)) for pid in (1, 2, 3)]
    cands, _ = frame_candidates(boxes, W, H, 0.5)
    verifier = make_verifier(name)
    frame = ImageFeatures(bgr)
    frame.cache["camera"] = camera
    if hasattr(verifier, "camera"):
        verifier.camera = camera
    model = learn_model(verifier, frame, cands[0], camera, 1)
    views = [view_of(c, i, camera) for i, c in enumerate(cands)]
    full = verifier.distances(frame, views, model)
    fresh = ImageFeatures(bgr)
    fresh.cache["camera"] = camera
    without = verifier.distances(fresh, [view_of(c, i, camera) for i, c in enumerate(cands[1:])],
                                 model)  # fmt: skip
    assert without == full[1:]


# --------------------------------------------------------------------------- box files


def test_mot_files_count_frames_from_one_and_skip_ignored_rows(tmp_path):
    p = tmp_path / "gt.txt"
    p.write_text(
        "1,7,10,20,16,40,1,1,1.0\n"  # MOT17 ground truth: frame 1 is the first frame
        "2,7,11,20,16,40,1,1,0.8\n"
        "2,8,50,20,16,40,0,3,1.0\n"  # flag 0: a box to ignore (e.g. a car)
        "3,-1,50,20,16,40,0.9,-1,-1,-1\n"  # a detection without identity
        "4,9,60.5,21.25,16,40\n"  # six columns only
    )
    b = read_boxes(p)
    assert b.format == "mot" and b.first_frame == 1
    assert {f: [x.id for x in bs] for f, bs in b.frames.items()} == {0: [7], 1: [7], 3: [9]}
    assert b.frames[3][0] == Box(9, 60.5, 21.25, 16.0, 40.0)
    assert b.rejected == {
        "marked to ignore (MOT flag 0)": [1, 3],
        "no identity (id < 0: a detections file?)": [1, 4],
    }
    # a MOT-style file whose frames count from 0
    b0 = read_boxes(p, first_frame=0)
    assert sorted(b0.frames) == [1, 2, 4]
    # numbers in exponent form are still a MOT row, not a header
    p.write_text("1,7,1e1,20,16,40\n")
    assert read_boxes(p).frames == {0: [Box(7, 10.0, 20.0, 16.0, 40.0)]}


def test_a_mot_file_of_the_clip_gives_the_same_figures_as_its_csv(clip, tmp_path):
    video, boxes = clip
    mot = tmp_path / "gt.txt"
    mot.write_text(
        "".join(
            f"{f + 1},{pid},{x},{y},{w},{h},1,1,1.0\n"
            for f in range(FRAMES)
            for pid in (1, 2, 3)
            for x, y, w, h in [person_box(pid, f)]
        )
    )

    def figures(b):
        report = evaluate(video, b, make_verifier("histogram"), lags=(10,), adapt_rate=0.1)
        return [{k: v for k, v in r.items() if "ms" not in k} for r in report.summary()["results"]]

    assert figures(read_boxes(mot)) == figures(read_boxes(boxes))
    # read as if frame 1 were the video's second frame, every box is a frame late
    assert figures(read_boxes(mot, first_frame=0)) != figures(read_boxes(boxes))


def test_the_pets09_csv_counts_frames_from_zero_and_finds_columns_by_name(tmp_path):
    p = tmp_path / "boxes.csv"
    # (with the byte-order mark a spreadsheet may put first)
    p.write_text("\ufeffid,frame,w_px,h_px,x_px,y_px,note\n9,0,31.03,75.17,499.2,157.69,a\n")
    b = read_boxes(p)
    assert b.format == "csv" and b.first_frame == 0
    assert b.frames == {0: [Box(9, 499.2, 157.69, 31.03, 75.17)]}


def test_bad_rows_are_counted_by_reason_with_their_first_line(tmp_path, clip, capsys):
    video, _ = clip
    p = tmp_path / "bad.csv"
    p.write_text(
        "frame,id,x_px,y_px,w_px,h_px\n"
        "0,1,5,40,16,40\n"
        "0,2,55,40,16,40\n"
        "zero,1,5,40,16,40\n"  # line 4
        "0,3,nan,40,16,40\n"  # line 5
        "0,3\n"  # line 6
        "1.5,1,6,40,16,40\n"  # line 7
        "0,1,5,40,16,40\n"  # line 8: id 1 again in frame 0
        "1,3,105,40,0,40\n"  # line 9: no width
        "\n"
        "1,1,6,40,16,40\n"
        "1,2,56,40,16,40\n"
    )
    b = read_boxes(p)
    assert b.rows == 10 and b.boxes == 4
    assert b.rejected == {
        "not a finite number": [2, 4],
        "too few columns": [1, 6],
        "frame or id not a whole number": [1, 7],
        "id twice in one frame": [1, 8],
        "empty box (width or height <= 0)": [1, 9],
    }
    # the command reports them and goes on
    out = tmp_path / "out.json"
    assert main([str(video), str(p), "--lags", "1", "--quiet", "--json", str(out)]) == 0
    err = capsys.readouterr().err
    assert "2 rows skipped: not a finite number (first: line 4)" in err
    rejected = json.loads(out.read_text())["boxes_file"]["rejected"]
    assert rejected["id twice in one frame"] == {"rows": 1, "first_line": 8}


def test_a_box_file_without_a_usable_box_is_a_clear_error(tmp_path, clip, capsys):
    video, _ = clip
    p = tmp_path / "none.txt"
    p.write_text("1,-1,5,5,10,10,0.9,-1,-1,-1\n")
    with pytest.raises(BoxFileError, match="no usable box"):
        read_boxes(p)
    p.write_text("frame,id,x,y,w,h\n0,1,5,5,10,10\n")
    with pytest.raises(BoxFileError, match="names no x_px, y_px, w_px, h_px column"):
        read_boxes(p)
    assert main([str(video), str(tmp_path / "missing.csv")]) == 2
    assert "cannot read box file" in capsys.readouterr().err


# --------------------------------------------------------------------------- boxes in frames


def test_boxes_past_the_border_are_clipped_and_mostly_outside_ones_skipped():
    boxes = [
        Box(1, -8, 10, 16, 40),  # half outside on the left
        Box(2, 150, 100, 20, 40),  # x: 10 of 20 inside, y: 20 of 40 -> a quarter
        Box(3, 60, 10, 16, 40),
    ]
    assert visible_fractions(boxes, W, H) == pytest.approx([0.5, 0.25, 1.0])
    cands, skipped = frame_candidates(boxes, W, H, min_visible=0.5)
    assert [c.id for c in cands] == [1, 3] and skipped == 1
    assert cands[0].rect == (0, 10, 8, 50) and cands[0].body == (-8, 10, 8, 50)
    v = view_of(cands[0], 0, footage_camera(W, H))
    assert v.rect == (0, 10, 8, 50) and v.body == (-8.0, 10.0, 8.0, 50.0) and v.ok
    cands, _ = frame_candidates(boxes, W, H, min_visible=0.2)
    assert [c.id for c in cands] == [1, 2, 3]
    assert cands[1].rect == (150, 100, 160, 120)


def test_a_nearer_box_hides_what_it_covers():
    far = Box(1, 10, 10, 20, 40)  # bottom edge at row 50
    near = Box(2, 20, 20, 20, 40)  # bottom edge at row 60: nearer, covers far's right half
    # of far's 20 x 40, columns 20-29 and rows 20-49 are covered: 10 x 30 of 800
    assert visible_fractions([far, near], W, H) == pytest.approx([1 - 300 / 800, 1.0])
    assert visible_fractions([far, near], W, H, occlusion=False) == [1.0, 1.0]
    hidden = Box(3, 22, 25, 10, 30)  # wholly inside near, bottom edge higher
    cands, skipped = frame_candidates([far, near, hidden], W, H, min_visible=0.5)
    assert [c.id for c in cands] == [1, 2] and skipped == 1


def test_the_pseudo_geometry_puts_a_box_on_its_bearing():
    camera = footage_camera(W, H)
    cands, _ = frame_candidates([Box(1, 100, 20, 20, 60)], W, H, 0.5)
    v = view_of(cands[0], 0, camera)
    assert v.depth_m == pytest.approx(camera.f * 1.7 / 60)
    # the candidate's bearing is the bearing of its box's centre column
    assert math.atan2(v.lateral_m, v.depth_m) == pytest.approx(float(camera.bearing(110.0)))
    assert v.u_px == 110.0


# --------------------------------------------------------------------------- videos


def test_a_video_that_does_not_open_is_a_clear_error(tmp_path, clip, capsys):
    _, boxes = clip
    fake = tmp_path / "notes.avi"
    fake.write_text("not a video\n")
    with pytest.raises(FootageError, match="OpenCV cannot open"):
        evaluate(fake, read_boxes(boxes), make_verifier("histogram"), lags=(1,))
    assert main([str(fake), str(boxes)]) == 2
    assert "OpenCV cannot open" in capsys.readouterr().err
    assert main([str(tmp_path / "missing.avi"), str(boxes)]) == 2
    assert "no video file" in capsys.readouterr().err


def test_boxes_beyond_the_video_are_counted(tmp_path, clip):
    video, _ = clip
    p = tmp_path / "long.csv"
    p.write_text(
        "frame,id,x_px,y_px,w_px,h_px\n"
        + "".join(f"{f},1,5,40,16,40\n{f},2,55,40,16,40\n" for f in (0, 1, 45, 46))
    )
    report = evaluate(video, read_boxes(p), make_verifier("histogram"), lags=(1,))
    assert report.frames == (0, 40)
    assert report.counts["boxes_after_the_video"] == 4


@pytest.mark.parametrize(
    "args, message",
    [
        (["--lags", "0"], "--lags: must be whole numbers"),
        (["--frames", "30:10"], "--frames: must be FIRST:END"),
        (["--min-visible", "1.5"], "--min-visible: must be a number in [0, 1]"),
    ],
)
def test_bad_options_are_refused_with_the_rule(args, message, clip, capsys):
    video, boxes = clip
    with pytest.raises(SystemExit) as exc:
        main([str(video), str(boxes), *args])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


# --------------------------------------------------------------------------- real footage

_PETS09 = Path(__file__).resolve().parents[1].parent / "shared/data/pets09/S2L1_frames_000-399.csv"


def test_on_pets09_the_histogram_verifier_beats_chance():
    from vision_verify.helpers import HOW, opencv_sample

    video = opencv_sample("vtest.avi")
    if video is None:
        pytest.skip(f"opencv-doc's vtest.avi {HOW}")
    if not _PETS09.is_file():
        pytest.skip(f"the pets09 boxes are not at {_PETS09}")
    report = evaluate(video, read_boxes(_PETS09), make_verifier("histogram"), lags=(25,),
                      frames=(0, 120))  # fmt: skip
    one = report.summary()["results"][0]
    assert one["choices"] > 300
    assert one["rank1"] > 2 * one["chance"]
