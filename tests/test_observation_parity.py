"""The closed-loop observer against the logged frames: the expert's own (logged) poses through
the observer give the log's JPEG bytes on the collection's path (or within a few levels where
the scene is posed a little differently), and on the cheap path (drawn at twice the input size
or more and averaged down, for an agent that declares its input size) the Dataset's pixels
within `PARITY_PSNR_DB`, in rain and at night too (noise and streaks made at the full size).
Drawn at the input size itself (`supersample=1`), thin lane lines break into dashes and the
overcast noon clip's images fall below the bound (23.8 dB): the test checks that twice the
input is clearly closer (about 6 dB here)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from drivee2e_data import store
from drivee2e_data.cli import main
from drivee2e_data.evaluate.observation import (
    PARITY_PSNR_DB,
    LoggedDrive,
    SensorObserver,
    planar,
)
from drivee2e_data.loaders.images import decode_cpu
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.scenario import Weather
from drivee2e_data.sim.world import World
from tests.conftest import copy_clips

FRONT = ("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT")
# the Dataset reads a 1/4 JPEG; the cheap path draws at 1/2 (twice the input) and averages down
SIZE, INPUT = (320, 180), (80, 45)
FRAMES = 6


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * np.log10(255.0**2 / max(mse, 1e-12))


CLIPS = ("synth_s0_c0001", "synth_s0_c0006", "synth_s0_c0011")


@pytest.fixture(scope="module")
def weathered_root(synthetic_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default set's overcast noon (c0006) and fog-night (c0011) clips, and c0001 (overcast
    noon too) turned to rain (the default set has no rain clip), 6 frames at 320x180."""
    root = copy_clips(synthetic_root, tmp_path_factory.mktemp("parity") / "data", list(CLIPS))
    scenario = store.read_scenario(root, CLIPS[0])
    rain = dataclasses.replace(scenario.conditions, weather=Weather.RAIN)
    store.write_scenario(root, dataclasses.replace(scenario, conditions=rain))
    size = f"{SIZE[0]}x{SIZE[1]}"
    assert main(["collect", str(root), "--max-frames", str(FRAMES), "--image-size", size]) == 0
    return root


@pytest.mark.parametrize("clip", CLIPS)
def test_the_observer_sees_the_logged_frames(weathered_root: Path, clip: str) -> None:
    scenario = store.read_scenario(weathered_root, clip)
    drive = LoggedDrive(scenario)
    intersection_map = store.read_map(weathered_root, scenario.map_id)
    with (
        World(intersection_map, scenario, "auto") as world,
        LogReader(weathered_root / "logs" / f"{clip}.mcap") as log,
    ):
        if world.renderer != "gl":
            pytest.skip("the cheap path draws with the GL renderer (no EGL here)")
        exact = SensorObserver(world, FRONT, SIZE)
        cheap = SensorObserver(world, FRONT, SIZE, INPUT)
        at_input = SensorObserver(world, FRONT, SIZE, INPUT, supersample=1)
        equal, exact_psnr, cheap_psnr, at_input_psnr = 0, [], [], []
        for frame in range(FRAMES):
            jpegs, _ = drive.observe(exact, frame)
            pixels, _ = drive.observe(cheap, frame)
            small, _ = drive.observe(at_input, frame)
            raw = log.frame_raw(log.first_frame + frame, [topics.image_topic(c) for c in FRONT])
            for camera in FRONT:
                logged = CompressedImage.FromString(raw[topics.image_topic(camera)]).data
                equal += logged == jpegs[camera]
                exact_psnr.append(psnr(decode_cpu(jpegs[camera], SIZE), decode_cpu(logged, SIZE)))
                assert pixels[camera].shape == (3, INPUT[1], INPUT[0])
                decoded = decode_cpu(logged, SIZE, INPUT)
                cheap_psnr.append(psnr(pixels[camera], decoded))
                at_input_psnr.append(psnr(small[camera], decoded))
    assert equal >= len(exact_psnr) // 2  # the same bytes on most frames
    assert min(exact_psnr) > 38.0
    assert min(cheap_psnr) > PARITY_PSNR_DB
    assert np.median(cheap_psnr) > np.median(at_input_psnr) + 3.0


