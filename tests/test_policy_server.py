"""The policy server's batches: each run at one fixed size, so that a plan depends on its own
inputs alone, not on which other workers' requests were gathered with it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from drivee2e_data.evaluate.policy_server import batch_plans


class _Toy:
    """A served agent's interface over a small network: `forward_batch` of stacked inputs."""

    def __init__(self) -> None:
        torch.manual_seed(0)
        self.net = torch.nn.Sequential(
            torch.nn.Linear(512, 256), torch.nn.ReLU(), torch.nn.Linear(256, 12)
        )
        self.sizes: list[int] = []

    @torch.no_grad()
    def forward_batch(self, inputs: dict[str, np.ndarray]) -> np.ndarray:
        self.sizes.append(len(inputs["x"]))
        return self.net(torch.from_numpy(inputs["x"])).reshape(-1, 6, 2).double().numpy()


def _inputs(count: int) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(0)
    return [{"x": rng.standard_normal(512).astype(np.float32)} for _ in range(count)]


def test_a_plan_is_the_same_whichever_requests_it_is_batched_with() -> None:
    agent, inputs = _Toy(), _inputs(8)
    alone = batch_plans(agent, inputs[:1], 4)[0]
    with_others = batch_plans(agent, [inputs[5], inputs[6], inputs[0]], 4)[2]
    in_a_full_batch = batch_plans(agent, [inputs[3], inputs[0], inputs[1], inputs[2]], 4)[1]
    assert np.array_equal(alone, with_others) and np.array_equal(alone, in_a_full_batch)
    # more requests than the shape: run in batches of that shape, every plan in order
    plans = batch_plans(agent, inputs[:6], 4)
    assert plans.shape == (6, 6, 2) and np.array_equal(plans[0], alone)
    assert agent.sizes == [4, 4, 4, 4, 4]
    # a batch of another size may sum in another order (1e-7 here on the CPU), no more
    unpadded = agent.forward_batch({"x": np.stack([inputs[0]["x"], inputs[1]["x"]])})[0]
    assert np.allclose(unpadded, alone, atol=1e-5)


class _ServedToy(_Toy):
    """`_Toy` with the rest of a servable agent's interface; its observation is its input."""

    name = "toy"
    sensors: tuple[str, ...] = ()
    image_size = None

    def model_inputs(self, observation: np.ndarray) -> dict[str, np.ndarray]:
        return {"x": observation}


def _toy_factory(name: str, checkpoint: object, network: bool = True) -> _ServedToy:
    return _ServedToy()


def test_served_agents_get_through_their_slots_the_plans_of_the_network() -> None:
    from drivee2e_data.evaluate.policy_server import (
        ServedAgent,
        ServerHandle,
        serve,
    )
    from drivee2e_data.evaluate.slots import remove_slots, slot_folder
    from drivee2e_data.processes import SPAWN

    folder, inputs = slot_folder(), _inputs(6)
    handle = ServerHandle(SPAWN.Queue(), (SPAWN.Queue(), SPAWN.Queue()), folder)
    server = SPAWN.Process(
        target=serve,
        args=("toy", None, "cpu", handle.requests, handle.replies, _toy_factory, 2, 2),
        daemon=True,
    )
    server.start()
    try:
        agents = [ServedAgent(_ServedToy(), handle, worker) for worker in (0, 1)]

        def full(inputs: dict[str, np.ndarray]) -> None:
            raise OSError(28, "No space left on device")

        assert agents[1].slot is not None
        agents[1].slot.write = full  # type: ignore[method-assign]  # a full /dev/shm
        plans = [agents[k % 2].act(row["x"]).xy_m for k, row in enumerate(inputs)]
        assert agents[0].slot is not None and agents[1].slot is None  # by the queue instead
    finally:
        handle.requests.put(None)
        server.join(timeout=60)
        remove_slots(folder)
    expected = batch_plans(_Toy(), inputs, 2)  # each alone in a batch of the server's size
    assert all(np.array_equal(plan, want) for plan, want in zip(plans, expected, strict=True))


