"""``followbot sweep``: every scenario over several seeds, summed up the way the issues judge.

    followbot sweep --output out/sweep/base                       # the 76 standard runs
    followbot sweep --output out/sweep/try --set tracker.max_misses=4 --against out/sweep/base

One seed says little in closed loop (a different pairing now and then sends the robot down
a slightly different path), so a change is judged on a grid of runs: every built-in scenario
with its own seed and seeds 1, 2, 3, and the eight with occlusions or crowds (``HARD``)
also with seeds 4 and 6 -- 84 runs in all (``--grid standard``). ``--grid own``
runs each scenario once with its own seed (17 runs); ``--seeds`` and ``--scenario`` choose
any other grid.

Each run goes through the real pipeline exactly as ``followbot eval`` runs it (lock-step, so
a run's figures do not depend on the machine's speed; ``--jobs`` runs that many at once) and
leaves its metrics in ``DIR/runs/SCENARIO__SEED.json``. A run whose file is there already is
not run again, so an interrupted sweep goes on where it stopped (``--fresh`` runs all again);
the settings the runs were made with are kept in ``DIR/sweep_settings.json`` and a sweep
with other settings into the same folder is refused. So is one with other code: the
settings file also holds a fingerprint of followbot's source (its ``.py`` and scenario
``.yaml`` files, as installed -- an editable install runs the working tree), and a sweep
whose code changes while it runs stops at the next finished run, keeping the runs that
finished before the change and dropping that one (each run starts the stages afresh, so
runs after an edit would mix versions). Run experiments from a separate clone.

Printed and written (``DIR/sweep.md``, ``DIR/sweep.json``):

- RMSE <= 0.08 m: runs meeting issue 6's accuracy target (``rmse_m``);
- tracked >= 98 %: runs whose ``tracked_visible_share_acquired`` meets it;
- time on wrong people: the sum of ``wrong_target_s`` over all runs;
- two-person runs with a switch: the runs of the four two-person scenarios (thesis 5.2.4)
  with an identity switch, and their time on the bystander;
- re-acquisitions: the occlusions of every run, how many were never re-acquired, how many
  within 1 s, and the mean time of the re-acquired ones; then the mean wait, from the
  target's reappearance, for a laser candidate on it and for it to be in the camera's view
  (the evaluation's ``reacquire_laser_s_episodes`` and ``reacquire_camera_s_episodes``):
  what is left of the re-acquisition time after the later of the two is the decision; and
  the mean least time the camera needed to turn to it from where it pointed then
  (``reacquire_turn_s_episodes``), which no re-acquisition by appearance from there can beat;
- mean followed: the mean ``followed_share_acquired``;
- bumps: the runs in which the robot ran into the world (the simulator's bumper stopped it;
  the evaluation's ``robot_bumps``), and the contacts over all runs.

With ``--against OTHER`` (another sweep's folder) the table gets OTHER's column beside this
one and lists the runs whose figures differ. Metrics are those of followbot.evaluation.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import hashlib
import json
import math
import multiprocessing
import sys
import tempfile
from pathlib import Path

from followbot.services.runtime.argtypes import positive_int

__all__ = ["HARD", "TWO_PERSON", "aggregate", "code_fingerprint", "grid", "main"]

#: The four two-person scenarios of thesis 5.2.4 (issue 6: 0 identity switches on each).
TWO_PERSON = (
    "thesis_5_2_4_side_by_side",
    "thesis_5_2_4_turn_apart",
    "thesis_5_2_4_two_people",
    "thesis_5_2_4_two_people_swapped",
)
#: Scenarios judged on two more seeds: the eight with occlusions or crowds.
HARD_EXTRA_SEEDS = (4, 6)
OWN_GRID_SEEDS = (None, 1, 2, 3)
HARD = (
    "bellotto_cluttered_office",
    "crowd_ten",
    "door_corner",
    "livingston_box_occlusion",
    "occlusion_pillar",
    "ristic_circles",
    "ristic_wall_corridor",
    "thesis_5_2_4_side_by_side",
)
RMSE_TARGET_M = 0.08
TRACKED_TARGET = 0.98
REACQUIRE_TARGET_S = 1.0


def code_fingerprint() -> str:
    """SHA-256 (hex, first 16) of followbot's source as the runs import it: every ``.py`` and
    ``.yaml`` file under the followbot package's folders, by path relative to them."""
    import followbot
    import followbot.schemas
    import followbot.services

    h = hashlib.sha256()
    roots = sorted({Path(p).resolve() for m in (followbot, followbot.schemas, followbot.services)
                    for p in m.__path__})  # fmt: skip
    for root in roots:
        for f in sorted(root.rglob("*")):
            if f.suffix in (".py", ".yaml") and f.is_file() and "__pycache__" not in f.parts:
                h.update(f"{root.name}/{f.relative_to(root).as_posix()}\0".encode())
                h.update(f.read_bytes())
    return h.hexdigest()[:16]


