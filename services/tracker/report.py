"""What the tracker publishes: the target (TrackState) and every person (People): the tracks
the initiator confirmed (initiators.py), and the target.

Target status: ``initialising`` (no target yet), ``tracking`` (the target took a candidate
this scan), ``coasting`` (1..max_misses misses: the estimate is a prediction), ``lost`` (more
than max_misses misses: the robot stops; the target's track is deleted and a new one is taken
only by appearance, or -- without vision -- near where it was lost). While lost, the state
carries the lost target's last position and whom the camera should look at (search.py).

The target's reported position is its estimate plus its lone-leg shift (``lone_leg_output_m``);
every other person's is the estimate.
"""

from __future__ import annotations

import numpy as np

from followbot.schemas import People, PersonTrack, TrackState

from .lifecycle import Track
from .settings import TrackerSettings

__all__ = ["people", "shift_after_update", "status", "target_state"]

_NS = 1_000_000_000

#: At most this many people in one People message (the wire limit).
MAX_PEOPLE = 256


def status(target: Track | None, had_target: bool) -> str:
    if target is not None:
        return "tracking" if target.misses == 0 else "coasting"
    return "lost" if had_target else "initialising"


def target_state(
    stamp: int,
    frame_id: str,
    *,
    target: Track | None,
    had_target: bool,
    lost_at: np.ndarray | None,
    look: tuple[int, float, float],
    estimator: str,
    flags: list[str],
    sources: list[str],
) -> TrackState:
    """tracking/target: the target's estimate, or -- none -- where it was lost."""
    look_id, lx, ly = look
    common = dict(
        stamp_ns=stamp,
        frame_id=frame_id,
        status=status(target, had_target),
        sources=sources,
        flags=flags,
        estimator=estimator,
        look_track_id=look_id,
        look_x_m=lx,
        look_y_m=ly,
    )
    if target is None:
        x, y = (0.0, 0.0) if lost_at is None else map(float, lost_at)
        return TrackState(x_m=x, y_m=y, misses=0, **common)
    m, cov = target.estimator.mean, target.estimator.covariance
    xy = target.reported
    return TrackState(
        track_id=target.id,
        x_m=float(xy[0]),
        y_m=float(xy[1]),
        vx_mps=float(m[2]),
        vy_mps=float(m[3]),
        covariance=cov.reshape(-1).tolist(),
        misses=target.misses,
        shift_x_m=float(target.shift[0]),
        shift_y_m=float(target.shift[1]),
        **common,
    )


def people(
    stamp: int,
    frame_id: str,
    tracks: dict[int, Track],
    target_id: int,
    estimator: str,
    settings: TrackerSettings,
) -> People:
    """tracking/people: every track the initiator confirmed, and the target."""
    out = []
    for t in tracks.values():
        if not t.person and t.id != target_id:
            continue
        m = t.estimator.mean
        xy = t.reported if t.id == target_id else m[:2]
        out.append(
            PersonTrack(
                id=t.id,
                x_m=float(xy[0]),
                y_m=float(xy[1]),
                vx_mps=float(m[2]),
                vy_mps=float(m[3]),
                covariance=t.estimator.covariance.reshape(-1).tolist(),
                misses=t.misses,
                age_s=max(0.0, (stamp - t.born_ns) / _NS),
                confidence=max(0.0, 1.0 - t.misses / (settings.max_misses + 1)),
            )
        )
    return People(
        stamp_ns=stamp,
        frame_id=frame_id,
        tracks=out[:MAX_PEOPLE],
        target_id=target_id,
        estimator=estimator,
    )


def shift_after_update(t: Track, z: np.ndarray, lone: bool, scale: float, b: float) -> None:
    """The target's reported shift after its update with ``z`` (lone_leg_output_m ``b``).

    Had the measurement lain ``b`` farther out along its bearing u, the update would have
    moved the estimate by ``moved`` (the estimator's ``mean_if``), that is k b along u: so the
    update keeps 1 - k of the earlier shift and, for a ``lone`` leg, adds ``moved``. An
    estimator whose ``mean_if`` cannot tell keeps no shift."""
    r = float(np.hypot(*z))
    if not r > 0:
        return
    u = z / r
    moved = t.estimator.mean_if(z + b * u, scale)
    if moved is None:
        return
    moved = moved[:2] - t.estimator.mean[:2]
    if not np.isfinite(moved).all():
        t.shift = np.zeros(2)
        return
    k = min(max(float(moved @ u) / b, 0.0), 1.0)
    t.shift = (1.0 - k) * t.shift + (moved if lone else 0.0)
