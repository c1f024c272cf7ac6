"""Apollo 7-9 HD map and routing-graph protobuf messages, built at import time.

Apollo's public `.proto` files define `apollo.hdmap.Map` (base_map / sim_map) and
`apollo.routing.Graph` (routing_map). We do not ship or generate from those files: the
tables below restate the messages we read and write, with Apollo's field names and
numbers, and `_build` turns them into descriptors in a private descriptor pool. Apollo 10+
additions (Map.ad_area, Map.barrier_gate, lane type SHARED) are deliberately absent, so
nothing written with these classes is rejected by Apollo 7-9's text parser.

Table syntax, one field per string: ``"<label> <type> <name> = <number> [default=<v>]"``
with label ``optional``/``repeated`` or ``oneof:<group>``; a type is a scalar, a message
or enum of the same package (enum names are looked up in the message first), or a fully
qualified name such as ``apollo.common.PointENU``.
"""
from __future__ import annotations

import re
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, text_format
from google.protobuf.message import DecodeError, Message

from ...errors import MapFormatError

_SCALARS = {
    "double": descriptor_pb2.FieldDescriptorProto.TYPE_DOUBLE,
    "float": descriptor_pb2.FieldDescriptorProto.TYPE_FLOAT,
    "int32": descriptor_pb2.FieldDescriptorProto.TYPE_INT32,
    "int64": descriptor_pb2.FieldDescriptorProto.TYPE_INT64,
    "uint32": descriptor_pb2.FieldDescriptorProto.TYPE_UINT32,
    "bool": descriptor_pb2.FieldDescriptorProto.TYPE_BOOL,
    "string": descriptor_pb2.FieldDescriptorProto.TYPE_STRING,
    "bytes": descriptor_pb2.FieldDescriptorProto.TYPE_BYTES,
}

# --- apollo.common (modules/common_msgs/basic_msgs/geometry.proto) -------------------------
_COMMON_MESSAGES: dict[str, list[str]] = {
    "PointENU": [
        "optional double x = 1 [default=nan]",  # east, metres
        "optional double y = 2 [default=nan]",  # north, metres
        "optional double z = 3 [default=0]",
    ],
}

# --- apollo.hdmap (modules/common_msgs/map_msgs/map_*.proto, Apollo 7.0-9.0) ---------------
_HDMAP_ENUMS: dict[str, dict[str, int]] = {
    "LaneBoundaryType.Type": {"UNKNOWN": 0, "DOTTED_YELLOW": 1, "DOTTED_WHITE": 2, "SOLID_YELLOW": 3,
                              "SOLID_WHITE": 4, "DOUBLE_YELLOW": 5, "CURB": 6},
    "Lane.LaneType": {"NONE": 1, "CITY_DRIVING": 2, "BIKING": 3, "SIDEWALK": 4, "PARKING": 5,
                      "SHOULDER": 6},
    "Lane.LaneTurn": {"NO_TURN": 1, "LEFT_TURN": 2, "RIGHT_TURN": 3, "U_TURN": 4},
    "Lane.LaneDirection": {"FORWARD": 1, "BACKWARD": 2, "BIDIRECTION": 3},
    "BoundaryEdge.Type": {"UNKNOWN": 0, "NORMAL": 1, "LEFT_BOUNDARY": 2, "RIGHT_BOUNDARY": 3},
    "Road.Type": {"UNKNOWN": 0, "HIGHWAY": 1, "CITY_ROAD": 2, "PARK": 3},
    "Junction.Type": {"UNKNOWN": 0, "IN_ROAD": 1, "CROSS_ROAD": 2, "FORK_ROAD": 3, "MAIN_SIDE": 4,
                      "DEAD_END": 5},
    "Subsignal.Type": {"UNKNOWN": 1, "CIRCLE": 2, "ARROW_LEFT": 3, "ARROW_FORWARD": 4, "ARROW_RIGHT": 5,
                       "ARROW_LEFT_AND_FORWARD": 6, "ARROW_RIGHT_AND_FORWARD": 7, "ARROW_U_TURN": 8},
    "SignInfo.Type": {"None": 0, "NO_RIGHT_TURN_ON_RED": 1},
    "Signal.Type": {"UNKNOWN": 1, "MIX_2_HORIZONTAL": 2, "MIX_2_VERTICAL": 3, "MIX_3_HORIZONTAL": 4,
                    "MIX_3_VERTICAL": 5, "SINGLE": 6},
    "StopSign.StopType": {"UNKNOWN": 0, "ONE_WAY": 1, "TWO_WAY": 2, "THREE_WAY": 3, "FOUR_WAY": 4,
                          "ALL_WAY": 5},
    "Passage.Type": {"UNKNOWN": 0, "ENTRANCE": 1, "EXIT": 2},
}

