import numpy as np
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
        "thesis_5_2_3_room_corridor",
        "thesis_5_2_4_side_by_side",
        "thesis_5_2_4_turn_apart",
        "thesis_5_2_4_two_people_swapped",
        "bellotto_cluttered_office",
        "ristic_wall_corridor",
        "ristic_circles",
        "crowd_ten",
        "occlusion_pillar",
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


def _clearance(points: np.ndarray, segments: np.ndarray, circles: np.ndarray) -> np.ndarray:
    """Distance from each of (N, 2) points to the nearest wall segment or circle surface."""
    d = np.full(points.shape[0], np.inf)
    if segments.shape[0]:
        a, e = segments[None, :, :2], segments[None, :, 2:] - segments[None, :, :2]
        rel = points[:, None, :] - a
        t = np.clip((rel * e).sum(-1) / np.maximum((e * e).sum(-1), 1e-12), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(rel - t[..., None] * e, axis=-1).min(axis=1))
    if circles.shape[0]:
        dc = np.linalg.norm(points[:, None, :] - circles[None, :, :2], axis=-1) - circles[:, 2]
        d = np.minimum(d, dc.min(axis=1))
    return d


@pytest.mark.parametrize("name", builtin_names())
def test_builtin_people_never_walk_through_walls_or_obstacles(name):
    sim = Simulation(load_builtin(name))
    times = np.arange(0.0, sim.scenario.duration_s, 0.2)
    states = []  # as the simulation places them: giving way to each other and the (still) robot
    for t in times:
        sim.advance_to(round(t * 1e9))
        states.append(sim.people_states())
    for k, person in enumerate(sim.people):
        legs = np.concatenate([s[k].legs for s in states])
        gap = _clearance(legs, sim.world.segments, sim.world.circles) - person.leg_radius_m
        worst = int(np.argmin(gap))
        assert gap[worst] > 0.0, (
            f"person {person.id} at t={times[worst // 2]:.1f} s: a leg at {legs[worst]} "
            f"overlaps the static world by {-gap[worst]:.3f} m"
        )


@pytest.mark.parametrize("name", [n for n in builtin_names() if n != "door_corner"])
def test_builtin_target_starts_visible_to_the_laser(name):
    sim = Simulation(load_builtin(name))
    (target,) = [p for p in sim.truth().people if p.is_target]
    assert target.visible_laser
