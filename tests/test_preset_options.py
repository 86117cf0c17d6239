"""``--preset``: the pipeline commands take it alike, and ``followbot run SERVICE --preset NAME``
starts a service from that preset's part, under its settings file and ``--set``."""

from __future__ import annotations

import pytest
import yaml

from followbot import benchmark, demo, eval_cli, track
from followbot.services.runtime.compose import PRESETS
from followbot.services.runtime.container import main as run_together
from followbot.services.runtime.container import split_settings
from followbot.services.tracker.node import main as run_tracker

#: command -> (its main, the arguments it requires)
COMMANDS = {
    "track": (track.main, ["run.bag", "--output", "out"]),
    "eval": (eval_cli.main, ["--output", "out"]),
    "demo": (demo.main, []),
    "benchmark": (benchmark.main, []),
}


@pytest.mark.parametrize("name", COMMANDS)
def test_every_pipeline_command_takes_the_same_preset_and_set_options(name, capsys):
    main, required = COMMANDS[name]
    with pytest.raises(SystemExit) as exit_:
        main([*required, "--help"])
    assert exit_.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert f"--preset NAME system preset: {', '.join(PRESETS)} (default: followbot" in text
    assert "--set SERVICE.KEY=VALUE a stage setting on top of the preset" in text
    with pytest.raises(SystemExit) as exit_:
        main([*required, "--preset", "nope"])
    assert exit_.value.code == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err


def tracker_settings(capsys, *argv: str) -> tuple[int, dict, str]:
    code = run_tracker([*argv, "--print-settings"])
    out, err = capsys.readouterr()
    return code, (yaml.safe_load(out) if code == 0 else {}), err


def test_run_preset_starts_a_service_from_the_preset_under_its_file_and_set(tmp_path, capsys):
    code, own, _ = tracker_settings(capsys)  # no preset: the settings' own defaults
    assert code == 0 and own["initiator"] == "hits" and own["estimator_settings"] == {}
    code, s, _ = tracker_settings(capsys, "--preset", "followbot")
    assert code == 0 and s["initiator"] == "evidence"
    assert s["estimator_settings"] == {"gate_m": 0.5}
    assert s["max_misses"] == own["max_misses"]  # what the preset does not name: the defaults
    cfg = tmp_path / "tracker.yaml"
    cfg.write_text("initiator: hits\n")
    code, s, _ = tracker_settings(
        capsys, "--preset", "followbot", "--config", str(cfg),
        "--set", "estimator_settings.particles=300",
    )  # fmt: skip
    assert code == 0 and s["initiator"] == "hits"  # the file over the preset
    assert s["estimator_settings"] == {"gate_m": 0.5, "particles": 300}  # --set merged on top
    code, s, _ = tracker_settings(capsys, "--preset", "bellotto")
    assert code == 0 and s["estimator"] == "ukf"


def test_run_refuses_an_unknown_preset_naming_the_presets(capsys):
    code, _, err = tracker_settings(capsys, "--preset", "nope")
    assert code == 2
    assert "--preset: unknown preset 'nope'; presets: followbot, thesis" in err


def test_services_run_together_each_take_their_part_of_the_preset(capsys):
    presets = {"laser_legs": {"detector": "learned"}, "tracker": {"initiator": "evidence"}}
    data = {"log_level": "warning", "tracker": {"seed": 3}}
    _, merged = split_settings(["laser_legs", "tracker"], data, ["tracker.seed=4"], presets)
    assert merged["laser_legs"] == {"detector": "learned", "log_level": "warning"}
    assert merged["tracker"] == {"initiator": "evidence", "log_level": "warning", "seed": 4}
    argv = ["--preset", "followbot", "--set", "tracker.initiator=hits", "--print-settings"]
    assert run_together(["laser_legs", "tracker"], argv) == 0
    out = capsys.readouterr().out
    laser, tracker = (yaml.safe_load(part) for part in out.split("# tracker\n"))
    assert laser["detector"] == "learned"
    assert tracker["initiator"] == "hits" and tracker["estimator_settings"] == {"gate_m": 0.5}
