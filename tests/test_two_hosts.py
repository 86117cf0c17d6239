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
        assert after["lost"] == 0 and after["rejected"] == 0
