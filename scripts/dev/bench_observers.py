"""How the closed-loop observer scales with the processes that share a host's GPU: N processes,
each drawing the logged drive of its own clip through `SensorObserver` (the agent's three front
cameras at its input size, the cheap path; no agent, no episode), all started together; per
process count, the mean ms a step, the host's steps a second, and both against one process
alone (the reference, in the same run).

    python scripts/dev/bench_observers.py DATA [--processes 1 4 8 16] [--steps 60]
        [--input 256x144] [--supersample 2] [--cameras 3] [--no-shadows]
        [--turns K] [--profile] [--network CHECKPOINT [--rows 8 4]]

DATA holds scenario bundles (`drivee2e synth`). Where the steps a second stop growing with the
processes, the GPU (or the cores) is the limit: a host's closed loop cannot go faster than
that whatever the agent (docs/benchmarks.md, closed loop). `--cameras 1` draws the front camera
alone, `--no-shadows` every clip without the sun's shadow map (what a view and the shadow pass
cost, to find where a step's GPU time goes; no agent sees such steps); `--turns K` lets at
most K processes observe at once (a semaphore around each step: whether fewer GL contexts
submitting at a time give the GPU more steps a second). Each row gives the CPU time of a step
too (the processes' own, `time.process_time`): where the steps slow down
with more processes but their CPU time does not grow, they wait (for the GPU); `--profile`
prints where the first process's steps went (cProfile: the most own time, then the most
cumulative) at each process count, to compare the functions that grow with the count.
`--network` runs a TCP checkpoint's served forward (the policy server's call:
`ServedAgent`'s stacked inputs through `forward_batch`, batches of each of `--rows`, random
images) in one more process on the GPU, alone before the observers start
and then over and over while they draw: what the GPU's graphics do to the network a policy
server runs beside them (a batch's milliseconds, stacking and forward apart).
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
    turns, barrier, out, profiled: bool = False,
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
            stats = pstats.Stats(profile, stream=text)
            stats.sort_stats("tottime").print_stats(18)
            stats.sort_stats("cumulative").print_stats(30)  # where the own times sit
            report = text.getvalue()
        out.put((seconds, cpu, observer.drawn_rig.cameras[0].width,
                 observer.drawn_rig.cameras[0].height, report))  # fmt: skip


def _network(checkpoint: str, rows: tuple[int, ...], barrier, stop, out) -> None:
    """One process: the TCP agent of `checkpoint` on the GPU; a batch of each of `rows` timed
    alone (after warm-up), then again and again from the observers' start until `stop`; into
    `out`: {rows: (alone ms, stacking ms, during ms, batches during)}."""
    import numpy as np

    from drivee2e_data.agents.tcp import TCPAgent

    agent = TCPAgent(Path(checkpoint))
    generator = np.random.default_rng(0)
    width, height = agent.input_size
    one = [{"images": generator.integers(0, 256, (3, 3, height, width), dtype=np.uint8),
            "vector": generator.standard_normal(6).astype(np.float32)} for _ in range(max(rows))]  # fmt: skip

    def stacked(count: int) -> dict:
        return {key: np.stack([row[key] for row in one[:count]]) for key in one[0]}

    def timed(count: int, repeats: int) -> tuple[float, float]:
        stack_s = forward_s = 0.0
        for _ in range(repeats):
            began = time.perf_counter()
            inputs = stacked(count)
            ready = time.perf_counter()
            agent.forward_batch(inputs)
            stack_s, forward_s = stack_s + ready - began, forward_s + time.perf_counter() - ready
        return 1000 * stack_s / repeats, 1000 * forward_s / repeats

    for count in rows:
        timed(count, 10)  # records its graph
    alone = {count: timed(count, 100) for count in rows}
    barrier.wait()
    during = {count: [0.0, 0] for count in rows}
    while not stop.is_set():
        for count in rows:
            _, forward_ms = timed(count, 1)
            during[count][0] += forward_ms
            during[count][1] += 1
    out.put({count: (alone[count][1], alone[count][0], during[count][0] / max(1, during[count][1]),
                     during[count][1]) for count in rows})  # fmt: skip


def run(data: Path, clips: list[str], processes: int, steps: int, input_size, supersample,
        cameras=FRONT, shadows: bool = True, turns: int = 0,
        profile: bool = False, network: Path | None = None, rows=(8,)):  # fmt: skip
    """(mean seconds a step per process, mean CPU seconds a step, steps a second of them all,
    drawn size, the first process's profile or "", the network's timings or None)."""
    context = multiprocessing.get_context("spawn")
    barrier = context.Barrier(processes + (network is not None))
    out, stop, network_out = context.Queue(), context.Event(), context.Queue()
    served = None
    if network is not None:
        served = context.Process(target=_network,
                                 args=(str(network), tuple(rows), barrier, stop, network_out))  # fmt: skip
        served.start()
    semaphore = context.Semaphore(turns) if 0 < turns < processes else None
    workers = [
        context.Process(target=_drive, args=(str(data), clips[k % len(clips)], steps,
                                             input_size, supersample, cameras, shadows,
                                             semaphore, barrier, out,
                                             profile and k == 0))
        for k in range(processes)
    ]  # fmt: skip
    for worker in workers:
        worker.start()
    results = [out.get() for _ in workers]
    for worker in workers:
        worker.join()
    timings = None
    if served is not None:
        stop.set()
        timings = network_out.get()
        served.join()
    seconds = [r[0] for r in results]
    per_step = sum(seconds) / len(seconds) / steps
    cpu_per_step = sum(r[1] for r in results) / len(results) / steps
    report = "".join(r[4] for r in results)
    return (per_step, cpu_per_step, processes * steps / max(seconds), results[0][2:4], report,
            timings)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--processes", type=int, nargs="+", default=[1, 4, 8, 16])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--input", default="256x144", help="the agent's input size, WxH")
    parser.add_argument("--supersample", type=float, default=2.0)
    parser.add_argument("--cameras", type=int, choices=(1, 3), default=3)
    parser.add_argument("--no-shadows", action="store_true")
    parser.add_argument("--turns", type=int, default=0, help="at most this many observing at once")
    parser.add_argument("--profile", action="store_true", help="cProfile the first process")
    parser.add_argument("--network", type=Path, help="a TCP checkpoint served beside them")
    parser.add_argument("--rows", type=int, nargs="+", default=[8], help="its batches' rows")
    args = parser.parse_args()
    input_size = tuple(int(v) for v in args.input.split("x"))
    clips = store.scenario_ids(args.data)
    reference = None
    cameras = FRONT if args.cameras == 3 else ("CAM_FRONT",)
    print(f"input {args.input}, supersample {args.supersample}, {args.steps} steps a process, "
          f"{len(cameras)} cameras, shadows {'off' if args.no_shadows else 'as the clip'}, "
          f"turns {args.turns or 'all'}")  # fmt: skip
    print("| processes | drawn | ms a step | CPU ms a step | steps a second "
          "| against one process (step, host) |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    reports = []
    for processes in args.processes:
        per_step, cpu, rate, drawn, report, timings = run(
            args.data, clips, processes, args.steps, input_size, args.supersample, cameras,
            not args.no_shadows, args.turns, args.profile, args.network,
            args.rows,
        )  # fmt: skip
        if reference is None:
            reference = (per_step, rate)
        reports.append((processes, report))
        print(f"| {processes} | {drawn[0]}x{drawn[1]} | {1000 * per_step:.1f} | {1000 * cpu:.1f} "
              f"| {rate:.0f} | {per_step / reference[0]:.2f}x, {rate / reference[1]:.2f}x |",
              flush=True)  # fmt: skip
        for count, (alone, stack, during, batches) in sorted((timings or {}).items()):
            print(f"|   the network, {count} rows | | alone {alone:.2f} ms a batch (stacking "
                  f"{stack:.2f}) | during {during:.2f} ms ({batches} batches) | "
                  f"| {during / alone:.2f}x alone |", flush=True)  # fmt: skip
    for processes, report in reports:
        if report:
            print(f"\n## the first process's profile, {processes} processes\n{report}")


if __name__ == "__main__":
    main()
