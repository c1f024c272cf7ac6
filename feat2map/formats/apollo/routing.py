"""Apollo's routing topology graph (routing_map) from an Apollo `Map`, as topo_creator builds it.

One node per CITY_DRIVING lane (U-turns tighter than the vehicle's turn radius dropped), cost
= length x sqrt(base speed / speed limit) (when faster than the base speed) + turn penalty;
left/right "out" ranges along dotted boundaries. Edges: FORWARD to successors (cost 0), LEFT /
RIGHT to forward neighbours when the lane is >= 1 m long and every boundary type on that side
is dotted (cost = change penalty, raised when the changing area is shorter than 50 m).
Apollo 9's own `generate_routing_topo_graph.sh` is broken, so we build the file ourselves.
"""
from __future__ import annotations

import math
from typing import Any

from . import schema as aps
from ...config import (APOLLO_MIN_TURN_RADIUS_M, ROUTING_BASE_CHANGING_LENGTH_M, ROUTING_BASE_SPEED_MPS,
                     ROUTING_CHANGE_PENALTY, ROUTING_LEFT_TURN_PENALTY, ROUTING_MIN_LENGTH_FOR_LANE_CHANGE_M,
                     ROUTING_RIGHT_TURN_PENALTY, ROUTING_UTURN_PENALTY)
from ...routes import end_circle_radius

_DOTTED = (aps.LaneBoundaryType.DOTTED_YELLOW, aps.LaneBoundaryType.DOTTED_WHITE)


def _first_type(bt: Any) -> int:
    # Apollo reads types(0) unchecked; an empty list is undefined behaviour there (the validator
    # flags it); here it counts as not dotted.
    return bt.types[0] if bt.types else aps.LaneBoundaryType.UNKNOWN


def allowed_to_cross(boundary: Any) -> bool:
    """Every boundary type along the boundary is dotted (graph_creator's IsAllowedToCross)."""
    return all(_first_type(bt) in _DOTTED for bt in boundary.boundary_type)


def lane_length(lane: Any) -> float:
    """Sum of the central curve's segment lengths (node_creator's GetLaneLength)."""
    return sum(seg.length for seg in lane.central_curve.segment)


def _out_ranges(boundary: Any, length: float, out: Any) -> None:
    """Dotted stretches of a boundary as s ranges on the lane (node_creator's AddOutBoundary)."""
    types = boundary.boundary_type
    for i, bt in enumerate(types):
        if _first_type(bt) not in _DOTTED:
            continue

        def rate(s: float) -> float:
            return min(s / boundary.length * length, length) if boundary.length else length

        r = out.add()
        r.start.s = rate(bt.s)
        r.end.s = rate(types[i + 1].s) if i != len(types) - 1 else length


def node_cost(lane: Any) -> float:
    length = lane_length(lane)
    speed = lane.speed_limit if lane.HasField("speed_limit") else ROUTING_BASE_SPEED_MPS
    ratio = 1.0 / math.sqrt(speed / ROUTING_BASE_SPEED_MPS) if speed >= ROUTING_BASE_SPEED_MPS else 1.0
    cost = length * ratio
    if lane.HasField("turn"):
        cost += {aps.Lane.LEFT_TURN: ROUTING_LEFT_TURN_PENALTY, aps.Lane.RIGHT_TURN: ROUTING_RIGHT_TURN_PENALTY,
                 aps.Lane.U_TURN: ROUTING_UTURN_PENALTY}.get(lane.turn, 0.0)
    return cost


def valid_uturn(lane: Any, radius: float = APOLLO_MIN_TURN_RADIUS_M) -> bool:
    """Radius of the circle through the centreline's first, middle and last points >= `radius`."""
    pts = [(p.x, p.y) for seg in lane.central_curve.segment for p in seg.line_segment.point]
    return bool(pts) and end_circle_radius(pts) >= radius


def build_routing_graph(m: Any) -> Any:
    """The `apollo.routing.Graph` Apollo's topo_creator would write for map `m`."""
    g = aps.Graph()
    g.hdmap_version = m.header.version.decode("utf-8", "replace")
    g.hdmap_district = m.header.district.decode("utf-8", "replace")
    road_of = {aps.text(lid.id): aps.text(road.id.id) for road in m.road for sec in road.section for lid in sec.lane_id}
    forbidden = {aps.text(ln.id.id) for ln in m.lane if ln.type != aps.Lane.CITY_DRIVING}
    index: dict[str, int] = {}
    for ln in m.lane:
        lid = aps.text(ln.id.id)
        if lid in forbidden or (ln.turn == aps.Lane.U_TURN and not valid_uturn(ln)):
            continue
        index[lid] = len(g.node)
        node = g.node.add()
        length = lane_length(ln)
        node.lane_id = lid
        node.road_id = road_of.get(lid, "")
        _out_ranges(ln.left_boundary, length, node.left_out)
        _out_ranges(ln.right_boundary, length, node.right_out)
        node.length = length
        node.central_curve.CopyFrom(ln.central_curve)
        node.is_virtual = not (not ln.HasField("junction_id") or ln.left_neighbor_forward_lane_id
                               or ln.right_neighbor_forward_lane_id)
        node.cost = node_cost(ln)
    seen: set[tuple[str, str]] = set()

    def add_edges(frm: Any, targets: Any, kind: int) -> None:
        for t in targets:
            to = aps.text(t.id)
            if to in forbidden or (frm.lane_id, to) in seen:
                continue
            seen.add((frm.lane_id, to))
            if to not in index:
                continue
            e = g.edge.add()
            e.from_lane_id, e.to_lane_id, e.direction_type = frm.lane_id, to, kind
            e.cost = 0.0
            if kind != aps.Edge.FORWARD:
                ranges = frm.left_out if kind == aps.Edge.LEFT else frm.right_out
                area = sum(r.end.s - r.start.s for r in ranges)
                ratio = 1.0
                if area < ROUTING_BASE_CHANGING_LENGTH_M:
                    ratio = (area / ROUTING_BASE_CHANGING_LENGTH_M) ** -1.5 if area > 0 else math.inf
                e.cost = ROUTING_CHANGE_PENALTY * ratio

    for ln in m.lane:
        lid = aps.text(ln.id.id)
        if lid in forbidden or lid not in index:
            continue
        frm = g.node[index[lid]]
        add_edges(frm, ln.successor_id, aps.Edge.FORWARD)
        if ln.length < ROUTING_MIN_LENGTH_FOR_LANE_CHANGE_M:
            continue
        if ln.HasField("left_boundary") and allowed_to_cross(ln.left_boundary):
            add_edges(frm, ln.left_neighbor_forward_lane_id, aps.Edge.LEFT)
        if ln.HasField("right_boundary") and allowed_to_cross(ln.right_boundary):
            add_edges(frm, ln.right_neighbor_forward_lane_id, aps.Edge.RIGHT)
    return g
