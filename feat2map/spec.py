"""Hand-written map specs (paper Sec. IV-RQ4): explicit junctions and road chains.

A spec file (YAML or JSON, schema `feat2map/schemas/spec.schema.json`, guide `docs/specs.md`)
lists junction features with per-socket road types and lane counts and, optionally, a grid
cell each, plus chains of roads given pose by pose. `load_spec` validates it (the schema,
then what a schema cannot say: socket separation, room for the lanes, chains that cross
themselves or bend tighter than their lanes) and `build_spec` turns it into an `HDMap`,
optionally on top of features sampled from a feature space (mixed use). Every error names
the file and the element path, e.g. `mega.yaml: junctions[0].sockets[2].lanes_in: must be >= 0`.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, replace
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from shapely.geometry import LineString, Polygon
from shapely.ops import unary_union

from .angles import positive_degrees, wrap_angle
from .bezier import Bezier
from .config import ENDPOINT_TOLERANCE_M, MIN_STUB_LENGTH_M, RAMP_LANE_M, GenerationConfig, limits
from .construct import MidblockRequest, RoadChain, chain_road_id, junction_radius, pavement
from .documents import check_schema, element_path, element_where, load_document
from .errors import FeatureError, LayoutError, LimitError
from .features import FeatureSpace, JunctionFeature, MidblockFeature, Socket, socket_lanes
from .invariants import AREA_EPS_M2, connectivity, dead_ends, two_way
from .layout import Cell
from .model import HDMap
from .ramps import ramp_fit

SPEC_VERSION = 1
HEADING_TOLERANCE_DEG = 0.01  # a chain is closed when its last pose equals its start within this


class SpecError(FeatureError):
    """A spec that is malformed or cannot be built; `where` is `file: element.path`."""


@dataclass(frozen=True)
class JunctionSpec:
    """One hand-written junction: its feature (sockets in counter-clockwise order) and cell;
    `midblock`: (socket index in that order, crosswalk, element path) of the mid-block
    crosswalks its sockets ask for on their roads."""

    feature: JunctionFeature
    cell: Cell | None = None
    name: str | None = None
    midblock: tuple[tuple[int, MidblockFeature, str], ...] = ()


@dataclass(frozen=True)
class MapSpec:
    """A parsed, validated spec; `source` names its file in later error messages."""

    junctions: tuple[JunctionSpec, ...] = ()
    chains: tuple[RoadChain, ...] = ()
    config: Mapping[str, Any] | None = None
    source: str = "spec"

    def generation_config(self, overrides: Mapping[str, Any] | None = None) -> GenerationConfig:
        """The spec's config with `overrides` (e.g. command-line options) on top."""
        data = {**(self.config or {}), **(overrides or {})}
        try:
            cfg = GenerationConfig.from_dict(data)
            cfg.check_limits()  # a spec's config may ask for more than the limits allow: name the file
            return cfg
        except LimitError as exc:
            raise LimitError(exc.message, f"{self.source}: config") from None
        except ValueError as exc:
            raise SpecError(str(exc), f"{self.source}: config") from None

    def features(self) -> list[JunctionFeature]:
        return [j.feature for j in self.junctions]

    def midblock(self) -> list[MidblockRequest]:
        """The mid-block crosswalks the junctions' sockets ask for, on their sockets' roads."""
        return [MidblockRequest(f, (i, k), where) for i, j in enumerate(self.junctions) for k, f, where in j.midblock]


@lru_cache(maxsize=1)
def spec_schema() -> dict:
    """The published JSON schema of spec files."""
    text = resources.files("feat2map").joinpath("schemas/spec.schema.json").read_text(encoding="utf-8")
    return json.loads(text)


# ---------------------------------------------------------------------------------------- parsing


def load_spec(path: str | Path) -> MapSpec:
    """Read and validate a YAML (.yaml/.yml) or JSON spec file."""
    return parse_spec(load_document(path, SpecError), str(path))


