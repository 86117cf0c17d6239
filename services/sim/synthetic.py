"""synthetic: a sensor publisher for smoke, load and soak tests (no physics, no feedback).

Publishes sensors/scan, sensors/odom and (optionally) sensors/image at chosen rates, with
sequence numbers and wall-clock stamps, for as long as asked, in bounded memory. The scene is
fixed and cheap to compute: a round room and ``people`` walkers (default one) evenly spaced
on one circle round a still robot, each with two alternating legs (so scans contain real leg
arcs for a detector to find and a tracker to follow). Use the simulator (services/sim, issue 3)
when you need ground truth and closed-loop control.

    followbot run synthetic --set scan_rate_hz=1000 --set count=100000
    followbot run synthetic --set people=3 --set 'wait_for_stages=[laser_legs]'   # soak
"""

from __future__ import annotations

import math
import time
from typing import Annotated

import msgspec
import numpy as np

from followbot.schemas import Image, LaserScan, Odometry
from followbot.services.runtime.node import Node
from followbot.services.runtime.service import service_main
from followbot.services.runtime.settings import NodeSettings

__all__ = ["SyntheticScene", "SyntheticSettings", "main"]

_Rate = Annotated[float, msgspec.Meta(ge=0, le=100_000)]
#: Scans published at most per timer tick when catching up.
_MAX_BURST = 8
#: A backlog older than this is dropped rather than published in a burst, s.
_MAX_BACKLOG_S = 0.05


class SyntheticSettings(NodeSettings, kw_only=True, forbid_unknown_fields=True):
    scan_rate_hz: _Rate = 40.0
    """Laser scans published per second (wall clock); 0: none."""
    beams: Annotated[int, msgspec.Meta(ge=1, le=10_000)] = 720
    """Beams per scan, spread evenly over fov_deg."""
    fov_deg: Annotated[float, msgspec.Meta(gt=0, le=360)] = 270.0
    """The laser's field of view (deg), centred straight ahead."""
    max_range_m: Annotated[float, msgspec.Meta(gt=0)] = 8.0
    """Returns beyond this (m) are no return (inf); also the scan's range_max_m."""
    noise_m: Annotated[float, msgspec.Meta(ge=0)] = 0.015
    """Standard deviation (m) of the Gaussian noise added to every range."""
    room_radius_m: Annotated[float, msgspec.Meta(gt=0)] = 4.0
    """Radius (m) of the round room around the robot: the wall every beam not on a leg hits."""
    walk_radius_m: Annotated[float, msgspec.Meta(gt=0)] = 1.5
    """Radius (m) of the circle the walkers walk round the robot."""
    walk_speed_mps: Annotated[float, msgspec.Meta(ge=0)] = 0.6
    """The walkers' speed along their circle (m/s)."""
    people: Annotated[int, msgspec.Meta(ge=0, le=16)] = 1
    """Walkers on the circle, evenly spaced, all walking the same way (the image shows the
    first)."""
    odom_rate_hz: _Rate = 50.0
    """Odometry messages per second (the robot stands still at the origin); 0: none."""
    image_rate_hz: _Rate = 0.0
    """Camera images per second; 0: none."""
    image_width: Annotated[int, msgspec.Meta(ge=8, le=4096)] = 320
    """Image width (px)."""
    image_height: Annotated[int, msgspec.Meta(ge=8, le=4096)] = 240
    """Image height (px)."""
    jpeg: bool = False
    """Send images as JPEG rather than raw BGR."""
    count: Annotated[int, msgspec.Meta(ge=0)] = 0
    """Stop after this many scans (0: run until stopped)."""
    seed: int = 0
    """Seed of the range noise, so two runs publish the same ranges."""
    wait_for_subscribers_s: Annotated[float, msgspec.Meta(ge=0)] = 0.0
    """Hold back the first scan until someone subscribes to sensors/scan (at most this long)."""
    reliable: bool = False
    """Block rather than drop when the network is congested (a live sensor drops: False)."""
    wait_for_stages: list[str] = []
    """Also hold back the first scan until these services are alive (their liveliness tokens
    seen), at most start_timeout_s: a subscriber elsewhere (a monitor) must not start the stream
    before the stages that should see all of it are connected."""
    start_timeout_s: Annotated[float, msgspec.Meta(ge=0)] = 10.0
    """Longest wait (s) for wait_for_stages; then publishing starts anyway, with a warning."""


