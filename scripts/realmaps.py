"""Survey real maps end to end: read, extract, build the route-coverage suite, drive it.

For every map file under the given folders (default ../shared/maps; more with --corpus DIR):
read it, extract its junctions (the skipped ones with their reasons), count its controls
(signal / stop / bare) and its signals' phase groups per junction, list its motorway ramps
(`extract_ramps`), build the route-coverage suite (traffic 6 by default; its scenarios that
merge from an on-ramp or diverge onto an off-ramp are named so) and roll it out with the
baseline planner (all of it, or --max-scenarios spread over the suite). Any exception is a
finding, recorded with the map and the stage (read / extract / ramps / phases / suite / export /
rollout), and the survey goes on with the next map.
Every map that reads is exported to Apollo, OpenDRIVE, Lanelet2 and CommonRoad the way a user would
(`feat2map export`), and each export is checked by `feat2map validate` (each ecosystem's own rules):
the `exports` column gives the problems per format, or the refusal.

Writes a Markdown table (--md) and a JSON file (--json) after every map, so a long survey can be
watched and an interrupted one keeps what it did. Progress is shown on a terminal only.

Usage:
  .venv/bin/python scripts/realmaps.py                              # ../shared/maps, whole suites
  .venv/bin/python scripts/realmaps.py --corpus /work/corpus --max-scenarios 10 --workers 1
  .venv/bin/python scripts/realmaps.py --no-shared --corpus DIR --no-rollout   # extract + suite only
  .venv/bin/python scripts/realmaps.py --compare before.json after.json --md changes.md   # map by map
  .venv/bin/python scripts/realmaps.py --from-json shared.json corpus.json --doc docs/realmaps.md   # the reference
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from feat2map import atomic, cli
from feat2map.config import LIMIT_FLAG, raised_limits
from feat2map.errors import Feat2MapError
from feat2map.extract import SkippedJunction, extract_junctions
from feat2map.extract_ramps import extract_ramps
from feat2map.formats import FORMATS, read_map
from feat2map.phases import junction_phases
from feat2map.routes import route_ramps
from feat2map.scenarios.rollout import run_suite
from feat2map.scenarios.routes import build_suite
from feat2map.scenarios.scenario import Suite

try:  # load-time semantic checks (issue 21), where this checkout has them
    from feat2map import semantics
except ImportError:
    semantics = None

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared" / "maps"
TRAFFIC = 6  # the traffic level
NOT_MAPS = ("routing_map",)  # Apollo routing graphs sit beside base maps but are no HD maps
WARNINGS_KEPT = 20  # distinct warning lines kept per map
EXPORTS = {"apollo": "apollo", "opendrive": "map.xodr", "lanelet2": "lanelet2/map.osm", "commonroad": "map.xml"}


@dataclass
class MapSurvey:
    """What one map gave at each stage; `errors` holds one entry per stage that raised."""

    path: str
    source: str = ""
    size: int = 0
    junction_elements: int = 0
    junctions: int = 0
    skipped: list[dict] = field(default_factory=list)
    controls: dict[str, int] = field(default_factory=dict)
    signals: int = 0
    phases: dict[str, int] = field(default_factory=dict)  # junction id -> number of phase groups
    checks: list[str] | None = None  # semantic findings (None: this checkout has no feat2map.semantics)
    ramps: dict[str, int] = field(default_factory=dict)  # "on" / "off" -> ramps `extract_ramps` finds
    ramp_scenarios: list[dict] = field(default_factory=list)  # {"scenario", "kinds": merge/diverge, "outcome"}
    scenarios: int = 0
    driven: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)
    exports: dict[str, dict] = field(default_factory=dict)  # format -> {"problems": n, "warnings": n, "first": line}
    # or {"refused": line}
    failing: list[dict] = field(default_factory=list)
    errors: list[dict] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    wall_s: float = 0.0


def map_files(folder: Path) -> list[Path]:
    """Every file under `folder` that a reader takes: by suffix, Apollo text files by their first
    bytes (a README.txt is no map), routing maps left out."""
    readable = {s for f in FORMATS.values() if f.read is not None for s in f.suffixes}
    out = []
    for p in sorted(folder.rglob("*")):
        if not p.is_file() or p.suffix.lower() not in readable or p.stem.startswith(NOT_MAPS):
            continue
        if p.suffix.lower() == ".txt":
            with p.open("rb") as fh:
                if not FORMATS["apollo"].sniff(fh.read(512)):
                    continue
        out.append(p)
    return out


def sample(suite: Suite, k: int | None) -> Suite:
    """`k` scenarios spread evenly over the suite (all of them when k is None or large)."""
    n = len(suite.scenarios)
    if k is None or k >= n:
        return suite
    picked = sorted({round(i * (n - 1) / max(k - 1, 1)) for i in range(k)})
    return Suite(suite.name, tuple(suite.scenarios[i] for i in picked), suite.base_dir)


def _error(stage: str, exc: BaseException) -> dict:
    """A refusal (Feat2MapError: one clear line) or a traceback (anything else), for the record."""
    if isinstance(exc, Feat2MapError):
        return {"stage": stage, "kind": "refusal", "error": str(exc), "message": exc.message}
    frames = traceback.extract_tb(exc.__traceback__)
    return {"stage": stage, "kind": "traceback", "error": f"{type(exc).__name__}: {exc}",
            "at": [f"{Path(f.filename).name}:{f.lineno} {f.name}" for f in frames[-4:]]}


def _cli(argv: list[str]) -> tuple[int, list[str], list[str]]:
    """`feat2map ARGV` in this process: exit status, stdout lines, stderr lines."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(argv)
    return rc, out.getvalue().splitlines(), err.getvalue().splitlines()


