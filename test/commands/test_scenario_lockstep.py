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
Lockstep you can rely on (issue 42), `valve-sim scenario run` as a user types it.

Inputs that change every tick (a flow ramp, a sine, a tank-pressure ramp) are stamped
with the model time they apply from: the run steps ten ticks per /clock as a step does,
each tick applies the value sampled for it, and the bag's log times are model time
(test_scenario.py compares two runs' bags). A run that aborts midway, and one whose expectation
cannot be judged, still write every report with what was measured. The long version,
every scenario many times under a busy loop per core, is bench/bench_determinism.py.
"""

import json
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

import pytest
from valve_sim.recording.bag import BagReader
from valve_sim.recording.cdr import read_message


RUN_TIMEOUT = 600.0  # [s] a run: node start-up on a loaded machine, then 0.3 s of model time
NS_PER_S = 1_000_000_000
PROFILES = """duration: 0.3
inputs:
  inlet_flow:
    initial: 5 L/min
    changes:
      - {at: 0.05, ramp: 15 L/min, over: 0.1}
      - {at: 0.18, sine: {amplitude: 4 L/min, frequency: 20}}
  tank_pressure:
    initial: 0 bar
    changes:
      - {at: 0.02, ramp: 3 bar, over: 0.2}
expect:
  - no_alarm: {}
"""


def scenario_run(path, out):
    return subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'scenario', 'run', str(path),
         '--out', str(out)], cwd=path.parent, capture_output=True, text=True,
        timeout=RUN_TIMEOUT)


@pytest.fixture(scope='module')
def profile_run(tmp_path_factory, valve_node_kernels):
    """Run the scenario of PROFILES: (its folder, the completed process)."""
    folder = tmp_path_factory.mktemp('profiles')
    path = folder / 'profiles.yaml'
    path.write_text(PROFILES)
    return folder / 'out', scenario_run(path, folder / 'out')


def test_inputs_changing_every_tick_run_ten_ticks_per_clock_each_tick_applying_its_own(
        profile_run):
    from valve_sim.analysis.scenarios.bench_scenario import load_scenario
    from valve_sim.ros.scenario_runner import input_values

    out, completed = profile_run
    assert completed.returncode == 0, completed.stdout + completed.stderr
    report = json.loads((out / 'report.json').read_text())
    assert report['run']['states'] == 301
    assert report['run']['clock_steps'] <= 31  # 300 ticks, 10 per /clock: none forced to 1
    (bag,) = out.glob('*.mcap')
    applied = {}
    for channel, _, message in BagReader(bag).messages({'/applied_inlet_flow'}):
        fields = read_message('sensor_msgs/msg/JointState', message.data)
        stamp = fields.header.stamp.sec * NS_PER_S + fields.header.stamp.nanosec
        applied[stamp] = fields.velocity[0]
    flows, _ = input_values(load_scenario(out.parent / 'profiles.yaml'))
    ticks = sorted(applied)[1:]  # after the first state: tick k ends at START + k + 1 ms
    assert len(set(flows)) > 150  # the flow changes at most ticks
    assert [applied[t] for t in ticks] == flows[:300].tolist()


def check_reports(out, error, names):
    """Every report of a failed run is there, says the error and holds the checks of names."""
    report = json.loads((out / 'report.json').read_text())
    assert error in report['error'] and report['passed'] is False
    assert [check['name'] for check in report['checks']] == names
    text = (out / 'report.txt').read_text()
    assert 'ERROR: the run did not complete' in text and error in text
    assert (out / 'scenario.png').stat().st_size > 10_000
    suite = ElementTree.parse(out / 'junit.xml').getroot().find('testsuite')
    assert suite.get('errors') == '1' and int(suite.get('tests')) == len(names) + 1
    assert [case.get('name') for case in suite.findall('testcase')] == [*names, 'run']
    assert error in suite.find('.//error').get('message')
    return report


PEAK = 'supply_pressure never above 7.5 MPa (the whole run)'


def test_a_run_that_aborts_writes_every_report_with_what_it_measured_to_then(
        tmp_path, valve_node_kernels):
    """An event valve_node refuses at 0.15 s stops the run there: 150 states judged."""
    path = tmp_path / 'broken.yaml'
    path.write_text(
        'duration: 0.3\ninputs: {inlet_flow: {initial: 5 L/min, changes: '
        '[{at: 0.05, ramp: 8 L/min, over: 0.2}]}}\n'
        'events: [{t: 0.15, set: {preset_pressure: 1 kPa}}]\n'
        'expect:\n  - steady: {signal: supply_pressure, flow: 5 L/min, min: 6.9 MPa, '
        'max: 7.1 MPa, window: 0.04}\n'
        '  - never_above: {signal: supply_pressure, value: 7.5 MPa}\n')
    completed = scenario_run(path, tmp_path / 'out')
    error = 'the event at 0.15 s'
    assert completed.returncode == 1 and error in completed.stderr, completed.stderr
    report = check_reports(tmp_path / 'out', error, [
        'steady supply_pressure at 5 L/min 6.9 MPa .. 7.1 MPa', PEAK])
    assert 140 <= report['run']['states'] <= 160
    assert all(check['passed'] for check in report['checks'])
    assert 6.9e6 < report['checks'][1]['measured'] < 7.5e6


def test_an_expectation_that_cannot_be_judged_keeps_the_others_and_every_report(
        profile_run, tmp_path):
    """
    An expectation whose judging raises (a LookupError) after a whole run of PROFILES.

    `scenario check` refuses every such expectation in a file (a window of -1 among them,
    test_hostile_scenarios), so the loaded one is given a signal the series does not have:
    what a judging that fails at run time leaves.
    """
    import shutil

    from valve_sim.analysis.scenarios.bench_scenario import load_scenario
    from valve_sim.analysis.scenarios.report import write_reports
    from valve_sim.ros.scenario_runner import measure_partial, RunRecord

    out, _ = profile_run
    shutil.copy(next(out.glob('*.mcap')), tmp_path)
    path = tmp_path / 'profiles.yaml'
    path.write_text(PROFILES.replace('  - no_alarm: {}\n', (
        '  - steady: {signal: supply_pressure, flow: 5 L/min, min: 6.9 MPa, max: 7.1 MPa, '
        'window: 0.02}\n  - never_above: {signal: supply_pressure, value: 7.5 MPa}\n')))
    scenario = load_scenario(path)
    scenario.expectations[0].signal = 'no_such_signal'
    record = RunRecord(scenario, tmp_path, error='the judging failed')
    measure_partial(record)
    write_reports(record)
    report = check_reports(tmp_path, 'expect[0] cannot be judged', [PEAK])
    assert report['run']['states'] == 301 and report['checks'][0]['passed']
