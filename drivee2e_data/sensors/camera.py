"""Cameras of the rig rendered in the world: RGB, metric depth, a body-id mask, JPEG bytes."""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.sensors.rig import Camera
from drivee2e_data.sim.conditions import (
    Exposure,
    exposure,
    meter,
    night_noise_start,
    post_process,
    reduced_sensor_effects,
)
from drivee2e_data.sim.gl_readback import bgra_under
from drivee2e_data.sim.world import World


@dataclass(frozen=True)
class DrawnView:
    """A camera and the size its view is drawn at (`World.drawn_size`): what box visibility
    needs to choose its pixels before the view is drawn."""

    camera: Camera
    drawn_shape: tuple[int, int]  # (rows, columns)

    @property
    def drawn_per_camera_px(self) -> tuple[float, float]:
        """Drawn pixels per camera pixel along x and y."""
        rows, columns = self.drawn_shape
        return columns / self.camera.width, rows / self.camera.height


@dataclass(frozen=True)
class CameraFrame:
    """A camera's view as the renderer drew it: at the camera's size, or smaller where the
    renderer draws smaller (EGL: at most 1024x768, `World.drawn_size`); `with_conditions`
    gives the RGB at the camera's size."""

    camera: Camera
    rgb: NDArray[np.uint8]  # (h, w, 3) as drawn
    depth_m: NDArray[np.float32] | None  # (h, w); None where only `depth_samples` were read
    mask: NDArray[np.int32] | None  # (h, w) pybullet body id per pixel, -1 where none
    # depth as float32 from the shader (the GL renderer), not from a 16-bit depth buffer
    float_depth: bool = False
    # (N,) the depth at the pixels `render`'s `depth_at` named, where the renderer gathered
    # them (`World.render`); the whole `depth_m` was not read back then
    depth_samples: NDArray[np.float32] | None = None

    @property
    def drawn_shape(self) -> tuple[int, int]:
        """(rows, columns) as drawn."""
        return self.rgb.shape[0], self.rgb.shape[1]

    @property
    def drawn_per_camera_px(self) -> tuple[float, float]:
        """Drawn pixels per camera pixel along x and y."""
        return DrawnView(self.camera, self.drawn_shape).drawn_per_camera_px


# The near plane sets the depth buffer's precision (it falls with distance squared over the near
# distance): at 0.1 m a bus 80 m away read up to 0.3 m deep, too coarse to tell its surface from
# the space around it (visibility by depth, `annotate.visible_share`); nothing nearer than
# 0.5 m to a camera is drawn, and the cameras sit on the ego's body.
NEAR_M = 0.5
FAR_M = 200.0


def camera_to_world(camera: Camera, ego_to_world: NDArray[np.float64]) -> NDArray[np.float64]:
    return ego_to_world @ camera.sensor_to_ego


# `render`'s `depth_at` for a view whose depth nobody reads (closed-loop observations, videos:
# the GL renderer's shaders draw the weather themselves): none is read back on a GPU
NO_DEPTH = np.zeros((0, 2), np.int32)


def drawn_view(world: World, camera: Camera) -> DrawnView:
    """The camera with the size `world` draws its view at."""
    width, height = world.drawn_size(camera.width, camera.height)
    return DrawnView(camera, (height, width))


def render(
    world: World,
    camera: Camera,
    ego_to_world: NDArray[np.float64],
    mask: bool = True,
    depth_at: NDArray[np.int32] | None = None,
) -> CameraFrame:
    """The camera's view at the world's current frame (the rig's cameras are level).
    `depth_at` `(N, 2)` (column, row as drawn): the pixels whose depth is needed, read alone
    where the renderer can (`CameraFrame.depth_samples`)."""
    eye, target = _eye_and_target(camera, ego_to_world)
    image = world.render(
        eye, target, camera.width, camera.height, camera.vertical_fov_deg, segmentation=mask,
        near_m=NEAR_M, far_m=FAR_M, native=True, depth_at=depth_at,
    )  # fmt: skip
    # without ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX the mask holds body ids, -1 for none
    return CameraFrame(camera, image.rgb, image.depth_m, image.segmentation,
                       world.renderer == "gl", image.depth_samples)  # fmt: skip


