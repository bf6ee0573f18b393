"""An episode as an MCAP log Foxglove opens as is: the map once, then per 10 Hz step the ego's
pose (`/tf`), the scene (`/closedloop/scene`: agents as cubes, the ego in green, the driven path
in green beside the logged path in white) and the step's controls as entity metadata."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap_protobuf.writer import Writer
from numpy.typing import NDArray

from drivee2e_data.evaluate.episode import EpisodeResult, StepRecord
from drivee2e_data.geometry import quaternion_from_yaw
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.logs import messages, topics
from drivee2e_data.scenario import Scenario
from drivee2e_data.sensors.ego_state import se3
from drivee2e_data.sim.vehicle import Bicycle

SCENE_TOPIC = "/closedloop/scene"
EGO_COLOUR = Color(r=0.1, g=0.9, b=0.3, a=0.8)
LOGGED_COLOUR = Color(r=0.95, g=0.95, b=0.95, a=0.9)


def write_record(
    path: Path,
    scenario: Scenario,
    intersection_map: IntersectionMap,
    result: EpisodeResult,
    logged_xy_m: NDArray[np.float64],
    bicycle: Bicycle,
) -> None:
    """Write `result.trace` (the episode must keep its trace) to `path`, atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    t0 = int(scenario.t_ns[0])
    with open(partial, "wb") as stream:
        writer = Writer(stream)
        writer.write_message(topics.MAP, messages.map_scene(t0, intersection_map), t0, t0)
        driven: list[NDArray[np.float64]] = []
        for record in result.trace:
            t = t0 + record.step * 100_000_000
            driven.append(record.state.xy_m)
            ego_to_world = se3(record.state.x_m, record.state.y_m, 0.0, record.state.yaw_rad)
            writer.write_message(topics.TF, messages.frame_transforms(t, ego_to_world, {}), t, t)
            scene = _scene(t, record, np.array(driven), logged_xy_m, bicycle)
            writer.write_message(SCENE_TOPIC, scene, t, t)
        writer.finish()
    partial.replace(path)


def _scene(
    t_ns: int,
    record: StepRecord,
    driven_xy_m: NDArray[np.float64],
    logged_xy_m: NDArray[np.float64],
    bicycle: Bicycle,
) -> SceneUpdate:
    update = SceneUpdate()

    def entity(entity_id: str):  # type: ignore[no-untyped-def]
        item = update.entities.add(id=entity_id, frame_id=topics.WORLD_FRAME)
        item.timestamp.FromNanoseconds(t_ns)
        item.lifetime.FromNanoseconds(150_000_000)
        return item

    def cube(item, x: float, y: float, z: float, yaw: float, size, colour: Color) -> None:  # type: ignore[no-untyped-def]
        primitive = item.cubes.add()
        primitive.pose.position.x, primitive.pose.position.y, primitive.pose.position.z = x, y, z
        w, _, _, qz = quaternion_from_yaw(yaw)
        primitive.pose.orientation.w, primitive.pose.orientation.z = float(w), float(qz)
        primitive.size.x, primitive.size.y, primitive.size.z = (float(v) for v in size)
        primitive.color.CopyFrom(colour)

    for pose in record.agents:
        item = entity(pose.track_id)
        red, green, blue = (0.2, 0.6, 1.0)
        cube(item, pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad,
             (pose.length_m, pose.width_m, pose.height_m), Color(r=red, g=green, b=blue, a=0.45))  # fmt: skip
    ego = entity("ego")
    centre = bicycle.centre_xy_m(record.state)
    cube(ego, float(centre[0]), float(centre[1]), 0.75, record.state.yaw_rad,
         (bicycle.length_m, bicycle.width_m, 1.5), EGO_COLOUR)  # fmt: skip
    for key, value in (
        ("speed_mps", record.state.speed_mps),
        ("steer", record.control.steer),
        ("throttle", record.control.throttle),
        ("brake", record.control.brake),
    ):
        ego.metadata.add(key=key, value=f"{value:.3f}")
    for name, points, colour in (
        ("driven", driven_xy_m, EGO_COLOUR),
        ("logged", logged_xy_m, LOGGED_COLOUR),
    ):
        if len(points) < 2:
            continue
        line = entity(f"path/{name}").lines.add(
            type=LinePrimitive.LINE_STRIP, thickness=2.0, scale_invariant=True
        )
        line.pose.orientation.w = 1.0
        line.color.CopyFrom(colour)
        for x, y in points:
            line.points.add(x=float(x), y=float(y), z=0.05)
    return update
