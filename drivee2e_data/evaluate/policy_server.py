"""One network per GPU for every concurrent episode: a policy server process loads the agent's
network once and runs the observations of all the episodes that wait on it as one batch.

Each evaluation worker keeps its own world and renderer and prepares its agent's inputs (the
images it drew, the measurement vector); a `ServedAgent` writes them into its own slot of shared
memory (`evaluate/slots.py`: a file in a folder of the run's under /dev/shm, which the server
maps too) and sends the server of its GPU their layout, a few hundred bytes instead of the
images' 330 kB pickled through a pipe, then waits for the plan. The server takes the first
request, then every request already queued and those that arrive within `gather_seconds()`
(none by default, `GATHER_MS`), stacks them, runs the network once, and answers each worker.
A worker then holds no copy of the network and no CUDA context of its own. Where the server
serves more workers than the host has spare cores, the workers run at a lower priority than
it (`WORKER_NICENESS`), so that a request never waits for a core. With `stats_path`, a server
writes what its batches cost when it stops (`ServerStats`): requests, batches, the network's
time, the gathering's.

An agent can be served when its class offers `model_inputs(observation)` (numpy arrays of one
observation) and `forward_batch(inputs)` (the stacked arrays to plans `(B, T, 2)` in metres,
ego frame); `agents/camera.py` and `agents/tcp.py` do, and their `example_inputs()` (arrays of
those shapes and types) give the server a batch to run before the first request (`warm_up`).
Batched and unbatched runs of the network differ only in the device's arithmetic (a kernel may sum in another order for another
batch size: 1e-7 m here on the CPU), so the episodes are the same (tested on the CPU). A server
runs every batch at one size, `BATCH_ROWS` whatever the number of workers (`batch_plans`: the
requests, then copies of the first): with batches of whatever size had gathered, a plan's last
bits depended on which requests came with it, and on a GPU host the same checkpoint scored DS
38.37 and 39.08 in two runs; at the number of workers a server serves, a run with 24 workers
scored DS 45.643 where 12 and 16 scored 45.638 (H200, 40 clips). At one size for all, a plan
is a function of its own inputs on a given GPU, whatever the worker count.

A run's servers are started by `start_servers` (one per CUDA device, forked with the workers
from the pool's server) and stopped by `stop_servers`.
"""

from __future__ import annotations

import os
import queue
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.evaluate.agent import AgentFailure, Observation, Route, Waypoints
from drivee2e_data.evaluate.options import EvaluationOptions
from drivee2e_data.evaluate.slots import InputSlot, SlotReader, remove_slots, slot_folder
from drivee2e_data.processes import SPAWN, end_with

# After the first request, how long the server waits for more (milliseconds; the variable
# GATHER_MS_VARIABLE overrides it). None: requests queued while the network ran make the next
# batch, so batches grow only when the server is busy. A batch runs at BATCH_ROWS rows whatever
# it holds, so a wait buys no cheaper forward, only a later one: with 2 ms, an H200 host's TCP
# workers waited 12.8 ms a step for a 1.65 ms forward.
GATHER_MS = 0.0
GATHER_MS_VARIABLE = "DRIVEE2E_GATHER_MS"
# the niceness an evaluation worker takes where a policy server shares its cores (0 keeps
# it; WORKER_NICENESS_VARIABLE overrides): a server woken by a request then runs at once, not
# after a worker's time slice
WORKER_NICENESS = 5
WORKER_NICENESS_VARIABLE = "DRIVEE2E_WORKER_NICENESS"
MAX_BATCH = 256
# every batch's rows (`batch_plans`): a server of 16 workers gathers about four requests a
# batch (TCP on an H200: the forward of 8 rows as a graph 1.65 ms, of 16 rows 2.44)
BATCH_ROWS = 8
REPLY_TIMEOUT_S = 600.0  # a server that answers nothing for this long is gone
# where the server runs its network: the agent's device variable, set in the server process
AGENT_DEVICE_VARIABLE = "DRIVEE2E_AGENT_DEVICE"


def gather_seconds() -> float:
    """How long a server waits for more requests after a batch's first (`GATHER_MS`)."""
    return float(os.environ.get(GATHER_MS_VARIABLE, GATHER_MS)) / 1000.0


def worker_niceness() -> int:
    """The niceness served workers take (`WORKER_NICENESS`)."""
    return int(os.environ.get(WORKER_NICENESS_VARIABLE, WORKER_NICENESS))


