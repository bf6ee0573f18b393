"""Actor blueprints: a shape per class and size, coloured deterministically per track.

The annotation box of an actor is its blueprint's box (as the paper adjusts boxes to the asset
used); the source's size is kept beside it, so the size error can be reported. The GL renderer
draws each actor's procedural model (`sim.models`); the pybullet body carries the model's
shape as a compound of convex parts (what LiDAR rays hit) and, for pybullet's own renderers,
the simple boxes of before as its visual shape.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from drivee2e_data import store
from drivee2e_data.scenario import AgentClass, Track
from drivee2e_data.sim.models import ModelMesh
from drivee2e_data.sim.obj_text import obj_text

# pybullet takes at most 16 shapes in one compound (MAX_COMPOUND_COLLISION_SHAPES in its
# shared-memory commands; the rest are dropped without a word)
MAX_PARTS = 16
# a vehicle's rigid body is cut into cells, each hulled: two layers up its height (sills and
# greenhouse apart, so no hull fills the air beside the tumblehome), the rest of the parts along
# its length (bonnet, cabin and boot apart)
LAYERS = 2

# (name, length, width, height) of the blueprints; a track takes the nearest of its class.
BLUEPRINTS: dict[AgentClass, tuple[tuple[str, float, float, float], ...]] = {
    AgentClass.CAR: (
        ("sedan", 4.6, 1.85, 1.45),
        ("compact", 3.9, 1.7, 1.45),
        ("suv", 4.8, 1.95, 1.75),
    ),
    AgentClass.VAN: (("van", 5.2, 2.0, 2.1), ("minibus", 6.0, 2.1, 2.5)),
    AgentClass.TRUCK: (("box_truck", 7.5, 2.5, 3.4), ("truck", 10.0, 2.5, 3.6)),
    AgentClass.BUS: (("bus", 11.5, 2.55, 3.2), ("articulated_bus", 18.0, 2.55, 3.2)),
    AgentClass.PEDESTRIAN: (("pedestrian", 0.6, 0.6, 1.72),),
    AgentClass.CYCLIST: (("bicycle_with_rider", 1.8, 0.65, 1.7),),
    AgentClass.TRICYCLIST: (("tricycle_with_rider", 2.8, 1.2, 1.8),),
    AgentClass.MOTORCYCLIST: (("motorcycle_with_rider", 2.1, 0.8, 1.6),),
}


@dataclass(frozen=True)
class Blueprint:
    name: str
    size_m: tuple[float, float, float]  # length, width, height: the annotation box
    rgba: tuple[float, float, float, float]


def choose_blueprint(track: Track) -> Blueprint:
    """The blueprint of the track's class nearest its median logged size; a colour from its id."""
    valid = track.valid
    logged = np.array(
        [
            np.median(track.length_m[valid]),
            np.median(track.width_m[valid]),
            np.median(track.height_m[valid]),
        ]
    )
    options = BLUEPRINTS[track.agent_class]
    name, *size = min(options, key=lambda o: float(np.abs(np.array(o[1:]) - logged).sum()))
    digest = hashlib.sha256(track.track_id.encode()).digest()
    rgba = (
        0.15 + 0.7 * digest[0] / 255,
        0.15 + 0.7 * digest[1] / 255,
        0.15 + 0.7 * digest[2] / 255,
        1.0,
    )
    return Blueprint(name, (float(size[0]), float(size[1]), float(size[2])), rgba)


