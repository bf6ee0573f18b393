"""Pool workers get one native thread each: the environment the parent sets while a pool spawns
its workers, which OpenBLAS reads when numpy loads (before any of our code runs in a worker)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from drivee2e_data import processes
from drivee2e_data.collect.preload import pools_workers
from drivee2e_data.evaluate.preload import pools_workers as evaluation_pools_workers
from drivee2e_data.processes import WORKER_THREADS, one_thread_per_worker

# a child that loads numpy, multiplies 200,000 rows by a 3x3 matrix (the size the LiDAR's
# rotations have) and reports its OpenBLAS setting and how many threads it runs
CHILD = (
    "import os, numpy as np; a = np.ones((200000, 3)); a @ np.ones((3, 3)); "
    "print(os.getenv('OPENBLAS_NUM_THREADS'), len(os.listdir('/proc/self/task')))"
)


def child_threads() -> tuple[str, int]:
    done = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True)
    setting, threads = done.stdout.split()
    return setting, int(threads)


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads in /proc")
def test_workers_spawned_under_one_thread_per_worker_run_numpy_on_one_thread(monkeypatch):
    for name in WORKER_THREADS:
        monkeypatch.delenv(name, raising=False)
    with one_thread_per_worker():
        assert child_threads() == ("1", 1)
    assert all(name not in os.environ for name in WORKER_THREADS)  # the parent's, as it was
    if len(os.sched_getaffinity(0)) > 1:  # without it OpenBLAS starts a thread per core
        setting, threads = child_threads()
        assert setting == "None" and threads > 1


def test_a_setting_of_the_users_own_is_kept(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    monkeypatch.delenv("LP_NUM_THREADS", raising=False)
    with one_thread_per_worker():
        assert os.environ["OPENBLAS_NUM_THREADS"] == "3"
        assert os.environ["LP_NUM_THREADS"] == "1"
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3"
    assert "LP_NUM_THREADS" not in os.environ


# a parent that starts a preloading pool and asks its worker what it had imported before the
# task ran, and which OpenBLAS setting it got; then reports its own setting
PRELOADING_PARENT = """
import os, sys
from multiprocessing import forkserver
from drivee2e_data.collect.preload import pools_workers
from drivee2e_data.processes import preloading, start_server, worker_pool

def report():
    return "colorsys" in sys.modules, os.getenv("OPENBLAS_NUM_THREADS")

def nothing():
    pass

if __name__ == "__main__":
    context = preloading(["colorsys"])
    start_server(context)  # started before any pool, and the pool's workers fork from it
    server = forkserver._forkserver._forkserver_pid
    with worker_pool(2, nothing, (), context) as pool:
        first = pool.submit(report).result()
    print(context.get_start_method(), first[0], first[1], os.getenv("OPENBLAS_NUM_THREADS"),
          "colorsys" in sys.modules, server is not None, server == forkserver._forkserver._forkserver_pid)
"""


@pytest.mark.skipif(sys.platform != "linux", reason="the forkserver start method is Linux's here")
def test_a_preloading_pool_forks_workers_that_imported_the_modules_in_one_thread(
    tmp_path, monkeypatch
):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    script = tmp_path / "parent.py"
    script.write_text(PRELOADING_PARENT)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          check=True, cwd=tmp_path)  # fmt: skip
    method, preloaded, worker_setting, parent_setting, parent_imported, *server = (
        done.stdout.split()
    )
    # the worker had the module before its task ran; the parent never imported it
    assert (method, preloaded, parent_imported) == ("forkserver", "True", "False")
    assert (worker_setting, parent_setting) == ("1", "None")
    assert server == ["True", "True"]  # started early, and the one the pool used


LONG_TEMP_PARENT = """
import os
from drivee2e_data.processes import preloading, start_server, worker_pool

def pid():
    return os.getpid()

if __name__ == "__main__":
    context = preloading(["colorsys"])
    start_server(context)
    with worker_pool(2, pid, (), context) as pool:
        worker = pool.submit(pid).result()
    print(context.get_start_method(), worker != os.getpid())
"""


@pytest.mark.skipif(sys.platform != "linux", reason="the forkserver start method is Linux's here")
@pytest.mark.parametrize("length, method", [(40, "forkserver"), (90, "spawn")])
def test_a_temp_folder_too_long_for_the_servers_socket_gives_a_spawning_pool(
    tmp_path, length, method
):
    """A TMPDIR whose path leaves the fork server's socket no room (a Unix socket's path is at
    most 107 bytes) gets a pool of spawned workers instead of "AF_UNIX path too long"."""
    temporary = Path(tempfile.mkdtemp(prefix="t", dir="/tmp"))
    try:
        long = temporary / ("x" * (length - len(str(temporary)) - 1))
        long.mkdir()
        assert len(str(long)) == length and processes.socket_fits(str(long)) == (length == 40)
        script = tmp_path / "parent.py"
        script.write_text(LONG_TEMP_PARENT)
        done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                              cwd=tmp_path, env={**os.environ, "TMPDIR": str(long)})  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert done.stdout.split() == [method, "True"]
    finally:
        shutil.rmtree(temporary)


KILLED_PARENT = """
import os, sys, time
from drivee2e_data.processes import SPAWN, preloading, worker_pool

def nothing():
    pass

if __name__ == "__main__":
    context = preloading(["colorsys"]) if sys.argv[1] == "forkserver" else SPAWN
    with worker_pool(2, nothing, (), context) as pool:
        busy = [pool.submit(time.sleep, 120) for _ in range(2)]
        time.sleep(1.0)
        print(*[process.pid for process in pool._processes.values()], flush=True)
        time.sleep(120)
