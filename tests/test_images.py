"""JPEG decoding for samples (`loaders/images.py`): an image decoded smaller than logged is the
area reduction of the logged image, on the CPU and by the GPU path's resize."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from drivee2e_data.loaders.images import (
    area_resize,
    area_weights,
    decode_cpu,
    jpeg_size,
    reduction,
)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * np.log10(255.0**2 / max(mse, 1e-12))


def crosswalk(width: int = 1600, height: int = 900) -> np.ndarray:
    """A grey road under a blue sky with white stripes across its lower third, 6 px high and
    8 px apart, as a crosswalk seen ahead: BGR uint8 `(H, W, 3)`."""
    image = np.full((height, width, 3), (150, 120, 90), np.uint8)
    image[height // 2 :] = (70, 72, 75)
    for top in range(2 * height // 3, height, 14):
        image[top : top + 6, width // 8 : 7 * width // 8] = (235, 235, 235)
    return image


def test_a_reduction_divides_the_logged_size() -> None:
    assert reduction((1600, 900), (128, 72)) == 4  # 900 is no multiple of 8
    assert reduction((1600, 896), (128, 72)) == 8
    assert reduction((1600, 900), (256, 144)) == 4
    assert reduction((1600, 900), (800, 450)) == 2
    assert reduction((320, 180), (80, 45)) == 4
    assert reduction((1600, 900), (1600, 900)) == 1
    assert reduction((1601, 900), (128, 72)) == 1  # no reduction divides an odd width


def test_the_decoded_image_is_the_area_reduction_of_the_logged_one() -> None:
    """On stripes at the image's foot, where the 1/8 reduction's partial row of blocks (113
    rows for 112.5) stretched the image by half a row."""
    ok, jpeg = cv2.imencode(".jpg", crosswalk(), [cv2.IMWRITE_JPEG_QUALITY, 85])
    assert ok
    full = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)
    expected = cv2.resize(full, (128, 72), interpolation=cv2.INTER_AREA)[..., ::-1]
    decoded = np.moveaxis(decode_cpu(jpeg.tobytes(), (1600, 900), (128, 72)), 0, -1)
    assert psnr(decoded, expected) > 38.0  # 39.9
    # the stripes tell the two decodes apart: 1/8, area-resized, lies far from the reduction
    eighth = cv2.imdecode(jpeg, cv2.IMREAD_REDUCED_COLOR_8)
    assert eighth.shape[:2] == (113, 200)
    stretched = cv2.resize(eighth, (128, 72), interpolation=cv2.INTER_AREA)[..., ::-1]
    assert psnr(stretched, expected) < 31.0  # 29.4


def test_area_weights_share_each_source_pixel_by_its_overlap() -> None:
    weights = area_weights(5, 2, torch.device("cpu"))  # intervals [0, 2.5) and [2.5, 5)
    expected = torch.tensor([[1, 1, 0.5, 0, 0], [0, 0, 0.5, 1, 1]]) / 2.5
    assert torch.allclose(weights, expected)
    assert torch.allclose(area_weights(900, 72, torch.device("cpu")).sum(1), torch.ones(72))


@pytest.mark.parametrize(
    ("source", "target"),
    [
        ((1600, 900), (128, 72)),
        ((400, 225), (128, 72)),
        ((320, 180), (80, 45)),
        ((1600, 900), (256, 144)),
    ],
)
def test_area_resize_gives_opencvs_area_reduction(source, target) -> None:
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, (source[1], source[0], 3), dtype=np.uint8)
    image[source[1] // 2 :] = crosswalk(*source)[source[1] // 2 :]  # smooth and sharp parts
    expected = cv2.resize(image, target, interpolation=cv2.INTER_AREA)
    reduced = area_resize(torch.from_numpy(np.ascontiguousarray(np.moveaxis(image, -1, 0))), target)
    assert reduced.dtype == torch.uint8 and tuple(reduced.shape) == (3, target[1], target[0])
    difference = np.abs(np.moveaxis(reduced.numpy(), 0, -1).astype(int) - expected.astype(int))
    assert difference.max() <= 1
    assert np.mean(difference > 0) < 0.01


@pytest.mark.parametrize("progressive", [False, True])
def test_jpeg_size_reads_the_frame_header(progressive: bool) -> None:
    for width, height in ((1600, 900), (320, 180), (17, 5)):
        image = np.zeros((height, width, 3), np.uint8)
        flags = [cv2.IMWRITE_JPEG_QUALITY, 85, cv2.IMWRITE_JPEG_PROGRESSIVE, int(progressive)]
        ok, jpeg = cv2.imencode(".jpg", image, flags)
        assert ok and jpeg_size(jpeg.tobytes()) == (width, height)
    with pytest.raises(ValueError, match="frame header"):
        jpeg_size(b"\xff\xd8\xff\xd9")


@pytest.mark.parametrize(
    ("source", "size"),
    [((1600, 900), (128, 72)), ((800, 450), (200, 112)), ((1600, 900), (800, 450))],
)
def test_an_agent_gets_the_datasets_pixels_at_its_size(source, size) -> None:
    """`Observation.image(camera, size=)` in process and the one-file client's
    `Message.image(camera, size=)` give the Dataset's decode to that size, to the byte."""
    from types import SimpleNamespace

    from drivee2e_data.evaluate import agent_client
    from drivee2e_data.evaluate.agent import Observation

    ok, encoded = cv2.imencode(".jpg", crosswalk(*source), [cv2.IMWRITE_JPEG_QUALITY, 85])
    assert ok
    jpeg = encoded.tobytes()
    expected = np.moveaxis(decode_cpu(jpeg, source, size), 0, -1)
    assert expected.shape == (size[1], size[0], 3)
    in_process = Observation.image(
        SimpleNamespace(images={"CAM_FRONT": jpeg}), "CAM_FRONT", size=size
    )
    client = agent_client.Message({"images": {"CAM_FRONT": jpeg}}).image("CAM_FRONT", size=size)
    assert np.array_equal(in_process, expected) and np.array_equal(client, expected)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="nvJPEG decodes on a CUDA device")
def test_the_gpus_decode_is_the_area_reduction_of_the_full_image() -> None:
    """`decode_batch` on CUDA (nvJPEG, then `area_resize`) against the CPU's full decode
    area-reduced (62-67 dB: the two decoders' pixels a level apart at most) and, at 128x72,
    against `decode_cpu` (its 1/4 DCT reduction is not an exact area mean: on this crosswalk's
    hard stripes 39.8 dB at 128x72, 31.8 at 256x144; 40-48 dB on rendered frames,
    docs/loaders.md)."""
    pytest.importorskip("torchvision")
    from drivee2e_data.loaders.images import decode_batch

    ok, encoded = cv2.imencode(".jpg", crosswalk(), [cv2.IMWRITE_JPEG_QUALITY, 85])
    assert ok
    full = np.moveaxis(cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1], -1, 0)
    gpu = {}
    for size in ((128, 72), (256, 144)):
        gpu[size] = decode_batch([torch.from_numpy(encoded.copy())], (1600, 900), size, "cuda")
        reduced = area_resize(torch.from_numpy(np.ascontiguousarray(full)), size).numpy()
        assert psnr(gpu[size][0].cpu().numpy(), reduced) > 45.0  # 66.7 and 62.6 on an H200
    dataset = decode_cpu(encoded.tobytes(), (1600, 900), (128, 72))
    assert psnr(gpu[128, 72][0].cpu().numpy(), dataset) > 38.0  # 39.8