def convex_parts(model: ModelMesh) -> list[NDArray[np.float64]]:
    """The model as at most `MAX_PARTS` convex pieces `(V_k, 3)`: each moving joint's
    vertices (a wheel, a limb), and the rigid body in the cells left: along its longest axis,
    in `LAYERS` layers where that axis is horizontal (each triangle in the cell of its
    centroid)."""
    positions = model.positions.astype(np.float64).reshape(-1, 3, 3)
    joints = model.joints[::3]
    moving = [positions[joints == joint].reshape(-1, 3) for joint in np.unique(joints) if joint]
    body = positions[joints == 0]
    cells = max(MAX_PARTS - len(moving), 1)
    parts = [part for part in moving if len(part) >= 4][: MAX_PARTS - 1]
    if not len(body):
        return parts
    extent = body.reshape(-1, 3).max(axis=0) - body.reshape(-1, 3).min(axis=0)
    centres = body.mean(axis=1)
    axis = int(np.argmax(extent))
    layers = LAYERS if axis != 2 and cells >= 2 * LAYERS else 1
    slices = max(1, cells // layers)
    along, up = _bins(centres[:, axis], slices), _bins(centres[:, 2], layers)
    for index in range(slices * layers):
        chosen = body[(along == index // layers) & (up == index % layers)]
        if len(chosen):
            parts.append(chosen.reshape(-1, 3))
    return [part for part in parts if len(part) >= 4][:MAX_PARTS]


def _bins(values: NDArray[np.float64], count: int) -> NDArray[np.int64]:
    """Each value's bin among `count` equal bins over the values' range."""
    edges = np.linspace(values.min(), values.max() + 1e-9, count + 1)
    return np.clip(np.searchsorted(edges, values, side="right") - 1, 0, count - 1)


def geometry_key(model: ModelMesh) -> int:
    """What a model's collision shape depends on (`convex_parts`), as a 64-bit number: models
    with the same key have the same shape (a run's workers share the shapes' files by it, so
    the key is a digest, not a 32-bit checksum a few thousand shapes could collide in)."""
    digest = hashlib.blake2b(model.joints.tobytes(), digest_size=8)
    digest.update(model.positions.tobytes())
    return int.from_bytes(digest.digest(), "little")


def _part_files(model: ModelMesh, folder: Path, key: int) -> list[str]:
    """OBJ files of the model's convex parts (their triangles; pybullet hulls a mesh shape's
    vertices), written once per shape (`key`: its `geometry_key`) into `folder`, which the
    workers of a run may share: each file is written whole under a temporary name, then
    renamed, and the list of the parts (`actor_<key>.parts`) last, so a list found means its
    files are there."""
    listing = folder / f"actor_{key:016x}.parts"
    try:
        return [str(folder / name) for name in listing.read_text().split()]
    except FileNotFoundError:
        pass
    names = []
    for index, part in enumerate(convex_parts(model)):
        path = folder / f"actor_{key:016x}_{index:02d}.obj"
        store.write_bytes_atomic(path, obj_text(part).encode())
        names.append(path.name)
    store.write_bytes_atomic(listing, "\n".join(names).encode())
    return [str(folder / name) for name in names]


def create_actor(
    client: int,
    blueprint: Blueprint,
    model: ModelMesh | None = None,
    folder: Path | None = None,
    made: dict[int, int] | None = None,
) -> int:
    """A pybullet body for the blueprint, its origin at the box centre: its visual shape the
    blueprint's boxes (pybullet's renderers), its collision shape the `model`'s convex parts
    (files written into `folder`) or, without a model, the same boxes. `made`: the client's
    collision shapes made so far, by model geometry (`geometry_key`), shared by the bodies of
    models of one geometry (the vehicles of a blueprint: `models.vehicles.vehicle_shape`) and
    added to here; pybullet keeps a shape when a body that uses it is removed."""
    import pybullet

    length, width, height = blueprint.size_m
    if blueprint.name == "pedestrian":
        shapes = [(pybullet.GEOM_CYLINDER, {"radius": 0.22, "length": height * 0.75}, [0, 0, -height * 0.1], blueprint.rgba),
                  (pybullet.GEOM_SPHERE, {"radius": 0.12}, [0, 0, height * 0.38], (0.85, 0.7, 0.6, 1.0))]  # fmt: skip
    elif "rider" in blueprint.name:
        shapes = [(pybullet.GEOM_BOX, {"halfExtents": [length / 2, width / 4, height / 4]}, [0, 0, -height / 4], (0.1, 0.1, 0.1, 1.0)),
                  (pybullet.GEOM_BOX, {"halfExtents": [0.2, width / 2, height / 4]}, [0, 0, height / 4], blueprint.rgba)]  # fmt: skip
    else:
        cabin = 0.45 if blueprint.name in ("sedan", "compact", "suv") else 0.9
        shapes = [(pybullet.GEOM_BOX, {"halfExtents": [length / 2, width / 2, height * 0.3]}, [0, 0, -height * 0.2], blueprint.rgba),
                  (pybullet.GEOM_BOX, {"halfExtents": [length * cabin / 2, width * 0.45, height * 0.2]},
                   [-length * (1 - cabin) * 0.1, 0, height * 0.3], (0.15, 0.2, 0.25, 1.0))]  # fmt: skip
    kinds, extras, offsets, colours = zip(*shapes, strict=True)
    geometry = {
        "shapeTypes": list(kinds),
        "halfExtents": [e.get("halfExtents", [0, 0, 0]) for e in extras],
        "radii": [e.get("radius", 0.0) for e in extras],
        "lengths": [e.get("length", 0.0) for e in extras],
        "physicsClientId": client,
    }
    visual = pybullet.createVisualShapeArray(
        rgbaColors=[list(c) for c in colours],
        visualFramePositions=[list(o) for o in offsets],
        **geometry,
    )
    # LiDAR rays hit what the cameras see (and what the depth-image LiDAR reads): the
    # collision shapes are the model's; the annotation box stays the blueprint's box
    if model is not None and folder is not None:
        key = geometry_key(model)
        collision = made.get(key) if made is not None else None
        if collision is None:
            files = _part_files(model, folder, key)
            collision = pybullet.createCollisionShapeArray(
                shapeTypes=[pybullet.GEOM_MESH] * len(files), fileNames=files,
                meshScales=[[1.0, 1.0, 1.0]] * len(files), physicsClientId=client,
            )  # fmt: skip
            if made is not None:
                made[key] = collision
    else:
        collision = pybullet.createCollisionShapeArray(
            collisionFramePositions=[list(o) for o in offsets], **geometry
        )
    return pybullet.createMultiBody(0, collision, visual, [0, 0, -100], physicsClientId=client)
