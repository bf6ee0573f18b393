"""One pybullet world replaying one clip: the intersection's twin, an actor per track placed at
its logged pose for a frame, and the signals showing their logged states.

The renderer is chosen at run time: OpenGL through moderngl (`sim/gl_renderer.py`, a GPU or
Mesa's llvmpipe behind EGL) when a context can be made, else pybullet's own: EGL
(`ER_BULLET_HARDWARE_OPENGL` through its `eglRenderer` plugin) when that loads, else
TinyRenderer; the choice is logged once per process. The ego is placed by the caller (logged
pose for collection, controlled pose for closed loop). Actors farther than `draw_radius_m` from
the ego are not drawn.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import pkgutil
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.arrays import nearest_indices
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.hdmap import IntersectionMap
from drivee2e_data.scenario import AgentClass, Scenario, SignalState, Track
from drivee2e_data.sim import mesa, reuse
from drivee2e_data.sim.actors import Blueprint, choose_blueprint, create_actor
from drivee2e_data.sim.animation import TrackMotion, animation_at, track_motion
from drivee2e_data.sim.conditions import lighting, shader_look
from drivee2e_data.sim.gl_context import gl_available, gl_renderer_name
from drivee2e_data.sim.gl_renderer import GLRenderer, PendingView, SceneLights
from drivee2e_data.sim.models import LOOK_VERSION, Animation, ModelMesh, agent_model
from drivee2e_data.sim.twin import Twin, build_twin
from drivee2e_data.sim.twin_plan import TwinPlan

LOG = logging.getLogger(__name__)
_LIBC = ctypes.CDLL(ctypes.util.find_library("c"))
HIDDEN_Z_M = -100.0  # actors not drawn wait here, under the ground
RENDERERS = ("auto", "gl", "egl", "tiny")
# pybullet's EGL plugin draws into a 1024x768 window it makes once (eglRendererVisualShapeConverter,
# START_WIDTH/START_HEIGHT) and stretches larger requests to size by repeating pixels: a
# 1600x900 request is a 1024x768 drawing. Drawing at the largest size of the request's aspect
# ratio that fits (1024x576 for 1600x900: square pixels, as sharp across as the window allows)
# and resizing here costs 25% less than the anisotropic 1024x768, and 41% of the pixels
# pybullet's per-pixel copy loops would handle at 1600x900.
EGL_WINDOW_PX = (1024, 768)
# The GL renderer draws the twin's kinds in this order (others before the ground): what lies on
# top first, so that the depth test spares shading what it covers (paint over road over ground:
# 12% less CPU a camera image on llvmpipe than in the order built).
GL_DRAW_ORDER = ("stop_line", "road_mark", "crosswalk", "road", "sidewalk", "obstacle", "signal",
                 "pole", "vegetation", "building", "ground")  # fmt: skip
_logged_choice: set[str] = set()
# EGL clients connected in this process so far. The plugin makes each new client's GL context
# current and never makes an older one current again, so once a newer client has come (and
# gone), an older client's renders read back another context's memory: garbage, not an error.
_egl_clients = 0
DEPTH_BITS = 16  # pybullet asks EGL for 8 bits at least; depth errors seen on llvmpipe fit 16


@dataclass(frozen=True)
class Image:
    rgb: NDArray[np.uint8]  # (H, W, 3)
    # (H, W) metric depth along the optical axis; None where only `depth_samples` were read
    depth_m: NDArray[np.float32] | None
    segmentation: NDArray[np.int32] | None  # (H, W) body id per pixel, -1 for background
    # (N,) the depth at the pixels `render`'s `depth_at` named, where the renderer gathered
    # them on the GPU instead of reading the whole image (`GLRenderer.gathers`)
    depth_samples: NDArray[np.float32] | None = None

    def resized(self, width: int, height: int) -> Image:
        """The image at another size: RGB interpolated bilinearly, depth and body ids taken from
        the nearest pixel (`nearest_indices`)."""
        import cv2

        rows = nearest_indices(height, self.rgb.shape[0])
        columns = nearest_indices(width, self.rgb.shape[1])
        rgb = cv2.resize(self.rgb, (width, height), interpolation=cv2.INTER_LINEAR)
        mask = None if self.segmentation is None else self.segmentation[rows[:, None], columns]
        return Image(rgb, self.depth_m[rows[:, None], columns], mask)


@contextmanager
def quiet_native_output() -> Iterator[None]:
    """Silence what pybullet's C code prints (its build time on import, the EGL driver's banner
    on loading and unloading the plugin, on stdout and stderr) around one call; Python's own
    output and exceptions are untouched."""
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        saved = (os.dup(1), os.dup(2))
    except OSError:  # no file descriptors 1 and 2 (embedded interpreters): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 1)
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        _LIBC.fflush(None)  # C's buffered output goes to /dev/null, not to the restored streams
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)


def connect(renderer: str = "auto") -> tuple[int, str]:
    """A new DIRECT pybullet client and the renderer it will use ('gl', 'egl' or 'tiny')."""
    with quiet_native_output():
        return _connect(renderer)


def _connect(renderer: str) -> tuple[int, str]:
    import pybullet

    if renderer not in RENDERERS:
        raise DriveE2EError(f"renderer {renderer!r}: expected one of {', '.join(RENDERERS)}")
    if renderer == "gl" and not gl_available():
        raise DriveE2EError(
            "renderer 'gl': no OpenGL context can be made here (moderngl over EGL; is libEGL "
            "installed?)"
        )
    client = pybullet.connect(pybullet.DIRECT)
    chosen = "tiny"
    if renderer == "gl" or (renderer == "auto" and gl_available()):
        chosen = "gl"
    elif renderer in ("auto", "egl"):
        loader = pkgutil.get_loader("eglRenderer")
        plugin = -1
        if loader is not None:
            mesa.activate()  # the plugin's EGL: the same driver as the GL renderer's
            plugin = pybullet.loadPlugin(
                loader.get_filename(), "_eglRendererPlugin", physicsClientId=client
            )
        if plugin >= 0:
            chosen = "egl"
            global _egl_clients
            _egl_clients += 1
        elif renderer == "egl":
            pybullet.disconnect(client)
            raise DriveE2EError("renderer 'egl': pybullet's eglRenderer plugin did not load here")
    if chosen not in _logged_choice:
        names = {
            "gl": f"OpenGL through moderngl ({gl_renderer_name()})",
            "egl": "pybullet's EGL plugin",
            "tiny": "pybullet's TinyRenderer (CPU)",
        }
        LOG.info("renderer: %s", names[chosen])
        _logged_choice.add(chosen)
    return client, chosen


class World:
    """The twin of `intersection_map` with `scenario`'s agents, in one pybullet client; the
    twin built from `twin_plan` where the map's plan is at hand (`reuse`), else planned."""

    def __init__(
        self,
        intersection_map: IntersectionMap,
        scenario: Scenario,
        renderer: str = "auto",
        draw_radius_m: float = 120.0,
        frames: range | None = None,
        twin_plan: TwinPlan | None = None,
    ) -> None:
        with quiet_native_output():
            import pybullet

        if twin_plan is not None and twin_plan.map_id != intersection_map.map_id:
            raise DriveE2EError(
                f"a twin plan of map {twin_plan.map_id!r} given for map {intersection_map.map_id!r}"
            )
        self.p = pybullet
        self.client, self.renderer = connect(renderer)
        self.egl_client = _egl_clients if self.renderer == "egl" else None
        self.closed = False
        self.intersection_map, self.draw_radius_m = intersection_map, draw_radius_m
        self.twin: Twin = build_twin(twin_plan or intersection_map, self.client)
        self.bodies: dict[str, int] = {}
        self.collision_shapes: dict[int, int] = {}  # the actors' by geometry (`create_actor`)
        self.gl: GLRenderer | None = None
        self.state = 0  # counts changes to what is drawn (poses, lamps, actors)
        self.animations: dict[int, Animation] = {}  # body -> its model's pose inputs now
        # what the scene's lights are made from (`_animate`: the log frame, the shown vehicles'
        # headlights, the shadow's key), and the lights made from it and the ego's placement
        # (`scene_lights`; None: to be made again, the ego or the scene moved)
        self._light_inputs: tuple[int, list, object] | None = None
        self._scene_lights: SceneLights | None = SceneLights()
        self.replay(scenario, frames)
        if self.renderer == "gl":
            lamps = {body for head in self.twin.lamps.values() for body, _ in head}
            kind_rank = {kind: rank for rank, kind in enumerate(GL_DRAW_ORDER)}
            static = sorted((m for m in self.twin.meshes if m.body not in lamps),
                            key=lambda m: kind_rank.get(m.kind, len(kind_rank)))  # fmt: skip
            self.gl = GLRenderer(self.p, self.client, static, self.look, sorted(lamps),
                                 self.twin.street_lamps, self.twin.wear)  # fmt: skip
            self.gl.set_models(self.body_models())

    def replay(self, scenario: Scenario, frames: range | None = None) -> None:
        """Swap in another clip of the same map: its actors replace the previous clip's, the
        twin stays (a twin is built once per map and reused for the map's clips). With
        `frames`, the world will show only those of the clip's frames: actors that appear in
        none of them get no procedural model (a collection unit of 50 frames shows about half
        of a clip's actors, and the models were the larger part of its set-up); their bodies
        are still made, in the same order, so every body keeps its id."""
        if scenario.map_id != self.intersection_map.map_id:
            raise DriveE2EError(
                f"scenario {scenario.scenario_id!r} is on map {scenario.map_id!r}, this world shows "
                f"{self.intersection_map.map_id!r}"
            )
        for body in self.bodies.values():
            self.p.removeBody(body, physicsClientId=self.client)
        self.scenario = scenario
        self.blueprints: dict[str, Blueprint] = {
            t.track_id: choose_blueprint(t) for t in scenario.tracks
        }
        shown = tracks_shown_in(scenario, frames)
        self.models: dict[str, ModelMesh] = {
            t.track_id: agent_model(t.agent_class, self.blueprints[t.track_id].name,
                                    self.blueprints[t.track_id].size_m, t.track_id)
            for t in scenario.tracks if t.track_id in shown
        }  # fmt: skip
        self.motions: dict[str, TrackMotion] = {
            t.track_id: track_motion(t) for t in scenario.tracks
        }
        # the actors' shape files in the run's shared folder, where the workers share one
        shapes = reuse.shared_folder() or self.twin.mesh_dir
        self.bodies = {
            track_id: create_actor(
                self.client, bp, self.models.get(track_id), shapes, self.collision_shapes
            )
            for track_id, bp in self.blueprints.items()
        }
        self.lighting = lighting(scenario.conditions, self.intersection_map.origin)
        self.look = shader_look(scenario.conditions, self.intersection_map.origin)
        self.animations = {}
        self._light_inputs, self._scene_lights = None, None
        if self.gl is not None:
            self.gl.set_look(self.look)
            self.gl.forget_bodies()
            self.gl.set_models(self.body_models())
        self.state += 1
        self.ego_xy = np.zeros(2)
        self.ego_pose: tuple[float, float, float] | None = None  # x, y, yaw: its headlights
        self.ego_id: str | None = None
        self.frame = -1

    def body_models(self) -> dict[int, ModelMesh]:
        """Each actor body's procedural model (what the GL renderer draws for it)."""
        return {self.bodies[track_id]: model for track_id, model in self.models.items()}

    def _animate(
        self,
        frame: int,
        shown: Mapping[str, tuple[float, float, float]],
        shadow_key: object = None,
    ) -> None:
        """Each shown actor's animation at the log's `frame` (wheels, steps, brake lights), the
        headlights that light the scene, and the ego's shadow where the ego is hidden (its
        cameras' view) but placed (`place_ego` with a pose); `shown` maps track ids to (x, y,
        yaw); `shadow_key` names the shadow map's content (`SceneLights`)."""
        headlights = self.look.headlights
        self.animations = {}
        spots = []
        for track in self.scenario.tracks:
            pose = shown.get(track.track_id)
            if pose is None:
                continue
            animation, motor = self._animation(track, frame)
            self.animations[self.bodies[track.track_id]] = animation
            if headlights and motor:
                spots.append(_headlight(pose, self.blueprints[track.track_id].size_m))
        self._light_inputs = (frame, spots, shadow_key)
        self._scene_lights = None

    @property
    def scene_lights(self) -> SceneLights:
        """The lights of the scene as shown (`show`, `set_time`) around the ego as placed
        (`place_ego`): the vehicles' headlights and the ego's, nearest the ego first, and the
        ego's shadow where it is hidden but placed; made when first asked for after either
        changed, so that a scene shown before its ego is placed (a closed-loop step's scene,
        shown while its agent thinks) gets the lights of that ego."""
        if self._scene_lights is None:
            self._scene_lights = self._make_scene_lights()
        return self._scene_lights

    @scene_lights.setter
    def scene_lights(self, lights: SceneLights) -> None:
        """Lights of the caller's own, until the scene or the ego moves."""
        self._scene_lights = lights

    def _make_scene_lights(self) -> SceneLights:
        if self._light_inputs is None:
            return SceneLights()
        frame, vehicle_spots, shadow_key = self._light_inputs
        spots = list(vehicle_spots)
        casters = []
        ego = self.scenario.ego
        shown = self.animations
        if (ego is not None and self.ego_pose is not None
                and self.bodies[ego.track_id] not in shown):  # fmt: skip
            at = min(max(frame, 0), self.scenario.num_frames - 1)
            position, orientation = self._logged_placement(ego, at, self.ego_pose)
            animation = self._animation(ego, at)[0]
            casters.append((self.bodies[ego.track_id], tuple(position), tuple(orientation),
                            animation))  # fmt: skip
        if self.look.headlights and self.ego_pose is not None:
            size = self.blueprints[ego.track_id].size_m if ego is not None else (4.6, 1.85, 1.45)
            spots.append(_headlight(self.ego_pose, size))
        # the nearest first: the renderer lights the scene with the first MAX_SPOTS
        spots.sort(
            key=lambda spot: float(
                np.hypot(spot[0][0] - self.ego_xy[0], spot[0][1] - self.ego_xy[1])
            )
        )
        return SceneLights(
            (float(self.ego_xy[0]), float(self.ego_xy[1])), tuple(spots), tuple(casters),
            shadow_key,
        )  # fmt: skip

    def _animation(self, track: Track, frame: int) -> tuple[Animation, bool]:
        """A track's animation at `frame` and whether it is a motor vehicle (lit at night)."""
        walks = track.agent_class == AgentClass.PEDESTRIAN
        motor = track.agent_class.is_motor_vehicle or track.agent_class == AgentClass.MOTORCYCLIST
        model = self.models[track.track_id]
        headlights = self.look.headlights and motor
        return animation_at(self.motions[track.track_id], frame, model, headlights, walks), motor

    def close(self) -> None:
        """Disconnect and delete the twin's files; a second call does nothing."""
        if self.closed:
            return
        self.closed = True
        if self.gl is not None:
            self.gl.release()
        with quiet_native_output():
            self.p.disconnect(self.client)
        self.twin.remove_files()

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def place_ego(
        self, x_m: float, y_m: float, ego_id: str | None = None, yaw_rad: float | None = None
    ) -> None:
        """Where the ego is: actors farther than the draw radius from here are hidden, and so is
        the ego's own logged actor (`ego_id`), which the cameras sit inside; with `yaw_rad`,
        its headlights light the road at night (else they follow the ego's logged heading)."""
        self.ego_xy = np.array([x_m, y_m])
        self.ego_id = ego_id
        self.ego_pose = None if yaw_rad is None else (float(x_m), float(y_m), float(yaw_rad))
        self._scene_lights = None

    def set_time(self, frame: int) -> None:
        """Every agent at its logged pose of `frame` (blueprint box centred on the logged box's
        ground point) and every signal at its logged state; agents invalid then are hidden."""
        shown: dict[str, tuple[float, float, float]] = {}
        ego = self.scenario.ego
        if self.ego_id is not None and ego is not None and self.ego_id == ego.track_id:
            self.ego_pose = (
                float(ego.x_m[frame]),
                float(ego.y_m[frame]),
                float(ego.yaw_rad[frame]),
            )
        for track in self.scenario.tracks:
            body = self.bodies[track.track_id]
            visible = (
                track.track_id != self.ego_id
                and bool(track.valid[frame])
                and (
                    np.hypot(track.x_m[frame] - self.ego_xy[0], track.y_m[frame] - self.ego_xy[1])
                    <= self.draw_radius_m
                )
            )
            if visible:
                if track.track_id not in self.models:
                    raise DriveE2EError(
                        f"{self.scenario.scenario_id} frame {frame}: track {track.track_id!r} "
                        "shows, but this world was set up for frames it is absent from"
                    )
                position, orientation = self._logged_placement(track, frame)
                shown[track.track_id] = (position[0], position[1], float(track.yaw_rad[frame]))
            else:
                orientation, position = [0, 0, 0, 1], [0.0, 0.0, HIDDEN_Z_M]
            self.p.resetBasePositionAndOrientation(
                body, position, orientation, physicsClientId=self.client
            )
        states = {s.signal_id: SignalState(int(s.states[frame])) for s in self.scenario.signals}
        self.twin.show(states)
        # the scene of a log frame casts the same shadows whether the ego is shown (the top
        # view) or hidden and casting (its cameras): one shadow map for both
        key = (self.scenario.scenario_id, frame, *self.ego_xy.tolist())
        self._animate(frame, shown, shadow_key=key)
        self.frame = frame
        self.state += 1

    def _logged_placement(
        self, track: Track, frame: int, xy_yaw: tuple[float, float, float] | None = None
    ) -> tuple[list[float], list[float]]:
        """Where a track's body stands at `frame` (its blueprint's box on the logged box's
        ground point), at its logged (x, y, yaw) or at `xy_yaw`: position and quaternion."""
        x, y, yaw = xy_yaw or (track.x_m[frame], track.y_m[frame], track.yaw_rad[frame])
        ground = track.z_m[frame] - 0.5 * track.height_m[frame]
        z = ground + 0.5 * self.blueprints[track.track_id].size_m[2]
        orientation = self.p.getQuaternionFromEuler([0.0, 0.0, float(yaw)])
        return [float(x), float(y), float(z)], list(orientation)

    def show(
        self,
        placements: Mapping[str, tuple[float, float, float, float]],
        signal_states: Mapping[str, SignalState],
        frame: int = 0,
    ) -> None:
        """A closed-loop step's scene: each actor in `placements` at (x, y, z of its box centre,
        yaw), every other actor hidden, the signals at `signal_states`; the models move (wheels,
        steps, brake lights) as their tracks do at the log's `frame`."""
        self._animate(frame, {t: (x, y, yaw) for t, (x, y, _, yaw) in placements.items()})
        for track_id, body in self.bodies.items():
            placement = placements.get(track_id)
            if placement is None:
                orientation, position = [0, 0, 0, 1], [0.0, 0.0, HIDDEN_Z_M]
            else:
                x, y, z, yaw = placement
                orientation = self.p.getQuaternionFromEuler([0.0, 0.0, float(yaw)])
                position = [float(x), float(y), float(z)]
            self.p.resetBasePositionAndOrientation(
                body, position, orientation, physicsClientId=self.client
            )
        self.twin.show(dict(signal_states))
        self.state += 1

    def sync_bodies(self) -> None:
        """Hand the GL renderer the moving bodies as they stand (what its next draw would do
        first, `GLRenderer.sync_bodies`), so that a scene shown ahead of its draw (a closed-loop
        step's, while the agent thinks) leaves the draw only the ego's part; nothing without
        the GL renderer."""
        if self.gl is not None:
            self.gl.sync_bodies(self.state, self.animations)

    def actor_pose(self, track_id: str) -> tuple[NDArray[np.float64], float]:
        """(x, y, z) and yaw of a drawn actor."""
        position, orientation = self.p.getBasePositionAndOrientation(
            self.bodies[track_id], physicsClientId=self.client
        )
        return np.asarray(position), float(self.p.getEulerFromQuaternion(orientation)[2])

    def render(self, *args, **kwargs) -> Image:
        """The image `render_later` draws, its pixels read at once (`queued` False)."""
        return self.render_later(*args, queued=False, **kwargs)()

    def render_later(
        self,
        eye_m: NDArray[np.float64],
        target_m: NDArray[np.float64],
        width: int,
        height: int,
        vertical_fov_deg: float,
        far_m: float = 200.0,
        segmentation: bool = False,
        near_m: float = 0.1,
        up: NDArray[np.float64] | tuple[float, float, float] = (0.0, 0.0, 1.0),
        native: bool = False,
        frustum: tuple[float, float, float, float] | None = None,
        look: str = "camera",
        casters_drawn: bool = False,
        queued: bool = True,
        depth_at: NDArray[np.int32] | None = None,
    ) -> Callable[[], Image]:
        """The image drawn, returned by the function this returns: with the GL renderer on a
        GPU and `queued`, its pixels come back through pixel buffers while the caller draws its
        next views (`GLRenderer.queue`); else, and with pybullet's renderers, they are read at
        once. Queued reads pay for one copy more on the CPU: worth it for small views drawn in
        a row (the LiDAR's six), not for a camera's 1600x900 (docs/benchmarks.md). The image: a
        `width` x `height` image from a pinhole camera at `eye_m` looking at `target_m`, `up`
        pointing up in the image (world z unless given). With `native`, the image as drawn: with
        EGL, at most `EGL_WINDOW_PX` (`drawn_size`), to be resized by the caller. `frustum`
        (left, right, bottom, top), tangents of the image's edges off the view axis, replaces
        `vertical_fov_deg` with an off-centre (or non-square-pixel) view. `look` (the GL
        renderer's): "camera" draws the clip's weather and light, "plain" its sun alone (the top
        view), "labels" depth and body ids alone (RGB black). `casters_drawn` (the GL
        renderer's): the ego hidden from its cameras but placed with its pose (`place_ego`) is
        drawn too, where it stands: the top view of the cameras' state. `depth_at` `(N, 2)`
        (column, row of the image as drawn): the pixels whose depth the caller needs; the GL
        renderer on a GPU reads the depth there alone (`Image.depth_samples`)."""
        if not self.can_render:
            raise DriveE2EError(
                "this World's EGL renderer was superseded: another World (or pybullet EGL client) "
                "was made in this process after it, and pybullet's EGL plugin draws only in the "
                "newest one's context; close this World and make a new one"
            )
        view, projection = self._matrices(eye_m, target_m, width / height, vertical_fov_deg,
                                          near_m, far_m, up, frustum)  # fmt: skip
        drawn_width, drawn_height = self.drawn_size(width, height)
        if self.gl is not None:
            pending = self._gl_queue(view, projection, drawn_width, drawn_height, segmentation,
                                     far_m, look, casters_drawn, queued, depth_at)  # fmt: skip
            if pending.gathered is None:
                return lambda: Image(*pending.result())

            def gathered() -> Image:
                rgb, samples, mask = pending.result()
                return Image(rgb, None, mask, samples)

            return gathered
        image = self.draw(view, projection, drawn_width, drawn_height, segmentation, near_m, far_m,
                          look, casters_drawn)  # fmt: skip
        if not native and (drawn_width, drawn_height) != (width, height):
            image = image.resized(width, height)
        return lambda: image

    def render_reduced(
        self,
        views: Sequence[tuple[NDArray[np.float64], NDArray[np.float64], int, int, float]],
        size: tuple[int, int],
        near_m: float = 0.1,
        far_m: float = 200.0,
        noise_starts: Sequence[int | None] | None = None,
        full_size: tuple[int, int] | None = None,
    ) -> list[NDArray[np.uint8]]:
        """RGB `(H, W, 3)` at `size` (width, height) of each of `views` (eye, target, width,
        height, vertical field of view: `render`'s, z up), drawn by the GL renderer with the
        clip's weather and light and area-resized to `size`, all the views drawn before any is
        read, and with `noise_starts` the night's noise of cameras of `full_size` added
        (`GLRenderer.reduced_views`): the closed-loop observer's cameras, before their
        exposure (`sensors.camera.render_reduced`)."""
        if self.gl is None:
            raise ValueError("views reduced by the renderer (render_reduced) need the GL renderer")
        matrices = [
            (*self._matrices(eye_m, target_m, width / height, vertical_fov_deg, near_m, far_m),
             width, height)
            for eye_m, target_m, width, height, vertical_fov_deg in views
        ]  # fmt: skip
        self.gl.sync(self.state, self.animations, self.scene_lights)
        return self.gl.reduced_views(matrices, far_m, size, noise_starts, full_size)

    def _matrices(
        self,
        eye_m: NDArray[np.float64],
        target_m: NDArray[np.float64],
        aspect: float,
        vertical_fov_deg: float,
        near_m: float,
        far_m: float,
        up: NDArray[np.float64] | tuple[float, float, float] = (0.0, 0.0, 1.0),
        frustum: tuple[float, float, float, float] | None = None,
    ) -> tuple[list[float], list[float]]:
        """pybullet's view and projection matrices (column-major) of a pinhole camera at `eye_m`
        looking at `target_m` (`render_later`'s arguments; `aspect`: width over height)."""
        view = self.p.computeViewMatrix(
            [float(v) for v in eye_m],
            [float(v) for v in target_m],
            [float(v) for v in up],
            physicsClientId=self.client,
        )
        if frustum is None:
            projection = self.p.computeProjectionMatrixFOV(vertical_fov_deg, aspect, near_m, far_m,
                                                           physicsClientId=self.client)  # fmt: skip
        else:
            left, right, bottom, top = (near_m * float(t) for t in frustum)
            projection = self.p.computeProjectionMatrix(
                left, right, bottom, top, near_m, far_m, physicsClientId=self.client
            )
        return view, projection

    @property
    def look_version(self) -> int:
        """The look of this world's images (`models.LOOK_VERSION` with the GL renderer; 1,
        pybullet's boxes, with its own renderers)."""
        return LOOK_VERSION if self.renderer == "gl" else 1

    @property
    def can_render(self) -> bool:
        """False for an EGL world made before the process's newest EGL client."""
        return self.egl_client is None or self.egl_client == _egl_clients

    def drawn_size(self, width: int, height: int) -> tuple[int, int]:
        """The size the renderer draws a `width` x `height` image at: with pybullet's EGL plugin,
        the largest of the same aspect ratio that fits `EGL_WINDOW_PX`; the size asked for with
        the others."""
        if self.renderer != "egl":
            return width, height
        scale = min(1.0, EGL_WINDOW_PX[0] / width, EGL_WINDOW_PX[1] / height)
        return round(width * scale), round(height * scale)

    def _gl_queue(self, *args, **kwargs) -> PendingView:
        """`GLRenderer.queue`'s view of the world as it stands: the bodies synced first."""
        self.gl.sync(self.state, self.animations, self.scene_lights)
        return self.gl.queue(*args, **kwargs)

    def draw(
        self,
        view: list[float],
        projection: list[float],
        width: int,
        height: int,
        segmentation: bool,
        near_m: float,
        far_m: float,
        look: str = "camera",
        casters_drawn: bool = False,
    ) -> Image:
        """The image drawn with pybullet's column-major `view` and `projection` matrices at
        `width` x `height` (pybullet's EGL plugin stretches what exceeds its window; `render`
        keeps within it), depth in metres; `look` and `casters_drawn` as in `render`
        (pybullet's renderers have one look and draw the bodies where they stand)."""
        import cv2

        if self.gl is not None:
            return Image(*self._gl_queue(view, projection, width, height, segmentation, far_m,
                                         look, casters_drawn, queued=False).result())  # fmt: skip
        flags = 0 if segmentation else self.p.ER_NO_SEGMENTATION_MASK
        renderer = self.p.ER_TINY_RENDERER
        if self.renderer == "egl":
            renderer = self.p.ER_BULLET_HARDWARE_OPENGL
            # The projective-texture pass draws in one pass what the default draws in two: a
            # 4096x4096 shadow map, then the scene. The shadow map spans 10 m around the light's
            # target, so it cast no shadow our scenes showed; a texture projected from the
            # camera itself is the default white. Same picture, a quarter less time on llvmpipe.
            flags |= self.p.ER_USE_PROJECTIVE_TEXTURE
        with quiet_native_output():
            _, _, rgba, depth, seg = self.p.getCameraImage(
                width,
                height,
                view,
                projection,
                renderer=renderer,
                flags=flags,
                physicsClientId=self.client,
            )
        # one contiguous RGB copy (OpenCV's is several times faster than numpy's strided one)
        rgb = cv2.cvtColor(np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4),
                           cv2.COLOR_RGBA2RGB)  # fmt: skip
        buffer = np.asarray(depth, dtype=np.float32).reshape(height, width)
        depth_m = (far_m * near_m / (far_m - (far_m - near_m) * buffer)).astype(np.float32)
        mask = np.asarray(seg, dtype=np.int32).reshape(height, width) if segmentation else None
        return Image(rgb, depth_m, mask)


