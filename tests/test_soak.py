"""Soak: the synthetic publisher drives a monitor at a high rate for a long time.

Opt-in (`make soak`). Duration and rate from FOLLOWBOT_SOAK_S (default 60) and
FOLLOWBOT_SOAK_RATE (scans/s, default 200). Reports message loss, latency p99 over time and
resident memory growth of both processes, and writes them to out/soak/report.json.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import time

import pytest
from conftest import REPO

from followbot.schemas import Health, Keys, decode

pytestmark = [pytest.mark.soak, pytest.mark.multiprocess]


def test_soak_no_loss_flat_latency_bounded_memory(spawn, endpoint, robot, tmp_path, zenoh_session):
    duration = float(os.environ.get("FOLLOWBOT_SOAK_S", "60"))
    rate = float(os.environ.get("FOLLOWBOT_SOAK_RATE", "200"))
    keys = Keys(robot)
    healths: queue.SimpleQueue = queue.SimpleQueue()
    hsub = zenoh_session.declare_subscriber(
        keys.all_health,
        lambda s: healths.put((time.monotonic(), decode(Health, s.payload.to_bytes()))),
    )
    summary = tmp_path / "monitor.json"
    monitor = spawn(
        "run", "monitor", "--robot", robot, "--connect", endpoint,
        "--set", f"summary={summary}", "--set", "report_period_s=5", "--set", "health_period_s=5",
    )  # fmt: skip
    monitor.wait_for_output("monitor up")
    synthetic = spawn(
        "run", "synthetic", "--robot", robot, "--connect", endpoint,
        "--set", f"scan_rate_hz={rate}", "--set", f"count={int(rate * duration)}",
        "--set", "odom_rate_hz=0", "--set", "wait_for_subscribers_s=10",
        "--set", "reliable=true",  # the soak measures the pipeline's losses, not the sender's
        "--set", "health_period_s=5",
    )  # fmt: skip
    t0 = time.monotonic()
    while synthetic.p.poll() is None and time.monotonic() - t0 < duration + 60:
        time.sleep(5)
        print(f"  soak {time.monotonic() - t0:6.0f}/{duration:.0f} s", flush=True)
    assert synthetic.wait(30) == 0, synthetic.output
    time.sleep(1.0)
    monitor.signal(signal.SIGTERM)
    assert monitor.wait(10) == 0, monitor.output
    hsub.undeclare()

    stats = json.loads(summary.read_text())["sensors/scan"]
    rss: dict[str, list[tuple[float, float]]] = {}
    while not healths.empty():
        t, h = healths.get()
        rss.setdefault(h.service, []).append((t - t0, h.rss_mb))
    # memory growth after a warm-up of 20 % of the run
    growth = {}
    for service, samples in rss.items():
        settled = [m for t, m in samples if t > 0.2 * duration]
        growth[service] = (settled[-1] - settled[0]) if len(settled) >= 2 else None
    # windows that saw a full period of traffic (not the start-up or shutdown fringes)
    full = 0.8 * rate * 5
    p99s = [w["age_p99_ms"] for w in stats["series"] if w["received"] >= full]
    report = {
        "duration_s": duration,
        "rate_hz": rate,
        "received": stats["received"],
        "lost": stats["lost"],
        "rejected": stats["rejected"],
        "age_p50_ms": stats["age_p50_ms"],
        "age_p99_ms": stats["age_p99_ms"],
        "age_p99_ms_per_window": p99s,
        "rss_growth_mb": growth,
        "rss_mb": {s: [round(m, 1) for _, m in v] for s, v in rss.items()},
    }
    out = REPO / "out" / "soak"
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps({k: v for k, v in report.items() if k != "rss_mb"}, indent=2))

    assert stats["received"] == int(rate * duration) and stats["lost"] == 0
    assert stats["rejected"] == 0
    # flat p99: the last windows are no worse than 3x the median window
    if len(p99s) >= 4:
        median = sorted(p99s)[len(p99s) // 2]
        assert max(p99s[-2:]) <= 3 * median + 1.0, p99s
    for service, g in growth.items():
        assert g is None or g < 20.0, f"{service} grew {g:.1f} MB"
