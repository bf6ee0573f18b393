"""The signal that binds the ego frame by frame (`binding`), on staged routes with known answers."""

from __future__ import annotations

import numpy as np

from drivee2e_data.binding import binding_signals, front_bumper, route_stops
from drivee2e_data.hdmap import GeoOrigin, IntersectionMap, Lane, SignalHead, StopLine

HALF = np.array([0.0, 1.75, 0.0])


def _lane(lane_id: str, x0: float, x1: float, **fields) -> Lane:
    centre = np.array([[x0, 0.0, 0.0], [x1, 0.0, 0.0]])
    return Lane(lane_id, centre, centre + HALF, centre - HALF, **fields)


def _stop(stop_id: str, x: float, lane_id: str) -> StopLine:
    return StopLine(stop_id, np.array([[x, -1.75, 0.0], [x, 1.75, 0.0]]), (lane_id,))


def _heads(*signals: str) -> tuple[SignalHead, ...]:
    return tuple(
        SignalHead(f"head_{s}", s, np.array([10.0 * k, 4.0, 5.0]), np.pi)
        for k, s in enumerate(signals)
    )


def two_junctions() -> IntersectionMap:
    """East along y = 0: approach a (-50..0), junction j1 (0..12, signal s1), link b (12..40),
    junction j2 (40..52, signal s2), exit c (52..90); stop lines where a and b end, held by
    the junction lanes' signals beyond them (as most maps place them)."""
    lanes = (
        _lane("a", -50.0, 0.0, successors=("j1",)),
        _lane(
            "j1",
            0.0,
            12.0,
            is_intersection=True,
            signal_id="s1",
            predecessors=("a",),
            successors=("b",),
        ),
        _lane("b", 12.0, 40.0, predecessors=("j1",), successors=("j2",)),
        _lane(
            "j2",
            40.0,
            52.0,
            is_intersection=True,
            signal_id="s2",
            predecessors=("b",),
            successors=("c",),
        ),
        _lane("c", 52.0, 90.0, predecessors=("j2",)),
    )
    return IntersectionMap(
        "two_junctions",
        GeoOrigin(39.9, 116.4, 40.0),
        lanes,
        stop_lines=(_stop("stop_1", 0.0, "a"), _stop("stop_2", 40.0, "b")),
        signal_heads=_heads("s0", "s1", "s2"),
    )


ROUTE = ("a", "j1", "b", "j2", "c")


def test_route_stops_in_order_with_their_holding_signals():
    stops = route_stops(two_junctions(), ROUTE)
    assert [(s.stop_line_id, s.signal_ids) for s in stops] == [
        ("stop_1", ("s1",)),
        ("stop_2", ("s2",)),
    ]
    # metres along the route's centreline from its start at x = -50
    np.testing.assert_allclose([s.along_m for s in stops], [50.0, 90.0])


def test_green_through_two_junction_lights():
    """A car at 10 m/s from x = -30 to x = 70: s1 binds until its front crosses x = 0, then s2
    until x = 40, then none."""
    centre_x = np.arange(-30.0, 70.0, 1.0)  # 1 m a frame
    xy = np.stack([centre_x, np.zeros_like(centre_x)], axis=1)
    front = front_bumper(xy, np.zeros(len(xy)), 4.0)  # front = centre + 2 m
    bound = binding_signals(two_junctions(), ROUTE, front)
    expected = ["s1" if x + 2.0 < 0.0 else "s2" if x + 2.0 < 40.0 else None for x in centre_x]
    assert bound == expected
    assert bound.count("s1") == 28 and bound.count("s2") == 40 and bound.count(None) == 32


def test_red_light_stop_stays_bound():
    """Stopped 1 m short of the first line for the whole clip: s1 binds at every frame."""
    front = np.array([[-1.0, 0.0]] * 50)
    assert binding_signals(two_junctions(), ROUTE, front) == ["s1"] * 50


def test_lane_changes_and_offsets_do_not_matter():
    """The progress is the front's projection on the route: 1.5 m off the centreline reads the
    same as on it."""
    front = np.array([[-10.0, 1.5], [10.0, -1.5], [45.0, 1.0]])
    assert binding_signals(two_junctions(), ROUTE, front) == ["s1", "s2", None]


def test_signal_on_the_approach_lane_and_unsignalled_routes():
    intersection_map = two_junctions()
    lanes = list(intersection_map.lanes)
    # the signal on the approach lane itself (some maps): it holds its own stop line
    lanes[0] = _lane("a", -50.0, 0.0, successors=("j1",), signal_id="s0")
    moved = IntersectionMap(
        "approach",
        intersection_map.origin,
        tuple(lanes),
        stop_lines=intersection_map.stop_lines,
        signal_heads=intersection_map.signal_heads,
    )
    assert binding_signals(moved, ROUTE, np.array([[-5.0, 0.0]])) == ["s0"]
    # a route through lanes no stop line crosses, and a route not on the map: nothing binds
    assert binding_signals(intersection_map, ("c",), np.array([[60.0, 0.0]])) == [None]
    assert binding_signals(intersection_map, ("nowhere",), np.array([[0.0, 0.0]])) == [None]


def test_the_red_light_rule_reads_the_same_signals_as_the_label():
    """Crossing a stop line counts as running a red only when that line's holding signal (the
    one the label binds before the line) is red: the second line with s2 red and s1 green, not
    the first line's s1 once it is behind."""
    from drivee2e_data.metrics.closedloop import MapRules
    from drivee2e_data.scenario import SignalState

    rules = MapRules(two_junctions(), ROUTE)
    red_second = {"s1": SignalState.GREEN, "s2": SignalState.RED}
    red_first = {"s1": SignalState.RED, "s2": SignalState.GREEN}
    across = {1: (np.array([-0.5, 0.0]), np.array([0.5, 0.0])),
              2: (np.array([39.5, 0.0]), np.array([40.5, 0.0]))}  # fmt: skip
    assert rules.red_lights_crossed(*across[1], 0.0, red_first) == ["stop_1"]
    assert rules.red_lights_crossed(*across[1], 0.0, red_second) == []
    assert rules.red_lights_crossed(*across[2], 0.0, red_second) == ["stop_2"]
    assert rules.red_lights_crossed(*across[2], 0.0, red_first) == []
    # and the label at those moments names the signal the rule reads
    fronts = np.array([across[1][0], across[2][0]])
    assert binding_signals(two_junctions(), ROUTE, fronts) == ["s1", "s2"]