class SyntheticScene:
    """A round room with one walker; everything is a pure function of time."""

    LEG_RADIUS_M = 0.06
    STEP_M = 0.3  # thesis 5.2.2: 0.3 m steps

    def __init__(self, settings: SyntheticSettings) -> None:
        self.s = settings
        fov = math.radians(settings.fov_deg)
        n = settings.beams
        self.angle_min = -fov / 2
        self.angle_inc = fov / n if settings.fov_deg >= 360 else fov / max(n - 1, 1)
        self.angles = self.angle_min + self.angle_inc * np.arange(n)
        self.dirs = np.stack([np.cos(self.angles), np.sin(self.angles)], axis=1)
        self.rng = np.random.default_rng(settings.seed)

    def legs(self, t_s: float) -> np.ndarray:
        """Centres (2 people x 2) of the walkers' legs at time ``t_s``: walker ``i`` is ``i /
        people`` of a turn ahead on the circle; each one's legs swing alternately."""
        n = self.s.people
        if n == 0:
            return np.empty((0, 2))
        return np.concatenate([self._walker(t_s, 2 * math.pi * i / n) for i in range(n)])

    def _walker(self, t_s: float, phase: float) -> np.ndarray:
        s = self.s
        phi = s.walk_speed_mps / s.walk_radius_m * t_s + phase
        cos_phi, sin_phi = math.cos(phi), math.sin(phi)
        cx, cy = s.walk_radius_m * cos_phi, s.walk_radius_m * sin_phi  # centre of the walker
        hx, hy = -sin_phi, cos_phi  # heading (tangent of the circle)
        sx, sy = hy, -hx  # to the walker's right
        stride = s.walk_speed_mps / (2 * self.STEP_M) if s.walk_speed_mps else 0.0
        swing = 0.5 * self.STEP_M * math.sin(2 * math.pi * stride * t_s / 2)
        return np.array(
            [
                [cx + 0.1 * sx + swing * hx, cy + 0.1 * sy + swing * hy],
                [cx - 0.1 * sx - swing * hx, cy - 0.1 * sy - swing * hy],
            ]
        )

    def ranges(self, t_s: float) -> np.ndarray:
        """Ranges of every beam (float32): the room's wall, or the nearer leg."""
        room = self.s.room_radius_m
        r = np.full(len(self.angles), room)
        for c in self.legs(t_s):
            # ray p = t*d meets circle |p - c| = R where t^2 - 2 t d.c + |c|^2 - R^2 = 0;
            # whole-array operations only (boolean indexing costs more than it saves here)
            b = self.dirs @ c
            disc = b * b - (c @ c - self.LEG_RADIUS_M**2)
            t = b - np.sqrt(np.maximum(disc, 0.0))
            np.minimum(r, np.where((disc >= 0) & (t > 0), t, room), out=r)
        if self.s.noise_m:
            r += self.rng.normal(0.0, self.s.noise_m, r.shape)
        r[r > self.s.max_range_m] = np.inf
        return r.astype(np.float32)

    def image(self, t_s: float) -> np.ndarray:
        """A textured background with the walker as a coloured column where the camera sees it."""
        w, h = self.s.image_width, self.s.image_height
        img = np.empty((h, w, 3), np.uint8)
        img[:] = (np.arange(w, dtype=np.uint16)[None, :, None] * 200 // w).astype(np.uint8)
        if self.s.people == 0:
            return img
        c = self.legs(t_s)[:2].mean(axis=0)
        bearing = math.atan2(c[1], c[0])
        f = (w / 2) / math.tan(math.radians(47.5 / 2))
        if c[0] > 0.1 and abs(bearing) < math.radians(47.5 / 2):
            u = int(w / 2 - f * c[1] / c[0])
            half = max(2, int(f * 0.2 / c[0]))
            img[h // 4 : h // 2, max(0, u - half) : u + half] = (40, 40, 200)  # shirt
            img[h // 2 :, max(0, u - half) : u + half] = (120, 60, 20)  # trousers
        return img


def setup(node: Node, settings: SyntheticSettings) -> SyntheticScene:
    scene = SyntheticScene(settings)
    scans = node.publisher("sensors/scan", reliable=settings.reliable)
    odom = node.publisher("sensors/odom", reliable=settings.reliable)
    images = node.publisher("sensors/image", reliable=settings.reliable)
    t0 = time.monotonic()
    sent = [0]
    period_s = 1.0 / settings.scan_rate_hz if settings.scan_rate_hz > 0 else 0.0
    due = [0.0]  # monotonic time the next scan is due (set by the first tick)
    skipped = [0]

    def publish_one() -> None:
        scans.put(
            LaserScan.from_ranges(
                scene.ranges(time.monotonic() - t0),
                stamp_ns=time.time_ns(),
                angle_min_rad=scene.angle_min,
                angle_increment_rad=scene.angle_inc,
                range_min_m=0.02,
                range_max_m=settings.max_range_m,
                scan_time_s=period_s,
            )
        )
        sent[0] += 1

    def publish_scan() -> None:
        # The node's timer skips ticks it was too busy to fire (no bursts); at 1 kHz that loses
        # a few per cent of the rate to scheduling jitter. Keep the mean rate instead: publish
        # every scan due since the last tick, at most _MAX_BURST at once, and give up a backlog
        # older than _MAX_BACKLOG_S (counted, like a sensor that missed its slot).
        now = time.monotonic()
        if not due[0]:
            due[0] = now
        if now - due[0] > _MAX_BACKLOG_S:
            missed = int((now - due[0]) / period_s)
            skipped[0] += missed
            due[0] += missed * period_s
            node.notes = [f"scans_skipped={skipped[0]}"]
        n = 0
        while due[0] <= now and n < _MAX_BURST:
            publish_one()
            due[0] += period_s
            n += 1
            if settings.count and sent[0] >= settings.count:
                node.log.info(
                    "published %d scans (%d skipped as the process fell behind), stopping",
                    sent[0],
                    skipped[0],
                )
                node.stop()
                return

    def publish_odom() -> None:
        # The robot stands still at the odom origin.
        odom.put(Odometry(stamp_ns=time.time_ns(), frame_id="odom", x_m=0.0, y_m=0.0, yaw_rad=0.0))

    def publish_image() -> None:
        pixels = scene.image(time.monotonic() - t0)
        make = Image.jpeg_from_array if settings.jpeg else Image.from_array
        images.put(make(pixels, stamp_ns=time.time_ns()))

    if settings.wait_for_subscribers_s > 0:
        node.log.info("waiting up to %.1f s for a scan subscriber", settings.wait_for_subscribers_s)
        if not node.wait_for_subscribers(scans, settings.wait_for_subscribers_s):
            node.log.warning("no scan subscriber yet; publishing anyway")
    if settings.wait_for_stages:
        _wait_for_stages(node, settings.wait_for_stages, settings.start_timeout_s)
    if settings.scan_rate_hz > 0:
        node.every(1.0 / settings.scan_rate_hz, publish_scan, name="scan")
    if settings.odom_rate_hz > 0:
        node.every(1.0 / settings.odom_rate_hz, publish_odom, name="odom")
    if settings.image_rate_hz > 0:
        node.every(1.0 / settings.image_rate_hz, publish_image, name="image")
    return scene


def _wait_for_stages(node: Node, stages: list[str], timeout_s: float) -> None:
    """Block until every service in ``stages`` is alive, ``timeout_s`` passes or the node stops
    (the loop is not running yet, so liveliness is watched on the bus directly)."""
    alive: set[str] = set()
    for name in stages:
        node.bus.watch_liveliness(
            node.keys.alive(name), lambda _k, up, n=name: (alive.add if up else alive.discard)(n)
        )
    node.log.info("waiting up to %.1f s for %s", timeout_s, ", ".join(stages))
    deadline = time.monotonic() + timeout_s
    while not alive >= set(stages):
        if node.stopping or time.monotonic() >= deadline:
            node.log.warning("not alive yet: %s; publishing anyway", sorted(set(stages) - alive))
            return
        time.sleep(0.01)


def main(argv: list[str] | None = None) -> int:
    return service_main("synthetic", SyntheticSettings, setup, argv, __doc__)
