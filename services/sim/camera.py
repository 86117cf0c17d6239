"""A pinhole camera that paints the world and the people with OpenCV polygons.

The camera sits ``height_m`` above the floor at the robot's front (``mount_x_m``), looks
horizontally along the robot heading plus the pan angle, and has focal length

    f = (W / 2) / tan(hfov / 2)        (320 px, 47.5 deg: f ~ 363 px; DESIGN.md "Verification")

A world point P = (X, Y, Z) with camera position C and camera yaw psi (robot yaw + pan) maps to

    (x, y) = R(-psi) (P_xy - C),   u = W/2 - f y / x,   v = H/2 - f (Z - h_cam) / x,

which is the inverse of the verifier's rectangle centre u = W/2 - f y / x (same convention, so
the column a person is drawn at is the column vision_verify will look at).

Drawing. Walls and box faces are cut into pieces of at most ``PIECE_M`` (so painter's order by
piece distance is right for long walls too), clipped in the floor plane to the horizontal view
frustum (no coordinates explode near the camera), and filled as quads with a panel shade, a
skirting board and a rail (the texture that gives edges). Circles are upright cylinders.
People are groups of convex polygons: trouser legs from each leg circle to the hip, shoes, a
shirt trapezoid as wide as the body seen from that side, arms, hands, neck, hair and face
ellipses, with optional stripes or checks. Everything is sorted far to near and painted
(painter's algorithm). Brightness is scaled by the lighting gain and sensor noise is added from
a bank of pre-drawn noise frames at a random offset (drawing 230 000 normals per frame would
take longer than the whole render).

Beyond that, each off by default (docs/realism.md "Camera" says what real cameras do):

* **Shade**: a person is painted with the lighting gain times the world's light zones at their
  body centre (``StaticWorld.light_at``).
* **Motion blur** (``exposure_ms``): the frame's stamp is the middle of the exposure. A person
  moves in the image by their velocity less the camera's (the robot's travel) times the
  exposure; they are painted sharp over a snapshot of what lay behind them, then the painted
  pixels (what changed) and their coverage are both smeared with a line kernel of that
  length and direction and laid back over the snapshot (a smeared person is see-through at
  their edges, as on film). The camera's turn (robot and pan) then smears the whole frame
  sideways by f x turn rate x exposure pixels (forward travel's zoom blur is left out: under a
  pixel at the image centre, ~2 px at the edges at 0.75 m/s and 20 ms).
* **Softness** (``optics_blur_px``): a Gaussian blur before the noise (lens, demosaicing).
* **Compression** (``jpeg_quality``): a JPEG round trip after the noise.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from .people import PersonState
from .scenario import AppearanceSpec, CameraSpec
from .world import StaticWorld, rgb_to_bgr

__all__ = ["PIECE_M", "CameraModel", "CameraMotion"]

#: Longest wall piece drawn as one quad, m.
PIECE_M = 0.5
_NEAR_M = 0.05
_NOISE_BANK = 4
_NOISE_PAD = 16
#: Direction the light comes from (world frame), for shading walls by their orientation.
_LIGHT = np.array([math.cos(0.6), math.sin(0.6)])


def _shade(bgr: tuple[int, int, int] | np.ndarray, k: float) -> tuple[int, int, int]:
    return (min(255, int(bgr[0] * k)), min(255, int(bgr[1] * k)), min(255, int(bgr[2] * k)))


class CameraMotion(NamedTuple):
    """How the camera moves while a frame is exposed (world frame)."""

    vx_mps: float
    vy_mps: float
    turn_radps: float
    """The camera's turn rate: the robot's plus the pan unit's."""


def _far_first(job: tuple) -> tuple[float, int]:
    """Painter's order: far to near; at equal distance by kind (pieces, cylinders, people)."""
    return (-job[0], job[1])


