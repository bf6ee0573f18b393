"""The project's protobuf messages, for what no Foxglove schema fits: IMU, ego state, box
annotations, traffic lights and the cameras' exposure (package `drivee2e`).

They are declared here as descriptors rather than compiled from a .proto file, so no protoc step
is needed; every log embeds their FileDescriptorSet, so any protobuf reader decodes them without
this module (see `docs/logs.md`).
"""

from __future__ import annotations

from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2

FILE_NAME = "drivee2e/drivee2e.proto"
PACKAGE = "drivee2e"

_F = descriptor_pb2.FieldDescriptorProto
_SCALAR = {
    "double": _F.TYPE_DOUBLE,
    "float": _F.TYPE_FLOAT,
    "uint32": _F.TYPE_UINT32,
    "int64": _F.TYPE_INT64,
    "string": _F.TYPE_STRING,
    "bool": _F.TYPE_BOOL,
}

# message name -> fields as (name, type, repeated); a type that is not a scalar names a message
# (or enum) of this package, or google.protobuf.Timestamp
MESSAGES: dict[str, tuple[tuple[str, str, bool], ...]] = {
    "Imu": (
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("frame_id", "string", False),
        ("linear_acceleration_x", "double", False),  # m/s^2, vehicle frame, gravity included
        ("linear_acceleration_y", "double", False),
        ("linear_acceleration_z", "double", False),
        ("angular_velocity_x", "double", False),  # rad/s
        ("angular_velocity_y", "double", False),
        ("angular_velocity_z", "double", False),
    ),
    "EgoState": (
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("frame", "uint32", False),
        ("x", "double", False),  # rear-axle centre on the ground, world ENU metres
        ("y", "double", False),
        ("z", "double", False),
        ("yaw", "double", False),  # rad, counter-clockwise from east
        ("vx", "double", False),  # world frame, m/s
        ("vy", "double", False),
        ("speed", "double", False),  # m/s
        ("acceleration", "double", False),  # longitudinal, m/s^2
        ("yaw_rate", "double", False),  # rad/s
        ("steer", "double", False),  # front-wheel angle, rad, positive left
        ("throttle", "double", False),  # 0..1
        ("brake", "double", False),  # 0..1
        ("command", ".drivee2e.Command", False),
        ("length", "double", False),  # the ego's box, metres
        ("width", "double", False),
        ("height", "double", False),
        ("rear_axle_to_centre", "double", False),  # box centre ahead of the rear axle, metres
    ),
    "Object": (
        ("instance_id", "string", False),
        ("category", "string", False),  # one of the 8 agent classes
        ("blueprint", "string", False),
        ("length", "double", False),  # the blueprint's box, metres
        ("width", "double", False),
        ("height", "double", False),
        ("x", "double", False),  # box centre, world frame
        ("y", "double", False),
        ("z", "double", False),
        ("yaw", "double", False),
        ("vx", "double", False),  # world frame, m/s
        ("vy", "double", False),
        ("ego_x", "double", False),  # box centre, ego frame
        ("ego_y", "double", False),
        ("ego_z", "double", False),
        ("ego_yaw", "double", False),
        ("ego_vx", "double", False),  # velocity in the ego frame (not relative to the ego)
        ("ego_vy", "double", False),
        ("visibility", "uint32", False),  # nuScenes token: 0 unseen, 1: 0-40%, ..., 4: 80-100%
        ("visible_share", "float", False),  # best share of the projected box seen, any camera
        ("cameras", "string", True),  # cameras that see any of it
        ("num_lidar_points", "uint32", False),
        ("num_radar_points", "uint32", False),
    ),
    "ObjectAnnotations": (
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("frame", "uint32", False),
        ("objects", ".drivee2e.Object", True),
    ),
    "TrafficLight": (
        ("signal_id", "string", False),
        ("state", "string", False),  # SignalState name: RED, YELLOW, GREEN, ...
        ("controlled_lane_ids", "string", True),
    ),
    "TrafficLights": (
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("lights", ".drivee2e.TrafficLight", True),
        # the signal that binds the ego at this frame ('' for none: `binding.binding_signals`)
        ("ego_signal_id", "string", False),
    ),
    "CameraExposure": (
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("frame_id", "string", False),  # the camera
        # the gain on the drawn image's 8-bit values before the sensor's noise (1: as drawn)
        ("gain", "double", False),
        ("metered", "double", False),  # the mean grey (luma, 0-255) the camera's meter read
    ),
}
# high-level command, as nuScenes-trained planners read it (ego_fut_cmd: right, left, straight)
COMMANDS = ("COMMAND_UNKNOWN", "RIGHT", "LEFT", "STRAIGHT")


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    document = descriptor_pb2.FileDescriptorProto(
        name=FILE_NAME,
        package=PACKAGE,
        syntax="proto3",
        dependency=[timestamp_pb2.DESCRIPTOR.name],
    )
    command = document.enum_type.add(name="Command")
    for number, name in enumerate(COMMANDS):
        command.value.add(name=name, number=number)
    for message_name, fields in MESSAGES.items():
        message = document.message_type.add(name=message_name)
        for number, (name, kind, repeated) in enumerate(fields, start=1):
            field = message.field.add(
                name=name,
                number=number,
                label=_F.LABEL_REPEATED if repeated else _F.LABEL_OPTIONAL,
            )
            if kind in _SCALAR:
                field.type = _SCALAR[kind]
            else:
                field.type = _F.TYPE_ENUM if kind.endswith("Command") else _F.TYPE_MESSAGE
                field.type_name = kind
    return document


def _message_classes() -> dict[str, Any]:
    pool = descriptor_pool.Default()
    try:
        pool.FindFileByName(FILE_NAME)
    except KeyError:
        pool.Add(_file_descriptor())
    return {
        name: message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{PACKAGE}.{name}"))
        for name in MESSAGES
    }


_CLASSES = _message_classes()
Imu = _CLASSES["Imu"]
EgoState = _CLASSES["EgoState"]
Object = _CLASSES["Object"]
ObjectAnnotations = _CLASSES["ObjectAnnotations"]
TrafficLight = _CLASSES["TrafficLight"]
TrafficLights = _CLASSES["TrafficLights"]
CameraExposure = _CLASSES["CameraExposure"]
