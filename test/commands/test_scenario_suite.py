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
Suites of scenarios on one valve_node (issue 46): `valve-sim scenario run A B C` as typed.

One suite: a seized main valve on a 21 MPa supply (a fault and a parameter the next
must not inherit), a healthy step (its messages must equal, bit for bit, those of the
same file run alone), a scenario whose event valve_node refuses (an error case: the
next starts on a fresh valve_node), and the healthy step again. The suite's JUnit has
a testsuite per scenario, its summary lists each, and the exit code says one failed.
"""

import json
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

import pytest
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.ros.lockstep import NS_PER_S, START_NS
from valve_sim.ros.scenario_runner import lockstep_messages


RUN_TIMEOUT = 600.0  # [s] node start-ups on a loaded machine, then about 1 s of model time
STUCK = """scenario: stuck
duration: 0.7
valve: {parameters: {supply_pressure_limit: 21 MPa}}
inputs: {inlet_flow: {initial: 5 L/min, changes: [{at: 0.1, step: 20 L/min}]}}
events: [{t: 0.05, set: {fault.main_valve_stuck: true}}]
expect:
  - alarm: {after: 0.1, within: 0.6}
"""
# Two parameter events inside the step's window: one sets the value in effect (no change,
# the window runs on: after STUCK's 21 MPa too, for a restart sets it back), one a new one
# (it ends the window)
HEALTHY = """scenario: healthy
duration: 0.25
inputs: {inlet_flow: {initial: 8 L/min, changes: [{at: 0.05, step: 20 L/min}]}}
events:
  - {t: 0.1, set: {supply_pressure_limit: 0}}
  - {t: 0.2, set: {damping_orifice_diameter: 0.9 mm}}
expect:
  - never_above: {signal: supply_pressure, value: 7.5 MPa}
  - no_alarm: {}
"""
REFUSED = """scenario: refused
duration: 0.2
inputs: {inlet_flow: {initial: 5 L/min}}
events: [{t: 0.1, set: {preset_pressure: 1 kPa}}]
expect:
  - no_alarm: {}
"""


def scenario_run(*paths, out):
    return subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'scenario', 'run', *map(str, paths),
         '--out', str(out)], capture_output=True, text=True, timeout=RUN_TIMEOUT)


def test_a_suite_runs_each_scenario_from_its_own_start_as_if_alone(tmp_path, valve_node_kernels):
    files = {}
    for name, text in (('stuck', STUCK), ('healthy', HEALTHY), ('refused', REFUSED)):
        files[name] = tmp_path / f'{name}.yaml'
        files[name].write_text(text)
    suite = scenario_run(files['stuck'], files['healthy'], files['refused'], files['healthy'],
                         out=tmp_path / 'suite')
    alone = scenario_run(files['healthy'], out=tmp_path / 'alone')
    assert alone.returncode == 0, alone.stdout + alone.stderr
    assert suite.returncode == 1, suite.stdout + suite.stderr  # one scenario did not complete
    assert 'valve_node started 2 time(s) for 4 scenarios' in suite.stdout, suite.stdout

    summary = (tmp_path / 'suite' / 'summary.txt').read_text()
    assert summary.splitlines()[0] == 'suite: 3 of 4 scenarios passed', summary
    assert [line.split()[:2] for line in summary.splitlines()[1:]] == [
        ['PASSED', 'stuck:'], ['PASSED', 'healthy:'], ['ERROR', 'refused:'],
        ['PASSED', 'healthy:']], summary
    root = ElementTree.parse(tmp_path / 'suite' / 'junit.xml').getroot()
    suites = root.findall('testsuite')
    assert [s.get('name') for s in suites] == ['stuck', 'healthy', 'refused', 'healthy']
    assert [s.get('errors') for s in suites] == ['0', '0', '1', '0']
    assert root.get('errors') == '1' and root.get('failures') == '0'
    assert 'the event at 0.1 s' in suites[2].find('.//error').get('message')

    # bit for bit: the healthy step after the seized valve (same valve_node), and after
    # the refused one (a fresh valve_node), records what it records alone
    bag, = (tmp_path / 'alone').glob('*.mcap')
    expected = lockstep_messages(bag)
    assert len(expected['/joint_states']) == 251
    for folder in ('2_healthy', '4_healthy'):
        bag, = (tmp_path / 'suite' / folder).glob('*.mcap')
        assert lockstep_messages(bag) == expected, folder
    for folder in (tmp_path / 'alone', tmp_path / 'suite' / '2_healthy',
                   tmp_path / 'suite' / '4_healthy'):
        assert_live_windows_are_the_reports(folder)
    # and the seized valve's fault was its own: the healthy step never raised the alarm
    stuck_log = (tmp_path / 'suite' / '1_stuck' / 'report.txt').read_text()
    assert 'PASSED' in stuck_log.splitlines()[0]


def assert_live_windows_are_the_reports(folder):
    """
    Assert that the analyser's live measures.json has the report's steps and windows (issue 41).

    The window ends at the change of damping_orifice_diameter only: a parameter set to its
    own value is no change, live as offline (the analyser knows valve_node's start values).
    """
    live = json.loads(next(folder.glob('*.measures.json')).read_text())['steps']
    offline = json.loads((folder / 'report.json').read_text())['steps']
    assert len(live) == len(offline) == 1, (live, offline)
    start = START_NS / NS_PER_S  # live times are the model clock's
    assert live[0]['t_step'] - start == pytest.approx(offline[0]['t_step'], abs=1e-9)
    cut = live[0]['details']['window_cut']
    assert cut['time'] - start == pytest.approx(0.2, abs=2e-3), cut
    assert 'damping_orifice_diameter' in cut['by'] and 'supply_pressure_limit' not in cut['by']
    for name in MEASURE_NAMES:
        assert (live[0][name] is None) == (offline[0][name] is None), name
        if live[0][name] is not None:
            assert live[0][name] == pytest.approx(offline[0][name], rel=1e-9), name
    assert all('damping_orifice_diameter' in reason for reason in live[0]['reasons'].values())


def test_check_takes_a_folder_and_names_each_broken_file(tmp_path):
    (tmp_path / 'a.yaml').write_text(HEALTHY)
    (tmp_path / 'b.yaml').write_text('scenario: b\nduration: -1\n')
    completed = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'scenario', 'check', str(tmp_path)],
        capture_output=True, text=True, timeout=RUN_TIMEOUT)
    assert completed.returncode == 1, completed.stdout + completed.stderr
    lines = completed.stdout.splitlines()
    assert lines[0].startswith('scenario healthy (')
    assert any(line.startswith(f'scenario {tmp_path / "b.yaml"}: ERROR') for line in lines)
    assert lines[-1] == '1 of 2 scenario files check'
