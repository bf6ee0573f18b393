"""Contact sheets of the look: the same frames of several clips (busy ones: the most agents ahead) under day, dusk, night, rain and
fog, stacked into one image (docs/img/look_before.jpg, look_after.jpg in docs/twins.md).

    python scripts/look_sheets.py DATA --out docs/img/look_after.jpg

DATA holds the clips named in ROWS (make them with `drivee2e synth --out DATA --clips 8
--seed 0`, `drivee2e import av2 ../shared/realdata/argoverse2/sensor-log-7fab2350 --out DATA`,
`drivee2e curate DATA`). Each row is one clip's six cameras and top view under one condition.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import cv2
import numpy as np

from drivee2e_data import store
from drivee2e_data.scenario import TimeOfDay, Weather
from drivee2e_data.sensors.contact_sheet import contact_sheet, outlined_text
from drivee2e_data.sim.world import World
from drivee2e_data.sun import start_time_for

# (scenario, frame, weather, time of day): four synthetic clips and one real clip, the
# conditions a reader compares (day, dusk, night, rain, fog)
ROWS = (
    ("synth_s0_c0006", 70, Weather.CLEAR, TimeOfDay.NOON),
    ("synth_s0_c0003", 220, Weather.CLEAR, TimeOfDay.DUSK),
    ("synth_s0_c0007", 130, Weather.CLEAR, TimeOfDay.NIGHT),
    ("synth_s0_c0005", 150, Weather.RAIN, TimeOfDay.AFTERNOON),
    ("av2_sensor-log-7fab2350", 30, Weather.FOG, TimeOfDay.MORNING),
)
SCALE = 0.75  # each sheet is 1980x540 drawn, shown at this scale


def sheet_for(root: Path, scenario_id: str, frame: int, weather: Weather, time_of_day: TimeOfDay,
              renderer: str) -> np.ndarray:  # fmt: skip
    scenario = store.read_scenario(root, scenario_id)
    intersection_map = store.read_map(root, scenario.map_id)
    start = start_time_for(
        time_of_day, scenario.conditions.start_time_utc.date(), intersection_map.origin
    )
    conditions = dataclasses.replace(
        scenario.conditions, weather=weather, time_of_day=time_of_day, start_time_utc=start
    )
    scenario = dataclasses.replace(scenario, conditions=conditions)
    with World(intersection_map, scenario, renderer) as world:
        sheet = contact_sheet(world, frame)
    caption = f"{weather.value}, {time_of_day.value}"
    outlined_text(sheet, caption, (3 * 480 + 8, 48))
    return cv2.resize(sheet, None, fx=SCALE, fy=SCALE, interpolation=cv2.INTER_AREA)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--out", type=Path, required=True, help=".jpg or .png")
    parser.add_argument("--renderer", default="auto")
    parser.add_argument("--rows", type=int, nargs="*", help="only these rows (0-based)")
    args = parser.parse_args()
    chosen = [ROWS[k] for k in args.rows] if args.rows else list(ROWS)
    sheets = [sheet_for(args.data, *row, renderer=args.renderer) for row in chosen]
    image = np.concatenate(sheets, axis=0)
    parameters = [cv2.IMWRITE_JPEG_QUALITY, 85] if args.out.suffix == ".jpg" else []
    ok, encoded = cv2.imencode(args.out.suffix, image[:, :, ::-1], parameters)
    if not ok:
        raise SystemExit(f"could not encode {args.out}")
    args.out.write_bytes(encoded.tobytes())
    print(f"wrote {args.out} ({image.shape[1]}x{image.shape[0]})")


if __name__ == "__main__":
    main()