@dataclass
class ServerStats:
    """What a server's batches cost, summed (seconds): its warm-up batch before the first
    request (`warm_up_s`, `warm_up`), from a batch's first request taken to its last
    (`gather_s`), the network's (`forward_s`: stacking, the batch's forwards and the plans
    back), and the answers' sending (`reply_s`)."""

    device: str = ""
    warm_up_s: float = 0.0
    requests: int = 0
    batches: int = 0
    forwards: int = 0
    gather_s: float = 0.0
    forward_s: float = 0.0
    reply_s: float = 0.0

    def write(self, path: Path) -> None:
        """The totals and the means per batch, as JSON (written whole or not at all)."""
        import json

        from drivee2e_data.store import write_bytes_atomic

        batches = max(1, self.batches)
        fields = {**self.__dict__, "requests_per_batch": self.requests / batches,
                  "gather_ms_per_batch": 1000 * self.gather_s / batches,
                  "forward_ms_per_batch": 1000 * self.forward_s / batches,
                  "reply_ms_per_batch": 1000 * self.reply_s / batches}  # fmt: skip
        write_bytes_atomic(path, (json.dumps(fields, indent=1) + "\n").encode())


def servable(agent: Any) -> bool:
    """Whether an agent offers what a policy server needs."""
    return callable(getattr(agent, "model_inputs", None)) and callable(
        getattr(agent, "forward_batch", None)
    )


@dataclass(frozen=True)
class ServerHandle:
    """What a worker needs to reach its server: the shared request queue, its own reply queue
    (by worker number) and the folder of the input slots (`slot_folder`; "" sends the arrays
    through the queue)."""

    requests: Any
    replies: tuple[Any, ...]
    slots: str = ""


