"""Static obstacles' models: inside their boxes, closed and facing out, turned and placed as
the box; a kind without a model stays its box."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_data.hdmap import StaticObstacle
from drivee2e_data.sim.obstacles import (
    ORANGE_RGBA,
    REFLECTIVE_RGBA,
    UNMODELLED_RGBA,
    obstacle_parts,
)


def _signed_volume(triangles: np.ndarray) -> float:
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@pytest.mark.parametrize(
    ("kind", "size"),
    [
        ("cone", (0.45, 0.48, 0.78)),  # nuScenes scene-0061's
        ("construction_cone", (0.4, 0.4, 0.7)),
        ("construction_barrel", (0.6, 0.6, 1.0)),
        ("bollard", (0.25, 0.34, 0.94)),  # Argoverse 2's
        ("barrier", (0.65, 1.99, 1.11)),  # nuScenes': its long side across (y)
        ("barrier", (2.0, 0.6, 0.8)),
        ("sign", (0.1, 0.7, 2.2)),
        ("stop_sign", (0.1, 0.75, 2.4)),
        ("stroller", (0.9, 0.6, 1.0)),  # no model: its box
    ],
)
def test_a_model_fills_its_box_closed_and_facing_out(kind: str, size: tuple) -> None:
    yaw, centre = 0.7, np.array([12.0, -3.0, 0.5 * size[2]])
    obstacle = StaticObstacle("o_1", kind, centre, yaw, np.array(size))
    parts = obstacle_parts(obstacle)
    assert parts
    # back into the box's frame: every vertex inside the box
    c, s = np.cos(yaw), np.sin(yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    points = np.concatenate([t.reshape(-1, 3) for _, t in parts])
    local = (points - centre) @ rotation
    assert np.all(np.abs(local) <= 0.5 * np.array(size) + 1e-9)
    # it reaches the box's floor and top, and fills most of its longer side
    assert local[:, 2].min() == pytest.approx(-0.5 * size[2])
    assert local[:, 2].max() == pytest.approx(0.5 * size[2])
    assert np.ptp(local[:, :2], axis=0).max() >= 0.8 * max(size[:2])
    # the model closed (every edge shared by two triangles) and counter-clockwise seen from
    # outside (a positive volume)
    triangles = np.concatenate([t for _, t in parts]) - centre
    assert _signed_volume(triangles) > 0.0
    edges = np.sort(np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=2), axis=2)
    _, counts = np.unique(np.round(edges.reshape(-1, 6), 9), axis=0, return_counts=True)
    assert np.all(counts == 2)
    if kind == "stroller":
        ((rgba, triangles),) = parts
        assert rgba == UNMODELLED_RGBA and _signed_volume(triangles) == pytest.approx(np.prod(size))


def test_a_cone_is_orange_with_white_bands_on_a_black_foot() -> None:
    obstacle = StaticObstacle(
        "c", "cone", np.array([0.0, 0.0, 0.35]), 0.0, np.full(3, 0.7) * [0.6, 0.6, 1]
    )
    colours = [rgba for rgba, _ in obstacle_parts(obstacle)]
    assert colours.count(REFLECTIVE_RGBA) == 2 and colours.count(ORANGE_RGBA) == 3
    assert len(colours) == 6


def test_the_twin_collides_with_the_model_not_its_box() -> None:
    """The LiDAR's rays meet the model's surfaces: down a cone's axis at its tip, beside it
    (inside the box) on its foot; a barrier's slope below its box's top edge."""
    import pybullet

    from drivee2e_data.sim.twin import build_twin
    from drivee2e_data.sim.twin_plan import plan_twin
    from tests.factories import small_map

    cone = StaticObstacle(
        "cone_1", "cone", np.array([20.0, 0.0, 0.39]), 0.0, np.array([0.45, 0.48, 0.78])
    )
    barrier = StaticObstacle(
        "barrier_1", "barrier", np.array([30.0, 0.0, 0.55]), 0.0, np.array([0.6, 2.0, 1.1])
    )
    plan = plan_twin(small_map(static_obstacles=(cone, barrier)))
    colours = {body.rgba for body in plan.bodies if body.kind == "obstacle"}
    assert {ORANGE_RGBA, REFLECTIVE_RGBA} <= colours
    client = pybullet.connect(pybullet.DIRECT)
    try:
        twin = build_twin(plan, client)
        rays = [
            ((20.0, 0.0, 3.0), (20.0, 0.0, -1.0)),  # the cone's axis: its tip
            ((20.2, 0.2, 3.0), (20.2, 0.2, -1.0)),  # a corner of its box: the foot
            ((30.25, 0.0, 3.0), (30.25, 0.0, -1.0)),  # the barrier's sloped side
        ]
        hits = pybullet.rayTestBatch([a for a, _ in rays], [b for _, b in rays],
                                     physicsClientId=client)  # fmt: skip
        heights = [hit[3][2] for hit in hits]
        assert heights[0] == pytest.approx(0.78, abs=0.02)
        assert heights[1] == pytest.approx(0.05, abs=0.01)
        assert 0.1 < heights[2] < 1.0
        twin.remove_files()
    finally:
        pybullet.disconnect(client)
