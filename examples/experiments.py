"""Reproduce the Feat2Map paper's experiments (Section V, RQ1-RQ4) with this project's pieces.

  RQ1  extract the feature space of San Francisco (Apollo map), generate M1-M3 (three seeds);
       pictures of SF (junctions numbered, coloured by control), M1-M3 and M1's junctions.
  RQ2  route-coverage suites with the baseline planner on SF (read from the Apollo file and
       driven in feat2map/MapFile-v0) and on M1-M3: accumulated planner line coverage per
       junction (Fig. 6a), stage transitions and stage paths covered (Figs. 6b, 7), a table.
  RQ3  M4 from SF + GoMentum + Shalun; the same measurements; what the bare junctions add.
  RQ4  the custom maps of examples/*.yaml (mega junction, road circle, one-way T) built and driven,
       and a highway-and-city map sampled from the paper's space with every mid-block crosswalk,
       filter lane and ramp value: the stage paths at each of those features.

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python examples/experiments.py --rq all
Writes out/experiments/rqN/ (maps, results JSON, pictures, tables) and copies the small
pictures and the tables to docs/experiments/. Real maps come from ../shared/maps (--maps);
when they are missing the script names them and exits with code 2.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from tqdm import tqdm  # noqa: E402

import feat2map  # noqa: E402
from feat2map import atomic  # noqa: E402
from feat2map.formats import native  # noqa: E402
from feat2map.errors import Feat2MapError  # noqa: E402
from feat2map.extract import ExtractedJunction, extract_junctions, map_feature  # noqa: E402
from feat2map.features import HIGHWAY_CITY_FEATURE_SPACE, FeatureSpace  # noqa: E402
from feat2map.model import HDMap  # noqa: E402
from feat2map.render import CONTROL_COLOURS, draw_map, render_junctions, save_figure  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_MAPS = ROOT.parent / "shared" / "maps"
DEFAULT_OUT = ROOT / "out" / "experiments"
DEFAULT_DOCS = ROOT / "docs" / "experiments"
REAL_MAPS = {  # name -> path under the maps folder (see ../shared/maps/SOURCES.md)
    "san_francisco": "apollo/san_francisco/base_map.bin",
    "gomentum": "apollo/gomentum/base_map.bin",
    "shalun": "apollo/shalun/base_map.bin",
}
NEEDS = {1: ("san_francisco",), 2: ("san_francisco",), 3: ("san_francisco", "gomentum", "shalun"), 4: ()}
SEEDS = (1, 2, 3)  # M1-M3
M4_SEED = 4
HIGHWAY_CITY = ("highway and city", 5)  # RQ4's sampled map (features.HIGHWAY_CITY_FEATURE_SPACE) and its seed
CUSTOM_SPECS = {"mega junction": "examples/mega_junction.yaml", "road circle": "examples/road_circle.yaml",
                "one-way roads": "examples/one_way_t.yaml"}
PAPER = {  # the paper's numbers (Sec. V), shown next to ours
    "sf_junctions": 91, "sf_signal": 88, "sf_stop": 3, "sf_roads": 164, "sf_lanes": 1524, "sf_crosswalk_junctions": 13,
    "generated_junctions": 8, "m4_junctions": 12,
    "lines": {"SF": 8275, "M1": 8232, "M2": 8205, "M3": 8238, "M4": 8236}, "stage_paths": 4,
}
NEW_LINES_COLOUR = "#ef6c00"
NO_NEW_LINES_COLOUR = "#90caf9"  # the paper's light blue: a junction that covers nothing new
MAX_DOC_PICTURE_BYTES = 300_000


class ExperimentError(Feat2MapError):
    """A missing input or a failed step; `where` names the file or the research question."""


@dataclass(frozen=True)
class Settings:
    """Where inputs and outputs live and how big the driving runs are."""

    out: Path = DEFAULT_OUT
    docs: Path | None = DEFAULT_DOCS
    maps: Path = DEFAULT_MAPS
    inputs: Mapping[str, Path] = field(default_factory=dict)  # overrides of REAL_MAPS (tests, other maps)
    seeds: tuple[int, ...] = SEEDS
    m4_seed: int = M4_SEED
    sf_junctions: int | None = None  # drive only manoeuvres of the first N SF junctions (None: all)
    budget_s: float | None = None  # wall-clock budget per map's suite (None: run every route)
    max_scenarios: int | None = None  # cap per map's suite (None: every route)
    max_junctions: int = 4  # junctions per route in the coverage suites
    workers: int = 1
    reuse: bool = False  # take maps' suites saved by an earlier run instead of driving again
    traffic: int = 0  # traffic vehicles per scenario (the paper's sim-control runs have none)
    duration_slack_s: float = 0.0  # added to every route's duration budget
    progress: bool = True

    def input(self, name: str) -> Path:
        return Path(self.inputs[name]) if name in self.inputs else self.maps / REAL_MAPS[name]


# ---- inputs ----------------------------------------------------------------------------------------
def missing_inputs(settings: Settings, rqs: Sequence[int]) -> list[str]:
    """The real map files the chosen research questions need that are not there."""
    names = dict.fromkeys(n for rq in rqs for n in NEEDS[rq])
    paths = [settings.input(n) for n in names if not settings.input(n).is_file()]
    # relative to --maps where they lie under it: the error line names all of them within its cap
    return [str(p.relative_to(settings.maps)) if p.is_relative_to(settings.maps) else str(p) for p in paths]


def read_input(settings: Settings, name: str) -> HDMap:
    """Read a real map with the project's readers (Apollo via read_map when wired, else read_apollo)."""
    from feat2map.readers import read_map

    path = settings.input(name)
    try:
        return read_map(path)
    except Feat2MapError as exc:
        if path.suffix not in (".bin", ".txt"):
            raise
        try:
            from feat2map.formats.apollo import read_apollo
        except ImportError:
            raise ExperimentError(f"cannot read the Apollo map: {exc.message}", str(path)) from None
        return read_apollo(path)


# ---- pictures --------------------------------------------------------------------------------------
def junction_numbers(junctions: Sequence[ExtractedJunction], m: HDMap) -> dict[str, int]:
    """Junction id -> number 0..N-1 in map order (the order the picture and tables use)."""
    ids = [jid for jid in m.junctions if len(m.junctions[jid].polygon) >= 3]
    return {jid: i for i, jid in enumerate(ids)}


