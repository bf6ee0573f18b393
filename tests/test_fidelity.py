"""Twin fidelity (`sim/fidelity.py`) on a tiny site with known answers: the twin drawn from a map
matches that map's elements, and a crosswalk moved by a known amount loses the known overlap."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_data.hdmap import Crosswalk, StopLine
from drivee2e_data.sim.fidelity import Grid, element_iou
from drivee2e_data.sim.gl_context import gl_available
from drivee2e_data.sim.world import World
from tests.factories import small_map, small_scenario

pytestmark = pytest.mark.skipif(not gl_available(), reason="no OpenGL context (EGL) here")
CROSSWALK_X_M = (20.0, 24.0)


def _site(shift_m: float = 0.0):
    """A 50 m lane along x with a 4 m crosswalk across it (moved `shift_m` along x) and a stop
    line before it."""
    x0, x1 = CROSSWALK_X_M[0] + shift_m, CROSSWALK_X_M[1] + shift_m
    crosswalk = Crosswalk("cw", np.array([[x0, -1.75], [x1, -1.75], [x1, 1.75], [x0, 1.75]]))
    stop = StopLine("stop", np.array([[18.0, -1.75, 0.0], [18.0, 1.75, 0.0]]), ("l1",))
    return small_map(crosswalks=(crosswalk,), stop_lines=(stop,))


def test_a_twin_matches_its_own_map_and_a_moved_crosswalk_loses_its_overlap():
    intersection_map = _site()
    grid = Grid(np.array([22.0, 0.0]), 240, 0.05)  # 12 m around the crosswalk
    with World(intersection_map, small_scenario(), renderer="gl") as world:
        own = element_iou(world, intersection_map, grid, fine_resolution_m=0.01, tile_px=1200)
        # the same twin measured against a map whose crosswalk lies 1 m further along:
        # 3 m of 4 overlap, over a union of 5: IoU 0.6
        moved = element_iou(world, _site(1.0), grid, fine_resolution_m=0.01, tile_px=1200)
    assert own["lanes"] >= 0.99 and own["crosswalks"] >= 0.99 and own["stop_lines"] >= 0.95
    assert moved["crosswalks"] == pytest.approx(0.6, abs=0.02)
    assert moved["lanes"] == pytest.approx(own["lanes"], abs=1e-9)  # the lanes did not move
    assert np.isnan(own["road_marks"]) or own["road_marks"] >= 0.95
