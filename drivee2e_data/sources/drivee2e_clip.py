"""The DriveE2E release's own clips: a CSV of V2X-Seq columns plus `weather`, `ori_clip_index`
and `blueprint`, a route XML naming the ego and the weather parameters, and a V2X-Seq HD map.

The CSV's weather name and the route's weather parameters become our conditions (rain or fog
from the parameters win over the name; the sun's altitude sets the time of day); each agent's
blueprint is kept in its track metadata; the CSV name's prefix (STR_000, YLW_001) is the clip's
behaviour category, kept as the label where it names a sub-scenario (STR, LFT, RT, STP).
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np

from drivee2e_data.errors import ScenarioFormatError
from drivee2e_data.hdmap import GeoOrigin
from drivee2e_data.scenario import (
    BehaviorLabel,
    Conditions,
    Scenario,
    SubScenario,
    TimeOfDay,
    Weather,
)
from drivee2e_data.sources.common import ImportReport, read_csv_rows, utc_from_ns
from drivee2e_data.sources.v2x_seq import V2XImport, map_id_of, read_hdmap, read_trajectories
from drivee2e_data.sun import start_time_for, time_of_day_of

SOURCE = "drivee2e"
EXTRA_COLUMNS = ("weather", "ori_clip_index", "blueprint")
WEATHER_NAMES = {
    "clear": Weather.CLEAR,
    "sunny": Weather.CLEAR,
    "cloudy": Weather.CLOUDY,
    "overcast": Weather.OVERCAST,
    "rain": Weather.RAIN,
    "rainy": Weather.RAIN,
    "fog": Weather.FOG,
    "foggy": Weather.FOG,
    "wet": Weather.WET,
}
RAIN_PRECIPITATION = 30.0  # CARLA precipitation (0-100) from which a clip counts as rainy
FOG_DENSITY = 30.0
WET_DEPOSITS = 30.0


def read_route(path: Path) -> dict[str, object]:
    """The first <route> of a route XML: its attributes and its first <weather> element's."""
    path = Path(path)
    if not path.is_file():
        raise ScenarioFormatError(f"{path}: file is missing")
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as error:
        raise ScenarioFormatError(f"{path}: not valid XML ({error})") from None
    route = root if root.tag == "route" else root.find("route")
    if route is None:
        raise ScenarioFormatError(f"{path}: no <route> element")
    for key in ("ego_id", "scenario_csv_id"):
        if key not in route.attrib:
            raise ScenarioFormatError(f"{path}: <route> attribute {key!r} is missing")
    weather = route.find("./weathers/weather")
    parameters = {}
    if weather is not None:
        for key, text in weather.attrib.items():
            try:
                parameters[key] = float(text)
            except ValueError:
                raise ScenarioFormatError(
                    f"{path}: <weather> attribute {key!r} is {text!r}, expected a number"
                ) from None
    return {**route.attrib, "weather": parameters}


def conditions_of(
    name: str, parameters: dict[str, float], start_ns: int, origin: GeoOrigin
) -> Conditions:
    """Our conditions from the CSV's weather name and the route's CARLA weather parameters.

    The route's sun altitude decides the time of day, and the start moves within the clip's
    UTC date so that the rendered sun earns that label at the map's origin; without a sun in
    the route, the label is the one the recorded time earns."""
    weather = WEATHER_NAMES.get(name.strip().lower(), Weather.CLEAR)
    if parameters.get("fog_density", 0.0) >= FOG_DENSITY:
        weather = Weather.FOG
    elif parameters.get("precipitation", 0.0) >= RAIN_PRECIPITATION:
        weather = Weather.RAIN
    elif weather == Weather.CLEAR and parameters.get("precipitation_deposits", 0.0) >= WET_DEPOSITS:
        weather = Weather.WET
    altitude = parameters.get("sun_altitude_angle")
    azimuth = parameters.get("sun_azimuth_angle", 0.0)
    start = utc_from_ns(start_ns)
    if altitude is None:
        return Conditions(weather, time_of_day_of(start, origin), start)
    if altitude < 0:
        time_of_day = TimeOfDay.NIGHT
    elif altitude < 15:
        time_of_day = TimeOfDay.EARLY_MORNING if azimuth < 180 else TimeOfDay.DUSK
    elif altitude < 45:
        time_of_day = TimeOfDay.MORNING if azimuth < 180 else TimeOfDay.AFTERNOON
    else:
        time_of_day = TimeOfDay.NOON
    return Conditions(weather, time_of_day, start_time_for(time_of_day, start.date(), origin))


def import_clip(clip_csv: Path, route_xml: Path, hdmap: Path) -> V2XImport:
    """One DriveE2E clip with its route and its intersection's map."""
    clip_csv, route_xml = Path(clip_csv), Path(route_xml)
    report = ImportReport()
    route = read_route(route_xml)
    _, first = read_csv_rows(clip_csv, ["intersect_id", *EXTRA_COLUMNS])
    map_id = map_id_of(first[0]["intersect_id"])
    intersection_map = read_hdmap(hdmap, map_id, report=report)
    offset = np.asarray(intersection_map.metadata["offset_m"])
    grid, tracks, extra = read_trajectories(clip_csv, offset, report, EXTRA_COLUMNS)
    ego_id = str(route["ego_id"])
    if ego_id not in {t.track_id for t in tracks}:
        raise ScenarioFormatError(
            f"{route_xml}: ego_id {ego_id!r} is not a track of {clip_csv.name}"
        )
    csv_id = str(route["scenario_csv_id"])
    prefix = csv_id.split("_")[0].upper()
    label = None
    if prefix in {s.value for s in SubScenario}:
        label = BehaviorLabel(SubScenario(prefix), "imported")
    scenario = Scenario(
        scenario_id=f"drivee2e_{csv_id}",
        map_id=map_id,
        source=SOURCE,
        t_ns=grid,
        tracks=tuple(tracks),
        signals=(),
        conditions=conditions_of(
            extra["weather"], route["weather"], int(grid[0]), intersection_map.origin
        ),
        ego_id=ego_id,
        behavior=label,
        metadata={
            "clip_csv": clip_csv.name,
            "route": {k: v for k, v in route.items() if k != "weather"},
            "weather_parameters": route["weather"],
            "weather_name": extra["weather"],
            "imported_category": prefix,
            "ori_clip_index": extra["ori_clip_index"],
        },
    )
    return V2XImport(intersection_map, scenario, report)
