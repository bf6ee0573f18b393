"""The actors' procedural models posed on the GPU: each model uploaded once, in its own frame,
and at every state only its joints' transforms from the model frame to the world.

`gl_vertices.PlacedModel` poses and places a model on the CPU: every vertex of every shown actor
moved, gathered into one buffer and uploaded at each state. On a GPU host that was the largest
part of a closed-loop step's CPU (posing, ordering and uploading the moving bodies 13.3 of a
worker's 24 ms observing, H200 host, 2026-11-29), while the GPU moved the same vertices again
in its vertex stage at no cost worth counting. Here the models lie in one buffer made when the
world's actors are (`VERTEX_FORMAT` with the joint's row after the position, see
`POSED_FORMAT`), and the scene, labels and shadow shaders compiled with `POSED` read each
vertex's `[R | t]` from a float texture (`shaders/scene.vert`, `shadow.vert`): four texels a
joint, the three rows of its transform and the emission of its model's head and tail lights.
A state writes every joint's texels (a few kilobytes; a hidden model's zero, which collapses
it to a point) and draws the shown models' vertex ranges, each culled against the view by a
box its model cannot leave. The vertices are the CPU's to the float32 rounding of the
shader's products (`PlacedModel` multiplies the same float32 matrices). One worker's
observing fell from 23.5-26.3 to 8.7-13.3 ms a step; with 16 workers on one H200 it stayed
(the GPU was what they waited on: docs/benchmarks.md, closed loop).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim.gl_batches import DrawBatches
from drivee2e_data.sim.gl_vertices import placed_joints
from drivee2e_data.sim.models import Animation, ModelMesh
from drivee2e_data.sim.models.mesh import JointChains, emission_levels

# position (3), joint row (1), normal (3), colour (3), body id + 1, light kind (`ModelMesh.lights`:
# the shader looks its emission up in the joint's texels), material (`Material`)
POSED_FLOATS_PER_VERTEX = 13
POSED_FORMAT = "3f 1f 3f 3f 1f 1f 1f"
POSED_INPUTS = (
    "in_position", "in_joint", "in_normal", "in_colour", "in_body", "in_emission", "in_material",
)  # fmt: skip
POSED_POSITION_ONLY = f"3f 1f {4 * (POSED_FLOATS_PER_VERTEX - 4)}x"  # the shadow pass's inputs
# the joints' texture: JOINTS_PER_ROW joints (four RGBA float texels each) to a texture row, so
# that no clip's joints run past a texture's largest width (GL guarantees 1024)
TEXELS_PER_JOINT = 4
JOINTS_PER_ROW = 256
JOINT_TEXTURE_UNIT = 3  # after the shadow map, the ground's wear and the lamps' light


def model_vertices(model: ModelMesh, body: int, first_joint: int) -> NDArray[np.float32]:
    """`(N, POSED_FLOATS_PER_VERTEX)` the vertices of `body`'s `model` in its model frame, in the
    model's order, each naming the texture row of its joint (`first_joint` + the joint)."""
    out = np.empty((len(model.positions), POSED_FLOATS_PER_VERTEX), np.float32)
    out[:, 0:3] = model.positions
    out[:, 3] = first_joint + np.asarray(model.joints, np.int64)
    out[:, 4:7] = model.normals
    out[:, 7:10] = model.colours
    out[:, 10] = body + 1
    out[:, 11] = model.lights
    out[:, 12] = model.materials
    return out


def joint_texels(
    model: ModelMesh, animation: Animation, position: Sequence[float], orientation: Sequence[float]
) -> NDArray[np.float32]:
    """`(J, TEXELS_PER_JOINT, 4)` what the shader reads of each joint of `model` posed by
    `animation` at a body's pose (pybullet's position and quaternion): the three rows of its
    model-to-world `[R | t]`, then the emission of the model's headlights and tail lights (one
    model at a time, as `PlacedModel` poses it: `JointTable.texels` poses many at once)."""
    texels = np.zeros((len(model.joint_table), TEXELS_PER_JOINT, 4), np.float32)
    texels[:, 0:3, :] = placed_joints(model, animation, position, orientation)
    texels[:, 3, 0:2] = emission_levels(animation)[1:]
    return texels