_HDMAP_MESSAGES: dict[str, list[str]] = {
    "Id": ["optional string id = 1"],
    # geometry
    "Polygon": ["repeated apollo.common.PointENU point = 1"],
    "LineSegment": ["repeated apollo.common.PointENU point = 1"],
    "CurveSegment": [
        "oneof:curve_type LineSegment line_segment = 1",
        "optional double s = 6",
        "optional apollo.common.PointENU start_position = 7",
        "optional double heading = 8",
        "optional double length = 9",
    ],
    "Curve": ["repeated CurveSegment segment = 1"],
    # lanes
    "LaneBoundaryType": ["optional double s = 1", "repeated Type types = 2"],
    "LaneBoundary": [
        "optional Curve curve = 1",
        "optional double length = 2",
        "optional bool virtual = 3",
        "repeated LaneBoundaryType boundary_type = 4",
    ],
    "LaneSampleAssociation": ["optional double s = 1", "optional double width = 2"],
    "Lane": [
        "optional Id id = 1",
        "optional Curve central_curve = 2",
        "optional LaneBoundary left_boundary = 3",
        "optional LaneBoundary right_boundary = 4",
        "optional double length = 5",
        "optional double speed_limit = 6",  # m/s
        "repeated Id overlap_id = 7",
        "repeated Id predecessor_id = 8",
        "repeated Id successor_id = 9",
        "repeated Id left_neighbor_forward_lane_id = 10",
        "repeated Id right_neighbor_forward_lane_id = 11",
        "optional LaneType type = 12",
        "optional LaneTurn turn = 13",
        "repeated Id left_neighbor_reverse_lane_id = 14",
        "repeated Id right_neighbor_reverse_lane_id = 15",
        "optional Id junction_id = 16",
        "repeated LaneSampleAssociation left_sample = 17",
        "repeated LaneSampleAssociation right_sample = 18",
        "optional LaneDirection direction = 19",
        "repeated LaneSampleAssociation left_road_sample = 20",
        "repeated LaneSampleAssociation right_road_sample = 21",
        "repeated Id self_reverse_lane_id = 22",
    ],
    # roads
    "BoundaryEdge": ["optional Curve curve = 1", "optional Type type = 2"],
    "BoundaryPolygon": ["repeated BoundaryEdge edge = 1"],
    "RoadBoundary": ["optional BoundaryPolygon outer_polygon = 1", "repeated BoundaryPolygon hole = 2"],
    "RoadROIBoundary": ["optional Id id = 1", "repeated RoadBoundary road_boundaries = 2"],
    "RoadSection": ["optional Id id = 1", "repeated Id lane_id = 2", "optional RoadBoundary boundary = 3"],
    "Road": [
        "optional Id id = 1",
        "repeated RoadSection section = 2",
        "optional Id junction_id = 3",  # set for roads inside a junction
        "optional Type type = 4",
    ],
    # junctions and other areas
    "Junction": [
        "optional Id id = 1",
        "optional Polygon polygon = 2",
        "repeated Id overlap_id = 3",
        "optional Type type = 4",  # Apollo 7+
    ],
    "Crosswalk": ["optional Id id = 1", "optional Polygon polygon = 2", "repeated Id overlap_id = 3"],
    "ClearArea": ["optional Id id = 1", "repeated Id overlap_id = 2", "optional Polygon polygon = 3"],
    "SpeedBump": ["optional Id id = 1", "repeated Id overlap_id = 2", "repeated Curve position = 3"],
    "ParkingSpace": [
        "optional Id id = 1",
        "optional Polygon polygon = 2",
        "repeated Id overlap_id = 3",
        "optional double heading = 4",
    ],
    "ParkingLot": ["optional Id id = 1", "optional Polygon polygon = 2", "repeated Id overlap_id = 3"],
    "Passage": [
        "optional Id id = 1",
        "repeated Id signal_id = 2",
        "repeated Id yield_id = 3",
        "repeated Id stop_sign_id = 4",
        "repeated Id lane_id = 5",
        "optional Type type = 6",
    ],
    "PassageGroup": ["optional Id id = 1", "repeated Passage passage = 2"],
    "PNCJunction": [
        "optional Id id = 1",
        "optional Polygon polygon = 2",
        "repeated Id overlap_id = 3",
        "repeated PassageGroup passage_group = 4",
    ],
    "RSU": ["optional Id id = 1", "optional Id junction_id = 2", "repeated Id overlap_id = 3"],
    # traffic control
    "Subsignal": ["optional Id id = 1", "optional Type type = 2", "optional apollo.common.PointENU location = 3"],
    "SignInfo": ["optional Type type = 1"],
    "Signal": [
        "optional Id id = 1",
        "optional Polygon boundary = 2",
        "repeated Subsignal subsignal = 3",
        "repeated Id overlap_id = 4",
        "optional Type type = 5",
        "repeated Curve stop_line = 6",
        "repeated SignInfo sign_info = 7",
    ],
    "StopSign": [
        "optional Id id = 1",
        "repeated Curve stop_line = 2",
        "repeated Id overlap_id = 3",
        "optional StopType type = 4",
    ],
    "YieldSign": ["optional Id id = 1", "repeated Curve stop_line = 2", "repeated Id overlap_id = 3"],
    # overlaps
    "LaneOverlapInfo": [
        "optional double start_s = 1",
        "optional double end_s = 2",
        "optional bool is_merge = 3",
        "optional Id region_overlap_id = 4",
    ],
    "SignalOverlapInfo": [],
    "StopSignOverlapInfo": [],
    "CrosswalkOverlapInfo": ["optional Id region_overlap_id = 1"],
    "JunctionOverlapInfo": [],
    "YieldOverlapInfo": [],
    "ClearAreaOverlapInfo": [],
    "SpeedBumpOverlapInfo": [],
    "ParkingSpaceOverlapInfo": [],
    "PNCJunctionOverlapInfo": [],
    "RSUOverlapInfo": [],
    "RegionOverlapInfo": ["optional Id id = 1", "repeated Polygon polygon = 2"],
    "ObjectOverlapInfo": [
        "optional Id id = 1",
        "oneof:overlap_info LaneOverlapInfo lane_overlap_info = 3",
        "oneof:overlap_info SignalOverlapInfo signal_overlap_info = 4",
        "oneof:overlap_info StopSignOverlapInfo stop_sign_overlap_info = 5",
        "oneof:overlap_info CrosswalkOverlapInfo crosswalk_overlap_info = 6",
        "oneof:overlap_info JunctionOverlapInfo junction_overlap_info = 7",
        "oneof:overlap_info YieldOverlapInfo yield_sign_overlap_info = 8",
        "oneof:overlap_info ClearAreaOverlapInfo clear_area_overlap_info = 9",
        "oneof:overlap_info SpeedBumpOverlapInfo speed_bump_overlap_info = 10",
        "oneof:overlap_info ParkingSpaceOverlapInfo parking_space_overlap_info = 11",
        "oneof:overlap_info PNCJunctionOverlapInfo pnc_junction_overlap_info = 12",
        "oneof:overlap_info RSUOverlapInfo rsu_overlap_info = 13",
    ],
    "Overlap": [
        "optional Id id = 1",
        "repeated ObjectOverlapInfo object = 2",  # exactly two objects in practice
        "repeated RegionOverlapInfo region_overlap = 3",
    ],
    # the map
    "Projection": ["optional string proj = 1"],  # PROJ.4 string, e.g. +proj=utm +zone=10 ...
    "Header": [
        "optional bytes version = 1",
        "optional bytes date = 2",
        "optional Projection projection = 3",
        "optional bytes district = 4",
        "optional bytes generation = 5",
        "optional bytes rev_major = 6",
        "optional bytes rev_minor = 7",
        "optional double left = 8",
        "optional double top = 9",
        "optional double right = 10",
        "optional double bottom = 11",
        "optional bytes vendor = 12",
    ],
    "Map": [
        "optional Header header = 1",
        "repeated Crosswalk crosswalk = 2",
        "repeated Junction junction = 3",
        "repeated Lane lane = 4",
        "repeated StopSign stop_sign = 5",
        "repeated Signal signal = 6",
        "repeated YieldSign yield = 7",
        "repeated Overlap overlap = 8",
        "repeated ClearArea clear_area = 9",
        "repeated SpeedBump speed_bump = 10",
        "repeated Road road = 11",
        "repeated ParkingSpace parking_space = 12",
        "repeated PNCJunction pnc_junction = 13",
        "repeated RSU rsu = 14",
    ],
}

