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
valve_simulator stepped by a client that uses only simulation_interfaces and standard topics.

One simulator process, driven in file order: its features, the state machine (stopped,
paused, a step refused while stopped), 1000 ticks stepped (StepSimulation, then the
SimulateSteps action with its feedback) with the states read from supply_pressure as
CDR bytes, playing and pausing, a reset (valve_node's ~/restart: the same process, its
start state heard again), the same 1000 ticks again in one call: the same bytes, and
the scenario runner's bytes for the same scenario (its bag); the client of
docs/scenarios.md as it stands. Then quit.
"""

import importlib.util
import re
import subprocess
import sys
import threading
import time

from mcap.reader import make_reader
import pytest
import rclpy
from rclpy.action import ActionClient
from rclpy.event_handler import SubscriptionEventCallbacks
from sensor_msgs.msg import FluidPressure
from simulation_interfaces.action import SimulateSteps
from simulation_interfaces.msg import Result, SimulationState, SimulatorFeatures
from simulation_interfaces.srv import (
    GetSimulationState,
    GetSimulatorFeatures,
    ResetSimulation,
    SetSimulationState,
    StepSimulation,
)
from valve_harness import REPO, SpinningNode, stop_node, TIMEOUT
from valve_sim.core.errors import MissingExtraError
from valve_sim.ros.lockstep import stamp_ns, START_NS
from valve_sim.ros.lockstep_protocol import gid_process
from valve_sim.ros.spinning import EXECUTORS


pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures('valve_node_kernels')]

SERVER = '/valve_simulator'
SCENARIOS_PAGE = REPO / 'docs' / 'scenarios.md'  # its Python block of node 'step_valve'
TICKS = 1000
JOIN_ATTEMPTS = 100  # single ticks stepped at most until the client sees states
JOIN_WAIT = 5.0  # [s] for a tick's state to come before the next is stepped
PERIOD_NS = 1_000_000
SCENARIO = """
scenario: stepped
description: a flow step and a fault event within the first 1000 ticks
duration: 1.0
inputs:
  inlet_flow:
    initial: 5 L/min
    changes:
      - {at: 0.25, step: 20 L/min}
events:
  - t: 0.6
    set: {fault.seat_leakage_diameter: 0.0002}
expect:
  - no_alarm: {}
