"""Rollout reports: OUT/summary.json (the SuiteResult, loads back with `load_result`),
OUT/junit.xml (one testcase per scenario, for CI systems), OUT/report.md (tables, plots, one
GIF per scenario that did not complete under OUT/failures/, whatever the failure policy, the stage
codes explained), OUT/report.html (the same as one self-contained page, pictures inline),
OUT/outcomes.png and OUT/coverage.png. The directory is staged and moved into place whole. Names,
messages and planner stderr enter the Markdown as literal text (`markup`), never as markup.
"""
from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Collection

from feat2map import atomic
from feat2map.documents import load_document
from feat2map.errors import Feat2MapError
from feat2map.messages import counted

from .bridge import BRIDGE_NAME_PREFIX
from .markup import html_page, md_code, md_fenced, md_text
from .metrics import FULL_COVERAGE_SHARE, compare, junctions_to_reach, plot_accumulated, suite_coverage
from .rollout import FAIL_POLICIES, MIXED_DIGEST, OUTCOMES, ROAD_CONTEXT, Outcome, SuiteResult

SUMMARY = "summary.json"
JUNIT = "junit.xml"
REPORT = "report.md"
REPORT_HTML = "report.html"  # the same, one self-contained page (pictures inline)
FAILURES = "failures"
OUTCOMES_PNG = "outcomes.png"
COVERAGE_PNG = "coverage.png"
OUTCOME_COLOURS = {"completed": "#4caf50", "collision": "#d32f2f", "off_road": "#ff9800",
                   "timeout": "#9e9e9e", "violation": "#7b1fa2", "error": "#000000"}


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "scenario"


def junit_xml(result: SuiteResult, fail_on: str = "any") -> bytes:
    """JUnit XML: one testcase per scenario; outcomes failing under `fail_on` are <failure>s
    (planner/env exceptions are <error>s), the others pass with their outcome in system-out."""
    failing = FAIL_POLICIES[fail_on]
    fails = sum(o.outcome in failing and o.outcome != "error" for o in result.outcomes)
    errors = sum(o.outcome in failing and o.outcome == "error" for o in result.outcomes)
    root = ET.Element("testsuites", name="feat2map rollout", tests=str(len(result.outcomes)),
                      failures=str(fails), errors=str(errors), time=f"{result.wall_s:.3f}")
    suite = ET.SubElement(root, "testsuite", name=result.name, tests=str(len(result.outcomes)),
                          failures=str(fails), errors=str(errors), skipped="0", time=f"{result.wall_s:.3f}")
    props = ET.SubElement(suite, "properties")
    for k, v in (("planner", result.planner), ("fail_on", fail_on), ("workers", result.workers),
                 ("backend", result.backend), ("stopped", result.stopped)):
        ET.SubElement(props, "property", name=k, value=str(v))
    for o in result.outcomes:
        case = ET.SubElement(suite, "testcase", classname=f"{result.name}", name=o.name, time=f"{o.wall_s:.3f}")
        if o.outcome in failing:
            tag = "error" if o.outcome == "error" else "failure"
            el = ET.SubElement(case, tag, message=f"{o.outcome}: {o.message}", type=o.outcome)
            el.text = _details(o)
        out = ET.SubElement(case, "system-out")
        out.text = f"outcome: {o.outcome}\n" + _details(o)
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def _details(o: Outcome) -> str:
    v = ", ".join(f"{k}={n}" for k, n in o.violations.items())
    return (f"map: {o.map}\nseed: {o.seed}\nsimulated: {o.sim_s:.1f} s in {o.steps} steps\n"
            f"route progress: {100 * o.route_progress:.0f}%\nviolations: {v or 'none'}\n"
            f"junctions: {' -> '.join(o.junctions) or '-'}\nstage path: {' -> '.join(o.stage_path) or '-'}\n"
            f"last stage: {o.stage_path[-1] if o.stage_path else '-'}\n")


TICK_LABEL_CHARS = 32


def _tick_label(name: str) -> str:
    """`name` as a tick label: its first TICK_LABEL_CHARS characters on one line ("…" where cut)."""
    one_line = " ".join(name.split())
    return one_line if len(one_line) <= TICK_LABEL_CHARS else one_line[:TICK_LABEL_CHARS - 1] + "…"