# --- apollo.routing (modules/routing/proto/topo_graph.proto): the routing_map file ---------
_ROUTING_ENUMS: dict[str, dict[str, int]] = {
    "Edge.DirectionType": {"FORWARD": 0, "LEFT": 1, "RIGHT": 2},
}
_ROUTING_MESSAGES: dict[str, list[str]] = {
    "CurvePoint": ["optional double s = 1"],
    "CurveRange": ["optional CurvePoint start = 1", "optional CurvePoint end = 2"],
    "Node": [
        "optional string lane_id = 1",
        "optional double length = 2",
        "repeated CurveRange left_out = 3",
        "repeated CurveRange right_out = 4",
        "optional double cost = 5",
        "optional apollo.hdmap.Curve central_curve = 6",
        "optional bool is_virtual = 7 [default=true]",
        "optional string road_id = 8",
    ],
    "Edge": [
        "optional string from_lane_id = 1",
        "optional string to_lane_id = 2",
        "optional double cost = 3",
        "optional DirectionType direction_type = 4",
    ],
    "Graph": [
        "optional string hdmap_version = 1",
        "optional string hdmap_district = 2",
        "repeated Node node = 3",
        "repeated Edge edge = 4",
    ],
}

_LABELS = {
    "optional": descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL,
    "repeated": descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED,
}