class CameraModel:
    """Renders BGR frames of a :class:`StaticWorld` and people (settings: :class:`CameraSpec`)."""

    def __init__(self, spec: CameraSpec, world: StaticWorld, rng: np.random.Generator) -> None:
        self.spec = spec
        self.width, self.height = spec.width, spec.height
        self.cx, self.cy = spec.width / 2.0, spec.height / 2.0
        self.focal_px = (spec.width / 2.0) / math.tan(math.radians(spec.hfov_deg) / 2.0)
        self.world = world
        self.period_s = 1.0 / spec.rate_hz
        # frustum half-angle, a little wider than the image so quads reach its edges
        self._tan_half = (self.cx + 4.0) / self.focal_px
        self._pieces, self._piece_h, self._piece_bgr = self._cut_pieces(world)
        # Python floats/ints for the per-polygon hot path (numpy scalars cost ~1 us per access)
        self._piece_bgr_t = [tuple(c) for c in self._piece_bgr.tolist()]
        self._circle_bgr_t = [tuple(c) for c in world.circle_colour.tolist()]
        self._circle_h = world.circle_height_m.tolist()
        self._shades: dict[tuple, tuple[int, int, int]] = {}
        self._bg: tuple[float, np.ndarray] | None = None
        if spec.noise_std > 0:
            shape = (_NOISE_BANK, spec.height + _NOISE_PAD, spec.width + _NOISE_PAD, 3)
            self._noise = np.round(rng.normal(0.0, spec.noise_std, shape)).astype(np.int16)
        else:
            self._noise = None

    # ------------------------------------------------------------------ static geometry

    @staticmethod
    def _cut_pieces(world: StaticWorld) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cut every segment into pieces of at most PIECE_M; colours carry texture and light."""
        pieces, heights, colours = [], [], []
        for k, (x0, y0, x1, y1) in enumerate(world.segments):
            length = math.hypot(x1 - x0, y1 - y0)
            n = max(1, math.ceil(length / PIECE_M))
            s = np.linspace(0.0, 1.0, n + 1)
            xs, ys = x0 + s * (x1 - x0), y0 + s * (y1 - y0)
            normal = np.array([-(y1 - y0), x1 - x0]) / max(length, 1e-12)
            light = 0.75 + 0.25 * abs(float(normal @ _LIGHT))  # Lambert-ish, either side
            base = world.segment_colour[k].astype(float) * light
            for i in range(n):
                pieces.append([xs[i], ys[i], xs[i + 1], ys[i + 1]])
                heights.append(world.segment_height_m[k])
                panel = 1.0 + (0.06 if (i % 2 == 0) else -0.06) if world.segment_is_wall[k] else 1.0
                colours.append(base * panel)
        return (
            np.asarray(pieces, dtype=np.float64).reshape(-1, 4),
            np.asarray(heights, dtype=np.float64),
            np.asarray(colours, dtype=np.float64).reshape(-1, 3),
        )

    def _shade(self, bgr: tuple, k: float) -> tuple[int, int, int]:
        """:func:`_shade` memoised: a frame shades the same few colours hundreds of times."""
        key = (bgr, k)
        out = self._shades.get(key)
        if out is None:
            if len(self._shades) > 4096:  # lighting ramps make new gains; stay bounded
                self._shades.clear()
            out = self._shades[key] = _shade(bgr, k)
        return out

    # ------------------------------------------------------------------ geometry helpers

    def camera_pose(
        self, robot_pose: tuple[float, float, float], pan_rad: float
    ) -> tuple[float, float, float]:
        x, y, yaw = robot_pose
        mx, my = self.spec.mount_x_m, self.spec.mount_y_m  # the mount, in the base frame
        return (
            x + mx * math.cos(yaw) - my * math.sin(yaw),
            y + mx * math.sin(yaw) + my * math.cos(yaw),
            yaw + math.radians(self.spec.mount_yaw_deg) + pan_rad,
        )

    def to_camera(self, cam: tuple[float, float, float], pts: np.ndarray) -> np.ndarray:
        """World (..., 2) points to camera-frame (x forward, y left)."""
        c, s = math.cos(cam[2]), math.sin(cam[2])
        dx = pts[..., 0] - cam[0]
        dy = pts[..., 1] - cam[1]
        return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)

    def column(self, x_cam: float, y_cam: float) -> float:
        """Image column of a camera-frame point: u = W/2 - f y / x."""
        return self.cx - self.focal_px * y_cam / x_cam

    def row(self, x_cam: float, z_m: float) -> float:
        """Image row of height z at depth x: v = H/2 - f (z - h_cam) / x."""
        return self.cy - self.focal_px * (z_m - self.spec.height_m) / x_cam

    def sees(
        self,
        robot_pose: tuple[float, float, float],
        pan_rad: float,
        point: np.ndarray,
        z_m: float,
    ) -> bool:
        """Whether ``point`` at height ``z_m`` is in the image and not behind a taller wall."""
        cam = self.camera_pose(robot_pose, pan_rad)
        x, y = self.to_camera(cam, np.asarray(point, dtype=float))
        if not (0.3 < x <= self.spec.max_range_m):
            return False
        if not (0.0 <= self.column(x, y) < self.width):
            return False
        segs = self.world.segments[self.world.segment_height_m > z_m]
        if segs.shape[0] == 0:
            return True
        # does the sight line cam -> point cross a segment? (both orientation tests change sign)
        px, py = float(point[0]), float(point[1])
        ax, ay, bx, by = segs[:, 0], segs[:, 1], segs[:, 2], segs[:, 3]

        def side(x0, y0, x1, y1, qx, qy):
            return (x1 - x0) * (qy - y0) - (y1 - y0) * (qx - x0)

        d1 = side(cam[0], cam[1], px, py, ax, ay)
        d2 = side(cam[0], cam[1], px, py, bx, by)
        d3 = side(ax, ay, bx, by, cam[0], cam[1])
        d4 = side(ax, ay, bx, by, px, py)
        return not bool(np.any((d1 * d2 < 0) & (d3 * d4 < 0)))

    # ------------------------------------------------------------------ rendering

    def render(
        self,
        robot_pose: tuple[float, float, float],
        pan_rad: float,
        people: list[tuple[PersonState, AppearanceSpec, float]],
        gain: float,
        rng: np.random.Generator,
        motion: CameraMotion | None = None,
    ) -> np.ndarray:
        """One HxWx3 BGR uint8 frame.

        ``people`` holds (state, appearance, leg radius) per person; ``gain`` scales brightness;
        ``motion`` (None: still) makes the motion blur when the spec has an exposure.
        """
        w = self.width
        cam = self.camera_pose(robot_pose, pan_rad)
        img = self._background(gain).copy()

        jobs: list[tuple[float, int, object]] = []
        self._queue_pieces(cam, jobs)
        self._queue_circles(cam, jobs)
        c, s = math.cos(cam[2]), math.sin(cam[2])
        for k, (state, look, leg_r) in enumerate(people):
            dx, dy = float(state.position[0]) - cam[0], float(state.position[1]) - cam[1]
            x, y = c * dx + s * dy, -s * dx + c * dy
            margin = 0.6 * self.focal_px / max(x, 1e-9)  # a person is < 1.2 m wide
            if 0.3 < x <= self.spec.max_range_m and -margin < self.column(x, y) < w + margin:
                jobs.append((math.hypot(x, y), 2, (k, state, look, leg_r)))
        jobs.sort(key=_far_first)
        for _, kind, data in jobs:
            if kind == 0:
                self._draw_piece(img, data, gain)
            elif kind == 1:
                self._draw_cylinder(img, data, gain)
            else:
                self._draw_person_blurred(img, cam, data, gain, motion)
        return self._finish(img, motion, rng)

    def _finish(self, img: np.ndarray, motion: CameraMotion | None, rng) -> np.ndarray:
        """What the camera does to the scene: turn blur, softness, noise, compression."""
        spec, h, w = self.spec, self.height, self.width
        if spec.exposure_ms > 0 and motion is not None:
            smear = self.focal_px * abs(motion.turn_radps) * spec.exposure_ms * 1e-3
            if smear >= 0.5:
                img = cv2.filter2D(img, -1, _line_kernel(smear, 0.0))
        if spec.optics_blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), spec.optics_blur_px)
        if self._noise is not None:
            k = int(rng.integers(_NOISE_BANK))
            dy, dx = (int(v) for v in rng.integers(_NOISE_PAD, size=2))
            img = cv2.add(img, self._noise[k, dy : dy + h, dx : dx + w], dtype=cv2.CV_8U)
        if spec.jpeg_quality is not None:
            _, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, spec.jpeg_quality])
            img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        return img

    def _background(self, gain: float) -> np.ndarray:
        """Ceiling and floor for this gain (cached: filling them costs ~0.7 ms, a copy ~20 us)."""
        if self._bg is None or self._bg[0] != gain:
            img = np.empty((self.height, self.width, 3), dtype=np.uint8)
            horizon = round(self.cy)
            img[:horizon] = _shade(self.world.ceiling_bgr, gain)
            img[horizon:] = _shade(self.world.floor_bgr, gain)
            # far floor is darker: one band at the horizon gives the floor edge a gradient
            band = max(1, self.height // 12)
            img[horizon : horizon + band] = _shade(self.world.floor_bgr, 0.85 * gain)
            self._bg = (gain, img)
        return self._bg[1]

    def _queue_pieces(self, cam: tuple[float, float, float], jobs: list) -> None:
        if self._pieces.shape[0] == 0:
            return
        a = self.to_camera(cam, self._pieces[:, 0:2])
        b = self.to_camera(cam, self._pieces[:, 2:4])
        keep = np.ones(a.shape[0], dtype=bool)
        t = self._tan_half
        # clip to the half-planes x >= near, t x - y >= 0, t x + y >= 0 (g(P) >= 0 is inside)
        with np.errstate(divide="ignore", invalid="ignore"):
            for gx, gy, g0 in ((1.0, 0.0, -_NEAR_M), (t, -1.0, 0.0), (t, 1.0, 0.0)):
                ga = gx * a[:, 0] + gy * a[:, 1] + g0
                gb = gx * b[:, 0] + gy * b[:, 1] + g0
                keep &= (ga >= 0) | (gb >= 0)
                s = ga / (ga - gb)
                cut = a + s[:, None] * (b - a)  # where the piece crosses the plane
                a, b = (
                    np.where((ga < 0)[:, None], cut, a),
                    np.where((gb < 0)[:, None], cut, b),
                )
        idx = np.flatnonzero(keep)
        if idx.size == 0:
            return
        a, b = a[idx], b[idx]
        mid = 0.5 * (a + b)
        dist = np.hypot(mid[:, 0], mid[:, 1]).tolist()
        # all quads of all pieces at once: body, skirting board, rail -> (P, 3, 4, 2) pixels
        f, cx, cy, hc = self.focal_px, self.cx, self.cy, self.spec.height_m
        ua = cx - f * a[:, 1] / a[:, 0]
        ub = cx - f * b[:, 1] / b[:, 0]
        top = self._piece_h[idx]
        n = idx.size
        z = np.empty((n, 3, 2))  # [z0, z1] of each quad
        z[:, 0, 0], z[:, 0, 1] = 0.0, top
        z[:, 1] = (0.0, 0.1)
        z[:, 2] = (0.88, 0.93)
        va = cy - f * (z - hc) / a[:, 0, None, None]
        vb = cy - f * (z - hc) / b[:, 0, None, None]
        quads = np.empty((n, 3, 4, 2))
        quads[:, :, 0, 0], quads[:, :, 0, 1] = ua[:, None], va[..., 1]
        quads[:, :, 1, 0], quads[:, :, 1, 1] = ub[:, None], vb[..., 1]
        quads[:, :, 2, 0], quads[:, :, 2, 1] = ub[:, None], vb[..., 0]
        quads[:, :, 3, 0], quads[:, :, 3, 1] = ua[:, None], va[..., 0]
        quads = np.rint(quads * 16).astype(np.int32)
        walled = (top > 1.2).tolist()
        for j, k in enumerate(idx.tolist()):
            jobs.append((dist[j], 0, (quads[j], walled[j], self._piece_bgr_t[k])))

    def _draw_piece(self, img, data, gain) -> None:
        quads, walled, base = data
        shade = self._shade
        cv2.fillConvexPoly(img, quads[0], shade(base, gain), cv2.LINE_8, 4)
        if walled:  # walls: skirting board and a rail, so walls have edges
            cv2.fillConvexPoly(img, quads[1], shade(base, 0.55 * gain), cv2.LINE_8, 4)
            cv2.fillConvexPoly(img, quads[2], shade(base, 0.8 * gain), cv2.LINE_8, 4)

    def _queue_circles(self, cam, jobs: list) -> None:
        circles = self.world.circles
        if circles.shape[0] == 0:
            return
        rel = self.to_camera(cam, circles[:, 0:2])
        near = np.flatnonzero(rel[:, 0] > 0.3).tolist()
        if not near:
            return
        xs, ys = rel[near, 0].tolist(), rel[near, 1].tolist()
        radii = circles[near, 2].tolist()
        f, cx, w = self.focal_px, self.cx, self.width
        for k, x, y, r in zip(near, xs, ys, radii, strict=True):
            half = f * r / x
            u = cx - f * y / x
            if -half <= u <= w + half:
                jobs.append((math.hypot(x, y), 1, (x, u, half, k)))

    def _draw_cylinder(self, img, data, gain) -> None:
        x, u, half, k = data
        top = round(self.row(x, self._circle_h[k]) * 16)
        bottom = round(self.row(x, 0.0) * 16)
        bgr = self._circle_bgr_t[k]
        lit = self._shade(bgr, gain)
        dark = self._shade(bgr, 0.65 * gain)
        # an upright rectangle: cv2.rectangle fills exactly what fillConvexPoly would (shift 4)
        for (ua, ub), colour in (((u - half, u + half), lit), ((u + 0.3 * half, u + half), dark)):
            pt1, pt2 = (round(ua * 16), top), (round(ub * 16), bottom)
            cv2.rectangle(img, pt1, pt2, colour, -1, cv2.LINE_8, 4)

    # people -----------------------------------------------------------------

    def _draw_person_blurred(self, img, cam, data, gain, motion: CameraMotion | None) -> None:
        """Paint one person in their light, smeared by their image motion (module docstring)."""
        _, state, look, _ = data
        gain *= self.world.light_at(float(state.position[0]), float(state.position[1]))
        smear = self._person_smear(cam, state, look, motion)
        if smear is None:
            self._draw_person(img, cam, data, gain)
            return
        du, dv = smear
        box = self._box(self._person_view(cam, state, look.height_m), look)
        pad = 0.5 * max(abs(du), abs(dv)) + 2.0
        x0, y0 = max(0, math.floor(box[0] - pad)), max(0, math.floor(box[1] - pad))
        x1 = min(self.width, math.ceil(box[2] + pad))
        y1 = min(self.height, math.ceil(box[3] + pad))
        if x1 <= x0 or y1 <= y0:
            return
        before = img[y0:y1, x0:x1].copy()
        self._draw_person(img, cam, data, gain)
        _smear(img[y0:y1, x0:x1], before, _line_kernel(du, dv))

    def _person_smear(self, cam, state: PersonState, look: AppearanceSpec, motion):
        """(du, dv) pixels the person's hip moves in the image during the exposure, from
        their velocity less the camera's; None: no blur (no exposure, or under half a px)."""
        if self.spec.exposure_ms <= 0:
            return None
        t = self.spec.exposure_ms * 1e-3
        vx, vy = float(state.velocity[0]), float(state.velocity[1])
        if motion is not None:
            vx, vy = vx - motion.vx_mps, vy - motion.vy_mps
        c, s = math.cos(cam[2]), math.sin(cam[2])
        dx, dy = float(state.position[0]) - cam[0], float(state.position[1]) - cam[1]
        x0, y0 = c * dx + s * dy, -s * dx + c * dy
        x1, y1 = x0 - (c * vx + s * vy) * t, y0 - (-s * vx + c * vy) * t  # at the start
        if x0 < 0.3 or x1 < 0.3:
            return None
        z = 0.52 * look.height_m
        du = self.column(x0, y0) - self.column(x1, y1)
        dv = self.row(x0, z) - self.row(x1, z)
        return (du, dv) if math.hypot(du, dv) >= 0.5 else None

    def person_box(
        self,
        robot_pose: tuple[float, float, float],
        pan_rad: float,
        state: PersonState,
        look: AppearanceSpec,
    ) -> tuple[float, float, float, float] | None:
        """The person's whole body in the image (x0, y0, x1, y1 pixels, unclipped: it may
        reach past the border), as drawn without blur; None when not in front of the camera."""
        cam = self.camera_pose(robot_pose, pan_rad)
        view = self._person_view(cam, state, look.height_m)
        if view.body[0] < 0.3 or view.body[0] > self.spec.max_range_m:
            return None
        return self._box(view, look)

    def _box(self, view: _PersonView, look: AppearanceSpec) -> tuple[float, float, float, float]:
        torso = self._torso(view, look)
        reach = torso.half_w + 0.06 * view.px_per_m * 1.1  # the sleeves
        us, vs = [torso.u0 - reach, torso.u0 + reach], [self.row(view.body[0], look.height_m)]
        for foot in view.legs:
            if foot[0] >= 0.2:
                u = self.column(foot[0], foot[1])
                r = self.focal_px * 0.08 / foot[0]
                us += [u - r, u + r]
                vs.append(self.row(foot[0], 0.0))
        return (min(us), min(vs), max(us), max(vs))

    def _draw_person(self, img, cam, data, gain) -> None:
        """Paint one person: the quads of legs and upper body back to front (converted to
        pixels at once), then the head."""
        _, state, look, leg_r = data
        view = self._person_view(cam, state, look.height_m)
        pal = self._palette(look, gain)
        polys = self._leg_quads(view, pal, leg_r)
        torso = None
        if view.body[0] >= 0.3:
            torso = self._torso(view, look)
            polys += _arm_quads(view, torso, pal)
            polys += _shirt_quads(view, torso, pal, look.pattern)
            polys.append(self._neck_quad(view, torso, pal))
        if polys:
            flat = np.rint(np.array([pt for pts, _ in polys for pt in pts]) * 16).astype(np.int32)
            for k, (_, colour) in enumerate(polys):  # every polygon is a quad
                cv2.fillConvexPoly(img, flat[4 * k : 4 * k + 4], colour, cv2.LINE_8, 4)
        if torso is not None:
            self._draw_head(img, view, torso, pal)

    def _person_view(self, cam, state: PersonState, height_m: float) -> _PersonView:
        """Where the person's body and legs are in the camera frame, and how they are turned."""
        c, s = math.cos(cam[2]), math.sin(cam[2])
        dx, dy = float(state.position[0]) - cam[0], float(state.position[1]) - cam[1]
        body = [c * dx + s * dy, -s * dx + c * dy]
        legs = []
        for lx, ly in state.legs.tolist():
            dx, dy = lx - cam[0], ly - cam[1]
            legs.append([c * dx + s * dy, -s * dx + c * dy])
        rel_h = state.heading_rad - cam[2]
        view = math.atan2(body[1], body[0])
        px_per_m = self.focal_px / body[0]
        return _PersonView(
            body=body,
            legs=legs,
            z_hip=0.52 * height_m,
            z_shoulder=0.82 * height_m,
            z_head=height_m - 0.115,
            rel_heading_rad=rel_h,
            side=(-math.sin(rel_h), math.cos(rel_h)),
            view_rad=view,
            facing=math.cos(rel_h - view),
            px_per_m=px_per_m,
            detail=px_per_m > 40.0,  # far people lose stripes, creases and hands
        )

    def _palette(self, look: AppearanceSpec, gain: float) -> _Palette:
        """The person's colours as BGR under this lighting gain (shaded variants included)."""

        def pal(rgb, k=1.0):
            return self._shade(rgb_to_bgr(rgb), k * gain)

        return _Palette(
            trousers=pal(look.trousers_rgb),
            trousers_dark=pal(look.trousers_rgb, 0.8),
            shirt=pal(look.shirt_rgb),
            shirt_dark=pal(look.shirt_rgb, 0.78),
            skin=pal(look.skin_rgb),
            hair=pal(look.hair_rgb),
            shoes=pal(look.shoes_rgb),
        )

    def _pixel(self, pt, z: float) -> tuple[float, float]:
        """Pixel of a camera-frame floor point ``pt`` raised to height ``z``."""
        f = self.focal_px
        return (self.cx - f * pt[1] / pt[0], self.cy - f * (z - self.spec.height_m) / pt[0])

    def _leg_quads(self, view: _PersonView, pal: _Palette, leg_r: float) -> list[_Quad]:
        """Trouser legs, far one first, each from its leg circle on the floor to its hip joint,
        with a crease (near people) and a shoe."""
        P = self._pixel
        body, side, z_hip = view.body, view.side, view.z_hip
        polys: list[_Quad] = []
        far_first = sorted(range(2), key=lambda i: -math.hypot(*view.legs[i]))
        for rank, i in enumerate(far_first):
            sgn = 0.09 if i == 0 else -0.09
            hip = (body[0] + side[0] * sgn, body[1] + side[1] * sgn)
            foot = view.legs[i]
            if foot[0] < 0.2 or hip[0] < 0.2:
                continue
            fl, fr = _across(foot, leg_r * 1.05)
            hl, hr = _across(hip, leg_r * 1.5)
            colour = pal.trousers_dark if rank == 0 else pal.trousers
            polys.append(([P(fl, 0.0), P(fr, 0.0), P(hr, z_hip), P(hl, z_hip)], colour))
            if view.detail:  # a crease: a darker strip down one side of the leg
                fm, _ = _across(foot, leg_r * 0.3)
                hm, _ = _across(hip, leg_r * 0.45)
                polys.append(
                    ([P(fl, 0.0), P(fm, 0.0), P(hm, z_hip), P(hl, z_hip)], _shade(colour, 0.8))
                )
            polys.append(([P(fl, 0.0), P(fr, 0.0), P(fr, 0.08), P(fl, 0.08)], pal.shoes))
        return polys

    def _torso(self, view: _PersonView, look: AppearanceSpec) -> _Torso:
        """The torso's outline in pixels: as wide as the shoulders across, ~0.25 m deep."""
        body, px_per_m, hc = view.body, view.px_per_m, self.spec.height_m
        turn = view.rel_heading_rad - view.view_rad
        half_w = (
            0.5
            * px_per_m
            * max(
                look.shoulder_width_m * abs(math.cos(turn)) + 0.25 * abs(math.sin(turn)),
                0.25,
            )
        )
        return _Torso(
            u0=self.cx - self.focal_px * body[1] / body[0],
            half_w=half_w,
            waist=0.82 * half_w,
            v_shoulder=self.cy - (view.z_shoulder - hc) * px_per_m,
            v_hip=self.cy - (view.z_hip - hc) * px_per_m,
        )

    def _neck_quad(self, view: _PersonView, torso: _Torso, pal: _Palette) -> _Quad:
        u0, v_sh = torso.u0, torso.v_shoulder
        neck = 0.05 * view.px_per_m
        v_neck = self.cy - (view.z_head - 0.08 - self.spec.height_m) * view.px_per_m
        quad = [
            (u0 - neck, v_neck),
            (u0 + neck, v_neck),
            (u0 + neck, v_sh + 1),
            (u0 - neck, v_sh + 1),
        ]
        return (quad, _shade(pal.skin, 0.85))

    def _draw_head(self, img, view: _PersonView, torso: _Torso, pal: _Palette) -> None:
        """Hair all round; a face when turned towards the camera (off-centre when half turned)."""
        px_per_m = view.px_per_m
        vh = self.cy - (view.z_head - self.spec.height_m) * px_per_m
        ax_w, ax_h = 0.085 * px_per_m, 0.115 * px_per_m
        centre = (round(torso.u0 * 16), round(vh * 16))
        axes = (max(1, round(ax_w * 16)), max(1, round(ax_h * 16)))
        cv2.ellipse(img, centre, axes, 0, 0, 360, pal.hair, -1, cv2.LINE_8, 4)
        facing = view.facing
        if facing < 0.5:
            frac = 0.8 if facing < -0.3 else 0.55
            turn = (
                0.0
                if facing < -0.3
                else 0.2 * ax_w * math.sin(view.rel_heading_rad - view.view_rad)
            )
            fc = (round((torso.u0 - turn) * 16), round((vh + 0.25 * ax_h) * 16))
            fa = (max(1, round(ax_w * frac * 16)), max(1, round(ax_h * 0.75 * 16)))
            cv2.ellipse(img, fc, fa, 0, 0, 360, pal.skin, -1, cv2.LINE_8, 4)


