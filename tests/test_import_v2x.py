"""V2X-Seq, DriveE2E-clip and INTERACTION importers on files the tests write in each layout,
and bad input: one clear error naming file, row and column, exit 2, nothing written."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from drivee2e_data import pipeline, store
from drivee2e_data.cli import main
from drivee2e_data.errors import DriveE2EError, ScenarioFormatError
from drivee2e_data.scenario import AgentClass, SignalState, SubScenario, TimeOfDay, Weather
from drivee2e_data.sources import drivee2e_clip, v2x_seq
from tests.factories import assert_sun_matches_label

SUB_TYPES = ["Car", "Van", "Truck", "Bus", "Pedestrian", "Cyclist", "Tricyclist", "Motorcyclist"]
BASE = (417_700.0, 4_731_500.0)  # a shifted UTM 50 frame, as in the published files
T0 = 1_626_150_000.0


def _pt(x, y):
    return f"({BASE[0] + x:.2f}, {BASE[1] + y:.2f})"


def write_hdmap(path: Path, bad_successor: bool = False) -> None:
    """Two lanes and a junction lane, every value string-encoded like the DriveE2E release."""
    lanes = {
        "1": {
            "centerline": str([_pt(-60, -1.75), _pt(-10, -1.75)]),
            "is_intersection": "False",
            "turn_direction": "NONE",
            "has_traffic_control": "True",
            "lane_type": "CITY_DRIVING",
            "predecessors": "[]",
            "successors": "['3']",
            "l_neighbor_id": "None",
            "r_neighbor_id": "None",
        },
        "3": {
            "centerline": str([_pt(-10, -1.75), _pt(10, -1.75)]),
            "is_intersection": "True",
            "turn_direction": "STRAIGHT",
            "predecessors": "['1']",
            "successors": "['99']" if bad_successor else "['2']",
        },
        "2": {
            "centerline": str([_pt(10, -1.75), _pt(60, -1.75)]),
            "is_intersection": "False",
            "turn_direction": "NONE",
            "predecessors": "['3']",
            "successors": "[]",
            "left_boundary": str([_pt(10, 0), _pt(60, 0)]),
            "right_boundary": str([_pt(10, -3.5), _pt(60, -3.5)]),
        },
    }
    document = {
        "LANE": lanes,
        "STOPLINE": {"7": {"centerline": str([_pt(-10, 0), _pt(-10, -3.5)])}},
        "CROSSWALK": {"8": {"polygon": str([_pt(-9, 0), _pt(-5, 0), _pt(-5, -7), _pt(-9, -7)])}},
    }
    path.write_text(json.dumps(document))


def trajectory_rows(extra: bool = False) -> list[dict[str, str]]:
    rows = []
    for k, sub_type in enumerate(SUB_TYPES):
        for step in range(30):
            row = {
                "city": "Beijing",
                "timestamp": f"{T0 + 0.1 * step:.1f}",
                "id": str(100 + k),
                "type": "VEHICLE",
                "sub_type": sub_type,
                "tag": "",
                "x": f"{BASE[0] - 50 + step + 3 * k:.3f}",
                "y": f"{BASE[1] - 1.75:.3f}",
                "z": "0.8",
                "length": "4.5",
                "width": "1.8",
                "height": "1.6",
                "theta": "0.0",
                "v_x": "10.0",
                "v_y": "0.0",
                "intersect_id": "yizhuang#4-1_po",
            }
            if extra:
                row.update(
                    weather="Cloudy",
                    ori_clip_index="17",
                    blueprint=f"vehicle.bp.{sub_type.lower()}",
                )
            rows.append(row)
    return rows


def write_csv(path: Path, rows: list[dict[str, str]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as stream:
        writer = csv.DictWriter(stream, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def light_rows() -> list[dict[str, str]]:
    rows = []
    for k, colour in enumerate(["GREEN", "YELLOW", "RED"]):
        rows.append(
            {
                "city": "Beijing",
                "timestamp": f"{T0 + k:.1f}",
                "x": f"{BASE[0] + 12:.2f}",
                "y": f"{BASE[1] + 4:.2f}",
                "direction": "west",
                "lane_id": "1",
                "color_1": colour,
                "remain_1": "3",
                "color_2": "RED",
                "remain_2": "9",
                "color_3": "",
                "remain_3": "",
                "intersect_id": "yizhuang#4-1_po",
            }
        )
    return rows


@pytest.fixture
def v2x_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "v2x"
    write_csv(folder / "trajectories" / "scene_001.csv", trajectory_rows())
    write_csv(folder / "traffic_light" / "scene_001.csv", light_rows())
    (folder / "maps").mkdir()
    write_hdmap(folder / "maps" / "hdmap4.json")
    return folder


def test_v2x_seq_scene(v2x_folder: Path):
    result = v2x_seq.import_v2x_seq(
        v2x_folder / "trajectories" / "scene_001.csv",
        v2x_folder / "traffic_light" / "scene_001.csv",
        v2x_folder / "maps" / "hdmap4.json",
    )
    scenario, m = result.scenario, result.intersection_map
    assert {t.agent_class for t in scenario.tracks} == set(AgentClass)
    assert scenario.num_frames == 30 and m.map_id == "v2x_yizhuang_4_1_po"
    assert np.allclose(scenario.track("100").vx_mps[scenario.track("100").valid], 10.0)
    light = scenario.signal("light_1_1")
    assert [light.state_at(f) for f in (0, 12, 25)] == [
        SignalState.GREEN,
        SignalState.YELLOW,
        SignalState.RED,
    ]
    assert scenario.signal("light_1_2").state_at(5) == SignalState.RED
    assert m.lane("1").signal_id == "light_1_1" and m.lane("3").is_intersection
    assert m.lane("3").turn_direction.value == "straight" and m.lane("1").successors == ("3",)
    assert len(m.crosswalks) == 1 and m.stop_lines[0].lane_ids == ("1",)
    assert np.allclose(
        m.lane("2").left_boundary_m[0, :2] - m.lane("2").right_boundary_m[0, :2], [0, 3.5]
    )
    assert_sun_matches_label(scenario.conditions, m.origin)


def test_drivee2e_clip_with_route(tmp_path: Path):
    write_csv(tmp_path / "YLW_001.csv", trajectory_rows(extra=True))
    write_hdmap(tmp_path / "hdmap4.json")
    (tmp_path / "route.xml").write_text(
        '<routes><route id="0" road_id="4" town="yizhuang" scenario_csv_id="YLW_001" ego_id="100">'
        '<weathers><weather route_percentage="0" cloudiness="80" precipitation="60" '
        'precipitation_deposits="40" wind_intensity="10" sun_azimuth_angle="200" '
        'sun_altitude_angle="-10"/></weathers></route></routes>'
    )
    result = drivee2e_clip.import_clip(
        tmp_path / "YLW_001.csv", tmp_path / "route.xml", tmp_path / "hdmap4.json"
    )
    scenario = result.scenario
    assert scenario.ego_id == "100"
    assert scenario.conditions.weather == Weather.RAIN  # precipitation 60 overrides 'Cloudy'
    assert scenario.conditions.time_of_day == TimeOfDay.NIGHT  # the sun is below the horizon
    assert_sun_matches_label(scenario.conditions, result.intersection_map.origin)
    assert scenario.track("103").metadata["blueprint"] == "vehicle.bp.bus"
    assert scenario.metadata["imported_category"] == "YLW" and scenario.behavior is None
    straight = drivee2e_clip.conditions_of(
        "Cloudy", {"sun_altitude_angle": 60.0}, 0, result.intersection_map.origin
    )
    assert straight.weather == Weather.CLOUDY and straight.time_of_day == TimeOfDay.NOON
    assert_sun_matches_label(straight, result.intersection_map.origin)
    (tmp_path / "route.xml").write_text(
        '<routes><route scenario_csv_id="STR_000" ego_id="101"/></routes>'
    )
    (tmp_path / "YLW_001.csv").rename(tmp_path / "STR_000.csv")
    labelled = drivee2e_clip.import_clip(
        tmp_path / "STR_000.csv", tmp_path / "route.xml", tmp_path / "hdmap4.json"
    )
    assert labelled.scenario.behavior.sub_scenario == SubScenario.STR


def test_unknown_class_is_dropped_with_a_warning_and_counted(v2x_folder: Path):
    rows = trajectory_rows()
    for row in rows[:30]:
        row["sub_type"] = "Hovercraft"
    write_csv(v2x_folder / "trajectories" / "scene_001.csv", rows)
    summary = pipeline.import_source(v2x_folder.parent / "out", "v2x-seq", v2x_folder)
    assert summary.report.dropped["Hovercraft"][1] == 30
    assert any("row 2: sub_type 'Hovercraft' is unknown" in w for w in summary.report.warnings)


def _damage_row(column, value, row=3):
    def damage(folder: Path) -> None:
        rows = trajectory_rows()
        rows[row - 2][column] = value
        write_csv(folder / "trajectories" / "scene_001.csv", rows)

    return damage


def _drop_column(folder: Path) -> None:
    rows = [{k: v for k, v in r.items() if k != "theta"} for r in trajectory_rows()]
    write_csv(folder / "trajectories" / "scene_001.csv", rows)


def _empty(folder: Path) -> None:
    (folder / "trajectories" / "scene_001.csv").write_text("")


def _out_of_order(folder: Path) -> None:
    rows = trajectory_rows()
    rows[4]["timestamp"], rows[5]["timestamp"] = rows[5]["timestamp"], rows[4]["timestamp"]
    write_csv(folder / "trajectories" / "scene_001.csv", rows)


def _binary(folder: Path) -> None:
    """A JPEG (or any binary file) given where the trajectory CSV belongs."""
    path = folder / "trajectories" / "scene_001.csv"
    path.write_bytes(bytes([0xFF, 0xD8, 0xFF, 0xE0]) + bytes(range(256)) * 8)


def _cut_map(folder: Path) -> None:
    path = folder / "maps" / "hdmap4.json"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


BAD = {
    "missing column": (_drop_column, r"scene_001.csv: column 'theta' is missing"),
    "nan coordinate": (
        _damage_row("x", "nan"),
        r"scene_001.csv row 3: column 'x' is 'nan', expected a finite number",
    ),
    "non-numeric field": (
        _damage_row("length", "long"),
        r"scene_001.csv row 3: column 'length' is 'long', expected a number",
    ),
    "timestamps out of order": (
        _out_of_order,
        r"scene_001.csv row 7: column 'timestamp' is out of order for track '100'",
    ),
    "empty file": (_empty, r"scene_001.csv: file is empty"),
    "binary file": (
        _binary,
        r"scene_001.csv: not UTF-8 text \(byte \d+\); expected a CSV file",
    ),
    "cut map": (_cut_map, r"hdmap4.json: not valid JSON"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_one_clear_error_and_writes_nothing(
    case, v2x_folder: Path, tmp_path: Path, capsys
):
    damage, message = BAD[case]
    damage(v2x_folder)
    out = tmp_path / "out"
    with pytest.raises(ScenarioFormatError, match=message):
        pipeline.import_source(out, "v2x-seq", v2x_folder)
    assert main(["import", "v2x-seq", str(v2x_folder), "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("drivee2e: error: ")
    assert not out.exists()


def test_a_folder_imports_what_it_can_and_lists_the_failures(
    v2x_folder: Path, tmp_path: Path, capsys
):
    for name in ("scene_002", "scene_003"):
        write_csv(v2x_folder / "trajectories" / f"{name}.csv", trajectory_rows())
    (v2x_folder / "trajectories" / "scene_002.csv").write_bytes(b"\xff\xd8\xff\xe0JFIF" * 50)
    out = tmp_path / "out"
    assert main(["import", "v2x-seq", str(v2x_folder), "--out", str(out)]) == 1
    assert store.scenario_ids(out) == ["v2x_scene_001", "v2x_scene_003"]
    error = capsys.readouterr().err
    assert "1 failed (nothing of them written):" in error
    assert "scene_002.csv: not UTF-8 text" in error
    summary = pipeline.import_source(tmp_path / "again", "v2x-seq", v2x_folder)
    assert list(summary.failures) == [str(v2x_folder / "trajectories" / "scene_002.csv")]
    for name in ("scene_001", "scene_003"):
        (v2x_folder / "trajectories" / f"{name}.csv").write_text("nonsense\n")
    with pytest.raises(DriveE2EError, match="all 3 clips failed to import; the first: "):
        pipeline.import_source(tmp_path / "none", "v2x-seq", v2x_folder)
    assert not (tmp_path / "none").exists()


def write_interaction_map(osm: Path) -> None:
    """One 55.7 m lanelet on the equator with a dashed left bound and a kerb on the right."""
    nodes = "".join(
        f"<node id='{i}' lat='{lat}' lon='{lon}'/>"
        for i, (lat, lon) in enumerate(
            [(0.0, 0.0), (0.0, 0.0005), (0.00003, 0.0), (0.00003, 0.0005)], 1
        )
    )
    osm.parent.mkdir(parents=True, exist_ok=True)
    osm.write_text(
        f"<osm>{nodes}<way id='10'><nd ref='3'/><nd ref='4'/><tag k='type' v='line_thin'/>"
        "<tag k='subtype' v='dashed'/></way><way id='11'><nd ref='1'/><nd ref='2'/>"
        "<tag k='type' v='curbstone'/></way><relation id='20'><member type='way' ref='10' role='left'/>"
        "<member type='way' ref='11' role='right'/><tag k='type' v='lanelet'/>"
        "<tag k='subtype' v='road'/></relation></osm>"
    )


def write_interaction_tracks(folder: Path, number: str = "000") -> list[Path]:
    """A car and a pedestrian over 2 s, as INTERACTION's vehicle and pedestrian files."""
    vehicles = [
        {
            "track_id": "1",
            "frame_id": str(k),
            "timestamp_ms": str(100 * k),
            "agent_type": "car",
            "x": str(5 + k),
            "y": "1.7",
            "vx": "10",
            "vy": "0",
            "psi_rad": "0",
            "length": "4.2",
            "width": "1.8",
        }
        for k in range(1, 21)
    ]
    walkers = [
        {
            "track_id": "P1",
            "frame_id": str(k),
            "timestamp_ms": str(100 * k),
            "agent_type": "pedestrian/bicycle",
            "x": "20",
            "y": str(0.12 * k),
            "vx": "0",
            "vy": "1.2",
        }
        for k in range(1, 21)
    ]
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"vehicle_tracks_{number}.csv", folder / f"pedestrian_tracks_{number}.csv"]
    write_csv(paths[0], vehicles)
    write_csv(paths[1], walkers)
    return paths


