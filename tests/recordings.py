"""Recordings made by tests: MCAP files laid out as ``followbot record`` writes them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from followbot.mcapio import McapTopicWriter
from followbot.schemas import LaserScan, Odometry, TrackState, VelocityCommand, encode
from followbot.services.sim.synthetic import SyntheticScene, SyntheticSettings

SCAN_PERIOD_NS = 50_000_000  # 20 Hz
T0_NS = 1_700_000_000_000_000_000


@dataclass
class Layout:
    """Where the parts of a written recording are."""

    path: Path
    chunk_ends: list[int]
    """File offset just after each chunk (and its message indexes), in order."""
    scans_per_chunk: int
    size: int

    def scans_before(self, offset: int) -> int:
        """Scans in the chunks that end at or before ``offset``."""
        return self.scans_per_chunk * sum(1 for end in self.chunk_ends if end <= offset)


def write_recording(
    path: Path,
    chunks: int = 8,
    scans_per_chunk: int = 20,
    commands: bool = True,
    robot: str = "testbot",
) -> Layout:
    """A finished MCAP of a walker round a still robot: 20 Hz scans (two people's legs, from
    the synthetic scene), odometry at each scan and, with ``commands``, control/cmd_vel and
    tracking/target too. A chunk is ended every ``scans_per_chunk`` scans, as the recorder's
    periodic flush does."""
    scene = SyntheticScene(SyntheticSettings(people=2, noise_m=0.0))
    out = McapTopicWriter(path, robot, flush_period_s=3600)  # chunks ended here, by hand
    ends = []
    for i in range(chunks * scans_per_chunk):
        stamp = T0_NS + i * SCAN_PERIOD_NS
        items = [
            ("sensors/odom", Odometry(stamp_ns=stamp, x_m=0.0, y_m=0.0, yaw_rad=0.0)),
            (
                "sensors/scan",
                LaserScan.from_ranges(
                    scene.ranges(i * SCAN_PERIOD_NS / 1e9),
                    stamp_ns=stamp,
                    angle_min_rad=scene.angle_min,
                    angle_increment_rad=scene.angle_inc,
                    range_min_m=0.02,
                    range_max_m=8.0,
                ),
            ),
        ]
        if commands:
            items += [
                ("tracking/target", TrackState(stamp_ns=stamp, status="tracking", x_m=1.5)),
                (
                    "control/cmd_vel",
                    VelocityCommand(stamp_ns=stamp, linear_mps=0.3, angular_radps=math.pi / 8),
                ),
            ]
        for k, (topic, message) in enumerate(items):
            out.write(topic, encode(message), stamp, stamp + k)
        if (i + 1) % scans_per_chunk == 0:
            out.flush()
            ends.append(out.size_bytes())
    out.close()
    return Layout(path, ends, scans_per_chunk, path.stat().st_size)


def write_ros1_bag(
    path: Path, scans: int = 60, compression: str = "none", chunk_bytes: int = 1 << 20
) -> list[int]:
    """A ROS 1 bag of 10 Hz LaserScans on /scan (written by rosbags, as `rosbag record`
    would: connection records inside the chunks, the index at the end); returns the stamps."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    scan_type, header_type = (
        store.types["sensor_msgs/msg/LaserScan"],
        store.types["std_msgs/msg/Header"],
    )
    time_type = store.types["builtin_interfaces/msg/Time"]
    scene = SyntheticScene(SyntheticSettings(noise_m=0.0))
    stamps = []
    writer = Writer(path)
    if compression != "none":
        writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    writer.chunk_threshold = chunk_bytes
    with writer:
        conn = writer.add_connection("/scan", scan_type.__msgtype__, typestore=store)
        for i in range(scans):
            stamp = T0_NS + i * 100_000_000
            sec, nsec = divmod(stamp, 1_000_000_000)
            msg = scan_type(
                header=header_type(seq=i, stamp=time_type(sec=sec, nanosec=nsec), frame_id="laser"),
                angle_min=scene.angle_min, angle_max=scene.angle_min + scene.angle_inc * 719,
                angle_increment=scene.angle_inc, time_increment=0.0, scan_time=0.1,
                range_min=0.02, range_max=8.0, ranges=scene.ranges(i * 0.1),
                intensities=np.zeros(0, np.float32),
            )  # fmt: skip
            writer.write(conn, stamp, store.serialize_ros1(msg, scan_type.__msgtype__))
            stamps.append(stamp)
    return stamps
