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

A Scenario (valve_sim.core.scenario) is the paper's test: the valve at the exact steady state of
initial_flow, the inlet flow changed to final_flow at step_time (at once, or over
ramp_time), and the run ended at end_time. initial_flow = 0 starts from the
empty, closed valve.
"""

from dataclasses import dataclass

import numpy as np
from valve_sim.core.integrator import advance
from valve_sim.core.model import coefficients, STATE_NAMES
from valve_sim.core.scenario import LITRE_PER_MINUTE, Scenario  # noqa: F401 (also offered here)
from valve_sim.core.steady_state import steady_state


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