def export_check(path: Path, fmt: str, folder: Path) -> dict:
    """Export `path` to `fmt` under `folder` with `feat2map export` and check the result with
    `feat2map validate`: {"problems": n, "warnings": n (what the format's own tool rates a warning),
    "first": the first problem's line}, or {"refused": the error line}."""
    out = folder / EXPORTS[fmt]
    out.parent.mkdir(parents=True, exist_ok=True)
    def said(err: list[str], rc: int) -> str:  # the error line, the temporary folder's path left out
        line = next((ln for ln in err if "error:" in ln), f"exit {rc}").split("error: ", 1)[-1]
        return line.replace(str(out), out.name)

    rc, _, err = _cli(["export", fmt, str(path), "--out", str(out)])
    if rc:
        return {"refused": said(err, rc)}
    rc, lines, err = _cli(["validate", "--quiet", "--format", fmt, str(out)])
    found = lines[:-1]  # the last line is the count
    problems = [ln for ln in found if not ln.startswith("warning: ")]
    if rc and not problems:
        return {"refused": said(err, rc)}
    return {"problems": len(problems), "warnings": len(found) - len(problems),
            "first": problems[0].replace(str(out), out.name) if problems else ""}


def survey_map(path: Path, label: str, *, traffic: int = TRAFFIC, rollout: bool = True, export: bool = True,
               max_scenarios: int | None = None, workers: int = 1, progress: bool = False) -> MapSurvey:
    """One map through every stage. A stage that raises is recorded; the stages that need its
    result are left out for this map (a map that cannot be read ends here), never the survey."""
    s = MapSurvey(label, size=path.stat().st_size)
    t0 = time.perf_counter()
    seen: Counter[str] = Counter()

    def stage(name: str, fn: Callable[[], Any]) -> Any:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                return fn()
            except Exception as exc:  # every failure is a finding, never the end of the survey
                s.errors.append(_error(name, exc))
                return None
            finally:
                for w in caught:
                    line = f"{name}: {w.category.__name__}: {str(w.message).splitlines()[0]}"
                    if not seen[line] and len(s.warnings) < WARNINGS_KEPT:
                        s.warnings.append(line)
                    seen[line] += 1

    m = stage("read", lambda: read_map(path))
    if m is None:
        s.wall_s = time.perf_counter() - t0
        return s
    s.junction_elements, s.signals = len(m.junctions), len(m.signals)
    skipped: list[SkippedJunction] = []
    found = stage("extract", lambda: extract_junctions(m, label, skipped=skipped))
    if found is not None:
        s.junctions = len(found)
        s.skipped = [{"id": k.id, "n_arms": k.n_arms, "reason": k.reason} for k in skipped]
        s.controls = dict(Counter(j.feature.control for j in found))
    ramps = stage("ramps", lambda: extract_ramps(m, label)) or []
    s.ramps = dict(Counter(r.kind for r in ramps))
    groups = stage("phases", lambda: junction_phases(m))
    if groups:
        s.phases = {str(j): len(p) for j, p in groups.items()}
    if semantics is not None:
        found_checks = stage("checks", lambda: semantics.findings(m))
        if found_checks is not None:
            s.checks = [f"{'fatal: ' if f.fatal else ''}{f}" for f in found_checks]
    if export:
        with tempfile.TemporaryDirectory(prefix="realmaps-") as tmp:
            for fmt in EXPORTS:
                done = stage("export", lambda fmt=fmt: export_check(path, fmt, Path(tmp) / fmt))
                if done is not None:
                    s.exports[fmt] = done
    suite = stage("suite", lambda: build_suite(path, traffic_vehicles=traffic, name=Path(label).stem))
    if suite is not None:
        s.scenarios = len(suite.scenarios)
        s.ramp_scenarios = [{"scenario": sc.name, "kinds": kinds, "outcome": ""} for sc in suite.scenarios
                            if (kinds := route_ramps(m, sc.route, ramps))]
        if rollout:
            picked = sample(suite, max_scenarios)
            result = stage("rollout", lambda: run_suite(picked, "baseline", workers=workers, progress=progress,
                                                         record_failure_gif=False))
            if result is not None:
                s.driven = len(result.outcomes)
                s.outcomes = {k: v for k, v in result.counts().items() if v}
                s.failing = [{"scenario": o.name, "outcome": o.outcome, "message": o.message, "seed": o.seed}
                             for o in result.failures("any")]
                driven = {o.name: o.outcome for o in result.outcomes}
                for r in s.ramp_scenarios:
                    r["outcome"] = driven.get(r["scenario"], "")
    s.wall_s = time.perf_counter() - t0
    return s