def _validate_schema(doc: Any, source: str) -> None:
    if doc is None:
        raise SpecError("empty spec", source)
    if not isinstance(doc, Mapping):  # the document is not quoted: it may be any file
        raise SpecError(f"a spec must be an object (mapping) with junctions and/or chains, got a {type(doc).__name__}", source)
    check_schema(doc, spec_schema(), source, SpecError)


def _socket(raw: Any, where: str) -> Socket:
    if not isinstance(raw, Mapping):
        return Socket(float(raw), 1, 1)
    explicit = "lanes_in" in raw or "lanes_out" in raw
    if explicit and ("type" in raw or "lanes" in raw):
        raise SpecError("give either type/lanes or lanes_in/lanes_out, not both", where)
    if explicit:
        lanes_in, lanes_out = int(raw.get("lanes_in", 0)), int(raw.get("lanes_out", 0))
        if lanes_in + lanes_out == 0:
            raise SpecError("a socket needs at least one lane (lanes_in + lanes_out > 0)", where)
    else:
        lanes_in, lanes_out = socket_lanes(raw.get("type", "in-out"), int(raw.get("lanes", 1)))
    if "ramp" in raw:
        if "filter" in raw:
            raise SpecError("a ramp has no filter lane (a ramp junction has none)", f"{where}.filter")
        kind = raw["ramp"].get("kind", "on")
        if (kind == "on" and lanes_out) or (kind == "off" and lanes_in):
            raise SpecError(f"an {kind}-ramp is one-way {'in' if kind == 'on' else 'out'}: give it type "
                            f"{'in' if kind == 'on' else 'out'} (or lanes_{'in' if kind == 'on' else 'out'} only)",
                            f"{where}.ramp")
        return Socket(float(raw["angle"]), lanes_in, lanes_out, ramp=str(kind), link=bool(raw["ramp"].get("link", False)))
    if "filter" not in raw:
        return Socket(float(raw["angle"]), lanes_in, lanes_out)
    f = raw["filter"]
    if not lanes_in:
        raise SpecError("a filter lane leaves an approach: this socket has no incoming lanes", f"{where}.filter")
    return Socket(float(raw["angle"]), lanes_in, lanes_out, str(f.get("control", "yield")), bool(f.get("island", True)))


def _midblock(raw: Any, where: str) -> MidblockFeature | None:
    """A socket's `midblock` crosswalk on its road (None when it asks for none)."""
    if not isinstance(raw, Mapping) or "midblock" not in raw:
        return None
    m = raw["midblock"]
    try:
        return MidblockFeature(m.get("control", "bare"), float(m.get("position", 0.5)))
    except FeatureError as exc:
        raise SpecError(exc.message, f"{where}.midblock") from None