_Quad = tuple[list[tuple[float, float]], tuple[int, int, int]]
"""A filled quad: four pixel corners and a BGR colour."""


class _PersonView(NamedTuple):
    """A person as the camera sees them (camera frame: x forward, y left)."""

    body: list[float]
    """Body centre on the floor."""
    legs: list[list[float]]
    """Leg centres on the floor."""
    z_hip: float
    z_shoulder: float
    z_head: float
    """Height of the head's centre, m."""
    rel_heading_rad: float
    """Body heading relative to the camera's."""
    side: tuple[float, float]
    """The body's left, in the camera frame."""
    view_rad: float
    """Bearing of the body from the camera."""
    facing: float
    """> 0: walking away from the camera (back visible); < 0: facing it."""
    px_per_m: float
    """Pixels per metre at the body's depth."""
    detail: bool
    """Near enough for stripes, creases and hands."""


class _Palette(NamedTuple):
    """A person's BGR colours under the current lighting."""

    trousers: tuple[int, int, int]
    trousers_dark: tuple[int, int, int]
    shirt: tuple[int, int, int]
    shirt_dark: tuple[int, int, int]
    skin: tuple[int, int, int]
    hair: tuple[int, int, int]
    shoes: tuple[int, int, int]


class _Torso(NamedTuple):
    """The torso's outline in pixels: centre column, half widths at the shoulders and the
    waist, rows of the shoulders and the hips."""

    u0: float
    half_w: float
    waist: float
    v_shoulder: float
    v_hip: float