def _plot_outcomes(result: SuiteResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = result.counts()
    kinds = [k for k in OUTCOMES if counts[k] or k in ("completed",)]
    fig, (ax_c, ax_s) = plt.subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [1, 2.2]})
    ax_c.bar(kinds, [counts[k] for k in kinds], color=[OUTCOME_COLOURS[k] for k in kinds])
    ax_c.set(title=f"{result.name}: outcomes", ylabel="scenarios")
    ax_c.tick_params(axis="x", labelrotation=30)
    xs = range(len(result.outcomes))
    ax_s.bar(xs, [o.sim_s for o in result.outcomes], color=[OUTCOME_COLOURS[o.outcome] for o in result.outcomes])
    ax_s.set(title="simulated duration per scenario (colour = outcome)", xlabel="scenario", ylabel="s")
    if len(result.outcomes) <= 60:  # name the scenarios, else index them
        # a long name would take the whole figure's height (tight_layout gives up): cut it short
        ax_s.set_xticks(list(xs), [_tick_label(o.name) for o in result.outcomes], rotation=90, fontsize=7)
    else:
        ax_s.set_xlabel("scenario index (suite order)")
    ax_s.grid(axis="y", alpha=0.3)
    from matplotlib.patches import Patch

    present = [k for k in OUTCOMES if any(o.outcome == k for o in result.outcomes)]
    if present:
        ax_s.legend(handles=[Patch(color=OUTCOME_COLOURS[k], label=k) for k in present], title="outcome",
                    fontsize=8, title_fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _short_stage_names(transitions) -> dict[str, str]:
    """"Scenario.Stage" -> "Stage" where no other scenario has a stage of that name."""
    names = {n for t in transitions for n in t}
    owners: dict[str, set[str]] = {}
    for n in names:
        sc, _, st = n.rpartition(".")
        owners.setdefault(st, set()).add(sc)
    return {n: (n.rpartition(".")[2] if len(owners[n.rpartition(".")[2]]) == 1 else n) for n in names}


def report_markdown(result: SuiteResult, fail_on: str = "any", gifs: dict[str, str] | None = None) -> str:
    """The Markdown report: summary, per-scenario table, failures with GIFs, coverage tables."""
    gifs = gifs or {}
    counts = result.counts()
    failing = result.failures(fail_on)
    cov = suite_coverage(result)
    road = ROAD_CONTEXT in cov.pairs or ROAD_CONTEXT in cov.transitions  # a first row: driving between junctions
    rows = ((ROAD_CONTEXT,) if road else ()) + cov.junctions
    cov_acc_pairs = ((len(cov.pairs.get(ROAD_CONTEXT, ())),) if road else ()) + cov.accumulated_pairs
    cov_acc_trans = ((len(cov.transitions.get(ROAD_CONTEXT, ())),) if road else ()) + cov.accumulated_transitions
    sum_pairs = sum(len(cov.pairs.get(j, ())) for j in rows)
    verdict = "FAILED" if failing or result.stopped else "passed"
    ran = len(result.outcomes)
    lines = [f"# Rollout report: {md_text(result.name)}", "",
             f"Planner {md_code(result.planner)}, {counted(ran, 'scenario')}, failure policy `--fail-on {fail_on}`: "
             f"**{verdict}** ({len(failing)} failing). Wall time {result.wall_s:.1f} s on "
             f"{counted(result.workers, 'worker')}, backend {md_text(result.backend)}.", "",
             *([f"**Stopped early**: {md_text(result.stopped)}; {ran} of "
                f"{counted(ran if result.scenarios is None else result.scenarios, 'scenario')} ran.", ""]
               if result.stopped else []),
             "| " + " | ".join(OUTCOMES) + " |", "|" + "---:|" * len(OUTCOMES),
             "| " + " | ".join(str(counts[k]) for k in OUTCOMES) + " |", "", f"![outcomes]({OUTCOMES_PNG})", "",
             "## Scenarios", "", "Stage codes (`LF`, `T_A`, ...) are explained under *Stage codes* at the end.", "",
             "| scenario | outcome | simulated s | steps | route | violations | junctions | stage path |",
             "|---|---|---:|---:|---:|---|---|---|"]
    for o in result.outcomes:
        v = ", ".join(f"{k} {n}" for k, n in o.violations.items() if n) or "-"
        mark = f"**{md_text(o.outcome)}**" if o.fails(fail_on) else md_text(o.outcome)  # a summary read back may hold anything
        lines.append(f"| {md_text(o.name)} | {mark} | {o.sim_s:.1f} | {o.steps} | {100 * o.route_progress:.0f}% | "
                     f"{md_text(v)} | {md_text(' '.join(o.junctions) or '-')} | {md_text(' → '.join(o.stage_path) or '-')} |")
    not_completed = [o for o in result.outcomes if not o.passed]
    if not_completed:
        lines += ["", "## Failures", "", f"Every scenario that did not complete; those marked *passes* do not fail "
                  f"the run under `--fail-on {fail_on}`.", ""]
        for o in not_completed:
            verdict_o = "" if o.fails(fail_on) else " (*passes*)"
            lines += [f"### {md_text(o.name)}: {md_text(o.outcome)}{verdict_o}", "", *md_fenced(o.message), "",
                      *md_fenced(_details(o).rstrip()), ""]
            if o.planner_stderr and o.planner_stderr not in o.message:  # an error's message quotes it already
                lines += ["The planner's stderr (its end):", "", *md_fenced(o.planner_stderr), ""]
            elif not o.planner_stderr and _out_of_process(result) and "planner stderr" not in o.message:
                lines += ["The planner's stderr was empty.", ""]
            if o.name in gifs:
                lines += [f"![GIF of the scenario]({gifs[o.name]})", ""]
    lines += ["", "## Behaviour coverage", "",
              f"The planner made {counted(len(cov.all_pairs), 'distinct (planner scenario, stage path) pair')} and "
              f"{counted(len(cov.all_transitions), 'distinct stage transition')}; the suite drove "
              f"{counted(len({p for _, p in cov.paths}), 'distinct whole-route stage path')} through "
              f"{counted(len(cov.junctions), 'junction')}. Per row: the pairs and transitions seen there (a pair "
              f"seen at several junctions counts at each, so the column sums to {sum_pairs}), and the distinct "
              f"ones accumulated over the rows so far, in the order the suite first reaches the junctions; the "
              f"last row's accumulated counts are the totals.", "",
              "| junction | pairs | accumulated pairs | transitions | accumulated transitions | "
              "planner scenarios: stage paths |", "|---|---:|---:|---:|---:|---|"]
    for j, acc_p, acc_t in zip(rows, cov_acc_pairs, cov_acc_trans):
        p = sorted(cov.pairs.get(j, ()))
        text = "; ".join(f"{sc}: {' → '.join(st)}" for sc, st in p) or "-"  # md_text escapes it below
        name = "roads between junctions" if j == ROAD_CONTEXT else j
        lines.append(f"| {md_text(name)} | {len(p)} | {acc_p} | {len(cov.transitions.get(j, ()))} | {acc_t} | "
                     f"{md_text(text)} |")
    if cov.all_transitions:
        short = _short_stage_names(cov.all_transitions)
        lines += ["", "Transitions seen: " + ", ".join(md_code(f"{short[a]} → {short[b]}")
                                                      for a, b in sorted(cov.all_transitions)) + "."]
    if result.coverage:
        acc = cov.accumulated_lines
        if result.planner_digest == MIXED_DIGEST:
            lines += ["", "Warning: the planner's sources changed during the run; line numbers mix versions."]
        new = cov.new_lines()
        k = junctions_to_reach(acc)
        share = int(FULL_COVERAGE_SHARE * 100)
        reach = (f"The first {counted(k, 'junction')} the suite reaches ({md_text(', '.join(cov.junctions[:k]))}) "
                 f"already cover {share}% of them ({acc[k - 1]} of {acc[-1]} lines)." if k else "")
        covered = (f"{counted(len(cov.all_lines), 'line')} of the planner covered over "
                   f"{counted(len(cov.junctions), 'junction')}. {reach}")
        if result.sent_no_coverage:
            covered = ("The planner sent no coverage: its `bye` carried no `coverage` (docs/planners.md, close), "
                       "so its lines covered are unknown, not 0.")
        lines += ["", "## Planner line coverage", "", covered, "",
                  "| junction index | junction | lines at junction | new lines | accumulated |", "|---:|---|---:|---:|---:|"]
        for i, j in enumerate(cov.junctions):
            lines.append(f"| {i + 1} | {md_text(j)} | {len(cov.lines.get(j, ()))} | {new[i]} | {acc[i]} |")
    else:
        lines += ["", "Planner line coverage was not measured (`feat2map rollout --line-coverage` measures it).", ""]
    lines += ["", f"![coverage]({COVERAGE_PNG})", ""]
    lines += _stage_legend(result)
    return "\n".join(lines)


def _out_of_process(result: SuiteResult) -> bool:
    """Whether the planner ran in its own process (the planner bridge: BridgePlanner's name)."""
    return result.planner.startswith(BRIDGE_NAME_PREFIX)


def _stage_legend(result: SuiteResult) -> list[str]:
    """A table of the stage codes the report shows, with their meaning where the planner is ours."""
    from .planner import SCENARIO_STAGES, STAGE_NAMES

    seen = {st for o in result.outcomes for st in o.stage_path}
    seen |= {n.rpartition(".")[2] for o in result.outcomes for t in o.transitions for n in t}
    if not seen:
        return []
    order = [st for stages in SCENARIO_STAGES.values() for st in stages]
    codes = sorted(seen, key=lambda st: (order.index(st) if st in order else len(order), st))
    return ["## Stage codes", "",
            "Stages of the planner's scenarios (after Apollo's planning; scenarios/README.md explains when "
            "each is selected):", "", "| code | stage |", "|---|---|",
            *(f"| {md_code(c)} | {md_text(STAGE_NAMES.get(c, 'defined by the planner under test'))} |" for c in codes), ""]


def report_html(markdown_text: str, folder: Path, title: str, files: Collection[str] = ()) -> str:
    """The Markdown report as one self-contained HTML page (`markup.html_page`): only the
    pictures among `files`, the paths under `folder` the rollout wrote, are inlined."""
    return html_page(markdown_text, folder, title, files)


def write_report(result: SuiteResult, out: str | Path, fail_on: str = "any") -> Path:
    """Write summary, JUnit XML, Markdown report, plots and failure GIFs into `out` atomically."""
    out = Path(out)
    with atomic.staged_dir(out, (SUMMARY,)) as tmp:
        gifs: dict[str, str] = {}
        used: set[str] = set()
        for o in result.outcomes:
            if o.gif and not o.passed:  # every scenario that did not complete, whatever fail_on says
                name = _safe(o.name)
                while name in used:
                    name += "_"
                used.add(name)
                rel = f"{FAILURES}/{name}.gif"
                atomic.write_bytes(tmp / rel, o.gif)
                gifs[o.name] = rel
        doc = result.to_dict()
        doc["fail_on"] = fail_on
        doc["failed"] = [o.name for o in result.failures(fail_on)]
        doc["gifs"] = gifs
        atomic.write_text(tmp / SUMMARY, json.dumps(doc, indent=1) + "\n")
        atomic.write_bytes(tmp / JUNIT, junit_xml(result, fail_on))
        _plot_outcomes(result, tmp / OUTCOMES_PNG)
        plot_accumulated(compare({result.name: result}), tmp / COVERAGE_PNG, title=result.name)
        text = report_markdown(result, fail_on, gifs)
        atomic.write_text(tmp / REPORT, text)
        pictures = {OUTCOMES_PNG, COVERAGE_PNG, *gifs.values()}  # what this rollout wrote, nothing else
        atomic.write_text(tmp / REPORT_HTML, report_html(text, tmp, f"Rollout report: {result.name}", pictures))
    return out


def load_result(path: str | Path) -> SuiteResult:
    """A SuiteResult from a rollout output directory (or its summary.json)."""
    p = Path(path)
    f = p / SUMMARY if p.is_dir() else p
    if not f.is_file():
        raise Feat2MapError("no rollout summary here (run `feat2map rollout ... --out DIR` first)", str(f))
    doc = load_document(f, fmt="json")
    if not isinstance(doc, dict):
        raise Feat2MapError("rollout summary must be a JSON object", str(f))
    return SuiteResult.from_dict(doc, str(f))
