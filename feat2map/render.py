"""Bird's-eye pictures of maps (PNG or SVG by file extension), in the style of the paper's Figs. 4-5."""
from __future__ import annotations

import io
from pathlib import Path
from typing import Iterable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402

from . import atomic  # noqa: E402
from .model import HDMap  # noqa: E402

CONTROL_COLOURS = {"signal": "#2e7d32", "stop": "#c62828", "bare": "#1565c0"}


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Write a matplotlib figure atomically (format from the suffix, PNG by default) and close it."""
    path = Path(path)
    try:
        buf = io.BytesIO()
        fig.savefig(buf, format=path.suffix.lstrip(".").lower() or "png", dpi=dpi)
    finally:
        plt.close(fig)
    atomic.write_bytes(path, buf.getvalue())
    return path


def draw_map(m: HDMap, ax, *, labels: bool = True, controls: dict[str, str] | None = None,
             highlight_lanes: Iterable[str] = ()) -> None:
    """Draw `m` on a matplotlib axis: pavement, junctions, lanes, controls, crosswalks, ids.

    `controls` (junction id -> control) colours junction areas, as in extraction pictures.
    """
    ctrl = controls if controls is not None else {
        jid: j.feature.control for jid, j in m.junctions.items() if j.feature is not None}
    ax.add_collection(PolyCollection(
        [j.polygon for j in m.junctions.values() if len(j.polygon) >= 3],
        facecolors=[CONTROL_COLOURS.get(ctrl.get(jid, ""), "#9e9e9e") for jid, j in m.junctions.items()
                    if len(j.polygon) >= 3], alpha=0.18, edgecolors="#616161", linewidths=0.5, zorder=1))
    road = [ln for ln in m.lanes.values() if ln.junction_id is None]
    inner = [ln for ln in m.lanes.values() if ln.junction_id is not None]
    ax.add_collection(PolyCollection([ln.left_boundary + tuple(reversed(ln.right_boundary)) for ln in road],
                                     facecolors="#cfd8dc", edgecolors="none", zorder=0))
    ax.add_collection(LineCollection([ln.left_boundary for ln in road] + [ln.right_boundary for ln in road],
                                     colors="#455a64", linewidths=0.4, zorder=2))
    ax.add_collection(LineCollection([ln.centerline for ln in inner], colors="#90a4ae", linewidths=0.4,
                                     linestyles="dashed", zorder=2))
    ax.add_collection(LineCollection([ln.centerline for ln in road], colors="#ffffff", linewidths=0.3, zorder=2))
    hl = [m.lanes[i].centerline for i in highlight_lanes if i in m.lanes]
    if hl:
        ax.add_collection(LineCollection(hl, colors="#ff6f00", linewidths=2.0, zorder=6))
    if m.crosswalks:
        ax.add_collection(PolyCollection([c.polygon for c in m.crosswalks.values() if len(c.polygon) >= 3],
                                         facecolors="none", edgecolors="#212121", hatch="////", linewidths=0.4,
                                         zorder=3))
    for s in m.signals.values():
        ax.plot(*zip(*s.stop_line), color=CONTROL_COLOURS["signal"], lw=1.2, zorder=4)
        ax.plot(*s.position, marker="o", ms=3.5, color=CONTROL_COLOURS["signal"], mec="k", mew=0.3, zorder=5)
    for s in m.stop_signs.values():
        ax.plot(*zip(*s.stop_line), color=CONTROL_COLOURS["stop"], lw=1.2, zorder=4)
        ax.plot(*s.position, marker="8", ms=4.0, color=CONTROL_COLOURS["stop"], mec="k", mew=0.3, zorder=5)
    if labels:
        for jid, j in m.junctions.items():
            if len(j.polygon) >= 3:
                ax.annotate(jid, j.center, ha="center", va="center", fontsize=6, zorder=7,
                            bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.7))
    if controls is not None:  # extraction pictures: say what the junction colours mean
        from matplotlib.patches import Patch

        marked = [(j.center, CONTROL_COLOURS.get(ctrl.get(jid, ""), "#9e9e9e")) for jid, j in m.junctions.items()
                  if len(j.polygon) >= 3]
        if marked:  # a dot per junction, visible at whole-map scale
            ax.scatter([c[0] for c, _ in marked], [c[1] for c, _ in marked], s=60, c=[k for _, k in marked],
                       alpha=0.6, edgecolors="k", linewidths=0.3, zorder=6)
        ax.legend(handles=[Patch(facecolor=c, alpha=0.5, label=k) for k, c in CONTROL_COLOURS.items()],
                  loc="upper right", fontsize=7, title="junction control", title_fontsize=7)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def render_map(m: HDMap, path: str | Path, *, title: str | None = None, size_in: float = 9.0, dpi: int = 150,
               **kwargs) -> None:
    """Write a bird's-eye picture of `m` to `path` (PNG or SVG), atomically."""
    path = Path(path)
    fig, ax = plt.subplots(figsize=(size_in, size_in))
    try:
        draw_map(m, ax, **kwargs)
        if title:
            ax.set_title(title)
        fig.tight_layout()
    except BaseException:
        plt.close(fig)
        raise
    save_figure(fig, path, dpi)


def render_junctions(m: HDMap, path: str | Path, *, margin: float = 12.0, cols: int = 4, dpi: int = 130) -> None:
    """A gallery with one close-up per junction (paper Fig. 5), titled with its feature."""
    ids = [jid for jid, j in m.junctions.items() if len(j.polygon) >= 3]
    rows = max(1, -(-len(ids) // cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 3.4 * rows), squeeze=False)
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
        fig.tight_layout()
    except BaseException:
        plt.close(fig)
        raise
    save_figure(fig, path, dpi)
