"""Two real hosts (network namespaces joined by veth): 'robot' and 'offboard' over Zenoh."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
from netns import two_hosts, unavailable

reason = unavailable()
pytestmark = [
    pytest.mark.multiprocess,
    pytest.mark.skipif(reason is not None, reason=f"two-host tests skipped: {reason}"),
]


def start(host, log, *args):
    env = dict(os.environ, PYTHONUNBUFFERED="1", RUST_LOG="error")
    return subprocess.Popen(
        host.argv(sys.executable, "-m", "followbot", *args), stdout=log, stderr=subprocess.STDOUT,
        env=env,
    )  # fmt: skip


def test_scans_cross_from_robot_to_offboard_and_back_after_an_outage(tmp_path, robot):
    with two_hosts() as (bot, off):
        endpoint = f"tcp/{bot.address}:7447"
        logs = {n: (tmp_path / f"{n}.log").open("w") for n in ("syn", "mon1", "mon2")}
        summary1, summary2 = tmp_path / "m1.json", tmp_path / "m2.json"
        procs = []
        try:
            syn = start(bot, logs["syn"], "run", "synthetic", "--robot", robot,
                        "--listen", endpoint, "--set", "scan_rate_hz=50")  # fmt: skip
            procs.append(syn)
            mon = start(off, logs["mon1"], "run", "monitor", "--robot", robot,
                        "--connect", endpoint, "--set", f"summary={summary1}",
                        "--set", "report_period_s=0.5")  # fmt: skip
            procs.append(mon)
            time.sleep(4)
            # the offboard machine goes away, then comes back
            mon.send_signal(signal.SIGKILL)
            mon.wait(5)
            time.sleep(1)
            mon2 = start(off, logs["mon2"], "run", "monitor", "--robot", robot,
                         "--connect", endpoint, "--set", f"summary={summary2}",
                         "--set", "report_period_s=0.5")  # fmt: skip
            procs.append(mon2)
            time.sleep(4)
            mon2.send_signal(signal.SIGTERM)
            assert mon2.wait(5) == 0
            assert syn.poll() is None, "the robot side died when offboard went away"
            syn.send_signal(signal.SIGTERM)
            assert syn.wait(5) == 0
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.wait()
            for fh in logs.values():
                fh.close()
        before = json.loads(summary1.read_text())["sensors/scan"]
        after = json.loads(summary2.read_text())["sensors/scan"]
        assert before["received"] > 50, (tmp_path / "mon1.log").read_text()
        assert after["received"] > 50, (tmp_path / "mon2.log").read_text()
        # Scans are best effort: while the returning machine's routes are being declared, the
        # robot's publisher may drop a sample (one in about 200 was seen once in six CI runs
        # on 2 loaded cores). A stream that stutters after the outage loses far more.
        assert after["lost"] <= max(1, after["received"] // 100), after
        assert after["rejected"] == 0


def test_split_deployment_keeps_tracking_without_vision_and_recovers_the_model(tmp_path, robot):
    """compose/split.yaml on two hosts: the robot follows; the offboard vision machine dies
    (the robot keeps tracking on the laser and says no_vision); it comes back, with
    acquire.auto as before, and verifies again with the target model recovered from the
    robot, not rebuilt."""
    import yaml
    from conftest import REPO

    from followbot.bags import open_recording

    with two_hosts() as (bot, off):
        env = dict(os.environ, PYTHONUNBUFFERED="1", RUST_LOG="error", ROBOT_HOST=bot.address,
                   FOLLOWBOT_ROBOT=robot, FOLLOWBOT_SCENARIO="thesis_5_2_1_arc")  # fmt: skip
        vision_cfg = tmp_path / "vision.yaml"
        vision = {"robot": robot, "verifier": "histogram", "acquire": {"auto": True},
                  "zenoh": {"mode": "client", "connect": [f"tcp/{bot.address}:7447"]}}  # fmt: skip
        vision_cfg.write_text(yaml.safe_dump(vision))
        logs = {n: (tmp_path / f"{n}.log").open("w") for n in ("up", "rec", "v1", "v2")}

        def start(host, log, *args):
            return subprocess.Popen(
                host.argv(sys.executable, "-m", "followbot", *args), stdout=logs[log],
                stderr=subprocess.STDOUT, env=env,
            )  # fmt: skip

        procs = []
        try:
            split = str(REPO / "compose" / "split.yaml")
            procs.append(start(bot, "up", "up", split, "--host", "robot",
                               "--log-dir", str(tmp_path / "robot")))  # fmt: skip
            time.sleep(2.0)
            procs.append(start(bot, "rec", "record", "tracking/target", "perception/verification",
                               "-o", str(tmp_path / "run.mcap"), "--robot", robot, "--mode",
                               "client", "--connect", f"tcp/{bot.address}:7447"))  # fmt: skip
            v1 = start(off, "v1", "run", "vision_verify", "--config", str(vision_cfg))
            procs.append(v1)
            # model built (processes on two cores can take several seconds to start), then
            # the robot following for a while
            deadline = time.monotonic() + 40
            while "target model 1 built" not in (tmp_path / "v1.log").read_text():
                assert time.monotonic() < deadline, (tmp_path / "v1.log").read_text()
                time.sleep(0.5)
            time.sleep(6)
            t_kill = time.time_ns()
            v1.send_signal(signal.SIGKILL)
            v1.wait(5)
            time.sleep(9)
            t_back = time.time_ns()
            # the same settings, acquire.auto too: it must take the robot's model back
            procs.append(start(off, "v2", "run", "vision_verify", "--config", str(vision_cfg)))
            time.sleep(9)
            t_end = time.time_ns()
        finally:
            for p in reversed(procs):
                if p.poll() is None:
                    p.send_signal(signal.SIGINT)
            for p in procs:
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
            for fh in logs.values():
                fh.close()
        targets, verifications = [], []
        for log_ns, topic, m in open_recording(tmp_path / "run.mcap").messages():
            (targets if topic == "tracking/target" else verifications).append((log_ns, m))

        def phase(items, t0, t1):
            return [m for t, m in items if t0 <= t < t1]

        before = phase(targets, t_kill - 4_000_000_000, t_kill)
        outage = phase(targets, t_kill + 3_000_000_000, t_back)
        after = phase(verifications, t_back + 3_000_000_000, t_end)
        diag = (tmp_path / "v2.log").read_text()
        assert before and sum(m.status == "tracking" for m in before) > 0.8 * len(before), diag
        assert sum("vision" in m.sources for m in before) > 0.5 * len(before)
        # offboard gone: still tracking on the laser, and saying so
        assert outage, "no tracker output while vision was down"
        assert sum(m.status in ("tracking", "coasting") for m in outage) > 0.8 * len(outage)
        assert all("no_vision" in m.flags or "vision_stale" in m.flags for m in outage)
        assert not phase(verifications, t_kill + 1_000_000_000, t_back)
        # back: verifying again with the recovered model (same id, no rebuild)
        assert "target model 1 from query" in diag, diag
        assert "built" not in diag and "auto-acquisition stopped: model 1 is in use" in diag
        assert after and any(v.chosen >= 0 and v.model_id == 1 for v in after), diag
