"""Every benchmark table in one command, saved as docs/benchmarks.md.

Runs, one after another (never in parallel: the tables are wall-clock ratios measured on a
shared machine):
  1. generation time vs junction count        (benchmarks/bench_generate.py)
  2. extraction time for each real map          (benchmarks/bench_extract.py, when present;
                                                 else read + extract timed here)
     Apollo export and validation vs map size    (benchmarks/bench_apollo.py)
     route coverage and planner overhead         (benchmarks/bench_scenarios.py)
     and any other benchmarks/bench_*.py
  3. env steps/s: feat2map vs highway-env intersection-v1 (benchmarks/bench_env.py)
  4. rollout throughput: scenarios per minute per core with the baseline planner, plain and
     with line coverage measured (this file; baseline = the plain run in the same process)

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python benchmarks/run_all.py [--only NAME ...] [--no-save]
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DOC = ROOT / "docs" / "benchmarks.md"
ROLLOUT_SCENARIOS = 12  # scenarios per throughput run: enough for a stable rate, ~1 min per run


@dataclass(frozen=True)
class Table:
    """One benchmark's printed table (or the reason it was not run)."""

    name: str
    title: str
    command: str
    text: str
    seconds: float
    ok: bool


def run_script(name: str, title: str, script: str, *args: str) -> Table:
    """Run a benchmark script in a fresh interpreter and capture its table."""
    path = HERE / script
    cmd = f".venv/bin/python benchmarks/{script} {' '.join(args)}".strip()
    if not path.is_file():
        return Table(name, title, cmd, f"(not run: {script} is not in benchmarks/ yet)", 0.0, False)
    env = {**os.environ, "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, str(path), *args], cwd=ROOT, env=env, capture_output=True, text=True)
    text = proc.stdout.rstrip()
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or ["(no message)"]
        text = f"{text}\n(failed with exit code {proc.returncode}: {tail[0]})".strip()
    return Table(name, title, cmd, text, time.perf_counter() - t, proc.returncode == 0)


def _rollout_suite(workdir: Path, n: int):
    """A suite of `n` route-coverage scenarios on the paper's M1 (SF feature space, seed 1)."""
    import feat2map
    from feat2map.formats import native
    from feat2map.scenarios.routes import build_suite

    path = workdir / "m1.json"
    native.save(feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1), path)
    suite = build_suite(path)
    scenarios = list(getattr(suite, "scenarios", suite))
    return scenarios[:n], len(scenarios)


def rollout_throughput(n: int = ROLLOUT_SCENARIOS) -> Table:
    """Scenarios per minute on one core (workers=1), without and with line coverage."""
    title = "Rollout throughput (baseline planner, M1, one core)"
    cmd = ".venv/bin/python benchmarks/run_all.py --only rollout"
    try:
        from feat2map.scenarios.rollout import run_suite
        from feat2map.scenarios import routes  # noqa: F401
    except ImportError as exc:
        return Table("rollout", title, cmd, f"(not run: scenario machinery missing: {exc})", 0.0, False)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        scenarios, total = _rollout_suite(Path(tmp), n)
        rows = []
        for label, cov in (("plain", False), ("line coverage", True)):
            t = time.perf_counter()
            res = run_suite(scenarios, "baseline", workers=1, progress=False, coverage=cov, record_failure_gif=False)
            wall = time.perf_counter() - t
            sim = sum(o.sim_s for o in res.outcomes)
            done = sum(o.outcome == "completed" for o in res.outcomes)
            rows.append((label, len(scenarios), done, sim, wall))
    base = rows[0][1] / rows[0][4]
    lines = [f"suite: first {len(scenarios)} of {total} route-coverage scenarios of M1 (seed 1)",
             f"{'mode':<14} {'scenarios':>9} {'completed':>9} {'sim s':>8} {'wall s':>7} "
             f"{'scen/min/core':>13} {'sim x real':>10} {'vs plain':>8}"]
    for label, k, done, sim, wall in rows:
        rate = k / wall
        lines.append(f"{label:<14} {k:>9d} {done:>9d} {sim:>8.1f} {wall:>7.1f} {60 * rate:>13.1f} "
                     f"{sim / wall:>10.1f} {rate / base:>8.2f}")
    return Table("rollout", title, cmd, "\n".join(lines), time.perf_counter() - t0, True)


SHARED_MAPS = ROOT.parent / "shared" / "maps"


