"""`drivee2e evaluate` end to end: result files, resuming after SIGKILL, determinism, agents
in a child process (same scores as in-process; crashes, hangs and garbage reported per
episode), recordings, occlusion variants from collected logs, the camera policy with cameras."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

from drivee2e_data import splits, store
from drivee2e_data.cli import main
from drivee2e_data.evaluate.runner import EPISODES_FOLDER
from drivee2e_data.sim.egl_context import Priority, requested_priority
from drivee2e_data.sim.gl_context import context_made
from tests.conftest import copy_clips

SCORE_COLUMNS = ("status", "success", "route_completion", "penalty", "driving_score", "events")
CLIENT = f"{sys.executable} -m drivee2e_data.evaluate.agent_client"


@pytest.fixture(scope="module")
def three_clips(synthetic_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    ids = store.scenario_ids(synthetic_root)[:3]
    root = copy_clips(synthetic_root, tmp_path_factory.mktemp("evaluate") / "data", ids)
    assert main(["split", str(root)]) == 0
    return root


def episodes(out: Path) -> dict[str, dict]:
    return {
        p.stem: json.loads(p.read_text()) for p in sorted((out / EPISODES_FOLDER).glob("*.json"))
    }


def scores(out: Path) -> dict[str, tuple]:
    return {k: tuple(row[c] for c in SCORE_COLUMNS) for k, row in episodes(out).items()}


def test_evaluate_writes_episodes_summary_and_table(three_clips: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["evaluate", str(three_clips), "--split", "all", "--out", str(out)]
    assert main([*args, "--agent", "expert", "--record"]) == 0
    table = pq.read_table(out / "episodes.parquet").to_pylist()
    assert len(table) == 3 and all(row["success"] for row in table)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["success_rate"] == 100.0 and summary["driving_score"] == 100.0
    assert "| 3 | 100.0 | 100.00 | 100.0 |" in (out / "table.md").read_text()
    record = out / "records" / f"{table[0]['scenario_id']}.mcap"
    with open(record, "rb") as stream:
        topics = {channel.topic for channel in make_reader(stream).get_summary().channels.values()}
    assert topics == {"/map", "/tf", "/closedloop/scene"}
    # another agent into the same folder is refused, naming it; so are a missing or bad
    # checkpoint and an unknown agent, before any episode
    assert main([*args, "--agent", "constant-velocity"]) == 2
    assert main([*args, "--agent", "admlp"]) == 2
    assert main([*args, "--agent", "camera", "--checkpoint", str(record)]) == 2
    assert main([*args, "--agent", "no_such_module:Agent"]) == 2


@pytest.mark.slow
def test_record_mp4_is_the_front_camera_beside_the_top_view_at_every_step(
    three_clips: Path, tmp_path: Path
) -> None:
    import cv2

    from drivee2e_data.evaluate import video

    scenario_id = store.scenario_ids(three_clips)[0]
    out = tmp_path / "run"
    assert main(["evaluate", str(three_clips), "--split", "all", "--only", scenario_id,
                 "--agent", "constant-velocity", "--record", "mp4", "--out", str(out)]) == 0  # fmt: skip
    (row,) = episodes(out).values()
    capture = cv2.VideoCapture(str(out / "records" / f"{scenario_id}.mp4"))
    frames = []
    ok, image = capture.read()
    while ok:
        frames.append(image)
        ok, image = capture.read()
    assert len(frames) == row["steps"]
    assert frames[0].shape == (video.FRONT_SIZE[1], video.FRONT_SIZE[0] + video.TOP_PX, 3)
    # the ego's box outline (green) around the top view's centre, in the first frame
    top = frames[0][:, video.FRONT_SIZE[0] :].astype(int)
    green = (top[..., 1] > 150) & (top[..., 0] < 140) & (top[..., 2] < 140)
    rows, columns = np.nonzero(green)
    centre = video.TOP_PX / 2
    assert abs(np.median(rows) - centre) < 25 and abs(np.median(columns) - centre) < 25
    assert not (out / "records" / f".{scenario_id}.mp4.partial.mp4").exists()


def test_top_view_pixels_put_the_heading_up_and_the_left_to_the_left() -> None:
    from drivee2e_data.evaluate import video

    scale = video.TOP_PX / (2 * video.TOP_HALF_WIDTH_M)
    centre = video.TOP_PX / 2
    # the ego at (5, 5) heading north (+y): 10 m north is up, 10 m west is left
    pixels = video.top_view_pixels(np.array([[5.0, 15.0], [-5.0, 5.0]]), 5.0, 5.0, np.pi / 2)
    assert pixels.tolist() == [[centre, round(centre - 10 * scale)],
                               [round(centre - 10 * scale), centre]]  # fmt: skip


def test_same_agent_same_seed_same_scores(three_clips: Path, tmp_path: Path) -> None:
    for name in ("a", "b"):
        args = ["evaluate", str(three_clips), "--split", "all", "--out", str(tmp_path / name)]
        assert main([*args, "--agent", "constant-velocity", "--reactive"]) == 0
    assert scores(tmp_path / "a") == scores(tmp_path / "b")
    assert any(not row[1] for row in scores(tmp_path / "a").values())  # it fails somewhere


@pytest.mark.slow
def test_workers_give_the_same_scores(three_clips: Path, tmp_path: Path) -> None:
    base = ["evaluate", str(three_clips), "--split", "all", "--agent", "constant-velocity"]
    assert main([*base, "--out", str(tmp_path / "one")]) == 0
    assert main([*base, "--out", str(tmp_path / "two"), "--workers", "2"]) == 0
    assert scores(tmp_path / "one") == scores(tmp_path / "two")


SLOW_AGENT = """
import time
from drivee2e_data.agents.expert import LogReplayExpert

