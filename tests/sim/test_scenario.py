import pytest

from followbot.services.sim.scenario import (
    ScenarioError,
    builtin_names,
    json_schema,
    load_builtin,
    load_scenario,
)
from followbot.services.sim.simulation import Simulation

GOOD = """
name: ok
people:
  - id: 1
    start: [2.0, 0.0]
    path:
      - {kind: walk, to: [3.0, 0.0]}
"""


def test_builtin_library_is_there():
    names = builtin_names()
    for expected in (
        "thesis_5_2_1_arc",
        "thesis_5_2_2_straight",
        "thesis_5_2_4_two_people",
        "livingston_box_occlusion",
        "door_corner",
    ):
        assert expected in names


@pytest.mark.parametrize("name", builtin_names())
def test_builtin_scenarios_load_and_run(name):
    sim = Simulation(load_builtin(name))
    msgs = []
    while sim.t_s < 1.0:
        msgs += sim.tick()
    kinds = {type(m).__name__ for m in msgs}
    assert kinds == {"LaserScan", "GroundTruth", "Image", "Odometry"}


def test_good_file_loads(tmp_path):
    path = tmp_path / "ok.yaml"
    path.write_text(GOOD)
    sc = load_scenario(path)
    assert sc.people[0].path[0].to == (3.0, 0.0)


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        (
            GOOD.replace("start: [2.0, 0.0]", "start: [2.0, fast]"),
            ["Expected `float`, got `str`", "$.people[0].start[1]"],
        ),
        (GOOD.replace("start:", "sart:"), ["unknown field `sart`", "$.people[0]"]),
        (
            GOOD.replace("kind: walk", "kind: wlak"),
            ["Invalid value 'wlak'", "$.people[0].path[0].kind"],
        ),
        (
            GOOD + "laser: {range_noise_m: -1}\n",
            ["Expected `float` >= 0.0", "$.laser.range_noise_m"],
        ),
        (GOOD + "  - id: 1\n    start: [1, 1]\n", ["person ids must be unique"]),
        ("name: x\npeople: [\n", ["not valid YAML"]),
        ("- just\n- a list\n", ["expected a mapping"]),
    ],
)
def test_broken_file_names_the_file_field_and_fault(tmp_path, text, needles):
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    msg = str(err.value)
    assert "broken.yaml" in msg
    for needle in needles:
        assert needle in msg


def test_missing_file_and_unknown_builtin():
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario("/nonexistent/scenario.yaml")
    with pytest.raises(ScenarioError, match="thesis_5_2_1_arc"):
        load_builtin("no_such_scenario")


def test_json_schema_describes_the_format():
    schema = json_schema()
    defs = schema["$defs"]
    assert "Scenario" in defs and "PersonSpec" in defs and "WalkStep" in defs
    assert defs["Scenario"]["additionalProperties"] is False
    assert "people" in defs["Scenario"]["properties"]
