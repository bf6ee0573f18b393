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
