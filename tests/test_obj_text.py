"""OBJ text for pybullet's mesh shapes: the records a reader expects, 1-based, 0.1 mm."""

from __future__ import annotations

import numpy as np

from drivee2e_data.sim.obj_text import obj_text


def test_a_triangle_with_normals_reads_back_as_written():
    vertices = np.array([[0.0, 0.0, 0.0], [1.23456, 0.0, -0.00004], [0.0, 2.0, 0.5]])
    normals = np.array([[0.0, 0.0, 1.0]] * 3)
    assert obj_text(vertices, np.array([[0, 1, 2]]), normals) == (
        "v 0.0000 0.0000 0.0000\nv 1.2346 0.0000 -0.0000\nv 0.0000 2.0000 0.5000\n"
        "vn 0.0000 0.0000 1.0000\nvn 0.0000 0.0000 1.0000\nvn 0.0000 0.0000 1.0000\n"
        "f 1//1 2//2 3//3\n"
    )


def test_without_triangles_every_three_vertices_make_one():
    """A convex part's triangle soup: seven vertices make two faces (the seventh is left out of
    the faces, as pybullet's hull still takes it as a point)."""
    vertices = np.arange(21, dtype=np.float32).reshape(7, 3)
    text = obj_text(vertices)
    lines = text.splitlines()
    assert len(lines) == 9 and text.endswith("\n")
    assert lines[6] == "v 18.0000 19.0000 20.0000"
    assert lines[7:] == ["f 1 2 3", "f 4 5 6"]
