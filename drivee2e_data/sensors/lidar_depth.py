"""The 64-channel LiDAR read from depth images: six narrow views around the LiDAR's origin, each
covering 60 degrees of azimuth and the beams' elevations, rendered with the body mask at about
the beam pattern's resolution; every beam takes the range the depth image holds along it.

The renderer does what ray casting does on the CPU, nearly for free on a GPU. For a plane,
inverse depth is affine in image coordinates, so a beam between pixel centres takes the bilinear
interpolation of the four neighbours' inverse depth when all four show the same surface (exact
on flat surfaces; the road and its markings count as one). Where they show different surfaces (a
silhouette, about 5% of the beams) and one of them is an agent, the beam is cast as a ray: a
nearest-pixel guess there moves a box's outline by up to half a pixel, and a box top lying along
a beam ring then gains or loses a whole row of points. Such a ray goes only a little beyond
the agent's pixels; one that hits nothing that far takes the surface the image shows behind the
agent (a ray on to the ground there cost Bullet about twice one that ends at the agent). At the
twin's own silhouettes (a tree before a wall, a kerb, about nine in ten of them) the beam takes
the surface that carries most of its bilinear weight, interpolated over that surface's pixels:
no box counts those points, and the side of the edge is then off by at most half a pixel (a
tenth of a degree, within a real beam's divergence). It sees what the cameras see: agents'
visual shapes, which are their collision shapes too (`sim/actors.py`), and paint, whose surface
class gives the intensity directly.
`sensors/lidar.py` (ray casting) stays the reference; `tests/test_lidar.py` checks they agree.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sensors.lidar import LidarSweep, beam_directions, cast, intensities, on_grid
from drivee2e_data.sensors.rig import Lidar
from drivee2e_data.sim.twin import PaintRaster

VIEWS = 6  # views around the LiDAR, each 360 / VIEWS degrees of azimuth wide
# pixels per azimuth step at the centre of a view (more towards its edges). One pixel a step
# reads the same ranges as 1.5 did (median difference to ray casting 0.02 cm, identical points
# per box, docs/benchmarks.md) from 2.25x fewer pixels: a sweep 268 -> 196 ms on llvmpipe
OVERSAMPLE = 1.0
# rows per column's worth of angle: the beams' rings lie 3.2 azimuth steps apart, and half as
# many rows read the same ranges (docs/benchmarks.md)
ROW_SCALE = 0.5
# a beam at an agent's edge is cast this far beyond its farthest agent pixel (times, plus
# metres): one pixel away along a side seen at 5 degrees, a car's surface lies 2 m deeper at 50 m
AGENT_REACH = 1.25
AGENT_REACH_M = 1.0
CAST_THROUGH = -2  # `_sample`'s body for a beam at agents' pixels alone
NEAR_M = 1.0  # nothing nearer is seen: the roof LiDAR clears its own car by more, and the
# 16-bit depth buffer steps r^2 / (near * 65535) at range r: 11 cm at 85 m (37 cm with 0.3 m)


@dataclass(frozen=True)
class _Geometry:
    """One view's image: focal lengths in pixels, size, the view axis's row offset (rows above
    it) and the frustum's edge tangents (left, right, bottom, top)."""

    focal_x: float
    focal_y: float
    width: int
    height: int
    rows_above: int
    frustum: tuple[float, float, float, float]


