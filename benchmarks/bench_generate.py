"""Generation time vs junction count (issue 2 target: 1,000 junctions under 10 s, about linear).

Run: .venv/bin/python benchmarks/bench_generate.py
"""
from __future__ import annotations

import time
import tracemalloc

import feat2map
from feat2map.config import GenerationConfig
from feat2map.features import FeatureSpace

# every (n, control, crosswalk) combination of 3- and 4-leg junctions: 12 junctions per sample
SPACE = FeatureSpace((3, 4), ("bare", "signal", "stop"), (True, False), feat2map.PAPER_SF_FEATURE_SPACE.rotation_ranges)


def run(k: int) -> tuple[int, int, float, float]:
    cfg = GenerationConfig(samples_per_combination=k)
    t = time.perf_counter()
    m = feat2map.generate(SPACE, seed=0, config=cfg)
    dt = time.perf_counter() - t
    del m
    tracemalloc.start()  # memory in a second, traced run: tracing slows the code down
    m = feat2map.generate(SPACE, seed=0, config=cfg)
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return len(m.junctions), len(m.lanes), dt, peak


def main() -> None:
    rows = [run(k) for k in (1, 9, 84)]  # 12, 108, 1008 junctions
    base = rows[0][2] / rows[0][0]
    print(f"{'junctions':>9} {'lanes':>7} {'time [s]':>9} {'ms/junction':>12} {'vs smallest':>12} {'peak MiB':>9}")
    for n, lanes, dt, peak in rows:
        per = dt / n
        print(f"{n:>9} {lanes:>7} {dt:>9.2f} {1000 * per:>12.2f} {per / base:>11.2f}x {peak:>9.0f}")


if __name__ == "__main__":
    main()
