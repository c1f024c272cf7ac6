"""RQ2/RQ3 with a planner none of us wrote: a generated map's route-coverage suite driven by an
out-of-process planner through the planner bridge (CommonRoad's reactive planner by default)
and by the in-process baseline planner, side by side: outcomes, behaviour coverage (what the
planner did at each junction: its stage paths) and line coverage of each planner's own code.

  # M1 (feat2map generate --seed 1; feat2map suite map.json --traffic 6), resumable chunk by chunk
  SDL_VIDEODRIVER=offscreen nice -n 10 .venv/bin/python examples/planner_experiments.py --maps m1 --traffic 6
  .venv/bin/python examples/planner_experiments.py --maps m1 --report-only   # tables from what ran
  # SF (../shared/maps' Apollo San Francisco map): the manoeuvres of its first N junctions only
  SDL_VIDEODRIVER=offscreen nice -n 10 .venv/bin/python examples/planner_experiments.py --maps sf --sf-junctions 4
  # M2-M4 likewise (M4: generated from SF + GoMentum + Shalun's merged features, seed 4, as RQ3)
  # HC: the highway-and-city map (every mid-block, filter and ramp value, RQ4); --ramps-only for the
  # routes that merge from an on-ramp or diverge onto an off-ramp
  SDL_VIDEODRIVER=offscreen nice -n 10 .venv/bin/python examples/planner_experiments.py --maps hc --ramps-only

Writes out/planners/<map>/{map.json, suite.yaml, chunkN/ (rollout reports), <planner>/ (merged
report with its failure GIFs), tables.md}. Chunks make a long run (minutes per scenario for a
sampling planner on a shared machine) resumable: a chunk with a summary.json is not run again.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import feat2map  # noqa: E402
from feat2map.formats import native  # noqa: E402
from feat2map.messages import counted, one_line  # noqa: E402
from feat2map.scenarios.bridge import BridgePlanner  # noqa: E402
from feat2map.scenarios.metrics import compare, outcome_behaviour, suite_coverage  # noqa: E402
from feat2map.scenarios.report import load_result, write_report  # noqa: E402
from feat2map.scenarios.rollout import SuiteResult, run_suite, suite_digest  # noqa: E402
from feat2map.scenarios.routes import build_suite  # noqa: E402
from feat2map.scenarios.scenario import Suite, load_suite, save_suite  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEEDS = {"m1": 1, "m2": 2, "m3": 3, "m4": 4, "hc": 5}
SHARED = ROOT.parent / "shared" / "maps"  # ../shared/maps/SOURCES.md
SF_MAP = SHARED / "apollo" / "san_francisco" / "base_map.bin"
M4_MAPS = (SF_MAP, SHARED / "apollo" / "gomentum" / "base_map.bin", SHARED / "apollo" / "shalun" / "base_map.bin")
CR_CMD = f"{ROOT / '.venv-crplanner' / 'bin' / 'python'} {ROOT / 'adapters' / 'commonroad' / 'planner.py'}"


def sf_suite(traffic: int, junctions: int | None) -> Suite:
    """SF's route-coverage suite (as examples/experiments.py drives it): with `junctions`, only the
    manoeuvres of SF's first `junctions` junctions."""
    from feat2map.readers import read_map
    from feat2map.routes import DEFAULT_ROUTE_JUNCTIONS, coverage_routes, manoeuvres
    from feat2map.scenarios.routes import route_duration
    from feat2map.scenarios.scenario import Scenario

    m = read_map(SF_MAP)
    moves = manoeuvres(m)
    if junctions is not None:
        keep = set(list(m.junctions)[:junctions])
        moves = [mv for mv in moves if mv[0] in keep]
    routes = coverage_routes(m, DEFAULT_ROUTE_JUNCTIONS, moves)
    return Suite("sf", tuple(Scenario(name=f"sf-r{i:03d}", map=str(SF_MAP.resolve()), route=r, traffic_vehicles=traffic,
                                      seed=i, duration=route_duration(m, r)) for i, r in enumerate(routes)),
                 SF_MAP.resolve().parent)


def m4_space():
    """RQ3's feature space: SF, GoMentum and Shalun's junctions merged (as examples/experiments.py makes M4)."""
    from feat2map.extract import extract_junctions, map_feature
    from feat2map.readers import read_map

    missing = [str(p) for p in M4_MAPS if not p.is_file()]
    if missing:
        raise SystemExit(f"{', '.join(missing)}: not found (M4 comes from ../shared/maps, see SOURCES.md there)")
    return map_feature([j for p in M4_MAPS for j in extract_junctions(read_map(p), p.parent.name)])


def space_of(name: str):
    """The feature space map `name` is generated from."""
    from feat2map.features import HIGHWAY_CITY_FEATURE_SPACE

    return {"m4": m4_space, "hc": lambda: HIGHWAY_CITY_FEATURE_SPACE}.get(name, lambda: feat2map.PAPER_SF_FEATURE_SPACE)()


