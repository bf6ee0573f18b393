"""The GL renderer's draw order and culling: triangles in material groups and cells with tight
boxes, the frustum test on known boxes, the draws a view makes, and images unchanged by what a
view skips."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_data.sim import gl_batches, gl_context, gl_renderer
from drivee2e_data.sim.gl_batches import (
    CELL_M,
    MERGE_GAP_VERTICES,
    DrawBatches,
    in_draw_order,
)
from drivee2e_data.sim.gl_context import gl_available
from drivee2e_data.sim.gl_renderer import look_at, shadow_matrix
from drivee2e_data.sim.gl_vertices import FLOATS_PER_VERTEX
from drivee2e_data.sim.models import Material
from drivee2e_data.sim.world import World
from tests.factories import front_view, pose_on_cpu, synthetic_clip


def _triangle_rows(centres: np.ndarray, material: int) -> np.ndarray:
    """A small triangle (0.5 m) at each `(x, y)` centre, numbered in its first normal float."""
    rows = np.zeros((3 * len(centres), FLOATS_PER_VERTEX), np.float32)
    offsets = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 1.0]])
    for k, (x, y) in enumerate(centres):
        rows[3 * k : 3 * k + 3, :3] = offsets + np.array([x, y, 0.0])
        rows[3 * k : 3 * k + 3, 3] = k
        rows[3 * k : 3 * k + 3, -1] = material
    return rows


def test_a_large_group_is_cut_into_cells_with_tight_boxes_and_a_small_one_is_not():
    rng = np.random.default_rng(3)
    spread = rng.uniform(-100.0, 100.0, size=(2000, 2))  # 6000 vertices: cut into cells
    few = rng.uniform(-100.0, 100.0, size=(50, 2))  # 150 vertices: one batch
    rows = np.concatenate([_triangle_rows(few, Material.ASPHALT),
                           _triangle_rows(spread, Material.FOLIAGE)])  # fmt: skip
    ordered, batches = in_draw_order(rows)
    assert len(ordered) == len(rows)
    np.testing.assert_array_equal(np.sort(ordered[:, 3]), np.sort(rows[:, 3]))
    asphalt = [g for g, (m, _) in enumerate(gl_batches.MATERIAL_GROUPS) if Material.ASPHALT in m]
    assert list(batches.group).count(asphalt[0]) == 1  # under MIN_SPLIT_VERTICES
    assert batches.group[0] == asphalt[0]  # it came first
    cells = len(batches.group) - 1
    assert 64 <= cells <= 100  # 200 m / 24 m: 9 x 9 cells (less where a cell drew none)
    assert np.array_equal(batches.first, np.concatenate(([0], np.cumsum(batches.count)[:-1])))
    for low, high, first, count in zip(batches.low_m, batches.high_m, batches.first,
                                       batches.count, strict=True):  # fmt: skip
        points = ordered[first : first + count, :3]
        np.testing.assert_allclose(points.min(axis=0), low)  # tight: the extremes of its own
        np.testing.assert_allclose(points.max(axis=0), high)
        if first == 0:
            continue  # the uncut group
        # one cell's triangles: their centroids within CELL_M of each other on each axis
        centroids = ordered[first : first + count, :2].reshape(-1, 3, 2).mean(axis=1)
        assert np.ptp(centroids, axis=0).max() < CELL_M
    assert batches.groups[1] == (batches.group[1], 150, 6000)  # the cells make one group range


def _perspective(eye, target, fov_deg=60.0, near=0.5, far=200.0) -> np.ndarray:
    """A world-to-clip matrix (OpenGL's perspective) of a square view."""
    view = look_at(np.asarray(eye, float), np.asarray(target, float), np.array([0.0, 0.0, 1.0]))
    f = 1.0 / np.tan(np.radians(fov_deg) / 2)
    projection = np.array([[f, 0, 0, 0], [0, f, 0, 0],
                           [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
                           [0, 0, -1, 0]])  # fmt: skip
    return projection @ view


def _boxes(centres: list[tuple[float, float, float]], half_m: float = 1.0) -> DrawBatches:
    centre = np.array(centres, float)
    count = np.full(len(centres), 3)
    return DrawBatches(np.zeros(len(centres), np.int64), 3 * np.arange(len(centres)), count,
                       centre - half_m, centre + half_m)  # fmt: skip


def test_boxes_ahead_are_visible_and_boxes_behind_beside_or_beyond_are_not():
    """From (0, 0, 2) looking along +x with a 60 degree view out to 200 m."""
    matrix = _perspective([0, 0, 2], [10, 0, 2])
    boxes = _boxes([(20, 0, 1), (-20, 0, 1), (20, 40, 1), (250, 0, 1), (20, 12.5, 1),
                    (0.2, 0, 2)])  # fmt: skip
    # ahead; behind; 63 degrees off the axis; past the far plane; 32 degrees off (its near
    # corner inside the 30 degree half-angle); around the eye (its box holds the eye)
    assert boxes.visible(matrix).tolist() == [True, False, False, False, True, True]


def test_the_sun_s_square_culls_what_lies_outside_it():
    matrix = shadow_matrix((0.0, 0.0, 1.0), (100.0, 0.0))  # 150 m square around (100, 0)
    boxes = _boxes([(100, 0, 1), (170, 70, 1), (190, 0, 1), (100, -80, 1)])
    assert boxes.visible(matrix).tolist() == [True, True, False, False]


def test_runs_join_neighbours_and_short_gaps_but_never_span_a_skipped_group():
    counts = np.array([300, 300, MERGE_GAP_VERTICES + 3, 300, 300, 300, 300])
    first = np.concatenate(([0], np.cumsum(counts)[:-1]))
    group = np.array([0, 0, 0, 0, 1, 2, 6])
    batches = DrawBatches(group, first, counts, np.zeros((7, 3)), np.ones((7, 3)))
    visible = np.array([True, True, False, True, True, True, True])
    f = first.tolist()
    # 0 and 1 touch; 2 is a gap too long to draw; then 3, and 4 and 5 are other groups
    assert batches.runs(visible) == [(0, 0, 600), (0, f[3], 300), (1, f[4], 300),
                                     (2, f[5], 300), (6, f[6], 300)]  # fmt: skip
    # one program for all: groups join, the long gap still splits
    assert batches.runs(visible, by_group=False) == [(0, 0, 600), (0, f[3], 1200)]
    # group 2 left out: it splits what it lay between, though 4 and 6 are only 300 apart
    assert batches.runs(visible, by_group=False, skip=frozenset({2})) == [
        (0, 0, 600), (0, f[3], 600), (6, f[6], 300)
    ]  # fmt: skip
    hidden = np.array([True, True, False, True, True, False, True])
    assert batches.runs(hidden, by_group=False, skip=frozenset({2})) == [
        (0, 0, 600), (0, f[3], 600), (6, f[6], 300)
    ]  # fmt: skip
    # a batch excluded (another level of detail's) is never drawn as part of a gap: 0 and 2,
    # 300 vertices apart, are joined over the hidden 1 unless 1 is excluded
    short = DrawBatches(
        group, 300 * np.arange(7), np.full(7, 300), np.zeros((7, 3)), np.ones((7, 3))
    )
    g = [300 * k for k in range(7)]
    gap = np.array([True, False, True, True, True, True, True])
    assert short.runs(gap) == [(0, 0, 1200), (1, g[4], 300), (2, g[5], 300), (6, g[6], 300)]
    excluded = np.array([False, True, False, False, False, False, False])
    assert short.runs(gap, excluded=excluded) == [
        (0, 0, 300), (0, g[2], 600), (1, g[4], 300), (2, g[5], 300), (6, g[6], 300)
    ]  # fmt: skip


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    return synthetic_clip(tmp_path_factory.mktemp("batches_site"))


@pytest.mark.skipif(not gl_available(), reason="no OpenGL context (EGL) here")
def test_what_a_view_skips_changes_no_pixel(site, monkeypatch):
    """The same frame drawn with the scene cut into cells (most of them skipped by the front
    camera) and a program per material group (what a renderer on the CPU does), cut into
    cells with one program for every material (what a GPU does), and as one batch per
    material group, all drawn (culling off): the same image, with the crowns detailed at any
    distance (drawn whole, every crown is; cut, the coarse ones beyond `FOLIAGE_DETAIL_M` are
    the only change)."""
    intersection_map, scenario = site
    monkeypatch.setattr(gl_batches, "FOLIAGE_DETAIL_M", np.inf)
    ego = scenario.ego
    eye = np.array([ego.x_m[20], ego.y_m[20], 1.6])
    heading = np.array([np.cos(ego.yaw_rad[20]), np.sin(ego.yaw_rad[20]), 0.0])
    images = {}
    for cull, on_cpu in ((True, True), (True, False), (False, False)):
        monkeypatch.setattr(gl_context, "rasterises_on_cpu", lambda on_cpu=on_cpu: on_cpu)
        monkeypatch.setenv(gl_renderer.CULL_VARIABLE, "1" if cull else "0")
        with World(intersection_map, scenario, renderer="gl") as world:
            pose_on_cpu(world)  # the models posed alike (`test_gl_posed` compares the two)
            images[cull, on_cpu] = front_view(world, 20, (320, 180), segmentation=True,
                                              near_m=0.5)  # fmt: skip
            batches = world.gl.static_batches
            # a program per material group on the CPU, one for all of them on a GPU
            scene = {key for _, key in world.gl.arrays if key not in ("labels", "shadow")}
            assert (len(scene) > 4) if on_cpu else (len(scene) == 1)
            if cull:
                assert len(batches.group) > 2 * len(batches.groups)  # cut into cells
                skipped = ~batches.visible(_perspective(eye, eye + 10 * heading, fov_deg=70.0))
                assert batches.count[skipped].sum() > 0.3 * batches.count.sum()
            else:
                assert len(batches.group) == len(batches.groups)
    reference = images[True, True]
    for other in (images[True, False], images[False, False]):
        # the colour to a level: the ways compile the materials into different programs, and
        # Mesa 25's llvmpipe rounds one pixel of this image a level apart between them (Mesa
        # 22.3 none); what is drawn where, depth and ids, is the same to the bit
        difference = np.abs(reference.rgb.astype(int) - other.rgb.astype(int))
        assert difference.max() <= 1 and (difference.max(axis=2) > 0).mean() < 1e-4
        assert np.array_equal(reference.depth_m, other.depth_m)
        assert np.array_equal(reference.segmentation, other.segmentation)


def test_walls_and_windows_facing_away_from_the_sun_are_drawn_without_the_shadow_lookup():
    """Facade and window triangles whose normal points away from the sun go to their own groups
    (compiled with SUN_AVERTED and without SHADOWS); those facing it, roofs and everything else
    keep theirs. Windows cast no shadow (their walls do); averted walls still do."""
    materials = [Material.FACADE, Material.FACADE, Material.FACADE, Material.WINDOW,
                 Material.WINDOW_LIT, Material.ASPHALT]  # fmt: skip
    normals = [(1, 0, 0), (-1, 0, 0), (0, 0, 1), (-1, 0, 0), (1, 0, 0), (-1, 0, 0)]
    rows = np.zeros((3 * len(materials), FLOATS_PER_VERTEX), np.float32)
    for k, (material, normal) in enumerate(zip(materials, normals, strict=True)):
        rows[3 * k : 3 * k + 3, 0] = k
        rows[3 * k : 3 * k + 3, 3:6] = normal
        rows[3 * k : 3 * k + 3, -1] = material
    sun = (0.6, 0.0, 0.8)  # in the east, high
    ordered, batches = in_draw_order(rows, cells=False, light_direction=sun)
    group_of = dict(zip(ordered[::3, 0].astype(int).tolist(), np.repeat(
        batches.group, batches.count // 3).tolist(), strict=True))  # fmt: skip
    groups = gl_batches.MATERIAL_GROUPS
    facades = next(k for k, (m, _) in enumerate(groups) if Material.FACADE in m)
    windows = next(k for k, (m, _) in enumerate(groups) if Material.WINDOW in m)
    averted_facades, averted_windows = gl_batches.AVERTED[facades], gl_batches.AVERTED[windows]
    assert group_of[0] == facades and group_of[2] == facades  # sunward wall, roof
    assert group_of[1] == averted_facades
    assert group_of[3] == averted_windows and group_of[4] == windows
    assert group_of[5] not in gl_batches.AVERTED.values()  # only walls and windows
    for group in (averted_facades, averted_windows):
        defines = gl_batches.group_defines(group, ("SHADOWS", "FOG"))
        assert "SUN_AVERTED" in defines and "SHADOWS" not in defines and "FOG" in defines
    assert "SHADOWS" in gl_batches.group_defines(facades, ("SHADOWS",))
    assert {windows, averted_windows} <= gl_batches.NOT_CASTING
    assert not {facades, averted_facades} & gl_batches.NOT_CASTING
    # without a sun every wall keeps its group
    _, unsorted = in_draw_order(rows, cells=False)
    assert averted_facades not in unsorted.group and averted_windows not in unsorted.group


@pytest.mark.parametrize("cells", [False, True])
def test_a_kept_group_order_gives_what_sorting_afresh_gives_frame_after_frame(cells):
    """The moving bodies' order kept from frame to frame (`GroupOrder`), without cells (by
    material) and with them (by material and place): kept while the triangles' materials (and,
    with cells, their places) are the same, recomputed when they change, and every frame's
    vertices and batches are those of `in_draw_order` sorting them afresh."""
    rng = np.random.default_rng(5)
    order = gl_batches.GroupOrder(cells)
    materials = [Material.PAINT, Material.GLASS, Material.MATTE, Material.TYRE, Material.LAMP]
    codes = rng.choice(materials, size=2000)  # paint, glass and tyre: over 3000 vertices
    centres = rng.uniform(-50.0, 50.0, size=(len(codes), 2))
    frames = []
    for frame in range(5):
        if frame == 1 and not cells:  # everything moved: by material alone, the same order
            centres = rng.uniform(-50.0, 50.0, size=(len(codes), 2))
        if frame == 2:  # a body appears: other materials in other places
            codes = np.concatenate([codes, rng.choice(materials, size=40)])
            centres = np.concatenate([centres, rng.uniform(-50.0, 50.0, size=(40, 2))])
        if frame == 4 and cells:  # one triangle moved: in cells, a new order
            centres = centres.copy()
            centres[7] += 30.0
        frames.append(np.concatenate([_triangle_rows(centres[k : k + 1], code)
                                      for k, code in enumerate(codes)]))  # fmt: skip
    kept = []
    for rows in frames:
        ordered, batches = order(rows)
        expected, expected_batches = in_draw_order(rows, cells=cells)
        np.testing.assert_array_equal(ordered, expected)
        for field in ("group", "first", "count", "low_m", "high_m"):
            np.testing.assert_array_equal(getattr(batches, field),
                                          getattr(expected_batches, field))  # fmt: skip
        kept.append(order.order)
    assert kept[1] is kept[0] and kept[2] is not kept[1] and kept[3] is kept[2]
    assert (kept[4] is not kept[3]) if cells else (kept[4] is kept[3])
    if not cells:
        assert len(batches.group) == 2  # paint, glass and tyre; matte and lamps: two groups
    else:
        assert len(batches.group) > 2  # a group of 3000 vertices or more is cut into cells


@pytest.mark.skipif(not gl_available(), reason="no OpenGL context (EGL) here")
def test_walls_drawn_without_the_shadow_lookup_where_the_sun_is_behind_them_look_the_same(
    site, monkeypatch
):
    """The clip at a clear noon (sun and shadows), drawn with the walls that face away from the
    sun in their own group and with every wall in one: the same image. (A window facing away
    from the sun beyond the shadow map's square would lose a highlight that Blinn-Phong put
    on it with the sun behind its wall; this view has none.)"""
    import dataclasses
    from datetime import datetime, timezone

    from drivee2e_data.scenario import Conditions, TimeOfDay, Weather

    intersection_map, scenario = site
    noon = Conditions(
        Weather.CLEAR, TimeOfDay.NOON, datetime(2026, 6, 1, 4, 0, tzinfo=timezone.utc)
    )
    scenario = dataclasses.replace(scenario, conditions=noon)
    monkeypatch.setattr(gl_context, "rasterises_on_cpu", lambda: True)  # the split is llvmpipe's
    facades = next(k for k, (m, _) in enumerate(gl_batches.MATERIAL_GROUPS)
                   if Material.FACADE in m)  # fmt: skip
    images = {}
    for averted in (True, False):
        split = dict(gl_batches.AVERTED) if averted else {}
        monkeypatch.setattr(gl_batches, "AVERTED", split)
        with World(intersection_map, scenario, renderer="gl") as world:
            assert world.gl.look.shadows
            groups = set(world.gl.static_batches.group.tolist())
            assert (gl_batches.AVERTED.get(facades, -1) in groups) == averted
            images[averted] = front_view(world, 20, (320, 180), segmentation=True, near_m=0.5)
    assert np.array_equal(images[True].rgb, images[False].rgb)
    assert np.array_equal(images[True].depth_m, images[False].depth_m)
    assert np.array_equal(images[True].segmentation, images[False].segmentation)


def test_crowns_are_detailed_near_the_eye_and_coarse_beyond_and_a_tree_stays_in_one_cell():
    """Crown batches whose box comes within FOLIAGE_DETAIL_M of the eye draw their detailed
    mesh and hide the coarse one; beyond, the reverse; other batches always draw. Triangles
    anchored at a trunk fall in the trunk's cell, wherever their own centroid lies."""
    near, far = gl_batches.NEAR_FOLIAGE, gl_batches.FAR_FOLIAGE
    reach = gl_batches.FOLIAGE_DETAIL_M
    low = np.array([[10, 0, 0], [10, 0, 0], [reach + 5, 0, 0], [reach + 5, 0, 0], [500, 0, 0]])
    batches = DrawBatches(np.array([near, far, near, far, 0]), np.arange(5) * 3,
                          np.full(5, 3), low.astype(float), low + 2.0)  # fmt: skip
    drawn = gl_batches.level_of_detail(batches, np.zeros(3))
    assert drawn.tolist() == [True, False, False, True, True]
    # a crown across a cell border: half its triangles' centroids west of it, half east
    centres = np.array([[CELL_M - 2.0, 1.0]] * 1000 + [[CELL_M + 1.0, 1.0]] * 1000)
    rows = _triangle_rows(centres, Material.FOLIAGE)
    _, by_centroid = in_draw_order(rows)
    _, by_trunk = in_draw_order(rows, anchors_xy=np.tile([CELL_M + 0.5, 1.0], (2000, 1)))
    assert len(by_centroid.group) == 2 and len(by_trunk.group) == 1
    # the one batch's box is still its triangles'
    np.testing.assert_allclose(by_trunk.low_m[0, :2], [CELL_M - 2.0, 1.0])
    np.testing.assert_allclose(by_trunk.high_m[0, :2], [CELL_M + 1.5, 1.5])
