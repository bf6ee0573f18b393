"""ScenarioNet's unified format: the shared nuScenes scenes, a Waymo-style scenario written here,
database folders, and pickles that must not be trusted."""

import os
import pickle
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from conftest import REALDATA

from drivee2e_data import pipeline, store
from drivee2e_data.cli import main
from drivee2e_data.errors import ScenarioFormatError
from drivee2e_data.hdmap import MarkColour, MarkPattern
from drivee2e_data.scenario import AgentClass, SignalState, TimeOfDay
from drivee2e_data.sources import scenarionet
from tests.factories import assert_sun_matches_label

SAMPLES = REALDATA / "scenarionet"
needs_samples = pytest.mark.skipif(not SAMPLES.is_dir(), reason="../shared/realdata is absent")


@pytest.fixture(scope="module")
def seaport():
    return scenarionet.import_scenario(SAMPLES / "sd_nuscenes_v1.0-mini_scene-0553.pkl")


@needs_samples
def test_nuscenes_scene_facts(seaport):
    scenario, m = seaport.scenario, seaport.intersection_map
    assert scenario.num_frames == 201 and scenario.ego_id == "ego"
    classes = scenario.class_counts()
    # 28 VEHICLE tracks (the recording car too): 23 cars, 2 trucks and a trailer, 2 buses
    assert classes[AgentClass.CAR] == 23  # the recording car among them
    assert classes[AgentClass.TRUCK] == 3 and classes[AgentClass.BUS] == 2
    assert classes[AgentClass.PEDESTRIAN] == 12 and classes[AgentClass.CYCLIST] == 1
    assert len(m.static_obstacles) == 16  # the barriers
    assert {o.kind for o in m.static_obstacles} == {"barrier"}
    ego = scenario.ego
    assert ego.valid.all()
    assert ego.length_m[0] == pytest.approx(4.08) and ego.width_m[0] == pytest.approx(1.73)
    assert abs(m.origin.latitude_deg - 42.35) < 0.02 and abs(m.origin.longitude_deg + 71.04) < 0.02
    assert scenario.conditions.start_time_utc.date().isoformat() == "2018-08-28"
    assert scenario.conditions.time_of_day == TimeOfDay.NOON
    assert_sun_matches_label(scenario.conditions, m.origin)
    assert len(m.lanes) == 421 and sum(lane.is_intersection for lane in m.lanes) == 237
    marks = {lane.left_mark for lane in m.lanes} | {lane.right_mark for lane in m.lanes}
    assert (MarkPattern.DASHED, MarkColour.WHITE) in {(k.pattern, k.colour) for k in marks}
    assert (MarkPattern.SOLID, MarkColour.YELLOW) in {(k.pattern, k.colour) for k in marks}
    assert sum(bool(lane.successors) for lane in m.lanes) > 300  # linked by geometry


@needs_samples
def test_nuscenes_positions_are_the_files_minus_the_offset(seaport):
    document = scenarionet.load_pickle(SAMPLES / "sd_nuscenes_v1.0-mini_scene-0553.pkl")
    offset = np.asarray(seaport.intersection_map.metadata["offset_m"])
    track_id = "d9a4df9e92804a44a039eb21e0dc1349"  # a car that moves 106 m, valid throughout
    source = document["tracks"][track_id]["state"]["position"][:, :2] - offset[:2]
    track = seaport.scenario.track(track_id)
    assert np.abs(np.column_stack([track.x_m, track.y_m]) - source).max() < 0.01
    assert np.allclose(track.z_m, 0.5 * track.height_m)  # the map is flat: boxes stand on it


@needs_samples
@pytest.mark.slow
def test_shared_scenes_import_curate_and_render(tmp_path: Path, capsys):
    assert main(["import", "scenarionet", str(SAMPLES), "--out", str(tmp_path)]) == 0
    ids = store.scenario_ids(tmp_path)
    assert ids == [
        "scenarionet_nuscenes_scene-0061",
        "scenarionet_nuscenes_scene-0553",
        "scenarionet_nuscenes_scene-1100",
    ]
    rows = pipeline.curate(tmp_path)
    assert all(row.behavior != "-" for row in rows)
    # scene-0553's recording car stands still for 20 s: a moving car is chosen instead;
    # scene-1100's barely moves, but no other vehicle is seen throughout, so it stays
    assert [row.ego_source for row in rows] == [
        "kept from the source",
        "chosen (the source's ego stands still)",
        "kept from the source",
    ]
    assert (
        main(["view", str(tmp_path), ids[0], "--frame", "50", "--out", str(tmp_path / "v.png")])
        == 0
    )
    assert (tmp_path / "v.png").stat().st_size > 10_000


