import numpy as np
import pytest
from factories import straight_track

from drivee2e_data.scenario import AgentClass
from drivee2e_data.sensors.radar import RCS_DBSM, detect
from drivee2e_data.sensors.rig import default_rig, pose


def _oncoming(x0_m: float, speed_mps: float, agent_class=AgentClass.CAR, track_id="t"):
    x = x0_m - speed_mps * np.arange(10) * 0.1
    return straight_track(track_id, 10, agent_class, x_m=x, y_m=np.zeros(10), yaw_rad=np.full(10, np.pi),
                          vx_mps=np.full(10, -speed_mps))  # fmt: skip


def _front_radar_at_origin():
    radar = default_rig().radars[0]  # RADAR_FRONT
    return radar, pose(np.eye(3), np.array([0.0, 0.0, 0.5]))


def test_a_car_closing_at_5_mps_reads_minus_5():
    radar, radar_to_world = _front_radar_at_origin()
    result = detect(radar, radar_to_world, np.zeros(2), [_oncoming(30.0, 5.0)], frame=0)
    assert result.track_ids == ("t",)
    assert result.radial_velocity_mps[0] == pytest.approx(-5.0, abs=0.1)
    assert result.points_m[0, 0] == pytest.approx(30.0 - 2.25, abs=0.05)  # the car's front face
    assert result.rcs_dbsm[0] == RCS_DBSM[AgentClass.CAR]


def test_ego_motion_is_compensated():
    radar, radar_to_world = _front_radar_at_origin()
    parked = _oncoming(30.0, 0.0)
    result = detect(radar, radar_to_world, np.array([10.0, 0.0]), [parked], frame=0)
    assert result.radial_velocity_mps[0] == pytest.approx(0.0, abs=0.1)
    assert result.raw_radial_velocity_mps[0] == pytest.approx(-10.0, abs=0.1)


def test_field_of_view_and_range():
    radar, radar_to_world = _front_radar_at_origin()
    behind = _oncoming(-20.0, 0.0, track_id="behind")
    far = _oncoming(150.0, 0.0, track_id="far")
    result = detect(radar, radar_to_world, np.zeros(2), [behind, far], frame=0)
    assert result.track_ids == ()
