"""A map's digital twin as data: what `twin.build_twin` makes into pybullet bodies, planned by
a pure function of the `IntersectionMap` (shapely and numpy; no pybullet, no GL).

Flat surfaces are triangulated meshes lifted a few millimetres apart so that road, markings,
crosswalks and stop lines never fight for depth: road at 0, sidewalks raised to their kerb
height, paint 5 mm above the road. Buildings are extruded footprints in varied facade colours,
trees a trunk and a crown of clustered spheres, street lamps stand along the sidewalks, signals
a pole (with a mast arm where the head hangs over the road) with one head of three lamps. Static
elements are merged into one body per kind, colour and material, each with the `Material` the
GL renderer's shaders read; `scenery.wear_raster` gives the darker wheel tracks along the lanes.
Planning is most of a twin's set-up (0.4-0.5 of 0.6 s on 2 cores), and a plan is the same for
every clip of its map, so a collection keeps plans for reuse (`sim.reuse`).
"""

from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass, field

import numpy as np
import shapely
import shapely.ops
from numpy.typing import NDArray

from drivee2e_data.hdmap import Building, IntersectionMap, LaneMark, MarkColour, MarkPattern
from drivee2e_data.scenario import SignalState
from drivee2e_data.sim.models.mesh import Material, box_mesh
from drivee2e_data.sim.obj_text import obj_text
from drivee2e_data.sim.obstacles import obstacle_parts
from drivee2e_data.sim.scenery import (
    LIT_WINDOW_RGBAS,
    WearRaster,
    facade_windows,
    generated_buildings,
    street_lamp_sites,
    wear_raster,
)

PAINT_Z_M = 0.005  # markings sit this far above the road
ROAD_RGBA = (0.28, 0.28, 0.3, 1.0)
CROSSWALK_RGBA = (0.36, 0.36, 0.38, 1.0)
SIDEWALK_RGBA = (0.62, 0.6, 0.56, 1.0)
WHITE_RGBA = (0.92, 0.92, 0.9, 1.0)
YELLOW_RGBA = (0.95, 0.75, 0.1, 1.0)
GROUND_RGBA = (0.42, 0.5, 0.32, 1.0)
TRUNK_RGBA = (0.4, 0.28, 0.15, 1.0)
TRUNK_SIDES = 8
PAINT_KINDS = ("road_mark", "crosswalk", "stop_line")
GROUND_MARGIN_M = 150.0  # the ground reaches this far beyond the road's bounding box
# ...and this far in under the road's and the sidewalks' edges, so that no view low over the
# grass sees past an edge into a gap (10 cm of drop over 2 m: a ray under 3 degrees)
GROUND_UNDER_M = 2.0
LAMP_OFF_RGBA = (0.12, 0.12, 0.12, 1.0)
LAMP_RADIUS_M = 0.12  # a signal lamp's lens, 24 cm across (a common size is 20 or 30 cm)
LINE_WIDTH_M = 0.15
STOP_LINE_WIDTH_M = 0.4
DASH_M, GAP_M = 3.0, 6.0
ZEBRA_STRIPE_M = 0.5
# facades: renders, brick, concrete and stone, muted as city blocks are
FACADE_RGBAS = ((0.72, 0.68, 0.60, 1.0), (0.60, 0.42, 0.34, 1.0), (0.58, 0.58, 0.60, 1.0),
                (0.78, 0.74, 0.66, 1.0), (0.45, 0.47, 0.52, 1.0), (0.66, 0.56, 0.44, 1.0))  # fmt: skip
