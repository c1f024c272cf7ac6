"""Every tunable constant of feat2map, named once.

`GenerationConfig` is the one value object the generator takes; the module-level
constants are its defaults and are shared by readers, writers and the envs.
"""
from __future__ import annotations

import contextlib
import contextvars
import math
from dataclasses import asdict, dataclass, fields, replace
from types import MappingProxyType
from typing import Any, Iterator, Mapping

GRID_GAP_M = 100.0  # paper: P_{x+1,y} is 100 m east of P_{x,y}
LANE_WIDTH_M = 3.5  # paper: default lane width of the input maps
CROSSWALK_WIDTH_M = 4.5  # paper: slightly longer than a sedan
STUB_LENGTH_M = 25.0  # dead-end roads: the map's entries and exits; short of half a grid gap
# The one leg rule, shared by features, specs, generation and extraction: a junction's legs are
# at least MIN_LEG_SEPARATION_DEG apart (features and specs refuse closer legs, generation's
# min_socket_separation_deg never goes below it, extraction skips junctions with closer legs), and
# extraction counts lane mouths that all enter (or all leave) as one leg only when their
# directions differ by less than LEG_MERGE_DEG, half the rule, so legs the rule allows stay apart.
MIN_LEG_SEPARATION_DEG = 20.0
LEG_MERGE_DEG = MIN_LEG_SEPARATION_DEG / 2
MAX_LEGS = 8  # legs per junction in features, specs and feature spaces (README: 3-8)
MAX_CARDINAL_DEVIATION_DEG = 90.0  # layout: a socket serves a grid direction at most this far from it ...
STRICT_CARDINAL_DEVIATION_DEG = 45.0  # ... or this far, when the first layout's roads would cross
MIN_STUB_LENGTH_M = 10.0  # a junction must leave at least this much road before the half-way line
MIN_JUNCTION_RADIUS_M = 12.0  # centre to socket, before lane-width growth
JUNCTION_MARGIN_M = 1.5  # between crosswalk and socket, and around stop lines
# mid-block crosswalks (on a road between two junctions): their centre lies this fraction of the road's
# length from the upstream junction when sampled; one asked for (specs) may lie anywhere its strip and
# stop lines keep JUNCTION_MARGIN_M clear of both ends of the road
MIDBLOCK_POSITION_RANGE = (0.35, 0.65)
MIDBLOCK_LINE_REACH_M = 5.0  # a signal's stop line this close before a crosswalk outside junctions guards that crossing
# filter lanes (slip lanes): one leaves its approach this far before the junction's socket and joins
# its exit road as far after that road's socket (both roads are split there; a road too short for it
# is split nearer, down to half as far, so that a quarter as much road is left beyond the split); its
# Bezier handles are this fraction of the distances from its ends to where their lines meet (a
# rounder curve would cut into the junction's core)
FILTER_DIVERGE_M = 16.0
FILTER_HANDLE = 0.4
FILTER_LEAD_MAX_M = 60.0  # extraction: a right turn leaving its approach at most this far before the core's entries
# motorway ramps (a ramp junction: two main legs and on-/off-ramp legs beside them): a ramp leaves (an
# off-ramp) or joins (an on-ramp) its main leg's carriageway on the right, RAMP_ANGLE_DEG from it (specs
# say it with the socket angles; sampling draws it in RAMP_ANGLE_RANGE_DEG; a feature allows
# RAMP_MIN_ANGLE_DEG to RAMP_MAX_ANGLE_DEG); the main legs lie within RAMP_MAIN_BEND_DEG of straight on
RAMP_ANGLE_DEG = 15.0
RAMP_ANGLE_RANGE_DEG = (10.0, 15.0)
RAMP_MIN_ANGLE_DEG, RAMP_MAX_ANGLE_DEG = 5.0, 30.0
RAMP_MAIN_BEND_DEG = 30.0
# the acceleration (on-ramp) or deceleration (off-ramp) lane's length: the distance between the main
# legs' sockets, along which the ramp's lane runs beside the main lanes. Design guidance asks ~150-250 m at
# motorway speeds; a 100 m grid holds up to grid_gap - 2 * (MIN_STUB_LENGTH_M + junction_margin) = 77 m,
# so the default is 75 m (raise grid_gap for longer ones). A ramp's socket lies where its road's line,
# through the junction's centre, passes the main socket RAMP_GORE_M beyond the main road's edge.
RAMP_LANE_M = 75.0
RAMP_GORE_M = 0.75
# a feature space's `motorway_lanes` (lanes per direction of sampled ramp junctions' main roads) lie in
# 1..this: a wider road needs a steeper ramp to clear it within RAMP_LANE_M (ramps.min_ramp_angle: 19.3 deg
# for 3 lanes, 24 for 4), and a ramp at MIN_LEG_SEPARATION_DEG or more no longer measures as a ramp
MAX_MOTORWAY_LANES = 3
RAMP_PROBE_M = 60.0  # extraction: a ramp's lane joining its main road parallel is measured this far along it
# route coverage: what a suite calls the manoeuvre that takes a ramp of each kind (generated ramp junctions
# and real maps' ramps alike, inside a junction or through a direct link)
RAMP_MANOEUVRES: Mapping[str, str] = MappingProxyType({"on": "merge", "off": "diverge"})
SPEED_LIMIT_MPS = 13.4  # 30 mph, as in the SVL maps
JUNCTION_SPEED_LIMIT_MPS = 8.94  # 20 mph inside junctions
# motorway speeds (ramp junctions, ramps.py): a ramp junction's main carriageway (its main legs' roads and
# lanes straight on) and its acceleration lanes (merging traffic gets up to the main road's speed on them)
# are a motorway at MOTORWAY_SPEED_LIMIT_MPS, 55 mph (88.5 km/h, an urban motorway's limit, which its short
# 75 m auxiliary lanes fit); its ramps' roads, its deceleration lanes (leaving traffic slows on them, where
# design guidance puts the deceleration: the envs take a lower limit where its lane begins) and an on-ramp's
# lane going on to an off-ramp at RAMP_SPEED_LIMIT_MPS, 35 mph (56 km/h): design guidance (AASHTO's Green
# Book) asks a ramp design speed of about 50-85% of the motorway's, 64% here, above the town limit. A road
# between two junctions is driven at the lower of its two ends' limits (a motorway into a town junction at
# the town's), so roads between two ramp junctions' main legs are motorway
MOTORWAY_SPEED_LIMIT_MPS = 24.59  # 55 mph
RAMP_SPEED_LIMIT_MPS = 15.65  # 35 mph
# declared lane speeds a map reads (semantics.plausible_speeds): a driving lane's limit outside this range
# is no car's (a converter wrote 2.68 mph, 1.2 m/s, on every town lane); it reads as SPEED_LIMIT_MPS
# (JUNCTION_SPEED_LIMIT_MPS in junctions), with one warning per map naming the lanes
PLAUSIBLE_SPEED_MPS = (2.5, 70.0)  # 9 to 252 km/h
STRAIGHT_TOLERANCE_DEG = 30.0  # |heading change| at most this is "straight"
UTURN_THRESHOLD_DEG = 170.0  # |heading change| of a junction lane at least this is a U-turn (sharp lefts reach 150):
# the turn of lanes whose map declares none (OpenDRIVE reader, `angles.turn_name`) and the CommonRoad export's turn sets
MIN_UTURN_RADIUS_M = 5.05386147161  # a U-turn tighter than this (Apollo's default car's turn radius) is no suite manoeuvre
TIGHT_BEND_RADIUS_M = MIN_UTURN_RADIUS_M  # a bend tighter than a car turns: swept for waits beside it, no goal past it
TURN_WINDOW_M = 3.0  # a lane's sharpest turn: the heading change over this much of its centreline (a car's wheelbase)
KINK_RADIUS_M = 2.0  # a U-turn whose sharpest turn is tighter than this kinks (the env's cars leave the road there)
MAX_TURN_DEG = 270.0  # a junction lane whose heading turns further than this (unwrapped) loops: no suite manoeuvre
TURNAROUND_DEG = 135.0  # a junction lane turning at least this (a turnaround classed left/right) ...
TURNAROUND_RADIUS_M = 4.0  # ... on a mean radius (length / turn) under this is no suite manoeuvre (osm2xodr's
# dual-carriageway ends turn on 1.3-3.7 m; generated junctions' sharpest turns, 5.0 m, are driven clean)
SAMPLE_SPACING_M = 2.0  # polyline resolution of sampled curves
ENDPOINT_TOLERANCE_M = 0.01  # lanes meet their neighbours within 1 cm
MAX_ORDER_RETRIES = 1000  # rejection sampling of ordered socket angles
# Apollo export (formats/apollo: writer, sim_map, routing topo graph)
APOLLO_KMH_SPEED_MPS = 40.0  # an Apollo map whose median lane speed_limit exceeds this wrote km/h into the m/s field
APOLLO_SIGNAL_HEIGHT_M = 5.0  # centre of the light head above the road
APOLLO_SIGNAL_HEAD_SIZE_M = (0.4, 1.2)  # width, height of a 3-light vertical head (its boundary)
APOLLO_STOP_LINE_OVERLAP_M = 0.5  # signal/stop-sign overlaps span +- this around the stop line
APOLLO_SAMPLE_WINDOW_M = 5.0  # width samples measure the boundary within this arc length of the point
APOLLO_END_TANGENT_M = 0.05  # exported centrelines get a point this far inside each end (exact end headings)
APOLLO_MIN_HALF_WIDTH_M = 1.05  # Apollo rejects lane width samples below this ("too small")
APOLLO_WIDEN_MARGIN_M = 0.01  # a side widened for Apollo (boundary and width samples) lies this beyond the minimum
APOLLO_MIN_TURN_RADIUS_M = 5.05386147161  # Apollo's default vehicle (Lincoln MKZ); U-turns tighter are dropped
SIM_MAP_ANGLE_THRESHOLD_RAD = 3.141592653589793 / 180.0  # sim_map_generator: 1 degree
SIM_MAP_DOWNSAMPLE_DISTANCE_M = 5.0
SIM_MAP_STEEP_TURN_DOWNSAMPLE_DISTANCE_M = 1.0
ROUTING_BASE_SPEED_MPS = 4.167  # Apollo routing_config defaults
ROUTING_LEFT_TURN_PENALTY = 50.0
ROUTING_RIGHT_TURN_PENALTY = 20.0
ROUTING_UTURN_PENALTY = 100.0
ROUTING_CHANGE_PENALTY = 500.0
ROUTING_BASE_CHANGING_LENGTH_M = 50.0
ROUTING_MIN_LENGTH_FOR_LANE_CHANGE_M = 1.0
SIGNAL_POLE_OFFSET_M = 1.0  # pole beyond the road edge
# fixed-time signal plans (feat2map/phases.py: the env's defaults, the CommonRoad export's cycles)
SIGNAL_GREEN_S, SIGNAL_AMBER_S, SIGNAL_ALL_RED_S = 12.0, 3.0, 2.0
# the driving scenario's defaults, keyed as the env's config (envs/config.py `SETTINGS` takes these values;
# tests/test_layers.py checks the env's defaults) and read by the OpenSCENARIO export and the
# scenario tools, which must model the drive as the env does without importing it
# the controlled vehicles' lane keeping and speed control (envs/sim/vehicle.py `keeping_steering`,
# `speed_control`): highway-env's ControlledVehicle gains
LANE_KEEPING_TAU_S, LANE_KEEPING_KP_LATERAL, LANE_KEEPING_KP_HEADING = 0.1, 1 / 0.6, 1 / 0.2
SPEED_CONTROL_KP = 1 / 0.6  # [1/s] acceleration per m/s off the target speed (highway-env's KP_A = 1 / TAU_ACC)
DRIVE_DEFAULTS: Mapping[str, Any] = MappingProxyType({
    "ego_start_distance": 30.0,  # [m] before the end of the route's first lane (the first stop line)
    "ego_initial_speed": 4.5,  # [m/s]
    "goal_distance": 15.0,  # [m] into the last lane of the route
    "traffic_initial_speed": 5.0,  # [m/s]
    "signal_green": SIGNAL_GREEN_S, "signal_amber": SIGNAL_AMBER_S, "signal_all_red": SIGNAL_ALL_RED_S,  # [s]
    "signal_phases": "paired",  # "paired": opposite approaches together; "single": one at a time
    "pedestrian_speed": 1.4,  # [m/s]
    "pedestrians_per_crosswalk": 3,
    # the ego's body and steering (envs/sim/vehicle.py): a mid-size car, reference point the body's centre
    "vehicle": MappingProxyType({"length": 4.8, "width": 1.9, "wheelbase": 2.9, "front_overhang": 0.95,  # [m]
                                 "max_steering": round(math.radians(35.0), 4)}),  # [rad]
})
SIGNAL_SAME_APPROACH_DEG = 30.0  # signals whose traffic travels within this of one direction: one approach
SIGNAL_OPPOSITE_DEG = 150.0  # approaches further apart than this are opposite (paired phases)
APPROACH_SPLIT_DEG = 90.0  # a control's lanes ending further apart in heading are separate approaches (own stop lines)
STOP_SIGN_SIZE_M = 0.75  # an octagon this wide, its lower edge this high (exports that draw signs)
STOP_SIGN_HEIGHT_M = 2.0
COMMONROAD_DT_S = 0.1  # CommonRoad export: time step of the scenario (light cycles count in steps)
COMMONROAD_CONTINUATION_M = 100.0  # CommonRoad export: straight lanelets past map exits / before entries
COMMONROAD_HORIZON_S = 120.0  # CommonRoad export: its planning problem's goal time
COMMONROAD_DATE = "2020-01-01"  # the date a CommonRoad file needs, when SOURCE_DATE_EPOCH is not set
COMMONROAD_SHARED_BORDER_M = 1.5  # CommonRoad export: neighbours whose common border starts and ends at one point
# and whose two drawings of it lie this close are adjacent, with one border (their mean); others are not
COMMONROAD_VERTEX_STEP_M = 0.01  # CommonRoad export: a lanelet keeps its lane's vertices but for those this close
# (along the lines) to one kept already (adjacent lanelets need one vertex count, so each takes all theirs)
OPENDRIVE_JOINT_TANGENT_M = 0.01  # OpenDRIVE export: a polyline road starts (ends) with a chord this long along its
# neighbour's end heading, so the lane borders of linked roads meet (ASAM's contact_point_no_horizontal_gaps)
LANE_END_SNAP_M = 2.0  # Lanelet2/CommonRoad export: ends of linked lanes (per side) this close become one point
LANELET2_MERGE_M = 0.05  # Lanelet2 export: points closer are one node (lanelet2_validation warns below this)
MAP_FORMAT_VERSION = 1
UTM_ZONE = 10
UTM_ORIGIN = (587000.0, 4141000.0)  # San Francisco area, zone 10
UTM_EASTING = (100_000.0, 900_000.0)  # absolute UTM metres lie in these ranges; an Apollo map outside them
UTM_NORTHING = (0.0, 10_000_000.0)  # is in local metres and is placed at the export's origin like OpenDRIVE
OPENDRIVE_VERSIONS = ("1.8", "1.7", "1.6", "1.4")  # revisions the OpenDRIVE writer produces, default first
IMPLICIT_LANE_LINK_M = 0.5  # a road link with no lane links: same-id lanes whose ends lie this close are linked
ROAD_CONTACT_M = 0.5  # a road link whose contactPoint names an end further than this, while the other road's
# other end lies within it, is read at that other end (CommonRoad's OpenDRIVE export names the far end)
LANE_LINK_GAP_M = 5.0  # a lane link whose ends lie further apart than this is no link (converters jumping junctions)
LINK_REVERSAL_DEG = 120.0  # ... nor is one whose successor starts heading more than this away from the lane's end
TOUCHING_LINK_DEG = 45.0  # a lane without successor ending where another starts (ENDPOINT_TOLERANCE_M), heading
# within this, leads into it (SVL maps leave right-turn lanes and back-to-back junction lanes unlinked)
BRIDGE_AHEAD_M = 1.0  # a link whose successor starts further ahead than this (a stretch without lane) is bridged ...
BRIDGE_ASIDE_M = 2.0  # ... and so is one whose successor starts further to the side than this (osm2xodr lane shifts)
BRIDGE_TAIL_M = 10.0  # a bridged lane's last metres (at most) are bent smoothly to meet its successor's start
FOLD_BACK_M = 0.05  # a boundary point this far behind the one before it (along the centre line) is a fold: dropped
FOLD_LOCATE_WINDOW = 0.3  # ... located on the centre line's stretch within this fraction of its length of the point's
# own fraction along its boundary (a U-turn's centre line passes its own start again near its end)
FOLD_LOOP_SPAN = 0.5  # ... and a border crossing itself between points further apart along the centre line than
# this fraction of its length is no fold (a U-turn's inner border crosses itself where the lane's ends meet)
NEGATIVE_WIDTH_TOL_M = 0.01  # an OpenDRIVE width polynomial dipping further below 0 makes its road a bad road (a
# lane closing to 0 dips a few mm below it in converters' output: clamped to 0)
APOLLO_CROSSWALK_LINK_M = 3.0  # a crosswalk without lane overlaps belongs to a junction this close
APOLLO_JUNCTION_COVER_M = 0.5  # a junction-lane overlap within this of both lane ends makes a junction lane
APOLLO_GENERATED_MARK = b"feat2map"  # header.generation of maps feat2map generated (validate holds them to check_map)
OPENDRIVE_VENDOR = "feat2map"  # <header vendor> of feat2map's OpenDRIVE files (one element per junction: read apart)
OPENDRIVE_TURN_CODE = "feat2map:turn"  # <userData code> of a connecting road's lane: its turn (OpenDRIVE declares none)
OPENDRIVE_NEIGHBOURS_CODE = "feat2map:neighbours"  # <userData code> of a lane: neighbours written as other roads
# (only where roads name no junction: maps draw junction polygons over approach lanes too)
# junction extraction from real maps (feat2map/extract.py, docs/extraction.md)
ARM_CLUSTER_DEG = 30.0  # outward directions of one arm's lanes differ by less than this (LEG_MERGE_DEG when
# the lanes all enter or all leave)
ARM_PROBE_M = 20.0  # an arm's direction: towards the point this far out along its road
ARM_MAX_WIDTH_M = 30.0  # lanes of one arm lie within this across the arm (medians included)
ARM_MAX_DEPTH_M = 15.0  # ... and within this along it
ARM_NEAR_M = 8.0  # lane ends this close with the same local direction belong to one arm
ARM_TIE_M = 1e-3  # ... each limit less this: a map drawn in round metres (an entry ramp 15 m along from an exit
# ramp) must fall on one side of a limit, not on either by rounding, which an export and re-read changes
ARM_CENTRE_EXACT_M = 0.05  # mouth tangents meeting this closely define the centre exactly
ARM_SAME_POINT_M = 0.05  # lane mouths this close are one arm, whatever their tangents
MIN_ARM_LENGTH_M = 0.5  # a road shorter than this between two ends of one junction is part of it, not an arm
EDGE_STUB_LENGTH_M = 3.0  # a road at the map's edge shorter than this is part of its junction (a car on it stands in it)
OUTPUT_MANIFEST_MAX_BYTES = 16 << 20  # an output folder's .feat2map-output.json larger than this is not ours