def grid(kind: str, scenarios: list[str]) -> list[tuple[str, int | None]]:
    """(scenario, seed) pairs; seed None is the scenario's own."""
    if kind == "own":
        return [(s, None) for s in scenarios]
    runs = [(s, seed) for s in scenarios for seed in OWN_GRID_SEEDS]
    runs += [(s, seed) for s in scenarios if s in HARD for seed in HARD_EXTRA_SEEDS]
    return runs


def run_key(scenario: str, seed: int | None) -> str:
    return f"{scenario}__{'own' if seed is None else seed}"


def aggregate(metrics: dict[str, dict]) -> dict:
    """The sweep's figures from ``{run_key: metrics}`` (module docstring)."""
    rows = list(metrics.values())

    def ok(v, bound, below=True):
        return v is not None and (v <= bound if below else v >= bound)

    two = [m for m in rows if m["scenario"] in TWO_PERSON]
    switched = [m for m in two if (m.get("identity_switches") or 0) > 0]
    episodes = [e for m in rows for e in (m.get("reacquire_s_episodes") or [])]
    done = [e for e in episodes if e is not None]
    followed = [
        m["followed_share_acquired"] for m in rows if m.get("followed_share_acquired") is not None
    ]

    def mean_part(key: str) -> float | None:  # over the episodes where that part came
        part = [e for m in rows for e in (m.get(key) or []) if e is not None]
        return round(sum(part) / len(part), 2) if part else None

    return {
        "runs": len(rows),
        "rmse_ok": sum(ok(m.get("rmse_m"), RMSE_TARGET_M) for m in rows),
        "tracked_ok": sum(
            ok(m.get("tracked_visible_share_acquired"), TRACKED_TARGET, below=False) for m in rows
        ),
        "wrong_s": round(sum(m.get("wrong_target_s") or 0.0 for m in rows), 2),
        "two_person_runs": len(two),
        "two_person_switch_runs": len(switched),
        "two_person_switch_s": round(sum(m.get("wrong_target_s") or 0.0 for m in switched), 2),
        "occlusions": len(episodes),
        "reacquire_never": len(episodes) - len(done),
        "reacquire_within_1s": sum(e <= REACQUIRE_TARGET_S for e in done),
        "reacquire_mean_s": round(sum(done) / len(done), 2) if done else None,
        "reacquire_laser_mean_s": mean_part("reacquire_laser_s_episodes"),
        "reacquire_camera_mean_s": mean_part("reacquire_camera_s_episodes"),
        "reacquire_turn_mean_s": mean_part("reacquire_turn_s_episodes"),
        "followed_mean": round(sum(followed) / len(followed), 3) if followed else None,
        "bump_runs": sum((m.get("robot_bumps") or 0) > 0 for m in rows),
        "bumps": sum(m.get("robot_bumps") or 0 for m in rows),
    }


_LABELS = (
    ("runs", "runs"),
    ("rmse_ok", f"RMSE <= {RMSE_TARGET_M} m"),
    ("tracked_ok", f"tracked >= {TRACKED_TARGET:.0%} after acquisition"),
    ("wrong_s", "time on wrong people, s"),
    ("two_person_switch_runs", "two-person runs with a switch"),
    ("two_person_switch_s", "their time on the bystander, s"),
    ("occlusions", "occlusions"),
    ("reacquire_never", "never re-acquired"),
    ("reacquire_within_1s", f"re-acquired within {REACQUIRE_TARGET_S:g} s"),
    ("reacquire_mean_s", "mean re-acquisition, s"),
    ("reacquire_laser_mean_s", "... mean wait for a laser candidate on the target, s"),
    ("reacquire_camera_mean_s", "... mean wait for the target in the camera's view, s"),
    ("reacquire_turn_mean_s", "... mean least turn of the camera to it, s"),
    ("followed_mean", "mean followed"),
    ("bump_runs", "runs in which the robot ran into the world"),
    ("bumps", "its contacts with the world, all runs"),
)
_RUN_FIELDS = (
    ("rmse_m", "RMSE m", ".3f"),
    ("tracked_visible_share_acquired", "tracked", ".2f"),
    ("followed_share_acquired", "followed", ".2f"),
    ("identity_switches", "ID sw.", "d"),
    ("wrong_target_s", "wrong s", ".2f"),
    ("robot_bumps", "bumps", "d"),
)


def _fmt(v, spec: str = "") -> str:
    if v is None:
        return "–"
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return format(v, spec) if spec else str(v)


