"""`feat2map search` against random search at an equal CPU budget: Optuna's TPE sampler vs its
RandomSampler over the same joined space (the paper's San Francisco feature space, traffic,
signals, pedestrians, the ego), 3 seeds each, counting distinct failure signatures as the CPU
seconds go by, for

  baseline   the baseline planner;
  amber      AmberRunner (scenarios/faulty_planners.py), the baseline that takes amber for green:
             the known-answer check (its planted fault must show up as red_light signatures);
  commonroad CommonRoad's reactive planner through the planner bridge, when
             `.venv-crplanner` (here, or /work/main's) and adapters/commonroad/ run (small budget).

Shrinking is off (the table measures finding, not shrinking). Prints a Markdown table per
planner: distinct signatures at half and at the whole budget, per sampler and seed, and their
means; docs/search.md keeps the latest.

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python benchmarks/bench_search.py [--budget-seconds S]
     [--planners baseline,amber,commonroad] [--seeds 3] [--workers 2]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

ROOT = Path(__file__).resolve().parent.parent
CR_VENVS = (ROOT / ".venv-crplanner", Path("/work/main/.venv-crplanner"))
AMBER = "feat2map.scenarios.faulty_planners:AmberRunner"


def planner_spec(name: str, cr_budget: float) -> tuple[object, float] | None:
    """(planner spec, budget factor) of a named planner, or None where it cannot run here."""
    if name == "baseline":
        return "baseline", 1.0
    if name == "amber":
        return AMBER, 1.0
    if name == "commonroad":
        from feat2map.scenarios.bridge import BridgePlanner

        venv = next((v for v in CR_VENVS if (v / "bin" / "python").is_file()), None)
        if venv is None or not (ROOT / "adapters" / "commonroad" / "planner.py").is_file():
            return None
        cmd = f"{venv / 'bin' / 'python'} {ROOT / 'adapters' / 'commonroad' / 'planner.py'}"
        return BridgePlanner(cmd, step_timeout=60.0), cr_budget
    raise SystemExit(f"unknown planner {name!r} (baseline, amber, commonroad)")


def at(history, cpu: float) -> int:
    """Distinct signatures once `cpu` CPU seconds were spent (the last batch ended by then)."""
    return max([k for c, _, k in history if c <= cpu + 1e-9], default=0)


def main(argv: list[str] | None = None) -> int:
    from feat2map.scenarios.search import evaluator, search
    from feat2map.scenarios.search_space import start_from

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--budget-seconds", type=float, default=30.0, help="CPU seconds per search (default 30)")
    p.add_argument("--cr-budget-factor", type=float, default=2.0, help="the bridged planner's budget, times this "
                   "(it is ~30x slower per step)")
    p.add_argument("--planners", default="baseline,amber,commonroad")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    for name in args.planners.split(","):
        spec = planner_spec(name, args.cr_budget_factor)
        if spec is None:
            print(f"\n{name}: skipped (no .venv-crplanner or adapters/commonroad here)")
            continue
        planner, factor = spec
        budget = args.budget_seconds * factor
        rows, rules = [], {}
        with evaluator(planner, workers=args.workers) as ev, tempfile.TemporaryDirectory() as work:
            start = start_from(workdir=Path(work))
            for sampler in ("tpe", "random"):
                for seed in range(args.seeds):
                    t0 = time.perf_counter()
                    r = search(start, ev, workdir=Path(work), budget_seconds=budget, seed=seed, sampler=sampler,
                               shrink_failures=False)
                    rows.append((sampler, seed, len(r.trials), r.cpu_s, at(r.history, budget / 2),
                                 len(r.findings), time.perf_counter() - t0))
                    for f in r.findings:
                        rules.setdefault(f"{f.signature.outcome}/{f.signature.rule}", set()).add(sampler)
                    print(f"  {name} {sampler} seed {seed}: {len(r.trials)} scenarios, {r.cpu_s:.0f} CPU s, "
                          f"{len(r.findings)} signatures", file=sys.stderr, flush=True)
        print(f"\n### {name} ({budget:g} CPU s per search, {args.workers} workers)\n")
        print("| sampler | seed | scenarios | CPU s | signatures at half the budget | signatures at the budget | "
              "wall s |\n|---|---:|---:|---:|---:|---:|---:|")
        for sampler, seed, n, cpu, half, full, wall in rows:
            print(f"| {sampler} | {seed} | {n} | {cpu:.0f} | {half} | {full} | {wall:.0f} |")
        for sampler in ("tpe", "random"):
            mine = [r for r in rows if r[0] == sampler]
            print(f"| **{sampler} mean** | | {statistics.mean(r[2] for r in mine):.1f} | | "
                  f"{statistics.mean(r[4] for r in mine):.2f} | {statistics.mean(r[5] for r in mine):.2f} | |")
        print("\nfailure kinds (outcome/rule) found by: " +
              "; ".join(f"{k}: {', '.join(sorted(v))}" for k, v in sorted(rules.items())) if rules else
              "\nno failure found")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