"""


class SimulationClient(SpinningNode):
    """A client node of the simulator's standard services; records supply_pressure's bytes."""

    def __init__(self, context):
        self.node = rclpy.create_node('simulation_client', context=context)
        self.condition = threading.Condition()
        self.states = {}  # stamp [ns]: CDR bytes of supply_pressure
        self.matches = 0  # valve_node publishers of supply_pressure matched so far
        self.node.create_subscription(
            FluidPressure, 'supply_pressure', self._on_state, 10_000, raw=True,
            event_callbacks=SubscriptionEventCallbacks(matched=self._on_matched))
        self.clients = {name: self.node.create_client(kind, f'{SERVER}/{name}') for name, kind in (
            ('get_simulator_features', GetSimulatorFeatures),
            ('get_simulation_state', GetSimulationState),
            ('set_simulation_state', SetSimulationState),
            ('step_simulation', StepSimulation),
            ('reset_simulation', ResetSimulation))}
        self.steps = ActionClient(self.node, SimulateSteps, f'{SERVER}/simulate_steps')
        self.feedback = []
        # the action's feedback topic itself: rclpy's ActionClient drops feedback that comes
        # after the goal's result, as a loaded machine may deliver the last ticks'
        self.node.create_subscription(SimulateSteps.Impl.FeedbackMessage,
                                      f'{SERVER}/simulate_steps/_action/feedback',
                                      self._on_feedback, 10_000)
        self.spin_in_background(context, EXECUTORS['single-threaded'])

    def _on_state(self, data):
        with self.condition:
            self.states[stamp_ns(data)] = bytes(data)
            self.condition.notify_all()

    def _on_feedback(self, message):
        with self.condition:
            self.feedback.append(message.feedback)
            self.condition.notify_all()

    def _on_matched(self, status):
        with self.condition:
            self.matches = status.total_count
            self.condition.notify_all()

    def wait_for_match(self, count):
        """Wait until count publishers of supply_pressure were matched (a valve_node each)."""
        with self.condition:
            assert self.condition.wait_for(lambda: self.matches >= count, TIMEOUT), 'no match'

    def call(self, name, request):
        """Call a service and return its response (within TIMEOUT)."""
        return wait(self.clients[name].call_async(request))

    def set_state(self, state):
        request = SetSimulationState.Request(state=SimulationState(state=state))
        return self.call('set_simulation_state', request).result

    def get_state(self):
        return self.call('get_simulation_state', GetSimulationState.Request()).state.state

    def wait_for_states(self, last_ns):
        """Wait until the state stamped last_ns has come; return the states up to it."""
        with self.condition:
            assert self.condition.wait_for(lambda: last_ns in self.states, TIMEOUT), (
                f'no state at {last_ns} ns')
            return {k: v for k, v in self.states.items() if k <= last_ns}


def wait(future):
    """Block until future is done (the client spins in the background); return its result."""
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    assert done.wait(TIMEOUT), 'no answer'
    return future.result()


@pytest.fixture(scope='module')
def scenario_file(tmp_path_factory):
    """Return the path of SCENARIO written to a file."""
    path = tmp_path_factory.mktemp('scenario') / 'stepped.yaml'
    path.write_text(SCENARIO)
    return path


@pytest.fixture(scope='module')
def runner(scenario_file, tmp_path_factory):
    """
    Return the scenario runner's supply_pressure bytes by stamp for SCENARIO (its bag).

    Run before the simulator starts: two valves in one namespace would hear each other's
    /clock and inputs.
    """
    from valve_sim.analysis.scenarios.bench_scenario import load_scenario
    from valve_sim.ros.scenario_runner import run_scenario

    record = run_scenario(load_scenario(scenario_file), tmp_path_factory.mktemp('runner'),
                          progress=lambda text: None)
    with open(record.bag, 'rb') as stream:
        return {stamp_ns(message.data): bytes(message.data)
                for _, channel, message in make_reader(stream).iter_messages()
                if channel.topic == '/supply_pressure'}


@pytest.fixture(scope='module')
def simulator(context, scenario_file, runner, tmp_path_factory):
    """Start valve_simulator on SCENARIO; yields (client, scenario file, folder, process)."""
    folder = tmp_path_factory.mktemp('simulator')
    scenario = scenario_file
    with open(folder / 'simulator.log', 'w') as log:
        process = subprocess.Popen(
            [sys.executable, '-m', 'valve_sim.ros.simulation_server', str(scenario),
             '--output-dir', str(folder / 'nodes')], stdout=log, stderr=subprocess.STDOUT,
            cwd=REPO)
    client = SimulationClient(context)
    try:
        deadline = time.monotonic() + 180.0  # a valve starts first
        for name, service in client.clients.items():
            while not service.wait_for_service(timeout_sec=1.0):
                assert process.poll() is None, (folder / 'simulator.log').read_text()[-3000:]
                assert time.monotonic() < deadline, name
        assert client.steps.wait_for_server(timeout_sec=TIMEOUT)
        yield client, scenario, folder, process
    finally:
        client.close()
        stop_node(process)


def test_features_name_state_setting_stepping_and_reset(simulator):
    client, *_ = simulator
    features = client.call('get_simulator_features', GetSimulatorFeatures.Request()).features
    assert set(features.features) == {
        SimulatorFeatures.SIMULATION_RESET, SimulatorFeatures.SIMULATION_STATE_GETTING,
        SimulatorFeatures.SIMULATION_STATE_SETTING, SimulatorFeatures.SIMULATION_STATE_PAUSE,
        SimulatorFeatures.STEP_SIMULATION_SINGLE, SimulatorFeatures.STEP_SIMULATION_MULTIPLE,
        SimulatorFeatures.STEP_SIMULATION_ACTION}


def test_it_starts_stopped_and_steps_only_when_paused(simulator):
    client, *_ = simulator
    assert client.get_state() == SimulationState.STATE_STOPPED
    refused = client.call('step_simulation', StepSimulation.Request(steps=1)).result
    assert refused.result == Result.RESULT_OPERATION_FAILED and 'paused' in refused.error_message
    assert client.set_state(SimulationState.STATE_PAUSED).result == Result.RESULT_OK
    assert client.set_state(SimulationState.STATE_PAUSED).result == (
        SetSimulationState.Response.ALREADY_IN_TARGET_STATE)
    assert client.get_state() == SimulationState.STATE_PAUSED


def join(client, matches):
    """
    Step single ticks until one's state reaches the client; return the ticks stepped.

    A subscriber that joins a running publisher sees its states only once both sides
    matched: the subscriber's match event says its side has; a state that came says both.
    """
    client.wait_for_match(matches)
    for ticks in range(1, JOIN_ATTEMPTS + 1):
        with client.condition:
            before = len(client.states)
        assert client.call('step_simulation', StepSimulation.Request(steps=1)).result.result == (
            Result.RESULT_OK)
        with client.condition:
            if client.condition.wait_for(lambda: len(client.states) > before, JOIN_WAIT):
                return ticks
    raise AssertionError(f'no state came in {JOIN_ATTEMPTS} ticks')


def valve_processes(client):
    """Return the processes (PID mod 65536, Fast DDS) publishing supply_pressure."""
    return {gid_process(info.endpoint_gid)
            for info in client.node.get_publishers_info_by_topic('/supply_pressure')}


def contiguous(states, end_ns):
    """Return states (stamp: bytes) up to end_ns, asserting none is missing after the first."""
    stamps = sorted(stamp for stamp in states if stamp <= end_ns)
    assert stamps == list(range(stamps[0], end_ns + 1, PERIOD_NS)), 'a state is missing'
    return {stamp: states[stamp] for stamp in stamps}


@pytest.fixture(scope='module')
def stepped(simulator):
    """
    1000 ticks: joining, then by StepSimulation, the last 600 by SimulateSteps.

    Returns the states that came, by stamp: every one from the first to come.
    """
    client, *_ = simulator
    assert client.set_state(SimulationState.STATE_PAUSED).result in (
        Result.RESULT_OK, SetSimulationState.Response.ALREADY_IN_TARGET_STATE)
    joined = join(client, 1)
    assert client.call('step_simulation', StepSimulation.Request(
        steps=400 - joined)).result.result == Result.RESULT_OK
    goal = wait(client.steps.send_goal_async(SimulateSteps.Goal(steps=TICKS - 400)))
    assert goal.accepted
    outcome = wait(goal.get_result_async()).result
    assert outcome.result.result == Result.RESULT_OK
    with client.condition:  # feedback is a topic: it may come after the result
        assert client.condition.wait_for(
            lambda: client.feedback and client.feedback[-1].remaining_steps == 0, TIMEOUT), (
            'no feedback of the last step')
    return contiguous(client.wait_for_states(START_NS + TICKS * PERIOD_NS),
                      START_NS + TICKS * PERIOD_NS)


def test_a_step_publishes_every_tick_and_the_action_gives_feedback(simulator, stepped):
    client, *_ = simulator
    assert len(stepped) > TICKS - JOIN_ATTEMPTS, 'the client joined late'
    assert client.feedback, 'no feedback'
    done = [(f.completed_steps, f.remaining_steps) for f in client.feedback]
    assert done == sorted(done) and done[-1] == (TICKS - 400, 0)
    assert all(c + r == TICKS - 400 for c, r in done)


def test_playing_advances_the_clock_and_pausing_stops_it(simulator, stepped):
    client, *_ = simulator
    assert client.set_state(SimulationState.STATE_PLAYING).result == Result.RESULT_OK
    client.wait_for_states(START_NS + (TICKS + 50) * PERIOD_NS)
    assert client.set_state(SimulationState.STATE_PAUSED).result == Result.RESULT_OK
    with client.condition:
        last = max(client.states)
    step = client.call('step_simulation', StepSimulation.Request(steps=1)).result
    assert step.result == Result.RESULT_OK
    client.wait_for_states(last + PERIOD_NS)


def test_after_a_reset_the_same_steps_give_the_same_bytes_as_the_scenario_runner(
        simulator, stepped, runner):
    client, *_ = simulator
    valve = valve_processes(client)
    with client.condition:  # every state of the run before has come (stepped, playing)
        client.states.clear()
    assert client.call('reset_simulation', ResetSimulation.Request()).result.result == (
        Result.RESULT_OK)
    assert client.get_state() == SimulationState.STATE_STOPPED
    assert client.set_state(SimulationState.STATE_PAUSED).result == Result.RESULT_OK
    joined = join(client, 1)  # the same valve_node (its ~/restart): matched already
    assert valve_processes(client) == valve and len(valve) == 1
    assert client.call('step_simulation', StepSimulation.Request(
        steps=TICKS - joined)).result.result == Result.RESULT_OK
    end_ns = START_NS + TICKS * PERIOD_NS
    again = contiguous(client.wait_for_states(end_ns), end_ns)
    assert min(again) == START_NS  # the start state too, heard: the publisher stayed
    both = set(again) & set(stepped)
    assert len(both) > TICKS - JOIN_ATTEMPTS
    assert {stamp: again[stamp] for stamp in both} == {stamp: stepped[stamp] for stamp in both}
    assert len(set(again.values())) > 100, 'the states vary: the step and the event acted'
    assert {stamp: runner[stamp] for stamp in again} == again


def test_the_documented_client_steps_it(simulator, tmp_path):
    client, *_ = simulator
    (block,) = [block for block in re.findall(r'```python\n(.*?)```', SCENARIOS_PAGE.read_text(),
                                              flags=re.DOTALL) if "'step_valve'" in block]
    script = tmp_path / 'step_valve.py'
    script.write_text(block)
    with client.condition:
        before = max(client.states)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=TIMEOUT)
    assert done.returncode == 0, done.stderr
    match = re.fullmatch(r'stepped 200 ticks; feedback up to (\d+)/100; state 2\n', done.stdout)
    assert match and int(match[1]) <= 100, done.stdout
    client.wait_for_states(before + 200 * PERIOD_NS)


def test_quitting_ends_the_simulator(simulator):
    client, _, folder, process = simulator
    assert client.set_state(SimulationState.STATE_QUITTING).result == Result.RESULT_OK
    assert process.wait(TIMEOUT) == 0, (folder / 'simulator.log').read_text()


def test_without_simulation_interfaces_it_says_what_to_install(monkeypatch):
    """The missing package is a ValveSimError (one line) and still an ImportError."""
    for name in [name for name in sys.modules if name.startswith('simulation_interfaces')]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, 'simulation_interfaces', None)  # its import fails
    spec = importlib.util.find_spec('valve_sim.ros.simulation_server')
    with pytest.raises(MissingExtraError, match='ros-jazzy-simulation-interfaces') as refused:
        spec.loader.exec_module(importlib.util.module_from_spec(spec))
    assert isinstance(refused.value, ImportError) and '\n' not in str(refused.value)
