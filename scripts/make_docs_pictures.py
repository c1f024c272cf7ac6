"""Regenerate every picture and generated table in docs/ from the current code, so the docs
cannot drift from what the code draws. One job per picture (or group); each writes its files
atomically and prints them.

    .venv/bin/python scripts/make_docs_pictures.py              # the fast pictures (about a minute)
    .venv/bin/python scripts/make_docs_pictures.py --slow       # also the slow ones (see --list): the
        # M1 vs M1x3 rollout comparison (~10 min), docs/benchmarks.md (~10 min), docs/experiments/ (hours)
        # and the PPO run of examples/README.md (~30 min; take it on a quiet machine)
    .venv/bin/python scripts/make_docs_pictures.py --only m1 drive

Jobs that read the real maps skip (saying so) when ../shared/maps is absent; the netconvert
picture needs the dev extra's eclipse-sumo.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import feat2map  # noqa: E402
from feat2map import atomic  # noqa: E402
from feat2map.cli import main as cli  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
SHARED_MAPS = REPO.parent / "shared" / "maps"
SPECS = {"spec_mega.png": "mega_junction", "spec_one_way.png": "one_way_t", "spec_circle.png": "road_circle",
         "spec_multi_lane.png": "multi_lane", "spec_midblock.png": "midblock", "spec_filter_lanes.png": "filter_lanes",
         "spec_ramps.png": "ramps", "spec_motorway_links.png": "motorway_links",
         "spec_highway_city.png": "highway_city"}


@dataclass(frozen=True)
class Job:
    name: str
    makes: str  # what it writes, for --list
    run: Callable[[Path], list[Path]]  # (scratch folder) -> docs files written
    slow: bool = False
    needs_shared: bool = False


def run_cli(*args: str, ok: tuple[int, ...] = (0,)) -> None:
    with contextlib.redirect_stdout(io.StringIO()):  # this script prints what it wrote
        code = cli(list(args))
    if code not in ok:
        raise SystemExit(f"feat2map {' '.join(args)}: exit {code}")


def run_python(*args: str) -> None:
    subprocess.run([sys.executable, *args], cwd=REPO, check=True)


def copy(src: Path, name: str) -> Path:
    atomic.write_bytes(DOCS / name, src.read_bytes())
    return DOCS / name


def m1(tmp: Path) -> list[Path]:
    run_cli("generate", "--seed", "1", "--no-apollo", "--quiet", "--out", str(tmp / "m1"))
    return [copy(tmp / "m1" / "map.png", "m1.png"), copy(tmp / "m1" / "junctions.png", "m1_junctions.png")]


def drive(tmp: Path) -> list[Path]:
    run_cli("generate", "--seed", "1", "--no-apollo", "--no-picture", "--quiet", "--out", str(tmp / "m1"))
    run_python("examples/demo.py", "--map", str(tmp / "m1" / "map.json"), "--out", str(tmp))
    return [copy(tmp / "drive.png", "drive.png")]


def specs(tmp: Path) -> list[Path]:
    out = []
    for picture, spec in SPECS.items():
        run_cli("generate", "--spec", str(REPO / "examples" / f"{spec}.yaml"), "--no-apollo", "--quiet",
                "--out", str(tmp / spec))
        out.append(copy(tmp / spec / "map.png", picture))
    return out


def apollo_export(tmp: Path) -> list[Path]:
    """The Apollo export of a 3-junction map (the fixture of tests/formats/test_apollo_export.py)."""
    from feat2map.formats.apollo import render_problems, write_apollo

    J = feat2map.JunctionFeature.make
    m = feat2map.generate_from_features([J([0, 120, 240], "signal", True, lanes=[2, 2, 1]),
                                         J([0, 90, 180, 270], "stop", True),
                                         J([10, 80, 170, 260, 300], "bare", False)], seed=3)
    write_apollo(m, tmp / "apollo")
    render_problems(tmp / "apollo", DOCS / "apollo_export.png",
                    title="Apollo export of a 3-junction map (signalled T with 2-lane legs, all-way stop, bare 5-leg)")
    return [DOCS / "apollo_export.png"]


def env_frame(tmp: Path) -> list[Path]:
    """One frame of feat2map/JunctionGrid-v0: a signal and a stop junction, traffic, pedestrians."""
    import gymnasium as gym
    import matplotlib.pyplot as plt

    from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver

    J = feat2map.JunctionFeature.make
    feats = [J([0, 90, 180, 270], "signal", True), J([0, 90, 180, 270], "stop", True)]
    env = gym.make("feat2map/JunctionGrid-v0", render_mode="rgb_array", config={
        "features": [f.to_dict() for f in feats], "centering_position": [0.3, 0.5], "screen_width": 900,
        "screen_height": 520, "scaling": 3.6, "pedestrian_rate": 60.0, "traffic_vehicles": 8,
        "action": DRIVER_ACTION_CONFIG, "policy_frequency": 5, "duration": 80})
    env.reset(seed=2)
    driver = ScriptedDriver(env)
    for _ in range(15):
        env.step(driver.act())
    plt.imsave(tmp / "env_frame.png", env.render())
    env.close()
    return [copy(tmp / "env_frame.png", "env_frame.png")]


def extract_gomentum(tmp: Path) -> list[Path]:
    run_cli("extract", str(SHARED_MAPS / "apollo" / "gomentum" / "base_map.bin"), "--quiet", "--picture",
            str(tmp / "g.png"))
    return [copy(tmp / "g.png", "extract_gomentum.png")]


def validate_shalun(tmp: Path) -> list[Path]:
    run_cli("validate", str(SHARED_MAPS / "apollo" / "shalun"), "--quiet", "--picture", str(tmp / "s.png"), ok=(0, 1))
    return [copy(tmp / "s.png", "apollo_validate_shalun.png")]


def netconvert(tmp: Path) -> list[Path]:
    run_python("scripts/opendrive_netconvert.py", "--out", str(DOCS / "opendrive_netconvert.png"))
    return [DOCS / "opendrive_netconvert.png"]


def rollout_coverage(tmp: Path) -> list[Path]:
    """M1 against M1x3 (three junctions per feature combination): docs/rollout_coverage.png and the
    table between the markers in docs/rollouts.md."""
    from feat2map.scenarios.metrics import compare, junctions_to_reach, plot_accumulated, suite_coverage
    from feat2map.scenarios.report import load_result

    results, walls = {}, {}
    for name, extra in (("M1", []), ("M1x3", ["--samples-per-combination", "3"])):
        d = tmp / name
        run_cli("generate", "--seed", "1", *extra, "--no-apollo", "--no-picture", "--quiet", "--out", str(d))
        run_cli("suite", str(d / "map.json"), "--traffic", "2", "--name", name, "--out", str(d / "suite.yaml"))
        t0 = time.perf_counter()
        run_cli("rollout", str(d / "suite.yaml"), "--workers", "2", "--fail-on", "none", "--no-gif", "--quiet",
                "--line-coverage", "--out", str(d / "r"))
        walls[name] = time.perf_counter() - t0
        results[name] = load_result(d / "r")
    table = compare(results)
    plot_accumulated(table, tmp / "c.png", title="M1 vs M1x3: accumulated coverage by junction")
    rows = ["| map | scenarios | junctions | distinct stage paths | (scenario, stage path) pairs | transitions | "
            "planner lines | lines only this map covers | junctions to 95% of lines | wall time (2 workers) |",
            "|---|" + "---:|" * 9]
    for (name, r), row in zip(results.items(), table.rows):
        c = suite_coverage(r)
        rows.append(f"| {name} | {len(r.outcomes)} | {len(c.junctions)} | {len({p for _, p in c.paths})} | "
                    f"{len(c.all_pairs)} | {len(c.all_transitions)} | {len(c.all_lines)} | {row[-1]} | "
                    f"{junctions_to_reach(c.accumulated_lines)} | {walls[name]:.0f} s |")
    replace_marked(DOCS / "rollouts.md", "rollout_coverage", "\n".join(rows))
    return [copy(tmp / "c.png", "rollout_coverage.png"), DOCS / "rollouts.md"]


def architecture(tmp: Path) -> list[Path]:
    """docs/architecture.png: the layers and the data flow formats -> model -> envs -> scenarios."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    from feat2map.render import save_figure

    fig, ax = plt.subplots(figsize=(13.4, 6.2))
    ax.set_xlim(0, 13.4)
    ax.set_ylim(0, 6.2)
    ax.set_axis_off()
    layers = [  # (x, y, w, h, colour, title, lines)
        (0.2, 3.3, 2.6, 2.5, "#dbe9f6", "inputs", ["feature space (.json)", "spec (.yaml)", "real maps:",
                                                   "Apollo .bin/.txt", "OpenDRIVE .xodr", "native .json"]),
        (3.6, 3.3, 2.6, 2.5, "#fde2c8", "feat2map.formats", ["FORMATS: one package each", "read -> HDMap",
                                                             "write HDMap (atomic)", "validate -> [Problem]",
                                                             "base.py: Protocols"]),
        (3.6, 0.3, 2.6, 2.6, "#e4f3d8", "feat2map (map layer)", ["generate: features ->", "sampling, construct,",
                                                                 "layout -> HDMap", "extract: HDMap -> features",
                                                                 "phases, routes, angles,", "config (constants)"]),
        (7.0, 1.8, 2.6, 2.6, "#f2f2f2", "model.HDMap", ["frozen value: lanes, roads,", "junctions, signals,",
                                                        "stop signs, crosswalks", "(the one type every",
                                                        "layer exchanges)"]),
        (10.4, 3.3, 2.8, 2.5, "#e8def8", "feat2map.envs", ["MapNetwork (lanes, STRtree)", "rules, control",
                                                          "core (traffic arrays)", "MapEnv + subclasses",
                                                          "observation, DriverView"]),
        (10.4, 0.3, 2.8, 2.6, "#fbe3ea", "feat2map.scenarios", ["scenario: Suite (.yaml)", "routes: coverage",
                                                               "planner (baseline)", "rollout -> report",
                                                               "metrics, report.md/html"]),
    ]
    centre = {}
    for x, y, w, h, colour, title, lines in layers:
        ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.05", fc=colour, ec="#444", lw=1.2))
        ax.text(x + w / 2, y + h - 0.28, title, ha="center", va="center", fontsize=11, weight="bold")
        for k, line in enumerate(lines):
            ax.text(x + 0.15, y + h - 0.7 - 0.33 * k, line, ha="left", va="center", fontsize=8.5)
        centre[title] = (x, y, w, h)

    def arrow(a: str, b: str, label: str, sa: str, sb: str) -> None:
        def port(name: str, side: str) -> tuple[float, float]:
            x, y, w, h = centre[name]
            return {"l": (x, y + h / 2), "r": (x + w, y + h / 2), "t": (x + w / 2, y + h),
                    "b": (x + w / 2, y)}[side]
        (x0, y0), (x1, y1) = port(a, sa), port(b, sb)
        ax.add_patch(FancyArrowPatch((x0, y0), (x1, y1), arrowstyle="-|>", mutation_scale=14, lw=1.4,
                                     color="#333", connectionstyle="arc3,rad=0.0"))
        ax.text((x0 + x1) / 2, (y0 + y1) / 2 + 0.12, label, ha="center", va="bottom", fontsize=8, color="#333",
                bbox={"fc": "white", "ec": "none", "pad": 1})

    arrow("inputs", "feat2map.formats", "read_map", "r", "l")
    arrow("feat2map.formats", "model.HDMap", "HDMap", "r", "t")
    arrow("feat2map (map layer)", "model.HDMap", "generate", "r", "l")
    arrow("model.HDMap", "feat2map.envs", "MapNetwork", "r", "l")
    arrow("feat2map.envs", "feat2map.scenarios", "gym env, rules", "b", "t")
    ax.text(6.7, 5.95, "imports point downwards only: scenarios -> envs -> map layer / formats -> model "
            "(no cycles; formats never import envs or scenarios)", ha="center", fontsize=9, style="italic")
    ax.text(8.3, 0.7, "write_map: Apollo, OpenDRIVE, Lanelet2,\nCommonRoad, native; a Suite -> OpenSCENARIO",
            ha="center", fontsize=8.5, color="#555")
    out = DOCS / "architecture.png"
    save_figure(fig, out, 110)
    return [out]


