"""Every tunable constant of feat2map, named once.

`GenerationConfig` is the one value object the generator takes; the module-level
constants are its defaults and are shared by readers, writers and the envs.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

GRID_GAP_M = 100.0  # paper: P_{x+1,y} is 100 m east of P_{x,y}
LANE_WIDTH_M = 3.5  # paper: default lane width of the input maps
CROSSWALK_WIDTH_M = 4.5  # paper: slightly longer than a sedan
STUB_LENGTH_M = 25.0  # dead-end roads: the map's entries and exits; short of half a grid gap
MIN_SOCKET_SEPARATION_DEG = 20.0
MIN_STUB_LENGTH_M = 10.0  # a junction must leave at least this much road before the half-way line
MIN_JUNCTION_RADIUS_M = 12.0  # centre to socket, before lane-width growth
JUNCTION_MARGIN_M = 1.5  # between crosswalk and socket, and around stop lines
SPEED_LIMIT_MPS = 13.4  # 30 mph, as in the SVL maps
JUNCTION_SPEED_LIMIT_MPS = 8.94  # 20 mph inside junctions
STRAIGHT_TOLERANCE_DEG = 30.0  # |heading change| below this is "straight"
UTURN_THRESHOLD_DEG = 150.0
SAMPLE_SPACING_M = 2.0  # polyline resolution of sampled curves
ENDPOINT_TOLERANCE_M = 0.01  # lanes meet their neighbours within 1 cm
MAX_ORDER_RETRIES = 1000  # rejection sampling of ordered socket angles
# Apollo export (formats/apollo: writer, sim_map, routing topo graph)
APOLLO_SIGNAL_HEIGHT_M = 5.0  # centre of the light head above the road
APOLLO_SIGNAL_HEAD_SIZE_M = (0.4, 1.2)  # width, height of a 3-light vertical head (its boundary)
APOLLO_STOP_LINE_OVERLAP_M = 0.5  # signal/stop-sign overlaps span +- this around the stop line
APOLLO_SAMPLE_WINDOW_M = 5.0  # width samples measure the boundary within this arc length of the point
APOLLO_END_TANGENT_M = 0.05  # exported centrelines get a point this far inside each end (exact end headings)
APOLLO_MIN_HALF_WIDTH_M = 1.05  # Apollo rejects lane width samples below this ("too small")
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
SIGNAL_SAME_APPROACH_DEG = 30.0  # signals whose traffic travels within this of one direction: one approach
SIGNAL_OPPOSITE_DEG = 150.0  # approaches further apart than this are opposite (paired phases)
STOP_SIGN_SIZE_M = 0.75  # an octagon this wide, its lower edge this high (exports that draw signs)
STOP_SIGN_HEIGHT_M = 2.0
COMMONROAD_DT_S = 0.1  # CommonRoad export: time step of the scenario (light cycles count in steps)
COMMONROAD_HORIZON_S = 120.0  # CommonRoad export: its planning problem's goal time
COMMONROAD_DATE = "2020-01-01"  # the date a CommonRoad file needs, when SOURCE_DATE_EPOCH is not set
LANE_END_SNAP_M = 2.0  # Lanelet2/CommonRoad export: ends of linked lanes (per side) this close become one point
LANELET2_MERGE_M = 0.05  # Lanelet2 export: points closer are one node (lanelet2_validation warns below this)
MAP_FORMAT_VERSION = 1
UTM_ZONE = 10
UTM_ORIGIN = (587000.0, 4141000.0)  # San Francisco area, zone 10
OPENDRIVE_VERSIONS = ("1.8", "1.7", "1.6", "1.4")  # revisions the OpenDRIVE writer produces, default first
APOLLO_CROSSWALK_LINK_M = 3.0  # a crosswalk without lane overlaps belongs to a junction this close
APOLLO_JUNCTION_COVER_M = 0.5  # a junction-lane overlap within this of both lane ends makes a junction lane
# (only where roads name no junction: maps draw junction polygons over approach lanes too)
# junction extraction from real maps (feat2map/extract.py, docs/extraction.md)
ARM_CLUSTER_DEG = 30.0  # outward directions of one arm's lanes differ by less than this
ARM_PROBE_M = 20.0  # an arm's direction: towards the point this far out along its road
ARM_MAX_WIDTH_M = 30.0  # lanes of one arm lie within this across the arm (medians included)
ARM_MAX_DEPTH_M = 15.0  # ... and within this along it
ARM_NEAR_M = 8.0  # lane ends this close with the same local direction belong to one arm
ARM_CENTRE_EXACT_M = 0.05  # mouth tangents meeting this closely define the centre exactly
MIN_EXTRACTED_SEPARATION_DEG = 1.0  # real maps may have legs much closer than generated ones
MIN_ARM_LENGTH_M = 0.5  # a road shorter than this between two ends of one junction is part of it, not an arm


@dataclass(frozen=True)
class GenerationConfig:
    """Knobs of map construction; every field has the paper's default."""

    grid_gap: float = GRID_GAP_M
    lane_width: float = LANE_WIDTH_M
    crosswalk_width: float = CROSSWALK_WIDTH_M
    stub_length: float = STUB_LENGTH_M
    min_socket_separation_deg: float = MIN_SOCKET_SEPARATION_DEG
    min_junction_radius: float = MIN_JUNCTION_RADIUS_M
    junction_margin: float = JUNCTION_MARGIN_M
    speed_limit: float = SPEED_LIMIT_MPS
    junction_speed_limit: float = JUNCTION_SPEED_LIMIT_MPS
    sample_spacing: float = SAMPLE_SPACING_M
    samples_per_combination: int = 1
    uturns: bool = False

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool):
                continue
            if not isinstance(value, (int, float)) or value <= 0:
                raise ValueError(f"config field '{f.name}' must be a positive number, got {value!r}")
        if self.samples_per_combination != int(self.samples_per_combination):
            raise ValueError("config field 'samples_per_combination' must be an integer >= 1")
        if self.grid_gap < 4 * self.min_junction_radius:
            raise ValueError(
                f"config field 'grid_gap' ({self.grid_gap}) must be at least 4x min_junction_radius"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "GenerationConfig":
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown config field(s): {', '.join(sorted(unknown))}")
        return replace(cls(), **data)
