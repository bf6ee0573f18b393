"""The traffic data model: a `Scenario` is one clip of tracked agents and signal states at 10 Hz.

Frames: positions in the map's world frame (local ENU, metres); (x, y, z) is the box centre;
yaw in radians counter-clockwise from +x; time in int64 nanoseconds on a uniform 10 Hz grid.
Construction validates everything and raises `ScenarioFormatError` naming field and index.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.arrays import ArrayValueEq, frozen_array
from drivee2e_data.errors import ScenarioFormatError

FRAME_PERIOD_NS = 100_000_000
"""10 Hz: every scenario timeline steps by exactly 0.1 s."""


class AgentClass(enum.Enum):
    """The eight agent classes of V2X-Seq; every importer maps its own classes onto these."""

    CAR = "car"
    VAN = "van"
    TRUCK = "truck"
    BUS = "bus"
    PEDESTRIAN = "pedestrian"
    CYCLIST = "cyclist"
    TRICYCLIST = "tricyclist"
    MOTORCYCLIST = "motorcyclist"

    @property
    def is_motor_vehicle(self) -> bool:
        """Cars, vans, trucks and buses: the classes an ego can be."""
        return self in (AgentClass.CAR, AgentClass.VAN, AgentClass.TRUCK, AgentClass.BUS)

    @property
    def is_vulnerable(self) -> bool:
        """Pedestrians and riders of two- and three-wheelers (the 'P' and 'C' of IPC)."""
        return self in (
            AgentClass.PEDESTRIAN,
            AgentClass.CYCLIST,
            AgentClass.TRICYCLIST,
            AgentClass.MOTORCYCLIST,
        )


class SignalState(enum.IntEnum):
    """State of a signal (one phase group) at one frame; stored as this small integer."""

    UNKNOWN = 0
    RED = 1
    YELLOW = 2
    GREEN = 3
    OFF = 4


class Weather(enum.Enum):
    """Six weathers: the five of SPEC.md plus wet roads after rain (CARLA's 'Wet' presets)."""

    CLEAR = "clear"
    CLOUDY = "cloudy"
    OVERCAST = "overcast"
    RAIN = "rain"
    FOG = "fog"
    WET = "wet"


class TimeOfDay(enum.Enum):
    """Local time-of-day bins from early morning to night."""

    EARLY_MORNING = "early_morning"
    MORNING = "morning"
    NOON = "noon"
    AFTERNOON = "afternoon"
    DUSK = "dusk"
    NIGHT = "night"

    @classmethod
    def from_local_hour(cls, hour: float) -> TimeOfDay:
        """The bin of a local clock hour in [0, 24)."""
        if 5.0 <= hour < 7.0:
            return cls.EARLY_MORNING
        if 7.0 <= hour < 11.0:
            return cls.MORNING
        if 11.0 <= hour < 14.0:
            return cls.NOON
        if 14.0 <= hour < 17.0:
            return cls.AFTERNOON
        if 17.0 <= hour < 19.5:
            return cls.DUSK
        return cls.NIGHT


class BehaviorCategory(enum.Enum):
    """The eight ego behaviour categories of DriveE2E (SPEC.md)."""

    IPC = "IPC"  # interaction with pedestrians and cyclists
    COV = "COV"  # competing with other vehicles
    YLW = "YLW"  # passing during yellow
    UT = "UT"  # U-turn
    STP = "STP"  # stopping at red
    STR = "STR"  # plain straight
    LFT = "LFT"  # plain left turn
    RT = "RT"  # plain right turn


class SubScenario(enum.Enum):
    """The fourteen sub-scenarios; each belongs to exactly one category."""

    COV_LFT = "COV-LFT"
    COV_RT = "COV-RT"
    COV_STR = "COV-STR"
    IPC_LFT = "IPC-LFT"
    IPC_RT = "IPC-RT"
    IPC_STR = "IPC-STR"
    YLW_LFT = "YLW-LFT"
    YLW_STR = "YLW-STR"
    UT_N = "UT-N"
    UT_AN = "UT-AN"
    STP = "STP"
    STR = "STR"
    LFT = "LFT"
    RT = "RT"

    @property
    def category(self) -> BehaviorCategory:
        """The category this sub-scenario refines."""
        return BehaviorCategory(self.value.split("-")[0])


@dataclass(frozen=True, eq=False)
class BehaviorLabel(ArrayValueEq):
    """The ego's behaviour; `source` says who decided it ('staged', 'labelled', 'imported')."""

    sub_scenario: SubScenario
    source: str

    @property
    def category(self) -> BehaviorCategory:
        return self.sub_scenario.category


@dataclass(frozen=True, eq=False)
class Conditions(ArrayValueEq):
    """Weather and lighting of a clip. `start_time_utc` is the UTC time of frame 0.

    The WGS84 origin that places the clip on Earth (for the sun and GNSS) belongs to the
    intersection and lives on `IntersectionMap.origin`.
    """

    weather: Weather
    time_of_day: TimeOfDay
    start_time_utc: datetime

    def __post_init__(self) -> None:
        if self.start_time_utc.tzinfo is None:
            raise ScenarioFormatError("conditions.start_time_utc: expected a timezone-aware time")
        object.__setattr__(self, "start_time_utc", self.start_time_utc.astimezone(timezone.utc))


TRACK_ARRAYS = (
    "x_m",
    "y_m",
    "z_m",
    "yaw_rad",
    "length_m",
    "width_m",
    "height_m",
    "vx_mps",
    "vy_mps",
)


@dataclass(frozen=True, eq=False)
class Track(ArrayValueEq):
    """One agent over the scenario timeline; every array is `(T,)` with T the scenario's frames.

    Values at frames where `valid` is False carry no meaning and are set to NaN.
    `metadata` holds source-specific facts as strings (blueprint, size source, violator flag).
    """

    track_id: str
    agent_class: AgentClass
    x_m: NDArray[np.float64]
    y_m: NDArray[np.float64]
    z_m: NDArray[np.float64]
    yaw_rad: NDArray[np.float64]
    length_m: NDArray[np.float64]
    width_m: NDArray[np.float64]
    height_m: NDArray[np.float64]
    vx_mps: NDArray[np.float64]
    vy_mps: NDArray[np.float64]
    valid: NDArray[np.bool_]
    metadata: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = f"track {self.track_id!r}"
        if not isinstance(self.track_id, str) or not self.track_id:
            raise ScenarioFormatError(
                f"track_id: expected a non-empty string, got {self.track_id!r}"
            )
        if not isinstance(self.agent_class, AgentClass):
            raise ScenarioFormatError(
                f"{where}: agent_class {self.agent_class!r} is not an AgentClass"
            )
        valid = frozen_array(self.valid, bool)
        if valid.ndim != 1:
            raise ScenarioFormatError(f"{where}: valid must be 1-D, got shape {valid.shape}")
        object.__setattr__(self, "valid", valid)
        for name in TRACK_ARRAYS:
            values = frozen_array(getattr(self, name), np.float64)
            if values.shape != valid.shape:
                raise ScenarioFormatError(
                    f"{where}: {name} has shape {values.shape}, expected {valid.shape} like valid"
                )
            bad = np.flatnonzero(valid & ~np.isfinite(values))
            if bad.size:
                raise ScenarioFormatError(
                    f"{where}: {name} is {values[bad[0]]} at frame {bad[0]}, expected a finite value"
                )
            if not valid.all():  # values at invalid frames mean nothing: store NaN there
                values = frozen_array(np.where(valid, values, np.nan), np.float64)
            object.__setattr__(self, name, values)
        for name in ("length_m", "width_m", "height_m"):
            bad = np.flatnonzero(valid & (getattr(self, name) <= 0))
            if bad.size:
                raise ScenarioFormatError(f"{where}: {name} <= 0 at frame {bad[0]}")
        object.__setattr__(self, "metadata", dict(sorted(self.metadata.items())))

    @property
    def num_frames(self) -> int:
        return int(self.valid.shape[0])

    @property
    def xy_m(self) -> NDArray[np.float64]:
        """`(T, 2)` box-centre positions in the world frame."""
        return np.stack([self.x_m, self.y_m], axis=-1)

    @property
    def speed_mps(self) -> NDArray[np.float64]:
        """`(T,)` ground speed."""
        return np.hypot(self.vx_mps, self.vy_mps)


@dataclass(frozen=True, eq=False)
class SignalTimeline(ArrayValueEq):
    """States `(T,)` of one signal (a phase group controlling one or more lanes) per frame.

    `origin` says how the states were obtained: 'measured', 'cycle_derived' or 'synthetic'.
    """

    signal_id: str
    states: NDArray[np.uint8]
    origin: str = "measured"

    def __post_init__(self) -> None:
        states = frozen_array(self.states, np.uint8)
        if states.ndim != 1:
            raise ScenarioFormatError(f"signal {self.signal_id!r}: states must be 1-D")
        known = np.isin(states, [s.value for s in SignalState])
        if not known.all():
            index = int(np.flatnonzero(~known)[0])
            raise ScenarioFormatError(
                f"signal {self.signal_id!r}: state {states[index]} at frame {index} is not one of "
                f"{[s.value for s in SignalState]}"
            )
        object.__setattr__(self, "states", states)

    def state_at(self, frame: int) -> SignalState:
        return SignalState(int(self.states[frame]))


@dataclass(frozen=True, eq=False)
class Route(ArrayValueEq):
    """The ego's route: the map lanes it drives through and waypoints `(N, 2)` in the world frame."""

    lane_ids: tuple[str, ...]
    waypoints_xy_m: NDArray[np.float64]

    def __post_init__(self) -> None:
        object.__setattr__(self, "lane_ids", tuple(self.lane_ids))
        waypoints = frozen_array(self.waypoints_xy_m, np.float64)
        if waypoints.ndim != 2 or waypoints.shape[1] != 2 or len(waypoints) < 2:
            raise ScenarioFormatError(
                f"route.waypoints_xy_m: expected (N>=2, 2), got {waypoints.shape}"
            )
        if not np.isfinite(waypoints).all():
            raise ScenarioFormatError("route.waypoints_xy_m: contains a non-finite value")
        object.__setattr__(self, "waypoints_xy_m", waypoints)


@dataclass(frozen=True, eq=False)
class Scenario(ArrayValueEq):
    """One clip: a 10 Hz timeline, its tracks and signal timelines, conditions and curation.

    `ego_id`, `route`, `behavior` and `quality` stay None until a source or curation sets them.
    `metadata` holds JSON-serialisable facts about the clip's origin (source file, seed, ...).
    """

    scenario_id: str
    map_id: str
    source: str
    t_ns: NDArray[np.int64]
    tracks: tuple[Track, ...]
    signals: tuple[SignalTimeline, ...]
    conditions: Conditions
    ego_id: str | None = None
    route: Route | None = None
    behavior: BehaviorLabel | None = None
    quality: Mapping[str, float] | None = None
    metadata: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("scenario_id", "map_id"):
            value = getattr(self, name)
            if not isinstance(value, str) or not value or "/" in value or value.startswith("."):
                raise ScenarioFormatError(f"{name}: expected a plain non-empty name, got {value!r}")
        t_ns = frozen_array(self.t_ns, np.int64)
        if t_ns.ndim != 1 or t_ns.size < 2:
            raise ScenarioFormatError(f"t_ns: expected at least 2 frames, got shape {t_ns.shape}")
        steps = np.diff(t_ns)
        if (steps <= 0).any():
            index = int(np.flatnonzero(steps <= 0)[0]) + 1
            raise ScenarioFormatError(
                f"t_ns: not strictly increasing at frame {index} ({t_ns[index - 1]} then {t_ns[index]})"
            )
        if (steps != FRAME_PERIOD_NS).any():
            index = int(np.flatnonzero(steps != FRAME_PERIOD_NS)[0]) + 1
            raise ScenarioFormatError(
                f"t_ns: step of {steps[index - 1]} ns before frame {index}, expected "
                f"{FRAME_PERIOD_NS} (10 Hz)"
            )
        object.__setattr__(self, "t_ns", t_ns)
        object.__setattr__(self, "tracks", tuple(self.tracks))
        object.__setattr__(self, "signals", tuple(self.signals))
        _check_unique("track", [t.track_id for t in self.tracks])
        _check_unique("signal", [s.signal_id for s in self.signals])
        for index, track in enumerate(self.tracks):
            if track.num_frames != t_ns.size:
                raise ScenarioFormatError(
                    f"tracks[{index}] ({track.track_id!r}): {track.num_frames} frames, "
                    f"expected {t_ns.size} like t_ns"
                )
        for index, signal in enumerate(self.signals):
            if signal.states.shape != t_ns.shape:
                raise ScenarioFormatError(
                    f"signals[{index}] ({signal.signal_id!r}): {signal.states.size} frames, "
                    f"expected {t_ns.size}"
                )
        if self.ego_id is not None and self.ego_id not in self.track_ids:
            raise ScenarioFormatError(f"ego_id: {self.ego_id!r} is not a track of the scenario")
        if self.quality is not None:
            object.__setattr__(self, "quality", dict(sorted(self.quality.items())))

    @property
    def num_frames(self) -> int:
        return int(self.t_ns.size)

    @property
    def duration_s(self) -> float:
        return (int(self.t_ns[-1]) - int(self.t_ns[0])) / 1e9

    @property
    def track_ids(self) -> list[str]:
        return [t.track_id for t in self.tracks]

    def track(self, track_id: str) -> Track:
        """The track with this id; `KeyError` naming it when absent."""
        for candidate in self.tracks:
            if candidate.track_id == track_id:
                return candidate
        raise KeyError(f"scenario {self.scenario_id!r} has no track {track_id!r}")

    def signal(self, signal_id: str) -> SignalTimeline:
        for candidate in self.signals:
            if candidate.signal_id == signal_id:
                return candidate
        raise KeyError(f"scenario {self.scenario_id!r} has no signal {signal_id!r}")

    @property
    def ego(self) -> Track | None:
        return None if self.ego_id is None else self.track(self.ego_id)

    def class_counts(self) -> dict[AgentClass, int]:
        """Number of tracks per agent class, every class listed."""
        counts = {agent_class: 0 for agent_class in AgentClass}
        for track in self.tracks:
            counts[track.agent_class] += 1
        return counts


def _check_unique(kind: str, ids: list[str]) -> None:
    seen: dict[str, int] = {}
    for index, item in enumerate(ids):
        if item in seen:
            raise ScenarioFormatError(
                f"{kind} id {item!r} at index {index} duplicates index {seen[item]}"
            )
        seen[item] = index