def serve(
    agent_name: str,
    checkpoint: str | None,
    device: str,
    requests: Any,
    replies: tuple[Any, ...],
    agent_factory: Any,
    served: int = 1,
    batch_shape: int = BATCH_ROWS,
    stats_path: str | None = None,
    command: int | None = None,
) -> None:
    """The server's loop (its own process): build the agent on `device`, then answer the
    requests of the `served` workers it serves in batches (each run at `batch_shape` rows,
    `batch_plans`) until a None request comes, or until the command that started it is gone
    (`processes.end_with`: killed outright, it sends none); at a None request, its
    `ServerStats` into `stats_path` (JSON) if given. `command` is the process that started it
    (its parent where not given; a fork server's child has the server as its parent)."""
    end_with(os.getppid() if command is None else command)
    os.environ[AGENT_DEVICE_VARIABLE] = device
    import torch

    torch.set_num_threads(max(1, torch.get_num_threads()))
    if device.startswith("cuda"):  # its GPU current, so nothing it starts lands on cuda:0
        torch.cuda.set_device(device)
    agent, failure = None, ""
    stats = ServerStats(device=device)
    try:
        agent = agent_factory(agent_name, None if checkpoint is None else Path(checkpoint))
        began = time.perf_counter()
        warm_up(agent, batch_shape)
        stats.warm_up_s = time.perf_counter() - began
    except Exception as error:  # every episode then ends with this reason, none waits
        agent, failure = None, f"the policy server could not build agent {agent_name!r}: {error}"
    slots = SlotReader()
    # a worker asks once at a time: no more requests can come once every worker served has
    most = max(1, min(MAX_BATCH, served))
    gather_s = gather_seconds()
    while True:
        first = requests.get()
        if first is None:
            if stats_path:
                stats.write(Path(stats_path))
            return
        batch = [first]
        taken = time.perf_counter()
        deadline = taken + gather_s
        while len(batch) < most:
            try:
                item = requests.get_nowait()
            except queue.Empty:
                remaining = deadline - time.perf_counter()
                if remaining <= 0:
                    break
                try:
                    item = requests.get(timeout=remaining)
                except queue.Empty:
                    break
            if item is None:
                requests.put(None)  # answer this batch first, then stop
                break
            batch.append(item)
        gathered = time.perf_counter()
        workers = [worker for worker, _ in batch]
        if agent is None:
            for worker in workers:
                replies[worker].put(failure)
            continue
        try:
            inputs = [m if isinstance(m, dict) else slots.read(m) for _, m in batch]
            plans = batch_plans(agent, inputs, batch_shape)
            answers: list[Any] = list(plans)
        except Exception as error:  # the network's failure ends those episodes, not the run
            answers = [f"the served network raised {type(error).__name__}: {error}"] * len(batch)
        planned = time.perf_counter()
        for worker, answer in zip(workers, answers, strict=True):
            replies[worker].put(answer)
        stats.requests += len(batch)
        stats.batches += 1
        stats.forwards += -(-len(batch) // max(1, batch_shape))
        stats.gather_s += gathered - taken
        stats.forward_s += planned - gathered
        stats.reply_s += time.perf_counter() - planned


def warm_up(agent: Any, shape: int) -> bool:
    """Run one batch of `shape` rows of the agent's `example_inputs()` (one observation's
    inputs of the shapes and types `model_inputs` gives) through `batch_plans`, where it offers
    them: a GPU's first batch records its CUDA graph (0.3-0.4 s on an H200,
    `scripts/dev/profile_server_start.py`), which the episodes' first steps waited for when
    the first request made it. Returns whether it ran one."""
    example = getattr(agent, "example_inputs", None)
    if not callable(example):
        return False
    batch_plans(agent, [example()], shape)
    return True


def batch_plans(agent: Any, inputs: list[dict[str, np.ndarray]], shape: int) -> np.ndarray:
    """The plans `(N, T, 2)` of `inputs` (one observation's arrays each), run through
    `agent.forward_batch` in batches of exactly `shape` rows (a short one filled up with copies
    of its first row, whose plans are dropped): a device may pick its kernels, and so the order
    of its sums, by a batch's size, and then a plan would depend on the requests it came with."""
    shape = max(1, shape)
    plans = []
    for start in range(0, len(inputs), shape):
        chunk = inputs[start : start + shape]
        rows = chunk + [chunk[0]] * (shape - len(chunk))
        stacked = {key: np.stack([row[key] for row in rows]) for key in chunk[0]}
        plans.append(np.asarray(agent.forward_batch(stacked), np.float64)[: len(chunk)])
    return np.concatenate(plans)


class ServedAgent:
    """An agent whose network runs on a policy server: its own `model_inputs` here, the batched
    forward there, its waypoints back."""

    def __init__(self, agent: Any, handle: ServerHandle, worker: int) -> None:
        if not servable(agent):
            raise DriveE2EError(f"agent {agent.name!r} cannot be served (no model_inputs)")
        self.agent, self.handle, self.worker = agent, handle, worker
        self.slot = InputSlot(handle.slots, worker) if handle.slots else None
        self.name = agent.name
        self.sensors = tuple(agent.sensors)
        self.image_size = agent.image_size
        self.input_size = getattr(agent, "input_size", None)

    def setup(self, route: Route, rig: Any) -> None:
        self.agent.setup(route, rig)

    def act(self, observation: Observation) -> Waypoints:
        return self.act_later(observation)()

    def act_later(self, observation: Observation) -> Callable[[], Waypoints]:
        """Send `observation`'s inputs to the server; the function returned waits for the plan
        (call it once, before the next request: a worker has one request out at a time), so
        that the episode can do its own work meanwhile."""
        inputs = self.agent.model_inputs(observation)
        message: Any = inputs
        if self.slot is not None:
            try:
                message = self.slot.write(inputs)
            except OSError:  # no room for the slot (a full /dev/shm): the arrays go by the queue
                self.slot = None
        self.handle.requests.put((self.worker, message))
        return self._answer

    def _answer(self) -> Waypoints:
        try:
            answer = self.handle.replies[self.worker].get(timeout=REPLY_TIMEOUT_S)
        except queue.Empty:
            raise AgentFailure("the policy server answered nothing") from None
        if isinstance(answer, str):
            raise AgentFailure(answer)
        return Waypoints(answer)


def start_servers(
    options: EvaluationOptions,
    workers: int,
    agent_factory: Any,
    probe: Any,
    out: Path,
    context: Any = SPAWN,
) -> list[tuple[Any, Any]]:
    """One policy server per CUDA device (or one on the CPU with `policy_server="on"` and no
    GPU) for a servable agent: (handle, process) each, each writing what its batches cost into
    `out`/policy_server_<device>.json when it stops; none where the agent runs in its
    workers. `agent_factory` (name, checkpoint) builds the agent in each server; `probe` is
    the agent built without its network (None: an agent command, never served). A GPU's server
    is started by `context` (the pool's), the CPU's spawned."""
    if options.policy_server == "off" or probe is None or not servable(probe):
        return []
    import torch

    devices = [f"cuda:{k}" for k in range(torch.cuda.device_count())]
    if not devices:
        if options.policy_server != "on":
            return []
        devices = ["cpu"]
    replies = tuple(SPAWN.Queue() for _ in range(workers))
    # worker k is served by server k mod len(devices)
    served = -(-workers // len(devices))
    servers = []
    slots = slot_folder()
    for device in devices:
        handle = ServerHandle(SPAWN.Queue(), replies, slots)
        # forked from the workers' server, a GPU's server finds torch imported (CUDA is not
        # started there, so a fork may start it): ready about when the workers are, where
        # spawned it imported torch after the command had (4 s each on an H200 host); the CPU's
        # is spawned, with the host's threads rather than the workers' one
        starter = context if device.startswith("cuda") else SPAWN
        process = starter.Process(
            target=serve,
            args=(options.agent, options.checkpoint, device, handle.requests, replies,
                  agent_factory, served, BATCH_ROWS,
                  str(out / f"policy_server_{device.replace(':', '')}.json"), os.getpid()),
            daemon=True,
        )  # fmt: skip
        process.start()
        servers.append((handle, process))
    return servers


def stop_servers(servers: list[tuple[Any, Any]]) -> None:
    """Ask each of `start_servers`' servers to stop (each writes its account), wait for them
    (a server still running after 30 s is terminated) and remove their input slots."""
    for handle, _ in servers:
        handle.requests.put(None)
    for _, process in servers:
        process.join(timeout=30)
        if process.is_alive():
            process.terminate()
    for folder in {handle.slots for handle, _ in servers}:
        remove_slots(folder)
