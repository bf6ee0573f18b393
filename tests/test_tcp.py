"""The TCP-class camera baseline: its ResNet trunk has ResNet-18's shape and starts each block
as the identity, the policy learns a known plan, trains through the CLI (resuming), plans open
loop and drives a clip in closed loop on the CPU."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from drivee2e_data.agents import device, tcp
from drivee2e_data.agents.resnet import BasicBlock, ResNet
from drivee2e_data.agents.training import TrainOptions, fit
from drivee2e_data.cli import main


def test_the_trunk_has_resnet18s_parameters_and_blocks_start_as_the_identity():
    # ResNet-18 holds 11,689,512 parameters, 513,000 of them in its 1000-class layer
    assert sum(p.numel() for p in ResNet().parameters()) == 11_689_512 - 513_000
    assert ResNet().features == 512 and ResNet(width=16).features == 128
    block = ResNet(width=8).body[4].eval()  # the first block: same size, same channels
    assert isinstance(block, BasicBlock)
    x = torch.rand(2, 8, 6, 6)  # non-negative: relu(x + 0) is x
    assert torch.equal(block(x), x)
    strided = BasicBlock(8, 16, 2)
    assert strided(x).shape == (2, 16, 3, 3)


@pytest.mark.slow
def test_the_policy_learns_plans_that_follow_the_command(tmp_path: Path, monkeypatch):
    """Eight samples whose future goes left (command left) or right (command right): a small
    trunk fits them to decimetres, and its speed head learns the speed."""
    torch.manual_seed(0)
    count = 8
    images = torch.randint(0, 255, (count, 3, 3, 32, 48), dtype=torch.uint8)
    left = torch.arange(count) % 2 == 0
    command = torch.zeros(count, 3)
    command[left, 1] = 1.0  # left
    command[~left, 0] = 1.0  # right
    steps = torch.arange(1, 7, dtype=torch.float32)
    y = torch.stack([steps * 2.0, torch.zeros(6)], 1).repeat(count, 1, 1)
    y[left, :, 1], y[~left, :, 1] = 0.3 * steps, -0.3 * steps
    speed = torch.full((count,), 4.0)
    vector = torch.cat([command, speed[:, None] / 10.0, y[:, -1] / 20.0], 1)
    data = {"images": images, "vector": vector, "speed": speed, "y": y,
            "mask": torch.ones(count, 6, dtype=torch.bool)}  # fmt: skip
    model = tcp.TCPPolicy(3, 6, width=8, blocks=(1, 1))
    options = TrainOptions(epochs=150, batch_size=8, learning_rate=3e-3)
    monkeypatch.setattr(tcp, "SPEED_LOSS_WEIGHT", 1.0)
    saved = fit(model, data, tcp._predict, tmp_path / "tcp.pt", options, {"kind": "tcp"})
    assert saved["losses"][-1] < 0.1 * saved["losses"][0]
    model.eval()
    with torch.no_grad():
        plan, seen_speed = model(images, vector)
    # a plan blind to the command would be 1.8 m off at 3 s on every sample
    assert (plan - y).abs().max() < 0.5
    assert torch.equal(plan[:, -1, 1] > 0, left)
    assert (seen_speed - 4.0).abs().max() < 0.5


def test_the_augmentation_draws_from_the_counter_it_was_loaded_with():
    """The brightness gains follow the step counter saved with the weights, also after a
    `load_state_dict` into a model that had already drawn (its host copy is read again)."""
    from drivee2e_data.agents.camera import brightness_gains

    def gains_of(step: int) -> torch.Tensor:
        return torch.empty(6).uniform_(0.7, 1.3, generator=torch.Generator().manual_seed(step))

    trained, fresh = tcp.TCPPolicy(3, 6, 8, (1, 1)), tcp.TCPPolicy(3, 6, 8, (1, 1))
    cpu = torch.device("cpu")
    for step in range(3):
        assert torch.equal(brightness_gains(trained, 6, cpu), gains_of(step))
    assert int(trained.augment_step) == 3
    assert torch.equal(brightness_gains(fresh, 6, cpu), gains_of(0))
    fresh.load_state_dict(trained.state_dict())
    assert torch.equal(brightness_gains(fresh, 6, cpu), gains_of(3))
    assert int(fresh.augment_step) == 4
    # what the forward pass draws: the images times those gains
    images = torch.full((2, 3, 3, 8, 8), 128, dtype=torch.uint8)
    pixels = fresh.train().normalise(images) * tcp.PIXEL_STD + tcp.PIXEL_MEAN
    assert torch.allclose(pixels[:, 0, 0, 0], (128 / 255 * gains_of(4)).clamp(0, 1), atol=1e-6)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a GPU")
def test_a_training_replaying_cuda_graphs_is_the_eager_training(tmp_path: Path) -> None:
    """On a GPU: TCP trained with its step recorded as CUDA graphs (bfloat16 autocast, last
    batch shorter, so eager) against the same training launching every kernel: the same losses
    and weights to the GPU's arithmetic, the batch norms' statistics untouched by the capture."""
    torch.manual_seed(0)
    count = 40  # batches of 16, 16 and 8
    images = torch.randint(0, 255, (count, 3, 3, 36, 64), dtype=torch.uint8)
    vector, speed = torch.rand(count, 6), torch.rand(count) * 10
    y = torch.cumsum(torch.rand(count, 6, 2), 1)
    data = {"images": images, "vector": vector, "speed": speed, "y": y,
            "mask": torch.ones(count, 6, dtype=torch.bool)}  # fmt: skip
    options = TrainOptions(epochs=3, batch_size=16, learning_rate=1e-3)
    results = []
    for capture in (None, tcp._capture):
        torch.manual_seed(0)
        model = tcp.TCPPolicy(3, 6, width=16, blocks=(1, 1, 1))
        model.trunk.to(memory_format=torch.channels_last)
        saved = fit(model, data, tcp._predict, tmp_path / f"{capture is None}.pt", options,
                    {"kind": "tcp"}, device="cuda", mixed_precision=True, capture=capture)  # fmt: skip
        assert bool(model._graphs) == (capture is not None)
        results.append(saved)
    eager, graphed = results
    assert graphed["losses"] == pytest.approx(eager["losses"], rel=1e-3)
    for key, value in eager["model"].items():
        assert torch.allclose(graphed["model"][key].float(), value.float(), atol=1e-3), key


@pytest.mark.slow
def test_tcp_trains_resumes_plans_and_drives_a_clip(
    loader_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    checkpoint = tmp_path / "tcp.pt"
    # a quarter of ResNet-18's width: the same path at a sixteenth of the trunk's arithmetic
    train = ["train", "tcp", str(loader_root), "--out", str(checkpoint), "--epochs", "2",
             "--batch-size", "8", "--device", "cpu", "--width", "16"]  # fmt: skip
    assert main(train) == 0
    saved = torch.load(checkpoint, map_location="cpu", weights_only=True)
    assert saved["kind"] == "tcp" and saved["epoch"] == 2 and saved["samples"] == 14
    assert saved["options"]["learning_rate"] == 3e-4 and saved["width"] == 16
    assert main([*train[:6], "3", *train[7:-1], "8"]) == 2  # another width: not resumed
    assert "other shapes" in capsys.readouterr().err
    assert main([*train[:6], "3", *train[7:]]) == 0  # resumes: one more epoch
    resumed = torch.load(checkpoint, map_location="cpu", weights_only=True)
    assert resumed["epoch"] == 3 and resumed["losses"][:2] == saved["losses"]
    plans = tmp_path / "plans.parquet"
    predict = ["predict", str(loader_root), "--model", "tcp", "--checkpoint", str(checkpoint),
               "--out", str(plans)]  # fmt: skip
    assert main(predict) == 0 and plans.stat().st_size > 0
    out = tmp_path / "run"
    assert main(["evaluate", str(loader_root), "--split", "val", "--agent", "tcp",
                 "--checkpoint", str(checkpoint), "--out", str(out)]) == 0  # fmt: skip
    (episode,) = [json.loads(p.read_text()) for p in (out / "episodes").glob("*.json")]
    assert episode["failure"] == "" and episode["steps"] > 10


def test_a_device_that_is_not_there_is_one_clear_error(loader_root: Path, tmp_path: Path, capsys):
    out = tmp_path / "tcp.pt"
    for wanted, message in (("tpu", "expected auto, cpu, cuda or cuda:N"),
                            ("cuda", "torch sees no CUDA device here")):  # fmt: skip
        if wanted == "cuda" and torch.cuda.is_available():
            continue
        code = main(["train", "tcp", str(loader_root), "--out", str(out), "--device", wanted])
        assert code != 0 and message in capsys.readouterr().err
        assert not out.exists()
        plans = tmp_path / "plans.parquet"  # the open-loop planner takes the same choice
        code = main(["predict", str(loader_root), "--model", "tcp", "--checkpoint", str(out),
                     "--out", str(plans), "--device", wanted])  # fmt: skip
        assert code != 0 and message in capsys.readouterr().err
        assert not plans.exists()


def test_the_closed_loop_device_comes_from_the_environment(monkeypatch):
    from drivee2e_data.errors import DriveE2EError

    monkeypatch.setenv(device.AGENT_DEVICE_VARIABLE, "cpu")
    assert device.agent_device() == "cpu"
    monkeypatch.setenv(device.AGENT_DEVICE_VARIABLE, "auto")
    assert device.agent_device() == ("cuda" if torch.cuda.is_available() else "cpu")
    monkeypatch.setenv(device.AGENT_DEVICE_VARIABLE, "tpu")
    with pytest.raises(DriveE2EError, match="expected auto, cpu or cuda"):
        device.agent_device()
