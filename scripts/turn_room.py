"""Is there room for the ego in every junction turn? CommonRoad's own road-boundary check over the
ego's swept path (issue 33: "drivable in turns").

For each map: export it to CommonRoad (feat2map's writer, as the planner bridge does), drive the
ego on its own through every (junction, entry road, exit road) manoeuvre with the env's lane
keeping and vehicle model (`feat2map.envs.sim.vehicle`), and keep its body's pose every frame on
the junction's lanes. Then, in CommonRoad's venv (`bash adapters/commonroad/setup.sh`), build
commonroad-drivability-checker's road boundary (`create_road_boundary_obstacle`, the
"obb_rectangles" method the reactive planner's adapter uses) and test every pose's body
rectangle against it. A pose that touches the boundary is one a CommonRoad planner rejects as
"left the road".

    .venv/bin/python scripts/turn_room.py MAP [MAP ...]          # a table, one row per map
    .venv/bin/python scripts/turn_room.py --generate 1           # M1 (`feat2map generate --seed 1`)
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CR_PYTHON = REPO / ".venv-crplanner" / "bin" / "python"
SPEED_MPS = 6.0  # the ego's speed through the turns (the baseline planner's junction speed)

CHECK = r"""
import json, logging, sys
logging.disable(logging.WARNING)
from commonroad.common.file_reader import CommonRoadFileReader
from commonroad_dc.boundary.boundary import create_road_boundary_obstacle
import commonroad_dc.pycrcc as pycrcc

xml, poses_file = sys.argv[1], sys.argv[2]
scenario, _ = CommonRoadFileReader(xml).open()
_, boundary = create_road_boundary_obstacle(scenario, method="obb_rectangles")
cc = pycrcc.CollisionChecker()
cc.add_collision_object(boundary)
out = {}
for name, (length, width, poses) in json.load(open(poses_file)).items():
    out[name] = sum(bool(cc.collide(pycrcc.RectOBB(length / 2, width / 2, h, x, y))) for x, y, h in poses)
print(json.dumps(out))
"""


def turn_poses(map_path: Path) -> dict[str, tuple[float, float, list[tuple[float, float, float]]]]:
    """{manoeuvre: (length, width, [(x, y, heading) of the body in the map's frame on its junction's lanes])}."""
    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    import gymnasium as gym

    import feat2map  # noqa: F401  (registers the envs)
    from feat2map.routes import manoeuvres

    env = gym.make("feat2map/MapFile-v0", config={
        "map_file": str(map_path), "traffic_vehicles": 0, "pedestrian_rate": 0.0, "policy_frequency": 5,
        "action": {"type": "ContinuousAction", "longitudinal": True, "lateral": False}, "offroad_terminal": False,
        "duration": 60.0})
    env.reset(seed=0)
    e = env.unwrapped
    m = e.net.hdmap
    out = {}
    for mv in manoeuvres(m):
        e.config["route"] = [list(mv)]
        env.reset(seed=0)
        ego, poses = e.vehicle, []
        for _ in range(300):
            _, _, term, trunc, info = env.step(np.array([np.clip((SPEED_MPS - ego.speed) / 3, -1, 1)], dtype=np.float32))
            if m.lanes[ego.lane_route[ego.route_pos]].junction_id == mv[0]:
                poses.append((float(ego.position[0]), -float(ego.position[1]), -float(ego.heading)))  # y up
            if term or trunc or info["route_completed"]:
                break
        out["/".join(mv)] = (float(ego.LENGTH), float(ego.WIDTH), poses)
    env.close()
    return out


def check(map_path: Path) -> dict:
    """The manoeuvres of `map_path` and how many of each one's poses touch CommonRoad's road boundary."""
    from feat2map.formats import read_map, write_map

    poses = turn_poses(map_path)
    with tempfile.TemporaryDirectory() as tmp:
        xml, pfile = Path(tmp) / "map.xml", Path(tmp) / "poses.json"
        write_map(read_map(map_path), xml, "commonroad")
        pfile.write_text(json.dumps(poses))
        run = subprocess.run([str(CR_PYTHON), "-c", CHECK, str(xml), str(pfile)], capture_output=True, text=True)
    if run.returncode:
        raise SystemExit(f"{map_path}: the CommonRoad check failed: {run.stderr.strip()[-500:]}")
    hits = json.loads(run.stdout)
    return {"map": str(map_path), "manoeuvres": len(poses), "poses": sum(len(p[2]) for p in poses.values()),
            "touching": sum(hits.values()), "manoeuvres_touching": sorted(k for k, v in hits.items() if v)}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("maps", nargs="*", type=Path, help="map files (native JSON, OpenDRIVE, Apollo)")
    ap.add_argument("--generate", type=int, metavar="SEED", help="also a map generated with this seed (1: M1)")
    ap.add_argument("--json", type=Path, help="write the rows here too")
    args = ap.parse_args(argv)
    if not CR_PYTHON.exists():
        print(f"{CR_PYTHON} is absent: bash adapters/commonroad/setup.sh builds it", file=sys.stderr)
        return 2
    maps = list(args.maps)
    with tempfile.TemporaryDirectory() as tmp:
        if args.generate is not None:
            subprocess.run([str(Path(sys.executable).with_name("feat2map")), "generate", "--seed", str(args.generate), "--out",
                            f"{tmp}/gen", "--quiet", "--no-picture", "--no-apollo"], check=True)
            maps.insert(0, Path(tmp) / "gen" / "map.json")
        rows = []
        print("| map | manoeuvres | poses in junctions | touching the road boundary | manoeuvres touching |")
        print("|---|---|---|---|---|")
        for p in maps:
            r = check(p)
            rows.append(r)
            print(f"| {p} | {r['manoeuvres']} | {r['poses']} | {r['touching']} | "
                  f"{', '.join(r['manoeuvres_touching'][:5]) or '-'}{' ...' if len(r['manoeuvres_touching']) > 5 else ''} |",
                  flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0 if all(r["touching"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
