"""Fixed-time signal plans: per axis a through phase (with permissive or protected lefts),
each green followed by yellow and all-red; pedestrians walk beside the perpendicular through phase.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivee2e_data.scenario import SignalState
from drivee2e_data.sources.synthetic.layout import (
    Layout,
    left_signal_id,
    pedestrian_signal_id,
    through_signal_id,
)

YELLOW_S = 3.0
ALL_RED_S = 2.0
PEDESTRIAN_CLEARANCE_S = 6.0  # the walk signal flashes (yellow) this long before the phase ends


@dataclass(frozen=True)
class Phase:
    """One green interval: the signals that show green, then yellow, then an all-red gap."""

    green_signals: tuple[str, ...]
    walk_signals: tuple[str, ...]
    green_s: float


@dataclass(frozen=True)
class SignalPlan:
    phases: tuple[Phase, ...]
    offset_s: float  # plan time at sim time 0
    signal_ids: tuple[str, ...]

    @property
    def cycle_s(self) -> float:
        return sum(p.green_s + YELLOW_S + ALL_RED_S for p in self.phases)

    def states_at(self, time_s: float) -> dict[str, SignalState]:
        """Every signal's state at sim time `time_s`."""
        states = dict.fromkeys(self.signal_ids, SignalState.RED)
        t = (time_s + self.offset_s) % self.cycle_s
        for phase in self.phases:
            length = phase.green_s + YELLOW_S + ALL_RED_S
            if t < length:
                if t < phase.green_s:
                    vehicle = SignalState.GREEN
                elif t < phase.green_s + YELLOW_S:
                    vehicle = SignalState.YELLOW
                else:
                    vehicle = SignalState.RED
                for signal_id in phase.green_signals:
                    states[signal_id] = vehicle
                walk_end = phase.green_s + YELLOW_S - PEDESTRIAN_CLEARANCE_S
                walk = (
                    SignalState.GREEN
                    if t < walk_end
                    else (SignalState.YELLOW if t < phase.green_s + YELLOW_S else SignalState.RED)
                )
                for signal_id in phase.walk_signals:
                    states[signal_id] = walk
                break
            t -= length
        return states

    def timeline(self, times_s: NDArray[np.float64]) -> dict[str, NDArray[np.uint8]]:
        """States `(T,)` per signal at the given sim times."""
        table = {signal_id: np.zeros(len(times_s), np.uint8) for signal_id in self.signal_ids}
        for k, time_s in enumerate(times_s):
            for signal_id, state in self.states_at(float(time_s)).items():
                table[signal_id][k] = state.value
        return table


def make_plan(layout: Layout, rng: np.random.Generator) -> SignalPlan:
    """A fixed-time plan for the layout, with random green times and cycle offset."""
    phases = []
    signal_ids: list[str] = []
    for axis_index, axis in enumerate(layout.axes):
        others = [a for k, group in enumerate(layout.axes) if k != axis_index for a in group]
        walk = tuple(pedestrian_signal_id(a) for a in others)
        through = tuple(through_signal_id(a) for a in axis)
        phases.append(Phase(through, walk, float(rng.uniform(14.0, 20.0))))
        signal_ids.extend(through)
        if layout.protected_left[axis_index]:
            lefts = tuple(left_signal_id(a) for a in axis)
            phases.append(Phase(lefts, (), float(rng.uniform(7.0, 10.0))))
            signal_ids.extend(lefts)
    signal_ids.extend(pedestrian_signal_id(arm.index) for arm in layout.arms)
    plan = SignalPlan(tuple(phases), 0.0, tuple(signal_ids))
    return SignalPlan(plan.phases, float(rng.uniform(0.0, plan.cycle_s)), plan.signal_ids)
