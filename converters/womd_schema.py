"""The WOMD ``waymo.open_dataset.Scenario`` protobuf schema, declared by this project in code.

Built from the field numbers and wire types in ``docs/womd.md`` ("The Scenario message") (which match the
public ``scenario.proto`` / ``map.proto``) as a ``FileDescriptorProto`` in a private descriptor pool:
no TensorFlow, no ``waymo-open-dataset`` package, no generated ``_pb2`` files. proto2; entry/exit
lanes are packed. Fields this schema does not declare (camera/lidar fields 12, 13, anything newer)
are kept as unknown fields by the protobuf runtime and otherwise ignored.

Usage::

    from .womd_schema import Scenario
    msg = Scenario.FromString(record_bytes)
"""

from __future__ import annotations

from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

PACKAGE = "waymo.open_dataset"

_F = descriptor_pb2.FieldDescriptorProto
_OPT, _REP = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED
_TYPES = {"double": _F.TYPE_DOUBLE, "float": _F.TYPE_FLOAT, "int32": _F.TYPE_INT32,
          "int64": _F.TYPE_INT64, "bool": _F.TYPE_BOOL, "string": _F.TYPE_STRING}

# enum name -> [(value name, number)]; declared nested in the message named before the dot
_ENUMS: dict[str, list[tuple[str, int]]] = {
    "Track.ObjectType": [("TYPE_UNSET", 0), ("TYPE_VEHICLE", 1), ("TYPE_PEDESTRIAN", 2),
                         ("TYPE_CYCLIST", 3), ("TYPE_OTHER", 4)],
    "RequiredPrediction.DifficultyLevel": [("NONE", 0), ("LEVEL_1", 1), ("LEVEL_2", 2)],
    "TrafficSignalLaneState.State": [
        ("LANE_STATE_UNKNOWN", 0), ("LANE_STATE_ARROW_STOP", 1), ("LANE_STATE_ARROW_CAUTION", 2),
        ("LANE_STATE_ARROW_GO", 3), ("LANE_STATE_STOP", 4), ("LANE_STATE_CAUTION", 5),
        ("LANE_STATE_GO", 6), ("LANE_STATE_FLASHING_STOP", 7), ("LANE_STATE_FLASHING_CAUTION", 8)],
    "LaneCenter.LaneType": [("TYPE_UNDEFINED", 0), ("TYPE_FREEWAY", 1), ("TYPE_SURFACE_STREET", 2),
                            ("TYPE_BIKE_LANE", 3)],
    "RoadLine.RoadLineType": [
        ("TYPE_UNKNOWN", 0), ("TYPE_BROKEN_SINGLE_WHITE", 1), ("TYPE_SOLID_SINGLE_WHITE", 2),
        ("TYPE_SOLID_DOUBLE_WHITE", 3), ("TYPE_BROKEN_SINGLE_YELLOW", 4), ("TYPE_BROKEN_DOUBLE_YELLOW", 5),
        ("TYPE_SOLID_SINGLE_YELLOW", 6), ("TYPE_SOLID_DOUBLE_YELLOW", 7), ("TYPE_PASSING_DOUBLE_YELLOW", 8)],
    "RoadEdge.RoadEdgeType": [("TYPE_UNKNOWN", 0), ("TYPE_ROAD_EDGE_BOUNDARY", 1),
                              ("TYPE_ROAD_EDGE_MEDIAN", 2)],
}

