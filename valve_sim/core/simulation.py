# Copyright 2026 valve_sim developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Offline runs of the valve model: an inlet-flow scenario in, sampled waveforms out.

A Scenario is the paper's test: the valve at the exact steady state of
initial_flow, the inlet flow changed to final_flow at step_time (at once, or over
ramp_time), and the run ended at end_time. initial_flow = 0 starts from the
empty, closed valve. Faults (a FaultSet) hold from the start; a fault schedule
(valve_sim.core.fault_schedule) changes them at the ticks valve_node would.
"""

from dataclasses import dataclass, field

import numpy as np
from valve_sim.core.fault_schedule import tick_index
from valve_sim.core.faults import FAULT_NAMES, HEALTHY
from valve_sim.core.integrator import advance
from valve_sim.core.model import coefficients, STATE_NAMES, X_DOT
from valve_sim.core.parameters import ParameterError
from valve_sim.core.steady_state import steady_state


LITRE_PER_MINUTE = 1e-3 / 60.0  # [m^3/s]


@dataclass(frozen=True)
class Scenario:
    """Inlet-flow step test. Flows in m^3/s, times in s."""

    initial_flow: float = 5.0 * LITRE_PER_MINUTE
    final_flow: float = 20.0 * LITRE_PER_MINUTE
    step_time: float = 0.25
    end_time: float = 1.25
    ramp_time: float = 0.0

    def inlet_flow(self, t):
        """q_in(t) [m^3/s] (vectorised)."""
        t = np.asarray(t, dtype=float)
        if self.ramp_time > 0.0:
            progress = np.clip((t - self.step_time) / self.ramp_time, 0.0, 1.0)
        else:
            progress = (t >= self.step_time).astype(float)
        return self.initial_flow + (self.final_flow - self.initial_flow) * progress


@dataclass
class Waveforms:
    """
    Sampled run: time [s], states (rows of the 8 model states, SI), and inlet flow.

    inlet_flow [m^3/s] is the flow applied over the interval that ends at each sample.
    """

    time: np.ndarray
    states: np.ndarray
    inlet_flow: np.ndarray
    events: list = field(default_factory=list)  # [(time [s], {name: value})] applied

    def __getitem__(self, name):
        return self.states[:, STATE_NAMES.index(name)]


def apply_faults(state, faults, changes):
    """
    Return the FaultSet after the fault parameters in changes; state updated in place.

    A main valve that becomes stuck stops where it is: its velocity becomes zero.
    """
    new = faults.changed({n: v for n, v in changes.items() if n in FAULT_NAMES})
    if new.main_valve_stuck and not faults.main_valve_stuck:
        state[X_DOT] = 0.0
    return new


def _event_steps(schedule, steps, step_size, record_every, tick_interval):
    """[(step index, changes)] of the schedule's events, at their ticks, within the run."""
    tick_steps = int(round(tick_interval / step_size))
    if schedule and (
        tick_steps < 1
        or abs(tick_steps * step_size - tick_interval) > 1e-9 * tick_interval
        or tick_steps % record_every
    ):
        raise ParameterError(
            f'a fault schedule needs the tick interval ({tick_interval:g} s) to be a whole '
            f'multiple of the step size ({step_size:g} s) and of the record interval'
        )
    tick_ns = int(round(tick_interval * 1e9))
    grouped = {}
    for event in schedule:
        k = tick_index(event.time_ns, tick_ns) * tick_steps
        if k <= steps:
            grouped.setdefault(k, {}).update(event.changes)
    return sorted(grouped.items())


def simulate(
    params,
    scenario=Scenario(),
    step_size=1e-5,
    record_interval=1e-4,
    faults=HEALTHY,
    schedule=(),
    tick_interval=1e-3,
):
    """
    Run a scenario with fixed-step RK4; returns Waveforms sampled every record_interval [s].

    faults: FaultSet from the start (the start is its steady state); schedule: FaultEvents,
    each applied at the first tick (every tick_interval [s], valve_node's publish period)
    at or after its time. Waveforms.events lists what was applied when (sensor settings
    included, for the sensor stage). Raises IntegrationError if the run diverges,
    SteadyStateError if the start fails, ParameterError for a bad fault or tick interval.
    """
    record_every = max(1, int(round(record_interval / step_size)))
    steps = int(round(scenario.end_time / step_size))
    step_starts = np.arange(steps) * step_size
    # Each step holds the flow at its midpoint: exact for a step on the grid,
    # second order for a ramp.
    flows = scenario.inlet_flow(step_starts + 0.5 * step_size)
    state = steady_state(params, scenario.initial_flow, faults)
    initial = state.copy()
    records, events, start = [], [], 0
    for stop, changes in _event_steps(schedule, steps, step_size, record_every, tick_interval):
        records.append(
            advance(
                state,
                flows[start:stop],
                coefficients(params, faults),
                step_size,
                record_every,
                start * step_size,
            )
        )
        faults = apply_faults(state, faults, changes)
        if stop == 0:
            initial = state.copy()
        elif len(records[-1]):
            records[-1][-1] = state  # the tick's sample shows the state after the event
        events.append((stop * step_size, changes))
        start = stop
    records.append(
        advance(
            state,
            flows[start:],
            coefficients(params, faults),
            step_size,
            record_every,
            start * step_size,
        )
    )
    record = np.vstack(records)
    sample_steps = np.arange(1, len(record) + 1) * record_every
    return Waveforms(
        time=np.concatenate([[0.0], sample_steps * step_size]),
        states=np.vstack([initial, record]),
        inlet_flow=np.concatenate([[scenario.initial_flow], flows[sample_steps - 1]]),
        events=events,
    )
