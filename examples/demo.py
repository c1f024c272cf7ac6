"""One drive through the Python API: a map file in `feat2map/MapFile-v0`, the baseline planner
on a sampled route, headless. Writes OUT/drive.png: the route on the map with the ego's
trajectory coloured by simulated time, and the env's own frame in each junction of the route
(titled with the time and the planner's stage); prints the outcome and the stage path.

    .venv/bin/python examples/demo.py --map out/demo/m1/map.json --out out/demo
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

import feat2map  # noqa: E402,F401  (registers the feat2map/ environment ids)
from feat2map.formats import read_map  # noqa: E402
from feat2map.render import draw_map, legend_handles, save_figure  # noqa: E402
from feat2map.scenarios.planner import STAGE_NAMES, BaselinePlanner  # noqa: E402

FRAME_AFTER_ENTRY_S = 1.0  # a junction's frame is taken this long after the ego enters it
FRAME_SCALING = 8.0  # env frame pixels per metre (600 px: 75 m around the ego)
MARGIN_M = 20.0  # around the route in the map panel
LABEL_REACH_M = 15.0  # junctions whose centre is this close outside the panel are taken in
LABEL_MARGIN_M = 8.0  # around those junctions' centres (their labels)


def drive(map_file: str, seed: int):
    """Drive one sampled route; returns (trajectory [(t, x, y)], frames [(junction, t, stage, image)],
    route lane ids, last info, steps, stage path)."""
    env = gym.make("feat2map/MapFile-v0", render_mode="rgb_array", config={
        "map_file": map_file, "action": BaselinePlanner.action_config, "policy_frequency": 5,
        "route_junctions": 3, "traffic_vehicles": 6, "pedestrian_rate": 6.0, "duration": 120,
        "scaling": FRAME_SCALING})
    planner = BaselinePlanner()
    obs, info = env.reset(seed=seed)
    planner.reset(env)
    m = read_map(map_file)
    route = list(env.unwrapped.route_lanes)
    track, frames, entered = [], [], {}
    done, steps = False, 0
    while not done:
        obs, _, terminated, truncated, info = env.step(planner.act(obs, info))
        done = terminated or truncated
        steps += 1
        t = info["time"]
        x, y = map(float, env.unwrapped.vehicle.position)
        track.append((t, x, -y))  # highway-env's y points down; the map's up
        lane = m.lanes.get(info.get("lane_id") or "")
        jid = lane.junction_id if lane is not None else None
        if jid is not None and jid not in {f[0] for f in frames}:
            entered.setdefault(jid, t)
            if t - entered[jid] >= FRAME_AFTER_ENTRY_S:
                frames.append((jid, t, planner.stage, env.render()))
    from highway_env.vehicle.graphics import VehicleGraphics

    info = dict(info, ego_rgb=VehicleGraphics.get_color(env.unwrapped.vehicle))  # the frames' ego colour
    env.close()
    return m, track, frames, route, info, steps, planner.stage_path()


def frame_legend(ego_rgb) -> list:
    """What the colours of the env's frames mean (envs/render.py and highway-env's vehicle colours)."""
    from matplotlib.patches import Patch
    from highway_env.vehicle.graphics import VehicleGraphics

    from feat2map.envs.render import PED_RGB, ROUTE_RGB, SIGNAL_RGB

    def rgb(c):
        return tuple(v / 255 for v in c)

    return [Patch(color=rgb(ego_rgb), label="ego vehicle (at the centre)"),
            Patch(color=rgb(VehicleGraphics.BLUE), label="other vehicles"),
            Line2D([], [], color=rgb(ROUTE_RGB), lw=2, label="ego route"),
            Line2D([], [], ls="none", marker="o", ms=6, color=rgb(PED_RGB), mec="k", label="pedestrian"),
            *(Line2D([], [], color=rgb(c), lw=3, marker="o", ms=6, mec="k", label=f"signal {state}: head, stop line")
              for state, c in SIGNAL_RGB.items()),
            Line2D([], [], ls="none", marker="8", ms=7, color=(200 / 255, 0, 0), mec="w", label="stop sign")]


def draw(m, track, frames, route, info, steps, stages, path: Path) -> None:
    """The map panel (route, trajectory) above one env frame per junction."""
    cols = max(2, len(frames))
    fig = plt.figure(figsize=(4.0 * cols + 1.0, 12.0), layout="constrained")
    top, bottom, key = fig.subfigures(3, 1, height_ratios=[1.5, 1, 0.17])
    ax = top.subplots()
    draw_map(m, ax, highlight_lanes=route)
    pts = np.array([(x, y) for _, x, y in track])
    ts = np.array([t for t, _, _ in track])
    seg = LineCollection(np.stack([pts[:-1], pts[1:]], axis=1), array=ts[1:], cmap="viridis", linewidths=2.5,
                         zorder=8)
    ax.add_collection(seg)
    ax.plot(*pts[0], marker="o", ms=8, color="#ffffff", mec="k", zorder=9)
    ax.plot(*pts[-1], marker="s", ms=8, color="#ffffff", mec="k", zorder=9)
    route_pts = np.concatenate([np.asarray(m.lanes[i].centerline) for i in route])
    lo, hi = route_pts.min(axis=0) - MARGIN_M, route_pts.max(axis=0) + MARGIN_M
    # a junction whose label would sit on the panel's edge is taken in whole (its label not cut)
    near = [j.center for j in m.junctions.values() if len(j.polygon) >= 3
            and np.all(np.asarray(j.center) > lo - LABEL_REACH_M) and np.all(np.asarray(j.center) < hi + LABEL_REACH_M)]
    if near:
        lo = np.minimum(lo, np.min(near, axis=0) - LABEL_MARGIN_M)
        hi = np.maximum(hi, np.max(near, axis=0) + LABEL_MARGIN_M)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    top.colorbar(seg, ax=ax, label="simulated time [s]", location="bottom", shrink=0.5, aspect=40)
    handles = legend_handles(m, highlight=True) + [
        Line2D([], [], color="#21918c", lw=2.5, label="ego trajectory (colour: time)"),
        Line2D([], [], ls="none", marker="o", ms=7, color="#ffffff", mec="k", label="start"),
        Line2D([], [], ls="none", marker="s", ms=7, color="#ffffff", mec="k", label="end")]
    top.legend(handles=handles, loc="outside right upper", fontsize=8)  # the layout makes room for it
    junctions = list(dict.fromkeys(m.lanes[i].junction_id for i in route if m.lanes[i].junction_id))
    ax.set_title(f"route through {' → '.join(junctions)} on the map (bird's-eye)", fontsize=10)
    key.legend(handles=frame_legend(info["ego_rgb"]), loc="center", ncol=4, fontsize=8, frameon=False,
               title="env frames", title_fontsize=8)
    for k, (jid, t, stage, img) in enumerate(frames):
        a = bottom.add_subplot(1, cols, k + 1)
        a.imshow(img)
        a.set_axis_off()
        a.set_title(f"env frame in {jid} at t = {t:.1f} s (ego at the centre)\n"
                    f"planner stage {stage}: {STAGE_NAMES.get(stage, stage)}",
                    fontsize=9)
    outcome = ("completed" if info["route_completed"] else "not completed") + (
        ", collision" if info["collision"] else "") + (", off road" if info["off_road"] else "")
    v = ", ".join(f"{k} {n}" for k, n in info["violations"].items() if n) or "no violation"
    fig.suptitle(f"feat2map/MapFile-v0, baseline planner: {outcome} after {info['time']:.1f} s simulated "
                 f"({steps} steps), {v}\nstage path: {' → '.join(stages)}", fontsize=11)
    save_figure(fig, path, dpi=100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--map", required=True, help="a map file (.json, .xodr or Apollo .bin/.txt)")
    ap.add_argument("--out", default="out/demo", help="folder for drive.png (default: out/demo)")
    ap.add_argument("--seed", type=int, default=1, help="episode seed: route, traffic, pedestrians (default: 1)")
    args = ap.parse_args()
    out = Path(args.out)
    m, track, frames, route, info, steps, stages = drive(args.map, args.seed)
    draw(m, track, frames, route, info, steps, stages, out / "drive.png")
    print(f"drove {steps} steps: completed={info['route_completed']} collision={info['collision']} "
          f"progress={info['route_progress']:.2f} violations={info['violations']}")
    print("stage path:", " -> ".join(stages), f"; picture: {out / 'drive.png'}")


if __name__ == "__main__":
    main()
