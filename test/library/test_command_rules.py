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
What the commands give, from the library: the rules simulate and calibrate apply, tested here.

simulate's report of a run (steps.simulated_step.measure_run: no measures after an
overpressure halt), the interval its MCAP publishes at (valve_topics.publish_interval_for),
and calibrate's cut of a recording to the rows where every signal exists
(signal_reader.from_every_signal) and its target (RecordingTarget.from_recording).
"""

from pathlib import Path

import numpy as np
import pytest
from valve_sim.analysis.calibration.targets import RecordingTarget
from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures
from valve_sim.analysis.steps.simulated_step import measure_run
from valve_sim.core.errors import CalibrationError
from valve_sim.core.flow_step import FlowStep
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import simulate
from valve_sim.recording.signal_reader import from_every_signal, read_recording, Recording
from valve_sim.recording.valve_topics import publish_interval_for

BAGS = Path(__file__).resolve().parents[2] / 'bags'
STEP = FlowStep(step_time=0.05, end_time=0.25)


def test_a_run_halted_at_an_overpressure_has_no_measures_and_says_when():
    params = {**load_parameters().params, 'burst_pressure': 7.1e6}  # below the step's peak
    waveforms = simulate(params, STEP, record_interval=1e-4, halt_on_overpressure=True)
    assert waveforms.halted
    run = measure_run(params, waveforms, STEP)
    halted_at = waveforms.halted[0]
    assert run.measures.values == dict.fromkeys(MEASURE_NAMES)
    assert all(f't = {halted_at:.6f} s' in why for why in run.measures.reasons.values())
    assert run.measures.details['overpressure']['t'] == halted_at
    assert run.alarms == [] and run.measures.details['invariant_alarms'] == []


def test_a_healthy_run_has_the_step_measures_of_its_waveforms():
    params = load_parameters().params
    waveforms = simulate(params, STEP, record_interval=1e-4, halt_on_overpressure=True)
    run = measure_run(params, waveforms, STEP)
    direct = step_measures(waveforms.time, waveforms['supply_pressure'],
                           waveforms['main_valve_displacement'], STEP.step_time, 1)
    assert run.measures.values == direct.values and run.measures.values['T_1_ms'] > 0
    assert not (run.faulty or run.above_tank)
    assert 'overpressure' not in run.measures.details


@pytest.mark.parametrize('record_interval, published', [
    (1e-4, 1e-3), (1e-3, 1e-3), (5e-4, 1e-3), (3e-4, 3e-4), (2e-3, 2e-3),
])
def test_an_offline_bag_publishes_at_valve_nodes_tick_where_the_samples_allow(
    record_interval, published
):
    assert publish_interval_for(record_interval) == published


def recording(main_valve):
    rows = len(main_valve)
    time = np.arange(rows) * 1e-3
    return Recording(time, np.full(rows, 7e6), np.asarray(main_valve, dtype=float),
                     np.full(rows, np.nan), np.full(rows, 1e-4),
                     tank_pressure=np.arange(rows, dtype=float))


def test_a_recording_is_cut_to_the_rows_where_every_signal_exists():
    late = recording([np.nan] * 3 + [1e-5] * 7)
    cut, note = from_every_signal(late, {'main_valve': '/joint_states'})
    assert len(cut.time) == 7 and cut.time[0] == late.time[3]
    assert list(cut.tank_pressure) == list(late.tank_pressure[3:])  # every array alike
    assert '/joint_states' in note and 'first 3 samples dropped' in note
    whole = recording([1e-5] * 10)
    assert from_every_signal(whole) == (whole, None)
    no_valve = recording([np.nan] * 10)  # a rig without a position sensor: nothing to wait for
    assert from_every_signal(no_valve) == (no_valve, None)
    flowless = recording([1e-5] * 10)
    flowless.inlet_flow[:] = np.nan
    with pytest.raises(CalibrationError, match='every mapped signal'):
        from_every_signal(flowless)


def test_a_recordings_target_counts_time_from_its_first_row():
    bag = read_recording(BAGS / 'reference_step.mcap')
    target = RecordingTarget.from_recording(from_every_signal(bag)[0], 1e-5)
    assert target.time[0] == 0.0 and len(target.time) == len(bag.time)
    assert target.time[-1] == pytest.approx(bag.time[-1] - bag.time[0])
