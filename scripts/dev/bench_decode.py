"""Decoding one frame's six JPEGs: OpenCV at full and half size (one thread, the reference:
full size), the Dataset's decode to `--input` (`loaders.images.decode_cpu`: the largest JPEG
reduction that divides the logged size, then an area resize) beside the 1/8 reduction resized
the same way (what it did before 1/8 had to divide the size), and, where CUDA is present, one
nvJPEG batch through torchvision, also resized to `--input` as `decode_batch` resizes (an area
reduction) and as it did before (an antialiased bilinear), each against the CPU's decode (PSNR).

    python scripts/dev/bench_decode.py LOG.mcap [--input 128x72]
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
import torch

from drivee2e_data.loaders.images import decode_batch, decode_cpu
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader


def per_frame_ms(frames: list, decode) -> float:  # type: ignore[no-untyped-def]
    for jpegs in frames[:2]:
        decode(jpegs)  # warm up
    start = time.perf_counter()
    for jpegs in frames:
        decode(jpegs)
    return (time.perf_counter() - start) / len(frames) * 1e3


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log")
    parser.add_argument("--input", default="128x72", help="the Dataset's image size, WxH")
    args = parser.parse_args()
    target = tuple(int(v) for v in args.input.split("x"))
    cv2.setNumThreads(1)
    with LogReader(args.log) as log:
        names = [topics.image_topic(c) for c in log.cameras]
        frames = [[m.data for m in log.frame(f, names).values()] for f in log.sensor_frames]
        calibration = log.rig["cameras"][log.cameras[0]]
        full = (int(calibration["width"]), int(calibration["height"]))
    rows = {
        "OpenCV, full size (reference)": per_frame_ms(
            frames,
            lambda js: [cv2.imdecode(np.frombuffer(j, np.uint8), cv2.IMREAD_COLOR) for j in js],
        ),
        "OpenCV, half size (reduced DCT)": per_frame_ms(
            frames,
            lambda js: [
                cv2.imdecode(np.frombuffer(j, np.uint8), cv2.IMREAD_REDUCED_COLOR_2) for j in js
            ],
        ),
        f"the Dataset's decode to {args.input}": per_frame_ms(
            frames, lambda js: [decode_cpu(j, full, target) for j in js]
        ),
        f"1/8 reduction, area-resized to {args.input}": per_frame_ms(
            frames,
            lambda js: [
                cv2.resize(
                    cv2.imdecode(np.frombuffer(j, np.uint8), cv2.IMREAD_REDUCED_COLOR_8),
                    target,
                    interpolation=cv2.INTER_AREA,
                )
                for j in js
            ],
        ),
    }
    if torch.cuda.is_available():
        from torchvision.io import decode_jpeg

        tensors = [[torch.frombuffer(bytearray(j), dtype=torch.uint8) for j in js] for js in frames]

        def on_gpu(js: list) -> None:
            decode_jpeg(js, device="cuda")
            torch.cuda.synchronize()

        rows[f"nvJPEG batch on {torch.cuda.get_device_name()}"] = per_frame_ms(tensors, on_gpu)
        rows[f"nvJPEG batch, area-resized to {args.input} (decode_batch)"] = per_frame_ms(
            tensors, lambda js: synchronized(decode_batch(js, full, target, "cuda"))
        )
        rows[f"nvJPEG batch, bilinear (antialiased) to {args.input}"] = per_frame_ms(
            tensors, lambda js: synchronized(bilinear(js, target))
        )
    reference = next(iter(rows.values()))
    print(f"{len(frames)} frames of {len(frames[0])} JPEGs from {args.log}")
    for label, ms in rows.items():
        print(f"{label:60s} {ms:7.2f} ms/frame  {reference / ms:5.1f}x")
    if torch.cuda.is_available():  # the GPU's images against the Dataset's on the CPU
        cpu = [torch.from_numpy(decode_cpu(j, full, target)) for js in frames for j in js]
        for label, decode in (
            ("decode_batch (area)", lambda js: decode_batch(js, full, target, "cuda")),
            ("bilinear, antialiased", lambda js: bilinear(js, target)),
        ):
            gpu = [image.cpu() for js in tensors for image in decode(js)]
            values = [psnr(a.numpy(), b.numpy()) for a, b in zip(gpu, cpu, strict=True)]
            print(f"{label:25s} against the CPU's decode: PSNR min {min(values):.1f}, median "
                  f"{np.median(values):.1f} dB over {len(values)} images")  # fmt: skip
    return 0


def synchronized(images: torch.Tensor) -> torch.Tensor:
    torch.cuda.synchronize()
    return images


def bilinear(jpegs: list, target: tuple[int, int]) -> torch.Tensor:
    """The GPU path's resize until 2026-11-30: torchvision's antialiased bilinear."""
    from torchvision.io import decode_jpeg
    from torchvision.transforms.v2.functional import resize

    images = decode_jpeg(jpegs, device="cuda")
    return torch.stack([resize(image, [target[1], target[0]], antialias=True) for image in images])


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * np.log10(255.0**2 / max(mse, 1e-12))


if __name__ == "__main__":
    raise SystemExit(main())
