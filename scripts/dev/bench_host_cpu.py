"""What a host's cores do together on the collector's kind of CPU work, against one core alone:
whether the CPUs of a larger host scale with their number.

    python scripts/dev/bench_host_cpu.py [--processes 1 16 32] [--seconds 10] [--images 1]

For each count N in `--processes`, N processes (one thread each) repeat one round of CPU work
for `--seconds`: a 1600x900 camera-like image encoded to JPEG (OpenCV, quality 90, as
`sensors.camera.encode_jpeg`), 40 000 samples gathered from a float32 image of the same size
and 200 000 floats sorted (the LiDAR's and box visibility's array work). It prints rounds a
second per process and for all together, and the speed-up against one process (the named
reference): a perfectly scaling host gives N. A collection whose workers are bound by their
CPUs (a 2-GPU host with a worker a core, docs/benchmarks.md) cannot scale past this.
`--images K`: each process encodes K different images in turn (4.3 MB each), so that its work
streams through memory as a collector's does instead of staying in cache: where the scaling is
the same for 1 and 16, memory bandwidth is not what the cores share.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time

import numpy as np

IMAGE_PX = (900, 1600)  # rows, columns: a camera image
SAMPLES = 40_000
SORTED = 200_000


def camera_like_image(seed: int = 0) -> np.ndarray:
    """(900, 1600, 3) uint8: smooth shading, hard edges and fine noise, so that a JPEG of it
    costs about what a rendered street's does."""
    import cv2

    rng = np.random.default_rng(seed)
    rows, columns = IMAGE_PX
    y, x = np.mgrid[0:rows, 0:columns].astype(np.float32)
    image = np.stack([x / columns * 180 + 40, y / rows * 120 + 60, (x + y) / (rows + columns) * 200],
                     axis=-1)  # fmt: skip
    image = image.astype(np.uint8)
    for _ in range(300):  # boxes: facades, cars, windows
        x0, y0 = int(rng.integers(columns)), int(rng.integers(rows))
        size = int(rng.integers(8, 200))
        colour = tuple(int(c) for c in rng.integers(0, 256, 3))
        cv2.rectangle(image, (x0, y0), (x0 + size, y0 + size // 2), colour, -1)
    noise = rng.integers(-6, 7, image.shape)
    return np.clip(image.astype(np.int16) + noise, 0, 255).astype(np.uint8)


def one_round(image: np.ndarray, depth: np.ndarray, where: np.ndarray, values: np.ndarray) -> int:
    """One round of the work; returns a number that depends on all of it (kept from being
    optimised away)."""
    import cv2

    ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    gathered = np.take(depth, where)
    ordered = np.sort(values)
    return len(encoded) + int(gathered[0] > 0) + int(ordered[0] > 0)


def _worker(seconds: float, start_at: float, results, images: int = 1) -> None:
    import cv2

    cv2.setNumThreads(1)
    pictures = [camera_like_image(seed) for seed in range(images)]
    image = pictures[0]
    rng = np.random.default_rng(os.getpid())
    depth = rng.random(IMAGE_PX, dtype=np.float32)
    where = rng.integers(0, depth.size, SAMPLES)
    values = rng.random(SORTED, dtype=np.float32)
    one_round(image, depth, where, values)  # warm
    while time.perf_counter() < start_at:  # all begin together
        time.sleep(0.001)
    rounds, began = 0, time.perf_counter()
    while time.perf_counter() - began < seconds:
        one_round(pictures[rounds % images], depth, where, values)
        rounds += 1
    results.put(rounds / (time.perf_counter() - began))


def rounds_per_second(processes: int, seconds: float, images: int = 1) -> list[float]:
    """Each of `processes` processes' rounds a second, all running at once, each going through
    `images` images."""
    context = multiprocessing.get_context("fork")
    results = context.Queue()
    start_at = time.perf_counter() + 1.0 + 0.02 * processes  # after every process is ready
    started = [context.Process(target=_worker, args=(seconds, start_at, results, images))
               for _ in range(processes)]  # fmt: skip
    for process in started:
        process.start()
    rates = [results.get(timeout=seconds + 120) for _ in started]
    for process in started:
        process.join()
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--processes", type=int, nargs="+", default=[1, os.cpu_count() or 1])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--images", type=int, default=1, help="different images a process encodes")
    args = parser.parse_args()
    if args.images < 1:
        parser.error(f"--images {args.images}: expected 1 or more")
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    print(f"{os.cpu_count()} CPUs; {args.seconds:g} s a count; {args.images} image(s) a "
          "process; rounds a second")  # fmt: skip
    reference = None
    for count in sorted({1, *args.processes}):  # one process first: the reference
        rates = rounds_per_second(count, args.seconds, args.images)
        total = sum(rates)
        reference = reference or total
        print(f"  {count:>3} processes: {total / count:7.2f} each, {total:8.2f} in all, "
              f"{total / reference:6.2f}x one process")  # fmt: skip


if __name__ == "__main__":
    main()
