"""Scenario files: the world, the robot, its sensors and the people's scripts, as YAML.

A scenario is parsed by ``yaml.safe_load`` and then converted with ``msgspec.convert`` into the
Structs below. Every Struct forbids unknown fields, so a misspelt key is an error, and every
bound is a ``msgspec.Meta`` constraint, so a wrong value is an error naming its path:

    ScenarioError: arc.yaml: Expected `float` > 0.0 - at `$.people[0].path[1].speed_mps`

Units are SI (m, s, m/s). Angles a person writes by hand are in degrees and say so in the
field name (``yaw_deg``, ``fov_deg``); they are converted to radians where they are used.
Colours are ``[r, g, b]`` with components 0-255. The format is documented in
``docs/scenarios.md``; :func:`json_schema` exports the JSON Schema.
"""

from __future__ import annotations

import json
import math
import sys
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal

import msgspec
import yaml

from followbot.services.runtime.mount import LaserMount

__all__ = [
    "ArcStep",
    "BoxSpec",
    "CameraSpec",
    "CircleSpec",
    "DressSpec",
    "GaitSpec",
    "LaserSpec",
    "LightZoneSpec",
    "LightingKey",
    "MeasuredLaserSpec",
    "OdometrySpec",
    "PauseStep",
    "PersonSpec",
    "RobotSpec",
    "Scenario",
    "ScenarioError",
    "TurnStep",
    "WalkStep",
    "WallSpec",
    "WorldSpec",
    "builtin_names",
    "json_schema",
    "load_builtin",
    "load_scenario",
    "parse_scenario",
]

Pos = Annotated[float, msgspec.Meta(gt=0.0, le=1e6)]
NonNeg = Annotated[float, msgspec.Meta(ge=0.0, le=1e6)]
Coord = Annotated[float, msgspec.Meta(ge=-1e4, le=1e4)]
Point = tuple[Coord, Coord]
Prob = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
Channel = Annotated[int, msgspec.Meta(ge=0, le=255)]
RGB = tuple[Channel, Channel, Channel]


class _Spec(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Base of every scenario Struct: unknown keys are errors, not silently ignored."""


# --------------------------------------------------------------------------- static world


class WallSpec(_Spec):
    """A polyline of wall segments (``closed`` joins the last point to the first)."""

    points: Annotated[list[Point], msgspec.Meta(min_length=2)]
    closed: bool = False
    height_m: Pos = 2.5
    colour_rgb: RGB = (200, 196, 182)


class CircleSpec(_Spec):
    """A vertical cylinder: table or chair leg, pillar, bin."""

    centre: Point
    radius_m: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)]
    height_m: Pos = 0.75
    colour_rgb: RGB = (90, 70, 50)


class BoxSpec(_Spec):
    """An upright box (4 wall faces): cabinet, crate, door jamb. ``size`` is (length, width)."""

    centre: Point
    size_m: tuple[Pos, Pos]
    yaw_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    height_m: Pos = 1.0
    colour_rgb: RGB = (150, 110, 60)


class LightZoneSpec(_Spec):
    """A floor rectangle (axis-aligned) where people are lit by ``gain`` times the scene's
    lighting: shade under a gallery (< 1), sun from a window (> 1). The camera paints a person
    by the zones at their body centre; across ``edge_m`` outside the rectangle the gain blends
    linearly back to 1 (a soft shadow edge). Walls, floor and furniture are not changed."""

    centre: Point
    size_m: tuple[Pos, Pos]
    gain: Annotated[float, msgspec.Meta(ge=0.0, le=4.0)]
    edge_m: NonNeg = 0.5


class WorldSpec(_Spec):
    walls: list[WallSpec] = []
    circles: list[CircleSpec] = []
    boxes: list[BoxSpec] = []
    floor_rgb: RGB = (120, 118, 112)
    ceiling_rgb: RGB = (225, 225, 220)
    light_zones: list[LightZoneSpec] = []
    """Where people stand in shade or in light (camera only; docs/realism.md "Camera")."""


# --------------------------------------------------------------------------- people


class WalkStep(_Spec, tag_field="kind", tag="walk"):
    """Walk in a straight line to ``to`` (at ``speed_mps``, else the person's speed)."""

    to: Point
    speed_mps: Annotated[float, msgspec.Meta(gt=0.0, le=5.0)] | None = None


class ArcStep(_Spec, tag_field="kind", tag="arc"):
    """Walk round ``centre`` by ``sweep_deg`` (counter-clockwise positive) at constant radius."""

    centre: Point
    sweep_deg: Annotated[float, msgspec.Meta(ge=-3600.0, le=3600.0)]
    speed_mps: Annotated[float, msgspec.Meta(gt=0.0, le=5.0)] | None = None


class PauseStep(_Spec, tag_field="kind", tag="pause"):
    """Stand still for ``duration_s``."""

    duration_s: NonNeg


class TurnStep(_Spec, tag_field="kind", tag="turn"):
    """Turn on the spot to face ``heading_deg`` (world frame, counter-clockwise from +x)."""

    heading_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)]


