"""The world drawn with OpenGL through moderngl, outside pybullet's `getCameraImage`.

pybullet stays the simulator: the renderer takes the twin's meshes with their materials once,
and at every state change the moving bodies' poses: actors drawn from their procedural models
(posed by their `Animation`), the signal lamps and any other body from its pybullet visual
shapes (`gl_vertices`). The static twin is one vertex buffer in world coordinates, the moving
bodies a second one rebuilt per state; an image is a few draw calls into an offscreen
framebuffer that takes colour, each pixel's depth along the view axis (written by the fragment
shader, in metres) and its body id in one pass, read straight into numpy arrays at the size
asked for.

The shaders (`sim/shaders/`, one file per pass) draw the clip's `ShaderLook`: materials, the
sun's shadow map (one per state, shared by every view), the sky, fog, wet ground, street lamps
and headlights; the scene shader is compiled per look (`gl_programs.scene_variant`). Pixels
are square and unfiltered (no antialiasing), as with pybullet's renderers.
"""

from __future__ import annotations

import functools
import logging
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sim import gl_context, gl_programs
from drivee2e_data.sim.conditions import (
    Box,
    LampRaster,
    ShaderLook,
    add_headlights,
    box_union,
    lamp_raster,
    with_reduced_noise,
)
from drivee2e_data.sim.gl_batches import (
    DECALS,
    MATERIAL_GROUPS,
    NEAR_FOLIAGE,
    NOT_CASTING,
    SHADOW_ONLY,
    DrawBatches,
    GroupOrder,
    group_defines,
    in_draw_order,
    level_of_detail,
)
from drivee2e_data.sim.gl_posed import (
    JOINT_TEXTURE_UNIT,
    POSED_FORMAT,
    POSED_INPUTS,
    POSED_POSITION_ONLY,
    PosedModels,
)
from drivee2e_data.sim.gl_readback import PendingPixels, PixelReads, Read
from drivee2e_data.sim.gl_reduce import (
    NightNoise,
    ViewReduction,
    atlas,
    reduced_on_cpu,
)
from drivee2e_data.sim.gl_vertices import (
    FLOATS_PER_VERTEX,
    POSITION_ONLY,
    VERTEX_FORMAT,
    VERTEX_INPUTS,
    PlacedModel,
    _Body,
    static_anchors,
    static_vertices,
)
from drivee2e_data.sim.models import Animation, ModelMesh
from drivee2e_data.sim.scenery import WearRaster
from drivee2e_data.sim.twin_plan import TwinMesh

LOG = logging.getLogger(__name__)
CLEAR_RGB = (0.70, 0.78, 0.90)  # background of a view without a sky (labels)
LOOKS = ("camera", "plain", "labels")  # weather and night; the top view's daylight; ids only
# the colour attachments each look's shaders write, in the order of their output locations
# (scene.frag and sky.frag: colour, depth, body id; labels.frag: depth, body id); a view whose
# ids are not read gets the first two alone. Colour is held blue first (BGRA), the order the
# JPEG encoder takes: it encodes the read-back bytes as they are (`camera.encode_jpeg`)
FRAMEBUFFER_OUTPUTS = {
    "camera": ("bgra", "depth", "body"),
    "plain": ("bgra", "depth", "body"),
    "labels": ("depth", "body"),
}
# The sun's shadow map: 2048 texels over 150 m is 7 cm a texel, sharp enough for a pedestrian's
# shadow; beyond 75 m from the ego the shadows fade out (`scene.frag`'s `sunlit`)
SHADOW_MAP_PX = 2048
SHADOW_HALF_WIDTH_M = 75.0
# The map centres on the ego's position rounded to this grid: the static casters' depth stays
# the same over many frames and is drawn once into a map of its own, which each frame copies
# before drawing the moving casters (llvmpipe: 9-10 ms a frame drawing all, 4.4-4.9 copying
# and drawing the moving ones)
SHADOW_FOCUS_STEP_M = 8.0
SHADOW_DEPTH_M = 600.0
MAX_SPOTS = 6  # the nearest vehicles' headlights light the scene (`SceneLights`)
# "1" or "0": cut the scene into cells tested per view (`cull`) or not, whatever draws it
CULL_VARIABLE = "DRIVEE2E_GL_CULL"
HIDDEN_BELOW_M = -50.0  # actors parked under the ground (`world.HIDDEN_Z_M`) are not drawn


def look_at(eye: NDArray[np.float64], target: NDArray[np.float64], up: NDArray[np.float64]):
    """4x4 view matrix (OpenGL convention: the camera looks down its -z)."""
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, true_up, -forward
    view[:3, 3] = -view[:3, :3] @ eye
    return view


def shadow_matrix(light_direction: Sequence[float], centre_xy: Sequence[float]) -> NDArray:
    """4x4 world to the shadow map's clip space: an orthographic view from the sun over a
    square `2 SHADOW_HALF_WIDTH_M` wide around `centre_xy`."""
    towards_sun = np.asarray(light_direction, dtype=np.float64)
    towards_sun /= np.linalg.norm(towards_sun)
    centre = np.array([centre_xy[0], centre_xy[1], 0.0])
    up = np.array([0.0, 1.0, 0.0]) if abs(towards_sun[2]) > 0.99 else np.array([0.0, 0.0, 1.0])
    view = look_at(centre + 0.5 * SHADOW_DEPTH_M * towards_sun, centre, up)
    half, depth = SHADOW_HALF_WIDTH_M, SHADOW_DEPTH_M
    projection = np.diag([1.0 / half, 1.0 / half, -2.0 / depth, 1.0])
    projection[2, 3] = -1.0
    return projection @ view


@functools.lru_cache(maxsize=64)
def _sun_matrix(light_direction: tuple[float, ...], centre_xy: tuple[float, ...]) -> NDArray:
    """`shadow_matrix`, read-only and kept: every view of a state, and every state while the
    focus stays on its grid square, has the same (0.08 ms a call on 2 cores, 13 views a frame
    in collection)."""
    matrix = shadow_matrix(light_direction, centre_xy)
    matrix.setflags(write=False)
    return matrix


@dataclass(frozen=True)
class SceneLights:
    """What the scene's light follows at one state besides the look: the focus the sun's shadow
    map centres on (the ego) and the vehicles' headlights, nearest first (position and unit
    direction, world frame); `casters`, bodies with a model drawn into the shadow map alone,
    at (position, orientation (x, y, z, w)) in their animation: the ego, hidden from the
    cameras it carries, still casts its shadow into their view; `shadow_key`, what names the
    shadow map's content (two states with the same key share one map: a frame's cameras, with
    the ego hidden but casting, and its top view, with the ego shown); None: the state
    itself."""

    focus_xy_m: tuple[float, float] = (0.0, 0.0)
    headlights: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = ()
    casters: tuple[tuple[int, tuple[float, ...], tuple[float, ...], Animation], ...] = ()
    shadow_key: object = None


