"""``followbot smoke``: a live transport smoke with real processes over Zenoh.

Starts the synthetic sensor publisher and the monitor as two separate processes joined by a
Zenoh link on a free loopback port, lets them run, and reports what the monitor measured
(rates, losses, rejects, message age) and what each service's Health said. Every figure
printed comes from the running processes; nothing is assumed.

It needs no perception stage: it checks the wire format, the node runtime and the transport
on this machine (``followbot demo`` runs the whole system).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from followbot import progress
from followbot.schemas import Health, decode
from followbot.services.runtime.argtypes import non_negative_float, positive_float

SERVICES = ("synthetic", "monitor")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="followbot smoke",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--duration", type=positive_float, default=5.0, help="seconds of streaming (5)")
    p.add_argument("--scan-rate", type=positive_float, default=40.0, help="scans per second (40)")
    p.add_argument(
        "--image-rate", type=non_negative_float, default=10.0,
        help="images per second, 0 for none (10)",
    )  # fmt: skip
    p.add_argument("--output", default="out/smoke", help="folder for logs and summary (out/smoke)")
    args = p.parse_args(argv)

    from followbot.services.runtime.session import free_loopback_endpoint, open_session
    from followbot.services.runtime.settings import ZenohSettings

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    endpoint = free_loopback_endpoint()
    robot = f"smoke{os.getpid()}"
    summary_file = out / "monitor.json"
    summary_file.unlink(missing_ok=True)
    common = ["--robot", robot, "--set", "health_period_s=0.5"]
    cmds = {
        "monitor": [
            "run", "monitor", "--listen", endpoint, *common,
            "--set", "topics=[sensors/scan, sensors/odom, sensors/image]",
            "--set", f"summary={summary_file}", "--set", "report_period_s=1.0",
        ],
        "synthetic": [
            "run", "synthetic", "--connect", endpoint, *common,
            "--set", f"scan_rate_hz={args.scan_rate}",
            "--set", f"image_rate_hz={args.image_rate}",
            "--set", "wait_for_subscribers_s=10",
        ],
    }  # fmt: skip
    print(f"followbot smoke: 2 processes over Zenoh on {endpoint}, robot '{robot}'")
    print(f"  logs and summary in {out}/")
    healths: dict[str, Health] = {}
    procs: dict[str, subprocess.Popen] = {}
    logs = {name: (out / f"{name}.log").open("w") for name in SERVICES}
    env = dict(os.environ, RUST_LOG="error")
    with open_session(ZenohSettings(connect=[endpoint])) as session:
        sub = session.declare_subscriber(
            f"followbot/{robot}/health/*",
            lambda s: healths.__setitem__((h := decode(Health, s.payload.to_bytes())).service, h),
        )
        try:
            for name in ("monitor", "synthetic"):
                procs[name] = subprocess.Popen(
                    [sys.executable, "-m", "followbot", *cmds[name]],
                    stdout=logs[name], stderr=subprocess.STDOUT, env=env,
                )  # fmt: skip
            # The clock starts once scans reach the monitor, so start-up is not counted.
            deadline = time.monotonic() + 30
            while not (h := healths.get("monitor")) or not h.received.get("sensors/scan"):
                dead = [n for n, pr in procs.items() if pr.poll() is not None]
                if dead or time.monotonic() > deadline:
                    why = f"{dead[0]} exited" if dead else "no scans reached the monitor in 30 s"
                    print(f"{why}; see the logs in {out}/")
                    return 1
                time.sleep(0.05)
            t0 = time.monotonic()
            shown = -1
            while (elapsed := time.monotonic() - t0) < args.duration:
                dead = [n for n, pr in procs.items() if pr.poll() is not None]
                if dead:
                    print(f"\n{dead[0]} exited early; see {out / (dead[0] + '.log')}")
                    return 1
                # every 0.1 s on a terminal; in logs a line a second, not a line storm
                if progress.on_terminal() or int(elapsed) != shown:
                    shown = int(elapsed)
                    progress.show("  streaming " + progress.bar(elapsed, args.duration))
                time.sleep(0.1)
            progress.show("  streaming " + progress.bar(args.duration, args.duration))
            progress.finish()
            for name in ("synthetic", "monitor"):  # stop the source first, then the sink
                procs[name].terminate()
                procs[name].wait(10)
        finally:
            for pr in procs.values():
                if pr.poll() is None:
                    pr.kill()
            for fh in logs.values():
                fh.close()
            sub.undeclare()

    codes = {n: pr.returncode for n, pr in procs.items()}
    if not summary_file.exists():
        print(f"the monitor wrote no summary; see {out / 'monitor.log'}")
        return 1
    stats = json.loads(summary_file.read_text())
    print()
    print(f"{'topic':<16}{'received':>9}{'rate Hz':>9}{'lost':>6}{'rejected':>9}"
          f"{'age p50 ms':>12}{'age p99 ms':>12}")  # fmt: skip
    for topic, s in stats.items():
        p50 = "-" if s["age_p50_ms"] is None else f"{s['age_p50_ms']:.2f}"
        p99 = "-" if s["age_p99_ms"] is None else f"{s['age_p99_ms']:.2f}"
        print(f"{topic:<16}{s['received']:>9}{s['rate_hz']:>9.1f}{s['lost']:>6}"
              f"{s['rejected']:>9}{p50:>12}{p99:>12}")  # fmt: skip
    print()
    for name in SERVICES:
        h = healths.get(name)
        if h is None:
            print(f"{name:<10} no health message seen")
            continue
        work = (
            f"handler p50 {h.proc_p50_ms:.3f} ms p99 {h.proc_p99_ms:.3f} ms"
            if h.received
            else "publisher only"
        )
        print(f"{name:<10} status {h.status}, {work}, errors {h.errors}, exit {codes[name]}")
    result = {"endpoint": endpoint, "topics": stats, "exit_codes": codes}
    (out / "summary.json").write_text(json.dumps(result, indent=2) + "\n")
    ok = all(c == 0 for c in codes.values()) and stats["sensors/scan"]["received"] > 0
    print(f"\n{'OK' if ok else 'PROBLEM'}: summary in {out / 'summary.json'}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