def _view_geometry(lidar: Lidar, oversample: float, row_scale: float) -> _Geometry:
    """One view with `oversample` pixels per azimuth step at its centre and `row_scale` rows per
    column's worth of angle, framed off-centre to span just the beams' elevations (a level
    view's beams rise at most `upper_deg` and fall at most `lower_deg`, steepest at its edges)."""
    half_width = math.pi / VIEWS
    focal_x = oversample / math.tan(math.radians(lidar.azimuth_step_deg))
    focal_y = row_scale * focal_x
    rise = math.tan(math.radians(max(lidar.upper_deg, 0.0))) / math.cos(half_width)
    fall = math.tan(math.radians(max(-lidar.lower_deg, 0.0))) / math.cos(half_width)
    half_columns = math.ceil(focal_x * math.tan(half_width)) + 1
    rows_above = math.ceil(focal_y * rise) + 1  # one pixel beyond the extreme beams each way
    rows_below = math.ceil(focal_y * fall) + 1
    frustum = (
        -half_columns / focal_x,
        half_columns / focal_x,
        -rows_below / focal_y,
        rows_above / focal_y,
    )
    return _Geometry(focal_x, focal_y, 2 * half_columns, rows_above + rows_below, rows_above,
                     frustum)  # fmt: skip


@dataclass(frozen=True)
class _Samples:
    """Where one view's beams fall in its image: the four pixels around each and their
    bilinear weights, fixed by the beam pattern (computed once per LiDAR geometry)."""

    beams: NDArray[np.intp]  # indices into the sweep's beams
    corners: NDArray[np.intp]  # (4, B) flat pixel indices of the four pixels around each beam
    weights: NDArray[np.float64]  # (4, B)
    nearest: NDArray[np.intp]  # (B,) which corner is nearest
    along: NDArray[np.float64]  # (B,) the beam's share of the view axis


@dataclass(frozen=True)
class _Layout:
    directions: NDArray[np.float64]  # (R, 3) LiDAR frame
    ring: NDArray[np.uint8]
    geometry: _Geometry
    views: tuple[_Samples, ...]


@functools.lru_cache(maxsize=4)
def _layout(
    channels: int,
    upper_deg: float,
    lower_deg: float,
    step_deg: float,
    oversample: float,
    row_scale: float,
) -> _Layout:
    lidar = Lidar("layout", np.eye(4), channels, 0.0, upper_deg, lower_deg, step_deg)
    directions, ring = beam_directions(lidar)
    geometry = _view_geometry(lidar, oversample, row_scale)
    width, height = geometry.width, geometry.height
    azimuth = np.arctan2(directions[:, 1], directions[:, 0])
    elevation = np.arcsin(np.clip(directions[:, 2], -1.0, 1.0))
    view_of = np.floor((azimuth + math.pi / VIEWS) / (2 * math.pi / VIEWS)).astype(int) % VIEWS
    views = []
    for view in range(VIEWS):
        beams = np.flatnonzero(view_of == view)
        relative = azimuth[beams] - view * 2 * math.pi / VIEWS
        relative = (relative + math.pi) % (2 * math.pi) - math.pi
        # image coordinates of each beam, pixel centres at integers; x right, row 0 at the top
        column = width / 2 - 0.5 - geometry.focal_x * np.tan(relative)
        row = (
            geometry.rows_above
            - 0.5
            - geometry.focal_y * np.tan(elevation[beams]) / np.cos(relative)
        )
        left = np.clip(np.floor(column).astype(np.intp), 0, width - 2)
        top = np.clip(np.floor(row).astype(np.intp), 0, height - 2)
        dx = np.clip(column - left, 0.0, 1.0)
        dy = np.clip(row - top, 0.0, 1.0)
        corners = np.stack([top * width + left, top * width + left + 1,
                            (top + 1) * width + left, (top + 1) * width + left + 1])  # fmt: skip
        weights = np.stack([(1 - dx) * (1 - dy), dx * (1 - dy), (1 - dx) * dy, dx * dy])
        along = np.cos(elevation[beams]) * np.cos(relative)
        views.append(_Samples(beams, corners, weights, np.argmax(weights, axis=0), along))
    return _Layout(directions, ring, geometry, tuple(views))


