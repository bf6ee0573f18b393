"""What a collection pool's workers import before their first job, and the server they are
forked from, started as early as a command can (`drivee2e_data.launch`)."""

from __future__ import annotations

import multiprocessing.context
from collections.abc import Sequence

from drivee2e_data.processes import argument_value, preloading, start_server

# what every pool worker imports, once, in the server it is forked from (`processes.preloading`):
# the collector, and what a world imports when it is set up. numpy loads `numpy.ma` and
# `numpy.random` on first use (`np.median` in the twin's build, `secrets` in a temporary name):
# in each worker's first set-up that was 0.1 s on an H100 host (scripts/dev/profile_setup.py)
WORKER_MODULES = (
    "drivee2e_data.collect.runner",
    "numpy.ma",
    "numpy.random",
    "pybullet",
    "moderngl",
    "glcontext.egl",
)


def worker_context() -> multiprocessing.context.BaseContext:
    """The start method of the collector's pools (`processes.preloading` of `WORKER_MODULES`)."""
    return preloading(WORKER_MODULES)


def start_worker_server() -> None:
    """Start the server the collector's pool workers fork from, if not running: it imports
    `WORKER_MODULES` (about a second) while the command goes on (`processes.start_server`)."""
    start_server(worker_context())


def pools_workers(argv: Sequence[str]) -> bool:
    """Whether `drivee2e` arguments `argv` run a collection on a local pool of workers:
    `collect` with `--workers` other than 1 (the default) and the local backend."""
    if not argv or argv[0] != "collect":
        return False
    workers, backend = argument_value(argv, "--workers"), argument_value(argv, "--backend")
    return workers not in (None, "1") and backend in (None, "local")
