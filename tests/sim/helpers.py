"""Small builders shared by the simulator tests."""

from __future__ import annotations

import msgspec

from followbot.services.sim.scenario import Scenario


def scenario(**fields) -> Scenario:
    """A scenario from plain data; noise-free sensors unless the test asks otherwise."""
    data = {
        "name": "test",
        "laser": {"range_noise_m": 0.0},
        "camera": {"noise_std": 0.0},
        "robot": {"odometry": {"noise": False}},
    }
    for key, value in fields.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key] = {**data[key], **value}
        else:
            data[key] = value
    return msgspec.convert(data, Scenario)


def standing(pid: int, x: float, y: float, heading_deg: float = 180.0, **extra) -> dict:
    """A person standing still at (x, y) with legs together."""
    return {"id": pid, "start": [x, y], "heading_deg": heading_deg, **extra}
