"""``followbot eval``: scenarios × presets through the real pipeline, in lock-step.

    followbot eval --output out/eval                          # every built-in scenario, followbot
    followbot eval --preset zhuang --output out/zhuang        # seed 001, camera only
    followbot eval --scenario thesis_5_2_4_two_people --scenario my.yaml \\
                   --preset thesis --preset bellotto --output out/eval

Each (scenario, preset) runs the simulator and the four stages as separate processes over
Zenoh (followbot.runner), then followbot.evaluation computes the metrics of DESIGN.md and
writes ``report.md``, ``summary.json`` and PNG plots into the output folder (one subfolder per
run holds its logs, settings and MCAP recording). A scenario file that fails validation stops
everything before any run, with the error naming the field (exit 2). A preset whose parts are
not installed is reported and skipped.

Without --scenario each preset runs the built-in scenarios written for every preset and those
naming it (a scenario's ``presets``: the zhuang_* ones are seed 001's, for --preset zhuang).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

from followbot.presetargs import DEFAULT_PRESET, add_preset_arguments

DEFAULT_PRESETS = (DEFAULT_PRESET,)


def builtin_scenarios(preset: str | None = "followbot") -> list[str]:
    """The built-in scenarios a run of ``preset`` takes by default: those written for every
    preset and those naming it (a scenario's ``presets``); None: all of them."""
    from followbot.services.sim.scenario import builtin_names, load_builtin

    names = list(builtin_names())
    if preset is None:
        return names
    return [n for n in names if not (p := load_builtin(n).presets) or preset in p]


def main(argv: list[str] | None = None) -> int:
    from followbot.runner import RunError, check_stage_overrides, run_scenario
    from followbot.services.sim.node import load_scenario_setting
    from followbot.services.sim.scenario import ScenarioError

    p = argparse.ArgumentParser(
        prog="followbot eval", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    p.add_argument(
        "--scenario", action="append", metavar="NAME|FILE",
        help="a built-in scenario name or a scenario file (repeatable; default: the built-in "
        "ones for each preset)",
    )  # fmt: skip
    p.add_argument("--output", required=True, metavar="DIR", help="report folder")
    p.add_argument("--seed", type=int, help="random seed (default: each scenario's own)")
    p.add_argument("--no-record", action="store_true", help="do not write MCAP recordings")
    p.add_argument(
        "--record-images", action="store_true",
        help="the recordings hold the camera's images too, to see what vision judged "
        "(about 2 MB per simulated second at 320 x 240 and 10 Hz)",
    )  # fmt: skip
    p.add_argument(
        "--laser-rate-hz", type=float, metavar="HZ",
        help="run every scenario's laser at this rate instead of its own (most are the "
        "thesis's 8.3 Hz; robots' scanners often run at 25-40 Hz); the run and report are "
        "named NAME_RATEhz",
    )  # fmt: skip
    add_preset_arguments(p, repeatable=True)
    args = p.parse_args(argv)
    presets = args.preset or list(DEFAULT_PRESETS)
    scenarios = {p: args.scenario or builtin_scenarios(p) for p in presets}
    for s in sorted({s for names in scenarios.values() for s in names}):  # validate first
        try:
            load_scenario_setting(s)
        except (ScenarioError, ValueError) as exc:
            print(f"followbot eval: {exc}", file=sys.stderr)
            return 2
    try:  # a malformed --set stops everything before any run
        check_stage_overrides(presets[0], args.set)
    except RunError as exc:
        print(f"followbot eval: {exc}", file=sys.stderr)
        return 2
    if args.laser_rate_hz is not None and not 0 < args.laser_rate_hz <= 10_000:
        print("followbot eval: --laser-rate-hz must be in (0, 10000]", file=sys.stderr)
        return 2
    run = functools.partial(
        run_scenario, overrides=args.set or None, laser_rate_hz=args.laser_rate_hz,
        record_images=args.record_images,
    )  # fmt: skip
    return evaluate(scenarios, presets, Path(args.output), args.seed, not args.no_record,
                    run, RunError)  # fmt: skip


def evaluate(scenarios, presets, out: Path, seed, record, run_scenario, run_error) -> int:
    """Run every scenario with every preset (``scenarios``: a list for all, or preset -> its
    list); write the report."""
    from followbot.evaluation import compute_metrics, write_report

    if not isinstance(scenarios, dict):
        scenarios = dict.fromkeys(presets, scenarios)
    out.mkdir(parents=True, exist_ok=True)
    results, failures = [], {}
    n = sum(len(scenarios[p]) for p in presets)
    i = 0
    for preset in presets:
        for scenario in scenarios[preset]:
            i += 1
            name = Path(scenario).stem if scenario.endswith((".yaml", ".yml")) else scenario
            print(f"[{i}/{n}] {name} with preset {preset}", file=sys.stderr, flush=True)
            try:
                run = run_scenario(
                    scenario, preset, out / "runs" / f"{name}__{preset}", seed=seed, record=record
                )
            except run_error as exc:
                print(f"  failed: {exc}", file=sys.stderr)
                failures[f"{name} / {preset}"] = str(exc)
                continue
            metrics = compute_metrics(run)
            results.append((run, metrics))
            print(f"  {_one_line(metrics)}", file=sys.stderr, flush=True)
    if results:
        report = write_report(results, out)
        print(f"wrote {report} and {out / 'summary.json'}")
    if failures:
        (out / "failures.json").write_text(json.dumps(failures, indent=2) + "\n")
        print(f"{len(failures)} run(s) failed; see {out / 'failures.json'}")
    return 0 if results and not failures else 1


def _one_line(m: dict) -> str:
    def f(key: str, fmt: str) -> str:
        v = m.get(key)
        return "-" if v is None else format(v, fmt)

    return (
        f"rmse {f('rmse_m', '.3f')} m, tracked {f('tracked_visible_share', '.1%')}, "
        f"followed {f('followed_share_acquired', '.1%')}, "
        f"identity switches {f('identity_switches', 'd')}, MOTA {f('mota', '.2f')}"
    )


if __name__ == "__main__":
    raise SystemExit(main())
