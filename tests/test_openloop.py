"""Open-loop metrics with known answers, their sync across processes, the baselines and the
predict/openloop/train commands."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from drivee2e_data.agents import admlp
from drivee2e_data.agents.training import TrainOptions
from drivee2e_data.cli import main
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.loaders import DriveE2EDataset, collate
from drivee2e_data.metrics.openloop import OpenLoopMetric, boxes_overlap, collisions, summarize

STEPS = 6


def _truth(batch: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    times = 0.5 * torch.arange(1, STEPS + 1, dtype=torch.float64)
    truth = torch.stack([torch.stack([8.0 * times, 0.3 * times**2], -1) for _ in range(batch)])
    return truth, torch.ones(batch, STEPS, dtype=torch.bool)


def _score(plan: torch.Tensor, truth: torch.Tensor, mask: torch.Tensor, convention: str) -> dict:
    metric = OpenLoopMetric(STEPS, convention)
    metric.update(plan, truth, mask)
    return metric.compute()


@pytest.mark.parametrize("convention", ["stp3", "uniad"])
def test_truth_as_plan_scores_zero(convention: str) -> None:
    truth, mask = _truth()
    result = _score(truth.clone(), truth, mask, convention)
    assert result["l2_1s"] == result["l2_2s"] == result["l2_3s"] == result["l2_avg"] == 0.0


@pytest.mark.parametrize("convention", ["stp3", "uniad"])
def test_constant_lateral_offset_scores_one_metre(convention: str) -> None:
    truth, mask = _truth()
    plan = truth + torch.tensor([0.0, 1.0], dtype=torch.float64)
    result = _score(plan, truth, mask, convention)
    for key in ("l2_1s", "l2_2s", "l2_3s", "l2_avg", "l2_avg_1_2s"):
        assert result[key] == pytest.approx(1.0)


def test_linearly_growing_error_gives_each_convention_its_value() -> None:
    truth, mask = _truth()
    error = 0.5 * torch.arange(1, STEPS + 1, dtype=torch.float64)  # 0.5 m at 0.5 s ... 3 m at 3 s
    plan = truth + torch.stack([error, torch.zeros(STEPS, dtype=torch.float64)], -1)
    uniad = _score(plan, truth, mask, "uniad")
    assert (uniad["l2_1s"], uniad["l2_2s"], uniad["l2_3s"]) == pytest.approx((1.0, 2.0, 3.0))
    assert uniad["l2_avg"] == pytest.approx(2.0) and uniad["l2_avg_1_2s"] == pytest.approx(1.5)
    stp3 = _score(plan, truth, mask, "stp3")  # means of 0.5..h
    assert (stp3["l2_1s"], stp3["l2_2s"], stp3["l2_3s"]) == pytest.approx((0.75, 1.25, 1.75))


def test_masked_steps_are_left_out_not_padded() -> None:
    truth, mask = _truth(2)
    plan = truth.clone()
    plan[1] += torch.tensor([0.0, 4.0], dtype=torch.float64)
    mask[1, 2:] = False  # the second sample's clip ends after 1 s
    result = _score(plan, truth, mask, "uniad")
    assert result["l2_1s"] == pytest.approx(2.0)  # (0 + 4) / 2
    assert result["l2_2s"] == pytest.approx(0.0)  # only the first sample has 2 s
    nothing = summarize(torch.zeros(STEPS), torch.zeros(STEPS), "stp3", "l2")
    assert math.isnan(nothing["l2_1s"])


def test_box_overlap_known_cases() -> None:
    car = torch.tensor([0.0, 0.0, 4.0, 2.0, 0.0], dtype=torch.float64)
    cases = {
        (3.9, 0.0, 0.0): True,  # bumpers overlap by 0.1 m
        (4.1, 0.0, 0.0): False,
        (0.0, 2.05, 0.0): False,  # side by side with a 5 cm gap
        (2.9, 2.9, math.pi / 4): True,  # a rotated corner reaching in
        (3.2, 3.2, math.pi / 4): False,
    }
    for (x, y, yaw), expected in cases.items():
        other = torch.tensor([x, y, 4.0, 2.0, yaw], dtype=torch.float64)
        assert bool(boxes_overlap(car, other)) is expected, (x, y, yaw)


def test_plan_through_a_logged_car_counts_a_collision(loader_root: Path) -> None:
    dataset = DriveE2EDataset(loader_root, "test", cameras=())
    batch = collate([dataset[k] for k in range(0, 20)])
    valid = batch["gt_agent_fut_masks"] & batch["gt_boxes_mask"][..., None]
    sample, agent = [int(v) for v in torch.nonzero(valid.all(-1))[0]]
    rows = slice(sample, sample + 1)
    offset = batch["ego_rear_axle_to_centre"][rows]
    agent_boxes = batch["gt_agent_fut_boxes"][rows].double()
    # a plan whose ego box centre sits on that agent's centre at every step
    heading = agent_boxes[0, agent, :, 4]
    through = agent_boxes[:, agent, :, :2] - offset.double()[:, None, None] * torch.stack(
        [torch.cos(heading), torch.sin(heading)], -1
    )
    hits = collisions(through, batch["ego_size"][rows], offset, agent_boxes, valid[rows])
    assert hits.all()
    logged = collisions(
        batch["gt_ego_fut_trajs"][rows].double(),
        batch["ego_size"][rows],
        offset,
        agent_boxes,
        valid[rows],
    )
    assert not logged[batch["gt_ego_fut_masks"][rows]].any()  # the expert itself hits nobody
    metric = OpenLoopMetric(STEPS)
    metric.update(
        through,
        batch["gt_ego_fut_trajs"][rows],
        torch.ones(1, STEPS, dtype=torch.bool),
        batch["ego_size"][rows],
        offset,
        agent_boxes,
        valid[rows],
    )
    assert metric.compute()["collision_1s"] == 1.0


def _sync_worker(
    rank: int, init_file: str, plan: torch.Tensor, truth: torch.Tensor, out: str
) -> None:
    dist.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=2)
    metric = OpenLoopMetric(STEPS, "uniad")
    half = slice(rank * 2, rank * 2 + 2)
    metric.update(plan[half], truth[half], torch.ones(2, STEPS, dtype=torch.bool))
    result = metric.compute()
    if rank == 0:
        torch.save(result, out)
    dist.barrier()
    dist.destroy_process_group()


@pytest.mark.slow
def test_metric_on_two_processes_equals_one(tmp_path: Path) -> None:
    truth, mask = _truth(4)
    generator = torch.Generator().manual_seed(3)
    plan = truth + torch.randn(truth.shape, generator=generator, dtype=torch.float64)
    alone = _score(plan, truth, mask, "uniad")
    out = tmp_path / "synced.pt"
    mp.spawn(
        _sync_worker, args=(str(tmp_path / "init"), plan, truth, str(out)), nprocs=2, join=True
    )
    synced = torch.load(out)
    for key, value in alone.items():
        assert synced[key] == pytest.approx(value, rel=1e-12), key


def test_cli_predict_and_score(loader_root: Path, tmp_path: Path, capsys) -> None:
    predictions = tmp_path / "cv.parquet"
    assert (
        main(
            [
                "predict",
                str(loader_root),
                "--split",
                "test",
                "--model",
                "constant-velocity",
                "--out",
                str(predictions),
            ]
        )
        == 0
    )
    out = tmp_path / "cv.json"
    code = main(
        [
            "openloop",
            str(loader_root),
            "--split",
            "test",
            "--predictions",
            str(predictions),
            "--json",
            str(out),
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "36 of 36 samples planned" in printed and "STR" in printed
    # the straight clip at near-constant speed: constant velocity is within a metre at 3 s
    results = json.loads(out.read_text())["results"]
    assert results["all"]["samples"] == 36
    assert 0.0 < results["all"]["l2_3s"] < 1.0
    # both conventions in one command: one file each, the same numbers as one at a time
    both = ["openloop", str(loader_root), "--split", "test", "--predictions", str(predictions),
            "--convention", "stp3", "uniad"]  # fmt: skip
    assert main([*both, "--json", str(tmp_path / "cv_{convention}.json")]) == 0
    assert json.loads((tmp_path / "cv_stp3.json").read_text())["results"] == results
    uniad = json.loads((tmp_path / "cv_uniad.json").read_text())
    assert uniad["convention"] == "uniad" and uniad["results"]["all"]["samples"] == 36
    assert uniad["results"]["all"]["l2_1s"] > results["all"]["l2_1s"]  # the step, not the mean
    capsys.readouterr()
    assert main([*both, "--json", str(tmp_path / "one.json")]) != 0  # two tables, one name
    assert "put {convention} in the path" in capsys.readouterr().err
    assert not (tmp_path / "one.json").exists()


def test_openloop_plans_and_scores_in_one_process_as_predict_then_openloop(
    loader_root: Path, tmp_path: Path, capsys
) -> None:
    """`openloop --model` (plans made in the same process) writes the same tables, and with
    `--write-predictions` the same predictions file, as `predict` and then `openloop`."""
    split = ["--split", "test"]
    two_step = tmp_path / "two_step.parquet"
    assert main(["predict", str(loader_root), *split, "--model", "constant-velocity",
                 "--out", str(two_step)]) == 0  # fmt: skip
    assert main(["openloop", str(loader_root), *split, "--predictions", str(two_step),
                 "--convention", "stp3", "uniad", "--json", str(tmp_path / "a_{convention}.json")]) == 0  # fmt: skip
    one_step = tmp_path / "one_step.parquet"
    assert main(["openloop", str(loader_root), *split, "--model", "constant-velocity",
                 "--write-predictions", str(one_step), "--convention", "stp3", "uniad",
                 "--json", str(tmp_path / "b_{convention}.json")]) == 0  # fmt: skip
    for convention in ("stp3", "uniad"):
        assert (tmp_path / f"a_{convention}.json").read_bytes() == (
            tmp_path / f"b_{convention}.json"
        ).read_bytes()
    assert pq.read_table(one_step).equals(pq.read_table(two_step))
    capsys.readouterr()
    # a checkpoint or a file to write without --model, and neither source: one error each
    assert main(["openloop", str(loader_root), *split, "--predictions", str(two_step),
                 "--write-predictions", str(tmp_path / "x.parquet")]) == 2  # fmt: skip
    assert "--write-predictions goes with --model" in capsys.readouterr().err
    assert main(["openloop", str(loader_root), *split, "--model", "admlp"]) == 2
    assert "--model admlp needs --checkpoint" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["openloop", str(loader_root), *split])
    assert "one of the arguments --predictions --model is required" in capsys.readouterr().err


def _write(path: Path, rows: dict) -> Path:
    pq.write_table(pa.table(rows), path)
    return path


def test_bad_predictions_name_file_and_row(loader_root: Path, tmp_path: Path, capsys) -> None:
    dataset = DriveE2EDataset(loader_root, "test", cameras=())
    scenario_id, frame = dataset.samples[0]
    good = [0.5 * k for k in range(1, 7)]
    cases = {
        "unknown.parquet": (
            {
                "scenario_id": [scenario_id, scenario_id],
                "frame": [frame, 999],
                "plan_x_m": [good, good],
                "plan_y_m": [good, good],
            },
            "row 1: .* frame 999\\) is no sample of split 'test'",
        ),
        "shape.parquet": (
            {
                "scenario_id": [scenario_id],
                "frame": [frame],
                "plan_x_m": [good[:4]],
                "plan_y_m": [good],
            },
            "row 0: plan_x_m and plan_y_m have 4 and 6 values, expected 6 each",
        ),
        "column.parquet": (
            {"scenario_id": [scenario_id], "frame": [frame]},
            "column 'plan_x_m' is missing",
        ),
    }
    for name, (rows, message) in cases.items():
        path = _write(tmp_path / name, rows)
        assert (
            main(["openloop", str(loader_root), "--split", "test", "--predictions", str(path)]) == 2
        )
        error = capsys.readouterr().err
        assert str(path) in error
        assert re.search(message, error), error


def test_admlp_trains_deterministically_and_resumes(loader_root: Path, tmp_path: Path) -> None:
    dataset = DriveE2EDataset(loader_root, "train", cameras=())
    options = TrainOptions(epochs=30, batch_size=8, seed=1)
    first = admlp.train(dataset, tmp_path / "a.pt", options)
    again = admlp.train(dataset, tmp_path / "b.pt", options)
    assert first["losses"] == again["losses"]
    assert first["losses"][-1] < 0.5 * first["losses"][0]
    for key, value in first["model"].items():
        assert torch.equal(value, again["model"][key])
    # a run cut short after 10 epochs resumes to the same weights as one uninterrupted run
    admlp.train(dataset, tmp_path / "c.pt", TrainOptions(epochs=10, batch_size=8, seed=1))
    resumed = admlp.train(dataset, tmp_path / "c.pt", options)
    assert resumed["losses"] == pytest.approx(first["losses"])
    for key, value in first["model"].items():
        assert torch.allclose(value, resumed["model"][key])
    with pytest.raises(DriveE2EError, match="made with other options"):
        admlp.train(dataset, tmp_path / "a.pt", TrainOptions(epochs=30, batch_size=4, seed=1))


def test_cli_trains_admlp_and_scores_it(loader_root: Path, tmp_path: Path) -> None:
    checkpoint = tmp_path / "admlp.pt"
    assert (
        main(["train", "admlp", str(loader_root), "--out", str(checkpoint), "--epochs", "5"]) == 0
    )
    predictions = tmp_path / "admlp.parquet"
    args = [
        "predict",
        str(loader_root),
        "--split",
        "val",
        "--model",
        "admlp",
        "--checkpoint",
        str(checkpoint),
        "--out",
        str(predictions),
    ]
    assert main(args) == 0
    assert pq.read_table(predictions).num_rows == 8
    assert main(["predict", str(loader_root), "--model", "admlp", "--out", str(predictions)]) == 2
    assert os.path.exists(predictions)


def test_errors_computed_once_score_every_convention_and_subset_as_metrics_do() -> None:
    """`drivee2e openloop` computes each sample's errors and collisions once and sums subsets
    of rows (the categories) for every convention: the same numbers as a Metric per convention
    fed each subset as a batch of its own."""
    from drivee2e_data.metrics.openloop import ErrorSums, sample_errors

    generator = torch.Generator().manual_seed(3)
    truth, mask = _truth(8)
    mask[5, 4:] = False  # a clip's end
    plan = truth + torch.randn(8, STEPS, 2, generator=generator, dtype=torch.float64)
    size = torch.tensor([[4.5, 1.9, 1.5]] * 8, dtype=torch.float64)
    offset = torch.full((8,), 1.3, dtype=torch.float64)
    boxes = torch.zeros(8, 2, STEPS, 5, dtype=torch.float64)
    boxes[..., 0], boxes[..., 2:4] = truth[:, None, :, 0] + 3.0, torch.tensor([4.0, 2.0])
    agent_masks = torch.ones(8, 2, STEPS, dtype=torch.bool)
    inputs = (plan, truth, mask, size, offset, boxes, agent_masks)
    errors, valid, hits = sample_errors(*inputs)
    assert hits is not None and hits.any() and not hits.all()  # collisions are scored
    rows = [0, 2, 5, 7]
    sums = ErrorSums.zeros(STEPS)
    sums.add(errors[rows], valid[rows], hits[rows])
    for convention in ("stp3", "uniad"):
        metric = OpenLoopMetric(STEPS, convention)
        metric.update(*(value[rows] for value in inputs))
        assert sums.summary(convention) == metric.compute()
