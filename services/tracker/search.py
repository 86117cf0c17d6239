"""Where to look for a lost target: the look gate, whom the camera turns to, the search point.

Beyond the thesis (whose camera stays where the target was lost). While the target is lost
and vision is alive, tracking/target names a person for the camera to look at
(``look_track_id``, ``look_x_m``/``look_y_m``), or, with nobody to look at, a point: where the
target should be now. Vision judges whoever the camera shows and may re-take the target by
appearance; the gate below also limits whom it may re-take (identity.py).

Where the target should be: where it was lost, moved on at its coasting velocity for at
most ``search.predict_s``, kept within the detector's reach (``search.within_reach``). The gate
round it has radius ``search.gate_m + search.gate_mps x t``, t the time since the target was
last seen (``search.gate_since_seen``), for ``search.max_s`` after the loss. Past that, the camera
looks at that point and, in turn, at each newcomer farther than ``search.wide_gate_m`` from
it, whom vision re-takes only on a close match (``search.wide_max_distance``).

When the point is hidden from the laser (the scan's ``horizon`` has something nearer on its
bearing), the camera looks past the edge of the cover, where the person will come out
(:func:`occluder_edge`).
"""

from __future__ import annotations

import math

import numpy as np

from followbot.schemas import Horizon
from followbot.services.runtime.mount import LaserMount

from .lifecycle import ScanTime, Track, Tracks
from .settings import TrackerSettings

__all__ = ["Search", "hidden_from_laser", "occluder_edge"]

_NS = 1_000_000_000

Gate = tuple[np.ndarray, float]
"""(centre, radius) in the current base frame."""


def hidden_from_laser(
    points: np.ndarray, horizon: Horizon, margin_m: float, radius_m: float, samples: int = 5
) -> np.ndarray:
    """True for each point of ``points`` (k, 2; the scan's frame) that the laser could not have
    seen in the scan whose ``horizon`` this is: of ``samples`` bearings spread over the point's
    width (``radius_m`` either side), at least half lie outside the horizon's bins or have a
    return nearer than the point's range minus ``margin_m``. A non-finite point: False."""
    r = horizon.ranges.numpy()
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    rho = np.hypot(pts[:, 0], pts[:, 1])
    finite = np.isfinite(rho)
    rho = np.where(finite, rho, 1.0)
    phi = np.where(finite, np.arctan2(pts[:, 1], pts[:, 0]), 0.0)
    half = np.arctan2(radius_m, rho)  # up to 90 deg for a point at the laser
    bearings = phi[:, None] + half[:, None] * np.linspace(-1.0, 1.0, samples)[None, :]
    u = np.mod(bearings - horizon.angle_min_rad, 2.0 * math.pi) / horizon.increment_rad
    k = np.floor(u).astype(np.intp)
    inside = k < r.shape[0]
    limit = np.broadcast_to(rho[:, None] - margin_m, k.shape)
    covered = np.zeros(k.shape, dtype=bool)
    covered[inside] = r[k[inside]] < limit[inside]  # NaN bins: not covered
    return finite & (np.count_nonzero(~inside | covered, axis=1) * 2 >= samples)


