"""How faithfully a twin reproduces its map, measured as the paper does: per map element, the IoU
between the element as drawn in a top-down render of the twin (segmentation mask; a narrow
camera 3 km up, orthographic to within a centimetre)
and the element's polygon in the map, rasterised on the same pixel grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.sim.twin_plan import paint_geometry, stop_line_band
from drivee2e_data.sim.world import World

ELEMENTS = ("lanes", "crosswalks", "stop_lines", "road_marks")
THIN_ELEMENTS = ("stop_lines", "road_marks")
FINE_RESOLUTION_M = 0.004  # 4 mm pixels for thin elements: a 0.15 m line is 37 pixels wide
# which twin body kinds count as each element when seen from above
DRAWN_AS = {
    "lanes": {"road", "road_mark", "crosswalk", "stop_line"},
    "crosswalks": {"crosswalk"},
    "stop_lines": {"stop_line"},
    "road_marks": {"road_mark"},
}


@dataclass(frozen=True)
class Grid:
    """A square pixel grid over the world: `size` pixels of `resolution_m`, centred on `centre`."""

    centre: NDArray[np.float64]
    size: int
    resolution_m: float

    @property
    def half_m(self) -> float:
        return 0.5 * self.size * self.resolution_m


def render_kinds(world: World, grid: Grid) -> NDArray[np.object_]:
    """(size, size) element kind of the topmost twin body per pixel ('' where none); row 0 is north."""
    # A camera far above with a narrow field of view sees the flat map almost orthographically:
    # at 3 km, a point 1 m above the road at the edge of a 60 m view shifts by 1 cm.
    p, client = world.p, world.client
    altitude = 3000.0
    eye = [float(grid.centre[0]), float(grid.centre[1]), altitude]
    view = p.computeViewMatrix(eye, [eye[0], eye[1], 0.0], [0, 1, 0], physicsClientId=client)
    fov = float(np.degrees(2 * np.arctan(grid.half_m / altitude)))
    projection = p.computeProjectionMatrixFOV(
        fov, 1.0, altitude - 100.0, altitude + 100.0, physicsClientId=client
    )
    image = world.draw(view, projection, grid.size, grid.size, True, altitude - 100.0,
                       altitude + 100.0, look="labels")  # fmt: skip
    body = image.segmentation.astype(np.int64) & ((1 << 24) - 1)
    lookup = np.vectorize(lambda b: world.twin.segmentation.get(int(b), ""), otypes=[object])
    return lookup(body)


def rasterise(geometry: shapely.Geometry, grid: Grid) -> NDArray[np.bool_]:
    """Pixels whose centres fall inside `geometry`, on the render's grid (row 0 north)."""
    offsets = (np.arange(grid.size) + 0.5) * grid.resolution_m - grid.half_m
    x = grid.centre[0] + offsets[None, :]
    y = grid.centre[1] - offsets[:, None]
    xx, yy = np.broadcast_arrays(x, y)
    return shapely.contains_xy(shapely.make_valid(geometry), xx, yy)


def truth(intersection_map: IntersectionMap) -> dict[str, shapely.Geometry]:
    """Each element's polygons in the map (marks: their painted area on the road, less the stop
    lines and crosswalks painted over them)."""
    stop_lines = shapely.union_all([stop_line_band(s.line_m) for s in intersection_map.stop_lines])
    crosswalks = shapely.union_all(
        [shapely.Polygon(c.polygon_m) for c in intersection_map.crosswalks]
    )
    marks = shapely.union_all([
        paint_geometry(boundary, mark)
        for lane in intersection_map.lanes if not lane.is_intersection
        for boundary, mark in ((lane.left_boundary_m, lane.left_mark), (lane.right_boundary_m, lane.right_mark))
    ])  # fmt: skip
    return {
        "lanes": intersection_map.drivable_union(),
        "crosswalks": crosswalks,
        "stop_lines": stop_lines,
        "road_marks": marks.intersection(intersection_map.drivable_union())
        .difference(stop_lines)
        .difference(crosswalks),
    }


def element_iou(
    world: World,
    intersection_map: IntersectionMap,
    grid: Grid,
    fine_resolution_m: float = FINE_RESOLUTION_M,
    tile_px: int = 2000,
) -> dict[str, float]:
    """IoU per element over the grid (NaN where the map has none of that element). Thin elements
    (stop lines, road marks) are measured in tiles of `fine_resolution_m` pixels, so the
    renderer's edge pixels do not dominate a line a few pixels wide."""
    geometries = truth(intersection_map)
    kinds = render_kinds(world, grid)
    result = {}
    for element, geometry in geometries.items():
        if element in THIN_ELEMENTS:
            continue
        expected = rasterise(geometry, grid)
        drawn = np.isin(kinds, list(DRAWN_AS[element]))
        union = (expected | drawn).sum()
        result[element] = (
            float((expected & drawn).sum() / union) if expected.any() else float("nan")
        )
    tile_m = tile_px * fine_resolution_m
    starts = np.arange(-grid.half_m, grid.half_m, tile_m) + 0.5 * tile_m
    window = shapely.box(*(grid.centre - grid.half_m), *(grid.centre + grid.half_m))
    for element in THIN_ELEMENTS:
        geometry = geometries[element].intersection(window)
        if geometry.is_empty:
            result[element] = float("nan")
            continue
        shapely.prepare(geometry)
        both = union = 0
        for dx in starts:
            for dy in starts:
                tile = Grid(grid.centre + np.array([dx, dy]), tile_px, fine_resolution_m)
                box = shapely.box(*(tile.centre - tile.half_m), *(tile.centre + tile.half_m))
                if not geometry.intersects(box.buffer(1.0)):
                    continue  # nothing of the element here, nor drawn near it
                inside = _inside_window(tile, grid)
                expected = rasterise(geometry, tile) & inside
                drawn = np.isin(render_kinds(world, tile), list(DRAWN_AS[element])) & inside
                both += int((expected & drawn).sum())
                union += int((expected | drawn).sum())
        result[element] = both / union if union else float("nan")
    return {element: result[element] for element in ELEMENTS}


def _inside_window(tile: Grid, window: Grid) -> NDArray[np.bool_]:
    """Pixels of `tile` whose centres lie inside `window`'s square."""
    offsets = (np.arange(tile.size) + 0.5) * tile.resolution_m - tile.half_m
    x = tile.centre[0] + offsets[None, :]
    y = tile.centre[1] - offsets[:, None]
    low, high = window.centre - window.half_m, window.centre + window.half_m
    return (x >= low[0]) & (x < high[0]) & (y >= low[1]) & (y < high[1])