def _junction(raw: Mapping[str, Any], where: str, min_sep: float, path: Sequence[Any] = ()) -> JunctionSpec:
    """Sockets are sorted counter-clockwise (their listed order needs no unwrapping);
    duplicates and legs closer than the minimum separation are errors naming the socket.
    `path`: the junction's element path (mid-block crosswalks name their socket by it)."""
    socks = [(i, _socket(s, f"{where}.sockets[{i}]")) for i, s in enumerate(raw["sockets"])]
    socks.sort(key=lambda t: positive_degrees(t[1].angle))
    crossings = tuple((k, f, element_path([*path, "sockets", i, "midblock"])) for k, (i, _) in enumerate(socks)
                      if (f := _midblock(raw["sockets"][i], f"{where}.sockets[{i}]")) is not None)
    n = len(socks)
    for k in range(n):
        (i, a), (j, b) = socks[k], socks[(k + 1) % n]
        gap = positive_degrees(b.angle - a.angle)
        if gap < 1e-9:
            raise SpecError(f"same direction ({b.angle:g} deg) as sockets[{i}]", f"{where}.sockets[{j}]")
        if gap < min_sep - 1e-9 and b.ramp != "on" and a.ramp != "off":  # a ramp keeps the ramp angles instead
            raise SpecError(f"{gap:g} deg from sockets[{i}], closer than the minimum separation {min_sep:g} deg "
                            "(config.min_socket_separation_deg)", f"{where}.sockets[{j}]")
    if not any(s.lanes_in for _, s in socks) or not any(s.lanes_out for _, s in socks):
        raise SpecError("needs a socket where traffic enters (in / in-out) and one where it leaves (out / in-out)",
                        where)
    first = positive_degrees(socks[0][1].angle)
    first = first - 360.0 if first >= 180.0 else first
    angles = [first + positive_degrees(s.angle - socks[0][1].angle) for _, s in socks]
    sockets = tuple(replace(s, angle=a) for a, (_, s) in zip(angles, socks))
    try:
        feature = JunctionFeature(sockets, raw.get("control", "bare"), bool(raw.get("crosswalk", False)), min_sep,
                                  float(raw.get("ramp_length", RAMP_LANE_M)))
    except FeatureError as exc:
        hit = re.match(r"socket (\d+): (.*filter lane.*)", exc.message)
        if hit:  # the socket in the spec's own order
            raise SpecError(hit.group(2), f"{where}.sockets[{socks[int(hit.group(1))][0]}].filter") from None
        hit = re.match(r"socket (\d+): (.*ramp.*)", exc.message)
        if hit:
            raise SpecError(hit.group(2), f"{where}.sockets[{socks[int(hit.group(1))][0]}].ramp") from None
        raise SpecError(exc.message, where) from None
    cell = tuple(int(c) for c in raw["cell"]) if "cell" in raw else None
    return JunctionSpec(feature, cell, raw.get("name"), crossings)  # type: ignore[arg-type]


def _chain(raw: Mapping[str, Any], index: int, where: str) -> RoadChain:
    start = raw["start"]
    poses = [((float(start["point"][0]), float(start["point"][1])), math.radians(float(start["heading"])))]
    lim = limits()
    for k, r in enumerate(raw["roads"]):
        p = (float(r["end"][0]), float(r["end"][1]))
        if max(abs(p[0]), abs(p[1]), abs(poses[0][0][0]), abs(poses[0][0][1])) > lim.max_coordinate_m:
            raise SpecError(f"point beyond the limit max_coordinate_m={lim.max_coordinate_m:g}", f"{where}.roads[{k}]")
        if math.dist(p, poses[-1][0]) < 1.0:
            raise SpecError("road shorter than 1 m: its end is (almost) the previous road's end", f"{where}.roads[{k}]")
        if math.dist(p, poses[-1][0]) > lim.max_road_length_m:
            raise SpecError(f"road {math.dist(p, poses[-1][0]):.0f} m long, above the limit max_road_length_m="
                            f"{lim.max_road_length_m:g} (raise it with --limit max_road_length_m=N)",
                            f"{where}.roads[{k}]")
        poses.append((p, math.radians(float(r["heading"]))))
    fwd, bwd = int(raw.get("lanes_forward", 1)), int(raw.get("lanes_backward", 1))
    if fwd + bwd == 0:
        raise SpecError("a chain needs at least one lane (lanes_forward + lanes_backward > 0)", where)
    last = len(poses) - 2
    closes = math.dist(poses[-1][0], poses[0][0]) <= ENDPOINT_TOLERANCE_M
    if closes:
        dh = math.degrees(wrap_angle(poses[-1][1] - poses[0][1]))
        if abs(dh) > HEADING_TOLERANCE_DEG:
            raise SpecError(f"ends at the chain's start but heading {math.degrees(poses[-1][1]):g} deg, not the start "
                            f"heading {math.degrees(poses[0][1]):g} deg: a closed chain must join smoothly",
                            f"{where}.roads[{last}]")
        if len(poses) < 3:
            raise SpecError("a closed chain needs at least 2 roads", where)
        poses[-1] = poses[0]
    return RoadChain(f"C{index}", tuple(poses), fwd, bwd, closes)