class PendingView:
    """A view drawn whose pixels may still be on their way from the GPU (`GLRenderer.queue`);
    `result` waits for them: RGB `(H, W, 3)`, depth in metres `(H, W)` (or `(N,)` at the pixels
    gathered) and the body ids `(H, W)` (-1 for none) where they were asked for."""

    def __init__(
        self,
        context,
        pixels: PendingPixels,
        width: int,
        height: int,
        colour: bool,
        segmentation: bool,
        gathered: Callable[[], NDArray[np.float32]] | None = None,
    ) -> None:
        self.context, self.pixels = context, pixels
        self.width, self.height = width, height
        self.colour, self.segmentation = colour, segmentation
        self.gathered = gathered

    def result(self) -> tuple[NDArray[np.uint8], NDArray[np.float32], NDArray[np.int32] | None]:
        with gl_context.current(self.context):
            arrays = list(self.pixels.result())
            # the depth at the pixels asked for (`GLRenderer.queue`'s `depth_at`), if gathered
            samples = self.gathered() if self.gathered is not None else None
        if self.colour:
            # the BGRA as read, seen as RGB without a copy (its first three bytes backwards):
            # `camera.encode_jpeg` hands the BGRA to the encoder as it is (`gl_readback.bgra_under`;
            # a conversion to BGR before had cost 0.8 ms a camera here, its fresh 4 MB output
            # included)
            rgb = arrays.pop(0)[..., 2::-1]
        else:
            rgb = np.zeros((self.height, self.width, 3), np.uint8)
        depth_m = samples if samples is not None else arrays.pop(0)
        body = None
        if self.segmentation:
            body = arrays.pop(0).astype(np.int32)
            body -= 1
        return rgb, depth_m, body


class DepthGather:
    """Reads a float texture at chosen texels on the GPU (`shaders/gather.vert`, transform
    feedback): its input and output buffers kept and grown for the largest set asked."""

    TEXTURE_UNIT = 3  # after the scene's shadow map, wear and lamp rasters (0-2)

    def __init__(self, context) -> None:
        self.context = context
        self.program = gl_programs.gather_program()
        self.capacity = 0
        self.texels = self.values = self.array = None

    def run(self, texture, texels: NDArray[np.int32]) -> Callable[[], NDArray[np.float32]]:
        """Queue the gather of `texture` (one float a texel) at `texels` `(N, 2)` (column,
        row); the function returned waits for and returns the `(N,)` values (the context
        current)."""
        import moderngl

        count = len(texels)
        values = np.empty(count, np.float32)
        if count == 0:
            return lambda: values
        if count > self.capacity:
            self.release()
            self.capacity = max(count, 2 * self.capacity, 4096)
            self.texels = self.context.buffer(reserve=8 * self.capacity, dynamic=True)
            self.values = self.context.buffer(reserve=4 * self.capacity)
            self.array = self.context.vertex_array(self.program, [(self.texels, "2i", "texel")])
        self.texels.write(np.ascontiguousarray(texels, dtype=np.int32).tobytes())
        texture.use(location=self.TEXTURE_UNIT)
        gl_programs.set_uniform(self.program, "image", self.TEXTURE_UNIT)
        self.array.transform(self.values, moderngl.POINTS, vertices=count)
        output = self.values

        def result() -> NDArray[np.float32]:
            output.read_into(values, size=4 * count)
            return values

        return result

    def release(self) -> None:
        for resource in (self.array, self.texels, self.values):
            if resource is not None:
                resource.release()
        self.texels = self.values = self.array = None
        self.capacity = 0


