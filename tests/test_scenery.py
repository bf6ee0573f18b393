"""Scenery a twin adds: the windows of a building's facades."""

from __future__ import annotations

import numpy as np
import shapely

from drivee2e_data.sim.scenery import (
    BAY_M,
    LIT_WINDOW_SHARE,
    PARAPET_M,
    WINDOW_PROUD_M,
    facade_windows,
)


def test_a_20_by_10_m_block_of_9_m_has_two_rows_of_fourteen_windows_out_of_its_walls():
    footprint = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 10.0], [0.0, 10.0]])
    windows = facade_windows(footprint, 9.0, seed=1)
    quads = windows.vertices.reshape(-1, 4, 3)
    # bays of 3.4 m: 5 on each 20 m wall, 2 on each 10 m wall; storeys of 3.2 m: the first
    # (4.16-5.824 m) and the second, cut to end 0.15 m under the roof (7.36-8.85 m)
    assert len(quads) == 2 * (5 + 2 + 5 + 2) == len(windows.lit)
    np.testing.assert_allclose(sorted(set(np.round(quads[:, :, 2].ravel(), 6))),
                               [4.16, 5.824, 7.36, 9.0 - PARAPET_M])  # fmt: skip
    # each window stands 2 cm out from its wall, inside the wall's length
    block = shapely.Polygon(footprint)
    for quad in quads:
        assert block.exterior.distance(shapely.Point(quad[0, :2])) < 1e-9 + WINDOW_PROUD_M
        assert not block.contains(shapely.Point(quad[:, :2].mean(axis=0)))
        width = np.hypot(*(quad[1, :2] - quad[0, :2]))
        assert abs(width - 0.56 * BAY_M) < 1e-9  # 22% to 78% of its bay
    # the south wall (y = 0) is seen from outside (y < 0): its windows' triangles wind so
    south = quads[np.all(quads[:, :, 1] < 0, axis=1)]
    assert len(south) == 10
    assert np.allclose(south[:, :, 1], -WINDOW_PROUD_M)
    first = south[0]
    normal = np.cross(first[1] - first[0], first[2] - first[0])
    assert normal[1] < 0  # counter-clockwise seen from the south: facing out
    # the five bays are centred on the 20 m wall: 1.5 m of wall at each end
    x = np.sort(south[south[:, 0, 2] < 6, :, 0].min(axis=1))
    np.testing.assert_allclose(x, 1.5 + BAY_M * np.arange(5) + 0.22 * BAY_M)


def test_a_ground_floor_alone_has_no_windows_and_lit_windows_repeat_by_seed():
    footprint = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 30.0], [0.0, 30.0]])
    assert len(facade_windows(footprint, 4.0, seed=1).lit) == 0
    tall = facade_windows(footprint, 60.0, seed=7)
    again = facade_windows(footprint, 60.0, seed=7)
    other = facade_windows(footprint, 60.0, seed=8)
    np.testing.assert_array_equal(tall.lit, again.lit)
    assert not np.array_equal(tall.lit, other.lit)
    assert abs((tall.lit >= 0).mean() - LIT_WINDOW_SHARE) < 0.05
    vertices, indices = tall.subset(tall.lit >= 0)
    assert len(vertices) == 4 * (tall.lit >= 0).sum() and len(indices) == 6 * (tall.lit >= 0).sum()
