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
Node processes of a run stop cleanly, die with their run, and never serve another run.

The determinism bench's one failure in 100 (both nodes exit 130 at the runner's SIGINT
"after the stepping") reproduced: a run whose own nodes were still starting was
stepped by nodes another run had left behind in its domain (their parent killed: the
domain's lock went with it, the nodes spun on). Now a node process holds its run's
domain lock and gets SIGTERM when its run's process ends; a stop during a node's
start-up says so; the run's own error is not replaced by the stop's.
"""

import fcntl
import os
from pathlib import Path
import subprocess
import sys
import time

import pytest
from valve_sim.core.errors import NodeExitError, WaitTimeoutError
from valve_sim.ros import node_command
from valve_sim.ros.isolation import LOCK_FOLDER
from valve_sim.ros.node_processes import NodeProcesses


PARENT = """
import sys, time
from pathlib import Path
from valve_sim.ros import isolation, node_command
from valve_sim.ros.isolation import claim_domain
from valve_sim.ros.node_processes import NodeProcesses
domain = claim_domain(keep_existing=False)
processes = NodeProcesses(Path(sys.argv[1]), {'analyser_node': node_command(
    'analyser_node', parameters={'output_dir': sys.argv[1]})})
isolation._held_locks.pop(domain).close()  # from now on only the node can hold it
print(domain, processes.processes['analyser_node'].pid, flush=True)
time.sleep(300)
"""
pytestmark = pytest.mark.usefixtures('valve_node_kernels')  # compiled before a start
LIMIT = 120.0  # [s] a node's start or end on a loaded machine


def alive(pid):
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def held(domain):
    with open(LOCK_FOLDER / f'{domain}.lock', 'w') as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(lock, fcntl.LOCK_UN)
        return False


def until(condition, what):
    deadline = time.monotonic() + LIMIT
    while not condition():
        assert time.monotonic() < deadline, f'no {what} within {LIMIT:g} s'
        time.sleep(0.05)


def test_a_node_left_by_a_killed_run_holds_its_domain_then_ends(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != 'ROS_DOMAIN_ID'}
    parent = subprocess.Popen([sys.executable, '-c', PARENT, str(tmp_path)], env=env,
                              stdout=subprocess.PIPE, text=True)
    try:
        domain, node = map(int, parent.stdout.readline().split())
        log = tmp_path / 'analyser_node.log'
        until(lambda: 'recording' in log.read_text(), "analyser_node's start")
        assert held(domain)  # by the node alone: main's node does not hold it
        parent.kill()  # SIGKILL: no clean-up of its own
        parent.wait()
        until(lambda: not alive(node), 'end of the node left behind')  # main: never
        assert 'closed' in log.read_text()  # SIGTERM: a clean stop, its bag closed
        until(lambda: not held(domain), 'the domain free with the node gone')
    finally:
        parent.kill()


def test_a_stop_during_start_up_says_the_node_took_no_part(tmp_path):
    processes = NodeProcesses(tmp_path, {'analyser_node': node_command(
        'analyser_node', parameters={'output_dir': tmp_path})})
    with pytest.raises(NodeExitError, match='still starting when stopped'):
        processes.stop()  # at once: long before its start-up ends


def test_the_run_s_own_error_is_not_replaced_by_the_stop_s(tmp_path, monkeypatch):
    from valve_sim.analysis.scenarios.bench_scenario import load_scenario
    from valve_sim.recording.tick_bags import bag_column
    from valve_sim.ros import scenario_runner

    class Stopped:
        folder = tmp_path

        def stop(self):
            raise NodeExitError('valve_node was still starting when stopped')

    def no_driver(*args, **kwargs):
        raise WaitTimeoutError('no valve_node subscribing /clock within 180 s')

    monkeypatch.setattr(scenario_runner, 'start_nodes', lambda *args: Stopped())
    monkeypatch.setattr(scenario_runner, 'Lockstep', no_driver)
    scenario = load_scenario(Path(__file__).parents[2] / 'scenarios' / 'paper_step.yaml',
                             bag_column)
    lines = []
    with pytest.raises(WaitTimeoutError):
        scenario_runner.run_scenario(scenario, tmp_path, progress=lines.append)
    assert any('still starting' in line for line in lines)


def test_a_run_refuses_a_valve_node_another_run_left_in_its_domain(tmp_path):
    """A valve_node alone: refused by its process (GID) even while the run's own starts."""
    from valve_sim.analysis.scenarios.bench_scenario import load_scenario
    from valve_sim.core.errors import IncompleteRunError
    from valve_sim.recording.tick_bags import bag_column
    from valve_sim.ros.lockstep import lockstep_parameters
    from valve_sim.ros.scenario_runner import run_scenario

    left = tmp_path / 'left'  # as main's runner left them: no lock, no parent tie
    left.mkdir()
    commands = {'valve_node': node_command('valve_node', parameters=lockstep_parameters())}
    leftovers = [subprocess.Popen(commands['valve_node'],
                                  stdout=open(left / 'valve_node.log', 'w'),
                                  stderr=subprocess.STDOUT)]
    try:
        until(lambda: 'ready: ' in (left / 'valve_node.log').read_text(), 'leftover up')
        scenario = load_scenario(Path(__file__).parents[2] / 'scenarios' / 'paper_step.yaml',
                                 bag_column)
        with pytest.raises(IncompleteRunError, match='nodes of another run are up here'):
            run_scenario(scenario, tmp_path, progress=lambda line: None)
    finally:
        for process in leftovers:
            process.kill()
            process.wait()


def test_an_analyser_recording_outside_the_run_s_folder_is_another_run_s(tmp_path):
    """Its /diagnostics status names its bag: one outside the run's folder is refused."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from valve_sim.core.errors import IncompleteRunError
    from valve_sim.ros.scenario_runner import AnalyserStatus

    class Node:

        def create_subscription(self, *args):
            self.callback = args[2]

    def status(file):
        return DiagnosticArray(status=[DiagnosticStatus(
            name='valve_analyser: recording', values=[KeyValue(key='file', value=file)])])

    node = Node()
    analyser = AnalyserStatus(node, tmp_path)
    node.callback(status(str(tmp_path / 'valve_1.mcap')))
    assert analyser.recording([]) and analyser.values['file'].endswith('valve_1.mcap')
    node.callback(status('/tmp/elsewhere/valve_2.mcap'))
    with pytest.raises(IncompleteRunError, match='another analyser_node .* /tmp/elsewhere/'):
        analyser.recording([])


def test_the_valve_waits_for_an_analyser_more_than_max_ahead_ticks_behind(tmp_path):
    """Stepping waits while the recording lags more than MAX_AHEAD ticks (states would drop)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from valve_sim.recording.valve_topics import TICK_TOPICS
    from valve_sim.ros.scenario_runner import AnalyserStatus, MAX_AHEAD
    from valve_sim.ros.valve_outputs import STATE_QUEUE_DEPTH

    class Node:

        def create_subscription(self, *args):
            self.callback = args[2]

        def resolve_topic_name(self, topic):
            return '/' + topic

    def status(count):
        return DiagnosticArray(status=[DiagnosticStatus(
            name='valve_analyser: recording', values=[KeyValue(key='file', value=file)] + [
                KeyValue(key=f'messages /{topic}', value=str(count)) for topic in TICK_TOPICS])])

    class Driver:
        """Records its waits; each spin brings the status of an analyser 100 states further."""

        node, waits, recorded = Node(), [], 0

        def spin_until(self, condition, what, timeout):
            self.waits.append(what)
            while not condition():
                self.recorded += 100
                self.node.callback(status(self.recorded))

    file = str(tmp_path / 'valve_1.mcap')
    driver = Driver()
    analyser = AnalyserStatus(driver.node, tmp_path)
    topics = [driver.node.resolve_topic_name(topic) for topic in TICK_TOPICS]
    assert 0 < MAX_AHEAD < STATE_QUEUE_DEPTH
    analyser.keep_up(driver, topics, MAX_AHEAD)  # nothing recorded yet, but not too far ahead
    assert driver.waits == []
    analyser.keep_up(driver, topics, MAX_AHEAD + 250)
    assert len(driver.waits) == 1 and driver.recorded == 300  # waited until 250 recorded
    analyser.keep_up(driver, topics, MAX_AHEAD + 300)
    assert len(driver.waits) == 1  # already there


def test_a_driver_announces_itself_often_at_first_and_leaves_a_users_profile(monkeypatch):
    """
    lockstep_protocol.announcing: the driver's participant, up before the nodes it starts.

    Within it both Fast DDS profile variables name a file holding ANNOUNCING_PROFILE,
    gone after (the nodes it starts then do not inherit them); a user's own profile
    stays as it is; a participant created within it reads the profile without error
    (Fast DDS prints XMLPARSER errors for a profile it cannot read).
    """
    from valve_sim.ros.lockstep_protocol import announcing, ANNOUNCING_PROFILE, PROFILE_VARIABLES

    for name in PROFILE_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    with announcing():
        paths = {os.environ[name] for name in PROFILE_VARIABLES}
        assert len(paths) == 1 and Path(paths.pop()).read_text() == ANNOUNCING_PROFILE
    assert not any(name in os.environ for name in PROFILE_VARIABLES)
    monkeypatch.setenv(PROFILE_VARIABLES[0], '/the/users/profile.xml')
    with announcing():
        assert os.environ[PROFILE_VARIABLES[0]] == '/the/users/profile.xml'
        assert PROFILE_VARIABLES[1] not in os.environ
    assert os.environ[PROFILE_VARIABLES[0]] == '/the/users/profile.xml'
    monkeypatch.delenv(PROFILE_VARIABLES[0])
    participant = subprocess.run(
        [sys.executable, '-c', 'import rclpy\n'
         'from valve_sim.ros.lockstep_protocol import announcing\n'
         'context = rclpy.Context()\nrclpy.init(context=context)\n'
         "with announcing():\n    node = rclpy.create_node('driver', context=context)\n"
         'node.destroy_node()\ncontext.try_shutdown()\n'],
        capture_output=True, text=True, timeout=120)
    assert participant.returncode == 0, participant.stderr
    assert 'XMLPARSER' not in participant.stderr and 'Error' not in participant.stderr
