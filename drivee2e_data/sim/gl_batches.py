"""The order the GL renderer draws triangles in, and what each view skips.

A vertex buffer's triangles are sorted into material groups (each drawn with the scene shader
compiled for its materials alone: `MATERIAL_GROUPS`) and, inside a large group, into square
cells of the ground plane. Each (group, cell) is a `DrawBatches` row with its bounding box; a
view draws only the batches whose box meets its frustum (`DrawBatches.runs`). Skipping a batch
changes no pixel: everything in it lies outside the view. On llvmpipe, the CPU's GL, every
vertex of a draw is shaded and clipped on the calling thread whatever the view sees, so a camera
that sees a fifth of the scene paid for all of it, thirteen views a frame; on an H100 or H200,
whose graphics run on a few of its units, a closed-loop step's vertices were most of its GPU
time.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim.gl_vertices import FLOATS_PER_VERTEX
from drivee2e_data.sim.models import Material

# The scene is drawn one group of materials at a time, each with the scene shader compiled for
# those materials alone (`scene.frag`'s HAS_* and GLOSSY defines): llvmpipe, the CPU's GL, runs
# every branch of a shader for every pixel (its "if" masks lanes, it does not jump), so a
# shader holding every material's code costs the sum of them all on every pixel. Each group:
# its materials (`Material` codes) and its defines; ground materials turn glossy when wet.
MATERIAL_GROUPS: tuple[tuple[frozenset[int], tuple[str, ...]], ...] = (
    (frozenset({Material.PAINT, Material.GLASS, Material.TYRE}), ("GLOSSY",)),
    (frozenset({Material.MATTE, Material.LAMP, Material.STREET_LAMP}), ()),
    (frozenset({Material.ASPHALT}), ("HAS_ASPHALT",)),
    (frozenset({Material.MARKING}), ("HAS_MARKING",)),
    (frozenset({Material.PAVEMENT}), ("HAS_PAVEMENT",)),
    (frozenset({Material.GRASS}), ("HAS_GRASS",)),
    (frozenset({Material.FOLIAGE}), ("HAS_FOLIAGE",)),
    (frozenset({Material.FOLIAGE_FAR}), ("HAS_FOLIAGE",)),
    (frozenset({Material.WINDOW, Material.WINDOW_LIT}), ("HAS_WINDOW", "GLOSSY")),
    (frozenset({Material.FACADE}), ("HAS_FACADE",)),
    # walls and windows that face away from the sun (`in_draw_order`'s `light_direction`): no
    # materials of their own; the sun's term is zero on them, so they skip the shadow lookup (a
    # third of a wall's cost on llvmpipe) and look the same
    (frozenset(), ("HAS_WINDOW", "GLOSSY", "SUN_AVERTED")),
    (frozenset(), ("HAS_FACADE", "SUN_AVERTED")),
)


def _group_of(material: Material) -> int:
    return next(k for k, (materials, _) in enumerate(MATERIAL_GROUPS) if material in materials)


# Crowns are drawn from two meshes (`twin.CROWN_SPHERES`): the detailed one where a batch's box
# comes within FOLIAGE_DETAIL_M of the eye, the coarse one beyond (a crown there spans under
# 150 pixels of the front camera), and the coarse one into the sun's shadow map. Where the scene
# is not cut into cells (`GLRenderer`'s `cull` off) every box is unbounded, so every crown is
# drawn detailed.
FOLIAGE_DETAIL_M = 40.0
NEAR_FOLIAGE = _group_of(Material.FOLIAGE)
FAR_FOLIAGE = _group_of(Material.FOLIAGE_FAR)
# each group of walls and windows, and the group its triangles facing away from the sun go to
AVERTED = {
    _group_of(Material.WINDOW): len(MATERIAL_GROUPS) - 2,
    _group_of(Material.FACADE): len(MATERIAL_GROUPS) - 1,
}
GROUND_MATERIALS = frozenset(
    {Material.ASPHALT, Material.MARKING, Material.PAVEMENT, Material.GRASS}
)
# The groups that cast no shadow: the road, its paint and the grass lie at ground level, below
# everything they could shade (raised sidewalks stay casters: their kerbs shade the gutter);
# windows lie on walls that cast the same shadow.
# Left out of the sun's shadow map, they no longer fill its 2048 x 2048 texels every state.
NOT_CASTING = frozenset(
    index
    for index, (materials, defines) in enumerate(MATERIAL_GROUPS)
    if (materials and materials <= {Material.ASPHALT, Material.MARKING, Material.GRASS})
    or "HAS_WINDOW" in defines
)
# Windows stand 2 cm out from the walls they belong to (same body, same kind): views of ids and
# depth alone (the depth-image LiDAR) leave them out, reading the wall behind instead
DECALS = frozenset(
    index for index, (_, defines) in enumerate(MATERIAL_GROUPS) if "HAS_WINDOW" in defines
)
# the group of bodies drawn into the sun's shadow map alone (`SceneLights.casters`), after every
# material group (the one past the end holds materials outside every group)
SHADOW_ONLY = len(MATERIAL_GROUPS) + 1
ALL_MATERIALS = ("HAS_ASPHALT", "HAS_MARKING", "HAS_PAVEMENT", "HAS_GRASS", "HAS_FOLIAGE",
                 "HAS_FACADE", "HAS_WINDOW", "GLOSSY")  # fmt: skip
# Cells of 24 m: a view's frustum leaves most of a 400 m scene's cells out, and a group's cells
# stay few enough that the draws a view makes (one per run of visible cells) cost less than the
# vertices they skip. Groups under MIN_SPLIT_VERTICES are one batch (a draw's own cost is worth
# more than their vertices); runs of visible batches closer than MERGE_GAP_VERTICES are drawn as
# one (drawing the few vertices between costs less than a second draw).
CELL_M = 24.0
MIN_SPLIT_VERTICES = 3000
MERGE_GAP_VERTICES = 1500
_CELL_OFFSET = 1 << 15  # cell indices shifted positive (scenes span far less than 786 km)


def group_defines(group: int, variant: tuple[str, ...]) -> tuple[str, ...]:
    """The scene shader's defines for drawing material group `group` (an index into
    `MATERIAL_GROUPS`; past its end: materials outside every group, all the code) in `variant`."""
    if group >= len(MATERIAL_GROUPS):
        return variant + ALL_MATERIALS
    materials, defines = MATERIAL_GROUPS[group]
    if "WET" in variant and materials and materials <= GROUND_MATERIALS:
        defines = (*defines, "GLOSSY")
    if "SUN_AVERTED" in defines:
        variant = tuple(define for define in variant if define != "SHADOWS")
    return variant + defines


_GROUP_OF = np.full(256, len(MATERIAL_GROUPS), np.int64)
for _index, (_materials, _) in enumerate(MATERIAL_GROUPS):
    _GROUP_OF[sorted(_materials)] = _index

# the eight corners of a unit box, as 0/1 choices of the low or high bound per axis
_CORNER_CHOICE = np.array([[(k >> axis) & 1 for axis in range(3)] for k in range(8)], bool)


@dataclass(frozen=True)
class DrawBatches:
    """A vertex buffer's batches in buffer order: each a contiguous run of whole triangles of
    one material group (and one cell), with the bounding box of its vertices (world frame, m)."""

    group: NDArray[np.int64]  # (B,) index into MATERIAL_GROUPS (its length: no group)
    first: NDArray[np.int64]  # (B,) first vertex
    count: NDArray[np.int64]  # (B,) vertices
    low_m: NDArray[np.float64]  # (B, 3)
    high_m: NDArray[np.float64]  # (B, 3)

    @staticmethod
    def empty() -> DrawBatches:
        none = np.zeros(0, np.int64)
        return DrawBatches(none, none, none, np.zeros((0, 3)), np.zeros((0, 3)))

    @property
    def groups(self) -> tuple[tuple[int, int, int], ...]:
        """Each material group present as `(group, first vertex, vertex count)`, in buffer order
        (a group's batches are contiguous)."""
        ranges: list[tuple[int, int, int]] = []
        for group, first, count in zip(self.group, self.first, self.count, strict=True):
            if ranges and ranges[-1][0] == group:
                ranges[-1] = (ranges[-1][0], ranges[-1][1], ranges[-1][2] + int(count))
            else:
                ranges.append((int(group), int(first), int(count)))
        return tuple(ranges)

    def then(
        self, group: int, first: int, count: int, vertices: NDArray[np.float32]
    ) -> DrawBatches:
        """These batches and one more after them: `count` vertices from `first` (rows of
        `VERTEX_FORMAT`, `vertices`) in `group`."""
        positions = vertices[:, :3].astype(np.float64)
        return DrawBatches(
            np.append(self.group, group),
            np.append(self.first, first),
            np.append(self.count, count),
            np.vstack([self.low_m, positions.min(axis=0)]),
            np.vstack([self.high_m, positions.max(axis=0)]),
        )

    @cached_property
    def _bounded(self) -> NDArray[np.bool_]:
        """(B,) which batches have a finite box."""
        return np.isfinite(self.low_m).all(axis=1) & np.isfinite(self.high_m).all(axis=1)

    @cached_property
    def _corners(self) -> NDArray[np.float64]:
        """(B, 8, 3) the corners of each batch's box."""
        return np.where(_CORNER_CHOICE[None], self.high_m[:, None], self.low_m[:, None])

    @cached_property
    def group_set(self) -> frozenset[int]:
        """The material groups of these batches (a view's programs are chosen by them)."""
        return frozenset(self.group.tolist())

    @cached_property
    def _group_masks(self) -> dict[frozenset[int], NDArray[np.bool_]]:
        return {}

    def _in_groups(self, groups: frozenset[int]) -> NDArray[np.bool_]:
        """(B,) which batches are of `groups` (read-only; kept per set: a view asks for the
        same few sets at every step, of batches that last a clip)."""
        mask = self._group_masks.get(groups)
        if mask is None:
            mask = np.isin(self.group, list(groups))
            mask.setflags(write=False)
            self._group_masks[groups] = mask
        return mask

    @cached_property
    def foliage(self) -> NDArray[np.int64]:
        """Indices of the batches of crowns, detailed or coarse (`level_of_detail`'s)."""
        return np.flatnonzero(self._in_groups(frozenset({NEAR_FOLIAGE, FAR_FOLIAGE})))

    def visible(self, matrix: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(B,) whether each batch's box may show in the view of `matrix` (world to clip space,
        4x4, perspective or orthographic): false only where all eight corners lie beyond one
        of the frustum's six planes."""
        if not len(self.group):
            return np.zeros(0, bool)
        bounded = self._bounded
        corners = self._corners[bounded]  # an unbounded box may show anywhere
        clip = corners @ matrix[:3, :3].T + matrix[:3, 3]  # (B, 8, 3)
        w = corners @ matrix[3, :3] + matrix[3, 3]  # (B, 8)
        outside = np.zeros(len(corners), bool)
        for axis in range(3):
            outside |= np.all(clip[..., axis] > w, axis=1)
            outside |= np.all(clip[..., axis] < -w, axis=1)
        visible = np.ones(len(self.group), bool)
        visible[bounded] = ~outside
        return visible

    def runs(
        self,
        visible: NDArray[np.bool_],
        by_group: bool = True,
        skip: frozenset[int] = frozenset(),
        excluded: NDArray[np.bool_] | None = None,
    ) -> list[tuple[int, int, int]]:
        """The draws for the `visible` batches, as `(group, first vertex, vertex count)`:
        neighbouring visible batches joined (across groups too unless `by_group`: one program
        for all), and runs less than `MERGE_GAP_VERTICES` apart joined with what lies between;
        batches of the groups in `skip`, and those `excluded` `(B,)` (another level of detail's),
        left out and never drawn as part of a gap."""
        skipped = self._in_groups(skip)
        if excluded is not None:
            skipped = skipped | excluded
        # skipped batches before each index: a draw never spans one, not even in a gap
        barriers = np.cumsum(skipped)
        drawn = np.flatnonzero(visible & ~skipped)
        if not len(drawn):
            return []
        group, first, count = self.group[drawn], self.first[drawn], self.count[drawn]
        # each drawn batch joins the one before it when nothing skipped lies between, the gap
        # is short, and (by group) the two share a group
        joins = (barriers[drawn[1:]] == barriers[drawn[:-1]]) & (
            first[1:] - (first[:-1] + count[:-1]) <= MERGE_GAP_VERTICES
        )
        if by_group:
            joins &= group[1:] == group[:-1]
        starts = np.flatnonzero(np.concatenate(([True], ~joins)))
        ends = np.append(starts[1:], len(drawn)) - 1
        counts = first[ends] + count[ends] - first[starts]
        return list(
            zip(group[starts].tolist(), first[starts].tolist(), counts.tolist(), strict=True)
        )


def level_of_detail(batches: DrawBatches, eye_m: NDArray[np.float64]) -> NDArray[np.bool_]:
    """`(B,)` which batches a view from `eye_m` (world frame) draws at their level of detail:
    detailed crowns whose box comes within `FOLIAGE_DETAIL_M`, coarse ones whose box does not;
    every other batch."""
    drawn = np.ones(len(batches.group), bool)
    crowns = batches.foliage  # only crowns have levels: the rest are drawn at every distance
    if len(crowns):
        eye = np.asarray(eye_m, np.float64)
        nearest = np.clip(eye, batches.low_m[crowns], batches.high_m[crowns])
        near = np.linalg.norm(nearest - eye, axis=1) <= FOLIAGE_DETAIL_M
        group = batches.group[crowns]
        drawn[crowns] = ~(((group == NEAR_FOLIAGE) & ~near) | ((group == FAR_FOLIAGE) & near))
    return drawn


def in_draw_order(
    vertices: NDArray[np.float32],
    cells: bool = True,
    light_direction: tuple[float, float, float] | None = None,
    anchors_xy: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float32], DrawBatches]:
    """`vertices` (rows of `VERTEX_FORMAT`, three to a triangle) with their triangles sorted into
    batches: by material group, the groups in the order of their first triangle (so what was
    drawn first mostly still is); with `cells`, inside a group of `MIN_SPLIT_VERTICES` or more,
    by the `CELL_M` cell of each triangle's centroid (row by row), each batch with its box;
    otherwise in their order, the boxes unbounded. With `light_direction` (towards the sun,
    world frame), wall and window triangles that face away from it go to their `AVERTED` group.
    `anchors_xy` `(T, 2)` puts triangles in the cell of that point instead of their centroid's
    (NaN rows: their centroid's)."""
    if not len(vertices):
        return vertices, DrawBatches.empty()
    order, batches = draw_order(vertices, cells, light_direction, anchors_xy)
    ordered = np.take(vertices.reshape(-1, 3, FLOATS_PER_VERTEX), order, axis=0)
    return ordered.reshape(-1, FLOATS_PER_VERTEX), batches