def depth_sweep(
    world,
    lidar: Lidar,
    sensor_to_world: NDArray[np.float64],
    paint: PaintRaster | None = None,
    oversample: float = OVERSAMPLE,
    row_scale: float = ROW_SCALE,
) -> LidarSweep:
    """One full sweep from the LiDAR at `sensor_to_world` (4x4), read from `world`'s renders;
    beams at an agent's silhouette (where neighbouring pixels show different surfaces, one of
    them an agent) are cast as rays instead, so agents' outlines fall exactly where ray casting
    puts them. `paint` gives road hits their markings' intensity, as in `lidar.sweep`;
    `oversample` sets the views' pixels per azimuth step and `row_scale` their rows per
    column's worth of angle."""
    layout = _layout(
        lidar.channels,
        lidar.upper_deg,
        lidar.lower_deg,
        lidar.azimuth_step_deg,
        oversample,
        row_scale,
    )
    geometry = layout.geometry
    directions = layout.directions
    origin = sensor_to_world[:3, 3]
    rotation = sensor_to_world[:3, :3]
    distance = np.full(len(directions), np.nan)
    body = np.full(len(directions), -1, np.int64)
    reach = np.full(len(directions), np.nan)  # how far to cast a beam at an agent's edge (m)
    surface = _surfaces(world)
    agent = _agents(world, len(surface))
    # all six views drawn before any is read: on a GPU they come back together, one wait a sweep
    drawn = []
    for view in range(len(layout.views)):
        centre_azimuth = view * 2 * math.pi / VIEWS
        forward = rotation @ np.array([math.cos(centre_azimuth), math.sin(centre_azimuth), 0.0])
        drawn.append(
            world.render_later(
                origin,
                origin + forward,
                geometry.width,
                geometry.height,
                0.0,
                far_m=lidar.range_m,
                segmentation=True,
                near_m=NEAR_M,
                up=rotation[:, 2],
                frustum=geometry.frustum,
                look="labels",
            )
        )
    for samples, pending in zip(layout.views, drawn, strict=True):
        image = pending()
        depth, hit_body, view_reach = _sample(
            image.depth_m, image.segmentation, samples, surface, agent
        )
        distance[samples.beams] = depth / samples.along
        body[samples.beams] = hit_body
        reach[samples.beams] = view_reach / samples.along
    world_directions = directions @ rotation.T
    rays = np.flatnonzero(np.isfinite(reach))
    length = np.minimum(reach[rays] * AGENT_REACH + AGENT_REACH_M, lidar.range_m)
    ray_body, ray_distance = cast(world.client, origin, world_directions[rays], length)
    struck = ray_body >= 0
    body[rays[struck]], distance[rays[struck]] = ray_body[struck], ray_distance[struck]
    through = np.flatnonzero(body == CAST_THROUGH)  # no surface behind: the whole ray
    body[through], distance[through] = cast(
        world.client, origin, world_directions[through], lidar.range_m
    )
    # rows taken by index (`np.take`): a boolean mask over (R, 3) rows costs numpy 2-3x more
    hit = np.flatnonzero((body >= 0) & (distance <= lidar.range_m))
    hit_body = body[hit].astype(np.int32)
    hit_distance = distance[hit, None]
    hit_xy = origin[:2] + np.take(world_directions, hit, axis=0)[:, :2] * hit_distance
    return LidarSweep(
        points_m=on_grid(np.take(directions, hit, axis=0) * hit_distance),
        intensity=intensities(world.twin.segmentation, hit_body, hit_xy, paint),
        ring=layout.ring[hit],
        body=hit_body,
    )


# the road and the markings on it lie within a centimetre of one plane: one surface, whose
# edges between paint and asphalt (a third of all edges) need no ray
ROAD_SURFACE_KINDS = ("road", "road_mark", "crosswalk", "stop_line")