def draw_numbered(m: HDMap, ax, controls: Mapping[str, str], numbers: Mapping[str, int]) -> None:
    """A real map with its junctions coloured by extracted control and labelled by number."""
    draw_map(m, ax, labels=False, controls=dict(controls))
    for jid, k in numbers.items():
        j = m.junctions[jid]
        colour = CONTROL_COLOURS.get(controls.get(jid, ""), "#616161")
        ax.annotate(str(k), j.center, ha="center", va="center", fontsize=5, zorder=8, color="white",
                    bbox=dict(boxstyle="circle,pad=0.15", fc=colour, ec="none", alpha=0.9))


def control_legend(ax) -> None:
    from matplotlib.patches import Patch

    ax.legend(handles=[Patch(color=c, label=k) for k, c in CONTROL_COLOURS.items()], loc="lower right", fontsize=7)


def picture_input(m: HDMap, junctions: Sequence[ExtractedJunction], title: str, path: Path) -> Path:
    """Bird's-eye picture of a real map, junctions numbered and coloured by control."""
    numbers = junction_numbers(junctions, m)
    controls = {j.id: j.feature.control for j in junctions}
    fig, ax = plt.subplots(figsize=(8, 8))
    draw_numbered(m, ax, controls, numbers)
    control_legend(ax)
    ax.set_title(title)
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)  # keeps the 1,500-lane picture under MAX_DOC_PICTURE_BYTES


def picture_maps(panels: Sequence[tuple[str, HDMap, Mapping[str, str] | None]], path: Path) -> Path:
    """Paper Fig. 4: the input map next to the generated maps, one panel each."""
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.4), squeeze=False)
    for ax, (title, m, controls) in zip(axes.flat, panels):
        draw_map(m, ax, labels=controls is None, controls=None if controls is None else dict(controls))
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("")
        ax.set_ylabel("")
        ax.tick_params(labelsize=6)
    control_legend(axes.flat[0])
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def map_stats(m: HDMap, junctions: Sequence[ExtractedJunction] | None = None) -> dict[str, Any]:
    """Counts the paper reports for a map: junctions by control, roads, lanes, crosswalks."""
    if junctions is None:
        junctions = extract_junctions(m)
    ctrl = [j.feature.control for j in junctions]
    road_lanes = sum(ln.junction_id is None for ln in m.lanes.values())
    return {"junctions": len(m.junctions), "junctions_with_features": len(junctions),
            "signal": ctrl.count("signal"), "stop": ctrl.count("stop"), "bare": ctrl.count("bare"),
            "crosswalk_junctions": sum(j.feature.crosswalk for j in junctions),
            "legs": {str(n): sum(j.feature.n_roads == n for j in junctions)
                     for n in sorted({j.feature.n_roads for j in junctions})},
            "roads": len(m.roads), "roads_outside_junctions": sum(r.junction_id is None for r in m.roads.values()),
            "lanes": len(m.lanes), "road_lanes": road_lanes,
            "junction_lanes": len(m.lanes) - road_lanes, "signals": len(m.signals),
            "stop_signs": len(m.stop_signs), "crosswalks": len(m.crosswalks)}


def copy_to_docs(settings: Settings, files: Sequence[Path]) -> list[Path]:
    """Copy final small pictures and tables into docs/experiments/ (pictures must stay small)."""
    if settings.docs is None:
        return []
    out = []
    for f in files:
        if f.suffix == ".png" and f.stat().st_size > MAX_DOC_PICTURE_BYTES:
            print(f"experiments: not copying {f.name} to docs ({f.stat().st_size // 1000} kB > "
                  f"{MAX_DOC_PICTURE_BYTES // 1000} kB)", file=sys.stderr)
            continue
        dst = settings.docs / f.name
        atomic.write_bytes(dst, f.read_bytes())
        out.append(dst)
    return out


def code_version() -> str:
    """The commit the results were made with, and whether the working tree differed from it."""
    import subprocess

    try:
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + (f" + uncommitted changes in {len(dirty)} tracked files" if dirty else "")


