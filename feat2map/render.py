"""Bird's-eye pictures of maps (PNG or SVG by file extension), in the style of the paper's Figs. 4-5."""
from __future__ import annotations

import io
from pathlib import Path
from typing import Iterable

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402

from . import atomic  # noqa: E402
from .errors import Feat2MapError  # noqa: E402
from .model import HDMap  # noqa: E402

CONTROL_COLOURS = {"signal": "#2e7d32", "stop": "#c62828", "bare": "#1565c0"}
YIELD_COLOUR = "#f9a825"  # yield signs (filter lanes)
NO_CONTROL_COLOUR = "#9e9e9e"  # junctions of unknown control
JUNCTION_KINDS = (("signal", "traffic lights"), ("stop", "stop signs"), ("bare", "no control"),
                  ("", "control unknown"))
PAVEMENT, LANE_EDGE, JUNCTION_LANE = "#cfd8dc", "#455a64", "#90a4ae"
ROUTE_COLOUR = "#ff6f00"
ONE_WAY_COLOUR = "#6a1b9a"
LEGEND_WIDTH_IN = 3.0  # beside the map in render_map
ONE_WAY_ARROW_SPACING_M = 40.0  # one direction arrow per this much lane of a one-way road


PICTURE_SUFFIXES = (".png", ".svg", ".pdf")


def check_picture_path(path: str | Path) -> Path:
    """`path` when a picture can be written there (a known suffix, not a folder); before any work."""
    path = atomic.check_file_target(path, "--picture")
    if path.suffix.lower() not in PICTURE_SUFFIXES:
        raise Feat2MapError(f"unknown picture type {path.suffix or '(no suffix)'!r}: use one of "
                            f"{', '.join(PICTURE_SUFFIXES)}", str(path))
    return path


