"""The thesis's particle filter (thesis 3.6.2, 4.5; DESIGN.md "Particle filter"), vectorised.

State of particle i: s_i = [x, y, vx, vy] in the base frame of the current scan. Per scan:

    ego-motion   p_i <- R p_i + t,  v_i <- R v_i          (R, t: SE(2) change, see core.py)
    propagate    v_i ~ N(0, sigma_v^2 I)  drawn afresh     (eq. 3-30, sigma_v = 1 m/s)
                 p_i <- p_i + v_i dT
    weight       w_i = exp(-(d_m - d_i)^2 / sigma_d^2) exp(-(A_m - A_i)^2 / sigma_A^2)
                 d_i = |p_i|, A_i = atan2(y_i, x_i)      (eq. 3-32..3-36; 100 mm, 5 deg)
    normalise    w_i <- w_i / sum_j w_j                  (eq. 3-37)
    estimate     s_hat = sum_i w_i s_i                   (eq. 3-38, MMSE)
    resample     systematic (numpy.searchsorted on the cumulative weights, one uniform draw)
                 or the thesis's sorted-copy scheme (4.5)

Without a measurement (a miss) the particles are only propagated, so the cloud spreads by
sigma_v dT per scan and the estimate is the cloud's mean.

The particles live in one (4, m) array: each row is contiguous, so every step is a handful of
numpy calls on rows, the random draws fill a preallocated buffer in place, and nothing is
allocated per particle. Randomness comes from a seeded ``numpy.random.Generator`` only.

With several people the tracker calls the class's batch steps (:meth:`ParticleEstimator.
motion_all`, :meth:`~ParticleEstimator.update_all`, :meth:`~ParticleEstimator.settle_all`):
the clouds are stacked into one (T, 4, m) array and every step is the same handful of numpy
calls for all T tracks, so ten people cost little more than one.
Each track still draws from its own Generator in the same order, so a batch step gives the
same numbers as the per-track one up to floating-point rounding of the stacked matrix products.

Resampling is deferred: :meth:`~ParticleEstimator.update` weighs the cloud and computes the
estimate, and the cloud is resampled when it is next used (the next prediction, a snapshot,
reading :attr:`~ParticleEstimator.particles`) or when the tracker calls :meth:`~ParticleEstimator.
settle_all` after it has published the target. The estimate, the random draws and so every
later step are the same as resampling at once; the tracker's answer just leaves sooner. After an
update, :attr:`~ParticleEstimator.covariance` is the weighted (posterior) covariance of the cloud
(sum_i w_i (s_i - s_hat)(s_i - s_hat)^T); after a prediction, the spread of the cloud.
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Sequence
from typing import Annotated, Literal

import msgspec
import numpy as np

from .base import EstimatorBase

__all__ = [
    "ParticleEstimator",
    "ParticleSettings",
    "sorted_copy_resample",
    "systematic_resample",
]


class ParticleSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    # thesis 4.5: 150 particles
    particles: Annotated[int, msgspec.Meta(ge=1, le=1_000_000)] = 150
    # thesis 4.5: sigma_vx = sigma_vy = 1 m/s
    velocity_std_mps: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    # thesis 4.5: sigma_d = 100 mm, sigma_A = 5 deg (used as exp(-e^2 / sigma^2), eq. 3-36)
    range_std_m: Annotated[float, msgspec.Meta(gt=0)] = 0.1
    bearing_std_deg: Annotated[float, msgspec.Meta(gt=0)] = 5.0
    """sigma_A (deg) of the bearing likelihood exp(-e^2 / sigma_A^2) (thesis 4.5, eq. 3-36)."""
    velocity_model: Literal["random_walk", "constant_velocity", "mixed"] = "random_walk"
    """random_walk: the thesis's eq. 3-30, v drawn afresh from N(0, sigma_v^2) every step.
    constant_velocity: v_k = v_{k-1} + N(0, (accel_std dT)^2), an alternative that keeps the
    velocity from step to step (less lag, unbiased speed; not the thesis). mixed: each
    particle keeps its velocity as constant_velocity does, except that a share
    ``redraw_share`` of them, drawn afresh each step, redraw it as random_walk does -- two
    motion models in one cloud (the particles of whichever fits survive the resampling): a
    walker's steady pace and a sudden turn or stop."""
    redraw_share: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.2
    """mixed only: the probability that a particle redraws its velocity in a step."""
    accel_std_mps2: Annotated[float, msgspec.Meta(gt=0)] = 1.5
    """constant_velocity only: the acceleration noise; the first step draws N(0, sigma_v^2)."""
    resampler: Literal["systematic", "sorted_copy"] = "systematic"
    """systematic: O(m) with one uniform draw; sorted_copy: the thesis's scheme (4.5)."""
    gate_m: Annotated[float, msgspec.Meta(gt=0)] = 0.35
    """Association gate around the prediction (m). The thesis's 400 mm (4.3, criterion 3: a
    leg within 400 mm of the prediction) is the laser detector's gate and stays there; the
    track's is 0.35 m, a walker's step at 1.5 m/s in 120 ms (0.18 m) plus the 0.13 m a lone
    leg lies off a person's centre: wider, a passer-by who hides the target for a scan just
    beyond a step from its prediction takes its track.
    docs/tracker_log.md: at 0.4 two of 76 runs spent a scan on a wrong person, at 0.3 a crowd
    lost its target."""
    gate_growth: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    """While coasting the gate grows by gate_growth * sigma_v * dT * sqrt(misses), the
    spread the random walk adds to the cloud."""


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of m particles drawn systematically: u_k = (U + k) / m, k = 0..m-1, U ~ U[0, 1).

    Particle i is drawn floor(m w_i) or ceil(m w_i) times. ``weights`` (m,) must sum to 1.
    """
    m = weights.shape[0]
    positions = (rng.random() + np.arange(m)) / m
    cumulative = np.cumsum(weights)
    idx = np.searchsorted(cumulative, positions, side="right")
    return np.minimum(idx, m - 1, out=idx)  # guards round-off: cumulative[-1] may be 1 - eps


def sorted_copy_resample(weights: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
    """The thesis's resampling (4.5, Table 4.6): sort from high to low weight, copy particle i
    floor(w_i m) times, stop at m copies.

    The floors leave up to m - 1 places empty; the pseudo-code does not say what fills them, so
    they go to the heaviest particles in order (one more copy each). Deterministic: ``rng`` is
    accepted for a common signature and not used.
    """
    m = weights.shape[0]
    order = np.argsort(-weights, kind="stable")
    counts = np.floor(weights[order] * m).astype(np.intp)
    idx = np.repeat(order, counts)
    short = m - idx.shape[0]
    if short > 0:
        idx = np.concatenate([idx, order[:short]])
    return idx[:m]


_RESAMPLERS = {"systematic": systematic_resample, "sorted_copy": sorted_copy_resample}


@functools.lru_cache(maxsize=64)
def _gather_base(tracks: int, m: int) -> np.ndarray:
    """(tracks, 4, 1) offsets of each (track, row) in a C-ordered (tracks, 4, m) cloud stack."""
    base = (np.arange(tracks)[:, None, None] * 4 + np.arange(4)[None, :, None]) * m
    base.flags.writeable = False  # shared by every call with these sizes
    return base


class ParticleEstimator(EstimatorBase):
    """One person's particle cloud (thesis 3.6.2). ``rng`` must be a seeded Generator."""

    name = "particle"
    settings_type = ParticleSettings

    def __init__(
        self,
        x_m: float,
        y_m: float,
        settings: ParticleSettings | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        s = settings or ParticleSettings()
        if rng is None:
            raise ValueError("ParticleEstimator needs a seeded numpy Generator (rng=...)")
        if not (math.isfinite(x_m) and math.isfinite(y_m)):
            raise ValueError(f"non-finite initial position ({x_m}, {y_m})")
        self.settings = s
        self.rng = rng
        m = s.particles
        self._m = m
        self._resample = _RESAMPLERS[s.resampler]
        self._inv_sd2 = 1.0 / s.range_std_m**2
        self._inv_sa2 = 1.0 / math.radians(s.bearing_std_deg) ** 2
        # thesis 4.5, eq. 4-8/4-9: every particle at the model position, velocity 0, w = 1/m
        self._p = np.zeros((4, m))
        self._p[0] = x_m
        self._p[1] = y_m
        self._spare = np.empty((4, m))
        self._mean = np.array([x_m, y_m, 0.0, 0.0])
        self._cov: np.ndarray | None = None  # covariance of the current estimate, when known
        self._w: np.ndarray | None = None  # weights of an update not yet resampled (m,)
        self._ahead = np.empty((2, m))  # the next prediction's normals, when drawn ahead
        self._ahead_ready = False
        self._dt_s = 0.0
        self._moved = False

    # ------------------------------------------------------------------ estimate

    @property
    def coasts_in_place(self) -> bool:
        """Whether a prediction without update leaves the estimate where it was (velocities
        redrawn around zero): the tracker then moves a hidden track on at its recent velocity."""
        return self.settings.velocity_model == "random_walk"

    @property
    def mean(self) -> np.ndarray:
        """(4,) the MMSE estimate (eq. 3-38) of the last update, else the cloud's mean."""
        return self._mean

    @property
    def particles(self) -> np.ndarray:
        """(4, m) the cloud, resampled (a deferred resampling is done first)."""
        if self._w is not None:
            self.settle()
        return self._p

    @property
    def covariance(self) -> np.ndarray:
        """(4, 4) after an update the weighted covariance of the cloud about the estimate,
        otherwise the spread of the (resampled, propagated) cloud."""
        if self._cov is None:
            p = self._p
            if self._w is not None:
                d = p - self._mean[:, None]
                self._cov = (d * self._w) @ d.T
            else:
                d = p - p.mean(axis=1, keepdims=True)
                self._cov = (d @ d.T) / self._m
        return self._cov

    def settle(self) -> None:
        """Do a deferred resampling now (the posterior covariance is kept first)."""
        w = self._w
        if w is None:
            return
        self.covariance  # noqa: B018 - cache the weighted covariance before the cloud changes
        p = self._p
        np.take(p, self._resample(w, self.rng), axis=1, out=self._spare)
        self._p, self._spare = self._spare, p
        self._w = None

    # ------------------------------------------------------------------ steps

    def ego_motion(self, rotation: np.ndarray, translation: np.ndarray) -> None:
        """p <- R p + t, v <- R v for every particle (the correct SE(2) change, core.py)."""
        p = self.particles
        self._cov = None
        p[0:2] = rotation @ p[0:2]
        p[0] += translation[0]
        p[1] += translation[1]
        p[2:4] = rotation @ p[2:4]
        self._mean[0:2] = rotation @ self._mean[0:2] + translation
        self._mean[2:4] = rotation @ self._mean[2:4]

    def predict(self, dt_s: float, misses: int = 0) -> None:
        """Eq. 3-30: velocities drawn afresh from N(0, sigma_v^2), positions moved v dT."""
        p = self.particles
        self._cov = None
        self._draw_velocities(p[2:4], dt_s)
        p[0:2] += p[2:4] * dt_s
        self._dt_s = dt_s
        self._mean = p.mean(axis=1)

    def _draw_velocities(self, v: np.ndarray, dt_s: float) -> None:
        """Rows 2..3 of the cloud (a contiguous (2, m) block), in place, from this rng."""
        s = self.settings
        if s.velocity_model == "random_walk" or not self._moved:
            self._normals(v)  # in place: rows 2..3 are one contiguous block
            v *= s.velocity_std_mps
            self._moved = True
        else:
            noise = self._spare[0:2]
            self._normals(noise)
            noise *= s.accel_std_mps2 * dt_s
            v += noise
            if s.velocity_model == "mixed":
                redraw = self.rng.random(v.shape[1]) < s.redraw_share
                k = int(redraw.sum())
                if k:
                    v[:, redraw] = self.rng.standard_normal((2, k)) * s.velocity_std_mps

    def _normals(self, out: np.ndarray) -> None:
        """Fill ``out`` (2, m) with the next standard normals of this rng (drawn ahead or now)."""
        if self._ahead_ready:
            np.copyto(out, self._ahead)
            self._ahead_ready = False
        else:
            self.rng.standard_normal(out=out)

    def draw_ahead(self) -> None:
        """Draw the next prediction's normals now (after a deferred resampling, whose uniform
        comes first): the same numbers in the same order, off the path to the next answer."""
        self.settle()
        if not self._ahead_ready:
            self.rng.standard_normal(out=self._ahead)
            self._ahead_ready = True

    def distance(self, points: np.ndarray, misses: int = 0) -> np.ndarray:
        """Euclidean distance of each candidate (n, 2) to the predicted position."""
        return np.hypot(points[:, 0] - self._mean[0], points[:, 1] - self._mean[1])

    def gate(self, misses: int = 0) -> float:
        s = self.settings
        return s.gate_m + s.gate_growth * s.velocity_std_mps * self._dt_s * math.sqrt(misses)

    def update(self, point: np.ndarray, noise_scale: float = 1.0) -> None:
        """Weight by range and bearing (eq. 3-36), normalise, estimate (eq. 3-38); the
        resampling is deferred (module docstring). ``noise_scale`` multiplies both standard
        deviations."""
        p = self.particles
        self._cov = None
        w = self._weights(p, point, noise_scale)
        self._mean = p @ w  # eq. 3-38
        self._w = w

    def mean_if(self, point: np.ndarray, noise_scale: float = 1.0) -> np.ndarray:
        """(4,) the estimate the last update would have given had it measured ``point``: the
        same cloud (the prediction it weighed) weighed for another measurement. Only between
        an update and the resampling that follows it (:meth:`settle`)."""
        if self._w is None:
            raise RuntimeError("mean_if needs an update not yet resampled")
        return self._p @ self._weights(self._p, point, noise_scale)

    def _weights(self, p: np.ndarray, point: np.ndarray, noise_scale: float) -> np.ndarray:
        """(m,) normalised weights of cloud ``p`` for the measurement ``point`` (eq. 3-36)."""
        zx, zy = float(point[0]), float(point[1])
        d_m = math.hypot(zx, zy)
        a_m = math.atan2(zy, zx)
        # bearing error of each particle = atan2 of its position rotated by -A_m (wrap-free)
        c, s = math.cos(a_m), math.sin(a_m)
        xr = c * p[0] + s * p[1]
        yr = c * p[1] - s * p[0]
        da = np.arctan2(yr, xr)
        dd = np.hypot(xr, yr)
        dd -= d_m
        # log w = -(d_m - d_p)^2 / sigma_d^2 - (A_m - A_p)^2 / sigma_A^2
        k = 1.0 / (noise_scale * noise_scale)
        dd *= dd
        dd *= -self._inv_sd2 * k
        da *= da
        dd -= da * (self._inv_sa2 * k)
        dd -= dd.max()  # the best particle gets exp(0): no underflow to all-zero weights
        w = np.exp(dd, out=dd)
        w /= w.sum()
        return w

    def expired(self) -> bool:
        return False

    def snapshot(self) -> ParticleEstimator:
        """An independent copy of the cloud (for the tracker's rollback); cheaper than
        ``copy.deepcopy``. The copy shares this estimator's Generator: what either draws next
        depends only on the order of the calls, so runs stay deterministic."""
        self.settle()
        c = copy.copy(self)
        c._p = self._p.copy()
        c._spare = np.empty_like(c._p)
        c._ahead, c._ahead_ready = np.empty_like(self._ahead), False  # draws afresh
        c._mean = self._mean.copy()
        return c

    # ------------------------------------------------------------------ all tracks at once

    @staticmethod
    def _batchable(estimators: Sequence[ParticleEstimator]) -> bool:
        """Batch steps need clouds of one size and one settings object (one tracker's)."""
        first = estimators[0].settings
        return len(estimators) > 1 and all(e.settings is first for e in estimators)

    @classmethod
    def motion_all(
        cls,
        estimators: Sequence[ParticleEstimator],
        rotation: np.ndarray | None,
        translation: np.ndarray | None,
        dt_s: float,
        misses: Sequence[int] = (),
    ) -> None:
        """:meth:`ego_motion` (when ``rotation`` is given) then :meth:`predict`, for all (the
        prediction does not depend on ``misses``)."""
        if not cls._batchable(estimators):
            for e in estimators:
                if rotation is not None:
                    e.ego_motion(rotation, translation)
                e.predict(dt_s)
            return
        cls.settle_all(estimators)
        p = np.stack([e._p for e in estimators])  # (T, 4, m)
        if rotation is not None:
            p[:, 0:2] = rotation @ p[:, 0:2]
            p[:, 0] += translation[0]
            p[:, 1] += translation[1]
            p[:, 2:4] = rotation @ p[:, 2:4]
        for i, e in enumerate(estimators):
            e._draw_velocities(p[i, 2:4], dt_s)  # each track's own Generator, in order
        p[:, 0:2] += p[:, 2:4] * dt_s
        means = p.mean(axis=2)
        for i, e in enumerate(estimators):
            e._p = p[i]
            e._mean = means[i]
            e._dt_s = dt_s
            e._cov = None

    @classmethod
    def cost_all(
        cls, estimators: Sequence[ParticleEstimator], points: np.ndarray, misses: Sequence[int]
    ) -> np.ndarray:
        """(T, n) :meth:`distance` of each candidate to each track; inf beyond its :meth:`gate`."""
        means = np.array([e._mean[0:2] for e in estimators])
        d = np.hypot(points[None, :, 0] - means[:, 0:1], points[None, :, 1] - means[:, 1:2])
        gates = np.array([e.gate(k) for e, k in zip(estimators, misses, strict=True)])
        d[d > gates[:, None]] = np.inf
        return d

    @classmethod
    def update_all(
        cls,
        estimators: Sequence[ParticleEstimator],
        points: np.ndarray,
        noise_scales: np.ndarray | None = None,
    ) -> None:
        """:meth:`update` of estimator i with ``points[i]`` (T, 2) and ``noise_scales[i]``
        (default 1), for all at once."""
        if not cls._batchable(estimators):
            for i, (e, z) in enumerate(zip(estimators, points, strict=True)):
                e.update(z, 1.0 if noise_scales is None else float(noise_scales[i]))
            return
        e0 = estimators[0]
        cls.settle_all(estimators)
        p = np.stack([e._p for e in estimators])  # (T, 4, m)
        zx = points[:, 0:1]
        zy = points[:, 1:2]
        a_m = np.arctan2(zy, zx)
        c, s = np.cos(a_m), np.sin(a_m)
        xr = c * p[:, 0] + s * p[:, 1]  # (T, m): each track's cloud rotated by -A_m
        yr = c * p[:, 1] - s * p[:, 0]
        da = np.arctan2(yr, xr)
        dd = np.sqrt(xr * xr + yr * yr)
        dd -= np.hypot(zx, zy)
        k = 1.0 if noise_scales is None else (1.0 / np.square(noise_scales))[:, None]
        dd *= dd
        dd *= -e0._inv_sd2 * k
        da *= da
        dd -= da * (e0._inv_sa2 * k)
        dd -= dd.max(axis=1, keepdims=True)
        w = np.exp(dd, out=dd)
        w /= w.sum(axis=1, keepdims=True)
        means = np.matmul(p, w[:, :, None])[:, :, 0]  # eq. 3-38 per track
        for i, e in enumerate(estimators):
            e._p = p[i]
            e._w = w[i]
            e._mean = means[i]
            e._cov = None

    @classmethod
    def prepare_all(cls, estimators: Sequence[ParticleEstimator]) -> None:
        """Between scans, after the answer has left: :meth:`settle_all`, then
        :meth:`draw_ahead` for each."""
        cls.settle_all(estimators)
        for e in estimators:
            e.draw_ahead()

    @classmethod
    def settle_all(cls, estimators: Sequence[ParticleEstimator]) -> None:
        """:meth:`settle` for all: the posterior covariances and the resampling of every
        estimator with a deferred resampling, in one batch where they can be."""
        pending = [e for e in estimators if e._w is not None]
        if len(pending) < 2 or not cls._batchable(pending):
            for e in pending:
                e.settle()
            return
        e0 = pending[0]
        m = e0._m
        p = np.stack([e._p for e in pending])
        w = np.stack([e._w for e in pending])
        means = np.stack([e._mean for e in pending])
        d = p - means[:, :, None]
        covs = np.matmul(d * w[:, None, :], d.transpose(0, 2, 1))  # posterior, per track
        if e0._resample is systematic_resample:
            # one searchsorted over all tracks: row r's cumulative weights are shifted by r
            t = len(pending)
            rows = np.arange(t)[:, None]
            u = np.array([e.rng.random() for e in pending])[:, None]
            cumulative = np.cumsum(w, axis=1)
            cumulative += rows
            positions = (u + np.arange(m)) / m + rows
            idx = np.searchsorted(cumulative.ravel(), positions.ravel(), side="right")
            idx = idx.reshape(t, m) - rows * m
            np.minimum(idx, m - 1, out=idx)  # round-off: a row may sum to 1 - eps
            np.clip(idx, 0, m - 1, out=idx)
        else:
            idx = np.stack([e._resample(w[i], e.rng) for i, e in enumerate(pending)])
        # gather each track's resampled particles: one flat take (take_along_axis does the
        # same with ~3x the overhead at these sizes)
        out = np.take(p.ravel(), _gather_base(len(pending), m) + idx[:, None, :])
        for i, e in enumerate(pending):
            if e._cov is None:  # (one read before, e.g. the target's: the same value)
                e._cov = covs[i]
            e._p = out[i]
            e._w = None
