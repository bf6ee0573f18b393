"""What an evaluation pool's workers import before their first episode, and the server they are
forked from, started as early as a command can (`drivee2e_data.launch`)."""

from __future__ import annotations

import multiprocessing.context
from collections.abc import Sequence

from drivee2e_data.processes import argument_value, preloading, start_server

# what every evaluation worker imports, once, in the server it is forked from
# (`processes.preloading`): the episode loop, torch (each worker sets its threads, and a camera
# agent's inputs are tensors), OpenCV, the simulator and the renderer. Sixteen spawned workers
# importing them at once took 4.2-5.0 s each on an H200 host before their first episode
# (docs/benchmarks.md, closed loop); the agent's module is added by the command's entry point.
WORKER_MODULES = (
    "drivee2e_data.evaluate.runner",
    "drivee2e_data.evaluate.episode",
    "torch",
    "cv2",
    "numpy.ma",
    "numpy.random",
    "pybullet",
    "moderngl",
    "glcontext.egl",
)


def worker_context(modules: Sequence[str] = ()) -> multiprocessing.context.BaseContext:
    """The start method of the evaluator's pools (`processes.preloading` of `WORKER_MODULES` and
    `modules`, where the server is not running yet)."""
    return preloading((*WORKER_MODULES, *modules))


def start_worker_server(modules: Sequence[str] = ()) -> None:
    """Start the server the evaluator's pool workers fork from, if not running: it imports
    while the command validates its agent and starts the policy servers."""
    start_server(worker_context(modules))


def pools_workers(argv: Sequence[str]) -> bool:
    """Whether `drivee2e` arguments `argv` run an evaluation on a pool of workers: `evaluate`
    with `--workers` other than 1 (the default)."""
    if not argv or argv[0] != "evaluate":
        return False
    return argument_value(argv, "--workers") not in (None, "1")
