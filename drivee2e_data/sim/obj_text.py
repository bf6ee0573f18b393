"""Wavefront OBJ text of a triangle mesh, the form pybullet's mesh shapes are read from.

Formatted by one `%` over all values: a line at a time through f-strings took a fifth of a
world's set-up (twin and actors, 0.64 s a clip on this machine, docs/benchmarks.md)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def obj_text(
    vertices: NDArray[np.floating],
    triangles: NDArray[np.integer] | None = None,
    normals: NDArray[np.floating] | None = None,
) -> str:
    """The OBJ text of `vertices` (V, 3) and `triangles` (T, 3) of 0-based vertex indices (None:
    every three vertices in order make one), with per-vertex `normals` (V, 3) where given;
    coordinates to 0.1 mm, one record a line, ending in a newline."""
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if triangles is None:
        triangles = np.arange(len(vertices) - len(vertices) % 3).reshape(-1, 3)
    corners = np.asarray(triangles, dtype=np.int64).reshape(-1, 3) + 1
    text = "v %.4f %.4f %.4f\n" * len(vertices) % tuple(vertices.ravel().tolist())
    if normals is None:
        return text + "f %d %d %d\n" * len(corners) % tuple(corners.ravel().tolist())
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    text += "vn %.4f %.4f %.4f\n" * len(normals) % tuple(normals.ravel().tolist())
    both = np.repeat(corners, 2, axis=1)  # vertex//normal, the same index
    return text + "f %d//%d %d//%d %d//%d\n" * len(corners) % tuple(both.ravel().tolist())