@pytest.mark.parametrize("size", [(128, 72), (160, 90), (320, 180)])
def test_planar_gives_the_same_bytes_for_a_bgra_read_as_for_its_rgb_copy(size) -> None:
    """The observer's resize straight from the renderer's BGRA read (the fast path) equals
    resizing the same pixels as a contiguous RGB image, to the byte, at a reduction, an
    uneven one, and none."""
    rng = np.random.default_rng(3)
    bgra = rng.integers(0, 256, (180, 320, 4), dtype=np.uint8)
    view = bgra[:, :, 2::-1]  # as GLRenderer hands out its colour
    copy = np.ascontiguousarray(view)
    fast, reference = planar(view, size), planar(copy, size)
    assert fast.shape == (3, size[1], size[0]) and fast.flags.c_contiguous
    assert np.array_equal(fast, reference)
    # the middle view of an atlas of three side by side (the reduced views' read)
    atlas = rng.integers(0, 256, (180, 3 * 320, 4), dtype=np.uint8)
    middle = atlas[:, 320:640, 2::-1]
    assert np.array_equal(planar(middle, size), planar(np.ascontiguousarray(middle), size))
    assert np.array_equal(
        reference[0], cv2.resize(copy, size, interpolation=cv2.INTER_AREA)[..., 0]
    )


def test_the_gpus_reduction_gives_the_cpus_bytes_in_rain_and_at_night(weathered_root: Path):
    """On a GPU the observer's views are exposed and area-resized by the renderer's shaders
    (`GLRenderer.reduces`, forced here on llvmpipe); where GL draws on the CPU, by OpenCV: with
    the noise and streaks added after, the two give the same bytes (these clips' views reduce
    by a whole factor, 2)."""
    differences = []
    for clip in CLIPS:
        scenario = store.read_scenario(weathered_root, clip)
        drive = LoggedDrive(scenario)
        intersection_map = store.read_map(weathered_root, scenario.map_id)
        with World(intersection_map, scenario, "auto") as world:
            if world.renderer != "gl":
                pytest.skip("the cheap path draws with the GL renderer (no EGL here)")
            observer = SensorObserver(world, FRONT, SIZE, INPUT)
            for frame in (0, FRAMES - 1):
                views = []
                for on_gpu in (False, True):
                    world.gl.reduces = on_gpu
                    views.append(drive.observe(observer, frame)[0])
                for camera in FRONT:
                    cpu, gpu = (view[camera].astype(int) for view in views)
                    differences.append(np.abs(gpu - cpu))
    difference = np.concatenate([d.ravel() for d in differences])
    assert difference.max() == 0  # the same bytes: a whole factor (2), no weight to round


def test_the_cheap_path_meters_each_reduced_view_and_brings_its_mean_into_the_band(
    weathered_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The cheap path's exposure is metered on each view as reduced (every pixel of it) and
    applied to it (`sensors.camera.render_reduced`: one wait for the GPU a step): a view whose
    mean grey lies inside the band (80-100) comes back as reduced, one outside it with its
    mean at the aim (82 or 98, the levels that saturate counted), on the overcast noon clip,
    whose views lie on both sides."""
    from drivee2e_data.sim.conditions import EXPOSURE_AIM, EXPOSURE_BAND, exposure, meter

    scenario = store.read_scenario(weathered_root, "synth_s0_c0006")
    drive = LoggedDrive(scenario)
    reduced: list[np.ndarray] = []
    render_reduced = World.render_reduced

    def kept(self: World, *args, **kwargs) -> list[np.ndarray]:
        views = render_reduced(self, *args, **kwargs)
        reduced.extend(np.array(view) for view in views)
        return views

    monkeypatch.setattr(World, "render_reduced", kept)
    with World(store.read_map(weathered_root, scenario.map_id), scenario, "auto") as world:
        if world.renderer != "gl":
            pytest.skip("the cheap path draws with the GL renderer (no EGL here)")
        observer = SensorObserver(world, FRONT, SIZE, INPUT)
        inside = outside = 0
        for frame in range(FRAMES):
            reduced.clear()
            pixels, _ = drive.observe(observer, frame)
            names = [camera.name for camera in observer.drawn_rig.cameras]
            for camera, view in zip(names, reduced, strict=True):
                shown = pixels[camera].transpose(1, 2, 0)
                mean = float(meter(view).mean())
                if EXPOSURE_BAND[0] <= mean <= EXPOSURE_BAND[1]:
                    assert np.array_equal(shown, view)
                    inside += 1
                    continue
                gain = exposure(view, world.lighting).gain
                aim = EXPOSURE_AIM[0] if mean < EXPOSURE_BAND[0] else EXPOSURE_AIM[1]
                assert gain != 1.0 and abs(float(meter(shown).mean()) - aim) < 1.0, (frame, mean)
                outside += 1
    assert inside and outside