def _phase_cell(s: MapSurvey) -> str:
    """Total phase groups over signalled junctions, with the per-junction range."""
    per = [n for j, n in s.phases.items() if j != "None"]
    if not per:
        return "0"
    return f"{sum(per)} ({min(per)}-{max(per)})" if min(per) != max(per) else f"{sum(per)} ({len(per)}x{per[0]})"


def _checks_cell(s: MapSurvey) -> str:
    """Semantic findings (fatal ones in brackets); n/a where the checkout has no checks."""
    if s.checks is None:
        return "n/a"
    return f"{len(s.checks)} ({sum(c.startswith('fatal') for c in s.checks)} fatal)" if s.checks else "0"


def _failure_cell(s: MapSurvey) -> str:
    parts = [f"{k} {v}" for k, v in s.outcomes.items() if k != "completed"]
    parts += [f"{e['stage']}: {e['message'].split(':')[0]}" if e["kind"] == "refusal" else f"{e['stage']} traceback"
              for e in s.errors]
    return ", ".join(parts) or "-"


def _exports_cell(s: MapSurvey) -> str:
    """Problems per export format (Apollo / OpenDRIVE / Lanelet2 / CommonRoad), with the format's
    own tool's warnings as "+N w", "refused" where the export was refused, "-" where no export ran."""
    if not s.exports:
        return "-"

    def cell(e: dict) -> str:
        return "refused" if "refused" in e else str(e["problems"]) + (f" +{e['warnings']} w" if e.get("warnings") else "")

    return " / ".join("-" if fmt not in s.exports else cell(s.exports[fmt]) for fmt in EXPORTS)


