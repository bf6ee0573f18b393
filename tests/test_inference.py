from __future__ import annotations

import numpy as np
import pytest
import torch

from drivee2e_data.agents import tcp
from drivee2e_data.agents.inference import GRAPHS_VARIABLE, NetworkRunner


def _inputs(batch: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    generator = np.random.default_rng(seed)
    images = generator.integers(0, 256, (batch, 3, 3, 36, 64), dtype=np.uint8)
    return images, generator.standard_normal((batch, 6)).astype(np.float32)


def _small_policy() -> tcp.TCPPolicy:
    torch.manual_seed(0)
    return tcp.TCPPolicy(3, 6, width=8, blocks=(1, 1)).eval()


def test_the_runner_gives_the_networks_plans_as_float64_on_the_cpu(monkeypatch) -> None:
    monkeypatch.setenv(GRAPHS_VARIABLE, "1")
    model = _small_policy()
    runner = NetworkRunner(model, "cpu")
    assert not runner.graphs  # graphs are a CUDA device's
    images, vector = _inputs(2, 0)
    plans = runner.plans(images, vector)
    with torch.no_grad():
        expected, _ = model(torch.from_numpy(images), torch.from_numpy(vector))
    assert plans.dtype == np.float64 and plans.shape == (2, 6, 2)
    assert np.array_equal(plans, expected.double().numpy())


def test_graphs_are_switched_off_by_the_variable(monkeypatch) -> None:
    monkeypatch.setenv(GRAPHS_VARIABLE, "0")
    assert not NetworkRunner(_small_policy(), "cuda").graphs
    monkeypatch.setenv(GRAPHS_VARIABLE, "1")
    assert NetworkRunner(_small_policy(), "cuda").graphs


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a GPU")
def test_a_replayed_forward_gives_the_eager_plans_bit_for_bit() -> None:
    model = _small_policy().to("cuda")
    eager = NetworkRunner(model, "cuda", graphs=False)
    graphed = NetworkRunner(model, "cuda", graphs=True)
    for batch, seed in ((4, 0), (4, 1), (2, 2), (4, 3)):  # two shapes, new contents each time
        images, vector = _inputs(batch, seed)
        assert np.array_equal(graphed.plans(images, vector), eager.plans(images, vector))
    assert len(graphed._recordings) == 2


@pytest.mark.skipif(torch.cuda.device_count() < 2, reason="needs a second GPU")
def test_runners_on_two_gpus_record_each_on_its_own_while_the_first_is_current() -> None:
    torch.cuda.set_device(0)  # as a process that never chose a device has
    images, vector = _inputs(4, 0)
    first = _small_policy().to("cuda:0")
    NetworkRunner(first, "cuda:0", graphs=True).plans(images, vector)  # cuda:0 captured first
    model = _small_policy().to("cuda:1")
    eager = NetworkRunner(model, "cuda:1", graphs=False)
    graphed = NetworkRunner(model, "cuda:1", graphs=True)
    for seed in range(3):
        images, vector = _inputs(4, seed)
        assert np.array_equal(graphed.plans(images, vector), eager.plans(images, vector))
    assert torch.cuda.current_device() == 0  # the runner left the process's choice as it was
