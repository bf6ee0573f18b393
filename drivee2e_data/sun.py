"""The sun, the one source of truth for a clip's time of day: where it stands for a UTC time
and a WGS84 origin, the time-of-day label that position earns, and the start time that earns
a given label on a given day (for sources that record no clock time).

A label and a rendering therefore never disagree: the renderer lights the scene from
`sun_position(start_time_utc, origin)`, and every importer labels with `time_of_day_of` or sets
the start with `start_time_for`.
"""

from __future__ import annotations

import math
from datetime import date, datetime, timedelta, timezone

from drivee2e_data.hdmap import GeoOrigin
from drivee2e_data.scenario import TimeOfDay

NIGHT_BELOW_RAD = math.radians(-4.0)  # the renderer switches to street lights below this
LOW_SUN_BELOW_RAD = math.radians(15.0)  # early morning and dusk: a low, warm sun
# Local mean solar hours that earn the high-sun labels (bins of `TimeOfDay.from_local_hour`).
SOLAR_HOUR_OF = {TimeOfDay.MORNING: 9.0, TimeOfDay.NOON: 12.5, TimeOfDay.AFTERNOON: 15.5}
LOW_SUN_TARGET_DEG = 6.0  # early morning / dusk: the sun this high
HIGH_SUN_TARGET_DEG = 16.0  # morning / afternoon: at least this high, where the day allows


def sun_position(time_utc: datetime, origin: GeoOrigin) -> tuple[float, float]:
    """(azimuth clockwise from north, elevation) of the sun in radians, by the usual
    declination / equation-of-time approximation (about a degree of error)."""
    day = time_utc.timetuple().tm_yday
    hours = time_utc.hour + time_utc.minute / 60 + time_utc.second / 3600
    gamma = 2 * math.pi / 365 * (day - 1 + (hours - 12) / 24)
    equation_of_time_min = 229.18 * (0.000075 + 0.001868 * math.cos(gamma) - 0.032077 * math.sin(gamma)
                                     - 0.014615 * math.cos(2 * gamma) - 0.040849 * math.sin(2 * gamma))  # fmt: skip
    declination = (0.006918 - 0.399912 * math.cos(gamma) + 0.070257 * math.sin(gamma)
                   - 0.006758 * math.cos(2 * gamma) + 0.000907 * math.sin(2 * gamma))  # fmt: skip
    solar_minutes = hours * 60 + equation_of_time_min + 4 * origin.longitude_deg
    hour_angle = math.radians(solar_minutes / 4 - 180)
    latitude = math.radians(origin.latitude_deg)
    cos_zenith = math.sin(latitude) * math.sin(declination) + math.cos(latitude) * math.cos(
        declination
    ) * math.cos(hour_angle)
    zenith = math.acos(max(-1.0, min(1.0, cos_zenith)))
    azimuth = (
        math.atan2(
            math.sin(hour_angle),
            math.cos(hour_angle) * math.sin(latitude) - math.tan(declination) * math.cos(latitude),
        )
        + math.pi
    )
    return azimuth % (2 * math.pi), math.pi / 2 - zenith


def solar_hour(time_utc: datetime, longitude_deg: float) -> float:
    """Local mean solar time in hours, [0, 24)."""
    hours = time_utc.hour + time_utc.minute / 60 + time_utc.second / 3600
    return (hours + longitude_deg / 15.0) % 24.0


def time_of_day_of(time_utc: datetime, origin: GeoOrigin) -> TimeOfDay:
    """The label the sun earns: night below -4 degrees (where the renderer lights streets),
    early morning or dusk for a low sun (below 15 degrees, before or after solar noon),
    otherwise morning, noon or afternoon by the local solar hour."""
    _, elevation = sun_position(time_utc, origin)
    hour = solar_hour(time_utc, origin.longitude_deg)
    if elevation < NIGHT_BELOW_RAD:
        return TimeOfDay.NIGHT
    if elevation < LOW_SUN_BELOW_RAD:
        return TimeOfDay.EARLY_MORNING if hour < 12.0 else TimeOfDay.DUSK
    label = TimeOfDay.from_local_hour(hour)
    return label if label in SOLAR_HOUR_OF else TimeOfDay.NOON


def start_time_for(time_of_day: TimeOfDay, day: date, origin: GeoOrigin) -> datetime:
    """A UTC time on `day` (local solar date) whose sun earns `time_of_day` at `origin`, to the
    minute: for morning and afternoon, the solar hour of the label (9:00, 15:30) or, where the
    sun is still low then, the nearest time inside the label's bin that it stands 16 degrees up;
    solar 12:30 for noon; the sun 6 degrees up, rising or setting, for early morning and dusk;
    solar midnight for night. Where the sun never reaches such a place that day (polar day or
    night, a midwinter morning far north), the nearest the day allows."""
    midnight = datetime(day.year, day.month, day.day, tzinfo=timezone.utc) - timedelta(
        hours=origin.longitude_deg / 15.0
    )

    def at(solar_minutes: int) -> datetime:
        return (midnight + timedelta(minutes=solar_minutes)).replace(second=0, microsecond=0)

    def first(minutes: range, elevation_deg: float) -> int | None:
        target = math.radians(elevation_deg)
        return next((m for m in minutes if sun_position(at(m), origin)[1] >= target), None)

    if time_of_day == TimeOfDay.NIGHT:
        return at(0)
    if time_of_day == TimeOfDay.NOON:
        return at(round(SOLAR_HOUR_OF[TimeOfDay.NOON] * 60))
    if time_of_day == TimeOfDay.MORNING:
        minute = first(range(9 * 60, 11 * 60), HIGH_SUN_TARGET_DEG)
        return at(11 * 60 - 1 if minute is None else minute)
    if time_of_day == TimeOfDay.AFTERNOON:
        minute = first(range(15 * 60 + 30, 14 * 60, -1), HIGH_SUN_TARGET_DEG)
        return at(14 * 60 if minute is None else minute)
    rising = time_of_day == TimeOfDay.EARLY_MORNING
    minutes = range(0, 12 * 60) if rising else range(24 * 60 - 1, 12 * 60, -1)
    minute = first(minutes, LOW_SUN_TARGET_DEG)  # from midnight towards noon
    return at(12 * 60 if minute is None else minute)