PathStep = WalkStep | ArcStep | PauseStep | TurnStep


class GaitSpec(_Spec):
    """How a person's legs move (see ``people.py`` for the model)."""

    # thesis 5.2.2: 300 mm steps, two steps per second at 600 mm/s (cadence = speed / step)
    step_length_m: Annotated[float, msgspec.Meta(gt=0.05, le=1.2)] = 0.3
    leg_radius_m: Annotated[float, msgspec.Meta(ge=0.03, le=0.12)] = 0.06
    hip_width_m: Annotated[float, msgspec.Meta(ge=0.0, le=0.5)] = 0.18
    """Lateral distance between leg centres while walking."""
    stance: Literal["together", "apart"] = "together"
    """Pose when standing: legs side by side, or one a little ahead and wider."""
    turn_rate_deg_s: Annotated[float, msgspec.Meta(gt=0.0, le=2000.0)] = 180.0


class AppearanceSpec(_Spec):
    shirt_rgb: RGB = (40, 90, 200)
    trousers_rgb: RGB = (40, 40, 60)
    skin_rgb: RGB = (225, 180, 150)
    hair_rgb: RGB = (60, 40, 25)
    shoes_rgb: RGB = (25, 25, 25)
    pattern: Literal["plain", "stripes", "checks"] = "plain"
    height_m: Annotated[float, msgspec.Meta(ge=1.0, le=2.3)] = 1.75
    shoulder_width_m: Annotated[float, msgspec.Meta(ge=0.2, le=0.7)] = 0.44


class DressSpec(_Spec):
    """Clothes drawn at random (services/sim/dress.py) instead of ``appearance``'s colours,
    from the scenario's seed and the person's id (so adding a person changes nobody else)."""

    style: Literal["pedestrian", "lookalike"]
    """pedestrian: a plausible everyday outfit (dark, grey and blue tops; dark or blue
    trousers; docs/realism.md "Camera"), height and build drawn too. lookalike: dressed like
    person ``of``: each garment's colour moved by a random RGB offset of length
    ``colour_spread`` x U(0.5, 1), the same pattern; own height, build, skin and hair."""
    of: Annotated[int, msgspec.Meta(ge=0, le=10_000)] | None = None
    """lookalike: the id of the person copied (not itself a lookalike)."""
    colour_spread: Annotated[float, msgspec.Meta(ge=0.0, le=128.0)] = 30.0
    """lookalike: the largest RGB offset of a garment's colour, grey levels."""


class PersonSpec(_Spec):
    id: Annotated[int, msgspec.Meta(ge=0, le=10_000)]
    start: Point
    heading_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    speed_mps: Annotated[float, msgspec.Meta(gt=0.0, le=5.0)] = 0.6
    path: list[PathStep] = []
    loop: bool = False
    """Repeat the path from the start when it ends (the path should end where it starts)."""
    is_target: bool = False
    gait: GaitSpec = msgspec.field(default_factory=GaitSpec)
    appearance: AppearanceSpec = msgspec.field(default_factory=AppearanceSpec)
    dress: DressSpec | None = None
    """Random clothes instead of ``appearance``'s (null: ``appearance`` as written)."""


# --------------------------------------------------------------------------- robot, sensors


class OdometrySpec(_Spec):
    """Encoder noise: each wheel's distance is scaled by (1 + bias + slip) plus white noise."""

    noise: bool = True
    wheel_noise_m_per_sqrt_m: NonNeg = 0.01
    """Standard deviation of a wheel's distance error per sqrt(metre) travelled."""
    wheel_bias: Annotated[float, msgspec.Meta(ge=0.0, le=0.2)] = 0.005
    """Std of each wheel's fixed scale error, drawn once (calibration error)."""
    slip_std: Annotated[float, msgspec.Meta(ge=0.0, le=0.5)] = 0.01
    """Std of the per-step slip fraction (always over-reports distance)."""
    rate_hz: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] = 50.0