def printable(text: object) -> str:
    """`text` as fonts can draw it: a file name's undecodable bytes (surrogate escapes, as Python
    reads non-UTF-8 names) become U+FFFD instead of failing the renderer."""
    s = str(text)
    return s.encode("utf-8", "surrogateescape").decode("utf-8", "replace") if any(
        "\udc80" <= c <= "\udcff" for c in s) else s


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Write a matplotlib figure atomically (format from the suffix, PNG by default) and close it."""
    try:
        path = check_picture_path(path)
        for text in fig.findobj(lambda a: hasattr(a, "get_text") and hasattr(a, "set_text")):
            text.set_text(printable(text.get_text()))
        buf = io.BytesIO()
        fig.savefig(buf, format=path.suffix.lstrip(".").lower(), dpi=dpi)
    finally:
        plt.close(fig)
    atomic.write_bytes(path, buf.getvalue())
    return path


def draw_map(m: HDMap, ax, *, labels: bool = True, controls: dict[str, str] | None = None,
             highlight_lanes: Iterable[str] = (), legend: bool = False) -> None:
    """Draw `m` on a matplotlib axis: pavement, junctions, lanes, one-way arrows, controls,
    crosswalks, ids; `legend` adds a legend of what was drawn inside the axis (`legend_handles`
    gives the handles to place one elsewhere).

    `controls` (junction id -> control) colours junction areas, as in extraction pictures.
    """
    ctrl = controls if controls is not None else {
        jid: j.feature.control for jid, j in m.junctions.items() if j.feature is not None}
    ax.add_collection(PolyCollection(
        [j.polygon for j in m.junctions.values() if len(j.polygon) >= 3],
        facecolors=[CONTROL_COLOURS.get(ctrl.get(jid, ""), NO_CONTROL_COLOUR) for jid, j in m.junctions.items()
                    if len(j.polygon) >= 3], alpha=0.18, edgecolors="#616161", linewidths=0.5, zorder=1))
    road = [ln for ln in m.lanes.values() if ln.junction_id is None]
    inner = [ln for ln in m.lanes.values() if ln.junction_id is not None]
    ax.add_collection(PolyCollection([ln.left_boundary + tuple(reversed(ln.right_boundary)) for ln in road],
                                     facecolors=PAVEMENT, edgecolors="none", zorder=0))
    ax.add_collection(LineCollection([ln.left_boundary for ln in road] + [ln.right_boundary for ln in road],
                                     colors=LANE_EDGE, linewidths=0.4, zorder=2))
    ax.add_collection(LineCollection([ln.centerline for ln in inner], colors=JUNCTION_LANE, linewidths=0.4,
                                     linestyles="dashed", zorder=2))
    ax.add_collection(LineCollection([ln.centerline for ln in road], colors="#ffffff", linewidths=0.3, zorder=2))
    _one_way_arrows(m, ax)
    hl = [m.lanes[i].centerline for i in highlight_lanes if i in m.lanes]
    if hl:
        ax.add_collection(LineCollection(hl, colors=ROUTE_COLOUR, linewidths=2.0, zorder=6))
    if m.crosswalks:
        ax.add_collection(PolyCollection([c.polygon for c in m.crosswalks.values() if len(c.polygon) >= 3],
                                         facecolors="none", edgecolors="#212121", hatch="////", linewidths=0.4,
                                         zorder=3))
    for s in m.signals.values():
        ax.plot(*zip(*s.stop_line), color=CONTROL_COLOURS["signal"], lw=1.2, zorder=4)
        ax.plot(*s.position, marker="o", ms=3.5, color=CONTROL_COLOURS["signal"], mec="k", mew=0.3, zorder=5)
    for stop in m.stop_signs.values():
        ax.plot(*zip(*stop.stop_line), color=CONTROL_COLOURS["stop"], lw=1.2, zorder=4)
        ax.plot(*stop.position, marker="8", ms=4.0, color=CONTROL_COLOURS["stop"], mec="k", mew=0.3, zorder=5)
    for y in m.yield_signs.values():  # a filter lane's give-way line: dashed, a triangle on its pole
        ax.plot(*zip(*y.stop_line), color=YIELD_COLOUR, lw=1.2, ls=(0, (2, 1)), zorder=4)
        ax.plot(*y.position, marker="v", ms=4.5, color=YIELD_COLOUR, mec="k", mew=0.3, zorder=5)
    if labels:
        for jid, j in m.junctions.items():
            if len(j.polygon) >= 3:
                ax.annotate(jid, j.center, ha="center", va="center", fontsize=7, zorder=7,
                            bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.7))
    if controls is not None:  # extraction pictures: a dot per junction, visible at whole-map scale
        marked = [(j.center, CONTROL_COLOURS.get(ctrl.get(jid, ""), NO_CONTROL_COLOUR))
                  for jid, j in m.junctions.items() if len(j.polygon) >= 3]
        if marked:
            ax.scatter([c[0] for c, _ in marked], [c[1] for c, _ in marked], s=60, c=[k for _, k in marked],
                       alpha=0.6, edgecolors="k", linewidths=0.3, zorder=6)
    if legend:
        ax.legend(handles=legend_handles(m, labels=labels, controls=controls, highlight=bool(hl)), loc="best",
                  fontsize=6, framealpha=0.85)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def _one_way_roads(m: HDMap) -> list:
    return [r for r in m.roads.values() if r.junction_id is None and bool(r.right_lanes) != bool(r.left_lanes)]


def _one_way_arrows(m: HDMap, ax) -> None:
    """Arrows along every lane of each one-way road (lanes on one side only), in driving direction:
    one per ONE_WAY_ARROW_SPACING of lane, sized to the map."""
    lanes = [m.lanes[i] for r in _one_way_roads(m) for i in r.lane_ids if i in m.lanes]
    if not lanes:
        return
    x0, y0, x1, y1 = m.bounds()
    size = min(max(max(x1 - x0, y1 - y0) / 80.0, 3.0), 15.0)
    xs, ys, us, vs = [], [], [], []
    for ln in lanes:
        pts = np.asarray(ln.centerline, dtype=float)
        seg = np.hypot(*np.diff(pts, axis=0).T)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        if s[-1] < size:
            continue
        n = max(1, int(s[-1] // ONE_WAY_ARROW_SPACING_M))
        for at in (s[-1] * (k + 0.5) / n for k in range(n)):
            i = min(int(np.searchsorted(s, at, side="right")) - 1, len(seg) - 1)
            d = (pts[i + 1] - pts[i]) / max(seg[i], 1e-9)
            p = pts[i] + d * (at - s[i]) - d * size / 2
            xs.append(p[0])
            ys.append(p[1])
            us.append(d[0] * size)
            vs.append(d[1] * size)
    ax.quiver(xs, ys, us, vs, angles="xy", scale_units="xy", scale=1, color=ONE_WAY_COLOUR, width=0.003,
              headwidth=3.5, headlength=3.5, headaxislength=3, zorder=5)


def legend_handles(m: HDMap, *, labels: bool = True, controls: dict[str, str] | None = None,
                   highlight: bool = False) -> list:
    """Legend entries for what `draw_map` draws of `m` (only the kinds of element it has)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    ctrl = controls if controls is not None else {
        jid: j.feature.control for jid, j in m.junctions.items() if j.feature is not None}
    used = {ctrl.get(jid, "") for jid in m.junctions}
    out: list[Patch | Line2D] = [Patch(facecolor=CONTROL_COLOURS.get(k, NO_CONTROL_COLOUR), alpha=0.35, edgecolor="#616161",
                 label=f"junction: {name}") for k, name in JUNCTION_KINDS if k in used]
    if labels and m.junctions:
        out.append(Line2D([], [], ls="none", marker="$J0$", ms=11, color="k", label="junction id"))
    if any(ln.junction_id is None for ln in m.lanes.values()):
        out.append(Patch(facecolor=PAVEMENT, edgecolor=LANE_EDGE, label="road lanes (white: lane centre)"))
    if any(ln.junction_id is not None for ln in m.lanes.values()):
        out.append(Line2D([], [], color=JUNCTION_LANE, ls="--", lw=1, label="lane through a junction"))
    if _one_way_roads(m):
        out.append(Line2D([], [], ls="none", marker=r"$\rightarrow$", ms=12, color=ONE_WAY_COLOUR,
                          label="one-way road (driving direction)"))
    if highlight:
        out.append(Line2D([], [], color=ROUTE_COLOUR, lw=2, label="route"))
    if m.signals:
        out.append(Line2D([], [], color=CONTROL_COLOURS["signal"], marker="o", ms=5, mec="k", mew=0.3, lw=1.2,
                          label="traffic light and its stop line"))
    if m.stop_signs:
        out.append(Line2D([], [], color=CONTROL_COLOURS["stop"], marker="8", ms=5, mec="k", mew=0.3, lw=1.2,
                          label="stop sign and its stop line"))
    if m.yield_signs:
        out.append(Line2D([], [], color=YIELD_COLOUR, marker="v", ms=5, mec="k", mew=0.3, lw=1.2, ls=(0, (2, 1)),
                          label="yield sign and its give-way line"))
    if m.crosswalks:
        out.append(Patch(facecolor="none", edgecolor="#212121", hatch="////", label="crosswalk"))
    return out


