"""Scan matching: the pose of one laser scan in another's frame, by projective point-to-line ICP.

Censi's PL-ICP idea in its simplest form, all numpy. With ``c_i`` the points of the current
scan and ``p_j``, ``n_j`` the points and surface normals of the reference scan::

    q_i  = R(θ) c_i + t                      current point i in the reference scan's frame
    j(i) = the beam of the reference scan nearest q_i among the ±w beams around q_i's bearing
    e_i  = n_j · (q_i − p_j)                 distance to the reference surface (normal n_j)
    J_i  = [n_j,x, n_j,y, n_j · perp(q_i − t)]   perp(v) = (−v_y, v_x): ∂q/∂θ
    (Σ JᵀJ + λI) δ = −Σ Jᵀ e,  (t, θ) += δ   Gauss-Newton, 3 parameters, inliers |q − p| < d_max

from a guess (the caller's: a constant-velocity prediction, say). One implementation for every
user: the static background of laser_legs (consecutive scans) and the laser_odometry service
(scans against a keyframe).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MATCH_WINDOW", "ScanFrame", "beam_index", "compose", "invert", "match_scans"]

TWO_PI = 2.0 * math.pi


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose a ∘ b of (x, y, θ) poses: b given in a's frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def invert(a: np.ndarray) -> np.ndarray:
    """The inverse of pose ``a`` (x, y, θ): compose(a, invert(a)) is the identity."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


def beam_index(phi: np.ndarray, angle_min_rad: float, increment_rad: float, n: int) -> np.ndarray:
    """Beam index nearest each bearing ``phi`` (any shape), -1 where no beam looks there."""
    inc = abs(increment_rad)
    u = np.mod((phi - angle_min_rad) * (1.0 if increment_rad >= 0 else -1.0), TWO_PI)
    b = np.floor(u / inc + 0.5).astype(np.intp)
    full = round(TWO_PI / inc)
    b[b == full] = 0  # a full circle: the last bin wraps to beam 0
    b[b >= n] = -1
    return b


#: Half-width (beams) of the window searched around a point's bearing when matching.
MATCH_WINDOW = 3
#: Coordinates given to beams without a usable surface normal: never the nearest.
_FAR = 1.0e6


class ScanFrame:
    """One scan's points in its own frame, with per-beam surface normals (for matching).

    ``surf`` is (4, n + 2w): x, y, normal x, normal y, padded with ``w = MATCH_WINDOW`` beams
    on both sides; beams without a usable normal (and the pads) sit at ``_FAR``. A beam has a
    normal when both neighbours have returns at most ``max_chord_m`` apart (a sparse scanner's
    distant walls need more than the default). Points and normals are computed when the frame
    is first matched (or matched against): a scan placed by a given pose never needs them.
    """

    __slots__ = ("_cos", "_max_chord_m", "_n_normals", "_sin", "_surf", "_xy", "ok", "r")

    def __init__(
        self,
        r: np.ndarray,
        ok: np.ndarray,
        cos: np.ndarray,
        sin: np.ndarray,
        max_chord_m: float = 0.2,
    ) -> None:
        self.r = np.where(ok, r, np.nan)
        self.ok = ok
        self._cos, self._sin = cos, sin
        self._max_chord_m = max_chord_m
        self._xy: tuple[np.ndarray, np.ndarray] | None = None
        self._surf: np.ndarray | None = None
        self._n_normals = 0

    @property
    def x(self) -> np.ndarray:
        return self._points()[0]

    @property
    def y(self) -> np.ndarray:
        return self._points()[1]

    def _points(self) -> tuple[np.ndarray, np.ndarray]:
        if self._xy is None:
            ok, r = self.ok, self.r
            self._xy = (np.where(ok, r * self._cos, 0.0), np.where(ok, r * self._sin, 0.0))
        return self._xy

    @property
    def surf(self) -> np.ndarray:
        if self._surf is None:
            self._normals()
        return self._surf

    @property
    def n_normals(self) -> int:
        if self._surf is None:
            self._normals()
        return self._n_normals

    def _normals(self) -> None:
        (x, y), ok = self._points(), self.ok
        n = x.shape[0]
        w = MATCH_WINDOW
        surf = np.full((4, n + 2 * w), _FAR)
        surf[2:] = 0.0
        if n >= 3:
            # normal from the neighbours on both sides, at most max_chord_m apart (a locally
            # smooth surface only)
            tx = x[2:] - x[:-2]
            ty = y[2:] - y[:-2]
            t2 = tx * tx + ty * ty
            chord2 = self._max_chord_m * self._max_chord_m
            good = ok[2:] & ok[:-2] & ok[1:-1] & (t2 > 1e-8) & (t2 < chord2)
            norm = np.sqrt(np.where(good, t2, 1.0))
            sl = slice(w + 1, w + n - 1)
            surf[0, sl] = np.where(good, x[1:-1], _FAR)
            surf[1, sl] = np.where(good, y[1:-1], _FAR)
            surf[2, sl] = -ty / norm
            surf[3, sl] = tx / norm
            self._n_normals = int(np.count_nonzero(good))
        self._surf = surf