WINDOW_RGBA = (0.12, 0.14, 0.17, 1.0)  # dark glass (a lit window by day looks the same)
CROWN_RGBAS = ((0.20, 0.42, 0.16, 1.0), (0.26, 0.46, 0.18, 1.0), (0.16, 0.36, 0.17, 1.0))
CROWN_CLUSTERS = 3  # spheres per crown, each 72 triangles: the old crown's 192 in all
# each crown's spheres twice, (rings, segments): 72 triangles near the camera, 36 beyond
# `gl_batches.FOLIAGE_DETAIL_M` for the GL renderer alone (crowns were the most triangles any
# view drew, and llvmpipe pays for each small triangle's partly covered pixel blocks)
CROWN_SPHERES = ((5, 8), (4, 6))
STREET_LAMP_HEIGHT_M = 8.0
STREET_LAMP_ARM_M = 1.6
POLE_RGBA = (0.32, 0.33, 0.34, 1.0)
STREET_LAMP_RGBA = (1.0, 0.86, 0.62, 1.0)  # the lamp's face, shining at night
MAST_ARM_OVER_ROAD_M = 1.0  # a head this far inside the road hangs from a mast arm
KIND_MATERIAL = {"ground": Material.GRASS, "road": Material.ASPHALT,
                 "sidewalk": Material.PAVEMENT, "road_mark": Material.MARKING,
                 "stop_line": Material.MARKING, "building": Material.FACADE}  # fmt: skip


def triangulate(polygon: shapely.Geometry) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """Vertices `(V, 2)` and triangle indices `(3T,)` covering a (possibly concave) polygon."""
    triangles = shapely.constrained_delaunay_triangles(shapely.make_valid(polygon))
    vertices, indices = [], []
    for triangle in getattr(triangles, "geoms", [triangles]):
        if triangle.is_empty:
            continue
        corners = np.asarray(triangle.exterior.coords)[:3]
        if _signed_area(corners) < 0:
            corners = corners[::-1]
        indices.extend(range(len(vertices), len(vertices) + 3))
        vertices.extend(corners.tolist())
    return np.asarray(vertices, dtype=np.float64).reshape(-1, 2), np.asarray(
        indices, dtype=np.int32
    )


def _signed_area(corners: NDArray) -> float:
    (x0, y0), (x1, y1), (x2, y2) = corners
    return 0.5 * ((x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0))


@dataclass(frozen=True)
class TwinMesh:
    """One body's triangles for the GL renderer: `(V, 3)` vertices, `(3T,)` indices, per-vertex
    normals `(V, 3)` or None (flat), its colour and material."""

    body: int
    kind: str
    rgba: tuple[float, float, float, float]
    material: Material
    vertices: NDArray[np.float64]
    indices: NDArray[np.int64]
    normals: NDArray[np.float64] | None
    # `(T, 2)` where each triangle belongs on the ground (NaN: its own centroid): a tree's
    # triangles all at its trunk, so that the renderer's cells never split a tree
    anchors_xy: NDArray[np.float64] | None = None


