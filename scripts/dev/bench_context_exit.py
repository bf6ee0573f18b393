"""How long processes take to make a GL context together, as a collection pool's workers do as
they start, and to exit together holding it, as they do at its end: with their context held,
after releasing it, and without GL (the reference).

    python scripts/dev/bench_context_exit.py [--processes 32] [--gpus all]
        [--modes held released early none] [--at-once K]

Forks `--processes` processes; each touches 400 MB of memory and, unless its mode is "none",
makes the collector's GL context (`gl_context.gl_available`, on EGL device k mod the GPUs,
as `--gpus` deals them) with two 1600x900 framebuffers (RGBA, float depth) and 100 MB of
buffers, draws and reads once, then waits. All are then told to exit at once (`os._exit`;
"released": after moderngl's release of the context, which only asks EGL to destroy it once it
is no longer current) and the time until the last is gone is printed, with its ratio to "none".
"early": each gives its context back to the driver (`gl_context.release_context`: made current
nowhere, destroyed, its display terminated) as soon as it is ready, all at about the same time,
before they are told to exit; how long that took is printed too. NVIDIA's driver tears
contexts down one at a time, so the time grows with the processes (docs/benchmarks.md,
nineteenth session); llvmpipe's are freed with the process.
For the modes with GL it also prints how long a process took to make its context and be ready
(median and longest), when the median process was ready and when the last was, counted from the
first beginning. `--at-once K` lets only K processes make theirs at the same time, as the
collector's and a served evaluation's pools do (`egl_devices.contexts_at_once`); by default all do at once.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import statistics
import time

MODES = ("held", "released", "early", "none")
TOUCHED_BYTES = 400_000_000  # a worker's memory, roughly
FRAMEBUFFER_PX = (1600, 900)


def _process(k: int, mode: str, gpus: tuple[int, ...], ready, go, made, slots) -> None:
    import numpy as np

    from drivee2e_data.sim import egl_devices

    egl_devices.use_device(egl_devices.device_for_worker(k, gpus))
    memory = np.ones(TOUCHED_BYTES // 8)
    context = None
    began = time.perf_counter()  # CLOCK_MONOTONIC: one clock for all processes
    if mode != "none":
        from drivee2e_data.sim import gl_context

        with slots:
            if not gl_context.gl_available():
                raise SystemExit("no GL context can be made here")
        context = gl_context.context()
        framebuffers = []
        for _ in range(2):
            colour = [context.renderbuffer(FRAMEBUFFER_PX, 4),
                      context.renderbuffer(FRAMEBUFFER_PX, 1, dtype="f4")]  # fmt: skip
            depth = context.depth_renderbuffer(FRAMEBUFFER_PX)
            framebuffers.append(
                context.framebuffer(color_attachments=colour, depth_attachment=depth)
            )
        buffers = [context.buffer(reserve=20_000_000) for _ in range(5)]
        framebuffers[0].use()
        context.clear(0.1, 0.2, 0.3)
        framebuffers[0].read()
        del buffers
    ready_at = time.perf_counter()
    released = (ready_at, ready_at)
    if mode == "early":  # given back before the others are told to exit, all at once
        del framebuffers
        gl_context.release_context()
        released = (ready_at, time.perf_counter())
    made.put((began, ready_at, *released))
    ready.release()
    go.wait()
    if mode == "released" and context is not None:
        context.release()
    del memory
    os._exit(0)


def creation(spans: list[tuple[float, float]]) -> dict[str, float]:
    """Of each process's (began, ready) in seconds: the median and longest time a process took,
    and, from the first beginning, when the median process was ready and the last."""
    each = [ready - began for began, ready, *_ in spans]
    first = min(began for began, *_ in spans)
    readies = [ready - first for _, ready, *_ in spans]
    return {"median": statistics.median(each), "longest": max(each),
            "ready": statistics.median(readies),
            "span": max(readies)}  # fmt: skip


def releases(spans: list[tuple[float, ...]]) -> tuple[float, float]:
    """Of each process's (began, ready, releasing, released): the median time a release took
    and the span from the first release's beginning to the last's end."""
    each = [end - start for *_, start, end in spans]
    return statistics.median(each), max(s[3] for s in spans) - min(s[2] for s in spans)


def exit_seconds(
    processes: int, mode: str, gpus: tuple[int, ...], at_once: int = 0
) -> tuple[float, list[tuple[float, ...]]]:
    """Seconds from telling `processes` processes of `mode` to exit to the last one gone, and
    each process's (began, ready) making its context, `at_once` at a time (0: all). They are
    forked: call it from a process that has made no GL context."""
    context = multiprocessing.get_context("fork")
    ready, go, made = context.Semaphore(0), context.Event(), context.Queue()
    slots = context.Semaphore(at_once or processes)
    started = [context.Process(target=_process, args=(k, mode, gpus, ready, go, made, slots))
               for k in range(processes)]  # fmt: skip
    for process in started:
        process.start()
    for _ in started:
        while not ready.acquire(timeout=1.0):
            if any(p.exitcode not in (None, 0) for p in started):
                raise SystemExit(f"a process of mode {mode!r} failed before it was ready")
    spans = [made.get() for _ in started]
    time.sleep(0.5)  # settled: nothing else starting
    began = time.perf_counter()
    go.set()
    for process in started:
        process.join()
    return time.perf_counter() - began, spans


def main() -> None:
    from drivee2e_data.sim.egl_devices import gpu_devices, parse_gpus

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--processes", type=int, default=32)
    parser.add_argument("--gpus", default="all", help="'all' or EGL device indices like 0,1")
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    parser.add_argument("--at-once", type=int, default=0, help="contexts made at once (0: all)")
    args = parser.parse_args()
    gpus = parse_gpus(args.gpus)
    if gpus is None:  # asked of EGL in a fresh process: a forked child of one that asked cannot
        # make a context on NVIDIA's driver
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            gpus = pool.apply(gpu_devices)
    at_once = f"{args.at_once} at once" if args.at_once else "all at once"
    print(f"{args.processes} processes, GPUs {gpus or 'none (llvmpipe)'}, contexts {at_once}")
    measured = {mode: exit_seconds(args.processes, mode, gpus, args.at_once) for mode in args.modes}
    reference = measured["none"][0] if "none" in measured else None
    for mode, (value, _) in measured.items():
        ratio = f" ({value / reference:.1f}x without GL)" if reference and mode != "none" else ""
        print(f"  {mode:<9} all exited {value:.3f} s after told to{ratio}")
    for mode, (_, spans) in measured.items():
        if mode != "none":
            made = creation(spans)
            print(f"  {mode:<9} made a context in {made['median']:.3f} s (median), "
                  f"{made['longest']:.3f} longest; ready {made['ready']:.3f} s (median) and "
                  f"{made['span']:.3f} s (last) after the first began")  # fmt: skip
        if mode == "early":
            median, span = releases(spans)
            print(f"  {mode:<9} gave its context back in {median:.3f} s (median); all "
                  f"{len(spans)} within {span:.3f} s")  # fmt: skip


if __name__ == "__main__":
    main()
