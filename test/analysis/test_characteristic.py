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

"""The static characteristic: its analysis on arrays, the ramp test, the command, a bag."""

import json

import numpy as np
import pytest
from valve_sim.analysis.characteristic import (
    characteristic,
    CRACKING_FRACTION,
    CURVE_BASIS,
    MAIN_FLOW_BASIS,
    ramp_test,
    steady_marks,
)
from valve_sim.commands.cli import main as valve_sim
from valve_sim.core.simulation import LITRE_PER_MINUTE, ramp_flows, run_flows
from valve_sim.recording.valve_topics import write_simulation_bag


RATED = 20 * LITRE_PER_MINUTE


def _synthetic_ramp():
    """Make up a valve: pilot-only below 4 L/min, then p = 10 MPa + 0.1 MPa per 20 L/min."""
    q_up = np.linspace(0.0, RATED, 2001)
    q = np.concatenate([q_up, q_up[::-1]])
    crack_q = 4 * LITRE_PER_MINUTE
    line = 10e6 + 0.1e6 * q / RATED
    p = np.where(q < crack_q, line - 2e6 * (crack_q - q) / crack_q, line)
    falling = np.arange(len(q)) > 2000
    p = p - 5e3 * falling  # the falling ramp 5 kPa lower everywhere: a known hysteresis
    main = np.clip(q - crack_q, 0.0, None)
    return q, p, main, crack_q


def test_marks_of_a_known_curve():
    q, p, main, crack_q = _synthetic_ramp()
    marks = characteristic(p, q, RATED, main)
    assert marks.basis == MAIN_FLOW_BASIS and marks.reasons == {}
    level_q = crack_q + CRACKING_FRACTION * RATED  # where the main-stage flow reaches 1 %
    assert marks.cracking_flow == pytest.approx(level_q, rel=1e-9)
    assert marks.cracking_pressure == pytest.approx(10e6 + 0.1e6 * level_q / RATED, rel=1e-12)
    assert marks.rated_pressure == pytest.approx(10.1e6, rel=1e-12)
    assert marks.override == pytest.approx(marks.rated_pressure - marks.cracking_pressure)
    assert marks.reseat_flow == pytest.approx(level_q, rel=1e-3)
    assert marks.reseat_pressure == pytest.approx(marks.cracking_pressure - 5e3, abs=100.0)
    assert marks.hysteresis == pytest.approx(5e3, rel=1e-6)
    # Without the main-stage flow: from the curve, the first sample inside 0.1 % of the line.
    curve = characteristic(p, q, RATED)
    assert curve.basis == CURVE_BASIS
    assert curve.cracking_flow == pytest.approx(crack_q, rel=0.01)
    assert curve.reseat_flow == pytest.approx(crack_q, rel=0.01)


def test_bad_input_is_named():
    q, p, main, _ = _synthetic_ramp()
    with pytest.raises(ValueError, match='rated flow'):
        characteristic(p, q, 0.0)
    with pytest.raises(ValueError, match='finite'):
        characteristic(np.where(q > RATED / 2, np.nan, p), q, RATED)
    short = characteristic(p, q, 2 * RATED, main)  # rated flow never reached
    assert short.rated_pressure is None and 'never reaches' in short.reasons['rated_pressure']
    assert short.override is None
    closed = characteristic(p, q, RATED, np.zeros_like(q))  # the main stage never opens
    assert closed.cracking_pressure is None and closed.reseat_pressure is None
    assert closed.hysteresis is None
    assert {'cracking_pressure', 'reseat_pressure'} <= set(closed.reasons)


def test_ramp_cracking_equals_the_steady_state_solver(reference):
    """
    On a 10 s ramp each way, cracking (1 % main-stage flow) is the solver's within 0.2 %.

    From the pressure-flow curve alone (a rig's method) within 0.3 %: the curve bends
    into its override line over the first L/min after cracking (docs/characteristic.md).
    """
    _, _, marks = ramp_test(reference, RATED, RATED, 10.0, 0.5, 1e-5, 1e-3)
    steady = steady_marks(reference, RATED, RATED)
    ramp = marks['main_stage_flow']
    assert ramp.cracking_pressure == pytest.approx(steady['cracking_pressure'], rel=2e-3)
    assert ramp.rated_pressure == pytest.approx(steady['rated_pressure'], rel=2e-3)
    # The hydrostatic bearings leave no friction: the valve reseats where it cracks.
    assert ramp.reseat_pressure == pytest.approx(steady['cracking_pressure'], rel=2e-3)
    assert steady['lift_off_pressure'] < steady['cracking_pressure'] < steady['rated_pressure']
    curve = marks['pressure_flow_curve']
    assert curve.cracking_pressure == pytest.approx(steady['cracking_pressure'], rel=3e-3)


def test_command_and_bag_analysis_agree(tmp_path, capsys, reference):
    """Characteristic writes its files; analyse --characteristic on its bag finds the same."""
    out, bag = tmp_path / 'out', tmp_path / 'ramp.mcap'
    args = ['--ramp-time', '2', '--hold-time', '0.2', '--out', str(out), '--mcap', str(bag)]
    assert valve_sim(['characteristic', '--json', *args]) == 0
    report = json.loads(capsys.readouterr().out)
    for name in ('characteristic.csv', 'steady_state.csv', 'characteristic.png'):
        assert (out / name).stat().st_size > 0
    assert json.loads((out / 'characteristic.json').read_text()) == report
    assert valve_sim(['analyse', '--characteristic', '--json', str(bag)]) == 0
    from_bag = json.loads(capsys.readouterr().out)['characteristic']
    from_run = report['ramp']['pressure_flow_curve']
    assert from_bag['basis'] == CURVE_BASIS
    for name in ('cracking_pressure', 'rated_pressure', 'reseat_pressure'):
        assert from_bag[name] == pytest.approx(from_run[name], rel=1e-9), name


def test_a_missing_flow_topic_is_named(tmp_path, capsys, reference):
    """Name the missing inlet-flow topic: analyse --characteristic needs it."""
    waveforms = run_flows(reference, ramp_flows(RATED, 1.0, 0.1, 1e-5), 1e-5, 1e-3)
    bag = tmp_path / 'rig.mcap'
    write_simulation_bag(bag, waveforms, 101325.0, publish_interval=1e-3, start_time_ns=0)
    code = valve_sim(
        ['analyse', '--characteristic', str(bag), '--topic-inlet-flow', '/no_such_topic']
    )
    assert code == 1 and '/no_such_topic' in capsys.readouterr().err
