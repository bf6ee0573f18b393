"""The 64-channel LiDAR by batched ray casting against the world's collision geometry.

One full sweep per frame: every beam of `Lidar.elevations_rad` at every azimuth step. Points are
in the LiDAR frame (x forward, y left, z up); intensity comes from the surface class of what a
ray hits (paint reflects more than asphalt); `ring` is the beam index, 0 the highest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sensors.rig import Lidar
from drivee2e_data.sim.twin import PaintRaster

MAX_RAYS_PER_BATCH = 16_000  # pybullet's rayTestBatch takes at most 16,383 rays per call
# reflectivity per surface class (0..1); anything else is an agent
INTENSITY = {
    "road": 0.12,
    "ground": 0.08,
    "sidewalk": 0.2,
    "road_mark": 0.75,
    "crosswalk": 0.6,
    "stop_line": 0.75,
    "building": 0.3,
    "vegetation": 0.1,
    "signal": 0.45,
    "pole": 0.45,
    "obstacle": 0.6,
}
AGENT_INTENSITY = 0.5
# points are given on a grid of 1/1024 m (under a millimetre) in the LiDAR frame, as a real
# LiDAR gives its ranges in steps of 1 to 4 mm: a float32 at full precision holds digits below
# any sensor's, which the log's compression cannot pack (a sweep's chunk to 0.44 of its size; on
# the grid 0.30, in two thirds of the time: docs/benchmarks.md, "twenty-fourth session")
POINTS_PER_M = 1024


@dataclass(frozen=True)
class LidarSweep:
    points_m: NDArray[np.float32]  # (N, 3) in the LiDAR frame, on its grid (`on_grid`)
    intensity: NDArray[np.float32]  # (N,) 0..1
    ring: NDArray[np.uint8]  # (N,) beam index, 0 the highest
    body: NDArray[np.int32]  # (N,) pybullet body hit (to count points per box)


def on_grid(points_m: NDArray[np.float64]) -> NDArray[np.float32]:
    """`(N, 3)` points rounded to the nearest multiple of 1 / `POINTS_PER_M` metres, as float32
    (exact: such multiples within 16 km fit float32's 24-bit mantissa)."""
    scaled = points_m * float(POINTS_PER_M)
    np.rint(scaled, out=scaled)
    grid = scaled.astype(np.float32)
    grid *= np.float32(1.0 / POINTS_PER_M)  # a power of two: exact
    return grid


def beam_directions(lidar: Lidar) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """Unit directions `(R, 3)` in the LiDAR frame, ring by ring, and each ray's ring."""
    elevation, azimuth = np.meshgrid(lidar.elevations_rad, lidar.azimuths_rad, indexing="ij")
    directions = np.stack(
        [
            np.cos(elevation) * np.cos(azimuth),
            np.cos(elevation) * np.sin(azimuth),
            np.sin(elevation),
        ],
        -1,
    ).reshape(-1, 3)
    ring = np.repeat(np.arange(lidar.channels, dtype=np.uint8), len(lidar.azimuths_rad))
    return directions, ring


def ranges_per_beam(result: LidarSweep, lidar: Lidar) -> NDArray[np.float64]:
    """`(channels * azimuth steps,)` range of each beam of a sweep, ring by ring (NaN where it
    returned nothing), to compare two sweeps beam by beam."""
    steps = len(lidar.azimuths_rad)
    unit = result.points_m / np.linalg.norm(result.points_m, axis=1, keepdims=True)
    azimuth = np.degrees(np.arctan2(unit[:, 1], unit[:, 0])) % 360.0
    step = np.round(azimuth / lidar.azimuth_step_deg).astype(int) % steps
    ranges = np.full(lidar.channels * steps, np.nan)
    ranges[result.ring.astype(int) * steps + step] = np.linalg.norm(result.points_m, axis=1)
    return ranges


def sweep(
    client: int,
    lidar: Lidar,
    sensor_to_world: NDArray[np.float64],
    kinds: dict[int, str],
    paint: PaintRaster | None = None,
) -> LidarSweep:
    """Cast one full sweep from the LiDAR at `sensor_to_world` (4x4). `kinds` names static
    bodies (anything else is an agent); `paint` says where road hits land on markings, which
    rays pass through as drawn-only bodies."""
    directions, ring = beam_directions(lidar)
    origin = sensor_to_world[:3, 3]
    world_directions = directions @ sensor_to_world[:3, :3].T
    body, distance = cast(client, origin, world_directions, lidar.range_m)
    hit = body >= 0
    body, distance = body[hit], distance[hit]
    hit_xy = origin[:2] + world_directions[hit, :2] * distance[:, None]
    return LidarSweep(
        points_m=on_grid(directions[hit] * distance[:, None]),
        intensity=intensities(kinds, body, hit_xy, paint),
        ring=ring[hit],
        body=body,
    )


def cast(
    client: int,
    origin: NDArray[np.float64],
    world_directions: NDArray[np.float64],
    range_m: float | NDArray[np.float64],
) -> tuple[NDArray[np.int32], NDArray[np.float64]]:
    """Body hit (-1 for none) and range (m) of rays from `origin` along `world_directions`
    `(N, 3)`, up to `range_m` (one for all, or `(N,)`: each ray's own)."""
    import pybullet

    range_m = np.asarray(range_m, dtype=np.float64)
    ends = origin + range_m[..., None] * world_directions
    # numpy arrays go in as they are: converting 115,200 rays to lists costs a fifth of a sweep
    starts = np.repeat(origin[None], min(MAX_RAYS_PER_BATCH, len(world_directions)), axis=0)
    hits = []
    for start in range(0, len(world_directions), MAX_RAYS_PER_BATCH):
        stop = min(start + MAX_RAYS_PER_BATCH, len(world_directions))
        hits.extend(
            pybullet.rayTestBatch(starts[: stop - start], ends[start:stop], physicsClientId=client)
        )
    body = np.fromiter((h[0] for h in hits), np.int32, len(hits))
    fraction = np.fromiter((h[2] for h in hits), np.float64, len(hits))
    return body, np.where(body >= 0, fraction * range_m, np.nan)


def intensities(
    kinds: dict[int, str],
    body: NDArray[np.int32],
    hit_xy_m: NDArray[np.float64],
    paint: PaintRaster | None,
) -> NDArray[np.float32]:
    """Reflectivity of each hit: by the surface class of the body, and, for road hits, of the
    marking the paint raster shows at `hit_xy_m` `(N, 2)` (world frame), if any."""
    intensity = intensity_table(kinds, int(body.max(initial=0)))[body]
    if paint is not None:
        road = np.flatnonzero(np.isin(body, [b for b, kind in kinds.items() if kind == "road"]))
        codes = paint.kind_codes(np.take(hit_xy_m, road, axis=0))
        painted = road[codes > 0]
        marks = np.array([INTENSITY[kind] for kind in paint.kinds], np.float32)
        intensity[painted] = marks[codes[codes > 0] - 1]
    return intensity


def intensity_table(kinds: dict[int, str], largest_body: int) -> NDArray[np.float32]:
    """Reflectivity indexed by body id: by surface kind for the twin's bodies, else an agent's."""
    table = np.full(max(largest_body, *kinds, 0) + 1, AGENT_INTENSITY, np.float32)
    for body, kind in kinds.items():
        table[body] = INTENSITY.get(kind, AGENT_INTENSITY)
    return table