# ------------------------------------------------------------------ a scenario written here


def _agent(kind: str, xy: np.ndarray, heading: float, size: tuple[float, ...]) -> dict:
    """A ScenarioNet track: type, per-frame state (sizes as (T,)), metadata."""
    frames = len(xy)
    state = {
        "position": np.column_stack([xy, np.full(frames, 0.8)]),
        "heading": np.full(frames, heading),
        "velocity": np.zeros((frames, 2)),
        "valid": np.ones(frames),
        "length": np.full(frames, size[0]),
        "width": np.full(frames, size[1]),
        "height": np.full(frames, size[2]),
    }
    return {"type": kind, "state": state, "metadata": {}}


def waymo_like(frames: int = 41, rate_s: float = 0.05) -> dict:
    """4 s at 20 Hz around a lane with a light, a crosswalk, a stop sign and road edges."""
    t = rate_s * np.arange(frames)

    def row(value: float) -> np.ndarray:
        return np.full(frames, value)

    straight = np.column_stack([np.linspace(100.0, 160.0, 61), np.full(61, 200.0), np.zeros(61)])
    after = straight + np.array([61.0, 0.0, 0.0])
    crosswalk = np.array([[162.0, 197.0], [166.0, 197.0], [166.0, 203.0], [162.0, 203.0]])
    light_states = ["LANE_STATE_STOP"] * 20 + ["LANE_STATE_GO"] * (frames - 20)
    features = {
        "10": {
            "type": "LANE_SURFACE_STREET",
            "polyline": straight,
            "exit_lanes": ["11"],
            "width": np.full((61, 2), 1.8),
        },
        "11": {
            "type": "LANE_SURFACE_STREET",
            "polyline": after,
            "entry_lanes": ["10"],
            "left_neighbor": [{"feature_id": "99"}],
        },
        "20": {"type": "ROAD_LINE_SOLID_DOUBLE_YELLOW", "polyline": straight[:, :2] + [0, 1.9]},
        "30": {"type": "ROAD_EDGE_BOUNDARY", "polyline": straight[:, :2] - [0.0, 1.9]},
        "40": {"type": "CROSSWALK", "polygon": crosswalk},
        "50": {"type": "STOP_SIGN", "position": np.array([215.0, 198.0]), "lane": ["11"]},
        "60": {"type": "SPEED_BUMP", "polygon": np.zeros((4, 2))},
    }
    return {
        "id": "waymo-abc",
        "version": "v0.4",
        "length": frames,
        "metadata": {
            "dataset": "waymo",
            "sdc_id": "1",
            "ts": t,
            "sample_rate": rate_s,
            "date": "2021-05-02",
        },
        "tracks": {
            "1": _agent(
                "VEHICLE", np.column_stack([110 + 8 * t, row(200.0)]), 0.0, (4.5, 1.9, 1.6)
            ),
            "2": _agent(
                "VEHICLE", np.column_stack([140 - 5 * t, row(196.5)]), np.pi, (12, 2.6, 3.4)
            ),
            "3": _agent("TRAFFIC_CONE", np.column_stack([row(150.0), row(202.5)]), 0.0, (0.4,) * 3),
            "4": _agent("UNSET", np.column_stack([row(130.0), row(205.0)]), 0.0, (1.0, 1.0, 1.0)),
        },
        "dynamic_map_states": {
            "77": {
                "lane": "10",
                "stop_point": np.array([160.0, 200.0, 0.0]),
                "state": {"object_state": light_states},
            }
        },
        "map_features": defaultdict(dict, features),
    }


def _write(path: Path, document: object) -> Path:
    path.write_bytes(pickle.dumps(document))
    return path