def test_interaction_tracks_and_map(tmp_path: Path):
    from drivee2e_data.sources import interaction

    osm = tmp_path / "DR_TEST.osm"
    write_interaction_map(osm)
    result = interaction.import_interaction(write_interaction_tracks(tmp_path), osm)
    classes = sorted(t.agent_class.value for t in result.scenario.tracks)
    assert classes == ["car", "pedestrian"]
    lane = result.intersection_map.lanes[0]
    # 0.0005 deg of longitude on the equator is 55.66 m; UTM zone 31's scale 3 deg off its meridian
    # makes it 55.71 m. 0.00003 deg of latitude is 3.32 m.
    assert lane.length_m == pytest.approx(55.71, abs=0.05)
    width = lane.left_boundary_m[0, 1] - lane.right_boundary_m[0, 1]
    assert width == pytest.approx(3.32, abs=0.02)
    assert lane.left_mark.pattern.value == "dashed" and len(result.intersection_map.kerbs) == 1
    assert_sun_matches_label(result.scenario.conditions, result.intersection_map.origin)


def test_interaction_release_layout_from_its_root_or_one_recording(tmp_path: Path):
    release = tmp_path / "INTERACTION-Dataset-DR-v1_1"
    write_interaction_map(release / "maps" / "DR_TEST.osm")
    recording = release / "recorded_trackfiles" / "DR_TEST"
    write_interaction_tracks(recording, "000")
    write_interaction_tracks(recording, "001")
    out = tmp_path / "data"
    assert main(["import", "interaction", str(release), "--out", str(out)]) == 0
    assert store.scenario_ids(out) == ["interaction_DR_TEST_000", "interaction_DR_TEST_001"]
    assert store.map_ids(out) == ["interaction_DR_TEST"]
    one = tmp_path / "one"
    assert main(["import", "interaction", str(recording), "--out", str(one)]) == 0
    assert store.scenario_ids(one) == store.scenario_ids(out)
    (release / "maps" / "DR_TEST.osm").unlink()
    assert main(["import", "interaction", str(release), "--out", str(tmp_path / "x")]) == 2