"""


@pytest.mark.skipif(sys.platform != "linux", reason="the forkserver start method is Linux's here")
@pytest.mark.parametrize("method", ["forkserver", "spawn"])
def test_a_killed_commands_pool_workers_end_with_it(tmp_path, method):
    """A command killed outright (SIGKILL: no handler runs) takes its pool's workers with it,
    busy as they are, whether forked from the forkserver or spawned (`end_with`)."""
    import signal
    import time

    from drivee2e_data.processes import process_running

    script = tmp_path / "parent.py"
    script.write_text(KILLED_PARENT)
    parent = subprocess.Popen([sys.executable, str(script), method], stdout=subprocess.PIPE,
                              text=True, cwd=tmp_path)  # fmt: skip
    try:
        workers = [int(pid) for pid in parent.stdout.readline().split()]
        assert len(workers) == 2 and all(process_running(pid) for pid in workers)
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
    deadline = time.monotonic() + 20.0
    while any(process_running(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(process_running(pid) for pid in workers)


@pytest.mark.parametrize(
    ("argv", "pooled"),
    [
        (["collect", "DATA", "--workers", "auto"], True),
        (["collect", "DATA", "--workers=4"], True),
        (["collect", "DATA"], False),  # one worker by default
        (["collect", "DATA", "--workers", "1"], False),
        (["collect", "DATA", "--workers", "8", "--backend", "ray"], False),
        (["collect", "DATA", "--workers", "8", "--backend=local"], True),
        (["view", "DATA", "--workers", "8"], False),
        ([], False),
    ],
)
def test_the_command_line_says_when_a_collection_runs_a_local_pool(argv, pooled):
    assert pools_workers(argv) is pooled


def test_the_entry_point_starts_the_pool_server_before_the_command_runs(monkeypatch):
    from drivee2e_data import cli, launch
    from drivee2e_data.collect import preload

    events = []
    monkeypatch.setattr(preload, "start_worker_server", lambda: events.append("server"))
    monkeypatch.setattr(cli, "main", lambda argv: events.append(("command", argv)) or 0)
    for argv in (["collect", "D", "--workers", "2"], ["collect", "D"]):
        monkeypatch.setattr(sys, "argv", ["drivee2e", *argv])
        assert launch.main() == 0
    assert events == [
        "server",
        ("command", ["collect", "D", "--workers", "2"]),
        ("command", ["collect", "D"]),
    ]


@pytest.mark.parametrize(
    ("argv", "pooled"),
    [
        (["evaluate", "DATA", "--workers", "auto"], True),
        (["evaluate", "DATA", "--agent", "tcp", "--workers=16"], True),
        (["evaluate", "DATA"], False),  # one worker by default
        (["evaluate", "DATA", "--workers", "1"], False),
        (["collect", "DATA", "--workers", "8"], False),
        ([], False),
    ],
)
def test_the_command_line_says_when_an_evaluation_runs_a_pool(argv, pooled):
    assert evaluation_pools_workers(argv) is pooled


def test_the_entry_point_starts_an_evaluations_server_with_its_agents_module(monkeypatch):
    from drivee2e_data import cli, launch
    from drivee2e_data.evaluate import preload

    started = []
    monkeypatch.setattr(preload, "start_worker_server", started.append)
    monkeypatch.setattr(cli, "main", lambda argv: 0)
    for argv in (
        ["evaluate", "D", "--workers", "4", "--agent", "tcp", "--checkpoint", "t.pt"],
        ["evaluate", "D", "--workers", "4"],  # the expert by default
        ["evaluate", "D", "--workers", "4", "--agent", "my_module:MyAgent"],
        ["evaluate", "D", "--workers", "4", "--agent-cmd", "python my_agent.py"],
        ["evaluate", "D", "--agent", "tcp"],  # one worker: no pool, no server
    ):
        monkeypatch.setattr(sys, "argv", ["drivee2e", *argv])
        assert launch.main() == 0
    assert started == [
        ("drivee2e_data.agents.tcp",),
        ("drivee2e_data.agents.expert",),
        (),
        (),
    ]


WORKERS_JSON = """
import json
from drivee2e_data.agents import registry
from drivee2e_data.processes import SPAWN, preloading, worker_pool
if __name__ == "__main__":
    registry.resolve("expert")  # adds the working directory to the path, as evaluate does
    for context in (preloading(["json"]), SPAWN):
        with worker_pool(1, print, (), context) as pool:
            found = pool.submit(eval, "__import__('json').__file__").result()
            print(context.get_start_method(), found == json.__file__, found)
"""


def test_workers_import_what_their_parent_imported_wherever_it_started(tmp_path):
    """A command started from a checkout beside a plain `pip install .` had its forkserver
    import from the working directory first, where the checkout's `drivee2e_data/` (without
    `collect/`) shadowed the installed package (`No module named 'drivee2e_data.collect'` in
    every worker). Here a `json.py` in the working directory stands for it: the pools' workers,
    forked from a server that preloads json or spawned, must import the parent's json."""
    checkout, scripts = tmp_path / "checkout", tmp_path / "bin"
    checkout.mkdir()
    scripts.mkdir()
    (checkout / "json.py").write_text("SHADOW = True\n")
    (scripts / "command.py").write_text(WORKERS_JSON)  # as a console script: its folder first
    done = subprocess.run(
        [sys.executable, str(scripts / "command.py")],
        cwd=checkout, capture_output=True, text=True, check=True,
        env={k: v for k, v in os.environ.items() if k != "PYTHONSAFEPATH"},
    )  # fmt: skip
    lines = [line for line in done.stdout.splitlines() if line.startswith(("forkserver", "spawn"))]
    assert lines, done.stdout
    for line in lines:
        method, same, where = line.split(" ", 2)
        assert same == "True", (method, where)
