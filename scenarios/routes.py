"""Route coverage: every (junction, entry road, exit road) manoeuvre a map allows, few routes
that together drive each of them at least once, and suites of those routes.

A route is a tuple of manoeuvres in driving order, the format of `Scenario.route` and of the
env's `route` config: it starts on a lane of the first entry road and ends on a lane of the
last exit road, and consecutive manoeuvres are joined by road lanes only (no junction between
them that the route does not name). A ramp joined through a direct link (an OpenDRIVE direct
junction, which is no junction of the map) has no manoeuvre: its merge or diverge is a
lane-level route ({"lanes": [...]}, `feat2map.routes.ramp_routes`). Scenarios that take a ramp,
in a junction or not, are named after it ("-merge", "-diverge").
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable, Sequence, cast

from ..errors import Feat2MapError
from ..messages import counted
from ..config import DRIVE_DEFAULTS
from ..model import HDMap, Lane
from ..routes import (DEFAULT_ROUTE_JUNCTIONS, END_ROOM_M, AnyRoute, LaneRoute, Route, coverage_routes,  # noqa: F401 (re-exported)
                      manoeuvre_lane, edge_stub, manoeuvres, successor_graph, suite_manoeuvres, undrivable, _exit_room,
                      road_lanes_between, is_lane_route, lane_route_ids, ramp_routes, route_ramps)
from .scenario import Manoeuvre, Scenario, Suite

SECONDS_PER_JUNCTION = 35.0  # scenario duration budget per junction on the route (a red phase, a stop, a queue)
BASE_DURATION_S = 20.0
SIGNAL_CROSSING_S = 10.0  # after a whole signal cycle: time to cross the junction
YIELDING_TURN_CYCLES = 2  # signal cycles budgeted for a turn that yields to oncoming traffic in its green
ROUTE_SPEED_MPS = 8.0  # plus the route's length at this speed
START_AND_GOAL_M = 45.0  # the env starts the ego <= 30 m before the first junction and ends 15 m after the last


def pick_lane(m: HDMap, mv: Manoeuvre) -> Lane | None:
    """The junction lane the env drives for a manoeuvre (the map layer's rule,
    `feat2map.routes.manoeuvre_lane`)."""
    return manoeuvre_lane(m, mv)


def route_length(m: HDMap, route: Sequence[Manoeuvre]) -> float:
    """Metres the ego drives on `route` (from the env's start to its goal): the env's junction
    lanes, the road lanes joining them, and the start and goal stretches."""
    return _route_sum(m, route, lambda ln: 1.0)


def route_time(m: HDMap, route: Sequence[Manoeuvre]) -> float:
    """Seconds the ego needs to drive `route`'s length at the speeds it drives: each lane at its
    speed limit, at most ROUTE_SPEED_MPS (the mean budgeted on faster lanes, for starts, stops
    and curves)."""
    return _route_sum(m, route, lambda ln: 1.0 / min(ln.speed_limit, ROUTE_SPEED_MPS))


def _route_sum(m: HDMap, route: Sequence[Manoeuvre], per_metre: Callable[[Lane], float]) -> float:
    """`per_metre(lane)` summed over every metre of `route` (`route_length`'s stretches); the start
    and goal stretches at the dearer of the first and last junction lane's road neighbours."""
    found = [pick_lane(m, cast(Manoeuvre, tuple(str(x) for x in mv))) for mv in route]
    picks = [p for p in found if p is not None]
    if len(picks) != len(found):
        raise ValueError(f"route {list(route)} has a manoeuvre the map does not allow")
    ends = [m.lanes[x] for x in picks[0].predecessors + picks[-1].successors if x in m.lanes] if picks else []
    total = START_AND_GOAL_M * max((per_metre(x) for x in ends or picks), default=1.0)
    total += sum(p.length * per_metre(p) for p in picks)
    for a, b in zip(picks, picks[1:]):
        total += _road_gap(m, a, b, per_metre)
    return total


def _lane_route_time(m: HDMap, ids: Sequence[str]) -> float:
    """Seconds the ego needs on a lane route (`route_time`'s speeds): the start and goal
    stretches on its first and last lane, and every lane between them."""
    lanes = [m.lanes[x] for x in ids]
    per_metre = [1.0 / min(ln.speed_limit, ROUTE_SPEED_MPS) for ln in lanes]
    ends = START_AND_GOAL_M * max(per_metre[0], per_metre[-1])
    return ends + sum(ln.length * c for ln, c in zip(lanes[1:-1], per_metre[1:-1]))


def _road_gap(m: HDMap, a: Lane, b: Lane, per_metre: Callable[[Lane], float]) -> float:
    """`per_metre` summed over the cheapest chain of road lanes from junction lane `a` to junction
    lane `b` (with 1 per metre: its length)."""
    import heapq

    cost = lambda ln: ln.length * per_metre(ln)  # noqa: E731
    heap = [(cost(m.lanes[s]), s) for s in a.successors if s in m.lanes and m.lanes[s].junction_id is None]
    heapq.heapify(heap)
    seen: set[str] = set()
    while heap:
        d, lid = heapq.heappop(heap)
        if lid in b.predecessors:
            return d
        if lid in seen:
            continue
        seen.add(lid)
        for s in m.lanes[lid].successors:
            if s in m.lanes and m.lanes[s].junction_id is None and s not in seen:
                heapq.heappush(heap, (d + cost(m.lanes[s]), s))
    return 0.0


def signal_cycle(m: HDMap, junction_id: str) -> float:
    """The env's default signal cycle [s] at a junction (0 without signals): the longest red
    an approach can meet, plus its own green."""
    from ..phases import plan_junction

    signals = [s for s in m.signals.values() if s.junction_id == junction_id]
    if not signals:
        return 0.0
    cfg = DRIVE_DEFAULTS
    phases = plan_junction(m, signals, cfg["signal_phases"] == "paired")
    return len(phases) * (cfg["signal_green"] + cfg["signal_amber"] + cfg["signal_all_red"])


def signal_cycles(m: HDMap, mv: Manoeuvre) -> int:
    """Whole signal cycles a manoeuvre may wait at its junction: two for a left turn or U-turn
    (it yields to oncoming traffic in its green, and a steady stream can hold it through a whole
    green: CommonRoad's four_way_crossing r009 met red, waited out a green's oncoming stream and
    the next red, and went in its second green), else one."""
    lane = pick_lane(m, mv)
    return YIELDING_TURN_CYCLES if lane is not None and lane.turn in ("left", "uturn") else 1


def midblock_wait(m: HDMap, route: Sequence[Manoeuvre]) -> float:
    """The env's default cycle of the mid-block crossings' lights [s] (their shared plan) for
    each of them the route passes between its junctions (0 without)."""
    from ..model import midblock_controls
    from ..phases import junction_phases

    lit = {lid for _, lid, _ in midblock_controls(m).values()}
    if not lit:
        return 0.0
    passes = sum(len(lit & road_lanes_between(m, a, b)) for a, b in zip(route, route[1:]))
    cfg = DRIVE_DEFAULTS
    phases = junction_phases(m, cfg["signal_phases"] == "paired").get(None, ())
    return passes * len(phases) * (cfg["signal_green"] + cfg["signal_amber"] + cfg["signal_all_red"])


def route_duration(m: HDMap, route: Sequence[Manoeuvre] | LaneRoute) -> float:
    """A scenario duration [s] that leaves time for every junction (at least its signal cycles,
    `signal_cycles`, plus crossing at a signal: a 5-leg junction's red outlasts a fixed budget),
    for the mid-block crossings' lights it passes (`midblock_wait`) and for the distance at the
    speeds the ego drives there (`route_time`); a lane route (a direct-link ramp) as one
    junction's budget plus its lanes' time."""
    if is_lane_route(route):
        return round(BASE_DURATION_S + SECONDS_PER_JUNCTION + _lane_route_time(m, lane_route_ids(route)), 1)
    route = cast(Sequence[Manoeuvre], route)
    per_junction = sum(max(SECONDS_PER_JUNCTION, signal_cycles(m, mv) * signal_cycle(m, mv[0]) + SIGNAL_CROSSING_S)
                       for mv in route)
    return round(BASE_DURATION_S + per_junction + midblock_wait(m, route) + route_time(m, route), 1)


def route_coverage(m: HDMap, routes: Iterable[AnyRoute]) -> float:
    """Fraction of the suite manoeuvres of `m` (`suite_manoeuvres`: those no car drives left
    out) that the routes drive (1.0 for a map without any)."""
    all_moves = set(suite_manoeuvres(m))
    if not all_moves:
        return 1.0
    driven = {tuple(str(x) for x in mv) for r in routes if not is_lane_route(r) for mv in r}
    return len(all_moves & driven) / len(all_moves)


def build_suite(map_path: str | Path, *, seed: int = 0, traffic_vehicles: int = 0, pedestrian_rate: float = 0.0,
                max_junctions: int = DEFAULT_ROUTE_JUNCTIONS, duration: float | None = None,
                name: str | None = None, signal_offsets: dict[str, float] | None = None) -> Suite:
    """A route-coverage suite of the map file: one scenario per `coverage_routes` route, seeds
    `seed`, `seed + 1`, ...; durations from `route_duration` (junctions and length) unless given.
    Ramps joined through a direct link (no junction holds them) get a lane route each
    (`feat2map.routes.ramp_routes`) after the coverage routes; a scenario that takes a ramp is
    named after its merge or diverge (`scenario_name`).
    A map that gives no route (no junction, no manoeuvre, no ramp) is a Feat2MapError saying why; U-turns
    tighter than a car turns and lanes that loop (`feat2map.routes.undrivable`) are left out with
    one warning, and so are manoeuvres from a map-edge approach too short to hold a car
    (`feat2map.routes.edge_stub`)."""
    import warnings

    from ..extract_ramps import extract_ramps
    from ..formats import read_map

    path = Path(map_path)
    m = read_map(path)
    tight = [mv for mv in manoeuvres(m) if (ln := manoeuvre_lane(m, mv)) is not None and undrivable(ln)]
    if tight:
        warnings.warn(f"{path}: {counted(len(tight), 'manoeuvre')} no car drives (U-turns tighter than a car turns, lanes "
                      f"that loop) left out of the suite (first: junction {tight[0][0]}, road {tight[0][1]} -> "
                      f"{tight[0][2]})", stacklevel=2)
    stubs = [mv for mv in manoeuvres(m) if mv not in tight and edge_stub(m, mv)]
    if stubs:
        warnings.warn(f"{path}: {len(stubs)} manoeuvre(s) from an approach at the map's edge too short to hold a car "
                      f"left out of the suite (first: junction {stubs[0][0]}, road {stubs[0][1]} -> {stubs[0][2]})",
                      stacklevel=2)
    ramps = extract_ramps(m)
    routes: list[AnyRoute] = [*coverage_routes(m, max_junctions), *(r for _, r in ramp_routes(m, ramps))]
    if not routes:  # never an empty suite that "passes"
        raise Feat2MapError(_no_routes_reason(m), str(path))
    stem = name or path.stem
    scenarios = tuple(
        Scenario(name=scenario_name(stem, i, route_ramps(m, r, ramps)), map=str(path.resolve()), route=r,
                 traffic_vehicles=traffic_vehicles, pedestrian_rate=pedestrian_rate,
                 signal_offsets=dict(signal_offsets or {}), seed=seed + i,
                 duration=duration if duration is not None else route_duration(m, r))
        for i, r in enumerate(routes))
    return Suite(stem, scenarios, path.resolve().parent)


def scenario_name(stem: str, i: int, ramps: Sequence[str] = ()) -> str:
    """The name of a suite's scenario `i`: `<stem>-r<i>`, and the ramp manoeuvres it drives
    (`route_ramps`: "-merge", "-diverge"), so reports show which scenarios take a ramp."""
    return f"{stem}-r{i:03d}" + "".join(f"-{k}" for k in ramps)


def _route_label(route: AnyRoute) -> str:
    """A route in one line: its manoeuvres (junction:entry>exit), or its lanes."""
    if is_lane_route(route):
        return " → ".join(lane_route_ids(route))
    return " → ".join(f"{j}:{e}>{x}" for j, e, x in cast(Route, route))


def _no_routes_reason(m: HDMap) -> str:
    """Why a map gives no route-coverage route, in one line."""
    if not m.junctions:
        return "no junctions and no ramps: a route-coverage suite drives junction manoeuvres and ramps"
    found = manoeuvres(m)
    if found and not suite_manoeuvres(m):
        return f"no manoeuvres but {len(found)} that no car drives (tight U-turns, lanes that loop)"
    if not found:
        return (f"no manoeuvres: none of its {len(m.junctions)} junctions has a junction lane from a road lane "
                "to a road lane")
    return f"none of its {len(found)} manoeuvres can be driven (no junction lane the env drives)"


def render_routes(m: HDMap, routes: Sequence[AnyRoute], path: str | Path, *, names: Sequence[str] | None = None,
                  cols: int = 4, dpi: int = 110) -> None:
    """A picture (PNG or SVG) with one panel per route: the map, the route's lanes highlighted
    (as the env drives them) and its manoeuvres listed; written atomically."""
    import matplotlib.pyplot as plt

    from ..envs.routes import manoeuvres_to_lanes
    from ..envs.network import MapNetwork
    from ..render import draw_map, save_figure

    net = MapNetwork.from_map(m)
    n = max(len(routes), 1)
    cols = min(cols, n)
    rows = -(-n // cols)
    x0, y0, x1, y1 = m.bounds()
    aspect = min(max((x1 - x0) / max(y1 - y0, 1.0), 0.4), 2.5)  # panel shape follows the map's
    fig, axes = plt.subplots(rows, cols, figsize=(4.4 * aspect * cols + 0.4, 4.8 * rows), squeeze=False)
    try:
        for ax in axes.flat:
            ax.set_axis_off()
        for i, (ax, route) in enumerate(zip(axes.flat, routes)):
            ax.set_axis_on()
            lanes = lane_route_ids(route) if is_lane_route(route) else manoeuvres_to_lanes(net, cast(Route, route))
            draw_map(m, ax, labels=True, highlight_lanes=lanes)
            start = m.lanes[lanes[0]].centerline[0]
            ax.plot(*start, marker="o", ms=6, color="#ff6f00", mec="k", zorder=8)
            title = names[i] if names else f"route {i}"
            ax.set_title(f"{title}\n" + _route_label(route), fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_xlabel("")
            ax.set_ylabel("")
        fig.tight_layout()
    except BaseException:
        plt.close(fig)
        raise
    save_figure(fig, path, dpi)
