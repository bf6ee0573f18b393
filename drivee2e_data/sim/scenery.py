"""Scenery a twin adds where the map holds none: generated buildings, street-lamp sites along
the kerbs, and the ground-detail raster (wheel tracks along the lanes, a mottle of patches).
Pure functions of an `IntersectionMap`, deterministic (seeded by the map id)."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.hdmap import Building, IntersectionMap

BUILDING_SETBACK_M = 3.0  # generated buildings keep this far from road, crosswalks and sidewalks
BUILDING_REACH_M = 90.0  # ...and stand within this distance of the junction
# where that leaves room for fewer than this many, the reach grows step by step to the last
# (nuScenes' drivable area fills all but 1,187 m2 of the 90 m disc around scene-0061's junction:
# no building stood there, an open plain to the horizon; 21,195 m2 are free within 150 m)
MIN_GENERATED_BUILDINGS = 6
BUILDING_REACHES_M = (BUILDING_REACH_M, 135.0, 180.0)
BUILDING_GRID_M = 22.0  # one candidate building per grid cell
STREET_LAMP_SPACING_M = 30.0
STREET_LAMP_REACH_M = 110.0  # lamps stand within this of the junction's centre
WEAR_CELL_M = 0.2  # the ground-detail raster's cell (wheel tracks are 0.5 m wide)
GROUND_DETAIL_MARGIN_M = 40.0  # the raster reaches this far beyond the road (grass near it)
MOTTLE_SPACINGS_M = (6.0, 1.5)  # patches in asphalt and grass: two scales of value noise
WHEEL_TRACK_OFFSET_M = 0.85  # tracks run this far either side of a lane's centre line
WHEEL_TRACK_WIDTH_M = 0.5


@dataclass(frozen=True)
class WearRaster:
    """Ground detail per cell (cell (0, 0)'s corner at `origin_xy_m`, rows along y): channel
    0 how worn the road is (the wheel tracks along the lanes), channel 1 a mottle of patches for
    asphalt and grass; 0..255. A texel read replaces two value-noise evaluations a pixel in the
    shader (a tenth of a camera image on llvmpipe)."""

    origin_xy_m: tuple[float, float]
    cell_m: float
    values: NDArray[np.uint8]  # (rows, columns, 2)


def generated_buildings(intersection_map: IntersectionMap) -> list[Building]:
    """Buildings for a map that has none, placed deterministically (seeded by the map id) in the
    free space at least `BUILDING_SETBACK_M` from road, crosswalks and sidewalks, within
    `BUILDING_REACH_M` of the junction (farther, up to the last of `BUILDING_REACHES_M`, where
    fewer than `MIN_GENERATED_BUILDINGS` fit), each turned to the nearest lane; flagged
    `generated`."""
    return _generated(intersection_map, _built_up(intersection_map))


def _generated(intersection_map: IntersectionMap, built_up: shapely.Geometry) -> list[Building]:
    """`generated_buildings` given the map's `_built_up` area."""
    keep_out = built_up.buffer(BUILDING_SETBACK_M)
    buildings: list[Building] = []
    for reach_m in BUILDING_REACHES_M:
        buildings = _buildings_within(intersection_map, keep_out, reach_m)
        if len(buildings) >= MIN_GENERATED_BUILDINGS:
            break
    return buildings


def _built_up(intersection_map: IntersectionMap) -> shapely.Geometry:
    """Road, crosswalks and sidewalks: where no building stands."""
    return shapely.union_all(
        [intersection_map.drivable_union(), *(shapely.Polygon(c.polygon_m) for c in intersection_map.crosswalks),
         *(shapely.Polygon(a.polygon_m) for a in intersection_map.sidewalks)]
    )  # fmt: skip


def _buildings_within(
    intersection_map: IntersectionMap, keep_out: shapely.Geometry, reach_m: float
) -> list[Building]:
    """One candidate building per `BUILDING_GRID_M` cell within `reach_m` of the junction, kept
    where it clears `keep_out` and the buildings before it."""
    centre = junction_centre(intersection_map)
    rng = np.random.default_rng(zlib.crc32(intersection_map.map_id.encode()))
    placed: list[shapely.Polygon] = []
    buildings = []
    for x in np.arange(centre[0] - reach_m, centre[0] + reach_m, BUILDING_GRID_M):
        for y in np.arange(centre[1] - reach_m, centre[1] + reach_m, BUILDING_GRID_M):
            point = shapely.Point(x, y)
            if keep_out.contains(point) or point.distance(shapely.Point(centre)) > reach_m:
                continue
            heading = _heading_near(intersection_map, point)
            length, depth = rng.uniform(10, 20), rng.uniform(8, 16)
            corners = (
                np.array([[-length, -depth], [length, -depth], [length, depth], [-length, depth]])
                / 2
            )
            rotation = np.array(
                [[np.cos(heading), -np.sin(heading)], [np.sin(heading), np.cos(heading)]]
            )
            footprint = shapely.Polygon(corners @ rotation.T + [x, y])
            if footprint.intersects(keep_out) or any(footprint.intersects(p) for p in placed):
                continue
            placed.append(footprint)
            buildings.append(Building(f"generated_{len(buildings):03d}", np.asarray(footprint.exterior.coords)[:-1],
                                      float(rng.choice([6.0, 9.0, 15.0, 24.0, 40.0])), generated=True))  # fmt: skip
    return buildings


@dataclass(frozen=True)
class SceneryReport:
    """What a map's twin stands beside its roads: the map's own buildings or the generated ones
    (and the farthest of them from the junction), the street lamps, and the room the map
    leaves within `BUILDING_REACH_M` of the junction."""

    map_id: str
    map_buildings: int
    generated_buildings: int
    farthest_building_m: float
    street_lamps: int
    free_near_junction_m2: float

    def line(self) -> str:
        room = (
            f"{self.free_near_junction_m2:,.0f} m2 beside the roads within {BUILDING_REACH_M:g} m"
        )
        if self.map_buildings:
            built = f"{self.map_buildings} buildings from the map"
        elif self.generated_buildings:
            built = (f"{self.generated_buildings} buildings generated, the farthest "
                     f"{self.farthest_building_m:.0f} m from the junction")  # fmt: skip
        else:
            built = "no room for buildings (the map's roads and sidewalks cover it)"
        return f"{self.map_id}: {built}; {self.street_lamps} street lamps; {room}"


def scenery_report(intersection_map: IntersectionMap) -> SceneryReport:
    """The scenery a twin of this map gets (`SceneryReport`), without building the twin."""
    built_up = _built_up(intersection_map)
    centre = junction_centre(intersection_map)
    generated = [] if intersection_map.buildings else _generated(intersection_map, built_up)
    farthest = max(
        (
            shapely.Polygon(b.footprint_m).centroid.distance(shapely.Point(centre))
            for b in generated
        ),
        default=0.0,
    )
    return SceneryReport(
        intersection_map.map_id,
        len(intersection_map.buildings),
        len(generated),
        float(farthest),
        len(street_lamp_sites(intersection_map, intersection_map.drivable_union())),
        float(shapely.Point(centre).buffer(BUILDING_REACH_M).difference(built_up).area),
    )


def _heading_near(intersection_map: IntersectionMap, point: shapely.Point) -> float:
    nearest = min(
        intersection_map.lanes,
        key=lambda lane: shapely.LineString(lane.centerline_m[:, :2]).distance(point),
    )
    return nearest.heading_at(point.x, point.y, half_window_m=1.0)


def junction_centre(intersection_map: IntersectionMap) -> NDArray[np.float64]:
    """The junction's centre: the stop lines' mean, else the road's centroid."""
    stops = [s.line_m[:, :2] for s in intersection_map.stop_lines]
    if stops:
        return np.concatenate(stops).mean(axis=0)
    return np.asarray(intersection_map.drivable_union().centroid.coords[0])


def street_lamp_sites(
    intersection_map: IntersectionMap, road: shapely.Geometry
) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """(base (2,), unit vector towards the road (2,)) of each street lamp: every
    `STREET_LAMP_SPACING_M` along the road's edge, 0.5 m onto the sidewalk (or off the road),
    within `STREET_LAMP_REACH_M` of the junction and clear of crosswalks."""
    centre = shapely.Point(*junction_centre(intersection_map))
    crossings = shapely.union_all([shapely.Polygon(c.polygon_m).buffer(2.0)
                                   for c in intersection_map.crosswalks])  # fmt: skip
    sites = []
    for ring in shapely.get_parts(road.boundary):
        for distance in np.arange(0.5 * STREET_LAMP_SPACING_M, ring.length, STREET_LAMP_SPACING_M):
            point = ring.interpolate(distance)
            if point.distance(centre) > STREET_LAMP_REACH_M or crossings.contains(point):
                continue
            ahead = ring.interpolate(min(distance + 1.0, ring.length))
            behind = ring.interpolate(max(distance - 1.0, 0.0))
            tangent = np.array([ahead.x - behind.x, ahead.y - behind.y])
            if np.linalg.norm(tangent) < 1e-6:
                continue
            tangent /= np.linalg.norm(tangent)
            normal = np.array([-tangent[1], tangent[0]])
            probe = shapely.Point(point.x + 0.5 * normal[0], point.y + 0.5 * normal[1])
            towards_road = normal if road.contains(probe) else -normal
            sites.append((np.array([point.x, point.y]) - 0.5 * towards_road, towards_road))
    return sites


def wear_raster(intersection_map: IntersectionMap) -> WearRaster:
    """The ground detail: the wheel tracks (two softened bands along every lane,
    `WHEEL_TRACK_OFFSET_M` either side of its centre line) and a mottle of patches (value noise
    at `MOTTLE_SPACINGS_M`, seeded by the map id), rasterised at `WEAR_CELL_M` over the road and
    `GROUND_DETAIL_MARGIN_M` around it."""
    import cv2

    margin = GROUND_DETAIL_MARGIN_M
    x0, y0, x1, y1 = intersection_map.drivable_union().bounds
    origin = np.array([x0, y0]) - margin
    shape = (
        int(np.ceil((y1 - y0 + 2 * margin) / WEAR_CELL_M)),
        int(np.ceil((x1 - x0 + 2 * margin) / WEAR_CELL_M)),
    )
    values = np.zeros(shape, np.uint8)
    thickness = max(1, round(WHEEL_TRACK_WIDTH_M / WEAR_CELL_M))
    for lane in intersection_map.lanes:
        line = shapely.LineString(lane.centerline_m[:, :2])
        if line.length < 1.0:
            continue
        for offset in (-WHEEL_TRACK_OFFSET_M, WHEEL_TRACK_OFFSET_M):
            track = line.offset_curve(offset)
            for part in getattr(track, "geoms", [track]):
                if part.is_empty:
                    continue
                points = np.round((np.asarray(part.coords) - origin) / WEAR_CELL_M * 16).astype(
                    np.int32
                )
                cv2.polylines(values, [points], False, 200, thickness, cv2.LINE_AA, shift=4)
    values = cv2.GaussianBlur(values, (0, 0), 0.35 / WEAR_CELL_M)
    rng = np.random.default_rng(zlib.crc32(intersection_map.map_id.encode()))
    mottle = np.zeros(shape, np.float32)
    for weight, spacing in zip((0.65, 0.35), MOTTLE_SPACINGS_M, strict=True):
        grid = rng.random((int(shape[0] * WEAR_CELL_M / spacing) + 2,
                           int(shape[1] * WEAR_CELL_M / spacing) + 2)).astype(np.float32)  # fmt: skip
        mottle += weight * cv2.resize(grid, shape[::-1], interpolation=cv2.INTER_CUBIC)
    mottle = np.clip(mottle * 255, 0, 255).astype(np.uint8)
    return WearRaster(
        (float(origin[0]), float(origin[1])), WEAR_CELL_M, np.dstack([values, mottle])
    )


# Facades: storeys of 3.2 m (a common floor-to-floor height), one window bay every 3.4 m of
# wall, the ground floor without windows (shop fronts and doors read as wall at this size).
STOREY_M = 3.2
BAY_M = 3.4
WINDOW_SPAN_U = (0.22, 0.78)  # a window's share of its bay's width...
WINDOW_SPAN_V = (0.30, 0.82)  # ...and of its storey's height (sill to lintel)
PARAPET_M = 0.15  # the top storey's windows end at least this far below the roof...
MIN_WINDOW_M = 1.0  # ...and are left out if that leaves them shorter than this
# windows stand this far out from their wall: drawn first, they hide the wall behind them from
# the depth test (2 cm is 7 depth-buffer steps at 150 m with the cameras' 0.5 m near plane)
WINDOW_PROUD_M = 0.02
LIT_WINDOW_SHARE = 0.25  # of windows lit at night (a residential block in the evening)
# a lit window's warm light at three strengths (lamps and curtains differ)
LIT_WINDOW_RGBAS = ((0.95, 0.78, 0.45, 1.0), (0.76, 0.62, 0.36, 1.0), (0.57, 0.47, 0.27, 1.0))


@dataclass(frozen=True)
class FacadeWindows:
    """A building's windows as quads standing `WINDOW_PROUD_M` out from its walls: `(V, 3)`
    vertices, four a window, and `(3T,)` indices, two triangles a window (counter-clockwise
    seen from outside); `lit` `(W,)` the warm tone a window shows at night (an index into
    `LIT_WINDOW_RGBAS`), -1 for a window that stays dark."""

    vertices: NDArray[np.float64]
    indices: NDArray[np.int64]
    lit: NDArray[np.int64]

    def subset(self, windows: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Vertices and indices of the windows selected by a `(W,)` mask."""
        chosen = np.flatnonzero(windows)
        vertices = self.vertices.reshape(-1, 4, 3)[chosen].reshape(-1, 3)
        indices = (4 * np.arange(len(chosen))[:, None] + np.array([0, 1, 2, 0, 2, 3])).reshape(-1)
        return vertices, indices


def facade_windows(footprint_m: NDArray, height_m: float, seed: int) -> FacadeWindows:
    """The windows of a building extruded from `footprint_m` `(N, 2)` to `height_m`: on each
    wall, whole bays of `BAY_M` centred on the wall, a window in each bay of every storey above
    the ground floor (the top storey's shortened to stay under the roof); which are lit at night
    drawn from `seed`."""
    ring = np.asarray(shapely.Polygon(footprint_m).exterior.coords)[:-1, :2]
    if not shapely.Polygon(ring).exterior.is_ccw:
        ring = ring[::-1]
    rows = []  # (sill, lintel) of each storey's windows, m above the ground
    for storey in range(1, int(height_m // STOREY_M) + 1):
        sill = STOREY_M * (storey + WINDOW_SPAN_V[0])
        lintel = min(STOREY_M * (storey + WINDOW_SPAN_V[1]), height_m - PARAPET_M)
        if lintel - sill >= MIN_WINDOW_M:
            rows.append((sill, lintel))
    quads = []
    for start, end in zip(ring, np.roll(ring, -1, axis=0), strict=True):
        length = float(np.hypot(*(end - start)))
        bays = int(length // BAY_M)
        if bays == 0 or not rows:
            continue
        along = (end - start) / length
        outward = np.array([along[1], -along[0]])  # a counter-clockwise ring's right side
        margin = 0.5 * (length - bays * BAY_M)
        u = margin + BAY_M * (np.arange(bays)[:, None] + np.array(WINDOW_SPAN_U))  # (bays, 2)
        for bottom, top in rows:
            left = start + u[:, :1] * along + WINDOW_PROUD_M * outward  # (bays, 2)
            right = start + u[:, 1:] * along + WINDOW_PROUD_M * outward
            corners = np.stack([np.column_stack([left, np.full(bays, bottom)]),
                                np.column_stack([right, np.full(bays, bottom)]),
                                np.column_stack([right, np.full(bays, top)]),
                                np.column_stack([left, np.full(bays, top)])], axis=1)  # fmt: skip
            quads.append(corners)
    if not quads:
        empty = np.zeros(0, np.int64)
        return FacadeWindows(np.zeros((0, 3)), empty, empty)
    vertices = np.concatenate(quads).reshape(-1, 3)
    count = len(vertices) // 4
    indices = (4 * np.arange(count)[:, None] + np.array([0, 1, 2, 0, 2, 3])).reshape(-1)
    rng = np.random.default_rng(seed)
    lit = np.where(rng.random(count) < LIT_WINDOW_SHARE,
                   rng.integers(0, len(LIT_WINDOW_RGBAS), count), -1)  # fmt: skip
    return FacadeWindows(vertices, indices, lit)