def test_a_cropped_map_drops_references_outside_it_with_one_warning(
    v2x_folder: Path, tmp_path: Path, capsys
):
    """A map cut to one site names lanes beyond the cut: dropped and counted, as every map
    reader does (AV2's crops too), never a refused import."""
    write_hdmap(v2x_folder / "maps" / "hdmap4.json", bad_successor=True)
    summary = pipeline.import_source(tmp_path / "out", "v2x-seq", v2x_folder)
    warnings = [w for w in summary.report.warnings if "outside the map crop" in w]
    assert warnings == ["hdmap4.json: 1 lane references point outside the map crop; dropped"]
    intersection_map = store.read_map(tmp_path / "out", summary.maps[0])
    assert "99" not in intersection_map.lane("3").successors
    assert main(["import", "v2x-seq", str(v2x_folder), "--out", str(tmp_path / "cli")]) == 0
    assert capsys.readouterr().err.count("outside the map crop") == 1
    # the DriveE2E clip importer reads the same maps the same way
    write_csv(tmp_path / "STR_000.csv", trajectory_rows(extra=True))
    (tmp_path / "route.xml").write_text(
        '<routes><route scenario_csv_id="STR_000" ego_id="101"/></routes>'
    )
    clip = drivee2e_clip.import_clip(
        tmp_path / "STR_000.csv", tmp_path / "route.xml", v2x_folder / "maps" / "hdmap4.json"
    )
    assert any("1 lane references point outside the map crop" in w for w in clip.report.warnings)
    # a Lanelet2 crop keeps a lanelet whose bound was cut away and a way missing a node
    osm = tmp_path / "cropped.osm"
    write_interaction_map(osm)
    text = osm.read_text().replace(
        "</osm>",
        "<way id='12'><nd ref='1'/><nd ref='77'/></way>"
        "<relation id='21'><member type='way' ref='10' role='left'/>"
        "<member type='way' ref='66' role='right'/><tag k='type' v='lanelet'/></relation></osm>",
    )
    osm.write_text(text)
    summary = pipeline.import_source(tmp_path / "lanelet2", "lanelet2", osm)
    assert summary.report.warnings == [
        "cropped.osm: 1 lanelets and 1 ways reach outside the map crop; dropped"
    ]
    assert [
        lane.lane_id for lane in store.read_map(tmp_path / "lanelet2", summary.maps[0]).lanes
    ] == ["lanelet_20"]