def render_map(m: HDMap, path: str | Path, *, title: str | None = None, size_in: float = 9.0, dpi: int = 150,
               **kwargs) -> None:
    """Write a bird's-eye picture of `m` to `path` (PNG or SVG), atomically, with a legend of
    what it shows beside the map."""
    path = Path(path)
    x0, y0, x1, y1 = m.bounds() if m.lanes else (0.0, 0.0, 1.0, 1.0)
    aspect = min(max((y1 - y0) / max(x1 - x0, 1e-9), 0.4), 2.5)  # map height / width, bounded
    w, h = (size_in / aspect, size_in) if aspect >= 1 else (size_in, size_in * aspect)
    fig = plt.figure(figsize=(w + 1.0 + LEGEND_WIDTH_IN, h + 1.2), layout="constrained")
    try:
        ax = fig.add_subplot()
        draw_map(m, ax, **kwargs)
        ax.legend(handles=legend_handles(m, labels=kwargs.get("labels", True), controls=kwargs.get("controls"),
                                         highlight=bool(kwargs.get("highlight_lanes"))),
                  loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0, fontsize=8)
        if title:
            ax.set_title(title)
    except BaseException:
        plt.close(fig)
        raise
    save_figure(fig, path, dpi)


def render_junctions(m: HDMap, path: str | Path, *, margin: float = 12.0, cols: int = 4, dpi: int = 130) -> None:
    """A gallery with one close-up per junction (paper Fig. 5), titled with its feature, and one
    legend below."""
    ids = [jid for jid, j in m.junctions.items() if len(j.polygon) >= 3]
    rows = max(1, -(-len(ids) // cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.4 * rows + 0.9), squeeze=False, layout="constrained")
    try:
        for ax in axes.flat:
            ax.set_axis_off()
        for ax, jid in zip(axes.flat, ids):
            j = m.junctions[jid]
            ax.set_axis_on()
            draw_map(m, ax, labels=False)
            xs, ys = zip(*j.polygon)
            ax.set_xlim(min(xs) - margin, max(xs) + margin)
            ax.set_ylim(min(ys) - margin, max(ys) + margin)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_xlabel("")
            ax.set_ylabel("")
            f = j.feature
            title = jid if f is None else f"{jid}: n={f.n_roads}, {f.control}{', crosswalk' if f.crosswalk else ''}"
            ax.set_title(title, fontsize=8)
        fig.legend(handles=legend_handles(m, labels=False), loc="outside lower center", ncols=4, fontsize=8)
    except BaseException:
        plt.close(fig)
        raise
    save_figure(fig, path, dpi)
