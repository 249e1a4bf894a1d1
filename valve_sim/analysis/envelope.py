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
The valve across its operating envelope: every step or ramp must end where the physics says.

A run starts at the steady state of the initial flow (or from the empty, closed
valve for 0), changes the flow to the final one at STEP_TIME (at once or as a ramp)
and lasts until the valve has had time to fill V_s up to the preset and settle.
Its outcome:
  relieves        ends within 1 % of the steady state of the final flow, main stage open
                  (near the cracking flow it may still be approaching it slowly)
  pilot relieves  the same, with the main valve shut: the pilot passes the whole flow
  closed          final flow 0: the main valve shut, p_s not above the preset (the
                  poppet may still be closing: V_s drains through the pilot ever slower)
  stalled         ends anywhere else (another branch, still far from the steady state)
  diverged        the integration broke down (IntegrationError)
valve-sim's own measures say, with a reason, where a run has no step response.
"""

from dataclasses import dataclass

import numpy as np
from valve_sim.analysis.measures import step_measures
from valve_sim.core.errors import IntegrationError, SteadyStateError
from valve_sim.core.model import P_S, X
from valve_sim.core.simulation import Scenario, simulate
from valve_sim.core.steady_state import steady_state, with_preset_pressure


STEP_TIME = 0.1  # [s]
SETTLE_TIME = 1.0  # [s] after the flow change (the measures' window)
END_TOLERANCE = 0.01  # p_s at the end within 1 % of the steady state
GOOD = ('relieves', 'pilot relieves', 'closed')


@dataclass
class EnvelopeRun:
    """One run of the envelope and what became of it (pressures gauge, Pa; flows m^3/s)."""

    preset_pressure: float
    initial_flow: float
    final_flow: float
    ramp_time: float
    outcome: str
    end_pressure: float = float('nan')
    steady_pressure: float = float('nan')
    measures: dict = None
    message: str = ''

    @property
    def good(self):
        return self.outcome in GOOD


def filling_time(params, preset_pressure, flow):
    """Time [s] the inlet flow needs to compress V_s from 0 to 1.2 x the preset."""
    return params['supply_volume'] / params['bulk_modulus'] * 1.2 * preset_pressure / flow


def envelope_run(params, preset_pressure, initial_flow, final_flow, ramp_time=0.0,
                 step_size=1e-5):
    """Run one case of the envelope with the preload set for preset_pressure [Pa]."""
    run = EnvelopeRun(preset_pressure, initial_flow, final_flow, ramp_time, 'stalled')
    case = with_preset_pressure(params, preset_pressure)
    fill = filling_time(case, preset_pressure, final_flow) if final_flow > 0.0 else 0.0
    end_time = STEP_TIME + ramp_time + SETTLE_TIME + (fill if initial_flow == 0.0 else 0.0)
    scenario = Scenario(initial_flow, final_flow, STEP_TIME, end_time, ramp_time)
    try:
        waveforms = simulate(case, scenario, step_size, 1e-4)
    except IntegrationError as error:
        run.outcome, run.message = 'diverged', str(error)
        return run
    direction = 1 if final_flow >= initial_flow else -1
    run.measures = step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        STEP_TIME,
        direction,
    ).as_dict()
    settled = waveforms.time >= end_time - 0.05
    end = waveforms.states[-1]
    run.end_pressure = float(np.mean(waveforms.states[settled, P_S]))
    if final_flow == 0.0:
        if end[X] <= 0.0 and run.end_pressure <= 1.001 * preset_pressure:
            run.outcome = 'closed'
        else:
            run.message = 'flow stopped, but the valve did not close'
        return run
    try:
        steady = steady_state(case, final_flow)
    except SteadyStateError as error:
        run.message = str(error)
        return run
    run.steady_pressure = float(steady[P_S])
    error = abs(run.end_pressure / run.steady_pressure - 1.0)
    if error <= END_TOLERANCE:
        run.outcome = 'relieves' if end[X] > 0.0 else 'pilot relieves'
    else:
        run.message = (
            f'ends at p_s = {run.end_pressure:.6g} Pa, {error:.1%} from the steady state '
            f'{run.steady_pressure:.6g} Pa'
        )
    return run
