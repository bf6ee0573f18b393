"""A closed-loop evaluation of one agent over the clips of a split: one episode per clip, in
worker processes when asked, each episode's result written atomically as it finishes
(`RUN/episodes/<scenario_id>.json`), so a killed run resumes with the episodes it lacks; the
run's tables then come from `results`.

A worker builds its agent once (a `--agent-cmd` child once, again after a failure) and keeps
the pybullet world of its last map for the next clip on it; agents that ask for no sensors run
without pybullet at all.
"""

from __future__ import annotations

import atexit
import functools
import json
import os
import random
import resource
import signal
import sys
import tempfile
import time
import zlib
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_data import store
from drivee2e_data.curation.occlusion import Variant
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.evaluate import preload
from drivee2e_data.evaluate.claims import ClipOrder, all_claimed, claim, clip_order
from drivee2e_data.evaluate.episode import Episode, EpisodeOptions
from drivee2e_data.evaluate.options import EvaluationOptions
from drivee2e_data.evaluate.policy_server import start_servers, stop_servers
from drivee2e_data.evaluate.results import EPISODES_FOLDER, read_rows, result_row
from drivee2e_data.evaluate.variants import read_variant
from drivee2e_data.processes import (
    clean_up_when_stopped,
    start_server,
    usable_cores,
    worker_pool,
)

RESULTS_FOLDER = "results"
RECORDS_FOLDER = "records"


def run_name(options: EvaluationOptions, split: str) -> str:
    agent = "remote" if options.agent_cmd else options.agent.replace(":", ".")
    traffic = "-reactive" if options.reactive else ""
    return f"{agent}-{split}-{options.variant}{traffic}"


def prepare_run(
    root: Path, out: Path, options: EvaluationOptions, scenario_ids: list[str]
) -> list[str]:
    """Create or reopen the run folder; the clips still without a result. A missing occlusion
    variant fails here, before the folder or any episode."""
    read_variant(root, Variant(options.variant))
    out.mkdir(parents=True, exist_ok=True)
    run_file = out / "run.json"
    identity = options.identity()
    if run_file.is_file():
        previous = json.loads(run_file.read_text())
        if previous != identity:
            raise DriveE2EError(
                f"{run_file}: this folder holds a run with other options ({previous}); "
                "choose another --out or delete it"
            )
    else:
        store.write_bytes_atomic(run_file, json.dumps(identity, indent=1, sort_keys=True).encode())
    done = set()
    for path in (out / EPISODES_FOLDER).glob("*.json"):
        # a clip that could not be run (status 'error': a broken bundle) is tried again
        if json.loads(path.read_text()).get("status") != "error":
            done.add(path.stem)
    return [s for s in scenario_ids if s not in done]


# -- one episode, in whichever process runs it ------------------------------------------------

_agent: Any = None
_world: Any = None
# in a pool worker: its number, and the policy server its agent's network runs on (if any)
_worker_number = 0
_server: Any = None


# builds an agent from its name and checkpoint (the CLI hands `agents.registry.build`: agents
# sit above this layer, so the evaluator takes the builder rather than importing it); must be
# picklable (a module-level function) to reach pool workers
AgentFactory = Callable[[str, Path | None], Any]


def _agent_for(options: EvaluationOptions, agent_factory: AgentFactory | None) -> Any:
    global _agent
    if _agent is None:
        if options.agent_cmd:
            from drivee2e_data.evaluate.remote import RemoteAgent

            _agent = RemoteAgent(options.agent_cmd, step_timeout_s=options.step_timeout_s)
        else:
            if agent_factory is None:
                raise DriveE2EError(
                    f"agent {options.agent!r}: no agent factory given (pass agent_factory, "
                    "e.g. drivee2e_data.agents.registry.build, or an agent command)"
                )
            checkpoint = Path(options.checkpoint) if options.checkpoint else None
            if _server is None:
                _agent = agent_factory(options.agent, checkpoint)
            else:
                from drivee2e_data.evaluate.policy_server import ServedAgent

                inner = _without_network(agent_factory, options.agent, checkpoint)
                _agent = ServedAgent(inner, _server, _worker_number)
    return _agent


def _without_network(factory: AgentFactory, name: str, checkpoint: Path | None) -> Any:
    """The agent built without loading its network, where its factory allows it (the
    registry's does); a factory that does not gets the plain call."""
    try:
        return factory(name, checkpoint, network=False)  # type: ignore[call-arg]
    except TypeError:
        return factory(name, checkpoint)


