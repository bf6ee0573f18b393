"""Where collector workers' CPU time goes, by stage of a frame, from py-spy's samples.

    py-spy record --native --pid PID --duration 8 --rate 40 --format raw -o worker.txt
    python scripts/dev/spy_stages.py worker.txt [more.txt ...] [--top 12]

py-spy's raw output (one line a stack, frames separated by ';', then the sample count) of one or
more workers, sampled while `drivee2e collect` runs. Each sample goes to the first stage of
`STAGES` whose marker is in its stack (the pool's idle threads are left out), and the samples
whose innermost frame lies in the GPU driver or in the kernel's clock (a driver's wait polling
the time) are counted apart: that is the driver's share of the stage. It then lists the
innermost Python functions the most samples were in. py-spy is not a dependency: install it
where you sample (`pip install py-spy`; `--native` needs the process's libraries' symbols, and
ptrace rights).
"""

from __future__ import annotations

import argparse
import collections
import re
from pathlib import Path

# (stage, markers): a sample belongs to the first stage one of whose markers is in its stack
STAGES = (
    ("idle thread", ("Condition.wait",)),  # the pool's queue feeder, waiting
    ("write", ("FrameEncoder",)),
    ("jpeg", ("encode_jpeg",)),
    ("top view", ("top_view",)),
    ("lidar", ("depth_sweep", "lidar.py")),
    ("radar", ("radar.py",)),
    ("post-processing", ("with_conditions",)),
    ("annotate", ("_annotate", "_to_annotate", "depth_pixels", "drawn_view")),
    ("cameras drawn and read", ("camera.py",)),
    ("set-up", ("open_clip", "world_for", "build_twin")),
)
DRIVER = re.compile(r"libnvidia|libEGL_nvidia|libGLX_nvidia|\[vdso\]")
PYTHON_FRAME = re.compile(r"^(.*) \(([^()]*\.py):\d+\)$")


def read_samples(paths: list[Path]) -> list[tuple[list[str], int]]:
    """(frames outermost first, count) of every line of py-spy raw files."""
    samples = []
    for path in paths:
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if not line.strip():
                continue
            stack, _, count = line.rpartition(" ")
            if not stack or not count.isdigit():
                raise SystemExit(f"{path} line {number}: expected 'frame;frame;... count'")
            samples.append((stack.split(";"), int(count)))
    return samples


def stage_of(frames: list[str]) -> str:
    stack = ";".join(frames)
    for stage, markers in STAGES:
        if any(marker in stack for marker in markers):
            return stage
    return "other"


def shares(samples: list[tuple[list[str], int]]) -> tuple[int, dict[str, tuple[int, int]]]:
    """Samples counted (idle threads left out) and, per stage, (samples, of them in the
    driver), most first."""
    stages: dict[str, list[int]] = collections.defaultdict(lambda: [0, 0])
    for frames, count in samples:
        stage = stage_of(frames)
        stages[stage][0] += count
        stages[stage][1] += count if DRIVER.search(frames[-1]) else 0
    stages.pop("idle thread", None)
    total = sum(counted for counted, _ in stages.values())
    ordered = sorted(stages.items(), key=lambda item: -item[1][0])
    return total, {stage: (counted, driver) for stage, (counted, driver) in ordered}


def innermost_python(samples: list[tuple[list[str], int]]) -> collections.Counter:
    """Samples by the innermost Python function of their stack (`name (file.py)`)."""
    functions: collections.Counter = collections.Counter()
    for frames, count in samples:
        if stage_of(frames) == "idle thread":
            continue
        for frame in reversed(frames):
            match = PYTHON_FRAME.match(frame)
            if match:
                functions[f"{match.group(1)} ({Path(match.group(2)).name})"] += count
                break
    return functions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", type=Path, nargs="+", help="py-spy --format raw outputs")
    parser.add_argument("--top", type=int, default=12, help="Python functions to list")
    args = parser.parse_args()
    samples = read_samples(args.files)
    total, stages = shares(samples)
    if total == 0:
        raise SystemExit("no samples outside idle threads")
    print(f"{total} samples of {len(args.files)} file(s), idle threads left out")
    print(f"  {'stage':<24} {'share':>7} {'in the driver':>14}")
    for stage, (counted, driver) in stages.items():
        print(f"  {stage:<24} {100 * counted / total:6.1f}% {100 * driver / total:13.1f}%")
    print("innermost Python functions:")
    for function, counted in innermost_python(samples).most_common(args.top):
        print(f"  {100 * counted / total:6.1f}%  {function}")


if __name__ == "__main__":
    main()