class RobotSpec(_Spec):
    start: Point = (0.0, 0.0)
    yaw_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    # thesis 4.6 / 5.2.5: 750 mm/s, 100 deg/s; pan 90 deg/s within +-100 deg
    max_speed_mps: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 0.75
    max_turn_deg_s: Annotated[float, msgspec.Meta(gt=0.0, le=1000.0)] = 100.0
    max_accel_mps2: Annotated[float, msgspec.Meta(gt=0.0, le=50.0)] = 1.0
    max_turn_accel_deg_s2: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] = 300.0
    wheel_base_m: Annotated[float, msgspec.Meta(gt=0.05, le=2.0)] = 0.33
    radius_m: Annotated[float, msgspec.Meta(gt=0.0, le=2.0)] = 0.25
    people_clearance_m: Annotated[float, msgspec.Meta(ge=0.0, le=5.0)] | None = 0.3
    """People give way to the robot: a person's body centre keeps at least radius_m + this
    from the robot's centre, stepping aside as they pass (simulation.py, "Giving way").
    Scripts are written in the world frame, and a following robot can stop in their path;
    real people walk round it. null: they walk through it (as before this setting)."""
    bumper: bool = True
    """The base (a disc of radius_m) stops where it would run into a wall, box or circle of
    the world, and GroundTruth counts the contacts (robot.py, "Bumper"). false: it drives
    through them (as before this setting)."""
    pan_limit_deg: Annotated[float, msgspec.Meta(ge=0.0, le=180.0)] = 100.0
    pan_rate_deg_s: Annotated[float, msgspec.Meta(gt=0.0, le=2000.0)] = 90.0
    cmd_timeout_s: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 0.5
    """Stop when no velocity command arrived for this long (the base's watchdog)."""
    odometry: OdometrySpec = msgspec.field(default_factory=OdometrySpec)


class MeasuredLaserSpec(_Spec):
    """The ``measured`` laser model's parameters; each default was measured on real scans with
    ``followbot realstats`` (docs/realism.md says where and how)."""

    noise_at_zero_m: NonNeg = 0.003
    """Range noise std at 0 m (docs/realism.md, "Range noise")."""
    noise_per_m: NonNeg = 0.0005
    """Added range noise std per metre of range (growing with range)."""
    range_resolution_m: NonNeg = 0.001
    """Ranges are rounded to this (the scanners report millimetres)."""
    duplicate_prob: Prob = 0.33
    """A beam repeats the previous beam's range (docs/realism.md, "Duplicated beams")."""
    mixed_pixel_prob: Prob = 0.22
    """The beam just past a foreground edge reads a range between the edge and the background."""
    edge_invalid_prob: Prob = 0.15
    """The beam just past a foreground edge reads no return."""
    edge_min_jump_m: Pos = 0.3
    """Range step between neighbouring beams that makes a foreground edge."""
    invalid_prob: Prob = 0.01
    """A beam on any surface reads no return (NaN)."""
    leg_dropout_prob: Prob = 0.25
    """Share of scans a leg spends in a dropout (correlated in time per leg)."""
    leg_dropout_scans: Annotated[float, msgspec.Meta(ge=1.0, le=1e4)] = 5.0
    """Mean length of a leg's dropout, in scans."""
    leg_dropout_return_prob: Prob = 0.0
    """During a dropout, each of the leg's beams still returns with this probability (0: the
    leg vanishes)."""
    dark_trousers_prob: Prob = 0.1
    """A person wears dark trousers (drawn once per person): few or no returns from the legs."""
    dark_return_prob: Prob = 0.5
    """Each beam on a dark-trousered leg returns with this probability."""


