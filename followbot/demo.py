"""``followbot demo``: the whole system follows a person in the simulator, then tells you how.

Runs the default scenario (thesis 5.2.4: the target and a bystander cross, walk side by side
and turn apart) with the followbot preset (the defaults; ``--preset`` names another, ``--set``
changes a stage setting): the simulator, laser_legs, vision_verify, tracker and controller
each as its own process over Zenoh, in lock-step. Shows progress, then prints
whether the robot followed the right person, the tracking error, identity switches and the
stages' latency, and writes the report, plots and an MCAP recording of every topic to an
output folder. Every figure is measured in this run.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from followbot.presetargs import add_preset_arguments

DEFAULT_SCENARIO = "thesis_5_2_4_two_people"


def main(argv: list[str] | None = None) -> int:
    from followbot.evaluation import compute_metrics, write_report
    from followbot.runner import RunError, check_stage_overrides, run_scenario

    p = argparse.ArgumentParser(
        prog="followbot demo", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    p.add_argument("--scenario", default=DEFAULT_SCENARIO, help=f"({DEFAULT_SCENARIO})")
    add_preset_arguments(p)
    p.add_argument("--output", default="out/demo", help="output folder (out/demo)")
    args = p.parse_args(argv)
    out = Path(args.output)
    try:  # a malformed --set stops the demo before it starts
        check_stage_overrides(args.preset, args.set)
    except RunError as exc:
        print(f"followbot demo: {exc}", file=sys.stderr)
        return 2
    print(f"followbot demo: {args.scenario}, preset {args.preset}; sim + 4 stages as processes "
          "over Zenoh, lock-step")  # fmt: skip
    try:
        run = run_scenario(
            args.scenario, args.preset, out / "run", record=True, overrides=args.set or None
        )
    except (RunError, ValueError) as exc:
        print(f"followbot demo: {exc}", file=sys.stderr)
        return 1
    m = compute_metrics(run)
    report = write_report([(run, m)], out)

    def v(key, fmt=".3f"):
        x = m.get(key)
        return "n/a" if x is None else format(x, fmt)

    switches = m.get("identity_switches")
    right = switches == 0 and (m.get("tracked_visible_share") or 0) > 0.8
    verdict = (
        "yes" if right
        else f"mostly ({switches} identity switch(es), {v('wrong_target_s', '.2f')} s on another "
             "person)" if (m.get("tracked_visible_share") or 0) > 0.5
        else "no"
    )  # fmt: skip
    lat = m.get("latency_ms", {})
    e2e = lat.get("controller", {})
    print()
    print(f"  followed the right person:  {verdict}")
    print(f"  target tracked while visible: {v('tracked_visible_share', '.1%')}")
    print(f"  on the target after learning: {v('followed_share_acquired', '.1%')} of the time")
    print(f"  target position RMSE:         {v('rmse_m')} m")
    print(f"  identity switches:            {switches}")
    print(f"  follow distance in [1, 2] m:  {v('follow_distance_share', '.1%')} of tracked time")
    if e2e:
        print(f"  scan -> cmd_vel latency:      p50 {e2e.get('p50_ms', 0):.2f} ms, "
              f"p99 {e2e.get('p99_ms', 0):.2f} ms (through 4 processes)")  # fmt: skip
    print(f"  simulated {run.sim_s:.0f} s in {run.wall_s:.1f} s "
          f"({v('real_time_factor', '.1f')}x real time)")  # fmt: skip
    print()
    print(f"  report:    {report}")
    print(f"  plots:     {out / 'plots'}/")
    print(f"  recording: {out / 'run' / 'run.mcap'}  (followbot replay, or open it in Foxglove)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
