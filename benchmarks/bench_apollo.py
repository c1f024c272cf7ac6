"""Apollo export and validation time vs map size, against generation time in the same run.

Run: .venv/bin/python benchmarks/bench_apollo.py [--large]
Columns: generate (the baseline), to_apollo (base_map message), sim_map, routing graph,
write (serialise + text + atomic files), validate (the written folder); "x gen" is the whole
export (to_apollo + sim + routing + write) divided by generation time.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import feat2map
from feat2map import atomic
from feat2map.formats.apollo.routing import build_routing_graph
from feat2map.formats.apollo.validate import validate_apollo
from feat2map.config import GenerationConfig
from feat2map.features import FeatureSpace
from feat2map.formats.apollo.sim_map import to_sim_map
from feat2map.formats import FORMATS
from feat2map.formats.apollo.writer import text_of, to_apollo

# every (n, control, crosswalk) combination of 3- and 4-leg junctions: 12 junctions per sample
SPACE = FeatureSpace((3, 4), ("bare", "signal", "stop"), (True, False), feat2map.PAPER_SF_FEATURE_SPACE.rotation_ranges)


def _timed(fn, *args):
    t = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t


def run(k: int, folder: Path) -> dict[str, float]:
    m, t_gen = _timed(feat2map.generate, SPACE, 0, GenerationConfig(samples_per_combination=k))
    base, t_base = _timed(to_apollo, m)
    sim, t_sim = _timed(to_sim_map, base)
    graph, t_route = _timed(build_routing_graph, base)

    def write() -> None:
        with atomic.staged_dir(folder, FORMATS["apollo"].markers) as tmp:
            for name, msg in (("base_map", base), ("sim_map", sim), ("routing_map", graph)):
                atomic.write_bytes(tmp / f"{name}.bin", msg.SerializeToString())
                atomic.write_text(tmp / f"{name}.txt", text_of(msg))

    _, t_write = _timed(write)
    problems, t_val = _timed(validate_apollo, folder)
    size = sum(p.stat().st_size for p in folder.iterdir()) / 2**20
    return {"junctions": len(m.junctions), "lanes": len(m.lanes), "gen": t_gen, "base": t_base, "sim": t_sim,
            "route": t_route, "write": t_write, "validate": t_val, "MiB": size, "problems": len(problems)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--large", action="store_true", help="also the 1,008-junction map (about a minute)")
    args = ap.parse_args()
    sizes = (1, 9, 34) + ((84,) if args.large else ())  # 12, 108, 408 (, 1008) junctions
    print(f"{'junctions':>9} {'lanes':>6} {'generate':>9} {'to_apollo':>9} {'sim_map':>8} {'routing':>8} "
          f"{'write':>7} {'x gen':>6} {'validate':>9} {'MiB':>6} {'problems':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        for k in sizes:
            r = run(k, Path(tmp) / f"k{k}")
            export = r["base"] + r["sim"] + r["route"] + r["write"]
            print(f"{r['junctions']:>9} {r['lanes']:>6} {r['gen']:>8.2f}s {r['base']:>8.2f}s {r['sim']:>7.2f}s "
                  f"{r['route']:>7.2f}s {r['write']:>6.2f}s {export / r['gen']:>5.2f}x {r['validate']:>8.2f}s "
                  f"{r['MiB']:>6.1f} {r['problems']:>8}")


if __name__ == "__main__":
    main()
