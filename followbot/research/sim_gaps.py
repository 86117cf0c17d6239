"""Scenarios with and without vision (laser only), side by side (made for issue 35's
measurements, docs/tracker_log.md "Issue 35").

    python -m followbot.research.sim_gaps --output out/gaps/base \
        --scenario thesis_5_2_4_two_people --scenario occlusion_pillar --seeds own,1 \
        --vision both --set tracker.identity.laser_reacquire_m=1.0

``followbot sweep`` runs the thesis preset with vision only; a laser-only run (the target is
the nearest person ahead, no vision_verify: ``run_scenario(..., vision=False)``) needs this.
Each (scenario, seed, vision) run goes through the real pipeline in lock-step; its metrics are
kept in ``DIR/runs/SCENARIO__SEED__vision|laser.json`` (a run already there is not run again)
and one line per run is printed: tracked share of the visible time after acquisition,
identity switches, time on wrong people, followed share, and the lock-step timeouts (a run
with timeouts depends on the machine's load: run it again).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

__all__ = ["main"]


def _one(scenario: str, seed: int | None, vision: bool, overrides: list[str], out: str) -> dict:
    from followbot.evaluation import compute_metrics
    from followbot.runner import run_scenario

    with tempfile.TemporaryDirectory(prefix="gaps-", dir=out) as tmp:
        run = run_scenario(
            scenario, "thesis", Path(tmp), seed=seed, record=False, progress=False,
            vision=vision, overrides=overrides or None,
        )  # fmt: skip
        m = compute_metrics(run)
    return json.loads(json.dumps(m, default=float))


def _line(key: str, m: dict) -> str:
    def f(k: str, fmt: str) -> str:
        v = m.get(k)
        return "-" if v is None else format(v, fmt)

    return (
        f"{key:<52} tracked {f('tracked_visible_share_acquired', '.3f')}  "
        f"ID sw. {f('identity_switches', 'd')}  wrong {f('wrong_target_s', '.2f')} s  "
        f"followed {f('followed_share_acquired', '.3f')}  timeouts {f('timeouts_total', 'd')}"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--output", type=Path, required=True)
    p.add_argument("--scenario", action="append", required=True)
    p.add_argument("--seeds", default="own", help="own,1,2,...")
    p.add_argument("--vision", choices=("on", "off", "both"), default="both")
    p.add_argument("--set", action="append", default=[])
    p.add_argument("--jobs", type=int, default=2)
    a = p.parse_args(argv)
    seeds = [None if s == "own" else int(s) for s in a.seeds.split(",")]
    visions = {"on": [True], "off": [False], "both": [True, False]}[a.vision]
    runs = a.output / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    (a.output / "settings.json").write_text(json.dumps({"set": a.set}) + "\n")
    todo = {}
    for sc in a.scenario:
        for seed in seeds:
            for v in visions:
                key = f"{sc}__{'own' if seed is None else seed}__{'vision' if v else 'laser'}"
                todo[key] = (sc, seed, v)
    with ProcessPoolExecutor(a.jobs) as pool:
        futures = {
            k: pool.submit(_one, *args, a.set, str(a.output))
            for k, args in todo.items()
            if not (runs / f"{k}.json").exists()
        }
        for k in todo:
            path = runs / f"{k}.json"
            if k in futures:
                path.write_text(json.dumps(futures[k].result()) + "\n")
            print(_line(k, json.loads(path.read_text())), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
