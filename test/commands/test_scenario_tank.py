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
A scenario's tank_pressure input (issue 30): the runner drives the valve's second port.

A back-pressure step from 0 to 5 bar (gauge) under a constant inlet flow, run as a
user types it: the recorded supply pressure is the offline simulate() given the same
TankPressure step, tick by tick, and the bag holds the tank pressure as sent (absolute,
stamped with each tick's start) and as applied. Malformed tank entries are in
test_scenario.MALFORMED (one line naming the key).
"""

import json
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import FluidPressure
from valve_sim.analysis.scenarios.bench_scenario import load_scenario
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import (
    FlowStep, LITRE_PER_MINUTE, RELIEF_COLUMNS, relief_flows, simulate, TankPressure
)
from valve_sim.recording.bag import BagReader
from valve_sim.recording.tick_bags import tick_series


RUN_TIMEOUT = 600.0  # [s] node start-up on a loaded machine, then 0.3 s of model time
START_NS = 1_000_000_000  # lockstep.START_NS: the first tick's /clock
PERIOD_NS = 1_000_000  # 1 kHz, valve_node's default
BAR = 1e5
STEP = """duration: 0.3
inputs:
  inlet_flow: 5 L/min
  tank_pressure: {initial: 0 bar, changes: [{at: 0.1, step: 5 bar}]}  # gauge
expect:
  - no_alarm: {}
  - never_above: {signal: tank_pressure, value: 5.01 bar}
  - never_below: {signal: tank_pressure, value: 4.99 bar, from: 0.101}
  - steady: {signal: relief_flow, flow: 5 L/min, min: 4.9 L/min, max: 5.1 L/min}
"""


def scenario_command(*args, cwd):
    return subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'scenario', *args], cwd=cwd,
        capture_output=True, text=True, timeout=RUN_TIMEOUT)


def fluid_pressures(bag, topic):
    """Return [(header stamp [ns], fluid_pressure [Pa])] of a FluidPressure topic in a bag."""
    rows = []
    for _, _, message in BagReader(bag).messages({topic}):
        decoded = deserialize_message(bytes(message.data), FluidPressure)
        rows.append((decoded.header.stamp.sec * 1_000_000_000 + decoded.header.stamp.nanosec,
                     decoded.fluid_pressure))
    return rows


@pytest.mark.timeout(RUN_TIMEOUT)
def test_a_tank_pressure_step_in_a_scenario_is_the_offline_one(tmp_path, valve_node_kernels):
    """p_s at every tick as simulate() with the same TankPressure step; the tank topics."""
    (tmp_path / 'tank.yaml').write_text(STEP)
    checked = scenario_command('check', 'tank.yaml', cwd=tmp_path)
    assert checked.returncode == 0, checked.stderr
    assert 'input tank_pressure: starts at 0 Pa (gauge), 1 change(s)' in checked.stdout
    completed = scenario_command('run', 'tank.yaml', '--out', 'out', cwd=tmp_path)
    assert completed.returncode == 0, completed.stdout + completed.stderr
    loaded = load_parameters()
    params, settings = loaded.params, loaded.settings
    ambient = settings['ambient_pressure']
    (bag,) = (tmp_path / 'out').glob('*.mcap')
    series = tick_series(bag, start_ns=START_NS, ambient_pressure=ambient)
    assert series.stamps_ns.tolist() == [START_NS + k * PERIOD_NS for k in range(301)]

    flow = 5 * LITRE_PER_MINUTE
    offline = simulate(params, FlowStep(flow, flow, end_time=0.3005),
                       step_size=settings['step_size'], record_interval=PERIOD_NS / 1e9,
                       tank=TankPressure(0.0, 5 * BAR, step_time=0.1))
    node_p_s, offline_p_s = series['supply_pressure'], offline['supply_pressure'][:301]
    np.testing.assert_allclose(node_p_s, offline_p_s, atol=1e-3 * 5 * BAR)
    assert node_p_s[-1] - node_p_s[0] == pytest.approx(5 * BAR, rel=1e-3), 'one-to-one higher'
    assert node_p_s[100] == node_p_s[0] < node_p_s[101], 'the step acts from the tick at 0.1 s'

    sent = fluid_pressures(bag, '/tank_pressure')  # absolute, stamped with the tick's start
    assert sent[0] == (START_NS, ambient)
    held = dict(sent)  # of two at one stamp (a batch's cover, then a change) the later holds
    assert all(value == ambient + (5 * BAR if stamp >= START_NS + 100 * PERIOD_NS else 0.0)
               for stamp, value in held.items())
    assert (START_NS + 100 * PERIOD_NS, ambient + 5 * BAR) in sent
    applied = dict(fluid_pressures(bag, '/applied_tank_pressure'))
    ends = [START_NS + k * PERIOD_NS for k in range(1, 301)]  # stamped at the tick's end
    np.testing.assert_allclose([applied[t] - ambient for t in ends],
                               [5 * BAR if k > 100 else 0.0 for k in range(1, 301)], atol=1e-6)

    # the series' tank_pressure and relief_flow columns, which the report's checks read
    np.testing.assert_allclose(series['tank_pressure'][1:], [applied[t] - ambient for t in ends],
                               atol=1e-6)
    assert series['relief_flow'][0] == pytest.approx(flow, rel=1e-6), 'q_r = q_in when steady'
    offline_relief = relief_flows(params, offline)[:301, RELIEF_COLUMNS.index('relief_flow')]
    np.testing.assert_allclose(series['relief_flow'], offline_relief, rtol=1e-3)
    checks = json.loads((tmp_path / 'out' / 'report.json').read_text())['checks']
    assert len(checks) == 4 and all(check['passed'] for check in checks), checks
    assert [check['measured'] for check in checks[1:3]] == [
        pytest.approx(5 * BAR, rel=1e-9), pytest.approx(5 * BAR, rel=1e-9)]


BASE = 'duration: 1\nexpect: [{no_alarm: {}}]\ninputs:\n  inlet_flow: 5 L/min\n'


def test_a_constant_tank_parameter_stays_allowed_without_the_input(tmp_path):
    """No tank_pressure input: valve.parameters.tank_pressure is the valve's constant tank."""
    path = Path(tmp_path) / 'constant.yaml'
    path.write_text(BASE + 'valve: {parameters: {tank_pressure: 2 bar}}\n')
    scenario = load_scenario(path)
    assert scenario.parameters['tank_pressure'] == 2 * BAR
    assert 'tank_pressure' not in scenario.inputs
