"""Parse + extraction time per real map (issue 3 target: San Francisco base_map.bin under 1 s).

For every map in ../shared/maps: the bare decode of the file as baseline (protobuf parse for
Apollo, ElementTree parse for OpenDRIVE), then our reader (decode + conversion into HDMap),
then junction extraction. Best of REPEATS runs, CPU time of this process (the machine is
shared, so wall time is printed too); ratios are against the bare decode in the same run.

Run: .venv/bin/python benchmarks/bench_extract.py [MAP ...]
"""
from __future__ import annotations

import sys
import time
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Callable

from feat2map.formats.apollo import schema as apollo_schema
from feat2map.extract import extract_junctions
from feat2map.readers import read_map

SHARED = Path(__file__).resolve().parents[2] / "shared" / "maps"
REPEATS = 3


def best(fn: Callable[[], object]) -> tuple[float, float, object]:
    """(cpu seconds, wall seconds, result) of the fastest of REPEATS runs."""
    runs = []
    for _ in range(REPEATS):
        c, w = time.process_time(), time.perf_counter()
        out = fn()
        runs.append((time.process_time() - c, time.perf_counter() - w, out))
    return min(runs, key=lambda r: r[0])


def decode(path: Path) -> object:
    if path.suffix == ".xodr":
        return ET.parse(path)
    return apollo_schema.parse_map(path.read_bytes(), str(path))


def main(argv: list[str]) -> None:
    paths = [Path(a).resolve() for a in argv] or sorted(
        p for p in SHARED.rglob("*") if p.suffix in (".bin", ".txt", ".xodr"))
    if not paths:
        sys.exit(f"no maps given and none under {SHARED}")
    print(f"{'map':<46} {'MB':>5} {'J':>4} {'decode ms':>10} {'read ms':>8} {'extract ms':>11} "
          f"{'total ms':>9} {'wall ms':>8} {'total/decode':>13}")
    warnings.simplefilter("ignore")
    for p in paths:
        dec, _, _ = best(lambda p=p: decode(p))
        rd, rd_wall, m = best(lambda p=p: read_map(p))
        ex, ex_wall, js = best(lambda m=m: extract_junctions(m))  # type: ignore[arg-type]
        total = rd + ex
        name = str(p.relative_to(SHARED)) if p.is_relative_to(SHARED) else str(p)
        print(f"{name[-46:]:<46} {p.stat().st_size / 1e6:>5.2f} {len(js):>4} {1000 * dec:>10.1f} "  # type: ignore[arg-type]
              f"{1000 * rd:>8.1f} {1000 * ex:>11.1f} {1000 * total:>9.1f} {1000 * (rd_wall + ex_wall):>8.1f} "
              f"{total / max(dec, 1e-9):>12.1f}x")


if __name__ == "__main__":
    main(sys.argv[1:])