class SlowExpert(LogReplayExpert):
    def act(self, observation):
        time.sleep(0.01)
        return super().act(observation)
"""


@pytest.mark.slow
def test_sigkill_then_rerun_scores_every_episode_once(three_clips: Path, tmp_path: Path) -> None:
    (tmp_path / "slow_agent.py").write_text(SLOW_AGENT)
    out = tmp_path / "run"
    command = [sys.executable, "-m", "drivee2e_data.cli", "evaluate", str(three_clips),
               "--split", "all", "--agent", "slow_agent:SlowExpert", "--out", str(out)]  # fmt: skip
    process = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not list((out / EPISODES_FOLDER).glob("*.json")) and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)
    process.wait()
    finished = {
        p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (out / EPISODES_FOLDER).glob("*.json")
    }
    assert 1 <= len(finished) < 3
    assert not list((out / EPISODES_FOLDER).glob("*.partial"))
    rerun = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    for path, (content, mtime) in finished.items():
        assert path.read_bytes() == content and path.stat().st_mtime_ns == mtime
    rows = pq.read_table(out / "episodes.parquet").to_pylist()
    assert sorted(r["scenario_id"] for r in rows) == sorted(store.scenario_ids(three_clips))
    assert all(r["success"] for r in rows)


@pytest.mark.slow
def test_an_agent_in_a_child_process_scores_what_it_scores_in_process(
    three_clips: Path, tmp_path: Path
) -> None:
    base = ["evaluate", str(three_clips), "--split", "all"]
    assert main([*base, "--agent", "constant-velocity", "--out", str(tmp_path / "in")]) == 0
    remote = f"{CLIENT} drivee2e_data.agents.constant_velocity:ConstantVelocityAgent"
    assert main([*base, "--agent-cmd", remote, "--out", str(tmp_path / "child")]) == 0
    assert scores(tmp_path / "in") == scores(tmp_path / "child")
    remote = f"{CLIENT} drivee2e_data.agents.expert:LogReplayExpert"
    assert main([*base, "--agent-cmd", remote, "--out", str(tmp_path / "expert")]) == 0
    assert all(row[1] for row in scores(tmp_path / "expert").values())


BAD_AGENTS = {
    "crash": "raise RuntimeError('the model fell over')",
    "hang": "time.sleep(60)",
    "garbage": "os.write(real_stdout, b'this is not a message' * 4)",
}
BAD_AGENT = """
import os, sys, time
from drivee2e_data.evaluate import agent_client

real_stdout = None

class Bad:
    name, sensors, image_size = "bad", (), None

    def setup(self, route, rig):
        self.steps = 0

    def act(self, observation):
        self.steps += 1
        if self.steps == 3:
            {action}
        return agent_client.Waypoints([[1.0, 0.0]] * 6)

if __name__ == "__main__":
    real_stdout = os.dup(1)
    agent_client.serve(Bad())