def test_waymo_style_scenario(tmp_path: Path):
    imported = scenarionet.import_scenario(_write(tmp_path / "sd_waymo.pkl", waymo_like()))
    scenario, m = imported.scenario, imported.intersection_map
    assert scenario.scenario_id == "scenarionet_waymo_waymo-abc"
    assert scenario.num_frames == 21  # 4 s at 20 Hz resampled to 10 Hz
    ego = scenario.track("1")
    assert ego.x_m[10] - ego.x_m[0] == pytest.approx(8.0, abs=1e-6)  # 8 m/s for 1 s
    assert scenario.track("2").agent_class == AgentClass.TRUCK  # a 12 m VEHICLE
    assert imported.report.dropped["UNSET"][1] == 1
    assert [o.kind for o in m.static_obstacles] == ["cone"]
    lane = m.lane("10")
    assert lane.successors == ("11",) and m.lane("11").predecessors == ("10",)
    assert m.lane("11").left_neighbor is None  # 99 lies outside the crop: dropped, counted
    assert any("outside the map crop" in w for w in imported.report.warnings)
    assert np.allclose(lane.left_boundary_m[:, 1] - lane.right_boundary_m[:, 1], 3.6)
    assert lane.left_mark.pattern == MarkPattern.DOUBLE_SOLID
    assert (
        lane.left_mark.colour == MarkColour.YELLOW and lane.right_mark.pattern == MarkPattern.NONE
    )
    assert lane.signal_id == "light_77" and len(m.signal_heads) == 1
    light = scenario.signal("light_77")
    # source frames 0-19 stop (0-0.95 s), 20- go: 10 Hz frames 0-9 red, 10- green
    assert [SignalState(s) for s in light.states[[0, 9, 10, 20]]] == [
        SignalState.RED,
        SignalState.RED,
        SignalState.GREEN,
        SignalState.GREEN,
    ]
    assert {s.stop_line_id for s in m.stop_lines} == {"stop_light_77", "stop_sign_50"}
    assert len(m.crosswalks) == 1 and len(m.kerbs) == 1
    assert m.metadata["features not modelled"] == {"SPEED_BUMP": 1}
    assert m.origin.latitude_deg == 0.0 and "nominal" in m.metadata["origin"]
    assert_sun_matches_label(scenario.conditions, m.origin)


def test_database_folder_follows_its_mapping(tmp_path: Path):
    database = tmp_path / "db"
    (database / "part_0").mkdir(parents=True)
    _write(database / "part_0" / "sd_waymo_a.pkl", waymo_like())
    _write(database / "dataset_mapping.pkl", {"sd_waymo_a.pkl": "part_0"})
    _write(database / "dataset_summary.pkl", {"sd_waymo_a.pkl": {"id": "waymo-abc"}})
    assert scenarionet.scenario_files(database) == [database / "part_0" / "sd_waymo_a.pkl"]
    _write(database / "dataset_mapping.pkl", {"sd_missing.pkl": "part_0"})
    with pytest.raises(ScenarioFormatError, match=r"sd_missing\.pkl, which is missing"):
        scenarionet.scenario_files(database)


# ------------------------------------------------------------------ pickles not to be trusted


class _RunsACommand:
    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self):
        return (os.system, (self.command,))


def test_a_pickle_that_would_run_a_command_is_refused_and_nothing_runs(tmp_path: Path):
    marker = tmp_path / "it_ran"
    document = waymo_like()
    document["metadata"]["payload"] = _RunsACommand(f"touch {marker}")
    path = _write(tmp_path / "sd_evil.pkl", document)
    with pytest.raises(
        ScenarioFormatError, match=r"sd_evil\.pkl: the pickle names (posix|os)\.system"
    ):
        scenarionet.import_scenario(path)
    assert not marker.exists()
    out = tmp_path / "out"
    assert main(["import", "scenarionet", str(path), "--out", str(out)]) == 2
    assert not marker.exists() and not out.exists()


@pytest.mark.parametrize(
    "content, message",
    [
        (b"this is a text file, not a pickle\n", "not a readable pickle"),
        (pickle.dumps(waymo_like())[:500], "truncated pickle"),
        (pickle.dumps([1, 2, 3]), "expected a dict, found list"),
        (pickle.dumps({"id": "x"}), "key 'length' is missing"),
    ],
)
def test_damaged_files_are_one_clear_error(tmp_path: Path, content: bytes, message: str):
    path = tmp_path / "sd_bad.pkl"
    path.write_bytes(content)
    with pytest.raises(ScenarioFormatError, match=message):
        scenarionet.import_scenario(path)
