"""Importers on the real samples under ../shared/realdata (skipped when it is absent)."""

from pathlib import Path

import numpy as np
import pyarrow.feather as feather
import pytest
import shapely
from conftest import REALDATA

from drivee2e_data import pipeline, store
from drivee2e_data.geometry import rotation_from_quaternion
from drivee2e_data.scenario import AgentClass, SignalState
from drivee2e_data.sources import argoverse2, commonroad, lanelet2, sind
from drivee2e_data.sources.common import read_csv_rows
from tests.factories import assert_sun_matches_label

pytestmark = pytest.mark.skipif(not REALDATA.is_dir(), reason="../shared/realdata is absent")
AV2 = REALDATA / "argoverse2"


@pytest.fixture(scope="module")
def sensor_log():
    return argoverse2.import_sensor_log(AV2 / "sensor-log-7fab2350")


@pytest.fixture(scope="module")
def forecasting():
    return argoverse2.import_forecasting(AV2 / "forecasting-0a1e6f0a")


def _count(scenario, classes):
    return sum(1 for t in scenario.tracks if t.agent_class in classes)


VEHICLES = {AgentClass.CAR, AgentClass.VAN, AgentClass.TRUCK, AgentClass.BUS}


def test_av2_sensor_log_facts(sensor_log):
    scenario = sensor_log.scenario
    assert scenario.num_frames == 155  # 15.5 s at exactly 10 Hz
    assert _count(scenario, VEHICLES) == 63  # 60 cars, a box truck, a truck cab, the recording car
    assert _count(scenario, {AgentClass.PEDESTRIAN}) == 11
    assert scenario.ego_id == argoverse2.RECORDING_CAR_ID
    assert sensor_log.report.static["BOLLARD"] == 7
    assert len(sensor_log.intersection_map.lanes) == 183
    assert sum(lane.is_intersection for lane in sensor_log.intersection_map.lanes) == 73
    assert len(sensor_log.intersection_map.crosswalks) == 11
    assert all(s.derived for s in sensor_log.intersection_map.stop_lines)


def test_av2_recording_car_matches_its_poses_within_1cm(sensor_log):
    poses = feather.read_table(AV2 / "sensor-log-7fab2350" / "city_SE3_egovehicle.feather")
    t = poses.column("timestamp_ns").to_numpy()
    order = np.argsort(t)
    quaternion = np.stack([poses.column(c).to_numpy()[order] for c in ("qw", "qx", "qy", "qz")], -1)
    position = np.stack([poses.column(c).to_numpy()[order] for c in ("tx_m", "ty_m", "tz_m")], -1)
    forward = rotation_from_quaternion(quaternion)[:, :, 0]
    centre = position + argoverse2.REAR_AXLE_TO_CENTRE_M * forward
    offset = np.asarray(sensor_log.intersection_map.metadata["city_offset_m"])
    track = sensor_log.scenario.ego
    grid = sensor_log.scenario.t_ns
    for axis, values in ((0, track.x_m), (1, track.y_m)):
        expected = np.interp(grid, t[order], centre[:, axis]) - offset[axis]
        assert np.abs(values[track.valid] - expected[track.valid]).max() < 0.01


def test_av2_tracks_stay_near_road_or_crosswalk(sensor_log, forecasting):
    for imported in (sensor_log, forecasting):
        m = imported.intersection_map
        areas = [shapely.Polygon(a.polygon_m) for a in (*m.drivable_areas, *m.crosswalks)]
        reach = shapely.union_all([shapely.make_valid(a) for a in areas])
        for track in imported.scenario.tracks:
            distance = shapely.distance(
                reach, shapely.points(track.x_m[track.valid], track.y_m[track.valid])
            )
            assert distance.max() <= 2.0 + 1e-6, track.track_id


def test_av2_forecasting_facts(forecasting):
    scenario = forecasting.scenario
    assert scenario.num_frames == 110
    assert _count(scenario, {AgentClass.CAR}) == 25
    assert _count(scenario, {AgentClass.PEDESTRIAN}) == 7
    assert all("class default" in t.metadata["size_source"] for t in scenario.tracks)
    assert scenario.ego_id == "138951"  # the focal track
    assert len(forecasting.intersection_map.lanes) == 71
    assert len(forecasting.intersection_map.crosswalks) == 6


def test_av2_round_trips(sensor_log, forecasting, tmp_path: Path):
    for imported in (sensor_log, forecasting):
        store.write_map(tmp_path, imported.intersection_map)
        store.write_scenario(tmp_path, imported.scenario)
        assert (
            store.read_map(tmp_path, imported.intersection_map.map_id) == imported.intersection_map
        )
        assert store.read_scenario(tmp_path, imported.scenario.scenario_id) == imported.scenario


def test_commonroad_intersection():
    imported = commonroad.import_commonroad(REALDATA / "commonroad" / "USA_Peach-4_8_T-1.xml")
    assert _count(imported.scenario, {AgentClass.CAR}) == 9
    assert len(imported.intersection_map.stop_lines) == 13
    assert len(imported.scenario.signals) == 4 and len(imported.intersection_map.signal_heads) == 4
    assert all(s.origin == "cycle_derived" for s in imported.scenario.signals)
    light = imported.scenario.signals[0]
    assert {SignalState(v) for v in light.states} <= {
        SignalState.RED,
        SignalState.YELLOW,
        SignalState.GREEN,
    }
    older = commonroad.import_commonroad(
        REALDATA / "commonroad" / "USA_Lanker-1_1_T-1.xml"
    )  # 2018b
    assert _count(older.scenario, {AgentClass.CAR}) == 24 and not older.scenario.signals