"""


@pytest.mark.slow
@pytest.mark.parametrize("kind", sorted(BAD_AGENTS))
def test_a_failing_child_ends_its_episode_not_the_run(
    three_clips: Path, tmp_path: Path, kind: str
) -> None:
    script = tmp_path / f"{kind}.py"
    script.write_text(textwrap.dedent(BAD_AGENT).replace("{action}", BAD_AGENTS[kind]))
    out = tmp_path / "run"
    args = ["evaluate", str(three_clips), "--split", "all", "--out", str(out),
            "--agent-cmd", f"{sys.executable} {script}", "--step-timeout", "2"]  # fmt: skip
    assert main(args) == 0
    rows = episodes(out)
    assert len(rows) == 3
    for row in rows.values():
        assert row["status"] == "agent_failed" and row["agent_failed"] == 1
        assert row["steps"] == 2 and row["driving_score"] < 10
    failure = next(iter(rows.values()))["failure"]
    expected = {"crash": "the model fell over", "hang": "no answer to step 2 within 2 s",
                "garbage": "garbled message"}[kind]  # fmt: skip
    assert expected in failure


def test_occlusion_variant_from_collected_logs(collected_root: Path, tmp_path: Path) -> None:
    root = tmp_path / "data"
    copy_clips(collected_root, root, store.scenario_ids(collected_root))
    (root / "logs").symlink_to(collected_root / "logs")
    assert main(["split", str(root)]) == 0
    assert main(["evaluate", str(root), "--split", "all", "--variant", "occ-all"]) == 2  # none yet
    assert main(["curate", str(root), "--occlusion", "all"]) == 0
    assert main(["curate", str(root), "--occlusion", "vehicle"]) == 0
    removed = {
        v: json.loads((root / "variants" / f"{v}.json").read_text())["removed"]
        for v in ("occ-all", "occ-vehicle")
    }
    for scenario_id, ids in removed["occ-vehicle"].items():
        assert set(ids) <= set(removed["occ-all"][scenario_id])
    assert sum(len(v) for v in removed["occ-all"].values()) > 0
    assert main(["evaluate", str(root), "--split", "all", "--variant", "occ-all"]) == 0
    rows = pq.read_table(root / "results" / "expert-all-occ-all" / "episodes.parquet").to_pylist()
    assert [r["removed_agents"] for r in rows] == [
        len(removed["occ-all"][r["scenario_id"]]) for r in rows
    ]


@pytest.mark.slow
def test_camera_policy_trains_and_drives_with_its_cameras(
    loader_root: Path, tmp_path: Path
) -> None:
    checkpoint = tmp_path / "camera.pt"
    args = ["train", "camera", str(loader_root), "--out", str(checkpoint), "--epochs", "2"]
    assert main(args) == 0
    out = tmp_path / "run"
    assert main(["evaluate", str(loader_root), "--split", "val", "--agent", "camera",
                 "--checkpoint", str(checkpoint), "--out", str(out)]) == 0  # fmt: skip
    (row,) = episodes(out).values()
    assert row["failure"] == "" and row["steps"] > 10
    assert os.path.getsize(out / "table.md") > 0


@pytest.mark.slow
def test_a_served_network_drives_the_same_episodes_as_one_in_each_worker(
    loader_root: Path, tmp_path: Path
) -> None:
    """The camera policy's network on one policy server for two workers (batched) and in the
    evaluating process itself (unbatched, one episode after the other), on the CPU: the same
    episodes (scores, steps, events); the network's outputs differ at most in the arithmetic's
    last bits (1e-7 m), far below any threshold."""
    checkpoint = tmp_path / "camera.pt"
    args = ["train", "camera", str(loader_root), "--out", str(checkpoint), "--epochs", "1"]
    assert main(args) == 0
    # the two shortest clips: two episodes at once, so that the server batches them
    every = splits.scenario_ids(splits.split_path(loader_root, "default"), "all")
    clips = sorted(every, key=lambda s: store.read_scenario(loader_root, s).num_frames)[:2]
    rows = {}
    for server, workers in (("on", "2"), ("off", "1")):
        out = tmp_path / server
        assert main(["evaluate", str(loader_root), "--split", "all", "--agent", "camera",
                     "--checkpoint", str(checkpoint), "--out", str(out), "--workers", workers,
                     "--policy-server", server, "--only", *clips]) == 0  # fmt: skip
        rows[server] = episodes(out)
    assert sorted(rows["on"]) == sorted(clips)
    keys = ("status", "steps", "driving_score", "route_completion", "events", "failure")
    for clip in clips:
        assert rows["on"][clip]["failure"] == ""
        assert {k: rows["on"][clip][k] for k in keys} == {k: rows["off"][clip][k] for k in keys}
        assert rows["on"][clip]["driven_m"] == pytest.approx(
            rows["off"][clip]["driven_m"], abs=1e-4
        )
    # the server's account of its batches: a request per step of each episode, and one more:
    # a served agent's next observation goes out before the step driven is judged (the rules
    # are applied while the network runs), and the rules ended each episode there
    stats = json.loads((tmp_path / "on" / "policy_server_cpu.json").read_text())
    assert stats["requests"] == sum(rows["on"][clip]["steps"] + 1 for clip in clips)
    assert 0 < stats["batches"] <= stats["requests"] and stats["forward_s"] > 0
    assert not (tmp_path / "off" / "policy_server_cpu.json").exists()


def test_a_clip_without_an_ego_is_an_error_row_and_the_run_goes_on(
    three_clips: Path, tmp_path: Path
) -> None:
    import dataclasses
    import shutil

    root = tmp_path / "data"
    shutil.copytree(three_clips, root, ignore=shutil.ignore_patterns("results"))
    broken = store.read_scenario(root, store.scenario_ids(root)[0])
    store.write_scenario(root, dataclasses.replace(broken, ego_id=None, route=None))
    out = tmp_path / "run"
    assert main(["evaluate", str(root), "--split", "all", "--out", str(out)]) == 0
    rows = episodes(out)
    assert rows[broken.scenario_id]["status"] == "error"
    assert "has no ego" in rows[broken.scenario_id]["failure"]
    assert sum(row["status"] == "completed" for row in rows.values()) == 2


class _Probe:
    def __init__(self, sensors: tuple[str, ...]) -> None:
        self.sensors = sensors


def test_only_a_served_camera_agent_on_gpus_makes_contexts_a_few_at_a_time() -> None:
    import multiprocessing

    from drivee2e_data.evaluate import runner
    from drivee2e_data.sim.egl_devices import CONTEXTS_AT_ONCE_PER_GPU

    context = multiprocessing.get_context("spawn")
    served = [("handle", "process")]
    camera = _Probe(("CAM_FRONT",))
    assert runner._context_slots(context, (), camera, served) is None  # llvmpipe: no GPU
    assert runner._context_slots(context, (0, 1), camera, []) is None  # its CUDA in the workers
    assert runner._context_slots(context, (0, 1), _Probe(()), served) is None  # draws nothing
    assert runner._context_slots(context, (0, 1), None, served) is None  # an agent command
    slots = runner._context_slots(context, (0, 1), camera, served)
    taken = 0
    while slots.acquire(block=False):
        taken += 1
    assert taken == 2 * CONTEXTS_AT_ONCE_PER_GPU


def test_a_worker_given_context_slots_makes_its_context_with_one_before_any_episode() -> None:
    from drivee2e_data.evaluate import preload, runner
    from drivee2e_data.processes import worker_pool
    from drivee2e_data.sim.gl_context import gl_available

    if not gl_available():
        pytest.skip("no OpenGL context can be made here")
    context = preload.worker_context()
    slots = context.Semaphore(0)  # none free yet
    with worker_pool(1, runner._init_worker, (context.Value("i", 0), (), (), 1, slots),
                     context) as pool:  # fmt: skip
        job = pool.submit(context_made)
        time.sleep(1.0)
        assert not job.done()  # the worker waits for a slot before it takes a task
        slots.release()
        assert job.result(timeout=60) is True
        # made at low priority, so that the policy server's network goes first on the GPU
        assert pool.submit(requested_priority).result(timeout=60) is Priority.LOW
    assert slots.acquire(timeout=5)  # given back once made
    with worker_pool(1, runner._init_worker, (context.Value("i", 0),), context) as pool:
        assert pool.submit(context_made).result(timeout=60) is False  # none without slots
        assert pool.submit(requested_priority).result(timeout=60) is None


def test_a_probe_the_caller_built_is_not_built_again() -> None:
    """The CLI builds the agent without its network to check the name and checkpoint; the pool
    is laid out by that one (`runner._probe`), not by a second build."""
    from drivee2e_data.evaluate.options import EvaluationOptions
    from drivee2e_data.evaluate.runner import _probe

    built: list[bool] = []

    def factory(name: str, checkpoint: Path | None, network: bool = True) -> object:
        built.append(network)
        return object()

    options, given = EvaluationOptions(agent="tcp"), object()
    assert _probe(options, factory, given) is given and built == []
    assert _probe(options, factory) is not given and built == [False]
    assert _probe(EvaluationOptions(agent_cmd="python agent.py"), factory, given) is None