def _file(name: str, package: str, deps: list[str], messages: dict[str, list[str]],
          enums: dict[str, dict[str, int]]) -> descriptor_pb2.FileDescriptorProto:
    """One FileDescriptorProto (proto2) from a message table and its nested enums."""
    fdp = descriptor_pb2.FileDescriptorProto(name=name, package=package, syntax="proto2",
                                             dependency=deps)
    for msg_name, specs in messages.items():
        msg = fdp.message_type.add(name=msg_name)
        local_enums = {k.split(".", 1)[1]: v for k, v in enums.items() if k.split(".", 1)[0] == msg_name}
        for enum_name, values in local_enums.items():
            enum = msg.enum_type.add(name=enum_name)
            for value_name, value in values.items():
                enum.value.add(name=value_name, number=value)
        oneofs: list[str] = []
        for spec in specs:
            head, _, default = spec.partition("[default=")
            label, type_name, field_name, _eq, number = head.split()
            field = msg.field.add(name=field_name, number=int(number), json_name=field_name)
            if label.startswith("oneof:"):
                group = label.split(":", 1)[1]
                if group not in oneofs:
                    oneofs.append(group)
                    msg.oneof_decl.add(name=group)
                field.oneof_index = oneofs.index(group)
                field.label = _LABELS["optional"]
            else:
                field.label = _LABELS[label]
            if type_name in _SCALARS:
                field.type = _SCALARS[type_name]
            elif type_name in local_enums:
                field.type = descriptor_pb2.FieldDescriptorProto.TYPE_ENUM
                field.type_name = f".{package}.{msg_name}.{type_name}"
            elif "." in type_name:
                field.type = descriptor_pb2.FieldDescriptorProto.TYPE_MESSAGE
                field.type_name = "." + type_name
            else:
                if type_name not in messages:
                    raise AssertionError(f"apollo schema: unknown type {type_name} in {msg_name}")
                field.type = descriptor_pb2.FieldDescriptorProto.TYPE_MESSAGE
                field.type_name = f".{package}.{type_name}"
            if default:
                field.default_value = default.rstrip("]").strip()
    return fdp


