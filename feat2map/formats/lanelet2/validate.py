"""Check a Lanelet2 map with the `lanelet2` wheel (Lanelet2's own loader and routing), as
Autoware would load it: the projector origin from `map_projector_info.yaml` beside the file.

What is checked (each failure is a `Problem`):
- the file loads without parser errors (`lanelet2.io.loadRobust`);
- lanelet2_validation's map checks, on the loaded map: no point twice in a row in a linestring;
  no two points closer than 5 cm and lanelet bound curvature at most 0.5 1/m, which
  lanelet2_validation rates warnings (`Severity::Warning`: "can confuse algorithms"), and so do we;
- the routing graph for vehicles (German rules, the only ones Lanelet2 ships) has no validity
  errors (`RoutingGraph.checkValidity`, the check lanelet2_validation runs);
- every manoeuvre a junction lanelet is tagged with (feat2map:junction/from/to) is a route:
  from a lanelet of its entry road, via the junction lanelet, to a lanelet of its exit road;
- regulatory elements: traffic lights have their stop line, all-way stops one stop line per
  lanelet, every lanelet a right-of-way names refers back to it, every element is used;
- crosswalk lanelets are passable for pedestrians and not for vehicles;
- Autoware's `local_x`/`local_y` tags agree with the projected lat/lon within 1 cm.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import Feat2MapError
from ...routes import Manoeuvre
from ..base import Problem
from .writer import PROJECTOR_INFO, TAG

MAX_CURVATURE = 0.5  # 1/m, lanelet2_validation's CurvatureTooBig
MIN_POINT_DISTANCE_M = 0.05  # lanelet2_validation's PointsTooClose
LOCAL_TOLERANCE_M = 0.01


@dataclass
class Lanelet2Report:
    """What the wheel found: lanelets and regulatory elements by subtype, the manoeuvres that
    are routes, and the problems."""

    lanelets: Counter = field(default_factory=Counter)
    regulatory_elements: Counter = field(default_factory=Counter)
    routes: set[Manoeuvre] = field(default_factory=set)
    problems: list[Problem] = field(default_factory=list)


def _lanelet2():
    try:
        import lanelet2  # noqa: F401
        from lanelet2 import io, projection, routing, traffic_rules  # noqa: F401
    except ImportError:
        raise Feat2MapError("checking Lanelet2 maps needs the lanelet2 wheel (pip install lanelet2; "
                            "Linux x86_64)", "lanelet2") from None
    return lanelet2


def _origin(path: Path, report: Lanelet2Report) -> tuple[float, float]:
    """(lat, lon) of the projector origin: map_projector_info.yaml beside the map, else (with a
    problem) the first node."""
    import yaml

    info = path.parent / PROJECTOR_INFO
    try:
        doc = yaml.safe_load(info.read_text(encoding="utf-8"))
        o = doc["map_origin"]
        if doc.get("projector_type") != "LocalCartesianUTM":
            report.problems.append(Problem(str(info), f"projector_type {doc.get('projector_type')!r}, "
                                                      "expected LocalCartesianUTM"))
        return float(o["latitude"]), float(o["longitude"])
    except (OSError, TypeError, KeyError, ValueError, yaml.YAMLError) as exc:
        report.problems.append(Problem(str(info), f"no projector origin for Autoware ({type(exc).__name__}: {exc})"))
    from lxml import etree

    for _, el in etree.iterparse(str(path), tag="node"):
        return float(el.get("lat")), float(el.get("lon"))
    return 0.0, 0.0


def check_lanelet2(path: str | Path) -> Lanelet2Report:
    """Load `path` with the lanelet2 wheel and check it (see the module docstring)."""
    ll2 = _lanelet2()
    from lanelet2 import routing, traffic_rules
    from lanelet2.io import Origin
    from lanelet2.projection import UtmProjector

    path = Path(path)
    if not path.is_file():
        raise Feat2MapError("no such map file", str(path))
    report = Lanelet2Report()
    lat, lon = _origin(path, report)
    lmap, errors = ll2.io.loadRobust(str(path), UtmProjector(Origin(lat, lon)))
    report.problems += [Problem(str(path), f"lanelet2 loader: {e}") for e in errors]
    _points(lmap, report)
    report.lanelets = Counter(str(ll.attributes["subtype"]) if "subtype" in ll.attributes else "" for ll in lmap.laneletLayer)
    report.regulatory_elements = Counter(str(r.attributes["subtype"]) for r in lmap.regulatoryElementLayer)
    vehicle = traffic_rules.create(traffic_rules.Locations.Germany, traffic_rules.Participants.Vehicle)
    pedestrian = traffic_rules.create(traffic_rules.Locations.Germany, traffic_rules.Participants.Pedestrian)
    graph = routing.RoutingGraph(lmap, vehicle)
    # lanelet2's stub says checkValidity returns None; with throw_on_error=False it returns the errors
    invalid: Any = graph.checkValidity(False)  # type: ignore[func-returns-value]
    report.problems += [Problem(str(path), f"routing graph: {e}") for e in invalid]
    _manoeuvres(lmap, graph, report)
    _regulatory_elements(lmap, report)
    for ll in lmap.laneletLayer:
        if ll.attributes["subtype"] == "crosswalk" and (vehicle.canPass(ll) or not pedestrian.canPass(ll)):
            report.problems.append(Problem(f"lanelet {ll.id}", "crosswalk is not for pedestrians only"))
    return report


def validate_lanelet2(path: str | Path, progress: bool = False) -> list[Problem]:
    """The problems `check_lanelet2` finds (the validate face of the format table)."""
    return check_lanelet2(path).problems


def _tag(prim, key: str) -> str | None:
    return str(prim.attributes[key]) if key in prim.attributes else None


def _points(lmap, report: Lanelet2Report) -> None:
    from lanelet2.core import BasicPoint2d

    for ls in lmap.lineStringLayer:
        ids = [p.id for p in ls]
        if any(a == b for a, b in zip(ids, ids[1:])):
            report.problems.append(Problem(f"linestring {ls.id}", "a point twice in a row"))
    for p in lmap.pointLayer:
        near = lmap.pointLayer.nearest(BasicPoint2d(p.x, p.y), 2)
        other = next((q for q in near if q.id != p.id), None)
        if other is not None and math.dist((p.x, p.y, p.z), (other.x, other.y, other.z)) < MIN_POINT_DISTANCE_M:
            report.problems.append(Problem(f"point {p.id}", f"closer than {MIN_POINT_DISTANCE_M} m to point {other.id}",
                                           warning=True))
        if "local_x" in p.attributes and "local_y" in p.attributes:
            d = math.hypot(p.x - float(p.attributes["local_x"]), p.y - float(p.attributes["local_y"]))
            if d > LOCAL_TOLERANCE_M:
                report.problems.append(Problem(f"point {p.id}", f"local_x/local_y {d:.3f} m from its projected lat/lon"))
    for ll in lmap.laneletLayer:
        for side, bound in (("left", ll.leftBound), ("right", ll.rightBound)):
            pts = np.array([(p.x, p.y) for p in bound])
            if len(pts) >= 3:
                a, b, c = pts[:-2], pts[1:-1], pts[2:]
                cross = np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
                sides = np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - b, axis=1) * np.linalg.norm(c - a, axis=1)
                k = np.divide(2 * cross, sides, out=np.zeros_like(cross), where=sides > 0)
                if k.max() > MAX_CURVATURE:
                    report.problems.append(Problem(f"lanelet {ll.id}", f"{side} bound curvature {k.max():.2f} 1/m "
                                                                        f"> {MAX_CURVATURE}", warning=True))


def _manoeuvres(lmap, graph, report: Lanelet2Report) -> None:
    """Each tagged (junction, entry road, exit road) of a junction lanelet is a route through it."""
    for ll in lmap.laneletLayer:
        jid = _tag(ll, TAG + "junction")
        if jid is None or ll.attributes["subtype"] != "road":
            continue
        entries = (_tag(ll, TAG + "from") or "").split(";")
        exits = (_tag(ll, TAG + "to") or "").split(";")
        prev, nxt = graph.previous(ll), graph.following(ll)
        for e in filter(None, entries):
            for x in filter(None, exits):
                a = next((p for p in prev if _tag(p, TAG + "road") == e), None)
                b = next((n for n in nxt if _tag(n, TAG + "road") == x), None)
                route = graph.getRouteVia(a, [ll], b) if a is not None and b is not None else None
                if route is None:
                    report.problems.append(Problem(f"lanelet {ll.id} ({_tag(ll, TAG + 'lane')})",
                                                   f"manoeuvre {jid}: {e} -> {x} is no route for vehicles"))
                else:
                    report.routes.add((jid, e, x))


def _regulatory_elements(lmap, report: Lanelet2Report) -> None:
    import lanelet2.core as core

    users: dict[int, set[int]] = {}
    for ll in lmap.laneletLayer:
        for re in ll.regulatoryElements:
            users.setdefault(re.id, set()).add(ll.id)
    for re in lmap.regulatoryElementLayer:
        where = f"regulatory element {re.id} ({re.attributes['subtype']})"
        used = users.get(re.id, set())
        if not used:
            report.problems.append(Problem(where, "no lanelet refers to it"))
        if isinstance(re, core.TrafficLight):
            if re.stopLine is None or not re.trafficLights:
                report.problems.append(Problem(where, "traffic light without its light or stop line"))
        elif isinstance(re, core.AllWayStop):
            if len(re.stopLines()) != len(re.lanelets()):
                report.problems.append(Problem(where, "all-way stop without one stop line per lanelet"))
            named = {ll.id for ll in re.lanelets()}
            if named - used:
                report.problems.append(Problem(where, f"lanelets {sorted(named - used)} do not refer back"))
        elif isinstance(re, core.RightOfWay):
            named = {ll.id for ll in re.rightOfWayLanelets()} | {ll.id for ll in re.yieldLanelets()}
            if named - used:
                report.problems.append(Problem(where, f"lanelets {sorted(named - used)} do not refer back"))
