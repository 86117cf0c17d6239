"""Run one scenario through the real pipeline: every service its own process, over Zenoh.

The simulator (lock-step by default, so results do not depend on the machine's speed) and the
four stages (laser_legs, vision_verify, tracker, controller, configured by a preset) run as
processes connected to this one; this process watches every topic, joins what each stage
said about each scan stamp with the truth of that stamp (:class:`ScanRecord`), measures the
stages' latency as it sees their answers arrive, and can record everything to MCAP.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import yaml

from followbot import progress as progress_line
from followbot.schemas import (
    GroundTruth,
    People,
    PersonCandidates,
    TrackState,
    VelocityCommand,
    Verification,
)

__all__ = ["RunError", "invalid_stage_settings", "run_scenario"]

STAGES = ("laser_legs", "vision_verify", "tracker", "controller")
#: Seed 001 (``--preset zhuang``): candidates from the camera alone.
CAMERA_STAGES = ("camera_blobs", "tracker", "controller")
#: topic -> (stage whose answer it is, ScanRecord field)
ANSWERS = {
    "perception/candidates": ("laser_legs", "candidates"),
    "perception/verification": ("vision_verify", "verification"),
    "tracking/target": ("tracker", "target"),
    "tracking/people": (None, "people"),
    "control/cmd_vel": ("controller", "cmd"),
}
RECORDED = ("sensors/scan", "sensors/odom", "sim/truth", "control/pan", *ANSWERS)


class RunError(RuntimeError):
    """A run that could not be done (a stage failed to start, the sim failed); says why."""


@dataclass
class _Stamp:
    truth: GroundTruth | None = None
    scan_at: int | None = None
    msgs: dict[str, Any] = field(default_factory=dict)
    arrived: dict[str, int] = field(default_factory=dict)


class StageProcesses:
    """Services started as ``followbot run NAME --config FILE`` with their settings and logs
    in one folder; :meth:`stop` ends them (SIGTERM, then SIGKILL after 10 s)."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir
        self.procs: dict[str, subprocess.Popen] = {}
        self._logs: dict[str, Any] = {}
        self._env = dict(os.environ, RUST_LOG="error", PYTHONUNBUFFERED="1")

    def start(self, service: str, settings: dict[str, Any]) -> subprocess.Popen:
        cfg = self.out_dir / f"{service}.settings.yaml"
        cfg.write_text(yaml.safe_dump(settings, sort_keys=False))
        self._logs[service] = (self.out_dir / f"{service}.log").open("w")
        self.procs[service] = subprocess.Popen(
            [sys.executable, "-m", "followbot", "run", service, "--config", str(cfg)],
            stdout=self._logs[service], stderr=subprocess.STDOUT, env=self._env,
        )  # fmt: skip
        return self.procs[service]

    def exited(self, services) -> str | None:
        """The first of ``services`` that has exited, or None."""
        return next((s for s in services if self.procs[s].poll() is not None), None)

    def tail(self, service: str, n: int = 6) -> str:
        return _tail(self.out_dir / f"{service}.log", n)

    def stop(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.terminate()
        for p in self.procs.values():
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for fh in self._logs.values():
            fh.close()


def invalid_stage_settings(settings: dict[str, dict[str, Any]]) -> dict[str, str]:
    """Check each service's settings the way the service will when started (``followbot run
    NAME --config FILE --print-settings``, all at once, in about a second); returns {service:
    its error} for the ones refused: an unknown key, a bad value, an unknown plugin name."""
    with tempfile.TemporaryDirectory(prefix="followbot-check-") as tmp:
        checks, files = {}, {}
        for service, values in settings.items():
            cfg = files[service] = Path(tmp) / f"{service}.yaml"
            cfg.write_text(yaml.safe_dump(values, sort_keys=False))
            checks[service] = subprocess.Popen(
                [sys.executable, "-m", "followbot", "run", service, "--config", str(cfg),
                 "--print-settings"],
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            )  # fmt: skip
        errors = {s: p.communicate(timeout=120)[1] for s, p in checks.items()}
    # "followbot run tracker: /tmp/.../tracker.yaml: Object contains unknown field `bogus`"
    # -> "settings: Object contains unknown field `bogus`" (the file was ours, not the user's)
    return {
        s: errors[s].strip().removeprefix(f"followbot run {s}: ").replace(str(files[s]), "settings")
        for s, p in checks.items()
        if p.returncode != 0
    }


def preset_stages(preset: str) -> tuple[str, ...]:
    """The stages ``preset`` runs: the laser's four, or seed 001's camera-only three."""
    from followbot.services.runtime.compose import PRESETS

    if preset not in PRESETS:
        raise RunError(f"unknown preset {preset!r}; presets: {', '.join(PRESETS)}")
    return CAMERA_STAGES if "camera_blobs" in PRESETS[preset] else STAGES


def stage_settings(
    preset: str, lockstep: bool, *, odometry: bool = True, vision: bool = True
) -> dict[str, dict[str, Any]]:
    """Each stage's settings for ``preset``; ``lockstep``: as docs/runtime.md "Lock-step runs"
    needs them, for a source that sends odometry (``odometry``) and with vision_verify
    running (``vision``)."""
    from followbot.services.runtime.compose import PRESETS

    if preset not in PRESETS:
        raise RunError(f"unknown preset {preset!r}; presets: {', '.join(PRESETS)}")
    stages = preset_stages(preset)
    out = {s: dict(PRESETS[preset].get(s, {})) for s in stages}
    if "vision_verify" in out:
        # thesis 3.3: the model is built at the start, the robot still, the target moving alone
        vv = out["vision_verify"]
        vv["acquire"] = {**vv.get("acquire", {}), "auto": True}
    if lockstep:
        if "vision_verify" in out:
            out["vision_verify"]["answer_every_scan"] = True  # rule 2 of the lock-step protocol
        if "camera_blobs" in out:  # rule 2: one answer per scan, from the frame of its instant
            out["camera_blobs"].update(answer_on="scan", lockstep_image_wait_s=0.5)
        # rule 5: what a step combines reaches the stage over other links; wait for it
        # criterion 3 gates scan k+1 on the target of scan k
        if "laser_legs" in out:
            out["laser_legs"]["lockstep_target_wait_s"] = 0.5
        if odometry:
            if "laser_legs" in out:
                out["laser_legs"]["lockstep_odometry_wait_s"] = 0.5
            out["tracker"]["lockstep_odometry_wait_s"] = 0.5
        if vision and "vision_verify" in out:
            out["tracker"]["lockstep_vision_wait_s"] = 1.0
        # the wall-clock watchdog would brake the controller's own state between scans on a
        # slow machine (the sim ignores its commands, but the next command starts from them)
        out["controller"]["stale_after_s"] = 0.0
        out["tracker"]["stale_after_s"] = 0.0
        # the source sets the pace: a recording's gap is no stamp from the future
        for stage in stages:
            out[stage]["clock"] = {"max_ahead_s": None}
    return out


def sensor_mounts(spec) -> dict[str, Any]:
    """The settings every service of a run of scenario ``spec`` shares about where its sensors
    sit: ``laser_mount``, the scenario's laser (the sim checks it against its own). Empty for a
    laser at the base's origin, the default."""
    mount = spec.laser.mount()
    if mount.is_identity:
        return {}
    return {"laser_mount": msgspec.to_builtins(mount)}


def camera_only_settings(spec, settings: dict[str, dict[str, Any]]) -> None:
    """Seed 001's stages on scenario ``spec``: its camera (height, field of view, size, rate)
    for camera_blobs, the hybrid filter and the rule; the colour learnt from a rectangle on the
    target's trousers in the first frame (``learn_rect: trousers``, placed by
    :func:`place_learn_rect` once the overrides are in); the sim's lock-step awaits
    camera_blobs' candidates instead of laser_legs'."""
    c = spec.camera
    if (c.mount_y_m, c.mount_yaw_deg) != (0.0, 0.0):
        raise RunError(f"{spec.name}: seed 001's camera looks straight ahead from the centre line")
    cam = {
        "width": c.width, "height": c.height, "hfov_deg": c.hfov_deg, "height_m": c.height_m,
        "mount_x_m": c.mount_x_m,
    }  # fmt: skip
    blobs = settings["camera_blobs"]
    blobs.setdefault("camera", cam)
    blobs.setdefault("image_period_s", 1.0 / c.rate_hz)
    if "colour" not in blobs:
        blobs.setdefault("learn_rect", "trousers")
    settings["tracker"].setdefault("estimator_settings", {}).setdefault("camera", cam)
    zh = settings["controller"].setdefault("zhuang", {})
    zh.setdefault("hfov_deg", c.hfov_deg)
    zh.setdefault("camera_x_m", c.mount_x_m)
    if settings.get("sim", {}).get("mode") == "lockstep":
        settings["sim"]["stages"] = {  # laser_legs publishes the same topic: not awaited
            "laser_legs": [],
            "vision_verify": [],
            "camera_blobs": ["perception/candidates"],
            "tracker": ["tracking/target"],
            "controller": ["control/cmd_vel", "control/pan"],
        }


LEARN_PARTS = ("trousers", "shirt")


def place_learn_rect(spec, settings: dict[str, dict[str, Any]]) -> None:
    """camera_blobs' ``learn_rect`` given as a part of the target's clothing (``trousers``,
    the default, or ``shirt``: ``followbot eval --set camera_blobs.learn_rect=shirt``) into
    pixels of the first frame (:func:`learn_rect`). On the shirt the regions are the shirt's,
    whose bottom edge is its hem: their floor points are read on the hem's plane (camera_blobs'
    and the hybrid estimator's ``region_bottom_m``, unless set)."""
    blobs = settings.get("camera_blobs", {})
    part = blobs.get("learn_rect")
    if not isinstance(part, str):
        return
    if part not in LEARN_PARTS:
        raise RunError(f"camera_blobs.learn_rect: {part!r} is not a rectangle nor one of "
                       f"{', '.join(LEARN_PARTS)}")  # fmt: skip
    blobs["learn_rect"] = learn_rect(spec, part)
    if part == "shirt":
        hem = round(shirt_hem_m(spec), 3)
        blobs.setdefault("region_bottom_m", hem)
        hybrid = settings["tracker"].setdefault("estimator_settings", {})
        hybrid.setdefault("region_bottom_m", blobs["region_bottom_m"])


def _target(spec):
    target = next((p for p in spec.people if p.is_target), None)
    if target is None:
        raise RunError(f"{spec.name}: no target to learn a colour from (seed 001)")
    return target


def shirt_hem_m(spec) -> float:
    """Height of the target's shirt hem: the simulator draws the shirt down to 5 cm below the
    hips, at 0.52 of the person's height (services/sim/camera.py)."""
    return 0.52 * _target(spec).appearance.height_m - 0.05


def learn_rect(spec, part: str = "trousers") -> list[float]:
    """[x0, y0, w, h]: a rectangle on the scenario's target as the camera sees it at the
    start, 0.12 m wide: on the trousers 0.3-0.5 m above the floor (where the two legs meet, so
    no background between them), or on the shirt from 0.1 m above its hem to 0.2 m higher."""
    from followbot.services.runtime.ground_plane import GroundCamera

    c = spec.camera
    cam = GroundCamera(
        width=c.width, height=c.height, hfov_deg=c.hfov_deg, height_m=c.height_m,
        mount_x_m=c.mount_x_m,
    )  # fmt: skip
    target = _target(spec)
    yaw = math.radians(spec.robot.yaw_deg)
    dx, dy = target.start[0] - spec.robot.start[0], target.start[1] - spec.robot.start[1]
    x, y = math.cos(yaw) * dx + math.sin(yaw) * dy, -math.sin(yaw) * dx + math.cos(yaw) * dy
    u, v = cam.floor_to_pixel(x, y)
    d = math.hypot(x - c.mount_x_m, y)
    f = cam.focal_px
    bottom = 0.3 if part == "trousers" else shirt_hem_m(spec) + 0.1
    rect = [float(u) - f * 0.06 / d, float(v) - f * (bottom + 0.2) / d, f * 0.12 / d, f * 0.2 / d]
    if not (math.isfinite(rect[0]) and rect[0] >= 0 and rect[0] + rect[2] <= c.width):
        raise RunError(f"{spec.name}: the target does not start in the camera's view (seed 001)")
    return [round(v_, 1) for v_ in rect]


def apply_stage_overrides(settings: dict[str, dict[str, Any]], overrides: list[str]) -> None:
    """``STAGE.key=value`` items (value in YAML) into each stage's settings; a bad item raises
    :class:`RunError` naming it. Each stage validates its keys when it starts."""
    from followbot.services.runtime.settings import SettingsError, apply_overrides

    for item in overrides:
        stage, dot, _ = item.partition("=")[0].strip().partition(".")
        if not dot or stage not in settings or "=" not in item:
            raise RunError(
                f"--set {item!r}: expected STAGE.key=value with STAGE one of {', '.join(settings)}"
            )
        try:
            apply_overrides(settings[stage], [item.split(".", 1)[1]])
        except SettingsError as exc:
            raise RunError(f"--set {item!r}: {exc}") from exc


def check_stage_overrides(preset: str, overrides: list[str]) -> None:
    """Apply ``overrides`` to a throw-away copy of ``preset``'s settings (and the sim's), so a
    malformed ``--set`` raises :class:`RunError` before any run starts."""
    apply_stage_overrides({**stage_settings(preset, True), "sim": {}}, overrides)


def _at_laser_rate(spec, name: str, rate_hz: float, out_dir: Path):
    """``spec`` with its laser at ``rate_hz``, written to ``out_dir``: (its path, the spec)."""
    import msgspec
    import yaml

    from followbot.services.sim.scenario import parse_scenario

    data = msgspec.to_builtins(spec)
    data["laser"]["rate_hz"] = float(rate_hz)
    path = out_dir / f"{name}_{rate_hz:g}hz.yaml"
    spec = parse_scenario(data, source=str(path))  # a rate out of bounds fails here, named
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path), spec