class LaserSpec(_Spec):
    # thesis 5.1 (SICK LMS200): 100 deg field of view, 0.5 deg resolution, 15 mm noise
    fov_deg: Annotated[float, msgspec.Meta(gt=0.0, le=360.0)] = 100.0
    resolution_deg: Annotated[float, msgspec.Meta(ge=0.01, le=10.0)] = 0.5
    rate_hz: Annotated[float, msgspec.Meta(gt=0.0, le=10_000.0)] = 1.0 / 0.12
    """thesis 3.6: 120 ms between scans on the thesis robot."""
    range_max_m: Pos = 8.0
    range_min_m: NonNeg = 0.01
    range_noise_m: NonNeg = 0.015
    dropout_prob: Prob = 0.0
    """A beam returns NaN (no measurement)."""
    spurious_prob: Prob = 0.0
    """A beam returns a random range short of the true one."""
    height_m: Pos = 0.4
    mount_x_m: Coord = 0.0
    """Laser position ahead of the base origin."""
    min_visible_beams: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 3
    """Beams on a person's legs for truth to call the person visible to the laser."""
    # the laser's mount in the base frame, with mount_x_m (every stage gets it: laser_mount)
    mount_y_m: Coord = 0.0
    """Laser position left of the base origin."""
    mount_yaw_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    """The laser turned counter-clockwise from the base's heading."""

    model: Literal["ideal", "measured"] = "ideal"
    """ideal: Gaussian noise (range_noise_m), iid dropout_prob and spurious_prob. measured:
    the real scanners' faults (``measured``; docs/realism.md); range_noise_m, dropout_prob
    and spurious_prob are then not used."""
    measured: MeasuredLaserSpec = msgspec.field(default_factory=MeasuredLaserSpec)

    def mount(self) -> LaserMount:
        """The laser's pose in the base frame, as the stages' ``laser_mount`` setting."""
        return LaserMount(x_m=self.mount_x_m, y_m=self.mount_y_m, yaw_deg=self.mount_yaw_deg)


class CameraSpec(_Spec):
    width: Annotated[int, msgspec.Meta(ge=16, le=4096)] = 320
    height: Annotated[int, msgspec.Meta(ge=16, le=4096)] = 240
    # DESIGN.md "Verification": 320x240, horizontal FOV 47.5 deg (f ~ 363 px)
    hfov_deg: Annotated[float, msgspec.Meta(gt=1.0, lt=170.0)] = 47.5
    height_m: Pos = 1.0
    mount_x_m: Coord = 0.0
    rate_hz: Annotated[float, msgspec.Meta(gt=0.0, le=1000.0)] = 10.0
    noise_std: Annotated[float, msgspec.Meta(ge=0.0, le=64.0)] = 3.0
    """Sensor noise, standard deviation in grey levels."""
    max_range_m: Pos = 12.0
    mount_y_m: Coord = 0.0
    """Camera (pan axis) position left of the base origin; ``mount_x_m`` ahead of it."""
    mount_yaw_deg: Annotated[float, msgspec.Meta(ge=-360.0, le=360.0)] = 0.0
    """The camera's heading at pan 0, counter-clockwise from the base's heading."""
    exposure_ms: Annotated[float, msgspec.Meta(ge=0.0, le=200.0)] = 0.0
    """Shutter time: each person is smeared along their image motion during it (their own
    and the robot's travel), the whole frame along the camera's turn (robot and pan).
    0: no motion blur (as before this setting). docs/realism.md "Camera"."""
    optics_blur_px: Annotated[float, msgspec.Meta(ge=0.0, le=5.0)] = 0.0
    """Standard deviation of a Gaussian blur (lens and demosaicing softness), px; 0: none."""
    jpeg_quality: Annotated[int, msgspec.Meta(ge=1, le=100)] | None = None
    """Each frame goes through JPEG at this quality after the noise (as a camera streaming
    MJPEG does); null: no compression."""


class LightingKey(_Spec):
    """Image brightness ``gain`` (1 = nominal) from ``t_s`` on, linearly blended between keys."""

    t_s: NonNeg
    gain: Annotated[float, msgspec.Meta(ge=0.0, le=4.0)]


# --------------------------------------------------------------------------- scenario


