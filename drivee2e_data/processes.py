"""Process pools as the collector and the evaluator use them."""

from __future__ import annotations

import multiprocessing
import os
import select
import signal
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager

# Native thread pools of one thread in each pool worker: with a worker per core, pools as large
# as the host only fight. OpenBLAS (numpy's matrix products: the LiDAR's and the boxes' 3x3
# rotations of 100,000 rows) starts a thread per core whose threads spin between products, and
# reads its setting when numpy loads, which in a spawned worker is before any code of ours runs
# (unpickling the pool's initializer imports its module): so the parent sets them for the
# workers it spawns. `drivee2e collect --workers auto` on 2 cores: 5.24 -> 6.45 frames/s.
# llvmpipe (LP_NUM_THREADS) and torch (OMP_NUM_THREADS) read theirs later.
WORKER_THREADS = {
    "OPENBLAS_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "LP_NUM_THREADS": "1",
}


# A worker imports what its parent imported, wherever the command was started: a process
# started by `python -c` (spawn's workers, forkserver's server) puts the working directory first
# on sys.path, and from a checkout its `drivee2e_data/` (which holds no `collect/`: setuptools
# maps that in) shadowed the installed package, every worker failing with `No module named
# 'drivee2e_data.collect'`. Python 3.11 keeps the working directory off the path with this set
# (spawn then takes the parent's path; Python 3.11's forkserver ignores the parent's path).
WORKER_PATH = {"PYTHONSAFEPATH": "1"}


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the platform tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@contextmanager
def one_thread_per_worker() -> Iterator[None]:
    """`WORKER_THREADS` and `WORKER_PATH` in the environment (where the user set none) while a
    pool spawns and runs its workers, which inherit them; the parent's environment restored
    after."""
    wanted = {**WORKER_THREADS, **WORKER_PATH}
    added = {name: value for name, value in wanted.items() if name not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for name in added:
            os.environ.pop(name, None)


# spawn: a fresh interpreter per worker, no pybullet or EGL state inherited from the parent
SPAWN = multiprocessing.get_context("spawn")


def preloading(modules: Sequence[str]) -> multiprocessing.context.BaseContext:
    """The start method of a pool whose workers all import `modules`: forked from one server
    process that imported them once (multiprocessing's forkserver), where the system has it,
    else `SPAWN`. The server is a fresh interpreter too (no pybullet or EGL state of the
    parent's), started by `start_server` or the first pool of this process, with the environment
    of that moment (`one_thread_per_worker`'s included), and serving every later pool: sixteen
    workers importing the collector at once took about a second each on an H100 host. Also
    `SPAWN` where the temp folder's path is too long for the server's socket (`socket_fits`)."""
    if "forkserver" not in multiprocessing.get_all_start_methods() or not socket_fits():
        return SPAWN
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(modules))  # no effect once the server runs
    return context


# A Unix socket's path holds at most 107 bytes on Linux (`sun_path`), and the fork server's
# lies two levels under the temp folder: `pymp-XXXXXXXX/listener-XXXXXXXX`, 32 bytes with the
# slashes. A longer TMPDIR (a batch system's per-job folder, a test's temporary folder) failed
# every pool with "OSError: AF_UNIX path too long".
SOCKET_PATH_BYTES = 107
SERVER_SOCKET_SUFFIX_BYTES = 32


def socket_fits(temporary: str | None = None) -> bool:
    """Whether the fork server's socket fits under the temp folder (`temporary`, else this
    process's `tempfile.gettempdir()`)."""
    folder = os.fsencode(temporary if temporary is not None else tempfile.gettempdir())
    return len(folder) + SERVER_SOCKET_SUFFIX_BYTES <= SOCKET_PATH_BYTES


def argument_value(argv: Sequence[str], flag: str) -> str | None:
    """The value given to `flag` in command-line arguments `argv` (`--flag V` or `--flag=V`), the
    last one; None if absent (read before the command's parser runs: `drivee2e_data.launch`)."""
    value = None
    for k, word in enumerate(argv):
        if word == flag and k + 1 < len(argv):
            value = argv[k + 1]
        elif word.startswith(flag + "="):
            value = word.split("=", 1)[1]
    return value


def start_server(context: multiprocessing.context.BaseContext) -> None:
    """Start `preloading`'s server now, where `context` has one (with `one_thread_per_worker`'s
    environment), so that it imports while the parent still plans: its first pool's workers
    then fork from a server that is ready, or nearly."""
    if context.get_start_method() != "forkserver":
        return
    from multiprocessing import forkserver

    with one_thread_per_worker():
        forkserver.ensure_running()


def end_with(pid: int) -> None:
    """In a pool worker: SIGTERM itself when process `pid` (the command that made the pool)
    ends, so that a command killed outright (SIGKILL, a crash: no `stop_pool`) leaves no worker
    collecting on at full CPU for minutes; the worker's SIGTERM handler
    (`clean_up_when_stopped`) still cleans up. A thread waits on the process (a pidfd where
    Linux has them, else a check every second). Not the parent-death signal: a forkserver's
    workers are its children, and it lives while they do (each holds its liveness pipe)."""

    def watch() -> None:
        try:
            handle = os.pidfd_open(pid)
        except (AttributeError, OSError):  # no pidfd here, or the process has already ended
            while process_running(pid):
                time.sleep(1.0)
        else:
            select.select([handle], [], [])
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="end-with-command", daemon=True).start()


def _start_worker(command: int, initializer: Callable[..., None], *initargs: object) -> None:
    """A pool worker's start: `end_with` the command, then the pool's own initializer."""
    end_with(command)
    initializer(*initargs)


@contextmanager
def worker_pool(
    workers: int,
    initializer: Callable[..., None],
    initargs: Sequence[object] = (),
    context: multiprocessing.context.BaseContext = SPAWN,
) -> Iterator[ProcessPoolExecutor]:
    """A pool of `workers` processes started by `context` (`SPAWN`, or `preloading`'s; queues
    and values they share are made from it too), each with one native thread
    (`one_thread_per_worker`), shut down when the block ends; stopped at once (`stop_pool`)
    when it raises or is interrupted; each worker ends itself if the command is killed
    (`end_with`)."""
    with one_thread_per_worker():
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                   initializer=_start_worker,
                                   initargs=(os.getpid(), initializer, *initargs))  # fmt: skip
        try:
            yield pool
        except BaseException:
            stop_pool(pool)
            raise
        pool.shutdown()


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Stop the workers now (Ctrl-C or an error in the parent) rather than after every queued
    job; jobs already finished keep their outputs."""
    for process in list(getattr(pool, "_processes", {}).values()):
        process.terminate()
    pool.shutdown(wait=True, cancel_futures=True)


def clean_up_when_stopped(clean_up: Callable[[], None]) -> None:
    """In a pool worker: on SIGTERM (the parent's `stop_pool`) run `clean_up` (delete the
    worker's temporary files) and exit at once; the signal's default action ends the process
    without `atexit`, and left them in the temp folder."""

    def stop(signum: int, _frame: object) -> None:
        clean_up()
        os._exit(128 + signum)

    signal.signal(signal.SIGTERM, stop)


def process_running(pid: int) -> bool:
    """Whether a process with this id runs (one of another user counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
