"""Decoding one frame's six JPEGs: OpenCV at full and half size (one thread, the reference:
full size), the Dataset's decode to `--input` (`loaders.images.decode_cpu`: the largest JPEG
reduction that divides the logged size, then an area resize) beside the 1/8 reduction resized
the same way (what it did before 1/8 had to divide the size), and, where CUDA is present, one
nvJPEG batch through torchvision, also resized to `--input` as `decode_batch` resizes (an area
reduction) and as it did before (an antialiased bilinear), each against the CPU's decode (PSNR).
Also the PSNR of the Dataset's decode and of the 1/8 one against the area reduction of the full
image, and with `--sheet` the image where 1/8 lies farthest from it (docs/img).

    python scripts/dev/bench_decode.py LOG.mcap [--input 128x72] [--sheet PNG]
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
    parser.add_argument(
        "--sheet",
        default=None,
        help="a PNG of the image where 1/8 lies farthest from the full image's area reduction",
    )
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
    against_area(frames, full, target, args.sheet)
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


def against_area(
    frames: list, full: tuple[int, int], target: tuple[int, int], sheet: str | None
) -> None:
    """PSNR of the Dataset's decode and of the 1/8 reduction (area-resized) against the area
    reduction of the full image, over every image; with `sheet`, the image where 1/8 lies
    farthest: the area reduction, the Dataset's, 1/8's and 1/8's difference x4, 4x enlarged."""
    worst, spreads = None, {"the Dataset's decode": [], "1/8 reduction, area-resized": []}
    for jpeg in (j for js in frames for j in js):
        buffer = np.frombuffer(jpeg, np.uint8)
        area = cv2.resize(
            cv2.imdecode(buffer, cv2.IMREAD_COLOR), target, interpolation=cv2.INTER_AREA
        )
        dataset = np.ascontiguousarray(
            np.moveaxis(decode_cpu(jpeg, full, target), 0, -1)[..., ::-1]
        )
        eighth = cv2.imdecode(buffer, cv2.IMREAD_REDUCED_COLOR_8)
        eighth = cv2.resize(eighth, target, interpolation=cv2.INTER_AREA)
        values = [psnr(dataset, area), psnr(eighth, area)]
        for spread, value in zip(spreads.values(), values, strict=True):
            spread.append(value)
        if worst is None or values[1] < worst[0]:
            worst = (values[1], [area, dataset, eighth])
    for label, values in spreads.items():
        print(f"{label:30s} against the full image's area reduction: PSNR min "
              f"{min(values):.1f}, median {np.median(values):.1f} dB")  # fmt: skip
    if sheet and worst is not None:
        area, dataset, eighth = worst[1]
        difference = np.clip(4 * np.abs(eighth.astype(int) - area.astype(int)), 0, 255)
        row = np.concatenate([area, dataset, eighth, difference.astype(np.uint8)], axis=1)
        enlarged = cv2.resize(row, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(sheet, enlarged, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        print(f"wrote {sheet}: 1/8 at {worst[0]:.1f} dB")


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