def _failure_notes(results: Sequence[Any], text: Callable[[str], str] = str) -> list[str]:
    """A line per failing scenario and per export refused or with problems (`text` rewrites the
    messages, e.g. without this machine's paths)."""
    notes = [f"- `{s.path}` {f['scenario']}: {f['outcome']}: {text(f['message'])}" for s in results for f in s.failing]
    notes += [f"- `{s.path}` export {fmt}: " + (f"refused: {text(e['refused'])}" if "refused" in e else
                                                f"{e['problems']} problem(s), first: {text(e['first'])}")
              for s in results for fmt, e in s.exports.items() if e.get("refused") or e.get("problems")]
    return notes


def ramp_table(results: Sequence[MapSurvey]) -> list[str]:
    """The maps with ramps: ramps found (on / off), the suite's ramp scenarios (merge / diverge:
    from each on-ramp onto its road, from the road onto each off-ramp), how many were driven and
    completed, and the other outcomes; [] when no map has a ramp."""
    rows = []
    for s in results:
        if not s.ramps:
            continue
        kinds = Counter(k for r in s.ramp_scenarios for k in r["kinds"])
        driven = [r["outcome"] for r in s.ramp_scenarios if r["outcome"]]
        other = Counter(o for o in driven if o != "completed")
        rows.append(f"| `{s.path}` | {s.ramps.get('on', 0)} / {s.ramps.get('off', 0)} | {len(s.ramp_scenarios)} "
                    f"({kinds['merge']} / {kinds['diverge']}) | {len(driven)} / {driven.count('completed')} | "
                    + (", ".join(f"{k} {v}" for k, v in other.items()) or "-") + " |")
    if not rows:
        return []
    return ["| map | ramps (on / off) | ramp scenarios (merge / diverge) | driven / completed | failures |",
            "|" + "---|" * 5, *rows, ""]


def markdown(results: Sequence[MapSurvey]) -> str:
    """The survey table plus one line per error and per failing scenario."""
    head = ("| map | source | junction elements | junctions (skipped) | signal / stop / bare | signals | phase groups "
            "| checks | scenarios | driven | completed | failures | exports (A / O / L / C) |\n|" + "---|" * 13)
    rows = []
    for s in results:
        c = s.controls
        rows.append(f"| `{s.path}` | {s.source} | {s.junction_elements} | {s.junctions} ({len(s.skipped)}) | "
                    f"{c.get('signal', 0)} / {c.get('stop', 0)} / {c.get('bare', 0)} | {s.signals} | {_phase_cell(s)} | "
                    f"{_checks_cell(s)} | "
                    f"{s.scenarios} | {s.driven} | {s.outcomes.get('completed', 0)} | {_failure_cell(s)} | "
                    f"{_exports_cell(s)} |")
    tot = Counter()
    for s in results:
        tot.update(scenarios=s.scenarios, driven=s.driven, completed=s.outcomes.get("completed", 0),
                   errors=len(s.errors), tracebacks=sum(e["kind"] == "traceback" for e in s.errors),
                   junctions=s.junctions, skipped=len(s.skipped))
    lines = [head, *rows, "",
             f"**{len(results)} maps: {tot['junctions']} junctions ({tot['skipped']} skipped), {tot['scenarios']} "
             f"scenarios, {tot['completed']} of {tot['driven']} driven completed, {tot['errors']} stage errors "
             f"({tot['tracebacks']} tracebacks).**", ""]
    ramps = ramp_table(results)
    if ramps:
        lines += ["Ramp suites:", "", *ramps]
    details = [f"- `{s.path}` {e['stage']}: {e['kind']}: {e['error']}" + (f" (at {' <- '.join(reversed(e['at']))})"
                                                                         if e.get("at") else "")
               for s in results for e in s.errors]
    details += _failure_notes(results)
    details += [f"- `{s.path}` check: {c}" for s in results for c in (s.checks or ())]
    if details:
        lines += ["Errors and failing scenarios:", "", *details, ""]
    return "\n".join(lines)


