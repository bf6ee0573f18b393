"""Radar returns from the agents in each radar's field of view and range.

Clutter-free by design: only agents return, one point each, on the face of their box nearest the
radar (no ground, buildings or multipath), and occlusion is not modelled. Each point carries its
radial velocity, compensated for the ego's motion (the target's own velocity along the line of
sight, as nuScenes' `vx_comp`/`vy_comp`), the raw radial velocity the moving radar would measure,
and a radar cross-section by class.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.scenario import AgentClass, Track
from drivee2e_data.sensors.rig import Radar

# radar cross-section (dBsm) per class, typical values for 77 GHz automotive radar
RCS_DBSM = {
    AgentClass.CAR: 10.0,
    AgentClass.VAN: 13.0,
    AgentClass.TRUCK: 20.0,
    AgentClass.BUS: 22.0,
    AgentClass.PEDESTRIAN: -8.0,
    AgentClass.CYCLIST: -3.0,
    AgentClass.TRICYCLIST: 0.0,
    AgentClass.MOTORCYCLIST: 2.0,
}


@dataclass(frozen=True)
class RadarReturns:
    points_m: NDArray[np.float64]  # (N, 3) in the radar frame
    radial_velocity_mps: NDArray[np.float64]  # (N,) ego-motion compensated; negative closing
    raw_radial_velocity_mps: NDArray[np.float64]  # (N,) as the moving radar measures it
    velocity_comp_mps: NDArray[
        np.float64
    ]  # (N, 2) compensated radial velocity as x, y (radar frame)
    rcs_dbsm: NDArray[np.float64]  # (N,)
    track_ids: tuple[str, ...]


def detect(
    radar: Radar,
    radar_to_world: NDArray[np.float64],
    ego_velocity_world_mps: NDArray[np.float64],
    tracks: list[Track],
    frame: int,
    ego_id: str | None = None,
) -> RadarReturns:
    """Returns of the agents valid at `frame` within the radar's range and field of view."""
    world_to_radar = np.linalg.inv(radar_to_world)
    origin = radar_to_world[:3, 3]
    rows = []
    for track in tracks:
        if track.track_id == ego_id or not track.valid[frame]:
            continue
        centre = np.array([track.x_m[frame], track.y_m[frame], track.z_m[frame]])
        line = centre - origin
        distance = float(np.linalg.norm(line[:2]))
        if distance < 1e-6:
            continue
        sight = line / np.linalg.norm(line)
        local = world_to_radar[:3, :3] @ sight
        azimuth = np.degrees(np.arctan2(local[1], local[0]))
        if abs(azimuth) > radar.horizontal_fov_deg / 2:
            continue
        # the box face nearest the radar, along the line of sight
        yaw = track.yaw_rad[frame]
        along = abs(sight[0] * np.cos(yaw) + sight[1] * np.sin(yaw))
        across = abs(-sight[0] * np.sin(yaw) + sight[1] * np.cos(yaw))
        half = np.array([0.5 * track.length_m[frame], 0.5 * track.width_m[frame]])
        depth = min(half[0] / max(along, 1e-6), half[1] / max(across, 1e-6))
        surface = centre - sight * depth
        if np.linalg.norm(surface - origin) > radar.range_m:
            continue
        velocity = np.array([track.vx_mps[frame], track.vy_mps[frame], 0.0])
        ego_velocity = np.array([*ego_velocity_world_mps[:2], 0.0])
        compensated = float(velocity @ sight)
        rows.append(
            (
                world_to_radar[:3, :3] @ (surface - origin),
                compensated,
                float((velocity - ego_velocity) @ sight),
                compensated * local[:2],
                RCS_DBSM[track.agent_class],
                track.track_id,
            )
        )
    if not rows:
        empty = np.zeros((0,))
        return RadarReturns(np.zeros((0, 3)), empty, empty, np.zeros((0, 2)), empty, ())
    points, radial, raw, comp, rcs, ids = zip(*rows, strict=True)
    return RadarReturns(
        np.array(points), np.array(radial), np.array(raw), np.array(comp), np.array(rcs), tuple(ids)
    )
