"""followbot sweep: the grid, the figures summed up from known metrics, refusals, and one
real run through the pipeline (resumed, not run twice)."""

from __future__ import annotations

import json

import pytest

from followbot.sweep import HARD, aggregate, code_fingerprint, grid, main, report, run_key


def metric(scenario, rmse=0.05, tracked=1.0, wrong=0.0, switches=0, episodes=(), followed=1.0):
    return {
        "scenario": scenario,
        "rmse_m": rmse,
        "tracked_visible_share_acquired": tracked,
        "wrong_target_s": wrong,
        "identity_switches": switches,
        "reacquire_s_episodes": list(episodes),
        "followed_share_acquired": followed,
    }


def test_the_standard_grid_is_the_84_runs_of_the_docs():
    from followbot.eval_cli import builtin_scenarios

    runs = grid("standard", builtin_scenarios())
    assert len(runs) == 84 and len(set(runs)) == 84
    assert {seed for s, seed in runs if s not in HARD} == {None, 1, 2, 3}
    assert {seed for s, seed in runs if s in HARD} == {None, 1, 2, 3, 4, 6}
    assert grid("own", ["crowd_ten"]) == [("crowd_ten", None)]


def test_aggregate_counts_each_target_as_the_issues_state_it():
    metrics = {
        "a": metric("thesis_5_2_4_side_by_side", rmse=0.08, switches=1, wrong=0.12),
        "b": metric("thesis_5_2_4_two_people", rmse=0.081, tracked=0.979),
        "c": metric("occlusion_pillar", episodes=[0.5, 1.0, 1.56, None], wrong=1.0, followed=0.5),
        "d": metric("crowd_ten", rmse=None, tracked=None, followed=None),
    }
    s = aggregate(metrics)
    assert s["runs"] == 4
    assert s["rmse_ok"] == 2  # 0.08 meets <= 0.08; 0.081 and no RMSE do not
    assert s["tracked_ok"] == 2
    assert s["wrong_s"] == pytest.approx(1.12)
    assert (s["two_person_runs"], s["two_person_switch_runs"], s["two_person_switch_s"]) == (
        2, 1, 0.12,
    )  # fmt: skip
    assert (s["occlusions"], s["reacquire_never"], s["reacquire_within_1s"]) == (4, 1, 2)
    assert s["reacquire_mean_s"] == pytest.approx((0.5 + 1.0 + 1.56) / 3, abs=0.005)
    assert s["followed_mean"] == pytest.approx((1.0 + 1.0 + 0.5) / 3, abs=0.0005)
    # the parts of the waits, over the episodes where they came (none reported: None)
    assert s["reacquire_laser_mean_s"] is None
    metrics["c"]["reacquire_laser_s_episodes"] = [0.1, 0.2, None, 0.6]
    metrics["c"]["reacquire_camera_s_episodes"] = [0.4, None, None, None]
    metrics["c"]["reacquire_turn_s_episodes"] = [0.0, 0.5, 0.1, 0.2]
    s = aggregate(metrics)
    assert s["reacquire_turn_mean_s"] == pytest.approx(0.2)
    assert s["reacquire_laser_mean_s"] == pytest.approx(0.3)
    assert s["reacquire_camera_mean_s"] == pytest.approx(0.4)
    # the simulator's bumper: runs with a contact, and the contacts (missing: none)
    assert (s["bump_runs"], s["bumps"]) == (0, 0)
    metrics["a"]["robot_bumps"], metrics["b"]["robot_bumps"] = 2, 0
    s = aggregate(metrics)
    assert (s["bump_runs"], s["bumps"]) == (1, 2)


def test_report_against_another_sweep_lists_only_the_runs_that_differ():
    before = {"x__own": metric("crowd_ten"), "y__own": metric("door_corner", rmse=0.07)}
    after = {"x__own": metric("crowd_ten"), "y__own": metric("door_corner", rmse=0.09)}
    text = report(after, aggregate(after), "after", ("before", aggregate(before), before))
    assert "1 runs give the same figures" in text
    assert "| y__own (before) | 0.070 |" in text and "| y__own (after) | 0.090 |" in text
    assert "x__own (" not in text
    assert "| RMSE <= 0.08 m | 2 | 1 |" in text


def test_bad_arguments_are_refused_before_any_run(tmp_path, capsys):
    assert main(["--output", str(tmp_path / "a"), "--scenario", "nowhere"]) == 2
    assert "unknown scenario" in capsys.readouterr().err
    assert main(["--output", str(tmp_path / "a"), "--set", "oops=1"]) == 2
    assert main(["--output", str(tmp_path / "a"), "--seeds", "1,x"]) == 2
    assert main(["--output", str(tmp_path / "a"), "--against", str(tmp_path / "none")]) == 2
    assert not (tmp_path / "a").exists()


@pytest.mark.multiprocess
def test_a_sweep_runs_the_real_pipeline_and_resumes(tmp_path, capsys):
    out = tmp_path / "sweep"
    args = ["--output", str(out), "--scenario", "thesis_5_2_1_arc", "--seeds", "own", "--jobs", "1"]
    assert main(args) == 0
    doc = json.loads((out / "sweep.json").read_text())
    m = doc["runs"][run_key("thesis_5_2_1_arc", None)]
    assert m["scenario"] == "thesis_5_2_1_arc" and m["rmse_m"] < 0.1  # the arc walk is followed
    assert doc["summary"]["runs"] == 1
    capsys.readouterr()
    assert main(args) == 0  # the run's file is there: nothing is run again
    assert "[1/1]" not in capsys.readouterr().err
    # other settings into the same folder are refused
    assert main([*args, "--set", "tracker.max_misses=4"]) == 2


def test_a_sweep_over_other_code_is_refused(tmp_path, capsys):
    """The runs of a folder were made with one version of the source; resuming there with
    another is refused before any run (as other settings are)."""
    out = tmp_path / "sweep"
    (out / "runs").mkdir(parents=True)
    (out / "sweep_settings.json").write_text(json.dumps({"set": [], "code": "0" * 16}))
    args = ["--output", str(out), "--scenario", "thesis_5_2_1_arc", "--seeds", "own"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "other code" in err and code_fingerprint() in err
    assert not list((out / "runs").iterdir())


@pytest.mark.multiprocess
def test_a_sweep_whose_code_changes_while_it_runs_stops_and_drops_that_run(
    tmp_path, capsys, monkeypatch
):
    """An edit to the source while a sweep runs (an editable install runs the working tree)
    stops it at the next finished run, which is dropped: the runs after the edit would mix
    versions. The fingerprint is made to change after the sweep started."""
    import followbot.sweep as sweep

    versions = iter(["a" * 16, "b" * 16])
    monkeypatch.setattr(sweep, "code_fingerprint", lambda: next(versions, "b" * 16))
    out = tmp_path / "sweep"
    args = ["--output", str(out), "--scenario", "thesis_5_2_1_arc", "--seeds", "own", "--jobs", "1"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "the code changed while the sweep ran" in err and "a" * 16 in err
    assert not list((out / "runs").glob("*.json")) and not (out / "sweep.json").exists()