def match_scans(
    prev: ScanFrame,
    cur: ScanFrame,
    angle_min_rad: float,
    increment_rad: float,
    guess: np.ndarray,
    *,
    stride: int = 3,
    iterations: int = 10,
    max_distance_m: tuple[float, ...] = (0.4, 0.2, 0.1),
) -> tuple[np.ndarray, float]:
    """Pose (x, y, θ) of the ``cur`` scan in the ``prev`` scan's frame, and the share of the
    matched points that are inliers at the end (0 when too few points to match).

    ``max_distance_m``: the inlier distance of the first iterations, the last one after.
    """
    n = prev.r.shape[0]
    sel = np.flatnonzero(cur.ok[::stride]) * stride
    if sel.shape[0] < 10 or prev.n_normals < 10:
        return guess.copy(), 0.0
    cx, cy = cur.x[sel], cur.y[sel]
    tx, ty, th = (float(v) for v in guess)
    offsets = np.arange(2 * MATCH_WINDOW + 1)
    rows = np.arange(sel.shape[0])
    surf = prev.surf
    frac = 0.0
    for it in range(iterations):
        c, s = math.cos(th), math.sin(th)
        qx = c * cx - s * cy + tx
        qy = s * cx + c * cy + ty
        b = beam_index(np.arctan2(qy, qx), angle_min_rad, increment_rad, n)
        seen = b >= 0
        bw = b[:, None] + offsets  # padded indices: beam b - w .. b + w
        dx = qx[:, None] - surf[0, bw]
        dy = qy[:, None] - surf[1, bw]
        d2 = dx * dx + dy * dy
        j = d2.argmin(axis=1)
        dmax = max_distance_m[min(it, len(max_distance_m) - 1)]
        inl = (d2[rows, j] < dmax * dmax) & seen
        m = int(np.count_nonzero(inl))
        frac = m / sel.shape[0]
        if m < 10:
            return np.array([tx, ty, th]), 0.0
        jr = rows[inl]
        jb = bw[jr, j[inl]]
        nx, ny = surf[2, jb], surf[3, jb]
        e = nx * dx[jr, j[inl]] + ny * dy[jr, j[inl]]  # e_i = n · (q − p)
        jt = ny * (qx[inl] - tx) - nx * (qy[inl] - ty)  # ∂e/∂θ = n · perp(q − t)
        J = np.array([nx, ny, jt])
        H = J @ J.T
        H.flat[::4] += 1e-6
        delta = np.linalg.solve(H, -(J @ e))
        tx += float(delta[0])
        ty += float(delta[1])
        th += float(delta[2])
        if it >= len(max_distance_m) - 1 and abs(delta[0]) + abs(delta[1]) + abs(delta[2]) < 1e-3:
            break
    return np.array([tx, ty, th]), frac
