"""What worlds reuse: a twin's plan is pure data (equal for the same map, the same twin however
it came), kept in the process by its map file, shared through a run's folder, planned anew when
the file changes or a shared copy is damaged; actors' shape files are written once and found by
any world that shares the folder."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import pytest

from drivee2e_data import store
from drivee2e_data.errors import DriveE2EError
from drivee2e_data.sim import actors, reuse, twin_plan
from drivee2e_data.sim.twin import build_twin
from drivee2e_data.sim.world import World, connect
from tests.factories import small_scenario


@pytest.fixture
def shared(tmp_path: Path):
    """A run's shared folder for the test, and none again after it (with no plans kept)."""
    folder = tmp_path / "shared"
    folder.mkdir()
    reuse.forget_plans()
    reuse.share_in(folder)
    yield folder
    reuse.share_in(None)
    reuse.forget_plans()


def _counting_plans(monkeypatch) -> list[str]:
    """The map ids planned from now on (by `reuse`)."""
    planned = []

    def plan(intersection_map):
        planned.append(intersection_map.map_id)
        return twin_plan.plan_twin(intersection_map)

    monkeypatch.setattr(reuse, "plan_twin", plan)
    return planned


def _twin_arrays(twin) -> list:
    return [(m.body, m.kind, m.rgba, m.material, m.vertices.tobytes(), m.indices.tobytes(),
             None if m.normals is None else m.normals.tobytes()) for m in twin.meshes]  # fmt: skip


def test_a_plan_is_data_equal_for_the_same_map_and_builds_the_same_twin(synthetic_root: Path):
    intersection_map = store.read_map(synthetic_root, store.read_scenario(
        synthetic_root, store.scenario_ids(synthetic_root)[0]).map_id)  # fmt: skip
    plan = twin_plan.plan_twin(intersection_map)
    assert pickle.dumps(plan) == pickle.dumps(twin_plan.plan_twin(intersection_map))
    kinds = plan.body_kinds()
    assert kinds[: len(plan.lamps)] == ["signal"] * len(plan.lamps)
    assert len(plan.lamps) == 3 * len(intersection_map.signal_heads)  # red, yellow, green
    direct = build_twin(intersection_map, connect("tiny")[0])
    replayed = build_twin(pickle.loads(pickle.dumps(plan)), connect("tiny")[0])
    try:
        # a fresh client numbers the bodies in the plan's order
        assert direct.bodies == replayed.bodies == list(range(len(kinds)))
        assert [direct.segmentation[b] for b in direct.bodies] == kinds
        assert direct.lamps == replayed.lamps
        assert _twin_arrays(direct) == _twin_arrays(replayed)
        assert np.array_equal(direct.paint_raster().codes, replayed.paint_raster().codes)
    finally:
        direct.remove_files()
        replayed.remove_files()


def test_plans_are_kept_by_map_file_shared_and_made_again_when_it_changes(
    synthetic_root: Path, tmp_path: Path, shared: Path, monkeypatch
):
    root = tmp_path / "data"
    (root / "maps").mkdir(parents=True)
    map_id = store.read_scenario(synthetic_root, store.scenario_ids(synthetic_root)[0]).map_id
    intersection_map = store.read_map(synthetic_root, map_id)
    store.write_map(root, intersection_map)
    planned = _counting_plans(monkeypatch)

    first = reuse.twin_plan(root, intersection_map)
    assert reuse.twin_plan(root, intersection_map) is first  # kept in the process
    assert planned == [map_id]
    assert [p.name.split("-")[0] for p in shared.glob("*.plan")] == [map_id]

    reuse.forget_plans()  # as another worker of the run: read from the shared folder
    other = reuse.twin_plan(root, intersection_map)
    assert planned == [map_id] and pickle.dumps(other) == pickle.dumps(first)

    reuse.forget_plans()
    next(shared.glob("*.plan")).write_bytes(b"not a plan")  # damaged: planned anew
    assert pickle.dumps(reuse.twin_plan(root, intersection_map)) == pickle.dumps(first)
    assert planned == [map_id, map_id]
    reuse.forget_plans()  # and written again whole for the others
    assert pickle.dumps(reuse.twin_plan(root, intersection_map)) == pickle.dumps(first)
    assert planned == [map_id, map_id]

    path = store.map_path(root, map_id)  # the map file changed: its old plan is not used
    stat = path.stat()
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
    reuse.twin_plan(root, intersection_map)
    assert planned == [map_id] * 3
    assert not list(shared.glob(".*"))  # every plan written whole, then renamed


def test_a_world_refuses_a_plan_of_another_map(synthetic_root: Path):
    maps = sorted({store.read_scenario(synthetic_root, s).map_id
                   for s in store.scenario_ids(synthetic_root)})  # fmt: skip
    assert len(maps) >= 2
    plan = twin_plan.plan_twin(store.read_map(synthetic_root, maps[1]))
    with pytest.raises(DriveE2EError, match=f"plan of map '{maps[1]}' given for map '{maps[0]}'"):
        World(store.read_map(synthetic_root, maps[0]), small_scenario(), "tiny", twin_plan=plan)


def test_actor_shape_files_are_written_once_for_every_world_sharing_the_folder(
    synthetic_root: Path, shared: Path, monkeypatch
):
    scenario = store.read_scenario(synthetic_root, store.scenario_ids(synthetic_root)[0])
    intersection_map = store.read_map(synthetic_root, scenario.map_id)
    with World(intersection_map, scenario, "tiny") as world:
        keys = {actors.geometry_key(model) for model in world.models.values()}
    listings = sorted(shared.glob("actor_*.parts"))
    assert {int(p.name[6:22], 16) for p in listings} == keys  # one list per shape
    for listing in listings:
        parts = listing.read_text().split()
        assert 1 <= len(parts) <= actors.MAX_PARTS
        assert all((shared / name).stat().st_size > 0 for name in parts)
    assert not list(shared.glob(".*"))
    written = {p.name: p.stat().st_mtime_ns for p in shared.iterdir()}

    def no_parts(model):
        raise AssertionError("a shape found in the shared folder was cut into parts again")

    monkeypatch.setattr(actors, "convex_parts", no_parts)
    with World(intersection_map, scenario, "tiny") as again:  # another client, same shapes
        assert {actors.geometry_key(m) for m in again.models.values()} == keys
        assert again.bodies.keys() == world.bodies.keys()
    assert {p.name: p.stat().st_mtime_ns for p in shared.iterdir() if p.suffix != ".plan"} == {
        name: mtime for name, mtime in written.items() if not name.endswith(".plan")
    }