def compare(before: dict, after: dict) -> str:
    """Per map, before -> after (two --json files): junctions (skipped), controls, phase groups,
    scenarios, completed of driven, failures; maps whose row is the same are marked "=", plus totals."""
    def cells(s: dict | None) -> list[str]:
        if s is None:
            return ["-"] * 6
        x = MapSurvey(**{k: v for k, v in s.items() if k in MapSurvey.__dataclass_fields__})
        c = x.controls
        return [f"{x.junctions} ({len(x.skipped)})", f"{c.get('signal', 0)}/{c.get('stop', 0)}/{c.get('bare', 0)}",
                _phase_cell(x), str(x.scenarios), f"{x.outcomes.get('completed', 0)}/{x.driven}", _failure_cell(x)]

    b = {s["path"]: s for s in before["maps"]}
    a = {s["path"]: s for s in after["maps"]}
    heads = ("junctions (skipped)", "signal/stop/bare", "phase groups", "scenarios", "completed/driven", "failures")
    lines = ["| map | " + " | ".join(heads) + " |", "|---|" + "---|" * len(heads)]
    for path in sorted(set(b) | set(a)):
        old, new = cells(b.get(path)), cells(a.get(path))
        lines.append(f"| `{path}` | " + " | ".join(o if o == n else f"{o} -> **{n}**" for o, n in zip(old, new)) + " |")

    def total(maps: dict) -> str:
        t = Counter()
        for s in maps.values():
            t.update(scenarios=s["scenarios"], driven=s["driven"], completed=s["outcomes"].get("completed", 0),
                     tracebacks=sum(e["kind"] == "traceback" for e in s["errors"]))
        return f"{t['completed']} of {t['driven']} driven completed ({t['scenarios']} scenarios), {t['tracebacks']} tracebacks"
    return "\n".join([*lines, "", f"Before: {total(b)}. After: {total(a)}.", ""])


SHARED_SOURCES = (  # ../shared/maps: (files under maps/, repository and file date, path there)
    ('`apollo/{san_francisco,gomentum,shalun,borregas_ave,cube_town}/base_map.bin`; '
     '`apollo/{gomentum,shalun,cube_town}/sim_map.txt`',
     '`lgsvl/apollo-5.0`, 2021-10-01',
     '`modules/map/data/<name>/` (`go_mentum` for gomentum)'),
    ('`apollo/autonomous_stuff/base_map.bin`',
     '`lgsvl/apollo-5.0`, 2021-06-30',
     '`modules/map/data/autonomou_stuff/base_map.bin` (sic)'),
    ('`opendrive/carla_town0{1,2,4,6}/Town0N.xodr`',
     '`BerkeleyLearnVerify/Scenic`, 2023-06-29',
     '`assets/maps/CARLA/Town0N.xodr`'),
    ('`opendrive/carla_town0{3,5}/Town0N.xodr`',
     '`BerkeleyLearnVerify/Scenic`, 2021-04-20',
     '`tests/formats/opendrive/maps/CARLA/Town0N.xodr`'),
    ('`opendrive/svl_borregas_ave/borregasave.xodr`, `opendrive/svl_cubetown/cubetown.xodr`',
     '`BerkeleyLearnVerify/Scenic`, 2023-06-29',
     '`assets/maps/LGSVL/`'),
    ('`opendrive/esmini_fabriksgatan/fabriksgatan_traffic_lights.xodr`',
     '`esmini/esmini`, 2025-10-27',
     '`resources/xodr/`'),
    ('`opendrive/commonroad_arg_carcarana/ARG_Carcarana-1_1_T-1.xodr`',
     '`CommonRoad/commonroad-scenario-designer`, 2024-12-20',
     '`tests/map_conversion/test_maps/cr2odr/reference_xodr_files/`'),
    ('`opendrive/commonroad_four_way_crossing/four_way_crossing.xodr`',
     '`CommonRoad/commonroad-scenario-designer`, 2024-12-20',
     '`tests/map_conversion/test_maps/odr2cr/`'),
)