def replace_marked(path: Path, name: str, body: str) -> None:
    """Replace the text between `<!-- make_docs_pictures: NAME -->` and `<!-- end NAME -->`."""
    text = path.read_text(encoding="utf-8")
    pat = re.compile(rf"(<!-- make_docs_pictures: {name} -->\n).*?(\n<!-- end {name} -->)", re.S)
    if not pat.search(text):
        raise SystemExit(f"{path}: no markers for {name}")
    atomic.write_text(path, pat.sub(lambda m: m.group(1) + body + m.group(2), text))


def benchmarks(tmp: Path) -> list[Path]:
    run_python("benchmarks/run_all.py")
    return [DOCS / "benchmarks.md"]


def experiments(tmp: Path) -> list[Path]:
    run_python("examples/experiments.py", "--rq", "all", "--workers", "2", "--quiet")
    return sorted((DOCS / "experiments").iterdir())


def ppo(tmp: Path) -> list[Path]:
    """The reported PPO run (examples/train_ppo.py, ~30 min on 2 cores): its pictures, and its
    per-cell table and wall times in examples/README.md. Take it on a quiet machine."""
    run_python("examples/train_ppo.py", "--out", str(tmp / "ppo"))
    readme = REPO / "examples" / "README.md"
    replace_marked(readme, "ppo", (tmp / "ppo" / "summary.md").read_text(encoding="utf-8").strip())
    return [copy(tmp / "ppo" / "learning_curve.png", "ppo_learning_curve.png"),
            copy(tmp / "ppo" / "success.png", "ppo_success.png"), readme]


