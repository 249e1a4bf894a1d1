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
`valve-sim scenario run/check` end to end: valve_node and analyser_node in lockstep over DDS.

Each run is the command as a user types it, in a process of its own: the shipped
examples (one passes as shipped, one with two added expectations fails on purpose),
each judged by its exit code, report.json and JUnit file; the same scenario twice,
ten ticks per /clock and one, compared message by message; batch_starts' steps; a
use_sim_time controller of the test's own that the runner waits for (--wait-topic);
malformed files, each one line naming the key.
"""

import json
from pathlib import Path
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ElementTree

import pytest
from valve_sim.analysis.scenarios.bench_scenario import load_scenario
from valve_sim.core.errors import InputFileError
from valve_sim.recording.bag import BagReader
from valve_sim.recording.valve_topics import TICK_TOPICS
from valve_sim.ros.scenario_stepper import batch_starts


ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / 'scenarios'
RUN_TIMEOUT = 600.0  # [s] a run: node start-up on a loaded machine, then a second of model time
NS_PER_S = 1_000_000_000


def scenario_command(*args, cwd):
    """Run `valve-sim scenario ARGS` in its own process; returns the CompletedProcess."""
    return subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'scenario', *args], cwd=cwd,
        capture_output=True, text=True, timeout=RUN_TIMEOUT)


def junit_cases(path):
    """Return the suite's counts and [(name, failure message or None, system-out or None)]."""
    suites = ElementTree.parse(path).getroot()
    assert suites.tag == 'testsuites'
    (suite,) = suites.findall('testsuite')
    cases = [(case.get('name'),
              case.find('failure').get('message') if case.find('failure') is not None else None,
              case.findtext('system-out'))
             for case in suite.findall('testcase')]
    counts = {key: int(suite.get(key)) for key in ('tests', 'failures', 'errors')}
    return counts, cases


def recorded(folder):
    """Return {topic: [CDR bytes]} of every valve tick topic and the inlet flow in a run's bag."""
    (bag,) = folder.glob('*.mcap')
    topics = {f'/{name}' for name in (*TICK_TOPICS, 'inlet_flow_stamped')}
    messages = {}
    for channel, _, message in BagReader(bag).messages(topics):
        messages.setdefault(channel.topic, []).append(bytes(message.data))
    return messages


@pytest.fixture(scope='module')
def stuck_valve_runs(tmp_path_factory, valve_node_kernels):
    """
    Run the shipped stuck_main_valve example twice: [(CompletedProcess, output folder)].

    The first as `scenario run` does by default (TICKS_PER_CLOCK ticks per /clock), the
    second one tick per /clock.
    """
    runs = []
    for attempt, options in enumerate(((), ('--ticks-per-clock', '1'))):
        folder = tmp_path_factory.mktemp(f'stuck_{attempt}') / 'out'
        runs.append((scenario_command('run', str(EXAMPLES / 'stuck_main_valve.yaml'),
                                      '--out', str(folder), *options, cwd=ROOT), folder))
    return runs


