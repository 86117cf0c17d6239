"""Shared helpers of the vision_verify tests: OpenCV sample data, a simulator frame."""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path

import numpy as np

_CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "followbot"
_DATA_DIRS = [
    os.environ.get("FOLLOWBOT_OPENCV_DATA", ""),
    str(_CACHE / "opencv-doc/usr/share/doc/opencv-doc/examples/data"),  # `make opencv-data`
    "/usr/share/doc/opencv-doc/examples/data",
]
HOW = (
    "not found; `make opencv-data` fetches Debian's opencv-doc (95 MB) into ~/.cache/followbot, "
    "or set FOLLOWBOT_OPENCV_DATA=DIR/usr/share/doc/opencv-doc/examples/data"
)


def opencv_sample(name: str) -> Path | None:
    """A file of opencv-doc's examples/data, or None when it is not on this machine."""
    for d in _DATA_DIRS:
        if d and (Path(d) / name).is_file():
            return Path(d) / name
    return None


@cache
def acquired_scene():
    """Run the two-person scenario until the model is built (thesis 4.2), then on to t = 4.6 s
    (both people in view, the bystander crossing). Returns (camera, acquisition, frames), frames
    being (image message, pixels, candidates, truth) per scan with an image within 60 ms."""
    from followbot.schemas import GroundTruth, Image, LaserScan
    from followbot.services.laser_legs.detectors.thesis import ClusterLegDetector, ThesisSettings
    from followbot.services.sim.scenario import load_builtin
    from followbot.services.sim.simulation import Simulation
    from followbot.services.vision_verify.core import Camera
    from followbot.services.vision_verify.model import ModelBuilder

    sim = Simulation(load_builtin("thesis_5_2_4_two_people"))
    det = ClusterLegDetector(ThesisSettings(clip_range_m=None))
    camera = Camera()
    builder = ModelBuilder(camera)
    acq, image, px, frames = None, None, None, []
    while sim.t_s < 6.0:
        scan = truth = None
        for m in sim.tick():
            if isinstance(m, Image):
                image, px = m, m.pixels().copy()
                acq = acq or builder.add_image(m.stamp_ns, px, m.pan_rad)
            elif isinstance(m, LaserScan):
                scan = (m, det.detect(m))
                acq = acq or builder.add_scan(m.stamp_ns, m.ranges_m(), scan[1])
            elif isinstance(m, GroundTruth):
                truth = m
        if scan and image is not None and abs(image.stamp_ns - scan[0].stamp_ns) <= 60_000_000:
            frames.append((image, px, scan[1], truth, scan[0]))
    return camera, acq, frames


def owner(candidate, truth, radius_m: float = 0.5) -> int:
    best, who = radius_m, -1
    for p in truth.people:
        d = float(np.hypot(p.robot_x_m - candidate.x_m, p.robot_y_m - candidate.y_m))
        if d < best:
            best, who = d, p.id
    return who
