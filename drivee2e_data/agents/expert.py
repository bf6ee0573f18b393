"""The log-replay expert: drives the logged driver's path, at the logged driver's pace, through
the harness's own controllers. Its score is the harness's sanity check: on clips whose logged
driver commits no infraction it should score what the log scores, and `drivee2e curate` leaves
out of the splits any clip where it does not (`evaluate/expert_check.py`)."""

from __future__ import annotations

import numpy as np

from drivee2e_data.evaluate.agent import Observation, Route, Waypoints
from drivee2e_data.geometry import polyline_arclength
from drivee2e_data.sensors.ego_state import to_ego_frame
from drivee2e_data.sensors.rig import Rig

PLAN_STEPS = 6
PLAN_PERIOD_S = 0.5
# the ego's place on the logged path is searched this far behind and ahead of the last one (a
# U-turn comes back near its own start; a global nearest point would jump there)
SEARCH_BACK_M = 2.0
SEARCH_AHEAD_M = 15.0


class LogReplayExpert:
    """Plans points of the logged path: the places the logged driver reached 0.5 s to 3 s after
    the current time (its pace), never behind the ego's own place on that path (an ego ahead of
    its log waits for it instead of turning back), in the ego frame of the actual pose. Points
    along the path rather than straight chords keep the plan on a U-turn's arc."""

    name = "expert"
    sensors: tuple[str, ...] = ()
    image_size = None

    def __init__(self, checkpoint: object = None) -> None:
        del checkpoint  # nothing to load
        self.path_txy = np.zeros((0, 3))
        self.s_m = np.zeros(0)
        self.progress_m = 0.0

    def setup(self, route: Route, rig: Rig | None) -> None:
        self.path_txy = np.asarray(route.logged_path_txy, np.float64)
        self.s_m = polyline_arclength(self.path_txy[:, 1:])
        self.progress_m = 0.0

    def act(self, observation: Observation) -> Waypoints:
        t, xy = self.path_txy[:, 0], self.path_txy[:, 1:]
        self.progress_m = max(self.progress_m, self._place_on_path(observation.xy_m))
        times = observation.t_s + PLAN_PERIOD_S * np.arange(1, PLAN_STEPS + 1)
        s_plan = np.maximum(np.interp(times, t, self.s_m), self.progress_m)
        ahead = np.column_stack([np.interp(s_plan, self.s_m, xy[:, d]) for d in range(2)])
        return Waypoints(to_ego_frame(ahead, *observation.xy_m, observation.yaw_rad))

    def _place_on_path(self, xy_m: np.ndarray) -> float:
        """Arclength (m) of the point of the logged path nearest `xy_m`, near the last one."""
        xy = self.path_txy[:, 1:]
        window = np.flatnonzero(
            (self.s_m >= self.progress_m - SEARCH_BACK_M)
            & (self.s_m <= self.progress_m + SEARCH_AHEAD_M)
        )
        nearest = int(window[np.argmin(np.hypot(*(xy[window] - xy_m).T))])
        best_s, best_distance = float(self.s_m[nearest]), float(np.hypot(*(xy[nearest] - xy_m)))
        for start in (nearest - 1, nearest):  # project onto the segments either side
            if 0 <= start < len(xy) - 1 and self.s_m[start + 1] > self.s_m[start]:
                segment = xy[start + 1] - xy[start]
                share = float(np.clip((xy_m - xy[start]) @ segment / (segment @ segment), 0, 1))
                distance = float(np.hypot(*(xy[start] + share * segment - xy_m)))
                if distance < best_distance:
                    best_distance = distance
                    best_s = float(
                        self.s_m[start] + share * (self.s_m[start + 1] - self.s_m[start])
                    )
        return best_s
