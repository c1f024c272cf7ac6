"""Motorway ramp junctions: where their sockets lie and which lanes join them.

A ramp junction (`features.JunctionFeature` with `Socket.ramp`) is a straight-on main road
whose two main sockets lie half its `ramp_length` from the centre, with on-ramps and off-ramps
beside them. A ramp's socket lies on its own socket line, where that line passes its main
socket (its radius is the main radius over the cosine of the ramp angle), so every road of the
junction leaves along a line through the centre (extraction measures the feature's angles
exactly) and the ramp's lane runs the whole `ramp_length` beside the main lanes: an on-ramp's
lane joins the carriageway's rightmost lane at the far main socket (the acceleration lane and
its taper), an off-ramp's leaves the rightmost lane at the near one (the deceleration lane).
Main lanes go straight on lane by lane; there are no turns between the carriageways. A motorway
link (`Socket.link`, a motorway-to-motorway junction) lies where a ramp does, but its lanes
become the carriageway's rightmost lanes (a lane gain) or its rightmost lanes become the link's
(a lane drop), one to one (`link_lanes`).
"""
from __future__ import annotations

import math
from typing import Mapping, NamedTuple

from .config import RAMP_GORE_M, RAMP_MAX_ANGLE_DEG, RAMP_MIN_ANGLE_DEG, GenerationConfig
from .features import JunctionFeature, ramp_angle, ramp_carriageway, ramp_junction, ramp_main, ramp_mains

# Bezier handles of a ramp's lane, as fractions of the distance between its ends (start, end): an
# on-ramp's lane turns onto the main road's line early and runs beside it (a long end handle), an
# off-ramp's runs beside it and turns off late; main lanes and ramp-to-ramp lanes are the paper's
# halves (eq. 2)
MERGE_SHAPE = (0.3, 0.5)
DIVERGE_SHAPE = (0.5, 0.3)
THROUGH_SHAPE = (0.5, 0.5)


class RampLane(NamedTuple):
    """A junction lane of a ramp junction: from road lane `src` to `dst`, its Bezier handles and
    its `kind`: "main" (straight on), "merge" (an on-ramp's acceleration lane), "diverge" (an
    off-ramp's deceleration lane) or "ramp" (an on-ramp's lane going on to an off-ramp)."""

    src: str
    dst: str
    shape: tuple[float, float]
    kind: str


def socket_speed(feature: JunctionFeature, i: int, cfg: GenerationConfig) -> float:
    """The speed limit of the road at socket `i`: `motorway_speed_limit` at a ramp junction's
    main legs and motorway links (a link joins two motorways), `ramp_speed_limit` at its ramps,
    `speed_limit` (a town road) at any other socket."""
    if not feature.has_ramp:
        return cfg.speed_limit
    s = feature.sockets[i]
    return cfg.ramp_speed_limit if s.ramp != "none" and not s.link else cfg.motorway_speed_limit


def ramp_lane_speed(lane: RampLane, cfg: GenerationConfig) -> float:
    """A ramp junction's lane: the motorway's limit straight on and on an acceleration lane (merging
    traffic gets up to the main road's speed on it), the ramp's on a deceleration lane (leaving
    traffic slows on it, where design guidance puts the deceleration, not on the ramp: the envs take
    a lower limit where its lane begins) and between two ramps."""
    return cfg.motorway_speed_limit if lane.kind in ("main", "merge") else cfg.ramp_speed_limit


def ramp_radius(feature: JunctionFeature) -> float:
    """Centre to main socket: half the acceleration/deceleration lanes' length."""
    return feature.ramp_length / 2.0


def ramp_socket_radius(feature: JunctionFeature, i: int) -> float:
    """Centre to ramp socket `i`: on its socket line, level with its main socket."""
    return ramp_radius(feature) / math.cos(math.radians(ramp_angle(feature, i)))


def ramp_length_needed(feature: JunctionFeature, cfg: GenerationConfig) -> float:
    """The shortest `ramp_length` that keeps every ramp's road RAMP_GORE_M clear of its main
    road's pavement at the sockets (and diverging beyond), and the main sockets
    `min_junction_radius` from the centre."""
    w = cfg.lane_width
    need = cfg.min_junction_radius
    for i, s in enumerate(feature.sockets):
        if s.ramp == "none":
            continue
        main = feature.sockets[ramp_main(feature, i)]
        theta = math.radians(ramp_angle(feature, i))
        side = (main.lanes_in + main.lanes_out) * w / 2 + RAMP_GORE_M + (s.lanes_in + s.lanes_out) * w / 2 / math.cos(theta)
        need = max(need, side / math.tan(theta))
    return 2.0 * need


def min_ramp_angle(main_lanes: int, length: float, cfg: GenerationConfig) -> float:
    """The smallest ramp angle (degrees, to 1e-6, up to RAMP_MAX_ANGLE_DEG) at which a one-lane
    ramp beside a main road of `main_lanes` per direction clears it within `length`
    (`ramp_length_needed`, which falls as the angle grows): a wider motorway needs steeper ramps."""
    def fits(deg: float) -> bool:
        return ramp_length_needed(ramp_junction("on", deg, main_lanes, 1, length), cfg) <= length

    lo, hi = RAMP_MIN_ANGLE_DEG, RAMP_MAX_ANGLE_DEG
    if fits(lo) or not fits(hi):
        return lo if fits(lo) else hi
    while hi - lo > 1e-7:
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return math.ceil(hi * 1e6) / 1e6