class GroupOrder:
    """`in_draw_order` (without a light), remembered: its order and batches depend on nothing but
    each triangle's material and, with `cells`, its corners' positions, so while a frame's
    triangles carry the same materials (and lie in the same places) as the last frame's, the
    last order is taken again and only the triangles are moved: the same vertices and batches,
    without sorting them again. What the moving bodies' buffer holds where the GPU poses the
    models (`gl_posed`) is mostly the signals' lamps, which stand still and change colour."""

    def __init__(self, cells: bool = False) -> None:
        self.cells = cells
        self.key: NDArray[np.float32] | None = None
        self.order = np.zeros(0, np.int64)
        self.batches = DrawBatches.empty()

    def __call__(self, vertices: NDArray[np.float32]) -> tuple[NDArray[np.float32], DrawBatches]:
        if not len(vertices):
            return vertices, DrawBatches.empty()
        triangles = vertices.reshape(-1, 3, FLOATS_PER_VERTEX)
        # the materials, and the positions where cells are cut
        key = vertices[:, [0, 1, 2, FLOATS_PER_VERTEX - 1]] if self.cells else triangles[:, 0, -1]
        if self.key is None or not np.array_equal(key, self.key):
            self.order, self.batches = draw_order(vertices, cells=self.cells)
            self.key = key.copy()
        ordered = np.take(triangles, self.order, axis=0)
        return ordered.reshape(-1, FLOATS_PER_VERTEX), self.batches


