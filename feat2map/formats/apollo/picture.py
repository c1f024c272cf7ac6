"""A bird's-eye picture (PNG/SVG) of an Apollo map as Apollo will read it, with the validator's
problems marked where they are: lane boundaries by type (dashed = dotted, grey = virtual),
junction polygons, crosswalks, signal and stop-sign stop lines, the signal/stop/crosswalk
overlap ranges on lanes, and a red ring at every element with a problem.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from . import schema as aps
from ..base import Problem

_STYLE = {aps.LaneBoundaryType.DOTTED_YELLOW: ("#d4a000", "--"), aps.LaneBoundaryType.DOTTED_WHITE: ("0.35", "--"),
          aps.LaneBoundaryType.SOLID_YELLOW: ("#d4a000", "-"), aps.LaneBoundaryType.SOLID_WHITE: ("0.35", "-"),
          aps.LaneBoundaryType.DOUBLE_YELLOW: ("#d4a000", "-"), aps.LaneBoundaryType.CURB: ("k", "-")}
_OVERLAP_COLOUR = {"signal_overlap_info": "red", "stop_sign_overlap_info": "orange",
                   "crosswalk_overlap_info": "magenta"}


def _xy(points: Any) -> np.ndarray:
    return np.asarray([(p.x, p.y) for p in points], dtype=float).reshape(-1, 2)


def _curve(curve: Any) -> np.ndarray:
    return np.concatenate([_xy(s.line_segment.point) for s in curve.segment] or [np.zeros((0, 2))])


def problem_locations(m: Any, problems: Sequence[Problem]) -> list[tuple[float, float]]:
    """A point for every problem whose element has geometry (files and the header have none)."""
    where: dict[str, np.ndarray] = {}
    for ln in m.lane:
        c = _curve(ln.central_curve)
        if len(c):
            where[f"lane {ln.id.id}"] = c[len(c) // 2]
    for kind in ("junction", "crosswalk"):
        for e in getattr(m, kind):
            p = _xy(e.polygon.point)
            if len(p):
                where[f"{kind} {e.id.id}"] = p.mean(axis=0)
    for kind in ("signal", "stop_sign"):
        for e in getattr(m, kind):
            pts = [_curve(c) for c in e.stop_line]
            pts = [p for p in pts if len(p)]
            if pts:
                where[f"{kind} {e.id.id}"] = pts[0].mean(axis=0)
            elif kind == "signal" and e.boundary.point:
                where[f"{kind} {e.id.id}"] = _xy(e.boundary.point).mean(axis=0)
    for r in m.road:
        for sec in r.section:
            for lid in sec.lane_id:
                if f"lane {lid.id}" in where:
                    where.setdefault(f"road {r.id.id}", where[f"lane {lid.id}"])
    for ov in m.overlap:
        for o in ov.object:
            kind = (o.WhichOneof("overlap_info") or "").removesuffix("_overlap_info")
            if f"{kind} {o.id.id}" in where:
                where.setdefault(f"overlap {ov.id.id}", where[f"{kind} {o.id.id}"])
    out = []
    for prob in problems:
        key = prob.element.removeprefix("sim_map ")
        if key in where:
            out.append((float(where[key][0]), float(where[key][1])))
    return out


def render_apollo(m: Any, path: str | Path, problems: Sequence[Problem] = (), title: str | None = None) -> None:
    """Draw Apollo map `m` to `path` (format from the suffix), problems ringed in red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon as Patch

    from ...render import save_figure

    fig, ax = plt.subplots(figsize=(12.5, 10), layout="constrained")
    segs: dict[tuple[str, str], list[np.ndarray]] = {}
    centres = []
    lanes = {}
    for ln in m.lane:
        lanes[ln.id.id] = c = _curve(ln.central_curve)
        if len(c) > 1:
            centres.append(c)
        for b in (ln.left_boundary, ln.right_boundary):
            p = _curve(b.curve)
            if len(p) < 2:
                continue
            t = b.boundary_type[0].types[0] if b.boundary_type and b.boundary_type[0].types else None
            style = ("0.8", ":") if b.virtual or t is None else _STYLE.get(t, ("0.6", ":"))
            segs.setdefault(style, []).append(p)
    ax.add_collection(LineCollection(centres, colors="#9fd3e6", linewidths=0.4))
    for (colour, ls), lines in segs.items():
        ax.add_collection(LineCollection(lines, colors=colour, linestyles=ls, linewidths=0.6))
    for j in m.junction:
        if len(j.polygon.point) >= 3:
            ax.add_patch(Patch(_xy(j.polygon.point), closed=True, fc="none", ec="tab:blue", lw=0.6, ls="-."))
    for cw in m.crosswalk:
        if len(cw.polygon.point) >= 3:
            ax.add_patch(Patch(_xy(cw.polygon.point), closed=True, fc="none", ec="magenta", hatch="///", lw=0.5))
    for kind, colour in (("signal", "red"), ("stop_sign", "orange")):
        lines = [p for e in getattr(m, kind) for c in e.stop_line if len(p := _curve(c)) > 1]
        ax.add_collection(LineCollection(lines, colors=colour, linewidths=2.0))
    ranges: dict[str, list[np.ndarray]] = {}
    for ov in m.overlap:
        objs = {o.WhichOneof("overlap_info"): o for o in ov.object}
        lane = objs.get("lane_overlap_info")
        other = next((k for k in objs if k in _OVERLAP_COLOUR), None)
        if lane is None or other is None or len(lanes.get(lane.id.id, ())) < 2:
            continue
        c = lanes[lane.id.id]
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(c, axis=0).T))])
        a, b = lane.lane_overlap_info.start_s, lane.lane_overlap_info.end_s
        grid = np.linspace(a, max(a, b), 8)
        ranges.setdefault(other, []).append(np.column_stack([np.interp(grid, s, c[:, 0]), np.interp(grid, s, c[:, 1])]))
    for kind, lines in ranges.items():
        ax.add_collection(LineCollection(lines, colors=_OVERLAP_COLOUR[kind], linewidths=3.5, alpha=0.45))
    spots = problem_locations(m, problems)
    if spots:
        xs, ys = zip(*spots)
        ax.scatter(xs, ys, s=160, facecolors="none", edgecolors="red", linewidths=1.5, zorder=5)
    ax.legend(handles=_legend(problems), loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0, fontsize=8)
    ax.autoscale()
    ax.set_aspect("equal")
    ax.set_xlabel("UTM easting [m]")
    ax.set_ylabel("UTM northing [m]")
    ax.ticklabel_format(useOffset=True, style="plain")
    placed = len(spots)
    ax.set_title(title or f"{len(m.lane)} lanes, {len(m.junction)} junctions; {len(problems)} problems "
                          f"({placed} ringed)", fontsize=9)
    save_figure(fig, path)


