"""The simulator evaluation (evaluate.py): the hidden-target scene measures what it claims."""

from __future__ import annotations

import pytest

from followbot.research import vision_evaluate as evaluate
from followbot.research.vision_evaluate import SimScore, calibrate, evaluate_sim


def test_hidden_target_scene_hides_the_target_while_a_bystander_is_in_view():
    """First 25 s of hidden_target_bystanders: the model is learnt from the target, the target
    is judged in view, then hides behind the partition while bystander 2 walks in view. The
    histogram verifier takes the target when it is there and, with its threshold, nobody while
    it hides; without the threshold something is always taken."""
    s = evaluate_sim("histogram", scenario="hidden_target_bystanders", follow=False, duration_s=25)
    assert s.model_built_s is not None and s.model_built_s < 4.0
    assert s.target_in_view >= 40
    assert s.correct >= 0.97 * s.target_in_view
    assert s.hidden_with_others >= 50  # a real measurement, not one scan
    assert s.bystander_hidden_no_threshold == s.hidden_with_others
    assert s.hidden_chosen_by_no_threshold.get(2, 0) >= 40  # mostly the bystander, id 2
    assert s.bystander_hidden == 0


def test_calibration_is_midway_between_target_p99_and_apart_p1(monkeypatch):
    def fake(verifier_name, *, scenario, follow):
        sc = SimScore(verifier=verifier_name, scenario=scenario, threshold=None)
        sc.target_d = [0.1 + 0.005 * k for k in range(101)]  # p99 = 0.595
        sc.apart_d = [0.8 + 0.004 * k for k in range(101)]  # p1 = 0.804
        sc.other_d = [0.0]  # overlapping the target: not used
        return sc

    monkeypatch.setattr(evaluate, "evaluate_sim", fake)
    out = calibrate("histogram", ("a", "b"))
    assert out["target_distances"] == 202 and out["apart_distances"] == 202
    assert out["target_p50_p99_max"][1] == pytest.approx(0.595)
    assert out["apart_min_p1_p50"][1] == pytest.approx(0.804)
    assert out["threshold"] == pytest.approx(0.70)


def test_shared_width():
    assert evaluate._shared_width((0, 0, 100, 10), []) == 0.0
    assert evaluate._shared_width((0, 0, 100, 10), [(75, 0, 300, 10)]) == pytest.approx(0.25)
    assert evaluate._shared_width((0, 0, 100, 10), [(200, 0, 300, 10), (-50, 0, 50, 9)]) == 0.5
