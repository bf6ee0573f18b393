"""Decoding one frame's six JPEGs: OpenCV at full and half size (one thread, the reference:
full size) and, where CUDA is present, one nvJPEG batch through torchvision.

    python scripts/dev/bench_decode.py LOG.mcap
"""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np
import torch

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
    cv2.setNumThreads(1)
    with LogReader(sys.argv[1]) as log:
        names = [topics.image_topic(c) for c in log.cameras]
        frames = [[m.data for m in log.frame(f, names).values()] for f in log.frames]
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
    }
    if torch.cuda.is_available():
        from torchvision.io import decode_jpeg

        tensors = [[torch.frombuffer(bytearray(j), dtype=torch.uint8) for j in js] for js in frames]

        def on_gpu(js: list) -> None:
            decode_jpeg(js, device="cuda")
            torch.cuda.synchronize()

        rows[f"nvJPEG batch on {torch.cuda.get_device_name()}"] = per_frame_ms(tensors, on_gpu)
    reference = next(iter(rows.values()))
    print(f"{len(frames)} frames of {len(frames[0])} JPEGs from {sys.argv[1]}")
    for label, ms in rows.items():
        print(f"{label:45s} {ms:7.2f} ms/frame  {reference / ms:5.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
