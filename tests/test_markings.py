"""Markings derived for maps that give centre lines and no paint (V2X-Seq, DriveE2E)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from drivee2e_data.hdmap import GeoOrigin, Lane, LaneMark, MarkColour, MarkPattern
from drivee2e_data.sources import v2x_seq
from drivee2e_data.sources.markings import derive_markings
from drivee2e_data.sources.synthetic import make_site
from tests.factories import small_map
from tests.test_import_v2x import write_hdmap

DASHED = LaneMark(MarkPattern.DASHED, MarkColour.WHITE)
SOLID = LaneMark(MarkPattern.SOLID, MarkColour.WHITE)


def _lane(lane_id: str, y: float, eastbound: bool) -> Lane:
    x = np.array([-60.0, 60.0]) if eastbound else np.array([60.0, -60.0])
    centre = np.column_stack([x, [y, y], [0.0, 0.0]])
    left = np.array([0.0, 1.75 if eastbound else -1.75, 0.0])
    return Lane(lane_id, centre, centre + left, centre - left)


def _road(origin: GeoOrigin):
    """Two eastbound lanes (E0 by the centre line, E1 outside it) and one westbound lane."""
    lanes = (_lane("E0", -1.75, True), _lane("E1", -5.25, True), _lane("W0", 1.75, False))
    return small_map(lanes=lanes, signal_heads=(), origin=origin)


@pytest.mark.parametrize(
    "origin, opposing",
    [(GeoOrigin(39.9, 116.4), MarkColour.YELLOW), (GeoOrigin(48.1, 11.6), MarkColour.WHITE)],
)
def test_each_side_is_painted_after_what_lies_beyond_it(origin, opposing):
    derived = derive_markings(_road(origin))
    double = LaneMark(MarkPattern.DOUBLE_SOLID, opposing)
    marks = {lane.lane_id: (lane.left_mark, lane.right_mark) for lane in derived.lanes}
    assert marks == {
        "E0": (double, DASHED),  # opposing traffic on the left, a lane the same way on the right
        "E1": (DASHED, SOLID),  # the road's edge on the right
        "W0": (double, SOLID),
    }
    assert derived.metadata["markings"].startswith("derived")


@pytest.mark.parametrize("site_index", [0, 1, 2, 3])
def test_synthetic_paint_is_recovered_from_centre_lines_alone(site_index):
    """The synthetic sites paint by the same convention: strip every mark and stop line, derive
    them again, and the marks come back exactly; every signal-controlled approach lane gets a
    stop line at its end."""
    original = make_site(0, site_index).intersection_map
    bare = replace(
        original,
        lanes=tuple(
            replace(lane, left_mark=LaneMark(), right_mark=LaneMark()) for lane in original.lanes
        ),
        stop_lines=(),
    )
    signalised = {lane.lane_id for lane in original.lanes if lane.signal_id}
    controlled = [  # approach lanes whose movements a signal controls
        lane.lane_id
        for lane in original.lanes
        if not lane.is_intersection and signalised & set(lane.successors)
    ]
    derived = derive_markings(bare, controlled)
    for before, after in zip(original.lanes, derived.lanes, strict=True):
        assert (after.left_mark, after.right_mark) == (before.left_mark, before.right_mark), (
            before.lane_id
        )
    assert not any(
        lane.left_mark.pattern != MarkPattern.NONE for lane in derived.lanes if lane.is_intersection
    )
    stopped = {lane_id for line in derived.stop_lines for lane_id in line.lane_ids}
    assert controlled and stopped == set(controlled)
    assert all(line.derived for line in derived.stop_lines)


def test_a_v2x_seq_map_gets_its_paint_derived(tmp_path: Path):
    write_hdmap(tmp_path / "hdmap4.json")
    intersection_map = v2x_seq.read_hdmap(tmp_path / "hdmap4.json", "v2x_test")
    assert intersection_map.metadata["markings"].startswith("derived")
    assert (intersection_map.lane("1").left_mark, intersection_map.lane("1").right_mark) == (
        SOLID,
        SOLID,
    )
    assert intersection_map.lane("3").left_mark == LaneMark()  # the junction stays unpainted
    # lane 1 is signal-controlled but the map's stop line 7 already stands at its end
    assert [line.stop_line_id for line in intersection_map.stop_lines] == ["stop_7"]
