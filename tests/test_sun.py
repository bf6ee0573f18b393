from datetime import date, datetime, timezone

import pytest

from drivee2e_data.hdmap import GeoOrigin
from drivee2e_data.scenario import Conditions, TimeOfDay, Weather
from drivee2e_data.sun import start_time_for, sun_position, time_of_day_of
from tests.factories import assert_sun_matches_label

PLACES = {
    "beijing": GeoOrigin(39.9, 116.4),
    "boston": GeoOrigin(42.34, -71.06),
    "singapore": GeoOrigin(1.29, 103.78),
    "null island": GeoOrigin(0.0, 0.0),
    "oslo": GeoOrigin(59.9, 10.75),
}


def test_noon_at_greenwich_is_half_past_twelve_utc():
    start = start_time_for(TimeOfDay.NOON, date(2020, 1, 1), PLACES["null island"])
    assert start == datetime(2020, 1, 1, 12, 30, tzinfo=timezone.utc)
    # Beijing lies 116.4 deg east: local solar midnight is 7 h 45.6 min before UTC midnight.
    night = start_time_for(TimeOfDay.NIGHT, date(2026, 6, 1), PLACES["beijing"])
    assert night == datetime(2026, 5, 31, 16, 14, tzinfo=timezone.utc)


@pytest.mark.parametrize("place", sorted(PLACES))
@pytest.mark.parametrize("day", [date(2026, 3, 20), date(2026, 6, 21), date(2026, 12, 21)])
@pytest.mark.parametrize("label", list(TimeOfDay))
def test_the_start_for_a_label_earns_that_label(place, day, label):
    origin = PLACES[place]
    start = start_time_for(label, day, origin)
    high = (TimeOfDay.MORNING, TimeOfDay.NOON, TimeOfDay.AFTERNOON)
    if place == "oslo" and day.month == 12 and label in high:
        # the midwinter sun stays below 7 degrees in Oslo: only a low sun is to be had
        assert time_of_day_of(start, origin) in (TimeOfDay.EARLY_MORNING, TimeOfDay.DUSK)
        return
    if place == "oslo" and day.month == 6 and label == TimeOfDay.NIGHT:
        # midsummer at 60 N: the sun never sinks 4 degrees below the horizon
        assert sun_position(start, origin)[1] < 0
        return
    assert time_of_day_of(start, origin) == label
    assert_sun_matches_label(Conditions(Weather.CLEAR, label, start), origin)


def test_the_label_follows_the_sun_not_the_clock():
    beijing = PLACES["beijing"]
    # 06:00 Beijing time in June is after sunrise; in December it is dark
    assert time_of_day_of(datetime(2026, 6, 21, 22, 0, tzinfo=timezone.utc), beijing) == (
        TimeOfDay.EARLY_MORNING
    )
    assert time_of_day_of(datetime(2026, 12, 21, 22, 0, tzinfo=timezone.utc), beijing) == (
        TimeOfDay.NIGHT
    )