@pytest.mark.parametrize("offset_m", [25.0, -25.0])
def test_v2x_seq_boxes_raised_and_sloped_land_on_the_ground(tmp_path: Path, offset_m: float):
    """V2X-Seq gives object z (its map is flat): boxes standing on a road 25 m up or down and
    tilted 5% along x come out of `import` standing on z = 0 (the ground fitted to their
    bottoms)."""
    from drivee2e_data import pipeline, store

    folder = tmp_path / "v2x"
    rows = trajectory_rows()
    for row in rows:
        x = float(row["x"]) - BASE[0]
        row["z"] = f"{0.8 + offset_m + 0.05 * x:.4f}"  # centre 0.8 m up: a 1.6 m box on the road
    write_csv(folder / "trajectories" / "scene_001.csv", rows)
    write_csv(folder / "traffic_light" / "scene_001.csv", light_rows())
    (folder / "maps").mkdir()
    write_hdmap(folder / "maps" / "hdmap4.json")
    root = tmp_path / "data"
    summary = pipeline.import_source(root, "v2x-seq", folder)
    assert summary.grounds[summary.maps[0]].slope_x == pytest.approx(0.05, abs=1e-3)
    for scenario_id in summary.scenarios:
        scenario = store.read_scenario(root, scenario_id)
        for track in scenario.tracks:
            bottoms = track.z_m[track.valid] - 0.5 * track.height_m[track.valid]
            assert np.abs(bottoms).max() < 0.05, track.track_id
