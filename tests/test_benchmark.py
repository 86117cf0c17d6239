"""``followbot benchmark``: the real-data suite. A quick slice runs here, through the real CLI
and the real pipeline processes, and fails when a figure falls below the floor set a little
under what today's defaults measure (docs/benchmark.md has the full figures)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from followbot import benchmark

DATA = benchmark.default_data_dir()


def test_the_target_s_losses_and_id_changes_are_counted_from_the_rows():
    # people rows (stamp, id, x, y): the target is id 1, lost at stamp 3, taken again as id 2
    people = [(t, 1, 1.0, 0.0) for t in (1, 2)] + [(t, 2, 1.0, 0.0) for t in (3, 4, 5)]
    people += [(60_000_000_001, 3, 2.0, 0.0)]
    target = [(1, 1, 1.0, 0.0), (2, 1, 1.0, 0.0), (4, 2, 1.0, 0.0), (5, 2, 1.0, 0.0)]
    r = benchmark._judge_people(people, target, scans=6)
    assert (r["target_lost"], r["target_taken_again"], r["target_id_changes"]) == (2, 1, 1)
    assert r["new_person_ids_per_minute"] == pytest.approx(3.0, abs=0.1)
    assert r["target_held_after_first_chosen"] == pytest.approx(4 / 6, abs=1e-3)


def test_legs360_walker_and_ghosts_are_judged_against_the_labels(tmp_path):
    (tmp_path / "legs360").mkdir()
    (tmp_path / "legs360" / "legs360_labels.csv").write_text(
        "stamp_ns,scan,x_m,y_m,points\n10,0,1.0,0.1,5\n10,0,1.0,-0.1,5\n20,1,2.0,0.0,4\n"
    )
    # scan 10: the walker tracked and followed, plus a ghost; scan 20: only a ghost
    people = [(10, 1, 1.05, 0.0), (10, 2, -1.0, 0.0), (20, 2, -1.0, 0.0)]
    target = [(10, 1, 1.05, 0.0), (20, 2, -1.0, 0.0)]
    r = benchmark._judge_walker(people, target, [10, 20], tmp_path)
    assert r["walker_tracked"] == 0.5 and r["walker_followed"] == 0.5
    assert r["false_people_per_scan"] == 1.0 and r["scans_with_a_false_person"] == 1.0


def test_a_missing_data_folder_skips_each_section_with_its_reason(tmp_path):
    report = benchmark.run(tmp_path, tmp_path / "out", ["default"], list(benchmark.SECTIONS), True)
    for name in benchmark.SECTIONS:
        assert "not found" in report["sections"][name]["skipped"], name
    assert "Skipped:" in benchmark.markdown({**report, "command": "x"})


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    if not (DATA / "leg_tracker" / "negative_2.bag").is_file():
        pytest.skip(f"the real data is not at {DATA} (set FOLLOWBOT_DATA)")
    out = tmp_path_factory.mktemp("bench")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "followbot",
            "benchmark",
            str(DATA),
            "--quick",
            "--output",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (out / "benchmark.md").is_file() and (out / "false_people.png").is_file()
    return json.loads((out / "benchmark.json").read_text())


def test_quick_detectors_keep_their_recall_and_false_candidates(quick):
    rows = {r["detector"]: r for r in quick["sections"]["detectors"]["rows"]}
    assert rows["thesis"]["leg_recall"] >= 0.45
    assert rows["thesis"]["false_candidates_per_scan"] <= 2.0
    assert rows["learned"]["leg_recall"] >= 0.93
    assert rows["learned"]["false_candidates_per_scan"] <= 2.0


def test_quick_pipeline_false_people_stay_under_today_s_ceiling(quick):
    rows = quick["sections"]["people"]["presets"]["default"]
    carmen = [r for name, r in rows.items() if not name.startswith(("negative", "legs", "demo"))]
    assert len(carmen) == 8 and all("error" not in r for r in carmen)
    mean = sum(r["false_people_per_scan"] for r in carmen) / len(carmen)
    assert mean <= 3.5
    assert rows["negative_2:rear_scan"]["false_people_per_scan"] <= 4.2
    assert rows["legs360"]["walker_tracked"] >= 0.08
    assert rows["demo_stationary"]["scans_per_s"] > 0


def test_quick_appearance_keeps_its_rank1(quick):
    app = quick["sections"]["appearance"]
    if "skipped" in app:
        pytest.skip(app["skipped"])
    results = app["verifiers"]["histogram"]["results"]
    one_view = next(r for r in results if r["protocol"] == "one view" and r["lag"] == 25)
    assert one_view["rank1"] >= 0.70
