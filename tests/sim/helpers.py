"""Small builders shared by the simulator tests."""

from __future__ import annotations

import math

import msgspec

from followbot.schemas import LaserScan, Message, PanCommand, VelocityCommand
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


def controller_answer(scan: LaserScan) -> list[tuple[str, Message]]:
    """A deterministic 'controller': speed from the nearest return, turn from the stamp."""
    r = scan.ranges_m()
    near = float(r[(r > 0.05) & (r < 50)].min())
    v = 0.4 if near > 1.0 else 0.0
    w = 0.6 * math.sin(scan.stamp_ns / 1e9)
    return [
        ("control/cmd_vel", VelocityCommand(stamp_ns=scan.stamp_ns, linear_mps=v, angular_radps=w)),
        ("control/pan", PanCommand(stamp_ns=scan.stamp_ns, pan_rad=0.5 * w)),
    ]
