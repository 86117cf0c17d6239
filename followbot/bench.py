"""``followbot bench``: what the wire and the runtime cost, measured in one run.

1. Codec: encode and decode+validate of a 720-beam scan and a 640x480 BGR image (median of
   batches), and whether the decoded pixels are a view of the payload (no copy).
2. One hop between two processes on loopback, publish to receive, p50/p99, for the scan and
   the image: (a) a bare zenoh-python publisher/subscriber pair moving payloads of the same
   size (the floor), (b) followbot's node runtime: encode, publish, receive, hand to the node
   loop, decode and validate, call the handler. Also the bare round trip (ping-pong) / 2.

One-way times use CLOCK_MONOTONIC, which all processes of one Linux host share.
The sender is this process; each receiver is a fresh child process connected over TCP.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from followbot.schemas import Image, LaserScan, decode, encode
from followbot.services.runtime.argtypes import positive_float, positive_int

SCAN_BEAMS = 720
IMAGE_SHAPE = (480, 640, 3)


def _scan(stamp_ns: int = 0) -> LaserScan:
    ranges = np.random.default_rng(0).uniform(0.5, 8.0, SCAN_BEAMS).astype(np.float32)
    return LaserScan.from_ranges(
        ranges, stamp_ns=stamp_ns, angle_min_rad=-2.356, angle_increment_rad=4.712 / SCAN_BEAMS
    )


_IMAGE_PIXELS = np.random.default_rng(1).integers(0, 255, IMAGE_SHAPE, dtype=np.uint8)


def _image(stamp_ns: int = 0) -> Image:
    return Image.from_array(_IMAGE_PIXELS, stamp_ns=stamp_ns)


# ----------------------------------------------------------------------------- codec


def _time_per_call_us(fn, n: int, batches: int = 15) -> float:
    """Median over batches of the mean time per call, in microseconds."""
    fn()
    out = []
    for _ in range(batches):
        t0 = time.perf_counter_ns()
        for _ in range(n):
            fn()
        out.append((time.perf_counter_ns() - t0) / n / 1e3)
    return float(np.median(out))


def codec_figures() -> dict[str, float | bool]:
    scan = _scan(1)
    scan_payload = encode(scan)
    img = _image(1)
    img_payload = encode(img)
    decoded = decode(Image, img_payload)
    return {
        "scan_bytes": len(scan_payload),
        "scan_encode_us": _time_per_call_us(lambda: encode(scan), 2000),
        "scan_decode_us": _time_per_call_us(lambda: decode(LaserScan, scan_payload), 2000),
        "image_bytes": len(img_payload),
        "image_encode_us": _time_per_call_us(lambda: encode(img), 200),
        "image_decode_us": _time_per_call_us(lambda: decode(Image, img_payload).pixels(), 2000),
        "image_decode_zero_copy": bool(
            np.shares_memory(decoded.pixels(), np.frombuffer(img_payload, np.uint8))
        ),
    }


# ----------------------------------------------------------------------------- hop latency


def _zenoh_settings(**kw):
    from followbot.services.runtime.settings import ZenohSettings

    return ZenohSettings(**kw)


def _worker(argv: list[str]) -> int:
    """Child process: receive ``count`` samples and print their one-way latencies (ns)."""
    p = argparse.ArgumentParser()
    p.add_argument("mode", choices=["bare", "node", "pong"])
    p.add_argument("--endpoint", required=True)
    p.add_argument("--key", required=True)
    p.add_argument("--count", type=positive_int, default=1, help="samples to receive (not pong)")
    p.add_argument("--timeout", type=positive_float, default=60.0)
    a = p.parse_args(argv)
    lat: list[int] = []
    if a.mode == "node":
        from followbot.services.runtime.node import zenoh_node
        from followbot.services.runtime.settings import NodeSettings

        topic = a.key  # in node mode the key is a topic of robot "bench"
        settings = NodeSettings(
            robot="bench", zenoh=_zenoh_settings(connect=[a.endpoint]), log_level="warning"
        )
        with zenoh_node("bench_rx", settings) as node:

            def on_message(msg) -> None:
                lat.append(time.monotonic_ns() - msg.stamp_ns)
                if len(lat) >= a.count:
                    node.stop()

            node.subscribe(topic, on_message, policy="all")
            node.run(duration_s=a.timeout)
    else:
        from followbot.services.runtime.session import open_session

        with open_session(_zenoh_settings(connect=[a.endpoint])) as session:
            if a.mode == "pong":
                pub = session.declare_publisher(a.key + "/pong", express=True)
                session.declare_subscriber(a.key + "/ping", lambda s: pub.put(s.payload.to_bytes()))
                time.sleep(a.timeout)  # the parent kills us when done
            else:
                import threading

                done = threading.Event()

                def on_sample(sample) -> None:
                    now = time.monotonic_ns()
                    sent = int.from_bytes(sample.payload.to_bytes()[:8], "little")
                    lat.append(now - sent)
                    if len(lat) >= a.count:
                        done.set()

                sub = session.declare_subscriber(a.key, on_sample)
                done.wait(a.timeout)
                sub.undeclare()
    print(json.dumps(lat))
    return 0


def _spawn_worker(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "followbot.bench", "_worker", *args],
        stdout=subprocess.PIPE,
        env=dict(os.environ, RUST_LOG="error"),
        text=True,
    )


def _wait_matching(is_matching, timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not is_matching():
        if time.monotonic() > deadline:
            raise RuntimeError("the receiver process did not subscribe in time")
        time.sleep(0.01)
    time.sleep(0.2)  # let the receiver settle (its first sample pays for warm-up)


def _summary(lat_ns: list[int], sent: int) -> dict[str, float]:
    a = np.asarray(lat_ns, dtype=np.float64) / 1e6
    return {
        "p50_ms": float(np.percentile(a, 50)),
        "p99_ms": float(np.percentile(a, 99)),
        "received": len(lat_ns),
        "sent": sent,
    }


def hop_bare(session, endpoint: str, payload_size: int, count: int, rate_hz: float) -> dict:
    key = f"followbot/bench/bare{payload_size}"
    child = _spawn_worker("bare", "--endpoint", endpoint, "--key", key, "--count", str(count))
    try:
        pub = session.declare_publisher(key, express=True)
        _wait_matching(lambda: pub.matching_status.matching)
        body = bytearray(payload_size)
        period = 1.0 / rate_hz
        for _ in range(count):
            body[:8] = time.monotonic_ns().to_bytes(8, "little")
            pub.put(body)
            time.sleep(period)
        out, _ = child.communicate(timeout=60)
        pub.undeclare()
        return _summary(json.loads(out), count)
    finally:
        child.kill()


def hop_node(bus_node, endpoint: str, topic: str, make, count: int, rate_hz: float) -> dict:
    child = _spawn_worker("node", "--endpoint", endpoint, "--key", topic, "--count", str(count))
    try:
        pub = bus_node.publisher(topic)
        _wait_matching(pub.matching)
        period = 1.0 / rate_hz
        message = make(0)  # built once: only publishing is timed, not making sensor data
        for _ in range(count):
            message.stamp_ns = time.monotonic_ns()
            pub.put(message)
            time.sleep(period)
        out, _ = child.communicate(timeout=60)
        return _summary(json.loads(out), count)
    finally:
        child.kill()


def round_trip_bare(session, endpoint: str, payload_size: int, count: int) -> dict:
    import threading

    key = f"followbot/bench/rtt{payload_size}"
    child = _spawn_worker("pong", "--endpoint", endpoint, "--key", key)
    try:
        got = threading.Event()
        rtts: list[int] = []

        def on_pong(sample) -> None:
            sent = int.from_bytes(sample.payload.to_bytes()[:8], "little")
            rtts.append(time.monotonic_ns() - sent)
            got.set()

        sub = session.declare_subscriber(key + "/pong", on_pong)
        pub = session.declare_publisher(key + "/ping", express=True)
        _wait_matching(lambda: pub.matching_status.matching)
        time.sleep(0.3)  # the pong publisher must be matched too
        body = bytearray(payload_size)
        for _ in range(count):
            got.clear()
            body[:8] = time.monotonic_ns().to_bytes(8, "little")
            pub.put(body)
            got.wait(1.0)
            time.sleep(0.002)
        sub.undeclare()
        pub.undeclare()
        s = _summary(rtts, count)
        return {"rtt_p50_ms": s["p50_ms"], "rtt_p99_ms": s["p99_ms"], "received": s["received"]}
    finally:
        child.kill()
        child.communicate()  # reaps it and closes its pipe


def hop_figures(scan_count: int, image_count: int) -> dict:
    from followbot.services.runtime.bus import ZenohBus
    from followbot.services.runtime.node import Node
    from followbot.services.runtime.session import free_loopback_endpoint, open_session
    from followbot.services.runtime.settings import NodeSettings

    endpoint = free_loopback_endpoint()
    scan_size = len(encode(_scan()))
    image_size = len(encode(_image()))
    out: dict = {}
    with open_session(_zenoh_settings(listen=[endpoint])) as session:
        node = Node(
            "bench_tx", NodeSettings(robot="bench", health_period_s=3600), ZenohBus(session)
        )
        try:
            steps = [
                ("scan_floor", lambda: hop_bare(session, endpoint, scan_size, scan_count, 500)),
                (
                    "scan_floor_40hz",  # the rate of the end-to-end figures: idle in between
                    lambda: hop_bare(session, endpoint, scan_size, max(40, scan_count // 5), 40),
                ),
                ("scan", lambda: hop_node(node, endpoint, "sensors/scan", _scan, scan_count, 500)),
                ("image_floor", lambda: hop_bare(session, endpoint, image_size, image_count, 30)),
                (
                    "image",
                    lambda: hop_node(node, endpoint, "sensors/image", _image, image_count, 30),
                ),
                ("scan_round_trip", lambda: round_trip_bare(session, endpoint, scan_size, 500)),
            ]
            for name, step in _progress(steps):
                out[name] = step()
        finally:
            node.close()
    return out


def _progress(steps):
    for i, (name, fn) in enumerate(steps, 1):
        print(f"  [{i}/{len(steps)}] {name} ...", file=sys.stderr, flush=True)
        yield name, fn


# ----------------------------------------------------------------------------- report


def run(quick: bool = False, pipeline: bool = True) -> dict:
    print("codec ...", file=sys.stderr, flush=True)
    figures: dict = {"codec": codec_figures()}
    print("one hop between two processes ...", file=sys.stderr, flush=True)
    hops = hop_figures(scan_count=300 if quick else 1500, image_count=60 if quick else 300)
    figures["hop"] = hops
    ratios = {
        "scan_p50_ratio": hops["scan"]["p50_ms"] / hops["scan_floor"]["p50_ms"],
        "image_p50_ratio": hops["image"]["p50_ms"] / hops["image_floor"]["p50_ms"],
    }
    figures["ratios"] = ratios
    figures["hop_floor_p50_ms"] = hops["scan_floor"]["p50_ms"]
    figures["hop_floor_40hz_p50_ms"] = hops["scan_floor_40hz"]["p50_ms"]
    if pipeline:
        from followbot import bench_pipeline

        print("pipeline ...", file=sys.stderr, flush=True)
        p = bench_pipeline.run(
            Path("out/bench"),
            quick=quick,
            hop_floor_p50_ms=figures["hop_floor_p50_ms"],
            hop_floor_40hz_p50_ms=figures["hop_floor_40hz_p50_ms"],
        )
        figures["pipeline"] = p
        for key in (
            "e2e_p50_ms",
            "e2e_p99_ms",
            "e2e_200hz_p50_ms",
            "e2e_200hz_p99_ms",
            "e2e_together_p50_ms",
            "e2e_together_p99_ms",
            "max_sustained_scans_per_s",
        ):
            figures[key] = p[key]
        figures["stages"] = p["stages"]
    return figures


def format_report(f: dict) -> str:
    c, h, r = f["codec"], f["hop"], f["ratios"]
    lines = [
        "followbot bench (medians; one run)",
        "",
        "codec                                  time       target",
        f"  scan 720 beams encode ({c['scan_bytes']} B)      {c['scan_encode_us']:7.2f} us",
        f"  scan 720 beams decode+validate        {c['scan_decode_us']:7.2f} us   <= 20 us",
        f"  image 640x480 BGR encode ({c['image_bytes'] // 1024} KiB)  "
        f"{c['image_encode_us']:7.2f} us",
        f"  image 640x480 BGR decode+validate     {c['image_decode_us']:7.2f} us   "
        f"zero-copy: {'yes' if c['image_decode_zero_copy'] else 'NO'}",
        "",
        "one hop, publish -> handler          p50 ms   p99 ms   recv/sent",
    ]
    for name, label in [
        ("scan_floor", "scan  bare zenoh-python (floor)"),
        ("scan_floor_40hz", "scan  bare, at 40 Hz (idle between)"),
        ("scan", "scan  followbot node"),
        ("image_floor", "image bare zenoh-python (floor)"),
        ("image", "image followbot node"),
    ]:
        s = h[name]
        lines.append(
            f"  {label:<34} {s['p50_ms']:7.3f}  {s['p99_ms']:7.3f}   {s['received']}/{s['sent']}"
        )
    rt = h["scan_round_trip"]
    lines += [
        f"  scan  bare round trip / 2            {rt['rtt_p50_ms'] / 2:7.3f}  "
        f"{rt['rtt_p99_ms'] / 2:7.3f}",
        "",
        f"ratio node/floor p50: scan {r['scan_p50_ratio']:.2f}x, image {r['image_p50_ratio']:.2f}x"
        "   (target <= 1.5x)",
    ]
    if "pipeline" in f:
        from followbot.bench_pipeline import format_report as pipeline_report

        lines.append(pipeline_report(f["pipeline"]))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["_worker"]:
        return _worker(argv[1:])
    p = argparse.ArgumentParser(
        prog="followbot bench",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    p.add_argument("--quick", action="store_true", help="fewer samples (a smoke run)")
    p.add_argument(
        "--no-pipeline", action="store_true", help="skip the laser_legs/tracker/controller part"
    )
    args = p.parse_args(argv)
    figures = run(quick=args.quick, pipeline=not args.no_pipeline)
    print(format_report(figures))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + "\n")
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
