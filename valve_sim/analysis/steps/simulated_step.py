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
The measures of a simulated flow step, as `valve-sim simulate` reports them.

measure_run() takes the waveforms of core.simulation.simulate() and gives the six
measures on p_s - p_t (p_s itself with the tank at ambient) with the rules a run's
report follows: the tank's details when it is above ambient, reasons that name the
faults, no measures for a run halted at an overpressure (and why), and the run's
invariant alarms (core.invariants). Python users get what the command prints.
"""

from dataclasses import dataclass, field

import numpy as np
from valve_sim.analysis.steps.measure_windows import MEASURE_NAMES
from valve_sim.analysis.steps.measures import step_measures, StepMeasures
from valve_sim.analysis.steps.step_analysis import tank_details
from valve_sim.core.faults import HEALTHY


@dataclass
class MeasuredRun:
    """
    A simulated flow step's measures and what the report says about the run.

    measures: StepMeasures (details.invariant_alarms, details.overpressure when halted);
    alarms: core.invariants alarms of the run ([] when halted); faulty: faults from the
    start or a fault schedule's events were applied; above_tank: the tank's pressure is
    not ambient somewhere in the run (the measures are of p_s - p_t).
    """

    measures: StepMeasures
    alarms: list = field(default_factory=list)
    faulty: bool = False
    above_tank: bool = False


def measure_run(params, waveforms, flow_step, faults=HEALTHY, schedule_source=None):
    """
    Return the MeasuredRun of a simulated flow step.

    params: the run's parameters; waveforms: simulate()'s (halted when it stopped at an
    overpressure); flow_step: its core.flow_step.FlowStep; faults: the FaultSet from the
    start; schedule_source: the fault schedule's file when one applied events (named in
    the reasons). A halted run has every measure None, the reason naming the time, and
    details.overpressure {t, message}: the model held its last good state from there, as
    valve_node does, so the waveforms after it are not a response.
    """
    from valve_sim.core.simulation import simulate_alarms  # numba: when a run is measured

    direction = 1 if flow_step.final_flow >= flow_step.initial_flow else -1
    measures = step_measures(
        waveforms.time,
        waveforms['supply_pressure'] - waveforms.tank_pressure,
        waveforms['main_valve_displacement'],
        flow_step.step_time,
        direction,
    )
    above_tank = bool(np.any(waveforms.tank_pressure != 0.0))
    if above_tank:
        measures.details.update(
            tank_details(waveforms.time, waveforms.tank_pressure, flow_step.step_time)
        )
    faulty = bool(faults.active() or waveforms.events)
    if faulty:
        cause = '; '.join(
            [f'faults from the start: {faults.describe()}'] * bool(faults.active())
            + [f'fault schedule {schedule_source}'] * bool(schedule_source)
        )
        measures.reasons = {name: f'{why} ({cause})' for name, why in measures.reasons.items()}
    if waveforms.halted:
        halted_at, why = waveforms.halted
        overpressure = (
            f'OVERPRESSURE at t = {halted_at:.6f} s: {why} The model halts there, as '
            'valve_node does: it holds its last good state to the end of the run, and '
            f"supply_pressure is reported at burst_pressure = {params['burst_pressure']:g} Pa "
            '(gauge), the limit it passed'
        )
        measures.values = dict.fromkeys(MEASURE_NAMES)
        measures.reasons = dict.fromkeys(
            MEASURE_NAMES,
            f'the run halted at an overpressure at t = {halted_at:.6f} s '
            '(details.overpressure; stderr)',
        )
        measures.details['overpressure'] = {'t': halted_at, 'message': overpressure}
    alarms = [] if waveforms.halted else simulate_alarms(params, waveforms, faults)
    measures.details['invariant_alarms'] = [alarm.as_dict() for alarm in alarms]
    return MeasuredRun(measures, alarms, faulty, above_tank)
