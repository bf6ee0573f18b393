"""The log-replay expert: drives the logged driver's path, at the logged driver's pace, through
the harness's own controllers. Its score is the harness's sanity check: on clips whose logged
driver commits no infraction it should score what the log scores."""

from __future__ import annotations

import numpy as np

from drivee2e_data.evaluate.agent import Observation, Route, Waypoints
from drivee2e_data.sensors.ego_state import to_ego_frame
from drivee2e_data.sensors.rig import Rig

PLAN_STEPS = 6
PLAN_PERIOD_S = 0.5


class LogReplayExpert:
    """Plans the logged positions 0.5 s to 3 s after the current time (held at the last
    logged position after the log's end), in the ego frame of the actual pose."""

    name = "expert"
    sensors: tuple[str, ...] = ()
    image_size = None

    def __init__(self, checkpoint: object = None) -> None:
        del checkpoint  # nothing to load
        self.path_txy = np.zeros((0, 3))

    def setup(self, route: Route, rig: Rig | None) -> None:
        self.path_txy = np.asarray(route.logged_path_txy, np.float64)

    def act(self, observation: Observation) -> Waypoints:
        times = observation.t_s + PLAN_PERIOD_S * np.arange(1, PLAN_STEPS + 1)
        t, x, y = self.path_txy.T
        ahead = np.column_stack([np.interp(times, t, x), np.interp(times, t, y)])
        return Waypoints(to_ego_frame(ahead, *observation.xy_m, observation.yaw_rad))