def occluder_edge(
    point: np.ndarray,
    velocity: np.ndarray,
    horizon: Horizon,
    margin_m: float,
    radius_m: float,
    min_speed_mps: float = 0.05,
) -> np.ndarray | None:
    """Where a person hidden at ``point`` (the scan's frame), walking at ``velocity``, should come
    out: past the edge of what hides them, on the side they walk towards; None when the point is
    not hidden (:func:`hidden_from_laser`, same ``margin_m`` and ``radius_m``), the cover reaches
    beyond the horizon's bins (no edge seen), or the point is not finite.

    The horizon's bins are walked from the point's bearing in the direction its bearing changes
    (the sign of ``point x velocity``; both ways, the nearer edge, when the speed across the
    line of sight is below ``min_speed_mps``) to the first bin whose return is not nearer than
    the point's range minus ``margin_m``. The answer lies at the point's range, at that bin's
    near boundary turned a further ``atan(radius_m / range)`` (a person's centre just clear of
    the edge). A full-circle horizon wraps round."""
    p = np.asarray(point, dtype=float).reshape(2)
    rho = float(np.hypot(p[0], p[1]))
    if not (math.isfinite(rho) and rho > 1e-6):
        return None
    if not hidden_from_laser(p[None], horizon, margin_m, radius_m)[0]:
        return None
    r = horizon.ranges.numpy()
    n, inc, a0 = r.shape[0], horizon.increment_rad, horizon.angle_min_rad
    phi = math.atan2(p[1], p[0])
    b0 = math.floor(((phi - a0) % (2.0 * math.pi)) / inc)
    if b0 >= n:
        return None  # outside the laser's view: nothing tells where the cover ends
    v = np.asarray(velocity, dtype=float).reshape(2)
    across = float(p[0] * v[1] - p[1] * v[0]) / rho  # speed across the line of sight
    ways = [1 if across > 0 else -1] if abs(across) >= min_speed_mps else [1, -1]
    best = _nearest_clear_bin(r, b0, ways, rho - margin_m, full=n * inc >= 2.0 * math.pi - 1e-6)
    if best is None:
        return None
    k, d = best
    edge = a0 + (b0 + d * k + (0 if d > 0 else 1)) * inc
    bearing = edge + d * math.atan2(radius_m, rho)
    return np.array([rho * math.cos(bearing), rho * math.sin(bearing)])


def _nearest_clear_bin(
    r: np.ndarray, b0: int, ways: list[int], limit: float, full: bool
) -> tuple[int, int] | None:
    """(bins walked, direction) from bin ``b0`` to the nearest bin whose return is not nearer
    than ``limit``, walking each way in ``ways``; None when the cover runs out of the view."""
    n = r.shape[0]
    best: tuple[int, int] | None = None
    for d in ways:
        for k in range(n):
            b = b0 + d * k
            if full:
                b %= n
            elif not 0 <= b < n:
                break  # the cover runs out of the view
            if not r[b] < limit:  # (NaN: not covered, as in hidden_from_laser)
                if best is None or k < best[0]:
                    best = (k, d)
                break
    return best


