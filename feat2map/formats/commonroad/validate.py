"""Check a CommonRoad scenario with commonroad-io: its schema, its reader, and what a planner
needs from the lanelet network (each failure is a `Problem`):
- the file is valid against CommonRoad's XSD (shipped with commonroad-io, checked with its
  `XMLFileWriter.check_validity_of_commonroad_file`; the schema's messages name the lines);
- commonroad-io reads it (`XMLFileReader`);
- lanelets: predecessor/successor links go both ways and meet end to start (5 cm), adjacency is
  mutual (same direction: left/right, opposite: left/left) and adjacent lanelets share that
  border (its vertices within 5 cm; run the other way for an opposite lanelet): CommonRoad's
  tools take a lane section's road from its outermost borders and the ends of those inside it
  (commonroad-drivability-checker's road boundary), so borders apart make a road that is not the
  lanelets';
- every intersection manoeuvre is reachable: from an incoming lanelet, through each junction
  lanelet of its right/straight/left sets, to a lanelet past the intersection, searching
  commonroad-io's successor lists; a junction lanelet that crosses the intersection alone turns
  the way its set says (right: clockwise, left: anticlockwise or a U-turn, straight: within twice
  the straight tolerance);
- traffic lights: a cycle with positive durations, used by a lanelet; lights of one
  intersection whose greens overlap govern the same or opposite approaches, or approaches
  whose movements neither cross nor merge (opposed approaches' left turns permissive, as in
  feat2map's paired phase plans);
- stop signs: used by lanelets whose stop line refers to them;
- each planning problem starts on a lanelet from which its goal lanelets are reachable.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from ...angles import wrap_angle
from ...config import SIGNAL_OPPOSITE_DEG, SIGNAL_SAME_APPROACH_DEG
from ...errors import Feat2MapError
from ..base import Problem
from .writer import TURN_SETS as _TURN_SETS
from .writer import commonroad_io, quiet_commonroad, turn_deg

LINK_TOLERANCE_M = 0.05


@dataclass
class CommonRoadReport:
    """What commonroad-io read: element counts, the manoeuvres (intersection, incoming,
    junction lanelet) that are reachable, the scenario, and the problems."""

    counts: Counter = field(default_factory=Counter)
    routes: set[tuple[int, int, int]] = field(default_factory=set)
    problems: list[Problem] = field(default_factory=list)
    scenario: object | None = None


def check_commonroad(path: str | Path) -> CommonRoadReport:
    """Read `path` with commonroad-io and check it (see the module docstring)."""
    commonroad_io()
    from commonroad.common.reader.file_reader_xml import XMLFileReader
    from commonroad.common.writer.file_writer_xml import XMLFileWriter

    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise Feat2MapError(f"cannot read ({exc.strerror})", str(path)) from None
    report = CommonRoadReport()
    if not XMLFileWriter.check_validity_of_commonroad_file(data):
        report.problems += _schema_errors(data, path)
    try:
        with quiet_commonroad():
            scenario, problems = XMLFileReader(str(path)).open()
    except Exception as exc:  # commonroad-io raises many kinds on bad files
        report.problems.append(Problem(str(path), f"commonroad-io cannot read it: {type(exc).__name__}: {exc}"))
        return report
    report.scenario = scenario
    net = scenario.lanelet_network
    report.counts = Counter(lanelets=len(net.lanelets), intersections=len(net.intersections),
                            incomings=sum(len(i.incomings) for i in net.intersections),
                            traffic_lights=len(net.traffic_lights), traffic_signs=len(net.traffic_signs),
                            crosswalks=sum(1 for ll in net.lanelets if "crosswalk" in {t.value for t in ll.lanelet_type}))
    _links(net, report)
    _intersections(net, report)
    _controls(net, report)
    _planning(net, problems, report)
    return report


def validate_commonroad(path: str | Path, progress: bool = False) -> list[Problem]:
    """The problems `check_commonroad` finds (the validate face of the format table)."""
    return check_commonroad(path).problems


def _schema_errors(data: bytes, path: Path) -> list[Problem]:
    import commonroad
    from lxml import etree

    xsd = Path(commonroad.__file__).parent / "common" / "xml_definition_files" / "XML_commonRoad_XSD.xsd"
    schema = etree.XMLSchema(etree.parse(str(xsd)))
    try:
        schema.validate(etree.fromstring(data))
    except etree.XMLSyntaxError as exc:
        return [Problem(str(path), f"not XML: {exc}")]
    errors = [Problem(f"{path}:{e.line}", f"CommonRoad schema: {e.message}") for e in schema.error_log]
    return errors or [Problem(str(path), "CommonRoad schema: invalid")]


def _lanelet_ids(ids: Iterable[int]) -> list[int]:
    return sorted(int(i) for i in ids)


def _links(net, report: CommonRoadReport) -> None:
    lls = lanelet_index(net)
    for ll in net.lanelets:
        where = f"lanelet {ll.lanelet_id}"
        for s in ll.successor:
            other = lls.get(s)
            if other is None or ll.lanelet_id not in other.predecessor:
                report.problems.append(Problem(where, f"successor {s} does not name it as predecessor"))
                continue
            gap = max(np.hypot(*(ll.left_vertices[-1] - other.left_vertices[0])),
                      np.hypot(*(ll.right_vertices[-1] - other.right_vertices[0])))
            if gap > LINK_TOLERANCE_M:
                report.problems.append(Problem(where, f"successor {s} starts {gap:.3f} m from its end"))
        for p in ll.predecessor:
            if p not in lls or ll.lanelet_id not in lls[p].successor:
                report.problems.append(Problem(where, f"predecessor {p} does not name it as successor"))
        for side, adj, same in (("left", ll.adj_left, ll.adj_left_same_direction),
                                ("right", ll.adj_right, ll.adj_right_same_direction)):
            if adj is None:
                continue
            other = lls.get(adj)
            back = None if other is None else (
                (other.adj_right if side == "left" else other.adj_left) if same else
                (other.adj_left if side == "left" else other.adj_right))
            if other is None or back != ll.lanelet_id:
                report.problems.append(Problem(where, f"adjacent {side} {adj} is not adjacent back"))
                continue
            mine = ll.left_vertices if side == "left" else ll.right_vertices
            theirs = ((other.right_vertices if side == "left" else other.left_vertices) if same else
                      (other.left_vertices if side == "left" else other.right_vertices)[::-1])
            if len(mine) != len(theirs):
                report.problems.append(Problem(where, f"adjacent {side} {adj} does not share its border "
                                                      f"({len(mine)} and {len(theirs)} vertices)"))
                continue
            apart = float(np.hypot(*(np.asarray(mine) - np.asarray(theirs)).T).max())
            if apart > LINK_TOLERANCE_M:
                report.problems.append(Problem(where, f"adjacent {side} {adj} does not share its border "
                                                      f"(up to {apart:.2f} m apart)"))


def lanelet_index(net) -> dict[int, Any]:
    """Lanelet id -> commonroad-io Lanelet of a LaneletNetwork (commonroad-io is untyped: Any)."""
    return {ll.lanelet_id: ll for ll in net.lanelets}


def reachable(lls: Mapping[int, Any], starts: Iterable[int], goals: Iterable[int],
              allowed: Iterable[int] | None = None) -> bool:
    """Can a vehicle drive from a lanelet in `starts` to one in `goals` along successors and
    same-direction lane changes (commonroad-io's lists), within `allowed` lanelets (all when None)?"""
    goals = set(goals)
    allowed = set(allowed) if allowed is not None else set(lls)
    queue = deque(s for s in starts if s in lls and s in allowed)
    seen = set(queue)
    while queue:
        cur = queue.popleft()
        if cur in goals:
            return True
        ll = lls[cur]
        nxt = list(ll.successor)
        nxt += [a for a, same in ((ll.adj_left, ll.adj_left_same_direction), (ll.adj_right, ll.adj_right_same_direction))
                if a is not None and same]
        for n in nxt:
            if n in lls and n in allowed and n not in seen:
                seen.add(n)
                queue.append(n)
    return False


def _heading(vertices: np.ndarray, at: str) -> float:
    a, b = (vertices[0], vertices[1]) if at == "start" else (vertices[-2], vertices[-1])
    return math.atan2(b[1] - a[1], b[0] - a[0])


def _intersections(net, report: CommonRoadReport) -> None:
    lls = lanelet_index(net)
    inside = {x for i in net.intersections for inc in i.incomings
              for key in _TURN_SETS for x in getattr(inc, key) or ()}
    for inter in net.intersections:
        for inc in inter.incomings:
            where = f"intersection {inter.intersection_id} incoming {inc.incoming_id}"
            feeders = set(inc.incoming_lanelets or ())
            missing = feeders - set(lls)
            if missing or not feeders:
                report.problems.append(Problem(where, f"incoming lanelets {sorted(missing) or 'none'} not in the network"))
                continue
            for key in _TURN_SETS:
                for jl in _lanelet_ids(getattr(inc, key) or ()):
                    ll = lls.get(jl)
                    if ll is None:
                        report.problems.append(Problem(where, f"{key} lanelet {jl} not in the network"))
                        continue
                    exits = {s for s in ll.successor if s not in inside}
                    if exits == set(ll.successor) and not _TURN_SETS[key](_turn_deg(ll)):  # one lanelet across
                        report.problems.append(Problem(f"lanelet {jl}", f"listed as {key} of {where} but turns "
                                                                        f"{_turn_deg(ll):+.0f} deg"))
                    if not exits or not reachable(lls, feeders, {jl}, feeders | {jl}):
                        report.problems.append(Problem(f"lanelet {jl}", f"manoeuvre of {where} is not reachable "
                                                                        "from its incoming lanelets to a lanelet past it"))
                    else:
                        report.routes.add((inter.intersection_id, inc.incoming_id, jl))


def _turn_deg(ll) -> float:
    return turn_deg(ll.center_vertices)


def _green_steps(light) -> set[int]:
    """The time steps (within one cycle) at which a light is green."""
    out: set[int] = set()
    t = 0
    for el in light.traffic_light_cycle.cycle_elements:
        if el.state.value == "green":
            out.update(range(t, t + int(el.duration)))
        t += int(el.duration)
    return out


def _controls(net, report: CommonRoadReport) -> None:
    users_light: dict[int, set[int]] = {}
    users_sign: dict[int, set[int]] = {}
    for ll in net.lanelets:
        for t in ll.traffic_lights:
            users_light.setdefault(t, set()).add(ll.lanelet_id)
        for s in ll.traffic_signs:
            users_sign.setdefault(s, set()).add(ll.lanelet_id)
            refs = ll.stop_line.traffic_sign_ref if ll.stop_line is not None else None
            if not refs or s not in refs:
                report.problems.append(Problem(f"lanelet {ll.lanelet_id}",
                                               f"traffic sign {s} without a stop line referring to it"))
    for light in net.traffic_lights:
        where = f"traffic light {light.traffic_light_id}"
        cycle = light.traffic_light_cycle
        if cycle is None or not cycle.cycle_elements or any(int(e.duration) <= 0 for e in cycle.cycle_elements):
            report.problems.append(Problem(where, "no cycle, or a cycle element without duration"))
        if not users_light.get(light.traffic_light_id):
            report.problems.append(Problem(where, "no lanelet refers to it"))
    for sign in net.traffic_signs:
        if not users_sign.get(sign.traffic_sign_id):
            report.problems.append(Problem(f"traffic sign {sign.traffic_sign_id}", "no lanelet refers to it"))
    # lights green at once must govern the same or opposite approaches, unless their movements
    # through the intersection neither cross nor merge (a T-junction's stem turning right and
    # the main road's traffic turning left into the stem). A light's approach heading and
    # movements are those of its lanelets entering this intersection (a map may also put a light
    # on a lanelet that enters none: a dead end's heading says nothing here)
    lanelet_of = {ll.lanelet_id: ll for ll in net.lanelets}
    for inter in net.intersections:
        heading_in: dict[int, float] = {}
        moves: dict[int, list] = {}
        turn_of = {x: key for inc in inter.incomings for key in _TURN_SETS for x in getattr(inc, key) or ()}
        for inc in inter.incomings:
            for x in sorted(inc.incoming_lanelets or ()):
                ll = lanelet_of.get(x)
                if ll is None:
                    continue
                for t in ll.traffic_lights:
                    heading_in.setdefault(t, _heading(ll.center_vertices, "end"))
                    moves.setdefault(t, []).extend(lanelet_of[y] for y in ll.successor if y in lanelet_of)
        lights = [light for light in net.traffic_lights if light.traffic_light_id in heading_in]
        for i, a in enumerate(lights):
            for b in lights[i + 1:]:
                if a.traffic_light_cycle is None or b.traffic_light_cycle is None:
                    continue
                if _green_steps(a) & _green_steps(b):
                    ha, hb = heading_in[a.traffic_light_id], heading_in[b.traffic_light_id]
                    apart = math.degrees(abs(wrap_angle(ha - hb)))
                    if SIGNAL_SAME_APPROACH_DEG <= apart <= SIGNAL_OPPOSITE_DEG and \
                            _movements_meet(*_unprotected(moves[a.traffic_light_id], moves[b.traffic_light_id],
                                                          turn_of)):
                        report.problems.append(Problem(f"intersection {inter.intersection_id}",
                                                       f"traffic lights {a.traffic_light_id} and "
                                                       f"{b.traffic_light_id} are green together on crossing approaches"))


def _unprotected(xs: list, ys: list, turn_of: Mapping[int, str]) -> tuple[list, list]:
    """The movements of two lights green together that must not meet: all of them, but when the
    approaches are opposed (each has a straight movement, and no straight of one meets one of
    the other) their left turns and U-turns go permissive and yield, as in feat2map's paired
    phase plans (`phases.units_conflict`); a skewed junction's opposed approaches lie well under
    SIGNAL_OPPOSITE_DEG apart (San Francisco: 128 degrees)."""
    def of(moves: list, key: str) -> list:
        return [x for x in moves if turn_of.get(x.lanelet_id) == key]

    sx, sy = of(xs, "outgoing_straight"), of(ys, "outgoing_straight")
    if not sx or not sy or _movements_meet(sx, sy):
        return xs, ys
    left = {x.lanelet_id for x in of(xs, "outgoing_left") + of(ys, "outgoing_left")}
    return [x for x in xs if x.lanelet_id not in left], [y for y in ys if y.lanelet_id not in left]


def _movements_meet(xs: list, ys: list) -> bool:
    """Whether any movement lanelet of one set crosses one of the other (centre lines) or leads
    into the same lanelet (a merge)."""
    from shapely.geometry import LineString

    for x in xs:
        lx = LineString(x.center_vertices)
        for y in ys:
            if set(x.successor) & set(y.successor) or lx.intersects(LineString(y.center_vertices)):
                return True
    return False


def _planning(net, problems, report: CommonRoadReport) -> None:
    for pp in problems.planning_problem_dict.values():
        where = f"planning problem {pp.planning_problem_id}"
        start = net.find_lanelet_by_position([np.asarray(pp.initial_state.position, dtype=float)])[0]
        goals = {x for ids in (pp.goal.lanelets_of_goal_position or {}).values() for x in ids}
        if not start or not goals or not reachable(lanelet_index(net), start, goals):
            report.problems.append(Problem(where, f"its goal lanelets {sorted(goals)} are not reachable from "
                                                  f"its start (on lanelets {sorted(start)})"))