# (low, high) of every GenerationConfig number, inclusive; None: no bound besides the limits below.
# grid_gap and stub_length are also capped by Limits.max_road_length_m, samples_per_combination by
# Limits.max_junctions (both checked where they are used, so raised limits take effect).
CONFIG_RANGES: dict[str, tuple[float, float | None]] = {
    "grid_gap": (20.0, None), "lane_width": (1.0, 10.0), "crosswalk_width": (0.5, 20.0),
    "stub_length": (1.0, None), "min_socket_separation_deg": (MIN_LEG_SEPARATION_DEG, 120.0),
    "min_junction_radius": (1.0, 1000.0), "junction_margin": (0.01, 50.0), "speed_limit": (0.1, 100.0),
    "junction_speed_limit": (0.1, 100.0), "sample_spacing": (0.1, 100.0), "samples_per_combination": (1, None),
    "motorway_speed_limit": (0.1, 100.0), "ramp_speed_limit": (0.1, 100.0),
}
# fields added after maps recorded their config (`GenerationConfig.to_dict` writes them only when set off their
# defaults, so that maps generated without them keep their bytes)
LATE_CONFIG_FIELDS = ("motorway_speed_limit", "ramp_speed_limit")


@dataclass(frozen=True)
class GenerationConfig:
    """Knobs of map construction; every field has the paper's default. Values are checked on
    construction (finite, in CONFIG_RANGES, right type): a ConfigError names the field."""

    grid_gap: float = GRID_GAP_M
    lane_width: float = LANE_WIDTH_M
    crosswalk_width: float = CROSSWALK_WIDTH_M
    stub_length: float = STUB_LENGTH_M
    min_socket_separation_deg: float = MIN_LEG_SEPARATION_DEG
    min_junction_radius: float = MIN_JUNCTION_RADIUS_M
    junction_margin: float = JUNCTION_MARGIN_M
    speed_limit: float = SPEED_LIMIT_MPS
    junction_speed_limit: float = JUNCTION_SPEED_LIMIT_MPS
    sample_spacing: float = SAMPLE_SPACING_M
    samples_per_combination: int = 1
    uturns: bool = False
    motorway_speed_limit: float = MOTORWAY_SPEED_LIMIT_MPS  # ramp junctions' main carriageway (and auxiliary lanes)
    ramp_speed_limit: float = RAMP_SPEED_LIMIT_MPS  # ramp junctions' ramps

    def __post_init__(self) -> None:
        from .errors import ConfigError

        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "uturns":
                if not isinstance(value, bool):
                    raise ConfigError(f"config field 'uturns' must be true or false, got {_short(value)}")
                continue
            integer = f.name == "samples_per_combination"
            if isinstance(value, bool) or not isinstance(value, int if integer else (int, float)) \
                    or not math.isfinite(value):
                kind = "an integer" if integer else "a finite number"
                raise ConfigError(f"config field '{f.name}' must be {kind}, got {_short(value)}")
            lo, hi = CONFIG_RANGES[f.name]
            if value < lo or (hi is not None and value > hi):
                span = f"between {lo:g} and {hi:g}" if hi is not None else f"at least {lo:g}"
                raise ConfigError(f"config field '{f.name}' must be {span}, got {_short(value)}")
        if self.grid_gap < 4 * self.min_junction_radius:
            raise ConfigError(
                f"config field 'grid_gap' ({self.grid_gap}) must be at least 4x min_junction_radius"
            )

    def check_limits(self) -> None:
        """The fields bounded by the current `Limits` (raise them with `raised_limits`)."""
        lim = limits()
        for name in ("grid_gap", "stub_length"):
            lim.check("max_road_length_m", getattr(self, name), f"config field '{name}'")
        lim.check("max_junctions", self.samples_per_combination, "config field 'samples_per_combination'")

    def to_dict(self) -> dict[str, Any]:
        """Every field, those of LATE_CONFIG_FIELDS only when off their defaults (a map records this)."""
        default = GenerationConfig()
        return {k: v for k, v in asdict(self).items()
                if k not in LATE_CONFIG_FIELDS or v != getattr(default, k)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "GenerationConfig":
        from .errors import ConfigError

        if not isinstance(data, dict):
            raise ConfigError(f"a config must be a mapping of fields, got {_short(data)}")
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ConfigError(f"unknown config field(s): {', '.join(sorted(map(str, unknown)))[:200]}")
        return replace(cls(), **data)


def _short(value: Any, cap: int = 40) -> str:
    """`repr(value)`, cut to `cap` characters: errors never quote more than a short snippet."""
    text = repr(value)
    return text if len(text) <= cap else text[: cap - 3] + "..."


# ---------------------------------------------------------------------------------- size limits

LIMIT_FLAG = "--limit"  # the CLI option that raises a limit: feat2map --limit max_junctions=20000 generate ...


@dataclass(frozen=True)
class Limits:
    """Size caps that keep a hostile or careless input from running for hours or exhausting
    memory; each is checked before the work it bounds and its error says how to raise it
    (`feat2map --limit NAME=VALUE ...`, or `raised_limits(NAME=VALUE)` in Python)."""

    max_junctions: int = 20_000  # junctions one generate/spec run builds (linear: 10,000 take about 15 s)
    max_road_length_m: float = 20_000.0  # one road (OpenDRIVE road, spec chain piece, grid gap)
    max_lanes: int = 500_000  # lanes in one map read from a file
    max_points: int = 20_000_000  # polyline points in one map read from a file
    max_coordinate_m: float = 1e8  # |x|, |y| of any point (UTM northings are below 1e7)
    max_lane_width_m: float = 100.0  # one lane's width anywhere along it
    max_file_bytes: int = 2 << 30  # one input file (map, spec, suite, feature space)
    max_document_bytes: int = 64 << 20  # one JSON/YAML spec, suite or feature-space document
    max_nesting: int = 100  # nesting depth of JSON/YAML documents
    max_yaml_nodes: int = 2_000_000  # YAML nodes after expanding aliases (an alias bomb is billions)
    max_checker_s: float = 600.0  # [s] one run of a format's own checker on one file (ASAM's Quality Checker)

    def check(self, name: str, value: float, what: str) -> None:
        """Raise a LimitError when `value` exceeds limit `name`."""
        cap = getattr(self, name)
        if value > cap:
            from .errors import LimitError

            raise LimitError(f"{what} is {plain_number(value)}, above the limit {name}={plain_number(cap)} "
                             f"(raise it with {LIMIT_FLAG} {name}=N)")


def plain_number(value: float) -> str:
    """`2147483648`, `20000`, `0.5`, `1e+300`: whole numbers in full (not 2.14748e+09), others short."""
    if float(value).is_integer() and abs(value) < 1e16:
        return str(int(value))
    return f"{value:g}"


_LIMITS: contextvars.ContextVar[Limits] = contextvars.ContextVar("feat2map_limits", default=Limits())


def limits() -> Limits:
    """The size caps in force (defaults unless raised by `raised_limits` or `--limit`)."""
    return _LIMITS.get()


@contextlib.contextmanager
def raised_limits(**values: float) -> Iterator[Limits]:
    """Run a block with some limits changed: `with raised_limits(max_junctions=20000): ...`."""
    from .errors import ConfigError

    known = {f.name: f.type for f in fields(Limits)}
    for name, value in values.items():
        if name not in known:
            raise ConfigError(f"unknown limit {name!r} (limits: {', '.join(known)})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise ConfigError(f"limit {name} must be a positive finite number, got {_short(value)}")
    raised: dict[str, Any] = {k: (int(v) if known[k] == "int" else float(v)) for k, v in values.items()}
    token = _LIMITS.set(replace(limits(), **raised))
    try:
        yield limits()
    finally:
        _LIMITS.reset(token)


# rollout workers (scenarios/rollout.py worker_pool): none outlives its parent, however the parent ended
WORKER_PARENT_POLL_S = 0.2  # [s] how often a worker looks whether its parent is gone (it then kills its planners, exits)
# rollout reports (scenarios/markup.py): report.html loads nothing but its inline pictures and style, runs no script
REPORT_CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'; base-uri 'none'; form-action 'none'"

# criticality of a rollout (scenarios/criticality.py): what the search (scenarios/search.py) is guided by
TTC_CAP_S = 10.0  # a time-to-collision beyond this (or none: nobody closing in) counts as this
DISTANCE_CAP_M = 50.0  # the closest road user: farther than this (or none) counts as this
BRAKE_CAP_MPS2 = 8.0  # the hardest braking scores 1 at this deceleration (the baseline's action range)
TTC_RANGE_M = 60.0  # only road users this close to the ego enter its time-to-collision and distance
RED_MARGIN_CAP_S = 5.0  # arriving at a signal's line further than this from its turning red counts as this
RED_MARGIN_RANGE_M = 40.0  # only a signal line this close ahead (and the ego moving) enters the red margin
# `feat2map search` (scenarios/search.py, search_space.py): the layer-4 ranges it searches, all within legal
# driving and the env's config checks (envs/config.py), and how it proceeds
SEARCH_TRAFFIC_MAX = 12  # traffic vehicles 0..this
SEARCH_PEDESTRIAN_RATE_MAX = 12.0  # pedestrians per crosswalk per minute 0..this
SEARCH_PEDESTRIAN_SPEED_MPS = (0.8, 2.0)  # walking speed, slow to brisk
SEARCH_TRAFFIC_SPEED_MPS = (0.0, 12.0)  # traffic's speed at spawn (below SPEED_LIMIT_MPS)
SEARCH_EGO_SPEED_MPS = (0.0, 10.0)  # the ego's speed at reset
SEARCH_EGO_START_M = (10.0, 60.0)  # the ego starts this far before its first stop line
SEARCH_SIGNAL_GREEN_S = (6.0, 30.0)  # green time of a phase
SEARCH_SIGNAL_AMBER_S = (3.0, 5.0)  # amber: at least 3 s, as traffic engineering manuals ask
SEARCH_SIGNAL_ALL_RED_S = (0.0, 2.0)  # all-red between phases
SEARCH_LANES_MAX = 2  # lanes per direction of a generated junction's legs: 1..this
SEARCH_ENV_SEED_MAX = 2**31 - 1  # env seeds (traffic and pedestrian spawn places and times) 0..this
SEARCH_BATCH = 4  # candidates asked of the optimiser at once: results do not depend on the worker count
SEARCH_STARTUP_TRIALS = 8  # TPE draws at random this many candidates before it models the good ones
SEARCH_FAILURE_BONUS = 1.0  # a failing candidate scores this over its criticality (0..1), divided by 1 + earlier finds
SEARCH_MAX_INFEASIBLE = 200  # candidates whose junction cannot be built (legs too close) before the search gives up
SHRINK_MAX_ROUNDS = 6  # shrinking rounds per failure (each drives every smaller candidate once)


# ---- env layer (feat2map/envs): the traffic rules, the traffic core, the road network, the ego's
# observations and controllers. Units in the names: _M metres, _S seconds, _MPS m/s, _MPS2 m/s^2.
# the rules (envs/rules.py)
STOPPED_SPEED_MPS = 0.3  # a vehicle at most this fast has stopped (a stop at a stop sign, a stop-sign queue)
STOP_ZONE_M = 6.0  # a stop counts when made with the vehicle centre within this distance of the stop line
STOP_POINT_M = 1.0  # vehicles held by a rule stop their centre this far before the line
# the blocked early end of rollouts (scenarios/rollout.py; envs/rules.py EgoJudge.wait_reason), as CARLA
# leaderboard's AgentBlockedTest but for waits the rules do not justify
BLOCKED_AFTER_S = 30.0  # [s] a rollout ends as a timeout once the ego stood still this long with nothing in its way
BLOCKED_NEAR_M = 20.0  # a rule's stop point (not a stop sign not yet reached) or a road user this close ahead justifies a wait
COMMIT_DISTANCE_M = 10.0  # a vehicle allowed to go reserves its junction lane this close to the line
COMMIT_TIME_S = 1.5  # ... or this many seconds at its speed
AMBER_BRAKE_MPS2 = 3.0  # at amber a vehicle stops when it can at this deceleration (plus AMBER_STOP_MARGIN_M)
AMBER_STOP_MARGIN_M = 1.0  # ... and this much room before the line
AMBER_CAP_MARGIN_M = 1.0  # a signal approach keeps this much more room than stops_at_amber needs (a decision step's travel)
LOOKAHEAD_M = 60.0  # how far along its route a vehicle looks for leaders, stop lines and pedestrians
PASSAGE_HORIZON_M = 400.0  # how far along its route a vehicle looks for narrow passages it must claim together
PEDESTRIAN_CORRIDOR_M = 6.0  # beyond the lane half-width, a pedestrian walking towards the lane makes vehicles yield
PEDESTRIAN_IN_PATH_M = 0.6  # beyond the lane half-width, a pedestrian is in the vehicle's path
PEDESTRIAN_YIELD_SPEED_MPS = 0.5  # the ego moving faster than this on a crosswalk with a pedestrian in its path fails to yield
PEDESTRIAN_YIELD_STRETCH_M = 1.0  # ... on the crosswalk's stretch of its lane widened by this each way
PEDESTRIAN_CLEARANCE_M = 6.0  # a pedestrian does not step out in front of a vehicle this close
PEDESTRIAN_SPAWN_HORIZON_S = 3.0  # ... nor one this many seconds away (plus the clearance)
PEDESTRIAN_SIDE_OFFSET = 0.3  # a pedestrian steps out within this fraction of the crosswalk's width beside its axis
PEDESTRIAN_SPEED_SPREAD = 0.15  # ... at the configured walking speed times 1 +- this
PRIORITY_HORIZON_S = 3.0  # left turns wait for priority traffic this close in time
PRIORITY_MARGIN_M = 3.0  # ... plus this distance to the end of its approach lane
ROUTE_SAMPLE_TRIES = 100  # sampled routes through a junction tried before a map counts as having none
SPAWN_BRAKE_MPS2 = 3.0  # vehicles start at least their braking distance at this rate before the first stop line
SPAWN_MARGIN_M = 1.0  # ... plus this
OFF_ROAD_LATERAL_M = 1.5  # the ego is off the road this far beyond its lane's edge
OFF_ROAD_END_M = 3.0  # ... or this far past the end of a lane without successors
FINISH_MARGIN_M = 2.0  # traffic has finished its route this close to the end of its last lane
LEADER_LATERAL_M = 1.0  # beyond a lane's half width, a road user is not in the way of a vehicle on it
# IDM car following of our vehicles (own constants: highway-env's envs mutate IDMVehicle's class attributes)
IDM_ACC = 3.0  # [m/s^2] maximum acceleration
IDM_BRAKE = 4.0  # [m/s^2] comfortable deceleration
IDM_DELTA = 4.0  # free-road exponent (dimensionless)
IDM_GAP_M = 2.5  # jam distance to a leader
IDM_TIME_GAP_S = 1.2  # desired time headway
IDM_STOP_GAP_M = 0.3  # jam distance to a stop point (vs IDM_GAP_M to a leader)
IDM_STOP_MARGIN_M = 0.5  # the front bumper halts this short of a stop point
IDM_MIN_GAP_M = 0.05  # gaps below this count as this (no division by zero)
IDM_RANGE_MPS2 = (-8.0, 6.0)  # an IDM acceleration is clipped to these
# MOBIL lane changes of traffic (envs/sim/mobil.py, rules.may_change_lane)
MOBIL_PERIOD_S = 1.0  # traffic considers a lane change this often
MOBIL_GAIN_MPS2 = 0.3  # own acceleration gain that makes a lane change worth it
MOBIL_SAFE_BRAKE_MPS2 = 3.0  # the new follower must not need to brake harder
MOBIL_POLITENESS = 0.3  # weight of the new follower's acceleration loss (dimensionless)
MOBIL_MIN_ROOM_M = 30.0  # no lane change closer than this to the lane's end
MOBIL_MIN_SPEED_MPS = 1.0  # ... or slower than this
MOBIL_MIN_GAP_M = 2.0  # bumper gap to the new leader and the new follower at least
MOBIL_DETOUR_M = 5.0  # the route from the new lane may be at most this much longer
LANE_ROUTES_KEPT = 65536  # lane routes (start, goal) a network keeps found (`MapNetwork.lane_route`)
ROUTE_SEARCH_SLACK_M = 1.0  # a route search with a length limit goes this much farther (rounding)
# the traffic core (envs/core.py)
LANE_CHANGE_TAU_S = 1.0  # a lane change's lateral offset decays with this time constant
PAIR_SAMPLE_M = 0.5  # lane-pair tables sample the other lane this often
# the road network (envs/network.py, envs/lanes.py)
FOLD_TURN_DEG = 120.0  # a lane polyline turning more than this at a vertex ...
FOLD_SEGMENT_M = 1.0  # ... next to a segment shorter than this folds back (a cusp): the vertex is dropped
CONFLICT_DISTANCE_M = 2.2  # junction paths closer than a car width (+ margin) conflict
# two junction lanes merge (a conflict) where both lead into one road lane, directly or through road
# pieces shorter than this: a filter lane joins its exit road just after the piece the junction's
# own lanes run on (construct splits the road FILTER_DIVERGE_M or less from the junction)
MERGE_REACH_M = 2 * FILTER_DIVERGE_M
VEHICLE_LENGTH_M, VEHICLE_WIDTH_M = 5.0, 2.0  # highway-env's vehicle footprint
# traffic routes end on at least this much road after their last junction: a car whose route ends
# on less stands half inside the next junction, blind to it (Town07's 0.7 m road); Shalun's 3.5 m
# roads between junctions are room enough (a longer limit changed their traffic for no need)
TRAFFIC_END_ROOM_M = VEHICLE_LENGTH_M / 2
# road lanes of one direction that come within CONFLICT_DISTANCE_M converge (zip) only where they
# meet at most this steeply: a taper (Highway101GLE: 2.6 deg); steeper ones cross, as roads over
# roads do (Town04's bridges: 89.5 deg)
CONVERGE_MAX_ANGLE_DEG = 30.0
TRACKING_MARGIN_M = 0.5  # lateral error of the lane keeping on tight junction curves (corners are cut)
CROSSING_CLEARANCE_M = 1.0  # a stop line lies this far before another road's lane its lane crosses (plus half its width)
FOOTPRINT_STEP_M = 2.0  # footprints along a junction lane are placed this far apart
PASSAGE_DISTANCE_M = VEHICLE_WIDTH_M + TRACKING_MARGIN_M  # opposite road lanes closer than this are one narrow passage
PASSAGE_STEP_M = 1.0  # a lane is sampled this often to find where it runs that close to another
CURVE_CHORD_M = 2.0  # a lane's curvature is the turn between the chords this long either side of a point
# where a car may wait beside a narrow road (envs/sweep.py): out of the swept path of the lane
# keeping driven along the opposite lanes (from SWEEP_LEAD_M before them) at these speeds
SWEEP_SPEEDS_MPS = (3.0, 6.0)  # turning speeds of the ego through junctions and bends (the planner's)
SWEEP_STEP_S = 1 / 15  # one pose per simulation frame (the env's default simulation_frequency)
SWEEP_LEAD_M = 20.0  # a swept car starts this far before the lane it turns into
SWEEP_CLEARANCE_M = 0.2  # a waiting car's body keeps this far from the swept footprints
# speed in curves, one rule for traffic (envs/core.py) and the baseline planner (scenarios/planner.py):
# both take a curve at v <= sqrt(LATERAL_ACCEL_MPS2 * radius), from `lanes.curve_speeds`
LATERAL_ACCEL_MPS2 = 2.5  # lateral acceleration a curve is driven at, at most
CURVE_WINDOW_M = 4.0  # a lane's curvature for its curve speed is measured over this arc length
CURVE_MIN_SPEED_MPS = 3.0  # no curve is taken slower (a 4 m radius at LATERAL_ACCEL_MPS2)
CURVE_BRAKE_MPS2 = 2.0  # traffic's desired speed falls towards a curve ahead no faster than braking at this
CURVE_BEHIND_M = 1.0  # a curve point this close behind a vehicle still limits its speed
# the episode (envs/map_env.py): where traffic spawns
TRAFFIC_SPAWN_TRIES = 10  # random places tried per traffic vehicle (count)
TRAFFIC_SPAWN_GAP_M = 12.0  # a traffic vehicle spawns this far from any other
TRAFFIC_LANE_END_M = 8.0  # ... and not within this of its lane's end
EGO_CLEARANCE_M = 25.0  # ... and this far from the ego (or the agents) at reset
EGO_RESPAWN_CLEARANCE_M = 40.0  # ... and this far when it respawns
# observations (envs/observation.py, envs/driver_view.py): distances, times and speeds are divided by these
STOP_LINE_RANGE_M = 100.0  # the traffic-control vector's stop-line distance is metres / this, clipped to 1
DRIVER_VIEW_SPEED_SCALE_MPS = 15.0  # DriverView speeds / this
DRIVER_VIEW_LINE_NEAR_M = 2 * STOP_ZONE_M  # DriverView line_near: distance to the next stop line / this
DRIVER_VIEW_LINE_FAR_M = 60.0  # DriverView line_far: the same / this
DRIVER_VIEW_SIGNAL_SCALE_S = 15.0  # DriverView signal_change: time to the signal's next change / this
DRIVER_VIEW_QUEUE_SCALE = 3.0  # DriverView queue_ahead: vehicles / this
DRIVER_VIEW_CONFLICT_TIME_S = 8.0  # DriverView times to a line or a conflict / this
DRIVER_VIEW_CONFLICT_DISTANCE_M = 60.0  # DriverView distances of vehicles heading into a conflict / this
DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS = 1.0  # times to arrival divide by at least this speed (a waiting car is not "never")
DRIVER_VIEW_PEDESTRIAN_SCALE_M = 30.0  # DriverView pedestrian: distance to the stop it makes / this
DRIVER_VIEW_LEADER_SCALE_M = 40.0  # DriverView leader_gap: bumper gap / this
# the trajectory tracker (envs/tracking.py: an external planner's trajectory followed by the ego)
TRACKING_LOOKAHEAD_MIN_M = 2.5  # pure pursuit looks this far ahead (it cuts a curve of radius R by ~R - sqrt(R^2 - L^2))
TRACKING_LOOKAHEAD_TIME_S = 0.3  # ... plus this many seconds of the current speed
TRACKING_SPEED_GAIN = 1.5  # [1/s] speed error -> acceleration
TRACKING_POSITION_GAIN = 0.4  # [1/s^2] along-track position error -> acceleration
TRACKING_ACCEL_RANGE = (-8.0, 4.0)  # [m/s^2] the command is clipped to these (the baseline's range)
TRACKING_STOP_SPEED_MPS = 0.3  # a trajectory whose speed falls below this holds the ego still
TRACKING_PREVIEW_S = 0.2  # the speed reference is read this far ahead (the actuation lag of one decision)
TRACKING_HOLD_WINDOW_S = 1.0  # the ego is held still only if the trajectory stays below the stop speed this long
# the multi-agent env (envs/multi_agent.py)
AGENT_TARGET_SPEEDS = (0.0, 1.5, 3.0, 5.0, 7.5, 10.0)  # [m/s] the default TargetSpeed actions (examples/train_ppo.py's)
AGENT_ACCELERATION_RANGE = (-6.0, 3.0)  # [m/s^2] the default acceleration range of the agents' actions
AGENT_ENTRY_LOOK_M = 8.0  # the judge notes the rules' verdict for agents this close to their next stop line
