"""Generation time vs junction count: linear (ms per junction flat from about 100 to 10,000
junctions) and 10,000 junctions under 30 s (issue 25; issue 2 asked for 1,000 under 10 s).

Placement keeps each open grid point's score per feature signature and re-scores only the
points a placement changes, and the crossing-road check subtracts only the junctions a road
touches: both were quadratic (1,000 junctions 14.8 s, 2,000 51 s, 5,000 over 300 s).

Run: .venv/bin/python benchmarks/bench_generate.py [--quick]   (--quick: up to 1,000 junctions)
"""
from __future__ import annotations

import sys
import time
import tracemalloc

import feat2map
from feat2map.config import GenerationConfig, raised_limits
from feat2map.features import FeatureSpace

# every (n, control, crosswalk) combination of 3- and 4-leg junctions: 12 junctions per sample
SPACE = FeatureSpace((3, 4), ("bare", "signal", "stop"), (True, False), feat2map.PAPER_SF_FEATURE_SPACE.rotation_ranges)
SAMPLES = (9, 28, 84, 250, 834)  # 108, 336, 1,008, 3,000, 10,008 junctions
TRACE_UP_TO = 84  # peak memory in a second, traced run (tracing slows the code down) for the smaller maps


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
    samples = [k for k in SAMPLES if k <= 84] if "--quick" in sys.argv else SAMPLES
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


if __name__ == "__main__":
    main()