def test_every_real_import_renders_the_sun_its_label_says(sensor_log, forecasting):
    imports = [
        sensor_log,
        forecasting,
        commonroad.import_commonroad(REALDATA / "commonroad" / "USA_Peach-4_8_T-1.xml"),
    ]
    for imported in imports:
        assert_sun_matches_label(imported.scenario.conditions, imported.intersection_map.origin)
    for city in ("Changchun", "Chongqing", "Tianjin", "Xian"):
        imported = sind.import_sind(REALDATA / "sind" / "Data" / city)
        assert_sun_matches_label(imported.recording.conditions, imported.intersection_map.origin)


def test_lanelet2_example_map():
    m = lanelet2.read_map(REALDATA / "lanelet2" / "mapping_example.osm", "example")
    assert len(m.stop_lines) == 28
    assert len(m.crosswalks) == 8
    assert len({head.signal_id for head in m.signal_heads}) == 6
    assert abs(m.origin.latitude_deg - 49.0) < 0.05 and abs(m.origin.longitude_deg - 8.42) < 0.05
    extent = np.concatenate([lane.centerline_m[:, :2] for lane in m.lanes])
    assert 500.0 < np.ptp(extent, axis=0).max() < 5000.0  # a few km in metres, not degrees


@pytest.mark.parametrize("city", ["Changchun", "Chongqing", "Tianjin", "Xian"])
def test_sind_city_signals_match_the_csv(city):
    imported = sind.import_sind(REALDATA / "sind" / "Data" / city)
    assert imported.intersection_map.lanes and imported.intersection_map.stop_lines
    whole = imported.recording
    light_file = next(
        iter(sorted((REALDATA / "sind" / "Data" / city).glob("*/Traffic*Light*.csv"))), None
    )
    light_file = light_file or next(
        iter(sorted((REALDATA / "sind" / "Data" / city).glob("*/TrafficLight*.csv")))
    )
    header, rows = read_csv_rows(light_file, ["RawFrameID"])
    origin_ms = whole.metadata["signals_time_origin_ms"]
    times_ms = origin_ms + (whole.t_ns - whole.t_ns[0]) / 1e6
    columns = header[2:]
    checked = 0
    for k, row in enumerate(rows[:-1]):
        if not row["timestamp(ms)"].strip():
            continue
        start = float(row["timestamp(ms)"])
        following = [float(r["timestamp(ms)"]) for r in rows[k + 1 :] if r["timestamp(ms)"].strip()]
        end = following[0] if following else times_ms[-1]
        inside = np.flatnonzero((times_ms >= start) & (times_ms < end))
        if inside.size == 0:
            continue
        frame = int(inside[len(inside) // 2])
        for column in columns:
            expected = {0: SignalState.RED, 1: SignalState.GREEN, 3: SignalState.YELLOW}[
                int(row[column])
            ]
            signal = whole.signal(sind._snake(column))
            assert signal.state_at(frame) == expected, (city, column, row["RawFrameID"])
            checked += 1
    assert checked > 20


def test_sind_messy_row_is_handled_with_a_warning():
    imported = sind.import_sind(REALDATA / "sind" / "Data" / "Xian")
    assert any("Traffic_Lights.csv row 2: empty timestamp" in w for w in imported.report.warnings)
    assert len(imported.recording.tracks) == 16  # the pedestrians
    assert all(20.0 - 0.2 <= c.duration_s <= 20.0 for c in imported.clips[:-1])


def test_import_cli_writes_and_lists(tmp_path: Path, capsys):
    from drivee2e_data.cli import main

    assert main(["import", "av2", str(AV2 / "forecasting-0a1e6f0a"), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "vehicle: mapped to car (25)" in out and "dropped" in out
    assert main(["scenarios", str(tmp_path)]) == 0
    assert pipeline.summarize(tmp_path)[0].agents[AgentClass.CAR] == 25


def test_sind_vehicle_tracks_when_present(tmp_path: Path):
    """The shared sample has no vehicle file; one in SinD's documented layout is read too."""
    import shutil

    city = tmp_path / "Xian"
    shutil.copytree(REALDATA / "sind" / "Data" / "Xian", city)
    rows = ["track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,yaw_rad,heading_rad,length,width"]
    for k in range(50):
        rows.append(f"7,{k},{100.1 * k:.1f},car,{-30 + k:.2f},4.0,10.0,0.0,0.0,0.0,4.7,1.9")
        rows.append(
            f"8,{k},{100.1 * k:.1f},tricycle,5.0,{-30 + 0.5 * k:.2f},0.0,5.0,1.5708,1.5708,2.6,1.1"
        )
    (city / "Xian_412_m1" / "Veh_smoothed_tracks.csv").write_text("\n".join(rows) + "\n")
    imported = sind.import_sind(city)
    car = imported.recording.track("7")
    assert car.agent_class == AgentClass.CAR and car.length_m[car.valid][0] == pytest.approx(4.7)
    assert imported.recording.track("8").agent_class == AgentClass.TRICYCLIST
    assert np.allclose(
        car.vx_mps[car.valid][1:-1], 10.0 / 1.001, atol=0.05
    )  # frames 100.1 ms apart