def _legend(problems: Sequence[Problem]) -> list:
    """What render_apollo's colours and line styles mean."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    out = [Line2D([], [], color="#9fd3e6", lw=1, label="lane centre line"),
           Line2D([], [], color="0.35", lw=1, label="lane boundary: solid white (dashed: dotted)"),
           Line2D([], [], color="#d4a000", lw=1, label="lane boundary: yellow (dashed: dotted)"),
           Line2D([], [], color="0.8", ls=":", lw=1, label="virtual boundary (inside junctions)"),
           Patch(fc="none", ec="tab:blue", ls="-.", label="junction polygon"),
           Patch(fc="none", ec="magenta", hatch="///", label="crosswalk"),
           Line2D([], [], color="red", lw=2, label="signal stop line"),
           Line2D([], [], color="orange", lw=2, label="stop-sign stop line")]
    out += [Line2D([], [], color=c, lw=3.5, alpha=0.45, label=f"lane overlap with a {k.split('_overlap')[0].replace('_', ' ')}")
            for k, c in _OVERLAP_COLOUR.items()]
    if problems:
        out.append(Line2D([], [], ls="none", marker="o", ms=11, mfc="none", mec="red", mew=1.5, label="problem"))
    return out


def render_problems(path: str | Path, out: str | Path, problems: Sequence[Problem] = (),
                    title: str | None = None) -> None:
    """The base map of the Apollo folder or file at `path` drawn to `out`, problems ringed."""
    from .validate import load_base_map

    render_apollo(load_base_map(path), out, problems, title)
