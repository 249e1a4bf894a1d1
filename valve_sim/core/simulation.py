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
empty, closed valve.
"""

from dataclasses import dataclass

import numpy as np
from valve_sim.core.integrator import advance
from valve_sim.core.model import coefficients, STATE_NAMES
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

    def __getitem__(self, name):
        return self.states[:, STATE_NAMES.index(name)]


def simulate(params, scenario=Scenario(), step_size=1e-5, record_interval=1e-4):
    """
    Run a scenario with fixed-step RK4; returns Waveforms sampled every record_interval [s].

    Raises IntegrationError if the run diverges, SteadyStateError if the start fails.
    """
    record_every = max(1, int(round(record_interval / step_size)))
    steps = int(round(scenario.end_time / step_size))
    step_starts = np.arange(steps) * step_size
    # Each step holds the flow at its midpoint: exact for a step on the grid,
    # second order for a ramp.
    flows = scenario.inlet_flow(step_starts + 0.5 * step_size)
    state = steady_state(params, scenario.initial_flow)
    initial = state.copy()
    record = advance(state, flows, coefficients(params), step_size, record_every)
    sample_steps = np.arange(1, len(record) + 1) * record_every
    return Waveforms(
        time=np.concatenate([[0.0], sample_steps * step_size]),
        states=np.vstack([initial, record]),
        inlet_flow=np.concatenate([[scenario.initial_flow], flows[sample_steps - 1]]),
    )


def simulate_recorded_flow(params, time, inlet_flow, step_size=1e-5):
    """
    Run the model driven by a sampled inlet flow; returns the 8 states at the sample times.

    time [s]: increasing sample times; inlet_flow [m^3/s]: inlet_flow[i] is the flow
    over the interval (time[i-1], time[i]] that ends at sample i (valve_node's
    applied_inlet_flow; a flow meter averaging over its sample interval). The run
    starts at the exact steady state of inlet_flow[0] at time[0]. Sample intervals
    are rounded to whole steps (an error below step_size / 2 per sample, not
    accumulated). Raises IntegrationError or SteadyStateError.
    """
    time = np.asarray(time, dtype=float)
    inlet_flow = np.asarray(inlet_flow, dtype=float)
    ends = np.rint((time - time[0]) / step_size).astype(np.int64)
    counts = np.diff(ends)
    if len(time) < 2 or np.any(counts < 1):
        raise ValueError('sample times must increase by at least one step size')
    state = steady_state(params, float(inlet_flow[0]))
    states = np.empty((len(time), 8))
    states[0] = state
    record = advance(state, np.repeat(inlet_flow[1:], counts), coefficients(params), step_size, 1)
    states[1:] = record[ends[1:] - 1]
    return states