# message -> [(field name, number, label, type, packed, oneof)]; type is a scalar name above, an
# enum key of _ENUMS prefixed with "enum:", or a message name.
_Field = tuple[str, int, int, str, bool, str | None]
_MESSAGES: dict[str, list[_Field]] = {
    "MapPoint": [("x", 1, _OPT, "double", False, None), ("y", 2, _OPT, "double", False, None),
                 ("z", 3, _OPT, "double", False, None)],
    "ObjectState": [
        ("center_x", 2, _OPT, "double", False, None), ("center_y", 3, _OPT, "double", False, None),
        ("center_z", 4, _OPT, "double", False, None), ("length", 5, _OPT, "float", False, None),
        ("width", 6, _OPT, "float", False, None), ("height", 7, _OPT, "float", False, None),
        ("heading", 8, _OPT, "float", False, None), ("velocity_x", 9, _OPT, "float", False, None),
        ("velocity_y", 10, _OPT, "float", False, None), ("valid", 11, _OPT, "bool", False, None)],
    "Track": [("id", 1, _OPT, "int32", False, None),
              ("object_type", 2, _OPT, "enum:Track.ObjectType", False, None),
              ("states", 3, _REP, "ObjectState", False, None)],
    "RequiredPrediction": [("track_index", 1, _OPT, "int32", False, None),
                           ("difficulty", 2, _OPT, "enum:RequiredPrediction.DifficultyLevel", False, None)],
    "TrafficSignalLaneState": [("lane", 1, _OPT, "int64", False, None),
                               ("state", 2, _OPT, "enum:TrafficSignalLaneState.State", False, None),
                               ("stop_point", 3, _OPT, "MapPoint", False, None)],
    "DynamicMapState": [("lane_states", 1, _REP, "TrafficSignalLaneState", False, None)],
    "BoundarySegment": [("lane_start_index", 1, _OPT, "int32", False, None),
                        ("lane_end_index", 2, _OPT, "int32", False, None),
                        ("boundary_feature_id", 3, _OPT, "int64", False, None),
                        ("boundary_type", 4, _OPT, "enum:RoadLine.RoadLineType", False, None)],
    "LaneNeighbor": [("feature_id", 1, _OPT, "int64", False, None),
                     ("self_start_index", 2, _OPT, "int32", False, None),
                     ("self_end_index", 3, _OPT, "int32", False, None),
                     ("neighbor_start_index", 4, _OPT, "int32", False, None),
                     ("neighbor_end_index", 5, _OPT, "int32", False, None),
                     ("boundaries", 6, _REP, "BoundarySegment", False, None)],
    "LaneCenter": [("speed_limit_mph", 1, _OPT, "double", False, None),
                   ("type", 2, _OPT, "enum:LaneCenter.LaneType", False, None),
                   ("interpolating", 3, _OPT, "bool", False, None),
                   ("polyline", 8, _REP, "MapPoint", False, None),
                   ("entry_lanes", 9, _REP, "int64", True, None),
                   ("exit_lanes", 10, _REP, "int64", True, None),
                   ("left_neighbors", 11, _REP, "LaneNeighbor", False, None),
                   ("right_neighbors", 12, _REP, "LaneNeighbor", False, None),
                   ("left_boundaries", 13, _REP, "BoundarySegment", False, None),
                   ("right_boundaries", 14, _REP, "BoundarySegment", False, None)],
    "RoadLine": [("type", 1, _OPT, "enum:RoadLine.RoadLineType", False, None),
                 ("polyline", 2, _REP, "MapPoint", False, None)],
    "RoadEdge": [("type", 1, _OPT, "enum:RoadEdge.RoadEdgeType", False, None),
                 ("polyline", 2, _REP, "MapPoint", False, None)],
    "StopSign": [("lane", 1, _REP, "int64", False, None), ("position", 2, _OPT, "MapPoint", False, None)],
    "Crosswalk": [("polygon", 1, _REP, "MapPoint", False, None)],
    "SpeedBump": [("polygon", 1, _REP, "MapPoint", False, None)],
    "Driveway": [("polygon", 1, _REP, "MapPoint", False, None)],
    "MapFeature": [("id", 1, _OPT, "int64", False, None),
                   ("lane", 3, _OPT, "LaneCenter", False, "feature_data"),
                   ("road_line", 4, _OPT, "RoadLine", False, "feature_data"),
                   ("road_edge", 5, _OPT, "RoadEdge", False, "feature_data"),
                   ("stop_sign", 7, _OPT, "StopSign", False, "feature_data"),
                   ("crosswalk", 8, _OPT, "Crosswalk", False, "feature_data"),
                   ("speed_bump", 9, _OPT, "SpeedBump", False, "feature_data"),
                   ("driveway", 10, _OPT, "Driveway", False, "feature_data")],
    "Scenario": [("timestamps_seconds", 1, _REP, "double", False, None),
                 ("tracks", 2, _REP, "Track", False, None),
                 ("objects_of_interest", 4, _REP, "int32", False, None),
                 ("scenario_id", 5, _OPT, "string", False, None),
                 ("sdc_track_index", 6, _OPT, "int32", False, None),
                 ("dynamic_map_states", 7, _REP, "DynamicMapState", False, None),
                 ("map_features", 8, _REP, "MapFeature", False, None),
                 ("current_time_index", 10, _OPT, "int32", False, None),
                 ("tracks_to_predict", 11, _REP, "RequiredPrediction", False, None)],
}


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    fd = descriptor_pb2.FileDescriptorProto(name="coster_sumo/womd_scenario.proto", package=PACKAGE,
                                            syntax="proto2")
    msgs: dict[str, descriptor_pb2.DescriptorProto] = {}
    for name, fields in _MESSAGES.items():
        m = fd.message_type.add(name=name)
        msgs[name] = m
        oneofs: dict[str, int] = {}
        for fname, number, label, ftype, packed, oneof in fields:
            f = m.field.add(name=fname, number=number, label=label)
            if ftype in _TYPES:
                f.type = _TYPES[ftype]
            elif ftype.startswith("enum:"):
                f.type = _F.TYPE_ENUM
                f.type_name = f".{PACKAGE}.{ftype[5:]}"
            else:
                f.type = _F.TYPE_MESSAGE
                f.type_name = f".{PACKAGE}.{ftype}"
            if packed:
                f.options.packed = True
            if oneof is not None:
                if oneof not in oneofs:
                    oneofs[oneof] = len(m.oneof_decl)
                    m.oneof_decl.add(name=oneof)
                f.oneof_index = oneofs[oneof]
    for key, values in _ENUMS.items():
        owner, enum_name = key.split(".")
        e = msgs[owner].enum_type.add(name=enum_name)
        for vname, number in values:
            e.value.add(name=vname, number=number)
    return fd


_POOL = descriptor_pool.DescriptorPool()
_FILE = _POOL.Add(_file_descriptor())


def message_class(name: str) -> Any:
    """The message class of ``waymo.open_dataset.<name>`` in this schema."""
    return message_factory.GetMessageClass(_POOL.FindMessageTypeByName(f"{PACKAGE}.{name}"))


Scenario: Any = message_class("Scenario")
MapFeature: Any = message_class("MapFeature")
Track: Any = message_class("Track")