def _niceness_after(workers: int, servers: int, variable: str | None = None) -> int:
    """A fresh process's niceness after `runner._yield_to_servers(workers, servers)`."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "DRIVEE2E_WORKER_NICENESS"}
    if variable is not None:
        env["DRIVEE2E_WORKER_NICENESS"] = variable
    code = ("import os; from drivee2e_data.evaluate import runner; base = os.nice(0); "
            f"runner._yield_to_servers({workers}, {servers}); print(os.nice(0) - base)")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True)  # fmt: skip
    return int(done.stdout)


def test_served_workers_yield_to_their_server_only_where_they_fill_the_cores() -> None:
    """Workers and servers more than the cores: a worker takes `WORKER_NICENESS` (or the
    variable's), so that a woken server runs at once; fewer, or the variable at 0: unchanged."""
    import os

    from drivee2e_data.evaluate.policy_server import WORKER_NICENESS

    cores = len(os.sched_getaffinity(0))
    assert _niceness_after(cores, 1) == WORKER_NICENESS
    assert _niceness_after(cores, 1, variable="2") == 2
    assert _niceness_after(cores, 1, variable="0") == 0
    assert _niceness_after(max(1, cores - 1), 1) == 0


def test_the_server_takes_what_is_queued_without_waiting_unless_told(monkeypatch) -> None:
    from drivee2e_data.evaluate import policy_server

    monkeypatch.delenv(policy_server.GATHER_MS_VARIABLE, raising=False)
    assert policy_server.gather_seconds() == 0.0
    monkeypatch.setenv(policy_server.GATHER_MS_VARIABLE, "2.5")
    assert policy_server.gather_seconds() == 0.0025


def test_a_server_forked_from_the_fork_server_ends_with_the_command_it_is_given() -> None:
    """A GPU's policy server forks from the pool's fork server, which outlives a command killed
    outright: the server watches the command it is given, not its parent."""
    from drivee2e_data.agents.registry import build
    from drivee2e_data.evaluate.policy_server import ServerHandle, serve
    from drivee2e_data.processes import SPAWN, preloading

    context = preloading(["json"])
    if context.get_start_method() != "forkserver":
        pytest.skip("no fork server here")
    command = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    handle = ServerHandle(SPAWN.Queue(), (SPAWN.Queue(),), "")
    server = context.Process(
        target=serve,
        args=("constant-velocity", None, "cpu", handle.requests, handle.replies, build, 1, 2,
              None, command.pid),
        daemon=True,
    )  # fmt: skip
    server.start()
    try:
        server.join(timeout=3.0)
        assert server.exitcode is None  # serving while the command runs
        command.kill()
        command.wait()
        server.join(timeout=30.0)
        assert server.exitcode is not None  # ended with it, though no None request came
    finally:
        if server.exitcode is None:
            server.terminate()
        command.kill()


class _ExampleToy(_ServedToy):
    """`_ServedToy` offering the example inputs a server warms up on."""

    def example_inputs(self) -> dict[str, np.ndarray]:
        return {"x": np.zeros(512, np.float32)}


def _example_factory(name: str, checkpoint: object, network: bool = True) -> _ExampleToy:
    return _ExampleToy()


def test_a_server_warms_up_on_the_agents_example_before_its_first_request(tmp_path) -> None:
    """`warm_up` runs one batch of the server's rows of the agent's `example_inputs()` (a GPU's
    first batch records its CUDA graph), and nothing for an agent without them; a server runs
    it before its first request (its account's `warm_up_s`) and then answers as before."""
    import json

    from drivee2e_data.evaluate.policy_server import ServedAgent, ServerHandle, serve, warm_up
    from drivee2e_data.processes import SPAWN

    with_example, without = _ExampleToy(), _ServedToy()
    assert warm_up(with_example, 4) and with_example.sizes == [4]
    assert not warm_up(without, 4) and without.sizes == []
    handle = ServerHandle(SPAWN.Queue(), (SPAWN.Queue(),))
    stats = tmp_path / "server.json"
    server = SPAWN.Process(
        target=serve,
        args=("toy", None, "cpu", handle.requests, handle.replies, _example_factory, 1, 2,
              str(stats)),
        daemon=True,
    )  # fmt: skip
    server.start()
    inputs = _inputs(1)
    try:
        plan = ServedAgent(_ServedToy(), handle, 0).act(inputs[0]["x"]).xy_m
    finally:
        handle.requests.put(None)
        server.join(timeout=60)
    assert np.array_equal(plan, batch_plans(_Toy(), inputs, 2)[0])
    account = json.loads(stats.read_text())
    assert account["warm_up_s"] > 0.0 and account["requests"] == 1


@pytest.mark.parametrize("name", ["camera", "tcp"])
def test_the_camera_agents_examples_have_their_inputs_shapes_and_types(name: str) -> None:
    """A camera agent's `example_inputs()` are arrays of the shapes and types its
    `model_inputs` makes of an observation (the warm-up batch records the graph the
    observations' batches replay)."""
    import importlib

    from drivee2e_data.evaluate.agent import Observation

    module = importlib.import_module(f"drivee2e_data.agents.{name}")
    agent_class = module.CameraAgent if name == "camera" else module.TCPAgent
    agent = agent_class.__new__(agent_class)  # no checkpoint: the inputs need none
    agent.image_size = (1600, 900)
    width, height = module.INPUT_SIZE
    rng = np.random.default_rng(0)
    pixels = {c: rng.integers(0, 256, (3, height, width), dtype=np.uint8)
              for c in agent.sensors}  # fmt: skip
    observation = Observation(
        step=0, t_s=0.0, xy_m=np.zeros(2), yaw_rad=0.0, lat_lon_alt=np.zeros(3),
        speed_mps=4.0, imu_acceleration_mps2=np.zeros(3), imu_angular_velocity_radps=np.zeros(3),
        ego_status=np.zeros(10), history_xy_m=np.zeros((4, 2)), history_mask=np.ones(4, bool),
        command=2, target_point_m=np.array([12.0, 1.0]), pixels=pixels,
    )  # fmt: skip
    made, example = agent.model_inputs(observation), agent.example_inputs()
    assert made.keys() == example.keys()
    for key in made:
        assert (made[key].shape, made[key].dtype) == (example[key].shape, example[key].dtype), key