def ramp_scenarios(suite: Suite, m) -> Suite:
    """The scenarios of `suite` whose route takes a ramp's junction lane (a merge or a diverge)."""
    from feat2map.extract_ramps import ramp_moves
    from feat2map.routes import manoeuvre_lanes

    moves = ramp_moves(m)
    keep = tuple(sc for sc in suite.scenarios if any(ln.id in moves for mv in sc.route for ln in manoeuvre_lanes(m, mv)))
    return Suite(suite.name, keep, suite.base_dir)


def prepare(name: str, out: Path, traffic: int, chunk: int, sf_junctions: int | None = None,
            max_scenarios: int | None = None, ramps_only: bool = False) -> list[Path]:
    """The map, its suite and the suite's chunks (made once; with `ramps_only` the scenarios that
    take a ramp, `ramp_scenarios`; the first `max_scenarios` only)."""
    out.mkdir(parents=True, exist_ok=True)
    if name == "sf":
        if not SF_MAP.is_file():
            raise SystemExit(f"{SF_MAP}: not found (the SF map comes from ../shared/maps, see SOURCES.md there)")
        if not (out / "suite.yaml").exists():
            save_suite(sf_suite(traffic, sf_junctions), out / "suite.yaml")
    else:
        if not (out / "map.json").exists():
            native.save(feat2map.generate(space_of(name), seed=SEEDS[name]), out / "map.json")
        if not (out / "suite.yaml").exists():
            save_suite(build_suite(out / "map.json", traffic_vehicles=traffic, name=name), out / "suite.yaml")
    suite = load_suite(out / "suite.yaml")
    if ramps_only:
        suite = ramp_scenarios(suite, native.load(out / "map.json"))
    if max_scenarios is not None:
        suite = Suite(suite.name, suite.scenarios[:max_scenarios], suite.base_dir)
    paths = []
    for k in range(0, len(suite.scenarios), chunk):
        p = out / f"chunk{k // chunk}.yaml"
        if not p.exists():
            save_suite(Suite(name, suite.scenarios[k:k + chunk], suite.base_dir), p)
        paths.append(p)
    return paths


def run(planner_name: str, planner, chunks: list[Path], out: Path, workers: int) -> None:
    for p in chunks:
        dest = out / planner_name / p.stem
        if (dest / "summary.json").exists():
            continue
        result = run_suite(load_suite(p), planner, workers=workers, coverage=True, progress=sys.stderr.isatty())
        if result.stopped:  # Ctrl-C, SIGTERM or a planner's SystemExit: the chunk is not done (a rerun resumes at it)
            sys.exit(f"{planner_name} {p.stem}: stopped: {result.stopped}")
        write_report(result, dest)
        print(f"{planner_name} {p.stem}: {result.counts()} in {result.wall_s:.0f} s", flush=True)


def merge(planner_name: str, out: Path) -> SuiteResult | None:
    """One result of the chunks that ran (in suite order), its report and failure GIFs."""
    parts = sorted((out / planner_name).glob("chunk*/summary.json"), key=lambda p: int(p.parent.name[5:]))
    if not parts:
        return None
    results = [load_result(p.parent) for p in parts]
    outcomes = tuple(o for r in results for o in r.outcomes)
    merged = SuiteResult(name=results[0].name, planner=results[0].planner, outcomes=outcomes, coverage=True,
                         planner_digest=suite_digest(outcomes), wall_s=sum(r.wall_s for r in results))
    dest = out / f"{planner_name}-all"
    shutil.rmtree(dest, ignore_errors=True)  # derived from the chunks each time (it holds their GIFs too)
    write_report(merged, dest)
    (dest / "failures").mkdir(exist_ok=True)
    for p in parts:
        for gif in (p.parent / "failures").glob("*.gif"):
            shutil.copyfile(gif, dest / "failures" / gif.name)
    return merged