def _reacq(m: dict) -> str:
    eps = m.get("reacquire_s_episodes") or []
    return ", ".join("never" if e is None else f"{e:.2f}" for e in eps) or "–"


def report(
    metrics: dict[str, dict], summary: dict, name: str, against: tuple[str, dict, dict] | None
) -> str:
    """The Markdown of ``sweep.md``: the summary table, then every run (or, with ``against``,
    the runs whose figures differ from the other sweep's)."""
    lines = [f"# Sweep: {name}", ""]
    if against is None:
        lines += ["| | this sweep |", "|---|---|"]
        lines += [f"| {label} | {_fmt(summary[k])} |" for k, label in _LABELS]
    else:
        other_name, other_summary, _ = against
        lines += [f"| | {other_name} | {name} |", "|---|---|---|"]
        lines += [
            f"| {label} | {_fmt(other_summary.get(k))} | {_fmt(summary[k])} |"
            for k, label in _LABELS
        ]
    head = "| run | " + " | ".join(h for _, h, _ in _RUN_FIELDS) + " | re-acq. s |"
    rule = "|---" * (len(_RUN_FIELDS) + 2) + "|"

    def row(key: str, m: dict) -> str:
        cells = " | ".join(_fmt(m.get(f), spec) for f, _, spec in _RUN_FIELDS)
        return f"| {key} | {cells} | {_reacq(m)} |"

    if against is None:
        lines += ["", "Every run:", "", head, rule]
        lines += [row(k, metrics[k]) for k in sorted(metrics)]
    else:
        other_name, _, other = against

        def differs(k: str) -> bool:
            a, b = metrics[k], other[k]
            return _reacq(a) != _reacq(b) or any(
                _fmt(a.get(f), spec) != _fmt(b.get(f), spec) for f, _, spec in _RUN_FIELDS
            )

        changed = [k for k in sorted(metrics) if k in other and differs(k)]
        same = sum(1 for k in metrics if k in other) - len(changed)
        lines += ["", f"{same} runs give the same figures; those that differ ({other_name} "
                  f"first, then {name}):", "", head, rule]  # fmt: skip
        for k in changed:
            lines += [row(f"{k} ({other_name})", other[k]), row(f"{k} ({name})", metrics[k])]
    return "\n".join(lines) + "\n"


def _one_run(scenario: str, seed: int | None, overrides: list[str], out: str) -> dict:
    """Run one (scenario, seed) with the thesis preset in this (worker) process; its metrics
    as plain JSON values."""
    from followbot.evaluation import compute_metrics
    from followbot.runner import run_scenario

    with tempfile.TemporaryDirectory(prefix="sweep-", dir=out) as tmp:
        run = run_scenario(
            scenario, "thesis", Path(tmp), seed=seed,
            record=False, progress=False, overrides=overrides or None,
        )  # fmt: skip
        m = compute_metrics(run)
    m["seed"] = seed
    return json.loads(json.dumps(m, default=float))


