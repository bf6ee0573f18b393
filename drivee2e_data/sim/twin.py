"""A digital twin of an intersection in pybullet: a `TwinPlan` (`sim.twin_plan`) made into
bodies, with the lamps `Twin.show` lights by state and the markings' raster the LiDAR reads.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import shapely
from numpy.typing import NDArray

from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.processes import process_running
from drivee2e_data.scenario import SignalState
from drivee2e_data.sim.scenery import WearRaster
from drivee2e_data.sim.twin_plan import (
    LAMP_OFF_RGBA,
    PAINT_KINDS,
    TwinMesh,
    TwinPlan,
    plan_twin,
)

PAINT_RASTER_M = 0.05  # cell size of the paint raster (lines are 0.15 m wide)
LAMP_ON = {
    SignalState.RED: (1.0, 0.05, 0.05, 1.0),
    SignalState.YELLOW: (1.0, 0.8, 0.0, 1.0),
    SignalState.GREEN: (0.05, 1.0, 0.2, 1.0),
}

MESH_FOLDER_PREFIX = "drivee2e_twin_"


def mesh_folder(parent: Path | None = None) -> Path:
    """A new folder for a twin's mesh files, named for this process
    (`drivee2e_twin_<pid>_<random>` under `parent`, the system's temporary folder by default).
    Folders left there by processes that no longer run (killed before they could clean up, as a
    stopped collection's workers may be) are deleted first."""
    parent = Path(tempfile.gettempdir()) if parent is None else Path(parent)
    pattern = re.compile(rf"{MESH_FOLDER_PREFIX}(\d+)_")
    for folder in parent.glob(f"{MESH_FOLDER_PREFIX}*_*"):
        match = pattern.match(folder.name)
        if match and not process_running(int(match.group(1))):
            shutil.rmtree(folder, ignore_errors=True)
    return Path(tempfile.mkdtemp(prefix=f"{MESH_FOLDER_PREFIX}{os.getpid()}_", dir=parent))


@dataclass
class Twin:
    """Body ids of one built twin, and the lamps of each signal (red, yellow, green)."""

    client: int
    bodies: list[int] = field(default_factory=list)
    lamps: dict[str, list[tuple[int, SignalState]]] = field(default_factory=dict)
    segmentation: dict[int, str] = field(default_factory=dict)  # body id -> element kind
    # markings, drawn only: rays pass through them to the road, and `paint_raster` says
    # which road points are painted (kind, area) in the order drawn
    paint: list[tuple[str, shapely.Geometry]] = field(default_factory=list)
    _raster: PaintRaster | None = None
    meshes: list[TwinMesh] = field(default_factory=list)  # what the GL renderer draws
    street_lamps: list[tuple[float, float, float]] = field(default_factory=list)  # lamp heads
    wear: WearRaster | None = None

    def paint_raster(self) -> PaintRaster:
        """The markings rasterised (built on first use, then kept)."""
        if self._raster is None:
            self._raster = rasterize_paint(self.paint)
        return self._raster

    mesh_dir: Path = field(default_factory=lambda: mesh_folder())

    def remove_files(self) -> None:
        """Delete the mesh files written for this twin (call after disconnecting)."""
        shutil.rmtree(self.mesh_dir, ignore_errors=True)

    def show(self, states: dict[str, SignalState]) -> None:
        """Light each signal's lamp for its state (all dark for unknown or off)."""
        import pybullet

        for signal_id, lamps in self.lamps.items():
            state = states.get(signal_id, SignalState.UNKNOWN)
            for body, colour in lamps:
                rgba = LAMP_ON[colour] if colour == state else LAMP_OFF_RGBA
                pybullet.changeVisualShape(body, -1, rgbaColor=rgba, physicsClientId=self.client)


def build_twin(source: IntersectionMap | TwinPlan, client: int) -> Twin:
    """The twin of a map (planned here) or of its plan, as bodies of pybullet client `client`:
    the signal lamps, then one body per static batch, in the plan's order (so a fresh client
    numbers them alike whichever way the plan came). Each batch's OBJ file is written into the
    twin's own `mesh_dir` (pybullet's EGL renderer cannot take meshes given as vertex lists: it
    crashes); its collision shape, where it has one, is a static triangle mesh."""
    import pybullet

    plan = source if isinstance(source, TwinPlan) else plan_twin(source)
    twin = Twin(client, paint=list(plan.paint), street_lamps=list(plan.street_lamps),
                wear=plan.wear)  # fmt: skip
    for lamp in plan.lamps:
        shape = pybullet.createVisualShape(pybullet.GEOM_SPHERE, radius=lamp.radius_m,
                                           rgbaColor=LAMP_OFF_RGBA, physicsClientId=client)  # fmt: skip
        body = pybullet.createMultiBody(0, -1, shape, list(lamp.centre_m), physicsClientId=client)
        twin.bodies.append(body)
        twin.segmentation[body] = "signal"
        twin.lamps.setdefault(lamp.signal_id, []).append((body, lamp.colour))
    for planned in plan.bodies:
        path = twin.mesh_dir / f"mesh_{len(twin.bodies):05d}.obj"
        path.write_text(planned.obj)
        visual = pybullet.createVisualShape(pybullet.GEOM_MESH, fileName=str(path),
                                            rgbaColor=planned.rgba, physicsClientId=client)  # fmt: skip
        collision = -1
        if planned.collide:
            collision = pybullet.createCollisionShape(
                pybullet.GEOM_MESH, fileName=str(path),
                flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=client,
            )  # fmt: skip
        body = pybullet.createMultiBody(0, collision, visual, [0, 0, 0], physicsClientId=client)
        index = len(twin.bodies)
        twin.bodies.append(body)
        twin.segmentation[body] = planned.kind
        twin.meshes.extend(mesh if body == index else replace(mesh, body=body)
                           for mesh in planned.meshes)  # fmt: skip
    return twin


@dataclass(frozen=True)
class PaintRaster:
    """Which kind of marking covers each 5 cm cell of the road (0: none, k: `kinds[k - 1]`)."""

    origin_xy_m: NDArray[np.float64]  # world position of cell (0, 0)'s corner
    cell_m: float
    codes: NDArray[np.uint8]  # (rows along y, columns along x)
    kinds: tuple[str, ...] = PAINT_KINDS

    def kind_codes(self, xy_m: NDArray[np.float64]) -> NDArray[np.uint8]:
        """(N,) marking code under each world point `(N, 2)`, 0 off the raster."""
        cells = np.floor((np.asarray(xy_m) - self.origin_xy_m) / self.cell_m).astype(np.int64)
        rows, columns = self.codes.shape
        column, row = cells[:, 0], cells[:, 1]
        # taken by flat index: a boolean mask over (N, 2) rows and a 2-D lookup cost numpy a
        # third more (half a LiDAR sweep's road hits, 1.6 -> 1.1 ms here)
        inside = np.flatnonzero((column >= 0) & (column < columns) & (row >= 0) & (row < rows))
        result = np.zeros(len(cells), np.uint8)
        result[inside] = self.codes.reshape(-1)[row[inside] * columns + column[inside]]
        return result


def rasterize_paint(paint: list[tuple[str, shapely.Geometry]]) -> PaintRaster:
    """Markings (polygons, holes ignored: none of the twin's have any) to a `PaintRaster`."""
    import cv2

    if not paint:
        return PaintRaster(np.zeros(2), PAINT_RASTER_M, np.zeros((1, 1), np.uint8))
    x0, y0, x1, y1 = shapely.GeometryCollection([g for _, g in paint]).bounds
    origin = np.array([x0, y0]) - PAINT_RASTER_M
    shape = (
        int(np.ceil((y1 - y0) / PAINT_RASTER_M)) + 3,
        int(np.ceil((x1 - x0) / PAINT_RASTER_M)) + 3,
    )
    codes = np.zeros(shape, np.uint8)
    for kind, geometry in paint:
        outlines = [
            np.round((np.asarray(polygon.exterior.coords) - origin) / PAINT_RASTER_M * 16).astype(
                np.int32
            )
            for polygon in shapely.get_parts(geometry)
            if isinstance(polygon, shapely.Polygon) and not polygon.is_empty
        ]
        if outlines:
            cv2.fillPoly(codes, outlines, PAINT_KINDS.index(kind) + 1, cv2.LINE_8, shift=4)
    return PaintRaster(origin, PAINT_RASTER_M, codes)