def draw_order(
    vertices: NDArray[np.float32],
    cells: bool = True,
    light_direction: tuple[float, float, float] | None = None,
    anchors_xy: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.int64], DrawBatches]:
    """`in_draw_order`'s order of the triangles of `vertices` (not empty), `(T,)` indices, and
    its batches."""
    triangles = vertices.reshape(-1, 3, FLOATS_PER_VERTEX)
    codes = np.clip(np.rint(triangles[:, 0, FLOATS_PER_VERTEX - 1]), 0, 255).astype(np.int64)
    groups = _GROUP_OF[codes]
    if light_direction is not None:
        # the shader's sun term is max(n . l, 0): zero across a triangle whose three corners'
        # normals all face away from the sun
        normals = triangles[:, :, 3:6].astype(np.float64)
        averted = np.all(normals @ np.asarray(light_direction, np.float64) <= 0.0, axis=1)
        for facing, away in AVERTED.items():
            groups[(groups == facing) & averted] = away
    present = np.flatnonzero(np.bincount(groups, minlength=len(MATERIAL_GROUPS) + 1))
    first = [int(np.argmax(groups == group)) for group in present]
    in_order = present[np.argsort(first)]
    rank = np.empty(len(MATERIAL_GROUPS) + 1, np.int64)
    rank[in_order] = np.arange(len(in_order))
    # elementwise over the three corners: numpy's reductions over an axis of three are slow
    corner = [triangles[:, k, :3] for k in range(3)]
    cell_key = np.zeros(len(triangles), np.int64)
    if cells:
        centroid = (corner[0][:, :2] + corner[1][:, :2] + corner[2][:, :2]) / 3.0
        if anchors_xy is not None:
            centroid = np.where(np.isnan(anchors_xy), centroid, anchors_xy)
        cell = np.floor(centroid / CELL_M).astype(np.int64) + _CELL_OFFSET
        cell_key = cell[:, 1] * (2 * _CELL_OFFSET) + cell[:, 0]
        small = np.bincount(groups, minlength=len(MATERIAL_GROUPS) + 1) * 3 < MIN_SPLIT_VERTICES
        cell_key[small[groups]] = 0
    key = rank[groups] * (4 * _CELL_OFFSET * _CELL_OFFSET) + cell_key
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    starts = np.flatnonzero(np.concatenate(([True], sorted_key[1:] != sorted_key[:-1])))
    if cells:
        lowest = np.minimum(np.minimum(corner[0], corner[1]), corner[2])[order]
        highest = np.maximum(np.maximum(corner[0], corner[1]), corner[2])[order]
        low = np.minimum.reduceat(lowest, starts, axis=0).astype(np.float64)
        high = np.maximum.reduceat(highest, starts, axis=0).astype(np.float64)
    else:  # no boxes: every batch may show anywhere (and every crown is near: detailed)
        low = np.full((len(starts), 3), -np.inf)
        high = np.full((len(starts), 3), np.inf)
    counts = np.diff(np.append(starts, len(order)))
    batches = DrawBatches(
        group=groups[order][starts],
        first=3 * starts.astype(np.int64),
        count=3 * counts.astype(np.int64),
        low_m=low,
        high_m=high,
    )
    return order, batches
