"""Which clip a closed-loop worker takes next (`evaluate.claims`): its world's map first, the
longest first, every clip once however many tasks claim at the same time."""

from __future__ import annotations

import multiprocessing
from pathlib import Path

import pytest

from drivee2e_data.errors import DriveE2EError
from drivee2e_data.evaluate.claims import all_claimed, claim, clip_order

ORDER = (("long_a", "A"), ("long_b", "B"), ("mid_a", "A"), ("mid_b", "B"), ("short_a", "A"))


def test_a_worker_takes_the_longest_clip_left_on_its_map_else_the_longest_left(tmp_path):
    assert claim(tmp_path, ORDER, None) == "long_a"  # no world yet: the longest
    assert claim(tmp_path, ORDER, "B") == "long_b"
    assert claim(tmp_path, ORDER, "A") == "mid_a"  # not long_b: the worker shows map A
    assert claim(tmp_path, ORDER, "A") == "short_a"
    assert claim(tmp_path, ORDER, "A") == "mid_b"  # A has none left
    with pytest.raises(DriveE2EError, match="every one of the 5 clips"):
        claim(tmp_path, ORDER, "B")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(s for s, _ in ORDER)


def _claim_one(folder: str, order, map_id) -> str:
    return claim(Path(folder), order, map_id)


def test_tasks_claiming_at_once_take_every_clip_once(tmp_path):
    order = tuple((f"clip{k:02d}", "AB"[k % 2]) for k in range(40))
    with multiprocessing.get_context("spawn").Pool(4) as pool:
        taken = pool.starmap(_claim_one, [(str(tmp_path), order, "AB"[k % 3 % 2])
                                          for k in range(40)])  # fmt: skip
    assert sorted(taken) == sorted(s for s, _ in order)


def test_clips_are_ordered_longest_first_with_their_maps(tmp_path):
    from drivee2e_data import pipeline, store

    pipeline.synthesize(tmp_path, clips=3, seed=3)
    ids = store.scenario_ids(tmp_path)
    (tmp_path / "scenarios" / "broken").mkdir()  # no meta: sorts last without a map
    order = clip_order(tmp_path, [*ids, "broken"])
    frames = [store.read_timeline(tmp_path, s)[1] for s, _ in order[:-1]]
    assert frames == sorted(frames, reverse=True)
    assert {m for _, m in order[:-1]} == {store.read_meta(tmp_path, s)["map_id"] for s in ids}
    assert order[-1] == ("broken", "")


def test_every_clip_is_claimed_only_once_the_last_is(tmp_path):
    for _ in ORDER:
        assert not all_claimed(tmp_path, ORDER)
        claim(tmp_path, ORDER, None)
    assert all_claimed(tmp_path, ORDER)


class _World:
    def __init__(self, map_id: str) -> None:
        self.intersection_map = type("Map", (), {"map_id": map_id})()
        self.closed = False

    def close(self) -> None:
        self.closed = True


def test_a_worker_gives_its_world_back_once_no_clip_is_left_to_start(tmp_path, monkeypatch):
    from drivee2e_data.evaluate import runner
    from drivee2e_data.sim import gl_context

    released = []
    monkeypatch.setattr(gl_context, "release_context", lambda: released.append(1) or True)
    monkeypatch.setattr(runner, "evaluate_clip", lambda root, sid, *a: {"scenario_id": sid})
    world = _World("A")
    monkeypatch.setattr(runner, "_world", world)
    order = ORDER[:2]
    row = runner.evaluate_claimed(tmp_path, str(tmp_path), order, None, tmp_path)
    assert row == {"scenario_id": "long_a"}  # its map's clip; one left to start: kept
    assert runner._world is world and not world.closed and not released
    assert runner.evaluate_claimed(tmp_path, str(tmp_path), order, None, tmp_path) == {
        "scenario_id": "long_b"
    }
    assert world.closed and runner._world is None and released == [1]
    assert not runner.give_back_world()  # nothing left to give back