def _build() -> dict[str, Any]:
    """Register the three files in a private pool and return the message classes by name."""
    pool = descriptor_pool.DescriptorPool()
    files = [
        _file("feat2map/apollo/common/geometry.proto", "apollo.common", [], _COMMON_MESSAGES, {}),
        _file("feat2map/apollo/hdmap/map.proto", "apollo.hdmap", ["feat2map/apollo/common/geometry.proto"],
              _HDMAP_MESSAGES, _HDMAP_ENUMS),
        _file("feat2map/apollo/routing/topo_graph.proto", "apollo.routing",
              ["feat2map/apollo/hdmap/map.proto"], _ROUTING_MESSAGES, _ROUTING_ENUMS),
    ]
    classes: dict[str, Any] = {}
    for fdp in files:
        pool.Add(fdp)
        for msg in fdp.message_type:
            classes[msg.name] = message_factory.GetMessageClass(
                pool.FindMessageTypeByName(f"{fdp.package}.{msg.name}"))
    return classes


_CLASSES = _build()
globals().update(_CLASSES)
MESSAGE_NAMES: tuple[str, ...] = tuple(_CLASSES)

# Static names for readers and type checkers (the same objects as in _CLASSES).
PointENU = _CLASSES["PointENU"]
Id = _CLASSES["Id"]
Polygon = _CLASSES["Polygon"]
LineSegment = _CLASSES["LineSegment"]
CurveSegment = _CLASSES["CurveSegment"]
Curve = _CLASSES["Curve"]
LaneBoundaryType = _CLASSES["LaneBoundaryType"]
LaneBoundary = _CLASSES["LaneBoundary"]
LaneSampleAssociation = _CLASSES["LaneSampleAssociation"]
Lane = _CLASSES["Lane"]
BoundaryEdge = _CLASSES["BoundaryEdge"]
BoundaryPolygon = _CLASSES["BoundaryPolygon"]
RoadBoundary = _CLASSES["RoadBoundary"]
RoadSection = _CLASSES["RoadSection"]
Road = _CLASSES["Road"]
Junction = _CLASSES["Junction"]
Crosswalk = _CLASSES["Crosswalk"]
ClearArea = _CLASSES["ClearArea"]
SpeedBump = _CLASSES["SpeedBump"]
ParkingSpace = _CLASSES["ParkingSpace"]
PNCJunction = _CLASSES["PNCJunction"]
RSU = _CLASSES["RSU"]
Subsignal = _CLASSES["Subsignal"]
SignInfo = _CLASSES["SignInfo"]
Signal = _CLASSES["Signal"]
StopSign = _CLASSES["StopSign"]
YieldSign = _CLASSES["YieldSign"]
LaneOverlapInfo = _CLASSES["LaneOverlapInfo"]
CrosswalkOverlapInfo = _CLASSES["CrosswalkOverlapInfo"]
RegionOverlapInfo = _CLASSES["RegionOverlapInfo"]
ObjectOverlapInfo = _CLASSES["ObjectOverlapInfo"]
Overlap = _CLASSES["Overlap"]
Projection = _CLASSES["Projection"]
Header = _CLASSES["Header"]
Map = _CLASSES["Map"]
CurvePoint = _CLASSES["CurvePoint"]
CurveRange = _CLASSES["CurveRange"]
Node = _CLASSES["Node"]
Edge = _CLASSES["Edge"]
Graph = _CLASSES["Graph"]

