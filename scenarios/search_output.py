"""The output folder of `feat2map search`, staged and swapped in whole (feat2map/atomic.py):

- `regressions.yaml`: one scenario per failure signature (shrunk), a suite `feat2map rollout` runs;
- `maps/`: the maps those scenarios drive on (generated junctions, or the start's map);
- `openscenario/`: the same scenarios as OpenSCENARIO 1.3 with their OpenDRIVE maps;
- `failures/NAME.gif`: each one replayed from the written suite;
- `search.json`: every candidate (parameters, outcome, criticality, value), the findings and
  signatures found over the budget;
- `report.md` and `report.html` (scenarios/markup.py: names and messages as literal text, only the
  GIFs written here inlined, a strict Content-Security-Policy).

Every written scenario is replayed from `regressions.yaml` with the same planner: `replays` says
whether it fails with the same outcome (equal `Outcome`s: outcome, violations, steps, stage path,
criticality, ...), its GIF recorded on the way.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from feat2map import atomic
from feat2map.messages import counted

from .markup import html_page, md_code, md_fenced, md_text
from .rollout import Outcome
from .scenario import Suite, load_suite, save_suite
from .search import Evaluator, Finding, SearchResult
from .signature import signature_of

SEARCH_JSON = "search.json"  # marks a folder as an earlier `feat2map search` output
REGRESSIONS = "regressions.yaml"
REPORT_MD, REPORT_HTML = "report.md", "report.html"
MAPS, OPENSCENARIO, FAILURES = "maps", "openscenario", "failures"


@dataclass(frozen=True)
class Replay:
    """A finding written as a scenario and driven again from the written suite."""

    finding: Finding
    name: str
    outcome: Outcome
    replays: bool  # the replay's outcome equals the finding's (map path and name aside)
    gif: str  # the GIF's path in the folder ("" when none was recorded)


def same_outcome(a: Outcome, b: Outcome) -> bool:
    """Equal outcomes of one scenario written to two places (its map file's path and its name aside)."""
    return replace(a, name="", map="") == replace(b, name="", map="")


def scenario_name(k: int, f: Finding) -> str:
    """`sig-01-violation-stop_sign-straight`: the finding's index, outcome, rule and manoeuvre."""
    text = f"sig-{k:02d}-{f.signature.outcome}-{f.signature.rule}-{f.signature.manoeuvre}"
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)


def write_search(result: SearchResult, out: str | Path, evaluate: Evaluator) -> list[Replay]:
    """Write the search's folder (module docstring) atomically; replays every finding from the
    written suite with `evaluate` (the planner the search drove) and returns the replays."""
    out = Path(out)
    with atomic.staged_dir(out, (SEARCH_JSON,)) as staged:
        tmp = staged.resolve()  # the suite's map paths are made relative to it: never to the working directory
        replays: list[Replay] = []
        if result.findings:
            maps: dict[str, str] = {}
            scenarios = []
            for k, f in enumerate(result.findings, 1):
                src = Path(f.scenario.map)
                if str(src) not in maps:
                    rel = f"{MAPS}/{src.name}"
                    (tmp / MAPS).mkdir(exist_ok=True)
                    atomic.write_bytes(tmp / rel, src.read_bytes())
                    maps[str(src)] = rel
                scenarios.append(replace(f.scenario, name=scenario_name(k, f), map=str(tmp / maps[str(src)])))
            save_suite(Suite("search-regressions", tuple(scenarios), tmp), tmp / REGRESSIONS)
            suite = load_suite(tmp / REGRESSIONS)  # what a user runs: the written file
            outcomes = evaluate(suite.scenarios, gifs=True)
            for f, sc, o in zip(result.findings, suite.scenarios, outcomes):
                gif = ""
                if o.gif:
                    gif = f"{FAILURES}/{sc.name}.gif"
                    atomic.write_bytes(tmp / gif, o.gif)
                replays.append(Replay(f, sc.name, o, same_outcome(o, f.outcome) and signature_of(o) == f.signature,
                                      gif))
            from feat2map.formats.openscenario import write_openscenario

            write_openscenario(suite, tmp / OPENSCENARIO)
        doc = result.to_dict()
        for d, r in zip(doc["findings"], replays):
            d.update(name=r.name, replays=r.replays, replay_outcome=r.outcome.outcome, gif=r.gif)
        atomic.write_text(tmp / SEARCH_JSON, json.dumps(doc, indent=1) + "\n")
        text = report_markdown(result, replays)
        atomic.write_text(tmp / REPORT_MD, text)
        pictures = {r.gif for r in replays if r.gif}  # what this search wrote, nothing else
        atomic.write_text(tmp / REPORT_HTML, html_page(text, tmp, f"Search report: {result.planner}", pictures))
    return replays


def _number(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def report_markdown(result: SearchResult, replays: list[Replay]) -> str:
    """The search report: what was searched, signatures over the budget, one section per signature."""
    fails = sum(t.signature is not None for t in result.trials)
    lines = [f"# Search report: {md_text(result.planner)}", "",
             f"Start: {md_text(result.start.label)}. Sampler {md_code(result.sampler)}, seed {result.seed}, "
             f"{counted(len(result.trials), 'scenario')} driven in {result.cpu_s:.0f} CPU s "
             f"({counted(result.infeasible, 'candidate')} not buildable); {fails} failed, "
             f"**{counted(len(result.findings), 'distinct failure signature')}**"
             f"{'; stopped early: ' + md_text(result.stopped) if result.stopped else ''}.", "",
             "Replay the regression suite with `feat2map rollout regressions.yaml --planner ...` (the same planner); "
             "`openscenario/` holds the same scenarios as OpenSCENARIO.", "",
             "## Signatures found over the budget", "", "| CPU s | scenarios | distinct signatures |",
             "|---:|---:|---:|", *(f"| {c:.0f} | {n} | {k} |" for c, n, k in result.history), ""]
    if not replays:
        lines += ["No failure found within the budget.", ""]
    for r in replays:
        f, s = r.finding, r.finding.signature
        orig, shrunk = f.trial.scenario, f.scenario
        lines += [f"## {md_text(r.name)}", "",
                  "| outcome | rule | junction | manoeuvre | stage path in the junction | finds | replays |",
                  "|---|---|---|---|---|---:|---|",
                  f"| {md_text(s.outcome)} | {md_text(s.rule)} | {md_text(s.junction)} | {md_text(s.manoeuvre)} | "
                  f"{md_text(' → '.join(s.stage_path) or '-')} | {f.finds} | "
                  f"{'yes' if r.replays else '**no** (' + md_text(r.outcome.outcome) + ')'} |", "",
                  *md_fenced(r.outcome.message or f.outcome.message), "",
                  "Criticality of the scenario that found it (trial " + str(f.trial.number) + "): " +
                  ", ".join(f"{md_text(k)} {_number(v)}" for k, v in f.trial.outcome.criticality.items()) + ".", "",
                  f"Shrunk from {orig.traffic_vehicles} to {shrunk.traffic_vehicles} vehicles, pedestrians "
                  f"{orig.pedestrian_rate:g} to {shrunk.pedestrian_rate:g} per minute, route {len(orig.route)} to "
                  f"{counted(len(shrunk.route), 'manoeuvre')}: {md_text(' → '.join('/'.join(mv) for mv in shrunk.route))}.", "",
                  "| parameter that found it | value |", "|---|---|",
                  *(f"| {md_text(k)} | {md_text(_number(v))} |" for k, v in sorted(f.trial.params.items())), ""]
        if r.gif:
            lines += [f"![GIF of the replay]({r.gif})", ""]
    return "\n".join(lines)