def _check_ramp_kinds(doc: Any, source: str) -> None:
    """YAML 1.1 reads an unquoted on/off as true/false: a ramp kind that is a boolean is named
    with that hint (before the schema, whose message would only say it is no ramp kind)."""
    if not isinstance(doc, Mapping) or not isinstance(doc.get("junctions"), list):
        return
    for i, j in enumerate(doc["junctions"]):
        for k, sock in enumerate(j.get("sockets", []) if isinstance(j, Mapping) else []):
            ramp = sock.get("ramp") if isinstance(sock, Mapping) else None
            if isinstance(ramp, Mapping) and isinstance(ramp.get("kind"), bool):
                raise SpecError(f"must be \"on\" or \"off\", got {str(ramp['kind']).lower()} (YAML reads an unquoted "
                                "on/off as true/false: quote it)",
                                element_where(source, ["junctions", i, "sockets", k, "ramp", "kind"]))


def parse_spec(doc: Any, source: str = "spec") -> MapSpec:
    """Validate a spec document (already loaded from YAML/JSON) and build its values."""
    if isinstance(doc, Mapping) and isinstance(doc.get("junctions"), list):  # before the (slow) schema check
        try:
            limits().check("max_junctions", len(doc["junctions"]), "the number of junctions")
        except LimitError as exc:
            raise SpecError(exc.message, element_where(source, ["junctions"])) from None
    _check_ramp_kinds(doc, source)
    _validate_schema(doc, source)
    if not doc.get("junctions") and not doc.get("chains"):
        raise SpecError("a spec needs at least one junction or chain", source)
    config = dict(doc.get("config", {}))
    spec = MapSpec((), (), config, source)
    cfg = spec.generation_config()
    junctions = tuple(_junction(j, element_where(source, ["junctions", i]), cfg.min_socket_separation_deg,
                                ["junctions", i]) for i, j in enumerate(doc.get("junctions", [])))
    seen: dict[Cell, int] = {}
    for i, j in enumerate(junctions):
        if j.cell is not None:
            if j.cell in seen:
                raise SpecError(f"cell {list(j.cell)} is already taken by junctions[{seen[j.cell]}]",
                                element_where(source, ["junctions", i, "cell"]))
            seen[j.cell] = i
    chains = tuple(_chain(c, i, element_where(source, ["chains", i])) for i, c in enumerate(doc.get("chains", [])))
    spec = replace(spec, junctions=junctions, chains=chains)
    check_buildable(spec, cfg)
    return spec


# ------------------------------------------------------------------------------------- geometry


def _second_derivative(b: Bezier, t: np.ndarray) -> np.ndarray:
    c = b.control
    t = t[:, None]
    return 6.0 * ((1 - t) * (c[2] - 2 * c[1] + c[0]) + t * (c[3] - 2 * c[2] + c[1]))