DOC_HEAD = """# Real maps: the per-map reference

What feat2map does with every public map it has been tried on: read, junctions extracted (the
skipped ones with their reasons), controls, the route-coverage suite (traffic {traffic}) and how
much of it the baseline planner drove, and the export to Apollo, OpenDRIVE, Lanelet2 and CommonRoad
with each export checked by `feat2map validate`. The rules behind the numbers (how each class of
real-map quirk is read and handled) are in [semantics.md](semantics.md#real-map-rule-classes). This
page is generated; do not edit it by hand.

## Getting the maps

The 20 files are public but not in the repository (their licences differ). Fetch each from its
repository as of the date given (the last change of that file; `SOURCES.md` names the commits),
into a `maps/` folder at `../shared/maps` beside the repository
(or anywhere, with `FEAT2MAP_SHARED_MAPS=/path/to/maps`); `../shared/maps/SOURCES.md`, where it
exists, gives each file's size, sha256 and licence. Without them, the tests that read them skip
with one reason saying so.

{sources}

A corpus folder beside them (any folder of maps, one sub-folder per producing tool) has its own
`SOURCES.md` naming each file's repository, path, commit and sha256.

## Reproducing

With the maps in place:

```bash
python scripts/realmaps.py --md shared.md --json shared.json --workers 2 --limit max_checker_s=3000
python scripts/realmaps.py --no-shared --corpus DIR --md corpus.md --json corpus.json --workers 2
python scripts/realmaps.py --from-json shared.json corpus.json --doc docs/realmaps.md
```

`--no-rollout` reads, extracts, exports and builds suites only; `--max-scenarios N` drives N
scenarios spread over each suite instead of all (driving all of `../shared` takes about 45 minutes
on one worker; the corpus with its exports 15 minutes on two; ASAM's checker takes 9 minutes on San
Francisco's OpenDRIVE export alone, more under load: past its default limit). Columns: **source** = the map's
first sub-folder (its producing tool);
**junctions (skipped)** = junctions extracted (3 or more arms) and junction elements skipped, each
with a reason; **driven / completed** = scenarios driven (a sample spread over the suite, or all)
and completed; **failures** = other outcomes and stage errors (a refusal names the problem);
**exports** = problems `feat2map validate` finds in each export (Apollo / OpenDRIVE / Lanelet2 /
CommonRoad), with "+N w" for the warnings the format's own tool rates warnings, not errors
(lanelet2_validation's bound curvature and points closer than 5 cm), "refused" where the export
was refused.

## Rule classes

The classes of real-map quirk behind these numbers, each explained in
[semantics.md](semantics.md#real-map-rule-classes): touching junction elements read as one
junction; direct junctions; road links without lane links; road links that name the far end of
the road they link to; boundary types from road marks and Apollo types; left-hand traffic; declared
speeds in their unit and checked for plausibility; local coordinates; converter geometry repaired
(gaps bridged, reversing links dropped, link ends turned against each other closed, turnarounds,
edge stubs, folded lanes); manoeuvres no car drives left out of suites; no traffic into lanes it
cannot leave; exports that repair what a format cannot hold and name the first problem when they
refuse; the env's driving rules for real junctions (merges, converging lanes, junction chains,
narrow passages, swept paths, curve speed, the amber dilemma zone, wait points).
"""


RAMP_HEAD = """## Ramp suites

The maps with motorway ramps (`extract_ramps`, inside a junction or through a direct link: ASAM's
`Ex_Entry_Exit` joins its ramps through OpenDRIVE direct junctions, which are no junctions of the
map) and their route-coverage suites' ramp scenarios: a merge from each on-ramp onto the road it
joins, a diverge from the road onto each off-ramp (a ramp in a junction is that junction's
manoeuvre, a ramp through a direct link a lane route of its own), named `-merge` / `-diverge`.
"""