def main(argv: list[str] | None = None) -> int:
    from followbot.eval_cli import builtin_scenarios
    from followbot.runner import RunError, check_stage_overrides

    p = argparse.ArgumentParser(
        prog="followbot sweep", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    p.add_argument("--output", required=True, metavar="DIR", help="sweep folder")
    p.add_argument(
        "--grid", choices=("standard", "own"), default="standard",
        help="standard: own seed and 1-3 for all, 4 and 6 for the hard ones (84 runs); "
        "own: each scenario with its own seed",
    )  # fmt: skip
    p.add_argument(
        "--seeds", metavar="S,S,...",
        help="instead of --grid: these seeds for every scenario ('own' for its own seed)",
    )  # fmt: skip
    p.add_argument(
        "--scenario", action="append", metavar="NAME",
        help="a built-in scenario (repeatable; default: all)",
    )  # fmt: skip
    p.add_argument(
        "--set", action="append", default=[], metavar="STAGE.KEY=VALUE",
        help="a stage setting on top of the thesis preset, as for `followbot eval` (repeatable)",
    )  # fmt: skip
    p.add_argument("--jobs", type=positive_int, default=2, help="runs at once (default 2)")
    p.add_argument("--against", metavar="DIR", help="another sweep's folder to compare with")
    p.add_argument("--fresh", action="store_true", help="run again the runs already done")
    args = p.parse_args(argv)

    known = builtin_scenarios()
    scenarios = args.scenario or known
    unknown = [s for s in scenarios if s not in known]
    if unknown:
        print(f"followbot sweep: unknown scenario(s) {', '.join(unknown)}; built-in: "
              f"{', '.join(known)}", file=sys.stderr)  # fmt: skip
        return 2
    if args.jobs < 1:
        print("followbot sweep: --jobs must be at least 1", file=sys.stderr)
        return 2
    try:
        check_stage_overrides("thesis", args.set)
    except RunError as exc:
        print(f"followbot sweep: {exc}", file=sys.stderr)
        return 2
    if args.seeds:
        try:
            seeds = [None if s == "own" else int(s) for s in args.seeds.split(",")]
        except ValueError:
            print(f"followbot sweep: --seeds takes integers or 'own', got {args.seeds!r}",
                  file=sys.stderr)  # fmt: skip
            return 2
        runs = [(s, seed) for s in scenarios for seed in seeds]
    else:
        runs = grid(args.grid, scenarios)
    against = None
    if args.against:
        other = Path(args.against) / "sweep.json"
        if not other.is_file():
            print(f"followbot sweep: {other} not found (run that sweep first)", file=sys.stderr)
            return 2
        against = json.loads(other.read_text())

    out = Path(args.output)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    settings_file = out / "sweep_settings.json"
    settings = {"set": sorted(args.set), "code": code_fingerprint()}
    if settings_file.is_file() and not args.fresh:
        before = json.loads(settings_file.read_text())
        if before.get("set") != settings["set"]:
            print(f"followbot sweep: {out} holds runs made with {before.get('set')}, not "
                  f"{settings['set']}; use another folder or --fresh", file=sys.stderr)  # fmt: skip
            return 2
        if before.get("code") != settings["code"]:
            print(f"followbot sweep: {out} holds runs made with other code (source "
                  f"fingerprint {before.get('code')}, now {settings['code']}); use another "
                  "folder or --fresh", file=sys.stderr)  # fmt: skip
            return 2
    settings_file.write_text(json.dumps(settings) + "\n")

    metrics: dict[str, dict] = {}
    todo = []
    for scenario, seed in runs:
        f = out / "runs" / f"{run_key(scenario, seed)}.json"
        if f.is_file() and not args.fresh:
            metrics[run_key(scenario, seed)] = json.loads(f.read_text())
        else:
            todo.append((scenario, seed))
    failures: dict[str, str] = {}
    changed = ""
    done = len(metrics)
    # spawn, not fork: a forked worker inherits a parent's threads' locks (Zenoh's, a test
    # runner's) in whatever state they were, and can hang on them
    spawn = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.jobs, mp_context=spawn) as pool:
        futures = {
            pool.submit(_one_run, scenario, seed, args.set, str(out)): (scenario, seed)
            for scenario, seed in todo
        }
        for fut in concurrent.futures.as_completed(futures):
            scenario, seed = futures[fut]
            key = run_key(scenario, seed)
            done += 1
            try:
                m = fut.result()
            except RunError as exc:
                failures[key] = str(exc)
                print(f"[{done}/{len(runs)}] {key}: failed: {exc}", file=sys.stderr, flush=True)
                continue
            now = code_fingerprint()
            if now != settings["code"]:
                for f in futures:
                    f.cancel()
                changed = (f"followbot sweep: the code changed while the sweep ran (source "
                           f"fingerprint {settings['code']} -> {now}); stopped, {key} and the "
                           f"runs under way dropped, the {len(metrics)} run(s) that finished "
                           f"before kept in {out / 'runs'}")  # fmt: skip
                break
            (out / "runs" / f"{key}.json").write_text(json.dumps(m, indent=1) + "\n")
            metrics[key] = m
            print(f"[{done}/{len(runs)}] {key}: rmse {_fmt(m.get('rmse_m'), '.3f')} m, tracked "
                  f"{_fmt(m.get('tracked_visible_share_acquired'), '.2f')}, switches "
                  f"{_fmt(m.get('identity_switches'))}", file=sys.stderr, flush=True)  # fmt: skip
    if changed:
        print(changed, file=sys.stderr)
        return 2
    if not metrics:
        print("followbot sweep: no run finished", file=sys.stderr)
        return 1
    summary = aggregate(metrics)
    name = out.name or str(out)
    other = None
    if against is not None:
        other = (Path(args.against).name, against["summary"], against["runs"])
    text = report(metrics, summary, name, other)
    (out / "sweep.md").write_text(text)
    (out / "sweep.json").write_text(
        json.dumps({"settings": settings, "summary": summary, "runs": metrics}, indent=1) + "\n"
    )
    print(text.split("\n\n", 2)[1] if "\n\n" in text else text)
    print(f"wrote {out / 'sweep.md'} and {out / 'sweep.json'}")
    if failures:
        (out / "failures.json").write_text(json.dumps(failures, indent=2) + "\n")
        print(f"{len(failures)} run(s) failed; see {out / 'failures.json'}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
