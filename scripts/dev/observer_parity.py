"""The closed-loop observer against the logged frames, on collected logs: for every sensor frame
of each clip, the expert's logged pose through the observer's JPEG path (bytes equal to the log?
PSNR of the decoded images) and its cheap path (drawn at twice the input size or more,
PSNR against the logged JPEG decoded to the agent's input size), and the time of each path;
`--supersample 1 2` measures the cheap path drawn at (at least) each multiple of the input
size side by side, frame by frame (2 is the observer's default).

    python scripts/dev/observer_parity.py DATA --input 128x72 [--supersample 1 2] [--only CLIP ...]
        [--reduce-on auto|gpu|cpu] [--sheet PNG]

Prints one line per clip (weather, time of day, equal JPEGs, PSNR min and median, ms a step of
three front cameras each way) and the spread over all clips; docs/closedloop.md quotes it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

from drivee2e_data import store
from drivee2e_data.evaluate.observation import SUPERSAMPLE, SensorObserver
from drivee2e_data.evaluate.traffic import Traffic
from drivee2e_data.loaders.images import decode_cpu
from drivee2e_data.logs import topics
from drivee2e_data.logs.reader import LogReader
from drivee2e_data.sensors.ego_state import ego_motion
from drivee2e_data.sim.vehicle import VehicleState
from drivee2e_data.sim.world import World

FRONT = ("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT")


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * np.log10(255.0**2 / max(mse, 1e-12))


def clip_parity(
    root: Path, clip: str, input_size: tuple[int, int], supersamples: tuple[int, ...]
) -> dict:
    scenario = store.read_scenario(root, clip)
    motion, traffic, ego = ego_motion(scenario), Traffic(scenario), scenario.ego
    intersection_map = store.read_map(root, scenario.map_id)
    result: dict = {"equal": 0, "images": 0, "exact": [], "exact_s": []}
    result |= {("cheap", k): [] for k in supersamples} | {("cheap_s", k): [] for k in supersamples}
    with (
        World(intersection_map, scenario, "auto") as world,
        LogReader(root / "logs" / f"{clip}.mcap") as log,
    ):
        calibration = log.rig["cameras"]["CAM_FRONT"]
        full = (int(calibration["width"]), int(calibration["height"]))
        exact = SensorObserver(world, FRONT, full)
        cheap = {k: SensorObserver(world, FRONT, full, input_size, k) for k in supersamples}
        for logged_frame in log.sensor_frames:
            frame = logged_frame - log.first_frame
            state = VehicleState(float(motion.x_m[frame]), float(motion.y_m[frame]),
                                 float(motion.yaw_rad[frame]), float(motion.speed_mps[frame]))  # fmt: skip
            centre = np.array([ego.x_m[frame], ego.y_m[frame]])
            poses = traffic.poses(frame, centre, state.yaw_rad, state.speed_mps,
                                  tuple(motion.size_m[:2]))  # fmt: skip
            signals = {s.signal_id: s.state_at(frame) for s in scenario.signals}
            z = float(motion.z_m[frame])
            start = time.perf_counter()
            jpegs, _ = exact.observe(frame, frame, state, z, poses, signals, centre)
            result["exact_s"].append(time.perf_counter() - start)
            pixels = {}
            for k, observer in cheap.items():
                start = time.perf_counter()
                pixels[k], _ = observer.observe(frame, frame, state, z, poses, signals, centre)
                result["cheap_s", k].append(time.perf_counter() - start)
            raw = log.frame_raw(logged_frame, [topics.image_topic(c) for c in FRONT])
            for camera in FRONT:
                logged = CompressedImage.FromString(raw[topics.image_topic(camera)]).data
                result["images"] += 1
                result["equal"] += logged == jpegs[camera]
                result["exact"].append(
                    psnr(decode_cpu(jpegs[camera], full), decode_cpu(logged, full))
                )
                reference = decode_cpu(logged, full, input_size)
                for k in supersamples:
                    result["cheap", k].append(psnr(pixels[k][camera], reference))
            if logged_frame == log.sensor_frames[len(log.sensor_frames) // 2]:
                # the middle frame's three cameras, logged above, the cheap path below
                logged_row = [
                    decode_cpu(CompressedImage.FromString(raw[topics.image_topic(c)]).data, full,
                               input_size)
                    for c in FRONT
                ]  # fmt: skip
                result["sheet"] = np.concatenate([
                    np.concatenate([np.moveaxis(image, 0, -1) for image in row], axis=1)
                    for row in (logged_row, [pixels[supersamples[0]][c] for c in FRONT])
                ])  # fmt: skip
    result["conditions"] = (
        scenario.conditions.weather.value,
        scenario.conditions.time_of_day.value,
    )
    return result


def reduce_on(gpu: bool) -> None:
    """Every GL renderer made from here on reduces its views by its shader passes (`gpu`) or by
    OpenCV (`GLRenderer.reduces`), whatever draws."""
    from drivee2e_data.sim import gl_renderer

    made = gl_renderer.GLRenderer.__init__

    def init(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        made(self, *args, **kwargs)
        self.reduces = gpu

    gl_renderer.GLRenderer.__init__ = init  # type: ignore[method-assign]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--input", default="128x72", help="the agent's input size, WxH")
    parser.add_argument("--supersample", type=int, nargs="+", default=[SUPERSAMPLE])
    parser.add_argument("--only", nargs="+", default=None)
    parser.add_argument("--reduce-on", choices=["auto", "gpu", "cpu"], default="auto",
                        help="where the cheap path's exposure and resize run: the host's choice, "
                        "the renderer's shader passes (forced on llvmpipe too) or OpenCV")  # fmt: skip
    parser.add_argument("--sheet", type=Path, default=None,
                        help="a PNG of each clip's middle frame: its three front cameras as "
                        "logged (decoded to the input size), and below them the cheap path's")  # fmt: skip
    args = parser.parse_args()
    if args.reduce_on != "auto":
        reduce_on(args.reduce_on == "gpu")
    input_size = tuple(int(v) for v in args.input.split("x"))
    supersamples = tuple(args.supersample)
    clips = args.only or sorted(p.stem for p in (args.data / "logs").glob("*.mcap"))
    exact: list[float] = []
    sheets = []
    cheap: dict[int, list[float]] = {k: [] for k in supersamples}
    seconds: dict[int, list[float]] = {k: [] for k in supersamples}
    for clip in clips:
        r = clip_parity(args.data, clip, input_size, supersamples)  # type: ignore[arg-type]
        exact += r["exact"]
        sheets.append(r["sheet"])
        paths = []
        for k in supersamples:
            cheap[k] += r["cheap", k]
            seconds[k] += r["cheap_s", k]
            paths.append(f"x{k} PSNR min {min(r['cheap', k]):.1f} median "
                         f"{np.median(r['cheap', k]):.1f} dB, {1000 * np.median(r['cheap_s', k]):.0f} ms")  # fmt: skip
        print(f"{clip}  {r['conditions'][0]:8s} {r['conditions'][1]:13s} JPEG path "
              f"{r['equal']}/{r['images']} equal, PSNR min {min(r['exact']):.1f}, "
              f"{1000 * np.median(r['exact_s']):.0f} ms a step; cheap path " + "; ".join(paths),
              flush=True)  # fmt: skip
    print(f"all {len(exact)} images: JPEG path PSNR min {min(exact):.1f} dB")
    if args.sheet is not None:
        import cv2

        cv2.imwrite(
            str(args.sheet), np.concatenate(sheets)[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9]
        )
        print(f"wrote {args.sheet}")
    reference = supersamples[0]
    for k in supersamples:
        ratio = np.median(seconds[k]) / np.median(seconds[reference])
        print(f"cheap path drawn at >= {k}x the input: PSNR min {min(cheap[k]):.1f}, 5th "
              f"percentile {np.percentile(cheap[k], 5):.1f}, median {np.median(cheap[k]):.1f} dB; "
              f"{1000 * np.median(seconds[k]):.1f} ms a step (median), {ratio:.2f}x x{reference}'s")  # fmt: skip


if __name__ == "__main__":
    main()