def ramp_fit(feature: JunctionFeature, cfg: GenerationConfig, room: float) -> str:
    """Why a ramp junction cannot be built ("" when it can): its `ramp_length` too short for its
    ramp angles and lanes, or too long for the grid's `room` (half a gap less stub and margin)."""
    need = ramp_length_needed(feature, cfg)
    if feature.ramp_length < need - 1e-9:
        return (f"ramp_length {feature.ramp_length:g} m is too short for its ramp angles and lanes: the ramps' roads "
                f"clear the main road only from {math.ceil(need * 10) / 10:g} m on (raise ramp_length or widen "
                "the ramp angles)")
    if ramp_radius(feature) > room + 1e-9:
        grid = 2 * (ramp_radius(feature) + cfg.grid_gap / 2 - room)
        return (f"ramp_length {feature.ramp_length:g} m does not fit a {cfg.grid_gap:g} m grid, which holds "
                f"{2 * room:.1f} m (use grid_gap >= {math.ceil(grid):g})")
    return ""


def ramp_lanes(feature: JunctionFeature, incoming: Mapping[tuple[int, int], list[str]],
               outgoing: Mapping[tuple[int, int], list[str]], j: int) -> list[RampLane]:
    """The junction lanes of ramp junction `j` (`RampLane`), lanes listed right to left per
    socket: main lanes go on lane by lane (monotone, as
    `construct.lane_pairs` joins a single exit), on-ramp lane k joins the carriageway's lane k from the
    right, off-ramp lane k leaves its lane k from the right, and an on-ramp's rightmost lane also
    goes on to an off-ramp of the same carriageway. A motorway link's carriageway (`link_lanes`)
    instead pairs its lanes one to one."""
    a, b = ramp_mains(feature)
    out: list[RampLane] = []
    links = {ramp_carriageway(feature, i): i for i, s in enumerate(feature.sockets) if s.link}
    for x, y in ((a, b), (b, a)):
        ins, outs = incoming[(j, x)], outgoing[(j, y)]
        p, q = len(ins), len(outs)
        if (x, y) in links:
            out += link_lanes(feature, links[(x, y)], incoming, outgoing, j)
        elif p and q:  # a monotone map, as `construct.lane_pairs` joins one exit
            pairs = [(k * p // q, k) for k in range(q)] if q >= p else [(k, k * q // p) for k in range(p)]
            out += [RampLane(ins[u], outs[v], THROUGH_SHAPE, "main") for u, v in pairs]
    for i, s in enumerate(feature.sockets):
        if s.ramp == "none" or s.link:
            continue
        m = ramp_main(feature, i)
        other = b if m == a else a
        if s.ramp == "on":
            ramp_in, outs = incoming[(j, i)], outgoing[(j, other)]
            out += [RampLane(lane, outs[min(k, len(outs) - 1)], MERGE_SHAPE, "merge") for k, lane in enumerate(ramp_in)]
            for r, t in enumerate(feature.sockets):
                if t.ramp == "off" and ramp_main(feature, r) == other:
                    out.append(RampLane(ramp_in[0], outgoing[(j, r)][0], THROUGH_SHAPE, "ramp"))
        else:
            ins, ramp_out = incoming[(j, other)], outgoing[(j, i)]
            out += [RampLane(ins[min(k, len(ins) - 1)], lane, DIVERGE_SHAPE, "diverge") for k, lane in enumerate(ramp_out)]
    return out


def link_lanes(feature: JunctionFeature, i: int, incoming: Mapping[tuple[int, int], list[str]],
               outgoing: Mapping[tuple[int, int], list[str]], j: int) -> list[RampLane]:
    """The junction lanes of motorway link socket `i`'s carriageway, lanes right to left: a lane
    gain (on) joins the link's lanes and then the upstream main lanes, in order, to the downstream
    lanes; a lane drop (off) joins the upstream lanes to the link's lanes and then the downstream
    main lanes. One to one: every lane goes on, none merges or splits; all are motorway ("main")."""
    up, down = ramp_carriageway(feature, i)
    if feature.sockets[i].ramp == "on":
        ins = [(lane, MERGE_SHAPE) for lane in incoming[(j, i)]] + [(lane, THROUGH_SHAPE) for lane in incoming[(j, up)]]
        return [RampLane(src, dst, shape, "main") for (src, shape), dst in zip(ins, outgoing[(j, down)], strict=True)]
    outs = [(lane, DIVERGE_SHAPE) for lane in outgoing[(j, i)]] + [(lane, THROUGH_SHAPE) for lane in outgoing[(j, down)]]
    return [RampLane(src, dst, shape, "main") for src, (dst, shape) in zip(incoming[(j, up)], outs, strict=True)]