def test_the_stuck_valve_example_passes_with_its_reports(stuck_valve_runs):
    """Exit 0; report.json, report.txt, the figure, the bag and a JUnit case per check."""
    completed, folder = stuck_valve_runs[0]
    assert completed.returncode == 0, completed.stdout + completed.stderr
    report = json.loads((folder / 'report.json').read_text())
    assert report['passed'] is True
    assert report['run']['states'] == 801  # 0.8 s at 1 kHz, both ends
    names = [check['name'] for check in report['checks']]
    assert len(names) == 4 and all(check['passed'] for check in report['checks'])
    alarm = next(check for check in report['checks'] if check['name'].startswith('overpressure'))
    assert 0.0 < alarm['measured'] <= 0.5  # [s] after the flow step
    assert (folder / 'scenario.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    text = (folder / 'report.txt').read_text()
    assert 'PASSED, 4 of 4 checks hold' in text and text.count('  PASS  ') == 4
    counts, cases = junit_cases(folder / 'junit.xml')
    assert counts == {'tests': 4, 'failures': 0, 'errors': 0}
    assert [name for name, _, _ in cases] == names
    assert all(failure is None and out.startswith('measured ') for _, failure, out in cases)


def test_ten_ticks_per_clock_and_one_record_the_same_messages_bit_for_bit(stuck_valve_runs):
    """
    The same scenario twice, k = 10 and k = 1 ticks per /clock: equal bytes, in order.

    Header stamps and data of every state message, the applied inlet flow among them;
    the event (0.2 s) and the flow step (0.3 s) land on the same tick either way. (The
    stamped inputs sent differ by their covers, one per /clock step.)
    """
    assert stuck_valve_runs[1][0].returncode == 0, stuck_valve_runs[1][0].stdout
    first, second = (recorded(folder) for _, folder in stuck_valve_runs)
    assert sorted(first) == sorted(f'/{name}' for name in (*TICK_TOPICS, 'inlet_flow_stamped'))
    for topic in TICK_TOPICS:
        assert len(first[f'/{topic}']) == 801, topic
        assert second[f'/{topic}'] == first[f'/{topic}'], f'{topic} differs between the runs'


def test_both_runs_log_model_time_in_their_bags(stuck_valve_runs):
    """On /clock a bag's log and publish times are the model's: each state's stamp (issue 42)."""
    from valve_sim.ros.scenario_runner import lockstep_messages

    first, second = (lockstep_messages(next(folder.glob('*.mcap')), TICK_TOPICS)
                     for _, folder in stuck_valve_runs)
    assert first == second  # data and times, message by message
    stamps = [NS_PER_S + k * 1_000_000 for k in range(801)]
    for topic in TICK_TOPICS:
        assert [(log, publish) for log, publish, _ in first[f'/{topic}']] == list(
            zip(stamps, stamps)), topic


def test_a_failing_expectation_fails_the_run_and_its_junit_case(tmp_path, valve_node_kernels):
    """The paper's step with two expectations it cannot meet, at half speed: exit 1, 2 failures."""
    scenario = tmp_path / 'paper_step_too_strict.yaml'
    scenario.write_text((EXAMPLES / 'paper_step.yaml').read_text()
                        + '  - never_above: {signal: supply_pressure, value: 7.1 MPa}\n'
                        + '  - alarm: {after: 0.25, within: 0.5}\n')
    junit = tmp_path / 'ci' / 'scenario.xml'
    junit.parent.mkdir()
    completed = scenario_command('run', str(scenario), '--out', str(tmp_path / 'out'),
                                 '--junit', str(junit), '--rate', '0.5', cwd=tmp_path)
    assert completed.returncode == 1, completed.stdout + completed.stderr
    assert 'FAILED, 10 of 12 checks hold' in completed.stdout
    assert not (tmp_path / 'out' / 'junit.xml').exists()  # --junit put it elsewhere
    counts, cases = junit_cases(junit)
    assert counts == {'tests': 12, 'failures': 2, 'errors': 0}
    failures = {name: failure for name, failure, _ in cases if failure is not None}
    ceiling = failures['supply_pressure never above 7.1 MPa (the whole run)']
    assert ceiling.startswith('measured 7.') and ceiling.endswith('expected <= 7.1 MPa')
    assert failures['overpressure alarm within 0.5 s after 0.25 s'].startswith('measured none')
    report = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert report['passed'] is False
    assert report['run']['real_time_factor'] <= 0.5 * 1.001  # --rate 0.5: half speed at most
    ceiling_name = 'supply_pressure never above 7.1 MPa (the whole run)'
    peak = next(c for c in report['checks'] if c['name'] == ceiling_name)
    assert peak['measured'] > 7.1e6 and not peak['passed']  # SI in JSON, gauge [Pa]


class SlowController:
    """
    A use_sim_time node of the test's own, as a user's controller: a 1 ms timer on /clock.

    Each timer call takes a few ms of wall time (slower than the valve's tick), then
    publishes a stamped message on controller/command; the stamps it published are kept.
    """

    WORK = 0.003  # [s] of wall time per call: without lockstep it would miss ticks

    def __init__(self, context):
        import rclpy
        from geometry_msgs.msg import PointStamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter

        self.node = rclpy.create_node(
            'controller_under_test', context=context,
            parameter_overrides=[Parameter('use_sim_time', value=True)])
        self.publisher = self.node.create_publisher(PointStamped, 'controller/command', 1000)
        self.message, self.stamps = PointStamped(), []
        self.node.create_timer(0.001, self._on_timer)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on_timer(self):
        now = self.node.get_clock().now()
        if now.nanoseconds == 0:  # no /clock yet
            return
        time.sleep(self.WORK)  # the controller's computation
        self.message.header.stamp = now.to_msg()
        self.publisher.publish(self.message)
        self.stamps.append(now.nanoseconds)

    def close(self):
        self.executor.shutdown()
        self.thread.join(10.0)
        self.node.destroy_node()


def test_a_use_sim_time_controller_advances_in_lockstep_via_wait_topic(
        tmp_path, context, valve_node_kernels):
    """The runner waits for the controller's message each tick: it sees every tick, in order."""
    scenario = tmp_path / 'with_controller.yaml'
    scenario.write_text('duration: 0.2\n'
                        'inputs: {inlet_flow: {initial: 5 L/min, '
                        'changes: [{at: 0.1, step: 10 L/min}]}}\n'
                        'expect: [{no_alarm: {}}]\n')
    controller = SlowController(context)
    try:
        completed = scenario_command('run', str(scenario), '--out', str(tmp_path / 'out'),
                                     '--wait-topic', 'controller/command', cwd=tmp_path)
    finally:
        controller.close()
    assert completed.returncode == 0, completed.stdout + completed.stderr
    first_ns = 1 * NS_PER_S  # lockstep.START_NS: the first tick's /clock
    ticks = [first_ns + k * NS_PER_S // 1000 for k in range(1, 201)]
    stamps = [stamp for stamp in controller.stamps if first_ns < stamp <= ticks[-1]]
    assert stamps == ticks, 'the controller missed or repeated a tick'


TANK = 'duration: 1\nexpect: [{no_alarm: {}}]\ninputs:\n  inlet_flow: 5 L/min\n'
MALFORMED = [
    ('duration: -1\ninputs: {inlet_flow: {initial: 5 L/min}}\nexpect: [{no_alarm: {}}]\n',
     'duration'),
    ('duration: 1\ninputs: {inlet_flow: {initial: 5 furlongs}}\nexpect: [{no_alarm: {}}]\n',
     'inputs.inlet_flow.initial'),
    ('duration: 1\ninputs: {inlet_flow: {initial: 5 L/min}}\nexpect: [{sometimes: {}}]\n',
     'expect[0].sometimes'),
    ('duration: 1\ninputs: {inlet_flow: {initial: 5 L/min}}\n'
     'expect: [{measures: {at: 0.3, r_d: {max: nan}}}]\n', 'expect[0].measures.r_d.max'),
    ('duration: 1\ninputs: {inlet_flow: {initial: 5 L/min, changes: [{at: 0.2, ramp: 9 L/min}]}}'
     '\nexpect: [{no_alarm: {}}]\n', 'inputs.inlet_flow.changes[0]'),
    ('duration: 1\ninputs: {inlet_flow: {initial: 5 L/min}}\nexpect: [{no_alarm: {}}]\n'
     'valve: {parameters: {no_such_parameter: 3}}\n', 'valve.parameters.no_such_parameter'),
    ('duration: 1\ninputs: {inlet_flow: {initial: 500 L/min}}\nexpect: [{no_alarm: {}}]\n',
     'inputs.inlet_flow'),
    ('duration: 1\nexpect: [{no_alarm: {}}]\n', 'inputs'),
    ('duration: [1\n', 'line 2'),
    # the optional tank_pressure input (issue 30)
    (TANK + '  tank_pressure: {initial: 5 furlongs}\n', 'inputs.tank_pressure.initial'),
    (TANK + '  tank_pressure: {initial: 0, changes: [{at: 0.5, step: 400 bar}]}\n',
     'inputs.tank_pressure: at 0.5 s: tank pressure 4e+07'),
    (TANK + '  tank_pressure: -2 bar\n', 'inputs.tank_pressure: at 0 s: tank pressure'),
    (TANK + '  tank_pressure: {initial: 0, changes: [{at: 0.2, ramp: 3 bar}]}\n',
     'inputs.tank_pressure.changes[0]'),
    (TANK + '  tank_pressure: 1 bar\nvalve: {parameters: {tank_pressure: 2 bar}}\n',
     'valve.parameters.tank_pressure'),
    (TANK + '  tank_pressure: 1 bar\nevents: [{t: 0.2, set: {ambient_pressure: 0.9 bar}}]\n',
     'events.set.ambient_pressure'),
]


@pytest.mark.parametrize('ticks, breaks, size, expected', [
    (25, (), 10, [0, 10, 20]),
    (25, (3, 15), 10, [0, 3, 13, 15]),
    (25, (0, 10, 25, 40), 10, [0, 10, 20]),  # the ends and beyond split nothing
    (5, (2,), 1, [0, 1, 2, 3, 4]),
])
def test_batch_starts_split_the_steps_at_every_break(ticks, breaks, size, expected):
    assert batch_starts(ticks, breaks, size) == expected


@pytest.mark.parametrize('text, key', MALFORMED)
def test_a_malformed_scenario_is_one_line_naming_the_key(tmp_path, text, key):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(InputFileError) as caught:
        load_scenario(path)
    message = str(caught.value)
    assert '\n' not in message and str(path) in message and key in message, message


def test_scenario_check_says_the_problem_in_one_line_and_exits_1(tmp_path):
    (tmp_path / 'bad.yaml').write_text(MALFORMED[0][0])
    completed = scenario_command('check', 'bad.yaml', cwd=tmp_path)
    assert completed.returncode == 1
    assert completed.stderr.count('\n') == 1 and 'duration: must be in' in completed.stderr
    assert completed.stdout == ''


@pytest.mark.parametrize('name', ['paper_step', 'stuck_main_valve'])
def test_the_shipped_examples_check(name):
    scenario = load_scenario(EXAMPLES / f'{name}.yaml')
    assert scenario.name == name and scenario.expectations


def test_input_profiles_sample_steps_ramps_sines_and_a_csv_column(tmp_path):
    """Each kind at the start of the ticks it acts on; a recorded column interpolated."""
    from valve_sim.core.input_profile import parse_profile
    from valve_sim.core.quantities import FLOW

    (tmp_path / 'rig.csv').write_text('t,q\n0,10\n0.1,20\n0.2,30\n')
    profile = parse_profile(
        {'initial': '6 L/min', 'changes': [
            {'at': 0.1, 'step': '12 L/min'},
            {'at': 0.2, 'ramp': '24 L/min', 'over': 0.1},
            {'at': 0.4, 'sine': {'amplitude': '6 L/min', 'frequency': 5}, 'over': 0.1},
            {'at': 0.6, 'series': {'csv': 'rig.csv', 'time': 't', 'value': 'q',
                                   'unit': 'L/min'}}]},
        'inputs.inlet_flow', FLOW, tmp_path)
    times = [0.0, 0.099, 0.1, 0.25, 0.3, 0.45, 0.55, 0.65, 0.9]
    litres = profile.sample(times) * 60000
    assert litres == pytest.approx([6, 6, 12, 18, 24, 30, 24, 15, 30])


def test_expectations_judge_a_series_with_what_they_measured():
    """never_below, steady with its window, a step by number that is not there, no_alarm."""
    import numpy as np
    from valve_sim.analysis.scenarios.expectations import evaluate, parse_expectations
    from valve_sim.analysis.scenarios.tick_series import TickSeries

    rows = {1_000_000 * k: {'supply_pressure': 7e6 + (1e5 if k >= 100 else 0.0),
                            'main_valve': 1e-5, 'inlet_flow': 1e-4 if k < 100 else 2e-4}
            for k in range(201)}
    series = TickSeries.from_rows(rows)
    checks = evaluate(parse_expectations([
        {'never_below': {'signal': 'supply_pressure', 'value': '7 MPa'}},
        {'never_below': {'signal': 'supply_pressure', 'value': '7.05 MPa', 'to': 0.1}},
        {'steady': {'signal': 'supply_pressure', 'flow': 2e-4, 'min': '7.09 MPa',
                    'max': '7.11 MPa', 'window': 0.05}},
        {'steady': {'signal': 'supply_pressure', 'flow': 3e-4, 'max': '8 MPa'}},
        {'measures': {'step': 2, 'T_s_ms': {'max': 500}}},
        {'no_alarm': {}},
    ]), series, np.zeros(len(series)))
    assert [check.passed for check in checks] == [True, False, True, False, False, True]
    assert checks[1].measured == 7e6 and checks[2].measured == pytest.approx(7.1e6)
    assert 'never' in checks[3].detail and 'no such step' in checks[4].detail


def test_a_run_that_cannot_complete_still_writes_its_junit_with_the_error(tmp_path, monkeypatch):
    """run_and_report: the error becomes the JUnit file's one case, then is raised again."""
    from valve_sim.ros import scenario_runner

    def no_state(*_, **__):
        raise TimeoutError('no state of the valve within the limit')

    monkeypatch.setattr(scenario_runner, 'run_scenario', no_state)
    scenario = load_scenario(EXAMPLES / 'paper_step.yaml')
    for junit in (None, tmp_path / 'ci.xml'):
        with pytest.raises(TimeoutError):
            scenario_runner.run_and_report(scenario, tmp_path, junit=junit)
        counts, _ = junit_cases(junit or tmp_path / 'junit.xml')
        assert counts['errors'] == 1, counts
        error = ElementTree.parse(junit or tmp_path / 'junit.xml').find('.//error')
        assert error.get('message') == 'no state of the valve within the limit'