class Scenario(_Spec):
    name: Annotated[str, msgspec.Meta(min_length=1, max_length=128)]
    description: str = ""
    presets: list[Annotated[str, msgspec.Meta(min_length=1, max_length=64)]] = []
    """The presets the scenario is written for (``followbot eval`` and ``sweep`` run it by
    default only with them: seed 001's colour scenarios need its colour learning); empty:
    every preset."""
    duration_s: Annotated[float, msgspec.Meta(gt=0.0, le=1e6)] = 60.0
    seed: Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)] = 0
    world: WorldSpec = msgspec.field(default_factory=WorldSpec)
    robot: RobotSpec = msgspec.field(default_factory=RobotSpec)
    laser: LaserSpec = msgspec.field(default_factory=LaserSpec)
    camera: CameraSpec = msgspec.field(default_factory=CameraSpec)
    people: Annotated[list[PersonSpec], msgspec.Meta(max_length=256)] = []
    people_spacing_m: Annotated[float, msgspec.Meta(gt=0.0, le=5.0)] | None = 0.45
    """People give way to each other: two body centres stay about this far apart at least
    (a shoulder width: the default figure's 0.44 m), each stepping aside half the way
    (simulation.py, "Giving way"). Scripts crossing or standing in one spot no longer put
    two people in one place. null: they walk through each other (as before this setting)."""
    lighting: list[LightingKey] = []

    def __post_init__(self) -> None:
        ids = [p.id for p in self.people]
        if len(set(ids)) != len(ids):
            raise ValueError(f"person ids must be unique, got {ids}")
        if sum(p.is_target for p in self.people) > 1:
            raise ValueError("at most one person may have is_target: true")
        _check_dress(self.people)
        times = [k.t_s for k in self.lighting]
        if times != sorted(times):
            raise ValueError("lighting keys must be in increasing t_s")

    @property
    def target_id(self) -> int:
        return next((p.id for p in self.people if p.is_target), -1)


def _check_dress(people: list[PersonSpec]) -> None:
    """A lookalike names another person who is not a lookalike; a pedestrian names nobody."""
    dress = {p.id: p.dress for p in people}
    for p in people:
        d = p.dress
        if d is None:
            continue
        if d.style == "pedestrian" and d.of is not None:
            raise ValueError(f"person {p.id}: dress style pedestrian takes no `of`")
        if d.style != "lookalike":
            continue
        if d.of is None:
            raise ValueError(f"person {p.id}: a lookalike needs `of`, the id of the person copied")
        if d.of == p.id:
            raise ValueError(f"person {p.id}: a lookalike cannot copy itself")
        if d.of not in dress:
            raise ValueError(f"person {p.id}: lookalike of {d.of}, but there is no person {d.of}")
        other = dress[d.of]
        if other is not None and other.style == "lookalike":
            raise ValueError(
                f"person {p.id}: lookalike of {d.of}, itself a lookalike (copy the original)"
            )


class ScenarioError(ValueError):
    """A scenario file could not be read; the message names the file, the field and the fault."""


def parse_scenario(data: object, *, source: str = "<scenario>") -> Scenario:
    """Convert already-loaded YAML/JSON data into a :class:`Scenario`."""
    try:
        return msgspec.convert(data, Scenario)
    except msgspec.ValidationError as exc:
        raise ScenarioError(f"{source}: {exc}") from exc


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a YAML scenario file; any fault raises :class:`ScenarioError`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc}") from exc
    return _parse_text(text, source=str(path))


def _parse_text(text: str, *, source: str) -> Scenario:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ScenarioError(f"{source}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ScenarioError(
            f"{source}: expected a mapping at the top level, got {type(data).__name__}"
        )
    return parse_scenario(data, source=source)


def builtin_names() -> list[str]:
    """Names of the scenarios shipped in ``services/sim/scenarios``."""
    folder = resources.files(__package__).joinpath("scenarios")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_builtin(name: str) -> Scenario:
    """Load a shipped scenario by name (file stem); an unknown name lists the valid ones."""
    names = builtin_names()
    if name not in names:
        raise ScenarioError(f"unknown scenario {name!r}; built-in scenarios: {', '.join(names)}")
    res = resources.files(__package__).joinpath("scenarios", f"{name}.yaml")
    return _parse_text(res.read_text(encoding="utf-8"), source=f"{name}.yaml")


def json_schema() -> dict:
    """The JSON Schema of a scenario file (YAML is a superset of the JSON it describes)."""
    return msgspec.json.schema(Scenario)


def deg(value_deg: float) -> float:
    """Degrees (scenario files) to radians (everything else)."""
    return math.radians(value_deg)


if __name__ == "__main__":  # python -m followbot.services.sim.scenario > scenario.schema.json
    sys.stdout.write(json.dumps(json_schema(), indent=2) + "\n")
