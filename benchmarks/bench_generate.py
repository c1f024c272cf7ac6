"""Generation time vs junction count: linear (ms per junction flat from about 100 to 10,000
junctions) and 10,000 junctions under 30 s (issue 25; issue 2 asked for 1,000 under 10 s).

Placement keeps each open grid point's score per feature signature and re-scores only the
points a placement changes, and the crossing-road check subtracts only the junctions a road
touches: both were quadratic (1,000 junctions 14.8 s, 2,000 51 s, 5,000 over 300 s).

The second table times `feat2map generate --spec` (in this process, through the CLI's own
`main`: reading and validating the spec, layout, build, the route checks, map.json and
features.json; no pictures, no Apollo export) on specs of n three-leg junctions (issue 35):
it was quadratic too (250 junctions 12.2 ms/junction, 1,000 25.6, 2,000 45.9) because spec
junctions keep their written quarter turn, which sent every placement through the scan of all
open grid points, and the two-way route check searched the whole network from every entry.

Run: .venv/bin/python benchmarks/bench_generate.py [--quick] [--spec-only]
     (--quick: up to 1,000 junctions; --spec-only: only the spec table)
"""
from __future__ import annotations

import contextlib
import io
import re
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import yaml

import feat2map
from feat2map.cli import main as cli_main
from feat2map.config import GenerationConfig, raised_limits
from feat2map.features import CONTROLS, FeatureSpace

# every (n, control, crosswalk) combination of 3- and 4-leg junctions: 12 junctions per sample
SPACE = FeatureSpace((3, 4), ("bare", "signal", "stop"), (True, False), feat2map.PAPER_SF_FEATURE_SPACE.rotation_ranges)
SAMPLES = (9, 28, 84, 250, 834)  # 108, 336, 1,008, 3,000, 10,008 junctions
TRACE_UP_TO = 84  # peak memory in a second, traced run (tracing slows the code down) for the smaller maps
SPEC_JUNCTIONS = (100, 250, 1000, 2000, 5000)


def three_leg_spec(n: int) -> dict:
    """A spec of n three-leg junctions, no cells (the layout places them): T junctions whose
    side leg leans -15..15 degrees, every control, crosswalks on every other one."""
    return {"version": 1, "junctions": [
        {"control": CONTROLS[i % len(CONTROLS)], "crosswalk": i % 2 == 0, "sockets": [0, 90 + (7 * i) % 31 - 15, 180]}
        for i in range(n)]}


def run_spec(n: int, folder: Path) -> tuple[int, int, float, float]:
    """`feat2map generate --spec` of `three_leg_spec(n)` (YAML) without pictures or Apollo
    export: (junctions, lanes, wall s, CPU s)."""
    spec = folder / f"three_leg_{n}.yaml"
    spec.write_text(yaml.safe_dump(three_leg_spec(n)), encoding="utf-8")
    out = io.StringIO()
    wall, cpu = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(out):
        rc = cli_main(["generate", "--quiet", "--no-picture", "--no-apollo", "--spec", str(spec),
                       "--out", str(folder / f"out_{n}")])
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    if rc != 0:
        raise SystemExit(f"generate --spec failed on {n} junctions (exit {rc})")
    counts = dict((what, int(k)) for k, what in re.findall(r"(\d+) (junctions|lanes)", out.getvalue()))  # "wrote ..."
    return counts["junctions"], counts["lanes"], wall, cpu


def spec_table(quick: bool) -> None:
    sizes = [n for n in SPEC_JUNCTIONS if not quick or n <= 1000]
    with tempfile.TemporaryDirectory() as tmp:
        run_spec(sizes[0], Path(tmp))  # warm-up: the CLI's imports and caches are not the smallest run's cost
        rows = [run_spec(n, Path(tmp)) for n in sizes]
    base = rows[0][3] / rows[0][0]
    print("\ngenerate --spec, n three-leg junctions (CPU time; no pictures, no Apollo export)")
    print(f"{'junctions':>9} {'lanes':>7} {'wall [s]':>9} {'cpu [s]':>8} {'cpu ms/junction':>16} {'vs smallest':>12}")
    for n, lanes, wall, cpu in rows:
        print(f"{n:>9} {lanes:>7} {wall:>9.2f} {cpu:>8.2f} {1000 * cpu / n:>16.2f} {cpu / n / base:>11.2f}x")


def run(k: int) -> tuple[int, int, float, float, float | None]:
    cfg = GenerationConfig(samples_per_combination=k)
    wall, cpu = time.perf_counter(), time.process_time()
    m = feat2map.generate(SPACE, seed=0, config=cfg)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    n, lanes = len(m.junctions), len(m.lanes)
    del m
    peak = None
    if k <= TRACE_UP_TO:
        tracemalloc.start()
        feat2map.generate(SPACE, seed=0, config=cfg)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    return n, lanes, wall, cpu, peak


def main() -> None:
    quick = "--quick" in sys.argv
    if "--spec-only" in sys.argv:
        spec_table(quick)
        return
    samples = [k for k in SAMPLES if k <= 84] if quick else SAMPLES
    with raised_limits(max_junctions=max(20_000, 12 * max(samples))):
        rows = [run(k) for k in samples]
    base = rows[0][2] / rows[0][0]
    print(f"{'junctions':>9} {'lanes':>7} {'wall [s]':>9} {'cpu [s]':>8} {'ms/junction':>12} {'vs smallest':>12} "
          f"{'peak MiB':>9}")
    for n, lanes, wall, cpu, peak in rows:
        per = wall / n
        mem = f"{peak:>9.0f}" if peak is not None else f"{'-':>9}"
        print(f"{n:>9} {lanes:>7} {wall:>9.2f} {cpu:>8.2f} {1000 * per:>12.2f} {per / base:>11.2f}x {mem}")
    n, _, wall, _, _ = rows[-1]
    print(f"largest: {n} junctions in {wall:.1f} s ({'under' if wall < 30 else 'OVER'} 30 s)")
    spec_table(quick)


if __name__ == "__main__":
    main()