class Search:
    """The lost target's last sighting, the look gate, and whom the camera looks at."""

    def __init__(
        self, settings: TrackerSettings, tracks: Tracks, now: ScanTime, mount: LaserMount | None
    ) -> None:
        self.settings = settings
        self.mount = mount or LaserMount()
        """The laser's pose: the horizon and the reach are the laser's, seen from where it sits."""
        self._tracks = tracks
        self._now = now
        self.lost_at: np.ndarray | None = None
        """The lost target's last position, carried by ego-motion (None: nothing lost)."""
        self.lost_ns = 0  # scan stamp at which the target was lost
        self._lost_seen_ns = 0  # ... and at which it was last seen before that
        self._lost_v = np.zeros(2)  # its coasting velocity then, carried by ego-motion
        self.horizon: Horizon | None = None  # the last scan's (search.occluder_edge)
        self.reach: float | None = None  # the last scan's detector reach (search.within_reach)
        self._look: tuple[int, int] = (-1, 0)  # (track looked at, since when)
        self._rejected: dict[int, int] = {}  # rejections by vision since the loss, per track
        self._done: set[int] = set()  # looked at for search.dwell_s without a judgement
        self._looked: set[int] = set()  # looked at since the loss (search.new_first)
        self._bearing: float | None = None  # where the camera was last sent (search.turn_deg_s)

    # ------------------------------------------------------------------ the loss

    def note_loss(self, track: Track) -> None:
        """Where, when and how fast the target was lost (the look gate's origin)."""
        self.lost_at = np.array(track.position, dtype=float)
        self.lost_ns = self._now.stamp_ns
        self._lost_seen_ns = min(track.last_seen_ns, self._now.stamp_ns)
        self._lost_v = self._tracks.velocity(track, self._now.pose)

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None:
        if self.lost_at is not None:
            self.lost_at = rotation @ self.lost_at + translation
            self._lost_v = rotation @ self._lost_v

    def predicted(self) -> np.ndarray | None:
        """Where the lost target should be now (None: no loss)."""
        if self.lost_at is None:
            return None
        elapsed = (self._now.stamp_ns - self.lost_ns) / _NS
        where = self.lost_at + self._lost_v * min(elapsed, self.settings.search.predict_s)
        limit = self.reach if self.settings.search.within_reach else None
        if limit is not None:  # beyond the detector's reach: where it would come back into it
            mount = self.mount
            seen = where if mount.is_identity else mount.to_laser(where)[0]
            r = float(np.hypot(*seen))
            if r > limit:
                seen = seen * (limit / r)
                where = seen if mount.is_identity else mount.to_base(seen)[0]
        return where

    # ------------------------------------------------------------------ gates

    def gate(self, since_loss: bool = False) -> Gate | None:
        """The look gate, or None when it does not apply (off, no loss, or search.max_s past).
        ``since_loss``: the radius grown since the loss, whatever search.gate_since_seen says."""
        s = self.settings
        where = self.predicted()
        if s.search.gate_m is None or where is None:
            return None
        elapsed = (self._now.stamp_ns - self.lost_ns) / _NS
        if elapsed > s.search.max_s:
            return None
        if s.search.gate_since_seen and not since_loss:
            elapsed = (self._now.stamp_ns - self._lost_seen_ns) / _NS
        return where, s.search.gate_m + s.search.gate_mps * elapsed

    def wide_gate(self) -> Gate | None:
        """Past search.max_s with search.wide_max_distance: (where the lost target should be,
        search.wide_gate_m); else None."""
        s = self.settings
        where = self.predicted()
        if s.search.wide_max_distance is None or s.search.gate_m is None or where is None:
            return None
        if (self._now.stamp_ns - self.lost_ns) / _NS <= s.search.max_s:
            return None  # the gate itself applies
        return where, s.search.wide_gate_m

    @staticmethod
    def inside(gate: Gate | None, t: Track | None) -> bool:
        """Track ``t`` lies in ``gate`` (None: no gate, always)."""
        if gate is None:
            return True
        return t is not None and float(np.hypot(*(t.position - gate[0]))) <= gate[1]

    def may_retake(self, tid: int, distance: float | None) -> bool:
        """Vision accepting track ``tid`` at appearance ``distance`` may re-take the lost
        target: inside the look gate, and only on a close match (search.wide_max_distance) past
        the wide gate or in the gate's outer ring grown since the target was last seen."""
        s = self.settings
        t = self._tracks.by_id.get(tid)
        if s.search.enabled and not self.inside(self.gate(), t):
            return False
        wide = s.search.wide_max_distance
        if wide is None or (distance is not None and distance <= wide):
            return True
        last = self.wide_gate()
        beyond_wide = last is not None and not self.inside(last, t)
        beyond_loss = s.search.gate_since_seen and not self.inside(self.gate(since_loss=True), t)
        return not (beyond_wide or beyond_loss)

    # ------------------------------------------------------------------ the camera

    def rejections(self, tid: int) -> int:
        """How often vision rejected track ``tid`` since the loss."""
        return self._rejected.get(tid, 0)

    def note_rejection(self, tid: int) -> None:
        """Vision judged track ``tid`` and said it is not the target."""
        self._rejected[tid] = self._rejected.get(tid, 0) + 1

    def forget_looks(self) -> None:
        self._look = (-1, 0)
        self._rejected.clear()
        self._done.clear()
        self._looked.clear()

    def step(self, lost: bool, stamp: int) -> None:
        """Once per scan: choose whom to look at while ``lost`` and the gate applies (or the
        look goes on past it), else forget what was looked at."""
        s = self.settings
        wide = s.search.wide_max_distance is not None
        if lost and s.search.enabled and (s.search.gate_m is None or wide or self.gate()):
            self._choose(stamp)
        else:
            self.forget_looks()

    def _choose(self, stamp: int) -> None:
        """Keep looking at the current track until vision judged it or search.dwell_s passed,
        then the next: walking first, then nearest to where the target should be."""
        s = self.settings
        gate = self.gate()
        last = None if gate is not None else self.wide_gate()
        tid, since = self._look
        if tid >= 0 and (
            tid not in self._tracks.by_id
            or self._rejected.get(tid, 0) >= s.search.rejections
            or stamp - since > s.search.dwell_s * _NS
        ):
            self._done.add(tid)
            tid = -1
        if tid >= 0 and self._tracks.by_id[tid].misses <= s.search.keep_misses:
            return
        dwelling = (
            tid < 0 and last is not None and since and stamp - since <= s.search.dwell_s * _NS
        )
        eligible = self._eligible(gate, last)
        if dwelling:  # on where the target should be, between the rounds of newcomers
            if not (s.search.new_first and any(t.id not in self._looked for t in eligible)):
                return
            eligible = [t for t in eligible if t.id not in self._looked]
        fresh = [t for t in eligible if t.id not in self._done]
        if eligible and not fresh:  # each looked at once: round again
            self._done.clear()
            if last is not None:  # (via a dwell on the point)
                self._look = (-1, stamp)
                return
            fresh = eligible
        if not fresh:
            self._look = (-1, 0)
            return
        origin = np.zeros(2) if self.lost_at is None else self.lost_at
        if gate is not None:
            origin = gate[0]
        elif last is not None:
            origin = last[0]  # past search.max_s: still nearest where it should be first

        def rank(t: Track) -> tuple[bool, float]:
            walking = self._tracks.walking(t.id, s.search.moving_mps)
            return not walking, float(np.hypot(*(t.position - origin)))

        best = min(fresh, key=rank)
        start = since if best.id == tid else self._arrival(best, stamp)
        self._look = (best.id, start)
        self._looked.add(best.id)

    def _eligible(self, gate: Gate | None, last: Gate | None) -> list[Track]:
        """People (initiators.py) seen this scan, far enough from the laser, not rejected too
        often, inside the gate -- or, past search.max_s, newcomers away from where the target
        should be (there the camera looks at the point itself)."""
        s = self.settings

        def here(t: Track) -> bool:
            if last is None:
                return self.inside(gate, t)
            return not self.inside(last, t) and t.born_ns > self.lost_ns

        return [
            t
            for t in self._tracks.by_id.values()
            if t.person
            and t.misses == 0
            and self._rejected.get(t.id, 0) < s.search.rejections
            and float(np.hypot(*t.position)) >= s.search.min_range_m
            and here(t)
        ]

    def _arrival(self, t: Track, stamp: int) -> int:
        """When the camera, sent now from where it was last sent, can point at ``t``
        (search.turn_deg_s): the dwell runs from then."""
        rate = self.settings.search.turn_deg_s
        if rate is None or self._bearing is None:
            return stamp
        bearing = math.atan2(t.position[1], t.position[0])
        turn = abs(math.remainder(bearing - self._bearing, math.tau))
        return stamp + round(math.degrees(turn) / rate * _NS)

    def output(self, target_id: int) -> tuple[int, float, float]:
        """(look_track_id, look_x_m, look_y_m) for tracking/target: whom the camera should look
        at while the target is lost; (-1, 0, 0) while there is a target (the camera then
        follows it: pan = heading)."""
        if target_id >= 0:
            followed = self._tracks.by_id.get(target_id)
            if followed is not None:
                xy = followed.position
                self._bearing = math.atan2(float(xy[1]), float(xy[0]))
            return -1, 0.0, 0.0
        look = self._tracks.by_id.get(self._look[0])
        lx, ly = (0.0, 0.0) if look is None else map(float, look.position)
        where = self.search_point() if look is None else None
        if where is not None:
            lx, ly = map(float, where)  # nobody to look at: where the target should be
        if (lx, ly) != (0.0, 0.0):
            self._bearing = math.atan2(ly, lx)
        return -1 if look is None else look.id, lx, ly

    def search_point(self) -> np.ndarray | None:
        """Where the camera looks when it looks at nobody while the target is lost: where the
        target should be, or past the edge of what hides that point (search.occluder_edge);
        None without a gate."""
        s = self.settings
        if not (s.search.enabled and s.search.gate_m is not None):
            return None
        where = self.predicted()
        if where is not None and s.search.occluder_edge and self.horizon is not None:
            m = self.mount
            point, v = where, self._lost_v  # the horizon is the laser's: in its frame
            if not m.is_identity:
                point = m.to_laser(where)[0]
                v = m.to_laser(self._lost_v)[0] - m.to_laser([0.0, 0.0])[0]  # a vector
            edge = occluder_edge(point, v, self.horizon, s.occlusion_margin_m, s.occlusion_radius_m)
            if edge is not None:  # hidden there: where it comes out of hiding
                where = edge if m.is_identity else m.to_base(edge)[0]
        return where