def tables(out: Path, results: dict[str, SuiteResult]) -> str:
    runs = ", ".join(f"{k} {counted(len(r.outcomes), 'scenario')}" for k, r in results.items())
    md = [f"### {out.name}: {runs}", "",
          compare(results).to_markdown()]
    md += ["#### line coverage of each planner's own code, accumulated in the order the suite reaches the junctions",
           "", "| planner | " + " | ".join(f"{i + 1}" for i in range(max(len(suite_coverage(r).junctions)
                                                                    for r in results.values()))) + " |",
           "|---|" + "---:|" * max(len(suite_coverage(r).junctions) for r in results.values())]
    for name, r in results.items():
        c = suite_coverage(r)
        md.append(f"| {name} | " + " | ".join(f"{j}: {n}" for j, n in zip(c.junctions, c.accumulated_lines)) + " |")
    md.append("")
    for name, r in results.items():
        md += [f"#### {name}: what it did at each junction", "",
               "| junction | scenarios through it | outcomes | stage paths there |", "|---|---:|---|---|"]
        per: dict[str, dict] = {}
        for o in r.outcomes:
            for j, (pairs, _) in outcome_behaviour(o).items():
                d = per.setdefault(j, {"n": 0, "out": {}, "paths": set()})
                d["n"] += 1
                d["out"][o.outcome] = d["out"].get(o.outcome, 0) + 1
                d["paths"] |= {" -> ".join(p) for _, p in pairs}
        for j in suite_coverage(r).junctions:
            d = per.get(j)
            if d:
                md.append(f"| {j} | {d['n']} | {', '.join(f'{k} {v}' for k, v in sorted(d['out'].items()))} | "
                          f"{'; '.join(sorted(d['paths']))} |")
        fails = [o for o in r.outcomes if o.outcome != "completed"]
        md += ["", f"#### {name}: every scenario that did not complete ({len(fails)})", "",
               "| scenario | outcome | what happened | stage path | GIF |", "|---|---|---|---|---|"]
        for o in fails:
            gif = out / f"{name}-all" / "failures" / f"{o.name}.gif"
            what = one_line(o.message.splitlines()[0] + (f" ... {o.message.splitlines()[-1]}"
                                                          if len(o.message.splitlines()) > 1 else ""))
            md.append(f"| {o.name} | {o.outcome} | {what} | {' -> '.join(o.stage_path[:12])}"
                      f"{' ...' if len(o.stage_path) > 12 else ''} | {gif.relative_to(out) if gif.exists() else '-'} |")
        md.append("")
    return "\n".join(md)


def all_lines(r: SuiteResult) -> set[str]:
    """Every line of the planner's own code the suite ran (all junctions and the road between)."""
    return {x for o in r.outcomes for ls in o.junction_lines.values() for x in ls}


def cross_table(per_map: dict[str, dict[str, SuiteResult]]) -> str:
    """RQ2/RQ3 across suites: outcomes and line coverage of each planner's own code, SF's next to
    the generated maps' (lines a generated map runs that SF does not, and the other way round)."""
    md = ["| suite | planner | scenarios | completed | timeout | collision | violation | off road | error "
          "| lines run | not run on SF | run on SF only | steps/s |", "|---|---|" + "---:|" * 11]
    for planner in ("baseline", "reactive"):
        sf = per_map.get("sf", {}).get(planner)
        sf_lines = all_lines(sf) if sf else None
        for name, results in per_map.items():
            r = results.get(planner)
            if r is None:
                continue
            c, lines = r.counts(), all_lines(r)
            steps, wall = sum(o.steps for o in r.outcomes), sum(o.wall_s for o in r.outcomes)
            extra = ("-", "-") if sf_lines is None or name == "sf" else (len(lines - sf_lines), len(sf_lines - lines))
            md.append(f"| {name.upper()} | {planner} | {len(r.outcomes)} | {c['completed']} | {c['timeout']} | "
                      f"{c['collision']} | {c['violation']} | {c['off_road']} | {c['error']} | {len(lines)} | "
                      f"{extra[0]} | {extra[1]} | {steps / wall if wall else 0:.1f} |")
    union = {p: set().union(*(all_lines(rs[p]) for rs in per_map.values() if p in rs)) for p in ("baseline", "reactive")}
    md += ["", "Lines run by all the suites together: " + ", ".join(f"{p} {len(v)}" for p, v in union.items()), ""]
    return "\n".join(md)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maps", nargs="+", default=["m1"], choices=sorted(SEEDS) + ["sf"])
    ap.add_argument("--sf-junctions", type=int, default=None,
                    help="SF: only the manoeuvres of its first N junctions (the suite is made once)")
    ap.add_argument("--max-scenarios", type=int, default=None, help="only the first N scenarios of each suite")
    ap.add_argument("--ramps-only", action="store_true", help="only the scenarios that merge from an on-ramp or "
                    "diverge onto an off-ramp (a generated map's)")
    ap.add_argument("--traffic", type=int, default=6)
    ap.add_argument("--chunk", type=int, default=6)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--planner-cmd", default=CR_CMD)
    ap.add_argument("--planner-name", default="reactive")
    ap.add_argument("--step-timeout", type=float, default=120.0)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "planners")
    ap.add_argument("--report-only", action="store_true", help="only merge what ran and write the tables")
    ap.add_argument("--no-baseline", action="store_true")
    args = ap.parse_args()
    per_map: dict[str, dict[str, SuiteResult]] = {}
    for name in args.maps:
        out = args.out / name
        chunks = prepare(name, out, args.traffic, args.chunk, args.sf_junctions, args.max_scenarios, args.ramps_only)
        if not args.report_only:
            if not args.no_baseline:
                run("baseline", "baseline", chunks, out, args.workers)
            run(args.planner_name, BridgePlanner(args.planner_cmd, step_timeout=args.step_timeout), chunks, out,
                args.workers)
        results = {k: r for k in ("baseline", args.planner_name) if (r := merge(k, out)) is not None}
        per_map[name] = results
        if results:
            text = tables(out, results)
            (out / "tables.md").write_text(text)
            print(text)
    if len(per_map) > 1:
        text = cross_table(per_map)
        (args.out / "cross.md").write_text(text)
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
