"""The scenario commands of the `feat2map` CLI: `suite` (a route-coverage suite for a map),
`rollout` (run a suite headless, write summary/JUnit/report; exit 1 on failures by policy),
`search` (search maps and traffic for a planner's failures, write them as regression scenarios),
`replay` (a recorded planner-bridge session against a planner) and `coverage` (compare suites'
results side by side). Hooked into `feat2map.cli` by
`add_scenario_commands`.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import warnings
from pathlib import Path

from . import atomic
from .config import BLOCKED_AFTER_S
from .errors import Feat2MapError
from .messages import counted, on_terminal, one_line

COVERAGE_MARKERS = ("coverage.json",)  # a folder holding one is an earlier `coverage` output, replaced whole


def cmd_suite(args: argparse.Namespace) -> int:
    from .extract import extract_junctions
    from .formats import read_map
    from .scenarios.routes import build_suite, manoeuvres, route_coverage
    from .scenarios.scenario import check_suite_path, save_suite

    path = Path(args.map)
    if not path.is_file():
        raise Feat2MapError("map file not found", str(path))
    atomic.check_file_target(args.out)
    check_suite_path(args.out)
    if args.max_junctions < 1:
        raise Feat2MapError("--max-junctions must be at least 1", "command line")
    kw = {"seed": args.seed, "traffic_vehicles": args.traffic, "pedestrian_rate": args.pedestrian_rate,
          "max_junctions": args.max_junctions, "duration": args.duration, "name": args.name}
    suite = build_suite(path, **kw)
    save_suite(suite, args.out)
    m = read_map(path)
    cov = route_coverage(m, [s.route for s in suite.scenarios])
    with warnings.catch_warnings():  # the load and extract already said what they skip
        warnings.simplefilter("ignore")
        features = len(extract_junctions(m, str(path)))
    # manoeuvres are driven through every junction area of the map; `extract` counts only those
    # with 3 or more arms (a bend or a merge drawn as a junction is no junction feature)
    print(f"wrote {args.out}: {counted(len(suite.scenarios), 'scenario')} covering {100 * cov:.1f}% of "
          f"{counted(len(manoeuvres(m)), 'manoeuvre')} at {counted(len(m.junctions), 'map junction')} "
          f"({features} with 3 or more arms, as `extract` counts)")
    return 0


def cmd_rollout(args: argparse.Namespace) -> int:
    from .scenarios.report import SUMMARY, write_report
    from .scenarios.rollout import check_blocked_after, run_suite
    from .scenarios.scenario import load_suite

    if args.workers < 1:
        raise Feat2MapError("--workers must be at least 1", "command line")
    check_blocked_after(args.blocked_after, "--blocked-after")
    atomic.check_dir_target(args.out, (SUMMARY,))  # before the run, not after it
    suite = load_suite(args.suite)
    if args.record:
        if args.planner_cmd is None:
            raise Feat2MapError("--record needs --planner-cmd (it records the planner bridge's messages)",
                                "command line")
        from .scenarios.bridge_record import MESSAGES, recording_folder

        for s in suite.scenarios:  # each recording replaces only an earlier one
            atomic.check_dir_target(recording_folder(args.record, s.name), (MESSAGES,))
    factory = _planner_factory(args, record=str(Path(args.record).resolve()) if args.record else None)
    bar = not args.quiet and on_terminal()  # off a terminal: one line per finished scenario instead
    result = run_suite(suite, factory, workers=args.workers, backend=args.backend, progress=bar,
                       coverage=args.line_coverage, record_failure_gif=not args.no_gif, fail_on=args.fail_on,
                       blocked_after=args.blocked_after,
                       log=None if args.quiet or bar else functools.partial(print, flush=True))
    write_report(result, args.out, fail_on=args.fail_on)
    counts = ", ".join(f"{n} {k}" for k, n in result.counts().items() if n)
    failing = result.failures(args.fail_on)
    print(f"{result.name}: {counted(len(result.outcomes), 'scenario')} ({counts}) in {result.wall_s:.1f} s; "
          f"{len(failing)} failing under --fail-on {args.fail_on}; report {Path(args.out) / 'report.md'}")
    for o in failing:
        print(f"  FAIL {one_line(f'{o.name}: {o.outcome}: {o.message}')}")
    if result.stopped:
        print(f"  STOPPED after {len(result.outcomes)} of {counted(result.scenarios or 0, 'scenario')}: "
              f"{one_line(result.stopped)}")
    return result.exit_code(args.fail_on)


def cmd_replay(args: argparse.Namespace) -> int:
    from .scenarios.bridge_record import replay

    if not args.planner_cmd.strip():
        raise Feat2MapError("--planner-cmd is empty", "command line")
    if not args.planner_timeout > 0 or not args.tolerance >= 0:
        raise Feat2MapError("--planner-timeout must be positive and --tolerance at least 0", "command line")
    result = replay(args.recording, args.planner_cmd, tolerance=args.tolerance, step_timeout=args.planner_timeout)
    print(f"{args.recording}: replayed {counted(result.messages, 'message')}; "
          f"{counted(len(result.differences), 'difference')}")
    if result.differences:
        print(f"  first difference: {one_line(result.differences[0])}")
        for d in result.differences[1:]:
            print(f"  {one_line(d)}")
    return 1 if result.differences else 0


def cmd_coverage(args: argparse.Namespace) -> int:
    from .scenarios.markup import md_text
    from .scenarios.metrics import compare, plot_accumulated
    from .scenarios.report import load_result

    if args.names and len(args.names) != len(args.results):
        raise Feat2MapError(f"--names gives {len(args.names)} names for {len(args.results)} result dirs",
                            "command line")
    out = atomic.check_dir_target(args.out, COVERAGE_MARKERS)
    names = args.names or _dir_names(args.results)
    results = {n: load_result(d) for n, d in zip(names, args.results)}
    table = compare(results)
    unmeasured = [f"{n} ({d})" for n, d, r in zip(names, args.results, results.values()) if not r.coverage]
    note = (f"note: no planner line coverage for {', '.join(unmeasured)}: run without --line-coverage, so their "
            f"line columns are '-'; rerun them as `feat2map rollout SUITE --line-coverage --out DIR`" if unmeasured else "")
    with atomic.staged_dir(out, COVERAGE_MARKERS) as tmp:
        plot_accumulated(table, tmp / "coverage.png", title="accumulated coverage by junction")
        md = ["# Coverage comparison", "", *([md_text(note), ""] if note else []), table.to_markdown(),
              "![accumulated coverage](coverage.png)", ""]
        for name, c in zip(table.names, table.coverages):
            md += [f"## {md_text(name)}", "", "| junction index | junction | accumulated lines | accumulated transitions |",
                   "|---:|---|---:|---:|"]
            acc_l = c.accumulated_lines if c.lines else ("-",) * len(c.junctions)
            for i, (j, l, t) in enumerate(zip(c.junctions, acc_l, c.accumulated_transitions)):
                md.append(f"| {i + 1} | {md_text(j)} | {l} | {t} |")
            md.append("")
        atomic.write_text(tmp / "coverage.md", "\n".join(md))
        atomic.write_text(tmp / "coverage.json", json.dumps(table.to_dict(), indent=1) + "\n")
    print(table.to_markdown(), end="")
    if note:
        print(one_line(note, limit=2000))
    print(f"wrote {Path(args.out) / 'coverage.md'} and {Path(args.out) / 'coverage.png'}")
    return 0


def cmd_search(args: argparse.Namespace) -> int:
    import tempfile

    from .scenarios.rollout import check_blocked_after
    from .scenarios.search import check_budget, evaluator, make_study, search
    from .scenarios.search_output import SEARCH_JSON, write_search
    from .scenarios.search_space import start_from

    check_budget(args.budget_seconds, args.budget_scenarios)
    if args.workers < 1:
        raise Feat2MapError("--workers must be at least 1", "command line")
    if args.batch < 1:
        raise Feat2MapError("--batch must be at least 1", "command line")
    check_blocked_after(args.blocked_after, "--blocked-after")
    make_study(args.sampler, args.seed)  # Optuna there, the sampler and seed valid: before any work
    atomic.check_dir_target(args.out, (SEARCH_JSON,))
    factory = _planner_factory(args)
    bar = not args.quiet and on_terminal()
    log = None if args.quiet or bar else functools.partial(print, flush=True)
    with tempfile.TemporaryDirectory(prefix="feat2map-search-") as work, \
            evaluator(factory, workers=args.workers, backend=args.backend, blocked_after=args.blocked_after) as ev:
        start = start_from(features=args.features, spec=args.spec, map_file=args.map, workdir=Path(work))
        result = search(start, ev, workdir=Path(work), budget_seconds=args.budget_seconds,
                        budget_scenarios=args.budget_scenarios, seed=args.seed, sampler=args.sampler, batch=args.batch,
                        fail_on=args.fail_on, shrink_failures=not args.no_shrink, log=log, progress=bar)
        replays = write_search(result, args.out, ev)
    print(f"search ({result.sampler}, seed {result.seed}) of {start.label} with {result.planner}: "
          f"{counted(len(result.trials), 'scenario')} in {result.cpu_s:.0f} CPU s; "
          f"{counted(len(result.findings), 'distinct failure signature')}; report {Path(args.out) / 'report.md'}")
    for r in replays:
        print(f"  {one_line(f'{r.name}: {r.finding.signature.key}')}{'' if r.replays else ' (DOES NOT REPLAY)'}")
    if result.stopped:
        print(f"  STOPPED: {one_line(result.stopped)}")
    return 1 if replays else 0


def _planner_factory(args: argparse.Namespace, record: str | None = None):
    """The planner of `rollout` and `search`: --planner (in this process's workers) or --planner-cmd
    (its own process, through the planner bridge, its sessions kept in `record`), built once here
    to fail early."""
    from .scenarios.rollout import PlannerFactory

    if os.getcwd() not in sys.path:  # --planner mypkg.mod:Planner from the working directory
        sys.path.append(os.getcwd())  # (spawned workers inherit sys.path)
    if args.planner_cmd is not None:
        if args.planner != "baseline":
            raise Feat2MapError("give --planner or --planner-cmd, not both", "command line")
        if not args.planner_cmd.strip():
            raise Feat2MapError("--planner-cmd is empty", "command line")
        if not args.planner_timeout > 0:
            raise Feat2MapError("--planner-timeout must be positive", "command line")
        from .scenarios.bridge import BridgePlanner

        factory = PlannerFactory(BridgePlanner(args.planner_cmd, step_timeout=args.planner_timeout, record=record))
    else:
        factory = PlannerFactory(args.planner)
    factory()  # fail early, in this process, on a planner that cannot be imported or built
    return factory


def _dir_names(dirs: list[str]) -> list[str]:
    names = [Path(d).resolve().name or str(d) for d in dirs]
    if len(set(names)) < len(names):
        names = [str(d) for d in dirs]
    return names


def add_scenario_commands(sub: argparse._SubParsersAction) -> None:
    """Add `suite`, `rollout`, `search`, `replay` and `coverage` to the `feat2map` subcommands."""
    from .config import SEARCH_BATCH
    from .scenarios.bridge_record import REPLAY_TOLERANCE
    from .scenarios.rollout import BACKENDS, FAIL_POLICIES
    from .scenarios.search import SAMPLERS

    s = sub.add_parser("suite", help="build a route-coverage scenario suite for a map",
                       description="Write a scenario suite whose routes drive every (junction, entry, exit) "
                                   "manoeuvre of a map at least once, with few routes (format: scenarios/README.md).")
    s.add_argument("map", help="map file (feat2map .json, OpenDRIVE .xodr, Apollo)")
    s.add_argument("--out", required=True, metavar="FILE", help="suite file to write (.yaml or .json)")
    s.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the first scenario (then +1 each)")
    s.add_argument("--traffic", type=int, default=0, metavar="N", help="traffic vehicles per scenario")
    s.add_argument("--pedestrian-rate", type=float, default=0.0, metavar="RATE", help="pedestrians per crosswalk per minute")
    s.add_argument("--max-junctions", type=int, default=4, metavar="N", help="longest route (junctions)")
    s.add_argument("--duration", type=float, metavar="S", help="scenario duration [s] (default: from the route length)")
    s.add_argument("--name", help="suite name, the prefix of its scenarios' names (default: the map file's stem)")
    s.set_defaults(func=cmd_suite)

    r = sub.add_parser("rollout", help="run a scenario suite headless and write a report",
                       description="Drive every scenario of a suite headless with a planner and write DIR/report.md and "
                                   "report.html (one self-contained page), summary.json, junit.xml, plots and a GIF per "
                                   "scenario that did not complete (failures/), whatever --fail-on says; exit 1 when a "
                                   "scenario fails under --fail-on. Planner line coverage only with --line-coverage.")
    r.add_argument("suite", help="suite file (.yaml or .json)")
    r.add_argument("--planner", default="baseline", metavar="PLANNER",
                   help="'baseline' or module:attr (a Policy class/instance, a callable obs -> action or "
                        "(obs, info) -> action, told apart by its signature, an SB3 model); a planner raising "
                        "SystemExit/KeyboardInterrupt ends the run with the report of the scenarios so far")
    r.add_argument("--planner-cmd", metavar="CMD", help="run a planner in its own process that speaks the planner "
                   "bridge protocol over stdin/stdout (docs/planners.md), e.g. \"python examples/bridge_planner.py\"; "
                   "a crash, a missed deadline or garbage is an error outcome with its stderr in the report")
    r.add_argument("--planner-timeout", type=float, default=10.0, metavar="S",
                   help="with --planner-cmd: seconds the planner has for each step reply (default 10)")
    r.add_argument("--blocked-after", type=float, default=BLOCKED_AFTER_S, metavar="S",
                   help="end a scenario early as a timeout ('blocked: ...') once the ego has stood still S seconds of "
                        "simulated time with nothing in its way: no red or amber signal at its next stop line, no "
                        "stop-sign turn, conflicting traffic, pedestrian or road user close ahead (such waits do not "
                        f"count; moving resets); 0: never (default {BLOCKED_AFTER_S:g})")
    r.add_argument("--workers", type=int, default=1, metavar="N", help="scenarios driven in parallel")
    r.add_argument("--backend", choices=BACKENDS, default="process",
                   help="where the workers run: local processes, or a Ray cluster (needs the ray extra)")
    r.add_argument("--out", required=True, metavar="DIR", help="report folder, built whole and swapped in; an "
                   "existing folder is replaced as a whole if it is an earlier report (holds summary.json), else "
                   "refused (checked before the run)")
    r.add_argument("--fail-on", choices=tuple(FAIL_POLICIES), default="any",
                   help="outcomes that fail the run (exit 1): any non-completed; collision (+ off road, errors); "
                        "violation (+ collision, off road, errors); none")
    cov = r.add_mutually_exclusive_group()
    cov.add_argument("--line-coverage", action="store_true",
                     help="also measure the planner's line coverage per junction (coverage.py; for `feat2map coverage` "
                          "and the report's line tables; the rollout takes longer); off by default")
    cov.add_argument("--no-coverage", dest="line_coverage", action="store_false",
                     help="no line coverage (the default; kept for older command lines)")
    r.add_argument("--no-gif", action="store_true", help="do not re-run scenarios that did not complete to record "
                   "their GIFs (by default each one gets failures/NAME.gif, whatever --fail-on says)")
    r.add_argument("--record", metavar="DIR", help="with --planner-cmd: keep each scenario's bridge session in "
                   "DIR/SCENARIO (every message both ways with its wall time, and the map file the planner got) "
                   "for `feat2map replay`")
    r.add_argument("--quiet", action="store_true", help="no progress bar (off a terminal: no line per scenario)")
    r.set_defaults(func=cmd_rollout)

    p = sub.add_parser("replay", help="replay a recorded planner-bridge session against a planner",
                       description="Send the messages a rollout recorded (`feat2map rollout --planner-cmd CMD --record "
                                   "DIR`) to a planner, without the env, and report where its replies differ from the "
                                   "recorded ones (type, step, stage, control values and trajectory points within "
                                   "--tolerance); exit 1 when any does.")
    p.add_argument("recording", help="a scenario's recording folder (DIR/SCENARIO)")
    p.add_argument("--planner-cmd", required=True, metavar="CMD", help="the planner command to replay against")
    p.add_argument("--planner-timeout", type=float, default=10.0, metavar="S",
                   help="seconds the planner has for each step reply (default 10)")
    p.add_argument("--tolerance", type=float, default=REPLAY_TOLERANCE, metavar="X",
                   help=f"replies' numbers equal within this (default {REPLAY_TOLERANCE:g})")
    p.set_defaults(func=cmd_replay)

    q = sub.add_parser("search", help="search maps and traffic together for a planner's failures",
                       description="Search one space joining the junction (legs, angles within the feature space's "
                                   "ranges, control, crosswalk, lanes, a one-way leg; generated on the fly), traffic and "
                                   "pedestrians (count, speeds, the signal plan) and the ego (manoeuvre, start, seeds) "
                                   "for the planner's failures, guided by failures and criticality (time-to-collision, "
                                   "distance, braking, time blocked) with Optuna's TPE sampler (docs/search.md). Each "
                                   "distinct failure signature is shrunk and written to DIR/regressions.yaml (and "
                                   "OpenSCENARIO), replayed, and shown in DIR/report.html with its GIF; exit 1 when a "
                                   "failure is found. Needs the search extra (pip install 'feat2map[search]').")
    start = q.add_mutually_exclusive_group()
    start.add_argument("--features", metavar="FILE", help="feature-space JSON to generate junctions from (default: the "
                       "paper's San Francisco feature space)")
    start.add_argument("--spec", metavar="FILE", help="a map spec (YAML/JSON): its map is built once and its routes searched")
    start.add_argument("--map", metavar="FILE", help="a map file (feat2map .json, OpenDRIVE, Apollo): its routes searched")
    q.add_argument("--budget-seconds", type=float, metavar="S", help="CPU seconds to spend on candidates (the workers' "
                   "and this process's; checked after each batch)")
    q.add_argument("--budget-scenarios", type=int, metavar="N", help="candidate scenarios to drive")
    q.add_argument("--seed", type=int, default=0, metavar="N", help="the sampler's seed: the same seed and scenario "
                   "budget give the same candidates and findings, whatever --workers")
    q.add_argument("--sampler", choices=SAMPLERS, default="tpe", help="tpe (Optuna's TPE) or random (the baseline)")
    q.add_argument("--batch", type=int, default=SEARCH_BATCH, metavar="N", help="candidates asked and driven at once")
    q.add_argument("--planner", default="baseline", metavar="PLANNER", help="as rollout's --planner")
    q.add_argument("--planner-cmd", metavar="CMD", help="as rollout's --planner-cmd: a planner in its own process "
                   "through the planner bridge")
    q.add_argument("--planner-timeout", type=float, default=10.0, metavar="S",
                   help="with --planner-cmd: seconds the planner has for each step reply")
    q.add_argument("--blocked-after", type=float, default=BLOCKED_AFTER_S, metavar="S", help="as rollout's")
    q.add_argument("--fail-on", choices=tuple(FAIL_POLICIES), default="any", help="outcomes that count as failures")
    q.add_argument("--workers", type=int, default=1, metavar="N", help="candidates driven in parallel")
    q.add_argument("--backend", choices=BACKENDS, default="process", help="local processes or Ray (the ray extra)")
    q.add_argument("--no-shrink", action="store_true", help="write each failure as found, not shrunk")
    q.add_argument("--out", required=True, metavar="DIR", help="output folder, built whole and swapped in; an existing "
                   "folder is replaced only if it is an earlier search output (holds search.json)")
    q.add_argument("--quiet", action="store_true", help="no progress bar (off a terminal: no line per batch)")
    q.set_defaults(func=cmd_search)

    c = sub.add_parser("coverage", help="compare suites' rollout results side by side",
                       description="Put rollout results side by side: behaviour coverage (the planner's stage "
                                   "paths and transitions) and planner line coverage, per junction and "
                                   "accumulated in the order the suites reach the junctions. Line coverage is there "
                                   "only for rollouts run with `feat2map rollout --line-coverage` (else '-', and a "
                                   "note says which).")
    c.add_argument("results", nargs="+", metavar="RESULT_DIR", help="rollout output directories")
    c.add_argument("--out", required=True, metavar="DIR", help="directory for coverage.md, coverage.png, coverage.json")
    c.add_argument("--names", nargs="+", metavar="NAME", help="a name per result dir (default: the directory names)")
    c.set_defaults(func=cmd_coverage)