def run_scenario(
    scenario: str,
    preset: str,
    out_dir: Path,
    *,
    seed: int | None = None,
    realtime: bool = False,
    record: bool = True,
    progress: bool = True,
    timeout_s: float = 600.0,
    vision: bool = True,
    overrides: list[str] | None = None,
    laser_rate_hz: float | None = None,
    record_images: bool = False,
):
    """Run ``scenario`` with ``preset``; returns a :class:`followbot.evaluation.ScenarioRun`.
    ``overrides``: ``STAGE.key=value`` settings on top of the preset (``followbot eval --set``);
    ``laser_rate_hz``: the scenario's laser at this rate instead of its own (the scenario
    written into ``out_dir`` with that one change, named ``NAME_RATEhz``); ``record_images``:
    the recording holds the camera's images too (to see what vision judged)."""
    from followbot.evaluation import ScanRecord, ScenarioRun
    from followbot.mcapio import McapTopicWriter
    from followbot.services.runtime.bus import ZenohBus
    from followbot.services.runtime.node import Node
    from followbot.services.runtime.session import free_loopback_endpoint, open_session
    from followbot.services.runtime.settings import NodeSettings, ZenohSettings
    from followbot.services.sim.node import load_scenario_setting

    spec = load_scenario_setting(scenario)  # a broken file fails here, naming the field
    name = Path(scenario).stem if scenario.endswith((".yaml", ".yml")) else scenario
    duration_s = spec.duration_s
    out_dir.mkdir(parents=True, exist_ok=True)
    if laser_rate_hz is not None:
        scenario, spec = _at_laser_rate(spec, name, laser_rate_hz, out_dir)
        name = Path(scenario).stem
    endpoint = free_loopback_endpoint()
    robot = f"eval{os.getpid()}x{int(time.monotonic() * 1000) % 100000}"
    lockstep = not realtime
    stages = [s for s in preset_stages(preset) if vision or s != "vision_verify"]
    settings = stage_settings(preset, lockstep, vision=vision)
    if not vision:  # laser only: the target is the nearest person ahead (as followbot track)
        settings["tracker"]["acquire"] = "nearest"
    settings["sim"] = {
        "scenario": scenario,
        "mode": "lockstep" if lockstep else "realtime",
        "wait_for_stages": stages,
        "start_timeout_s": 60.0,
        **({"seed": seed} if seed is not None else {}),
    }
    cam = spec.camera
    if "camera_blobs" in stages:
        camera_only_settings(spec, settings)
    elif vision and (cam.mount_x_m, cam.mount_y_m, cam.mount_yaw_deg) != (0.0, 0.0, 0.0):
        # the camera's own mount, in the base frame as vision_verify's cameras take it
        mount = {"offset_x_m": cam.mount_x_m, "offset_y_m": cam.mount_y_m}
        settings["vision_verify"]["cameras"] = {"default": {**mount, "yaw_deg": cam.mount_yaw_deg}}
    apply_stage_overrides(settings, overrides or [])
    place_learn_rect(spec, settings)
    common = {
        "robot": robot,
        "zenoh": {"connect": [endpoint]},
        "log_level": "warning",
        **sensor_mounts(spec),
    }
    stamps: dict[int, _Stamp] = {}
    truth_ns = [0]  # newest truth stamp; the handlers (Zenoh threads) write, the loop reads
    writer = McapTopicWriter(out_dir / "run.mcap", robot) if record else None
    session = open_session(ZenohSettings(listen=[endpoint]))
    node = Node("eval", NodeSettings(robot=robot, health_period_s=3600), ZenohBus(session))

    def on(topic: str):
        def handle(msg, payload: bytes) -> None:
            now = time.monotonic_ns()
            if writer is not None:
                writer.write(topic, payload, msg.stamp_ns, time.time_ns())
            if topic in ("sensors/odom", "control/pan", "sensors/image"):
                return
            st = stamps.setdefault(msg.stamp_ns, _Stamp())
            if topic == "sim/truth":
                st.truth = msg
                truth_ns[0] = max(truth_ns[0], msg.stamp_ns)
            elif topic == "sensors/scan":
                st.scan_at = now
            else:
                st.msgs.setdefault(topic, msg)  # the first answer counts (lock-step: the only)
                st.arrived.setdefault(topic, now)

        return handle

    for topic in (*RECORDED, "sensors/image") if record_images and record else RECORDED:
        node.subscribe(topic, on(topic), with_payload=True)
    procs = StageProcesses(out_dir)
    t_wall0 = time.monotonic()
    try:
        for service in (*stages, "sim"):
            procs.start(service, {**common, **settings[service]})
        sim = procs.procs["sim"]
        last_shown = -1.0
        deadline = time.monotonic() + timeout_s
        while sim.poll() is None:
            if (s := procs.exited(stages)) is not None:
                raise RunError(
                    f"{name} / {preset}: {s} exited {procs.procs[s].returncode}: " + procs.tail(s)
                )
            if time.monotonic() > deadline:
                raise RunError(f"{name} / {preset}: no end after {timeout_s:.0f} s")
            node.spin_once()
            if progress:
                # not a scan of `stamps`: a handler may add to it meanwhile (this crashed)
                sim_s = truth_ns[0] / 1e9
                if sim_s - last_shown >= 1.0:
                    last_shown = sim_s
                    progress_line.show(
                        f"  {name + ' / ' + preset:<40} {progress_line.bar(sim_s, duration_s)}"
                    )
            time.sleep(0.05)
        if sim.returncode != 0:
            raise RunError(f"{name} / {preset}: sim exited {sim.returncode}: " + procs.tail("sim"))
        time.sleep(0.3)  # the last answers
        node.spin_once()  # and those that came while a handler ran (queued for the loop)
    finally:
        wall_s = time.monotonic() - t_wall0
        # stop listening first: stopping the stages makes the controller brake (tracker gone),
        # a command after the run that a recording would catch or not depending on timing
        node.close()
        procs.stop()
        session.close()
        if writer is not None:
            writer.close()
    if progress:
        progress_line.show(
            f"  {name + ' / ' + preset:<40} {progress_line.bar(duration_s, duration_s)}"
        )
        progress_line.finish()

    records, timeouts = [], dict.fromkeys(stages, 0)
    for stamp in sorted(stamps):
        st = stamps[stamp]
        if st.truth is None or st.scan_at is None:
            continue
        latency = {}
        for topic, (stage, _) in ANSWERS.items():
            if stage == "laser_legs" and "camera_blobs" in stages:
                stage = "camera_blobs"  # the candidates' stage of seed 001
            if stage is None or stage not in stages:
                continue
            if topic in st.arrived:
                latency[stage] = (st.arrived[topic] - st.scan_at) / 1e6
            else:
                timeouts[stage] += 1
        m = st.msgs
        records.append(
            ScanRecord(
                stamp_ns=stamp,
                truth=st.truth,
                candidates=_typed(m.get("perception/candidates"), PersonCandidates),
                verification=_typed(m.get("perception/verification"), Verification),
                target=_typed(m.get("tracking/target"), TrackState),
                people=_typed(m.get("tracking/people"), People),
                cmd=_typed(m.get("control/cmd_vel"), VelocityCommand),
                latency_ms=latency,
            )
        )
    sim_s = (records[-1].stamp_ns - records[0].stamp_ns) / 1e9 if len(records) > 1 else 0.0
    return ScenarioRun(
        scenario=name, preset=preset, records=records, timeouts=timeouts, wall_s=wall_s,
        sim_s=sim_s,
    )  # fmt: skip


def _typed(msg, t):
    return msg if isinstance(msg, t) else None


def _tail(path: Path, n: int = 6) -> str:
    try:
        lines = path.read_text().strip().splitlines()
    except OSError:
        return "(no log)"
    return " | ".join(lines[-n:]) or "(empty log)"
