"""Export the paper's M1-style map (seed 1) to OpenDRIVE, rebuild it with SUMO's netconvert,
and draw the SUMO network next to ours: docs/opendrive_netconvert.png.

Usage: .venv/bin/python scripts/opendrive_netconvert.py --seed 1 --out docs/opendrive_netconvert.png   # both optional
Needs the eclipse-sumo wheel (the dev extra: bash scripts/setup.sh dev) for the netconvert binary.
"""
from __future__ import annotations

import argparse
import io
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from lxml import etree  # noqa: E402

import feat2map  # noqa: E402
from feat2map import atomic  # noqa: E402
from feat2map.render import CONTROL_COLOURS, draw_map  # noqa: E402
from feat2map.formats.opendrive.writer import write_opendrive  # noqa: E402


def find_netconvert() -> str:
    exe = Path(sys.executable).parent / "netconvert"
    found = str(exe) if exe.exists() else shutil.which("netconvert")
    if not found:
        sys.exit("netconvert not found: pip install eclipse-sumo")
    return found


def sumo_lanes(net: Path):
    """(road lane shapes, internal lane shapes, node points by type) in the xodr's frame."""
    root = etree.parse(str(net)).getroot()
    loc = root.find("location")
    dx, dy = (float(v) for v in loc.get("netOffset").split(","))

    def shape(s: str):
        return [(float(x) - dx, float(y) - dy) for x, y in (p.split(",")[:2] for p in s.split())]
    road, internal = [], []
    for e in root.findall("edge"):
        for ln in e.findall("lane"):
            (internal if e.get("function") == "internal" else road).append(shape(ln.get("shape")))
    nodes = {}
    for j in root.findall("junction"):
        if j.get("type") != "internal":
            nodes.setdefault(j.get("type"), []).append((float(j.get("x")) - dx, float(j.get("y")) - dy))
    return road, internal, nodes, len(root.findall("tlLogic"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "opendrive_netconvert.png"))
    args = ap.parse_args()
    m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        xodr, net = Path(tmp) / "map.xodr", Path(tmp) / "map.net.xml"
        write_opendrive(m, xodr)
        subprocess.run([find_netconvert(), "--opendrive-files", str(xodr), "--no-turnarounds", "-o", str(net)],
                       check=True, capture_output=True)
        road, internal, nodes, n_tls = sumo_lanes(net)
    fig, (a, b) = plt.subplots(1, 2, figsize=(16, 8.5))
    draw_map(m, a)
    a.set_title(f"feat2map (seed {args.seed}): {len(m.junctions)} junctions, "
                f"{sum(ln.junction_id is not None for ln in m.lanes.values())} junction lanes, "
                f"{len({s.junction_id for s in m.signals.values()})} signalized")
    b.add_collection(LineCollection(road, colors="#455a64", linewidths=1.2))
    b.add_collection(LineCollection(internal, colors="#90a4ae", linewidths=0.6, linestyles="dashed"))
    colours = {"traffic_light": CONTROL_COLOURS["signal"], "priority": "#616161", "dead_end": "#bdbdbd"}
    for typ, pts in sorted(nodes.items()):
        xs, ys = zip(*pts)
        b.scatter(xs, ys, s=18, color=colours.get(typ, "#1565c0"), label=f"{typ} ({len(pts)})", zorder=3)
    b.legend(loc="upper right", fontsize=8)
    b.set_aspect("equal")
    b.autoscale_view()
    b.set_xlim(a.get_xlim())
    b.set_ylim(a.get_ylim())
    b.set_xlabel("x [m]")
    b.set_title(f"SUMO netconvert of the exported .xodr: {len(road)} lanes, {len(internal)} internal lanes, "
                f"{n_tls} traffic lights")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic.write_bytes(args.out, buf.getvalue())
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
