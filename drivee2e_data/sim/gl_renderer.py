"""The world drawn with OpenGL through moderngl, outside pybullet's `getCameraImage`.

pybullet stays the simulator: the renderer reads every body's visual shapes from it once
(`getVisualShapeData`: the twin's mesh files, the actors' boxes, cylinders and spheres) and its
poses (and the lamps' colours) whenever the world's state changes. The static twin is one vertex
buffer in world coordinates, the moving bodies and the signal lamps a second one rebuilt per
state; an image is two draw calls into an offscreen framebuffer that takes colour, each pixel's
depth along the view axis (written by the fragment shader, in metres) and its body id in one
pass, read straight into numpy arrays at the size asked for. pybullet's EGL plugin draws at
most 1024x768, draws the scene twice for a body mask and copies every pixel several times on
the CPU; on llvmpipe this renderer's 1600x900 camera image costs about two thirds of the CPU of
the plugin's 1024x576 one, a LiDAR view with body ids a quarter (docs/benchmarks.md).

Shading is Lambertian under the clip's `Lighting`: a neutral ambient share (the sky) plus the
sun's diffuse share in its colour and from its direction, which pybullet's renderer never took.
Pixels are square and unfiltered (no antialiasing), as with pybullet's renderers.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import logging
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim.conditions import Lighting
from drivee2e_data.sim.twin import box_mesh, prism_mesh, sphere_mesh

LOG = logging.getLogger(__name__)
SKY_RGB = (0.70, 0.78, 0.90)  # background where nothing is drawn
CYLINDER_SIDES = 16
# spheres are small here (signal lamps and heads, 12 cm): 80 triangles each, half the twin's
# crowns' (42 lamps are most of what moves or changes colour)
SPHERE_RINGS, SPHERE_SEGMENTS = 5, 10
FLOATS_PER_VERTEX = 11  # position (3), normal (3), colour (3), body id + 1, emission (0 or 1)
VERTEX_FORMAT = "3f 3f 3f 1f 1f"
VERTEX_INPUTS = ("in_position", "in_normal", "in_colour", "in_body", "in_emission")

VERTEX_SHADER = """
#version 330
uniform mat4 mvp;
in vec3 in_position;
in vec3 in_normal;
in vec3 in_colour;
in float in_body;
in float in_emission;
out vec3 normal;
out vec3 colour;
out float eye_depth;
flat out float body;
flat out float emission;
void main() {
    gl_Position = mvp * vec4(in_position, 1.0);
    eye_depth = gl_Position.w;  // a perspective projection's w: the depth along the view axis
    normal = in_normal;
    colour = in_colour;
    body = in_body;
    emission = in_emission;
}
"""
FRAGMENT_SHADER = """
#version 330
uniform vec3 light_direction;
uniform vec3 light_rgb;
uniform float ambient;
uniform float diffuse;
in vec3 normal;
in vec3 colour;
in float eye_depth;
flat in float body;
flat in float emission;
layout(location = 0) out vec4 rgba;
layout(location = 1) out float body_out;
layout(location = 2) out float depth_out;
void main() {
    float lambert = max(dot(normalize(normal), light_direction), 0.0);
    vec3 lit = min(colour * (ambient + diffuse * lambert * light_rgb), vec3(1.0));
    rgba = vec4(mix(lit, colour, emission), 1.0);  // lamps shine their own colour
    body_out = body;
    depth_out = eye_depth;
}
"""


@functools.cache
def _context():
    """The process's OpenGL context (EGL, headless), made on first use; None where none can
    be made (no moderngl, no EGL driver)."""
    try:
        import moderngl

        with current(None):
            return moderngl.create_standalone_context(backend="egl")
    except Exception as error:  # any failure means: no GL here
        LOG.debug("no OpenGL context: %s", error)
        return None


@functools.cache
def _libegl():
    """libEGL through ctypes (to save and restore another library's current context), or None."""
    name = ctypes.util.find_library("EGL")
    if name is None:
        return None
    library = ctypes.CDLL(name)
    for function in ("eglGetCurrentDisplay", "eglGetCurrentSurface", "eglGetCurrentContext"):
        getattr(library, function).restype = ctypes.c_void_p
    library.eglGetCurrentSurface.argtypes = [ctypes.c_int]
    library.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
    return library


EGL_DRAW, EGL_READ = 0x3059, 0x305A


@contextmanager
def current(context) -> Iterator[None]:
    """`context` (a moderngl context; None: one the block makes) current for the block, and
    whatever EGL context was current before (pybullet's EGL plugin's, in a process that has both
    kinds of world) made current again after it: the plugin never makes its own current again,
    and would draw into ours."""
    egl = _libegl()
    saved = None
    if egl is not None and egl.eglGetCurrentContext():
        saved = (egl.eglGetCurrentDisplay(), egl.eglGetCurrentSurface(EGL_DRAW),
                 egl.eglGetCurrentSurface(EGL_READ), egl.eglGetCurrentContext())  # fmt: skip
    try:
        if context is None:  # the block makes its own context (current)
            yield
        else:
            with context:
                yield
    finally:
        if saved is not None:
            egl.eglMakeCurrent(*saved)


def gl_available() -> bool:
    """Whether an OpenGL 3.3 context can be made in this process (made once, then kept)."""
    return _context() is not None


def gl_renderer_name() -> str:
    """The GL driver's renderer string (for example 'llvmpipe ...' or 'NVIDIA H100 ...')."""
    context = _context()
    return "" if context is None else str(context.info["GL_RENDERER"])


@dataclass(frozen=True)
class _Mesh:
    """Triangles as a vertex soup in a body's frame: `(3T, 3)` positions and normals, and the
    index of the visual shape (its colour) of each vertex."""

    positions: NDArray[np.float32]
    normals: NDArray[np.float32]
    shape: NDArray[np.int32]


def _flat_triangles(
    vertices: NDArray, indices: NDArray, normals: NDArray | None = None
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """An indexed mesh as a vertex soup, with the given per-vertex normals or each triangle's."""
    corners = np.asarray(indices, dtype=np.int64).reshape(-1)
    positions = np.asarray(vertices, dtype=np.float64)[corners]
    if normals is not None:
        return positions.astype(np.float32), np.asarray(normals, np.float64)[corners].astype(
            np.float32
        )
    triangles = positions.reshape(-1, 3, 3)
    face = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    face /= np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-12)
    return positions.astype(np.float32), np.repeat(face, 3, axis=0).astype(np.float32)


def read_obj(path: Path) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The triangles of an OBJ file as written by `sim.twin` (`v`, optional `vn`, `f` with
    1-based indices, `a` or `a//n`), as a vertex soup with normals."""
    vertices, normals, faces = [], [], []
    for line in path.read_text().splitlines():
        kind, _, rest = line.partition(" ")
        if kind == "v":
            vertices.append(rest.split())
        elif kind == "vn":
            normals.append(rest.split())
        elif kind == "f":
            faces.append([int(token.split("/")[0]) - 1 for token in rest.split()])
    if not faces:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    vertex_array = np.asarray(vertices, dtype=np.float64)
    normal_array = np.asarray(normals, dtype=np.float64) if normals else None
    return _flat_triangles(vertex_array, np.asarray(faces), normal_array)


def primitive_triangles(
    geometry: int, dimensions: Sequence[float], mesh_file: str
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The triangles of one pybullet visual shape in its own frame (pybullet's geometry codes:
    2 sphere (radius), 3 box (full extents), 4 cylinder (length, radius), 5 mesh (file))."""
    if geometry == 5:
        return read_obj(Path(mesh_file))
    if geometry == 3:
        return _flat_triangles(*box_mesh(np.zeros(3), 0.0, np.asarray(dimensions[:3])))
    if geometry == 2:
        vertices, indices, normals = sphere_mesh(
            np.zeros(3), float(dimensions[0]), rings=SPHERE_RINGS, segments=SPHERE_SEGMENTS
        )
        return _flat_triangles(vertices, indices, normals)
    if geometry == 4:
        length, radius = float(dimensions[0]), float(dimensions[1])
        angles = np.linspace(0.0, 2 * np.pi, CYLINDER_SIDES, endpoint=False)
        circle = radius * np.column_stack([np.cos(angles), np.sin(angles)])
        return _flat_triangles(*prism_mesh(circle, -0.5 * length, 0.5 * length))
    raise ValueError(f"pybullet visual geometry {geometry}: the GL renderer draws 2, 3, 4 and 5")


def _rotation(quaternion: Sequence[float]) -> NDArray[np.float64]:
    """3x3 rotation of a pybullet quaternion (x, y, z, w)."""
    x, y, z, w = quaternion
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


class _Body:
    """One body's visual shapes in its base frame, and each shape's colour as first read."""

    def __init__(self, p, client: int, body: int) -> None:
        self.body = body
        # each list starts empty-shaped: a body without visual shapes is an empty mesh
        positions, normals = [np.zeros((0, 3))], [np.zeros((0, 3))]
        shapes = [np.zeros(0, np.int32)]
        shape_data = p.getVisualShapeData(body, physicsClientId=client)
        for index, data in enumerate(shape_data):
            local_position, local_orientation = data[5], data[6]
            triangles, triangle_normals = primitive_triangles(data[2], data[3], data[4].decode())
            rotation = _rotation(local_orientation)
            positions.append(triangles @ rotation.T + np.asarray(local_position))
            normals.append(triangle_normals @ rotation.T)
            shapes.append(np.full(len(triangles), index, np.int32))
        self.mesh = _Mesh(
            np.concatenate(positions).astype(np.float32),
            np.concatenate(normals).astype(np.float32),
            np.concatenate(shapes),
        )
        self.colours = _colours(shape_data)

    def vertices(self, p, client: int, lamp: bool) -> NDArray[np.float32]:
        """`(3T, FLOATS_PER_VERTEX)` the body at its pose now, in world coordinates; a `lamp`
        has its colours read again and shines them unshaded."""
        position, orientation = p.getBasePositionAndOrientation(self.body, physicsClientId=client)
        if lamp:
            self.colours = _colours(p.getVisualShapeData(self.body, physicsClientId=client))
        rotation = _rotation(orientation)
        out = np.empty((len(self.mesh.positions), FLOATS_PER_VERTEX), np.float32)
        out[:, 0:3] = self.mesh.positions @ rotation.T + np.asarray(position)
        out[:, 3:6] = self.mesh.normals @ rotation.T
        out[:, 6:9] = self.colours[self.mesh.shape] if len(self.colours) else 0.0
        out[:, 9] = self.body + 1
        out[:, 10] = 1.0 if lamp else 0.0
        return out


def _colours(shape_data) -> NDArray[np.float32]:
    """`(S, 3)` RGB of each visual shape in pybullet's `getVisualShapeData` answer."""
    return np.asarray([data[7][:3] for data in shape_data], dtype=np.float32).reshape(-1, 3)


class GLRenderer:
    """Draws one pybullet client's bodies: `static` ones (never moved nor recoloured after the
    renderer is made) into a buffer once, in the order given; every other body's pose is read
    again at each `sync`. `lamps` (signal lamps) have their colours read again too, and shine
    them whatever the light (a lit lamp facing away from the sun is as bright as one facing
    it)."""

    def __init__(
        self,
        p,
        client: int,
        static: Sequence[int],
        lighting: Lighting,
        lamps: Sequence[int] = (),
    ) -> None:
        import moderngl

        context = _context()
        if context is None:
            raise RuntimeError("no OpenGL context can be made here (moderngl with EGL)")
        self.p, self.client, self.context = p, client, context
        self.static, self.lamps = frozenset(static), frozenset(lamps)
        with current(context):
            self.program = context.program(
                vertex_shader=VERTEX_SHADER, fragment_shader=FRAGMENT_SHADER
            )
            static_vertices = np.concatenate(
                [np.zeros((0, FLOATS_PER_VERTEX), np.float32)]
                + [_Body(p, client, body).vertices(p, client, False) for body in static]
            )
            self.static_count = len(static_vertices)
            self.static_buffer = context.buffer(
                static_vertices.tobytes() or b"\0" * 4 * FLOATS_PER_VERTEX
            )
            self.static_array = self._vertex_array(self.static_buffer)
            self.dynamic_buffer = context.buffer(reserve=4 * FLOATS_PER_VERTEX, dynamic=True)
            self.dynamic_array = self._vertex_array(self.dynamic_buffer)
        self.dynamic_count = 0
        self.bodies: dict[int, _Body] = {}
        self.synced: object = None
        self.framebuffers: dict[tuple[int, int], moderngl.Framebuffer] = {}
        self.set_lighting(lighting)

    def _vertex_array(self, buffer):
        """The program fed from `buffer`'s vertices (`VERTEX_FORMAT`), in the current context."""
        return self.context.vertex_array(self.program, [(buffer, VERTEX_FORMAT, *VERTEX_INPUTS)])

    def set_lighting(self, lighting: Lighting) -> None:
        with current(self.context):
            self.program["light_direction"].value = tuple(float(v) for v in lighting.direction)
            self.program["light_rgb"].value = tuple(float(v) for v in lighting.colour)
            self.program["ambient"].value = float(lighting.ambient)
            self.program["diffuse"].value = float(lighting.diffuse)

    def forget_bodies(self) -> None:
        """Read every moving body's shapes again at the next sync: bodies were removed and made
        (pybullet reuses the ids of removed bodies)."""
        self.bodies = {}
        self.synced = None

    def sync(self, state: object) -> None:
        """Read the moving bodies' poses and colours again unless `state` is the one last read
        (the world's state counter)."""
        if state == self.synced:
            return
        p, client = self.p, self.client
        present = [p.getBodyUniqueId(k, physicsClientId=client)
                   for k in range(p.getNumBodies(physicsClientId=client))]  # fmt: skip
        moving = [body for body in present if body not in self.static]
        self.bodies = {body: self.bodies.get(body) or _Body(p, client, body) for body in moving}
        parts = [np.zeros((0, FLOATS_PER_VERTEX), np.float32)]
        parts += [self.bodies[body].vertices(p, client, body in self.lamps) for body in moving]
        vertices = np.concatenate(parts)
        with current(self.context):
            if vertices.nbytes > self.dynamic_buffer.size:
                self.dynamic_array.release()
                self.dynamic_buffer.release()
                self.dynamic_buffer = self.context.buffer(reserve=2 * vertices.nbytes, dynamic=True)
                self.dynamic_array = self._vertex_array(self.dynamic_buffer)
            if vertices.nbytes:
                self.dynamic_buffer.write(vertices.tobytes())
        self.dynamic_count = len(vertices)
        self.synced = state

    def _framebuffer(self, width: int, height: int):
        framebuffer = self.framebuffers.get((width, height))
        if framebuffer is None:
            context = self.context
            framebuffer = context.framebuffer(
                color_attachments=[
                    context.renderbuffer((width, height), components=4),
                    context.renderbuffer((width, height), components=1, dtype="f4"),
                    context.renderbuffer((width, height), components=1, dtype="f4"),
                ],
                depth_attachment=context.depth_renderbuffer((width, height)),
            )
            self.framebuffers[(width, height)] = framebuffer
        return framebuffer

    def draw(
        self,
        view: Sequence[float],
        projection: Sequence[float],
        width: int,
        height: int,
        segmentation: bool,
        far_m: float,
    ) -> tuple[NDArray[np.uint8], NDArray[np.float32], NDArray[np.int32] | None]:
        """RGB `(H, W, 3)`, the depth along the view axis `(H, W)` in metres (`far_m` where
        nothing is drawn) and, with `segmentation`, the body id per pixel `(H, W)` (-1 for
        none), for pybullet's column-major `view` and perspective `projection` matrices; row 0
        is the top of the image. Depth is the fragment's own (float32), not read back from a
        depth buffer and linearised: finer than any depth buffer's step, and no CPU work."""
        import moderngl

        # drawn upside down (y flipped in clip space), so that OpenGL's bottom-up rows read out
        # top row first; the flip mirrors the winding, so the front faces turn clockwise
        flip = np.diag([1.0, -1.0, 1.0, 1.0])
        matrix = (
            flip
            @ np.asarray(projection, dtype=np.float64).reshape(4, 4).T
            @ np.asarray(view, dtype=np.float64).reshape(4, 4).T
        )
        with current(self.context):
            framebuffer = self._framebuffer(width, height)
            framebuffer.use()
            for attachment, value in enumerate(((*SKY_RGB, 1.0), (0.0,) * 4, (far_m,) * 4)):
                framebuffer.color_mask = tuple((k == attachment,) * 4 for k in range(3))
                framebuffer.clear(*value, depth=1.0)
            framebuffer.color_mask = ((True,) * 4,) * 3
            self.context.enable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
            self.context.front_face = "cw"
            self.program["mvp"].write(matrix.T.astype(np.float32).tobytes())
            # near things first, so that the depth test spares shading what they hide
            if self.dynamic_count:
                self.dynamic_array.render(moderngl.TRIANGLES, vertices=self.dynamic_count)
            if self.static_count:
                self.static_array.render(moderngl.TRIANGLES, vertices=self.static_count)
            # read into fresh arrays: writable, and no copy of bytes
            rgb = np.empty((height, width, 3), np.uint8)
            framebuffer.read_into(rgb, components=3, attachment=0)
            depth_m = np.empty((height, width), np.float32)
            framebuffer.read_into(depth_m, components=1, attachment=2, dtype="f4")
            body = None
            if segmentation:
                ids = np.empty((height, width), np.float32)
                framebuffer.read_into(ids, components=1, attachment=1, dtype="f4")
                body = ids.astype(np.int32)
                body -= 1
        return rgb, depth_m, body

    def release(self) -> None:
        """Free the buffers and framebuffers (the context stays for the process's next world)."""
        with current(self.context):
            for framebuffer in self.framebuffers.values():
                for attachment in (*framebuffer.color_attachments, framebuffer.depth_attachment):
                    attachment.release()
                framebuffer.release()
            for resource in (self.static_array, self.static_buffer, self.dynamic_array,
                             self.dynamic_buffer, self.program):  # fmt: skip
                resource.release()
        self.framebuffers = {}