def _world_for(root: Path, scenario: Any, renderer: str) -> Any:
    global _world
    from drivee2e_data.sim import reuse
    from drivee2e_data.sim.world import world_for

    _world = world_for(
        _world, scenario, lambda map_id: store.read_map(root, map_id), renderer,
        plan_for=functools.partial(reuse.twin_plan, root),
    )  # fmt: skip
    return _world


def close_process_state() -> None:
    global _agent, _world
    if _agent is not None and hasattr(_agent, "close"):
        _agent.close()
    if _world is not None:
        _world.close()
    _agent = _world = None


def _seed(seed: int, scenario_id: str) -> None:
    value = zlib.crc32(f"{seed}/{scenario_id}".encode())
    random.seed(value)
    np.random.seed(value)  # noqa: NPY002 (a user's agent may draw from the global generator)
    if "torch" in sys.modules:
        sys.modules["torch"].manual_seed(value)


def evaluate_clip(
    root: Path,
    scenario_id: str,
    options: EvaluationOptions,
    out: Path,
    agent_factory: AgentFactory | None = None,
) -> dict[str, Any]:
    """Run one episode and write its row; an agent failure is a result, a broken clip is a row
    with status 'error'."""
    start, started_at = time.perf_counter(), time.time()
    row: dict[str, Any]
    try:
        scenario = store.read_scenario(root, scenario_id)
        intersection_map = store.read_map(root, scenario.map_id)
        removed = read_variant(root, Variant(options.variant)).get(scenario_id)
        if removed is None and options.variant != Variant.COMPLETE.value:
            raise DriveE2EError(
                f"clip {scenario_id} has no {options.variant} variant; curate again"
            )
        began = time.perf_counter()
        agent = _agent_for(options, agent_factory)
        agent_built = time.perf_counter()
        world = _world_for(root, scenario, options.renderer) if tuple(agent.sensors) else None
        world_built = time.perf_counter()
        _seed(options.seed, scenario_id)
        episode = Episode(
            scenario,
            intersection_map,
            agent,
            EpisodeOptions(
                options.reactive, options.min_speed, removed or frozenset(), options.exact_images
            ),
            world=world,
            keep_trace=bool(options.record),
        )
        result = episode.run()
        if options.record == "mcap":
            from drivee2e_data.evaluate.record import write_record

            write_record(out / RECORDS_FOLDER / f"{scenario_id}.mcap", scenario, intersection_map,
                         result, episode.route_xy, episode.bicycle)  # fmt: skip
        elif options.record == "mp4":
            from drivee2e_data.evaluate.video import write_video

            world = world or _world_for(root, scenario, options.renderer)
            write_video(out / RECORDS_FOLDER / f"{scenario_id}.mp4", world, scenario, result,
                        episode.route_xy, episode.motion.z_m, episode.bicycle)  # fmt: skip
        row = result_row(scenario, result, options, len(removed or ()))
        # a scene's set-up: reading it, the agent (made once per process), the world (a
        # process's first one makes its GL context and compiles its shaders)
        row["read_seconds"] = began - start
        row["agent_build_seconds"] = agent_built - began
        row["world_seconds"] = world_built - agent_built
    except (DriveE2EError, ValueError, KeyError, OSError) as error:  # this clip only
        row = {"scenario_id": scenario_id, "status": "error", "failure": str(error)}
    row["wall_seconds"] = time.perf_counter() - start
    # when (Unix seconds): a run's start-up and wind-down are what its episodes do not cover
    row["started_at"], row["ended_at"] = started_at, time.time()
    row["peak_rss_bytes"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    store.write_bytes_atomic(
        out / EPISODES_FOLDER / f"{scenario_id}.json", json.dumps(row, sort_keys=True).encode()
    )
    return row


def evaluate_claimed(
    root: Path,
    claims: str,
    order: ClipOrder,
    options: EvaluationOptions,
    out: Path,
    agent_factory: AgentFactory | None = None,
) -> dict[str, Any]:
    """`evaluate_clip` of the clip this task claims in the folder `claims` (`claims.claim`: the
    longest of `order` left on the map this worker's world shows, else the longest left)."""
    shown = _world.intersection_map.map_id if _world is not None else None
    row = evaluate_clip(root, claim(Path(claims), order, shown), options, out, agent_factory)
    if all_claimed(Path(claims), order):
        give_back_world()
    return row


def give_back_world() -> bool:
    """Close this process's world and give its GL context back to the driver, where a pool
    worker has no episode left to run: NVIDIA's driver tears contexts down one at a time, so
    workers that give theirs back as they run out of clips do it while others still drive,
    rather than all together when the pool shuts down (the collector's workers do the same,
    `collect.job.release_world`). Returns whether there was a world."""
    global _world
    if _world is None:
        return False
    from drivee2e_data.sim import gl_context

    _world.close()
    _world = None
    gl_context.release_context()
    return True


# -- the whole run ----------------------------------------------------------------------------


def evaluate(
    root: Path,
    scenario_ids: list[str],
    options: EvaluationOptions,
    out: Path,
    workers: int = 1,
    on_episode: Callable[[dict[str, Any]], None] | None = None,
    agent_factory: AgentFactory | None = None,
    probe: Any = None,
) -> list[dict[str, Any]]:
    """Evaluate the clips without a result yet; returns every clip's row (old and new). Agents
    by name are built by `agent_factory` (name, checkpoint); a command needs none. `probe`: the
    agent built without its network, where the caller built one already (the CLI does, to check
    the name and checkpoint before anything starts): a pool is laid out by it, not by another."""
    pending = prepare_run(root, out, options, scenario_ids)
    if workers <= 1 or len(pending) <= 1:
        try:
            for scenario_id in pending:
                row = evaluate_clip(root, scenario_id, options, out, agent_factory)
                if on_episode is not None:
                    on_episode(row)
        finally:
            close_process_state()
    else:
        _run_pool(root, pending, options, out, workers, on_episode, agent_factory, probe)
    return read_rows(out, scenario_ids)


def _init_worker(
    counter: Any = None,
    servers: tuple[Any, ...] = (),
    gpus: tuple[int, ...] = (),
    workers: int = 1,
    context_slots: Any = None,
) -> None:
    """A pool worker's start (one of `workers`): its number (from `counter`), the policy server
    and the EGL GPU it uses (each round robin over its kind: EGL's and CUDA's orders of the
    GPUs are their own), one thread each; with `context_slots` (a semaphore: a served camera
    agent's worker on GPUs), its GL context made now, while holding one of them
    (`_context_slots`), at low priority on its GPU, so that the policy server's network, which
    every step waits for, takes its turns on that GPU before the workers' draws
    (`egl_context`: 0.36-0.37x real time against 0.38-0.41x, TCP, 16 workers, one H200)."""
    global _worker_number, _server
    if counter is not None:
        with counter.get_lock():
            _worker_number, counter.value = counter.value, counter.value + 1
    if servers:
        _server = servers[_worker_number % len(servers)]
        _yield_to_servers(workers, len(servers))
    if gpus:
        from drivee2e_data.sim import egl_devices

        egl_devices.use_device(egl_devices.device_for_worker(_worker_number, gpus))
    if context_slots is not None:
        from drivee2e_data.sim import egl_context, gl_context

        egl_context.use_priority(egl_context.Priority.LOW)
        with context_slots:
            gl_context.gl_available()
    # one thread per worker for OpenCV and torch too (llvmpipe's, OpenBLAS's and OpenMP's are
    # set for the workers by the parent, `one_thread_per_worker`): with a worker per core,
    # per-core threads only compete (a lone evaluation process keeps them all)
    import cv2
    import torch  # reads OMP_NUM_THREADS when first imported (the command line imports none)

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # stopped: the twin's meshes go (a child agent process, `--agent-cmd`, ends with its pipe)
    clean_up_when_stopped(_remove_world_files)
    atexit.register(close_process_state)  # the world's EGL context closes quietly


def _yield_to_servers(workers: int, servers: int) -> None:
    """A served worker's niceness (`policy_server.worker_niceness`) where the pool's `workers`
    and its `servers` are more than the cores: a server's answer then never waits for a core."""
    from drivee2e_data.evaluate.policy_server import worker_niceness

    if workers + servers > usable_cores() and worker_niceness() > 0:
        os.nice(worker_niceness())


def _context_slots(
    context: Any, gpus: tuple[int, ...], probe: Any, servers: list[tuple[Any, Any]]
) -> Any:
    """A semaphore of `egl_devices.contexts_at_once` slots, where a pool's workers draw on GPUs
    (`gpus`) for an agent that reads cameras (`probe`) and is served (its CUDA is the servers',
    none in the workers): each worker then makes its GL context as it starts, a few at a time,
    and the first take the first (longest) clips while the others wait, instead of all making
    theirs together in their first world (40 at once on four H200: 4.5 s each, 16: 2.2 s;
    docs/benchmarks.md, closed loop). None otherwise: a world makes its context."""
    if not gpus or not servers or probe is None or not tuple(probe.sensors):
        return None
    from drivee2e_data.sim.egl_devices import contexts_at_once

    return context.Semaphore(contexts_at_once(gpus))


def _remove_world_files() -> None:
    if _world is not None:
        _world.twin.remove_files()


def _run_pool(
    root: Path,
    pending: list[str],
    options: EvaluationOptions,
    out: Path,
    workers: int,
    on_episode: Callable[[dict[str, Any]], None] | None,
    agent_factory: AgentFactory | None,
    probe: Any = None,
) -> None:
    # the workers fork from a server that imported what they need once (started by the command's
    # entry point already, or now: its imports run while the policy servers start)
    context = preload.worker_context()
    start_server(context)
    counter = context.Value("i", 0)
    gpus = _render_gpus(options)
    probe = _probe(options, agent_factory, probe)
    servers = start_servers(options, workers, agent_factory, probe, out, context)
    handles = tuple(handle for handle, _ in servers)
    slots = _context_slots(context, gpus, probe, servers)
    try:
        _pool_episodes(root, pending, options, out, workers, on_episode, agent_factory,
                       (counter, handles, gpus, workers, slots), context)  # fmt: skip
    finally:
        stop_servers(servers)


# an episode of an agent that draws nothing takes well under a second, a worker's start a few:
# such runs get a worker for this many clips
CLIPS_PER_STATE_WORKER = 10


def auto_workers(clips: int, draws: bool) -> int:
    """`--workers auto`: one per core for an agent that reads cameras (drawing is the work);
    for one that reads none, one per `CLIPS_PER_STATE_WORKER` clips, at most one per core."""
    cores = usable_cores()
    if draws:
        return max(1, min(cores, clips))
    return max(1, min(cores, -(-clips // CLIPS_PER_STATE_WORKER)))


def _render_gpus(options: EvaluationOptions) -> tuple[int, ...]:
    """The EGL GPU devices a pool's workers spread their renderers over (none on a CPU)."""
    if options.renderer not in ("auto", "gl"):
        return ()
    from drivee2e_data.sim import egl_devices

    return egl_devices.gpu_devices()


def _probe(
    options: EvaluationOptions, agent_factory: AgentFactory | None, given: Any = None
) -> Any:
    """The run's agent built without its network (what it reads, whether it can be served):
    `given` where the caller built it, else built here; None for an agent command or without a
    factory."""
    if options.agent_cmd or agent_factory is None:
        return None
    if given is not None:
        return given
    checkpoint = Path(options.checkpoint) if options.checkpoint else None
    return _without_network(agent_factory, options.agent, checkpoint)


def _pool_episodes(
    root: Path,
    pending: list[str],
    options: EvaluationOptions,
    out: Path,
    workers: int,
    on_episode: Callable[[dict[str, Any]], None] | None,
    agent_factory: AgentFactory | None,
    initargs: tuple[Any, ...],
    context: Any,
) -> None:
    # a task a clip, each claiming its clip as it starts (`claims`): a worker keeps to its
    # world's map while that map has clips left, longest first
    order = clip_order(root, pending)
    reported: set[str] = set()
    with (
        tempfile.TemporaryDirectory(prefix="drivee2e_claims_") as claims,
        worker_pool(workers, _init_worker, initargs, context) as pool,
    ):
        remaining: set[Future] = {
            pool.submit(evaluate_claimed, root, claims, order, options, out, agent_factory)
            for _ in order
        }
        while remaining:
            done, remaining = wait(remaining, return_when=FIRST_COMPLETED)
            for future in done:
                try:
                    row = future.result()
                except BrokenProcessPool:
                    continue  # its clip is among those without a row, below
                reported.add(row["scenario_id"])
                if on_episode is not None:
                    on_episode(row)
    # a worker that died took its clip and the tasks not yet run with it
    for scenario_id, _ in order:
        if scenario_id not in reported and on_episode is not None:
            on_episode({"scenario_id": scenario_id, "status": "error",
                        "failure": "the worker process died"})  # fmt: skip