def min_turn_radius(b: Bezier, samples: int = 129) -> float:
    """Smallest radius of curvature along a Bézier (inf for a straight line)."""
    t = np.linspace(0.0, 1.0, samples)
    d1, d2 = b.derivative(t), _second_derivative(b, t)
    cross = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    speed = np.hypot(d1[:, 0], d1[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(cross > 1e-12, speed ** 3 / np.maximum(cross, 1e-300), np.inf)
    return float(np.min(r))


def chain_piece_polygons(chain: RoadChain, cfg: GenerationConfig) -> list[Polygon]:
    """The pavement of every piece: its reference line widened to the lanes on each side."""
    # the reference is centred between the outer edges (lanes split by the divider offset)
    half = (chain.lanes_forward + chain.lanes_backward) * cfg.lane_width / 2
    return [pavement(Bezier.from_poses(*chain.poses[k], *chain.poses[k + 1]), half, cfg)
            for k in range(chain.n_pieces)]


def _check_chain(chain: RoadChain, where: str, cfg: GenerationConfig) -> None:
    """Pieces must bend no tighter than their lanes are wide and must not cross each other."""
    half = (chain.lanes_forward + chain.lanes_backward) * cfg.lane_width / 2
    refs = []
    for k in range(chain.n_pieces):
        (p0, h0), (p1, h1) = chain.poses[k], chain.poses[k + 1]
        ref = Bezier.from_poses(p0, h0, p1, h1)
        line = LineString(ref.sample(cfg.sample_spacing / 2))
        d1 = ref.derivative(np.linspace(0.0, 1.0, 257))
        cusp = bool(np.any((d1[1:] * d1[:-1]).sum(axis=1) <= 0.0))  # the tangent flips: it backs up on itself
        if cusp or not line.is_simple:
            raise SpecError("the road crosses itself (its end heading turns it back over its own course)",
                            f"{where}.roads[{k}]")
        r = min_turn_radius(ref)
        if r < half + cfg.lane_width / 2:
            raise SpecError(f"bends with a {r:.1f} m radius, too tight for lanes reaching {half:.1f} m from its "
                            f"centre line (needs >= {half + cfg.lane_width / 2:.1f} m)", f"{where}.roads[{k}]")
        refs.append(line)
    polys = chain_piece_polygons(chain, cfg)
    n = chain.n_pieces
    for a in range(n):
        for b in range(a + 1, n):
            adjacent = b == a + 1 or (chain.closed and a == 0 and b == n - 1)
            if adjacent:
                if n == 2 and chain.closed:
                    continue  # two pieces meeting at both ends: checked through their references
                hit = polys[a].intersection(polys[b]).area > AREA_EPS_M2 * 20
            else:
                hit = refs[a].distance(refs[b]) < 2 * half or polys[a].intersection(polys[b]).area > AREA_EPS_M2
            if hit:
                raise SpecError(f"crosses or overlaps roads[{a}] of the same chain", f"{where}.roads[{b}]")
    if n == 2 and chain.closed and refs[0].intersection(refs[1]).geom_type not in ("MultiPoint", "Point"):
        raise SpecError("the two roads of this closed chain overlap", f"{where}.roads[1]")


def check_buildable(spec: MapSpec, cfg: GenerationConfig) -> None:
    """What the schema cannot check before building: room for every junction's lanes inside
    half a grid gap, and chains that neither fold nor cross themselves or each other."""
    room = cfg.grid_gap / 2 - MIN_STUB_LENGTH_M - cfg.junction_margin
    for i, j in enumerate(spec.junctions):
        if j.feature.has_ramp and (why := ramp_fit(j.feature, cfg, room)):
            raise SpecError(why, element_where(spec.source, ["junctions", i, "ramp_length"]))
        r = junction_radius(j.feature, cfg)
        if r > room:
            need = 2 * (r + MIN_STUB_LENGTH_M + cfg.junction_margin)
            raise SpecError(f"legs too close to fit their lanes: the junction needs a {r:.1f} m radius, a "
                            f"{cfg.grid_gap:g} m grid leaves {room:.1f} m (raise config.grid_gap to >= {need:.0f}, "
                            "spread the sockets or drop lanes)", element_where(spec.source, ["junctions", i]))
    polys = []
    for i, c in enumerate(spec.chains):
        _check_chain(c, element_where(spec.source, ["chains", i]), cfg)
        polys.append(unary_union(chain_piece_polygons(c, cfg)))
    for a in range(len(polys)):
        for b in range(a + 1, len(polys)):
            if polys[a].intersection(polys[b]).area > AREA_EPS_M2:
                raise SpecError(f"overlaps chains[{a}]", element_where(spec.source, ["chains", b]))


# ------------------------------------------------------------------------------------- building


def build_spec(spec: MapSpec, seed: int = 0, config: GenerationConfig | None = None,
               space: FeatureSpace | None = None) -> HDMap:
    """The map of a spec: its junctions (listed first, ids J0.. in spec order) plus, when
    `space` is given, one sampled junction per feature combination of it (Algorithm 1) and its
    sampled mid-block crosswalks, laid out together on the grid, and its chains; the mid-block
    crosswalks its sockets ask for. Raises `SpecError` naming the element when the layout or
    the resulting network is impossible."""
    from .generate import generate_from_features
    from .sampling import sample_features, sample_midblock, sample_ramps

    cfg = config if config is not None else spec.generation_config()
    if config is not None:
        check_buildable(spec, cfg)
    features = spec.features()
    cells: list[Cell | None] = [j.cell for j in spec.junctions]
    names = [element_path(["junctions", i]) for i in range(len(spec.junctions))]
    meta: dict[str, Any] = {"spec": spec.source}
    midblock = spec.midblock()
    if space is not None:
        rng = np.random.default_rng([int(seed), 0])
        sampled = sample_features(space, rng, cfg)
        midblock += [MidblockRequest(f, None, f"sampled mid-block crosswalk {k} ({f.control})")
                     for k, f in enumerate(sample_midblock(space, rng, cfg))]
        sampled += sample_ramps(space, rng, cfg)
        features += sampled
        cells += [None] * len(sampled)
        names += [f"sampled junction {k} (J{len(spec.junctions) + k})" for k in range(len(sampled))]
        meta["feature_space"] = space.to_dict()
    try:
        keep = [True] * len(spec.junctions) + [False] * (len(features) - len(spec.junctions))
        m = generate_from_features(features, seed, cfg, cells, meta, spec.chains, names, keep, midblock=midblock)
    except LayoutError as exc:
        raise SpecError(exc.message, f"{spec.source}: {exc.where}" if exc.where else spec.source) from None
    _check_network(m, spec, names, cfg)
    return m


def _element(m: HDMap, lane_id: str, spec: MapSpec, names: Sequence[str]) -> str:
    """The spec element a lane belongs to: its chain road, or the junction it drives into."""
    lane = m.lanes[lane_id]
    road = m.roads[lane.road_id]
    if road.kind == "chain":
        for i, c in enumerate(spec.chains):
            for k in range(c.n_pieces):
                if chain_road_id(c, k) == road.id:
                    return element_where(spec.source, ["chains", i, "roads", k])
    jid = lane.junction_id or (road.end_junction if lane_id in road.right_lanes else road.start_junction) \
        or road.start_junction or road.end_junction
    if jid is not None and jid.startswith("J") and jid[1:].isdigit() and int(jid[1:]) < len(names):
        return f"{spec.source}: {names[int(jid[1:])]}"
    return spec.source


def _check_network(m: HDMap, spec: MapSpec, names: Sequence[str], cfg: GenerationConfig) -> None:
    """Routes must exist: one-way roads must not trap traffic (a dead end) nor leave lanes
    no entry can reach; chains must not overlap the junction grid."""
    problems = dead_ends(m) + connectivity(m)
    if problems:
        lane = next((w for w in problems[0].split() if w in m.lanes), None)
        where = _element(m, lane, spec, names) if lane else spec.source
        what = f" (road {m.lanes[lane].road_id})" if lane else ""
        hint = "" if two_way(m, m.lanes) else "; check the in/out road types around it"
        raise SpecError(f"routes impossible: {problems[0]}{what}{hint}", where)
    if not spec.chains or not m.junctions:
        return
    from shapely import STRtree

    chain_roads = {chain_road_id(c, k) for c in spec.chains for k in range(c.n_pieces)}
    others = [(f"junction {j.id}", Polygon(j.polygon)) for j in m.junctions.values()]
    others += [(f"road {ln.road_id}", Polygon(ln.left_boundary + tuple(reversed(ln.right_boundary))).buffer(0))
               for ln in m.lanes.values() if ln.junction_id is None and ln.road_id not in chain_roads]
    tree = STRtree([p for _, p in others])
    for i, c in enumerate(spec.chains):
        for k, poly in enumerate(chain_piece_polygons(c, cfg)):
            for idx in tree.query(poly, predicate="intersects"):
                if poly.intersection(others[idx][1]).area > AREA_EPS_M2:
                    raise SpecError(f"overlaps {others[idx][0]} of the junction grid (move the chain)",
                                    element_where(spec.source, ["chains", i, "roads", k]))
