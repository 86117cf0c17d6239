import itertools
import math

import msgspec
import numpy as np
import pytest

from followbot.services.sim.people import Person
from followbot.services.sim.scenario import PersonSpec, builtin_names, load_builtin


def _person(**fields) -> Person:
    return Person(msgspec.convert({"id": 1, "start": [0.0, 0.0], **fields}, PersonSpec))


def test_walking_gait_two_steps_a_second_at_0_3_m():
    # thesis 5.2.2: 300 mm steps, two steps per second, 600 mm/s
    p = _person(speed_mps=0.6, path=[{"kind": "walk", "to": [30.0, 0.0]}])
    ts = np.arange(2.0, 6.0, 0.01)
    states = [p.state(t) for t in ts]
    along = np.array([s.legs[0, 0] - s.legs[1, 0] for s in states])
    assert along.max() == pytest.approx(0.3, abs=0.01)
    assert along.min() == pytest.approx(-0.3, abs=0.01)
    # the legs pass each other (sign change of the along-track gap) twice per stride: 2 steps/s
    crossings = np.count_nonzero(np.diff(np.sign(along)) != 0)
    assert crossings == pytest.approx(2 * (ts[-1] - ts[0]), abs=1)
    speeds = [np.hypot(*s.velocity) for s in states]
    assert np.allclose(speeds, 0.6)
    lateral = np.array([s.legs[0, 1] - s.legs[1, 1] for s in states])
    assert np.allclose(lateral, 0.18)


def test_stance_foot_stays_on_the_floor():
    p = _person(speed_mps=0.6, path=[{"kind": "walk", "to": [30.0, 0.0]}])
    # leg 0 is in stance while (s / L) mod 2 is in [0, 1): s in [1.2, 1.5) at t in [2, 2.5)
    feet = np.array([p.state(t).legs[0] for t in np.linspace(2.0, 2.49, 20)])
    assert np.ptp(feet[:, 0]) < 1e-9


def test_arc_keeps_the_radius():
    p = _person(start=[1.2, 0.0], path=[{"kind": "arc", "centre": [0.0, 0.0], "sweep_deg": 90.0}])
    for t in np.linspace(0.0, p.duration_s, 30):
        assert np.hypot(*p.state(t).position) == pytest.approx(1.2)
    end = p.state(p.duration_s + 1.0)
    assert end.position == pytest.approx([0.0, 1.2], abs=1e-9)
    assert np.hypot(*end.velocity) == 0.0


@pytest.mark.parametrize(("stance", "gap"), [("together", 0.14), ("apart", None)])
def test_standing_pose_after_stopping(stance, gap):
    p = _person(
        path=[{"kind": "walk", "to": [1.0, 0.0]}, {"kind": "pause", "duration_s": 5.0}],
        gait={"stance": stance},
    )
    s = p.state(1.0 / 0.6 + 1.0)  # 1 s into the pause: blend finished
    sep = np.hypot(*(s.legs[0] - s.legs[1]))
    if gap is not None:
        assert sep == pytest.approx(gap)
    else:
        assert sep > 0.3
    assert np.allclose(s.legs.mean(axis=0), s.position)


def test_turn_on_the_spot_at_the_turn_rate():
    p = _person(
        heading_deg=0.0,
        path=[{"kind": "turn", "heading_deg": 90.0}],
        gait={"turn_rate_deg_s": 90.0},
    )
    assert p.state(0.5).heading_rad == pytest.approx(math.radians(45))
    assert p.state(2.0).heading_rad == pytest.approx(math.radians(90))


def test_looping_path_repeats():
    p = _person(
        loop=True,
        path=[{"kind": "walk", "to": [1.2, 0.0]}, {"kind": "walk", "to": [0.0, 0.0]}],
    )
    period = p.duration_s
    for t in (0.3, 1.1, 2.9):
        assert p.state(t).position == pytest.approx(p.state(t + 3 * period).position)


def _end_heading(ph) -> float:
    """The heading a compiled phase leaves the person with (the next phase's heading0)."""
    if ph.kind == "arc":
        a1 = ph.path_heading_rad + ph.sign * ph.speed_mps * ph.duration_s / ph.radius_m
        return a1 + ph.sign * math.pi / 2
    return ph.path_heading_rad  # line: direction of travel; stand: its goal


def _assert_phases_join_up(person: Person) -> None:
    phases = [ph for ph in person.phases if math.isfinite(ph.duration_s)]
    for prev, ph in itertools.pairwise(phases):
        assert ph.t0 == pytest.approx(prev.t1, abs=1e-9)
        assert ph.s0_m == pytest.approx(prev.s0_m + prev.speed_mps * prev.duration_s, abs=1e-9)
        turn = math.remainder(ph.heading0_rad - _end_heading(prev), math.tau)
        assert turn == pytest.approx(0.0, abs=1e-9)
        if ph.kind == "stand":  # the legs blend into the stance pose after a walk, and out
            assert ph.after_walk == (prev.kind != "stand")
        else:
            assert ph.after_stand == (prev.kind == "stand")
        end = person.state(prev.t1 - 1e-9).position
        assert person.state(ph.t0).position == pytest.approx(end, abs=1e-6)
    walked = sum(ph.speed_mps * ph.duration_s for ph in phases)
    assert person.path_length_m == pytest.approx(walked, abs=1e-9)


def test_a_script_compiles_to_phases_that_join_up():
    """Each phase starts when, where and with the heading and walked distance the previous
    one leaves; steps that go nowhere (a walk to where the person is, a 0 deg arc) are left
    out."""
    p = _person(
        heading_deg=30.0,
        path=[
            {"kind": "walk", "to": [2.0, 0.0]},
            {"kind": "walk", "to": [2.0, 0.0]},  # already there: no phase
            {"kind": "arc", "centre": [2.0, 1.0], "sweep_deg": 135.0, "speed_mps": 0.5},
            {"kind": "arc", "centre": [0.0, 0.0], "sweep_deg": 0.0},  # no phase
            {"kind": "pause", "duration_s": 1.0},
            {"kind": "turn", "heading_deg": -120.0},
            {"kind": "arc", "centre": [0.0, 0.0], "sweep_deg": -90.0},
            {"kind": "walk", "to": [-1.0, -1.0], "speed_mps": 1.2},
        ],
    )
    assert [ph.kind for ph in p.phases[:-1]] == ["line", "arc", "stand", "stand", "arc", "line"]
    assert p.phases[2].after_walk and not p.phases[3].after_walk
    _assert_phases_join_up(p)


@pytest.mark.parametrize("name", builtin_names())
def test_builtin_scripts_compile_to_phases_that_join_up(name):
    for spec in load_builtin(name).people:
        _assert_phases_join_up(Person(spec))
