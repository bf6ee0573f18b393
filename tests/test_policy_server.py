"""The policy server's batches: each run at one fixed size, so that a plan depends on its own
inputs alone, not on which other workers' requests were gathered with it."""

from __future__ import annotations

import numpy as np
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


def test_a_slot_carries_a_requests_arrays_and_grows_with_them(tmp_path) -> None:
    import gc
    import os

    from drivee2e_data.evaluate.policy_server import InputSlot, SlotReader

    slot, reader = InputSlot(str(tmp_path), 3), SlotReader()
    rng = np.random.default_rng(1)
    small = {"images": rng.integers(0, 256, (3, 3, 9, 16), dtype=np.uint8),
             "vector": rng.standard_normal(6).astype(np.float32)}  # fmt: skip
    layout = slot.write(small)
    assert layout[0] == str(tmp_path / "worker-3")
    assert [entry[0] for entry in layout[1]] == ["images", "vector"]
    read = reader.read(layout)
    assert all(np.array_equal(read[k], small[k]) and read[k].dtype == small[k].dtype for k in small)
    # the next request's arrays, larger: the file grows and the server maps it again
    large = {"images": rng.integers(0, 256, (3, 3, 36, 64), dtype=np.uint8),
             "vector": rng.standard_normal(6).astype(np.float32)}  # fmt: skip
    read = reader.read(slot.write(large))
    assert all(np.array_equal(read[k], large[k]) for k in large)
    del slot, read
    gc.collect()
    assert not os.path.exists(tmp_path / "worker-3")  # a worker's slot goes with it


def test_a_runs_slot_folder_is_in_memory_and_removed_at_its_end() -> None:
    import os

    from drivee2e_data.evaluate.policy_server import InputSlot, remove_slots, slot_folder

    folder = slot_folder()
    try:
        if os.access("/dev/shm", os.W_OK):
            assert folder.startswith(f"/dev/shm/drivee2e-policy-{os.getpid()}-")
        InputSlot(folder, 0).write({"x": np.zeros(4, np.float32)})
    finally:
        remove_slots(folder)
    assert not os.path.exists(folder)


def test_the_slots_of_a_command_killed_outright_go_with_the_next_run() -> None:
    import os
    import subprocess
    import sys
    from pathlib import Path

    from drivee2e_data.evaluate.policy_server import remove_slots, slot_folder

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    probe = slot_folder()
    root = Path(probe).parent
    remove_slots(probe)
    orphan = root / f"drivee2e-policy-{gone.stdout.strip()}-left"
    living = root / f"drivee2e-policy-{os.getppid()}-kept"  # this process's parent runs
    for folder in (orphan, living):
        folder.mkdir()
        (folder / "worker-0").write_bytes(b"x")
    try:
        remove_slots(slot_folder())
        assert not orphan.exists() and living.exists()
    finally:
        remove_slots(str(orphan))
        remove_slots(str(living))


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
        remove_slots,
        serve,
        slot_folder,
    )
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
        plans = [agents[k % 2].act(row["x"]).xy_m for k, row in enumerate(inputs)]
    finally:
        handle.requests.put(None)
        server.join(timeout=60)
        remove_slots(folder)
    expected = batch_plans(_Toy(), inputs, 2)  # each alone in a batch of the server's size
    assert all(np.array_equal(plan, want) for plan, want in zip(plans, expected, strict=True))