HEADLIGHT_HEIGHT_M = 0.7
HEADLIGHT_DIP_RAD = 0.08  # dipped beams aim a little down


def _headlight(
    pose: tuple[float, float, float], size_m: tuple[float, float, float]
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """A vehicle's headlights as one spot light: at the middle of its front, along its
    heading, dipped."""
    x, y, yaw = pose
    front = 0.5 * size_m[0]
    position = (x + front * np.cos(yaw), y + front * np.sin(yaw), HEADLIGHT_HEIGHT_M)
    c = np.cos(HEADLIGHT_DIP_RAD)
    direction = (c * np.cos(yaw), c * np.sin(yaw), -np.sin(HEADLIGHT_DIP_RAD))
    return (tuple(float(v) for v in position), tuple(float(v) for v in direction))


def depth_step_m(depth_m: NDArray[np.float64], near_m: float, far_m: float) -> NDArray[np.float64]:
    """The depth buffer's step at each depth `depth_m` (m) for a view with these near and far
    planes: a `DEPTH_BITS` buffer steps evenly in 1 / depth, so by depth^2 / near roughly."""
    return depth_m**2 * (far_m - near_m) / (near_m * far_m * (2**DEPTH_BITS - 1))


def egl_available() -> bool:
    """Whether pybullet's EGL renderer loads in this process: known once a client has loaded it,
    else tried with a client made and dropped (which supersedes any older EGL world)."""
    if _egl_clients:
        return True
    client, chosen = connect("auto")  # imports pybullet
    import pybullet

    with quiet_native_output():
        pybullet.disconnect(client)
    return chosen == "egl"


def resolve_renderer(renderer: str) -> str:
    """The renderer `renderer` names ('gl', 'egl' or 'tiny'); for "auto", the first of those
    that works here (tried once per process)."""
    if renderer not in RENDERERS:
        raise DriveE2EError(f"renderer {renderer!r}: expected one of {', '.join(RENDERERS)}")
    if renderer != "auto":
        return renderer
    if gl_available():
        return "gl"
    return "egl" if egl_available() else "tiny"


def world_for(
    previous: World | None,
    scenario: Scenario,
    read_map: Callable[[str], IntersectionMap],
    renderer: str = "auto",
    frames: range | None = None,
    plan_for: Callable[[IntersectionMap], TwinPlan] | None = None,
) -> World:
    """A world showing `scenario` (only its `frames` where given: `World.replay`): `previous`
    itself when it shows the same map with a renderer that suits (a twin takes a second or
    two to build) and can still render, else a new one (`previous` closed), its twin built from
    `plan_for(map)` where given (`reuse.twin_plan`: plans kept for reuse)."""
    if previous is not None and (
        previous.intersection_map.map_id != scenario.map_id
        or renderer not in ("auto", previous.renderer)
        or not previous.can_render
    ):
        previous.close()
        previous = None
    if previous is None:
        intersection_map = read_map(scenario.map_id)
        plan = plan_for(intersection_map) if plan_for is not None else None
        return World(intersection_map, scenario, renderer, frames=frames, twin_plan=plan)
    previous.replay(scenario, frames)
    return previous


def tracks_shown_in(scenario: Scenario, frames: range | None) -> set[str]:
    """The tracks a world showing `frames` of `scenario` may draw (all for None): those valid
    in any of them, and the ego, whose shadow its cameras see."""
    if frames is None:
        return {track.track_id for track in scenario.tracks}
    first, stop = max(frames.start, 0), min(frames.stop, scenario.num_frames)
    shown = {track.track_id for track in scenario.tracks if track.valid[first:stop].any()}
    if scenario.ego is not None:
        shown.add(scenario.ego.track_id)
    return shown