def extraction_inline() -> Table:
    """Read + extract time of every real map, used while benchmarks/bench_extract.py is absent;
    baseline: generating the paper's M1 in the same process."""
    import warnings

    import feat2map
    from feat2map.errors import Feat2MapError
    from feat2map.extract import extract_junctions
    from feat2map.readers import read_map

    title = "Extraction time for each real map"
    cmd = ".venv/bin/python benchmarks/run_all.py --only extract"
    if not SHARED_MAPS.is_dir():
        return Table("extract", title, cmd, f"(not run: {SHARED_MAPS} is absent)", 0.0, False)
    t0 = time.perf_counter()
    t = time.perf_counter()
    feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1)
    base = time.perf_counter() - t
    files = sorted(p for p in SHARED_MAPS.rglob("*") if p.suffix in (".bin", ".xodr")
                   or (p.suffix == ".txt" and "apollo" in p.parts))
    lines = [f"baseline: generating M1 (8 junctions) took {base:.3f} s",
             f"{'map':<62} {'bytes':>9} {'junctions':>9} {'extracted':>9} {'read s':>7} {'extract s':>9} {'x M1 gen':>8}"]
    for p in files:
        rel = str(p.relative_to(SHARED_MAPS))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t = time.perf_counter()
                m = read_map(p)
                read_s = time.perf_counter() - t
                t = time.perf_counter()
                js = extract_junctions(m, rel)
                ext_s = time.perf_counter() - t
        except Feat2MapError as exc:
            lines.append(f"{rel:<62} (not read: {exc.message[:60]})")
            continue
        lines.append(f"{rel:<62} {p.stat().st_size:>9,d} {len(m.junctions):>9d} {len(js):>9d} {read_s:>7.3f} "
                     f"{ext_s:>9.3f} {(read_s + ext_s) / base:>8.2f}")
    return Table("extract", title, cmd, "\n".join(lines), time.perf_counter() - t0, True)


def extraction() -> Table:
    if (HERE / "bench_extract.py").is_file():
        return run_script("extract", "Extraction time for each real map", "bench_extract.py")
    return extraction_inline()


BENCHMARKS: dict[str, Callable[[], Table]] = {
    "generate": lambda: run_script("generate", "Generation time vs junction count", "bench_generate.py"),
    "extract": extraction,
    "apollo": lambda: run_script("apollo", "Apollo export and validation time vs map size", "bench_apollo.py"),
    "env": lambda: run_script("env", "Env steps/s: feat2map vs highway-env intersection-v1",
                              "bench_env.py"),
    "vector": lambda: run_script("vector", "Native batched vector env: N sub-envs in one core", "bench_vector.py"),
    "scenarios": lambda: run_script("scenarios", "Route coverage vs map size; baseline planner vs scripted driver",
                                    "bench_scenarios.py"),
    "rollout": rollout_throughput,
}
KNOWN_SCRIPTS = {"bench_generate.py", "bench_extract.py", "bench_apollo.py", "bench_env.py", "bench_vector.py",
                 "bench_scenarios.py"}
for _extra in sorted(HERE.glob("bench_*.py")):  # benchmarks added later still get a table
    if _extra.name not in KNOWN_SCRIPTS:
        _key = _extra.stem.removeprefix("bench_")
        BENCHMARKS[_key] = (lambda k=_key, n=_extra.name: run_script(k, f"{n} (no title registered)", n))


def machine() -> str:
    """One line describing where the numbers were measured."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores visible (shared with other jobs), Python {platform.python_version()}, "
            f"{platform.system()} {platform.release()}")


def markdown(tables: list[Table], when: str, load: float | None = None) -> str:
    """docs/benchmarks.md: every table as a code block with the command that made it."""
    busy = f" Load average when the run started: {load:.1f}." if load is not None else ""
    out = ["# Benchmarks", "",
           f"Latest run: {when}, `.venv/bin/python benchmarks/run_all.py`.", f"Machine: {machine()}.{busy}", "",
           "Speed is reported as ratios against a baseline measured in the same process: on a shared "
           "2-core machine absolute timings move by up to 2x between runs with the other jobs' load; "
           "the ratios are what to compare.", ""]
    for t in tables:
        out += [f"## {t.title}", "", f"`{t.command}` ({t.seconds:.0f} s)", "", "```", t.text, "```", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=sorted(BENCHMARKS), help="run only these benchmarks")
    ap.add_argument("--no-save", action="store_true",
                    help=f"do not write {DOC.relative_to(ROOT)} (never written by an --only run)")
    args = ap.parse_args(argv)
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    os.environ.setdefault("MPLBACKEND", "Agg")
    names = args.only or list(BENCHMARKS)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    tables = []
    for name in names:
        print(f"== {name} ...", file=sys.stderr, flush=True)
        t = BENCHMARKS[name]()
        tables.append(t)
        print(f"\n## {t.title}\n{t.text}\n", flush=True)
    if not args.no_save and not args.only:
        from feat2map import atomic

        when = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        atomic.write_text(DOC, markdown(tables, when, load))
        print(f"wrote {DOC.relative_to(ROOT)}", file=sys.stderr)
    return 0 if all(t.ok for t in tables) else 1


if __name__ == "__main__":
    raise SystemExit(main())
