"""``make bench``'s laser table: every detector timed, and the machine reference beside them."""

from __future__ import annotations

from followbot.services.laser_legs import bench
from followbot.services.laser_legs.detectors import DETECTORS


def test_bench_prints_every_detector_and_its_time_in_reference_calls(capsys):
    assert bench.main(["--repeats", "3", "--warmup", "2"]) == 0
    rows = [line.split("|")[1:-1] for line in capsys.readouterr().out.splitlines()]
    by_name = {r[0].strip(): [c.strip() for c in r[1:]] for r in rows}
    for name in DETECTORS:
        median, low, ratio = (float(v) for v in by_name[name])
        assert 0 < low <= median
        assert ratio > 1  # a detector is more than one numpy call
    assert any(k.startswith("thesis (tracking") for k in by_name)  # criterion 3 and anchor
    reference = next(v for k, v in by_name.items() if k.startswith("(reference"))
    assert float(reference[0]) > 0 and reference[2] == "1"