def _surfaces(world) -> NDArray[np.int64]:
    """Surface id of each mask value `v` at index `v + 1`: the body itself (-1 for nothing),
    except that the road and its markings are one surface."""
    road = sorted(b for b, kind in world.twin.segmentation.items() if kind in ROAD_SURFACE_KINDS)
    largest = max([*world.bodies.values(), *world.twin.segmentation], default=0)
    surface = np.arange(-1, largest + 1, dtype=np.int64)
    if road:
        surface[np.asarray(road) + 1] = road[0]
    return surface


def _agents(world, size: int) -> NDArray[np.bool_]:
    """Whether each mask value `v` (at index `v + 1`, `size` of them) is an agent's body."""
    agent = np.zeros(size, dtype=bool)
    agent[np.asarray(list(world.bodies.values()), dtype=np.int64) + 1] = True
    return agent


def _sample(
    depth_m: NDArray[np.float32],
    mask: NDArray[np.int32],
    samples: _Samples,
    surface: NDArray[np.int64],
    agent: NDArray[np.bool_],
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """Depth and body along each beam, and how far to cast it (NaN: no ray). Where the four
    neighbouring pixels show one surface (`surface`, indexed by mask value + 1), inverse depth
    interpolated bilinearly and the nearest pixel's body. At an edge, the beam lies on the
    surface whose pixels carry most of its bilinear weight (at a straight edge: the side it
    falls on) and takes the interpolation over that surface's pixels alone.

    Where one of the four shows an agent (`agent`, indexed alike) the beam is to be cast, up to
    `AGENT_REACH` beyond the farthest of its agent pixels; the depth and body given for it are
    then those of the surface behind (the weightiest of its pixels that show no agent), which
    it takes if the ray hits nothing that far: a ray all the way through costs Bullet about
    twice as much (the ground far behind), for a background the image already shows. A beam
    with no weight on pixels without agents has NaN depth and body `CAST_THROUGH`: cast it
    all the way.
    """
    corner_bodies = np.take(mask, samples.corners)  # of the flattened image
    corner_bodies = np.where(corner_bodies >= 0, corner_bodies & ((1 << 24) - 1), -1)
    corner_depths = np.take(depth_m, samples.corners).astype(np.float64)
    corner_surfaces = np.take(surface, corner_bodies + 1)
    one_surface = (corner_surfaces == corner_surfaces[0]).all(axis=0)
    weights = samples.weights
    depth = 1.0 / (weights / corner_depths).sum(axis=0)
    body = corner_bodies[samples.nearest, np.arange(len(samples.beams))].astype(np.int64)
    reach = np.full(len(samples.beams), np.nan)
    edges = np.flatnonzero(~one_surface)
    if len(edges):
        surfaces, edge_weights = corner_surfaces[:, edges], weights[:, edges]
        at_agent = np.take(agent, corner_bodies[:, edges] + 1)  # (4, E)
        # the surface behind an agent's edge: agents' pixels carry no weight
        edge_weights = np.where(at_agent, 0.0, edge_weights)
        alike = surfaces[:, None, :] == surfaces[None, :, :]  # (4, 4, E)
        # each corner's surface's share of the weight; ties go to the nearer corner's
        share = (alike * edge_weights[None]).sum(axis=1) + 1e-6 * edge_weights
        winner = surfaces[np.argmax(share, axis=0), np.arange(len(edges))]
        on = np.where(surfaces == winner, edge_weights, 0.0)  # agents' pixels: 0 already
        behind = on.sum(axis=0)  # the weight on the surface taken (0: agents' pixels alone)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth[edges] = behind / (on / corner_depths[:, edges]).sum(axis=0)
        body[edges] = corner_bodies[np.argmax(on, axis=0), edges]
        cast = at_agent.any(axis=0)
        through = cast & (behind == 0)  # no weight on any surface behind
        depth[edges[through]] = np.nan
        body[edges[through]] = CAST_THROUGH
        agent_depths = np.where(at_agent, corner_depths[:, edges], 0.0)
        reach[edges[cast]] = agent_depths[:, cast].max(axis=0)
    return depth, body, reach