def reference(runs: Sequence[tuple[dict, list[MapSurvey]]]) -> str:
    """docs/realmaps.md: how to reproduce, then per survey run (a --json file) one row per map and
    its totals, then the refusals and failing scenarios by map."""
    traffic = ", ".join(sorted({str(meta.get("traffic", TRAFFIC)) for meta, _ in runs}))
    sources = "\n".join(["| file under `maps/` | repository, file as of | path there |", "|---|---|---|",
                         *("| " + " | ".join(row) + " |" for row in SHARED_SOURCES)])
    lines = [DOC_HEAD.replace("{traffic}", traffic).replace("{sources}", sources)]
    for meta, maps in runs:
        folders = ", ".join(f"`{Path(f).name}`" for f in meta.get("folders", ())) or "maps"
        drive = ("not driven" if not meta.get("rollout", True) else "whole suites driven"
                 if meta.get("max_scenarios") is None else f"at most {meta['max_scenarios']} scenarios driven per map")
        drive += "" if meta.get("export", True) else ", not exported"
        lines += [f"## {folders}", "", f"{len(maps)} maps, traffic {meta.get('traffic', TRAFFIC)}, {drive}.", "",
                  "| map | source | junctions (skipped) | signal / stop / bare | scenarios | driven / completed "
                  "| failures | exports (A / O / L / C) |", "|" + "---|" * 8]
        tot = Counter()
        for s in maps:
            c = s.controls
            lines.append(f"| `{s.path}` | {s.source} | {s.junctions} ({len(s.skipped)}) | {c.get('signal', 0)} / "
                         f"{c.get('stop', 0)} / {c.get('bare', 0)} | {s.scenarios} | {s.driven} / "
                         f"{s.outcomes.get('completed', 0)} | {_failure_cell(s)} | {_exports_cell(s)} |")
            tot.update(junctions=s.junctions, skipped=len(s.skipped), scenarios=s.scenarios, driven=s.driven,
                       completed=s.outcomes.get("completed", 0), tracebacks=sum(e["kind"] == "traceback" for e in s.errors),
                       clean=all(e.get("problems") == 0 for e in s.exports.values()) and len(s.exports) == len(EXPORTS))
        lines += ["", f"Totals: {tot['junctions']} junctions ({tot['skipped']} skipped), {tot['scenarios']} scenarios, "
                  f"{tot['completed']} of {tot['driven']} driven completed, {tot['tracebacks']} tracebacks"
                  + (f"; {tot['clean']} of {len(maps)} maps export to all four formats with no problem"
                     if meta.get("export", True) else "") + ".", ""]
        parents = [str(Path(f).parent) + "/" for f in meta.get("folders", ())]

        def local(text: str, parents: list[str] = parents) -> str:  # a map by its label, not this machine's path
            for parent in parents:
                text = text.replace(parent, "")
            return text
        notes = [f"- `{s.path}` {e['stage']}: {e['kind']}: {local(e['error'])}" for s in maps for e in s.errors]
        notes += _failure_notes(maps, local)
        if notes:
            lines += ["Refusals, failing scenarios and export problems:", "", *notes, ""]
    ramps = ramp_table([s for _, maps in runs for s in maps])
    if ramps:
        lines += [RAMP_HEAD, *ramps]
    return "\n".join(lines)


