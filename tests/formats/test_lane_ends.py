"""Where linked lanes meet (formats/lane_ends.py): gaps between linked lanes close, nothing else moves."""
from __future__ import annotations

import math
from dataclasses import replace

from feat2map.config import LANE_END_SNAP_M
from feat2map.formats.lane_ends import lane_ends


def _shift_start(m, lane_id: str, dx: float):
    ln = m.lanes[lane_id]
    moved = replace(ln, left_boundary=((ln.left_boundary[0][0] + dx, ln.left_boundary[0][1]), *ln.left_boundary[1:]),
                    right_boundary=((ln.right_boundary[0][0] + dx, ln.right_boundary[0][1]), *ln.right_boundary[1:]))
    return replace(m, lanes={**m.lanes, lane_id: moved})


def test_linked_ends_meet_and_gaps_close(sf_default_map):
    m = sf_default_map
    jl = next(ln for ln in m.lanes.values() if ln.junction_id and ln.predecessors)
    pred = jl.predecessors[0]
    for dx, closes in ((0.3, True), (LANE_END_SNAP_M + 0.5, False)):
        gap = _shift_start(m, jl.id, dx)
        ends = lane_ends(gap)
        for side in ("left", "right"):
            meet = ends[(jl.id, side, "start")] == ends[(pred, side, "end")]
            assert meet == closes
            if closes:  # the shifted start moves to the predecessor's end (within the map's 1 cm), not it to us
                line = m.lanes[pred].left_boundary if side == "left" else m.lanes[pred].right_boundary
                assert math.dist(ends[(jl.id, side, "start")], line[-1][:2]) < 0.011
    ends = lane_ends(m)
    for (lid, side, at), p in ends.items():  # a generated map moves by less than its 1 cm link tolerance
        line = m.lanes[lid].left_boundary if side == "left" else m.lanes[lid].right_boundary
        assert math.dist(p, line[0 if at == "start" else -1][:2]) < 0.011
        other = "right" if side == "left" else "left"
        assert p != ends[(lid, other, at)]  # the two sides never merge