def write_json(path: Path, doc: Any) -> Path:
    """Write a results document; top-level results (rq*.json) record the code version."""
    if isinstance(doc, dict) and path.name.startswith("rq"):
        doc = {**doc, "code": code_version(), "written": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    atomic.write_text(path, json.dumps(doc, indent=2, sort_keys=False, default=str) + "\n")
    return path


def md_table(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


# ---- RQ1 -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Generated:
    """A feature space extracted from input maps and the maps generated from it."""

    space: FeatureSpace
    maps: Mapping[str, HDMap]  # "M1" -> map
    paths: Mapping[str, Path]  # "M1" -> out/.../M1.json


def generate_maps(space: FeatureSpace, names_seeds: Sequence[tuple[str, int]], folder: Path) -> Generated:
    """Generate and save one map per (name, seed) from `space`."""
    maps, paths = {}, {}
    for name, seed in names_seeds:
        m = feat2map.generate(space, seed=seed)
        maps[name] = m
        paths[name] = folder / f"{name}.json"
        native.save(m, paths[name])
    return Generated(space, maps, paths)


def rq1(settings: Settings) -> dict[str, Any]:
    """Extract SF's feature space, generate M1-M3, draw Figs. 4-5, tabulate the maps."""
    folder = settings.out / "rq1"
    folder.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    sf = read_input(settings, "san_francisco")
    read_s = time.perf_counter() - t
    t = time.perf_counter()
    junctions = extract_junctions(sf, "san_francisco")
    extract_s = time.perf_counter() - t
    if not junctions:
        raise ExperimentError("no junctions with 3 or more arms found", str(settings.input("san_francisco")))
    space = map_feature(junctions)
    names_seeds = [(f"M{i + 1}", s) for i, s in enumerate(settings.seeds)]
    saved = [folder / "sf_features.json"] + [folder / f"{k}.json" for k, _ in names_seeds]
    if settings.reuse and all(p.is_file() for p in saved):  # redraw the maps the saved suites drove
        space = FeatureSpace.from_json(saved[0].read_text(), str(saved[0]))
        gen = Generated(space, {k: native.load(folder / f"{k}.json") for k, _ in names_seeds},
                        {k: folder / f"{k}.json" for k, _ in names_seeds})
    else:
        atomic.write_text(folder / "sf_features.json", space.to_json())
        gen = generate_maps(space, names_seeds, folder)
    numbers = junction_numbers(junctions, sf)
    write_json(folder / "sf_junctions.json", [{"number": numbers.get(j.id), **j.to_dict()} for j in junctions])
    pics = [picture_input(sf, junctions, f"San Francisco: {len(sf.junctions)} junctions", folder / "rq1_sf.png")]
    controls = {j.id: j.feature.control for j in junctions}
    pics.append(picture_maps([("San Francisco", sf, controls)] +
                             [(f"{k} (seed {s})", m, None) for (k, m), s in zip(gen.maps.items(), settings.seeds)],
                             folder / "rq1_maps.png"))
    for name, m in gen.maps.items():
        fig, ax = plt.subplots(figsize=(6, 6))
        draw_map(m, ax)
        ax.set_title(f"{name}: {len(m.junctions)} junctions")
        fig.tight_layout()
        pics.append(save_figure(fig, folder / f"rq1_{name.lower()}.png"))
    first = next(iter(gen.maps))
    render_junctions(gen.maps[first], folder / f"rq1_{first.lower()}_junctions.png", dpi=80)
    pics.append(folder / f"rq1_{first.lower()}_junctions.png")
    stats = {"San Francisco": map_stats(sf, junctions)} | {k: map_stats(m) for k, m in gen.maps.items()}
    m1_junctions = [{"id": jid, "n": j.feature.n_roads, "control": j.feature.control,
                     "crosswalk": j.feature.crosswalk, "rotation": [round(a, 2) for a in j.feature.rotation]}
                    for jid, j in gen.maps[first].junctions.items() if j.feature is not None]
    result = {"input": str(settings.input("san_francisco")), "read_s": round(read_s, 3),
              "extract_s": round(extract_s, 3), "feature_space": space.to_dict(), "stats": stats,
              "seeds": dict(zip(gen.maps, settings.seeds)), "m1_junctions": m1_junctions,
              "maps": {k: str(p) for k, p in gen.paths.items()}}
    write_json(folder / "rq1.json", result)
    table = rq1_markdown(result)
    atomic.write_text(folder / "rq1.md", table)
    copy_to_docs(settings, pics + [folder / "rq1.md"])
    return result


def _ranges(space: Mapping[str, Any]) -> str:
    rr = space.get("rotation_ranges", {})
    return "; ".join(f"n={n}: " + ", ".join(f"[{a:.2f}, {b:.2f}]" for a, b in v) for n, v in rr.items())


def rq1_markdown(r: Mapping[str, Any]) -> str:
    """RQ1 tables: the extracted feature space and the maps' sizes (ours and the paper's)."""
    s = r["stats"]
    sf = s["San Francisco"]
    sp = r["feature_space"]
    rows = [("junctions", sf["junctions"], PAPER["sf_junctions"]),
            ("junctions with >= 3 arms (features extracted)", sf["junctions_with_features"], "-"),
            ("signal / stop / bare", f"{sf['signal']} / {sf['stop']} / {sf['bare']}",
             f"{PAPER['sf_signal']} / {PAPER['sf_stop']} / 0"),
            ("junctions with crosswalks", sf["crosswalk_junctions"], PAPER["sf_crosswalk_junctions"]),
            ("roads outside junctions (all road elements)", f"{sf['roads_outside_junctions']} ({sf['roads']})",
             PAPER["sf_roads"]),
            ("lanes (junction / road)", f"{sf['lanes']} ({sf['junction_lanes']} / {sf['road_lanes']})", "1524 (868 / 656)")]
    out = ["### San Francisco (input)\n", md_table(("", "ours", "paper"), rows),
           "\n### Extracted feature space (paper Table I)\n",
           md_table(("F_road", "F_ctrl", "F_xwlk", "F_rot"),
                    [(sp.get("road_counts"), sp.get("controls"), sp.get("crosswalks"), _ranges(sp))]),
           "\n### Generated maps\n",
           md_table(("map", "seed", "junctions (paper)", "3-leg / 4-leg", "signal / stop / bare", "crosswalk junctions",
                     "roads", "lanes"),
                    [(k, r["seeds"][k], f"{v['junctions']} ({PAPER['generated_junctions']})",
                      f"{v['legs'].get('3', 0)} / {v['legs'].get('4', 0)}", f"{v['signal']} / {v['stop']} / {v['bare']}",
                      v["crosswalk_junctions"], v["roads"], v["lanes"]) for k, v in s.items() if k != "San Francisco"]),
           f"\nReading the Apollo file took {r['read_s']:.2f} s, extraction {r['extract_s']:.2f} s.\n"]
    return "".join(out)


# ---- driving (RQ2-RQ4) -----------------------------------------------------------------------------
@dataclass(frozen=True)
class MapRun:
    """One map's route-coverage suite, run with the baseline planner and line coverage."""

    name: str
    map_path: str
    junctions: int  # junctions of the map
    routes: int  # routes of the whole suite
    manoeuvres: int
    result: Any  # SuiteResult of the scenarios actually run
    subset: str  # "" when every route ran, else what was left out and why


def _scenario_machinery():
    try:
        from feat2map.scenarios import metrics, rollout, routes
        from feat2map.scenarios import planner  # noqa: F401
    except ImportError as exc:
        raise ExperimentError(f"the scenario machinery is not available ({exc})", "feat2map.scenarios") from None
    return routes, rollout, metrics


def drive_map(settings: Settings, name: str, map_path: Path, junction_subset: Sequence[str] | None = None) -> MapRun:
    """Build the route-coverage suite of a map and run it (within the settings' budget)."""
    routes, rollout, _ = _scenario_machinery()
    from feat2map.readers import read_map
    from feat2map.scenarios.scenario import Scenario

    m = read_map(map_path)
    moves = routes.manoeuvres(m)
    notes = [] if m.junctions else ["no junction manoeuvres: driven as laps (drive_lap)"]
    if junction_subset is not None:
        keep = set(junction_subset)
        moves = [mv for mv in moves if mv[0] in keep]
        notes.append(f"manoeuvres of {len(keep)} of {len(m.junctions)} junctions")
    rts = routes.coverage_routes(m, settings.max_junctions, moves)
    scenarios = [Scenario(name=f"{name}-r{i:03d}", map=str(map_path.resolve()), route=r,
                          traffic_vehicles=settings.traffic, seed=i,
                          duration=routes.route_duration(m, r) + settings.duration_slack_s)
                 for i, r in enumerate(rts)]
    todo = scenarios if settings.max_scenarios is None else scenarios[:settings.max_scenarios]
    outcomes = []
    t0 = time.perf_counter()
    if settings.budget_s is None:  # one pool for the whole suite
        if todo:
            outcomes = list(rollout.run_suite(todo, "baseline", workers=settings.workers, progress=settings.progress,
                                              coverage=True, record_failure_gif=False).outcomes)
    else:  # chunks of `workers` scenarios until the budget is spent
        chunk = max(1, settings.workers)
        bar = tqdm(total=len(todo), desc=f"drive {name}", unit="scenario", disable=None if settings.progress else True)
        for i in range(0, len(todo), chunk):
            if time.perf_counter() - t0 > settings.budget_s:
                break
            res = rollout.run_suite(todo[i:i + chunk], "baseline", workers=settings.workers, progress=False,
                                    coverage=True, record_failure_gif=False)
            outcomes.extend(res.outcomes)
            bar.update(len(res.outcomes))
        bar.close()
    if len(outcomes) < len(scenarios):
        why = (f"budget of {settings.budget_s:.0f} s" if settings.budget_s is not None
               and len(outcomes) < len(todo) else f"--max-scenarios {settings.max_scenarios}")
        notes.append(f"{len(outcomes)} of {len(scenarios)} routes driven ({why})")
    result = rollout.SuiteResult(name=name, planner="baseline", outcomes=tuple(outcomes), coverage=True,
                                 workers=settings.workers, wall_s=time.perf_counter() - t0)
    return MapRun(name, str(map_path), len(m.junctions), len(scenarios), len(moves), result, "; ".join(notes))


def drive_lap(map_path: Path, seed: int = 0, traffic: int = 4) -> dict[str, Any]:
    """One lap of a map without junctions (the road circle) with the baseline planner: a lane
    route from the first lane round to itself."""
    import gymnasium as gym

    from feat2map.scenarios.planner import BaselinePlanner

    m = native.load(map_path)
    start = next(iter(m.lanes))
    env = gym.make("feat2map/MapFile-v0", config={
        "map_file": str(map_path), "route": {"from_lane": start, "to_lane": start}, "traffic_vehicles": traffic,
        "action": BaselinePlanner.action_config, "policy_frequency": 5, "duration": 120})
    planner = BaselinePlanner()
    obs, info = env.reset(seed=seed)
    planner.reset(env)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(planner.act(obs, info))
        done = terminated or truncated
    env.close()
    return {"completed": bool(info["route_completed"]), "collision": bool(info["collision"]),
            "off_road": bool(info["off_road"]), "sim_s": round(float(info["time"]), 1),
            "violations": dict(info["violations"]), "stage_path": list(planner.stage_path())}


def stage_label(name: str) -> str:
    """Short label of a "SCENARIO.Stage" name: the baseline planner's stages already use the
    paper's abbreviations (LF, T_A, S_PS, ...), so the stage part is the label."""
    scen, _, stage = name.partition(".")
    return stage or scen


def junction_paths(outcome: Any) -> list[tuple[str, tuple[str, ...]]]:
    """Per junction the ego drove through: the planner's stages there in order, across
    scenarios (a right turn on red may continue as a protected crossing when the light turns
    green), as the paper counts paths from road (LF) back to road. A junction where the
    planner never leaves lane following gives the `LF`-only path (empty tuple here)."""
    per: dict[str, list[str]] = {}
    for _, _, junction, scenario, stage in outcome.events:
        if junction is None:
            continue
        name = f"{scenario}.{stage}"
        seq = per.setdefault(str(junction), [])
        if not seq or seq[-1] != name:
            seq.append(name)
    return [(j, tuple(per.get(j, ()))) for j in dict.fromkeys(outcome.junctions)]


def path_label(path: Sequence[str], lane_follow: str) -> str:
    """`LF -> T_A -> T_C -> LF` for a junction's stage path."""
    inner = [stage_label(s) for s in path if s.partition(".")[0] != lane_follow.partition(".")[0]]
    return " -> ".join([stage_label(lane_follow)] + inner + ([stage_label(lane_follow)] if inner else []))


def run_summary(run: MapRun, lane_follow: str) -> dict[str, Any]:
    """Table row and plot data of one map's run."""
    from feat2map.scenarios.metrics import junctions_to_reach, suite_coverage

    cov = suite_coverage(run.result)
    paths: dict[str, set[str]] = {}
    for o in run.result.outcomes:
        for j, p in junction_paths(o):
            paths.setdefault(path_label(p, lane_follow), set()).add(j)
    counts = run.result.counts()
    return {
        "map": run.name, "map_path": run.map_path, "junctions": run.junctions, "manoeuvres": run.manoeuvres,
        "routes": run.routes, "driven": len(run.result.outcomes), "subset": run.subset,
        "outcomes": {k: v for k, v in counts.items() if v}, "junctions_driven": len(cov.junctions),
        "lines": len(cov.all_lines), "junction_order": list(cov.junctions),
        "accumulated_lines": list(cov.accumulated_lines), "new_lines": list(cov.new_lines()),
        "road_lines": len(cov.lines.get("(road)", ())),
        "junctions_to_95pct_lines": junctions_to_reach(cov.accumulated_lines),
        "transitions": sorted(f"{a} -> {b}" for a, b in cov.all_transitions),
        "accumulated_transitions": list(cov.accumulated_transitions),
        "stage_paths": {p: len(js) for p, js in sorted(paths.items())},
        "path_junctions": {p: sorted(js) for p, js in sorted(paths.items())},
        "sim_s": round(sum(o.sim_s for o in run.result.outcomes), 1), "wall_s": round(run.result.wall_s, 1),
    }


def lane_follow_name(runs: Sequence[MapRun]) -> str:
    """The planner's lane-following stage ("Scenario.Stage"): its most frequent event."""
    from collections import Counter

    c = Counter(f"{e[3]}.{e[4]}" for r in runs for o in r.result.outcomes for e in o.events)
    return c.most_common(1)[0][0] if c else "LaneFollow.LaneFollow"


def plot_lines(summaries: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Fig. 6a: accumulated planner lines per junction, one panel per map; junctions that add
    no new line in light blue."""
    fig, axes = plt.subplots(len(summaries), 1, figsize=(9, 1.9 * len(summaries) + 0.6), squeeze=False)
    top = max([max(s["accumulated_lines"] or [0]) for s in summaries] + [1])
    for ax, s in zip(axes.flat, summaries):
        acc, new = s["accumulated_lines"], s["new_lines"]
        x = list(range(len(acc)))
        ax.bar(x, acc, color=[NEW_LINES_COLOUR if n > 0 else NO_NEW_LINES_COLOUR for n in new], width=0.85)
        dup = sum(n == 0 for n in new)
        ax.set_ylim(0, top * 1.08)
        ax.set_xlim(-0.8, max(len(acc), 8) - 0.2)
        ax.set_ylabel("lines", fontsize=8)
        ax.set_title(f"{s['map']}: {s['lines']} lines over {len(acc)} junctions ({dup} add nothing new)",
                     fontsize=9, loc="left")
        ax.tick_params(labelsize=7)
    axes.flat[-1].set_xlabel("junction (order first driven)")
    fig.suptitle("Accumulated baseline-planner line coverage per junction", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def plot_stages(summaries: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Figs. 6b/7: which stage paths (per junction, LF to LF) and stage transitions each map covers."""
    paths = sorted({p for s in summaries for p in s["stage_paths"]}, key=lambda p: (p.count("->"), p))
    trans = sorted({t for s in summaries for t in s["transitions"]})
    rows = [("path", p) for p in paths] + [("transition", t) for t in trans]
    fig, ax = plt.subplots(figsize=(2.2 + 1.1 * len(summaries), 0.8 + 0.28 * len(rows)))
    for i, (kind, item) in enumerate(rows):
        for k, s in enumerate(summaries):
            if kind == "path":
                n = s["stage_paths"].get(item, 0)
                covered, text = n > 0, str(n) if n else ""
            else:
                covered, text = item in s["transitions"], ""
            ax.add_patch(plt.Rectangle((k - 0.45, i - 0.4), 0.9, 0.8, color=NEW_LINES_COLOUR if covered else "#e0e0e0"))
            if text:
                ax.text(k, i, text, ha="center", va="center", fontsize=7, color="white")
    ax.set_xlim(-0.6, len(summaries) - 0.4)
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.set_xticks(range(len(summaries)), [s["map"] for s in summaries], fontsize=8)
    ax.set_yticks(range(len(rows)), [item if kind == "path" else " -> ".join(stage_label(x) for x in item.split(" -> "))
                                     for kind, item in rows], fontsize=7)
    if paths and trans:
        ax.axhline(len(paths) - 0.5, color="k", lw=0.8)
    ax.set_title("stage paths (junctions) / transitions", fontsize=9)
    ax.tick_params(length=0)
    for sp in ax.spines.values():
        sp.set_visible(False)
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def _stage_machine() -> tuple[dict[str, tuple[str, ...]], set[tuple[str, str]]]:
    """The baseline planner's scenarios, their stages, and the stage transitions it can make."""
    from feat2map.scenarios import planner as pl

    stages = dict(pl.SCENARIO_STAGES)
    edges: set[tuple[str, str]] = set()
    lf = f"{pl.LANE_FOLLOW}.LF"
    for scen, st in stages.items():
        if scen == pl.LANE_FOLLOW:
            continue
        names = [f"{scen}.{x}" for x in st]
        edges.add((lf, names[0]))
        edges.update(zip(names, names[1:]))
        cruise = f"{scen}.{pl.CRUISE_STAGE[scen]}"
        edges.update((n, cruise) for n in names[:-1] if n != cruise)  # any stage may skip to cruising
        edges.add((cruise, lf))
    return stages, edges


def plot_stage_graph(summaries: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Fig. 7: the planner's scenarios and stages as a graph per map, covered transitions and
    stages in orange, the rest grey (LF drawn at both ends)."""
    stages, edges = _stage_machine()
    rows = [sc for sc in stages if len(stages[sc]) > 1 or sc != next(iter(stages))]
    lf_name = next(f"{sc}.{st[0]}" for sc, st in stages.items() if st == ("LF",))
    rows = [sc for sc in stages if f"{sc}.{stages[sc][0]}" != lf_name]
    width = max(len(stages[sc]) for sc in rows) + 1
    fig, axes = plt.subplots(1, len(summaries), figsize=(3.3 * len(summaries), 0.55 * len(rows) + 1.0), squeeze=False)
    for ax, s in zip(axes.flat, summaries):
        covered = {tuple(t.split(" -> ")) for t in s["transitions"]}
        seen = {x for t in covered for x in t}
        pos = {}
        for r, sc in enumerate(rows):
            for k, st in enumerate(stages[sc]):
                pos[f"{sc}.{st}"] = (k + 1, -r)
        mid = -(len(rows) - 1) / 2
        pos_in, pos_out = (0, mid), (width, mid)
        for a, b in sorted(edges | covered):
            pa = pos_in if a == lf_name else pos.get(a)
            pb = pos_out if b == lf_name else pos.get(b)
            if pa is None or pb is None:
                continue
            on = (a, b) in covered
            ax.annotate("", xy=pb, xytext=pa, zorder=1, arrowprops=dict(
                arrowstyle="-|>", lw=1.3 if on else 0.6, color=NEW_LINES_COLOUR if on else "#bdbdbd",
                shrinkA=7, shrinkB=7, connectionstyle="arc3,rad=0.15" if pb[0] - pa[0] > 1 and pa[1] == pb[1] else None))
        for name, (x, y) in list(pos.items()) + [(lf_name, pos_in), (lf_name, pos_out)]:
            on = name in seen
            ax.text(x, y, stage_label(name), ha="center", va="center", fontsize=6.5, zorder=3,
                    bbox=dict(boxstyle="round,pad=0.25", fc=NEW_LINES_COLOUR if on else "#eeeeee",
                              ec="#616161" if on else "#bdbdbd", lw=0.5), color="white" if on else "#9e9e9e")
        ax.set_xlim(-0.6, width + 0.6)
        ax.set_ylim(-len(rows) + 0.4, 0.6)
        ax.set_axis_off()
        ax.set_title(f"{s['map']}: {len(covered)} transitions", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)


def coverage_markdown(summaries: Sequence[Mapping[str, Any]], lane_follow: str) -> str:
    """The RQ2/RQ3 table: junctions, routes, lines covered, stage paths covered per map."""
    rows = []
    for s in summaries:
        paper = PAPER["lines"].get(s["map"].split()[0], "-")
        rows.append((s["map"], s["junctions"], s["junctions_driven"], f"{s['driven']} / {s['routes']}",
                     ", ".join(f"{k} {v}" for k, v in s["outcomes"].items()), s["lines"], paper,
                     s["junctions_to_95pct_lines"], len(s["stage_paths"]), len(s["transitions"]), s["subset"] or "all routes"))
    head = ("map", "junctions", "junctions driven", "routes driven / suite", "outcomes", "planner lines covered",
            "paper (Apollo lines)", "junctions to 95% lines", "stage paths", "transitions", "subset")
    paths = sorted({p for s in summaries for p in s["stage_paths"]}, key=lambda p: (p.count("->"), p))
    prow = [(p, *[s["stage_paths"].get(p, 0) for s in summaries]) for p in paths]
    return (md_table(head, rows) + f"\nStage paths per junction (lane following = `{lane_follow}` = "
            f"{stage_label(lane_follow)}; numbers = junctions where the path occurred):\n\n"
            + md_table(("stage path", *[s["map"] for s in summaries]), prow))


def save_run(run: MapRun, folder: Path) -> None:
    write_json(folder / f"{run.name.replace(' ', '_')}_suite.json",
               {**run.result.to_dict(), "routes": run.routes, "subset": run.subset, "map_path": run.map_path})


def load_run(path: Path) -> MapRun | None:
    """A map's run saved by `save_run` (to reuse RQ2's drives in RQ3), or None if absent."""
    if not path.is_file():
        return None
    from feat2map.scenarios.rollout import SuiteResult

    d = json.loads(path.read_text())
    res = SuiteResult.from_dict(d, str(path))
    m = native.load(d["map_path"]) if d["map_path"].endswith(".json") else read_map_file(Path(d["map_path"]))
    from feat2map.scenarios.routes import manoeuvres

    return MapRun(res.name, d["map_path"], len(m.junctions), int(d["routes"]), len(manoeuvres(m)), res, d["subset"])


def read_map_file(path: Path) -> HDMap:
    from feat2map.readers import read_map

    return read_map(path)


def measure(settings: Settings, rq: int, maps: Sequence[tuple[str, Path, Sequence[str] | None] | MapRun]
            ) -> dict[str, Any]:
    """Drive every map (or take an earlier run), save suites, tables and Figs. 6-7 for one RQ."""
    folder = settings.out / f"rq{rq}"
    folder.mkdir(parents=True, exist_ok=True)
    runs = []
    for item in maps:
        if isinstance(item, MapRun):
            runs.append(item)
            continue
        name, path, subset = item
        saved = load_run(folder / f"{name.replace(' ', '_')}_suite.json") if settings.reuse else None
        if saved is not None:
            runs.append(saved)
            continue
        run = drive_map(settings, name, path, subset)
        save_run(run, folder)
        runs.append(run)
    lf = lane_follow_name(runs)
    summaries = [run_summary(r, lf) for r in runs]
    pics = [plot_lines(summaries, folder / f"rq{rq}_lines.png"), plot_stages(summaries, folder / f"rq{rq}_stages.png"),
            plot_stage_graph(summaries, folder / f"rq{rq}_stage_graph.png")]
    table = coverage_markdown(summaries, lf)
    atomic.write_text(folder / f"rq{rq}.md", table)
    result = {"lane_follow": lf, "maps": summaries, "settings": {
        "max_junctions": settings.max_junctions, "budget_s": settings.budget_s,
        "max_scenarios": settings.max_scenarios, "sf_junctions": settings.sf_junctions,
        "traffic": settings.traffic, "workers": settings.workers}}
    write_json(folder / f"rq{rq}.json", result)
    copy_to_docs(settings, pics + [folder / f"rq{rq}.md"])
    return result


def _generated_or_load(settings: Settings) -> dict[str, Path]:
    """M1-M3 from RQ1's output folder, running RQ1 first when they are not there."""
    folder = settings.out / "rq1"
    paths = {f"M{i + 1}": folder / f"M{i + 1}.json" for i in range(len(settings.seeds))}
    if not all(p.is_file() for p in paths.values()):
        rq1(settings)
    return paths


def rq2(settings: Settings) -> dict[str, Any]:
    """SF and M1-M3 driven with the baseline planner; line and behaviour coverage."""
    gen = _generated_or_load(settings)
    folder = settings.out / "rq2"
    folder.mkdir(parents=True, exist_ok=True)
    sf = read_input(settings, "san_francisco")
    sf_path = settings.input("san_francisco").resolve()  # driven from the Apollo file itself
    subset = None
    if settings.sf_junctions is not None:
        subset = [jid for jid in sf.junctions][:settings.sf_junctions]
    maps = [("SF", sf_path, subset)] + [(k, p, None) for k, p in gen.items()]
    result = measure(settings, 2, maps)
    write_json(folder / "rq2.json", result)
    return result


def rq3(settings: Settings) -> dict[str, Any]:
    """M4 from SF + GoMentum + Shalun: feature space, picture, the same measurements as RQ2."""
    folder = settings.out / "rq3"
    folder.mkdir(parents=True, exist_ok=True)
    junctions, spaces, stats = [], {}, {}
    for name in ("san_francisco", "gomentum", "shalun"):
        m = read_input(settings, name)
        js = extract_junctions(m, name)
        junctions += js
        spaces[name] = map_feature(js).to_dict() if js else None
        stats[name] = map_stats(m, js)
    space = map_feature(junctions)
    atomic.write_text(folder / "m4_features.json", space.to_json())
    if settings.reuse and (folder / "M4.json").is_file():  # the map the saved suite drove
        gen = Generated(space, {"M4": native.load(folder / "M4.json")}, {"M4": folder / "M4.json"})
    else:
        gen = generate_maps(space, [("M4", settings.m4_seed)], folder)
    m4 = gen.maps["M4"]
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    draw_map(m4, ax)
    control_legend(ax)
    ax.set_title(f"M4 (SF + GoMentum + Shalun, seed {settings.m4_seed}): {len(m4.junctions)} junctions")
    fig.tight_layout()
    pics = [save_figure(fig, folder / "rq3_m4.png")]
    render_junctions(m4, folder / "rq3_m4_junctions.png", dpi=70)
    pics.append(folder / "rq3_m4_junctions.png")
    copy_to_docs(settings, pics)
    earlier = [load_run(settings.out / "rq2" / f"{k}_suite.json") for k in ("SF", "M1", "M2", "M3")]
    earlier = [r for r in earlier if r is not None]
    if not any(r.name == "M1" for r in earlier):  # RQ2 not run: drive M1 as the reference
        earlier = [("M1", _generated_or_load(settings)["M1"], None)]
    measured = measure(settings, 3, earlier + [("M4", gen.paths["M4"], None)])
    m4_sum = measured["maps"][-1]
    before = [x for x in measured["maps"][:-1] if x["map"] != "SF"] or measured["maps"][:-1]  # M1-M3, as the paper
    seen_paths = set().union(*(x["stage_paths"] for x in before))
    seen_trans = set().union(*(x["transitions"] for x in before))
    all_paths = set().union(*(x["stage_paths"] for x in measured["maps"][:-1]))
    bare = [jid for jid, j in m4.junctions.items() if j.feature is not None and j.feature.control == "bare"]
    result = {"inputs": {k: str(settings.input(k)) for k in spaces}, "input_stats": stats,
              "input_spaces": spaces, "feature_space": space.to_dict(), "m4_stats": map_stats(m4),
              "bare_junctions": bare, "measured": measured,
              "compared_with": [x["map"] for x in before],
              "paths_only_in_m4": sorted(set(m4_sum["stage_paths"]) - seen_paths),
              "transitions_only_in_m4": sorted(set(m4_sum["transitions"]) - seen_trans),
              "paths_only_in_m4_of_all": sorted(set(m4_sum["stage_paths"]) - all_paths),
              "m4_bare_path_junctions": {p: js for p, js in m4_sum["path_junctions"].items() if "B_A" in p}}
    write_json(folder / "rq3_summary.json", result)
    text = (md_table(("input", "junctions", "signal / stop / bare", "crosswalk junctions", "F_ctrl"),
                     [(k, v["junctions"], f"{v['signal']} / {v['stop']} / {v['bare']}", v["crosswalk_junctions"],
                       (spaces[k] or {}).get("controls")) for k, v in stats.items()])
            + "\n" + md_table(("merged F_road", "F_ctrl", "F_xwlk", "F_rot", "M4 junctions (paper)"),
                              [(space.to_dict().get("road_counts"), space.to_dict().get("controls"),
                                space.to_dict().get("crosswalks"), _ranges(space.to_dict()),
                                f"{len(m4.junctions)} ({PAPER['m4_junctions']})")])
            + f"\nStage paths only in M4 (not in {', '.join(result['compared_with'])}): "
              f"{', '.join(f'`{p}`' for p in result['paths_only_in_m4']) or 'none'}; transitions: "
              f"{', '.join(f'`{t}`' for t in result['transitions_only_in_m4']) or 'none'}. Bare junctions of M4: "
              f"{', '.join(bare) or 'none'}.\n")
    atomic.write_text(folder / "rq3_inputs.md", text)
    copy_to_docs(settings, [folder / "rq3_inputs.md"])
    return result


# ---- RQ4 -------------------------------------------------------------------------------------------
def build_custom(settings: Settings) -> dict[str, tuple[HDMap, str]]:
    """The three custom maps from their spec files (feat2map.spec); name -> (map, how built)."""
    try:
        from feat2map import spec as specmod
    except ImportError as exc:
        raise ExperimentError(f"custom specs are not available ({exc})", "feat2map.spec") from None
    out = {}
    for name, rel in CUSTOM_SPECS.items():
        path = ROOT / rel
        if not path.is_file():
            raise ExperimentError("spec file missing", str(path))
        out[name] = (spec_map(specmod, path), rel)
    return out


def spec_map(specmod: Any, path: Path) -> HDMap:
    """Build one spec file's map with whatever entry point feat2map.spec offers."""
    for fn in ("build_from_spec", "generate_from_spec", "build_spec_file", "build"):
        f = getattr(specmod, fn, None)
        if callable(f):
            try:
                return f(path)
            except TypeError:
                continue
    load = getattr(specmod, "load_spec", None)
    build = getattr(specmod, "build_map", None) or getattr(specmod, "build_spec", None)
    if callable(load) and callable(build):
        return build(load(path))
    raise ExperimentError("feat2map.spec has no entry point to build a map from a spec file", str(path))


def rq4(settings: Settings) -> dict[str, Any]:
    """Build the custom maps, draw Fig. 8, drive each with the baseline planner."""
    folder = settings.out / "rq4"
    folder.mkdir(parents=True, exist_ok=True)
    built = build_custom(settings)
    name, seed = HIGHWAY_CITY
    built[name] = (feat2map.generate(HIGHWAY_CITY_FEATURE_SPACE, seed=seed), f"HIGHWAY_CITY_FEATURE_SPACE, seed {seed}")
    paths = {}
    for name, (m, rel) in built.items():
        paths[name] = folder / f"{name.replace(' ', '_')}.json"
        if settings.reuse and paths[name].is_file():  # the map the saved suite drove
            built[name] = (native.load(paths[name]), rel)
        else:
            native.save(m, paths[name])
    pic = picture_maps([(name, m, None) for name, (m, _) in built.items()], folder / "rq4_custom.png")
    copy_to_docs(settings, [pic])
    measured = measure(settings, 4, [(name, p, None) for name, p in paths.items()])
    details = {}
    for name, (m, rel) in built.items():
        feats = [j.feature for j in m.junctions.values() if j.feature is not None]
        details[name] = {"spec": rel, "stats": map_stats(m),
                         "junction_features": [{"n": f.n_roads, "rotation": [round(a, 1) for a in f.rotation],
                                                "control": f.control, "crosswalk": f.crosswalk,
                                                "road_types": list(f.road_types)} for f in feats]}
        if not m.junctions:
            details[name]["lap"] = drive_lap(paths[name])
    hc_map, _ = built[HIGHWAY_CITY[0]]
    hc_run = load_run(folder / f"{HIGHWAY_CITY[0].replace(' ', '_')}_suite.json")
    features_md = feature_paths_markdown(hc_map, hc_run, settings, measured["lane_follow"]) if hc_run else ""
    laps = [f"- {name}: one lap with the baseline planner: " + ", ".join(f"{k} {v}" for k, v in d["lap"].items())
            for name, d in details.items() if "lap" in d]
    md = folder / "rq4.md"
    atomic.write_text(md, md.read_text() + features_md + ("\nMaps without junctions, driven as laps (lane routes):\n\n"
                                                          + "\n".join(laps) + "\n" if laps else ""))
    copy_to_docs(settings, [md])
    result = {"maps": details, "measured": measured}
    write_json(folder / "rq4_summary.json", result)
    return result


def feature_moves(m: HDMap) -> dict[str, set[str]]:
    """The future work's features of a map as what a route takes: feature -> the junction lanes
    (a ramp merge or diverge, a filter lane) or road lanes (across a mid-block crosswalk) of it."""
    from shapely.geometry import LineString, Polygon

    from feat2map.extract import extract_filters
    from feat2map.extract_ramps import ramp_moves

    out: dict[str, set[str]] = {"ramp merge": set(), "ramp diverge": set(), "filter lane": set(),
                                "mid-block crosswalk": set()}
    for lane, move in ramp_moves(m).items():
        out[f"ramp {move}"].add(lane)
    out["filter lane"] = {f.id for f in extract_filters(m)}
    walks = [Polygon(c.polygon) for c in m.crosswalks.values() if c.junction_id is None]
    out["mid-block crosswalk"] = {ln.id for ln in m.lanes.values() if ln.junction_id is None
                                  and any(LineString(ln.centerline).intersects(w) for w in walks)}
    return out


def feature_paths_markdown(m: HDMap, run: MapRun, settings: Settings, lane_follow: str) -> str:
    """Per feature of the future work, the scenarios of `run` whose route takes it, their outcomes
    and the planner's stage paths there (at the junction; on the road, for a mid-block crosswalk)."""
    from feat2map.routes import manoeuvre_lanes

    routes, _, _ = _scenario_machinery()
    rts = routes.coverage_routes(m, settings.max_junctions, routes.manoeuvres(m))
    by_name = {o.name: o for o in run.result.outcomes}
    rows = []
    for feature, lanes in feature_moves(m).items():
        n, outs, paths = 0, {}, set()
        for i, route in enumerate(rts):
            o = by_name.get(f"{run.name}-r{i:03d}")
            takes = [mv for mv in route if any(ln.id in lanes for ln in manoeuvre_lanes(m, mv))]
            roads = {r for mv in route for r in mv[1:]}
            if o is None or not (takes or any(m.lanes[x].road_id in roads for x in lanes if feature.startswith("mid"))):
                continue
            n += 1
            outs[o.outcome] = outs.get(o.outcome, 0) + 1
            at = {mv[0] for mv in takes}
            paths |= {path_label(p, lane_follow) for j, p in junction_paths(o) if j in at}
        rows.append((feature, len(lanes), n, ", ".join(f"{k} {v}" for k, v in sorted(outs.items())) or "-",
                     "; ".join(sorted(paths)) or "LF (no junction scenario: the crossing's rules in lane following)"))
    return (f"\nThe future work's features in the {run.name} map: the scenarios whose route takes each, their "
            "outcomes and the planner's stage paths there:\n\n"
            + md_table(("feature", "lanes", "scenarios", "outcomes", "stage paths there"), rows))


# ---- command line ----------------------------------------------------------------------------------
RQS: dict[int, Callable[[Settings], dict[str, Any]]] = {1: rq1, 2: rq2, 3: rq3, 4: rq4}


def parse_rqs(text: str) -> list[int]:
    if text == "all":
        return sorted(RQS)
    try:
        rqs = [int(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 1, 2, 3, 4, a list like 1,4 or 'all', got {text!r}") from None
    bad = [x for x in rqs if x not in RQS]
    if bad:
        raise argparse.ArgumentTypeError(f"no research question {bad[0]} (choose 1-4 or all)")
    return rqs


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="experiments.py", description=__doc__.splitlines()[0])
    ap.add_argument("--rq", type=parse_rqs, default=[1, 2, 3, 4], help="1, 2, 3, 4, a list (1,4) or all")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--docs", type=Path, default=DEFAULT_DOCS, help="where final pictures/tables are copied")
    ap.add_argument("--no-docs", action="store_true", help="do not copy anything to docs/")
    ap.add_argument("--maps", type=Path, default=DEFAULT_MAPS, help="folder of the real maps (../shared/maps)")
    ap.add_argument("--input", action="append", default=[], metavar="NAME=PATH",
                    help=f"use another file for a real map ({', '.join(REAL_MAPS)})")
    ap.add_argument("--seeds", type=int, nargs=3, default=list(SEEDS), help="seeds of M1-M3")
    ap.add_argument("--sf-junctions", type=int, help="RQ2: drive only the manoeuvres of the first N SF junctions")
    ap.add_argument("--budget", type=float, help="wall-clock budget per map's suite [s]")
    ap.add_argument("--max-scenarios", type=int, help="at most this many routes per map")
    ap.add_argument("--route-junctions", type=int, default=4, help="junctions per coverage route")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--reuse", action="store_true",
                    help="rebuild tables and figures from suites saved in OUT by an earlier run (no driving)")
    ap.add_argument("--quiet", action="store_true")
    return ap


def settings_from_args(args: argparse.Namespace) -> Settings:
    inputs = {}
    for item in args.input:
        name, sep, path = item.partition("=")
        if not sep or name not in REAL_MAPS:
            raise ExperimentError(f"expected NAME=PATH with NAME one of {', '.join(REAL_MAPS)}", f"--input {item!r}")
        inputs[name] = Path(path)
    for flag, v in (("--sf-junctions", args.sf_junctions), ("--max-scenarios", args.max_scenarios),
                    ("--workers", args.workers), ("--route-junctions", args.route_junctions)):
        if v is not None and v < 1:
            raise ExperimentError("must be at least 1", f"{flag} {v}")
    if args.budget is not None and args.budget <= 0:
        raise ExperimentError("must be positive", f"--budget {args.budget}")
    return Settings(out=args.out, docs=None if args.no_docs else args.docs, maps=args.maps, inputs=inputs,
                    seeds=tuple(args.seeds), sf_junctions=args.sf_junctions, budget_s=args.budget,
                    max_scenarios=args.max_scenarios, max_junctions=args.route_junctions, workers=args.workers,
                    reuse=args.reuse, progress=not args.quiet)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        settings = settings_from_args(args)
        missing = missing_inputs(settings, args.rq)
        if missing:
            raise ExperimentError(
                f"missing real map(s) {', '.join(missing)}: RQ{','.join(map(str, args.rq))} need(s) the SVL "
                f"Apollo maps listed in ../shared/maps/SOURCES.md (set --maps or --input NAME=PATH)",
                str(settings.maps))
        for rq in args.rq:
            t = time.perf_counter()
            RQS[rq](settings)
            print(f"RQ{rq}: done in {time.perf_counter() - t:.0f} s -> {settings.out / f'rq{rq}'}")
    except Feat2MapError as exc:
        print(f"experiments: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
