"""Camera images finished with torch (the GPU path) against the OpenCV path they mirror: the
torch code runs here on the CPU, the same operations a CUDA device runs."""

from __future__ import annotations

from datetime import datetime, timezone
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.scenario import Conditions, TimeOfDay, Weather
from drivee2e_data.sensors import camera_gpu
from drivee2e_data.sensors.camera import (
    CameraFrame,
    camera_exposure,
    encode_jpeg,
    with_conditions,
)
from drivee2e_data.sensors.rig import default_rig
from drivee2e_data.sim import conditions_torch
from drivee2e_data.sim.conditions import EXPOSURE_AIM, Exposure, Lighting, exposure, post_process

WHEN = datetime(2026, 5, 1, tzinfo=timezone.utc)
DAY = Lighting((0.0, 0.0, 1.0), (1.0, 1.0, 1.0), 0.5, 0.5, False)
NIGHT = Lighting((0.0, 0.0, 1.0), (1.0, 0.85, 0.6), 0.5, 0.4, True)


def scene(height: int = 96, width: int = 128, seed: int = 0):
    """A textured image and a depth ramp from 1 m (top) to 300 m (bottom)."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    depth = np.tile(np.linspace(1.0, 300.0, height, dtype=np.float32)[:, None], (1, width))
    return rgb, depth


@pytest.mark.parametrize("weather", list(Weather))
@pytest.mark.parametrize("light", [DAY, NIGHT], ids=["day", "night"])
@pytest.mark.parametrize("headlights", [False, True])
@pytest.mark.parametrize("gain", [1.0, 0.7, 1.6])
@pytest.mark.parametrize("shaded", [False, True])
def test_torch_post_processing_equals_opencv_within_one_level(
    weather, light, headlights, gain, shaded
):
    rgb, depth = scene()
    conditions = Conditions(weather, TimeOfDay.NOON, WHEN)
    reference = post_process(rgb, depth, conditions, light, 5, headlights, shaded, gain)
    ours = conditions_torch.post_process(
        torch.from_numpy(rgb), torch.from_numpy(depth), conditions, light, 5, headlights,
        shaded, gain,
    ).numpy()  # fmt: skip
    difference = np.abs(reference.astype(int) - ours)
    assert ours.dtype == np.uint8 and ours.shape == rgb.shape
    assert difference.max() <= 1
    assert (difference > 0).mean() < 1e-3  # float rounding at a level's edge, rarely


def test_torch_night_noise_and_rain_follow_the_seed():
    rgb, depth = scene()
    rain_night = Conditions(Weather.RAIN, TimeOfDay.NIGHT, WHEN)

    def run(seed: int) -> np.ndarray:
        image = conditions_torch.post_process(
            torch.from_numpy(rgb), torch.from_numpy(depth), rain_night, NIGHT, seed
        )
        return image.numpy()

    assert np.array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))


def frame_views(weather: Weather, time_of_day: TimeOfDay, light: Lighting):
    """Two cameras drawn at 1024x768 (EGL's size) for 1600x900 images, and a stand-in world
    holding what the finishing reads: the scenario's id and conditions, and the lighting."""
    cameras = default_rig().cameras[:2]
    views = [CameraFrame(c, *scene(768, 1024, seed=k), None) for k, c in enumerate(cameras)]
    scenario = SimpleNamespace(scenario_id="s0", conditions=Conditions(weather, time_of_day, WHEN))
    return SimpleNamespace(scenario=scenario, lighting=light, renderer="tiny"), views


@pytest.mark.parametrize(
    ("weather", "time_of_day", "light"),
    [(Weather.CLEAR, TimeOfDay.NOON, DAY), (Weather.FOG, TimeOfDay.NIGHT, NIGHT)],
)
def test_finishing_a_frame_with_torch_matches_the_opencv_path(weather, time_of_day, light):
    world, views = frame_views(weather, time_of_day, light)
    exposures = [camera_exposure(world, view) for view in views]
    images = camera_gpu.finish(world, views, frame=7, device="cpu", exposures=exposures)
    for view, image in zip(views, images, strict=True):
        reference = with_conditions(world, view, 7)  # OpenCV: weather, then the resize
        ours = image.permute(1, 2, 0).numpy()
        assert ours.shape == reference.shape == (900, 1600, 3)
        difference = np.abs(reference.astype(int) - ours)
        assert difference.max() <= 2  # OpenCV's 11-bit fixed-point resize weights
        assert difference.mean() < 0.2  # on pixel noise, the worst case for a resize


def test_jpeg_from_tensors_off_cuda_is_the_opencv_encoding():
    world, views = frame_views(Weather.CLEAR, TimeOfDay.NOON, DAY)
    images = camera_gpu.finish(world, views, 0, "cpu", [Exposure(1.0, 0.0)] * len(views))
    encoded = camera_gpu.encode(images, quality=85)
    for image, data in zip(images, encoded, strict=True):
        assert data == encode_jpeg(image.permute(1, 2, 0).numpy(), 85)
        decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        assert decoded.shape == (900, 1600, 3)


def test_the_exposure_holds_a_days_mean_grey_in_its_band_and_night_dark():
    """A dim day is brightened to just inside the band (80-100 of 255), a bright fog darkened
    to just inside its top, an image inside the band left alone; a night image is never
    brightened, only darkened where too bright; levels that saturate are counted."""

    def grey(level: float, shape=(90, 160)) -> np.ndarray:
        return np.full((*shape, 3), level, dtype=np.uint8)

    def exposed_mean(image: np.ndarray, light: Lighting) -> float:
        found = exposure(image, light)
        shown = post_process(image, None, Conditions(Weather.CLEAR, TimeOfDay.NOON, WHEN),
                             light, 0, shaded=True, gain=found.gain)  # fmt: skip
        return float(cv2.cvtColor(shown, cv2.COLOR_RGB2GRAY).mean())

    dim = exposure(grey(41), DAY)
    assert dim.metered == pytest.approx(41, abs=0.01) and dim.gain == pytest.approx(2.0, rel=1e-3)
    assert exposed_mean(grey(41), DAY) == pytest.approx(EXPOSURE_AIM[0], abs=0.5)
    assert exposure(grey(147), DAY).gain == pytest.approx(98 / 147, rel=1e-3)
    assert exposed_mean(grey(147), DAY) == pytest.approx(EXPOSURE_AIM[1], abs=0.5)
    assert exposure(grey(90), DAY) == Exposure(1.0, pytest.approx(90, abs=0.01))
    assert exposure(grey(20), NIGHT).gain == 1.0  # real night stays dark
    assert exposure(grey(150), NIGHT).gain == pytest.approx(98 / 150, rel=1e-3)
    assert exposure(grey(2), DAY).gain == 3.0  # the gain's range
    # a quarter of the view a bright sky (mean 75): raised, it saturates; the gain counts it
    # and still lands (255 + 3 x 20 g = 4 x 82: g = 1.217, where the mean alone asks 1.093)
    sky = np.concatenate([grey(240, (30, 160)), grey(20, (90, 160))])
    assert exposure(sky, DAY).gain == pytest.approx(1.217, abs=0.01)
    assert exposed_mean(sky, DAY) == pytest.approx(82, abs=1.0)
    # the meter reads the same places of a view drawn smaller (the closed loop's views)
    big = cv2.resize(scene(90, 160)[0], (1600, 900), interpolation=cv2.INTER_NEAREST)
    small = cv2.resize(big, (400, 225), interpolation=cv2.INTER_AREA)
    assert exposure(big, DAY).metered == pytest.approx(exposure(small, DAY).metered, abs=2.0)


def test_pybullet_renderers_keep_their_images_as_drawn():
    """Look 1 (pybullet's renderers) is metered but not exposed: its images do not change."""
    world, views = frame_views(Weather.CLEAR, TimeOfDay.NOON, DAY)
    dark = CameraFrame(views[0].camera, views[0].rgb // 4, views[0].depth_m, None)
    assert exposure(dark.rgb, DAY).gain > 1.0
    assert camera_exposure(world, dark).gain == 1.0
    gl = SimpleNamespace(**{**vars(world), "renderer": "gl"})
    assert camera_exposure(gl, dark).gain == exposure(dark.rgb, DAY).gain


def test_post_process_device_is_checked():
    with pytest.raises(DriveE2EError, match="expected one of cpu, cuda"):
        camera_gpu.check_device("gpu")
    if not camera_gpu.cuda_available():
        with pytest.raises(DriveE2EError, match="torch sees no CUDA device"):
            camera_gpu.check_device("cuda")