def quaternion_rotations(quaternions: NDArray[np.float64]) -> NDArray[np.float64]:
    """`(B, 3, 3)` the rotations of `(B, 4)` pybullet quaternions (x, y, z, w)."""
    x, y, z, w = np.moveaxis(np.asarray(quaternions, np.float64), -1, 0)
    rotations = np.empty((len(x), 3, 3))
    rotations[:, 0, 0] = 1 - 2 * (y * y + z * z)
    rotations[:, 0, 1] = 2 * (x * y - z * w)
    rotations[:, 0, 2] = 2 * (x * z + y * w)
    rotations[:, 1, 0] = 2 * (x * y + z * w)
    rotations[:, 1, 1] = 1 - 2 * (x * x + z * z)
    rotations[:, 1, 2] = 2 * (y * z - x * w)
    rotations[:, 2, 0] = 2 * (x * z - y * w)
    rotations[:, 2, 1] = 2 * (y * z + x * w)
    rotations[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return rotations


class JointTable:
    """The joints of many models (`models.mesh.JointChains`, which poses them together), placed
    at their bodies' poses as the shader's texels; `owner` `(G,)` the model of each joint."""

    def __init__(self, models: Sequence[ModelMesh]) -> None:
        self.chains = JointChains(models)
        self.owner = self.chains.owner

    def texels(
        self,
        positions: NDArray[np.float64],
        quaternions: NDArray[np.float64],
        animations: Sequence[Animation],
    ) -> NDArray[np.float32]:
        """`(G, TEXELS_PER_JOINT, 4)` every joint's texels (`joint_texels`) with model k posed by
        `animations[k]` at `positions[k]` `(3,)` and `quaternions[k]` (pybullet's x, y, z, w)."""
        transforms = self.chains.transforms(animations)
        body = quaternion_rotations(quaternions)[self.owner]  # (G, 3, 3)
        texels = np.zeros((len(self.owner), TEXELS_PER_JOINT, 4), np.float32)
        texels[:, 0:3, 0:3] = body @ transforms[:, :, :3]
        texels[:, 0:3, 3] = (body @ transforms[:, :, 3:])[:, :, 0] + np.asarray(
            positions, np.float64
        )[self.owner]
        lights = np.array([emission_levels(a)[1:] for a in animations], np.float64)
        texels[:, 3, 0:2] = lights.reshape(-1, 2)[self.owner]
        return texels


class PosedModels:
    """Every actor body's model in one vertex buffer of `context`, posed by `pose` (see the
    module's docstring). `batches`: the shown models' vertex ranges, a batch each, in material
    group 0 (a GPU draws all groups with one program) and bounded by a cube the model cannot
    leave (`reach_m`), for the views' frustum tests; neighbours are drawn as one run."""

    def __init__(self, context, models: Mapping[int, ModelMesh]) -> None:
        self.models = dict(models)
        parts = [np.zeros((0, POSED_FLOATS_PER_VERTEX), np.float32)]
        # body -> (first vertex, vertex count, first joint row)
        self.ranges: dict[int, tuple[int, int, int]] = {}
        vertex = joint = 0
        for body in sorted(self.models):
            model = self.models[body]
            parts.append(model_vertices(model, body, joint))
            self.ranges[body] = (vertex, len(model.positions), joint)
            vertex += len(model.positions)
            joint += len(model.joint_table)
        vertices = np.concatenate(parts)
        rows = max(1, -(-joint // JOINTS_PER_ROW))
        self.texels = np.zeros((rows * JOINTS_PER_ROW, TEXELS_PER_JOINT, 4), np.float32)
        self.buffer = context.buffer(vertices.tobytes() or b"\0" * 4 * POSED_FLOATS_PER_VERTEX)
        self.texture = context.texture(
            (JOINTS_PER_ROW * TEXELS_PER_JOINT, rows), 4, self.texels.tobytes(), dtype="f4"
        )
        import moderngl

        self.texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.batches = DrawBatches.empty()
        self.bodies = sorted(self.models)
        self.slot = {body: slot for slot, body in enumerate(self.bodies)}
        self.joints = JointTable([self.models[body] for body in self.bodies])
        # every model's last pose (a hidden one's texels are zeroed, whatever its pose)
        self.positions = np.zeros((len(self.bodies), 3))
        self.quaternions = np.tile([0.0, 0.0, 0.0, 1.0], (len(self.bodies), 1))
        self.animations = [Animation()] * len(self.bodies)
        # how far a model's vertices reach from its origin, however its joints turn (a joint
        # turns its part about a pivot inside the model's box: the box's half diagonal from
        # the pivot, at most the model's reach twice); each shown model's batch is a cube of
        # this half side about its body's position, tested against each view's frustum
        self.reach_m = np.array(
            [2.0 * float(np.linalg.norm(np.abs(self.models[b].positions).max(axis=0)))
             for b in self.bodies], np.float64)  # fmt: skip

    def pose(
        self, placements: Sequence[tuple[int, Sequence[float], Sequence[float], Animation]]
    ) -> None:
        """The models shown now, each `(body, position, quaternion, animation)`: their joints'
        texels written and uploaded, `batches` made of their vertex ranges; every other model
        is not drawn."""
        shown = np.zeros(len(self.bodies), bool)
        for body, position, orientation, animation in placements:
            slot = self.slot[body]
            self.positions[slot] = position
            self.quaternions[slot] = orientation
            self.animations[slot] = animation
            shown[slot] = True
        if self.bodies:
            texels = self.joints.texels(self.positions, self.quaternions, self.animations)
            # a model not shown has every vertex at the origin: its triangles have no area, so
            # a draw that spans it (a run joined across a gap, `DrawBatches.runs`) draws nothing
            texels[~shown[self.joints.owner]] = 0.0
            self.texels[: len(texels)] = texels
        self.texture.write(self.texels.tobytes())
        slots = np.flatnonzero(shown)  # in buffer order: the bodies are sorted
        ranges = np.array([self.ranges[self.bodies[k]][:2] for k in slots], np.int64)
        reach = self.reach_m[slots, None]
        self.batches = DrawBatches(
            group=np.zeros(len(slots), np.int64),
            first=ranges[:, 0] if len(slots) else np.zeros(0, np.int64),
            count=ranges[:, 1] if len(slots) else np.zeros(0, np.int64),
            low_m=self.positions[slots] - reach,
            high_m=self.positions[slots] + reach,
        )

    def release(self) -> None:
        self.buffer.release()
        self.texture.release()