JOBS = [
    Job("m1", "docs/m1.png, docs/m1_junctions.png (README)", m1),
    Job("architecture", "docs/architecture.png (docs/architecture.md)", architecture),
    Job("drive", "docs/drive.png", drive),
    Job("specs", ", ".join(f"docs/{p}" for p in SPECS), specs),
    Job("apollo_export", "docs/apollo_export.png", apollo_export),
    Job("env_frame", "docs/env_frame.png", env_frame),
    Job("extract_gomentum", "docs/extract_gomentum.png", extract_gomentum, needs_shared=True),
    Job("validate_shalun", "docs/apollo_validate_shalun.png", validate_shalun, needs_shared=True),
    Job("netconvert", "docs/opendrive_netconvert.png (needs eclipse-sumo)", netconvert),
    Job("rollout_coverage", "docs/rollout_coverage.png and its table in docs/rollouts.md", rollout_coverage, slow=True),
    Job("benchmarks", "docs/benchmarks.md (benchmarks/run_all.py)", benchmarks, slow=True),
    Job("experiments", "docs/experiments/ (examples/experiments.py --rq all)", experiments, slow=True,
        needs_shared=True),
    Job("ppo", "docs/ppo_learning_curve.png, docs/ppo_success.png and the table in examples/README.md "
        "(examples/train_ppo.py, ~30 min)", ppo, slow=True),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--slow", action="store_true", help="also run the slow jobs")
    ap.add_argument("--only", nargs="+", choices=[j.name for j in JOBS], metavar="JOB", help="run only these jobs")
    ap.add_argument("--list", action="store_true", help="list the jobs and what they write, then stop")
    args = ap.parse_args()
    if args.list:
        for j in JOBS:
            print(f"{j.name:<18} {'slow ' if j.slow else ''}{'needs ../shared ' if j.needs_shared else ''}-> {j.makes}")
        return
    for job in JOBS:
        if (args.only and job.name not in args.only) or (job.slow and not args.slow and not args.only):
            continue
        if job.needs_shared and not SHARED_MAPS.is_dir():
            print(f"{job.name}: skipped ({SHARED_MAPS} is absent)")
            continue
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            written = job.run(Path(tmp))
        print(f"{job.name} ({time.perf_counter() - t0:.0f} s): " + ", ".join(str(p.relative_to(REPO)) for p in written))


if __name__ == "__main__":
    main()