def _loaded(path: Path) -> tuple[dict, list[MapSurvey]]:
    """A --json file: its settings and its maps."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    maps = [MapSurvey(**{k: v for k, v in s.items() if k in MapSurvey.__dataclass_fields__}) for s in doc["maps"]]
    return {k: v for k, v in doc.items() if k != "maps"}, maps


def _labelled(folders: Sequence[Path], written: Sequence[Path] = ()) -> Iterator[tuple[Path, str, str]]:
    """(file, label: its path under its folder with the folder's name first, source: its first sub-folder);
    the files this survey writes (`written`: --md, --json, --doc) are no maps, even inside a folder."""
    ours = {p.resolve() for p in written}
    for folder in folders:
        for p in map_files(folder):
            if p.resolve() in ours:
                continue
            rel = p.relative_to(folder)
            yield p, f"{folder.name}/{rel}", rel.parts[0] if len(rel.parts) > 1 else folder.name


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="*", type=Path, help=f"map folders (default {SHARED} when it exists)")
    ap.add_argument("--corpus", action="append", type=Path, default=[], help="another map folder (repeatable)")
    ap.add_argument("--no-shared", action="store_true", help="leave the default ../shared/maps out")
    ap.add_argument("--traffic", type=int, default=TRAFFIC, help=f"traffic vehicles per scenario (default {TRAFFIC})")
    ap.add_argument("--workers", type=int, default=1, help="rollout worker processes (default 1)")
    ap.add_argument("--max-scenarios", type=int, default=None, help="drive at most N scenarios per map, spread over "
                                                                     "its suite (default: the whole suite)")
    ap.add_argument("--no-rollout", action="store_true", help="read, extract, export and build suites only")
    ap.add_argument("--no-export", action="store_true", help="leave out the exports to the four formats")
    ap.add_argument("--only", action="append", default=[], help="survey only maps whose label contains this")
    ap.add_argument(LIMIT_FLAG, action="append", type=cli.limit_arg, metavar="NAME=VALUE", default=[],
                    help="raise a size limit for every stage, as feat2map's own flag (San Francisco's OpenDRIVE "
                         "export needs max_checker_s above 600 on a loaded machine)")
    ap.add_argument("--md", type=Path, default=Path("realmaps.md"), help="Markdown table (default realmaps.md)")
    ap.add_argument("--json", type=Path, default=Path("realmaps.json"), help="JSON results (default realmaps.json)")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"),
                    help="no survey: compare two --json files map by map into --md")
    ap.add_argument("--doc", type=Path, help="also write the per-map reference page (docs/realmaps.md)")
    ap.add_argument("--from-json", nargs="+", type=Path, metavar="JSON",
                    help="no survey: write --doc from these --json files, one section each")
    args = ap.parse_args(argv)
    if args.from_json:
        if not args.doc:
            ap.error("--from-json needs --doc")
        atomic.write_text(args.doc, reference([_loaded(p) for p in args.from_json]))
        return 0
    if args.compare:
        before, after = (json.loads(p.read_text(encoding="utf-8")) for p in args.compare)
        atomic.write_text(args.md, compare(before, after))
        return 0
    folders = list(args.folders) or ([] if args.no_shared or not SHARED.is_dir() else [SHARED])
    folders += args.corpus
    for f in folders:
        if not f.is_dir():
            print(f"{f}: no such folder", file=sys.stderr)
            return 2
    ours = [args.md, args.json, *([args.doc] if args.doc else [])]
    todo = [t for t in _labelled(folders, ours) if not args.only or any(o in t[1] for o in args.only)]
    if not todo:
        print("no map files found in " + ", ".join(map(str, folders)), file=sys.stderr)
        return 2
    with raised_limits(**dict(args.limit)):
        return _survey(args, folders, todo)


def _survey(args: argparse.Namespace, folders: list[Path], todo: list[tuple[Path, str, str]]) -> int:
    """Survey `todo` ((path, label, source) of each map), writing --md, --json and --doc."""
    tty = sys.stderr.isatty()
    results: list[MapSurvey] = []
    for i, (path, label, source) in enumerate(todo, 1):
        if tty:
            print(f"[{i}/{len(todo)}] {label}", file=sys.stderr, flush=True)
        s = survey_map(path, label, traffic=args.traffic, rollout=not args.no_rollout, export=not args.no_export,
                       max_scenarios=args.max_scenarios, workers=args.workers, progress=tty)
        s.source = source
        results.append(s)
        atomic.write_text(args.json, json.dumps({"folders": [str(f) for f in folders], "traffic": args.traffic,
                                                 "max_scenarios": args.max_scenarios, "rollout": not args.no_rollout,
                                                 "export": not args.no_export, "maps": [r.__dict__ for r in results]},
                                                indent=1))
        atomic.write_text(args.md, markdown(results))
    if args.doc:
        atomic.write_text(args.doc, reference([({"folders": [str(f) for f in folders], "traffic": args.traffic,
                                                 "max_scenarios": args.max_scenarios, "rollout": not args.no_rollout,
                                                 "export": not args.no_export}, results)]))
    if tty:
        print(f"wrote {args.md} and {args.json}", file=sys.stderr)
    return 1 if any(r.errors for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