@dataclass
class _Batch:
    """Triangles of one kind and colour, drawn as one body: pybullet's renderer pays a fixed
    cost per body each time it draws (a 16x16 render of the benchmark clip took 6.3 ms with its
    450 bodies on llvmpipe, 2.7 ms with 93 left), so the twin's static elements are merged by
    kind and colour."""

    vertices: list[NDArray[np.float64]] = field(default_factory=list)  # (V, 3) each
    indices: list[NDArray[np.int64]] = field(default_factory=list)  # (3T,) each
    normals: list[NDArray[np.float64] | None] = field(default_factory=list)  # (V, 3) or None
    anchors: list[NDArray[np.float64]] = field(default_factory=list)  # (T, 2) each
    count: int = 0

    def add(
        self,
        vertices: NDArray,
        indices: NDArray,
        normals: NDArray[np.float64] | None,
        anchor_xy: NDArray | None = None,
    ) -> None:
        self.indices.append(np.asarray(indices, dtype=np.int64).reshape(-1) + self.count)
        self.vertices.append(np.asarray(vertices, dtype=np.float64).reshape(-1, 3))
        self.normals.append(normals)
        anchor = np.full(2, np.nan) if anchor_xy is None else np.asarray(anchor_xy, np.float64)
        self.anchors.append(np.tile(anchor, (len(self.indices[-1]) // 3, 1)))
        self.count += len(self.vertices[-1])


@dataclass(frozen=True)
class LampPlan:
    """One lamp of a signal head: a sphere lit in `colour` when its signal shows that state."""

    signal_id: str
    colour: SignalState
    centre_m: tuple[float, float, float]  # world frame
    radius_m: float = LAMP_RADIUS_M


@dataclass(frozen=True)
class BodyPlan:
    """One static body: a batch of one kind, colour and material. `obj` is its triangles' OBJ
    text (pybullet's visual shape, and with `collide` its static triangle-mesh collision shape,
    what LiDAR rays hit); `meshes`, what the GL renderer draws for it (the triangles it hosts
    for the GL renderer alone first, then its own), their `body` its index among the plan's
    bodies (`TwinPlan.body_kinds`)."""

    kind: str
    rgba: tuple[float, float, float, float]
    collide: bool
    obj: str
    meshes: tuple[TwinMesh, ...]


@dataclass(frozen=True)
class TwinPlan:
    """A map's twin as data, bodies in the order they are made: the signal lamps (`lamps`),
    then the static batches (`bodies`). `paint`: the markings (kind, area) in the order drawn;
    `street_lamps`, each lamp head's light (x, y, z); `wear`, the ground detail raster."""

    map_id: str
    lamps: tuple[LampPlan, ...]
    bodies: tuple[BodyPlan, ...]
    paint: tuple[tuple[str, shapely.Geometry], ...]
    street_lamps: tuple[tuple[float, float, float], ...]
    wear: WearRaster | None

    def body_kinds(self) -> list[str]:
        """Each body's element kind, in the order the bodies are made."""
        return ["signal"] * len(self.lamps) + [body.kind for body in self.bodies]


def plan_twin(intersection_map: IntersectionMap) -> TwinPlan:
    """The twin of `intersection_map` as data (pure: the same map gives an equal plan)."""
    return _Planner().plan(intersection_map)


class _Planner:
    """Gathers a map's elements: static ones merged into one batch per kind, colour and material
    (`_Batch`), each signal lamp a body of its own (`Twin.show` recolours it)."""

    def __init__(self) -> None:
        self.batches: dict[tuple[str, tuple, bool, Material], _Batch] = {}
        # triangles for the GL renderer alone, part of a batch's body (the key of the batch
        # that hosts them), each by colour and material: the buildings' windows, the crowns'
        # coarse spheres
        self.gl_only: dict[tuple, dict[tuple[tuple, Material], _Batch]] = {}
        self.lamps: list[LampPlan] = []
        self.paint: list[tuple[str, shapely.Geometry]] = []
        self.street_lamps: list[tuple[float, float, float]] = []

    def _add(
        self,
        kind: str,
        rgba: tuple,
        vertices: NDArray,
        indices: NDArray,
        collide: bool = True,
        normals: NDArray[np.float64] | None = None,
        material: Material | None = None,
        anchor_xy: NDArray | None = None,
    ) -> None:
        """Triangles (counter-clockwise seen from outside) for the batch of `kind`, `rgba` and
        `material` (by default the kind's, `KIND_MATERIAL`); `normals` per vertex for smooth
        shading (else each triangle is flat); `anchor_xy`, where on the ground they belong
        (`TwinMesh.anchors_xy`)."""
        material = KIND_MATERIAL.get(kind, Material.MATTE) if material is None else material
        self.batches.setdefault((kind, tuple(rgba), collide, material), _Batch()).add(
            vertices, indices, normals, anchor_xy
        )

    def _bodies(self) -> tuple[BodyPlan, ...]:
        """One body per batch, in the order the batches began, after the lamps; the GL-only
        triangles a batch hosts come just before its own (windows are drawn before the walls
        they stand on)."""
        bodies = []
        for key, batch in self.batches.items():
            kind, rgba, collide, material = key
            index = len(self.lamps) + len(bodies)
            meshes = [
                _twin_mesh(index, kind, extra_rgba, extra_material, extra)
                for (extra_rgba, extra_material), extra in self.gl_only.get(key, {}).items()
            ]
            own = _twin_mesh(index, kind, rgba, material, batch)
            meshes.append(own)
            obj = obj_text(own.vertices, own.indices, own.normals)
            bodies.append(BodyPlan(kind, rgba, collide, obj, tuple(meshes)))
        return tuple(bodies)

    def _windows(self, building: Building, rgba: tuple) -> None:
        """A building's windows (`scenery.facade_windows`), hosted by its walls' batch: dark
        ones in one batch, the ones lit at night in one a tone."""
        windows = facade_windows(building.footprint_m, building.height_m,
                                 zlib.crc32(building.building_id.encode()))  # fmt: skip
        host = ("building", tuple(rgba), True, Material.FACADE)
        parts = [(WINDOW_RGBA, Material.WINDOW, windows.lit < 0)]
        parts += [(lit, Material.WINDOW_LIT, windows.lit == tone)
                  for tone, lit in enumerate(LIT_WINDOW_RGBAS)]  # fmt: skip
        for glass_rgba, material, chosen in parts:
            if chosen.any():
                self._add_gl_only(host, glass_rgba, material, *windows.subset(chosen))

    def _add_gl_only(self, host: tuple, rgba: tuple, material: Material, vertices: NDArray,
                     indices: NDArray, normals: NDArray | None = None,
                     anchor_xy: NDArray | None = None) -> None:  # fmt: skip
        """Triangles the GL renderer draws as part of the body of batch `host`; pybullet never
        sees them."""
        batch = self.gl_only.setdefault(host, {}).setdefault((rgba, material), _Batch())
        batch.add(vertices, indices, normals, anchor_xy)

    def _flat(self, geometry: shapely.Geometry, z_m: float, rgba: tuple, kind: str,
              material: Material | None = None) -> None:  # fmt: skip
        vertices, indices = triangulate(geometry)
        if len(indices) == 0:
            return
        vertices_3d = np.column_stack([vertices, np.full(len(vertices), z_m)])
        painted = kind in PAINT_KINDS
        if painted:
            self.paint.append((kind, geometry))
        self._add(kind, rgba, vertices_3d, indices, collide=not painted, material=material)

    def _prism(
        self, footprint: NDArray, bottom_m: float, top_m: float, rgba: tuple, kind: str,
        collide: bool = True,
    ) -> None:  # fmt: skip
        """An extruded polygon (walls and a roof)."""
        self._add(kind, rgba, *prism_mesh(footprint, bottom_m, top_m), collide=collide)

    def _line_paint(self, line: NDArray, mark: LaneMark, road: shapely.Geometry) -> None:
        """Paint a boundary's mark, on the road only (an edge line's outer half would be under
        the kerb)."""
        paint = paint_geometry(line, mark).intersection(road)
        if not paint.is_empty:
            rgba = YELLOW_RGBA if mark.colour == MarkColour.YELLOW else WHITE_RGBA
            self._flat(paint, PAINT_Z_M, rgba, "road_mark")

    def plan(self, intersection_map: IntersectionMap) -> TwinPlan:
        m = intersection_map
        road = m.drivable_union()
        # the grass stops under the road and the sidewalks, which cover it: a plane under the
        # whole scene cost llvmpipe its rasterising and depth test over every road pixel
        covered = shapely.union_all([road, *(shapely.Polygon(a.polygon_m) for a in m.sidewalks)])
        ground = road.envelope.buffer(GROUND_MARGIN_M, join_style="mitre")
        self._flat(ground.difference(covered.buffer(-GROUND_UNDER_M)), -0.1, GROUND_RGBA, "ground")
        self._flat(road, 0.0, ROAD_RGBA, "road")
        for area in m.sidewalks:
            self._prism(area.polygon_m, -0.05, area.kerb_height_m, SIDEWALK_RGBA, "sidewalk")
        for lane in m.lanes:
            if not lane.is_intersection:
                self._line_paint(lane.left_boundary_m, lane.left_mark, road)
                self._line_paint(lane.right_boundary_m, lane.right_mark, road)
        for crosswalk in m.crosswalks:
            self._flat(shapely.Polygon(crosswalk.polygon_m), 0.5 * PAINT_Z_M, CROSSWALK_RGBA,
                       "crosswalk", Material.ASPHALT)  # fmt: skip
            self._flat(_zebra(crosswalk.polygon_m), PAINT_Z_M, WHITE_RGBA, "crosswalk",
                       Material.MARKING)  # fmt: skip
        for stop_line in m.stop_lines:
            self._flat(stop_line_band(stop_line.line_m), 2 * PAINT_Z_M, WHITE_RGBA, "stop_line")
        for building in m.buildings or generated_buildings(m):
            rgba = FACADE_RGBAS[zlib.crc32(building.building_id.encode()) % len(FACADE_RGBAS)]
            self._windows(building, rgba)
            self._prism(building.footprint_m, 0.0, building.height_m, rgba, "building")
        for tree in m.trees:
            self._tree(tree.position_m, tree.height_m, tree.crown_radius_m)
        for head in m.signal_heads:
            self._signal(head.signal_id, head.position_m, head.facing_yaw_rad, road)
        self._street_lamps(m, road)
        wear = wear_raster(m)
        for obstacle in m.static_obstacles:  # cones, barriers, bollards... as models
            for rgba, triangles in obstacle_parts(obstacle):
                self._add("obstacle", rgba, triangles.reshape(-1, 3), np.arange(3 * len(triangles)))
        return TwinPlan(m.map_id, tuple(self.lamps), self._bodies(), tuple(self.paint),
                        tuple(self.street_lamps), wear)  # fmt: skip

    def _box(self, centre: NDArray, yaw: float, size: NDArray, rgba: tuple, kind: str,
             material: Material | None = None) -> None:  # fmt: skip
        self._add(kind, rgba, *box_mesh(centre, yaw, size), material=material)

    def _tree(self, position: NDArray, height_m: float, crown_m: float) -> None:
        # trees are drawn only: rays through crowns made ray casting 1.7x slower a sweep
        x, y = position[:2]
        angles = np.linspace(0.0, 2 * np.pi, TRUNK_SIDES, endpoint=False)
        trunk = np.column_stack([x + 0.15 * np.cos(angles), y + 0.15 * np.sin(angles)])
        self._prism(trunk, 0.0, height_m * 0.6, TRUNK_RGBA, "vegetation", collide=False)
        # a crown of clustered spheres (a lumpy outline, not a ball), within the crown radius
        rng = np.random.default_rng(zlib.crc32(f"{x:.2f},{y:.2f}".encode()))
        centre = np.array([x, y, height_m - crown_m])
        for k in range(CROWN_CLUSTERS):
            angle = 2 * np.pi * (k / CROWN_CLUSTERS + rng.uniform(0.0, 0.2))
            offset = (
                0.38 * crown_m * np.array([np.cos(angle), np.sin(angle), rng.uniform(-0.4, 0.5)])
            )
            rgba = CROWN_RGBAS[int(rng.integers(len(CROWN_RGBAS)))]
            near, far = (
                sphere_mesh(centre + offset, 0.68 * crown_m, rings=rings, segments=segments)
                for rings, segments in CROWN_SPHERES
            )
            vertices, indices, normals = near
            self._add("vegetation", rgba, vertices, indices, collide=False, normals=normals,
                      material=Material.FOLIAGE, anchor_xy=(x, y))  # fmt: skip
            host = ("vegetation", tuple(rgba), False, Material.FOLIAGE)
            self._add_gl_only(host, rgba, Material.FOLIAGE_FAR, *far, anchor_xy=(x, y))

    def _street_lamps(self, intersection_map: IntersectionMap, road: shapely.Geometry) -> None:
        """Lamp posts every `STREET_LAMP_SPACING_M` along the kerb (the sidewalks' road side, or
        the road's edge where the map has no sidewalks), each with an arm over the road."""
        for base, towards_road in street_lamp_sites(intersection_map, road):
            x, y = base
            self._box(np.array([x, y, 0.5 * STREET_LAMP_HEIGHT_M]), 0.0,
                      np.array([0.16, 0.16, STREET_LAMP_HEIGHT_M]), POLE_RGBA, "pole")  # fmt: skip
            yaw = float(np.arctan2(towards_road[1], towards_road[0]))
            arm_centre = base + 0.5 * STREET_LAMP_ARM_M * towards_road
            self._box(np.array([*arm_centre, STREET_LAMP_HEIGHT_M - 0.1]), yaw,
                      np.array([STREET_LAMP_ARM_M, 0.1, 0.1]), POLE_RGBA, "pole")  # fmt: skip
            head = base + STREET_LAMP_ARM_M * towards_road
            self._box(np.array([*head, STREET_LAMP_HEIGHT_M - 0.22]), yaw, np.array([0.6, 0.28, 0.14]),
                      STREET_LAMP_RGBA, "pole", Material.STREET_LAMP)  # fmt: skip
            self.street_lamps.append((float(head[0]), float(head[1]), STREET_LAMP_HEIGHT_M - 0.35))

    def _signal(self, signal_id: str, position: NDArray, facing_rad: float,
                road: shapely.Geometry) -> None:  # fmt: skip
        x, y, z = position
        point = shapely.Point(x, y)
        if road.buffer(-MAST_ARM_OVER_ROAD_M).contains(point):  # a mast arm from the kerb
            edge = shapely.ops.nearest_points(road.boundary, point)[0]
            outward = np.array([edge.x - x, edge.y - y])
            outward /= max(float(np.linalg.norm(outward)), 1e-9)
            pole = np.array([edge.x, edge.y]) + 0.6 * outward
            span = float(np.linalg.norm(pole - [x, y]))
            self._box(np.array([*pole, 0.5 * (z + 1.0)]), 0.0, np.array([0.22, 0.22, z + 1.0]),
                      (0.2, 0.2, 0.2, 1.0), "pole")  # fmt: skip
            middle = 0.5 * (pole + np.array([x, y]))
            self._box(np.array([*middle, z + 0.9]), float(np.arctan2(*(pole - [x, y])[::-1])),
                      np.array([span, 0.14, 0.14]), (0.2, 0.2, 0.2, 1.0), "pole")  # fmt: skip
        else:
            self._box(np.array([x, y, 0.5 * z]), 0.0, np.array([0.15, 0.15, z]),
                      (0.2, 0.2, 0.2, 1.0), "pole")  # fmt: skip
        self._box(
            np.array([x, y, z + 0.45]),
            facing_rad,
            np.array([0.3, 0.35, 1.0]),
            (0.08, 0.08, 0.08, 1.0),
            "signal",
        )
        forward = np.array([np.cos(facing_rad), np.sin(facing_rad)])
        for index, colour in enumerate((SignalState.RED, SignalState.YELLOW, SignalState.GREEN)):
            centre = (*(np.array([x, y]) + 0.17 * forward), z + 0.8 - 0.3 * index)
            self.lamps.append(LampPlan(signal_id, colour, tuple(float(c) for c in centre)))


def _twin_mesh(body: int, kind: str, rgba: tuple, material: Material, batch: _Batch) -> TwinMesh:
    normals = None
    if all(n is not None for n in batch.normals):
        normals = np.concatenate(batch.normals)
    anchors = np.concatenate(batch.anchors)
    return TwinMesh(body, kind, rgba, material, np.concatenate(batch.vertices),
                    np.concatenate(batch.indices), normals,
                    None if np.isnan(anchors).all() else anchors)  # fmt: skip


def prism_mesh(
    footprint: NDArray, bottom_m: float, top_m: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Vertices `(V, 3)` and triangle indices `(3T,)` of a polygon `(N, 2)` extruded from
    `bottom_m` to `top_m`: walls and a roof, counter-clockwise seen from outside."""
    ring = np.asarray(shapely.Polygon(footprint).exterior.coords)[:-1, :2]
    if not shapely.Polygon(ring).exterior.is_ccw:
        ring = ring[::-1]
    following = np.roll(ring, -1, axis=0)
    walls = np.stack(
        [
            np.column_stack([ring, np.full(len(ring), bottom_m)]),
            np.column_stack([following, np.full(len(ring), bottom_m)]),
            np.column_stack([following, np.full(len(ring), top_m)]),
            np.column_stack([ring, np.full(len(ring), top_m)]),
        ],
        axis=1,
    ).reshape(-1, 3)
    base = 4 * np.arange(len(ring))[:, None]
    wall_indices = (base + np.array([0, 1, 2, 0, 2, 3])).reshape(-1)
    roof, roof_indices = triangulate(shapely.Polygon(ring))
    vertices = np.concatenate([walls, np.column_stack([roof, np.full(len(roof), top_m)])])
    return vertices, np.concatenate([wall_indices, roof_indices + len(walls)])


def sphere_mesh(
    centre: NDArray, radius_m: float, rings: int = 8, segments: int = 12
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """A UV sphere: vertices `(V, 3)`, outward triangles `(3T,)` and unit normals `(V, 3)`."""
    normals, indices = _unit_sphere(rings, segments)
    return np.asarray(centre, dtype=np.float64) + radius_m * normals, indices, normals


@functools.cache
def _unit_sphere(rings: int, segments: int) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The unit sphere's normals (its vertices) and triangles (made once: a twin has hundreds
    of crown and lamp spheres of a few sizes)."""
    polar = np.linspace(0.0, np.pi, rings + 1)
    azimuth = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    polar_grid, azimuth_grid = np.meshgrid(polar, azimuth, indexing="ij")
    normals = np.stack(
        [
            np.sin(polar_grid) * np.cos(azimuth_grid),
            np.sin(polar_grid) * np.sin(azimuth_grid),
            np.cos(polar_grid),
        ],
        axis=-1,
    ).reshape(-1, 3)
    indices = []
    for ring in range(rings):
        for segment in range(segments):
            a = ring * segments + segment
            b = ring * segments + (segment + 1) % segments
            c, d = a + segments, b + segments
            if ring > 0:
                indices += [a, c, b]  # (a: upper, c: lower) going east: outward
            if ring < rings - 1:
                indices += [b, c, d]
    normals.flags.writeable = False
    index_array = np.asarray(indices)
    index_array.flags.writeable = False
    return normals, index_array


def paint_geometry(line: NDArray, mark: LaneMark) -> shapely.Geometry:
    """The painted area of a boundary line with mark `mark` (dashes 3 m on, 6 m off; doubles
    0.3 m apart; lines 0.15 m wide)."""
    if mark.pattern == MarkPattern.NONE:
        return shapely.Polygon()
    geometry = shapely.LineString(line[:, :2])
    double = (
        MarkPattern.DOUBLE_SOLID,
        MarkPattern.DOUBLE_DASHED,
        MarkPattern.SOLID_DASHED,
        MarkPattern.DASHED_SOLID,
    )
    offsets = [-0.15, 0.15] if mark.pattern in double else [0.0]
    pieces = []
    for index, offset in enumerate(offsets):
        side = geometry.offset_curve(offset) if offset else geometry
        dashed = (
            mark.pattern in (MarkPattern.DASHED, MarkPattern.DOUBLE_DASHED)
            or (mark.pattern == MarkPattern.SOLID_DASHED and index == 1)
            or (mark.pattern == MarkPattern.DASHED_SOLID and index == 0)
        )
        if dashed:
            for start in np.arange(0.0, side.length, DASH_M + GAP_M):
                pieces.append(shapely.ops.substring(side, start, min(start + DASH_M, side.length)))
        else:
            pieces.append(side)
    return shapely.union_all(
        [piece.buffer(0.5 * LINE_WIDTH_M, cap_style="flat") for piece in pieces]
    )


def stop_line_band(line_m: NDArray) -> shapely.Geometry:
    return shapely.LineString(line_m[:, :2]).buffer(0.5 * STOP_LINE_WIDTH_M, cap_style="flat")


def _zebra(polygon_m: NDArray) -> shapely.Geometry:
    """Stripes across the walking direction: parallel to the crosswalk's longer side."""
    polygon = shapely.Polygon(polygon_m)
    rectangle = np.asarray(polygon.minimum_rotated_rectangle.exterior.coords)[:4]
    sides = [rectangle[1] - rectangle[0], rectangle[2] - rectangle[1]]
    walk = sides[0] if np.linalg.norm(sides[0]) > np.linalg.norm(sides[1]) else sides[1]
    along = walk / np.linalg.norm(walk)
    origin = rectangle.mean(axis=0)
    length = float(np.linalg.norm(walk))
    across = np.array([-along[1], along[0]])
    stripes = []
    for offset in np.arange(-0.5 * length + 0.25, 0.5 * length, 2 * ZEBRA_STRIPE_M):
        centre = origin + offset * along
        stripes.append(
            shapely.LineString([centre - 20 * across, centre + 20 * across]).buffer(
                0.5 * ZEBRA_STRIPE_M, cap_style="flat"
            )
        )
    return shapely.union_all(stripes).intersection(polygon.buffer(-0.1))