def _eye_and_target(
    camera: Camera, ego_to_world: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The camera's position in the world and a point 10 m along its optical axis."""
    pose = camera_to_world(camera, ego_to_world)
    return pose[:3, 3], pose[:3, 3] + 10.0 * pose[:3, 2]


def noise_seed(scenario_id: str, frame: int, camera: Camera) -> int:
    """The seed of a camera image's noise and rain: scenario, frame and camera, so the same image
    comes out however often, and wherever, the frame is made."""
    return zlib.crc32(f"{scenario_id}/{frame}/{camera.name}".encode())


def has_headlights(camera: Camera) -> bool:
    """Whether the ego's headlights light this camera's view at night (the front camera's)."""
    return camera.name == "CAM_FRONT"


def camera_exposure(world: World, view: CameraFrame) -> Exposure:
    """The camera's auto-exposure for this view, metered on the image as drawn
    (`conditions.exposure`; the CPU, GPU and closed-loop paths all meter it here). pybullet's
    renderers (look 1) keep their images as drawn: metered, gain 1."""
    if world.renderer != "gl":
        return Exposure(1.0, float(meter(view.rgb).mean()))
    return exposure(view.rgb, world.lighting)


def with_conditions(
    world: World, view: CameraFrame, frame: int, exposed: Exposure | None = None
) -> NDArray[np.uint8]:
    """The view's RGB at the camera's size under the clip's weather and light, exposed as the
    camera meters it (`exposed`, else `camera_exposure`), its noise seeded by scenario, frame
    and camera (the same image however often the frame is made); headlights on the front
    camera. The weather is applied as drawn, before resizing (fewer pixels); the GL renderer's
    shaders draw fog, wet roads and night light themselves, so its images get only the
    exposure, the rain's streaks and the low-light noise here."""
    import cv2

    scenario = world.scenario
    exposed = exposed or camera_exposure(world, view)
    rgb = post_process(
        view.rgb,
        view.depth_m,
        scenario.conditions,
        world.lighting,
        noise_seed(scenario.scenario_id, frame, view.camera),
        headlights=has_headlights(view.camera),
        shaded=world.renderer == "gl",
        gain=exposed.gain,
    )
    size = (view.camera.width, view.camera.height)
    if rgb.shape[1::-1] == size:
        return rgb
    return cv2.resize(rgb, size, interpolation=cv2.INTER_LINEAR)


def render_reduced(
    world: World,
    cameras: Sequence[Camera],
    ego_to_world: NDArray[np.float64],
    size: tuple[int, int],
    frame: int,
    full_size: tuple[int, int],
) -> dict[str, NDArray[np.uint8]]:
    """Per camera of `cameras` (each drawn at its size, smaller than a camera of `full_size`:
    width, height) its view under the clip's weather and light as that camera's image would
    show after an area reduction to `size`, RGB `(H, W, 3)`: area-resized by the GL renderer
    (`World.render_reduced`), the night's noise from the pool added there, then exposed
    (`conditions.exposure`, metered on the reduced image itself, every pixel of it, and
    applied to it), then the rest of the low-light noise and the rain's streaks made at the
    full size with the same seed as collection (`with_conditions`) and averaged over each
    pixel (`conditions.reduced_sensor_effects`). The closed-loop observer's cheap path: what a
    model reading images at a fraction of the logged size sees, without drawing, weathering,
    encoding and decoding the full image; on a GPU only `size`'s pixels are read back, with
    one wait for the GPU a step.

    The logged image is exposed before it is averaged, at the meter's places of the full view
    (`meter`): metered and exposed after the reduction, a view's gain is its mean's over other
    pixels, and a pixel that saturates under the gain in part of its area saturates here as a
    whole; the images stay within `evaluate.observation.PARITY_PSNR_DB` of the logged ones
    (docs/closedloop.md), and a step waits for the GPU once instead of twice (with sixteen
    processes on an H200, 2.3 ms less a step's observing, docs/benchmarks.md)."""
    if world.renderer != "gl":
        raise ValueError("a reduced view needs the GL renderer (it draws the weather itself)")
    lighting, scenario = world.lighting, world.scenario
    views = [(*_eye_and_target(camera, ego_to_world), camera.width, camera.height,
              camera.vertical_fov_deg) for camera in cameras]  # fmt: skip
    seeds = [noise_seed(scenario.scenario_id, frame, camera) for camera in cameras]
    full_shape = (full_size[1], full_size[0])
    # the night's noise added by the renderer where it comes from the pool (all but images
    # larger than half the pool, drawn afresh below)
    starts = [night_noise_start(seed, full_shape) if lighting.night else None for seed in seeds]
    reduced = world.render_reduced(views, size, NEAR_M, FAR_M, starts, full_size)
    images = {}
    for camera, rgb, seed, start in zip(cameras, reduced, seeds, starts, strict=True):
        images[camera.name] = reduced_sensor_effects(
            rgb, scenario.conditions, lighting, seed, full_shape,
            gain=exposure(rgb, lighting).gain, noise_added=start is not None,
        )  # fmt: skip
    return images


def encode_jpeg(rgb: NDArray[np.uint8], quality: int = 90) -> bytes:
    """JPEG bytes of an RGB image (contiguous, or a view of a BGRA one, as the GL renderer
    reads its views: the BGRA goes to OpenCV's encoder as it is, which takes the blue, green
    and red of each pixel's four bytes, the same bytes as from BGR)."""
    import cv2

    bgra = bgra_under(rgb)
    if bgra is not None:
        bgr = bgra
    else:
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    ok, encoded = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return encoded.tobytes()
