"""How the closed-loop observer scales with the processes that share a host's GPU: N processes,
each drawing the logged drive of its own clip through `SensorObserver` (the agent's three front
cameras at its input size, the cheap path; no agent, no episode), all started together; per
process count, the mean ms a step, the host's steps a second, and both against one process
alone (the reference, in the same run).

    python scripts/dev/bench_observers.py DATA [--processes 1 4 8 16] [--steps 60]
        [--input 256x144] [--supersample 2] [--cameras 3] [--no-shadows] [--no-meter]
        [--turns K] [--profile]

DATA holds scenario bundles (`drivee2e synth`). Where the steps a second stop growing with the
processes, the GPU (or the cores) is the limit: a host's closed loop cannot go faster than
that whatever the agent (docs/benchmarks.md, closed loop). `--cameras 1` draws the front camera
alone, `--no-shadows` every clip without the sun's shadow map (what a view and the shadow pass
cost, to find where a step's GPU time goes; no agent sees such steps); `--no-meter` without
the exposure meter (its sample pass and the first of a step's two waits for the GPU);
`--turns K` lets at most K processes observe at once (a semaphore around each step: whether
fewer GL contexts submitting at a time give the GPU more steps a second). Each row gives the
CPU time of a step too (the processes' own, `time.process_time`): where the steps slow down
with more processes but their CPU time does not grow, they wait (for the GPU); `--profile`
prints where the first process's steps went (cProfile) at each process count, to compare the
functions that grow with the count.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import multiprocessing
import pstats
import time
from pathlib import Path

from drivee2e_data import store

FRONT = ("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT")


def _drive(
    data: str, clip: str, steps: int, input_size, supersample: float, cameras, shadows: bool,
    meter: bool, turns, barrier, out, profiled: bool = False,
) -> None:  # fmt: skip
    """One process: the world of `clip`, a step to warm up, then `steps` steps timed after every
    process is ready; its seconds, its CPU seconds, the drawn size and (`profiled`) its
    profile's top functions into `out`."""
    from drivee2e_data.evaluate.observation import LoggedDrive, SensorObserver
    from drivee2e_data.sim.world import World

    scenario = store.read_scenario(Path(data), clip)
    drive = LoggedDrive(scenario)
    frames = len(drive.motion.x_m)
    with World(store.read_map(Path(data), scenario.map_id), scenario, "auto") as world:
        if not shadows and world.gl is not None:
            import dataclasses

            world.look = dataclasses.replace(world.look, shadows=False)
            world.gl.set_look(world.look)
        if not meter:
            render_reduced = world.render_reduced

            def unmetered(views, size, gain_of=None, *args, **kwargs):
                return render_reduced(views, size, None, *args, **kwargs)

            world.render_reduced = unmetered
        observer = SensorObserver(world, cameras, (1600, 900), input_size, supersample)
        drive.observe(observer, 0)
        barrier.wait()
        profile = cProfile.Profile() if profiled else None
        start, cpu = time.perf_counter(), time.process_time()
        if profile is not None:
            profile.enable()
        for step in range(1, steps + 1):
            if turns is None:
                drive.observe(observer, 1 + step % (frames - 1))
            else:
                with turns:
                    drive.observe(observer, 1 + step % (frames - 1))
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
        report = ""
        if profile is not None:
            profile.disable()
            text = io.StringIO()
            pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(18)
            report = text.getvalue()
        out.put((seconds, cpu, observer.drawn_rig.cameras[0].width,
                 observer.drawn_rig.cameras[0].height, report))  # fmt: skip


def run(data: Path, clips: list[str], processes: int, steps: int, input_size, supersample,
        cameras=FRONT, shadows: bool = True, meter: bool = True, turns: int = 0,
        profile: bool = False):  # fmt: skip
    """(mean seconds a step per process, mean CPU seconds a step, steps a second of them all,
    drawn size, the first process's profile or "")."""
    context = multiprocessing.get_context("spawn")
    barrier, out = context.Barrier(processes), context.Queue()
    semaphore = context.Semaphore(turns) if 0 < turns < processes else None
    workers = [
        context.Process(target=_drive, args=(str(data), clips[k % len(clips)], steps,
                                             input_size, supersample, cameras, shadows,
                                             meter, semaphore, barrier, out,
                                             profile and k == 0))
        for k in range(processes)
    ]  # fmt: skip
    for worker in workers:
        worker.start()
    results = [out.get() for _ in workers]
    for worker in workers:
        worker.join()
    seconds = [r[0] for r in results]
    per_step = sum(seconds) / len(seconds) / steps
    cpu_per_step = sum(r[1] for r in results) / len(results) / steps
    report = "".join(r[4] for r in results)
    return per_step, cpu_per_step, processes * steps / max(seconds), results[0][2:4], report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--processes", type=int, nargs="+", default=[1, 4, 8, 16])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--input", default="256x144", help="the agent's input size, WxH")
    parser.add_argument("--supersample", type=float, default=2.0)
    parser.add_argument("--cameras", type=int, choices=(1, 3), default=3)
    parser.add_argument("--no-shadows", action="store_true")
    parser.add_argument("--no-meter", action="store_true")
    parser.add_argument("--turns", type=int, default=0, help="at most this many observing at once")
    parser.add_argument("--profile", action="store_true", help="cProfile the first process")
    args = parser.parse_args()
    input_size = tuple(int(v) for v in args.input.split("x"))
    clips = store.scenario_ids(args.data)
    reference = None
    cameras = FRONT if args.cameras == 3 else ("CAM_FRONT",)
    print(f"input {args.input}, supersample {args.supersample}, {args.steps} steps a process, "
          f"{len(cameras)} cameras, shadows {'off' if args.no_shadows else 'as the clip'}, "
          f"meter {'off' if args.no_meter else 'on'}, turns {args.turns or 'all'}")  # fmt: skip
    print("| processes | drawn | ms a step | CPU ms a step | steps a second "
          "| against one process (step, host) |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    reports = []
    for processes in args.processes:
        per_step, cpu, rate, drawn, report = run(
            args.data, clips, processes, args.steps, input_size, args.supersample, cameras,
            not args.no_shadows, not args.no_meter, args.turns, args.profile,
        )  # fmt: skip
        if reference is None:
            reference = (per_step, rate)
        reports.append((processes, report))
        print(f"| {processes} | {drawn[0]}x{drawn[1]} | {1000 * per_step:.1f} | {1000 * cpu:.1f} "
              f"| {rate:.0f} | {per_step / reference[0]:.2f}x, {rate / reference[1]:.2f}x |",
              flush=True)  # fmt: skip
    for processes, report in reports:
        if report:
            print(f"\n## the first process's profile, {processes} processes\n{report}")


if __name__ == "__main__":
    main()