def _line_kernel(du: float, dv: float) -> np.ndarray:
    """A normalised kernel that spreads a pixel evenly along the segment (-du/2, -dv/2) ..
    (du/2, dv/2) about its centre (bilinear weights, so sub-pixel lengths count)."""
    half = math.ceil(0.5 * max(abs(du), abs(dv))) + 1
    k = np.zeros((2 * half + 1, 2 * half + 1), dtype=np.float32)
    n = max(2, math.ceil(4 * math.hypot(du, dv)) + 1)
    for t in np.linspace(-0.5, 0.5, n).tolist():
        x, y = half + t * du, half + t * dv
        ix, iy = math.floor(x), math.floor(y)
        fx, fy = x - ix, y - iy
        k[iy, ix] += (1 - fx) * (1 - fy)
        k[iy, ix + 1] += fx * (1 - fy)
        k[iy + 1, ix] += (1 - fx) * fy
        k[iy + 1, ix + 1] += fx * fy
    return k / k.sum()


def _smear(region: np.ndarray, before: np.ndarray, kernel: np.ndarray) -> None:
    """Smear what was painted over ``before`` in ``region`` (in place): the changed pixels and
    their coverage are blurred with ``kernel`` and laid over ``before``."""
    cover = np.any(region != before, axis=2).astype(np.float32)
    fg = region.astype(np.float32) * cover[..., None]
    fg = cv2.filter2D(fg, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    cover = cv2.filter2D(cover, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    out = fg + (1.0 - cover)[..., None] * before.astype(np.float32)
    region[:] = np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _across(pt, r: float):
    """The points ``r`` either side of camera-frame ``pt``, perpendicular to the sight line."""
    n = math.hypot(pt[0], pt[1])
    ox, oy = -pt[1] / n * r, pt[0] / n * r
    return (pt[0] + ox, pt[1] + oy), (pt[0] - ox, pt[1] - oy)


def _arm_quads(view: _PersonView, torso: _Torso, pal: _Palette) -> list[_Quad]:
    """Sleeves just outside the torso's edges, and hands below them on near people."""
    u0, half_w, v_sh, v_hip = torso.u0, torso.half_w, torso.v_shoulder, torso.v_hip
    arm = 0.06 * view.px_per_m
    polys: list[_Quad] = []
    for sgn in (-1.0, 1.0):
        xo = u0 + sgn * (half_w + arm * 0.6)
        a0, a1 = xo - arm / 2, xo + arm / 2
        sleeve = [
            (a0, v_sh + arm * 0.3),
            (a1, v_sh + arm * 0.3),
            (a1, v_hip + arm),
            (a0, v_hip + arm),
        ]
        polys.append((sleeve, pal.shirt_dark))
        if view.detail:
            hand = [
                (a0, v_hip + arm),
                (a1, v_hip + arm),
                (a1, v_hip + 2.2 * arm),
                (a0, v_hip + 2.2 * arm),
            ]
            polys.append((hand, pal.skin))
    return polys


def _shirt_quads(view: _PersonView, torso: _Torso, pal: _Palette, pattern: str) -> list[_Quad]:
    """The shirt: a trapezoid from the shoulders to just below the hips, darker strips inside
    both edges (the torso is round), and on near people its stripes or checks."""
    u0, half_w, waist = torso.u0, torso.half_w, torso.waist
    v_sh, v_hip = torso.v_shoulder, torso.v_hip
    v_waist = v_hip + 0.05 * view.px_per_m
    shirt = [(u0 - half_w, v_sh), (u0 + half_w, v_sh), (u0 + waist, v_waist), (u0 - waist, v_waist)]
    polys: list[_Quad] = [(shirt, pal.shirt)]
    for sgn in (-1.0, 1.0):
        edge = [
            (u0 + sgn * half_w, v_sh),
            (u0 + sgn * 0.7 * half_w, v_sh),
            (u0 + sgn * 0.7 * waist, v_hip),
            (u0 + sgn * waist, v_hip),
        ]
        polys.append((edge, pal.shirt_dark))
    if view.detail and pattern in ("stripes", "checks"):
        polys += _shirt_pattern(torso, _shade(pal.shirt, 0.6), pattern)
    return polys


def _shirt_pattern(torso: _Torso, stripe: tuple[int, int, int], pattern: str) -> list[_Quad]:
    """Five horizontal stripes following the shirt's taper; checks add three vertical bars."""
    u0, half_w, waist = torso.u0, torso.half_w, torso.waist
    v_sh, v_hip = torso.v_shoulder, torso.v_hip
    polys: list[_Quad] = []
    n = 5
    for k in range(n):
        va = v_sh + (v_hip - v_sh) * (2 * k + 0.5) / (2 * n)
        vb = v_sh + (v_hip - v_sh) * (2 * k + 1.5) / (2 * n)
        wa = half_w - (half_w - waist) * (va - v_sh) / (v_hip - v_sh)
        wb = half_w - (half_w - waist) * (vb - v_sh) / (v_hip - v_sh)
        polys.append(([(u0 - wa, va), (u0 + wa, va), (u0 + wb, vb), (u0 - wb, vb)], stripe))
    if pattern == "checks":
        bw = 0.08 * waist
        for frac in (-0.4, 0.0, 0.4):
            uc = u0 + frac * waist
            bar = [(uc - bw, v_sh), (uc + bw, v_sh), (uc + bw, v_hip), (uc - bw, v_hip)]
            polys.append((bar, stripe))
    return polys
