"""Which work an idle pool worker takes once no job is waiting: what a world's set-up costs,
measured as the pool runs (`SetupCosts`), and which running unit's frames to take
(`split_order`), so that the workers end together.

Counts are in sensor frames of work (a sensor frame and the state frames up to the next): a
unit's frames are claimed one by one (`runner._Claims`), so the later part of a running unit
can go to another worker, which first sets up its world for the clip.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field

# What setting up a clip's world costs a worker, in sensor frames of its work, before a run has
# measured it (`SetupCosts`): a world on another map, its twin built, and on the map the
# worker's world shows already, only the actors replaced. With the twins' plans shared by a
# run's workers (`sim.reuse`), a later world on another map took 0.14-0.50 s and a replay
# 0.07-0.23 s on an H100 host, against 0.29 s a sensor frame at 2 Hz (`scripts/dev/bench_collect.py`,
# docs/benchmarks.md, "fifteenth session"); before, a new twin took 0.7-1.0 s there, and a prior
# of 6 frames kept the end of a 2 Hz run from being split at all (its set-ups are measured only
# as the run goes, and at 2 Hz few come before its end).
SETUP_FRAMES = 3
REPLAY_SETUP_FRAMES = 1
# a new world's first frames are slower (programs, buffers, the shadow and paint rasters): one
# sensor frame more than its set-up
FIRST_FRAMES_EXTRA = 1
# the fewest sensor frames worth splitting off: with the set-up counted in the split, any piece
# ends the run sooner; a piece of one frame would hardly be worth the world
MIN_SPLIT_SENSOR_FRAMES = 2


def sensor_frames(first: int, frames: int, sensor_every: int) -> int:
    """How many of frames `first` .. `first + frames - 1` carry sensors (multiples of
    `sensor_every`)."""
    return len(range(-(-first // sensor_every) * sensor_every, first + frames, sensor_every))


@dataclass
class SetupCosts:
    """A world's set-up in sensor frames of work, as a pool measures them: the median set-up of
    each kind (a new world, a replay), reported as each ends (`add_setup`), over the mean time
    a sensor frame took in the units ended so far (`add_unit`); `SETUP_FRAMES` and
    `REPLAY_SETUP_FRAMES` until both are known. A worker's first world is left out: it comes
    with the process's GL context and compiled programs."""

    sensor_every: int = 1
    capture_seconds: float = 0.0  # the units' time less their set-up...
    captured: int = 0  # ...over this many sensor frames
    setups: dict[bool, list[float]] = field(default_factory=lambda: {True: [], False: []})

    def add_setup(self, setup: float, new_world: bool | None) -> None:
        """A world set up in `setup` seconds; `new_world` whether the worker built a twin
        (None: the worker's first world, not counted)."""
        if new_world is not None and setup > 0.0:
            self.setups[new_world].append(setup)

    def add_unit(self, seconds: float, setup: float, first: int, frames: int) -> None:
        """A finished unit: `seconds` in all, `setup` of them its world's, `frames` from
        `first`."""
        count = sensor_frames(first, frames, self.sensor_every)
        if count:
            self.capture_seconds += seconds - setup
            self.captured += count

    def frames(self, new_world: bool) -> int:
        """A set-up of this kind, in sensor frames (its first frames' extra cost included)."""
        measured = self.setups[new_world]
        if not measured or not self.captured:
            return SETUP_FRAMES if new_world else REPLAY_SETUP_FRAMES
        per_frame = self.capture_seconds / self.captured
        extra = FIRST_FRAMES_EXTRA if new_world else 0
        return math.ceil(statistics.median(measured) / per_frame) + extra


@dataclass(frozen=True)
class Candidate:
    """A running unit an idle worker may take frames of: its claims slot, its clip, the sensor
    frames it has left, whether its worker began it, and, for a unit not begun, the sensor
    frames its worker has before it (the units ahead of it in its job) and whether it is on the
    map of the unit before it (its worker then only replaces the actors)."""

    slot: int
    scenario_id: str
    left: int
    begun: bool
    ahead: int = 0
    follows_its_map: bool = True


def split_order(
    candidates: list[Candidate],
    taker_map: str | None,
    maps: dict[str, str],
    costs: SetupCosts,
) -> list[tuple[Candidate, int]]:
    """The candidates worth taking frames of, with the taker's set-up in sensor frames, those
    that end their worker's work soonest first. A begun unit gives the taker the later half of
    what is left less its set-up, so both end together: (left - setup) / 2 sooner. A unit not
    begun goes whole: its worker then ends after the units ahead of it, the taker after its
    set-up and the unit, where the unit would have ended after its worker's set-up for it; one
    that would end later with the taker is left to its worker. A unit on the map the taker's
    world shows costs it a replay, any other a new world (`SetupCosts`)."""
    ranked = []
    for candidate in candidates:
        same = taker_map is not None and maps.get(candidate.scenario_id) == taker_map
        setup = costs.frames(new_world=not same)
        if candidate.begun:
            gain = (candidate.left - setup) // 2
        else:
            giver_setup = costs.frames(new_world=not candidate.follows_its_map)
            before = candidate.ahead + giver_setup + candidate.left
            gain = before - max(candidate.ahead, setup + candidate.left)
        if gain > 0:
            ranked.append((-gain, len(ranked), candidate, setup))
    return [(candidate, setup) for _, _, candidate, setup in sorted(ranked)]