# Bytes that never occur in a protobuf text file (control characters other than whitespace).
_BINARY_BYTES = bytes(b for b in range(32) if b not in (9, 10, 11, 12, 13)) + b"\x7f"


def is_text(data: bytes) -> bool:
    """True when `data` looks like protobuf text format rather than the binary wire format."""
    head = data[:4096]
    if any(b in head for b in _BINARY_BYTES):
        return False
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:  # a multi-byte character cut at 4096 is still text
        return exc.start >= len(head) - 3
    return True


def text(value: str | bytes) -> str:
    """A protobuf string field as str: proto2 hands a value that is not UTF-8 (a damaged file's
    id) back as bytes, which no string field of a new message accepts; decoded with U+FFFD."""
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else value


# where protobuf's text parser quotes the offending token ("Couldn't parse float: <token>",
# "Expected string but found: <token>", "... has no value named <token>."): cut there
PROTOBUF_TOKEN = re.compile(r"(?:(?: but found)?:|, got| named)\s.*$", re.S)


def _parse(cls: Any, data: bytes, where: str, what: str) -> Message:
    if not data.strip():
        raise MapFormatError(f"empty file, expected an Apollo {what}", where)
    msg = cls()
    if is_text(data):
        try:
            text_format.Parse(data.decode("utf-8", errors="strict"), msg, allow_unknown_field=True)
        except text_format.ParseError as exc:  # its message quotes the offending line: not repeated
            reason = str(exc).rpartition("': ")[2] if "': " in str(exc) else "unexpected token"
            reason = PROTOBUF_TOKEN.sub("", reason) or "unexpected token"  # nor the offending token (file content)
            raise MapFormatError(f"broken Apollo {what} text (line {exc.GetLine()}, column {exc.GetColumn()}: "
                                 f"{reason})", where) from None
        except UnicodeDecodeError as exc:
            raise MapFormatError(f"broken Apollo {what} text: not UTF-8 (byte {exc.start})", where) from None
        except RecursionError:
            raise MapFormatError(f"broken Apollo {what} text: nested too deeply", where) from None
        return msg
    try:
        msg.ParseFromString(data)
    except (DecodeError, RuntimeError, ValueError) as exc:
        raise MapFormatError(f"corrupt or truncated Apollo {what} (binary protobuf): {exc}", where) from None
    return msg


def parse_map(data: bytes, where: str) -> Message:
    """Parse an Apollo `Map` from binary or text protobuf (detected from content).

    Unknown fields (newer Apollo versions, vendor extensions) are kept or skipped, never an
    error. Raises MapFormatError naming `where` for corrupt, truncated or random input.
    """
    msg = _parse(Map, data, where, "map")
    if not (msg.lane or msg.junction or msg.road or msg.HasField("header")):
        raise MapFormatError("not an Apollo map: no header, lanes, roads or junctions", where)
    return msg


def parse_graph(data: bytes, where: str) -> Message:
    """Parse an Apollo routing topology `Graph` (routing_map.bin/.txt)."""
    msg = _parse(Graph, data, where, "routing graph")
    if not (msg.node or msg.edge or msg.hdmap_version):
        raise MapFormatError("not an Apollo routing graph: no nodes or edges", where)
    return msg


def to_text(msg: Message) -> str:
    """Protobuf text format as Apollo's tools print it (for `.txt` maps)."""
    return text_format.MessageToString(msg)