class GLRenderer:
    """Draws one pybullet client's world: the twin's `static_meshes` into a buffer once (in the
    order given); every other body's pose read again at each `sync`, drawn from its procedural
    model where it has one (`set_models`: the actors, posed by their `Animation`), else from
    its pybullet visual shapes. `lamps` (signal lamps) have their colours read again too, and
    shine them whatever the light. The shaders (`sim/shaders`) draw materials, the sky, the
    sun's shadows, fog, wet surfaces and light at night from the clip's `ShaderLook`. With
    `cull` (None: everywhere, unless `CULL_VARIABLE` says otherwise) each view draws only the
    cells of the scene its frustum meets (`gl_batches`).
    With `pose_on_gpu` (None: where a GPU draws) the actors' models are posed by the vertex
    shader (`gl_posed`), else on the CPU (`gl_vertices.PlacedModel`)."""

    def __init__(
        self,
        p,
        client: int,
        static_meshes: Sequence[TwinMesh],
        look: ShaderLook,
        lamps: Sequence[int] = (),
        street_lamps: Sequence[tuple[float, float, float]] = (),
        wear: WearRaster | None = None,
        cull: bool | None = None,
        pose_on_gpu: bool | None = None,
    ) -> None:
        import moderngl

        context = gl_context.context()
        if context is None:
            raise RuntimeError("no OpenGL context can be made here (moderngl with EGL)")
        self.p, self.client, self.context = p, client, context
        self.static = frozenset(mesh.body for mesh in static_meshes)
        self.lamps = frozenset(lamps)
        self.street_lamps = np.asarray(street_lamps, dtype=np.float64).reshape(-1, 3)
        with gl_context.current(context):
            self.labels_program = gl_programs.program("scene.vert", "labels.frag")
            self.sky_program = gl_programs.program("sky.vert", "sky.frag")
            self.shadow_program = gl_programs.program("shadow.vert", "shadow.frag")
            # cut into cells that each view tests against its frustum (None: everywhere, unless
            # CULL_VARIABLE says otherwise); drawn whole otherwise. On llvmpipe every vertex of a
            # draw is shaded on the calling thread; on an H100 or H200 only a few of the GPU's
            # units run graphics, and a closed-loop step's vertices were most of its GPU time:
            # cut, sixteen processes drawing TCP's cameras took 25.5 ms a step against 38.3
            # (`scripts/dev/bench_observers.py`)
            if cull is None:
                cull = os.environ.get(CULL_VARIABLE, "1") != "0"
            self.cull = cull
            # where a GPU draws, one scene program for every material (a branch on a
            # triangle's material costs it next to nothing, and a world compiles two programs
            # instead of a dozen); where the CPU does, one per material group
            self.one_program = not gl_context.rasterises_on_cpu()
            # llvmpipe shades every vertex of a draw on the calling thread, once per view (13
            # a collection frame): there the CPU poses the models once per state instead
            self.poses_on_gpu = (
                not gl_context.rasterises_on_cpu() if pose_on_gpu is None else pose_on_gpu
            )
            self.static_vertices = static_vertices(static_meshes)
            self.static_anchors = static_anchors(static_meshes)
            self.static_buffer = None
            self.static_light: tuple | None = None  # the sun the static batches were sorted by
            self.arrays: dict[tuple[str, object], object] = {}  # moderngl vertex arrays
            self._sort_static(look.light_direction)
            self.dynamic_buffer = context.buffer(reserve=4 * FLOATS_PER_VERTEX, dynamic=True)
            corners = np.array([[-1.0, -1.0], [3.0, -1.0], [-1.0, 3.0]], np.float32)
            self.sky_buffer = context.buffer(corners.tobytes())
            self.sky_array = context.vertex_array(
                self.sky_program, [(self.sky_buffer, "2f", "in_corner")]
            )
            reduce_program = gl_programs.program("reduce.vert", "reduce.frag")
            self.reduction = ViewReduction(context, reduce_program, self.sky_buffer)
            self.shadow_texture = context.depth_texture((SHADOW_MAP_PX, SHADOW_MAP_PX))
            self.shadow_texture.compare_func = "<="
            self.shadow_texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
            # clamped, not repeated: the shader gives full sun outside the map anyway, and
            # llvmpipe's clamped addressing saved 1-3 ms of a frame's six cameras
            self.shadow_texture.repeat_x = self.shadow_texture.repeat_y = False
            self.shadow_framebuffer = context.framebuffer(depth_attachment=self.shadow_texture)
            # the static casters' depth alone, for the sun matrix `static_shadow_key` names
            self.static_shadow_texture = context.depth_texture((SHADOW_MAP_PX, SHADOW_MAP_PX))
            self.static_shadow_framebuffer = context.framebuffer(
                depth_attachment=self.static_shadow_texture
            )
            self.static_shadow_key: bytes | None = None
            self.wear_texture = gl_programs.wear_texture(context, wear)
            self.lamp_texture = gl_programs.float_texture(context, np.zeros((1, 1, 2), np.float32))
        self.lamp_light: LampRaster | None = None
        self.lit: object = None  # the state whose headlights the light texture holds
        # the light texture's values as written, and the box its beams lit (`_light_texture`)
        self.light_values: NDArray[np.float32] | None = None
        self.light_box: Box | None = None
        self.wear = wear
        self.dynamic_batches = DrawBatches.empty()
        self.dynamic_order = GroupOrder(self.cull)  # the moving bodies' order, kept while it holds
        self.bodies: dict[int, _Body] = {}
        self.models: dict[int, ModelMesh] = {}
        self.placers: dict[int, PlacedModel] = {}  # each model body's posing, made once
        self.posed: PosedModels | None = None  # the models posed on the GPU (`poses_on_gpu`)
        # each model's vertices in the world at its last pose (position, orientation and
        # animation): a frame syncs twice (the cameras, then the top view with the ego shown),
        # only the ego moves between the two, and stationary actors keep their vertices
        self.placed: dict[int, tuple[tuple, NDArray[np.float32]]] = {}
        self.synced: object = None
        # what the dynamic buffer's drawn part was last written from (`_order_dynamic`): its
        # parts' ids (None: none yet, or bodies forgotten since), the parts, and their vertices
        # in draw order with their batches
        self.dynamic_key: tuple | None = None
        self.dynamic_parts: list[NDArray] = []
        self.dynamic_ordered: tuple[NDArray[np.float32], DrawBatches] = (
            np.zeros((0, FLOATS_PER_VERTEX), np.float32),
            DrawBatches.empty(),
        )
        self.dynamic_written = True  # whether the ordered vertices are in the buffer
        self.shadowed: object = None
        # the lights last taken, whether they were taken since the bodies' last sync
        # (`sync_bodies`), and how many times lights were taken: with the bodies' state, what
        # the light texture and the shadow map are keyed by (`drawn_state`)
        self.lights = SceneLights()
        self.lights_taken = False
        self.lights_serial = 0
        self.framebuffers: dict[tuple[int, int, tuple[str, ...]], moderngl.Framebuffer] = {}
        # queued into pixel buffers on a GPU, read at once where GL draws on the CPU
        self.readback = PixelReads(context, queued=not gl_context.rasterises_on_cpu())
        # depth read at the pixels asked for (`queue`'s `depth_at`) on a GPU; where GL draws on
        # the CPU the whole image is a copy in memory, cheaper than a gather pass (0.13 against
        # 0.2 ms for ten thousand pixels of a 1600x900 view, llvmpipe)
        self.gathers = not gl_context.rasterises_on_cpu()
        self.gather: DepthGather | None = None
        # views area-resized on the GPU (`reduced_views`) on a GPU; where GL draws on the CPU,
        # by OpenCV from the whole view read back, as the shader does it (the shader's
        # per-texel weights cost llvmpipe 3-5% more of a closed-loop step)
        self.reduces = not gl_context.rasterises_on_cpu()
        info = context.info  # the largest framebuffer side: a layout of views keeps within it
        self.max_framebuffer_px = int(min(info["GL_MAX_TEXTURE_SIZE"],
                                          info["GL_MAX_RENDERBUFFER_SIZE"],
                                          *info["GL_MAX_VIEWPORT_DIMS"]))  # fmt: skip
        self.set_look(look)

    def _scene_program(self, variant: tuple[str, ...]):
        """The scene shader compiled with `variant`'s defines."""
        return gl_programs.program("scene.vert", "scene.frag", variant)

    def _scene_defines(self, group: int, variant: tuple[str, ...]) -> tuple[str, ...]:
        """The scene shader's defines for material group `group` in `variant`: the group's own
        where the CPU draws (`gl_batches.group_defines`: llvmpipe pays for every branch), every
        material's on a GPU, where a branch on a triangle's material costs next to nothing and a
        world compiles two scene programs instead of a dozen (each new world's first frame
        waited on them). The shadow-only casters, where drawn (`draw`'s `casters_drawn`), take
        every material's too."""
        every = self.one_program or group == SHADOW_ONLY
        return group_defines(len(MATERIAL_GROUPS) if every else group, variant)

    def _array(self, buffer_name: str, program_key: object):
        """The vertex array feeding a program from the static, dynamic or posed buffer (made
        once per pair, again after the dynamic buffer grows or the posed models are made
        anew)."""
        array = self.arrays.get((buffer_name, program_key))
        if array is None and buffer_name == "posed":
            assert self.posed is not None
            if program_key == "shadow":
                content = [(self.posed.buffer, POSED_POSITION_ONLY, "in_position", "in_joint")]
            else:
                content = [(self.posed.buffer, POSED_FORMAT, *POSED_INPUTS)]
            array = self.context.vertex_array(self._posed_program(program_key), content,
                                              skip_errors=True)  # fmt: skip
            self.arrays[(buffer_name, program_key)] = array
        if array is None:
            buffer = self.static_buffer if buffer_name == "static" else self.dynamic_buffer
            if program_key == "shadow":
                array = self.context.vertex_array(self.shadow_program,
                                                  [(buffer, POSITION_ONLY, "in_position")])  # fmt: skip
            else:
                program = (
                    self.labels_program
                    if program_key == "labels"
                    else self._scene_program(program_key)
                )
                array = self.context.vertex_array(
                    program, [(buffer, VERTEX_FORMAT, *VERTEX_INPUTS)], skip_errors=True
                )
            self.arrays[(buffer_name, program_key)] = array
        return array

    def _posed_program(self, program_key: object):
        """The program of `program_key` ("shadow", "labels" or the scene's defines) compiled to
        draw the models posed on the GPU (`gl_posed`)."""
        if program_key == "shadow":
            return gl_programs.program("shadow.vert", "shadow.frag", (), ("POSED",))
        if program_key == "labels":
            return gl_programs.program("scene.vert", "labels.frag", (), ("POSED",))
        assert isinstance(program_key, tuple)
        return gl_programs.program("scene.vert", "scene.frag", program_key, ("POSED",))

    def _posed_in_use(self, program_keys: Sequence[object]) -> list:
        """The posed programs of `program_keys` where models are posed on the GPU, their joints'
        texture bound (none elsewhere): what a pass sets its uniforms into besides its own."""
        if self.posed is None:
            return []
        self.posed.texture.use(location=JOINT_TEXTURE_UNIT)
        programs = [self._posed_program(key) for key in program_keys]
        for program in programs:
            gl_programs.set_uniform(program, "joints", JOINT_TEXTURE_UNIT)
        return programs

    def set_look(self, look: ShaderLook) -> None:
        """The clip's sky, light and weather (the uniforms of `sim/shaders`)."""
        self.look = look
        self.shadowed = None
        self.static_shadow_key = None
        self.lit = None
        self._sort_static(look.light_direction)

    def _sort_static(self, light_direction: tuple[float, float, float]) -> None:
        """The twin's triangles into the static buffer in draw order (in cells where culling);
        where a program is compiled per material group (llvmpipe), the walls and windows that
        face away from the sun of `light_direction` in groups of their own
        (`gl_batches.AVERTED`: they save its shadow lookups; on a GPU they would only add
        draws), sorted again when the sun moves (a world's next clip)."""
        light = None if self.one_program else tuple(float(v) for v in light_direction)
        if light == self.static_light and self.static_buffer is not None:
            return
        vertices, self.static_batches = in_draw_order(
            self.static_vertices, self.cull, light, self.static_anchors
        )
        with gl_context.current(self.context):
            for key in [k for k in self.arrays if k[0] == "static"]:
                self.arrays.pop(key).release()
            if self.static_buffer is not None:
                self.static_buffer.release()
            self.static_buffer = self.context.buffer(
                vertices.tobytes() or b"\0" * 4 * FLOATS_PER_VERTEX
            )
        self.static_light = light

    def _apply_look(
        self,
        programs: Sequence,
        look: ShaderLook,
        camera_position: NDArray[np.float64],
        far_m: float,
        matrices: Mapping[str, NDArray[np.float64]],
    ) -> None:
        """`look`'s uniforms and the view's `matrices` (name: 4x4) into each scene program of
        the draw (one per material group), the look's into the sky's too."""
        values = {
            "light_direction": look.light_direction, "sun_rgb": look.sun_rgb,
            "zenith_rgb": look.zenith_rgb, "horizon_rgb": look.horizon_rgb,
            "cloud_cover": look.cloud_cover, "cloud_rgb": look.cloud_rgb, "sun_disc": look.sun_disc,
            "sky_ambient": look.sky_ambient, "ground_ambient": look.ground_ambient,
            "fog_rgb": look.fog_rgb, "fog_density": look.fog_density, "wetness": look.wetness,
            "lamp_rgb": look.lamp_rgb, "spot_rgb": look.spot_rgb,
            "spot_reach_m": look.spot_reach_m, "far_m": far_m,
        }  # fmt: skip
        camera = tuple(float(v) for v in camera_position)
        for name, value in values.items():
            gl_programs.set_uniform(self.sky_program, name, value)
        gl_programs.set_uniform(self.sky_program, "camera_position", camera)
        if look.lamps_on:
            raster = self._lamp_raster()
            extent = np.array(raster.values.shape[::-1], np.float64) * raster.cell_m
            values["lamp_origin"] = raster.origin_xy_m
            values["lamp_extent"] = tuple(float(v) for v in extent)
        if self.wear is not None:
            cells = np.array(self.wear.values.shape[1::-1], np.float64) * self.wear.cell_m
            values["wear_origin"] = self.wear.origin_xy_m
            values["wear_extent"] = tuple(float(v) for v in cells)
        else:
            values["wear_extent"] = (1.0, 1.0)
        values.update(shadow_map=0, wear_map=1, lamp_map=2)
        # the look's uniforms are the same at every view of a frame: set them into a program
        # only when they differ from what it was last given as a whole (`_set` would find each
        # unchanged, but thirty calls a program, a dozen programs a view, cost a millisecond)
        key = tuple(values.items())
        for program in programs:
            if gl_programs.LOOKS_SET.get(program.glo) != key:
                for name, value in values.items():
                    gl_programs.set_uniform(program, name, value)
                gl_programs.LOOKS_SET[program.glo] = key
            gl_programs.set_uniform(program, "camera_position", camera)
            for name, matrix in matrices.items():
                gl_programs.set_matrix(program, name, matrix)

    def _lamp_raster(self) -> LampRaster:
        """The street lamps' light (`conditions.lamp_raster`), made on the first draw that needs
        it (only clips with the lamps on do)."""
        if self.lamp_light is None:
            lamps = self.street_lamps
            if len(lamps):
                low, high = lamps[:, :2].min(axis=0), lamps[:, :2].max(axis=0)
                self.lamp_light = lamp_raster(lamps, (low[0], low[1], high[0], high[1]))
            else:
                self.lamp_light = LampRaster((0.0, 0.0), 1.0, np.zeros((1, 1), np.float32))
        return self.lamp_light

    def _light_texture(self, look: ShaderLook) -> None:
        """The light on level ground as a two-channel texture, the street lamps' (red) and the
        nearest `MAX_SPOTS` headlights' (green; `conditions.headlight_raster`), made again when
        the state's lights changed: one texel read in the shader for every lamp and beam. Made
        whole after a new look or new bodies; from one state to the next only the beams' box of
        both states is made again and written (the lamps stay)."""
        if self.lit == self.drawn_state:
            return
        raster = self._lamp_raster()
        spots = self.lights.headlights[:MAX_SPOTS] if look.headlights else ()
        values = self.light_values
        if self.lit is None or values is None or values.shape[:2] != raster.values.shape:
            values = np.zeros((*raster.values.shape, 2), np.float32)
            values[..., 0] = raster.values
            self.light_box = add_headlights(values[..., 1], spots, raster, look.spot_reach_m)
            if self.lamp_texture.size != values.shape[1::-1]:
                self.lamp_texture.release()
                self.lamp_texture = gl_programs.float_texture(self.context, values)
            else:
                self.lamp_texture.write(values.tobytes())
            self.light_values = values
        else:
            old = self.light_box
            if old is not None:
                values[old[0] : old[1], old[2] : old[3], 1] = 0.0
            self.light_box = add_headlights(values[..., 1], spots, raster, look.spot_reach_m)
            changed = box_union(old, self.light_box)
            if changed is not None:
                r0, r1, c0, c1 = changed
                self.lamp_texture.write(np.ascontiguousarray(values[r0:r1, c0:c1]).tobytes(),
                                        viewport=(c0, r0, c1 - c0, r1 - r0))  # fmt: skip
        self.lit = self.drawn_state

    def set_models(self, models: Mapping[int, ModelMesh]) -> None:
        """The procedural model of each actor body (drawn instead of its pybullet shapes)."""
        self.models = dict(models)
        self.placers = {}
        self.placed = {}
        if self.poses_on_gpu:
            with gl_context.current(self.context):
                if self.posed is not None:
                    for key in [k for k in self.arrays if k[0] == "posed"]:
                        self.arrays.pop(key).release()
                    self.posed.release()
                self.posed = PosedModels(self.context, self.models)

    def forget_bodies(self) -> None:
        """Read every moving body's shapes again at the next sync: bodies were removed and made
        (pybullet reuses the ids of removed bodies)."""
        self.bodies = {}
        self.placers = {}
        self.placed = {}
        self.synced = None
        self.dynamic_key, self.dynamic_parts = None, []  # ordered again, whatever is found
        self.shadowed = None
        self.lit = None

    def sync(
        self,
        state: object,
        animations: Mapping[int, Animation] | None = None,
        lights: SceneLights | None = None,
    ) -> None:
        """Read the moving bodies' poses and colours again unless `state` is the one last read
        (the world's state counter; `sync_bodies`), and take `lights` (the shadow casters'
        vertices written again) where they are not the last ones."""
        lights = lights or SceneLights()
        moved = state != self.synced
        if moved:
            self.sync_bodies(state, animations)
        elif self.lights_taken and (lights is self.lights or lights == self.lights):
            return
        casters = [self._placed(body, position, orientation, animation)
                   for body, position, orientation, animation in lights.casters
                   if body in self.models]  # fmt: skip
        with gl_context.current(self.context):
            self._write_dynamic(casters)
        self.lights, self.lights_taken = lights, True
        self.lights_serial += 1

    def sync_bodies(self, state: object, animations: Mapping[int, Animation] | None = None) -> None:
        """Read the moving bodies' poses and colours again unless `state` is the one last read:
        `sync`'s part that does not depend on its lights (the ego, placed after the scene, moves
        only those), which a closed-loop step does while its agent thinks. The shadow casters
        are written by the next `sync`."""
        if state == self.synced:
            return
        p, client = self.p, self.client
        animations = animations or {}
        present = [p.getBodyUniqueId(k, physicsClientId=client)
                   for k in range(p.getNumBodies(physicsClientId=client))]  # fmt: skip
        moving = [body for body in present if body not in self.static]
        parts = [np.zeros((0, FLOATS_PER_VERTEX), np.float32)]
        placements = []  # the models the GPU poses
        for body in moving:
            position, orientation = p.getBasePositionAndOrientation(body, physicsClientId=client)
            if position[2] < HIDDEN_BELOW_M:
                continue
            if body in self.models:
                animation = animations.get(body, Animation())
                if self.posed is not None:
                    placements.append((body, position, orientation, animation))
                else:
                    parts.append(self._placed(body, position, orientation, animation))
            else:
                if body not in self.bodies:
                    self.bodies[body] = _Body(p, client, body)
                parts.append(self.bodies[body].vertices(p, client, body in self.lamps))
        with gl_context.current(self.context):
            self._order_dynamic(parts)
            if self.posed is not None:
                self.posed.pose(placements)
        self.synced = state
        self.lights_taken = False  # the casters follow the bodies (`sync`)

    @property
    def drawn_state(self) -> tuple[object, int]:
        """What names the scene as drawn: the bodies' state and the lights taken since."""
        return self.synced, self.lights_serial

    def _order_dynamic(self, parts: list[NDArray]) -> None:
        """The moving bodies' vertices (`parts`) in draw order into the dynamic buffer, and
        their batches. Each part is the very array of the last sync while its body stood still
        in the same colours (`_Body.vertices`, `_placed` keep them): then the ordered vertices,
        their batches and their bytes in the buffer are the last ones (where the GPU poses the
        models, the parts are the signals' lamps, which change a few times a clip)."""
        key = tuple(map(id, parts[1:]))  # [0]: an empty start, made anew
        if key == self.dynamic_key:
            return
        if self.one_program:
            ordered, batches = self.dynamic_order(np.concatenate(parts))
        else:
            ordered, batches = in_draw_order(np.concatenate(parts), self.cull)
        # the parts held, so that no new array takes one of their ids
        self.dynamic_key, self.dynamic_parts = key, parts
        self.dynamic_ordered = (ordered, batches)
        self.dynamic_written = False

    def _write_dynamic(self, casters: list[NDArray]) -> None:
        """The moving bodies' ordered vertices (`_order_dynamic`) where not yet in the dynamic
        buffer, then the shadow casters' after them (the ego alone, which moves most steps);
        the buffer's batches."""
        ordered, batches = self.dynamic_ordered
        written = self.dynamic_written
        shadow_only = np.concatenate(casters) if casters else ordered[:0]
        if ordered.nbytes + shadow_only.nbytes > self.dynamic_buffer.size:
            for name in [k for k in self.arrays if k[0] == "dynamic"]:
                self.arrays.pop(name).release()
            self.dynamic_buffer.release()
            size = 2 * (ordered.nbytes + shadow_only.nbytes)
            self.dynamic_buffer = self.context.buffer(reserve=size, dynamic=True)
            written = False
        if not written and ordered.nbytes:
            self.dynamic_buffer.write(ordered)  # its bytes as they lie: no copy
        self.dynamic_written = True
        if casters:  # after the drawn vertices, in a batch only the shadow pass draws
            batches = batches.then(SHADOW_ONLY, len(ordered), len(shadow_only), shadow_only)
            self.dynamic_buffer.write(shadow_only, offset=ordered.nbytes)
        self.dynamic_batches = batches

    def _placed(self, body: int, position, orientation, animation: Animation) -> NDArray:
        """The model of `body` posed by `animation` at (position, orientation), in the world
        (kept with its pose: a frame draws most models twice at the same pose)."""
        placed = self.placed.get(body)
        if placed is not None and placed[0] == (position, orientation, animation):
            return placed[1]
        placer = self.placers.get(body)
        if placer is None or placer.model is not self.models[body]:
            placer = self.placers[body] = PlacedModel(self.models[body], body)
        vertices = placer.vertices(animation, position, orientation)
        self.placed[body] = ((position, orientation, animation), vertices)
        return vertices

    def _framebuffer(
        self,
        width: int,
        height: int,
        outputs: tuple[str, ...],
        sampled: bool = False,
        slot: int = 0,
    ):
        """A framebuffer of `width` x `height` with one colour attachment per name in `outputs`
        (`FRAMEBUFFER_OUTPUTS`, in the order of the shaders' output locations) and a depth
        buffer; made once per size and kind. The depth is a texture, which the gather pass
        reads (`queue`'s `depth_at`); so is the colour where `sampled` (`slot`: one of several
        such framebuffers of a size, drawn before any is reduced; the area reduction reads
        it: `reduced_views`)."""
        import moderngl

        framebuffer = self.framebuffers.get((width, height, outputs, sampled, slot))
        if framebuffer is None:
            context = self.context
            attachments = []
            for name in outputs:
                if name == "bgra" and sampled:
                    texture = context.texture((width, height), 4)
                    texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
                    attachments.append(texture)
                elif name == "bgra":
                    attachments.append(context.renderbuffer((width, height), components=4))
                elif name == "depth":
                    texture = context.texture((width, height), 1, dtype="f4")
                    texture.filter = (moderngl.NEAREST, moderngl.NEAREST)  # complete, unfiltered
                    attachments.append(texture)
                else:
                    attachments.append(
                        context.renderbuffer((width, height), components=1, dtype="f4")
                    )
            framebuffer = context.framebuffer(
                color_attachments=attachments,
                depth_attachment=context.depth_renderbuffer((width, height)),
            )
            self.framebuffers[(width, height, outputs, sampled, slot)] = framebuffer
        return framebuffer

    def _in_view(
        self,
        matrix: NDArray[np.float64],
        buffers: tuple[str, ...] = ("dynamic", "posed", "static"),
    ) -> Iterator[tuple[str, DrawBatches, NDArray]]:
        """Each of `buffers` ("dynamic", "posed", then "static") with its batches and which of them the
        view of `matrix` (world to clip space) may see: tested where culling, else all."""
        posed = self.posed.batches if self.posed is not None else DrawBatches.empty()
        for buffer_name, batches in (("dynamic", self.dynamic_batches), ("posed", posed),
                                     ("static", self.static_batches)):  # fmt: skip
            if buffer_name not in buffers:
                continue
            visible = batches.visible(matrix) if self.cull else np.ones(len(batches.group), bool)
            yield buffer_name, batches, visible

    def _draw_geometry(
        self,
        program_key: object,
        matrix: NDArray[np.float64],
        eye_m: NDArray[np.float64],
        casters_drawn: bool = False,
    ) -> None:
        """Both buffers' batches that the view of `matrix` (world to clip space) from `eye_m`
        may see, at their level of detail (`gl_batches.level_of_detail`): with the labels
        program (`program_key` "labels") in as few draws as they allow, or with the scene shader
        of variant `program_key` one material group at a time (`MATERIAL_GROUPS`); the
        shadow-only casters too where `casters_drawn`, with every material's code."""
        import moderngl

        # near things first, so that the depth test spares shading what they hide; actors are
        # drawn two-sided (their thin parts), the twin with back faces culled
        for buffer_name, batches, visible in self._in_view(matrix):
            detail = level_of_detail(batches, eye_m)
            visible = visible & detail
            if not visible.any():
                continue
            if buffer_name != "static":
                self.context.disable(moderngl.CULL_FACE)
            else:
                self.context.enable(moderngl.CULL_FACE)
            labels = program_key == "labels"
            hidden = frozenset() if casters_drawn and not labels else frozenset({SHADOW_ONLY})
            skip = hidden | (DECALS if labels else frozenset())
            by_group = not labels and not self.one_program  # one for all groups on a GPU
            draws = batches.runs(visible, by_group=by_group, skip=skip, excluded=~detail)
            for group, first, vertices in draws:
                key = "labels" if labels else self._scene_defines(group, program_key)
                self._array(buffer_name, key).render(moderngl.TRIANGLES, vertices=vertices,
                                                     first=first)  # fmt: skip

    def _shadow_pass(self, matrix: NDArray[np.float64]) -> None:
        """The sun's depth over the focus into the shadow map (once per state): what can cast a
        shadow there (`gl_batches.NOT_CASTING` left out). The static casters' part is drawn once
        per `matrix` into a map of its own and copied (`gl_context.depth_copy`), where GL allows."""
        import moderngl

        copy = gl_context.depth_copy()
        self.context.enable(moderngl.DEPTH_TEST)
        self.context.disable(moderngl.CULL_FACE)
        for program in (self.shadow_program, *self._posed_in_use(["shadow"])):
            program["shadow_matrix"].write(matrix.T.astype(np.float32).tobytes())
        moving = ("dynamic", "posed") if self.posed is not None else ("dynamic",)
        if copy is None:
            self._cast(self.shadow_framebuffer, matrix, (*moving, "static"))
            return
        key = matrix.tobytes()
        if key != self.static_shadow_key:
            self._cast(self.static_shadow_framebuffer, matrix, ("static",))
            self.static_shadow_key = key
        copy(self.static_shadow_framebuffer, self.shadow_framebuffer, SHADOW_MAP_PX)
        self._cast(self.shadow_framebuffer, matrix, moving, clear=False)

    def _cast(
        self, framebuffer, matrix: NDArray[np.float64], buffers: tuple[str, ...], clear=True
    ) -> None:
        """The casters of `buffers` ("dynamic", "static") into `framebuffer`'s depth, seen by
        the sun's `matrix`, after clearing it unless not `clear`."""
        import moderngl

        framebuffer.use()
        if clear:
            framebuffer.clear(depth=1.0)
        for buffer_name, batches, visible in self._in_view(matrix, buffers):
            # crowns cast from their coarse mesh
            draws = batches.runs(visible, by_group=False, skip=NOT_CASTING | {NEAR_FOLIAGE})
            for _, first, vertices in draws:
                self._array(buffer_name, "shadow").render(moderngl.TRIANGLES, vertices=vertices,
                                                          first=first)  # fmt: skip

    def draw(
        self, *args, **kwargs
    ) -> tuple[NDArray[np.uint8], NDArray[np.float32], NDArray[np.int32] | None]:
        """`queue`'s view, read back at once (not through pixel buffers)."""
        return self.queue(*args, **kwargs, queued=False).result()

    def queue(
        self,
        view: Sequence[float],
        projection: Sequence[float],
        width: int,
        height: int,
        segmentation: bool,
        far_m: float,
        look: str = "camera",
        casters_drawn: bool = False,
        queued: bool = True,
        depth_at: NDArray[np.int32] | None = None,
    ) -> PendingView:
        """The view drawn, its pixels on their way back (`gl_readback`: with `queued`, on a GPU,
        the caller draws its next views while they come; `PendingView.result` waits). Its
        result: RGB `(H, W, 3)`, the depth along the view axis `(H, W)` in metres (`far_m` where
        nothing is drawn) and, with `segmentation`, the body id per pixel `(H, W)` (-1 for
        none), for pybullet's column-major `view` and perspective `projection` matrices; row 0
        is the top of the image. `look`: "camera" (the clip's weather and light), "plain"
        (its sun without weather or night: the top view) or "labels" (ids and depth only, RGB
        black). Depth is the fragment's own (float32), not read back from a depth buffer and
        linearised: finer than any depth buffer's step, and no CPU work. `casters_drawn`: the
        moving bodies that only cast shadows (`SceneLights.casters`: the ego, hidden from its
        own cameras) are drawn too, as they would be shown: the top view of a camera frame's
        state, without syncing the bodies again (4 ms of a frame on llvmpipe). `depth_at`
        `(N, 2)` (column, row) pixels: where the renderer `gathers`, the depth is read at these
        alone, `(N,)`, in their order (the same floats as the whole image holds there); the
        whole image elsewhere."""
        if look not in LOOKS:
            raise ValueError(f"look {look!r}: expected one of {', '.join(LOOKS)}")
        with gl_context.current(self.context):
            framebuffer, outputs = self._draw(view, projection, width, height, segmentation,
                                              far_m, look, casters_drawn)  # fmt: skip
            # read into fresh arrays: writable, and no copy of bytes. Colour as the buffer holds
            # it (four bytes a pixel, BGRA): asking GL for three makes the driver convert on
            # the CPU (llvmpipe: 0.79 ms a 1600x900 image, against 0.20 for both)
            gathered = None
            if depth_at is not None and self.gathers:
                if self.gather is None:
                    self.gather = DepthGather(self.context)
                gathered = self.gather.run(framebuffer.color_attachments[outputs.index("depth")],
                                           depth_at)  # fmt: skip
            reads = tuple(
                Read(outputs.index(name), 4, "f1") if name == "bgra" else
                Read(outputs.index(name), 1, "f4")
                for name in ("bgra", "depth", "body")
                if name in outputs and (name != "body" or segmentation)
                and (name != "depth" or gathered is None)
            )  # fmt: skip
            pixels = self.readback.read(framebuffer, reads, width, height, queued)
        return PendingView(self.context, pixels, width, height, "bgra" in outputs, segmentation,
                           gathered)  # fmt: skip

    def _draw(
        self,
        view: Sequence[float],
        projection: Sequence[float],
        width: int,
        height: int,
        segmentation: bool,
        far_m: float,
        look: str = "camera",
        casters_drawn: bool = False,
        sampled: bool = False,
        slot: int = 0,
    ) -> tuple[object, tuple[str, ...]]:
        """The view drawn (`queue`'s arguments) into the framebuffer of its size and outputs
        (`_framebuffer`'s `sampled` and `slot`), and those outputs; the context current."""
        import moderngl

        # drawn upside down (y flipped in clip space), so that OpenGL's bottom-up rows read out
        # top row first; the flip mirrors the winding, so the front faces turn clockwise
        flip = np.diag([1.0, -1.0, 1.0, 1.0])
        view_matrix = np.asarray(view, dtype=np.float64).reshape(4, 4).T
        projection_matrix = flip @ np.asarray(projection, dtype=np.float64).reshape(4, 4).T
        matrix = projection_matrix @ view_matrix
        camera_position = -view_matrix[:3, :3].T @ view_matrix[:3, 3]
        shader_look = self.look if look == "camera" else self.look.plain()
        shadows = look != "labels" and shader_look.shadows
        focus = np.round(np.asarray(self.lights.focus_xy_m) / SHADOW_FOCUS_STEP_M)
        # (+ 0.0: a focus of -0.0 keys the same matrix as 0.0 and gets its bytes)
        sun_matrix = _sun_matrix(tuple(shader_look.light_direction),
                                 tuple((focus * SHADOW_FOCUS_STEP_M + 0.0).tolist()))  # fmt: skip
        key = self.drawn_state if self.lights.shadow_key is None else self.lights.shadow_key
        if shadows and self.shadowed != key:
            self._shadow_pass(sun_matrix)
            self.shadowed = key
        # what a view writes: a camera's ids only when they are read (an attachment fewer
        # saved llvmpipe 8 ms of six cameras), a labels view no colour
        outputs = FRAMEBUFFER_OUTPUTS[look] if segmentation else FRAMEBUFFER_OUTPUTS[look][:2]
        framebuffer = self._framebuffer(width, height, outputs, sampled, slot)
        framebuffer.use()
        clear = {"bgra": (*CLEAR_RGB[::-1], 1.0), "depth": (far_m,) * 4, "body": (0.0,) * 4}
        # the sky, drawn last wherever nothing else is, writes every output a camera's or
        # the top view's pixel holds (colour, depth far_m, body 0): only a labels view,
        # without a sky, has its attachments cleared (clearing them cost llvmpipe 0.7 ms a
        # 1600x900 view)
        cleared = outputs if look == "labels" else ()
        for attachment, name in enumerate(cleared):
            framebuffer.color_mask = tuple((k == attachment,) * 4 for k in range(len(outputs)))
            framebuffer.clear(*clear[name], depth=1.0)
        if not cleared:
            framebuffer.color_mask = ((False,) * 4,) * len(outputs)
            framebuffer.clear(depth=1.0)
        framebuffer.color_mask = ((True,) * 4,) * len(outputs)
        self.context.front_face = "cw"
        if look == "labels":
            self.context.enable(moderngl.DEPTH_TEST)
            for program in (self.labels_program, *self._posed_in_use(["labels"])):
                program["mvp"].write(matrix.T.astype(np.float32).tobytes())
            self._draw_geometry("labels", matrix, camera_position)
        else:
            # shadows, night, wet and fog are compiled in: the variant the look needs
            variant = gl_programs.scene_variant(shader_look)
            if shader_look.lamps_on:
                self._light_texture(shader_look)
            groups = {*self.dynamic_batches.group_set, *self.static_batches.group_set}
            if self.posed is not None:
                groups.update(self.posed.batches.group_set)
            if not casters_drawn:
                groups.discard(SHADOW_ONLY)
            defines = {self._scene_defines(group, variant) for group in groups}
            programs = [self._scene_program(key) for key in sorted(defines)]
            programs += self._posed_in_use(sorted(defines))
            self._apply_look(programs, shader_look, camera_position, far_m,
                             {"mvp": matrix, "shadow_matrix": sun_matrix})  # fmt: skip
            rotation_only = view_matrix.copy()
            rotation_only[:3, 3] = 0.0
            inverse = np.linalg.inv(projection_matrix @ rotation_only)
            gl_programs.set_matrix(self.sky_program, "inverse_view_projection", inverse)
            self.context.enable(moderngl.DEPTH_TEST)
            self.shadow_texture.use(location=0)
            self.wear_texture.use(location=1)
            self.lamp_texture.use(location=2)
            self._draw_geometry(variant, matrix, camera_position, casters_drawn)
            # the sky last, on the far plane, where nothing was drawn: the depth test spares
            # shading the sky behind the scene
            self.context.disable(moderngl.CULL_FACE)
            self.context.depth_func = "<="
            self.sky_array.render(moderngl.TRIANGLES, vertices=3)
            self.context.depth_func = "<"
        return framebuffer, outputs

    def reduced_views(
        self,
        views: Sequence[tuple[Sequence[float], Sequence[float], int, int]],
        far_m: float,
        size: tuple[int, int],
        noise_starts: Sequence[int | None] | None = None,
        full_size: tuple[int, int] | None = None,
    ) -> list[NDArray[np.uint8]]:
        """Each of `views` (pybullet's `view` and `projection` matrices, width, height: as
        `queue`'s) drawn with the clip's look and area-resized to `size` (width, height): RGB
        `(H, W, 3)` each, a view of its BGRA read (`queue`'s colour), each pixel the mean of the
        drawn pixels under it (OpenCV's INTER_AREA; halves rounded up). With `noise_starts` (one
        per view; None: none), each view's night noise added after the reduction, made at the
        camera's `full_size` (width, height) from the pool at its start
        (`conditions.with_reduced_noise`; by the reduction's shader on a GPU: the same bytes
        where the scale is a multiple of a quarter, as TCP's and the camera policy's are). On
        a GPU by a shader (`shaders/reduce.frag`), only `size`'s pixels read back, with one
        wait for the GPU in all: every view is drawn, then all are reduced into one framebuffer
        (`gl_reduce.atlas`) and read at once. Where GL draws on the CPU, or a view is smaller
        than `size` (OpenCV's INTER_AREA then enlarges it bilinearly), each view is read whole
        and resized by OpenCV, as the shader does it (`gl_reduce.reduced_on_cpu`)."""
        colour = (Read(0, 4, "f1"),)
        # a view smaller than `size` is enlarged, by OpenCV (the shader only averages)
        enlarged = any(size[0] > width or size[1] > height for _, _, width, height in views)
        with gl_context.current(self.context):
            starts = tuple(noise_starts) if noise_starts is not None else (None,) * len(views)
            if any(start is not None for start in starts) and full_size is None:
                raise ValueError("night noise needs the cameras' full size")
            if not self.reduces or enlarged:
                reduced = []
                for (view, projection, width, height), start in zip(views, starts, strict=True):
                    framebuffer, _ = self._draw(view, projection, width, height, False, far_m)
                    bgra = self.readback.read(framebuffer, colour, width, height, queued=False)
                    rgb = reduced_on_cpu(bgra.result()[0], size)[..., 2::-1]
                    if start is not None:
                        rgb = with_reduced_noise(rgb, start, full_size[::-1])
                    reduced.append(rgb)
                return reduced
            # each view drawn into a framebuffer of its own (the scene's rasterisation then
            # the same as a view drawn alone, to the bit), then all reduced into one
            # (`gl_reduce.atlas`): a bind and a read
            sources = []
            for slot, (view, projection, width, height) in enumerate(views):
                framebuffer, _ = self._draw(view, projection, width, height, False, far_m,
                                            sampled=True, slot=slot)  # fmt: skip
                sources.append(framebuffer.color_attachments[0])
            drawn = [(width, height) for _, _, width, height in views]
            reduced = atlas([tuple(size)] * len(views), self.max_framebuffer_px)
            target = self._framebuffer(*reduced.size, ("bgra",))
            noise = None
            if any(start is not None for start in starts):
                noise = NightNoise(starts, tuple(full_size), gl_programs.noise_textures())
            self.reduction.reduce(sources, drawn, target, reduced, noise)
            (pixels,) = self.readback.read(target, colour, *reduced.size).result()
            return [reduced.view_of(pixels, k)[..., 2::-1] for k in range(len(views))]

    def release(self) -> None:
        """Free the buffers and framebuffers (the context and the compiled programs stay for the
        process's next world)."""
        with gl_context.current(self.context):
            self.readback.release()
            if self.gather is not None:
                self.gather.release()
                self.gather = None
            for framebuffer in self.framebuffers.values():
                for attachment in (*framebuffer.color_attachments, framebuffer.depth_attachment):
                    attachment.release()
                framebuffer.release()
            for array in self.arrays.values():
                array.release()
            self.reduction.release()
            if self.posed is not None:
                self.posed.release()
                self.posed = None
            for resource in (self.static_buffer, self.dynamic_buffer, self.sky_array,
                             self.sky_buffer, self.shadow_framebuffer, self.shadow_texture,
                             self.static_shadow_framebuffer, self.static_shadow_texture,
                             self.wear_texture, self.lamp_texture):  # fmt: skip
                resource.release()
        self.framebuffers = {}
